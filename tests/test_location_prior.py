"""The location prior (models/location_prior.py): uniform in log depth, the MAP taken in log
coordinates, and a thin design's posterior that no longer leans to the far end of the ridge."""

import warnings

import numpy as np
import pytest

from creference_bayes.bench.runner import variant
from creference_bayes.bench.simulate import simulate_scene, true_params
from creference_bayes.camera_setup import setup_camera
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.inference.summary import draws_from_inference_data
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.camera_terms import FocalPrior
from creference_bayes.models.location_prior import LocationPrior
from creference_bayes.pipeline import build_models, estimate


def _scene(seed, tier="high", n_refs=5):
    d = simulate_scene(np.random.default_rng([19, seed]), setting="outdoor", tier=tier, distance_range=(15, 60),
                       n_references=n_refs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def test_unknown_location_prior_is_refused():
    with pytest.raises(ValueError, match="location prior: expected one of"):
        LocationPrior("1/d")
    with pytest.raises(ValueError, match="location prior"):
        estimate(variant(_scene(0), 1, ()), posterior=False, location_prior="uniform")


@pytest.mark.parametrize("model", ["metrology", "paper"])
def test_flat_prior_keeps_the_map_in_the_parameters(model):
    scene = variant(_scene(1), 1, (0, 1))
    m = build_models(scene, setup_camera(scene, location_prior="flat"), model=model)[0]
    p = true_params(scene)[None] * np.array([[1, 1, 1.3, 1, 1.2, 1, 1]])
    assert m.map_cost(p) == pytest.approx(m.cost(p))


@pytest.mark.parametrize("model", ["metrology", "paper"])
def test_log_depth_map_is_the_likelihood_times_the_informative_priors(model):
    """In log coordinates the scale priors (1/z, and 1/µ without a focal prior) and the Jacobian
    cancel: the MAP's cost differs from the flat-prior cost without a focal prior (the
    likelihood alone) by a constant, anywhere on the ridge."""
    scene = variant(_scene(2), 1, (0,))
    kw = dict(focal_prior="none")
    logd = build_models(scene, setup_camera(scene, location_prior="log-depth", **kw), model=model)[0]
    flat = build_models(scene, setup_camera(scene, location_prior="flat", **kw), model=model)[0]
    rng = np.random.default_rng(0)
    p = true_params(scene)[None].repeat(6, axis=0)
    lam = np.exp(rng.uniform(-1, 1, 6))
    p[:, 2] *= lam
    p[:, 4] *= lam  # along the depth–focal-length ridge
    diff = logd.map_cost(p) - flat.cost(p)
    assert np.ptp(diff) < 1e-9 * max(1.0, np.abs(diff).max())
    # while the posterior's own density (linear coordinates) is not flat-prior + constant
    assert np.ptp(logd.cost(p) - flat.cost(p)) > 0.5


def test_map_is_the_mode_of_the_sampled_density():
    """The MAP minimises the cost in (log y, log z, log µ, …): a step in any log coordinate
    raises it; the linear-coordinate cost is not minimal there (the answer would move)."""
    scene = variant(_scene(3), 1, ())
    models = build_models(scene, setup_camera(scene))
    est = optimize_map(models)
    m = next(m for m in models if m.handedness == est.handedness)
    free = np.flatnonzero(m.free)
    p0 = est.params[None]
    f0 = m.map_cost(p0)[0]
    for i in free:
        for s in (-1, 1):
            p = p0.copy()
            p[0, i] = p[0, i] * np.exp(s * 1e-3) if m.bounds.lower[i] > 0 else p[0, i] + s * 1e-3
            assert m.map_cost(p)[0] >= f0 - 1e-7
    up, down = p0.copy(), p0.copy()
    up[0, 2] *= np.exp(1e-4)
    down[0, 2] *= np.exp(-1e-4)
    slope = (m.cost(up)[0] - m.cost(down)[0]) / 2e-4  # ∂cost/∂log z: the Jacobian's T = 1
    assert slope == pytest.approx(1.0, abs=0.05)  # the linear-coordinate mode lies elsewhere


def _truth_quantile(scene, location_prior):
    g = scene.ground_truth
    prior = FocalPrior(g.focal_length_px, 0.5, np.inf, source="scene")  # a prior centred on the truth
    r = estimate(scene, seed=1, sampling={"min_ess": 200}, focal_prior=prior, location_prior=location_prior)
    d = draws_from_inference_data(r.inference_data)
    dist = np.hypot(np.ravel(d["x"]), np.ravel(d["z"]))
    return float(np.mean(dist < np.hypot(g.location_m[0], g.location_m[2]))), float(np.quantile(dist, 0.95))


def test_thin_design_does_not_lean_far():
    """One set of dimension lines, no references, a far target, a focal prior centred on the true
    µ: with the log-depth prior the truth sits near the posterior's median; the flat prior put it
    in the lowest tail (the posterior leant to the far end)."""
    q_new, q_flat = [], []
    for seed in (4, 6):
        scene = variant(_scene(seed, tier="high"), 1, ())
        q_new.append(_truth_quantile(scene, "log-depth")[0])
        q_flat.append(_truth_quantile(scene, "flat")[0])
    assert all(0.2 < q < 0.8 for q in q_new), q_new
    assert np.mean(q_flat) < np.mean(q_new) - 0.15, (q_flat, q_new)


def test_cli_option_and_result_record_the_prior(tmp_path):
    import json

    from creference_bayes.cli.main import example_scene_path, main

    for choice, kind in (("flat", "flat"), ("auto", "log-depth")):
        out = tmp_path / f"{choice}.json"
        assert main(["estimate", str(example_scene_path()), "--no-posterior", "--quiet",
                     "--location-prior", choice, "--out", str(out)]) == 0
        assert json.loads(out.read_text())["camera"]["location_prior"] == {"kind": kind}
