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
                                               ReferenceMeasurement, estimate_target_sigma,
                                               ground_lengths, segment_reading)
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.camera_setup import setup_camera
from creference_bayes.pipeline import build_models, estimate
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.bench.simulate import simulate_scene, true_params


def _scene(seed, n=5, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = parse_scene(simulate_scene(np.random.default_rng(seed), **kw))
    return replace(s, target=replace(s.target, dimension_lines=s.target.dimension_lines[:n]))




def _model(scene, **kw):
    return MetrologyModel.from_scene(scene, scene.ground_truth.extra["handedness"],
                                     camera=Camera.from_scene(scene), **kw)


def _models(scene, **kw):
    return build_models(scene, setup_camera(scene, focal_prior="none"), model="metrology", **kw)


def test_noise_free_recovery_with_and_without_references():
    for seed in range(4):
        s = _scene(seed, tier="none", principal_offset=0.05, decimals=None)
        g = s.ground_truth
        for refs, tol in ((False, 1e-6), (True, 0.5)):  # stated values are rounded; ranges ±12 %
            models = _models(s, use_references=refs)
            m = optimize_map(models, "default")
            err = np.linalg.norm(m.params[:3] - g.location_m) / np.linalg.norm(g.location_m) * 100
            assert err < tol, (seed, refs, err)
            assert m.handedness == g.extra["handedness"]


def test_reference_terms_against_scipy_student_t():
    """Single values: −log t-density in log-length; ranges: −log of a t-probability (scipy)."""
    s = _scene(3, tier="none")
    m = _model(s, ref_scale=0.75)  # a fixed crowd scale: the plain product over references
    ell = np.array(s.ground_truth.extra["reference_lengths_m"])
    shifts = np.array([0.0, 0.3, -0.8, 2.5])  # move the true lengths by these log factors
    dist = stats.t(m.ref_dof, scale=m.ref_scale)
    for d in shifts:
        log_len = np.log(ell)[None] + d
        got = m._reference_nll(log_len)[0]
        want = 0.0
        for r, li in zip(s.references, log_len[0]):
            lo, hi = r.length_bounds_m(s.target)
            if r.is_range:
                want -= np.log(dist.cdf(np.log(hi) - li) - dist.cdf(np.log(lo) - li))
            else:  # −log density, up to the constant −log t_ν(0) of the standard t
                want -= dist.logpdf(np.log(lo) - li) - stats.t(m.ref_dof).logpdf(0.0)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-9)
    # far in the tails the range term stays finite and keeps growing
    far = m._reference_nll(np.log(ell)[None] + np.array([[8.0], [16.0]]))
    assert np.all(np.isfinite(far)) and far[1] > far[0]
    # the scale integrated out: −log Σ_k w_k Π_j p_jk, with the same per-scale terms
    grid = _model(s)
    log_len = np.log(ell)[None] + 0.3
    per_k = np.array([_model(s, ref_scale=float(k))._reference_nll(log_len)[0] for k in grid._scale_grid])
    want = -np.log(np.sum(np.exp(grid._log_w - per_k)))
    assert grid._reference_nll(log_len)[0] == pytest.approx(want, rel=1e-9)
    assert np.exp(grid._log_w).sum() == pytest.approx(1.0)


def test_closed_form_t2_interval_matches_scipy_far_into_the_tails():
    from creference_bayes.models.metrology import t_interval

    rng = np.random.default_rng(0)
    lo = -np.exp(rng.uniform(-5, 14, 2000))
    hi = lo + np.exp(rng.uniform(-6, 15, 2000))
    t2, t3 = stats.t(2), stats.t(3)
    # scipy's lower-tail form where the interval sits in the lower half, its upper-tail form otherwise
    lower = lo + hi <= 0
    want2 = np.where(lower, t2.cdf(hi) - t2.cdf(lo), t2.sf(lo) - t2.sf(hi))
    want3 = np.where(lower, t3.cdf(hi) - t3.cdf(lo), t3.sf(lo) - t3.sf(hi))
    assert 0 < lower.sum() < len(lo)  # both halves are exercised
    np.testing.assert_allclose(t_interval(2.0, lo, hi), want2, rtol=1e-6)  # both lose digits to cancellation
    np.testing.assert_allclose(t_interval(3.0, lo, hi), want3, rtol=1e-8, atol=1e-15)
    # mirrored intervals have the same probability
    np.testing.assert_allclose(t_interval(2.0, -hi, -lo), t_interval(2.0, lo, hi), rtol=1e-12)


def test_crowd_scale_adapts_to_the_references():
    """Exact references put the crowd-scale posterior on its smallest values; paper-like guesses
    on large ones."""
    exact = _scene(7, tier="none", setting="outdoor", n_references=10, single_values=True)
    noisy = _scene(7, tier="high", setting="outdoor", n_references=10)
    means = []
    for sc in (exact, noisy):
        m = _model(sc)
        grid, w = m.crowd_scale_weights(true_params(sc))
        means.append(float(np.exp(np.sum(w[0] * np.log(grid)))))
    assert means[0] < 0.02 < 0.2 < means[1]


def test_a_short_noisy_segment_is_read_for_the_segment_it_was_drawn_from():
    """End-point noise lengthens a segment a few σ long: its raw reading is biased long (by about
    0.2 in log-length here), which the model used to take as unbiased. Drawing short true
    segments (3–6σ, across the image's lower half) 100 times each (σ = 10 px) and correcting each
    drawing by its own shift, the corrected reading's median is the true log-length, and its
    stated spread covers the truth about as often as it says (a little less: the errors of such
    segments are heavier-tailed than a normal); a long segment is left about as it was (a shift
    under 0.03, the linearised spread or a little more)."""
    s = _scene(4, tier="medium", setting="outdoor")
    m = _model(s)
    p, pp = true_params(s), m.camera.principal_point
    sigma, rng = 10.0, np.random.default_rng(1)
    w, h = s.image_width, s.image_height

    def draw(y, length, n):
        # horizontal segments: along the image's rows the vertical noise is read as depth, the
        # convex direction
        centre = np.array([0.5 * w, y * h])
        true = np.array([centre - [0.5 * length, 0.0], centre + [0.5 * length, 0.0]])
        drawn = true[None] + rng.normal(0.0, sigma, (n, 2, 2))
        truth = np.log(ground_lengths(true[None], pp, p[None]))[0, 0]
        return drawn, truth, np.log(ground_lengths(drawn, pp, p[None]))[0]

    raw_bias, bias, z = [], [], []
    for y in (0.6, 0.7, 0.85):
        for length in (30, 40, 60):
            drawn, truth, raw = draw(y, length, 100)
            shift, var = segment_reading(drawn, pp, p, sigma)
            raw_bias.append(np.median(raw) - truth)
            bias.append(np.median(raw - shift) - truth)
            z += list(np.abs(raw - shift - truth) / np.sqrt(var))
    assert np.median(raw_bias) > 0.15 and min(raw_bias) > 0.1
    assert abs(np.median(bias)) < 0.08 and np.mean(np.abs(bias)) < 0.12
    z = np.array(z)
    assert 0.55 <= np.mean(z < 1.0) <= 0.85 and 0.68 <= np.mean(z < 1.645) <= 0.95

    drawn, truth, raw = draw(0.6, 400, 100)
    shift, var = segment_reading(drawn, pp, p, sigma)
    assert np.all(shift < 0.03) and abs(np.median(raw - shift) - truth) < 0.01
    grad = [(np.log(ground_lengths(drawn + d, pp, p[None])) - np.log(ground_lengths(drawn - d, pp, p[None])))[0] / 1e-3
            for d in np.eye(4).reshape(4, 2, 2) * 5e-4]
    ratio = var / (sigma**2 * np.sum(np.square(grad), axis=0))
    assert np.all(ratio >= 0.999) and np.median(ratio) < 1.25  # (the model differences over 0.5 px)


def test_the_corrected_line_reading_is_an_option_and_the_cost_reads_through_it():
    """line_reading="corrected" takes each reference's shift off its reading (cost against an
    independent sum over the references); the default reads as drawn (no shift); an unknown
    reading is refused by name."""
    s = _scene(4, tier="high", setting="outdoor")
    p = true_params(s)
    plain, fixed = _model(s, ref_scale=0.75), _model(s, ref_scale=0.75, line_reading="corrected")
    for m in (plain, fixed):
        m.set_pilot(p)
    assert plain.line_reading == "linear" and np.all(plain.line_shifts == 0)
    assert np.any(fixed.line_shifts > 0.05)
    assert np.all(fixed.line_variances >= plain.line_variances * (1 - 1e-9))
    q = np.tile(p, (3, 1))
    q[1, 4] *= 1.2
    q[2, 1] *= 0.8
    t = stats.t(fixed.ref_dof)
    for m in (plain, fixed):
        log_len = np.log(ground_lengths(m._lines, m.camera.principal_point, q)) - m.line_shifts
        scale = m.reference_scales[:, 0]
        want = np.zeros(len(q))
        for j, r in enumerate(s.references):
            lo, hi = np.log(r.length_bounds_m(s.target))
            if r.is_range:
                want -= np.log(t.cdf((hi - log_len[:, j]) / scale[j]) - t.cdf((lo - log_len[:, j]) / scale[j]))
            else:
                want -= t.logpdf((lo - log_len[:, j]) / scale[j]) - np.log(scale[j]) - t.logpdf(0.0)
        got = m.reference_nll(q)
        np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="line_reading.*'exact'"):
        _model(s, line_reading="exact")


def test_line_noise_widens_far_references():
    """s_j² = s² + σ_line² |∇ log ℓ_j|² at the pilot: against an independent central difference of
    the log-length over the endpoints (backprojection through the horizon), larger for the
    segment nearest the horizon, and fixed: the cost no longer moves the scales."""
    s = _scene(4, tier="medium", setting="outdoor")
    m = _model(s, ref_line_sigma=10.0, ref_scale=0.75)
    np.testing.assert_allclose(m.reference_scales, m.ref_scale)  # no pilot yet
    p = true_params(s)
    m.set_pilot(p)
    scale = m.reference_scales[:, 0]
    cam, mu, h = m.camera, p[4], p[1]
    lines = m._lines
    g2 = np.zeros(len(lines))
    for k in range(4):
        d = np.eye(4)[k].reshape(2, 2) * 1e-3

        def length(ls):
            P = cam.backproject_to_ground(ls.reshape(-1, 2), mu, h).reshape(-1, 2, 3)
            return np.log(np.linalg.norm(P[:, 1] - P[:, 0], axis=1))

        g2 += ((length(lines + d) - length(lines - d)) / 2e-3) ** 2
    np.testing.assert_allclose(scale, np.sqrt(m.ref_scale**2 + 100.0 * g2), rtol=0.05)
    assert np.all(scale >= m.ref_scale)
    dist = np.min(lines.reshape(-1, 2, 2) @ m.camera.horizon[:2] + m.camera.horizon[2], axis=1)
    assert scale[np.argmin(dist)] == scale.max()  # the segment nearest the horizon
    flat = _model(s, ref_line_sigma=0.0, ref_scale=0.75)
    flat.set_pilot(p)
    np.testing.assert_allclose(flat.reference_scales, m.ref_scale)
    assert _model(s).ref_line_sigma == pytest.approx(2.0 * _model(s).target_sigma)
    # the reference term's normaliser is now the same at every state
    q = np.tile(p, (3, 1))
    q[1, 4] *= 1.3
    q[2, 1] *= 0.7
    stats_t = stats.t(m.ref_dof)
    for row in q:
        log_len = np.log(ground_lengths(m._lines, cam.principal_point, row[None]))[0]
        want = 0.0
        for j, r in enumerate(s.references):
            lo, hi = np.log(r.length_bounds_m(s.target))
            if r.is_range:
                want -= np.log(stats_t.cdf((hi - log_len[j]) / scale[j]) - stats_t.cdf((lo - log_len[j]) / scale[j]))
            else:
                # −log density of log v (scale s_j), up to the constant −log t_ν(0)
                want -= stats_t.logpdf((lo - log_len[j]) / scale[j]) - np.log(scale[j]) - stats_t.logpdf(0.0)
        assert m.reference_nll(row[None])[0] == pytest.approx(want, rel=1e-8)


def test_exact_references_never_hurt_and_recover_far_targets():
    """Noise-free annotations stored to 0.01 px, 20 exact references (single values), far outdoor
    targets, pitch, roll, an off-centre principal point: with the references the MAP is within
    0.1 % of the truth, and the references never make it worse (beyond 0.01 %). (Without them the
    0.01 px rounding alone moves far targets along the depth–focal-length ridge by up to 0.2 %.)"""
    for seed in range(3):
        d = simulate_scene(np.random.default_rng(100 + seed), setting="outdoor", tier="none",
                           n_references=20, principal_offset=0.08, roll_deg=5.0,
                           distance_range=(25.0, 45.0), single_values=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            s = parse_scene(d)
        errs = {}
        for refs in (False, True):
            r = estimate(s, use_references=refs, posterior=False)
            errs[refs] = r.evaluation.location_pct_error
        assert errs[True] < 0.1, (seed, errs)
        assert errs[True] <= errs[False] + 0.01, (seed, errs)


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
        m = optimize_map(_models(bad, target_sigma=2.0, **kw), "default")
        return np.linalg.norm(m.params[:3] - truth) / np.linalg.norm(truth) * 100

    robust, gaussian = err(), err(target_dof=1e6)
    assert robust < 3.0
    assert gaussian > 3 * robust


def test_interface_and_bounds():
    s = _scene(5, tier="medium")
    m = _model(s)
    assert m.name == "metrology" and m.default_temperature == 1.0
    assert m.bounds.lower[1] == MIN_CAMERA_HEIGHT_M
    assert not m.free[5:].any() and m.free[:5].all()  # pitch and roll follow from the horizon
    p = np.tile(true_params(s), (7, 1))
    assert m.cost(p).shape == (7,)
    np.testing.assert_allclose(m.expand(p[:, m.free]), p, atol=1e-6)  # derived angles ≈ the truth
    assert m.observed.shape == (4, 2) and m.obj_corners.shape == (4, 3)
    known = Camera(s.principal_point, Camera.from_scene(s).horizon, 1500.0)
    mk = MetrologyModel.from_scene(s, 1, camera=known)
    assert not mk.free[4] and mk.expand(np.zeros((1, 4)))[0, 4] == 1500.0
    free = MetrologyModel.from_scene(s, 1, camera=Camera(s.principal_point), orientation_free=True)
    assert free.free.all() and np.all(free.expand(p)[:, 5:] == p[:, 5:])
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['sigma'\]"):
        MetrologyModel.from_scene(s, 1, camera=known, sigma=3.0)
    with pytest.raises(ValueError, match="ref_scale"):
        MetrologyModel.from_scene(s, 1, camera=known, ref_scale=-1.0)


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

