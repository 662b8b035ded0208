"""The location prior (models/location_prior.py): uniform in log depth, the MAP taken in log
coordinates, and a thin design's posterior that no longer leans to the far end of the ridge."""

import json

import numpy as np
import pytest

from creference_bayes.inference.map import optimize
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.camera_terms import FocalPrior
from creference_bayes.models.contract import C_FOCAL, O_Z
from creference_bayes.models.location_prior import LocationPrior
from creference_bayes.pipeline import build_model, estimate


def _scene(seed, **kw):
    from tests.conftest import truth_scene

    d, truth = truth_scene(seed, noise_px=1.0, **kw)
    return parse_scene(d), truth


def test_unknown_location_prior_is_refused():
    with pytest.raises(ValueError, match="location prior: expected one of"):
        LocationPrior("1/d")
    with pytest.raises(ValueError, match="location prior"):
        estimate(_scene(0)[0], posterior=False, location_prior="uniform")


@pytest.mark.parametrize("model", ["metrology", "paper"])
def test_flat_prior_takes_the_map_in_the_parameters(model):
    scene, truth = _scene(1, n_refs=3)
    m = build_model(scene, model=model, location_prior="flat")[0]
    m.handedness = truth["handedness"]
    cams = truth["camera"][None] * np.array([[1.2, 1, 1, 1, 1]])
    objs = truth["objects"][None] * np.array([1, 1.3, 1, 1, 1, 1, 1])
    assert m.map_objective(cams, objs) == pytest.approx(m.neg_log_posterior(cams, objs))


@pytest.mark.parametrize("model", ["metrology", "paper"])
def test_log_depth_map_is_the_likelihood_times_the_informative_priors(model):
    """In log coordinates the scale priors (1/z, and 1/µ without a focal prior) and the Jacobian
    cancel: the MAP's objective differs from the flat-prior posterior without a focal prior (the
    likelihood alone) by a constant, anywhere on the depth–focal-length ridge."""
    scene, truth = _scene(2, depth=(25.0, 50.0))
    logd = build_model(scene, model=model, location_prior="log-depth", focal_prior="none")[0]
    flat = build_model(scene, model=model, location_prior="flat", focal_prior="none")[0]
    for m in (logd, flat):
        m.handedness = truth["handedness"]
    lam = np.exp(np.random.default_rng(0).uniform(-1, 1, 6))
    cams = truth["camera"][None].repeat(6, axis=0)
    objs = truth["objects"][None].repeat(6, axis=0)
    cams[:, C_FOCAL] *= lam
    objs[:, :, O_Z] *= lam[:, None]  # along the ridge
    diff = logd.map_objective(cams, objs) - flat.neg_log_posterior(cams, objs)
    assert np.all(np.isfinite(diff))
    assert np.ptp(diff) < 1e-9 * max(1.0, np.abs(diff).max())
    # while the posterior's own density (linear coordinates) is not flat-prior + constant
    assert np.ptp(logd.neg_log_posterior(cams, objs) - flat.neg_log_posterior(cams, objs)) > 0.5


def test_map_is_the_mode_of_the_sampled_density():
    """The MAP minimises the objective in (log µ, x, log z, …): a step in any of those raises it,
    and the linear-coordinate density is not stationary there (its mode lies elsewhere)."""
    scene, _ = _scene(3, n_refs=4)
    m = build_model(scene)[0]
    est = optimize(m)
    m = est.fitted(m)  # the model at the MAP's handedness and pilot
    c0, o0 = est.camera[None], est.objects[None]
    f0 = m.map_objective(c0, o0)[0]
    steps = [("camera", k) for k in np.flatnonzero(m.camera_free)] + [("object", k) for k in (0, 1, 2)]
    for block, k in steps:
        for s in (-1, 1):
            c, o = c0.copy(), o0.copy()
            if block == "camera":
                c[0, k] = c[0, k] * np.exp(s * 1e-3) if k == C_FOCAL else c[0, k] + s * 1e-3
            else:
                o[0, 0, k] = o[0, 0, k] * np.exp(s * 1e-3) if k == O_Z else o[0, 0, k] + s * 1e-3
            assert m.map_objective(c, o)[0] >= f0 - 1e-6, (block, k, s)
    up, down = o0.copy(), o0.copy()
    up[0, 0, O_Z] *= np.exp(1e-4)
    down[0, 0, O_Z] *= np.exp(-1e-4)
    slope = (m.neg_log_posterior(c0, up)[0] - m.neg_log_posterior(c0, down)[0]) / 2e-4
    assert slope == pytest.approx(1.0, abs=0.05)  # ∂(−log p)/∂log z = 1: the Jacobian z


def _truth_quantile(scene, truth, location_prior):
    prior = FocalPrior(float(truth["camera"][C_FOCAL]), 0.5, np.inf, source="scene")  # centred on the truth
    r = estimate(scene, seed=1, sampling={"min_ess": 200}, focal_prior=prior, location_prior=location_prior)
    objs = r.draws.objects.reshape(-1, 1, 7)
    dist = np.hypot(objs[:, 0, 0], objs[:, 0, O_Z])
    return float(np.mean(dist < np.hypot(truth["objects"][0, 0], truth["objects"][0, O_Z])))


@pytest.mark.slow  # estimates of thin designs (about 20 s)
def test_thin_design_does_not_lean_far():
    """One set of dimension lines, no references, a far target, a focal prior centred on the true
    µ: with the log-depth prior the truth sits in the posterior's body; the flat prior puts it in
    the lower tail (the posterior leans to the far end of the ridge)."""
    q_new, q_flat = [], []
    for seed in (4, 6):
        scene, truth = _scene(seed, depth=(30.0, 60.0))
        q_new.append(_truth_quantile(scene, truth, "log-depth"))
        q_flat.append(_truth_quantile(scene, truth, "flat"))
    assert all(0.1 < q < 0.9 for q in q_new), q_new
    assert np.mean(q_flat) < np.mean(q_new) - 0.1, (q_flat, q_new)


def test_cli_option_and_result_record_the_prior(tmp_path):
    from creference_bayes.cli.main import example_scene_path, main

    for choice, kind in (("flat", "flat"), ("auto", "log-depth")):
        out = tmp_path / f"{choice}.json"
        assert main(["estimate", str(example_scene_path()), "--no-posterior", "--quiet",
                     "--location-prior", choice, "--out", str(out)]) == 0
        assert json.loads(out.read_text())["provenance"]["location_prior"] == kind


def test_a_distance_range_keeps_a_thin_designs_posterior_inside_it(tmp_path):
    """A far target with one set of lines and no focal prior: its posterior stretches along the
    ridge; the data set's range (the truth inside) holds the posterior's bulk within it, softly (a
    few per cent past each edge), and the result records the range and rebuilds its model with it."""
    from creference_bayes.pipeline import rebuild_model

    scene, truth = _scene(4, depth=(30.0, 60.0))
    d_true = float(np.hypot(truth["objects"][0, 0], truth["objects"][0, O_Z]))
    lo, hi = 0.8 * d_true, 1.25 * d_true

    def distances(r):
        objs = r.draws.objects.reshape(-1, 1, 7)
        return np.hypot(objs[:, 0, 0], objs[:, 0, O_Z])

    free = distances(estimate(scene, seed=1, sampling={"min_ess": 200}))
    r = estimate(scene, seed=1, sampling={"min_ess": 200}, distance_range=(lo, hi))
    held = distances(r)
    assert np.mean((free < lo) | (free > hi)) > 0.3  # without the range the posterior is wider than it
    assert np.mean(held < lo * 0.9) < 0.03 and np.mean(held > hi * 1.1) < 0.03
    assert np.mean((held > lo) & (held < hi)) > 0.6
    doc = json.loads(json.dumps(r.to_dict()))
    assert doc["provenance"]["distance_range_m"] == pytest.approx([lo, hi])
    path = tmp_path / "scene.json"
    from creference_bayes.io.scene import scene_to_dict

    path.write_text(json.dumps(scene_to_dict(scene)))
    assert rebuild_model(doc, path).location.distance_m == pytest.approx((lo, hi))
    assert "distance_range_m" not in estimate(scene, posterior=False).to_dict()["provenance"]
    for bad in ((5.0, 2.0), (0.0, 3.0), (1.0, np.inf), (1.0,), "29"):
        with pytest.raises(ValueError, match="distance_range"):
            LocationPrior(distance_m=bad)
    with pytest.raises(ValueError, match=r"distance_range: \[60, 200\] m lies beyond"):  # the paper's box: z ≤ 50 m
        estimate(scene, posterior=False, preset="paper", distance_range=(60, 200))


def test_cli_distance_range_reaches_the_result_and_a_batch_recomputes_for_a_new_one(tmp_path, capsys):
    from creference_bayes.cli.main import example_scene_path, main

    out = tmp_path / "r.json"
    assert main(["estimate", str(example_scene_path()), "--no-posterior", "--distance-range", "2,9",
                 "--out", str(out)]) == 0
    assert "; distance range given: 2–9 m)" in capsys.readouterr().out  # the objects' table says so
    assert json.loads(out.read_text())["provenance"]["distance_range_m"] == [2.0, 9.0]
    with pytest.raises(SystemExit):
        main(["estimate", str(example_scene_path()), "--distance-range", "9,2"])
    assert "--distance-range: expected LOW,HIGH" in capsys.readouterr().err
    assert main(["estimate", str(example_scene_path()), "--preset", "paper", "--distance-range", "60,200"]) == 2
    assert "--distance-range: [60, 200] m lies beyond the ground distances the bounds allow" in capsys.readouterr().err
    batch = tmp_path / "batch"
    common = ["batch", str(example_scene_path()), "--out", str(batch), "--no-posterior", "--workers", "1"]
    assert main(common) == 0
    capsys.readouterr()
    assert main(common + ["--distance-range", "2,9"]) == 0
    assert "1 estimated" in capsys.readouterr().out  # the result of no range is not this one's
    assert main(common + ["--distance-range", "2,9"]) == 0
    assert "0 estimated" in capsys.readouterr().out  # the same range: up to date
    (result,) = (batch / "results").glob("*.json")
    assert json.loads(result.read_text())["provenance"]["distance_range_m"] == [2.0, 9.0]
