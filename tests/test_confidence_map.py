"""Confidence maps (models/confidence_map.py): quantiles against scipy, the coverage a scale
implies, monotone interpolation, the file format and its errors, resolving names."""

import json

import numpy as np
import pytest
from scipy import stats

from creference_bayes.models.confidence_map import (COVERAGE_CEIL, COVERAGE_FLOOR, DEFAULT_CONFIDENCE_MAP,
                                                    ConfidenceMap, ConfidenceMapError, CoverageCurve,
                                                    describe_confidence_map, interval_quantile,
                                                    resolve_confidence_map)

P = np.array([0.1, 0.5, 0.8, 0.9, 0.95, 0.99])


def _fitted(**kw):
    curve = CoverageCurve((0.5, 0.7, 0.9, 0.99), (0.3, 0.4, 0.6, 0.7), low=(0.2, 0.3, 0.5, 0.6),
                          high=(0.4, 0.5, 0.7, 0.8), sd=(0.05,) * 4, n=(50, 60, 70, 80))
    return ConfidenceMap(kind="fitted", pooled=curve, **kw)


@pytest.mark.parametrize("dof", [None, 1.0, 2.0, 10.0])
def test_interval_quantile_is_the_central_interval_of_scipy_distributions(dof):
    dist = stats.norm if dof is None else stats.t(dof)
    q = interval_quantile(P, dof)
    np.testing.assert_allclose(q, dist.ppf(0.5 + P / 2), rtol=1e-10)
    np.testing.assert_allclose(dist.cdf(q) - dist.cdf(-q), P, rtol=1e-10)


@pytest.mark.parametrize("cmap", [ConfidenceMap.identity(), ConfidenceMap.identity(dof=3.0), _fitted(dof=5.0)])
def test_the_scale_of_a_range_gives_it_the_mapped_coverage(cmap):
    """P(|ε| s < w) = g(c) for ε from the map's distribution: what the metrology model relies on."""
    c = np.array([0.5, 0.7, 0.9, 0.95])
    w = np.array([0.05, 0.2, 0.4, 1.0])
    s = cmap.scale(c, w)
    dist = stats.norm if cmap.dof is None else stats.t(cmap.dof)
    np.testing.assert_allclose(dist.cdf(w / s) - dist.cdf(-w / s), cmap.coverage(c), rtol=1e-9)
    if cmap.kind == "identity":
        np.testing.assert_allclose(cmap.coverage(c), c)


def test_coverage_is_kept_within_its_limits():
    ident = ConfidenceMap.identity()
    assert ident.coverage(0.0) == COVERAGE_FLOOR and ident.coverage(1.0) == COVERAGE_CEIL
    assert np.isfinite(ident.scale(1.0, 0.1)) and ident.scale(1.0, 0.1) > 0


def test_a_curve_passes_through_its_levels_is_monotone_and_constant_beyond():
    cmap = _fitted()
    curve = cmap.pooled
    np.testing.assert_allclose(curve(curve.levels), curve.coverage, atol=1e-12)
    c = np.linspace(0.0, 1.0, 1001)
    g = curve(c)
    assert np.all(np.diff(g) >= -1e-12)
    assert np.all(g[c <= 0.5] == 0.3) and np.all(g[c >= 0.99] == 0.7)
    lo, hi = curve.band(c)
    assert np.all(lo <= g + 1e-12) and np.all(g <= hi + 1e-12)
    single = CoverageCurve((0.8,), (0.55,))
    np.testing.assert_allclose(single([0.1, 0.8, 0.99]), 0.55)


def test_groups_are_used_for_their_measure_and_mode_only():
    own = CoverageCurve((0.5, 0.9), (0.45, 0.85))
    cmap = _fitted(groups={"distance/direct": own})
    assert cmap.coverage(0.9, "distance", "direct") == pytest.approx(0.85)
    assert cmap.coverage(0.9, "length", "direct") == pytest.approx(0.6)
    assert cmap.coverage(0.9) == pytest.approx(0.6)


def test_file_round_trip_and_digest(tmp_path):
    cmap = _fitted(dof=5.0, groups={"length/relative": CoverageCurve((0.5, 0.9), (0.4, 0.5))},
                   fit={"method": "truth", "ranges": 260})
    path = tmp_path / "map.json"
    path.write_text(json.dumps(cmap.to_dict()))
    back = ConfidenceMap.load(path)
    assert back == cmap and back.source == str(path)
    assert back.digest() == cmap.digest()
    assert _fitted(dof=4.0).digest() != _fitted(dof=5.0).digest()
    assert describe_confidence_map(back) == {"name": "file", "source": str(path), "sha256": cmap.digest()}
    assert describe_confidence_map(None) == {"name": "none"}


def _doc(**changes):
    d = _fitted().to_dict()
    d.update(changes)
    return d


@pytest.mark.parametrize("doc, message", [
    (_doc(format="other/1"), "format: expected 'creference-confidence-map/1', got 'other/1'"),
    (_doc(pooled={"levels": [0.5, 0.9], "coverage": [0.6, 0.4]}),
     "pooled.coverage: expected non-decreasing values (a map is monotone), got [0.6, 0.4]"),
    (_doc(pooled={"levels": [0.9, 0.5], "coverage": [0.4, 0.6]}), "pooled.levels: expected increasing values"),
    (_doc(pooled={"levels": [0.5, 0.9], "coverage": [0.4]}),
     "pooled.coverage: expected 2 values (one per level), got 1"),
    (_doc(pooled={"levels": [0.5, 1.2], "coverage": [0.4, 0.5]}),
     "pooled.levels[1]: expected a number in [0, 1], got 1.2"),
    (_doc(dof=-1), "dof: expected a number > 0 or null (normal), got -1"),
    (_doc(colour="red"), "unknown key(s) ['colour']"),
    (_doc(groups={"width/direct": {"levels": [0.5]}}), "groups.width/direct: missing required key 'coverage'"),
])
def test_invalid_map_files_name_the_key_and_the_value(doc, message):
    with pytest.raises(ConfidenceMapError) as err:
        ConfidenceMap.from_dict(doc)
    assert message in str(err.value)


def test_resolve_names_files_and_the_default(tmp_path):
    assert resolve_confidence_map("none") is None and resolve_confidence_map(None) is None
    assert resolve_confidence_map("identity") == ConfidenceMap.identity()
    assert resolve_confidence_map("default") == resolve_confidence_map(DEFAULT_CONFIDENCE_MAP)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(_fitted().to_dict()))
    assert resolve_confidence_map(str(path)) == _fitted()
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ConfidenceMapError, match="bad.json: not valid JSON"):
        resolve_confidence_map(tmp_path / "bad.json")
    with pytest.raises(ConfidenceMapError, match="expected 'none', 'identity'"):
        resolve_confidence_map(3)
