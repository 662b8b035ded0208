"""Simulation-based calibration (bench/sbc.py, ``creference bench --sbc``): the rank statistic
passes a calibrated posterior and fails an over-confident one; the bench's SBC runs end to end."""

import json

import numpy as np
import pytest

from creference_bayes.bench.sbc import (N_RANK_DRAWS, REF_ROWS_PX, SBC_BOX, TARGET_SCALE_PX, draw_truth, rank_of_truth,
                                        rank_uniformity, run_sbc, sbc_reference, sbc_summary, simulate_sbc_scene)
from creference_bayes.cli.main import main
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.contract import C_SCALE, REF_SCALE_LOG_SD, REF_SCALE_MEDIAN


def _normal_ranks(n_scenes: int, temperature: float, seed: int) -> list[int]:
    """Ranks of θ in a conjugate normal model, θ ~ N(0, 1), y ~ N(θ, 1): the exact posterior is
    N(y/2, 1/2); a temperature T scales its variance by T."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_scenes):
        theta = rng.normal()
        y = rng.normal(theta, 1.0)
        draws = rng.normal(y / 2, np.sqrt(0.5 * temperature), (4, 250))
        out.append(rank_of_truth(draws, theta))
    return out


def test_rank_statistic_passes_the_exact_posterior():
    u = rank_uniformity(_normal_ranks(200, 1.0, seed=1))
    assert u["n"] == 200 and sum(u["counts"]) == 200
    assert u["chi2_p"] > 0.01 and u["ks_p"] > 0.01


@pytest.mark.parametrize("temperature", [0.3, 3.0])
def test_rank_statistic_fails_a_miscalibrated_posterior(temperature):
    """Too narrow (T = 0.3: ranks piled at both ends) or too wide (T = 3: in the middle)."""
    u = rank_uniformity(_normal_ranks(200, temperature, seed=1))
    assert u["chi2_p"] < 0.01
    counts = np.asarray(u["counts"])
    ends = counts[[0, -1]].sum() / counts.sum()
    assert (ends > 0.4) if temperature < 1 else (ends < 0.15)


def test_truths_are_in_the_box_and_scenes_parse():
    rng = np.random.default_rng(3)
    b = SBC_BOX.bounds()
    for _ in range(20):
        camera, obj = draw_truth(rng)
        assert np.all((camera >= b.camera_lower) & (camera <= b.camera_upper))
        assert b.object_lower[0] <= obj[0] <= b.object_upper[0] and b.object_lower[1] <= obj[1] <= b.object_upper[1]
    d = None
    while d is None:
        d = simulate_sbc_scene(rng, draw_truth(rng), 5, 2)
    scene = parse_scene(d)
    assert len(scene.targets[0].dimension_lines) == 5 and len(scene.references) == 2
    assert scene.horizon is None and scene.focal_length_px is None and d["format"] == "creference-scene/2"


def test_the_crowd_scale_comes_from_its_continuous_prior():
    """The model's ref_scale is a parameter with a log-normal prior: the simulator draws it from
    that prior (within the model's bounds), not from a grid."""
    rng = np.random.default_rng(4)
    scales = np.array([draw_truth(rng)[0][C_SCALE] for _ in range(3000)])
    b = SBC_BOX.bounds()
    assert np.all((scales >= b.camera_lower[C_SCALE]) & (scales <= b.camera_upper[C_SCALE]))
    assert len(np.unique(scales)) == len(scales)
    from scipy import stats

    z = lambda v: np.log(v / REF_SCALE_MEDIAN) / REF_SCALE_LOG_SD  # noqa: E731
    prior = stats.truncnorm(z(b.camera_lower[C_SCALE]), z(b.camera_upper[C_SCALE]))
    assert stats.kstest(z(scales), prior.cdf).pvalue > 0.01


def test_a_second_worker_measures_the_same_segment_with_the_models_noise():
    """The scene records each reference's true line; ``sbc_reference`` on it is another worker's
    reading: the drawn line is the true one off by N(0, (2σ)²) px per coordinate, the stated
    length the ground's real length under the true line times exp(s·ε), ε ~ t₂ (quartiles ±0.816 s);
    the true line is placed in the image, not by the camera."""
    from creference_bayes.core.geometry import rotation_from_pitch_roll
    from creference_bayes.models.metrology import ground_lengths

    rng = np.random.default_rng(5)
    d = None
    while d is None:
        truth = draw_truth(rng)
        d = simulate_sbc_scene(rng, truth, 1, 1)
    camera = truth[0]
    true_line = np.asarray(d["ground_truth"]["reference_lines_true_px"][0])
    assert true_line.shape == (2, 2) and REF_ROWS_PX[0] <= true_line[0, 1] <= REF_ROWS_PX[1]
    assert d["ground_truth"]["crowd_scale"] == camera[C_SCALE]
    length = ground_lengths(true_line[None], np.array([1440.0, 900.0]), camera[None])[0, 0]
    R = rotation_from_pitch_roll(camera[1], camera[2])  # by hand: the rays meet the ground h below
    ends = []
    for u, v in true_line:
        ray = R.T @ np.array([(u - 1440.0) / camera[0], (v - 900.0) / camera[0], 1.0])
        ends.append(ray * camera[3] / ray[1])
    assert length == pytest.approx(np.linalg.norm(ends[1] - ends[0]), rel=1e-9)
    s = 0.4
    reads = [r for r in (sbc_reference(rng, truth, true_line, s, "w") for _ in range(4000)) if r is not None]
    assert len(reads) > 1000
    offs = np.array([np.asarray(r["line"]) - true_line for r in reads]).reshape(-1)
    assert abs(offs.mean()) < 0.3 and offs.std() == pytest.approx(2 * TARGET_SCALE_PX, rel=0.05)
    err = np.log([r["value"] / length for r in reads])
    q1, q2, q3 = np.percentile(err, [25, 50, 75])
    assert abs(q2) < 0.03 and (q3 - q1) / 2 == pytest.approx(0.8165 * s, rel=0.08)
    assert {r["unit"] for r in reads} == {"m"} and {r["measure"] for r in reads} == {"length"}


def test_where_the_reference_lines_fall_says_nothing_about_the_camera():
    """The true lines of the references are drawn in the image whatever the parameters: two
    cameras pitched 0° and 20° down get the same lines from the same random numbers."""
    obj = np.array([0.0, 20.0, 0.3, 4.0, 1.8, 1.5, 0.0])
    lines = []
    for pitch in (0.0, np.radians(20.0)):
        d = None
        rng = np.random.default_rng(8)
        while d is None:
            d = simulate_sbc_scene(rng, (np.array([2000.0, pitch, 0.0, 1.6, 0.5]), obj), 1, 3)
        lines.append(np.asarray(d["ground_truth"]["reference_lines_true_px"]))
    assert lines[0].shape == (3, 2, 2) and np.array_equal(lines[0], lines[1])


def test_ranks_count_the_draws_below():
    draws = np.arange(400.0).reshape(4, 100)
    assert rank_of_truth(draws, -1.0) == 0
    assert rank_of_truth(draws, 1e9) == N_RANK_DRAWS
    assert 15 <= rank_of_truth(draws, 200.0) <= 24


def test_bench_sbc_runs_on_a_tiny_budget(tmp_path):
    out = tmp_path / "sbc"
    assert main(["bench", "--sbc", "--sbc-scenes", "1", "--out", str(out), "--quiet", "--seed", "2"]) == 0
    doc = json.loads((out / "sbc.json").read_text())
    assert set(doc["summary"]) == {"thin", "full"}
    for rec in doc["records"]:
        assert set(rec["ranks"]) == {"distance_m", "focal_length_px", "pitch", "roll"}
        assert all(0 <= r <= N_RANK_DRAWS for r in rec["ranks"].values())
    assert (out / "sbc_ranks.png").stat().st_size > 0 and "χ² p" in (out / "sbc.md").read_text()


def test_bench_sbc_rejects_bad_options(tmp_path):
    assert main(["bench", "--sbc", "--sbc-scenes", "0", "--out", str(tmp_path / "x"), "--quiet"]) == 2


@pytest.mark.slow
def test_sbc_catches_an_over_confident_pipeline():
    """The whole pipeline at T = 0.2 on full designs: the ranks pile at both ends. (The tempered
    likelihood narrows the camera's posterior most; the distance's is held wide by the untempered
    focal prior along the depth–focal ridge, so its ranks alone are a weaker signal on 30 scenes.)"""
    recs = run_sbc(30, designs=("full",), seed=5, temperature=0.2, sampling={"min_ess": 200})
    q = sbc_summary(recs)["full"]["quantities"]
    assert min(u["chi2_p"] for u in q.values()) < 0.01
    counts = np.sum([u["counts"] for u in q.values()], axis=0)
    assert counts[[0, -1]].sum() / counts.sum() > 0.4  # a calibrated posterior puts a quarter there


def test_a_map_on_the_box_bound_is_still_sampled():
    """A MAP on the box's bound is sampled (it used to start at −∞ after the round trip through the
    sampler's coordinates: "posterior not sampled"). The bound is put on the MAP by construction:
    the true pitch is 8°, well identified by five sets of lines and five references, and the box
    stops pitch at 3°, so the constrained optimum lies on that bound whatever the optimiser's
    version (where exactly an unconstrained optimiser stops is not what this test is about)."""
    import warnings

    from creference_bayes.bench.sbc import DESIGNS
    from creference_bayes.models.contract import C_PITCH, Bounds
    from creference_bayes.pipeline import estimate

    rng = np.random.default_rng([0, list(DESIGNS).index("full"), 27])
    d = None
    while d is None:
        camera, obj = draw_truth(rng)
        camera[C_PITCH] = np.radians(8.0)
        d = simulate_sbc_scene(rng, (camera, obj), 5, 5)
    box = SBC_BOX.bounds()
    upper = box.camera_upper.copy()
    upper[C_PITCH] = np.radians(3.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = estimate(d, seed=[0, 27], bounds=Bounds(box.camera_lower, upper, box.object_lower, box.object_upper),
                     sampling={"min_ess": 100}).to_dict()
    assert r["camera"]["map"]["pitch"] == pytest.approx(upper[C_PITCH], abs=1e-4)  # on the bound (or a hair
    # inside: the search before sampling may polish it)
    assert "posterior" in r["camera"], r["warnings"]
    assert r["camera"]["posterior"]["hdi"]["pitch"][1] <= upper[C_PITCH] + 1e-6  # the file keeps 6 decimals


def test_a_target_whose_start_is_on_the_box_bound_still_gets_a_map():
    """A scene of the calibration box whose target stands near its x bound: every start placed the
    target on the bound, where the working coordinates' round trip left the box (zero density) and
    no start was refined. The MAP is found, inside the box, and at least as good as the truth."""
    from creference_bayes.bench.sbc import DESIGNS
    from creference_bayes.pipeline import estimate, map_state

    rng = np.random.default_rng([0, list(DESIGNS).index("full"), 58])
    d = None
    while d is None:
        camera, obj = draw_truth(rng, SBC_BOX)
        d = simulate_sbc_scene(rng, (camera, obj), *DESIGNS["full"][:1], DESIGNS["full"][1][58 % len(DESIGNS["full"][1])])
    assert abs(obj[0] - SBC_BOX.bounds().object_lower[0]) < 0.25  # the case: the truth by the bound
    res = estimate(d, seed=[0, 58], bounds=SBC_BOX.bounds(), location_prior="log-depth", focal_prior="default",
                   posterior=False)
    cam, objs = map_state(res.to_dict())
    model = res.model
    assert np.all(objs[0, :2] >= model.object_lower[:2]) and np.all(objs[0, :2] <= model.object_upper[:2])
    at_map = float(model.map_objective(cam[None], objs[None], 1.0)[0])
    at_truth = []
    for h in (1.0, -1.0):
        model.handedness = np.array([h])
        at_truth.append(float(model.map_objective(np.asarray(camera)[None], np.asarray(obj)[None, None], 1.0)[0]))
    assert np.isfinite(at_map) and at_map <= min(at_truth) + 1e-6
