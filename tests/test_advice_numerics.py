"""The advice's numerics: pairwise IoU, weighted HDI, the importance weights of a simulated
annotation (against the models' own costs), the tempered fallback, candidates and their costs."""

import dataclasses

import arviz as az
import numpy as np
import pytest

from creference_bayes.camera_setup import setup_camera
from creference_bayes.workflows.advice.candidates import (PAPER_REFERENCE_SECONDS, PAPER_TARGET_SECONDS,
                                                          annotation_seconds, candidates, format_mix)
from creference_bayes.workflows.advice.iou import iou_3d_pairs
from creference_bayes.workflows.advice.observe import ModelContext, ReferenceObservation, TargetObservation
from creference_bayes.workflows.advice.update import location_sd, normalise, tempered_update, weighted_hdi
from creference_bayes.workflows.labels.quality import box_iou_3d


def test_pairwise_iou_matches_shapely():
    rng = np.random.default_rng(0)
    n = 400
    a = np.column_stack([rng.normal(0, 0.6, n), rng.normal(1.5, 0.2, n), rng.normal(6, 0.6, n),
                         rng.uniform(-np.pi, np.pi, n), rng.uniform(0.2, 3, (n, 3))])
    b = a + np.column_stack([rng.normal(0, 0.3, (n, 3)), rng.normal(0, 0.5, n), rng.normal(0, 0.2, (n, 3))])
    b[:, 4:] = np.abs(b[:, 4:]) + 0.05
    b[:50] = a[:50]  # identical boxes
    expected = np.array([box_iou_3d(a[i], b[i:i + 1])[0] for i in range(n)])
    np.testing.assert_allclose(iou_3d_pairs(a, b), expected, atol=1e-9)
    assert np.all(iou_3d_pairs(a[:50], b[:50]) > 1 - 1e-9)
    assert (expected == 0).any() and ((expected > 0) & (expected < 1)).sum() > 100


def test_weighted_hdi_with_equal_weights_is_the_sample_hdi():
    x = np.random.default_rng(1).gamma(3.0, 1.0, 4000)
    width, median = weighted_hdi(x, np.full((1, x.size), 1 / x.size), 0.9)
    lo, hi = az.hdi(x, hdi_prob=0.9)
    assert width[0] == pytest.approx(hi - lo, rel=2e-3)
    assert median[0] == pytest.approx(np.median(x), abs=2e-3)


def test_the_location_sd_of_uneven_weights_is_not_short():
    """Weights unrelated to the draws, a few dozen effective draws of 1000: the location's
    variance from them must be the draws' (3 m², unit normals in x, y, z) on average; the plain
    weighted variance is short by 1/ESS (here 3–4 %)."""
    rng = np.random.default_rng(0)
    full = np.zeros((1000, 7))
    full[:, :3] = rng.standard_normal((1000, 3))
    w, ess = normalise(2.0 * rng.standard_normal((400, 1000)))
    assert 20 < np.median(ess) < 60
    var = location_sd(full, w) ** 2
    centred = full[:, :3] - full[:, :3].mean(axis=0)
    truth = np.sum(centred ** 2) / 999
    assert np.mean(var) == pytest.approx(truth, rel=0.015)
    assert location_sd(full, np.full((1, 1000), 1e-3))[0] ** 2 == pytest.approx(truth, rel=1e-9)


def test_reweighting_a_gaussian_gives_the_conjugate_posterior():
    x = np.random.default_rng(2).normal(0.0, 1.0, 200_000)
    # observation y = 1 with noise sd 1: posterior N(0.5, 0.5); sd 0.5: N(0.8, 0.2)
    log_w = np.stack([-0.5 * (1.0 - x) ** 2, -0.5 * ((1.0 - x) / 0.5) ** 2])
    w, ess = normalise(log_w)
    width, median = weighted_hdi(x, w, 0.9)
    np.testing.assert_allclose(width, 2 * 1.6449 * np.sqrt([0.5, 0.2]), rtol=0.01)
    np.testing.assert_allclose(median, [0.5, 0.8], atol=0.01)
    assert ess[0] > ess[1] > 0


def test_tempered_update_recovers_a_posterior_plain_reweighting_cannot():
    rng = np.random.default_rng(3)
    prior = rng.normal(0.0, 1.0, (400, 2))
    mu, sd = np.array([1.2, -0.7]), 0.03   # the likelihood is 30 times narrower than the prior

    def log_old(p):
        return -0.5 * np.sum(p * p, axis=1)

    def log_new(p):
        return log_old(p) - 0.5 * np.sum(((p - mu) / sd) ** 2, axis=1)

    _, ess = normalise((log_new(prior) - log_old(prior))[None])
    assert ess[0] < 5  # collapsed
    moved, info = tempered_update(log_old, log_new, prior, rng)
    post_var = 1 / (1 + 1 / sd**2)
    post_mean = mu * post_var / sd**2
    np.testing.assert_allclose(moved.mean(axis=0), post_mean, atol=0.01)
    np.testing.assert_allclose(moved.std(axis=0), np.sqrt(post_var), rtol=0.25)
    assert info["beta"] == 1.0 and info["stages"] >= 2


# ------------------------------------------------------------------------------------------------
# weights against the models


def _truth_draws(scene, n, rng, spread=(0.05, 0.02, 0.2, 0.03, 40.0)):
    """Parameter vectors scattered around the scene's truth (the weights are defined pointwise, so
    any states will do); derived pitch and roll are filled in by the model."""
    gt = scene.ground_truth
    t = np.array([*gt.location_m, gt.yaw_rad, gt.focal_length_px, gt.extra["pitch_rad"], gt.extra["roll_rad"]])
    out = np.tile(t, (n, 1))
    out[:, :5] += rng.normal(0, 1, (n, 5)) * np.array(spread)
    return out


@pytest.fixture(scope="module")
def context():
    from creference_bayes.bench.runner import variant
    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.scene import parse_scene

    scene = variant(parse_scene(simulate_scene(np.random.default_rng(5), tier="medium", setting="indoor")),
                    3, range(4))
    setup = setup_camera(scene)
    gt = scene.ground_truth
    pilot = np.array([*gt.location_m, gt.yaw_rad, gt.focal_length_px, gt.extra["pitch_rad"], gt.extra["roll_rad"]])
    ctx = ModelContext(scene, setup, gt.extra["handedness"], pilot)
    draws = ctx.model.expand(_truth_draws(scene, 300, np.random.default_rng(6))[:, ctx.model.free])
    return ctx, draws


@pytest.mark.parametrize("range_share", [0.0, 1.0])
def test_reference_weights_are_the_cost_difference_of_the_models(context, range_share):
    ctx, draws = context
    ref = ctx.scene.references[1]
    obs = ReferenceObservation(ctx, ref.line, measure=ref.measure, object=ref.object, range_share=range_share)
    obs.simulate(np.random.default_rng(7), draws[:6])
    fast = obs.log_ratio(draws)
    base = ctx.model.cost(draws)
    for i in range(6):
        brute = -(ctx.model_of(obs.scene_with(i)).cost(draws) - base)
        diff = fast[i] - brute
        assert np.ptp(diff) < 1e-8, f"row {i}: not a constant offset ({np.ptp(diff):.2e})"
    assert obs.is_range.all() == bool(range_share)


def test_target_weights_use_the_new_corner_scale(context):
    ctx, draws = context
    obs = TargetObservation(ctx)
    obs.simulate(np.random.default_rng(8), draws[:4])
    new = ctx.model_of(obs.scene_with(0))
    assert new.target_sigma != ctx.model.target_sigma  # the added set changes σ …
    fixed = dataclasses.replace(ctx.model, annotations=np.concatenate([ctx.model.annotations, obs.corners[:1]]))
    fixed.set_pilot(ctx.pilot)
    with_sigma = obs.log_ratio(draws)[0]
    without = -(fixed.cost(draws) - ctx.model.cost(draws))
    assert np.ptp(with_sigma - without) > 1e-3  # … and the weights account for it


def test_simulated_target_annotations_scatter_as_the_scenes_sets_do(context):
    """Three sets: the model's corner scale is their pooled sd, and a simulated set must scatter
    by that sd (a t₄ of that scale would scatter √2 more than any set seen). One set: the model's
    stated t₄ scale (5 px), whose sd is √2 · 5 px."""
    from creference_bayes.core.cost import project_params

    ctx, draws = context
    rows = np.repeat(draws[:1], 4000, axis=0)
    proj, _ = project_params(draws[:1], ctx.model.obj_corners, ctx.model.camera.principal_point)
    assert len(ctx.model.annotations) == 3
    obs = TargetObservation(ctx)
    obs.simulate(np.random.default_rng(9), rows)
    err = (obs.corners - proj).reshape(-1)
    assert np.std(err) == pytest.approx(ctx.model.target_sigma, rel=0.1)
    assert abs(np.median(err)) < 0.05 * ctx.model.target_sigma
    t = ctx.scene.target
    one = dataclasses.replace(ctx.scene, target=dataclasses.replace(t, dimension_lines=t.dimension_lines[:1]))
    ctx1 = ModelContext(one, ctx.setup, ctx.handedness, ctx.pilot)
    assert ctx1.model.target_sigma == 5.0
    obs1 = TargetObservation(ctx1)
    obs1.simulate(np.random.default_rng(9), rows)
    err1 = (obs1.corners - proj).reshape(-1)
    # bivariate t with ν = 4 and scale σ: each coordinate has variance σ² ν / (ν − 2) = 2σ²
    assert np.std(err1) == pytest.approx(np.sqrt(2) * 5.0, rel=0.1)


# ------------------------------------------------------------------------------------------------
# candidates


def test_candidates_group_repeated_segments_and_add_distances(make_scene):
    scene = make_scene(11, tier="low", n_references=3)
    refs = list(scene.references)
    # a second worker on reference 0's object and measure, drawn a few pixels off and reversed
    twin = dataclasses.replace(refs[0], index=3, line=refs[0].line[::-1] + 2.0, worker="w-twin")
    # the same object name but a segment far away: another object of that name
    other = dataclasses.replace(refs[0], index=4, line=refs[0].line + np.array([400.0, 0.0]), worker="w-far")
    scene = dataclasses.replace(scene, references=tuple(refs) + (twin, other))
    cands = candidates(scene)
    assert cands[0].kind == "target"
    repeats = [c for c in cands if c.kind == "reference" and not c.new_segment]
    assert [c.based_on for c in repeats][:1] == [(0, 3)]
    assert any(c.based_on == (4,) for c in repeats)
    for c in cands:
        if c.new_segment:
            assert c.measure == "distance" and c.line[0, 1] == scene.image_height - 1
            assert scene.references[c.based_on[0]].measure != "distance"


def test_seconds_are_the_scenes_medians_else_the_papers(make_scene):
    scene = make_scene(12, n_references=2, n_target_annotations=3)
    t = scene.target
    lines = tuple(dataclasses.replace(d, seconds=s) for d, s in zip(t.dimension_lines, (100.0, None, 300.0)))
    scene = dataclasses.replace(scene, target=dataclasses.replace(t, dimension_lines=lines),
                                references=tuple(dataclasses.replace(r, seconds=None) for r in scene.references))
    assert annotation_seconds(scene) == {"target": 200.0, "reference": PAPER_REFERENCE_SECONDS}
    bare = dataclasses.replace(scene, target=dataclasses.replace(
        t, dimension_lines=tuple(dataclasses.replace(d, seconds=None) for d in t.dimension_lines)))
    assert annotation_seconds(bare)["target"] == PAPER_TARGET_SECONDS


def test_format_mix_counts_ranges_and_their_precision(make_scene):
    scene = make_scene(13, n_references=10, format_offset=0)
    mix = format_mix(scene)
    assert mix.range_share == pytest.approx(sum(r.is_range for r in scene.references) / 10)
    assert 0.0 < mix.range_precision < 2.0
