"""``creference bench --quick``: every estimator appears, the noise-free tier is solved, the tables,
JSON and figures are written (the run takes about a minute on one core); scenes of several targets
go through the same runner."""

import json
from collections import Counter

import numpy as np
import pytest

from creference_bayes.bench.runner import CONFIGS, BenchConfig, bench_scenes, calibration_of, run_bench
from creference_bayes.cli.main import main
from creference_bayes.pipeline import EstimateSettings, estimate


PAPER_RESTARTS = 2


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    # --paper-restarts: the paper's basin hopping is a fifth of the run at the quick default (8)
    assert main(["bench", "--quick", "--paper-restarts", str(PAPER_RESTARTS), "--out", str(out), "--quiet"]) == 0
    return out, json.loads((out / "bench.json").read_text())


@pytest.mark.slow  # the quick bench run (about 2 CPU-minutes)
def test_every_estimator_appears(quick):
    _, doc = quick
    recs = doc["records"]
    names = {r["estimator"] for r in recs}
    every_scene = ("paper", "p4pf", "ours-paper", "ours-metrology", "crb-target", "crb-refs",
                   "ours-metrology-nohorizon", "ours-metrology-flatfocal", "crb-target-nohorizon",
                   "crb-refs-nohorizon")
    assert set(every_scene) | {"exact-metrology"} <= names
    scenes = {r["scene"] for r in recs if r["estimator"] != "exact-metrology"}
    for name in every_scene:
        assert {r["scene"] for r in recs if r["estimator"] == name} == scenes, name
    exact = [r for r in recs if r["estimator"] == "exact-metrology"]
    assert {r["n_refs"] for r in exact} == {0, 20} and all(r["error"] < 0.1 for r in exact)
    for model in ("paper", "metrology"):  # MAP with 0 and 5 references, and a posterior
        rows = [r for r in recs if r["estimator"] == f"ours-{model}"]
        assert {r["n_refs"] for r in rows} >= {0, 5}
        assert any("coverage" in r and "post_error" in r for r in rows)
    assert {r["tier"] for r in recs} == {"none", "low", "medium", "high"}
    assert {r["setting"] for r in recs} == {"indoor", "outdoor"}
    crb = {(r["scene"], r["estimator"]): r["error"] for r in recs if r["estimator"].startswith("crb-refs")}
    for sid in scenes:  # unknown pitch and roll can only cost information
        assert crb[(sid, "crb-refs-nohorizon")] >= crb[(sid, "crb-refs")] - 1e-9
    paper = [r for r in recs if r["estimator"] == "paper"]
    assert paper and all(r["restarts"] == PAPER_RESTARTS for r in paper)


def test_real_cameras_reach_the_bench_scenes_and_their_noise_free_scenes_are_solved(tmp_path):
    from dataclasses import replace

    from creference_bayes.bench.simulate import REAL_CAMERAS

    scenes = bench_scenes(replace(CONFIGS["quick"], cameras="real"))
    assert len(scenes) == len(bench_scenes(CONFIGS["quick"]))
    kinds = {s.ground_truth["camera_kind"] for _, s in scenes}
    assert kinds and kinds <= set(REAL_CAMERAS)
    assert all(s.image_size == tuple(REAL_CAMERAS[s.ground_truth["camera_kind"]]["image"]) for _, s in scenes)
    none = [s for sid, s in scenes if s.ground_truth["tier"] == "none"]
    assert none
    for scene in none:  # exact annotations (stored to 0.01 px) on a real camera's image
        r = estimate(scene, seed=0).to_dict()
        assert r["objects"][0]["evaluation"]["location_pct_error"] < 0.5, scene.ground_truth["camera_kind"]
    assert main(["bench", "--sbc", "--cameras", "real", "--out", str(tmp_path / "x"), "--quiet"]) == 2


@pytest.mark.slow  # the quick bench run (about 2 CPU-minutes)
def test_noise_free_tier_is_solved(quick):
    _, doc = quick
    default_model = EstimateSettings().model
    none = [r for r in doc["records"] if r["tier"] == "none"]
    ours = [r for r in none if r["estimator"] == f"ours-{default_model}" and r["n_target"] == 5]
    assert ours and all(r["error"] < 0.5 for r in ours)  # the package's default estimator
    # coordinates are stored to 0.01 px, which alone moves far targets by up to a few 0.1 %
    assert all(r["error"] < 0.5 for r in none if r["estimator"] == "p4pf")
    assert all(r["error"] == 0.0 for r in none if r["estimator"].startswith("crb"))


@pytest.mark.slow  # the quick bench run (about 2 CPU-minutes)
def test_noisy_tiers_are_bounded_below_by_the_crb(quick):
    """The bound is positive with noise and grows with the tier's noise."""
    _, doc = quick
    crb = {}
    for r in doc["records"]:
        if r["estimator"] == "crb-target":
            crb.setdefault(r["tier"], []).append(r["error"])
    assert all(v > 0 for t in ("low", "medium", "high") for v in crb[t])
    assert np.median(crb["low"]) < np.median(crb["high"])


@pytest.mark.slow  # the quick bench run (about 2 CPU-minutes)
def test_tables_and_figures_are_written(quick):
    out, doc = quick
    md = (out / "bench.md").read_text()
    for heading in ("Location error", "Cramér–Rao", "Error against the number of references",
                    "Same human time", "Calibration", "Time per target", "REDUCED"):
        assert heading in md
    assert "1835.0 s" in md and "1239.5 s" in md  # 10 × 183.5 s against 5 × 183.5 + 5 × 64.4 s
    s = doc["summary"]
    assert s["timing"]["paper"]["ratio"] == 1.0
    for name in ("p4pf", "ours-paper MAP", "ours-metrology MAP + posterior"):
        assert s["timing"][name]["ratio"] > 0
    for model, c in s["calibration"].items():
        n_post = sum(1 for r in doc["records"]
                     if r["estimator"] == f"ours-{model}" and "coverage" in r and r["tier"] != "none")
        assert sum(c["ranks"]["distance_m"]) == n_post > 0  # pooled over the noisy tiers
        assert all(0 <= v[k] <= 1 for v in c["all"].values() for k in ("50", "90"))
    for name in ("bench_error_by_tier", "bench_error_vs_refs", "bench_same_time", "bench_calibration",
                 "bench_timing"):
        data = (out / f"{name}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert doc["seed"] == 0 and doc["format"] == "creference-bench/1"


def test_scenes_are_deterministic_and_cover_the_formats_equally():
    a = bench_scenes(CONFIGS["quick"], seed=3)
    b = bench_scenes(CONFIGS["quick"], seed=3)
    assert [s.targets[0].corners.tolist() for _, s in a] == [s.targets[0].corners.tolist() for _, s in b]
    full = bench_scenes(CONFIGS["full"], seed=0)
    counts = Counter((r.measure, r.mode, r.is_range) for _, s in full for r in s.references)
    assert len(counts) == 10 and len(set(counts.values())) == 1


def test_calibration_of_known_draws():
    """A true value at the 30 % quantile of N(0, 1) draws is inside the 50 % and 90 % HDIs with
    rank 0.3; one at the 99 % quantile is outside both."""
    draws = {"x": np.random.default_rng(0).normal(size=200_000)}
    cover, ranks = calibration_of(draws, {"x": -0.5244})
    assert cover["x"] == {"50": True, "90": True} and ranks["x"] == pytest.approx(0.3, abs=0.005)
    cover, ranks = calibration_of(draws, {"x": 2.326})
    assert cover["x"] == {"50": False, "90": False} and ranks["x"] == pytest.approx(0.99, abs=0.002)
    cover, _ = calibration_of(draws, {"x": 1.0})  # between the 50 % (±0.674) and 90 % (±1.645) ends
    assert cover["x"] == {"50": False, "90": True}


@pytest.mark.slow  # the quick bench run (about 2 CPU-minutes)
def test_the_error_by_tier_figure_has_few_distinct_series_per_panel(quick):
    from matplotlib.colors import to_hex

    from creference_bayes.bench.figures import error_by_tier

    fig = error_by_tier(quick[1])
    assert len(fig.axes) == 2
    for ax in fig.axes:
        handles, labels = ax.get_legend_handles_labels()
        assert 2 <= len(labels) <= 8, labels
        looks = {(to_hex(h.get_color()), h.get_marker(), str(h.get_markerfacecolor())) for h in handles}
        assert len(looks) == len(labels), labels  # no two series drawn alike


def test_scenes_of_several_targets_go_through_the_same_runner():
    """The frames size of the bench: every object of a street scene estimated jointly and alone,
    beside the scene's bound, in one record each; the tables by distance band and object count."""
    from creference_bayes.bench.report import markdown_report

    config = BenchConfig(name="tiny-frames", frame_counts=(2,), frames_per_count=1, frame_tiers=("low",),
                         sampler={"min_ess": 50, "max_steps": 600}, camera_studies=False)
    doc = run_bench(config, seed=1)
    recs = doc["records"]
    assert len(recs) == 2 and {r["estimator"] for r in recs} == {"frame"} and {r["n_objects"] for r in recs} == {2}
    for r in recs:
        assert r["error"] >= 0 and r["alone_error"] >= 0 and 0 < r["crb"] < 100 and r["distance_m"] > 0
        assert r["post_error"] is not None and isinstance(r["in_hdi90"], bool)
    f = doc["summary"]["frames"]
    assert sum(b["objects"] for b in f["bands"]) == 2 and f["counts"][0]["scenes"] == 1
    md = markdown_report(doc)
    assert "joint MAP median %" in md and "objects per scene" in md and "Location error (paper" not in md


def test_the_frames_coverage_states_its_interval_over_scenes_not_objects():
    """The objects of a scene share its camera, so a band's coverage counts scenes: 9 of 10 objects
    covered in 2 scenes says little, 9 of 10 scenes of one object each say more (Clopper–Pearson
    9 of 10: 0.555–0.997), and 12 scenes with every object covered still leave room below 100 %
    (0.025^(1/12) = 0.735), where a bootstrap would say 100–100."""
    from creference_bayes.bench.report import _frames, markdown_report

    def rec(scene, covered, n):
        return {"estimator": "frame", "scene": scene, "tier": "low", "n_objects": n, "distance_m": 25.0,
                "error": 3.0, "post_error": 3.0, "alone_error": 9.0, "crb": 4.0, "in_hdi90": covered,
                "seconds": 0.1, "post_seconds": 1.0, "converged": True}

    two = [rec("a", True, 9) for _ in range(9)] + [rec("b", False, 1)]
    ten = [rec(f"s{k}", k > 0, 1) for k in range(10)]
    every = [rec(f"s{k}", True, 3) for k in range(12) for _ in range(3)]
    (band_two,) = _frames({"records": two})["bands"]
    (band_ten,) = _frames({"records": ten})["bands"]
    (band_every,) = _frames({"records": every})["bands"]
    assert band_two["coverage_90"] == band_ten["coverage_90"] == 0.9 and band_every["coverage_90"] == 1.0
    assert band_ten["coverage_90_interval"] == pytest.approx([0.555, 0.997], abs=0.001)
    lo2, hi2 = band_two["coverage_90_interval"]
    assert lo2 < 0.2 and hi2 > 0.999  # two scenes: hardly anything
    assert band_every["coverage_90_interval"] == pytest.approx([0.735, 1.0], abs=0.001)
    doc = {"records": every, "summary": {"frames": _frames({"records": every})}, "config": {"name": "t"}, "seed": 0,
           "version": "x", "seconds": 1.0}
    assert "| 100% (74–100) |" in markdown_report(doc)
