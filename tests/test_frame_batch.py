"""creference batch and creference labels on frames (creference-scene/2): a frame is the unit."""

import csv
import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

from creference_bayes.bench.frame_simulate import simulate_frame
from creference_bayes.bench.runner import write_scenes
from creference_bayes.frame_pipeline import estimate_frame
from creference_bayes.io.frame_result import stored_draws
from creference_bayes.io.frame_scene import frame_fingerprint, load_frame, parse_frame
from creference_bayes.workflows.batch import BatchSettings, derive_seed, run_batch
from creference_bayes.workflows.batch.engines import LocalEngine
from creference_bayes.workflows.labels import export_labels

#: Small sampler budgets: the tests are about the batch and the labels, not the posterior.
FRAME_SAMPLING = {"n_chains": 4, "warmup": 100, "chunk": 100, "max_iterations": 200, "min_ess": 20}
SMALL = BatchSettings(seed=3, sampling={"n_ensembles": 2, "n_walkers": 16, "tau_multiple": 20, "min_ess": 100},
                      frame_sampling=FRAME_SAMPLING)
FRAMES = ["frame_0000", "frame_0001", "frame_0002"]


def _write_frames(folder, n=3, seed=4):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for k in range(n):
        scene = simulate_frame(rng, n_objects=2 + k % 2, n_annotations=3)
        (folder / f"frame_{k:04d}.json").write_text(json.dumps(scene))


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """3 simulated frames (2, 3 and 2 objects) and one one-target scene, by 2 local workers."""
    root = tmp_path_factory.mktemp("frame_batch")
    scenes = root / "scenes"
    _write_frames(scenes)
    write_scenes(scenes / "single", 1, seed=2, tier="low")
    report = run_batch([scenes], root / "out", LocalEngine(2), SMALL)
    return {"root": root, "scenes": scenes, "out": root / "out", "report": report}


def _result(out, key):
    return json.loads((out / "results" / f"{key}.json").read_text())


def _numbers(d: dict) -> dict:
    """Every number a user reads from a frame result (not the timings)."""
    diag = {k: v for k, v in d["diagnostics"].items() if k != "seconds"}
    return {"camera": d["camera"], "objects": d["objects"], "draws": d["draws"], "diagnostics": diag,
            "seed": d["batch"]["seed"]}


def test_frames_and_a_scene_are_estimated_each_with_its_own_settings(batch):
    out, report = batch["out"], batch["report"]
    assert report.status == {**{k: "done" for k in FRAMES}, "single/scene_0000": "done"}
    assert report.n_targets == 2 + 3 + 2 + 1
    for key in FRAMES:
        res = _result(out, key)
        frame = load_frame(batch["scenes"] / f"{key}.json")
        assert res["format"] == "creference-result/2" and len(res["objects"]) == len(frame.targets)
        assert res["scene_id"]["sha256"] == frame_fingerprint(frame)
        assert res["batch"]["seed"] == derive_seed(3, frame_fingerprint(frame))
        assert res["batch"]["settings"] == SMALL.frame_dict()
        assert res["provenance"]["sampling"] == FRAME_SAMPLING
        # the copy is the same frame
        assert frame_fingerprint(load_frame(out / res["batch"]["scene_copy"])) == res["scene_id"]["sha256"]
        # the draws kept: ≤ 400, as many per object as for the camera
        assert 0 < res["draws"]["n"] <= 400 and res["draws"]["of"] == 4 * 200
        assert len(res["draws"]["objects"]) == len(frame.targets)
    single = _result(out, "single/scene_0000")
    assert single["format"] == "creference-result/1" and single["batch"]["settings"] == SMALL.to_dict()
    assert json.loads((out / "batch.json").read_text())["frame_settings"] == SMALL.frame_dict()


def test_summary_has_one_row_per_object_with_its_class_and_error(batch):
    out = batch["out"]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [(r["scene"], r["target"]) for r in rows][:7] == [
        ("frame_0000", "t0"), ("frame_0000", "t1"), ("frame_0001", "t0"), ("frame_0001", "t1"),
        ("frame_0001", "t2"), ("frame_0002", "t0"), ("frame_0002", "t1")]
    assert rows[7]["scene"] == "single/scene_0000" and rows[7]["class"] == "" and rows[7]["map_distance_m"]
    for row in rows[:7]:
        scene = json.loads((batch["scenes"] / f"{row['scene']}.json").read_text())
        target = next(t for t in scene["targets"] if t["id"] == row["target"])
        obj = next(o for o in _result(out, row["scene"])["objects"] if o["id"] == row["target"])
        assert row["class"] == target["class"] and row["status"] == "ok"
        assert row["converged"] in ("true", "false")
        assert float(row["map_distance_m"]) == pytest.approx(math.hypot(obj["map"]["x"], obj["map"]["z"]), rel=1e-5)
        assert float(row["hdi_low_m"]) < float(row["mean_distance_m"]) < float(row["hdi_high_m"])
        # Eq. 3 from the truth, computed here
        loc = np.array(target["ground_truth"]["location_m"])
        err = 100 * np.linalg.norm([obj["map"]["x"] - loc[0], obj["map"]["y"] - loc[1], obj["map"]["z"] - loc[2]]) \
            / np.linalg.norm(loc)
        assert float(row["location_error_pct"]) == pytest.approx(err, rel=1e-3)


def test_one_worker_gives_the_numbers_of_two(batch, tmp_path):
    report = run_batch(sorted(batch["scenes"].glob("frame_*.json")), tmp_path / "one", LocalEngine(1), SMALL)
    assert report.status == {k: "done" for k in FRAMES}
    for key in FRAMES:
        assert _numbers(_result(tmp_path / "one", key)) == _numbers(_result(batch["out"], key))


def test_resume_recomputes_exactly_the_changed_frame(batch, tmp_path):
    scenes, out = tmp_path / "scenes", tmp_path / "out"
    shutil.copytree(batch["scenes"], scenes)
    shutil.copytree(batch["out"], out)
    path = scenes / "frame_0001.json"
    data = json.loads(path.read_text())
    data["targets"][1]["dimension_lines"][0]["corners"][0][0] += 1.0  # one pixel of one corner
    path.write_text(json.dumps(data, indent=1))
    (scenes / "frame_0000.json").write_text(json.dumps(json.loads((scenes / "frame_0000.json").read_text()),
                                                       indent=4))  # same content, other bytes
    before = {k: (out / "results" / f"{k}.json").read_bytes() for k in FRAMES}
    report = run_batch([scenes], out, LocalEngine(2), SMALL)
    assert report.keys("done") == ["frame_0001"]
    assert sorted(report.keys("skipped")) == ["frame_0000", "frame_0002", "single/scene_0000"]
    assert (out / "results" / "frame_0000.json").read_bytes() == before["frame_0000"]
    new = _result(out, "frame_0001")
    assert new["scene_id"]["sha256"] == frame_fingerprint(load_frame(path))
    assert new["objects"][1]["map"] != json.loads(before["frame_0001"])["objects"][1]["map"]
    # a frame setting changes the frames' numbers, not the one-target scene's
    other = BatchSettings(**{**SMALL.__dict__, "frame_sampling": {**FRAME_SAMPLING, "max_iterations": 300}})
    report = run_batch([scenes], out, LocalEngine(2), other)
    assert sorted(report.keys("done")) == FRAMES and report.keys("skipped") == ["single/scene_0000"]


def test_labels_of_a_frame_batch_one_file_per_image_from_the_shared_camera(batch, tmp_path):
    export = export_labels(batch["out"], tmp_path / "labels")
    assert export.images == FRAMES + ["scene_0000"] and not export.skipped
    for key in FRAMES:
        scene = json.loads((batch["scenes"] / f"{key}.json").read_text())
        res = _result(batch["out"], key)
        lines = (tmp_path / "labels" / "label_2" / f"{key}.txt").read_text().splitlines()
        assert [ln.split()[0] for ln in lines] == [t["class"] for t in scene["targets"]]
        assert (tmp_path / "labels" / "calib" / f"{key}.txt").read_text().startswith("P0: ")
        side = json.loads((tmp_path / "labels" / "uncertainty" / f"{key}.json").read_text())
        assert side["camera"]["posterior"] == res["camera"]["posterior"]
        for line, obj, o in zip(lines, side["objects"], res["objects"]):
            # the label is the MAP box in the gravity-aligned frame: x, y, z of the result's MAP
            x, y, z = map(float, line.split()[11:14])
            assert (x, y, z) == pytest.approx((o["map"]["x"], o["map"]["y"], o["map"]["z"]), abs=0.006)
            assert obj["posterior"] == o["posterior"] and obj["quality"]["n_draws"] == res["draws"]["n"]
            assert float(line.split()[15]) == pytest.approx(obj["quality"]["p_iou_ge_0.7"], abs=1e-4)
            assert 0.0 <= obj["true_iou"] <= 1.0 and obj["draws"]["n"] == 100
            assert len(obj["draws"]["x"]) == len(side["camera"]["draws"]["focal_length_px"]) == 100
    from creference_bayes.workflows.labels.report import write_report

    write_report(export, tmp_path / "labels", figure=False)
    rows = list(csv.DictReader((tmp_path / "labels" / "labels.csv").open()))
    assert [(r["image"], r["target"]) for r in rows][:3] == [("frame_0000", "t0"), ("frame_0000", "t1"),
                                                            ("frame_0001", "t0")]
    assert len(rows) == 8 and rows[-1]["image"] == "scene_0000"  # the one-target scene as before


def test_stored_draws_are_the_samplers_evenly_spaced(tmp_path):
    frame = parse_frame(simulate_frame(np.random.default_rng(8), n_objects=2, n_annotations=3))
    res = estimate_frame(frame, seed=1, sampling=FRAME_SAMPLING)
    d = json.loads(json.dumps(res.to_dict()))
    kept = stored_draws(d)
    cams = res.draws.cameras.reshape(-1, 5)
    idx = np.unique(np.linspace(0, len(cams) - 1, 400).round().astype(int))
    assert kept.cameras.shape == (1, len(idx), 5) and kept.objects.shape == (1, len(idx), 2, 7)
    np.testing.assert_allclose(kept.cameras[0], cams[idx], atol=1e-5)
    assert isinstance(d["draws"]["camera"]["ref_scale"], float)  # fixed (no references): one number
    assert estimate_frame(frame, seed=1, posterior=False).to_dict().get("draws") is None
    with pytest.raises(ValueError, match="draws"):
        stored_draws({**d, "draws": {**d["draws"], "n": 3}})


def test_the_copy_of_a_frame_keeps_its_camera_priors():
    """frame_to_dict kept no focal length or orientation prior: a changed prior did not change the
    fingerprint (the batch would not rerun the frame) and the copy lost it."""
    scene = simulate_frame(np.random.default_rng(1), n_objects=2, n_annotations=2)
    a = {**scene, "camera": {**scene["camera"], "focal_length_prior": {"median_px": 900.0, "log_sd": 0.2}}}
    b = {**scene, "camera": {**scene["camera"], "focal_length_prior": {"median_px": 1200.0, "log_sd": 0.2}}}
    assert frame_fingerprint(parse_frame(a)) != frame_fingerprint(parse_frame(b))


def test_frames_without_posterior_are_not_labelled(tmp_path):
    _write_frames(tmp_path / "scenes", n=1)
    run_batch([tmp_path / "scenes"], tmp_path / "out", LocalEngine(1), BatchSettings(posterior=False))
    export = export_labels(tmp_path / "out", tmp_path / "labels")
    assert not export.objects and "no posterior draws" in export.skipped[0]["reason"]


def test_the_kitti_path_on_the_command_line(tmp_path):
    """simulate --from-kitti → batch → labels → evaluate kitti, on the synthetic KITTI folder."""
    from test_kitti_frames import P2, write_kitti_folder

    kitti = write_kitti_folder(tmp_path / "kitti")

    def run(*args):
        proc = subprocess.run([sys.executable, "-m", "creference_bayes", *map(str, args)], capture_output=True,
                              text=True, timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout

    run("simulate", "--from-kitti", kitti, "--out", "scenes", "--annotations", "3")
    run("batch", "scenes", "--out", "batch", "--workers", "1", "--max-iterations", "200", "--min-ess", "20")
    out = run("labels", "batch", "--out", "labels")
    assert "wrote 3 labels for 1 images" in out
    lines = (tmp_path / "labels" / "label_2" / "000007.txt").read_text().splitlines()
    assert [ln.split()[0] for ln in lines] == ["Car", "Pedestrian", "Car"]
    calib = (tmp_path / "labels" / "calib" / "000007.txt").read_text()
    p2 = np.array([float(v) for v in next(ln for ln in calib.splitlines() if ln.startswith("P2:")).split()[1:]])
    np.testing.assert_allclose(p2.reshape(3, 4), P2, rtol=1e-9)  # KITTI's own P2: labels in its frame
    side = json.loads((tmp_path / "labels" / "uncertainty" / "000007.json").read_text())
    assert "kitti_p2" in side["frame"]["name"] and all("true_iou" in o for o in side["objects"])
    assert (tmp_path / "labels" / "report.md").is_file() and (tmp_path / "labels" / "quality.png").is_file()
    out = run("evaluate", "kitti", kitti / "label_2", tmp_path / "labels" / "label_2")
    assert "AP R40" in out and "Car         0.7  3D" in out


def test_load_batch_leaves_frames_to_callers_that_take_them(batch):
    """creference advise reads a batch with load_batch and takes one-target results only."""
    from creference_bayes.workflows.labels import LabelInput, load_batch

    inputs, skipped = load_batch(batch["out"])
    assert [i.key for i in inputs] == ["single/scene_0000"] and isinstance(inputs[0], LabelInput)
    assert sorted(s["key"] for s in skipped) == FRAMES and "a frame" in skipped[0]["reason"]
    inputs, skipped = load_batch(batch["out"], frames=True)
    assert len(inputs) == 4 and not skipped
