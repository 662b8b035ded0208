"""Fuzzing the importers: the shipped test exports (and a scene of several targets in each tool), mutated at random
(values replaced by other types, keys deleted or added, lists cut short, elements duplicated,
XML attributes and tags changed), must either convert or be refused with the package's own input
error, ConversionError (which the command line reports in one line with exit status 2), never
with any other exception. What converts must be writable (JSON with finite numbers only)."""

import copy
import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from test_import_labelstudio import KAYAK, tool_scene

from creference_bayes.io.annotation_tools import ConversionError
from creference_bayes.io.cvat import cvat_xml, read_cvat_xml, scenes_from_cvat
from creference_bayes.io.labelstudio import label_studio_tasks, loads_export, scenes_from_label_studio
from creference_bayes.models.size_priors import size_priors_from_dict

DATA = Path(__file__).parent / "data"
#: CREFERENCE_FUZZ_EXAMPLES=5000 runs a longer fuzz (and a random one) when looking for crashes.
_N = int(os.environ.get("CREFERENCE_FUZZ_EXAMPLES", "150"))
FUZZ = settings(max_examples=_N, deadline=None, derandomize=_N <= 150,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _second_task_on_one_image(tasks):
    """Task 17's image once more, with another target (the one-target layout of a photo)."""
    t = copy.deepcopy(tasks[0])
    t["id"], t["data"]["target_id"] = 170, "lamp"
    t["annotations"] = t["annotations"][:1]
    return t


def _with_camera_id(scene, camera_id="rig/front"):
    """The scene with its camera's name (a task's data.camera_id, a CVAT camera tag)."""
    return {**scene, "camera": {**scene.get("camera", {}), "id": camera_id}}


LS_EXPORT = json.loads((DATA / "label_studio_export.json").read_text())
#: The export, a second task on one of its images, and scenes of three targets (keypoints and vectors;
#: the first with its camera's name).
LS_SCENES = (LS_EXPORT + [_second_task_on_one_image(LS_EXPORT)]
             + label_studio_tasks([_with_camera_id(tool_scene(5))], lines="keypoints", start_id=30)
             + label_studio_tasks([tool_scene(5)], lines="vectors", start_id=40))
CVAT_XML = (DATA / "cvat_annotations.xml").read_bytes()
CVAT_SCENES = cvat_xml([_with_camera_id(tool_scene(5))], image_names=["drive/000007.png"]).encode()
CLASSES = size_priors_from_dict({"Kayak": KAYAK})  # a class of the scene's own: CVAT needs --classes

#: Keys and texts the importers look for, so that added keys and replaced values hit real branches.
WORDS = ["", "0", "-1", "1e400", "nan", "inf", "2.5", "id", "data", "annotations", "completions", "result",
         "value", "type", "from_name", "to_name", "original_width", "original_height", "image_rotation",
         "x", "y", "vertices", "prevPointId", "closed", "keypointlabels", "vectorlabels", "choices", "number",
         "text", "textarea", "relation", "from_id", "to_id", "points", "lines", "targets", "target", "class",
         "image", "target_id", "image_width", "image_height", "focal_length_px", "horizon", "principal_point",
         "ground_truth", "frame_id", "dimensions_m", "t1 bottom corner", "t4 top of height", "reference start",
         "reference end", "reference", "measure", "mode", "direct", "relative", "unit", "m", "range_low",
         "range_high", "confidence_pct", "was_cancelled", "lead_time", "completed_by", "creference_scene",
         "__undefined__", "Car", "Misc", "camera_id", "camera", "/data/local-files/?d=a/b.png", "http://[::1"]
LEAVES = st.one_of(st.none(), st.booleans(), st.integers(-10**4, 10**4), st.integers(), st.just(10**400),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8), st.sampled_from(WORDS))
VALUES = st.recursive(LEAVES, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.one_of(st.sampled_from(WORDS), st.text(max_size=4)),
                                                 inner, max_size=4)), max_leaves=6)


@pytest.fixture(scope="module")
def image_dir(tmp_path_factory):
    """A folder holding some of the images the seeds name (--image-dir looks for them)."""
    folder = tmp_path_factory.mktemp("images")
    for name in ("ab12cd34-room.jpg", "000007.png", "photos/street.png"):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"")
    return folder


def _options(data, image_dir):
    """--image-dir (or not), with the output folder beside it."""
    use = data.draw(st.booleans(), label="image_dir")
    return {"image_dir": image_dir, "out_dir": image_dir.parent / "out"} if use else {}


def _assert_imports_or_refuses(run):
    try:
        report = run()
    except ConversionError:
        return
    for err in report.errors:
        assert isinstance(err, ConversionError), repr(err)
    for s in report.scenes:
        json.dumps(s.scene, allow_nan=False)  # what write_scenes writes
    json.dumps(report.to_dict(), allow_nan=False)


# ----------------------------------------------------------------------------------------------
# Label Studio: JSON


def _places(node, path=()):
    """Every place in a JSON document, as a key path."""
    yield path
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _places(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _places(v, path + (i,))


def _mutate_json(doc, data):
    path = data.draw(st.sampled_from(list(_places(doc))[1:]), label="path")
    *head, last = path
    parent = doc
    for k in head:
        parent = parent[k]
    value = parent[last]
    kind = data.draw(st.sampled_from(["replace", "replace", "delete", "add", "truncate", "copy"]), label="kind")
    if kind == "replace":
        parent[last] = data.draw(VALUES, label="value")
    elif kind == "delete":
        del parent[last]
    elif kind == "add" and isinstance(value, dict):
        value[data.draw(st.sampled_from(WORDS), label="key")] = data.draw(VALUES, label="value")
    elif kind == "add" and isinstance(value, list):
        value.insert(data.draw(st.integers(0, len(value)), label="at"), copy.deepcopy(value[0]) if value
                     and data.draw(st.booleans(), label="copy") else data.draw(VALUES, label="value"))
    elif kind == "truncate" and isinstance(value, (list, str)):
        parent[last] = value[:data.draw(st.integers(0, max(len(value) - 1, 0)), label="length")]
    elif kind == "copy":  # another part of the document in its place: the right shape in the wrong place
        other = data.draw(st.sampled_from(list(_places(doc))), label="from")
        node = doc
        for k in other:
            node = node[k]
        parent[last] = copy.deepcopy(node)


def _mutated(doc, data) -> str:
    """The document mutated 1 to 3 times, as JSON text (an export is a file: the importer reads
    it as the command line does, with loads_export)."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        _mutate_json(doc, data)
    return json.dumps(doc)


@FUZZ
@given(data=st.data())
def test_mutated_label_studio_exports_convert_or_are_refused(data, image_dir):
    text, options = _mutated(LS_EXPORT, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_label_studio(loads_export(text), **options))


@FUZZ
@given(data=st.data())
def test_mutated_label_studio_scenes_of_several_targets_convert_or_are_refused(data, image_dir):
    text, options = _mutated(LS_SCENES, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_label_studio(loads_export(text), **options))


# ----------------------------------------------------------------------------------------------
# CVAT: XML


ATTRIBUTE_NAMES = ["name", "width", "height", "label", "points", "id", "target_id", "class", "length_m",
                   "width_m", "height_m", "measure", "mode", "value", "range_low", "range_high", "unit",
                   "confidence_pct", "worker", "object", "camera_id"]
TEXTS = st.one_of(st.sampled_from(WORDS + ATTRIBUTE_NAMES + ["1,2;3,4", "1,2;3,4;5,6;7,8", "0,0;0,0", "1;2",
                                                           "1e999,2;3,4", "nan,1;2,3", "2000", "4000.5"]),
                  st.text(max_size=10), st.integers().map(str), st.floats().map(str))
TAGS = ["image", "points", "polyline", "box", "polygon", "tag", "attribute", "track", "version", "meta", "x"]


def _mutate_xml(root, data):
    elements = list(root.iter())
    parents = {child: parent for parent in elements for child in parent}
    el = data.draw(st.sampled_from(elements[1:]), label="element")
    kind = data.draw(st.sampled_from(["attr", "attr", "text", "drop_attr", "delete", "duplicate", "tag",
                                      "truncate_points"]), label="kind")
    if kind == "attr":
        el.set(data.draw(st.sampled_from(sorted(el.attrib) + ATTRIBUTE_NAMES), label="name"), data.draw(TEXTS))
    elif kind == "text":
        el.text = data.draw(TEXTS, label="text")
    elif kind == "drop_attr" and el.attrib:
        del el.attrib[data.draw(st.sampled_from(sorted(el.attrib)), label="name")]
    elif kind == "delete":
        parents[el].remove(el)
    elif kind == "duplicate":
        parent = parents[el]
        parent.insert(list(parent).index(el), copy.deepcopy(el))
    elif kind == "tag":
        el.tag = data.draw(st.sampled_from(TAGS), label="tag")
    elif kind == "truncate_points" and el.get("points"):
        pts = el.get("points")
        el.set("points", pts[:data.draw(st.integers(0, len(pts) - 1), label="length")])


def _mutated_xml(text: bytes, data) -> bytes:
    root = ET.fromstring(text)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        _mutate_xml(root, data)
    out = ET.tostring(root)
    if data.draw(st.integers(0, 19), label="cut") == 0:  # now and then, a file cut short
        out = out[:data.draw(st.integers(0, len(out)), label="at")]
    return out


@FUZZ
@given(data=st.data())
def test_mutated_cvat_xml_converts_or_is_refused(data, image_dir):
    xml, options = _mutated_xml(CVAT_XML, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_cvat(read_cvat_xml(xml), **options))


@FUZZ
@given(data=st.data())
def test_mutated_cvat_scenes_of_several_targets_convert_or_are_refused(data, image_dir):
    xml, options = _mutated_xml(CVAT_SCENES, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_cvat(read_cvat_xml(xml), classes=CLASSES, **options))
