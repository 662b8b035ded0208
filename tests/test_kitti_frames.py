"""Scenes from a KITTI folder and labels back into KITTI's frame (synthetic KITTI files, no data):
simulate --from-kitti → batch → labels → evaluate kitti."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from creference_bayes.bench.kitti import kitti_scene, read_calib, read_p2
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.models.contract import CAMERA_NAMES, OBJECT_NAMES
from creference_bayes.pipeline import build_model
from creference_bayes.workflows.labels.kitti import LabelInput, kitti_poses, write_labels

P2 = np.array([[721.5377, 0.0, 609.5593, 44.85728], [0.0, 721.5377, 172.854, 0.2163791], [0.0, 0.0, 1.0, 0.002745884]])
# type trunc occ alpha  l t r b  h w l  x y z  ry
LABELS = """Car 0.00 0 -1.58 587.01 173.33 614.12 200.12 1.65 1.67 3.64 -0.65 1.71 46.70 -1.59
Pedestrian 0.00 0 -0.20 712.40 143.00 810.73 307.92 1.89 0.48 1.20 1.84 1.47 8.41 0.01
Car 0.00 1 1.85 387.63 175.00 423.81 203.12 1.67 1.87 3.69 -16.53 2.39 58.49 1.57
Cyclist 0.80 0 -1.00 0.0 170.0 40.0 260.0 1.7 0.6 1.8 -12.0 1.6 10.0 0.5
DontCare -1 -1 -10 503.89 169.71 590.61 190.13 -1 -1 -1 -1000 -1000 -1000 -10
"""

# a real drive's other calib lines (KITTI's 2011_09_26 calibration, as its calib files give them)
OTHER_CALIB = """R0_rect: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
Tr_velo_to_cam: 7.533745e-03 -9.999714e-01 -6.166020e-04 -4.069766e-03 1.480249e-02 7.280733e-04 -9.998902e-01 -7.631618e-02 9.998621e-01 7.523790e-03 1.480755e-02 -2.717806e-01
Tr_imu_to_velo: 9.999976e-01 7.553071e-04 -2.035826e-03 -8.086759e-01 -7.854027e-04 9.998898e-01 -1.482298e-02 3.195559e-01 2.024406e-03 1.482454e-02 9.998881e-01 -7.997231e-01
"""


def write_kitti_folder(d):
    """A one-frame KITTI folder (label_2/000007.txt with LABELS, calib/000007.txt with P2) at ``d``."""
    (d / "label_2").mkdir(parents=True)
    (d / "calib").mkdir()
    (d / "label_2" / "000007.txt").write_text(LABELS)
    rows = " ".join(f"{v:.12e}" for v in P2.ravel())
    (d / "calib" / "000007.txt").write_text(f"P0: {rows}\nP1: {rows}\nP2: {rows}\nP3: {rows}\n{OTHER_CALIB}")
    return d


@pytest.fixture
def kitti_dir(tmp_path):
    return write_kitti_folder(tmp_path / "kitti")


def _result(camera, objects) -> dict:
    """A result with this MAP and no posterior (enough to write labels and a calib)."""
    return {"camera": {"map": dict(zip(CAMERA_NAMES, map(float, camera)))},
            "objects": [{"map": dict(zip(OBJECT_NAMES, map(float, o)))} for o in objects]}


def test_scenes_from_kitti_keep_what_a_person_could_annotate(kitti_dir):
    scene, report = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                                rng=0, n_annotations=3, noise_px=0.0)
    assert [t["class"] for t in scene["targets"]] == ["Car", "Pedestrian", "Car"]
    assert report["skipped"]["truncation"] == 1  # the cyclist, truncated 0.8
    assert scene["camera"]["focal_length_px"] == pytest.approx(P2[0, 0])
    assert "horizon" not in scene and "dimensions_m" not in scene["targets"][0]
    np.testing.assert_allclose(read_p2(kitti_dir / "calib" / "000007.txt"), P2)


def test_labels_of_the_true_state_are_kittis_own_boxes(kitti_dir):
    """The scene's conventions (nearest corner, handedness, yaw, P2's offset) there and back."""
    from creference_bayes.evaluation.kitti_eval import evaluate_kitti

    scene, _ = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                           rng=0, n_annotations=2, noise_px=0.0)
    frame = parse_scene(scene)
    model, _ = build_model(frame)
    model.handedness = np.array([t["ground_truth"]["handedness"] for t in scene["targets"]], float)
    objs = np.array([[t["ground_truth"]["location_m"][0], t["ground_truth"]["location_m"][2], t["ground_truth"]["yaw_rad"],
                      *t["ground_truth"]["dimensions_m"].values(), 0.0] for t in scene["targets"]])
    h = np.array([t["ground_truth"]["location_m"][1] for t in scene["targets"]])
    objs[:, 6] = h.max() - h
    cam = np.array([P2[0, 0], 0.0, 0.0, h.max(), 0.5])
    # the annotations are the projection of the true state, to 0.01 px
    uv, _ = model.project(cam[None], objs[None])
    for i, t in enumerate(frame.targets):
        np.testing.assert_allclose(t.corners[0], uv[0, i], atol=0.006)
    boxes = kitti_poses(frame, cam[None], objs[None])[0]
    for t, b in zip(scene["targets"], boxes):
        k = t["ground_truth"]["kitti"]
        np.testing.assert_allclose(b[:3], k["location"], atol=1e-9)
        assert np.cos(b[3] - k["rotation_y"]) == pytest.approx(1.0, abs=1e-9) or \
            np.cos(b[3] - k["rotation_y"]) == pytest.approx(-1.0, abs=1e-9)
    objects, sidecar = write_labels(kitti_dir / "out", "000007", [LabelInput("000007", _result(cam, objs), frame)])
    assert sidecar is None and [o.quality for o in objects] == [None] * 3  # no draws: no uncertainty to write
    ev = evaluate_kitti(kitti_dir / "label_2", kitti_dir / "out" / "label_2")
    # label files hold two decimals (KITTI's own precision)
    assert [o["iou_3d"] for o in ev.objects] == pytest.approx([1.0, 1.0, 1.0], abs=1e-3)


def test_simulate_from_kitti_on_the_command_line(kitti_dir, tmp_path):
    out = tmp_path / "scenes"
    proc = subprocess.run([sys.executable, "-m", "creference_bayes", "simulate", "--from-kitti", str(kitti_dir),
                           "--out", str(out), "--annotations", "2"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "3 objects" in proc.stdout and "1 truncated by over 0.5 of their size" in proc.stdout
    data = json.loads((out / "000007.json").read_text())
    assert data["format"] == "creference-scene/2" and len(data["targets"][0]["dimension_lines"]) == 2
    proc = subprocess.run([sys.executable, "-m", "creference_bayes", "simulate", "--from-kitti", str(tmp_path),
                           "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "not a KITTI folder" in proc.stderr


@pytest.mark.slow  # three methods' labels; test_the_kitti_path_on_the_command_line keeps the folder's path
def test_kitti_study_example_runs_on_a_kitti_folder(kitti_dir, tmp_path):
    """examples/kitti_study.py end to end on the synthetic folder: labels of the three methods for
    every annotatable object, the AP table and study.json."""
    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    out = tmp_path / "study"
    proc = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(out), "--annotations", "2",
                           "--max-steps", "400", "--option", "ground_sd_m=0.05", "--option", "distance_range=2,90"],
                          capture_output=True, text=True,
                          timeout=300,
                          env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    written = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    for method in ("joint", "alone", "bound"):
        assert f"{method}/label_2/000007.txt" in written and f"{method}/calib/000007.txt" in written, written
        rows = (out / method / "label_2" / "000007.txt").read_text().splitlines()
        assert len(rows) == 3, (method, rows)  # the three annotatable objects, one row each
    study = json.loads((out / "study.json").read_text())
    assert len(study["times"]) == 1 and "AP3D R40" in proc.stdout
    assert "se by frame" in proc.stdout, proc.stdout  # the quality gap with its standard error
    # the Car box errors: one row per method and band that holds a car, each naming its count
    errors = [line for line in proc.stdout.splitlines() if " depth " in line and " n " in line]
    assert {line.split()[0] for line in errors} == {"joint", "alone", "bound"}, proc.stdout
    bad = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(tmp_path / "x"), "--option",
                          "ground_sd=1"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--option ground_sd: the metrology model has no such option" in bad.stderr
    bad = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(tmp_path / "x"), "--option",
                          "distance_range=80"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "distance_range" in bad.stderr and "'80'" in bad.stderr


def test_scenes_from_kitti_with_known_sizes_give_each_object_its_true_size(kitti_dir):
    scene, _ = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                           rng=0, n_annotations=2, noise_px=0.0, sizes="known")
    # LABELS' rows: h w l of the first car 1.65 1.67 3.64, of the pedestrian 1.89 0.48 1.20
    assert scene["targets"][0]["dimensions_m"] == {"length": 3.64, "width": 1.67, "height": 1.65}
    assert scene["targets"][1]["dimensions_m"] == {"length": 1.20, "width": 0.48, "height": 1.89}
    frame = parse_scene(scene)
    assert frame.targets[0].dimensions == (3.64, 1.67, 1.65)
    model, _ = build_model(frame)
    assert all(o.sizes is not None for o in model.objects)
    # the same draw of annotations either way: only the sizes differ
    prior, _ = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                           rng=0, n_annotations=2, noise_px=1.0)
    known, _ = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                           rng=0, n_annotations=2, noise_px=1.0, sizes="known")
    assert [t["dimension_lines"] for t in prior["targets"]] == [t["dimension_lines"] for t in known["targets"]]
    with pytest.raises(ValueError, match="sizes: expected one of"):
        kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt", sizes="true")


def test_simulate_from_kitti_with_known_sizes_on_the_command_line(kitti_dir, tmp_path):
    out = tmp_path / "scenes"
    proc = subprocess.run([sys.executable, "-m", "creference_bayes", "simulate", "--from-kitti", str(kitti_dir),
                           "--out", str(out), "--annotations", "1", "--sizes", "known"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = json.loads((out / "000007.json").read_text())
    assert [t["dimensions_m"]["length"] for t in data["targets"]] == [3.64, 1.20, 3.69]


def test_kitti_study_runs_the_bound_alone_under_other_assumptions(kitti_dir, tmp_path):
    """``--methods bound`` writes the bound's labels only; with ``--sizes known`` the bound's boxes
    keep each object's true size; the fully visible cars are counted by band (LABELS: one car
    with occlusion 0 at 46.7 m, the other occluded)."""
    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    out = tmp_path / "study"
    proc = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(out), "--annotations", "2",
                           "--methods", "bound", "--sizes", "known", "--bound-option", "ground_sd_m=0.005"],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert not (out / "joint").exists() and not (out / "alone").exists()
    rows = [r.split() for r in (out / "bound" / "label_2" / "000007.txt").read_text().splitlines()]
    assert [r[0] for r in rows] == ["Car", "Pedestrian", "Car"]
    assert [float(v) for v in rows[0][8:11]] == [1.65, 1.67, 3.64]  # KITTI's h w l, as given
    share = next(line for line in proc.stdout.splitlines() if line.startswith("bound") and "5-60 m" in line)
    assert "5-20 m  nan (0)" in share and "40-60 m" in share and share.rstrip().endswith("(1)"), share
    bad = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(tmp_path / "x"),
                          "--methods", "joint,best"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--methods 'joint,best'" in bad.stderr


def test_labels_of_a_kitti_scene_carry_the_folders_real_calibration(kitti_dir):
    """A scene made from a KITTI folder keeps the calib file's other lines, and its labels' calib
    file gives them back (KITTI tools that go through the lidar read Tr_velo_to_cam), with P2."""
    scene, _ = kitti_scene(kitti_dir / "label_2" / "000007.txt", kitti_dir / "calib" / "000007.txt",
                           rng=0, n_annotations=2, noise_px=1.0)
    frame = parse_scene(json.loads(json.dumps(scene)))
    assert parse_scene(scene_to_dict(frame)).kitti_calib == frame.kitti_calib  # round trip
    cam = np.array([P2[0, 0], 0.01, 0.0, 1.7, 0.5])
    objs = [[0.0, 10.0 + i, 0.1, 4.0, 1.8, 1.5, 0.0] for i in range(len(frame.targets))]
    write_labels(kitti_dir / "out", "000007", [LabelInput("000007", _result(cam, objs), frame)])
    written = read_calib(kitti_dir / "out" / "calib" / "000007.txt")
    given = read_calib(kitti_dir / "calib" / "000007.txt")
    assert list(written) == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"]
    for name in given:
        np.testing.assert_allclose(written[name], given[name], rtol=1e-12, err_msg=name)


def test_the_kitti_path_on_the_command_line(tmp_path):
    """simulate --from-kitti → batch → labels → evaluate kitti, on the synthetic KITTI folder."""
    kitti = write_kitti_folder(tmp_path / "kitti")

    def run(*args):
        proc = subprocess.run([sys.executable, "-m", "creference_bayes", *map(str, args)], capture_output=True,
                              text=True, timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout

    run("simulate", "--from-kitti", kitti, "--out", "scenes", "--annotations", "3")
    run("batch", "scenes", "--out", "batch", "--workers", "1", "--max-steps", "300", "--min-ess", "20")
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


@pytest.mark.slow  # the KITTI study's pooled run (about 30 s)
def test_kitti_study_pools_the_focal_length_of_frames_with_one_p2(kitti_dir, tmp_path):
    """Three frames with the same P2 and the focal length left out of the scenes: every scene names
    the same camera, and ``--rig focal`` gives each frame a focal-length prior from the two others
    (the study prints it against P2's and records it in study.json)."""
    import shutil

    for name in ("000008", "000009"):
        shutil.copy(kitti_dir / "label_2" / "000007.txt", kitti_dir / "label_2" / f"{name}.txt")
        shutil.copy(kitti_dir / "calib" / "000007.txt", kitti_dir / "calib" / f"{name}.txt")
    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    out = tmp_path / "study"
    proc = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(out), "--annotations", "3",
                           "--max-steps", "400", "--methods", "joint", "--focal", "unknown", "--rig", "focal"],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    scenes = [json.loads(p.read_text()) for p in sorted((out / "scenes").glob("*.json"))]
    assert len(scenes) == 3 and all("focal_length_px" not in s["camera"] for s in scenes)
    assert len({s["camera"]["id"] for s in scenes}) == 1 and scenes[0]["camera"]["id"].startswith("kitti-")
    assert all(s["ground_truth"]["focal_length_px"] == pytest.approx(P2[0, 0]) for s in scenes)
    rigs = json.loads((out / "study.json").read_text())["rigs"]
    informed = [r for r in rigs.values() if r is not None]
    assert informed and all(r["frames"] == 2 and r["focal_length_px"]["frames"] >= 1 for r in informed)
    assert f"P2 {P2[0, 0]:.1f}" in proc.stdout
    # each frame's focal length against P2's, by objects per frame (three frames of three objects)
    assert "the frames' focal lengths against P2" in proc.stdout and "2-3 objects:   3," in proc.stdout
    assert len(list((out / "joint" / "label_2").glob("*.txt"))) == 3
    bad = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(tmp_path / "x"), "--methods",
                          "bound", "--rig", "focal"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--rig focal: pools the joint" in bad.stderr


def test_kitti_study_gives_p2s_focal_length_as_a_prior_of_the_asked_width(kitti_dir, tmp_path):
    """``--focal unknown --focal-sd S``: a frame's focal length is not given, and its prior is P2's
    value at log-sd S (a log-normal), as a camera pooled over many frames would give; it is a usage
    error with --rig, without --focal unknown, or with a width that is not > 0."""
    import importlib.util
    import warnings

    from creference_bayes.bench.kitti import kitti_scenes
    from creference_bayes.pipeline import estimate

    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    spec = importlib.util.spec_from_file_location("kitti_study", script)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    kitti_scenes(kitti_dir, tmp_path / "s", n_annotations=1, focal_known=False)
    frame = study._load_frame(tmp_path / "s" / "000007.json", "unknown", 0.02)
    assert frame.focal_length_px is None
    assert frame.focal_prior.median_px == pytest.approx(P2[0, 0]) and frame.focal_prior.log_sd == 0.02
    assert np.isinf(frame.focal_prior.dof)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = estimate(frame, posterior=False).to_dict()["camera"]["setup"]["focal_prior"]
    assert setup["median_px"] == pytest.approx(P2[0, 0]) and setup["log_sd"] == 0.02 and setup["dof"] is None
    assert study._load_frame(tmp_path / "s" / "000007.json", "unknown").focal_prior is None
    for flags, said in ((["--focal", "unknown", "--focal-sd", "0.02", "--rig", "focal"], "without --rig"),
                        (["--focal-sd", "0.02"], "with --focal unknown"),
                        (["--focal", "unknown", "--focal-sd", "0"], "expected a log-sd > 0, got 0.0")):
        bad = subprocess.run([sys.executable, str(script), str(kitti_dir), "--out", str(tmp_path / "x"),
                              "--methods", "joint", *flags], capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and said in bad.stderr, (flags, bad.stderr)


@pytest.mark.slow  # a batch, labels and the reliability check on a KITTI folder (about a minute)
@pytest.mark.parametrize("flags,pooled", [([], True), (["--own-scale"], False)])
def test_label_reliability_on_a_kitti_folder_with_a_sample_annotated_twice(kitti_dir, tmp_path, flags, pooled):
    """examples/label_reliability.py --kitti --twice-every 2: the first frame's objects have two sets,
    the second frame's one, which takes the first frame's corner scale (--own-scale: its own; batch's
    --own-scale is checked in test_batch, its pass-through here among the slow tests)."""
    for sub in ("label_2", "calib"):
        shutil.copy(kitti_dir / sub / "000007.txt", kitti_dir / sub / "000008.txt")
    script = Path(__file__).resolve().parents[1] / "examples" / "label_reliability.py"
    out = tmp_path / f"lr{len(flags)}"
    proc = subprocess.run([sys.executable, str(script), "--kitti", str(kitti_dir), "--noise-px", "4",
                           "--twice-every", "2", "--min-ess", "50", "--workers", "1", "--out", str(out), *flags],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "annotated once: 3 objects" in proc.stdout and "annotated twice: 3 objects" in proc.stdout
    twice = json.loads((out / "scenes" / "000007.json").read_text())
    assert [len(t["dimension_lines"]) for t in twice["targets"]] == [2, 2, 2]
    copy = json.loads((out / "batch" / "scenes" / "000008.json").read_text())
    assert ("corner_scale" in copy) == pooled
    assert [len(t["dimension_lines"]) for t in copy["targets"]] == [1, 1, 1]


def test_kitti_study_states_the_quality_gap_with_a_standard_error_by_frame():
    """The labels of one image share its camera: the standard error of the mean gap between stated
    and reached quality treats each image as one cluster. With one label an image it is the usual
    standard error of a mean; copying every image's label k times leaves it unchanged, where the
    labels-as-independent standard error would shrink by √k."""
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    spec = importlib.util.spec_from_file_location("kitti_study", script)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    p = [0.9, 0.2, 0.6, 0.4, 0.7]
    iou = [0.8, 0.6, 0.3, 0.2, 0.75]
    one = [{"image": f"{i:06d}", "p_iou_ge_0.5": q, "iou_3d": v} for i, (q, v) in enumerate(zip(p, iou))]
    d = np.array(p) - (np.array(iou) >= 0.5)
    mean, se = study._frame_se(one, 0.5)
    assert mean == pytest.approx(d.mean())
    assert se == pytest.approx(np.sqrt(np.sum((d - d.mean()) ** 2)) / len(d))
    copied = [dict(o) for o in one for _ in range(4)]
    mean4, se4 = study._frame_se(copied, 0.5)
    assert mean4 == pytest.approx(mean) and se4 == pytest.approx(se)
    # labels without a stated quality are left out, not counted as misses
    assert study._frame_se(one + [{"image": "000009", "p_iou_ge_0.5": None, "iou_3d": 0.0}], 0.5) == pytest.approx((mean, se))


def test_kitti_study_tables_the_frames_focal_lengths_by_objects_per_frame():
    """Rows (objects, posterior median ÷ P2, quantile of P2, P2 in the HDI) go to their band by the
    number of objects, and every band states its frames, median ratio, mean quantile and HDI count."""
    import importlib.util

    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    spec = importlib.util.spec_from_file_location("kitti_study", script)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    rows = [(1, 0.8, 0.9, False), (1, 1.0, 0.5, True), (5, 1.1, 0.2, True)]
    text = study._focal_table(rows)
    assert "     1 objects:   2, 0.900, 0.70, 1 of 2" in text
    assert "   4-7 objects:   1, 1.100, 0.20, 1 of 1" in text
    assert "   all objects:   3, 1.000, 0.53, 2 of 3" in text
    assert "2-3 objects" not in text and "8+ objects" not in text  # no frames there


def test_the_kitti_page_fits_each_frames_ground_plane(tmp_path):
    """docs/studies/kitti.md's ground snippet, run as printed on a folder of two frames whose objects stand
    exactly on planes rising 1 cm per metre ahead: no spread around the plane, a slope of
    atan(0.01) = 0.57° in both; a frame of four objects (too few) and DontCare rows are left out."""
    import re

    block = re.findall(r"```python\n(.*?)```", (Path(__file__).resolve().parents[1] / "docs" / "studies" / "kitti.md").read_text(),
                       re.S)
    (snippet,) = [b for b in block if "ground plane" in b]
    labels = tmp_path / "kitti" / "label_2"
    labels.mkdir(parents=True)
    for name, n, height in (("000000", 6, 1.65), ("000001", 5, 1.5), ("000002", 4, 1.7)):
        rows = [f"Car 0.00 0 0.00 1 1 2 2 1.5 1.6 3.9 {x:.2f} {height + 0.01 * z:.4f} {z:.2f} 0.00"
                for x, z in zip([-6.0, 4.0, -2.0, 6.0, -4.0, 2.0][:n], np.linspace(8, 40, n))]
        rows.append("DontCare -1 -1 -10 1 1 2 2 -1 -1 -1 -1000 -1000 -1000 -10")
        (labels / f"{name}.txt").write_text("\n".join(rows) + "\n")
    code = snippet.replace('KITTI = "../shared/kitti_dev"', f'KITTI = {str(tmp_path / "kitti")!r}')
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("2 frames, 11 objects: sd of the objects' ground around their frame's plane 0.000 m")
    assert "slope along the view +0.57 ± 0.00 deg" in done.stdout


def test_kitti_ground_moves_only_the_heights_of_the_boxes(kitti_dir, tmp_path):
    """examples/kitti_ground.py: ``level`` puts every labelled object's bottom at the frame's
    median (1.47, 1.6, 1.71, 2.39 m: 1.655); ``plane`` onto the least-squares plane of the four,
    whose residuals it removes; every other field and the DontCare line are KITTI's, and the calib
    stays readable through the link."""
    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_ground.py"
    rows = [line.split() for line in LABELS.splitlines()]
    xyz = np.array([[float(r[k]) for k in (11, 12, 13)] for r in rows[:4]])
    design = np.c_[xyz[:, 0], xyz[:, 2], np.ones(4)]
    fitted = design @ np.linalg.lstsq(design, xyz[:, 1], rcond=None)[0]
    assert np.max(np.abs(fitted - xyz[:, 1])) > 0.1  # the example's boxes are off their plane
    for ground, expected in (("level", np.full(4, 1.655)), ("plane", fitted)):
        out = tmp_path / ground
        proc = subprocess.run([sys.executable, str(script), str(kitti_dir), str(out), "--ground", ground],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        new = [line.split() for line in (out / "label_2" / "000007.txt").read_text().splitlines()]
        assert len(new) == len(rows) and new[4] == rows[4]  # DontCare as it was
        for r, n, y in zip(rows[:4], new[:4], expected):
            assert abs(float(n[12]) - y) <= 0.005 + 1e-9  # written to 0.01 m, as KITTI's labels
            assert n[:12] == r[:12] and n[13:] == r[13:]
        np.testing.assert_allclose(read_p2(out / "calib" / "000007.txt"), P2)
        # a second run into the same folder is refused, the first left as it was
        again = subprocess.run([sys.executable, str(script), str(kitti_dir), str(out), "--ground", ground],
                               capture_output=True, text=True, timeout=120)
        assert again.returncode == 2 and "exists" in again.stderr
    bad = subprocess.run([sys.executable, str(script), str(tmp_path / "none"), str(tmp_path / "x"), "--ground", "level"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "not a KITTI folder" in bad.stderr


def test_kitti_study_gives_every_frame_of_a_camera_one_mounting_with_the_rig(kitti_dir, tmp_path):
    """``--camera rig``: every frame of a camera gets the same height prior, the median over its
    frames of their true heights (each the median bottom of the frame's objects) with their robust
    spread in log h (1.4826 median absolute deviations, at least 0.02), and a level pose ±0.5°."""
    import importlib.util
    import json

    from creference_bayes.bench.kitti import kitti_scenes

    script = Path(__file__).resolve().parents[1] / "examples" / "kitti_study.py"
    spec = importlib.util.spec_from_file_location("kitti_study", script)
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    paths = []
    for name, cam, ys in (("1", "a", [1.6, 1.5, 1.7]), ("2", "a", [1.7]), ("3", "a", [2.0, 2.2, 1.9]),
                          ("4", "b", [1.5, 1.4])):
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps({"camera": {"id": cam},
                                         "targets": [{"ground_truth": {"location_m": [0.0, y, 10.0]}} for y in ys]}))
    mounts = study._rig_mountings(paths)
    # camera a: medians 1.6, 1.7, 2.0; their logs lie 0.0606, 0 and 0.1625 from log 1.7
    assert mounts["a"][0] == pytest.approx(1.7)
    assert mounts["a"][1] == pytest.approx(1.4826 * np.log(1.7 / 1.6))
    assert mounts["b"] == pytest.approx((1.45, 0.02))
    text = study._mountings_text(paths, mounts).splitlines()
    assert text[1:] == ["  a: 3 frames, 1.70 m (0.090); 1.60, 1.65–1.85, 2.00 m",
                        "  b: 1 frames, 1.45 m (0.020); 1.45, 1.45–1.45, 1.45 m"]
    kitti_scenes(kitti_dir, tmp_path / "s", n_annotations=1)
    plain = study._load_frame(tmp_path / "s" / "000007.json", "unknown")
    frame = study._load_frame(tmp_path / "s" / "000007.json", "rig", mounts={plain.camera_id: (1.8, 0.07)})
    p = frame.orientation_prior
    assert (p.height_median_m, p.height_log_sd) == (1.8, 0.07)
    assert p.pitch_sd == pytest.approx(np.radians(0.5)) and p.roll_sd == pytest.approx(np.radians(0.5))
    known = study._load_frame(tmp_path / "s" / "000007.json", "known").orientation_prior
    truth = np.median([t.ground_truth["location_m"][1] for t in plain.targets])
    assert (known.height_median_m, known.height_log_sd) == (pytest.approx(truth), 0.02)
