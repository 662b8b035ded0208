"""Simulated workers who state a confidence (bench/confidence_workers.py): the true map against
Monte Carlo and closed forms, the scenes they make, the simulate command."""

import json
import warnings

import numpy as np
import pytest
from scipy import stats

from creference_bayes.bench.confidence_workers import STATED_LEVELS, TRUE_MAPS, ConfidentWorkers
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.cli.main import main
from creference_bayes.io.scene import parse_scene
from creference_bayes.pipeline import reference_terms


def test_without_jitter_the_true_map_is_a_normal_interval_scaled_by_the_width_factor():
    for kappa in (0.5, 1.0, 1.6):
        w = ConfidentWorkers(("a",), (0.3,), width_factor=kappa, width_jitter=0.0)
        c = np.array(STATED_LEVELS)
        want = 2 * stats.norm.cdf(kappa * stats.norm.ppf((1 + c) / 2)) - 1
        np.testing.assert_allclose(w.true_coverage(c), want, rtol=1e-10)
    np.testing.assert_allclose(ConfidentWorkers(("a",), (0.3,), width_factor=1.0, width_jitter=0.0)
                               .true_coverage(c), c, rtol=1e-10)


@pytest.mark.parametrize("kind", list(TRUE_MAPS))
def test_the_true_map_is_how_often_stated_ranges_hold_the_truth(kind):
    workers = ConfidentWorkers.pool(kind, n_workers=25, seed=4)
    rng = np.random.default_rng(0)
    n = 40_000
    stated = [workers.state(rng) for _ in range(n)]
    c = np.array([s[3] for s in stated])
    hit = np.array([s[1] <= 1.0 <= s[2] for s in stated])
    for level in STATED_LEVELS:
        m = c == level
        g = float(workers.true_coverage(level))
        se = np.sqrt(g * (1 - g) / m.sum())
        assert abs(hit[m].mean() - g) < 4 * se + 1e-3, (kind, level)
    ids = {s[0] for s in stated}
    assert ids == set(workers.ids)  # every worker answers, many times


def test_over_confident_workers_hold_a_stated_90_percent_about_60_percent_of_the_time():
    g = ConfidentWorkers.pool("over").true_coverage([0.5, 0.9])
    assert 0.55 < g[1] < 0.65 and g[0] < 0.3
    assert ConfidentWorkers.pool("under").true_coverage(0.5) > 0.65


def test_scenes_with_confident_workers():
    workers = ConfidentWorkers.pool("over", n_workers=8, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = simulate_scene(np.random.default_rng(3), tier="low", n_references=10, confidence=workers)
        scene = parse_scene(d)
    truth = d["ground_truth"]["reference_lengths_m"]
    kinds = set()
    for r, term in zip(scene.references, reference_terms(scene)):  # every range in metres
        assert r.is_range and r.confidence in STATED_LEVELS and r.worker in workers.ids
        sigma = workers.scales[workers.ids.index(r.worker)]
        assert abs(0.5 * np.log(term.low * term.high) - np.log(truth[r.index])) < 6 * sigma  # centred near the truth
        kinds.add((r.measure, r.mode))
    assert len(kinds) == 5  # measures and modes still cycle through the formats
    plain = simulate_scene(np.random.default_rng(3), tier="low", n_references=10)
    assert plain == simulate_scene(np.random.default_rng(3), tier="low", n_references=10, confidence=None)
    assert not any("confidence" in r for r in plain["references"])


def test_invalid_pools_are_rejected():
    with pytest.raises(ValueError, match="true map: expected one of"):
        ConfidentWorkers.pool("sloppy")
    with pytest.raises(ValueError, match="width_factor: expected a number > 0"):
        ConfidentWorkers.pool(-1.0)
    with pytest.raises(ValueError, match="levels: expected confidences in"):
        ConfidentWorkers(("a",), (0.2,), levels=(0.5, 1.0))


def test_simulate_command_writes_confident_workers(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "s"), "--n", "2", "--tier", "low", "--confidence", "0.7",
                 "--confidence-workers", "3", "--quiet"]) == 0
    for path in sorted((tmp_path / "s").glob("*.json")):
        refs = json.loads(path.read_text())["references"]
        assert all("range" in r and r["confidence"] in STATED_LEVELS for r in refs)
        assert {r["worker"] for r in refs} <= {"w001", "w002", "w003"}
    assert main(["simulate", str(tmp_path / "t"), "--n", "1", "--confidence", "wild"]) == 2
    assert "--confidence: expected one of ['calibrated', 'over', 'under'] or a width factor" in capsys.readouterr().err
