"""The simulator against benchmark.md: ranges, tiers, formats, units, noise models, several
targets, determinism; ``creference simulate``."""

import json
import math
import warnings
from collections import Counter

import numpy as np
import pytest
from scipy import stats

from creference_bayes.bench.simulate import (FORMATS, OBJECTS, REAL_CAMERAS, SETTINGS, TIERS, NoiseTier, draw_camera,
                                             measurement_factor, simulate_scene, true_state, write_scenes)
from creference_bayes.cli.main import main
from creference_bayes.core.geometry import Camera, box_points, dimension_corners
from creference_bayes.core.metrics import range_precision
from creference_bayes.io.scene import load_scene, parse_scene
from creference_bayes.models.size_priors import KITTI_SIZE_PRIORS


def _scene(seed, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = simulate_scene(np.random.default_rng(seed), **kw)
        return d, parse_scene(d)


def test_same_seed_same_scene_and_different_seed_differs():
    a = simulate_scene(np.random.default_rng(7), tier="high", n_objects=3)
    b = simulate_scene(np.random.default_rng(7), tier="high", n_objects=3)
    c = simulate_scene(np.random.default_rng(8), tier="high", n_objects=3)
    assert json.dumps(a) == json.dumps(b) != json.dumps(c)
    assert a["format"] == "creference-scene/2"


@pytest.mark.parametrize("setting", ["indoor", "outdoor"])
def test_camera_and_distance_ranges(setting):
    cfg = SETTINGS[setting]
    for seed in range(15):
        d, scene = _scene(seed, setting=setting, tier="none")
        g, t = d["ground_truth"], d["targets"][0]["ground_truth"]
        x, y, z = t["location_m"]
        assert cfg["distance"][0] <= math.hypot(x, z) <= cfg["distance"][1]
        assert cfg["height"][0] <= g["camera_height_m"] <= cfg["height"][1]
        assert y == pytest.approx(g["camera_height_m"])  # the box stands on the ground
        assert math.radians(cfg["pitch_deg"][0]) <= g["pitch_rad"] <= math.radians(cfg["pitch_deg"][1])
        assert abs(g["roll_rad"]) <= math.radians(3.0) and 1000 <= g["focal_length_px"] <= 2600
        assert scene.image_size == (2880, 1800)
        np.testing.assert_allclose(scene.principal_point, [1440, 900])
        (target,) = scene.targets
        length, width, height = target.dimensions
        assert 0.024 <= length <= 4.64 and 0.06 <= width <= 5.25 and 0.24 <= height <= 3.83
        assert len(target.dimension_lines) == 13 and len(scene.references) == 5


@pytest.mark.parametrize("setting", ["indoor", "outdoor", "street"])
def test_real_cameras_have_their_kinds_image_focal_length_and_mounting(setting):
    full_frame_diagonal = math.hypot(36.0, 24.0)  # mm
    vehicles = {"KITTI", "nuScenes front", "Cityscapes"}
    kinds = Counter()
    for seed in range(12):
        d, scene = _scene(seed, setting=setting, tier="none", cameras="real", n_objects=2 if setting == "street" else 1,
                          sizes="prior" if setting == "street" else "known")
        g = d["ground_truth"]
        cam = REAL_CAMERAS[g["camera_kind"]]
        kinds[g["camera_kind"]] += 1
        assert setting in cam["share"]
        assert scene.image_size == tuple(cam["image"])
        if "focal_px" in cam:  # a named rig: its calibrated focal length and its own mounting
            assert g["focal_length_px"] == cam["focal_px"]
            assert cam["height"][0] <= g["camera_height_m"] <= cam["height"][1]
            assert math.radians(cam["pitch_deg"][0]) <= g["pitch_rad"] <= math.radians(cam["pitch_deg"][1])
        else:  # a 35 mm-equivalent range on its own image, the setting's mounting
            mm = g["focal_length_px"] * full_frame_diagonal / math.hypot(*cam["image"])
            assert cam["equiv_mm"][0] - 1e-9 <= mm <= cam["equiv_mm"][1] + 1e-9
            assert SETTINGS[setting]["height"][0] <= g["camera_height_m"] <= SETTINGS[setting]["height"][1]
        t = d["targets"][0]["ground_truth"]
        assert t["location_m"][2] > 0  # in front of the camera, inside its image
        assert np.all((np.array(t["corners_px"]) >= 0) & (np.array(t["corners_px"]) <= cam["image"]))
    if setting == "street":
        assert set(kinds) <= vehicles
    if setting == "indoor":
        assert not set(kinds) & vehicles


def test_a_real_camera_whose_view_no_target_fits_is_drawn_again():
    # with this seed the first camera is a phone's 5x telephoto (13422 px) pitched 9.3 deg down, whose
    # view holds no ground 15-60 m away: a photographer would have framed the subject another way
    d = simulate_scene(np.random.default_rng([19, 30]), setting="outdoor", tier="medium", cameras="real",
                       distance_range=(15.0, 60.0))
    x, _, z = d["targets"][0]["ground_truth"]["location_m"]
    assert 15.0 <= math.hypot(x, z) <= 60.0
    assert len(d["references"]) == 5


def test_real_cameras_are_drawn_by_their_shares():
    rng = np.random.default_rng(3)
    n = 3000
    for setting in ("indoor", "outdoor", "street"):
        got = Counter(draw_camera(rng, setting, "real")["kind"] for _ in range(n))
        share = {k: c["share"][setting] for k, c in REAL_CAMERAS.items() if setting in c["share"]}
        total = sum(share.values())
        for kind, w in share.items():
            p = w / total
            assert abs(got[kind] / n - p) < 4 * math.sqrt(p * (1 - p) / n), (setting, kind)


def test_coordinates_are_stored_to_two_decimals_by_default():
    d, _ = _scene(3, tier="low")
    pts = np.concatenate([np.ravel(a["corners"]) for a in d["targets"][0]["dimension_lines"]]
                         + [np.ravel(r["line"]) for r in d["references"]] + [np.ravel(d["horizon"])])
    np.testing.assert_allclose(pts, np.round(pts, 2), atol=1e-9)
    raw, _ = _scene(3, tier="low", decimals=None)
    assert np.abs(np.ravel(raw["horizon"]) - np.round(np.ravel(raw["horizon"]), 2)).max() > 1e-6


def test_noise_free_tier_is_exact():
    """Tier none: annotations are the true projections (through the horizon, an independent path);
    stated lengths are the true lengths (4 significant digits)."""
    for seed in range(6):
        d, scene = _scene(seed, tier="none", principal_offset=0.05, decimals=None)
        t, g = scene.targets[0], scene.ground_truth
        truth = t.ground_truth
        params = np.array([*truth["location_m"], truth["yaw_rad"]])
        uv, _ = Camera.from_scene(scene).project(box_points(params, dimension_corners(*t.dimensions, truth["handedness"])),
                                                 g["focal_length_px"])
        for ann in t.corners:
            np.testing.assert_allclose(ann, uv, atol=1e-6)
        for ref, true_len in zip(scene.references, g["reference_lengths_m"]):
            factor = t.dimensions[("length", "width").index(ref.measure)] if ref.mode == "relative" else 1.0
            centre = (ref.low + ref.high) / 2 if ref.is_range else ref.low
            assert centre * factor == pytest.approx(true_len, rel=2e-3)
        camera, objects = true_state(scene)
        assert camera[0] == g["focal_length_px"] and objects.shape == (1, 7) and objects[0, 6] == pytest.approx(0)


def test_paper_like_measurement_noise_matches_table_2():
    """benchmark.md: median absolute error 50–65 %, mean 100–250 % (paper Table 2)."""
    err = np.abs(measurement_factor(np.random.default_rng(0), "paper", 400_000) - 1) * 100
    assert 50 <= np.median(err) <= 65
    assert 100 <= err.mean() <= 250
    assert np.isfinite(err).all() and err.max() <= 1900 + 1e-9  # clipped at a factor 20


@pytest.mark.parametrize("model, sd", [("10%", 0.1), ("40%", 0.4)])
def test_lognormal_tiers(model, sd):
    log = np.log(measurement_factor(np.random.default_rng(1), model, 100_000))
    assert abs(log.mean()) < 5 * sd / np.sqrt(len(log))
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
    _, scene = _scene(3, tier="low")  # random formats are distinct within a scene
    assert len({(r.measure, r.mode, r.is_range) for r in scene.references}) == 5


@pytest.mark.parametrize("tier", [TIERS["low"], TIERS["high"], NoiseTier("t3", 5.0, 0.0, "none", dof=3.0)])
def test_tier_noise_levels(tier):
    """Target corners scatter with σ_t around the truth (a Student-t tier with heavier tails)."""
    dev = []
    for seed in range(8):
        d, scene = _scene(seed, tier=tier, n_objects=2)
        for t in scene.targets:
            dev.append(t.corners - np.asarray(t.ground_truth["corners_px"]))
    dev = np.concatenate(dev).ravel()
    assert np.std(dev) == pytest.approx(tier.target_px, rel=0.12)
    kurtosis = np.mean(dev**4) / np.var(dev) ** 2
    assert (kurtosis > 4.0) if tier.dof else (abs(kurtosis - 3.0) < 0.5)


def test_several_targets_on_a_street():
    """Street scenes: KITTI-like camera, several targets that do not overlap, sizes left to the
    shipped class priors, grounds off the plane, no horizon; c1 the bottom corner nearest the camera."""
    d, scene = _scene(4, setting="street", n_objects=8, sizes="prior", horizon="none", n_references=0,
                      n_target_annotations=5, tier="low")
    assert scene.image_size == (1242, 375) and scene.horizon is None and len(scene.targets) == 8
    assert all(t.dimensions is None and t.cls in KITTI_SIZE_PRIORS for t in scene.targets)
    ground = [t.ground_truth["ground_m"] for t in scene.targets]
    assert np.std(ground) > 0.01 and max(map(abs, ground)) < 0.5
    xz = np.array([[t.ground_truth["location_m"][0], t.ground_truth["location_m"][2]] for t in scene.targets])
    gaps = np.linalg.norm(xz[:, None] - xz[None], axis=-1) + np.eye(len(xz)) * 1e9
    assert gaps.min() > 0.6
    camera, objects = true_state(scene)
    for t, o in zip(scene.targets, objects):
        params = np.array([o[0], camera[3] - o[6], o[1], o[2]])
        c = box_points(params, dimension_corners(*o[3:6], t.ground_truth["handedness"]))[:3]
        assert np.linalg.norm(c[0, [0, 2]]) <= min(np.linalg.norm(c[1:, [0, 2]], axis=1)) + 1e-9


def test_sizes_left_to_the_scenes_own_classes_and_what_a_scene_states():
    d, scene = _scene(5, setting="indoor", n_objects=3, sizes="prior", tier="medium", horizon="sd",
                      focal_known=True)
    assert set(d["classes"]) == set(OBJECTS["indoor"]) and all(t.dimensions is None for t in scene.targets)
    assert all(scene.size_prior(t.cls) is not None for t in scene.targets)
    relative = [o for r, o in zip(scene.references, scene.reference_targets) if r.mode == "relative"]
    assert relative and set(relative) == {0}  # relative to the first target
    assert scene.horizon_sd_px == 5.0 and scene.focal_length_px == d["ground_truth"]["focal_length_px"]


def test_bad_arguments_name_the_problem():
    with pytest.raises(ValueError, match="tier: expected one of"):
        simulate_scene(0, tier="extreme")
    with pytest.raises(ValueError, match="setting"):
        simulate_scene(0, setting="space")
    with pytest.raises(ValueError, match="n_target_annotations"):
        simulate_scene(0, n_target_annotations=0)
    with pytest.raises(ValueError, match="sizes"):
        simulate_scene(0, sizes="guess")
    with pytest.raises(ValueError, match="cameras: expected one of.*'phones'"):
        simulate_scene(0, cameras="phones")


def test_simulate_command_is_deterministic(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["simulate", str(a), "--n", "4", "--seed", "5", "--quiet"]) == 0
    assert main(["simulate", str(b), "--n", "4", "--seed", "5", "--quiet"]) == 0
    files = sorted(p.name for p in a.iterdir())
    assert files == [f"scene_{i:04d}.json" for i in range(4)]
    for name in files:
        assert (a / name).read_bytes() == (b / name).read_bytes()
    tiers = [load_scene(a / n).ground_truth["tier"] for n in files]
    assert tiers == list(TIERS)  # --tier all cycles through the tiers
    assert main(["simulate", str(tmp_path / "c"), "--n", "2", "--tier", "high", "--quiet"]) == 0
    assert main(["simulate", str(tmp_path / "d"), "--n", "0", "--quiet"]) == 2
    assert main(["simulate", str(tmp_path / "e"), "--n", "1", "--objects", "4", "--setting", "street", "--sizes", "prior",
                 "--horizon", "none", "--references", "0", "--annotations", "3", "--noise-px", "1", "--quiet"]) == 0
    scene = load_scene(tmp_path / "e" / "scene_0000.json")
    assert len(scene.targets) == 4 and scene.horizon is None and not scene.references
    assert all(len(t.dimension_lines) == 3 and t.dimensions is None for t in scene.targets)
    assert main(["simulate", "--from-kitti", str(tmp_path), "--out", str(tmp_path / "k"), "--objects", "5"]) == 2
    assert main(["simulate", "--from-kitti", str(tmp_path), "--out", str(tmp_path / "k"), "--cameras", "real"]) == 2
    assert main(["simulate", str(tmp_path / "r"), "--n", "3", "--cameras", "real", "--setting", "street", "--objects", "2",
                 "--sizes", "prior", "--quiet"]) == 0
    for name in sorted(p.name for p in (tmp_path / "r").iterdir()):
        g = load_scene(tmp_path / "r" / name).ground_truth
        assert g["focal_length_px"] == REAL_CAMERAS[g["camera_kind"]]["focal_px"]


def test_write_scenes_replaces_the_corner_noise(tmp_path):
    paths = write_scenes(tmp_path / "s", 2, seed=1, tier="high", noise_px=0.0, n_references=1)
    scene = load_scene(paths[0])
    t = scene.targets[0]
    np.testing.assert_allclose(t.corners, np.broadcast_to(t.ground_truth["corners_px"], t.corners.shape), atol=0.006)
    with pytest.raises(FileExistsError):
        write_scenes(tmp_path / "s", 1)


@pytest.mark.parametrize("crowd", ["light", "heavy"])
def test_the_crowds_draw_their_reference_segments_and_values_with_noise(crowd):
    """The crowds of issue 66: reference end points off by their σ around the true segment, direct
    values off by a log-normal of their log-sd, the heavy crowd's with 12 % outliers (a factor
    log-uniform within ±10); restricted to the relative formats, only those."""
    from creference_bayes.bench.simulate import CROWDS, OUTLIER_FACTOR
    from creference_bayes.core.units import UNITS_TO_M

    tier = CROWDS[crowd]
    ends, log_err = [], []
    for seed in range(30):
        d = simulate_scene(np.random.default_rng([7, seed]), tier=crowd, n_references=20, single_values=True)
        g = d["ground_truth"]
        for r, true_line, length in zip(d["references"], g["reference_lines_px"], g["reference_lengths_m"]):
            line = np.asarray(r["line"])
            if np.all((line > 1) & (line < [d["image"]["width"] - 1, d["image"]["height"] - 1])):  # not clipped
                ends.append(line - np.asarray(true_line))
            if r["mode"] == "direct":
                log_err.append(np.log(r["value"] * UNITS_TO_M[r["unit"]] / length))
    assert np.std(np.concatenate(ends)) == pytest.approx(tier.reference_px, rel=0.1)
    log_err, sd = np.array(log_err), float(tier.measurement[:-1]) / 100
    beyond = 1.2  # in log: a factor 3.3, out of reach of the light crowd
    want = tier.outliers * (1 - beyond / np.log(OUTLIER_FACTOR)) + (1 - tier.outliers) * 2 * stats.norm.sf(beyond / sd)
    assert np.mean(np.abs(log_err) > beyond) == pytest.approx(want, abs=0.035)
    assert stats.median_abs_deviation(log_err, scale="normal") == pytest.approx(sd, rel=0.2)
    relative = [i for i, (_, mode, _) in enumerate(FORMATS) if mode == "relative"]
    d = simulate_scene(np.random.default_rng(1), tier=crowd, n_references=8, formats=relative)
    assert {r["mode"] for r in d["references"]} == {"relative"}
    with pytest.raises(ValueError, match="formats"):
        simulate_scene(np.random.default_rng(1), tier=crowd, formats=(10,))
