"""``creference confidence fit|report`` and ``--confidence-map`` on estimate and batch, checked
against counts made independently from the scene files."""

import json
import math
import shutil

import numpy as np
import pytest

from creference_bayes.cli.main import main
from creference_bayes.core.units import UNITS_TO_M
from creference_bayes.models.confidence_map import ConfidenceMap
from creference_bayes.workflows.batch import BatchSettings


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("conf")
    assert main(["simulate", str(root / "scenes"), "--n", "24", "--seed", "2", "--tier", "low",
                 "--confidence", "over", "--quiet"]) == 0
    return root / "scenes"


def _independent_ranges(folder):
    """(confidence, low m, high m, truth m) of every range, read from the files by hand."""
    out = []
    for path in sorted(folder.glob("*.json")):
        d = json.loads(path.read_text())
        dims = d["target"]["dimensions_m"]
        for j, r in enumerate(d["references"]):
            lo, hi = r["range"]
            f = UNITS_TO_M[r["unit"]] if r["mode"] == "direct" else dims[r["measure"]]
            out.append((r["confidence"], lo * f, hi * f, d["ground_truth"]["reference_lengths_m"][j]))
    return out


def test_report_counts_coverage_and_scores_like_the_files_say(scenes, tmp_path):
    assert main(["confidence", "report", str(scenes), "--out", str(tmp_path / "rep"), "--min-answers", "2",
                 "--quiet"]) == 0
    rep = json.loads((tmp_path / "rep" / "report.json").read_text())
    ranges = _independent_ranges(scenes)
    for row in rep["reliability"]:
        mine = [lo <= t <= hi for c, lo, hi, t in ranges if c == row["level"]]
        assert (row["n"], row["covered"]) == (len(mine), sum(mine))
        assert row["low"] <= row["coverage"] <= row["high"]
    score = []
    for c, lo, hi, t in ranges:  # Gneiting & Raftery's interval score in log-length
        a, b, x = math.log(lo), math.log(hi), math.log(t)
        score.append((b - a) + 2 / (1 - c) * max(a - x, 0) + 2 / (1 - c) * max(x - b, 0))
    whole = next(r for r in rep["scores"] if r["by"] == "all")
    assert whole["n"] == len(ranges) == 24 * 5
    assert whole["score_mean"] == pytest.approx(np.mean(score), rel=1e-9)
    assert {r["key"] for r in rep["scores"] if r["by"] == "group"} == {
        "length/direct", "length/relative", "width/direct", "width/relative", "distance/direct"}
    assert rep["workers"] and all(w["n"] >= 2 for w in rep["workers"])
    for name in ("report.md", "reliability.png", "workers.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 0


def test_fit_writes_a_map_that_estimate_and_report_read(scenes, tmp_path, capsys):
    out = tmp_path / "map.json"
    assert main(["confidence", "fit", str(scenes), "--out", str(out), "--draws", "100",
                 "--min-per-level", "5"]) == 0
    text = capsys.readouterr().out
    assert "pooled:" in text and f"wrote {out}" in text
    cmap = ConfidenceMap.load(out)
    assert cmap.fit["method"] == "truth" and cmap.fit["ranges"] == 120
    assert cmap.coverage(0.9) < 0.85  # over-confident workers
    scene = sorted(scenes.glob("*.json"))[0]
    assert main(["estimate", str(scene), "--confidence-map", str(out), "--no-posterior", "--quiet",
                 "--out", str(tmp_path / "r.json")]) == 0
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["confidence"] == {"map": {"name": "file", "source": str(out), "sha256": cmap.digest()},
                                 "ranges_with_confidence": 5, "read_with_map": 5}
    assert main(["confidence", "report", str(scenes), "--out", str(tmp_path / "rep"), "--map", str(out),
                 "--no-figures", "--quiet"]) == 0
    whole = next(r for r in json.loads((tmp_path / "rep" / "report.json").read_text())["scores"] if r["by"] == "all")
    assert whole["recal_coverage"] > whole["coverage"]  # widened ranges hold the truth more often


def test_fit_without_ground_truth_runs_estimates(scenes, tmp_path):
    for i in range(2):
        d = json.loads((scenes / f"scene_{i:04d}.json").read_text())
        del d["ground_truth"]
        (tmp_path / f"s{i}.json").write_text(json.dumps(d))
    out = tmp_path / "m.json"
    assert main(["confidence", "fit", str(tmp_path / "s0.json"), str(tmp_path / "s1.json"), "--out", str(out),
                 "--min-per-level", "1", "--draws", "20", "--min-ess", "100", "--quiet"]) == 0
    cmap = ConfidenceMap.load(out)
    assert cmap.fit["method"] == "marginal" and cmap.fit["ranges"] == 10 and cmap.fit["scenes_failed"] == 0


@pytest.mark.parametrize("argv, message", [
    (["estimate", "{scene}", "--model", "paper", "--confidence-map", "identity"],
     "--confidence-map: the paper model turns ranges into bounds"),
    (["estimate", "{scene}", "--confidence-map", "{bad}"],
     "pooled.coverage: expected non-decreasing values (a map is monotone)"),
    (["batch", "{scene}", "--out", "{tmp}/b", "--confidence-map", "{bad}"], "--confidence-map: "),
    (["confidence", "fit", "{plain}", "--out", "{tmp}/m.json"], "no range with a stated confidence in 1 scene(s)"),
    (["confidence", "report", "{plain}", "--out", "{tmp}/r"], "no range with a stated confidence has a known truth"),
    (["confidence", "fit", "{scene}", "--out", "{tmp}/m.json", "--draws", "0"], "--draws: expected an integer >= 1"),
])
def test_user_errors_are_one_line(scenes, tmp_path, capsys, argv, message):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "creference-confidence-map/1", "kind": "fitted",
                               "pooled": {"levels": [0.5, 0.9], "coverage": [0.6, 0.4]}}))
    plain = tmp_path / "plain.json"
    d = json.loads((scenes / "scene_0000.json").read_text())
    for r in d["references"]:
        del r["confidence"]
    plain.write_text(json.dumps(d))
    fill = {"scene": str(scenes / "scene_0000.json"), "bad": str(bad), "plain": str(plain), "tmp": str(tmp_path)}
    assert main([a.format(**fill) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_batch_compares_the_map_by_content(scenes, tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "elsewhere.json"
    a.write_text(json.dumps(ConfidenceMap.identity(dof=4.0).to_dict()))
    shutil.copy(a, b)
    ident = {name: BatchSettings(confidence_map=m).to_dict()["confidence_map"] for name, m in
             {"default": "default", "none": "none", "identity": "identity", "a": ConfidenceMap.load(a),
              "b": ConfidenceMap.load(b)}.items()}
    assert ident["default"] == ident["none"] == {"name": "none"}
    assert ident["identity"] == {"name": "identity", "dof": None}
    assert ident["a"] == ident["b"] == {"name": "identity", "dof": 4.0}
    assert BatchSettings(model="paper", confidence_map="none").to_dict()["confidence_map"] == {"name": "none"}
    scene = str(scenes / "scene_0001.json")
    args = ["batch", scene, "--out", str(tmp_path / "batch"), "--workers", "1", "--no-posterior", "--quiet"]
    assert main(args + ["--confidence-map", "identity"]) == 0
    first = json.loads((tmp_path / "batch" / "results" / "scene_0001.json").read_text())
    assert first["confidence"]["read_with_map"] == 5
    assert first["batch"]["settings"]["confidence_map"] == {"name": "identity", "dof": None}
    assert main(args + ["--confidence-map", "none"]) == 0  # another map: computed again
    second = json.loads((tmp_path / "batch" / "results" / "scene_0001.json").read_text())
    assert second["confidence"]["read_with_map"] == 0 and second["map"] != first["map"]
