"""The paper's costs (Eq. 5, Eq. 6–7, Eq. 10–11) against direct evaluations of the formulas."""

import cv2
import numpy as np
import pytest
from scipy.stats import norm

from creference_bayes.core.cost import (PAPER_CAP, PAPER_SHARPNESS, SoftConstraints,
                                        sigmoid_penalty, soft_constraint_cost, target_cost)
from creference_bayes.core.geometry import (Camera, box_points, dimension_corners,
                                            horizon_from_rotation, horizon_line,
                                            rotation_from_pitch_roll)

SIGMA = 100.0
PP = np.array([1530.0, 840.0])


def _setup(seed=0, with_horizon=True):
    """A camera, a true pose and its noise-free corners t1..t4."""
    rng = np.random.default_rng(seed)
    f, pitch, roll = 1700.0, np.radians(8.0), np.radians(-2.5)
    R = rotation_from_pitch_roll(pitch, roll)
    camera = Camera(PP, horizon_line(horizon_from_rotation(R, f, PP, 2880)) if with_horizon else None)
    obj = dimension_corners(1.4, 0.6, 0.9, -1)
    # (x, y, z, yaw, µ, pitch, roll): the cost builds the camera rotation from the vector's angles
    angles = (pitch, roll) if with_horizon else (0.0, 0.0)
    truth = np.array([1.2, 1.5, 7.0, rng.uniform(-np.pi, np.pi), f, *angles])
    pts = box_points(truth, obj)
    rvec, _ = cv2.Rodrigues(R if with_horizon else np.eye(3))
    K = np.array([[f, 0, PP[0]], [0, f, PP[1]], [0, 0, 1]])
    observed = cv2.projectPoints(pts, rvec, np.zeros(3), K, None)[0].reshape(4, 2)
    return camera, obj, truth, observed, rng


def _eq5(projected, observed, sigma=SIGMA):
    """Eq. 5 written out: Σ −log N(‖tᵢ − Cᵢ‖; 0, σ²) + | ‖tᵢ‖ − ‖Cᵢ‖ |."""
    dist = np.linalg.norm(observed - projected, axis=1)
    return np.sum(-norm.logpdf(dist, 0.0, sigma)
                  + np.abs(np.linalg.norm(observed, axis=1) - np.linalg.norm(projected, axis=1)))


@pytest.mark.parametrize("with_horizon", [True, False])
def test_batch_equals_loop_of_single_evaluations(with_horizon):
    camera, obj, truth, observed, rng = _setup(1, with_horizon)
    batch = truth + rng.normal(0, [1.0, 0.3, 3.0, 1.0, 300.0, 0.05, 0.05], (64, 7))
    batch[:3, 2] = [-2.0, 0.0, 0.3]  # some corners behind the camera
    costs = target_cost(batch, observed, obj, camera, SIGMA)
    assert costs.shape == (64,) and np.all(np.isfinite(costs))
    single = [target_cost(p, observed, obj, camera, SIGMA)[0] for p in batch]
    single_2d = [target_cost(p[None], observed, obj, camera, SIGMA)[0] for p in batch]
    np.testing.assert_allclose(costs, single, rtol=1e-13)
    np.testing.assert_array_equal(single, single_2d)


def test_cost_at_the_true_pose_is_the_gaussian_normaliser_alone():
    camera, obj, truth, observed, _ = _setup(2)
    cost = target_cost(truth, observed, obj, camera, SIGMA)[0]
    # zero residuals and equal norms: only the four normalising constants of N(0; 0, σ²) remain
    assert cost == pytest.approx(-4 * norm.logpdf(0.0, 0.0, SIGMA), rel=1e-9)
    assert cost == pytest.approx(4 * np.log(SIGMA * np.sqrt(2 * np.pi)), rel=1e-9)


def test_cost_matches_eq5_computed_from_opencv_projections():
    camera, obj, truth, observed, rng = _setup(3)
    R = camera.rotation(truth[4])
    for _ in range(20):
        p = truth + rng.normal(0, [0.5, 0.1, 1.0, 0.3, 0.0, 0.0, 0.0])  # µ fixed: R from the horizon is the same
        pts = box_points(p, obj)
        rvec, _ = cv2.Rodrigues(R)
        K = np.array([[p[4], 0, PP[0]], [0, p[4], PP[1]], [0, 0, 1]])
        projected = cv2.projectPoints(pts, rvec, np.zeros(3), K, None)[0].reshape(4, 2)
        assert target_cost(p, observed, obj, camera, SIGMA)[0] == pytest.approx(_eq5(projected, observed), rel=1e-9)


def test_true_pose_is_the_minimum_nearby():
    camera, obj, truth, observed, rng = _setup(4)
    at_truth = target_cost(truth, observed, obj, camera)[0]
    near = truth + rng.normal(0, [0.05, 0.05, 0.05, 0.02, 20.0, 0.002, 0.002], (200, 7))
    assert np.all(target_cost(near, observed, obj, camera) > at_truth)


def test_corners_behind_the_camera_are_penalised():
    camera, obj, truth, observed, _ = _setup(5)
    behind = truth.copy()
    behind[2] = -5.0
    assert target_cost(behind, observed, obj, camera)[0] > 1e6


def _s(r, a=PAPER_SHARPNESS, cap=PAPER_CAP):
    """Eq. 7 with the cap as a minimum, evaluated directly."""
    return min((r + 1.0) / (1.0 + np.exp(-a * r)), cap)


def test_sigmoid_penalty_is_about_zero_well_inside():
    x = np.linspace(4.0, 6.0, 11)[:, None]  # at least 2 from both bounds: |P| ≤ 1/(1 + e^16)
    p = sigmoid_penalty(x, np.array([2.0]), np.array([8.0]))
    assert p.shape == (11, 1)
    assert np.all(np.abs(p) < 2e-7)


def test_sigmoid_penalty_is_capped_far_outside():
    far = np.array([[-1e3], [-100.0], [70.0], [1e6]])
    np.testing.assert_allclose(sigmoid_penalty(far, np.array([2.0]), np.array([8.0])), PAPER_CAP, rtol=1e-12)
    # a different cap and sharpness
    np.testing.assert_allclose(sigmoid_penalty(np.array([[50.0]]), np.array([0.0]), np.array([1.0]), a=2.0, cap=7.0), 7.0)


def test_sigmoid_penalty_matches_the_formula_with_min():
    low, high = 3.0, 4.5
    for x in np.linspace(-60, 70, 261):
        expected = _s(low - x) + _s(x - high)
        assert sigmoid_penalty(np.array([[x]]), np.array([low]), np.array([high]))[0, 0] == pytest.approx(expected, abs=1e-12)
    # just outside: grows like the distance + 1 (here 2 m beyond the upper bound)
    assert sigmoid_penalty(np.array([[6.5]]), np.array([low]), np.array([high]))[0, 0] == pytest.approx(3.0, rel=1e-6)
    # with max instead of min the penalty would be M everywhere; inside it is ~0, not 2M
    assert sigmoid_penalty(np.array([[3.75]]), np.array([low]), np.array([high]))[0, 0] < 1e-2


def test_sigmoid_penalty_single_value_and_broadcast():
    # a single-valued estimate gives l = u: the minimum of P is there, and P(u) = 2·S(0) = 2 · 1/2
    assert sigmoid_penalty(np.array([[2.0]]), np.array([2.0]), np.array([2.0]))[0, 0] == pytest.approx(1.0)
    x = np.array([[0.0], [5.0], [10.0]])
    bounds = np.array([[1.0, 2.0], [4.0, 6.0]])
    p = sigmoid_penalty(x, bounds[:, 0], bounds[:, 1])
    assert p.shape == (3, 2)
    for i in range(3):
        for j in range(2):
            assert p[i, j] == pytest.approx(_s(bounds[j, 0] - x[i, 0]) + _s(x[i, 0] - bounds[j, 1]), abs=1e-12)


def test_soft_constraint_cost_sums_pairs_on_x_and_z():
    xb = np.array([[1.0, 2.0], [0.5, 3.0]])
    zb = np.array([[6.0, 8.0], [9.0, 12.0]])
    params = np.array([[1.5, 1.4, 7.0, 0.0, 1000.0], [4.0, 1.4, 20.0, 0.0, 1000.0]])
    c = SoftConstraints(xb, zb)
    got = soft_constraint_cost(params, c)
    for i, p in enumerate(params):
        expected = sum(_s(lo - p[0]) + _s(p[0] - hi) for lo, hi in xb) + sum(_s(lo - p[2]) + _s(p[2] - hi) for lo, hi in zb)
        assert got[i] == pytest.approx(expected, abs=1e-12)
    d = SoftConstraints(xb, zb, distance_bounds=np.array([[7.0, 7.5]]), on="distance")
    dist = np.hypot(params[:, 0], params[:, 2])
    np.testing.assert_allclose(soft_constraint_cost(params, d), [_s(7.0 - r) + _s(r - 7.5) for r in dist], atol=1e-12)
    np.testing.assert_array_equal(soft_constraint_cost(params, None), 0.0)
    with pytest.raises(ValueError, match="on"):
        SoftConstraints(xb, zb, on="y")
