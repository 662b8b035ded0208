"""Label Studio import/export: a hand-written export in the documented JSON format, the round trip
through simulated scenes, the shipped configs, and one test per kind of bad input."""

import copy
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.cli import main
from creference_bayes.io.annotation_tools import REFERENCE_FIELDS, ConversionError
from creference_bayes.io.labelstudio import (TARGET_LABELS, label_studio_config, label_studio_task,
                                             label_studio_tasks, read_export, read_users,
                                             scenes_from_label_studio)

DATA = Path(__file__).parent / "data"
EXPORT = DATA / "label_studio_export.json"


def _export():
    return json.loads(EXPORT.read_text())


# ----------------------------------------------------------------------------------------------
# the hand-written export: values computed by hand from the percentages (x / 100 × width)


def test_export_file_gives_the_hand_computed_scenes(assert_same_scene):
    report = scenes_from_label_studio(_export())
    scenes = {s.name: s.scene for s in report.scenes}
    assert sorted(scenes) == ["cupboard", "table"]
    cupboard = {
        "format": "creference-scene/1",
        "image": {"width": 4000, "height": 3000},
        "horizon": [[0, 1200], [4000, 1260]],
        "target": {"id": "cupboard", "dimensions_m": {"length": 1.2, "width": 0.5, "height": 2.0},
                   "dimension_lines": [
                       {"worker": "3", "seconds": 120.0,  # lead_time 240 s over 2 items
                        "corners": [[1600, 2400], [2000, 2340], [1520, 2280], [1600, 1500]]},
                       {"worker": "6", "corners": [[1640, 2430], [2040, 2370], [1480, 2250], [1640, 1470]]}]},
        "references": [
            {"measure": "length", "mode": "direct", "value": 80, "unit": "in", "object": "sofa",
             "confidence": 0.6, "worker": "3", "seconds": 120.0, "line": [[400, 2700], [1200, 2760]]},
            {"measure": "width", "mode": "relative", "range": [0.9, 1.2], "worker": "4",
             "seconds": 64.4, "line": [[3000, 2850], [3400, 2820]]}],
    }
    table = {
        "format": "creference-scene/1",
        "image": {"width": 2000, "height": 1000},          # from data: no original_width in results
        "camera": {"focal_length_px": 1800.0},
        "horizon": [[0, 300], [2000, 300]],
        "target": {"id": "table", "dimensions_m": {"length": 1.6, "width": 0.8, "height": 0.75},
                   "dimension_lines": [{"worker": "ann@example.com", "seconds": 150.0,
                                        "corners": [[1000, 700], [1200, 700], [900, 650], [1000, 400]]}]},
        "references": [{"measure": "distance", "mode": "direct", "range": [10, 15], "unit": "ft",
                        "worker": "ann@example.com", "seconds": 150.0,
                        "line": [[400, 999], [500, 750]]}],
    }
    assert_same_scene(scenes["cupboard"], cupboard)
    assert_same_scene(scenes["table"], table)


def test_export_file_reports_the_bad_task_and_notes_the_unannotated_one():
    report = scenes_from_label_studio(_export())
    assert [str(e) for e in report.errors] == [
        "task 19, annotation 301, region 'a1b2': reference line has 3 points, expected 2"]
    assert "task 20: no annotations yet; skipped" in report.notes
    assert not report.ok


def test_cli_writes_the_good_tasks_and_exits_2(tmp_path, capsys):
    out = tmp_path / "scenes"
    assert main(["import", "label-studio", str(EXPORT), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "error: task 19, annotation 301, region 'a1b2': reference line has 3 points, expected 2" in err
    assert sorted(p.name for p in out.iterdir()) == ["cupboard.json", "table.json"]  # no temp files
    from creference_bayes.io.scene import load_scene

    assert load_scene(out / "cupboard.json").target.id == "cupboard"


def test_cli_exit_0_when_every_task_converts(tmp_path):
    tasks = [t for t in _export() if t["id"] != 19]
    path = tmp_path / "export.json"
    path.write_text(json.dumps(tasks))
    assert main(["import", "label-studio", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0


def test_image_dir_sets_a_path_relative_to_the_output_folder(tmp_path):
    images = tmp_path / "photos"
    images.mkdir()
    report = scenes_from_label_studio(_export(), image_dir=images, out_dir=tmp_path / "out")
    scenes = {s.name: s.scene for s in report.scenes}
    assert scenes["cupboard"]["image"]["path"] == "../photos/ab12cd34-room.jpg"
    assert scenes["table"]["image"]["path"] == "../photos/street.png"
    tasks = _export()
    tasks[0]["data"]["image"] = "/data/local-files/?d=shoots/day%201/room.jpg"
    tasks[1]["data"]["image_path"] = "given/as/is.png"
    report = scenes_from_label_studio(tasks, image_dir=images, out_dir=tmp_path / "out")
    scenes = {s.name: s.scene for s in report.scenes}
    assert scenes["cupboard"]["image"]["path"] == "../photos/room.jpg"
    assert scenes["table"]["image"]["path"] == "given/as/is.png"


def test_users_file_names_the_workers(tmp_path):
    users = tmp_path / "users.json"
    users.write_text(json.dumps([{"id": 3, "username": "alice", "email": "a@x.org"},
                                 {"id": 4, "username": "", "email": "bob@x.org"}]))
    report = scenes_from_label_studio(_export(), users=read_users(users))
    cup = next(s.scene for s in report.scenes if s.name == "cupboard")
    assert [d["worker"] for d in cup["target"]["dimension_lines"]] == ["alice", "6"]
    assert [r["worker"] for r in cup["references"]] == ["alice", "bob@x.org"]


def test_print_config_is_the_shipped_config(capsys):
    assert main(["import", "label-studio", "--print-config"]) == 0
    assert capsys.readouterr().out == label_studio_config("keypoints")
    assert main(["import", "label-studio", "--print-config", "--lines", "vectors"]) == 0
    assert capsys.readouterr().out == label_studio_config("vectors")


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
def test_configs_name_what_the_importer_reads(lines):
    root = ET.fromstring(label_studio_config(lines))
    kp = root.find(".//KeyPointLabels")
    labels = [e.get("value") for e in kp.findall("Label")]
    assert labels[:4] == list(TARGET_LABELS) and kp.get("name") == "points"
    if lines == "keypoints":
        assert labels[4:] == ["reference start", "reference end", "horizon"]
    else:
        vl = root.find(".//VectorLabels")
        assert vl.get("name") == "lines" and [e.get("value") for e in vl.findall("Label")] == [
            "reference", "horizon"]
        assert (vl.get("minPoints"), vl.get("maxPoints")) == ("2", "2")
    controls = {e.get("name"): e for e in root.iter() if e.get("perRegion") == "true"}
    assert set(controls) == set(REFERENCE_FIELDS)
    for e in controls.values():
        assert e.get("toName") == "image"
        assert e.get("whenLabelValue") == ("reference start" if lines == "keypoints" else "reference")
    for e in root.iter("Number"):
        # Label Studio rejects entries that are not a multiple of `step` from `min` (and a decimal
        # step can reject valid ones): no step at all means no such check.
        assert e.get("step") is None


# ----------------------------------------------------------------------------------------------
# round trip: simulated scene → Label Studio task → import → the same scene


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_through_a_task(lines, seed, assert_same_scene):
    scene = simulate_scene(np.random.default_rng(seed), tier="high", n_references=7,
                           target_id=f"obj{seed}")
    task = json.loads(json.dumps(label_studio_task(scene, task_id=5, lines=lines)))  # as a file would
    report = scenes_from_label_studio([task])
    assert report.ok and report.notes == ()
    (back,) = report.scenes
    assert back.name == f"obj{seed}"
    assert_same_scene(back.scene, scene, atol=1e-9)


def test_round_trip_with_a_worker_doing_several_items(assert_same_scene):
    scene = simulate_scene(np.random.default_rng(4), tier="low", n_references=3, n_target_annotations=3)
    lines = scene["target"]["dimension_lines"]
    lines[0]["worker"] = lines[1]["worker"] = "w"       # two target annotations by one worker
    for r in scene["references"]:
        r["worker"], r["seconds"] = "w", 183.5          # and all the references too
    del lines[2]["worker"]                               # an anonymous one
    scene["references"][0]["confidence"] = 0.7
    tasks = label_studio_tasks([scene], lines="keypoints")
    anns = tasks[0]["annotations"]
    assert [a.get("completed_by") for a in anns] == ["w", "w", None]  # one target per annotation
    (back,) = scenes_from_label_studio(tasks).scenes
    assert_same_scene(back.scene, scene)


def test_predictions_carry_the_same_results():
    scene = simulate_scene(np.random.default_rng(0), n_references=2)
    a = label_studio_task(scene)
    p = label_studio_task(scene, as_predictions=True)
    assert "annotations" not in p
    assert [x["result"] for x in p["predictions"]] == [x["result"] for x in a["annotations"]]


# ----------------------------------------------------------------------------------------------
# bad input: each message names the task and the region


def _task():
    """Task 17 of the file, alone: a valid task to break in one way."""
    return copy.deepcopy(_export()[0])


def _results(task, ann=0):
    return task["annotations"][ann]["result"]


def _find(results, rid, from_name=None):
    return next(r for r in results if r.get("id") == rid and (from_name is None or r.get("from_name") == from_name))


def _break(**kinds):
    t = _task()
    res = _results(t)
    kind = next(iter(kinds))
    if kind == "missing_corner":
        res.remove(_find(res, "a3"))
    elif kind == "two_t1":
        res.append({**copy.deepcopy(_find(res, "a1")), "id": "a1bis"})
    elif kind == "value_and_range":
        res.append({"id": "rs1", "type": "number", "from_name": "range_low", "to_name": "image",
                    "value": {"number": 70}})
    elif kind == "relative_with_unit":
        _find(res, "rs1", "mode")["value"]["choices"] = ["relative"]
    elif kind == "direct_without_unit":
        res.remove(_find(res, "rs1", "unit"))
    elif kind == "relative_distance":
        _find(_results(t, 1), "rs2", "measure")["value"]["choices"] = ["distance"]
    elif kind == "confidence":
        _find(res, "rs1", "confidence_pct")["value"]["number"] = 150
    elif kind == "not_a_number":
        _find(res, "rs1", "value")["value"]["number"] = "eighty"
    elif kind == "no_measure":
        res.remove(_find(res, "rs1", "measure"))
    elif kind == "half_range":
        _results(t, 1).remove(_find(_results(t, 1), "rs2", "range_high"))
    elif kind == "unlinked":
        res.remove(next(r for r in res if r.get("type") == "relation"))
        res += [{**copy.deepcopy(_find(res, "rs1", "points")), "id": "rs9"},
                {**copy.deepcopy(_find(res, "re1", "points")), "id": "re9"}]
    elif kind == "bad_relation":
        next(r for r in res if r.get("type") == "relation")["to_id"] = "a2"
    elif kind == "unknown_label":
        _find(res, "h1")["value"]["keypointlabels"] = ["sky"]
    elif kind == "rotated":
        _find(res, "a2")["image_rotation"] = 90
    elif kind == "sizes_disagree":
        _find(res, "a2")["original_width"] = 2000
    elif kind == "no_size":
        for ann in t["annotations"]:
            for r in ann["result"]:
                r.pop("original_width", None)
                r.pop("original_height", None)
    elif kind == "far_outside":
        _find(res, "re1")["value"]["x"] = 900.0
    elif kind == "one_horizon_point":
        res.remove(_find(res, "h2"))
    elif kind == "controls_on_a_corner":
        res.append({"id": "a1", "type": "number", "from_name": "value", "to_name": "image",
                    "value": {"number": 3}})
    elif kind == "no_target":
        t["annotations"] = [t["annotations"][1]]
    elif kind == "missing_dims":
        del t["data"]["target_width_m"]
    elif kind == "bad_dims":
        t["data"]["target_height_m"] = "two metres"
    return t


@pytest.mark.parametrize("kind, message", [
    ("missing_corner", "task 17, annotation 101: target corner(s) ['t3 end of width'] missing"),
    ("two_t1", "task 17, annotation 101: two points labelled 't1 bottom corner'"),
    ("value_and_range", "task 17, annotation 101, region 'rs1': both a value (80) and a range given"),
    ("relative_with_unit", "task 17, annotation 101, region 'rs1': a relative measurement takes no unit, got 'in'"),
    ("direct_without_unit", "task 17, annotation 101, region 'rs1': a direct measurement needs a unit"),
    ("relative_distance", "task 17, annotation 102, region 'rs2': a distance cannot be relative"),
    ("confidence", "task 17, annotation 101, region 'rs1': confidence (%) must be in [0, 100], got 150"),
    ("not_a_number", "task 17, annotation 101, region 'rs1': value is not a number: 'eighty'"),
    ("no_measure", "task 17, annotation 101, region 'rs1': reference has no measure"),
    ("half_range", "task 17, annotation 102, region 'rs2': a range needs both low and high, got only range low 0.9"),
    ("unlinked", "is not linked to a 'reference end' (draw a relation between the two ends)"),
    ("bad_relation", "task 17, annotation 101, region 'rs1': a relation links 'reference start' to 't2 end of length'"),
    ("unknown_label", "task 17, annotation 101, region 'h1': unknown keypoint label 'sky'"),
    ("rotated", "task 17, annotation 101, region 'a2': image_rotation 90 is not supported"),
    ("sizes_disagree", "task 17: results disagree on the image size: 4000x3000"),
    ("no_size", "task 17: no image size"),
    ("far_outside", "task 17, annotation 101, region 'rs1': references[0].line[1]: point [36000, 2760] is far outside"),
    ("one_horizon_point", "task 17, annotation 101: 1 points labelled 'horizon', expected 2"),
    ("controls_on_a_corner", "task 17, annotation 101, region 'a1': a 't1 bottom corner' point carries reference fields"),
    ("no_target", "task 17: no annotation draws the target's dimension lines"),
    ("missing_dims", "task 17: data has ['target_length_m', 'target_height_m'] but not ['target_width_m']"),
    ("bad_dims", "task 17: data.target_height_m is not a number: 'two metres'"),
])
def test_bad_task_is_reported_with_task_and_region(kind, message):
    good = _export()[1]
    report = scenes_from_label_studio([_break(**{kind: True}), good])
    assert [s.name for s in report.scenes] == ["table"], "the other task is still converted"
    (err,) = report.errors
    assert message in str(err), str(err)
    assert "\n" not in str(err)


def test_missing_size_can_come_from_the_targets_table(tmp_path):
    from creference_bayes.io.annotation_tools import load_target_table

    t = _task()
    for k in ("target_length_m", "target_width_m", "target_height_m"):
        del t["data"][k]
    assert "pass --targets" in str(scenes_from_label_studio([t]).errors[0])
    csv = tmp_path / "targets.csv"
    csv.write_text("target_id,length_m,width_m,height_m,focal_length_px\ncupboard,1.2,0.5,2.0,2100\n")
    (s,) = scenes_from_label_studio([t], targets=load_target_table(csv)).scenes
    assert s.scene["target"]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}
    assert s.scene["camera"]["focal_length_px"] == 2100
    csv.write_text("target_id,length_m,width_m,height_m\ncupboard,1.3,0.5,2.0\n")
    err = scenes_from_label_studio([_task()], targets=load_target_table(csv)).errors[0]
    assert "length 1.2 m in the export but 1.3 m in the --targets table" in str(err)


def test_duplicate_target_ids_keep_the_first_task():
    a, b = _task(), _task()
    b["id"] = 99
    report = scenes_from_label_studio([a, b])
    assert [s.source for s in report.scenes] == ["task 17"]
    assert "task 99: file name 'cupboard.json' is already used by task 17" in str(report.errors[0])


def test_vector_with_three_points_and_closed_vector():
    t = _export()[1]
    t["id"] = 5
    verts = t["completions"][0]["result"][4]["value"]["vertices"]
    verts.append({"id": "v1p2", "x": 30, "y": 70, "prevPointId": "v1p1", "isBezier": False})
    assert str(scenes_from_label_studio([t]).errors[0]) == (
        "task 5, annotation 201, region 'v1': reference line has 3 points, expected 2")
    t = _export()[1]
    t["completions"][0]["result"][4]["value"]["closed"] = True
    assert "a closed vector (a polygon) is not a line" in str(scenes_from_label_studio([t]).errors[0])


def test_vector_vertices_follow_prev_point_id():
    t = _export()[1]
    verts = t["completions"][0]["result"][4]["value"]["vertices"]
    verts.reverse()  # stored out of order: the chain of prevPointId still gives the drawing order
    (s,) = scenes_from_label_studio([t]).scenes
    assert s.scene["references"][0]["line"][0] == pytest.approx([400, 999])


@pytest.mark.parametrize("content, message", [
    ({"tasks": []}, "expected a list of tasks"),
    ([{"image": "a.jpg", "id": 3, "points": []}], "task 3: no 'data' and no 'annotations'"),
])
def test_not_a_json_export(content, message):
    with pytest.raises(ConversionError, match=message):
        report = scenes_from_label_studio(content)
        raise report.errors[0]


def test_unreadable_file_is_a_one_line_usage_error(tmp_path, capsys):
    bad = tmp_path / "export.json"
    bad.write_text('[{"id": 1,')
    assert main(["import", "label-studio", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "not valid JSON" in err and "\n" not in err
    with pytest.raises(ConversionError, match="not valid JSON"):
        read_export(bad)


def test_cli_needs_an_export_and_an_output_folder(tmp_path, capsys):
    assert main(["import", "label-studio"]) == 2
    assert main(["import", "label-studio", str(EXPORT)]) == 2
    err = capsys.readouterr().err
    assert "give the export file" in err and "--out DIR is required" in err


def test_vertices_without_ids_keep_their_list_order():
    # Label Studio's SDK writes vertices with "id": null and "prevPointId": null
    t = _export()[1]
    for v in t["completions"][0]["result"][4]["value"]["vertices"]:
        v["id"] = v["prevPointId"] = None
    (s,) = scenes_from_label_studio([t]).scenes
    assert np.allclose(s.scene["references"][0]["line"], [[400, 999], [500, 750]])


def _doc_blocks(name: str) -> list:
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / name).read_text()
    return [json.loads(b) for b in re.findall(r"```json\n(.*?)```", text, re.S)]


def test_the_documented_annotation_imports_as_a_references_only_annotation():
    """docs/import.md's example annotation (references only, no target points) converts as it says."""
    from creference_bayes.cli.main import example_scene_path
    from creference_bayes.io.labelstudio import scenes_from_label_studio
    from creference_bayes.io.labelstudio_export import label_studio_tasks

    documented = next(b for b in _doc_blocks("import.md") if isinstance(b, dict) and "completed_by" in b)
    task = label_studio_tasks([json.loads(example_scene_path().read_text())])[0]
    targets_only = [a for a in task["annotations"] if str(a["completed_by"]).startswith("t")]
    task["annotations"] = targets_only + [documented]
    report = scenes_from_label_studio([task])
    assert not report.errors, report.errors
    (scene,) = report.scenes
    (ref,) = scene.scene["references"]
    assert (ref["object"], ref["measure"], ref["mode"], ref["unit"], ref["range"], ref["worker"]) == \
        ("dining table", "width", "direct", "m", [0.734, 0.9024], "r01")
    assert ref["line"][0] == pytest.approx([0.287412 * 2880, 0.596782 * 1800], abs=0.01)


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
def test_the_configs_comment_lists_every_documented_task_field(lines):
    import re
    from pathlib import Path

    from creference_bayes.io.labelstudio import label_studio_config

    doc = (Path(__file__).resolve().parents[1] / "docs" / "import.md").read_text()
    table = doc[doc.index("| field | required | meaning |"):]
    table = table[:table.index("\n\n")]
    fields = set(re.findall(r"^\| `([a-z_]+)`", table, re.M)) | set(re.findall(r"`(target_[a-z]+_m)`", table))
    assert {"image", "target_id", "ground_truth", "image_width"} <= fields
    comment = label_studio_config(lines).split("-->")[0]
    missing = sorted(f for f in fields if f not in comment)
    assert not missing, missing


# ----------------------------------------------------------------------------------------------
# the --targets table: rows keyed by image and target; a focal length without sizes


def _no_dims(task):
    for k in ("target_length_m", "target_width_m", "target_height_m"):
        del task["data"][k]
    return task


def test_targets_rows_are_keyed_by_image_and_target(tmp_path):
    from creference_bayes.io.annotation_tools import load_target_table

    a, b = _no_dims(_task()), _no_dims(_task())
    b["id"], b["data"]["image"], b["data"]["target_id"] = 99, "/data/local-files/?d=yard/other.jpg", "cupboard2"
    csv = tmp_path / "t.csv"
    csv.write_text("image,target_id,length_m,width_m,height_m,focal_length_px\n"
                   "ab12cd34-room.jpg,cupboard,1.2,0.5,2.0,\n"   # the file name of data.image
                   "yard/other.jpg,cupboard2,0.9,0.4,1.0,\n"     # the path of a local file
                   "other.jpg,,,,,2400\n"                        # a camera-only row
                   "elsewhere.jpg,cupboard,3,3,3,\n")            # another image: not this cupboard
    report = scenes_from_label_studio([a, b], targets=load_target_table(csv))
    assert report.ok, report.errors
    scenes = {s.name: s.scene for s in report.scenes}
    assert scenes["cupboard"]["target"]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}
    assert "camera" not in scenes["cupboard"]
    assert scenes["cupboard2"]["target"]["dimensions_m"] == {"length": 0.9, "width": 0.4, "height": 1.0}
    assert scenes["cupboard2"]["camera"] == {"focal_length_px": 2400.0}
    assert ("--targets: no image of the export matches t.csv line 5 (image 'elsewhere.jpg'); not used"
            in report.notes)


def test_a_focal_length_row_of_a_frame_task_without_sizes(tmp_path):
    from creference_bayes.io.annotation_tools import load_target_table

    csv = tmp_path / "t.csv"
    csv.write_text("target_id,length_m,width_m,height_m,focal_length_px\ncupboard,,,,2100\n")
    (s,) = scenes_from_label_studio([_task()], targets=load_target_table(csv), frames=True).scenes
    assert s.scene["camera"] == {"focal_length_px": 2100.0}
    assert s.scene["targets"][0]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}


# ----------------------------------------------------------------------------------------------
# --frames on the one-target layout: the tasks of one image make one frame


def _second_target_task():
    """Task 17's image with another target, 'lamp' (its own task, as docs/import.md lays it out)."""
    t = _task()
    t["id"], t["data"]["target_id"] = 99, "lamp"
    t["data"].update(target_length_m=0.4, target_width_m=0.4, target_height_m=1.6)
    t["annotations"] = [t["annotations"][0]]
    t["annotations"][0]["result"] = [r for r in _results(t) if r.get("id") in ("a1", "a2", "a3", "a4")]
    for r in _results(t):
        r["value"]["x"] += 30
    return t


def test_frames_merge_the_tasks_of_one_image():
    report = scenes_from_label_studio([_task(), _second_target_task()], frames=True)
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.name == "ab12cd34-room" and s.source == "task 17, task 99 (one image)"
    d = s.scene
    assert [(t["id"], t["dimensions_m"]["height"], len(t["dimension_lines"])) for t in d["targets"]] == [
        ("cupboard", 2.0, 2), ("lamp", 1.6, 1)]
    # x % of 4000 px: a1 at 40 % + 30 %; annotation 101 of task 99 holds one item: 240 s
    assert d["targets"][1]["dimension_lines"] == [
        {"corners": [[2800, 2400], [3200, 2340], [2720, 2280], [2800, 1500]], "worker": "3", "seconds": 240.0}]
    assert [(r["mode"], r.get("target")) for r in d["references"]] == [("direct", None), ("relative", "cupboard")]
    assert d["horizon"] == [[0, 1200], [4000, 1260]]


def test_merged_one_target_tasks_split_their_truth_between_target_and_camera():
    camera = {"focal_length_px": 3000.0, "camera_height_m": 1.4, "pitch_rad": 0.05, "roll_rad": 0.0}
    first, second = _task(), _second_target_task()
    first["data"]["ground_truth"] = {"location_m": [0.5, 1.4, 5.0], "yaw_rad": 0.3, **camera}
    second["data"]["ground_truth"] = {"location_m": [1.5, 1.4, 6.0], "yaw_rad": -0.2, "handedness": -1, **camera}
    report = scenes_from_label_studio([first, second], frames=True)
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.scene["ground_truth"] == camera
    assert [t["ground_truth"] for t in s.scene["targets"]] == [
        {"location_m": [0.5, 1.4, 5.0], "yaw_rad": 0.3}, {"location_m": [1.5, 1.4, 6.0], "yaw_rad": -0.2, "handedness": -1}]
    second["data"]["ground_truth"]["camera_height_m"] = 1.6  # one camera: the tasks must agree on it
    (err,) = scenes_from_label_studio([first, second], frames=True).errors
    assert str(err) == ("task 17, task 99 (one image): data.ground_truth.camera_height_m is 1.4 in task 17 but 1.6 "
                        "in task 99 (the tasks of one image share it)")


@pytest.mark.parametrize("change, message", [
    (lambda t: t["data"].update(focal_length_px=1800),
     "task 17, task 99 (one image): data.focal_length_px is 2000 in task 17 but 1800 in task 99"),
    (lambda t: t["data"].update(target_id="cupboard"),
     "task 17, task 99 (one image): target 'cupboard' is in task 17 and in task 99"),
])
def test_the_tasks_of_one_frame_must_agree(change, message):
    first = _task()
    first["data"]["focal_length_px"] = 2000
    second = _second_target_task()
    change(second)
    report = scenes_from_label_studio([first, second], frames=True)
    assert report.scenes == ()
    (err,) = report.errors
    assert message in str(err), str(err)


def test_a_merged_frame_names_the_task_of_a_bad_region():
    second = _second_target_task()
    _find(_results(second), "a4")["value"]["y"] = 900.0  # far outside the image
    (err,) = scenes_from_label_studio([_task(), second], frames=True).errors
    assert str(err).startswith("task 17, task 99 (one image), task 99, annotation 101, region 'a1': "
                               "targets[1].dimension_lines[0]"), str(err)


# ----------------------------------------------------------------------------------------------
# malformed exports: a message naming the task, annotation, region and value, never a traceback


def test_a_result_that_is_not_a_list():
    t = _task()
    t["annotations"][1]["result"] = 150.0
    (err,) = scenes_from_label_studio([t]).errors
    assert str(err) == "task 17, annotation 102: 'result' is not a list: 150.0"


def test_a_vertex_whose_prev_point_id_is_not_an_id():
    t = _export()[1]
    t["completions"][0]["result"][4]["value"]["vertices"][1]["prevPointId"] = {"id": "v1p0"}
    (err,) = scenes_from_label_studio([t]).errors
    assert str(err) == ("task 18, annotation 201, region 'v1': vertex 1 ('v1p1'): prevPointId is not a vertex "
                        "id: {'id': 'v1p0'}")


def test_a_missing_export_says_it_does_not_exist(tmp_path, capsys):
    path = tmp_path / "export.json"
    assert main(["import", "label-studio", str(path), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {path}: no such file (it does not exist)"


@pytest.mark.parametrize("frames, truth", [
    (False, {"location_m": [1.0, 1.5, 6.0], "yaw_rad": 0.5}),  # a one-target scene's truth
    (True, {"camera_height_m": 1.5}),                          # a frame's: the camera's
])
def test_a_value_no_scene_file_can_hold_is_an_error_not_a_crash(tmp_path, capsys, frames, truth):
    t = _task()
    t["data"]["ground_truth"] = {**truth, "note": "INF"}
    export = tmp_path / "export.json"
    export.write_text(json.dumps([t]).replace('"INF"', "1e400"))  # JSON's 1e400 reads as infinity
    argv = ["import", "label-studio", str(export), "--out", str(tmp_path / "o")] + (["--frames"] if frames else [])
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == ("error: task 17, data.ground_truth: ground_truth.note: inf cannot "
                                               "be written (a scene file holds finite numbers, text, lists and "
                                               "objects)")
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())
