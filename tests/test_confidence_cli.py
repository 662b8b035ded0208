"""``creference confidence fit|report`` and ``--confidence-map`` on estimate and batch, on scenes of
one, two and three targets, checked against values kept when the scenes were made."""

import json
import math
import shutil

import numpy as np
import pytest
from test_confidence_fit import confident_scene

from creference_bayes.bench.confidence_workers import ConfidentWorkers
from creference_bayes.cli.main import main
from creference_bayes.models.confidence_map import ConfidenceMap


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """24 scenes of 1–3 targets with every kind of reference stated by over-confident workers, and
    (confidence, low, high, truth) of every range as stated in the files."""
    root = tmp_path_factory.mktemp("conf") / "scenes"
    root.mkdir()
    workers = ConfidentWorkers.pool("over", n_workers=8, seed=1)
    expected = []
    for i in range(24):
        m = 1 + i % 3
        d, values = confident_scene(i, workers, m=m, sizes_known=m == 1)
        (root / f"scene_{i:02d}.json").write_text(json.dumps(d))
        expected += [(r["confidence"], *r["range"], x) for r, x in zip(d["references"], values)]
    return root, expected


def test_report_counts_coverage_and_scores_like_the_files_say(data, tmp_path):
    scenes, ranges = data
    assert main(["confidence", "report", str(scenes), "--out", str(tmp_path / "rep"), "--min-answers", "2",
                 "--quiet"]) == 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    for row in rep["reliability"]:
        mine = [lo <= t <= hi for c, lo, hi, t in ranges if c == row["level"]]
        assert (row["n"], row["covered"]) == (len(mine), sum(mine))
        assert row["low"] <= row["coverage"] <= row["high"]
    score = []
    for c, lo, hi, t in ranges:  # Gneiting & Raftery's interval score in log-length
        a, b, x = math.log(lo), math.log(hi), math.log(t)
        score.append((b - a) + 2 / (1 - c) * max(a - x, 0) + 2 / (1 - c) * max(x - b, 0))
    whole = next(r for r in rep["scores"] if r["by"] == "all")
    assert whole["n"] == len(ranges) == 8 * (4 + 5 + 5)
    assert whole["score_mean"] == pytest.approx(np.mean(score), rel=1e-4)  # lines rounded to 0.01 px
    assert {r["key"] for r in rep["scores"] if r["by"] == "group"} == {
        "length/direct", "length/relative", "width/direct", "distance/direct"}
    assert rep["counts"]["truth"] == ["object", "segment"]
    assert rep["workers"] and all(w["n"] >= 2 for w in rep["workers"])
    for name in ("report.md", "reliability.png", "workers.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 0


def test_fit_writes_a_map_that_estimate_and_report_read(data, tmp_path, capsys):
    scenes, ranges = data
    out = tmp_path / "map.json"
    assert main(["confidence", "fit", str(scenes), "--out", str(out), "--draws", "100",
                 "--min-per-level", "5"]) == 0
    text = capsys.readouterr().out
    assert "pooled:" in text and f"wrote {out}" in text
    cmap = ConfidenceMap.load(out)
    assert cmap.fit["method"] == "truth" and cmap.fit["ranges"] == len(ranges) and cmap.fit["scenes"] == 24
    assert cmap.coverage(0.9) < 0.85  # over-confident workers
    frame = scenes / "scene_02.json"  # three targets, five ranges
    assert main(["estimate", str(frame), "--confidence-map", str(out), "--no-posterior", "--quiet",
                 "--out", str(tmp_path / "r.json")]) == 0
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["references"]["read_with_confidence_map"] == 5
    used = res["provenance"]["confidence_map"]
    assert (used["name"], used["source"], used["sha256"]) == ("file", str(out), cmap.digest())
    assert main(["confidence", "report", str(scenes), "--out", str(tmp_path / "rep"), "--map", str(out),
                 "--no-figures", "--quiet"]) == 0
    whole = next(r for r in json.loads((tmp_path / "rep" / "report.json").read_text())["scores"] if r["by"] == "all")
    assert whole["recal_coverage"] > whole["coverage"]  # widened ranges hold the truth more often


def test_fit_without_ground_truth_runs_estimates_and_logs_a_line_per_scene(data, tmp_path, capsys):
    """Standard error is not a terminal here: the leave-one-out fits print a line per scene."""
    scenes, _ = data
    for i in (0, 3):  # one target each, four ranges
        d = json.loads((scenes / f"scene_{i:02d}.json").read_text())
        del d["ground_truth"]
        (tmp_path / f"s{i}.json").write_text(json.dumps(d))
    out = tmp_path / "m.json"
    assert main(["confidence", "fit", str(tmp_path / "s0.json"), str(tmp_path / "s3.json"), "--out", str(out),
                 "--min-per-level", "1", "--draws", "20", "--min-ess", "100"]) == 0
    cmap = ConfidenceMap.load(out)
    assert cmap.fit["method"] == "marginal" and cmap.fit["ranges"] == 8 and cmap.fit["scenes_failed"] == 0
    lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("leave-one-out ")]
    assert [x.split(":")[0] for x in lines] == ["leave-one-out 1/2", "leave-one-out 2/2"], lines
    assert all("4 range(s)" in x for x in lines), lines


def test_fit_names_the_levels_it_left_out(data, tmp_path, capsys):
    from creference_bayes.workflows.confidence.fit import kept_levels

    scenes, expected = data
    levels, _, n, _ = kept_levels([e[0] for e in expected], 1)
    least = int(sorted(n)[1])  # the rarest level has fewer ranges than this
    assert main(["confidence", "fit", str(scenes), "--out", str(tmp_path / "m.json"), "--min-per-level", str(least),
                 "--quiet"]) == 0
    dropped = ", ".join(f"{c:g}" for c in levels[n < least])
    assert capsys.readouterr().err.startswith(f"warning: confidence level(s) {dropped} left out (fewer than {least} "
                                              "ranges each)")
    assert main(["confidence", "fit", str(scenes), "--out", str(tmp_path / "m.json"), "--min-per-level", "1",
                 "--quiet"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("argv, message", [
    (["estimate", "{scene}", "--model", "paper", "--confidence-map", "identity"],
     "--confidence-map: the paper model does not read stated confidences"),
    (["estimate", "{scene}", "--confidence-map", "{bad}"],
     "pooled.coverage: expected non-decreasing values (a map is monotone)"),
    (["batch", "{scene}", "--out", "{tmp}/b", "--confidence-map", "{bad}"], "--confidence-map: "),
    (["confidence", "fit", "{plain}", "--out", "{tmp}/m.json"], "no range with a stated confidence in 1 scene(s)"),
    (["confidence", "report", "{plain}", "--out", "{tmp}/r"], "no range with a stated confidence has a known truth"),
    (["confidence", "fit", "{scene}", "--out", "{tmp}/m.json", "--draws", "0"], "--draws: expected an integer >= 1"),
    (["confidence", "fit", "{scene}", "--out", "{tmp}/m.json", "--method", "marginal"],  # before any estimate
     "confidence level has 10 ranges or more (--min-per-level; ranges per level"),
    (["estimate", "{scene}", "--confidence-map", "identiy"],
     "--confidence-map: 'identiy' is none of none, identity and no such file; did you mean 'identity'?"),
])
def test_user_errors_are_one_line(data, tmp_path, capsys, argv, message):
    scenes, _ = data
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "creference-confidence-map/1", "kind": "fitted",
                               "pooled": {"levels": [0.5, 0.9], "coverage": [0.6, 0.4]}}))
    plain = tmp_path / "plain.json"
    d = json.loads((scenes / "scene_01.json").read_text())
    for r in d["references"]:
        del r["confidence"]
    plain.write_text(json.dumps(d))
    fill = {"scene": str(scenes / "scene_01.json"), "bad": str(bad), "plain": str(plain), "tmp": str(tmp_path)}
    assert main([a.format(**fill) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_batch_compares_the_map_by_content(data, tmp_path):
    scenes, _ = data
    a, b = tmp_path / "a.json", tmp_path / "elsewhere.json"
    a.write_text(json.dumps(ConfidenceMap.identity(dof=4.0).to_dict()))
    shutil.copy(a, b)
    args = ["batch", str(scenes / "scene_00.json"), "--out", str(tmp_path / "batch"), "--workers", "1",
            "--no-posterior", "--quiet"]
    path = tmp_path / "batch" / "results" / "scene_00.json"
    assert main(args + ["--confidence-map", str(a)]) == 0
    first = json.loads(path.read_text())
    assert first["references"]["read_with_confidence_map"] == 4
    assert first["batch"]["settings"]["confidence_map"] == {"name": "identity", "dof": 4.0}
    stamp = path.stat().st_mtime_ns
    assert main(args + ["--confidence-map", str(b)]) == 0  # the same map elsewhere: nothing to do
    assert path.stat().st_mtime_ns == stamp
    assert main(args + ["--confidence-map", "none"]) == 0  # another map: computed again
    second = json.loads(path.read_text())
    assert "read_with_confidence_map" not in second["references"] and second["objects"] != first["objects"]
