"""The Cramér–Rao bound over the block model: against the spread of a maximum-likelihood estimator
(efficient at small noise), its scaling, what references, a horizon and a known focal length add,
scenes of several targets, and the Student-t equivalence."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.optimize import least_squares

from creference_bayes.bench.crb import cramer_rao, measurement_log_sd, scene_bound
from creference_bayes.bench.runner import variant
from creference_bayes.bench.simulate import PAPER_NOISE, TIERS, simulate_scene
from creference_bayes.core.geometry import Camera, box_points, dimension_corners
from creference_bayes.io.scene import parse_scene


def _scene(seed, n=5, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = parse_scene(simulate_scene(np.random.default_rng(seed), **kw))
    return variant(s, n, range(len(s.references)))


def test_bound_matches_the_spread_of_maximum_likelihood():
    """At σ = 0.5 px least squares (ML) is unbiased and efficient: its covariance over 300 noisy
    draws (projected through the horizon by core.geometry, an independent path) must match F⁻¹."""
    scene = _scene(2, tier="none", decimals=None)
    t, g = scene.targets[0], scene.ground_truth
    cam = Camera.from_scene(scene)
    X = dimension_corners(*t.dimensions, t.ground_truth["handedness"])
    p0 = np.array([*t.ground_truth["location_m"], t.ground_truth["yaw_rad"], g["focal_length_px"]])

    def project(q):
        return cam.project(box_points(q, X), q[4])[0]

    sigma, n, trials = 0.5, 5, 300
    rng = np.random.default_rng(1)
    est = np.array([least_squares(lambda q, obs=project(p0) + rng.normal(0, sigma, (n, 4, 2)): (obs - project(q)).ravel(),
                                  p0, x_scale=np.array([1, 1, 1, 0.1, 1000.0])).x for _ in range(trials)])
    bound = scene_bound(scene, sigma, priors=False)
    assert bound.names == ("camera.focal_length_px", "camera.height_m", "0.x", "0.z", "0.yaw")
    sd_crb = np.sqrt(np.diag(bound.cov))
    sd_mc = np.std(est, axis=0, ddof=1)[[4, 1, 0, 2, 3]]  # (x, y, z, yaw, µ) in the bound's order
    np.testing.assert_allclose(sd_mc, sd_crb, rtol=4 / np.sqrt(2 * trials))
    C = np.cov(est[:, :3].T)  # the location's covariance
    np.testing.assert_allclose(np.sqrt(np.trace(C)), np.sqrt(np.trace(bound.location_cov[0])), rtol=0.15)


def test_scaling_with_noise_and_annotations():
    scene = _scene(5, tier="none")
    a = scene_bound(scene, 2.0, priors=False)
    b = scene_bound(scene, 4.0, priors=False)
    d = scene_bound(_scene(5, n=13, tier="none"), 4.0 * np.sqrt(13 / 5), priors=False)
    assert b.rmse_pct[0] == pytest.approx(2 * a.rmse_pct[0], rel=1e-6)
    assert b.median_pct[0] == pytest.approx(2 * a.median_pct[0], rel=1e-6)  # same draws, scaled
    assert d.rmse_pct[0] == pytest.approx(b.rmse_pct[0], rel=1e-6)
    assert 0 < a.median_m[0] < np.sqrt(np.trace(a.location_cov[0]))  # ‖e‖ of a 3D Gaussian: median below RMS
    zero = scene_bound(scene, 0.0)
    assert zero.rmse_pct[0] == 0.0 and not zero.singular


def test_references_a_horizon_and_a_known_focal_length_only_add_information():
    for seed in range(3):
        s = _scene(seed, tier="high")
        tier = TIERS["high"]
        refs = dict(reference_log_sd=measurement_log_sd(tier.measurement), reference_sigma_px=tier.reference_px)
        a, b = scene_bound(s, 10.0, priors=False), scene_bound(s, 10.0, priors=False, **refs)
        assert np.all(np.linalg.eigvalsh(a.cov[:5, :5] - b.cov[:5, :5]) > -1e-9 * np.abs(a.cov).max())
        free = scene_bound(replace(s, horizon=None), 10.0, priors=False, **refs)
        measured = scene_bound(replace(s, horizon_sd_px=2.0), 10.0, priors=False, **refs)
        assert free.names[1:3] == ("camera.pitch", "camera.roll") and measured.names == free.names
        assert b.median_pct[0] < measured.median_pct[0] < free.median_pct[0]
        known = scene_bound(replace(s, focal_length_px=s.ground_truth["focal_length_px"]), 10.0, priors=False, **refs)
        assert "camera.focal_length_px" not in known.names and known.rmse_pct[0] < b.rmse_pct[0]


def test_several_targets_share_the_camera_and_need_the_priors():
    """A street scene of several targets of unknown size: the Bayesian bound is finite for every
    one; a known focal length (conditioning on µ) can only narrow every target's location; the
    data alone cannot fix the scale (sizes, depths and camera height grow together)."""
    s = _scene(3, setting="street", n_objects=6, sizes="prior", horizon="none", n_references=0,
               n_target_annotations=5, tier="low")
    bound = scene_bound(s, 2.0)
    assert len(bound.median_pct) == len(s.targets) and not bound.singular
    assert np.all((bound.median_pct > 0) & np.isfinite(bound.median_pct)) and np.all(bound.distance_sd_m > 0)
    known = scene_bound(replace(s, focal_length_px=s.ground_truth["focal_length_px"]), 2.0)
    assert np.all(np.trace(known.location_cov, axis1=1, axis2=2) < np.trace(bound.location_cov, axis1=1, axis2=2))
    data_only = scene_bound(s, 2.0, priors=False)
    assert data_only.singular or np.all(data_only.median_pct > 100 * bound.median_pct)


def test_the_ground_prior_adds_its_expected_information_wherever_the_true_offset_lies():
    """A Student-t's Hessian is negative in its tails, so the bound takes the offset prior's
    expected information, (ν + 1) / ((ν + 3) s²), the same for an offset at 0 and at 0.4 m; the
    ground distance's effect on s(d) is the model's."""
    from creference_bayes.bench.simulate import true_state
    from creference_bayes.pipeline import build_model

    s = _scene(3, setting="street", n_objects=3, sizes="prior", horizon="none", n_references=0,
               n_target_annotations=5, tier="low")
    model, _ = build_model(s, use_references=False)
    flat, _ = build_model(s, use_references=False, ground_sd_m=1e4)  # the same but a flat offset prior
    for m in (model, flat):
        m.handedness = np.array([t.ground_truth["handedness"] for t in s.targets], float)
    camera, objects = true_state(s)
    info = []
    for g in (0.0, 0.4):
        objs = objects.copy()
        objs[0, 6] = g
        info.append(np.linalg.inv(cramer_rao(model, camera, objs, 2.0).cov)
                    - np.linalg.inv(cramer_rao(flat, camera, objs, 2.0).cov))
    k = list(cramer_rao(model, camera, objects, 2.0).names).index("0.ground_m")
    d = np.hypot(objects[0, 0], objects[0, 1])
    want = 3.0 / 5.0 / (0.056**2 + (0.0017 * d) ** 2)  # ν = 2
    for got in info:
        assert got[k, k] == pytest.approx(want, rel=1e-3)


def test_cramer_rao_takes_the_model_and_the_truth():
    from creference_bayes.bench.simulate import true_state
    from creference_bayes.pipeline import build_model

    s = _scene(6, tier="low")
    model, _ = build_model(s, use_references=False)
    model.handedness = np.array([s.targets[0].ground_truth["handedness"]], float)
    camera, objects = true_state(s)
    a = cramer_rao(model, camera, objects, 2.0, priors=False)
    assert a.median_pct[0] == pytest.approx(scene_bound(s, 2.0, priors=False).median_pct[0])
    assert cramer_rao(model, camera, objects, 2.0).rmse_pct[0] <= a.rmse_pct[0]  # the focal prior adds


def test_student_t_equivalent_log_sd_is_its_fisher_information():
    """1/I for a t location: compare (ν+3)s²/(ν+1) with ∫ score² p by quadrature."""
    nu, s = PAPER_NOISE["dof"], PAPER_NOISE["scale"]
    dist = stats.t(nu, scale=s)
    info = integrate.quad(lambda x: ((nu + 1) * x / (nu * s**2 + x**2)) ** 2 * dist.pdf(x), -np.inf, np.inf)[0]
    assert measurement_log_sd("paper") == pytest.approx(1 / np.sqrt(info), rel=1e-6)
    assert measurement_log_sd("40%") == 0.4 and measurement_log_sd("none") == 0.0
    with pytest.raises(ValueError, match="unknown"):
        measurement_log_sd("huge")
