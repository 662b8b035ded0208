"""MAP estimation: exact recovery on noise-free scenes, fixed focal length, reproducibility."""

import warnings

import numpy as np
import pytest

from creference_bayes.core.geometry import Camera, box_points, dimension_corners
from creference_bayes.core.metrics import location_percentage_error
from creference_bayes.models.params import Bounds, wrap_angle
from creference_bayes.models.paper import PaperModel
from creference_bayes.inference.optimize import (_Counter, _paper, optimize_map, preset_bounds,
                                                 theta_scan)
from creference_bayes.camera_setup import setup_camera
from creference_bayes.pipeline import build_models as _build_models
from creference_bayes.io.scene import parse_scene
from creference_bayes.bench.simulate import simulate_scene, true_params


def noise_free_scene(seed: int, setting: str, **kwargs):
    """A noise-free synthetic scene with pitch, roll and an off-centre principal point."""
    d = simulate_scene(seed, setting=setting, tier="none", principal_offset=0.1, n_target_annotations=1,
                       decimals=None, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)




def build_models(scene, model="paper", **kw):
    """The paper model (the optimiser's tests predate the default) with a flat focal prior."""
    return _build_models(scene, setup_camera(scene, focal_prior="none"), model=model, **kw)


def _check_recovered(scene, est, tol_pct=0.1):
    truth = true_params(scene)
    err = location_percentage_error(est.params[:3], truth[:3])
    assert err < tol_pct, f"location error {err:.4g} %"
    assert est.handedness == scene.ground_truth.extra["handedness"]
    assert abs(wrap_angle(est.params[3] - truth[3])) < 1e-3
    assert est.params[4] == pytest.approx(truth[4], rel=1e-3)
    return err


def _recovery(seeds):
    errors = []
    for seed in seeds:
        scene = noise_free_scene(seed, "indoor" if seed % 2 == 0 else "outdoor")
        assert abs(scene.principal_point - [1440, 900]).max() > 1.0  # really off-centre
        errors.append(_check_recovered(scene, optimize_map(build_models(scene), "default")))
    return errors


def test_default_recovers_noise_free_scenes():
    _recovery(range(10))


@pytest.mark.slow
def test_default_recovers_fifty_noise_free_scenes():
    errors = _recovery(range(100, 150))
    assert len(errors) == 50 and max(errors) < 0.1


def test_known_focal_length_is_kept_fixed():
    d = simulate_scene(21, setting="indoor", tier="none", principal_offset=0.1, n_target_annotations=1,
                       decimals=None)
    focal = d["ground_truth"]["focal_length_px"]
    d["camera"]["focal_length_px"] = focal
    known = parse_scene(d)
    models = build_models(known)
    assert [int(m.free.sum()) for m in models] == [4, 4]
    est = optimize_map(models, "default")
    assert est.params[4] == focal  # exactly the given value, never moved
    _check_recovered(known, est)


def test_theta_scan_is_exact_at_the_true_yaw():
    """For a yaw on the scan's grid, the linear solve returns the true pose and focal length."""
    scene = noise_free_scene(5, "outdoor")
    truth = true_params(scene)
    n_theta = 360
    grid = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
    k = 123
    truth[3] = grid[k]
    handed = scene.ground_truth.extra["handedness"]
    obj = dimension_corners(scene.target.length, scene.target.width, scene.target.height, handed)
    camera = Camera.from_scene(scene)
    pp = camera.principal_point
    observed, _ = camera.project(box_points(truth, obj), truth[4])
    bounds = Bounds.default(*scene.image_size)
    # with µ known, one solve is exact
    cands = theta_scan(observed, obj, bounds.with_fixed(4, truth[4]), pp, camera=camera, n_theta=n_theta)
    np.testing.assert_allclose(cands[k], truth, rtol=1e-9, atol=1e-9)
    # with µ unknown, R depends on µ through the horizon: the fixed-point iteration converges to it
    # (slowly: the default's 4 iterations only give a start for the local refinement)
    cands = theta_scan(observed, obj, bounds, pp, camera=camera, n_theta=n_theta, n_iter=300)
    np.testing.assert_allclose(cands[k], truth, rtol=1e-6, atol=1e-6)
    # a level camera (no horizon) needs a single solve
    level = Camera(pp)
    observed, _ = level.project(box_points(truth, obj), truth[4])
    cands = theta_scan(observed, obj, bounds, pp, camera=level, n_theta=n_theta, n_iter=1)
    np.testing.assert_allclose(cands[k], np.r_[truth[:5], 0.0, 0.0], rtol=1e-8, atol=1e-8)
    # a grid of fixed orientations: exact at the true (pitch, roll), for every candidate's rows
    observed, _ = camera.project(box_points(truth, obj), truth[4])
    grid = np.array([[0.0, 0.0], truth[5:], [0.2, -0.1]])
    cands = theta_scan(observed, obj, bounds, pp, orientations=grid, n_theta=n_theta)
    assert cands.shape == (3 * n_theta, 7)
    np.testing.assert_allclose(cands[n_theta + k], truth, rtol=1e-8, atol=1e-8)


def _paper_models(scene, preset):
    return build_models(scene, preset=preset)


def test_paper_optimiser_same_seed_same_result():
    """The paper's basin hopping with a few restarts: the same seed gives the same numbers."""
    scene = noise_free_scene(8, "indoor")
    model = _paper_models(scene, "paper")[0]

    def run(seed):
        return _paper(model, _Counter(model), 2, np.random.default_rng(seed))

    (x1, f1, _), (x2, f2, _), (x3, _, _) = run(5), run(5), run(6)
    np.testing.assert_array_equal(x1, x2)
    assert f1 == f2
    assert not np.array_equal(x1, x3)  # and the seed matters
    bounds = preset_bounds("paper", *scene.image_size)
    assert np.all((x1 >= bounds.lower[model.free]) & (x1 <= bounds.upper[model.free]))


@pytest.mark.slow
def test_paper_controlled_preset_same_seed_same_result():
    scene = noise_free_scene(8, "indoor")
    models = _paper_models(scene, "paper-controlled")
    a = optimize_map(models, "paper-controlled", rng=11)
    b = optimize_map(models, "paper-controlled", rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a.params, b.params)
    assert (a.cost, a.handedness, a.n_evaluations) == (b.cost, b.handedness, b.n_evaluations)
    assert a.info["handedness_+1"]["restarts"] == 50  # 100 restarts split over two handednesses


def test_presets_and_result_dict():
    scene = noise_free_scene(2, "indoor")
    with pytest.raises(ValueError, match="unknown preset 'fast'"):
        optimize_map(build_models(scene), "fast")
    est = optimize_map(build_models(scene), "default")
    assert set(est.to_dict()) == {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll"}
    assert est.preset == "default" and est.n_evaluations > 0 and est.seconds > 0
    assert -np.pi <= est.params[3] < np.pi
    assert isinstance(build_models(scene)[0], PaperModel)


def test_trust_newton_minimises_a_curved_valley_within_bounds():
    """Rosenbrock's banana (a curved ridge like depth against focal length) in 3 dimensions (where
    its only minimum is (1, 1, 1)): found inside the bounds, and a bound respected when the
    minimum lies outside it."""
    from creference_bayes.inference.newton import trust_newton

    def rosen(z):
        z = np.atleast_2d(z)
        return np.sum(100.0 * (z[:, 1:] - z[:, :-1] ** 2) ** 2 + (1 - z[:, :-1]) ** 2, axis=1)

    lo, hi = np.full(3, -5.0), np.full(3, 5.0)
    z = trust_newton(rosen, np.array([-1.2, 1.0, -0.5]), lo, hi)
    np.testing.assert_allclose(z, 1.0, atol=1e-4)
    z = trust_newton(rosen, np.zeros(3), lo, np.array([5.0, 0.5, 5.0]))
    assert z[1] <= 0.5 + 1e-12 and rosen(z)[0] < rosen(np.zeros(3))[0]
