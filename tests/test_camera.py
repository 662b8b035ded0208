"""What the estimate knows about the camera: orientation modes, the horizon as a measurement,
the focal-length prior (scene, EXIF, default), the pose prior, and the sampling coordinates."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image
from scipy import stats

import creference_bayes as cb
from creference_bayes.bench.simulate import simulate_scene, true_params
from creference_bayes.camera_setup import GIVEN_HORIZON_SD_PX, setup_camera
from creference_bayes.core.geometry import horizon_from_rotation, rotation_from_pitch_roll
from creference_bayes.io.scene import SceneError, parse_scene, scene_to_dict
from creference_bayes.models.camera_terms import (FULL_FRAME_DIAGONAL_MM, FocalPrior, OrientationPrior,
                                                  horizon_offsets)
from creference_bayes.models.coordinates import Chained, HorizonDistance, ImageRay
from creference_bayes.pipeline import build_models
from creference_bayes.vision.exif import focal_from_exif


def _scene_dict(seed=3, **kw):
    return simulate_scene(np.random.default_rng(seed), **{"tier": "low", **kw})


def _parse(d):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)




# -- orientation and focal prior decisions ------------------------------------------------------

def test_orientation_modes():
    d = _scene_dict()
    exact = setup_camera(_parse(d))
    assert exact.orientation == "horizon" and exact.camera.horizon is not None
    assert exact.terms.orientation is None and exact.terms.horizon is None
    d_sd = {**d, "horizon_sd_px": 3.0}
    measured = setup_camera(_parse(d_sd))
    assert measured.orientation == "free" and measured.camera.horizon is None
    assert measured.terms.horizon.sd_px == 3.0 and measured.terms.horizon.source == "scene"
    forced = setup_camera(_parse(d), orientation="free")
    assert forced.terms.horizon.sd_px == GIVEN_HORIZON_SD_PX
    no = {k: v for k, v in d.items() if k != "horizon"}
    free = setup_camera(_parse(no))
    assert free.orientation == "free" and free.terms.orientation is not None and free.terms.horizon is None
    assert any("no horizon and no image" in n for n in free.notes)
    level = setup_camera(_parse(no), orientation="level")
    assert level.orientation == "level" and level.camera.horizon is None
    with pytest.raises(ValueError, match="orientation"):
        setup_camera(_parse(d), orientation="tilted")


def test_focal_prior_sources():
    d = _scene_dict()
    default = setup_camera(_parse(d)).terms.focal
    assert default.source == "default"
    assert default.median_px == pytest.approx(30.0 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))
    assert setup_camera(_parse(d), focal_prior="none").terms.focal is None
    stated = _parse({**d, "camera": {**d["camera"], "focal_length_prior": {"equivalent_35mm_mm": 26, "log_sd": 0.05}}})
    fp = setup_camera(stated).terms.focal
    assert fp.source == "scene" and fp.log_sd == 0.05 and np.isinf(fp.dof)
    assert fp.median_px == pytest.approx(26 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))
    assert setup_camera(stated, focal_prior="default").terms.focal.source == "default"
    known = _parse({**d, "camera": {**d["camera"], "focal_length_px": 1500.0}})
    assert setup_camera(known).terms.focal is None


def test_scene_keys_are_validated_and_round_trip():
    d = _scene_dict()
    d["horizon_sd_px"] = 2.5
    d["camera"]["focal_length_prior"] = {"median_px": 1800, "log_sd": 0.2, "dof": 4}
    d["camera"]["orientation_prior"] = {"pitch_sd_deg": 5, "height_median_m": 1.2}
    s = _parse(d)
    assert s.horizon_sd_px == 2.5 and s.focal_prior.median_px == 1800 and s.focal_prior.dof == 4
    assert s.orientation_prior.pitch_sd == pytest.approx(np.radians(5))
    assert s.orientation_prior.height_median_m == 1.2 and s.orientation_prior.roll_sd == pytest.approx(np.radians(10))
    back = _parse(json.loads(json.dumps(scene_to_dict(s))))
    assert back.horizon_sd_px == 2.5 and back.focal_prior == s.focal_prior
    assert back.orientation_prior == s.orientation_prior
    bad = [({"horizon_sd_px": -1}, "horizon_sd_px: expected a number >= 0"),
           ({"camera": {"focal_length_prior": {"median_px": 1, "equivalent_35mm_mm": 2}}},
            "camera.focal_length_prior: expected exactly one of"),
           ({"camera": {"focal_length_prior": {"median_px": 1800, "log_sd": 0}}},
            "camera.focal_length_prior.log_sd: expected a positive number"),
           ({"camera": {"orientation_prior": {"pitch_sd_deg": -2}}}, "camera.orientation_prior.pitch_sd_deg")]
    for change, message in bad:
        with pytest.raises(SceneError, match=message.replace("(", r"\(")):
            parse_scene({**_scene_dict(), **change})
    no_horizon = {k: v for k, v in _scene_dict().items() if k != "horizon"}
    with pytest.raises(SceneError, match="horizon_sd_px: an uncertainty 2 px without a horizon"):
        parse_scene({**no_horizon, "horizon_sd_px": 2})


# -- the terms against independent formulas ----------------------------------------------------

def test_focal_and_pose_priors_against_scipy():
    fp = FocalPrior(1500.0, 0.3, 3.0)
    mu = np.array([600.0, 1500.0, 4000.0])
    want = -stats.t(3, loc=np.log(1500), scale=0.3).logpdf(np.log(mu)) + np.log(mu)
    got = fp.neg_log(mu)
    np.testing.assert_allclose(got - got[1], want - want[1], rtol=1e-10)
    lo, hi = fp.interval(0.9)
    assert stats.t(3).cdf(np.log(hi / 1500) / 0.3) == pytest.approx(0.95)
    op = OrientationPrior()
    p, r, h = np.radians([3.0, 20.0]), np.radians([-2.0, 7.0]), np.array([1.6, 6.0])
    want = -(stats.norm(0, op.pitch_sd).logpdf(p) + stats.norm(0, op.roll_sd).logpdf(r)
             + stats.norm(np.log(1.6), 0.6).logpdf(np.log(h)) - np.log(h))
    got = op.neg_log(p, r, h)
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-10)


def test_points_on_the_true_horizon_have_zero_offset():
    rng = np.random.default_rng(0)
    pp = np.array([1500.0, 880.0])
    for _ in range(5):
        pitch, roll, mu = rng.uniform(-0.2, 0.4), rng.uniform(-0.1, 0.1), rng.uniform(900, 3000)
        pts = horizon_from_rotation(rotation_from_pitch_roll(pitch, roll), mu, pp, 2880)
        full = np.array([[0, 1.5, 5, 0, mu, pitch, roll]])
        np.testing.assert_allclose(horizon_offsets(pts, full, pp), 0.0, atol=1e-7)
        below = pts + [[0.0, 10.0], [0.0, 10.0]]
        assert np.all(horizon_offsets(below, full, pp) > 9.0)


def test_sampling_coordinates_round_trip_and_jacobian():
    s = _parse({k: v for k, v in _scene_dict(5).items() if k != "horizon"})
    model = build_models(s, setup_camera(s))[0]
    hd = HorizonDistance.from_model(model)
    assert hd is not None and HorizonDistance.from_model(build_models(_parse(_scene_dict(5)),
                                                                      setup_camera(_parse(_scene_dict(5))))[0]) is None
    p = true_params(s)[model.free] + np.random.default_rng(1).normal(0, 0.01, (6, 7))
    q = hd.forward(p)
    np.testing.assert_allclose(hd.inverse(q), p, rtol=1e-12, atol=1e-12)
    eps = 1e-6
    for row in q:
        up, dn = row.copy(), row.copy()
        up[hd.i_pitch] += eps
        dn[hd.i_pitch] -= eps
        deriv = (hd.inverse(up[None])[0, hd.i_pitch] - hd.inverse(dn[None])[0, hd.i_pitch]) / (2 * eps)
        assert hd.log_jacobian(row[None])[0] == pytest.approx(np.log(deriv), abs=1e-6)
    above = p[:1].copy()
    above[0, hd.i_pitch] = -1.2  # the target's bottom far above the horizon: no ground there
    assert np.isnan(hd.forward(above)[0, hd.i_pitch])


def test_image_ray_coordinates_are_the_image_offsets_with_the_stated_jacobian():
    """x and y become µx/z and µy/z (the target's offset from the principal point, pixels), chained
    after the horizon distance: a bijection whose log |∂p/∂q| (the full determinant, by central
    differences) is what log_jacobian says."""
    s = _parse({k: v for k, v in _scene_dict(5).items() if k != "horizon"})
    model = build_models(s, setup_camera(s))[0]
    ray = ImageRay.from_model(model)
    coords = Chained.of(HorizonDistance.from_model(model), ray)
    assert isinstance(coords, Chained) and Chained.of(None, ray) is ray and Chained.of(None) is None
    p = true_params(s)[model.free] + np.random.default_rng(2).normal(0, 0.01, (5, 7))
    q = coords.forward(p)
    mu, z = p[:, ray.i_focal], p[:, ray.i_z]
    np.testing.assert_allclose(q[:, ray.i_x], mu * p[:, ray.i_x] / z, rtol=1e-12)
    np.testing.assert_allclose(q[:, ray.i_y], mu * p[:, ray.i_y] / z, rtol=1e-12)
    np.testing.assert_allclose(coords.inverse(q), p, rtol=1e-10, atol=1e-12)
    h = 1e-6
    for row in q:
        J = np.column_stack([(coords.inverse((row + h * e)[None]) - coords.inverse((row - h * e)[None]))[0] / (2 * h)
                             for e in np.eye(len(row))])
        assert coords.log_jacobian(row[None])[0] == pytest.approx(np.log(abs(np.linalg.det(J))), abs=1e-5)


def test_a_far_target_seen_once_mixes_along_its_viewing_ray():
    """An outdoor target at 28 m seen through one set of lines and one reference (the advice
    study's outdoor-017, first adaptive step): the posterior runs along the viewing ray from 17 m
    to the box's 1000 m. Sampled in x and y it held walkers for hundreds of steps in the ray's far
    part and ran to the 20 000-step cap unconverged (τ ≈ 850, 45 s); in the image offsets it
    converges in a few hundred steps."""
    from creference_bayes.bench.runner import variant

    pool = _parse(simulate_scene(np.random.default_rng([1000, 17]), tier="high", setting="outdoor",
                                 n_target_annotations=13, n_references=10, format_offset=17))
    r = cb.estimate(variant(pool, 1, [0]), seed=[0, 1017, 8, 1], sampling={"min_ess": 400})
    d = r.diagnostics
    assert d.converged
    assert d.n_steps + d.warmup_steps < 2000
    lo, hi = r.posterior.hdi["distance_m"]
    truth = float(np.hypot(*np.asarray(pool.ground_truth.location_m)[[0, 2]]))
    assert lo < truth < hi and hi > 5 * truth  # wide, as one set of lines on a far target is


# -- EXIF ---------------------------------------------------------------------------------------

def _jpeg(path, size=(720, 450), **tags):
    img = Image.new("RGB", size, (120, 120, 120))
    exif = Image.Exif()
    ifd = exif.get_ifd(0x8769)
    for tag, value in tags.items():
        ifd[{"f35": 0xA405, "focal": 0x920A, "xres": 0xA20E, "unit": 0xA210, "width": 0xA002}[tag]] = value
    img.save(path, exif=exif)
    return path


def test_exif_focal_length_routes(tmp_path):
    a = focal_from_exif(_jpeg(tmp_path / "a.jpg", f35=26), (2880, 1800))
    assert a.route == "35mm" and a.focal_px == pytest.approx(26 / FULL_FRAME_DIAGONAL_MM * np.hypot(2880, 1800))
    # a 6 mm lens on a sensor of 400 pixels per mm, recorded 4000 px wide, the scene 2880 wide
    b = focal_from_exif(_jpeg(tmp_path / "b.jpg", focal=6.0, xres=400.0, unit=4, width=4000), (2880, 1800))
    assert b.route == "focal_plane" and b.focal_px == pytest.approx(6.0 * 400.0 * 2880 / 4000)
    assert focal_from_exif(_jpeg(tmp_path / "c.jpg"), (2880, 1800)) is None
    (tmp_path / "d.jpg").write_bytes(b"not an image")
    assert focal_from_exif(tmp_path / "d.jpg", (2880, 1800)) is None
    assert focal_from_exif(tmp_path / "missing.jpg", (2880, 1800)) is None


def test_pipeline_uses_exif_and_warns_when_the_annotations_disagree(tmp_path):
    d = _scene_dict(4, n_target_annotations=5)
    truth_35 = d["ground_truth"]["focal_length_px"] / np.hypot(2880, 1800) * FULL_FRAME_DIAGONAL_MM
    for name, f35 in (("right", truth_35), ("wrong", 4 * truth_35)):
        _jpeg(tmp_path / f"{name}.jpg", size=(2880, 1800), f35=int(round(f35)))
        scene = {**d, "image": {**d["image"], "path": f"{name}.jpg"}}
        (tmp_path / f"{name}.json").write_text(json.dumps(scene))
        r = cb.estimate(tmp_path / f"{name}.json", posterior=False)
        assert r.to_dict()["camera"]["focal_prior"]["source"] == "exif"
        assert any("EXIF" in w for w in r.warnings)
        disagree = any("disagree with the exif focal length prior" in w for w in r.warnings)
        assert disagree == (name == "wrong"), r.warnings


# -- estimates ------------------------------------------------------------------------------------

def test_free_orientation_recovers_noise_free_scenes():
    """No horizon, noise-free annotations: pitch, roll and the location come back (the priors'
    pull on exact data is small)."""
    for seed in range(4):
        d = simulate_scene(np.random.default_rng([5, seed]), tier="none", n_target_annotations=5,
                           principal_offset=0.05, roll_deg=5.0, decimals=None)
        del d["horizon"]
        s = _parse(d)
        r = cb.estimate(s, posterior=False)
        m, t = r.map.params, true_params(s)
        assert r.evaluation.location_pct_error < 0.2, (seed, r.evaluation.location_pct_error)
        assert abs(m[5] - t[5]) < np.radians(0.2) and abs(m[6] - t[6]) < np.radians(0.2)


def test_without_a_horizon_the_posterior_widens_and_still_holds_thetrue_params():
    d = _scene_dict(11, n_target_annotations=5, roll_deg=4.0, principal_offset=0.05)
    s = _parse(d)
    kw = dict(seed=0, sampling={"min_ess": 300})
    with_h = cb.estimate(s, **kw)
    without = cb.estimate(replace(s, horizon=None), **kw)
    assert with_h.posterior.sd["pitch"] < without.posterior.sd["pitch"]
    width = lambda r: np.diff(r.posterior.hdi["distance_m"])[0]  # noqa: E731
    assert width(without) > width(with_h)
    assert without.evaluation.in_hdi["distance_m"] and without.evaluation.in_hdi["pitch"]
    assert without.diagnostics.converged, without.diagnostics.warnings
