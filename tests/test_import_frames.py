"""Frames through the annotation tools: a Label Studio task or a CVAT image holding every target of
its photo imports as one creference-scene/2 frame; simulated frames survive the round trip; the
shipped frame configs name what the importer reads; bad frame input names task/image and region."""

import copy
import json
import xml.etree.ElementTree as ET

import pytest

from creference_bayes.bench.frame_simulate import simulate_frame
from creference_bayes.cli import main
from creference_bayes.io.annotation_tools import REFERENCE_FIELDS
from creference_bayes.io.cvat import cvat_label_spec, cvat_xml, read_cvat_xml, scenes_from_cvat
from creference_bayes.io.frame_import import frame_differences
from creference_bayes.io.frame_scene import load_frame, parse_frame
from creference_bayes.io.labelstudio import (FRAME_DATA_FIELDS, TARGET_LABELS, label_studio_config,
                                             label_studio_task, label_studio_tasks, scenes_from_label_studio)
from creference_bayes.models.size_priors import KITTI_SIZE_PRIORS, SizePrior


def _frame(seed, n=4, kind="street"):
    """A simulated frame with references: a ratio to a target, a shared ground segment (with a
    worker, confidence and object) and a distance naming a target."""
    f = simulate_frame(seed, kind=kind, n_objects=n, n_annotations=3, horizon="sd")
    ids = [t["id"] for t in f["targets"]]
    w, h = f["image"]["width"], f["image"]["height"]
    f["targets"][0]["dimension_lines"][0]["worker"] = "w1"
    f["targets"][1]["dimension_lines"][0]["worker"] = "w1"  # one annotation draws both targets
    f["references"] = [
        {"measure": "length", "mode": "relative", "value": 2.0, "target": ids[0], "worker": "w1",
         "line": [[0.1 * w, 0.95 * h], [0.3 * w, 0.97 * h]]},
        {"measure": "width", "mode": "direct", "range": [1.0, 2.0], "unit": "m", "worker": "w2", "confidence": 0.7,
         "object": "bench", "line": [[0.5 * w, 0.96 * h], [0.6 * w, 0.97 * h]]},
        {"measure": "distance", "mode": "direct", "value": 30, "unit": "ft", "target": ids[-1],
         "line": [[0.7 * w, h - 1.0], [0.72 * w, 0.8 * h]]},
    ]
    return f


def _same(a, b, **kw):
    diff = frame_differences(a, b, **kw)
    assert not diff, "\n".join(diff)


# ----------------------------------------------------------------------------------------------
# round trips: simulated frame → tool → import → the same frame


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
@pytest.mark.parametrize("seed", [1, 2])
def test_round_trip_through_a_label_studio_task(lines, seed):
    frame = _frame(seed)
    task = json.loads(json.dumps(label_studio_task(frame, task_id=7, lines=lines)))
    report = scenes_from_label_studio([task])
    assert report.ok and report.notes == (), (report.errors, report.notes)
    (back,) = report.scenes
    assert back.scene["format"] == "creference-scene/2"
    _same(back.scene, frame, atol=1e-9)  # every key: targets, lines, references, camera, truth


def test_round_trip_of_an_indoor_frame_keeps_its_own_classes():
    frame = _frame(3, kind="indoor")
    assert "classes" in frame
    (back,) = scenes_from_label_studio(label_studio_tasks([frame])).scenes
    _same(back.scene, frame, atol=1e-9)


@pytest.mark.parametrize("seed", [1, 2])
def test_round_trip_through_cvat_xml(seed):
    frames = [_frame(seed), _frame(seed + 10, n=6)]
    text = cvat_xml(frames, image_names=["a.png", "b.png"])
    report = scenes_from_cvat(read_cvat_xml(text.encode()))
    assert report.ok, report.errors
    assert [s.name for s in report.scenes] == ["a", "b"]
    for s, f in zip(report.scenes, frames):
        # what CVAT cannot carry: the camera, the horizon's sd, seconds and the ground truth
        _same(s.scene, f, atol=0.005, drop=("camera", "horizon_sd_px", "seconds", "ground_truth"))


def test_a_frame_has_its_cvat_image_to_itself():
    f = _frame(1)
    with pytest.raises(ValueError, match="cannot share the image"):
        cvat_xml([f, f], image_names=["x.png", "x.png"])


def test_a_target_size_measurement_cannot_be_exported():
    f = _frame(1)
    f["references"].append({"measure": "height", "mode": "direct", "value": 1.8, "unit": "m",
                            "target": f["targets"][0]["id"]})
    with pytest.raises(ValueError, match=r"references\[3\]: a measurement of target 't0'"):
        label_studio_task(f)
    with pytest.raises(ValueError, match=r"references\[3\]: a measurement of target 't0'"):
        cvat_xml([f])


# ----------------------------------------------------------------------------------------------
# a hand-written frame task: targets named per region, classes per region, sizes from data


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


def _frame_task():
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


def test_a_frame_task_with_targets_named_per_region():
    report = scenes_from_label_studio([_frame_task()])
    assert report.ok, report.errors
    assert report.notes == ("task 41: target 'lamp' of data.targets has no dimension lines; left out",)
    (s,) = report.scenes
    assert s.name == "street"  # the image's name
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
    frame = parse_frame(d)
    assert frame.reference_targets == (1,)
    assert frame.size_prior("Van") == KITTI_SIZE_PRIORS["Van"]


def test_without_data_targets_the_regions_make_the_targets():
    task = _frame_task()
    del task["data"]["targets"]
    task["annotations"][0]["result"].append(_ctl("b1", "class", "choices", "Truck"))
    (s,) = scenes_from_label_studio([task]).scenes
    assert [(t["id"], t["class"]) for t in s.scene["targets"]] == [("car1", "Car"), ("van", "Truck")]


def test_unnamed_corners_join_the_annotations_one_named_target():
    task = _frame_task()
    res = task["annotations"][0]["result"]
    task["annotations"][0]["result"] = [r for r in res if not (r.get("id") in ("a2", "a3", "a4")
                                                               and r["from_name"] == "target")]
    task["annotations"][0]["result"] = [r for r in task["annotations"][0]["result"]
                                        if not r.get("id", "").startswith("b")]
    task["annotations"][0]["result"] = [r for r in task["annotations"][0]["result"] if r.get("id") not in ("rs", "re")
                                        and r.get("type") != "relation"]
    (s,) = scenes_from_label_studio([task]).scenes
    assert [t["id"] for t in s.scene["targets"]] == ["car1"]
    assert s.scene["targets"][0]["dimension_lines"][0]["corners"][3] == [400, 500]


def test_one_target_tasks_still_give_version_1_scenes_unless_frames_are_asked_for():
    scene = json.loads((__import__("creference_bayes.cli.main", fromlist=["x"]).example_scene_path()).read_text())
    tasks = label_studio_tasks([scene])
    (old,) = scenes_from_label_studio(tasks).scenes
    assert old.scene["format"] == "creference-scene/1"
    (new,) = scenes_from_label_studio(tasks, frames=True).scenes
    assert new.scene["format"] == "creference-scene/2"
    (t,) = new.scene["targets"]
    assert t["id"] == scene["target"]["id"] and t["dimensions_m"] == scene["target"]["dimensions_m"]
    assert t["dimension_lines"] == old.scene["target"]["dimension_lines"]
    assert new.scene["references"] == old.scene["references"]


def test_classes_file_supplies_a_class_the_frame_does_not_know():
    task = _frame_task()
    task["data"]["targets"][1]["class"] = "Kayak"
    (err,) = scenes_from_label_studio([task]).errors
    assert "task 41, annotation 7, region 'b1': targets[1].class: no size prior for class 'Kayak'" in str(err)
    kayak = SizePrior((4.0, 0.7, 0.4), (0.1, 0.1, 0.2), "file")
    (s,) = scenes_from_label_studio([task], classes={"Kayak": kayak, "Canoe": kayak}).scenes
    assert s.scene["classes"] == {"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4,
                                            "log_sd": [0.1, 0.1, 0.2]}}


# ----------------------------------------------------------------------------------------------
# bad frame input: one line naming the task, the region and the value


def _broken(kind):
    t = _frame_task()
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
        t["data"]["targets"][0] = {"id": "car1"}
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
                                "in a frame of several targets must name the target"),
    ("no_size_no_class", "task 41, annotation 7, region 'a1': targets[0]: needs 'dimensions_m' or a 'class'"),
    ("bad_targets", "task 41: data.targets[1].dimensions_m must be an object with length, width, height"),
    ("duplicate_ids", "task 41: data.targets[1].id: duplicate id 'car1'"),
])
def test_bad_frame_task_is_reported_with_task_and_region(kind, message):
    good = _frame_task()
    good["id"], good["data"]["image"] = 42, "other.png"
    report = scenes_from_label_studio([_broken(kind), good])
    assert [s.source for s in report.scenes] == ["task 42"], "the other task is still converted"
    (err,) = report.errors
    assert message in str(err), str(err)
    assert "\n" not in str(err)


# ----------------------------------------------------------------------------------------------
# CVAT: an image whose targets carry a class


_HEAD = '<?xml version="1.0"?><annotations><version>1.1</version><meta><task/></meta>'


def _target(tid, cls, pts="1000,700;1200,700;900,650;1000,400", size=None):
    attrs = f'<attribute name="target_id">{tid}</attribute><attribute name="class">{cls}</attribute>'
    if size:
        attrs += "".join(f'<attribute name="{k}_m">{v}</attribute>' for k, v in zip(("length", "width", "height"), size))
    return f'<points label="target" points="{pts}">{attrs}</points>'


def _ref(tid, mode="relative", value="2", unit=""):
    return (f'<polyline label="reference" points="100,990;600,980"><attribute name="target_id">{tid}</attribute>'
            f'<attribute name="measure">length</attribute><attribute name="mode">{mode}</attribute>'
            f'<attribute name="value">{value}</attribute><attribute name="unit">{unit}</attribute></polyline>')


def _doc(*shapes, name="street.png"):
    return (f'{_HEAD}<image id="0" name="{name}" width="2000" height="1000">{"".join(shapes)}</image>'
            f'</annotations>').encode()


def test_cvat_image_with_classes_is_one_frame():
    doc = _doc(_target("car1", "Car"), _target("car1", "Car", "1010,705;1210,700;905,650;1000,405"),
               _target("post", "", "300,700;320,700;300,690;300,300", size=(0.2, 0.2, 3.0)),
               _ref("car1"), _ref("", "direct", "5", "m"),
               '<polyline label="horizon" points="0,300;2000,320"></polyline>')
    report = scenes_from_cvat(read_cvat_xml(doc))
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.name == "street"
    d = s.scene
    assert [(t["id"], t.get("class"), t.get("dimensions_m"), len(t["dimension_lines"])) for t in d["targets"]] == [
        ("car1", "Car", None, 2), ("post", None, {"length": 0.2, "width": 0.2, "height": 3.0}, 1)]
    assert d["targets"][0]["dimension_lines"][1]["corners"] == [[1010, 705], [1210, 700], [905, 650], [1000, 405]]
    assert [(r["mode"], r.get("target")) for r in d["references"]] == [("relative", "car1"), ("direct", None)]
    assert d["horizon"] == [[0.0, 300.0], [2000.0, 320.0]]


@pytest.mark.parametrize("shapes, message", [
    ((_target("a", "Car"), _target("", "Car", "1,2;3,4;5,6;7,8")),
     "image 'street.png', shape 1 (points 'target'): this target shape has no target_id"),
    ((_target("a", "Car"), _target("a", "Van")), "shape 1 (points 'target'): class 'Van' here but 'Car' on shape 0"),
    ((_target("a", "Car"), _target("b", "Car", "1,2;3,4;5,6;7,8"), _ref("")),
     "shape 2 (polyline 'reference'): a relative reference needs a target_id"),
    ((_target("a", "Car"), _ref("zz")), "shape 1 (polyline 'reference'): reference for target 'zz'"),
    ((_target("a", "Spaceship"),), "shape 0 (points 'target'): targets[0].class: no size prior for class 'Spaceship'"),
])
def test_bad_cvat_frame_is_reported_with_image_and_shape(shapes, message):
    report = scenes_from_cvat(read_cvat_xml(_doc(*shapes)))
    (err,) = report.errors
    assert message in str(err), str(err)


# ----------------------------------------------------------------------------------------------
# the shipped configs and the CLI


@pytest.mark.parametrize("lines", ["keypoints", "vectors"])
def test_frame_configs_name_what_the_importer_reads(lines, capsys):
    assert main(["import", "label-studio", "--print-config", "--frame", "--lines", lines]) == 0
    text = capsys.readouterr().out
    assert text == label_studio_config(lines, frame=True)
    root = ET.fromstring(text)
    kp = root.find(".//KeyPointLabels")
    if lines == "keypoints":
        assert [e.get("value") for e in kp.findall("Label")] == list(TARGET_LABELS) + [
            "reference start", "reference end", "horizon"]
    else:
        assert kp is None
        vls = {v.get("name"): v for v in root.iter("VectorLabels")}
        assert [e.get("value") for e in vls["targets"].findall("Label")] == ["target"]
        assert (vls["targets"].get("minPoints"), vls["targets"].get("maxPoints")) == ("4", "4")
    controls = {e.get("name") for e in root.iter() if e.get("perRegion") == "true"}
    assert controls == set(REFERENCE_FIELDS) | {"target", "class"}
    classes = [c.get("value") for c in root.find(".//Choices[@name='class']").findall("Choice")]
    assert set(classes) == set(KITTI_SIZE_PRIORS)
    comment = text.split("-->")[0]
    assert all(f in comment for f in FRAME_DATA_FIELDS)


def test_cvat_spec_offers_the_kitti_classes():
    (target,) = [lab for lab in cvat_label_spec() if lab["name"] == "target"]
    (cls,) = [a for a in target["attributes"] if a["name"] == "class"]
    assert cls["values"][0] == "__undefined__" and set(cls["values"][1:]) == set(KITTI_SIZE_PRIORS)


def test_cli_imports_frames_and_estimate_runs_on_them(tmp_path, capsys):
    frames = [_frame(1), _frame(2)]
    export = tmp_path / "export.json"
    export.write_text(json.dumps(label_studio_tasks(frames)))
    xml = tmp_path / "annotations.xml"
    xml.write_text(cvat_xml(frames, image_names=["f1.png", "f2.png"]))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "ls"), "--quiet"]) == 0
    assert main(["import", "cvat", str(xml), "--out", str(tmp_path / "cv"), "--quiet"]) == 0
    assert sorted(p.name for p in (tmp_path / "ls").iterdir()) == ["task1.json", "task2.json"]
    assert sorted(p.name for p in (tmp_path / "cv").iterdir()) == ["f1.json", "f2.json"]
    assert [t.id for t in load_frame(tmp_path / "cv" / "f2.json").targets] == [t["id"] for t in frames[1]["targets"]]
    capsys.readouterr()
    out = tmp_path / "result.json"
    assert main(["estimate", str(tmp_path / "ls" / "task1.json"), "--no-posterior", "--quiet", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [o["id"] for o in result["objects"]] == [t["id"] for t in frames[0]["targets"]]


def test_cli_skips_the_bad_frame_task_writes_the_others_and_exits_2(tmp_path, capsys):
    good = _frame_task()
    good["id"], good["data"]["image"] = 42, "other.png"
    export = tmp_path / "export.json"
    export.write_text(json.dumps([_broken("unlisted_target"), good]))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o")]) == 2
    assert "error: task 41, annotation 7, region 'a1': target 'car2'" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["other.json"]


def test_cli_classes_option(tmp_path, capsys):
    task = _frame_task()
    task["data"]["targets"][1]["class"] = "Kayak"
    export = tmp_path / "export.json"
    export.write_text(json.dumps([task]))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    classes = tmp_path / "classes.json"
    classes.write_text(json.dumps({"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4}}))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o"), "--quiet",
                 "--classes", str(classes)]) == 0
    assert load_frame(tmp_path / "o" / "street.json").classes["Kayak"].median_m == (4.0, 0.7, 0.4)
    classes.write_text(json.dumps({"Kayak": {"length_m": -4.0, "width_m": 0.7, "height_m": 0.4}}))
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "p"), "--classes", str(classes)]) == 2
    assert "Kayak.length_m" in capsys.readouterr().err
