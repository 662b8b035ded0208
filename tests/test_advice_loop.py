"""The advice's answer loop on hostile and unlucky input (``creference advise BATCH --merge`` and
``--apply``): answers reach the frame of their full key, the user's scene file keeps what it had
(its other keys, its format version, its mode), a set of files is written whole or not at all, a
result's ``batch.source`` is checked against the scene it was estimated from, hidden temporary
files are passed over, and a second run that changes nothing says so and writes nothing.

The batch folders here are made without estimating: each frame's scene copy and a result that
records the scene's fingerprint and source, written by the batch's own writer (``record_result``)."""

import copy
import csv
import json
import os
import stat
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.cli.main import example_scene_path, main
from creference_bayes.io.labelstudio import label_studio_task
from creference_bayes.io.result import RESULT_FORMAT
from creference_bayes.io.scene import load_scene, scene_fingerprint
from creference_bayes.workflows.batch.files import layout, record_result


def _batch(root: Path, scenes: dict) -> Path:
    """``root/in/KEY.json`` (the user's scene files, ``scenes``: KEY → scene dict) and the batch
    folder ``root/out`` a batch over them leaves: each frame's copy and a result of its scene."""
    out = root / "out"
    for key, d in scenes.items():
        path = root / "in" / f"{key}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(d, indent=1))
        scene = load_scene(path)
        result = {"format": RESULT_FORMAT, "scene_id": {"sha256": scene_fingerprint(scene),
                                                        "image_size": [scene.image_width, scene.image_height]},
                  "objects": [{"id": t.id} for t in scene.targets]}
        record_result(layout(out, key), SimpleNamespace(key=key, path=path), scene, result, 0, {})
    return out


def _scene(seed: int) -> dict:
    d, _ = truth_scene(seed, m=2, noise_px=1.0, n_annotations=1, sizes_known=False, focal_known=True)
    return d


def _answers(path: Path, rows: list[dict]) -> Path:
    fields = ["rank", "key", "target", "camera", "kind", "measure", "object", "line_px", "answer"]
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows({k: r.get(k, "") for k in fields} for r in rows)
    return path


def _request_export(path: Path, key: str, base: dict, worker: str = "w-new") -> Path:
    """A Label Studio export of one answered request task of frame ``key`` (made for the scene
    ``base``): the worker drew one more set of lines on ``base``'s first target, 1.5 px off."""
    answer = copy.deepcopy(base)
    answer["targets"] = answer["targets"][:1]
    corners = np.asarray(base["targets"][0]["dimension_lines"][0]["corners"]) + 1.5
    answer["targets"][0]["dimension_lines"] = [{"worker": worker, "corners": corners.tolist()}]
    anns = [a for a in label_studio_task(answer)["annotations"] if a["completed_by"] == worker]
    task = {"id": 1, "data": {"image": "", "creference_scene": base, "request_key": key}, "annotations": anns}
    path.write_text(json.dumps([task]))
    return path


def _lines(path: Path) -> list[int]:
    return [len(t.dimension_lines) for t in load_scene(path).targets]


def test_merge_finds_the_frame_by_its_full_key(tmp_path, capsys):
    """Frames a/cam1 and b/cam1 (two cameras' folders): the answer to a/cam1's request goes into
    a/cam1's scene file, and b/cam1's is not touched."""
    a, b = _scene(1), _scene(2)
    out = _batch(tmp_path, {"a/cam1": a, "b/cam1": b})
    before_b = (tmp_path / "in" / "b" / "cam1.json").read_bytes()
    export = _request_export(tmp_path / "export.json", "a/cam1", a)
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "answered"), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered")]) == 0
    printed = capsys.readouterr().out
    assert _lines(tmp_path / "in" / "a" / "cam1.json") == [2, 1]
    assert (tmp_path / "in" / "b" / "cam1.json").read_bytes() == before_b
    assert f"{tmp_path / 'in' / 'a' / 'cam1.json'}: t0: a set of dimension lines" in printed


def test_merge_refuses_a_name_two_frames_share(tmp_path, capsys):
    """Frames a/cam1 and a_cam1 both import as a_cam1.json: which one is meant is not known."""
    a = _scene(1)
    out = _batch(tmp_path, {"a/cam1": a, "a_cam1": _scene(2)})
    export = _request_export(tmp_path / "export.json", "a/cam1", a)
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "answered"), "--quiet"]) == 0
    before = {p: p.read_bytes() for p in (tmp_path / "in").rglob("*.json")}
    capsys.readouterr()
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered")]) == 2
    err = capsys.readouterr().err
    assert "'a/cam1'" in err and "'a_cam1'" in err and "a_cam1.json" in err and len(err.strip().splitlines()) == 1
    assert before == {p: p.read_bytes() for p in (tmp_path / "in").rglob("*.json")}


@pytest.mark.filterwarnings("ignore:.*unknown key ignored")  # the test's own reading of the files
def test_apply_keeps_the_users_file_but_for_the_answer(tmp_path, capsys):
    """A creference-scene/1 file with keys of its own, readable by its owner only: a mounting
    answer adds the camera's orientation prior and nothing else changes (its keys, its format, its
    mode). A creference-scene/2 file keeps its own keys under a size answer too."""
    v1 = json.loads(example_scene_path().read_text())
    v1["notes"] = "shot from the bridge"
    v1["project_metadata"] = {"owner": "survey team", "batch": 7}
    v2 = _scene(3)
    v2["notes"] = ["checked"]
    out = _batch(tmp_path, {"old": v1, "new": v2})
    old, new = tmp_path / "in" / "old.json", tmp_path / "in" / "new.json"
    old.chmod(0o600)
    new.chmod(0o640)
    rows = [{"rank": "1", "key": "old", "kind": "mounting", "answer": "1.5,4,0.5"},
            {"rank": "2", "key": "new", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 0
    got = json.loads(old.read_text())
    assert got["format"] == "creference-scene/1" and "orientation_prior" in got["camera"]
    assert {k: v for k, v in got["camera"].items() if k != "orientation_prior"} == v1["camera"]
    assert {k: v for k, v in got.items() if k != "camera"} == {k: v for k, v in v1.items() if k != "camera"}
    assert load_scene(old).orientation_prior.height_median_m == pytest.approx(1.5, rel=0.05)
    assert stat.S_IMODE(old.stat().st_mode) == 0o600
    got = json.loads(new.read_text())
    assert got["notes"] == ["checked"] and got["format"] == v2["format"]
    assert load_scene(new).targets[0].size_prior.source == "catalogue"
    assert stat.S_IMODE(new.stat().st_mode) == 0o640


def test_an_answer_a_version_1_file_cannot_hold_is_refused_by_name(tmp_path, capsys):
    """A distance between two targets needs two targets; a target's own length names its target,
    which a creference-scene/1 reference cannot: refused, naming the file, and nothing written."""
    v1 = json.loads(example_scene_path().read_text())
    out = _batch(tmp_path, {"old": v1})
    path = tmp_path / "in" / "old.json"
    before = path.read_bytes()
    tid = load_scene(path).targets[0].id
    rows = [{"rank": "1", "key": "old", "target": tid, "kind": "reference", "measure": "length", "object": tid,
             "answer": "1.2"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "creference-scene/1" in err and len(err.strip().splitlines()) == 1
    assert path.read_bytes() == before


def test_apply_writes_every_file_or_none(tmp_path, capsys, monkeypatch):
    """The second of two files fails to write (the disk is full): the first is not written either."""
    out = _batch(tmp_path, {"f0": _scene(4), "f1": _scene(5)})
    before = {p.name: p.read_bytes() for p in (tmp_path / "in").glob("*.json")}
    rows = [{"rank": str(k + 1), "key": f"f{k}", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"}
            for k in range(2)]
    calls = []
    real = os.fsync

    def full(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real(fd)

    monkeypatch.setattr(os, "fsync", full)
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 2
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert "No space left on device" in err and len(err.strip().splitlines()) == 1
    assert before == {p.name: p.read_bytes() for p in (tmp_path / "in").glob("*.json")}
    assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["f0.json", "f1.json"]  # no temporary left


def test_apply_refuses_a_result_that_names_another_scene(tmp_path, capsys):
    """f0's result edited to name f1's scene file: an answer for f0 is refused, naming the result
    and the path, and f1's file is not touched."""
    out = _batch(tmp_path, {"f0": _scene(4), "f1": _scene(5)})
    result = out / "results" / "f0.json"
    d = json.loads(result.read_text())
    other = tmp_path / "in" / "f1.json"
    d["batch"]["source"] = str(other.resolve())
    result.write_text(json.dumps(d))
    before = other.read_bytes()
    rows = [{"rank": "1", "key": "f0", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(result) in err and str(other.resolve()) in err and len(err.strip().splitlines()) == 1
    assert other.read_bytes() == before
    result.write_text('{"format": "creference-res')  # a result cut short
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{result}: not a result file" in err and len(err.strip().splitlines()) == 1


def test_apply_after_merge_still_finds_its_scene(tmp_path, capsys):
    """--merge first, then --apply (the loop's order): the merged lines change the scene's
    fingerprint, and the scene is still the result's (the same scene with answers added)."""
    a = _scene(6)
    out = _batch(tmp_path, {"f0": a})
    export = _request_export(tmp_path / "export.json", "f0", a)
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "answered"), "--quiet"]) == 0
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered"), "--quiet"]) == 0
    rows = [{"rank": "1", "key": "f0", "target": "t1", "kind": "size", "answer": "4.0,1.8,1.5"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 0
    scene = load_scene(tmp_path / "in" / "f0.json")
    assert [len(t.dimension_lines) for t in scene.targets] == [2, 1] and scene.targets[1].size_prior is not None


def test_merge_passes_over_hidden_temporary_files(tmp_path, capsys):
    """An interrupted write leaves ``.NAME.json.XXXX.json`` behind, half-written: not a scene."""
    a = _scene(7)
    out = _batch(tmp_path, {"f0": a})
    export = _request_export(tmp_path / "export.json", "f0", a)
    answered = tmp_path / "answered"
    assert main(["import", "label-studio", str(export), "--out", str(answered), "--quiet"]) == 0
    (answered / ".f0.json.1a2b3c4d.json").write_text('{"format": "creference-sce')
    (out / "results" / ".f0.json.5e6f7a8b.json").write_text('{"format": "creference-res')
    capsys.readouterr()
    assert main(["advise", str(out), "--merge", str(answered)]) == 0
    assert _lines(tmp_path / "in" / "f0.json") == [2, 1]
    assert "1a2b3c4d" not in capsys.readouterr().err


def test_a_second_run_that_changes_nothing_says_so_and_writes_nothing(tmp_path, capsys):
    a = _scene(8)
    out = _batch(tmp_path, {"f0": a})
    path = tmp_path / "in" / "f0.json"
    rows = [{"rank": "1", "key": "f0", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"},
            {"rank": "2", "key": "f0", "kind": "mounting", "answer": "1.5,4,0.5"}]
    answers = _answers(tmp_path / "a.csv", rows)
    assert main(["advise", str(out), "--apply", str(answers)]) == 0
    printed = capsys.readouterr().out
    assert "run creference batch" in printed
    assert printed.count("note: a catalogue size ties the camera") == 1   # what the size costs, said once
    inode, text = path.stat().st_ino, path.read_bytes()
    assert main(["advise", str(out), "--apply", str(answers)]) == 0
    printed = capsys.readouterr().out
    assert "nothing changed" in printed and "run creference batch" not in printed
    assert (path.stat().st_ino, path.read_bytes()) == (inode, text)

    export = _request_export(tmp_path / "export.json", "f0", a)
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "answered"), "--quiet"]) == 0
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered")]) == 0
    assert "run creference batch" in capsys.readouterr().out
    inode, text = path.stat().st_ino, path.read_bytes()
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered")]) == 0
    printed = capsys.readouterr().out
    assert "nothing changed" in printed and "run creference batch" not in printed
    assert (path.stat().st_ino, path.read_bytes()) == (inode, text)


def test_apply_keeps_a_scene_file_that_is_a_symlink_a_link(tmp_path, capsys):
    """The user's scene file is a link into another folder: the answer goes into the file it points
    to, and the link stays a link."""
    out = _batch(tmp_path, {"new": _scene(3)})
    link = tmp_path / "in" / "new.json"
    real = tmp_path / "store" / "new.json"
    real.parent.mkdir()
    link.rename(real)
    link.symlink_to(real)
    rows = [{"rank": "1", "key": "new", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows)), "--quiet"]) == 0
    assert link.is_symlink() and link.resolve() == real
    assert load_scene(real).targets[0].size_prior.source == "catalogue"


def test_cvat_requests_name_frames_of_one_name_in_two_folders_apart_and_each_merges_back(tmp_path, capsys):
    """Frames a/cam1 and b/cam1 without an image path: two CVAT images (a_cam1.jpg, b_cam1.jpg),
    not one, and each image's answer goes into its own frame's scene file."""
    import xml.etree.ElementTree as ET

    from creference_bayes.io.cvat import cvat_xml
    from creference_bayes.workflows.advice.requests import cvat_requests

    a, b = _scene(1), _scene(2)
    assert not a["image"].get("path") and not b["image"].get("path")
    out = _batch(tmp_path, {"a/cam1": a, "b/cam1": b})
    size = SimpleNamespace(kind="size", line=None)
    xml = cvat_requests([(key, load_scene(tmp_path / "in" / f"{key}.json"), size) for key in ("a/cam1", "b/cam1")])
    names = [img.get("name") for img in ET.fromstring(xml.split("\n", 1)[1]).findall("image")]
    assert names == ["a_cam1.jpg", "b_cam1.jpg"]
    answered = []
    for d, shift in ((a, 1.5), (b, -2.0)):  # each worker drew one more set of lines on the first target
        d = copy.deepcopy(d)
        corners = np.asarray(d["targets"][0]["dimension_lines"][0]["corners"]) + shift
        d["targets"][0]["dimension_lines"].append({"worker": "w-new", "corners": corners.tolist()})
        answered.append(d)
    (tmp_path / "annotations.xml").write_text(cvat_xml(answered, image_names=names))
    assert main(["import", "cvat", str(tmp_path / "annotations.xml"), "--out", str(tmp_path / "answered"),
                 "--quiet"]) == 0
    capsys.readouterr()
    assert main(["advise", str(out), "--merge", str(tmp_path / "answered")]) == 0
    for key, shift in (("a/cam1", 1.5), ("b/cam1", -2.0)):
        lines = load_scene(tmp_path / "in" / f"{key}.json").targets[0].dimension_lines
        assert len(lines) == 2 and np.allclose(lines[1].corners - lines[0].corners, shift, atol=0.01), key


def test_advice_refuses_to_replace_a_plan_holding_answers_not_yet_applied(tmp_path, capsys):
    """Answers typed into the plan's requests.csv and not yet put in: a new advice would replace
    the file, so it refuses before advising, names the answers and what to do, and leaves the
    file as it was; once they are applied the file may be replaced (the check lets it through)."""
    from creference_bayes.cli.advise import _keep_answers

    out = _batch(tmp_path, {"f0": _scene(9), "f1": _scene(10)})
    (out / "advice").mkdir()
    rows = [{"rank": "1", "key": "f0", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"},
            {"rank": "2", "key": "f1", "target": "t1", "kind": "size", "answer": ""}]
    plan = _answers(out / "advice" / "requests.csv", rows)
    before = plan.read_bytes()
    capsys.readouterr()
    assert main(["advise", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "1 answer not yet in the scene files (t0: size [4.0, 1.8, 1.5] m)" in err, err
    assert f"--apply {plan}" in err and "nothing was advised" in err
    assert plan.read_bytes() == before
    assert main(["advise", str(out), "--apply", str(plan), "--quiet"]) == 0
    _keep_answers(str(out), plan)  # every answer in its scene file now: no error


def test_a_cameras_mounting_counts_as_one_answer_in_every_frame_it_goes_to(tmp_path, capsys):
    scenes = {f"f{i}": _scene(11 + i) for i in range(3)}
    for d in scenes.values():
        d["camera"]["id"] = "cam-a"
    out = _batch(tmp_path, scenes)
    rows = [{"rank": "1", "key": "f0", "camera": "cam-a", "kind": "mounting", "answer": "1.5,4,0.5"},
            {"rank": "2", "key": "f1", "target": "t0", "kind": "size", "answer": "4.0,1.8,1.5"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows))]) == 0
    assert "2 answers put into 3 scene file(s);" in capsys.readouterr().out


def test_two_frames_given_the_same_mounting_are_two_answers(tmp_path, capsys):
    """Each frame's own mounting row, the same values in both: two answers, not one (an answer is
    its row, whatever its text)."""
    out = _batch(tmp_path, {"f0": _scene(14), "f1": _scene(15)})
    rows = [{"rank": "1", "key": "f0", "kind": "mounting", "answer": "1.65,0,0"},
            {"rank": "2", "key": "f1", "kind": "mounting", "answer": "1.65,0,0"}]
    assert main(["advise", str(out), "--apply", str(_answers(tmp_path / "a.csv", rows))]) == 0
    assert "2 answers put into 2 scene file(s);" in capsys.readouterr().out
