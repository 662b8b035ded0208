"""The simulator against benchmark.md: ranges, tiers, formats, units, noise models, determinism."""

import json
import math
import warnings
from collections import Counter

import numpy as np
import pytest

from creference_bayes.cli.main import main
from creference_bayes.core.geometry import Camera, box_points, dimension_corners
from creference_bayes.core.metrics import range_precision
from creference_bayes.io.scene import load_scene, parse_scene
from creference_bayes.bench.simulate import (FORMATS, SETTINGS, TIERS, measurement_factor,
                                             simulate_scene)


def _scene(seed, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = simulate_scene(np.random.default_rng(seed), **kw)
        return d, parse_scene(d)


def test_same_seed_same_scene_and_different_seed_differs():
    a = simulate_scene(np.random.default_rng(7), tier="high")
    b = simulate_scene(np.random.default_rng(7), tier="high")
    c = simulate_scene(np.random.default_rng(8), tier="high")
    assert json.dumps(a) == json.dumps(b)
    assert json.dumps(a) != json.dumps(c)


@pytest.mark.parametrize("setting", ["indoor", "outdoor"])
def test_camera_and_distance_ranges(setting):
    cfg = SETTINGS[setting]
    for seed in range(15):
        d, scene = _scene(seed, setting=setting, tier="none")
        g = d["ground_truth"]
        x, y, z = g["location_m"]
        assert cfg["distance"][0] <= math.hypot(x, z) <= cfg["distance"][1]
        assert cfg["height"][0] <= g["camera_height_m"] <= cfg["height"][1]
        assert y == pytest.approx(g["camera_height_m"])  # the box stands on the ground
        assert math.radians(cfg["pitch_deg"][0]) <= g["pitch_rad"] <= math.radians(cfg["pitch_deg"][1])
        assert abs(g["roll_rad"]) <= math.radians(3.0)
        assert 1000 <= g["focal_length_px"] <= 2600
        assert scene.image_size == (2880, 1800)
        np.testing.assert_allclose(scene.principal_point, [1440, 900])
        t = scene.target
        assert 0.024 <= t.length <= 4.64 and 0.06 <= t.width <= 5.25 and 0.24 <= t.height <= 3.83
        assert len(t.dimension_lines) == 13 and len(scene.references) == 5


def test_coordinates_are_stored_to_two_decimals_by_default():
    d, _ = _scene(3, tier="low")
    pts = np.concatenate([np.ravel(a["corners"]) for a in d["target"]["dimension_lines"]]
                         + [np.ravel(r["line"]) for r in d["references"]] + [np.ravel(d["horizon"])])
    np.testing.assert_allclose(pts, np.round(pts, 2), atol=1e-9)
    raw, _ = _scene(3, tier="low", decimals=None)
    assert np.abs(np.ravel(raw["horizon"]) - np.round(np.ravel(raw["horizon"]), 2)).max() > 1e-6


def test_noise_free_tier_is_exact():
    """Tier none: annotations are the true projections; stated lengths are the true lengths."""
    for seed in range(6):
        d, scene = _scene(seed, tier="none", principal_offset=0.05, decimals=None)
        g = scene.ground_truth
        t = scene.target
        params = np.array([*g.location_m, g.yaw_rad, g.focal_length_px])
        corners = dimension_corners(t.length, t.width, t.height, g.extra["handedness"])
        cam = Camera(scene.principal_point, Camera.from_scene(scene).horizon, None)
        uv, _ = cam.project(box_points(params[None], corners), params[None, 4])
        for ann in t.corners:
            np.testing.assert_allclose(ann, uv[0], atol=1e-6)
        for ref, true_len in zip(scene.references, g.extra["reference_lengths_m"]):
            lo, hi = ref.length_bounds_m(t)
            centre = (lo + hi) / 2 if ref.is_range else lo
            assert centre == pytest.approx(true_len, rel=2e-3)  # stated to 4 significant digits


def test_paper_like_measurement_noise_matches_table_2():
    """benchmark.md: median absolute error 50–65 %, mean 100–250 % (paper Table 2)."""
    err = np.abs(measurement_factor(np.random.default_rng(0), "paper", 400_000) - 1) * 100
    assert 50 <= np.median(err) <= 65
    assert 100 <= err.mean() <= 250
    assert np.isfinite(err).all() and err.max() <= 1900 + 1e-9  # clipped at a factor 20


@pytest.mark.parametrize("model, sd", [("10%", 0.1), ("40%", 0.4)])
def test_lognormal_tiers(model, sd):
    f = measurement_factor(np.random.default_rng(1), model, 100_000)
    log = np.log(f)
    assert abs(log.mean()) < 5 * sd / np.sqrt(len(f))
    assert np.std(log) == pytest.approx(sd, rel=0.02)
    assert measurement_factor(np.random.default_rng(1), "none") == 1.0
    with pytest.raises(ValueError, match="unknown model 'huge'"):
        measurement_factor(np.random.default_rng(1), "huge")


def test_formats_units_and_range_precision():
    counts, units, precision = Counter(), Counter(), []
    for i in range(40):  # offsets 0, 5, 10, …: every two scenes cover the ten formats once
        _, scene = _scene(100 + i, tier="medium", format_offset=5 * i)
        for r in scene.references:
            counts[(r.measure, r.mode, r.is_range)] += 1
            units[r.unit] += 1
            if r.is_range:
                precision.append(float(range_precision(r.low, r.high)))
    assert set(counts) == set(FORMATS) and len(FORMATS) == 10
    assert set(counts.values()) == {20}
    assert ("distance", "relative", False) not in counts
    assert set(units) == {None, "m", "ft", "in", "yd"}  # None: relative values
    assert 20 <= np.median(precision) <= 30  # paper Table 3: medians 18–29 %


def test_random_formats_are_distinct_within_a_scene():
    _, scene = _scene(3, tier="low")
    kinds = [(r.measure, r.mode, r.is_range) for r in scene.references]
    assert len(set(kinds)) == len(kinds) == 5


def test_tier_noise_levels():
    """Target corners scatter with σ_t around the truth; worker values with the tier's model."""
    for name in ("low", "medium", "high"):
        tier = TIERS[name]
        dev = []
        for seed in range(8):
            d, scene = _scene(seed, tier=name)
            dev.append(scene.target.corners - np.asarray(d["ground_truth"]["target_corners_px"]))
        dev = np.concatenate(dev).ravel()
        assert np.std(dev) == pytest.approx(tier.target_px, rel=0.1)


def test_bad_arguments_name_the_problem():
    with pytest.raises(ValueError, match="tier: expected one of"):
        simulate_scene(0, tier="extreme")
    with pytest.raises(ValueError, match="setting"):
        simulate_scene(0, setting="space")
    with pytest.raises(ValueError, match="n_target_annotations"):
        simulate_scene(0, n_target_annotations=0)


def test_simulate_command_is_deterministic(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["simulate", str(a), "--n", "4", "--seed", "5", "--quiet"]) == 0
    assert main(["simulate", str(b), "--n", "4", "--seed", "5", "--quiet"]) == 0
    files = sorted(p.name for p in a.iterdir())
    assert files == [f"scene_{i:04d}.json" for i in range(4)]
    for name in files:
        assert (a / name).read_bytes() == (b / name).read_bytes()
    tiers = [load_scene(a / n).ground_truth.extra["tier"] for n in files]
    assert tiers == list(TIERS)  # --tier all cycles through the tiers
    assert main(["simulate", str(tmp_path / "c"), "--n", "2", "--tier", "high", "--quiet"]) == 0
    assert main(["simulate", str(tmp_path / "d"), "--n", "0", "--quiet"]) == 2
