"""Stated confidence in the metrology model, on scenes of one or more targets: ``none`` is the
treatment without confidences, mapped ranges of every kind (ground segments, relative, a target's
size, the distance between two targets) are normal/Student-t measurements of their log outside the
crowd's scale (against scipy), and the pipeline's option and what the result records."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats
from test_confidence_fit import _parse, confident_scene

from creference_bayes.bench.confidence_workers import ConfidentWorkers
from creference_bayes.models.confidence_map import ConfidenceMap, CoverageCurve, interval_quantile
from creference_bayes.models.contract import C_HEIGHT, C_SCALE
from creference_bayes.models.metrology import ground_lengths
from creference_bayes.pipeline import build_model, estimate

WORKERS = ConfidentWorkers.pool("over", n_workers=10, seed=3)
FITTED = ConfidenceMap(kind="fitted", pooled=CoverageCurve((0.5, 0.9, 0.99), (0.3, 0.55, 0.75)), dof=4.0)


def _scene(seed, m=2):
    d, _ = confident_scene(seed, WORKERS, m=m)
    return d, _parse(d)


def _states(d, n=6, seed=0):
    """(cams (n, 5), objs (n, m, 7)): the scene's true state, moved a little."""
    gt = d["ground_truth"]
    cam = np.array([gt["focal_length_px"], gt["pitch_rad"], gt["roll_rad"], gt["camera_height_m"], 0.3])
    objs = np.array([[t["ground_truth"]["location_m"][0], t["ground_truth"]["location_m"][2],
                      t["ground_truth"]["yaw_rad"], *t["ground_truth"]["dimensions_m"].values(),
                      t["ground_truth"]["ground_m"]] for t in d["targets"]])
    rng = np.random.default_rng(seed)
    cams = np.repeat(cam[None], n, axis=0) * np.exp(rng.normal(0, 0.05, (n, 5)) * [1, 0, 0, 1, 0])
    return cams, objs[None] * np.exp(rng.normal(0, 0.05, (n,) + objs.shape) * [1, 1, 0, 1, 1, 1, 0])


def _model(scene, cmap, cam):
    m, _ = build_model(scene, confidence_map=cmap)
    m.set_pilot(cam)
    return m


def _without_confidence(scene):
    return replace(scene, references=tuple(replace(r, confidence=None) for r in scene.references))


@pytest.mark.parametrize("seed", [0, 1])
def test_none_is_exactly_the_treatment_without_confidences(seed):
    """A scene with confidences under ``none`` (and under a map, without confidences) gives the
    numbers of the model that never heard of confidences."""
    d, scene = _scene(seed)
    cams, objs = _states(d)
    plain = _model(_without_confidence(scene), "none", cams[0])
    want = plain.pointwise_log_likelihood(cams, objs)["references"]
    for m in (_model(scene, "none", cams[0]), _model(_without_confidence(scene), ConfidenceMap.identity(), cams[0])):
        np.testing.assert_array_equal(m.pointwise_log_likelihood(cams, objs)["references"], want)
        np.testing.assert_array_equal(m.neg_log_posterior(cams, objs), plain.neg_log_posterior(cams, objs))
        assert m.n_stated_ranges == 0 and m.camera_free[C_SCALE]


@pytest.mark.parametrize("cmap", [ConfidenceMap.identity(), FITTED])
def test_mapped_ranges_are_measurements_of_their_log_against_scipy(cmap):
    """Every reference a confident range: log L = Σ log mean_b f_D((m − log ℓ + e_b)/S_b)/S_b with
    S_b² = s_c² + v_b, s_c = w / q_D((1 + g(c))/2), ℓ what the reference measures and (e_b, v_b)
    the bins of its line's reading error (none for the lineless)."""
    d, scene = _scene(4)
    cams, objs = _states(d)
    m = _model(scene, cmap, cams[0])
    assert m.n_stated_ranges == 5 and not m.camera_free[C_SCALE]  # no reference left for the crowd's scale
    seg = ground_lengths(np.stack([r.line for r in scene.references[:3]]), scene.principal_point, cams)
    ell = np.column_stack([seg[:, 0], seg[:, 1], seg[:, 2] / objs[:, 0, 3], objs[:, 1, 4],
                           np.hypot(objs[:, 0, 0] - objs[:, 1, 0], objs[:, 0, 1] - objs[:, 1, 1])])
    lo, hi = np.log([r["range"] for r in d["references"]]).T
    c = np.array([r["confidence"] for r in d["references"]])
    s_c = 0.5 * (hi - lo) / interval_quantile(cmap.coverage(c), cmap.dof)
    e, v = m.ref_shift[:, None] + m.ref_node_shift, m.ref_node_var
    assert e.shape == (5, 8) and np.all(v[:3] > 0) and np.all(v[3:] == 0) and np.all(e[3:] == 0)
    S = np.sqrt(s_c[:, None] ** 2 + v)
    dist = stats.norm if cmap.dof is None else stats.t(cmap.dof)
    want = np.log(np.mean(np.exp(dist.logpdf((0.5 * (lo + hi)[:, None] - np.log(ell)[..., None] + e) / S)) / S, axis=-1))
    got = m.pointwise_log_likelihood(cams, objs)["references"]
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-9, atol=1e-9)


def test_mixed_references_keep_the_crowd_scale_for_the_others():
    d, scene = _scene(5)
    refs = list(scene.references)
    refs[0] = replace(refs[0], confidence=None)  # a range without a confidence
    refs[1] = replace(refs[1], low=refs[1].high, is_range=False)  # a single value with a confidence
    mixed = replace(scene, references=tuple(refs))
    cams, objs = _states(d)
    m = _model(mixed, FITTED, cams[0])
    assert m.n_stated_ranges == 3 and m.camera_free[C_SCALE]
    got = m.pointwise_log_likelihood(cams, objs)["references"]
    crowd = _model(mixed, "none", cams[0]).pointwise_log_likelihood(cams, objs)["references"]
    mapped = _model(scene, FITTED, cams[0]).pointwise_log_likelihood(cams, objs)["references"]
    np.testing.assert_array_equal(got[:, :2], crowd[:, :2])
    np.testing.assert_array_equal(got[:, 2:], mapped[:, 2:])


def test_a_confident_narrow_range_is_stronger_evidence_than_the_same_range_at_low_confidence():
    """The log-likelihood lost by moving the measured length 10 % off the range's centre (the
    camera height scales every ground length)."""
    d, scene = _scene(6, m=1)
    cams, objs = _states(d, n=1)
    r = scene.references[0]
    centre = np.sqrt(r.low * r.high)
    cams[0, C_HEIGHT] *= centre / ground_lengths(r.line[None], scene.principal_point, cams)[0, 0]
    states = np.repeat(cams, 2, axis=0)
    states[1, C_HEIGHT] *= 1.1

    def loss(c, cmap):
        one = replace(scene, references=(replace(r, confidence=c),), reference_targets=(None,))
        ll = _model(one, cmap, cams[0]).pointwise_log_likelihood(states, np.repeat(objs, 2, axis=0))["references"]
        return ll[0, 0] - ll[1, 0]

    assert loss(0.95, ConfidenceMap.identity()) > 2 * loss(0.5, ConfidenceMap.identity()) > 0
    assert 0 < loss(0.95, FITTED) < loss(0.95, ConfidenceMap.identity())  # g(0.95) < 0.95: wider


def test_estimate_reads_the_map_and_records_it():
    d, scene = _scene(7)
    kw = dict(seed=0, posterior=False)
    d_none = estimate(scene, confidence_map="none", **kw).to_dict()
    d_id = estimate(scene, confidence_map="identity", **kw).to_dict()
    assert d_none["provenance"]["confidence_map"] == {"name": "none"}
    assert "read_with_confidence_map" not in d_none["references"]
    assert d_id["provenance"]["confidence_map"] == {"name": "identity", "dof": None}
    assert d_id["references"]["read_with_confidence_map"] == 5
    assert d_id["objects"] != d_none["objects"]
    assert build_model(scene)[0].confidence_map is None  # the default is none
    with pytest.raises(ValueError, match="the paper model does not read stated confidences"):
        estimate(scene, model="paper", confidence_map="identity", **kw)
