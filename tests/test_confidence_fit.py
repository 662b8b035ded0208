"""Stated ranges and their truth in scenes of one or more targets (workflows/confidence/data.py),
fitting confidence maps (fit.py) on statements with a known true map: with ground truth, without
(marginal likelihood), per group; levels, PAVA, the chosen shape; leave-one-out posteriors (loo.py)."""

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import truth_scene
from scipy import stats

from creference_bayes.bench.confidence_workers import ConfidentWorkers
from creference_bayes.io.scene import parse_scene
from creference_bayes.workflows.confidence.data import StatedRange, stated_ranges
from creference_bayes.workflows.confidence.fit import (_P_GRID, _pava, assign_levels, fit_marginal, fit_with_truth,
                                                     kept_levels)
from creference_bayes.workflows.confidence.loo import N_DRAWS, RangePrediction, predict_ranges


def confident_scene(seed, workers, *, m=3, sizes_known=False, **kw):
    """A scene of ``m`` targets made from a known state (conftest.truth_scene) whose references are
    ranges stated with a confidence by ``workers``: two ground segments, the second also relative
    to t0's length, t(m−1)'s own width and, with two targets or more, the ground distance t0–t1.
    Returns the scene's dict and each reference's true value in the unit it is stated in (metres,
    or the ratio to t0's length)."""
    d, truth = truth_scene(seed, m=m, sizes_known=sizes_known, n_annotations=4, noise_px=2.0, n_refs=2, **kw)
    objs, rng = truth["objects"], np.random.default_rng([seed, 7])
    seg = d["references"]
    refs = [dict(seg[0]), dict(seg[1]), {**seg[1], "mode": "relative", "target": "t0"},
            {"target": f"t{m - 1}", "measure": "width", "unit": "m"}]
    values = [seg[0]["value"], seg[1]["value"], seg[1]["value"] / objs[0, 3], objs[m - 1, 4]]
    if m > 1:
        refs.append({"targets": ["t0", "t1"], "measure": "distance", "unit": "m"})
        values.append(float(np.hypot(*(objs[0, :2] - objs[1, :2]))))
    del refs[2]["unit"]
    for r, x in zip(refs, values):
        worker, lo, hi, c = workers.state(rng)
        r.pop("value", None)
        r.update(range=[x * lo, x * hi], confidence=c, worker=worker)
    d["references"] = refs
    return d, values


def _parse(d):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def test_every_kind_of_reference_has_its_truth():
    """Ground segments under the true camera, a relative one over the target's true length, a
    target's own size and the distance between two targets from the targets' truth."""
    d, values = confident_scene(0, ConfidentWorkers.pool("over"))
    ranges = stated_ranges([("f", _parse(d))])
    assert [r.index for r in ranges] == list(range(5))
    np.testing.assert_allclose([r.truth for r in ranges], values, rtol=1e-3)
    np.testing.assert_allclose([[r.low, r.high] for r in ranges], [r["range"] for r in d["references"]], rtol=1e-12)
    assert [r.truth_source for r in ranges] == ["segment"] * 3 + ["object"] * 2
    assert [r.group for r in ranges] == ["length/direct", "length/direct", "length/relative", "width/direct",
                                         "distance/direct"]
    stated = [1.1 * v for v in values[:2]] + [1.1 * values[1], 2.0, 9.0]  # metres: the objects' own lengths
    d["ground_truth"]["reference_lengths_m"] = stated
    truth = [r.truth for r in stated_ranges([("f", _parse(d))])]
    np.testing.assert_allclose(truth, stated[:2] + [values[2] * 1.1] + stated[3:], rtol=1e-3)
    del d["ground_truth"]
    for t in d["targets"]:
        t["ground_truth"].pop("dimensions_m")
    ranges = stated_ranges([("f", _parse(d))])
    assert [r.truth is None for r in ranges] == [True, True, True, True, False]
    assert all(r.truth is None for r in stated_ranges([("f", _parse(d))], use_truth=False))


def test_a_relative_range_to_a_target_of_known_size_is_read_in_metres():
    d, values = confident_scene(1, ConfidentWorkers.pool("over"), m=1, sizes_known=True)
    r = stated_ranges([("s", _parse(d))])[2]
    length = d["targets"][0]["dimensions_m"]["length"]
    assert (r.measure, r.mode) == ("length", "relative")
    np.testing.assert_allclose([r.low, r.high, r.truth], np.array([*d["references"][2]["range"], values[2]]) * length,
                               rtol=1e-3)


def _statements(workers, n, seed, measure="length", mode="direct", scenes=None):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        w, lo, hi, c = workers.state(rng)
        out.append(StatedRange(f"s{i // 6 if scenes is None else scenes}", i % 6, w, measure, mode, c, lo, hi,
                               1.0, "object"))
    return out


def test_levels_are_the_distinct_confidences_or_quantile_bins():
    levels, idx = assign_levels([0.9, 0.5, 0.9, 0.7])
    np.testing.assert_allclose(levels, [0.5, 0.7, 0.9])
    np.testing.assert_array_equal(idx, [2, 0, 2, 1])
    c = np.random.default_rng(0).uniform(0.3, 1.0, 1000)
    levels, idx = assign_levels(c, max_levels=5)
    assert len(levels) == 5 and np.all(np.diff(levels) > 0)
    np.testing.assert_allclose(levels, [c[idx == k].mean() for k in range(5)])
    assert np.all(np.bincount(idx) == 200)


@pytest.mark.parametrize("kind", ["over", "calibrated", "under"])
def test_fit_with_truth_recovers_the_true_map(kind):
    workers = ConfidentWorkers.pool(kind, n_workers=30, seed=2)
    cmap = fit_with_truth(_statements(workers, 3000, seed=1), draws=400, interval_prob=0.999)
    c = cmap.pooled
    g = workers.true_coverage(np.array(c.levels))
    assert np.all((np.array(c.low) <= g) & (g <= np.array(c.high))), (c, g)
    assert np.all(np.diff(c.coverage) >= 0) and sum(c.n) == 3000
    assert np.all(np.array(c.high) - np.array(c.low) < 0.25)
    assert cmap.fit["method"] == "truth" and cmap.fit["ranges"] == 3000 and cmap.fit["scenes"] == 500
    assert cmap.dof in (10.0, 30.0, None)  # near-normal errors (mild width jitter)


def test_the_shape_follows_heavy_tailed_errors():
    """Errors drawn from a Student-t with 3 degrees of freedom: coverage g, and the fit picks a
    heavy-tailed shape."""
    rng = np.random.default_rng(5)
    g_true = {0.5: 0.3, 0.9: 0.6, 0.99: 0.8}
    ranges = []
    for i in range(3000):
        c = [0.5, 0.9, 0.99][i % 3]
        s = 1.0 / stats.t.ppf(0.5 + g_true[c] / 2, 3)  # half-width 1 in log-length
        centre = s * rng.standard_t(3)
        ranges.append(StatedRange(f"s{i // 6}", i % 6, None, "width", "direct", c, np.exp(centre - 1),
                                  np.exp(centre + 1), 1.0, "object"))
    cmap = fit_with_truth(ranges, draws=200)
    np.testing.assert_allclose(cmap.pooled.coverage, list(g_true.values()), atol=0.05)
    assert cmap.dof in (2.0, 3.0, 5.0)


def test_groups_get_their_own_curves():
    over = _statements(ConfidentWorkers.pool("over", seed=1), 1200, seed=2, measure="distance")
    under = _statements(ConfidentWorkers.pool("under", seed=1), 1200, seed=3, measure="width", mode="relative")
    cmap = fit_with_truth(over + under, draws=200, min_group=1000)
    assert set(cmap.groups) == {"distance/direct", "width/relative"}
    assert cmap.coverage(0.9, "distance", "direct") < 0.7 < cmap.coverage(0.9, "width", "relative")
    assert fit_with_truth(over + under, draws=50, min_group=2000).groups == {}


def test_pava_merges_levels_that_would_decrease():
    grid = np.log(_P_GRID / (1 - _P_GRID))
    tables = np.array([-(grid - m) ** 2 / (2 * 0.3**2) for m in (-1.0, 0.5, -0.5, 1.0)])
    p, total = _pava(tables)
    assert np.all(np.diff(p) >= 0)
    assert p[1] == p[2]  # the violators share one value: the maximiser of their summed profile
    np.testing.assert_allclose(np.log(p[1] / (1 - p[1])), 0.0, atol=0.02)
    np.testing.assert_allclose(np.log(p[[0, 3]] / (1 - p[[0, 3]])), [-1.0, 1.0], atol=0.02)


def _predictions(workers, n, seed, spread):
    """Statements with a calibrated leave-one-out posterior: the truth is a draw from it."""
    rng = np.random.default_rng(seed)
    preds = []
    for r in _statements(workers, n, seed):
        mu = np.log(r.truth) + spread * rng.standard_normal()  # the posterior's centre
        draws = mu + spread * rng.standard_normal(N_DRAWS)
        preds.append(RangePrediction(r, draws, 0.0, 0.0, False))
    return preds


@pytest.mark.slow  # 1,800 predictions bootstrapped; test_fits_are_deterministic_for_a_seed keeps the fit in the default run
def test_fit_without_truth_recovers_the_true_map_from_calibrated_posteriors():
    workers = ConfidentWorkers(tuple(f"w{i}" for i in range(20)),
                               tuple(np.geomspace(0.15, 0.5, 20)), width_factor=0.5, width_jitter=0.0)
    cmap = fit_marginal(_predictions(workers, 1800, seed=3, spread=0.05), draws=60)
    c = cmap.pooled
    g = workers.true_coverage(np.array(c.levels))
    sd = np.array(c.sd)
    assert np.all(np.abs(np.array(c.coverage) - g) < 4 * sd + 0.03), (c.coverage, g)
    assert cmap.dof in (10.0, 30.0, None)  # normal errors
    assert cmap.fit["method"] == "marginal" and cmap.fit["uncertainty"] == "bootstrap over scenes"


def test_fits_are_deterministic_for_a_seed():
    workers = ConfidentWorkers.pool("over", seed=0)
    r = _statements(workers, 300, seed=0)
    assert fit_with_truth(r, seed=4) == fit_with_truth(r, seed=4)
    p = _predictions(workers, 120, 1, 0.1)
    assert fit_marginal(p, seed=4, draws=20, min_per_level=5) == fit_marginal(p, seed=4, draws=20, min_per_level=5)


def test_nothing_to_fit_says_so():
    with pytest.raises(ValueError, match="no range with a stated confidence and a known truth"):
        fit_with_truth([StatedRange("s", 0, None, "length", "direct", 0.9, 1.0, 2.0)])
    with pytest.raises(ValueError, match="no confidence level has 10 ranges or more"):
        fit_with_truth(_statements(ConfidentWorkers.pool("over"), 20, seed=0))
    # one level kept of several would read every other confidence as that one; one level stated is fine
    with pytest.raises(ValueError, match=r"only one confidence level has 3 ranges or more \(--min-per-level; "
                                         r"ranges per level 0.5: 3, 0.9: 1\)"):
        kept_levels([0.5, 0.5, 0.5, 0.9], 3)
    levels, idx, n, keep = kept_levels([0.9, 0.9, 0.9], 3)
    assert levels.tolist() == [0.9] and n.tolist() == [3] and keep.all()


@pytest.mark.slow  # two estimates of a two-target frame and the leave-one-out predictions (about 90 s)
@pytest.mark.parametrize("j", [4, 0])
def test_leave_one_out_draws_match_an_estimate_without_the_range(j):
    """The importance-weighted draws of what a range measures equal (within Monte Carlo error) the
    posterior of an estimate made without that range: the distance between the two targets of a
    frame, and a ground segment."""
    from creference_bayes.models.metrology import ground_lengths
    from creference_bayes.pipeline import estimate

    scene = _parse(confident_scene(3, ConfidentWorkers.pool("over"), m=2)[0])
    sampling = {"min_ess": 100, "n_chains": 4, "warmup": 200}
    preds, info = predict_ranges(scene, "s", seed=1, sampling=sampling)
    assert info["ranges"] == len(preds) == 5 and info["skipped"] == 0
    keep = [i for i in range(5) if i != j]
    without = dataclasses.replace(scene, references=tuple(scene.references[i] for i in keep),
                                  reference_targets=tuple(scene.reference_targets[i] for i in keep))
    r = estimate(without, seed=2, confidence_map="none", sampling=sampling, keep_draws=0)
    cams, objs = r.draws.cameras.reshape(-1, 5), r.draws.objects.reshape(-1, 2, 7)
    if j == 4:
        exact = np.log(np.hypot(objs[:, 0, 0] - objs[:, 1, 0], objs[:, 0, 1] - objs[:, 1, 1]))
    else:
        exact = np.log(ground_lengths(scene.references[j].line[None], scene.principal_point, cams)[:, 0])
    p = preds[j]
    assert p.range.index == j and (p.line_var > 0) == (j == 0)
    assert abs(np.mean(p.log_length) - exact.mean()) < 0.15 * exact.std() + 1e-3
    assert np.std(p.log_length) == pytest.approx(exact.std(), rel=0.2)
