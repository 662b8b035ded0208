"""Every example script takes --help (and writes nothing then), and every one runs to the end on
a tiny budget: the scripts are run, not only parsed, so an API change that breaks one fails here."""

import json
import os
import runpy
import subprocess
import sys
import time
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))

#: A tiny run of each example: its arguments, and files (relative to its working folder) it must
#: write. Each one runs in a few seconds; each is a test of its own (the workers share them out).
TINY = {
    "advice_study.py": [(["predict", "--n", "1", "--min-ess", "100", "--focal-prior", "1650,0.27", "--cameras", "real",
                          "--out", "as"],
                         ["as/predict.jsonl"]),
                        (["predict", "--n", "1", "--min-ess", "100", "--dataset", "auto", "--declare-setting", "--out", "asd"],
                         ["asd/predict.jsonl", "asd/dataset/in/s0000.json"]),
                        (["own", "--n", "1", "--min-ess", "100", "--out", "as"], ["as/own.jsonl"]),
                        (["timing", "--n", "1", "--min-ess", "100", "--out", "as"], ["as/timing.jsonl"]),
                        (["report", "--out", "as"], ["as/advice_study.md"])],
    "advice_plans.py": [([str(Path(__file__).resolve().parents[1] / "creference_bayes" / "data" / "example_scene.json"),
                          "--out", "ap"], ["ap/example_scene.result.json", "ap/example_scene_0.json"])],
    "advice_says_nothing.py": [(["--posteriors", "1", "--seeds", "3", "--futures", "20", "30", "--min-ess", "100"], [])],
    "aggregation_study.py": [(["--draws", "50", "--out-dir", "agg"], ["agg/aggregation_study.png",
                                                                      "agg/aggregation_study.md"])],
    "batch_throughput.py": [(["--n", "2", "--engines", "local2", "--min-ess", "100", "--out", "bt"],
                             ["bt/local_2/summary.csv"])],
    "check_sampler.py": [(["--seeds", "1", "--steps", "400", "--min-ess", "200"], []),
                         (["--objects", "3", "--distances", "2", "--seeds", "1", "--steps", "1000", "--min-ess", "200"],
                          []),
                         (["--objects", "2", "--sizes", "known", "--vague", "1", "--seeds", "1", "--steps", "400",
                           "--min-ess", "100"], [])],
    "confidence_study.py": [(["--quick", "--parts", "a", "--n-a", "10", "--replicates", "2", "--out", "cs"],
                             ["cs/confidence_study.md"])],
    "dataset_pipeline.py": [(["--n", "2", "--workers", "1", "--min-ess", "100", "--out", "dp"],
                             ["dp/labels/report.md"])],
    "estimate_scene.py": [([], [])],
    "tree_cpu.py": [([sys.executable, "-c", "print('ran')"], [])],
    "speed_by_objects.py": [(["--counts", "3", "--scenes", "1", "--max-steps", "400"], [])],
    "serve_speed.py": [(["--targets", "1", "--repeats", "1"], [])],
    "fallback_accuracy.py": [(["--sweeps", "0", "2", "--seeds", "1", "--futures", "2", "--min-ess", "100", "--targets", "3"],
                              [])],
    "frame_steps.py": [([str(Path(__file__).resolve().parents[1] / "creference_bayes" / "data" / "example_scene.json"),
                         str(Path(__file__).resolve().parents[1] / "creference_bayes" / "data" / "cvat_labels.json"),
                         "--sampling", '{"min_ess": 100}', "--out", "fs.jsonl"], ["fs.jsonl"])],
    "frame_calibration.py": [(["--frames", "1", "--counts", "3", "--tiers", "low", "--min-ess", "100", "--out", "fc"],
                              ["fc/frames.jsonl", "fc/frames.md"]),
                             (["--frames", "1", "--counts", "2", "--tiers", "low", "--sizes", "known", "--min-ess", "100",
                               "--out", "fcs"], ["fcs/frames.md"])],
    "horizon_study.py": [(["--n", "1", "--min-ess", "100"], [])],
    "label_reliability.py": [(["--n", "2", "--workers", "1", "--min-ess", "100", "--out", "lr"],
                              ["lr/labels/report.md"])],
    "line_noise_bias.py": [(["--n", "2", "--draws", "200", "--estimates", "1", "--focal-prior", "1650,0.27"], [])],
    "map_speed.py": [(["--n", "1", "--kinds", "light", "--repeat", "1", "--out", "ms.json"], ["ms.json"]),
                     (["--n", "1", "--kinds", "light", "--repeat", "1", "--compare", "ms.json"], [])],
    "measure_presets.py": [(["--n", "2"], [])],
    "pilot_dependence.py": [(["--scenes", "0", "--n", "1", "--min-ess", "100", "--out", "pd"],
                             ["pd/dataset/in/s0000.json"])],
    "posterior_example.py": [(["--out", "pe", "--min-ess", "200"], ["pe/result.json", "pe/top_view.png"])],
    "profile_posterior.py": [(["--repeat", "1"], [])],
    "reference_reading_study.py": [(["--n", "1", "--crowds", "light", "--min-ess", "100", "--out", "rr"],
                                    ["rr/records.jsonl", "rr/table.md"]),
                                   (["--bench", "--n", "1", "--min-ess", "100", "--out", "rr"], ["rr/bench.jsonl"]),
                                   (["--n", "2", "--crowds", "light", "--readings", "tail", "--min-ess", "100",
                                     "--out", "rt"], ["rt/records.jsonl", "rt/tails_light_mixed_2.json"]),
                                   (["--monte-carlo"], []),
                                   (["--populations", "light", "--n", "1"], [])],
    "scale_spread_power.py": [(["--trials", "3"], [])],
    "thin_designs.py": [(["--n", "1", "--min-ess", "100", "--out", "td"], ["td/thin.jsonl", "td/thin.md"]),
                        (["--n", "2", "--min-ess", "100", "--refs", "0", "--mixed", "--dataset", "none", "--declare-setting",
                          "--out", "tdb"],
                         ["tdb/thin.jsonl", "tdb/refs0/batch/results/k0001.json"]),
                        (["--n", "1", "--min-ess", "100", "--out", "tr", "--cameras", "real", "--distance-range", "10,80"],
                         ["tr/thin.md"])],
}
#: Longer runs of the parts the tiny runs leave out (marked slow).
SLOW = {
    "confidence_study.py": [(["--quick", "--quick-b", "--n-a", "10", "--n-b", "4", "--n-c", "1",
                              "--replicates", "2", "--out", "cs"], ["cs/confidence_study.md"])],
    "batch_throughput.py": [(["--n", "2", "--min-ess", "100", "--out", "bt"], ["bt/dask_2/summary.csv"])],
    "serve_speed.py": [(["--jobs", "--targets", "1", "--min-ess", "50", "--advice-draws", "50", "--advice-futures",
                         "10"], [])],
}
#: Examples that need tools outside the package: run by the tests named, when the tools are there.
EXTERNAL = {"check_real_tools.py": "tests/test_real_tools.py (CREFERENCE_LABEL_STUDIO_VENV, CREFERENCE_DATUMARO_VENV)",
            "check_kitti_devkit.py": "tests/test_kitti_devkit.py (slow; the compiled official devkit)",
            # a KITTI folder is needed: the tests build a synthetic one in KITTI's layout
            "kitti_study.py": "tests/test_kitti_frames.py",
            "kitti_advice_study.py": "tests/test_kitti_advice_study.py",
            "kitti_ground.py": "tests/test_kitti_frames.py",
            "horizon_kitti_check.py": "tests/test_horizon.py",
            "kitti_one_car.py": "tests/test_horizon.py",
            # a rig batch's first pass is needed: the test makes one
            "rig_pool.py": "tests/test_rig.py",
            "dataset_pool.py": "tests/test_dataset.py",
            "focal_floor.py": "tests/test_dataset.py",
            "distance_population.py": "tests/test_dataset.py",
            # scene files with ground truth are needed: the test simulates one
            "advice_speed.py": "tests/test_examples.py::test_advice_speed_times_a_simulated_scene",
            # a folder of frames of several targets: the test simulates one
            "handedness_frames.py": "tests/test_modes.py::test_the_handedness_study_reads_a_folder_of_frames"}


def test_there_are_examples():
    assert len(EXAMPLES) >= 5


def test_every_example_has_a_tiny_run():
    names = {p.name for p in EXAMPLES}
    assert names == set(TINY) | set(EXTERNAL), names ^ (set(TINY) | set(EXTERNAL))


def test_every_example_takes_help_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.syspath_prepend(str(EXAMPLES[0].parent))  # as a script sees its folder
    for script in EXAMPLES:  # in this process: a subprocess each would pay the imports again
        cwd = tmp_path / script.stem
        cwd.mkdir()
        monkeypatch.chdir(cwd)
        monkeypatch.setattr(sys, "argv", [str(script), "--help"])
        with pytest.raises(SystemExit) as exit_:
            runpy.run_path(str(script), run_name="__main__")
        out, err = capsys.readouterr()
        assert exit_.value.code in (0, None), f"{script.name}: {err}"
        assert out.startswith("usage:"), script.name
        assert err == "", script.name
        assert list(cwd.iterdir()) == [], f"{script.name} --help wrote files"


def test_no_example_writes_into_docs_by_default():
    for script in EXAMPLES:
        text = script.read_text()
        assert 'default="docs' not in text and "default='docs" not in text, script.name


def _run_all(runs: dict, tmp_path: Path, parallel: int = 2) -> None:
    """Run each script's steps in order, ``parallel`` scripts at a time; check status and files."""
    env = {**os.environ, "MPLBACKEND": "Agg", "PYTHONWARNINGS": "ignore"}
    queue = [(name, steps) for name, steps in runs.items()]
    active, failures = {}, []

    def start(name, steps):
        cwd = tmp_path / Path(name).stem
        cwd.mkdir(exist_ok=True)
        args, files = steps[0]
        proc = subprocess.Popen([sys.executable, str(EXAMPLES[0].parent / name), *args], cwd=cwd, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                stdin=subprocess.DEVNULL)
        active[name] = (proc, steps, cwd, time.monotonic())

    while queue or active:
        while queue and len(active) < parallel:
            start(*queue.pop(0))
        time.sleep(0.1)
        for name, (proc, steps, cwd, t0) in list(active.items()):
            if proc.poll() is None:
                if time.monotonic() - t0 > 300:
                    proc.kill()
                continue
            out, err = proc.communicate()
            del active[name]
            print(f"{name} {' '.join(steps[0][0])}: {time.monotonic() - t0:.1f} s")
            args, files = steps[0]
            missing = [f for f in files if not (cwd / f).is_file()]
            if proc.returncode != 0 or missing:
                failures.append(f"{name} {' '.join(args)}: exit {proc.returncode}, missing {missing}\n"
                                f"{err[-1500:]}")
            elif len(steps) > 1:
                queue.insert(0, (name, steps[1:]))
    assert not failures, "\n\n".join(failures)


#: Examples whose tiny run has several steps (other modes of the same script) that the default
#: suite cuts to the first few; every step runs in the slow suite.
DEFAULT_STEPS = {"advice_study.py": 1, "reference_reading_study.py": 1, "thin_designs.py": 1, "check_sampler.py": 1}


#: Examples whose tiny run is among the longest (batches of their own) and whose path other default
#: tests cover: their tiny runs are in the slow suite.
SLOW_TINY = {"thin_designs.py", "pilot_dependence.py", "dataset_pipeline.py", "horizon_study.py",
             "fallback_accuracy.py", "aggregation_study.py", "batch_throughput.py", "profile_posterior.py",
             "advice_study.py"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_TINY else n for n in sorted(TINY)])
def test_every_example_runs_on_a_tiny_budget(name, tmp_path):
    # one test an example, so that the test runner's workers share them out
    _run_all({name: TINY[name][:DEFAULT_STEPS.get(name)]}, tmp_path, parallel=1)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(DEFAULT_STEPS))
def test_every_step_of_the_tiny_runs(name, tmp_path):
    _run_all({name: TINY[name]}, tmp_path, parallel=1)


@pytest.mark.slow
def test_the_examples_longer_runs(tmp_path):
    _run_all(SLOW, tmp_path)


@pytest.mark.slow  # the study script's own runs
def test_the_advice_study_accounts_for_every_estimate(tmp_path):
    """Each predict record carries every estimate it made (the one before the advice and one per
    annotation added), with its CPU seconds, convergence and overflow warnings, and ``report``
    counts them all in its time table (the issue's bound of 5 s per estimate)."""
    import json

    script = EXAMPLES[0].parent / "advice_study.py"
    env = {**os.environ, "MPLBACKEND": "Agg"}
    for args in (["predict", "--n", "2", "--min-ess", "100"], ["report"]):
        proc = subprocess.run([sys.executable, str(script), *args, "--out", "as"], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-1500:]
    recs = [json.loads(x) for x in (tmp_path / "as" / "predict.jsonl").read_text().splitlines()]
    assert all(r["focal_prior"] is None for r in recs)  # the package's default prior
    for r in recs:
        assert len(r["estimates"]) == 1 + len(r["rows"]), r["estimates"]
        assert all(e["cpu_s"] > 0 and isinstance(e["converged"], bool) and e["overflow_warnings"] >= 0
                   for e in r["estimates"])
    row = next(line for line in proc.stdout.splitlines() if line.startswith("| predict |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert int(cells[1]) == sum(len(r["estimates"]) for r in recs)
    assert float(cells[4]) == pytest.approx(max(e["cpu_s"] for r in recs for e in r["estimates"]), abs=0.006)


def _example(file: str):
    """A fresh copy of the example script ``file`` as a module (its globals are its own)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(Path(file).stem, EXAMPLES[0].parent / file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _spy_on(study, monkeypatch, *keys) -> dict:
    """Record, for every estimate the advice study makes, its keyword arguments ``keys`` (a tuple),
    and for every advice the model it was given and its model options; the real functions still run."""
    seen = {"estimate": [], "advise": []}
    real_estimate, real_advise = study.estimate, study.advise

    def spy_estimate(*a, **kw):
        seen["estimate"].append(tuple(kw.get(k) for k in keys))
        return real_estimate(*a, **kw)

    def spy_advise(model, *a, **kw):
        seen["advise"].append((model, kw.get("options")))
        return real_advise(model, *a, **kw)

    monkeypatch.setattr(study, "estimate", spy_estimate)
    monkeypatch.setattr(study, "advise", spy_advise)
    return seen


@pytest.mark.slow  # the study script's own runs
def test_the_advice_studys_own_scenes_follow_the_models_prior_and_noise(tmp_path, monkeypatch):
    """``own``: each scene's starting point and its three added annotations come from one truth of
    the model's prior; the next set and the new reference are the scene's next ones, the repeat is
    a second reading of the first reference's true segment; the advice is asked about exactly
    these, and the estimates and the advice share the box of simulation-based calibration."""

    import numpy as np

    from creference_bayes.bench.sbc import SBC_BOX

    script = EXAMPLES[0].parent / "advice_study.py"
    study = _example(script.name)
    case = next(c for c in (study._own_case(0, k) for k in range(12)) if c["n_r"] >= 1)
    base, added = case["base"], case["added"]
    n_t, n_r = case["n_t"], case["n_r"]
    assert len(base.targets[0].dimension_lines) == n_t and len(base.references) == n_r
    assert len(added["target"].targets[0].dimension_lines) == n_t + 1
    assert [r.line.tolist() for r in added["new-ref"].references[:n_r]] == [r.line.tolist() for r in base.references]
    assert len(added["new-ref"].references) == n_r + 1
    repeat = case["repeat"](0)  # a second worker's reading of the first reference, and only of it
    assert case["repeat"](1) is None and len(repeat.references) == n_r + 1
    rep, first = repeat.references[-1], base.references[0]
    assert rep.object == first.object and rep.worker != first.worker
    true_line = np.asarray(base.ground_truth["reference_lines_true_px"][0])
    assert np.abs(np.asarray(rep.line) - true_line).max() < 60 and np.abs(np.asarray(first.line) - true_line).max() < 60
    assert np.abs(np.asarray(rep.line) - first.line).max() > 0

    seen = _spy_on(study, monkeypatch, "bounds", "focal_prior")
    monkeypatch.chdir(tmp_path)
    study.main(["own", "--n", "1", "--min-ess", "100", "--out", "own"])
    box = SBC_BOX.bounds()
    same = lambda b: all(np.array_equal(getattr(b, k), getattr(box, k))
                         for k in ("camera_lower", "camera_upper", "object_lower", "object_upper"))
    assert seen["estimate"] and all(same(b) and fp == "default" for b, fp in seen["estimate"])
    assert seen["advise"] and all(same(model.bounds) for model, _ in seen["advise"])
    import json

    rec = json.loads((tmp_path / "own" / "own.jsonl").read_text().splitlines()[0])
    assert all(isinstance(h, bool) for h in rec["handedness_kept_true"])
    assert all(0.0 <= q <= 1.0 for q in rec["truth_quantile"])
    bad = subprocess.run([sys.executable, str(script), "own", "--focal-prior", "1650,0.27", "--out", "x"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--focal-prior" in bad.stderr


@pytest.mark.slow  # the study script's own runs
def test_the_advice_studys_own_scenes_start_from_the_sets_asked_for(tmp_path, monkeypatch):
    """``own --sets``: every scene starts from one of the numbers of target sets given (the
    default draws are the study's own: 1, 2, 3 or 5), a bad list is refused naming the option,
    and the report splits the target set's predicted and realised gain by the sets before it."""
    import json

    script = EXAMPLES[0].parent / "advice_study.py"
    study = _example(script.name)
    assert {study._own_case(0, k, (2,))["n_t"] for k in range(4)} == {2}
    assert {study._own_case(0, k)["n_t"] for k in range(12)} <= {1, 2, 3, 5}
    monkeypatch.chdir(tmp_path)
    study.main(["own", "--sets", "2", "--n", "1", "--min-ess", "100", "--out", "o2"])
    rec = json.loads((tmp_path / "o2" / "own.jsonl").read_text().splitlines()[0])
    assert rec["n_target"] == 2 and rec["setting"] == "own, sets 2"
    with pytest.raises(SystemExit, match="--sets 1"):  # a resumed run must not mix starting points
        study.main(["own", "--sets", "1", "--n", "2", "--min-ess", "100", "--out", "o2"])
    for bad_value in ("0", "1,x", ""):
        bad = subprocess.run([sys.executable, str(script), "own", "--sets", bad_value, "--out", "x"],
                             capture_output=True, text=True, timeout=120)
        assert bad.returncode == 2 and "--sets" in bad.stderr and repr(bad_value) in bad.stderr

    def row(kind, pred, real):  # gains in points of the distance's HDI share: predicted, realised
        return {"kind": kind, "measure": None if kind == "target" else "length", "pred_gain_pct": pred,
                "real_gain_pct": real, "real_before_share": [0.6], "ess": 0.5, "fallbacks": 0}
    recs = [{"scene": f"s{i:04d}", "n_target": n, "n_refs": 0, "truth_quantile": [0.5], "advice_only_s": 0.1,
             "handedness_kept_true": [True], "n_candidates": 2, "rows": [row("target", p, r), row("new-ref", 1, 1)]}
            for i, (n, p, r) in enumerate([(1, 6, 2), (1, 8, 1), (1, 4, 3), (3, 1, 2), (4, 2, 2), (5, 3, 2)])]
    (tmp_path / "fake").mkdir()
    (tmp_path / "fake" / "own.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    text = study.report_predict(tmp_path / "fake", "own.jsonl")
    part = text.split("by the number of sets before it")[1]
    one = next(x for x in part.splitlines() if x.startswith("| one set |")).split(" | ")
    more = next(x for x in part.splitlines() if x.startswith("| three or more |")).split(" | ")
    assert one[1:4] == ["3", "6.00", "2.00"] and one[4].startswith("0.33 [")
    assert more[1:4] == ["3", "2.00", "2.00"] and more[4].startswith("1.00 [")
    assert "| two |" not in part.split("\n\n")[1]  # fewer than three scenes: no row


def test_the_advice_studys_report_splits_the_gains_by_the_crowds_noise_tier(tmp_path):
    """With scenes of two noise tiers, ``report`` gives each tier's predicted and realised gains per
    kind (where the model's Student-t reading of references fits the crowd, and where not); with
    one tier, no such table."""
    import json

    study = _example("advice_study.py")

    def rec(i, tier, ref_pred, ref_real):
        rows = [{"kind": kind, "measure": None if kind == "target" else "length", "pred_gain_pct": p,
                 "real_gain_pct": r, "rew_gain_pct": r - 0.5, "real_before_share": [0.6], "ess": 0.5, "fallbacks": 0}
                for kind, p, r in (("target", 2.0, 2.0), ("new-ref", ref_pred, ref_real))]
        return {"scene": f"s{i:04d}", "tier": tier, "n_target": 1, "n_refs": 1, "truth_quantile": [0.5],
                "advice_only_s": 0.1, "handedness_kept_true": [True], "n_candidates": 2, "rows": rows}

    recs = [rec(i, "medium", 1.0, r) for i, r in enumerate((2.0, 3.0, 4.0))]
    recs += [rec(3 + i, "high", 2.0, r) for i, r in enumerate((1.0, 2.0, 3.0))]
    (tmp_path / "two").mkdir()
    (tmp_path / "two" / "predict.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    part = study.report_predict(tmp_path / "two").split("By the crowd's noise tier")[1].split("\n\n")[1]
    cells = {tuple(c.strip() for c in line.strip("|").split("|")[:2]): [c.strip() for c in line.strip("|").split("|")[2:]]
             for line in part.splitlines()[2:]}
    assert cells[("medium", "new-ref")][:3] == ["3", "1.00", "3.00"] and cells[("medium", "new-ref")][3].startswith("3.00 [")
    assert cells[("medium", "new-ref")][4] == "2.50"  # the draws reweighted by the reference actually added
    assert cells[("high", "new-ref")][:3] == ["3", "2.00", "2.00"] and cells[("high", "new-ref")][3].startswith("1.00 [")
    assert cells[("high", "target")][:3] == ["3", "2.00", "2.00"]
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "predict.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs[:3]))
    assert "noise tier" not in study.report_predict(tmp_path / "one")


def test_the_advice_studys_report_places_the_truth_by_band_and_by_setting(tmp_path):
    """The truth's quantile in the posterior before, by HDI band, and by band within each setting
    when the scenes have more than one (a prior can be calibrated over all and not within a band)."""
    import json

    study = _example("advice_study.py")

    def rec(i, setting, share, q):
        rows = [{"kind": "target", "measure": None, "pred_gain_pct": 1.0, "real_gain_pct": 1.0, "rew_gain_pct": 1.0,
                 "real_before_share": [share], "ess": 0.5, "fallbacks": 0}]
        return {"scene": f"s{i:04d}", "tier": "medium", "setting": setting, "n_target": 1, "n_refs": 0,
                "truth_quantile": [q], "advice_only_s": 0.1, "handedness_kept_true": [True], "n_candidates": 1,
                "rows": rows}

    recs = [rec(0, "outdoor", 0.2, 0.9), rec(1, "outdoor", 0.8, 0.2), rec(2, "outdoor", 0.9, 0.3),
            rec(3, "indoor", 0.1, 0.6)]
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "predict.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    part = study.report_predict(tmp_path / "p").split("Where the true distance falls")[1].split("\n\n")[1]
    rows = {line.strip("|").split("|")[0].strip(): [c.strip() for c in line.strip("|").split("|")[1:4]]
            for line in part.splitlines()[2:]}
    assert rows[">= 50 %"] == ["2", "0.25", "100 %"] and rows["all"] == ["4", "0.50", "50 %"]
    assert rows[">= 50 %, outdoor"] == ["2", "0.25", "100 %"] and rows["< 50 %, outdoor"] == ["1", "0.90", "0 %"]
    assert rows["all, indoor"] == ["1", "0.60", "0 %"] and ">= 50 %, indoor" not in rows
    (tmp_path / "one").mkdir()
    (tmp_path / "one" / "predict.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs[:3]))
    assert ", outdoor" not in study.report_predict(tmp_path / "one")


@pytest.mark.slow  # the study script's own runs
def test_the_advice_studys_model_options_reach_every_estimate_and_are_recorded(tmp_path, monkeypatch):
    """``--option ref_dof=30``: every estimate and advice of ``predict`` reads references with 30
    degrees of freedom, the records say so, and a resumed run with other options is refused; a
    bad option is a usage error that names it."""
    import json

    script = EXAMPLES[0].parent / "advice_study.py"
    study = _example(script.name)
    seen = _spy_on(study, monkeypatch, "ref_dof")
    monkeypatch.chdir(tmp_path)
    study.main(["predict", "--n", "1", "--min-ess", "100", "--option", "ref_dof=30", "--out", "o"])
    assert seen["estimate"] and all(kw == (30.0,) for kw in seen["estimate"])
    assert seen["advise"] and all(model.ref_dof == 30.0 and options.get("ref_dof") == 30.0
                                  for model, options in seen["advise"])
    rec = json.loads((tmp_path / "o" / "predict.jsonl").read_text().splitlines()[0])
    assert rec["options"] == {"ref_dof": 30.0}
    with pytest.raises(SystemExit, match="options"):  # a resumed run must not mix them
        study.main(["predict", "--n", "2", "--min-ess", "100", "--out", "o"])
    for bad in ("ref_dof", "ref_doff=3", "ref_dof=x", "line_reading=corrected"):
        proc = subprocess.run([sys.executable, str(script), "predict", "--option", bad, "--out", "x"],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2 and bad.split("=")[0] in proc.stderr, (bad, proc.stderr)


@pytest.mark.slow  # the study script's own runs
def test_the_advice_study_states_a_focal_prior_on_every_scene(tmp_path):
    """``--focal-prior MEDIAN,LOG_SD`` reaches the estimates (their camera block) and is recorded;
    a malformed value is a usage error that names the option and the value."""
    import json

    script = EXAMPLES[0].parent / "advice_study.py"
    proc = subprocess.run([sys.executable, str(script), "predict", "--n", "1", "--min-ess", "100",
                           "--focal-prior", "1650,0.27", "--out", "as"], cwd=tmp_path,
                          env={**os.environ, "MPLBACKEND": "Agg"}, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-1500:]
    rec = json.loads((tmp_path / "as" / "predict.jsonl").read_text().splitlines()[0])
    assert rec["focal_prior"]["median_px"] == 1650 and rec["focal_prior"]["log_sd"] == 0.27


    study = _example(script.name)
    study._FOCAL_PRIOR = study.FocalPrior(1650.0, 0.27, float("inf"), source="scene")
    base = study._predict_case(0, 0, ["medium"], 1, None)["base"]
    assert base.focal_prior == study._FOCAL_PRIOR
    from creference_bayes.camera_setup import setup_camera

    assert setup_camera(base).terms.focal == study._FOCAL_PRIOR

    # resuming that folder without the prior would mix the two: refused, the file named
    mixed = subprocess.run([sys.executable, str(script), "predict", "--n", "1", "--out", "as"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=120)
    assert mixed.returncode != 0 and "predict.jsonl" in mixed.stderr and "another --out" in mixed.stderr

    bad = subprocess.run([sys.executable, str(script), "predict", "--focal-prior", "1650", "--out", "x"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--focal-prior" in bad.stderr and "'1650'" in bad.stderr


@pytest.mark.slow  # the study script's own runs
def test_the_advice_study_reads_reference_lines_as_told_in_estimates_and_advice_alike(tmp_path, monkeypatch):
    """``--line-reading corrected`` reaches every estimate and every advice of the study (their
    model options), is recorded, and a folder made with another reading is refused on resume."""
    import json

    study = _example("advice_study.py")
    seen = _spy_on(study, monkeypatch, "line_reading")
    monkeypatch.chdir(tmp_path)
    study.main(["predict", "--n", "1", "--min-ess", "100", "--line-reading", "corrected", "--out", "lr"])
    assert seen["estimate"] and set(seen["estimate"]) == {("corrected",)}
    assert seen["advise"] and all(o == {"line_reading": "corrected"} for _, o in seen["advise"])
    rec = json.loads((tmp_path / "lr" / "predict.jsonl").read_text().splitlines()[0])
    assert rec["line_reading"] == "corrected"
    with pytest.raises(SystemExit, match="line reading 'corrected'.*'marginal'.*another --out"):
        study.main(["predict", "--n", "1", "--min-ess", "100", "--out", "lr"])


@pytest.mark.slow  # the study script's own runs
def test_the_advice_study_predicts_on_the_simulators_crowds(tmp_path, monkeypatch):
    """``predict --tiers light`` draws its scenes from the simulator's light crowd (2 px corners,
    5 px reference end points), as ``--tiers high`` from the paper-like tier, and records it."""
    import json

    study = _example("advice_study.py")
    monkeypatch.chdir(tmp_path)
    study.main(["predict", "--n", "1", "--min-ess", "100", "--tiers", "light", "--out", "lc"])
    rec = json.loads((tmp_path / "lc" / "predict.jsonl").read_text().splitlines()[0])
    assert rec["tier"] == "light" and rec["rows"]


@pytest.mark.slow  # the study's bench scenes (about 30 s)
def test_the_reading_study_reads_the_bench_scenes_of_other_seeds(tmp_path, monkeypatch):
    """``--bench --seeds 0,1``: the first scene of the bench's draw at each seed (another scene at
    seed 1, named so), each with the truth's quantile in the posterior of its distance."""
    import json

    study = _example("reference_reading_study.py")
    monkeypatch.chdir(tmp_path)
    study.main(["--bench", "--n", "1", "--seeds", "0,1", "--readings", "marginal", "--min-ess", "100", "--out", "rb"])
    recs = [json.loads(line) for line in (tmp_path / "rb" / "bench.jsonl").read_text().splitlines()]
    assert [r["scene"] for r in recs] == ["none-indoor-00", "none-indoor-00-seed1"]
    assert all(0.0 <= r["quantile"] <= 1.0 for r in recs) and recs[0]["map_error"] != recs[1]["map_error"]


def test_the_line_noise_study_finds_no_shift_without_noise_and_a_lengthening_with_it():
    """examples/line_noise_bias.py: with no end-point noise the reading is the true length; with
    noise a short segment reads longer (|d + e| grows with e), a long ground line hardly moves, and
    the model's corrected reading takes most of the lengthening off."""

    import numpy as np

    study = _example("line_noise_bias.py")
    exact = study.measure(3, ["none"], 50, 0)
    assert exact and max(abs(r["shift"]) for r in exact) < 1e-6
    noisy = study.measure(6, ["high"], 400, 0, corrected=40)
    widths = [r["shift"] for r in noisy if r["measure"] == "width"]
    distances = [r["shift"] for r in noisy if r["measure"] == "distance"]
    assert np.median(widths) > 0.1 and abs(np.median(distances)) < 0.05
    # the model's reading (less its shift) is centred where the raw one is not
    fixed = [r["corrected_shift"] for r in noisy if r["measure"] == "width"]
    assert abs(np.median(fixed)) < 0.5 * np.median(widths)


def test_frame_calibration_reads_each_true_value_against_its_own_draws(tmp_path, capsys):
    """Each quantity's quantile comes from its own column of the draws: with draws set just above
    the truth in some columns and just below it in the others, each quantile is 0 or 1 as set."""
    from types import SimpleNamespace

    import numpy as np

    from creference_bayes.models.contract import O_GROUND, O_SIZE, O_X, O_Z
    from creference_bayes.bench.simulate import true_state

    study = _example("frame_calibration.py")
    scene = study.street_scene("low", 3, 0, 5)
    cam, objs = true_state(scene)
    spread = 1.0 + 1e-5 * np.arange(40)  # 40 draws that differ a little (a fixed quantity's draws do not)
    cams = cam[None, None] * spread[None, :, None]  # (1 chain, 40 draws, 5)
    obj = objs[None, None] * spread[None, :, None, None]
    up, down = 1.001, 0.999  # above or below the truth, in every draw
    cams[..., 0] *= up  # the focal length: its truth below every draw, quantile 0
    cams[..., 3] *= down  # the height: quantile 1
    obj[..., O_X] *= up
    obj[..., O_Z] *= up  # the distance grows: quantile 0
    obj[..., O_SIZE.start] *= down  # length: 1
    obj[..., O_SIZE.start + 1] *= up  # width: 0
    obj[..., O_SIZE.start + 2] *= down  # height: 1
    obj[..., O_GROUND] = np.abs(obj[..., O_GROUND]) + 1.0  # above any truth: 0
    result = SimpleNamespace(draws=SimpleNamespace(cameras=cams, objects=obj))
    recs = study.frame_records(scene, result, "f")
    assert len(recs) == 3
    for r in recs:
        assert (r["focal_length_px"], r["camera_height_m"]) == (0.0, 1.0)
        assert (r["distance_m"], r["length_m"], r["width_m"], r["height_m"], r["ground_m"]) == (0.0, 1.0, 0.0, 1.0, 0.0)
    # a quantity the model holds fixed (the ground offset of a frame's only object) is not checked
    one = study.street_scene("low", 1, 0, 5)
    cam, objs = true_state(one)
    fixed = SimpleNamespace(draws=SimpleNamespace(cameras=cam[None, None] * spread[None, :, None] * up,
                                                  objects=objs[None, None] * spread[None, :, None, None]))
    (rec,) = study.frame_records(one, fixed, "g")
    assert rec["ground_m"] is None and rec["focal_length_px"] == 0.0
    assert "| ground_m | 0 (held fixed) |" in study.table([{**rec, "converged": True}])
    # bad options are usage errors that name the value, before anything is written
    for flags, said in ((["--tiers", "lo"], "got 'lo'"), (["--counts", "3,a"], "got --counts '3,a'"),
                        (["--frames", "0"], "--frames 0")):
        with pytest.raises(SystemExit) as stop:
            study.main([*flags, "--out", str(tmp_path / "never_written")])
        assert stop.value.code == 2 and said in capsys.readouterr().err
    assert not (tmp_path / "never_written").exists()


def test_the_advice_studys_policy_table_reads_the_adaptive_run_at_three_quarters_of_five_plus_five(tmp_path):
    """The policy goal: 5 + 5's median location error within 75 % of its human time (930 s of
    1239.5). The table's truncated row is each run's last estimate within 930 s: here 8 % and
    6 % (median 7), not the 5 % and 4 % they reach after it."""

    study = _example("advice_study.py")
    assert study.GOAL_S == pytest.approx(0.75 * (5 * 183.5 + 5 * 64.4))

    def step(seconds, error):
        return {"seconds": seconds, "error": error, "post_error": error, "covered": True, "share": 0.2}

    recs = []
    for k, (late, final) in enumerate(((8.0, 5.0), (6.0, 4.0))):
        steps = [step(183.5, 30.0), step(900.0, late), step(1000.0, final)]
        recs.append({"scene": f"paper-like-{k:03d}", "condition": "paper-like",
                     "adaptive": {**steps[-1], "steps": steps, "n_target": 3, "n_refs": 4},
                     "fixed": {"5 + 5 refs": step(1239.5, 6.5)}})
    (tmp_path / "policy.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    table = study.report_policy(tmp_path)
    row = next(line for line in table.splitlines() if line.startswith("| adaptive, stopped at 930 s"))
    assert row.split("|")[3:5] == [" 900 ", " 7.0 "]  # mean human s spent by then, median error %
    full = next(line for line in table.splitlines() if line.startswith("| adaptive |"))
    assert full.split("|")[4] == " 4.5 "


@pytest.mark.slow  # the study script's own runs
def test_the_advice_studys_policy_runs_on_a_tiny_budget(tmp_path, monkeypatch):
    """``policy`` end to end on one scene of each condition, its budget cut to a set of lines and
    one reference (247.9 s) and its fixed designs to one: every run stays within the budget, the
    adaptive run asks at most one more annotation, and ``report`` tables both conditions."""
    from types import SimpleNamespace as NS

    study = _example("advice_study.py")
    monkeypatch.setattr(study, "FIXED", {"target x1": (1, 0)})
    monkeypatch.setattr(study, "FIVE_PLUS_FIVE_S", study.TARGET_S + study.REF_S)
    study.run_policy(NS(out=str(tmp_path), n=1, seed=0, min_ess=100.0, rank_by="location"))
    recs = [json.loads(line) for line in (tmp_path / "policy.jsonl").read_text().splitlines()]
    assert [r["condition"] for r in recs] == ["paper-like", "outdoor"]
    assert all(r["rank_by"] == "location" for r in recs)
    with pytest.raises(SystemExit, match="ranked by"):  # a folder keeps one ranking
        study.run_policy(NS(out=str(tmp_path), n=1, seed=0, min_ess=100.0, rank_by="hdi"))
    for r in recs:
        steps = r["adaptive"]["steps"]
        assert 1 <= len(steps) <= 2 and steps[0]["seconds"] == study.TARGET_S
        assert all(s["seconds"] <= study.TARGET_S + study.REF_S + 1e-9 for s in steps)
        assert list(r["fixed"]) == ["target x1"] and r["fixed"]["target x1"]["error"] >= 0
        assert r["estimates"] and all(c["cpu_s"] > 0 for c in r["estimates"])
    table = study.report_policy(tmp_path)
    assert "Policies, paper-like scenes" in table and "Policies, outdoor scenes" in table


@pytest.mark.slow  # the study script's own runs
def test_the_advice_studys_what_ifs_reach_the_scenes_the_estimates_and_the_advice(tmp_path, monkeypatch):
    """``--distance-range setting``: every estimate and every advice of ``predict`` knows the
    simulator's distance range of the scene's setting; ``--reference-px 0``: the references'
    segments are the true ones; both are recorded, and a resumed run without them is refused."""
    import json

    import numpy as np

    from creference_bayes.bench.simulate import SETTINGS

    study = _example("advice_study.py")
    seen = _spy_on(study, monkeypatch, "distance_range")
    monkeypatch.chdir(tmp_path)
    study.main(["predict", "--n", "1", "--min-ess", "100", "--tiers", "medium", "--distance-range", "setting",
                "--reference-px", "0", "--out", "o"])
    rec = json.loads((tmp_path / "o" / "predict.jsonl").read_text().splitlines()[0])
    expected = SETTINGS[rec["setting"]]["distance"]
    assert seen["estimate"] and all(kw == (expected,) for kw in seen["estimate"])
    assert seen["advise"] and all(model.location.distance_m == expected for model, _ in seen["advise"])
    assert rec["options"] == {"distance_range": "setting", "reference_px": 0.0}
    case = study._predict_case(0, 0, ["medium"], 1, None)
    gt = case["added"]["new-ref"].ground_truth
    for ref, true_line in zip(case["added"]["new-ref"].references, gt["reference_lines_px"]):
        np.testing.assert_allclose(ref.line, true_line, atol=0.006)
    with pytest.raises(SystemExit, match="options"):
        study.main(["predict", "--n", "2", "--min-ess", "100", "--tiers", "medium", "--out", "o"])


def test_advice_speed_times_a_simulated_scene(tmp_path):
    """examples/advice_speed.py on one simulated scene: its table has the scene's row, with the
    advice's and the estimate's seconds."""
    from creference_bayes.cli import main

    assert main(["simulate", str(tmp_path / "s"), "--n", "1", "--quiet"]) == 0
    scene = next((tmp_path / "s").glob("*.json"))
    proc = subprocess.run([sys.executable, str(EXAMPLES[0].parent / "advice_speed.py"), str(scene)], cwd=tmp_path,
                          env={**os.environ, "MPLBACKEND": "Agg"}, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-1500:]
    rows = [line for line in proc.stdout.splitlines() if line.startswith("|") and scene.stem in line]
    assert rows, proc.stdout
