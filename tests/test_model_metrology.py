"""The metrology model (method.md §7): likelihood terms against independent formulas, exact
recovery, robustness of the heavy tails, the interface shared with PaperModel, the pipeline/CLI."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from creference_bayes.cli.main import main
from creference_bayes.core.geometry import Camera
from creference_bayes.models.params import Bounds
from creference_bayes.models.metrology import (DEFAULT_TARGET_SIGMA_PX, MIN_CAMERA_HEIGHT_M,
                                               MIN_TARGET_SIGMA_PX, MetrologyModel,
                                               ReferenceMeasurement, estimate_target_sigma)
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.pipeline import build_models, estimate
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.bench.simulate import simulate_scene


def _scene(seed, n=5, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = parse_scene(simulate_scene(np.random.default_rng(seed), **kw))
    return replace(s, target=replace(s.target, dimension_lines=s.target.dimension_lines[:n]))


def _truth(scene):
    g = scene.ground_truth
    return np.array([*g.location_m, g.yaw_rad, g.focal_length_px])


def _model(scene, **kw):
    return MetrologyModel.from_scene(scene, scene.ground_truth.extra["handedness"], **kw)


def test_noise_free_recovery_with_and_without_references():
    for seed in range(4):
        s = _scene(seed, tier="none", principal_offset=0.05)
        g = s.ground_truth
        for refs, tol in ((False, 1e-6), (True, 0.5)):  # stated values are rounded; ranges ±12 %
            models = build_models(s, model="metrology", use_references=refs)
            m = optimize_map(models, "default")
            err = np.linalg.norm(m.params[:3] - g.location_m) / np.linalg.norm(g.location_m) * 100
            assert err < tol, (seed, refs, err)
            assert m.handedness == g.extra["handedness"]


def test_reference_terms_against_scipy_student_t():
    """Single values: −log t-density in log-length; ranges: −log of a t-probability (scipy)."""
    s = _scene(3, tier="none")
    m = _model(s)
    p = _truth(s)
    ell = np.exp(np.log(np.array(s.ground_truth.extra["reference_lengths_m"])))
    shifts = np.array([0.0, 0.3, -0.8, 2.5])  # move the true lengths by these log factors
    dist = stats.t(m.ref_dof, scale=m.ref_scale)
    for d in shifts:
        log_len = np.log(ell)[None] + d
        got = m._reference_nll(log_len, m.ref_scale)[0]
        want = 0.0
        for r, li in zip(s.references, log_len[0]):
            lo, hi = r.length_bounds_m(s.target)
            if r.is_range:
                want -= np.log(dist.cdf(np.log(hi) - li) - dist.cdf(np.log(lo) - li))
            else:  # −log density, up to the constant −log t_ν(0) of the standard t
                want -= dist.logpdf(np.log(lo) - li) - stats.t(m.ref_dof).logpdf(0.0)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-9)
    # far in the tails the range term stays finite and keeps growing
    far = m._reference_nll(np.log(ell)[None] + np.array([[8.0], [16.0]]), m.ref_scale)
    assert np.all(np.isfinite(far)) and far[1] > far[0]


def test_line_noise_widens_far_references():
    """s_j² = s² + σ_line² |∇ log ℓ_j|²: against an independent central difference of the
    log-length over the endpoints, and larger for a segment nearer the horizon."""
    s = _scene(4, tier="medium", setting="outdoor")
    m = _model(s, ref_line_sigma=10.0)
    p = _truth(s)
    mu, h = p[None, 4], p[None, 1]
    log_len, scale = m._log_lengths(mu, h, m.camera.rotation(mu))
    from creference_bayes.models.metrology import ground_lengths

    lines = m._lines
    g2 = np.zeros(len(lines))
    for k in range(4):
        d = np.eye(4)[k].reshape(2, 2) * 1e-3
        up = np.log(ground_lengths(lines + d, m.camera, mu, h)[0])
        dn = np.log(ground_lengths(lines - d, m.camera, mu, h)[0])
        g2 += ((up - dn) / 2e-3) ** 2
    np.testing.assert_allclose(scale[0], np.sqrt(m.ref_scale**2 + 100.0 * g2), rtol=0.05)
    assert np.all(scale >= m.ref_scale)
    dist = np.min(lines.reshape(-1, 2, 2) @ m.camera.horizon[:2] + m.camera.horizon[2], axis=1)
    assert scale[0, np.argmin(dist)] == scale[0].max()  # the segment nearest the horizon
    flat = _model(s, ref_line_sigma=0.0)
    np.testing.assert_allclose(flat._log_lengths(mu, h, m.camera.rotation(mu))[1], m.ref_scale)
    assert _model(s).ref_line_sigma == pytest.approx(2.0 * _model(s).target_sigma)


def test_estimated_corner_scale():
    rng = np.random.default_rng(0)
    base = rng.uniform(0, 1000, (4, 2))
    many = base + rng.normal(0, 5.0, (400, 4, 2))
    assert estimate_target_sigma(many) == pytest.approx(5.0, rel=0.03)
    assert estimate_target_sigma(base[None]) == DEFAULT_TARGET_SIGMA_PX
    assert estimate_target_sigma(np.stack([base, base])) == MIN_TARGET_SIGMA_PX
    with pytest.raises(ValueError, match=r"shape \(n, 4, 2\)"):
        estimate_target_sigma(base)


def test_heavy_tails_resist_an_outlier_annotation():
    """One annotation shifted by 150 px: the Student-t likelihood barely moves; a Gaussian one
    (ν → ∞) is dragged."""
    s = _scene(1, n=5, tier="low")
    corners = s.target.corners.copy()
    corners[0] += 150.0
    lines = tuple(replace(d, corners=c) for d, c in zip(s.target.dimension_lines, corners))
    bad = replace(s, target=replace(s.target, dimension_lines=lines), references=())
    truth = s.ground_truth.location_m

    def err(**kw):
        m = optimize_map(build_models(bad, model="metrology", target_sigma=2.0, **kw), "default")
        return np.linalg.norm(m.params[:3] - truth) / np.linalg.norm(truth) * 100

    robust, gaussian = err(), err(target_dof=1e6)
    assert robust < 3.0
    assert gaussian > 3 * robust


def test_interface_and_bounds():
    s = _scene(5, tier="medium")
    m = _model(s)
    assert m.name == "metrology" and m.default_temperature == 1.0
    assert m.bounds.lower[1] == MIN_CAMERA_HEIGHT_M and m.free.all()
    p = np.tile(_truth(s), (7, 1))
    assert m.cost(p).shape == (7,)
    np.testing.assert_allclose(m.expand(p[:, m.free]), p)
    assert m.observed.shape == (4, 2) and m.obj_corners.shape == (4, 3)
    known = Camera(s.principal_point, Camera.from_scene(s).horizon, 1500.0)
    mk = MetrologyModel.from_scene(s, 1, camera=known)
    assert not mk.free[4] and mk.expand(np.zeros((1, 4)))[0, 4] == 1500.0
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['sigma'\]"):
        MetrologyModel.from_scene(s, 1, sigma=3.0)
    with pytest.raises(ValueError, match="ref_scale"):
        MetrologyModel.from_scene(s, 1, ref_scale=-1.0)


def test_reference_above_the_horizon_is_left_out():
    s = _scene(2, tier="none")
    cam = Camera.from_scene(s)
    above = ReferenceMeasurement(9, np.array([[100.0, 5.0], [300.0, 8.0]]), 2.0, 2.0, False)
    if cam.horizon is not None:  # make sure the segment really is above the horizon
        assert np.all(np.array([[100.0, 5.0], [300.0, 8.0]]) @ cam.horizon[:2] + cam.horizon[2] < 0)
    m = MetrologyModel(cam, s.target.corners, (s.target.length, s.target.width, s.target.height), 1,
                       Bounds.default(2880, 1800), references=(above,))
    assert m.reference_status == {9: "endpoint_above_horizon"} and m.n_references_used == 0


def test_pipeline_and_cli_select_the_model(tmp_path):
    s = _scene(0, tier="low")
    r = estimate(s, model="metrology", posterior=False)
    assert r.model == "metrology" and r.evaluation.location_pct_error < 5
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene_to_dict(s)))
    out = tmp_path / "r.json"
    assert main(["estimate", str(path), "--model", "metrology", "--out", str(out), "--quiet",
                 "--no-posterior"]) == 0
    assert json.loads(out.read_text())["model"] == "metrology"
    with pytest.raises(SystemExit):
        main(["estimate", str(path), "--model", "nonsense"])

