"""examples/kitti_advice_study.py on the synthetic KITTI-layout folder of test_kitti_frames (no
KITTI files): every design estimated and counted, answers drawn from the truth, the same for a seed."""

import importlib.util
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from test_kitti_frames import write_kitti_folder

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "kitti_advice_study.py"


@pytest.fixture
def kitti_dir(tmp_path):
    return write_kitti_folder(tmp_path / "kitti")


def _module():
    spec = importlib.util.spec_from_file_location("kitti_advice_study", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_answers_come_from_the_truth_and_the_seed(kitti_dir, tmp_path):
    """A new set of lines lies within the noise of the scene's own (the same box projected), a
    catalogue size within a few CATALOGUE_LOG_SD of the true one, the mounting is the frame's
    true camera; the same seed gives the same answers, another seed other lines."""
    from creference_bayes.bench.kitti import kitti_scenes
    from creference_bayes.io.scene import load_scene
    from creference_bayes.workflows.advice.answers import CATALOGUE_LOG_SD

    study = _module()
    kitti_scenes(kitti_dir, tmp_path / "frames", n_annotations=1, noise_px=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(tmp_path / "frames" / "000007.json")
    args = lambda seed: type("Args", (), {"seed": seed, "noise_px": 0.5})  # noqa: E731
    truth, again, other = (study.Truth(scene, "000007", kitti_dir, args(s)) for s in (0, 0, 1))
    for t in scene.targets:
        assert np.max(np.abs(truth.lines[t.id] - t.corners[0])) < 5.0  # two draws at 0.5 px
        np.testing.assert_array_equal(truth.lines[t.id], again.lines[t.id])
        assert not np.array_equal(truth.lines[t.id], other.lines[t.id])
        true = np.array(list(t.ground_truth["dimensions_m"].values()))
        assert np.all(np.abs(np.log(truth.sizes[t.id] / true)) < 5 * CATALOGUE_LOG_SD)
    h = np.median([t.ground_truth["location_m"][1] for t in scene.targets])
    assert truth.mounting == pytest.approx((h, 0.0, 0.0))
    added = truth.answer(scene, "dims", scene.targets[0].id)
    assert len(added.targets[0].dimension_lines) == 2 and added.targets[1:] == scene.targets[1:]


@pytest.mark.slow  # every design of the study (about a minute)
def test_the_study_runs_every_design_on_a_tiny_budget(kitti_dir, tmp_path):
    out = tmp_path / "study"
    proc = subprocess.run([sys.executable, str(SCRIPT), str(kitti_dir), "--out", str(out), "--max-steps", "300",
                           "--draws", "50", "--futures", "10", "--workers", "1"], capture_output=True, text=True,
                          timeout=600, env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((out / "advice_study.json").read_text())
    assert report["objects"] == 3 and report["cameras"] == 1 and report["round0"]["labels"] == 3
    designs = report["designs"]
    assert list(designs) == ["advised", "dims", "sizes", "mounting"]
    assert designs["dims"]["human_s"] == pytest.approx(3 * 183.5) == report["budget_s"]
    for name in ("dims", "sizes", "mounting"):  # every scene changed, every object labelled again
        assert designs[name]["estimated_after"] == 1 and designs[name]["labels_after"] == 3, name
    adv = designs["advised"]
    assert adv["human_s"] <= report["budget_s"]
    assert adv["estimated_after"] + adv["unchanged_after"] == 1
    assert adv["requests"] == len(adv["rows"]) and all("good_gain" in r for r in adv["rows"])
    scene = json.loads((out / "dims" / "scenes" / "000007.json").read_text())
    assert all(len(t["dimension_lines"]) == 2 for t in scene["targets"])
    assert "| design | human s |" in proc.stdout and "| mounting | 900 |" in proc.stdout
    # predicted against realised per design: a design's prediction is its requests answered together
    # by the plan's rule (combined_chance: their changes of each label add); beside it, their gains
    # alone summed
    from creference_bayes.workflows.advice import Moments, combined_chance

    advice = json.loads((out / "advice" / "advice.json").read_text())
    sizes = [p for sc in advice["scenes"] for p in sc["predictions"] if p["candidate"]["kind"] == "size"]
    assert len(advice["scenes"]) == 1
    sc = advice["scenes"][0]
    p_now, shift = np.asarray(sc["now"]["p_iou"]), np.asarray(sc["shift"])
    below = p_now < 0.5
    # each label below the bar is lifted with its chance after them all; each good one falls with
    # the rest; the net change is the labels lifted less those dropped
    after = combined_chance(p_now - shift, 0.5 - shift, [Moments.from_dict(p["moments"]) for p in sizes])
    lifted, dropped = np.sum(after[below]), np.sum(1.0 - after[~below])
    accuracy = {a["design"]: a for a in report["accuracy"]}
    assert list(accuracy) == ["advised", "dims", "sizes", "mounting"]
    assert accuracy["sizes"]["lifted"]["predicted"] == pytest.approx(lifted)
    assert accuracy["sizes"]["dropped"]["predicted"] == pytest.approx(dropped)
    assert accuracy["sizes"]["predicted"] == pytest.approx(lifted - dropped)
    assert accuracy["sizes"]["predicted_alone"] == pytest.approx(sum(p["good_gain"] for p in sizes))
    assert accuracy["sizes"]["realised"] == designs["sizes"]["good_gain"]
    for a in accuracy.values():
        assert a["realised"] == a["lifted"]["realised"] - a["dropped"]["realised"]
    # the plan states its lifts and losses the same way (requests.csv's good_gain and good_loss)
    assert accuracy["advised"]["lifted"]["predicted"] == pytest.approx(adv["predicted_good_gain"], abs=0.01)
    assert accuracy["advised"]["dropped"]["predicted"] == pytest.approx(adv["predicted_good_loss"], abs=0.01)
    assert "realised / predicted" in proc.stdout
    # and in bands of the round-0 P(IoU >= 0.7): 0-0.1, 0.1-0.3, 0.3-0.5 and the good ones (>= 0.5),
    # which are predicted to fall
    p_now = np.asarray(advice["scenes"][0]["now"]["p_iou"])
    counts = [np.sum(p_now < 0.1), np.sum((p_now >= 0.1) & (p_now < 0.3)), np.sum((p_now >= 0.3) & (p_now < 0.5)),
              np.sum(p_now >= 0.5)]
    for a in accuracy.values():
        assert [b["labels"] for b in a["bands"]] == counts, a["design"]
        assert sum(b["predicted"] for b in a["bands"]) == pytest.approx(a["predicted"])
        assert sum(b["realised"] for b in a["bands"]) == a["realised"]
        assert a["bands"][-1]["predicted"] <= 0.0 and a["bands"][-1]["band"] == "≥ 0.5 (good)"
        for b in a["bands"][:3]:  # the realised count's interval if the chances are right: within 0..labels
            lo, hi = b["expected_90"]
            assert 0 <= lo <= hi <= b["labels"] and lo - 1 <= b["predicted"] <= hi + 1  # a median is within 1 of the mean
            assert b["agrees"] == (lo <= b["realised"] <= hi)
        lo, hi = a["bands"][-1]["expected_90"]  # the good ones: from minus those that may fall to 0
        assert -a["bands"][-1]["labels"] <= lo <= hi <= 0 and lo - 1 <= a["bands"][-1]["predicted"] <= hi + 1
    in_band = [np.sum(after[(p_now >= lo) & (p_now < hi)]) for lo, hi in ((0, 0.1), (0.1, 0.3), (0.3, 0.5))]
    assert [b["predicted"] for b in accuracy["sizes"]["bands"][:3]] == pytest.approx(in_band)
    assert "| design | 0–0.1 | 0.1–0.3 | 0.3–0.5 | ≥ 0.5 (good) |" in proc.stdout
    # --tables-only: the same tables again from the folder, nothing estimated
    mtime = (out / "sizes" / "batch" / "batch.json").stat().st_mtime_ns
    again = subprocess.run([sys.executable, str(SCRIPT), str(kitti_dir), "--out", str(out), "--tables-only"],
                           capture_output=True, text=True, timeout=300, env={**os.environ, "MPLBACKEND": "Agg"})
    assert again.returncode == 0, again.stderr[-3000:]
    assert json.loads((out / "advice_study.json").read_text())["accuracy"] == report["accuracy"]
    assert again.stdout[again.stdout.index("| design | human s |"):] == proc.stdout[proc.stdout.index("| design | human s |"):]
    assert (out / "sizes" / "batch" / "batch.json").stat().st_mtime_ns == mtime


def test_a_designs_prediction_is_its_lifts_less_its_losses():
    """Two requests in one frame of three labels (0.2, 0.6 and 0.55; bar 0.5), their futures as sure
    as can be: the first moves them by +0.2, −0.15 and 0, the second by +0.2, 0 and −0.1. Answered
    together they lift the first (0.6) and drop the other two (0.45 each); the first alone lifts
    none (0.4) and drops the second. A frame no request is asked in changes nothing."""
    study = _module()
    scene = {"key": "f", "now": {"p_iou": [0.2, 0.6, 0.55]}, "shift": [0.0, 0.0, 0.0],
             "settings": {"min_quality": 0.5}}

    def moments(change):
        return {"change": change, "change_se": [0.0] * 3, "spread": [1e-9] * 3}

    first, second = moments([0.2, -0.15, 0.0]), moments([0.2, 0.0, -0.1])
    np.testing.assert_allclose(study._lifted([first, second], scene), [1.0, -1.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(study._lifted([first], scene), [0.0, -1.0, 0.0], atol=1e-9)
    np.testing.assert_array_equal(study._lifted([], scene), np.zeros(3))
    # an advice made before the moments were written is refused, and says so
    with pytest.raises(SystemExit, match="advise again"):
        study._lifted([None], scene)
