"""Stated confidence in the metrology model: ``none`` is the treatment from before, mapped ranges
are normal/Student-t measurements of log ℓ outside the crowd-scale mixture (against scipy), the
pipeline's option and result block."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from creference_bayes.bench.confidence_workers import ConfidentWorkers
from creference_bayes.bench.simulate import simulate_scene, true_params
from creference_bayes.core.geometry import Camera
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.confidence_map import ConfidenceMap, CoverageCurve, interval_quantile
from creference_bayes.models.metrology import MetrologyModel, ground_lengths
from creference_bayes.pipeline import estimate

WORKERS = ConfidentWorkers.pool("over", n_workers=10, seed=3)
FITTED = ConfidenceMap(kind="fitted", pooled=CoverageCurve((0.5, 0.9, 0.99), (0.3, 0.55, 0.75)), dof=4.0)


def _scene(seed, confidence=WORKERS, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(simulate_scene(np.random.default_rng(seed), tier="low", confidence=confidence, **kw))




def _model(scene, **kw):
    return MetrologyModel.from_scene(scene, scene.ground_truth.extra["handedness"],
                                     camera=Camera.from_scene(scene), **kw)


def _without_confidence(scene):
    return replace(scene, references=tuple(replace(r, confidence=None) for r in scene.references))


def _params(scene, n=6, seed=0):
    rng = np.random.default_rng(seed)
    p = np.repeat(true_params(scene)[None], n, axis=0)
    p[:, 1] *= np.exp(rng.normal(0, 0.1, n))
    p[:, 4] *= np.exp(rng.normal(0, 0.1, n))
    return p


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_none_is_exactly_the_treatment_without_confidences(seed):
    """A scene with confidences under ``none`` (and under a map, without confidences) gives the
    numbers of the model that never heard of confidences."""
    scene = _scene(seed)
    assert all(r.confidence is not None for r in scene.references)
    params = _params(scene)
    plain = _model(_without_confidence(scene))
    for m in (_model(scene), _model(scene, confidence_map=None),
              _model(_without_confidence(scene), confidence_map=ConfidenceMap.identity())):
        for model in (plain, m):
            model.set_pilot(true_params(scene))
        np.testing.assert_array_equal(m.cost(params), plain.cost(params))
        assert m.n_stated_ranges == 0


@pytest.mark.parametrize("cmap", [ConfidenceMap.identity(), FITTED])
def test_mapped_ranges_are_measurements_of_log_length_against_scipy(cmap):
    """Every reference a confident range: −log L = Σ −log f_D((m − log ℓ)/S)/S with
    S² = s_c² + line variance, s_c = w / q_D((1 + g(c))/2), outside any mixture."""
    scene = _scene(4)
    m = _model(scene, confidence_map=cmap)
    m.set_pilot(true_params(scene))
    assert m.n_stated_ranges == len(scene.references)
    params = _params(scene)
    lo, hi = np.log([r.length_bounds_m(scene.target) for r in scene.references]).T
    c = np.array([r.confidence for r in scene.references])
    s_c = 0.5 * (hi - lo) / interval_quantile(cmap.coverage(c), cmap.dof)
    S = np.sqrt(s_c**2 + m.line_variances)
    ell = ground_lengths(np.stack([r.line for r in scene.references]), scene.principal_point, params)
    dist = stats.norm if cmap.dof is None else stats.t(cmap.dof)
    want = -np.sum(dist.logpdf((0.5 * (lo + hi) - np.log(ell)) / S) - np.log(S), axis=1)
    got = m.reference_nll(params)
    np.testing.assert_allclose(got - got[0], want - want[0], rtol=1e-9, atol=1e-9)


def test_mixed_references_add_the_mapped_terms_to_the_mixture_of_the_others():
    scene = _scene(5)
    refs = list(scene.references)
    refs[0] = replace(refs[0], confidence=None)  # a range without a confidence: today's treatment
    refs[1] = replace(refs[1], low=refs[1].high, is_range=False)  # a single value with a confidence
    mixed = replace(scene, references=tuple(refs))
    m = _model(mixed, confidence_map=FITTED)
    others = _model(replace(mixed, references=tuple(refs[:2])))
    mapped = _model(replace(mixed, references=tuple(refs[2:])), confidence_map=FITTED)
    for model in (m, others, mapped):
        model.set_pilot(true_params(scene))
    assert m.n_stated_ranges == len(refs) - 2
    params = _params(scene)
    np.testing.assert_allclose(m.reference_nll(params),
                               others.reference_nll(params) + mapped.reference_nll(params), rtol=1e-12)
    _, w = m.crowd_scale_weights(params)
    _, w_others = others.crowd_scale_weights(params)
    np.testing.assert_allclose(w, w_others, rtol=1e-9)  # the mapped ranges say nothing about the crowd


def test_a_confident_narrow_range_is_stronger_evidence_than_the_same_range_at_low_confidence():
    scene = _scene(6, n_references=1)
    r = scene.references[0]
    strong = _model(replace(scene, references=(replace(r, confidence=0.95),)), confidence_map=ConfidenceMap.identity())
    weak = _model(replace(scene, references=(replace(r, confidence=0.5),)), confidence_map=ConfidenceMap.identity())
    assert strong.reference_scales[0, 0] < 0.5 * weak.reference_scales[0, 0]
    over = _model(replace(scene, references=(replace(r, confidence=0.95),)), confidence_map=FITTED)
    assert over.reference_scales[0, 0] > strong.reference_scales[0, 0]  # g(0.95) < 0.95: wider


def test_estimate_reads_the_map_and_reports_it():
    scene = _scene(7)
    kw = dict(seed=0, posterior=False)
    d_none = estimate(scene, confidence_map="none", **kw).to_dict()
    d_id = estimate(scene, confidence_map="identity", **kw).to_dict()
    assert d_none["confidence"] == {"map": {"name": "none"}, "ranges_with_confidence": 5, "read_with_map": 0}
    assert d_id["confidence"]["map"] == {"name": "identity", "dof": None}
    assert d_id["confidence"]["read_with_map"] == 5
    assert d_id["map"] != d_none["map"]
    assert estimate(scene, **kw).to_dict()["map"] == d_none["map"]  # the default is none
    assert estimate(scene, model="paper", confidence_map="none", **kw).to_dict()["confidence"]["map"] == {"name": "none"}
    with pytest.raises(ValueError, match="the paper model turns ranges into bounds"):
        estimate(scene, model="paper", confidence_map="identity", **kw)
