"""Fuzzing the importers: the shipped test exports (and a scene of several targets in each tool), mutated at random
(values replaced by other types, keys deleted or added, lists cut short, elements duplicated,
XML attributes and tags changed), must either convert or be refused with the package's own input
error, ConversionError (which the command line reports in one line with exit status 2), never
with any other exception. What converts must be writable (JSON with finite numbers only)."""

import copy
import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fuzz_strategies import FUZZ, mutated_json, mutated_xml

from test_import_labelstudio import KAYAK, tool_scene

from creference_bayes.io.annotation_tools import ConversionError
from creference_bayes.io.cvat import cvat_xml, read_cvat_xml, scenes_from_cvat
from creference_bayes.io.labelstudio import label_studio_tasks, loads_export, scenes_from_label_studio
from creference_bayes.models.size_priors import size_priors_from_dict

DATA = Path(__file__).parent / "data"


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


@FUZZ
@given(data=st.data())
def test_mutated_label_studio_exports_convert_or_are_refused(data, image_dir):
    text, options = mutated_json(LS_EXPORT, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_label_studio(loads_export(text), **options))


@FUZZ
@given(data=st.data())
def test_mutated_label_studio_scenes_of_several_targets_convert_or_are_refused(data, image_dir):
    text, options = mutated_json(LS_SCENES, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_label_studio(loads_export(text), **options))


# ----------------------------------------------------------------------------------------------
# CVAT: XML


@FUZZ
@given(data=st.data())
def test_mutated_cvat_xml_converts_or_is_refused(data, image_dir):
    xml, options = mutated_xml(CVAT_XML, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_cvat(read_cvat_xml(xml), **options))


@FUZZ
@given(data=st.data())
def test_mutated_cvat_scenes_of_several_targets_convert_or_are_refused(data, image_dir):
    xml, options = mutated_xml(CVAT_SCENES, data), _options(data, image_dir)
    _assert_imports_or_refuses(lambda: scenes_from_cvat(read_cvat_xml(xml), classes=CLASSES, **options))
