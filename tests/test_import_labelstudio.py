"""Label Studio import/export: a hand-written export in the documented JSON format, hand-written
tasks of several targets, round trips of scenes of one and several targets, the shipped configs,
the --targets table, the tasks of one image made one scene, request tasks, and one test per kind
of bad input (a message naming the task and the region, never a traceback)."""

import copy
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.cli import main
from creference_bayes.io.annotation_tools import REFERENCE_FIELDS, ConversionError, load_target_table
from creference_bayes.io.labelstudio import (DATA_FIELDS, TARGET_LABELS, label_studio_config, label_studio_task,
                                             label_studio_tasks, read_export, read_users, scenes_from_label_studio)
from creference_bayes.io.scene import load_scene, parse_scene
from creference_bayes.models.size_priors import KITTI_SIZE_PRIORS, SizePrior

DATA = Path(__file__).parent / "data"
EXPORT = DATA / "label_studio_export.json"
KAYAK = {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4, "log_sd": [0.1, 0.1, 0.2]}


def _export():
    return json.loads(EXPORT.read_text())


def tool_scene(seed=0, m=3):
    """A scene of ``m`` targets (conftest.truth_scene) holding everything the tools carry: two sets
    of lines per target (workers w0 and w1; each worker's items take the same time, as a Label
    Studio annotation's lead_time is shared equally among them), known sizes and class priors
    (the third target of a class of the scene's own), references of each kind (a ground segment
    with a confidence and an object, an anonymous one, a ratio to a target, a distance naming a
    target; in the order a task gives them back: by worker, the anonymous ones last), the
    horizon with its sd, the camera's and the targets' truth."""
    d, _ = truth_scene(seed, m=m, n_annotations=2, noise_px=1.0, horizon="sd", n_refs=2)
    for i, t in enumerate(d["targets"]):
        for k, dl in enumerate(t["dimension_lines"]):
            dl["seconds"] = 20.0 + 10.0 * k
        if i % 2 or i == 2:
            del t["dimensions_m"]
        if i == 2:
            t["class"] = "Kayak"
            d["classes"] = {"Kayak": KAYAK}
    w, h = d["image"]["width"], d["image"]["height"]
    ground, anonymous = d["references"]
    ground.update(worker="w0", seconds=20.0, confidence=0.7, object="kerb")
    del anonymous["worker"]
    d["references"] = [ground, {"measure": "length", "mode": "relative", "value": 2.5, "target": "t0", "worker": "w1",
                                "seconds": 30.0, "line": [[0.1 * w, 0.95 * h], [0.3 * w, 0.97 * h]]},
                       anonymous, {"measure": "distance", "mode": "direct", "range": [20, 30], "unit": "ft",
                                   "target": f"t{m - 1}", "line": [[0.7 * w, h - 1.0], [0.72 * w, 0.8 * h]]}]
    return d


# ----------------------------------------------------------------------------------------------
# the hand-written export: values computed by hand from the percentages (x / 100 × width)


def test_export_file_gives_the_hand_computed_scenes(assert_same_scene):
    report = scenes_from_label_studio(_export())
    scenes = {s.name: s.scene for s in report.scenes}
    assert sorted(scenes) == ["ab12cd34-room", "street"]  # named after the image
    cupboard = {
        "format": "creference-scene/2",
        "image": {"width": 4000, "height": 3000},
        "horizon": [[0, 1200], [4000, 1260]],
        "targets": [{"id": "cupboard", "dimensions_m": {"length": 1.2, "width": 0.5, "height": 2.0},
                     "dimension_lines": [
                         {"worker": "3", "seconds": 120.0,  # lead_time 240 s over 2 items
                          "corners": [[1600, 2400], [2000, 2340], [1520, 2280], [1600, 1500]]},
                         {"worker": "6", "corners": [[1640, 2430], [2040, 2370], [1480, 2250], [1640, 1470]]}]}],
        "references": [
            {"measure": "length", "mode": "direct", "value": 80, "unit": "in", "object": "sofa",
             "confidence": 0.6, "worker": "3", "seconds": 120.0, "line": [[400, 2700], [1200, 2760]]},
            {"measure": "width", "mode": "relative", "range": [0.9, 1.2], "worker": "4", "target": "cupboard",
             "seconds": 64.4, "line": [[3000, 2850], [3400, 2820]]}],
    }
    table = {
        "format": "creference-scene/2",
        "image": {"width": 2000, "height": 1000},          # from data: no original_width in results
        "camera": {"focal_length_px": 1800.0},
        "horizon": [[0, 300], [2000, 300]],
        "targets": [{"id": "table", "dimensions_m": {"length": 1.6, "width": 0.8, "height": 0.75},
                     "dimension_lines": [{"worker": "ann@example.com", "seconds": 150.0,
                                          "corners": [[1000, 700], [1200, 700], [900, 650], [1000, 400]]}]}],
        "references": [{"measure": "distance", "mode": "direct", "range": [10, 15], "unit": "ft",
                        "worker": "ann@example.com", "seconds": 150.0,
                        "line": [[400, 999], [500, 750]]}],
    }
    assert_same_scene(scenes["ab12cd34-room"], cupboard)
    assert_same_scene(scenes["street"], table)
    assert scenes["ab12cd34-room"]["references"][1]["target"] == "cupboard"  # written, not only implied


def test_export_file_reports_the_bad_task_and_notes_the_unannotated_one():
    report = scenes_from_label_studio(_export())
    assert [str(e) for e in report.errors] == [
        "task 19, annotation 301, region 'a1b2': reference line has 3 points, expected 2"]
    assert "task 20: no annotations yet; skipped" in report.notes
    assert not report.ok


def test_cli_writes_the_good_tasks_and_exits_2(tmp_path, capsys):
    out = tmp_path / "scenes"
    assert main(["import", "label-studio", str(EXPORT), "--out", str(out)]) == 2
    printed = capsys.readouterr()
    err = printed.err
    assert "error: task 19, annotation 301, region 'a1b2': reference line has 3 points, expected 2" in err
    # the last line counts every task not written: the one in error and the one nobody annotated
    assert printed.out.splitlines()[-1] == (f"2 scene(s) written to {out}, 1 skipped for errors, "
                                            "1 with nothing annotated yet skipped")
    assert sorted(p.name for p in out.iterdir()) == ["ab12cd34-room.json", "street.json"]  # no temp files
    scene = load_scene(out / "ab12cd34-room.json")
    assert scene.format == "creference-scene/2" and [t.id for t in scene.targets] == ["cupboard"]


def test_cli_exit_0_when_every_task_converts(tmp_path):
    tasks = [t for t in _export() if t["id"] != 19]
    path = tmp_path / "export.json"
    path.write_text(json.dumps(tasks))
    assert main(["import", "label-studio", str(path), "--out", str(tmp_path / "o"), "--quiet"]) == 0


def test_the_deprecated_frames_options_do_nothing_but_say_so(tmp_path, capsys):
    path = tmp_path / "export.json"
    path.write_text(json.dumps([t for t in _export() if t["id"] != 19]))
    assert main(["import", "label-studio", str(path), "--out", str(tmp_path / "a"), "--frames"]) == 0
    assert "note: --frames is deprecated and does nothing" in capsys.readouterr().err
    assert main(["import", "label-studio", str(path), "--out", str(tmp_path / "b"), "--quiet"]) == 0
    for name in ("ab12cd34-room.json", "street.json"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()
    assert main(["import", "label-studio", "--print-config", "--frame"]) == 0
    out = capsys.readouterr()
    assert out.out == label_studio_config("keypoints") and "--frame is deprecated" in out.err


def test_image_dir_sets_a_path_relative_to_the_output_folder(tmp_path):
    images = tmp_path / "photos"
    images.mkdir()
    report = scenes_from_label_studio(_export(), image_dir=images, out_dir=tmp_path / "out")
    scenes = {s.name: s.scene for s in report.scenes}
    assert scenes["ab12cd34-room"]["image"]["path"] == "../photos/ab12cd34-room.jpg"
    assert scenes["street"]["image"]["path"] == "../photos/street.png"
    tasks = _export()
    tasks[0]["data"]["image"] = "/data/local-files/?d=shoots/day%201/room.jpg"
    tasks[1]["data"]["image_path"] = "given/as/is.png"
    report = scenes_from_label_studio(tasks, image_dir=images, out_dir=tmp_path / "out")
    scenes = {s.name: s.scene for s in report.scenes}
    assert scenes["room"]["image"]["path"] == "../photos/room.jpg"
    assert scenes["is"]["image"]["path"] == "given/as/is.png"


def test_users_file_names_the_workers(tmp_path):
    users = tmp_path / "users.json"
    users.write_text(json.dumps([{"id": 3, "username": "alice", "email": "a@x.org"},
                                 {"id": 4, "username": "", "email": "bob@x.org"}]))
    report = scenes_from_label_studio(_export(), users=read_users(users))
    cup = next(s.scene for s in report.scenes if s.name == "ab12cd34-room")
    assert [d["worker"] for d in cup["targets"][0]["dimension_lines"]] == ["alice", "6"]
    assert [r["worker"] for r in cup["references"]] == ["alice", "bob@x.org"]


# ----------------------------------------------------------------------------------------------
# the shipped configs


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
def test_configs_name_what_the_importer_reads(lines, capsys):
    assert main(["import", "label-studio", "--print-config", "--lines", lines]) == 0
    text = capsys.readouterr().out
    assert text == label_studio_config(lines)
    root = ET.fromstring(text)
    kp = root.find(".//KeyPointLabels")
    vls = {v.get("name"): v for v in root.iter("VectorLabels")}
    if lines == "keypoints":
        assert kp.get("name") == "points" and not vls
        assert [e.get("value") for e in kp.findall("Label")] == list(TARGET_LABELS) + [
            "reference start", "reference end", "horizon"]
    else:
        assert kp is None
        assert [e.get("value") for e in vls["targets"].findall("Label")] == ["target"]
        assert (vls["targets"].get("minPoints"), vls["targets"].get("maxPoints")) == ("4", "4")
        assert [e.get("value") for e in vls["lines"].findall("Label")] == ["reference", "horizon"]
        assert (vls["lines"].get("minPoints"), vls["lines"].get("maxPoints")) == ("2", "2")
    controls = {e.get("name"): e for e in root.iter() if e.get("perRegion") == "true"}
    assert set(controls) == set(REFERENCE_FIELDS) | {"target", "class"}
    for name in REFERENCE_FIELDS:
        assert controls[name].get("toName") == "image"
        assert controls[name].get("whenLabelValue") == ("reference start" if lines == "keypoints" else "reference")
    classes = [c.get("value") for c in root.find(".//Choices[@name='class']").findall("Choice")]
    assert set(classes) == set(KITTI_SIZE_PRIORS)
    for e in root.iter("Number"):
        # Label Studio rejects entries that are not a multiple of `step` from `min` (and a decimal
        # step can reject valid ones): no step at all means no such check.
        assert e.get("step") is None
    comment = text.split("-->")[0]
    assert [f for f in DATA_FIELDS if f not in comment] == ["creference_scene"]  # written by advise only


def _doc_blocks(name: str) -> list:
    text = (Path(__file__).resolve().parents[1] / "docs" / name).read_text()
    return [json.loads(b) for b in re.findall(r"```json\n(.*?)```", text, re.S)]


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
def test_the_configs_comment_lists_every_documented_task_field(lines):
    doc = (Path(__file__).resolve().parents[1] / "docs" / "import.md").read_text()
    fields = set()
    for m in re.finditer(r"^\| (?:frame )?field \| required \| meaning \|$", doc, re.M):
        table = doc[m.start():]
        table = table[:table.index("\n\n")]
        fields |= set(re.findall(r"^\| `([a-z_]+)`", table, re.M)) | set(re.findall(r"`(target_[a-z]+_m)`", table))
    assert {"image", "ground_truth", "image_width"} <= fields
    comment = label_studio_config(lines).split("-->")[0]
    assert sorted(f for f in fields if f not in comment) == []


# ----------------------------------------------------------------------------------------------
# round trips: a scene → a Label Studio task → import → the same scene


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
@pytest.mark.parametrize("seed, m", [(0, 1), (1, 4), (2, 3)])
def test_round_trip_through_a_task(lines, seed, m, assert_same_scene):
    scene = tool_scene(seed, m)
    task = json.loads(json.dumps(label_studio_task(scene, task_id=5, lines=lines)))  # as a file would
    report = scenes_from_label_studio([task])
    assert report.ok and report.notes == (), (report.errors, report.notes)
    (back,) = report.scenes
    assert back.name == "task5" and back.scene["format"] == "creference-scene/2"
    assert_same_scene(back.scene, scene)  # every key: targets, lines, references, camera, classes, truth


def test_a_version_1_scene_round_trips_as_a_scene_of_one_target(assert_same_scene):
    from creference_bayes.cli.main import example_scene_path

    v1 = json.loads(example_scene_path().read_text())
    assert v1["format"] == "creference-scene/1"
    (back,) = scenes_from_label_studio(label_studio_tasks([v1], lines="vectors")).scenes
    assert_same_scene(back.scene, v1)  # its truth split between the target and the camera
    (t,) = back.scene["targets"]
    assert (t["id"], t["dimensions_m"]) == (v1["target"]["id"], v1["target"]["dimensions_m"])
    assert set(t["ground_truth"]) >= {"location_m", "yaw_rad"} and "camera_height_m" in back.scene["ground_truth"]


def test_a_worker_doing_several_items_gets_one_annotation_per_set_of_lines(assert_same_scene):
    scene = tool_scene(4, m=1)
    lines = scene["targets"][0]["dimension_lines"]
    lines[1]["worker"], lines[1]["seconds"] = "w0", 20.0  # two sets of lines by one worker
    lines.append({"corners": (np.array(lines[0]["corners"]) + 2.0).tolist()})  # and an anonymous one
    anns = label_studio_tasks([scene])[0]["annotations"]
    # w0's two sets of lines (its reference with the first), the anonymous lines, w1's reference, two anonymous ones
    assert [a.get("completed_by") for a in anns] == ["w0", "w0", None, "w1", None, None]
    (back,) = scenes_from_label_studio(label_studio_tasks([scene])).scenes
    assert_same_scene(back.scene, scene)


def test_predictions_carry_the_same_results():
    scene = tool_scene(0, m=2)
    a = label_studio_task(scene)
    p = label_studio_task(scene, as_predictions=True)
    assert "annotations" not in p
    assert [x["result"] for x in p["predictions"]] == [x["result"] for x in a["annotations"]]


def test_a_reference_without_a_line_cannot_be_written():
    scene = tool_scene(1, m=2)
    scene["references"].append({"measure": "height", "mode": "direct", "value": 1.8, "unit": "m", "target": "t0"})
    with pytest.raises(ValueError, match=r"references\[4\]: a height of 't0' without a line"):
        label_studio_task(scene)


# ----------------------------------------------------------------------------------------------
# hand-written tasks of several targets: targets named per region, classes per region


def _pt(rid, label, x, y):
    return {"id": rid, "type": "keypointlabels", "from_name": "points", "to_name": "image",
            "original_width": 2000, "original_height": 1000, "image_rotation": 0,
            "value": {"x": x, "y": y, "width": 0.5, "keypointlabels": [label]}}


def _ctl(rid, name, typ, value):
    key = {"textarea": "text", "choices": "choices", "number": "number"}[typ]
    return {"id": rid, "type": typ, "from_name": name, "to_name": "image",
            "value": {key: value if typ == "number" else [value]}}


def _target_points(prefix, name, x0, cls=None):
    """Four corner points of one target at x0 % (a 2000 x 1000 image), each naming ``name``."""
    out = []
    for i, (dx, y) in enumerate([(0, 80), (10, 78), (-2, 76), (0, 50)]):
        rid = f"{prefix}{i + 1}"
        out.append(_pt(rid, TARGET_LABELS[i], x0 + dx, y))
        if name is not None:
            out.append(_ctl(rid, "target", "textarea", name))
    if cls is not None:
        out.append(_ctl(f"{prefix}1", "class", "choices", cls))
    return out


def _street_task():
    """Task 41: two cars drawn (one class per region, one from data.targets), a lamp listed but
    not drawn, a relative reference naming its target."""
    result = (_target_points("a", "car1", 20, cls="Car") + _target_points("b", "van", 60)
              + [_pt("rs", "reference start", 10, 95), _pt("re", "reference end", 30, 96),
                 {"type": "relation", "from_id": "rs", "to_id": "re", "direction": "right", "labels": []},
                 _ctl("rs", "measure", "choices", "length"), _ctl("rs", "mode", "choices", "relative"),
                 _ctl("rs", "value", "number", 1.5), _ctl("rs", "target", "textarea", "van")])
    return {"id": 41, "data": {"image": "/data/upload/3/street.png",
                               "targets": [{"id": "car1"}, {"id": "van", "class": "Van"},
                                           {"id": "lamp", "dimensions_m": {"length": 0.3, "width": 0.3,
                                                                           "height": 4.0}}]},
            "annotations": [{"id": 7, "completed_by": 5, "lead_time": 30.0, "result": result}]}


def test_a_task_with_targets_named_per_region():
    report = scenes_from_label_studio([_street_task()])
    assert report.ok, report.errors
    assert report.notes == ("task 41: target 'lamp' has no dimension lines; left out",)
    (s,) = report.scenes
    assert s.name == "street"
    d = s.scene
    assert d["format"] == "creference-scene/2" and d["image"] == {"width": 2000, "height": 1000}
    assert [(t["id"], t.get("class"), t.get("dimensions_m")) for t in d["targets"]] == [
        ("car1", "Car", None), ("van", "Van", None)]
    # corners by hand: x % of 2000, y % of 1000; 30 s over three items (two targets, a reference)
    assert d["targets"][0]["dimension_lines"] == [{"corners": [[400, 800], [600, 780], [360, 760], [400, 500]],
                                                   "worker": "5", "seconds": 10.0}]
    assert d["targets"][1]["dimension_lines"][0]["corners"][1] == [1400, 780]
    assert d["references"] == [{"measure": "length", "mode": "relative", "value": 1.5, "target": "van",
                                "line": [[200, 950], [600, 960]], "worker": "5", "seconds": 10.0}]
    scene = parse_scene(d)
    assert scene.reference_targets == (1,)
    assert scene.size_prior("Van") == KITTI_SIZE_PRIORS["Van"]


def test_without_data_targets_the_regions_make_the_targets():
    task = _street_task()
    del task["data"]["targets"]
    task["annotations"][0]["result"].append(_ctl("b1", "class", "choices", "Truck"))
    (s,) = scenes_from_label_studio([task]).scenes
    assert [(t["id"], t["class"]) for t in s.scene["targets"]] == [("car1", "Car"), ("van", "Truck")]


def test_unnamed_corners_join_the_annotations_one_named_target():
    task = _street_task()
    res = task["annotations"][0]["result"]
    task["annotations"][0]["result"] = [r for r in res if r.get("id") in ("a1", "a2", "a3", "a4")
                                        and not (r["id"] != "a1" and r["from_name"] == "target")]
    (s,) = scenes_from_label_studio([task]).scenes
    assert [t["id"] for t in s.scene["targets"]] == ["car1"]
    assert s.scene["targets"][0]["dimension_lines"][0]["corners"][3] == [400, 500]


def test_a_task_naming_no_target_has_one_target_named_after_it():
    task = {"id": 8, "data": {"image": "x.png", "image_width": 2000, "image_height": 1000},
            "annotations": [{"id": 1, "result": _target_points("a", None, 20, cls="Car")},
                            {"id": 2, "result": _target_points("b", None, 21)}]}
    (s,) = scenes_from_label_studio([task]).scenes
    (t,) = s.scene["targets"]
    assert (t["id"], t["class"], len(t["dimension_lines"])) == ("task8", "Car", 2)


def test_classes_file_supplies_a_class_the_scene_does_not_know():
    task = _street_task()
    task["data"]["targets"][1]["class"] = "Kayak"
    (err,) = scenes_from_label_studio([task]).errors
    assert "task 41, annotation 7, region 'b1': targets[1].class: no size prior for class 'Kayak'" in str(err)
    kayak = SizePrior((4.0, 0.7, 0.4), (0.1, 0.1, 0.2), "file")
    (s,) = scenes_from_label_studio([task], classes={"Kayak": kayak, "Canoe": kayak}).scenes
    assert s.scene["classes"] == {"Kayak": KAYAK}


def _broken(kind):
    t = _street_task()
    res = t["annotations"][0]["result"]
    if kind == "unlisted_target":
        for r in res:
            if r.get("id", "").startswith("a") and r["from_name"] == "target":
                r["value"]["text"] = ["car2"]
    elif kind == "unnamed_among_several":
        res.remove(next(r for r in res if r["id"] == "b3" and r["from_name"] == "target"))
        res.remove(next(r for r in res if r["id"] == "a3" and r["from_name"] == "target"))
    elif kind == "two_t1_of_one_target":
        res.append({**copy.deepcopy(res[0]), "id": "a9"})
        res.append(_ctl("a9", "target", "textarea", "car1"))
    elif kind == "classes_disagree":
        res.append(_ctl("a2", "class", "choices", "Tram"))
    elif kind == "class_conflicts_with_data":
        res.append(_ctl("b2", "class", "choices", "Car"))
    elif kind == "class_on_reference":
        res.append(_ctl("rs", "class", "choices", "Car"))
    elif kind == "reference_names_nobody":
        t["data"] = {"image": "street.png"}
        res.append(_ctl("b1", "class", "choices", "Van"))
        next(r for r in res if r.get("id") == "rs" and r["from_name"] == "target")["value"]["text"] = ["bus"]
    elif kind == "relative_without_target":
        res.remove(next(r for r in res if r.get("id") == "rs" and r["from_name"] == "target"))
    elif kind == "no_size_no_class":
        res.remove(next(r for r in res if r["from_name"] == "class"))
    elif kind == "bad_targets":
        t["data"]["targets"][1]["dimensions_m"] = {"length": 4}
    elif kind == "duplicate_ids":
        t["data"]["targets"][1]["id"] = "car1"
    return t


@pytest.mark.parametrize("kind, message", [
    ("unlisted_target", "task 41, annotation 7, region 'a1': target 'car2' is not in data.targets"),
    ("unnamed_among_several", "task 41, annotation 7, region 'a3': a 't3 end of width' point names no target"),
    ("two_t1_of_one_target", "task 41, annotation 7: two points labelled 't1 bottom corner' (regions 'a1' and "
                             "'a9'); an annotation draws each target once (target 'car1')"),
    ("classes_disagree", "task 41, annotation 7, region 'a2': class 'Tram' here but 'Car' on region 'a1'"),
    ("class_conflicts_with_data", "task 41, annotation 7, region 'b1': class 'Car' for target 'van', which is 'Van'"),
    ("class_on_reference", "task 41, annotation 7, region 'rs': a reference carries a 'class'"),
    ("reference_names_nobody", "task 41, annotation 7, region 'rs': references[0].target: no target with id 'bus'"),
    ("relative_without_target", "task 41, annotation 7, region 'rs': references[0].target: a relative reference "
                                "in a scene of several targets must name the target"),
    ("no_size_no_class", "task 41, target 'car1': no size for target 'car1'"),
    ("bad_targets", "task 41: data.targets[1].dimensions_m must be an object with length, width, height"),
    ("duplicate_ids", "task 41: data.targets[1].id: duplicate id 'car1'"),
])
def test_bad_task_of_several_targets_is_reported_with_task_and_region(kind, message):
    good = _street_task()
    good["id"], good["data"]["image"] = 42, "other.png"
    report = scenes_from_label_studio([_broken(kind), good])
    assert [s.source for s in report.scenes] == ["task 42"], "the other task is still converted"
    (err,) = report.errors
    assert message in str(err), str(err)
    assert "\n" not in str(err)


# ----------------------------------------------------------------------------------------------
# bad input of the hand-written export: each message names the task and the region


def _task():
    """Task 17 of the file, alone: a valid task to break in one way."""
    return copy.deepcopy(_export()[0])


def _results(task, ann=0):
    return task["annotations"][ann]["result"]


def _find(results, rid, from_name=None):
    return next(r for r in results if r.get("id") == rid and (from_name is None or r.get("from_name") == from_name))


def _break(kind):
    t = _task()
    res = _results(t)
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
    ("no_target", "task 17: no annotation draws a target's dimension lines"),
    ("missing_dims", "task 17: data has ['target_length_m', 'target_height_m'] but not ['target_width_m']"),
    ("bad_dims", "task 17: data.target_height_m is not a number: 'two metres'"),
])
def test_bad_task_is_reported_with_task_and_region(kind, message):
    good = _export()[1]
    report = scenes_from_label_studio([_break(kind), good])
    assert [s.name for s in report.scenes] == ["street"], "the other task is still converted"
    (err,) = report.errors
    assert message in str(err), str(err)
    assert "\n" not in str(err)


def test_missing_size_can_come_from_the_targets_table(tmp_path):
    t = _task()
    for k in ("target_length_m", "target_width_m", "target_height_m"):
        del t["data"][k]
    assert "no size for target 'cupboard'" in str(scenes_from_label_studio([t]).errors[0])
    assert "pass --targets" in str(scenes_from_label_studio([t]).errors[0])
    csv = tmp_path / "targets.csv"
    csv.write_text("target_id,length_m,width_m,height_m,focal_length_px\ncupboard,1.2,0.5,2.0,2100\n")
    (s,) = scenes_from_label_studio([t], targets=load_target_table(csv)).scenes
    assert s.scene["targets"][0]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}
    assert s.scene["camera"]["focal_length_px"] == 2100
    csv.write_text("target_id,length_m,width_m,height_m\ncupboard,1.3,0.5,2.0\n")
    err = scenes_from_label_studio([_task()], targets=load_target_table(csv)).errors[0]
    assert "length 1.2 m in the export but 1.3 m in the --targets table" in str(err)


def test_two_photos_of_one_name_keep_the_first():
    a, b = _task(), _task()
    b["id"], b["data"]["image"] = 99, "/data/upload/2/ab12cd34-room.jpg"  # another folder, the same name
    report = scenes_from_label_studio([a, b])
    assert [s.source for s in report.scenes] == ["task 17"]
    assert "task 99: file name 'ab12cd34-room.json' is already used by task 17" in str(report.errors[0])


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


def test_vertices_without_ids_keep_their_list_order():
    # Label Studio's SDK writes vertices with "id": null and "prevPointId": null
    t = _export()[1]
    for v in t["completions"][0]["result"][4]["value"]["vertices"]:
        v["id"] = v["prevPointId"] = None
    (s,) = scenes_from_label_studio([t]).scenes
    assert np.allclose(s.scene["references"][0]["line"], [[400, 999], [500, 750]])


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


def test_the_documented_annotation_imports_as_a_references_only_annotation():
    """docs/labelstudio_annotations.md's example annotation (references only, no target points) converts as it says."""
    from creference_bayes.cli.main import example_scene_path

    documented = next(b for b in _doc_blocks("labelstudio_annotations.md") if isinstance(b, dict) and "completed_by" in b)
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


# ----------------------------------------------------------------------------------------------
# the --targets table: rows keyed by image and target; a focal length without sizes


def _no_dims(task):
    for k in ("target_length_m", "target_width_m", "target_height_m"):
        del task["data"][k]
    return task


def test_targets_rows_are_keyed_by_image_and_target(tmp_path):
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
    assert scenes["ab12cd34-room"]["targets"][0]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}
    assert "camera" not in scenes["ab12cd34-room"]
    assert scenes["other"]["targets"][0]["dimensions_m"] == {"length": 0.9, "width": 0.4, "height": 1.0}
    assert scenes["other"]["camera"] == {"focal_length_px": 2400.0}
    assert ("--targets: no image of the export matches t.csv line 5 (image 'elsewhere.jpg'); not used"
            in report.notes)


def test_a_focal_length_row_without_sizes(tmp_path):
    csv = tmp_path / "t.csv"
    csv.write_text("target_id,length_m,width_m,height_m,focal_length_px\ncupboard,,,,2100\n")
    (s,) = scenes_from_label_studio([_task()], targets=load_target_table(csv)).scenes
    assert s.scene["camera"] == {"focal_length_px": 2100.0}
    assert s.scene["targets"][0]["dimensions_m"] == {"length": 1.2, "width": 0.5, "height": 2.0}


# ----------------------------------------------------------------------------------------------
# the tasks of one image make one scene (a task per target, as docs/import.md lays it out)


def _second_target_task():
    """Task 17's image with another target, 'lamp' (its own task)."""
    t = _task()
    t["id"], t["data"]["target_id"] = 99, "lamp"
    t["data"].update(target_length_m=0.4, target_width_m=0.4, target_height_m=1.6)
    t["annotations"] = [t["annotations"][0]]
    t["annotations"][0]["result"] = [r for r in _results(t) if r.get("id") in ("a1", "a2", "a3", "a4")]
    for r in _results(t):
        r["value"]["x"] += 30
    return t


def test_the_tasks_of_one_image_make_one_scene():
    report = scenes_from_label_studio([_task(), _second_target_task()])
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.name == "ab12cd34-room" and s.source == "task 17, task 99 (one image)"
    d = s.scene
    assert [(t["id"], t["dimensions_m"]["height"], len(t["dimension_lines"])) for t in d["targets"]] == [
        ("cupboard", 2.0, 2), ("lamp", 1.6, 1)]
    # x % of 4000 px: a1 at 40 % + 30 %; annotation 101 of task 99 holds one item: 240 s
    assert d["targets"][1]["dimension_lines"] == [
        {"corners": [[2800, 2400], [3200, 2340], [2720, 2280], [2800, 1500]], "worker": "3", "seconds": 240.0}]
    # task 17's relative reference is a ratio to its own target
    assert [(r["mode"], r.get("target")) for r in d["references"]] == [("direct", None), ("relative", "cupboard")]
    assert d["horizon"] == [[0, 1200], [4000, 1260]]


def test_one_target_tasks_split_their_truth_between_target_and_camera():
    camera = {"focal_length_px": 3000.0, "camera_height_m": 1.4, "pitch_rad": 0.05, "roll_rad": 0.0}
    first, second = _task(), _second_target_task()
    first["data"]["ground_truth"] = {"location_m": [0.5, 1.4, 5.0], "yaw_rad": 0.3, **camera}
    second["data"]["ground_truth"] = {"location_m": [1.5, 1.4, 6.0], "yaw_rad": -0.2, "handedness": -1, **camera}
    report = scenes_from_label_studio([first, second])
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.scene["ground_truth"] == camera
    assert [t["ground_truth"] for t in s.scene["targets"]] == [
        {"location_m": [0.5, 1.4, 5.0], "yaw_rad": 0.3}, {"location_m": [1.5, 1.4, 6.0], "yaw_rad": -0.2, "handedness": -1}]
    second["data"]["ground_truth"]["camera_height_m"] = 1.6  # one camera: the tasks must agree on it
    (err,) = scenes_from_label_studio([first, second]).errors
    assert str(err) == ("task 17, task 99 (one image): data.ground_truth.camera_height_m is 1.4 in task 17 but 1.6 "
                        "in task 99 (the tasks of one image share it)")


@pytest.mark.parametrize("change, message", [
    (lambda t: t["data"].update(focal_length_px=1800),
     "task 17, task 99 (one image): data.focal_length_px is 2000 in task 17 but 1800 in task 99"),
    (lambda t: t["data"].update(target_id="cupboard"),
     "task 17, task 99 (one image): target 'cupboard' is in task 17 and in task 99"),
    (lambda t: [r.update(original_width=2000) for r in _results(t)],
     "task 17, task 99 (one image): the image is 4000x3000 in task 17 but 2000x3000 in task 99"),
])
def test_the_tasks_of_one_image_must_agree(change, message):
    first = _task()
    first["data"]["focal_length_px"] = 2000
    second = _second_target_task()
    change(second)
    report = scenes_from_label_studio([first, second])
    assert report.scenes == ()
    (err,) = report.errors
    assert message in str(err), str(err)


def test_a_merged_scene_names_the_task_of_a_bad_region():
    second = _second_target_task()
    _find(_results(second), "a4")["value"]["y"] = 900.0  # far outside the image
    (err,) = scenes_from_label_studio([_task(), second]).errors
    assert str(err).startswith("task 17, task 99 (one image), task 99, annotation 101, region 'a1': "
                               "targets[1].dimension_lines[0]"), str(err)


# ----------------------------------------------------------------------------------------------
# a request task of creference advise: the scene it carries, with the task's answers appended


def test_a_request_task_imports_as_its_scene_with_the_answers(assert_same_scene):
    from creference_bayes.cli.main import example_scene_path

    scene = json.loads(example_scene_path().read_text())  # a version-1 scene, as older requests carry
    task = {"id": 3, "data": {"image": "/data/upload/1/living.jpg", "creference_scene": scene}}
    new = copy.deepcopy(scene)
    new["target"]["dimension_lines"] = [{"worker": "w-new", "corners": (
        np.array(scene["target"]["dimension_lines"][0]["corners"]) + 1.5).tolist()}]
    new["references"] = [{**scene["references"][0], "worker": "w-new", "value": 0.8}]
    new["references"][0].pop("range", None)
    new["references"][0].pop("seconds", None)
    task["annotations"] = label_studio_task(new)["annotations"]
    for ann in task["annotations"]:  # the worker draws the target without naming it
        ann["result"] = [r for r in ann["result"] if r.get("from_name") != "target"]
    report = scenes_from_label_studio([task, copy.deepcopy(task)])  # two answers: two scenes of one name
    assert [str(e) for e in report.errors] == ["task 3: file name 'living.json' is already used by task 3 "
                                               "(each photo needs a name of its own)"]
    (s,) = report.scenes
    want = copy.deepcopy(scene)
    want["target"]["dimension_lines"] += new["target"]["dimension_lines"]
    want["references"] += new["references"]
    assert_same_scene(s.scene, want)


def test_the_answered_requests_of_one_frame_import_as_that_frame_with_every_answer(assert_same_scene):
    """Request tasks of one frame (one ``request_key``), each answered: one scene, named after the
    frame's full key (its ``/`` as ``_``), holding the scene the requests were made for once and every task's answer; tasks made
    for another state of the frame (another round) are refused."""
    from creference_bayes.cli.main import example_scene_path

    scene = json.loads(example_scene_path().read_text())
    lines = copy.deepcopy(scene)
    lines["target"]["dimension_lines"] = [{"worker": "w-lines", "corners": (
        np.array(scene["target"]["dimension_lines"][0]["corners"]) + 1.5).tolist()}]
    lines["references"] = []
    ref = copy.deepcopy(scene)  # the answering worker's reference (the lines only to make a valid scene)
    ref["references"] = [{**scene["references"][0], "worker": "w-ref", "value": 0.8}]
    ref["references"][0].pop("range", None)
    ref["references"][0].pop("seconds", None)

    def task(tid, answer, key="frames/f1", base=scene):
        t = {"id": tid, "data": {"image": "", "creference_scene": base, "request_key": key}}
        anns = [a for a in label_studio_task(answer)["annotations"] if a["completed_by"] in ("w-lines", "w-ref")]
        for ann in anns:  # the worker draws the target without naming it
            ann["result"] = [r for r in ann["result"] if r.get("from_name") != "target"]
        t["annotations"] = anns
        return t

    report = scenes_from_label_studio([task(2, lines), task(6, ref), task(7, lines, key="f2")])
    assert not report.errors, report.errors
    assert sorted(s.name for s in report.scenes) == ["f2", "frames_f1"]  # the full key: a/f1 and b/f1 are two frames
    f1 = next(s for s in report.scenes if s.name == "frames_f1")
    want = copy.deepcopy(scene)
    want["target"]["dimension_lines"] += lines["target"]["dimension_lines"]
    want["references"] += ref["references"]
    assert_same_scene(f1.scene, want)
    other = copy.deepcopy(scene)
    other["references"] = other["references"][:-1]  # the frame as it was a round earlier
    report = scenes_from_label_studio([task(2, lines), task(6, ref, base=other)])
    assert [s.name for s in report.scenes] == [] and len(report.errors) == 1
    assert "task 6 was made for another state of 'frames/f1' than task 2" in str(report.errors[0])


# ----------------------------------------------------------------------------------------------
# the command line: scenes of several targets, estimate on them, --classes


def test_cli_imports_scenes_and_estimate_runs_on_them(tmp_path, capsys):
    scenes = [tool_scene(1, m=3), tool_scene(2, m=1)]
    export = tmp_path / "export.json"
    export.write_text(json.dumps(label_studio_tasks(scenes)))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "ls"), "--quiet"]) == 0
    assert sorted(p.name for p in (tmp_path / "ls").iterdir()) == ["task1.json", "task2.json"]
    assert [t.id for t in load_scene(tmp_path / "ls" / "task1.json").targets] == ["t0", "t1", "t2"]
    capsys.readouterr()
    out = tmp_path / "result.json"
    assert main(["estimate", str(tmp_path / "ls" / "task2.json"), "--no-posterior", "--quiet", "--out", str(out)]) == 0
    assert [o["id"] for o in json.loads(out.read_text())["objects"]] == ["t0"]


def test_cli_skips_the_bad_task_writes_the_others_and_exits_2(tmp_path, capsys):
    good = _street_task()
    good["id"], good["data"]["image"] = 42, "other.png"
    export = tmp_path / "export.json"
    export.write_text(json.dumps([_broken("unlisted_target"), good]))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o")]) == 2
    assert "error: task 41, annotation 7, region 'a1': target 'car2'" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["other.json"]


def test_cli_classes_option(tmp_path, capsys):
    task = _street_task()
    task["data"]["targets"][1]["class"] = "Kayak"
    export = tmp_path / "export.json"
    export.write_text(json.dumps([task]))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    classes = tmp_path / "classes.json"
    classes.write_text(json.dumps({"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4}}))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o"), "--quiet",
                 "--classes", str(classes)]) == 0
    assert load_scene(tmp_path / "o" / "street.json").classes["Kayak"].median_m == (4.0, 0.7, 0.4)
    classes.write_text(json.dumps({"Kayak": {"length_m": -4.0, "width_m": 0.7, "height_m": 0.4}}))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "p"), "--classes", str(classes)]) == 2
    assert "Kayak.length_m" in capsys.readouterr().err


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


@pytest.mark.parametrize("truth, path", [
    ({"location_m": [1.0, 1.5, 6.0], "yaw_rad": 0.5}, "targets[0].ground_truth"),  # a one-target truth
    ({"camera_height_m": 1.5}, "ground_truth"),                                      # the camera's
])
def test_a_value_no_scene_file_can_hold_is_an_error_not_a_crash(tmp_path, capsys, truth, path):
    t = _task()
    t["data"]["ground_truth"] = {**truth, "note": "INF"}
    export = tmp_path / "export.json"
    export.write_text(json.dumps([t]).replace('"INF"', "1e400"))  # JSON's 1e400 reads as infinity
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()  # the scene check or the writability check refuses it
    assert err.startswith(f"error: task 17, data.ground_truth: {path}.note: ") and "inf" in err and "\n" not in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


# ----------------------------------------------------------------------------------------------
# the camera's name: data.camera_id → camera.id (frames of one camera: creference batch --rig)


def test_a_task_camera_id_is_the_scene_camera_id():
    t = _task()
    t["data"]["camera_id"] = "  dashcam-left "
    report = scenes_from_label_studio([t, _export()[1]])
    assert report.ok, report.errors
    room, street = report.scenes
    assert room.scene["camera"]["id"] == "dashcam-left"  # stripped
    assert "id" not in street.scene.get("camera", {})  # a task without one: no camera id
    t["data"]["camera_id"] = None  # null is "not given"
    (room,) = scenes_from_label_studio([t]).scenes
    assert "id" not in room.scene.get("camera", {})


def test_the_tasks_of_one_image_share_the_camera_id():
    first, second = _task(), _second_target_task()
    first["data"]["camera_id"] = "cam A"
    (s,) = scenes_from_label_studio([first, second]).scenes  # the task that gives it names the camera
    assert s.scene["camera"]["id"] == "cam A"
    second["data"]["camera_id"] = "cam A"
    (s,) = scenes_from_label_studio([first, second]).scenes
    assert s.scene["camera"]["id"] == "cam A"
    second["data"]["camera_id"] = "cam B"
    report = scenes_from_label_studio([first, second])
    assert report.scenes == ()
    (err,) = report.errors
    assert str(err) == ("task 17, task 99 (one image): data.camera_id is 'cam A' in task 17 but 'cam B' in "
                        "task 99 (the tasks of one image share it)")


@pytest.mark.parametrize("value, problem", [
    (7, "must be the camera's name (text), got 7"),
    (True, "must be the camera's name (text), got True"),
    (["cam"], "must be the camera's name (text), got ['cam']"),
    ({"id": "cam"}, "must be the camera's name (text), got {'id': 'cam'}"),
    ("", "is empty text ''"),
    ("  \t", "is blank text (only whitespace)"),
])
def test_a_bad_camera_id_names_the_task_and_the_value(value, problem):
    t = _task()
    t["data"]["camera_id"] = value
    report = scenes_from_label_studio([t, _export()[1]])
    assert [s.name for s in report.scenes] == ["street"], "the other task is still converted"
    (err,) = report.errors
    assert str(err) == (f"task 17: data.camera_id {problem}: give the camera's name, or leave the field out "
                        "(or null) for a photo of no known camera")


def test_the_camera_id_round_trips_through_a_task(assert_same_scene):
    d = tool_scene(3)
    d["camera"] = {**d.get("camera", {}), "id": "rig/front"}
    task = label_studio_task(d, task_id=5)
    assert task["data"]["camera_id"] == "rig/front"
    (s,) = scenes_from_label_studio([task]).scenes
    assert s.scene["camera"]["id"] == "rig/front"
    assert parse_scene(s.scene).camera_id == "rig/front"


def test_many_reference_lines_are_each_paired_with_their_own_end():
    """Relations are paired by set look-ups (linear): 600 lines, relations drawn either way and in
    shuffled order, each line keeps its own two ends and its own value."""
    rng = np.random.default_rng(3)
    n = 600
    res = _target_points("a", "car1", 20, cls="Car")
    relations = []
    for k in range(n):
        x, y = 1 + 98 * k / n, 90 + 5 * (k % 2)
        res += [_pt(f"s{k}", "reference start", x, y), _pt(f"e{k}", "reference end", x + 0.5, y + 1),
                _ctl(f"s{k}", "measure", "choices", "length"), _ctl(f"s{k}", "mode", "choices", "relative"),
                _ctl(f"e{k}", "value", "number", 1.0 + k)]
        a, b = (f"s{k}", f"e{k}") if k % 3 else (f"e{k}", f"s{k}")
        relations.append({"type": "relation", "from_id": a, "to_id": b, "direction": "right", "labels": []})
    res += [relations[i] for i in rng.permutation(n)]
    task = {"id": 5, "data": {"image": "x.png"}, "annotations": [{"id": 7, "result": res}]}
    report = scenes_from_label_studio([task])
    assert report.ok, report.errors[:1]
    refs = report.scenes[0].scene["references"]
    assert len(refs) == n
    by_value = {r["value"]: r["line"] for r in refs}
    for k in range(n):
        x, y = 20 * (1 + 98 * k / n), 10 * (90 + 5 * (k % 2))
        np.testing.assert_allclose(by_value[1.0 + k], [[x, y], [x + 10, y + 10]])


def test_a_task_whose_image_cannot_be_named_is_skipped_alone(tmp_path, capsys):
    """An image name past the file system's 255 bytes (with --image-dir), a NUL in data.image_path:
    that task is refused, naming it; the others are imported."""
    good, long, nul = _street_task(), _street_task(), _street_task()
    long["id"], long["data"]["image"] = 42, "/data/upload/3/" + "x" * 300 + ".png"
    nul["id"], nul["data"]["image"], nul["data"]["image_path"] = 43, "/data/upload/3/other.png", "a\0b.png"
    report = scenes_from_label_studio([good, long, nul], image_dir=tmp_path)
    assert [s.source for s in report.scenes] == ["task 41"]
    errors = [str(e) for e in report.errors]
    assert errors[0].startswith("task 42: the image's name 'xxx") and "cannot be looked up in the image folder" in errors[0]
    assert errors[1] == r"task 43: data.image_path 'a\x00b.png' holds a NUL character (no file has such a name)"
    assert [str(e) for e in scenes_from_label_studio([nul]).errors] == errors[1:]  # without --image-dir too
    export, out = tmp_path / "export.json", tmp_path / "o"
    export.write_text(json.dumps([good, long, nul]))
    assert main(["import", "label-studio", str(export), "--out", str(out), "--image-dir", str(tmp_path), "--quiet"]) == 2
    assert [p.name for p in out.iterdir()] == ["street.json"]
    err = capsys.readouterr().err.strip().splitlines()
    assert [line.split(":")[0] for line in err] == ["error", "error"] and "task 42" in err[0] and "task 43" in err[1]
