"""The Cramér–Rao bound: against the spread of a maximum-likelihood estimator (efficient at small
noise), its scaling, its reference term and the Student-t equivalence."""

import warnings

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.optimize import least_squares

from creference_bayes.bench.crb import (cramer_rao, cramer_rao_scene, log_length_gradient,
                                        line_log_sd, measurement_log_sd, projection_jacobian)
from creference_bayes.core.geometry import (Camera, box_points, dimension_corners, project,
                                           rotation_from_pitch_roll)
from creference_bayes.models.metrology import ground_lengths
from creference_bayes.io.scene import parse_scene
from creference_bayes.bench.simulate import PAPER_NOISE, simulate_scene, true_params


def _scene(seed, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(simulate_scene(np.random.default_rng(seed), **kw))


def _truth(scene):
    g, t = scene.ground_truth, scene.target
    return true_params(scene), dimension_corners(t.length, t.width, t.height, g.extra["handedness"]), Camera.from_scene(scene)


def test_bound_matches_the_spread_of_maximum_likelihood():
    """At σ = 0.5 px the least-squares (ML) estimator is unbiased and efficient: its sample
    covariance over 300 noisy draws must match F⁻¹ (sd within 4 Monte Carlo standard errors)."""
    scene = _scene(2, tier="none")
    p0, X, cam = _truth(scene)
    p0 = p0[:5]
    uv = cam.project(box_points(p0[None], X), p0[None, 4])[0][0]
    sigma, n, trials = 0.5, 5, 300
    rng = np.random.default_rng(1)
    est = []
    for _ in range(trials):
        obs = uv + rng.normal(0, sigma, (n, 4, 2))

        def resid(q):
            return (obs - cam.project(box_points(q[None], X), q[None, 4])[0][0]).ravel()

        est.append(least_squares(resid, p0, x_scale=np.array([1, 1, 1, 0.1, 1000.0])).x)
    sd_mc = np.std(np.array(est), axis=0, ddof=1)
    crb = cramer_rao(p0, X, cam, sigma_px=sigma, n_annotations=n)
    sd_crb = np.sqrt(np.diag(crb.cov))
    np.testing.assert_allclose(sd_mc, sd_crb, rtol=4 / np.sqrt(2 * trials))
    assert crb.names == ("x", "y", "z", "yaw", "focal_length_px")


def test_free_orientation_costs_information_and_a_horizon_measurement_gives_it_back():
    """Pitch and roll as parameters can only widen the bound; a precise horizon measurement
    brings it back to the bound with a known horizon."""
    s = _scene(3, tier="low")
    known = cramer_rao_scene(s, references=True)
    free = cramer_rao_scene(s, references=True, orientation_free=True)
    measured = cramer_rao_scene(s, references=True, orientation_free=True, horizon_sd_px=1e-4)
    assert free.names[-2:] == ("pitch", "roll")
    assert free.rmse_m > known.rmse_m
    assert measured.rmse_m == pytest.approx(known.rmse_m, rel=1e-3)


def test_scaling_with_noise_and_annotations():
    p0, X, cam = _truth(_scene(5, tier="none"))
    a = cramer_rao(p0, X, cam, sigma_px=2.0, n_annotations=5)
    b = cramer_rao(p0, X, cam, sigma_px=4.0, n_annotations=5)
    c = cramer_rao(p0, X, cam, sigma_px=4.0, n_annotations=20)
    assert b.rmse_m == pytest.approx(2 * a.rmse_m, rel=1e-9)
    assert c.rmse_m == pytest.approx(a.rmse_m, rel=1e-9)
    assert b.median_pct == pytest.approx(2 * a.median_pct, rel=1e-9)  # same draws, scaled
    assert 0 < a.median_m < a.rmse_m  # ‖e‖ of a 3D Gaussian: median below RMS
    zero = cramer_rao(p0, X, cam, sigma_px=0.0, n_annotations=5)
    assert zero.rmse_pct == 0.0 and not zero.singular


def test_projection_jacobian_against_a_coarser_difference():
    """With a horizon (pitch and roll follow from µ: Camera.project is an independent path) and
    with pitch and roll free (OpenCV-style projection with R from the angles)."""
    p0, X, cam = _truth(_scene(6, tier="none", principal_offset=0.05))
    J = projection_jacobian(p0, X, cam)
    assert J.shape == (8, 7) and np.all(J[:, 5:] == 0)
    h = np.array([1e-4, 1e-4, 1e-4, 1e-5, 1e-2, 1e-5, 1e-5])
    for k in range(5):
        d = np.zeros(7)
        d[k] = h[k]
        up = cam.project(box_points((p0 + d)[None], X), (p0 + d)[None, 4])[0][0].ravel()
        dn = cam.project(box_points((p0 - d)[None], X), (p0 - d)[None, 4])[0][0].ravel()
        np.testing.assert_allclose(J[:, k], (up - dn) / (2 * h[k]), rtol=1e-4, atol=1e-6)
    free_cam = Camera(cam.principal_point)
    Jf = projection_jacobian(p0, X, free_cam, orientation_free=True)

    def proj(q):
        R = rotation_from_pitch_roll(q[5], q[6])
        return project(box_points(q[None], X), R[None], q[None, 4], cam.principal_point)[0][0].ravel()

    for k in range(7):
        d = np.zeros(7)
        d[k] = h[k]
        np.testing.assert_allclose(Jf[:, k], (proj(p0 + d) - proj(p0 - d)) / (2 * h[k]), rtol=1e-4, atol=1e-6)


def test_ground_lengths_match_backprojection_and_truth():
    """ground_lengths against Camera.backproject_to_ground (an independent path) and the
    simulator's true reference lengths."""
    scene = _scene(9, tier="none", principal_offset=0.05, decimals=None)
    g = scene.ground_truth
    cam = Camera.from_scene(scene)
    lines = np.asarray(g.extra["reference_lines_px"])
    mu, h = g.focal_length_px, g.extra["camera_height_m"]

    def full(m):
        pitch, roll = cam.pitch_roll(m)
        return np.array([[0.0, h, 1.0, 0.0, m, float(pitch), float(roll)]])

    ell = ground_lengths(lines, cam.principal_point, full(mu))[0]
    P = cam.backproject_to_ground(lines.reshape(-1, 2), mu, h).reshape(-1, 2, 3)
    np.testing.assert_allclose(ell, np.linalg.norm(P[:, 1] - P[:, 0], axis=1), rtol=1e-10)
    np.testing.assert_allclose(ell, g.extra["reference_lengths_m"], rtol=1e-8)
    p = np.array([*g.location_m, g.yaw_rad, mu, 0.0, 0.0])
    grad = log_length_gradient(lines, cam, p)
    assert np.allclose(grad[:, [0, 2, 3, 5, 6]], 0) and np.allclose(grad[:, 1], 1 / h)
    e = 1e-2
    fd = (np.log(ground_lengths(lines, cam.principal_point, full(mu + e))[0])
          - np.log(ground_lengths(lines, cam.principal_point, full(mu - e))[0])) / (2 * e)
    np.testing.assert_allclose(grad[:, 4], fd, rtol=1e-5, atol=1e-12)
    assert np.all(line_log_sd(lines, cam, p, 5.0) > 0)
    free = log_length_gradient(lines, Camera(cam.principal_point), full(mu)[0], orientation_free=True)
    assert np.all(np.abs(free[:, 5]) > 0)  # pitch changes every length


def test_references_only_add_information():
    for seed in range(4):
        s = _scene(seed, tier="high")
        a = cramer_rao_scene(s)
        b = cramer_rao_scene(s, references=True)
        assert np.all(np.linalg.eigvalsh(a.cov - b.cov) > -1e-9 * np.abs(a.cov).max())
        assert b.rmse_m <= a.rmse_m + 1e-12


def test_student_t_equivalent_log_sd_is_its_fisher_information():
    """1/I for a t location: compare (ν+3)s²/(ν+1) with ∫ score² p by quadrature."""
    nu, s = PAPER_NOISE["dof"], PAPER_NOISE["scale"]
    dist = stats.t(nu, scale=s)

    def integrand(x):
        score = (nu + 1) * x / (nu * s**2 + x**2)
        return score**2 * dist.pdf(x)

    info = integrate.quad(integrand, -np.inf, np.inf)[0]
    assert measurement_log_sd("paper") == pytest.approx(1 / np.sqrt(info), rel=1e-6)
    assert measurement_log_sd("40%") == 0.4 and measurement_log_sd("none") == 0.0
    with pytest.raises(ValueError, match="unknown"):
        measurement_log_sd("huge")
