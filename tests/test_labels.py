"""creference labels: KITTI files that reproject onto the annotations, sidecars, the report; any
scene (one target or several, several scenes of one photo) and results of an earlier batch
(creference-result/1)."""

import json
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.cli.main import main
from creference_bayes.core.geometry import box_points, box_vertices, project, rotation_from_pitch_roll
from creference_bayes.io.scene import load_scene
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.engines import Engine
from creference_bayes.workflows.labels import export_labels
from creference_bayes.workflows.labels.report import write_report

SAMPLING = {"min_ess": 50, "max_steps": 500, "warmup": 200}
V1 = Path(__file__).parent / "data" / "batch_v1"  # a batch folder written by creference-bayes 0.1 (result/1)
IMAGES = ["photo_017", "photo_021", "s1", "street_004"]


class ThreadEngine(Engine):
    """One worker thread in this process: no process start-up in tests that are not about engines."""

    name = "thread"

    def __init__(self):
        self._executor = ThreadPoolExecutor(1)

    @property
    def executor(self):
        return self._executor

    def slots(self):
        return 1

    def close(self, abandon=False):
        self._executor.shutdown(wait=not abandon, cancel_futures=abandon)


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """A scene of one target without an image, a street of three targets with unknown sizes, two
    scenes of one photo (known focal length, exact horizon) and the result of an earlier batch."""
    root = tmp_path_factory.mktemp("labels")
    scenes = root / "scenes"
    scenes.mkdir()
    one, _ = truth_scene(11, noise_px=1.0, n_annotations=3, n_refs=2)
    (scenes / "s1.json").write_text(json.dumps(one))
    street, _ = truth_scene(12, m=3, noise_px=1.0, n_annotations=3, sizes_known=False)
    street["image"]["path"] = "images/street_004.png"
    (scenes / "street.json").write_text(json.dumps(street))
    photo, _ = truth_scene(13, m=2, noise_px=1.0, n_annotations=3, focal_known=True, horizon="exact")
    photo["image"]["path"] = "images/photo_021.png"
    for key, target, name in (("photo_a", photo["targets"][0], "crate 1"), ("photo_b", photo["targets"][1], "crate 2")):
        del target["class"]
        (scenes / f"{key}.json").write_text(json.dumps({**photo, "targets": [{**target, "id": name}]}))
    out = root / "batch"
    report = run_batch([scenes], out, ThreadEngine(), BatchSettings(seed=3, sampling=SAMPLING))
    assert report.ok, report.errors
    shutil.copytree(V1, out, dirs_exist_ok=True)
    labels = root / "labels"
    assert main(["labels", str(out), "--out", str(labels), "--quiet"]) == 0
    return {"scenes": scenes, "batch": out, "labels": labels}


def _side(batch, name) -> dict:
    return json.loads((batch["labels"] / "uncertainty" / f"{name}.json").read_text())


def _result(batch, key) -> dict:
    return json.loads((batch["batch"] / "results" / f"{key}.json").read_text())


# ------------------------------------------------------------------------------------------------
# The reprojection check, written as KITTI tooling does it (independently of the package's code)


def _read_calib(path) -> dict:
    calib = {}
    for line in path.read_text().splitlines():
        key, values = line.split(":", 1)
        calib[key] = np.array([float(v) for v in values.split()])
    return calib


def _read_labels(path) -> list[dict]:
    objs = []
    for line in path.read_text().splitlines():
        v = line.split()
        objs.append({"type": v[0], "truncated": float(v[1]), "occluded": int(v[2]), "alpha": float(v[3]),
                     "bbox": np.array(v[4:8], float), "hwl": np.array(v[8:11], float),
                     "loc": np.array(v[11:14], float), "ry": float(v[14]), "score": float(v[15])})
    return objs


def _kitti_corners(obj) -> np.ndarray:
    """The devkit's computeBox3D: 8 corners (3, 8) of a label in the rectified camera frame."""
    h, w, l = obj["hwl"]
    ry = obj["ry"]
    R = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    x = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    y = [0, 0, 0, 0, -h, -h, -h, -h]
    z = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    return R @ np.array([x, y, z]) + obj["loc"][:, None]


def _project_kitti(P2, corners) -> np.ndarray:
    uvw = P2.reshape(3, 4) @ np.vstack([corners, np.ones(corners.shape[1])])
    return (uvw[:2] / uvw[2]).T  # (8, 2)


def _set_distance(a, b) -> float:
    """Largest distance from a point of ``a`` to its nearest point of ``b``."""
    return float(np.max(np.min(np.linalg.norm(a[:, None] - b[None], axis=-1), axis=1)))


def test_kitti_boxes_projected_with_p2_land_on_the_estimate_and_the_annotations(batch):
    labels, out = batch["labels"], batch["batch"]
    assert sorted(p.stem for p in (labels / "label_2").glob("*.txt")) == IMAGES
    for name in ("photo_021", "s1", "street_004"):
        P2 = _read_calib(labels / "calib" / f"{name}.txt")["P2"]
        side = _side(batch, name)
        objs = _read_labels(labels / "label_2" / f"{name}.txt")
        assert len(objs) == len(side["objects"]) == {"photo_021": 2, "s1": 1, "street_004": 3}[name]
        for obj, entry in zip(objs, side["objects"]):
            uv = _project_kitti(P2, _kitti_corners(obj))
            result = _result(batch, entry["scene"])
            scene = load_scene(out / "scenes" / f"{entry['scene']}.json")
            i = [t.id for t in scene.targets].index(entry["target"])
            cam, m = result["camera"]["map"], result["objects"][i]["map"]
            # the estimate's own box, projected with its own camera
            corners = box_points(np.array([m["x"], m["y"], m["z"], m["yaw"]]),
                                 box_vertices(m["length_m"], m["width_m"], m["height_m"]))
            own, _ = project(corners, rotation_from_pitch_roll(cam["pitch"], cam["roll"]), cam["focal_length_px"],
                             scene.principal_point)
            assert _set_distance(uv, own) < 0.1 and _set_distance(own, uv) < 0.1
            # the annotated corners (median over workers) lie on the exported box's corners
            assert _set_distance(scene.targets[i].median_corners, uv) < 6.0
            # the 2D box is the projected box, clipped to the image
            w, h = scene.image_size
            lo, hi = uv.min(axis=0), uv.max(axis=0)
            expect = [np.clip(lo[0], 0, w - 1), np.clip(lo[1], 0, h - 1), np.clip(hi[0], 0, w - 1),
                      np.clip(hi[1], 0, h - 1)]
            np.testing.assert_allclose(obj["bbox"], expect, atol=0.1)  # label rounding
            assert obj["occluded"] == 3 and 0 <= obj["truncated"] <= 1
            alpha = np.angle(np.exp(1j * (obj["ry"] - np.arctan2(obj["loc"][0], obj["loc"][2]))))
            assert obj["alpha"] == pytest.approx(alpha, abs=2e-4)
            assert obj["score"] == pytest.approx(entry["quality"]["p_iou_ge_0.7"], abs=1e-4)


def test_calib_file_is_standard_and_r0_rect_is_the_identity(batch):
    calib = _read_calib(batch["labels"] / "calib" / "s1.txt")
    assert list(calib) == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"]
    np.testing.assert_array_equal(calib["R0_rect"].reshape(3, 3), np.eye(3))
    P2 = calib["P2"].reshape(3, 4)
    np.testing.assert_allclose(P2[:, 3], 0)
    cam = _side(batch, "s1")["camera"]
    K = np.array([[cam["focal_length_px"], 0, cam["principal_point"][0]],
                  [0, cam["focal_length_px"], cam["principal_point"][1]], [0, 0, 1]])
    R = np.linalg.solve(K, P2[:, :3])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)  # K·R with R a rotation
    assert abs(cam["pitch_rad"]) > 1e-3  # the camera is pitched: the image's vertical is not gravity


def test_scenes_of_one_photo_share_its_files(batch):
    side = _side(batch, "photo_021")
    assert side["scenes"] == ["photo_a", "photo_b"]
    assert [(o["line"], o["target"]) for o in side["objects"]] == [(1, "crate 1"), (2, "crate 2")]
    assert [o["type"] for o in side["objects"]] == ["crate_1", "crate_2"]  # whitespace is not allowed
    assert [o["calib_mismatch_px"] for o in side["objects"]] == [0.0, 0.0]  # known focal and horizon: one camera


def test_a_scene_of_several_targets_gets_one_file_from_its_shared_camera(batch):
    res = _result(batch, "street")
    side = _side(batch, "street_004")
    lines = (batch["labels"] / "label_2" / "street_004.txt").read_text().splitlines()
    scene = json.loads((batch["scenes"] / "street.json").read_text())
    assert [ln.split()[0] for ln in lines] == [t["class"] for t in scene["targets"]]
    assert side["camera"]["posterior"] == res["camera"]["posterior"] and side["camera"]["scene"] == "street"
    assert len(side["camera"]["draws"]["focal_length_px"]) == side["camera"]["draws"]["n"] == 100
    for line, obj, o in zip(lines, side["objects"], res["objects"]):
        # the label is the MAP box in the gravity-aligned frame: the result's x, y, z and sizes
        v = [float(s) for s in line.split()[8:14]]
        assert v[3:] == pytest.approx([o["map"][k] for k in "xyz"], abs=6e-5)
        assert v[:3] == pytest.approx([o["map"][k] for k in ("height_m", "width_m", "length_m")], abs=6e-5)
        assert obj["posterior"] == o["posterior"] and obj["size"] == "class prior"
        assert obj["quality"]["n_draws"] == res["draws"]["n"]
        assert 0.0 <= obj["true_iou"] <= 1.0 and obj["draws"]["n"] == len(obj["draws"]["length"]) == 100
        assert obj["covariance"]["parameters"] == ["x", "y", "z", "rotation_y", "length", "width", "height"]


def test_sidecar_draws_and_covariance_agree_with_the_result(batch):
    o = _side(batch, "s1")["objects"][0]
    assert o["point_label"] == "map" and o["size"] == "known" and set(o["draws"]) == {"n", "note", "x", "y", "z",
                                                                                      "rotation_y"}
    cov = np.array(o["covariance"]["matrix"])
    assert cov.shape == (4, 4) and np.all(np.linalg.eigvalsh(cov) > -1e-12)
    sd = o["posterior"]["sd"]["x"]
    assert np.std(o["draws"]["x"]) == pytest.approx(sd, rel=0.35)  # 100 of the result's draws
    assert np.sqrt(cov[0, 0]) == pytest.approx(sd, rel=0.2)
    assert 0 <= o["quality"]["p_iou_ge_0.7"] <= o["quality"]["p_iou_ge_0.5"] <= 1
    assert "true_iou" in o and o["evidence"]["dimension_lines"] == 3 and o["evidence"]["references"] == 2


def test_a_result_of_an_earlier_batch_is_labelled_from_its_own_numbers(batch):
    """creference-result/1 (one target; written by creference-bayes 0.1): the label is its MAP."""
    v1 = json.loads((V1 / "results" / "s0.json").read_text())
    dims = json.loads((V1 / "scenes" / "s0.json").read_text())["target"]["dimensions_m"]
    m = v1["map"]
    (obj,) = _read_labels(batch["labels"] / "label_2" / "photo_017.txt")
    assert obj["type"] == "target"
    np.testing.assert_allclose(obj["loc"], [m["x"], m["y"], m["z"]], atol=6e-5)
    assert obj["ry"] == pytest.approx(np.angle(np.exp(1j * m["yaw"])), abs=6e-5)
    np.testing.assert_allclose(obj["hwl"], [dims["height"], dims["width"], dims["length"]], atol=6e-5)
    P2 = _read_calib(batch["labels"] / "calib" / "photo_017.txt")["P2"].reshape(3, 4)
    pp = json.loads((V1 / "scenes" / "s0.json").read_text())["camera"]["principal_point"]
    K = np.array([[m["focal_length_px"], 0, pp[0]], [0, m["focal_length_px"], pp[1]], [0, 0, 1]])
    np.testing.assert_allclose(P2[:, :3], K @ rotation_from_pitch_roll(m["pitch"], m["roll"]), rtol=1e-9)
    (entry,) = _side(batch, "photo_017")["objects"]
    draws = v1["posterior"]["draws"]
    assert set(entry["draws"]["x"]) <= {round(v, 6) for v in draws["x"]}  # the earlier batch's own draws
    assert entry["quality"]["n_draws"] == len(draws["x"])
    assert entry["evidence"]["converged"] is True and "true_iou" in entry


def test_report_lists_objects_below_the_minimum_quality(batch, tmp_path):
    labels = batch["labels"]
    assert "7 objects in 4 image label files" in (labels / "report.md").read_text()
    assert (labels / "quality.png").stat().st_size > 1000
    assert len((labels / "labels.csv").read_text().splitlines()) == 8
    # everything is below a minimum of 1: the list holds every object whose score is below 1, worst first
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--min-quality", "1", "--no-figure",
                 "--quiet"]) == 0
    need = (tmp_path / "needs_annotation.csv").read_text().splitlines()
    scores = [float(r.split(",")[6]) for r in need[1:]]
    assert scores == sorted(scores) and all(s < 1 for s in scores)
    assert not (tmp_path / "quality.png").exists()


def test_a_changed_scene_copy_is_skipped_with_its_reason(batch, tmp_path):
    out = tmp_path / "batch"
    shutil.copytree(batch["batch"], out)
    for key in ("s1", "s0"):  # a copy of this version's and one of an earlier batch
        copy = out / "scenes" / f"{key}.json"
        d = json.loads(copy.read_text())
        (d["targets"][0] if key == "s1" else d["target"])["dimensions_m"]["height"] += 0.1
        copy.write_text(json.dumps(d))
    export = export_labels(out, tmp_path / "labels")
    assert [s["key"] for s in export.skipped] == ["s0", "s1"]
    assert all("rerun creference batch" in s["reason"] for s in export.skipped)
    assert len(export.objects) == 5
    paths = write_report(export, tmp_path / "labels", figure=False)
    assert "`s1`: its scene copy is not the scene of the result" in paths["report"].read_text()


def test_results_without_posterior_draws_are_not_labelled(tmp_path, capsys):
    scene, _ = truth_scene(14, m=2, noise_px=1.0, n_annotations=2)
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "f.json").write_text(json.dumps(scene))
    run_batch([tmp_path / "scenes"], tmp_path / "out", ThreadEngine(), BatchSettings(posterior=False))
    export = export_labels(tmp_path / "out", tmp_path / "labels")
    assert not export.objects and "no posterior draws" in export.skipped[0]["reason"]
    assert main(["labels", str(tmp_path / "out"), "--out", str(tmp_path / "labels")]) == 2
    assert "no posterior draws" in capsys.readouterr().err


def test_cli_labels_rejects_bad_options(batch, tmp_path):
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--score-iou", "0.6"]) == 2
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--min-quality", "2"]) == 2
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--type", "two words"]) == 2
    assert main(["labels", str(tmp_path), "--out", str(tmp_path / "x")]) == 2  # not a batch folder


def test_evaluate_kitti_reads_what_labels_writes(batch, tmp_path):
    """Reference boxes made from the scenes' ground truth: `creference evaluate kitti` finds for each
    label the IoU that `creference labels` recorded as `true_iou` (to the label file's 4 decimals)
    and the sidecar's P(IoU ≥ t)."""
    labels = batch["labels"]
    gt_dir = tmp_path / "gt" / "label_2"
    gt_dir.mkdir(parents=True)
    sidecar = {}
    for side in sorted((labels / "uncertainty").glob("*.json")):
        label_lines = (labels / "label_2" / f"{side.stem}.txt").read_text().splitlines()
        lines = []
        for obj in json.loads(side.read_text())["objects"]:
            scene = load_scene(batch["batch"] / "scenes" / f"{obj['scene']}.json")
            t = next(t for t in scene.targets if t.id == obj["target"])
            g = t.ground_truth
            l, w, h = [g["dimensions_m"][k] for k in ("length", "width", "height")] if "dimensions_m" in g \
                else t.dimensions
            bbox = label_lines[obj["line"] - 1].split()[4:8]
            lines.append(" ".join([obj["type"], "0.00", "0", "0.00", *bbox, f"{h:.4f}", f"{w:.4f}", f"{l:.4f}",
                                   *(f"{v:.4f}" for v in g["location_m"]), f"{g['yaw_rad']:.4f}"]))
            sidecar[(side.stem, obj["line"])] = obj
        (gt_dir / f"{side.stem}.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "eval"
    assert main(["evaluate", "kitti", str(gt_dir.parent), str(labels), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "evaluation.json").read_text())
    assert len(doc["objects"]) == len(sidecar) == 7
    for o in doc["objects"]:
        s = sidecar[(o["image"], o["line"])]
        assert o["iou_3d"] == pytest.approx(s["true_iou"], abs=2e-3)
        assert o["p_iou_ge_0.7"] == s["quality"]["p_iou_ge_0.7"]
    assert sum(0.05 < o["iou_3d"] < 0.99 for o in doc["objects"]) >= 3  # real partial overlaps
    assert doc["reliability"]["p_iou_ge_0.7"]["count"] == len(sidecar)
    assert (out / "reliability.png").is_file()


def test_the_advice_note_tells_a_frame_re_estimated_from_one_without_a_result(tmp_path):
    """``labels`` leaves out the verdicts of an advice's frames that changed since it was made, and
    says which: re-estimated (another fingerprint) or no longer labelled (no result now)."""
    import json

    from creference_bayes.workflows.labels.report import advice_verdicts

    settings = {"iou_threshold": 0.7, "min_quality": 0.5}
    scenes = [{"key": k, "scene_sha256": k + "-old", "settings": settings, "verdicts": [{"target": "t0"}]}
              for k in ("a", "b", "c")]
    (tmp_path / "advice").mkdir()
    (tmp_path / "advice" / "advice.json").write_text(json.dumps({"scenes": scenes}))
    kept, note = advice_verdicts(tmp_path, {"a": "a-old", "b": "b-new"}, score_iou=0.7, min_quality=0.5)
    assert list(kept) == [("a", "t0")]
    assert "1 frame(s) were re-estimated since the advice" in note
    assert "1 frame(s) of the advice" in note and "have no result labelled now" in note
    kept, note = advice_verdicts(tmp_path, {"a": "a-old", "b": "b-old"}, score_iou=0.7, min_quality=0.5)
    assert len(kept) == 2 and "re-estimated" not in note and "1 frame(s) of the advice" in note
    assert "for what would lift them" not in note  # a frame with no label has nothing to lift
    kept, note = advice_verdicts(tmp_path, {"a": "a-old", "b": None, "c": "c-old"}, score_iou=0.7, min_quality=0.5)
    assert len(kept) == 2 and "1 frame(s) were re-estimated" in note and "no result" not in note  # None: no fingerprint
