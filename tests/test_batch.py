"""creference batch: discovery, seeds, resume, failure isolation, the local pool and Dask. A scene
of one target and a scene of several go the same way: one result, one seed, one copy each."""

import csv
import json
import math
import shutil
import time

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.io.scene import load_scene, scene_fingerprint
from creference_bayes.workflows.batch import BatchSettings, derive_seed, discover_scenes, run_batch, run_scene
from creference_bayes.workflows.batch.engines import LocalEngine

#: Small sampler settings: the tests are about the batch, not the posterior's precision.
SMALL = BatchSettings(seed=5, sampling={"min_ess": 50, "max_steps": 500, "warmup": 200})
INVALID = {"format": "creference-scene/1", "image": {"width": 640}, "target": {}}
#: key → (seed, targets, truth_scene options)
SCENES = {"one_a": (1, 1, {"n_refs": 2}), "one_b": (2, 1, {"focal_known": True}),
          "street": (3, 3, {"sizes_known": False}), "sub/pair": (4, 2, {"horizon": "exact"})}
KEYS = ["one_a", "one_b", "street", "sub/pair"]


def write_scenes(folder, keys=KEYS):
    """The scenes of :data:`SCENES` (1 px noise, 3 annotations a target) as files below ``folder``."""
    for key in keys:
        seed, m, options = SCENES[key]
        scene, _ = truth_scene(seed, m=m, noise_px=1.0, n_annotations=3, **options)
        (folder / f"{key}.json").parent.mkdir(parents=True, exist_ok=True)
        (folder / f"{key}.json").write_text(json.dumps(scene))


def _result(out, key):
    return json.loads((out / "results" / f"{key}.json").read_text())


def _numbers(d: dict) -> dict:
    """Every number a user reads from a result (not the timings)."""
    diag = {k: v for k, v in d["diagnostics"].items() if k != "seconds"}
    return {"camera": d["camera"], "objects": d["objects"], "draws": d["draws"], "diagnostics": diag,
            "seed": d["batch"]["seed"]}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """4 scenes (1, 1, 3 and 2 targets) and an invalid one, estimated once by 2 local worker processes."""
    root = tmp_path_factory.mktemp("batch")
    scenes = root / "scenes"
    write_scenes(scenes)
    (scenes / "broken.json").write_text(json.dumps(INVALID))
    out = root / "out"
    events = []
    report = run_batch([scenes], out, LocalEngine(2), SMALL, on_event=lambda key, status: events.append((key, status)))
    return {"scenes": scenes, "out": out, "report": report, "events": events}


def test_batch_estimates_every_scene_alike_and_records_the_invalid_one(dataset):
    out, report = dataset["out"], dataset["report"]
    assert report.status == {"broken": "failed", **{k: "done" for k in KEYS}}
    assert not report.ok and report.n_targets == 1 + 1 + 3 + 2
    assert sorted(k for k, _ in dataset["events"]) == sorted(["broken", *KEYS])
    err = json.loads((out / "errors" / "broken.json").read_text())
    assert err["stage"] == "load" and "image.height" in err["error"]
    assert not (out / "results" / "broken.json").exists()
    for key in KEYS:
        res = _result(out, key)
        scene = load_scene(dataset["scenes"] / f"{key}.json")
        assert res["format"] == "creference-result/2" and len(res["objects"]) == len(scene.targets)
        assert res["scene_id"]["sha256"] == scene_fingerprint(scene)
        # the copy is the same scene, and the result knows where it is
        assert scene_fingerprint(load_scene(out / res["batch"]["scene_copy"])) == res["scene_id"]["sha256"]
        assert res["batch"]["key"] == key and res["batch"]["scene_copy"] == f"scenes/{key}.json"
        assert res["batch"]["seed"] == derive_seed(5, scene_fingerprint(scene))
        assert res["batch"]["settings"] == SMALL.to_dict() and res["provenance"]["sampling"] == SMALL.sampling
        assert 0 < res["draws"]["n"] <= 400 and len(res["draws"]["objects"]) == len(scene.targets)
    manifest = json.loads((out / "batch.json").read_text())
    assert [s["status"] for s in manifest["scenes"]] == ["failed"] + ["done"] * 4
    assert manifest["settings"] == SMALL.to_dict()


def test_summary_csv_has_one_row_per_target_with_its_class_distance_and_error(dataset):
    out = dataset["out"]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [(r["scene"], r["target"]) for r in rows] == [
        ("broken", ""), ("one_a", "t0"), ("one_b", "t0"), ("street", "t0"), ("street", "t1"), ("street", "t2"),
        ("sub/pair", "t0"), ("sub/pair", "t1")]
    assert rows[0]["status"] == "failed" and "image.height" in rows[0]["error"]
    for row in rows[1:]:
        target = next(t for t in json.loads((dataset["scenes"] / f"{row['scene']}.json").read_text())["targets"]
                      if t["id"] == row["target"])
        obj = next(o for o in _result(out, row["scene"])["objects"] if o["id"] == row["target"])
        assert row["status"] == "ok" and row["class"] == target["class"] and row["converged"] in ("true", "false")
        assert float(row["map_distance_m"]) == pytest.approx(math.hypot(obj["map"]["x"], obj["map"]["z"]), rel=1e-5)
        assert float(row["hdi_low_m"]) < float(row["mean_distance_m"]) < float(row["hdi_high_m"])
        assert float(row["sd_distance_m"]) > 0
        # Eq. 3 from the truth, computed here
        loc = np.array(target["ground_truth"]["location_m"])
        err = 100 * np.linalg.norm([obj["map"][k] - v for k, v in zip("xyz", loc)]) / np.linalg.norm(loc)
        assert float(row["location_error_pct"]) == pytest.approx(err, rel=1e-3)


def test_resume_after_deleting_two_results_recomputes_exactly_those_two(dataset, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(dataset["out"], out)
    deleted = ["one_b", "street"]
    before = {k: _result(out, k) for k in deleted}
    for k in deleted:
        (out / "results" / f"{k}.json").unlink()
    report = run_batch([dataset["scenes"]], out, LocalEngine(2), SMALL)
    assert sorted(report.keys("done")) == deleted
    assert sorted(report.keys("skipped")) == ["one_a", "sub/pair"] and report.keys("failed") == ["broken"]
    assert report.n_targets == 4
    for k in deleted:
        assert _numbers(_result(out, k)) == _numbers(before[k])


def test_dask_local_cluster_gives_identical_numbers(dataset, tmp_path):
    distributed = pytest.importorskip("distributed")
    from creference_bayes.workflows.batch.engines import DaskEngine

    inputs = [dataset["scenes"] / "one_b.json", dataset["scenes"] / "street.json"]  # one target and three
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        report = run_batch(inputs, tmp_path / "dask", DaskEngine(cluster.scheduler_address), SMALL)
    assert report.status == {"one_b": "done", "street": "done"}
    for key in report.keys("done"):
        assert _numbers(_result(tmp_path / "dask", key)) == _numbers(_result(dataset["out"], key))


def test_seed_follows_the_content_and_exactly_the_changed_scenes_are_recomputed(tmp_path):
    write_scenes(tmp_path / "a", ["one_a", "street"])
    src = tmp_path / "a" / "one_a.json"
    data = json.loads(src.read_text())
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "renamed.json").write_text(json.dumps(data, indent=3))  # same content
    settings = BatchSettings(seed=1, posterior=False)
    inputs = [tmp_path / "a", tmp_path / "b"]
    r1 = run_batch(inputs, tmp_path / "out", LocalEngine(1), settings)
    assert r1.status == {"one_a": "done", "street": "done", "renamed": "done"}
    a, b = _result(tmp_path / "out", "one_a"), _result(tmp_path / "out", "renamed")
    assert a["objects"] == b["objects"] and a["batch"]["seed"] == b["batch"]["seed"]
    data["targets"][0]["dimension_lines"][0]["corners"][0][0] += 1.0  # one pixel of one corner …
    src.write_text(json.dumps(data))
    street = tmp_path / "a" / "street.json"
    street.write_text(json.dumps(json.loads(street.read_text()), indent=4))  # … and the same content, other bytes
    r2 = run_batch(inputs, tmp_path / "out", LocalEngine(1), settings)
    assert r2.status == {"one_a": "done", "street": "skipped", "renamed": "skipped"}
    assert _result(tmp_path / "out", "one_a")["batch"]["seed"] != a["batch"]["seed"]
    # every scene when a setting changes
    r3 = run_batch(inputs, tmp_path / "out", LocalEngine(1), BatchSettings(seed=1, posterior=False,
                                                                           location_prior="flat"))
    assert set(r3.status.values()) == {"done"}


def test_time_limit_fails_the_scene_and_the_batch_goes_on(tmp_path):
    write_scenes(tmp_path / "s", ["one_a", "one_b", "street"])
    t0 = time.perf_counter()
    report = run_batch([tmp_path / "s"], tmp_path / "out", LocalEngine(2), BatchSettings(), time_limit=0.2)
    assert report.keys("failed") == ["one_a", "one_b", "street"]
    assert json.loads((tmp_path / "out" / "errors" / "street.json").read_text())["stage"] == "time limit"
    # abandoned processes are ended, not waited for: far less than three full estimates
    assert time.perf_counter() - t0 < 20


def test_run_scene_returns_an_exception_as_a_failure_record(tmp_path):
    from creference_bayes.pipeline import EstimateSettings

    write_scenes(tmp_path, ["one_a"])
    bad = EstimateSettings(posterior=False)
    object.__setattr__(bad, "model", "no-such-model")  # past the settings' own check: the estimate raises
    job = {"scene": load_scene(tmp_path / "one_a.json"), "seed": 1, "estimate": bad}
    res = run_scene(job)
    assert res["ok"] is False and res["stage"] == "estimate"
    assert "no-such-model" in res["error"] and "Traceback" in res["traceback"]


def test_discover_scenes_keys_nested_hidden_and_collisions(tmp_path):
    (tmp_path / "d" / "sub").mkdir(parents=True)
    (tmp_path / "d" / ".hidden").mkdir()
    for p in ("d/a.json", "d/sub/b.json", "d/.hidden/c.json", "d/notes.txt", "e.json"):
        (tmp_path / p).write_text("{}")
    found = discover_scenes([tmp_path / "d", tmp_path / "e.json", tmp_path / "d" / "a.json"])
    assert [(s.key, s.path.relative_to(tmp_path).as_posix()) for s in found] == [
        ("a", "d/a.json"), ("sub/b", "d/sub/b.json"), ("e", "e.json")]
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "a.json").write_text("{}")
    with pytest.raises(ValueError, match="share the name 'a'"):
        discover_scenes([tmp_path / "d", tmp_path / "f"])
    assert discover_scenes([tmp_path / "d"], exclude=tmp_path / "d" / "sub")[-1].key == "a"
    with pytest.raises(ValueError, match="no scene files"):
        discover_scenes([tmp_path / "f"], exclude=tmp_path / "f")


def test_derive_seed_depends_on_base_seed_and_content_only():
    assert derive_seed(0, "ab") == derive_seed(0, "ab")
    assert len({derive_seed(0, "ab"), derive_seed(1, "ab"), derive_seed(0, "ac")}) == 3
    assert 0 <= derive_seed(7, "f" * 64) < 2 ** 60


def test_every_setting_that_changes_the_numbers_is_compared_on_a_resume():
    from creference_bayes.models.size_priors import SizePrior

    base = BatchSettings()
    kayak = {"Kayak": SizePrior(np.array([3.5, 0.7, 0.4]), np.array([0.1, 0.1, 0.1]))}
    others = [BatchSettings(location_prior="flat"), BatchSettings(model="paper"), BatchSettings(classes=kayak),
              BatchSettings(sampling={"max_steps": 300}), BatchSettings(confidence_map="identity")]
    assert all(s.to_dict() != base.to_dict() for s in others)
    assert json.loads(json.dumps(others[2].to_dict()))["classes"]["Kayak"]  # recorded as plain JSON
    assert others[2].estimate_settings().classes == kayak
    with pytest.raises(ValueError, match="min_ess"):
        BatchSettings(sampling={"min_ess": -1})


def test_cli_batch_exit_status_summary_line_and_options(tmp_path, capsys):
    from creference_bayes.cli.main import main

    write_scenes(tmp_path / "s", ["one_a"])
    out = tmp_path / "out"
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior"]) == 0
    assert "1 scene: 1 estimated, 0 failed" in capsys.readouterr().out
    (tmp_path / "s" / "zz_bad.json").write_text("{not json")
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior"]) == 1
    captured = capsys.readouterr()
    assert "2 scenes: 0 estimated, 1 already done, 1 failed" in captured.out
    assert f"zz_bad: SceneError: {tmp_path / 's' / 'zz_bad.json'}: not valid JSON" in captured.err
    assert main(["batch", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "0"]) == 2
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--scheduler", "tcp://x:1", "--workers", "2"]) == 2
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--max-steps", "5"]) == 2
    (tmp_path / "classes.json").write_text('{"Kayak": {"length_m": 3.5}}')
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--classes", str(tmp_path / "classes.json")]) == 2
    assert "classes.json" in capsys.readouterr().err


def test_a_frame_annotated_once_takes_the_corner_scale_of_the_other_frames(tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    many, _ = truth_scene(11, m=2, noise_px=2.0, n_annotations=4)
    once, _ = truth_scene(12, m=2, noise_px=2.0, n_annotations=1)
    (scenes / "many.json").write_text(json.dumps(many))
    (scenes / "once.json").write_text(json.dumps(once))
    sets = [np.array([ann["corners"] if isinstance(ann, dict) else ann for ann in t["dimension_lines"]], float)
            for t in many["targets"]]
    ss = sum(np.sum((a - a.mean(axis=0)) ** 2) for a in sets)
    dof = sum(8 * (len(a) - 1) for a in sets)
    settings = BatchSettings(seed=1, posterior=False)
    run_batch([scenes], tmp_path / "pooled", LocalEngine(1), settings)
    copy = json.loads((tmp_path / "pooled" / "scenes" / "once.json").read_text())
    # two significant digits: at most a 5 % step
    assert copy["corner_scale"]["sd_px"] == pytest.approx(np.sqrt(ss / dof), rel=0.05)
    assert dof == 48 and copy["corner_scale"]["dof"] == 50  # one significant digit
    assert "corner_scale" not in json.loads((tmp_path / "pooled" / "scenes" / "many.json").read_text())
    got = [o["sigma_px"] for o in _result(tmp_path / "pooled", "once")["objects"]]
    assert got == pytest.approx([copy["corner_scale"]["sd_px"]] * 2, abs=1e-3)
    own = [o["sigma_px"] for o in _result(tmp_path / "pooled", "many")["objects"]]
    assert own == pytest.approx([np.sqrt(np.sum((a - a.mean(0)) ** 2) / (8 * (len(a) - 1))) for a in sets], abs=1e-3)
    from creference_bayes.cli.main import main  # --own-scale: each frame from its own annotations

    assert main(["batch", str(scenes), "--out", str(tmp_path / "alone"), "--workers", "1", "--seed", "1",
                 "--no-posterior", "--own-scale", "--quiet"]) == 0
    assert "corner_scale" not in json.loads((tmp_path / "alone" / "scenes" / "once.json").read_text())
    assert [o["sigma_px"] for o in _result(tmp_path / "alone", "once")["objects"]] == [5.0, 5.0]
    assert _result(tmp_path / "alone", "many")["objects"] == _result(tmp_path / "pooled", "many")["objects"]


def _drawn(scene, length_px, rng):
    """``scene`` with each reference segment redrawn ``length_px`` long (any direction) about its midpoint."""
    from dataclasses import replace

    refs = []
    for r in scene.references:
        mid, ang = np.mean(r.line, axis=0), rng.uniform(0, np.pi)
        half = 0.5 * length_px * np.array([np.cos(ang), np.sin(ang)])
        refs.append(replace(r, line=np.array([mid - half, mid + half])))
    return replace(scene, references=tuple(refs))


def test_the_segment_floor_is_learnt_from_the_other_frames_drawn_lengths_and_handed_back():
    """The crowd's segment floor (the marginal reading's prior of a segment's length): from the
    other frames' drawn lengths with the noise the model assumes (2 × their corner scale), leaving
    the frame out; a crowd that draws only long segments gets a floor of many σ, one whose
    segments are as long as noise alone draws them a floor below σ; handed back as
    ``read_floor_px`` unless the option is set (an override); too few segments: none."""
    import warnings

    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.scene import parse_scene
    from creference_bayes.models.metrology import corner_spread
    from creference_bayes.workflows.batch import MIN_FLOOR_SEGMENTS, hand_segments, segment_floors

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scenes = [parse_scene(simulate_scene(np.random.default_rng(k), tier="light", n_references=10,
                                             n_target_annotations=4)) for k in range(4)]
    spread = np.array([[v.sum() for v in corner_spread([t.corners for t in s.targets])] for s in scenes])
    rng = np.random.default_rng(5)
    long = [_drawn(s, 40 * 2 * np.sqrt(ss / dof), rng) for s, (ss, dof) in zip(scenes, spread)]
    short = [_drawn(s, 0.5 * 2 * np.sqrt(ss / dof), rng) for s, (ss, dof) in zip(scenes, spread)]
    for drawn, lo, hi in ((long, 10, 60), (short, 0, 1)):
        for k, g in enumerate(segment_floors(drawn)):
            ss, dof = spread.sum(axis=0) - spread[k]
            assert g["segments"] == 30 and g["noise_px"] == pytest.approx(2 * np.sqrt(ss / dof), rel=0.05)
            assert lo * g["noise_px"] < g["floor_px"] < hi * g["noise_px"]
    # the frame's own segments do not count: a frame redrawn short keeps its floor, the others' fall
    mixed = segment_floors([short[0], *long[1:]])
    assert mixed[0] == segment_floors(long)[0] and mixed[1]["floor_px"] < segment_floors(long)[1]["floor_px"]
    assert segment_floors(long[:2])[0] is None and MIN_FLOOR_SEGMENTS > 10  # 10 other segments: too few
    handed = hand_segments(long, BatchSettings())
    assert [h[0] for h in handed] == [{"read_floor_px": g["floor_px"]} for g in segment_floors(long)]
    assert handed[0][1]["segment_floor_px"]["from"] == "data set"
    over = hand_segments(long, BatchSettings(options={"read_floor_px": 3.0}))
    assert over[0] == ({}, {"segment_floor_px": {"from": "override", "why": "--option read_floor_px=3"}})
    assert hand_segments(long, BatchSettings(pool_scale=False)) == [({}, {})] * 4


def test_model_options_reach_every_result_and_a_result_of_another_ground_prior_is_recomputed(tmp_path, capsys):
    """``--option`` (and ``BatchSettings.options``) reach the estimates; a resume compares them, and
    compares the ground prior a multi-object result records with the one it would now be made under:
    a result of the earlier default (no ``provenance.ground``) is recomputed, a one-target result
    (whose ground offsets are fixed) is not."""
    from creference_bayes.cli.main import main

    write_scenes(tmp_path / "s", ["one_a", "street"])
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior", "--quiet"]
    assert main(args) == 0
    street = _result(out, "street")
    assert street["provenance"]["ground"]["dof"] == pytest.approx(2.0)  # the default: a t of 2 dof
    # an older result: no ground recorded (made under the normal of 8 cm)
    del street["provenance"]["ground"]
    (out / "results" / "street.json").write_text(json.dumps(street))
    report = run_batch([tmp_path / "s"], out, LocalEngine(1), BatchSettings(posterior=False))
    assert report.status == {"one_a": "skipped", "street": "done"}
    assert _result(out, "street")["provenance"]["ground"]["sd_per_m"] == pytest.approx(0.0017)
    # the earlier prior asked for explicitly: every scene again, with it recorded
    earlier = ["--option", "ground_sd_m=0.08", "--option", "ground_sd_per_m=0", "--option", "ground_dof=inf"]
    loud = [a for a in args if a != "--quiet"]
    capsys.readouterr()
    assert main(loud + earlier) == 0
    assert "2 scenes: 2 estimated, 0 failed" in capsys.readouterr().out
    street = _result(out, "street")
    assert street["provenance"]["ground"] == {"sd_m": 0.08, "sd_per_m": 0.0, "dof": None,
                                              "tilt_sd_rad": pytest.approx(np.radians(1.0))}
    assert street["provenance"]["options"]["ground_dof"] == "inf"
    assert street["batch"]["settings"]["options"] == {"ground_dof": "inf", "ground_sd_m": 0.08,
                                                      "ground_sd_per_m": 0.0}
    assert main(loud + earlier[2:] + earlier[:2]) == 0  # the same options in another order: up to date
    assert "2 scenes: 0 estimated, 2 already done, 0 failed" in capsys.readouterr().out
    r = run_batch([tmp_path / "s"], out, LocalEngine(1),
                  BatchSettings(posterior=False, options={"ground_sd_m": 0.08, "ground_sd_per_m": 0.0,
                                                          "ground_dof": math.inf}))
    assert set(r.status.values()) == {"skipped"}
    with pytest.raises(ValueError, match="'sigma'"):
        BatchSettings(options={"sigma": 3.0})  # the paper model's, not the metrology model's


def test_cli_model_options_are_typed_and_bad_ones_are_named(tmp_path, capsys):
    from creference_bayes.cli.main import main

    out = tmp_path / "r.json"
    assert main(["demo", "--no-posterior", "--quiet", "--out", str(out), "--option", "target_dof=7",
                 "--option", "line_reading=corrected"]) == 0
    assert json.loads(out.read_text())["provenance"]["options"] == {"line_reading": "corrected", "target_dof": 7.0}
    for bad, words in ((["ground_dof=abc"], ["ground_dof", "'abc'"]), (["nope=1"], ["nope", "target_dof"]),
                       (["ground_sd_m"], ["'ground_sd_m'", "KEY=VALUE"]), (["ground_sd_m=-1"], ["ground_sd_m", "-1"]),
                       (["target_dof=3", "target_dof=4"], ["target_dof", "twice"]),
                       (["ground_sd_m=nan"], ["ground_sd_m", "'nan'"])):
        argv = ["demo", "--no-posterior", "--quiet"] + [x for b in bad for x in ("--option", b)]
        assert main(argv) == 2, bad
        err = capsys.readouterr().err
        assert all(w in err for w in words), (bad, err)
    assert main(["batch", str(tmp_path), "--out", str(tmp_path / "b"), "--model", "paper", "--option",
                 "ground_sd_m=0.1"]) == 2
    assert "the paper model has no such option" in capsys.readouterr().err
    # a value out of range is refused before the batch reads a scene or writes a file
    assert main(["batch", str(tmp_path), "--out", str(tmp_path / "b"), "--option", "ground_tilt_sd_rad=-0.1"]) == 2
    assert "--option ground_tilt_sd_rad: expected a finite number >= 0 (radians), got -0.1" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_cli_batch_summary_line_counts_the_scenes_not_converged(tmp_path, capsys):
    """A scene whose posterior did not converge is not counted among the estimated ones (issue 64)."""
    from creference_bayes.cli.main import main

    write_scenes(tmp_path / "s", ["one_a", "one_b"])
    out = tmp_path / "out"
    # one_b's sampler gets an effective sample size it cannot reach in 300 steps
    args = ["--out", str(out), "--workers", "1", "--max-steps", "300"]
    assert main(["batch", str(tmp_path / "s" / "one_a.json"), "--min-ess", "50", *args]) == 0
    line = capsys.readouterr().out
    assert "1 scene: 1 estimated, 0 failed" in line and "converged" not in line
    assert main(["batch", str(tmp_path / "s"), "--min-ess", "100000", *args]) == 0
    rows = {r["scene"]: r["converged"] for r in csv.DictReader((out / "summary.csv").open())}
    assert rows == {"one_a": "false", "one_b": "false"}  # one_a again: the settings changed
    assert "2 scenes: 0 estimated and converged, 2 not converged (see summary.csv), 0 failed" in capsys.readouterr().out
    # a result already done that did not converge is counted so on a rerun
    (tmp_path / "s" / "zz_bad.json").write_text("{not json")
    assert main(["batch", str(tmp_path / "s"), "--min-ess", "100000", *args]) == 1
    assert "3 scenes: 0 estimated and converged, 2 not converged (see summary.csv), 1 failed" in capsys.readouterr().out


def test_a_batch_with_a_classes_file_can_be_plotted_and_advised(tmp_path, capsys):
    """The result and the scene copy carry the priors of --classes: plot and advise need no classes file."""
    from creference_bayes.cli.main import main

    scene, _ = truth_scene(1, m=1, noise_px=1.0, n_annotations=3, sizes_known=False)
    scene["targets"][0]["class"] = "Kayak"  # no shipped class: only the classes file knows it
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "kayak.json").write_text(json.dumps(scene))
    (tmp_path / "classes.json").write_text('{"Kayak": {"length_m": 3.5, "width_m": 0.7, "height_m": 0.4}}')
    out = tmp_path / "out"
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior",
                 "--classes", str(tmp_path / "classes.json")]) == 0
    copy = load_scene(out / "scenes" / "kayak.json")  # without the classes file
    assert copy.size_prior("Kayak").median_m == pytest.approx((3.5, 0.7, 0.4))
    assert scene_fingerprint(copy) == _result(out, "kayak")["scene_id"]["sha256"]
    capsys.readouterr()
    assert main(["plot", str(out / "results" / "kayak.json"), "--out", str(tmp_path / "figs"), "--quiet"]) == 0
    assert (tmp_path / "figs" / "boxes.png").is_file()
    assert main(["advise", str(out / "results" / "kayak.json"), "--draws", "50", "--futures", "10",
                 "--out", str(tmp_path / "advice.json"), "--quiet"]) == 0
    assert "Kayak" not in capsys.readouterr().err


def test_cli_batch_prints_a_line_per_finished_scene_when_stderr_is_not_a_terminal(tmp_path, capsys):
    """A batch run into a log file said nothing until its end (issue 64): a line per scene, with its
    key, how it ended and its time; --quiet prints none."""
    import re

    from creference_bayes.cli.main import main

    write_scenes(tmp_path / "s", ["one_a", "one_b"])
    (tmp_path / "s" / "zz_bad.json").write_text("{not json")
    args = ["batch", str(tmp_path / "s"), "--workers", "1", "--no-posterior"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 1  # capsys: standard error is not a terminal
    err = capsys.readouterr().err.splitlines()
    lines = [line for line in err if line.startswith("batch ")]
    assert len(lines) == 2, err  # the scenes estimated; the one that failed to load is named below them
    for line, key in zip(sorted(lines), ["one_a", "one_b"]):
        m = re.fullmatch(rf"batch [23]/3: {key} estimated in (\d+\.\d) s; 1 failed \((\d+) s\)", line)
        assert m, line
    assert main([*args, "--out", str(tmp_path / "quiet"), "--quiet"]) == 1
    assert not [line for line in capsys.readouterr().err.splitlines() if line.startswith("batch ")]
