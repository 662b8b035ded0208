"""The camera rig (workflows/batch/rig.py, ``creference batch --rig``): frames of one camera pool
what they share; each frame is re-estimated with the others' evidence."""

import json
import math

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.io.result import CAMERA_NAMES, OBJECT_NAMES
from creference_bayes.io.scene import SceneError, parse_scene
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.engines import LocalEngine
from creference_bayes.workflows.batch import rig as rig_module
from creference_bayes.workflows.batch.rig import (SHARED_BIAS_SD, RigPool, SharedLikelihood, apply_rig, rig_report,
                                                  shared_likelihood)

FLOOR = SHARED_BIAS_SD["log_focal"]


def _frames(values, precisions, camera="cam", name="log_focal"):
    return [SharedLikelihood(f"f{i}", camera, {name: float(m)}, {name: float(p)})
            for i, (m, p) in enumerate(zip(values, precisions))]


def test_a_shared_focal_length_is_recovered_and_its_spread_is_honest():
    rng = np.random.default_rng(3)
    truth = math.log(800.0)
    p = rng.uniform(16.0, 100.0, 40)  # log-sd 0.1 to 0.25 per frame: all informative
    est = RigPool(_frames(truth + rng.normal(0, 1 / np.sqrt(p)), p), "focal").estimate("cam")
    assert abs(est.center["log_focal"] - truth) < 4 * math.sqrt(est.var["log_focal"])
    # frames that agree: about the precisions' sum, and the floor for the model's shared bias
    assert est.var["log_focal"] <= 2.0 / p.sum() + FLOOR**2
    assert rig_report(est)["warnings"] == []  # forty frames that agree: nothing to warn of
    # frames that disagree beyond their stated precision (a likelihood the normal describes badly):
    # the rig widens instead of becoming over-sure
    m = truth + rng.normal(0, 1 / np.sqrt(p)) + rng.normal(0, 0.3, len(p))
    wide = RigPool(_frames(m, p), "focal").estimate("cam")
    assert wide.var["log_focal"] - FLOOR**2 > 3.0 / p.sum()
    assert abs(wide.center["log_focal"] - truth) < 4 * math.sqrt(wide.var["log_focal"])


def test_frames_with_a_wide_likelihood_are_left_out_of_the_pool():
    """Weak frames (likelihood log-sd > 0.25) are biased (docs/studies/rig.md): only informative
    frames are pooled, however many weak ones there are."""
    precise = _frames([math.log(700.0)] * 3, [1 / 0.1**2] * 3)
    weak = [SharedLikelihood(f"w{i}", "cam", {"log_focal": math.log(400.0)}, {"log_focal": 1 / 0.3**2})
            for i in range(10)]
    est = RigPool(precise + weak, "focal").estimate("cam")
    assert est.frames["log_focal"] == 3 and est.check["log_focal"].offered == 13
    assert est.center["log_focal"] == pytest.approx(math.log(700.0))
    block = rig_report(est)["focal_length_px"]
    assert (block["frames"], block["frames_offered"]) == (3, 13)
    # a frame whose only others are weak gets no prior from them
    scene = parse_scene(truth_scene(0)[0] | {"camera": {"id": "cam", "principal_point": [1483.2, 864.0]}})
    assert apply_rig(scene, _frames([6.6], [1 / 0.1**2]) + weak, "focal", "f0") == (scene, None)


def test_the_pooled_sd_is_never_below_the_floor():
    """However many frames agree, the model's bias that they share remains: the stated sd is at
    least the floor (in quadrature), in the pool and in the prior a frame gets from it."""
    rng = np.random.default_rng(4)
    p = np.full(200, 1 / 0.05**2)
    frames = _frames(math.log(720.0) + rng.normal(0, 0.05, 200), p)
    est = RigPool(frames, "focal").estimate("cam")
    assert math.sqrt(est.var["log_focal"]) >= FLOOR
    assert est.var["log_focal"] == pytest.approx(1 / p.sum() + FLOOR**2, rel=0.2)
    scene = parse_scene(truth_scene(0)[0] | {"camera": {"id": "cam", "principal_point": [1483.2, 864.0]}})
    pooled, _ = apply_rig(scene, frames, "focal", "f0")
    assert pooled.focal_prior.log_sd >= FLOOR
    block = rig_report(est)["focal_length_px"]
    assert block["log_sd"] >= FLOOR and block["floor_log_sd"] == FLOOR


def test_a_pool_resting_on_one_frame_warns():
    """One very precise frame among weak ones carries the pool: the rig block says so."""
    rng = np.random.default_rng(6)
    p = np.r_[1 / 0.01**2, np.full(10, 1 / 0.2**2)]
    est = RigPool(_frames(math.log(720.0) + rng.normal(0, 1 / np.sqrt(p)), p), "focal").estimate("cam")
    check = est.check["log_focal"]
    assert check.n_eff < 2 and check.top3_share > 0.9
    report = rig_report(est)
    assert report["focal_length_px"]["warnings"] == [rig_module.FEW_FRAMES]
    assert report["warnings"] == ["focal_length_px: " + rig_module.FEW_FRAMES]
    assert any("warning: rig cam: focal_length_px: the pool rests on few frames" == line
               for line in rig_module.rig_lines({"cam": report}))


def test_two_groups_of_frames_that_disagree_raise_d():
    """Ten precise frames say 700 px, twenty less precise ones 800 px: the pool follows the precise
    ten, the frames' median the twenty; D says they disagree (the pool rests on enough frames)."""
    rng = np.random.default_rng(7)
    m = np.r_[math.log(700.0) + rng.normal(0, 0.01, 10), math.log(800.0) + rng.normal(0, 0.01, 20)]
    p = np.r_[np.full(10, 1 / 0.05**2), np.full(20, 1 / 0.15**2)]
    est = RigPool(_frames(m, p), "focal").estimate("cam")
    check = est.check["log_focal"]
    assert check.d < -2 and check.n_eff > 5 and check.top3_share < 0.6
    assert check.median == pytest.approx(math.log(800.0), abs=0.03)
    assert rig_report(est)["focal_length_px"]["warnings"] == [rig_module.DISAGREE]
    # the same frames in one group: no disagreement
    same = RigPool(_frames(np.full(30, math.log(700.0)) + rng.normal(0, 0.01, 30), p), "focal").estimate("cam")
    assert abs(same.check["log_focal"].d) < 2 and rig_report(same)["warnings"] == []


def test_the_mountings_spread_between_frames_is_estimated():
    rng = np.random.default_rng(5)
    per_frame = math.log(1.65) + rng.normal(0, 0.05, 300)  # a vehicle's camera height, 5 % frame to frame
    p = np.full(300, 1 / 0.03**2)
    frames = _frames(per_frame + rng.normal(0, 0.03, 300), p, name="log_height")
    est = RigPool(frames, "mounting").estimate("cam")
    assert 0.035 < est.tau["log_height"] < 0.065
    assert abs(math.exp(est.center["log_height"]) - 1.65) < 0.03
    # focal pools no mounting
    assert RigPool(_frames(per_frame, p, name="log_height"), "focal").estimate("cam") is None
    # frames that agree exactly still leave the vehicle its least spread (rig.MIN_SPREAD: 3 % of height)
    frames = _frames(np.full(30, math.log(1.65)), p[:30], name="log_height")
    still = RigPool(frames, "mounting").estimate("cam")
    assert still.tau["log_height"] == pytest.approx(0.03)


def test_a_frames_prior_comes_from_the_other_frames_only():
    scene = parse_scene(truth_scene(0)[0] | {"camera": {"id": "cam", "principal_point": [1483.2, 864.0]}})
    frames = _frames([6.6, 6.7, 6.68], [50.0, 50.0, 50.0])
    a, est = apply_rig(scene, frames, "focal", "f0")
    moved = [SharedLikelihood("f0", "cam", {"log_focal": 9.0}, {"log_focal": 500.0})] + frames[1:]
    b, _ = apply_rig(scene, moved, "focal", "f0")
    assert a.focal_prior == b.focal_prior and a.focal_prior.source == "rig"
    assert est.keys == ("f1", "f2")
    other = parse_scene(truth_scene(0)[0] | {"camera": {"id": "another", "principal_point": [1483.2, 864.0]}})
    assert apply_rig(other, frames, "focal", "f0") == (other, None)  # no frame of its camera


def test_a_frames_calibrated_mounting_is_multiplied_into_the_pooled_one_not_replaced():
    """A mounting answer (advise --apply) stays in the frame's second pass: the product of the other
    frames' pooled mounting and the calibration's, so the answer the advice weighed is used."""
    from creference_bayes.workflows.advice.answers import with_mounting

    scene = parse_scene(truth_scene(0)[0] | {"camera": {"id": "cam", "principal_point": [1483.2, 864.0]}})
    frames = [SharedLikelihood(f"f{i}", "cam", {"log_height": math.log(h), "pitch": 0.02},
                               {"log_height": 1 / 0.05**2, "pitch": 1 / 0.01**2})
              for i, h in enumerate((1.5, 1.55, 1.45, 1.52))]
    plain, est = apply_rig(scene, frames, "mounting", "f0")
    pooled = plain.orientation_prior
    calibrated = with_mounting(scene, 1.70, 0.0)
    both, _ = apply_rig(calibrated, frames, "mounting", "f0")
    got, own = both.orientation_prior, calibrated.orientation_prior
    w0, w1 = pooled.height_log_sd ** -2, own.height_log_sd ** -2
    assert got.height_log_sd == pytest.approx((w0 + w1) ** -0.5)
    assert math.log(got.height_median_m) == pytest.approx(
        (w0 * math.log(pooled.height_median_m) + w1 * math.log(own.height_median_m)) / (w0 + w1))
    assert got.pitch_sd < min(pooled.pitch_sd, own.pitch_sd) and got.source == "calibration"
    assert "roll" not in est.center and got.roll_sd == own.roll_sd  # not pooled: the calibration's, counted once
    assert 1.6 < got.height_median_m < 1.70  # the calibration (2 %) outweighs the pool


def _result_with_draws(log_focal: np.ndarray, prior: dict) -> dict:
    n = len(log_focal)
    cam = {"focal_length_px": np.exp(log_focal).tolist(), "pitch": 0.1, "roll": 0.0, "height_m": 1.6, "ref_scale": 0.5}
    return {"camera": {"free": ["focal_length_px"], "setup": {"focal_prior": prior}},
            "objects": [{}], "draws": {"n": n, "camera": {k: cam[k] for k in CAMERA_NAMES},
                                       "objects": [{k: 1.0 for k in OBJECT_NAMES}]}}


def test_the_prior_a_frame_used_is_divided_out():
    # posterior = likelihood N(a, 1/p) × log-normal prior N(b, s²) on log µ
    a, p, b, s = math.log(700.0), 1 / 0.15**2, math.log(900.0), 0.3
    post_p = p + 1 / s**2
    post_m = (p * a + b / s**2) / post_p
    draws = np.random.default_rng(1).normal(post_m, 1 / math.sqrt(post_p), 20000)
    f = shared_likelihood("k", "cam", _result_with_draws(draws, {"median_px": 900.0, "log_sd": s, "dof": None}))
    assert f.mean["log_focal"] == pytest.approx(a, abs=0.01)
    assert f.precision["log_focal"] == pytest.approx(p, rel=0.1)
    # a frame whose posterior is its prior tells nothing and is left out of the pool
    flat = np.random.default_rng(2).normal(b, s, 20000)
    assert shared_likelihood("k", "cam", _result_with_draws(flat, {"median_px": 900.0, "log_sd": s, "dof": None})).mean == {}


def test_a_weak_frames_heavy_tailed_prior_is_divided_out_exactly():
    """A weak frame (likelihood log-sd 0.35) under a Student-t prior (the default's shape, 3 degrees
    of freedom) that pulls it up: the posterior is far from normal, and a Laplace step at its mean
    misreads the likelihood; reweighting the draws by 1/prior recovers its mean and variance."""
    a, sd, b, s, dof = math.log(500.0), 0.35, math.log(900.0), 0.25, 3.0
    rng = np.random.default_rng(8)
    lik = rng.normal(a, sd, 400000)  # the posterior by resampling the likelihood's draws by the prior
    w = (1 + ((lik - b) / s) ** 2 / dof) ** (-(dof + 1) / 2)
    post = rng.choice(lik, 20000, p=w / w.sum())
    f = shared_likelihood("k", "cam", _result_with_draws(post, {"median_px": 900.0, "log_sd": s, "dof": dof}))
    assert f.mean["log_focal"] == pytest.approx(a, abs=0.03)
    assert f.precision["log_focal"] ** -0.5 == pytest.approx(sd, rel=0.1)


def test_scene_camera_id_round_trips_and_is_validated():
    d = truth_scene(0)[0]
    d["camera"] = {"id": "kitti-1", "principal_point": [1483.2, 864.0]}
    from creference_bayes.io.scene import scene_to_dict

    assert parse_scene(scene_to_dict(parse_scene(d))).camera_id == "kitti-1"
    for bad in (3, " "):
        d["camera"]["id"] = bad
        with pytest.raises(SceneError, match="camera.id"):
            parse_scene(d)


@pytest.fixture(scope="module")
def rig_batch(tmp_path_factory):
    """Four frames of one camera (the same focal length, height, pitch), one frame of no named camera."""
    root = tmp_path_factory.mktemp("rig")
    (root / "in").mkdir()
    for seed in range(5):
        scene, _ = truth_scene(seed, m=2, noise_px=1.0, n_annotations=3, sizes_known=False, focal_px=1400.0)
        if seed < 4:
            scene["camera"]["id"] = "rig-A"
        (root / "in" / f"f{seed}.json").write_text(json.dumps(scene))
    settings = BatchSettings(seed=2, sampling={"min_ess": 50, "max_steps": 500, "warmup": 200}, rig="mounting")
    report = run_batch([root / "in"], root / "out", LocalEngine(2), settings)
    return root, settings, report


def test_batch_pools_the_focal_length_and_mounting_of_one_camera(rig_batch):
    root, settings, report = rig_batch
    assert report.ok and len(report.keys("done")) == 5
    out = root / "out"
    for k in range(4):
        res = json.loads((out / "results" / f"f{k}.json").read_text())
        first = json.loads((out / "first_pass" / "results" / f"f{k}.json").read_text())
        rig = res["rig"]
        assert rig["camera_id"] == "rig-A" and rig["frames"] == 3
        # the focal length is held: the pool of the camera's four frames, the frame's own; its copy of
        # the scene carries it for `labels`
        focal = res["dataset"]["focal_length_px"]
        copy = json.loads((out / "scenes" / f"f{k}.json").read_text())
        assert focal["held"] and copy["camera"]["focal_length_px"] == focal["median"] and "focal_length_px" not in rig
        # the frames know the focal length better than the default prior did
        assert focal["log_sd"] < first["camera"]["setup"]["focal_prior"]["log_sd"]
        assert abs(math.log(focal["median"] / 1400.0)) < 4 * focal["log_sd"]
        # the mounting: the frames' shared height (1.6 m) and pitch (6°), each with a spread
        height, pitch = rig["height_m"], rig["pitch_deg"]
        assert height["spread_log_sd"] >= 0.03 and pitch["spread_sd"] >= 0.5
        prior = copy["camera"]["orientation_prior"]
        assert prior["height_median_m"] == pytest.approx(height["median"], rel=1e-3)
        assert prior["pitch_mean_deg"] == pytest.approx(pitch["mean"], abs=1e-3)
        assert prior["pitch_sd_deg"] < 15.0 / 4  # far narrower than the default prior's 15°
        assert abs(math.log(height["median"] / 1.6)) < 4 * math.hypot(height["log_sd"], height["spread_log_sd"])
    alone = json.loads((out / "results" / "f4.json").read_text())
    assert "rig" not in alone and alone["camera"]["setup"]["focal_prior"]["source"] == "default"


def test_a_rig_batch_resumes(rig_batch):
    root, settings, _ = rig_batch
    again = run_batch([root / "in"], root / "out", LocalEngine(1), settings)
    assert again.keys("skipped") == [f"f{k}" for k in range(5)]


def test_a_frame_without_a_camera_id_is_named_by_its_photos_exif(tmp_path):
    from test_camera import _camera_jpeg

    d = truth_scene(0)[0]
    d["image"]["path"] = str(_camera_jpeg(tmp_path / "a.jpg", make="Canon", model="Canon EOS 80D", focal=35.0))
    scene = parse_scene(d)
    assert scene.camera_id is None
    frames = [SharedLikelihood(f"f{i}", "exif:Canon EOS 80D 35mm", {"log_focal": 7.2}, {"log_focal": 40.0})
              for i in range(3)]
    pooled, est = apply_rig(scene, frames, "focal", "f9")
    assert pooled.camera_id == "exif:Canon EOS 80D 35mm" and est.keys == ("f0", "f1", "f2")
    assert pooled.focal_prior.median_px == pytest.approx(math.exp(7.2))


def test_the_rig_pool_example_prints_every_cameras_pool_before_and_after(rig_batch):
    """examples/rig_pool.py (docs/studies/rig.md) on a rig batch's first pass: a row for camera
    rig-A under each rule, with its frames counted; it writes nothing."""
    import subprocess
    import sys
    from pathlib import Path

    root, _, _ = rig_batch
    example = Path(__file__).resolve().parents[1] / "examples" / "rig_pool.py"
    before = sorted(p for p in (root / "out").rglob("*"))
    proc = subprocess.run([sys.executable, str(example), str(root / "out"), "--groups", "0-1,2-3"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "rig-A" in proc.stdout and "before" in proc.stdout and "after" in proc.stdout, proc.stdout
    assert sorted(p for p in (root / "out").rglob("*")) == before


def test_the_labels_sidecar_says_what_each_frame_took_from_the_data_set(rig_batch, tmp_path):
    from creference_bayes.cli.main import main

    root, _, _ = rig_batch
    assert main(["labels", str(root / "out"), "--out", str(tmp_path / "l"), "--quiet", "--no-figure"]) == 0
    side = json.loads((tmp_path / "l" / "uncertainty" / "f0.json").read_text())
    took = side["dataset"]["focal_length_px"]
    assert took["from"] == "data set" and took["group"] == "rig-A" and took["log_sd"] >= FLOOR
    assert took["held"] and side["camera"]["focal_length_px"] == took["median"]  # the camera's one value
    assert took["shared_scale_log_sd"] == took["log_sd"]  # how sure the pool was: carried by the draws
    assert "dataset" not in json.loads((tmp_path / "l" / "uncertainty" / "f4.json").read_text())
