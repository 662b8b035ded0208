"""creference labels: KITTI files that reproject onto the annotations, sidecars, the report."""

import dataclasses
import json
import shutil
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.cli.main import main
from creference_bayes.core.geometry import (Camera, box_points, box_vertices, dimension_corners, project,
                                            rotation_from_pitch_roll)
from creference_bayes.io.scene import load_scene
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.engines import Engine
from creference_bayes.workflows.labels.report import write_report
from creference_bayes.workflows.labels import camera_angles, export_labels

SMALL_SAMPLER = {"n_ensembles": 2, "n_walkers": 16, "tau_multiple": 20, "min_ess": 100}


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


def _second_target(scene: dict, rng) -> dict:
    """Another target on the same photo: a box placed beside the first, annotated through the
    scene's true camera with 2 px noise."""
    gt = scene["ground_truth"]
    f, pp = gt["focal_length_px"], np.array(scene["camera"]["principal_point"])
    R = rotation_from_pitch_roll(gt["pitch_rad"], gt["roll_rad"])
    L, W, H = 0.8, 0.6, 1.1
    x, _, z = gt["location_m"]
    pose = np.array([x + 0.9, gt["camera_height_m"], z + 1.5, 0.4])
    corners, _ = project(box_points(pose, dimension_corners(L, W, H, 1)), R, f, pp)
    other = json.loads(json.dumps(scene))
    other["target"] = {"id": "crate 2", "dimensions_m": {"length": L, "width": W, "height": H},
                       "dimension_lines": [{"corners": (corners + rng.normal(0, 2.0, corners.shape)).tolist()}
                                           for _ in range(13)]}
    other["ground_truth"] = {**gt, "location_m": pose[:3].tolist(), "yaw_rad": float(pose[3]), "handedness": 1}
    other.pop("references")
    return other


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """3 simulated scenes without an image and two targets of one photo (known focal length)."""
    root = tmp_path_factory.mktemp("labels")
    scenes = root / "scenes"
    scenes.mkdir()
    for i in range(3):
        d = simulate_scene(np.random.default_rng([21, i]), tier="low")
        (scenes / f"s{i}.json").write_text(json.dumps(d))
    photo = simulate_scene(np.random.default_rng(99), tier="low", setting="indoor")
    photo["camera"]["focal_length_px"] = photo["ground_truth"]["focal_length_px"]
    photo["image"]["path"] = "images/photo_017.png"
    photo["target"]["id"] = "crate 1"
    (scenes / "photo_a.json").write_text(json.dumps(photo))
    (scenes / "photo_b.json").write_text(json.dumps(_second_target(photo, np.random.default_rng(1))))
    out = root / "batch"
    report = run_batch([scenes], out, ThreadEngine(), BatchSettings(seed=3, sampling=SMALL_SAMPLER))
    assert report.ok, report.errors
    labels = root / "labels"
    assert main(["labels", str(out), "--out", str(labels), "--quiet"]) == 0
    return {"scenes": scenes, "batch": out, "labels": labels}


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


def test_kitti_boxes_projected_with_p2_land_on_the_package_projection_and_the_annotations(batch):
    labels, out = batch["labels"], batch["batch"]
    names = sorted(p.stem for p in (labels / "label_2").glob("*.txt"))
    assert names == ["photo_017", "s0", "s1", "s2"]
    for name in names:
        P2 = _read_calib(labels / "calib" / f"{name}.txt")["P2"]
        side = json.loads((labels / "uncertainty" / f"{name}.json").read_text())
        objs = _read_labels(labels / "label_2" / f"{name}.txt")
        assert len(objs) == len(side["objects"]) == (2 if name == "photo_017" else 1)
        for obj, entry in zip(objs, side["objects"]):
            uv = _project_kitti(P2, _kitti_corners(obj))
            result = json.loads((out / "results" / f"{entry['scene']}.json").read_text())
            scene = load_scene(out / "scenes" / f"{entry['scene']}.json")
            m = result["map"]
            t = scene.target
            pkg, _ = Camera.from_scene(scene).project(
                box_points(np.array([m["x"], m["y"], m["z"], m["yaw"]]), box_vertices(t.length, t.width, t.height)),
                m["focal_length_px"])
            assert _set_distance(uv, pkg) < 0.1 and _set_distance(pkg, uv) < 0.1
            # the annotated corners (median over workers) lie on the exported box's corners
            assert _set_distance(t.median_corners, uv) < 6.0
            # the 2D box is the projected box, clipped to the image
            w, h = scene.image_size
            lo, hi = uv.min(axis=0), uv.max(axis=0)
            expect = [np.clip(lo[0], 0, w - 1), np.clip(lo[1], 0, h - 1), np.clip(hi[0], 0, w - 1), np.clip(hi[1], 0, h - 1)]
            np.testing.assert_allclose(obj["bbox"], expect, atol=0.1)  # label rounding
            assert obj["occluded"] == 3 and 0 <= obj["truncated"] <= 1
            assert obj["alpha"] == pytest.approx(np.angle(np.exp(1j * (obj["ry"] - np.arctan2(obj["loc"][0], obj["loc"][2])))), abs=2e-4)
            assert obj["score"] == pytest.approx(entry["quality"]["p_iou_ge_0.7"], abs=1e-4)


def test_calib_file_is_standard_and_r0_rect_is_the_identity(batch):
    calib = _read_calib(batch["labels"] / "calib" / "s0.txt")
    assert set(calib) == {"P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"}
    np.testing.assert_array_equal(calib["R0_rect"].reshape(3, 3), np.eye(3))
    P2 = calib["P2"].reshape(3, 4)
    K_R = P2[:, :3]
    np.testing.assert_allclose(P2[:, 3], 0)
    # K·R with K upper triangular and R a rotation: R's rows have unit norm after removing K
    side = json.loads((batch["labels"] / "uncertainty" / "s0.json").read_text())
    cam = side["camera"]
    K = np.array([[cam["focal_length_px"], 0, cam["principal_point"][0]],
                  [0, cam["focal_length_px"], cam["principal_point"][1]], [0, 0, 1]])
    R = np.linalg.solve(K, K_R)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    # the camera is pitched: the image's vertical is not gravity
    assert abs(cam["pitch_rad"]) > 1e-3


def test_targets_of_one_image_share_its_files(batch):
    side = json.loads((batch["labels"] / "uncertainty" / "photo_017.json").read_text())
    assert [o["target"] for o in side["objects"]] == ["crate 1", "crate 2"]
    assert [o["type"] for o in side["objects"]] == ["crate_1", "crate_2"]  # whitespace is not allowed
    assert [o["calib_mismatch_px"] for o in side["objects"]] == [0.0, 0.0]  # known focal: one camera


def test_sidecar_holds_map_mean_covariance_hdi_and_draws(batch):
    side = json.loads((batch["labels"] / "uncertainty" / "s1.json").read_text())
    o = side["objects"][0]
    assert o["point_label"] == "map" and {"pitch", "roll"} <= set(o["map"])
    names = o["covariance"]["parameters"]
    assert names[:4] == ["x", "y", "z", "yaw"] and o["covariance"]["units"][:4] == ["m", "m", "m", "rad"]
    cov = np.array(o["covariance"]["matrix"])
    assert cov.shape == (len(names), len(names)) and np.all(np.linalg.eigvalsh(cov) > -1e-12)
    d = o["draws"]
    assert d["n"] == 100 and all(len(d[k]) == 100 for k in names + ["pitch", "roll"])
    # the sidecar's draws reproduce the result's sd of x to within sampling error
    sd = o["posterior_sd"]["x"]
    assert np.std(d["x"]) == pytest.approx(sd, rel=0.35)
    assert np.sqrt(cov[0, 0]) == pytest.approx(sd, rel=0.2)
    assert o["hdi"]["prob"] == 0.9 and o["hdi"]["x"][0] < o["map"]["x"] < o["hdi"]["x"][1]
    assert 0 <= o["quality"]["p_iou_ge_0.7"] <= o["quality"]["p_iou_ge_0.5"] <= 1
    assert "true_iou" in o and o["evidence"]["dimension_lines"] == 13


def test_report_lists_objects_below_the_minimum_quality(batch, tmp_path):
    labels = batch["labels"]
    text = (labels / "report.md").read_text()
    assert "5 objects in 4 image label files" in text
    assert (labels / "quality.png").stat().st_size > 1000
    rows = (labels / "labels.csv").read_text().splitlines()
    assert len(rows) == 6
    # everything is below a minimum of 1.01: the list holds all objects, worst first
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--min-quality", "1", "--no-figure",
                 "--quiet"]) == 0
    need = (tmp_path / "needs_annotation.csv").read_text().splitlines()
    scores = [float(r.split(",")[6]) for r in need[1:]]
    assert scores == sorted(scores) and len(scores) == sum(s < 1 for s in scores)
    assert not (tmp_path / "quality.png").exists()


def test_a_changed_scene_copy_is_skipped_with_its_reason(batch, tmp_path):
    out = tmp_path / "batch"
    shutil.copytree(batch["batch"], out)
    copy = out / "scenes" / "s2.json"
    d = json.loads(copy.read_text())
    d["target"]["dimensions_m"]["height"] += 0.1
    copy.write_text(json.dumps(d))
    export = export_labels(out, tmp_path / "labels")
    assert [s["key"] for s in export.skipped] == ["s2"] and "rerun creference batch" in export.skipped[0]["reason"]
    assert len(export.objects) == 4
    paths = write_report(export, tmp_path / "labels", figure=False)
    assert "`s2`: its scene copy is not the scene of the result" in paths["report"].read_text()


def test_cli_labels_rejects_bad_options(batch, tmp_path):
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--score-iou", "0.6"]) == 2
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--min-quality", "2"]) == 2
    assert main(["labels", str(batch["batch"]), "--out", str(tmp_path), "--type", "two words"]) == 2
    assert main(["labels", str(tmp_path), "--out", str(tmp_path / "x")]) == 2  # not a batch folder


def test_camera_angles_come_from_the_result_or_the_horizon(make_scene):
    scene = make_scene(4)
    gt = scene.ground_truth
    pitch, roll = camera_angles({"focal_length_px": gt.focal_length_px}, scene)
    assert pitch == pytest.approx(gt.extra["pitch_rad"], abs=1e-4)  # horizon stored to 0.01 px
    assert roll == pytest.approx(gt.extra["roll_rad"], abs=1e-4)
    assert camera_angles({"focal_length_px": 1000.0, "pitch": 0.1, "roll": -0.2}, scene) == (0.1, -0.2)
    level = dataclasses.replace(scene, horizon=None)
    assert tuple(map(float, camera_angles({"focal_length_px": [900.0, 1100.0]}, level)[0])) == (0.0, 0.0)


def test_evaluate_kitti_reads_what_labels_writes(batch, tmp_path, capsys):
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
            gt = json.loads((batch["batch"] / "scenes" / f"{obj['scene']}.json").read_text())["ground_truth"]
            d = obj["dimensions_m"]
            bbox = label_lines[obj["line"] - 1].split()[4:8]
            lines.append(" ".join([obj["type"], "0.00", "0", "0.00", *bbox, f"{d['h']:.4f}", f"{d['w']:.4f}",
                                   f"{d['l']:.4f}", *(f"{v:.4f}" for v in gt["location_m"]), f"{gt['yaw_rad']:.4f}"]))
            sidecar[(side.stem, obj["line"])] = obj
        (gt_dir / f"{side.stem}.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "eval"
    assert main(["evaluate", "kitti", str(gt_dir.parent), str(labels), "--out", str(out), "--quiet"]) == 0
    doc = json.loads((out / "evaluation.json").read_text())
    assert len(doc["objects"]) == len(sidecar) >= 5
    for o in doc["objects"]:
        s = sidecar[(o["image"], o["line"])]
        assert o["iou_3d"] == pytest.approx(s["true_iou"], abs=2e-3)
        assert o["p_iou_ge_0.7"] == s["quality"]["p_iou_ge_0.7"]
    assert sum(0.05 < o["iou_3d"] < 0.99 for o in doc["objects"]) >= 3  # real partial overlaps
    assert doc["reliability"]["p_iou_ge_0.7"]["count"] == len(sidecar)
    assert (out / "reliability.png").is_file()
