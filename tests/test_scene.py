"""Loading and validating scene files (formats.md): version 1 (one target) as every scene reads it,
and the frame format (several targets) in tests/test_scenes_v2.py."""

import copy
import json
import math
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from creference_bayes.cli.main import example_scene_path
from creference_bayes.io.scene import (Scene, SceneError, SceneWarning, load_scene, parse_scene,
                                       scene_to_dict)
from creference_bayes.bench.simulate import simulate_scene

#: "<key path>: <problem>" on one line; key paths are dotted keys with [i] indices, or "(scene)" /
#: the file's path for a file that is not JSON.
MESSAGE = re.compile(r"^(?:\(scene\)|\S+\.json|[a-z_]+(?:\[\d+\]|\.[a-z_]+)*): \S[^\n]*$")


def _example() -> dict:
    return json.loads(example_scene_path().read_text())


def _parse(data, **kwargs) -> Scene:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return parse_scene(data, **kwargs)


def _error(data) -> SceneError:
    with pytest.raises(SceneError) as info:
        _parse(data)
    return info.value


# ------------------------------------------------------------------------------------------------
# valid scenes


def test_example_scene_loads():
    scene = load_scene(example_scene_path())
    raw = _example()
    assert scene.image_size == (2880, 1800)
    assert scene.targets[0].id == raw["target"]["id"]
    assert scene.targets[0].corners.shape == (len(raw["target"]["dimension_lines"]), 4, 2)
    assert len(scene.references) == len(raw["references"])
    np.testing.assert_array_equal(scene.principal_point, raw["camera"]["principal_point"])
    assert scene.focal_length_px is None
    np.testing.assert_array_equal(scene.horizon, raw["horizon"])
    np.testing.assert_array_equal(scene.targets[0].ground_truth["location_m"], raw["ground_truth"]["location_m"])
    assert scene.ground_truth["focal_length_px"] == raw["ground_truth"]["focal_length_px"]  # the camera's
    assert scene.targets[0].ground_truth["handedness"] in (1, -1)
    assert scene.warnings == ()
    assert scene.source == example_scene_path()


def test_defaults_when_optional_keys_absent():
    d = _example()
    for key in ("camera", "horizon", "references", "ground_truth"):
        del d[key]
    scene = _parse(d)
    np.testing.assert_array_equal(scene.principal_point, [1440.0, 900.0])  # image centre
    assert scene.horizon is None and scene.focal_length_px is None
    assert scene.references == () and scene.ground_truth is None


def test_known_focal_length_is_kept():
    d = _example()
    d["camera"]["focal_length_px"] = 1650
    assert _parse(d).focal_length_px == 1650.0


@pytest.mark.parametrize("unit, metres_per_unit", [
    ("m", 1.0), ("cm", 0.01), ("in", 0.0254), ("ft", 12 * 0.0254), ("yd", 36 * 0.0254)])
def test_direct_values_are_converted_to_metres(unit, metres_per_unit):
    d = _example()
    d["references"][0] = {"measure": "length", "mode": "direct", "value": 80, "unit": unit,
                          "line": [[400.0, 1290.0], [977.0, 1301.0]]}
    d["references"][1] = {"measure": "distance", "mode": "direct", "range": [10, 15], "unit": unit,
                          "line": [[2400.0, 1799.0], [2371.5, 1190.4]]}
    scene = _parse(d)
    r0, r1 = scene.references[:2]
    assert (r0.low, r0.high, r0.is_range) == pytest.approx((80 * metres_per_unit,) * 2 + (False,), rel=1e-12)
    assert (r1.low, r1.high, r1.is_range) == pytest.approx((10 * metres_per_unit, 15 * metres_per_unit, True),
                                                           rel=1e-12)


def test_relative_measures_scale_with_the_target():
    d = _example()
    d["target"]["dimensions_m"] = {"length": 1.2, "width": 0.5, "height": 2.0}
    d["references"][0] = {"measure": "length", "mode": "relative", "range": [0.5, 2.0],
                          "line": [[400.0, 1290.0], [977.0, 1301.0]]}
    d["references"][1] = {"measure": "width", "mode": "relative", "value": 3,
                          "line": [[400.0, 1290.0], [977.0, 1301.0]]}
    scene = _parse(d)
    r0, r1 = scene.references[:2]
    assert (r0.low, r0.high, r0.unit) == (0.5, 2.0, None)  # ratios are kept as ratios
    t = scene.targets[0]  # a ratio to the target's own length or width
    assert (r0.low * t.dimensions[0], r0.high * t.dimensions[0]) == pytest.approx((0.6, 2.4))
    assert (r1.low * t.dimensions[1], r1.high * t.dimensions[1]) == pytest.approx((1.5, 1.5))


def test_median_corners_is_per_corner_median():
    d = _example()
    base = np.array([[1000.0, 1200.0], [1200.0, 1190.0], [950.0, 1150.0], [1000.0, 900.0]])
    offsets = [0.0, 10.0, -4.0]  # per annotation, added to every coordinate
    d["target"]["dimension_lines"] = [{"corners": (base + o).tolist()} for o in offsets]
    d["target"]["dimension_lines"][2]["corners"][1] = [1300.0, 1000.0]  # one outlying corner
    scene = _parse(d)
    expected = base.copy()  # the median of offsets (0, 10, −4) is 0 ...
    expected[1] = [1210.0, 1190.0]  # ... of (1200, 1210, 1300) 1210, of (1190, 1200, 1000) 1190
    np.testing.assert_array_equal(scene.targets[0].median_corners, expected)


def test_unknown_keys_warn_with_their_names():
    d = _example()
    d["notes"] = "made by hand"
    d["image"]["colour"] = "rgb"
    d["target"]["dimension_lines"][0]["confidence"] = 0.5
    d["references"][1]["note"] = "hard to see"  # two edits from 'mode': too far for a short key
    d["references"][2]["order"] = 3  # two edits from 'worker'
    d["references"][3]["object_id"] = "c7"  # 'object' plus more than a third of it
    with pytest.warns(SceneWarning) as record:
        scene = parse_scene(d)
    messages = [str(w.message) for w in record]
    assert sorted(messages) == sorted([
        "notes: unknown key ignored", "image.colour: unknown key ignored",
        "target.dimension_lines[0].confidence: unknown key ignored",
        "references[1].note: unknown key ignored", "references[2].order: unknown key ignored",
        "references[3].object_id: unknown key ignored"])
    assert set(scene.warnings) == set(messages)


def _rename(path, new):
    """Mutation: rename the key at ``path`` (a tuple of keys and indices) to ``new``."""
    def mutate(d):
        *parent, key = path
        obj = d
        for k in parent:
            obj = obj[k]
        obj[new] = obj.pop(key, 0.5)  # a key the example lacks gets a value
    return mutate


@pytest.mark.parametrize("path, typo, expected", [
    (("references",), "refrences", "refrences: unknown key; did you mean 'references'?"),
    (("horizon",), "Horizon", "Horizon: unknown key; did you mean 'horizon'?"),
    (("ground_truth",), "ground-truth", "ground-truth: unknown key; did you mean 'ground_truth'?"),
    (("image", "height"), "heigth", "image.heigth: unknown key; did you mean 'height'?"),
    (("camera", "focal_length_px"), "focal_length", "camera.focal_length: unknown key; did you mean 'focal_length_px'?"),
    (("target", "dimension_lines"), "dimension_line", "target.dimension_line: unknown key; did you mean 'dimension_lines'?"),
    (("target", "dimensions_m", "length"), "lenght", "target.dimensions_m.lenght: unknown key; did you mean 'length'?"),
    (("target", "dimension_lines", 0, "corners"), "cornres", "target.dimension_lines[0].cornres: unknown key; did you mean 'corners'?"),
    (("references", 2, "value"), "valeu", "references[2].valeu: unknown key; did you mean 'value'?"),
    (("references", 0, "unit"), "units", "references[0].units: unknown key; did you mean 'unit'?"),
    (("references", 0, "mode"), "model", "references[0].model: unknown key; did you mean 'mode'?"),
    (("references", 1, "confidence"), "confidance", "references[1].confidance: unknown key; did you mean 'confidence'?"),
    (("camera", "principal_point"), "principal point", "camera.principal point: unknown key; did you mean 'principal_point'?"),
])
def test_a_near_miss_of_a_known_key_is_an_error_naming_the_suggestion(path, typo, expected):
    d = _example()
    d.setdefault("camera", {})["focal_length_px"] = 1200.0
    _rename(path, typo)(d)
    with pytest.raises(SceneError) as info:
        parse_scene(d)
    assert str(info.value) == expected


def test_ground_truth_is_free_form_even_for_near_misses():
    d = _example()
    d["ground_truth"]["yaw_radians"] = 0.3  # not checked against yaw_rad: extras are free-form
    assert _parse(d).targets[0].ground_truth["yaw_radians"] == 0.3


@pytest.mark.parametrize("a, b, distance", [
    ("height", "heigth", 1), ("references", "refrences", 1), ("mode", "note", 2),
    ("", "abc", 3), ("kitten", "sitting", 3), ("ca", "abc", 3),  # OSA, not full Damerau: 3
])
def test_edit_distance_known_answers(a, b, distance):
    from creference_bayes.io.validation import _edit_distance

    assert _edit_distance(a, b) == distance
    assert _edit_distance(b, a) == distance


@pytest.mark.parametrize("key, value", [("focal_length_px", -1.0), ("camera_height_m", 0.0), ("pitch_rad", "up")])
def test_the_cameras_truth_is_checked_in_both_formats(key, value):
    """A version-2 file's camera truth is held to what version 1 asks of the same keys."""
    from creference_bayes.io.scene import scene_to_dict

    v2 = scene_to_dict(_parse(_example()))
    v2["ground_truth"] = {**(v2.get("ground_truth") or {}), key: value}
    with pytest.raises(SceneError, match=f"ground_truth.{key}"):
        parse_scene(v2)
    v1 = _example()
    v1["ground_truth"][key] = value
    with pytest.raises(SceneError, match=f"ground_truth.{key}"):
        parse_scene(v1)


def test_ground_truth_may_carry_extra_keys():
    d = _example()
    d["ground_truth"]["notes"] = "measured with a tape"
    scene = _parse(d)
    assert scene.targets[0].ground_truth["notes"] == "measured with a tape"
    assert scene.warnings == ()


def test_scene_to_dict_round_trips():
    """A version-1 scene is written as version 2 (the format written) and reads back as the same
    scene; a version-2 dict round-trips exactly."""
    from creference_bayes.io.scene import scene_fingerprint

    for d in (_example(), simulate_scene(3, tier="high", n_target_annotations=3)):
        d["camera"]["focal_length_px"] = 1500.0
        d["image"]["path"] = "photo.png"
        d["references"][0]["confidence"] = 0.6
        scene = _parse(d)
        out = scene_to_dict(scene)
        json.dumps(out, allow_nan=False)  # plain JSON types only
        assert out["format"] == "creference-scene/2" and len(out["targets"]) == 1
        again = _parse(out)
        assert scene_fingerprint(again) == scene_fingerprint(scene)
        assert _same_targets(again.targets, scene.targets)
        assert scene_to_dict(again) == out


def test_corner_scale_round_trips_and_names_its_bad_key():
    d = _example()
    d["corner_scale"] = {"sd_px": 2.5, "dof": 48}
    scene = _parse(d)
    assert scene.corner_scale == (2.5, 48.0)
    assert scene_to_dict(scene)["corner_scale"] == {"sd_px": 2.5, "dof": 48.0}
    for bad, key in (({"sd_px": 0, "dof": 8}, "corner_scale.sd_px"), ({"sd_px": 2.0}, "corner_scale.dof"),
                     ([2.0, 8], "corner_scale")):
        d["corner_scale"] = bad
        with pytest.raises(SceneError, match=re.escape(key)):
            _parse(d)


def test_a_scenes_setting_round_trips_and_names_its_bad_value():
    d = _example()
    assert _parse(d).setting is None and "setting" not in scene_to_dict(_parse(d))
    d["setting"] = "warehouse aisle"
    scene = _parse(d)
    assert scene.setting == "warehouse aisle" and scene_to_dict(scene)["setting"] == "warehouse aisle"
    d["setting"] = "  warehouse aisle "
    assert _parse(d).setting == "warehouse aisle"  # one setting however it is padded
    for bad, says in (("", "(not empty), got ''"), ("  ", "(not empty), got '"),
                      (3, "expected a string"), ("a\tb", "control character"),
                      ("x" * 101, "(at most 100 characters)"), ("room\u202e", "(no invisible formatting characters)")):
        d["setting"] = bad
        with pytest.raises(SceneError, match=r"^setting: .*" + re.escape(says)):
            _parse(d)


def _same_targets(a, b) -> bool:
    return all(x.id == y.id and x.dimensions == y.dimensions and np.array_equal(x.corners, y.corners)
               and x.ground_truth == y.ground_truth for x, y in zip(a, b))


def test_scene_to_dict_keeps_image_path_relative_to_the_file(tmp_path):
    d = _example()
    d["image"]["path"] = "img/photo.png"
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    scene = load_scene(path)
    assert scene.image_path == tmp_path / "img" / "photo.png"
    assert scene_to_dict(scene)["image"]["path"] == "img/photo.png"


# ------------------------------------------------------------------------------------------------
# invalid files


@pytest.mark.parametrize("constant", ["NaN", "Infinity", "-Infinity"])
def test_json_nan_and_infinity_constants_are_rejected(tmp_path, constant):
    text = json.dumps(_example()).replace('"focal_length_px": null', f'"focal_length_px": {constant}', 1)
    assert constant in text
    path = tmp_path / "scene.json"
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"{path}: non-standard JSON constant")
    assert constant in str(info.value)


@pytest.mark.parametrize("content, start", [
    (b'{"format": "creference-scene/1",', "not valid JSON"),
    (b"\xff\xfe\x00garbage", "not UTF-8 text"),
    (b"[" * 100_000, ""),
])
def test_broken_files_give_scene_errors(tmp_path, content, start):
    path = tmp_path / "scene.json"
    path.write_bytes(content)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(info.value).startswith(f"{path}: {start}")  # the file's name, not "(file)"
    assert MESSAGE.match(str(info.value))


def test_missing_file_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_scene(tmp_path / "nope.json")


# ------------------------------------------------------------------------------------------------
# invalid scenes: each message starts with the key path and names the value


def _set(path, value):
    def mutate(d):
        *head, last = path
        obj = d
        for k in head:
            obj = obj[k]
        obj[last] = value(obj[last]) if callable(value) else value
    return mutate


def _delete(path):
    def mutate(d):
        *head, last = path
        obj = d
        for k in head:
            obj = obj[k]
        del obj[last]
    return mutate


def _ref2_furlong(d):
    d["references"][2].update(mode="direct", unit="furlong")


def _reversed_range(d):
    d["references"][1]["range"] = [15, 10]


def _relative_distance(d):
    d["references"][1]["mode"] = "relative"
    del d["references"][1]["unit"]


def _both_value_and_range(d):
    d["references"][0]["value"] = 3


def _neither_value_nor_range(d):
    del d["references"][0]["range"]


def _zero_length_reference(d):
    line = d["references"][3]["line"]
    line[1] = list(line[0])


def _zero_length_width_line(d):
    c = d["target"]["dimension_lines"][1]["corners"]
    c[2] = list(c[0])


def _direct_without_unit(d):
    del d["references"][0]["unit"]


def _relative_with_unit(d):
    d["references"][2]["unit"] = "m"


INVALID = [
    (_ref2_furlong, "references[2].unit: unknown unit 'furlong'"),
    (_reversed_range, "references[1].range: low 15 > high 10"),
    (_relative_distance, "references[1].mode: 'relative' is not valid for measure 'distance'"),
    (_both_value_and_range, "references[0]: both 'value' 3 and 'range' [0.734, 0.9024] given"),
    (_neither_value_nor_range, "references[0]: missing required key 'value' or 'range'"),
    (_zero_length_reference, "references[3].line: zero-length line from [2246.16, 985.385]"),
    (_zero_length_width_line, "target.dimension_lines[1].corners: zero-length width line from"),
    (_direct_without_unit, "references[0].unit: missing required key"),
    (_relative_with_unit, "references[2].unit: a relative measurement takes no unit, got 'm'"),
    (_set(("references", 4, "measure"), "height"), "references[4].measure: unknown measure 'height'"),
    (_set(("references", 4, "mode"), None), "references[4].mode: unknown mode None"),
    (_set(("references", 0, "range", 0), -1), "references[0].range[0]: expected a positive number, got -1"),
    (_set(("references", 2, "value"), 0), "references[2].value: expected a positive number, got 0"),
    (_set(("references", 0, "confidence"), 1.5), "references[0].confidence: expected a number in [0.0, 1.0], got 1.5"),
    (_set(("target", "dimensions_m", "height"), math.nan), "target.dimensions_m.height: expected a finite number, got nan"),
    (_set(("references", 1, "line", 0, 1), math.inf), "references[1].line[0][1]: expected a finite number, got inf"),
    (_set(("camera", "focal_length_px"), -math.inf), "camera.focal_length_px: expected a finite number, got -inf"),
    (_set(("image", "width"), 10**400), "image.width: expected a finite number, got 1000000"),
    (_set(("image", "width"), "2880"), "image.width: expected a number, got str '2880'"),
    (_set(("image", "height"), True), "image.height: expected a number, got bool True"),
    (_set(("image", "width"), 2880.5), "image.width: expected whole pixels, got 2880.5"),
    (_set(("image", "width"), 10**7), "image.width: expected at most 1000000 pixels, got 1e+07"),
    (_set(("target", "dimension_lines"), {}), "target.dimension_lines: expected a list, got dict {}"),
    (_set(("target", "dimension_lines"), []), "target.dimension_lines: expected at least one annotation"),
    (_set(("target", "dimension_lines", 0, "corners", 1), "a"), "target.dimension_lines[0].corners[1]: expected a list, got str 'a'"),
    (_set(("target", "dimension_lines", 0, "corners", 1), [1.0, 2.0, 3.0]),
     "target.dimension_lines[0].corners[1]: expected a point [u, v], got [1.0, 2.0, 3.0]"),
    (_set(("target", "dimension_lines", 0, "corners"), lambda c: c[:3]),
     "target.dimension_lines[0].corners: expected 4 points, got 3"),
    (_set(("target", "dimension_lines", 0, "worker"), 17), "target.dimension_lines[0].worker: expected a string, got int 17"),
    (_set(("target", "id"), None), "target.id: expected a string, got null None"),
    (_set(("references",), {"a": 1}), "references: expected a list, got dict {'a': 1}"),
    (_set(("references", 0), "sofa"), "references[0]: expected an object, got str 'sofa'"),
    (_set(("camera",), [1, 2]), "camera: expected an object, got list [1, 2]"),
    (_set(("camera", "principal_point"), [3000.0, 900.0]), "camera.principal_point: [3000, 900] lies outside the 2880x1800 image"),
    (_set(("camera", "principal_point"), [1440.0, "900"]), "camera.principal_point[1]: expected a number, got str '900'"),
    (_set(("target", "dimension_lines", 2, "corners", 3), [1e6, 5.0]),
     "target.dimension_lines[2].corners[3]: point [1e+06, 5] is far outside the 2880x1800 image"),
    (_set(("references", 0, "line", 1), [-2000.0, 900.0]), "references[0].line[1]: point [-2000, 900] is far outside"),
    (_set(("horizon", 1), [0.0, 885.287959567601]), "horizon: zero-length line"),
    (_set(("horizon", 1), [100.0, 5000.0]), "horizon: a horizon steeper than 45 degrees is not supported"),
    (_set(("horizon", 0, 1), -1e9), "horizon[0]: point [0, -1e+09] is far outside the 2880x1800 image"),
    (_set(("format",), "creference-scene/2"), "target: a key of 'creference-scene/1', but the scene's format is "
     "'creference-scene/2': write the one target as \"targets\": [ … ] (with an id), or set \"format\": \"creference-scene/1\""),
    (_set(("targets",), []), "targets: a key of 'creference-scene/2', but the scene's format is 'creference-scene/1': "
     "set \"format\": \"creference-scene/2\" (a list of targets, each with an id)"),
    (_set(("format",), "creference-scene/9"), "format: expected 'creference-scene/1' or 'creference-scene/2', got 'creference-scene/9'"),
    (_delete(("format",)), "format: missing required key"),
    (_delete(("image",)), "image: missing required key"),
    (_delete(("image", "width")), "image.width: missing required key"),
    (_delete(("target",)), "target: missing required key"),
    (_delete(("target", "dimensions_m")), "target.dimensions_m: missing required key"),
    (_delete(("target", "dimensions_m", "width")), "target.dimensions_m.width: missing required key"),
    (_delete(("target", "dimension_lines", 0, "corners")), "target.dimension_lines[0].corners: missing required key"),
    (_delete(("references", 3, "line")), "references[3].line: missing required key"),
    (_delete(("references", 3, "measure")), "references[3].measure: missing required key"),
    (_delete(("ground_truth", "location_m")), "ground_truth.location_m: missing required key"),
    (_set(("ground_truth", "location_m", 2), -1.0), "ground_truth.location_m[2]: z must be > 0 (in front of the camera), got -1.0"),
    (_set(("ground_truth", "location_m"), [1.0, 2.0]), "ground_truth.location_m: expected [x, y, z], got [1.0, 2.0]"),
    (_set(("ground_truth", "handedness"), 0), "ground_truth.handedness: expected 1 or -1, got int 0"),
    (_set(("ground_truth", "camera_height_m"), math.nan), "ground_truth.camera_height_m: expected a finite number, got nan"),
]


@pytest.mark.parametrize("mutate, expected", INVALID, ids=[e.split(":")[0] + "-" + str(i) for i, (_, e) in enumerate(INVALID)])
def test_invalid_scene_message(mutate, expected):
    d = _example()
    mutate(d)
    exc = _error(d)
    message = str(exc)
    assert message.startswith(expected), message
    assert MESSAGE.match(message), message
    assert message == f"{exc.path}: {exc.problem}"


def test_not_a_dict():
    assert str(_error([1, 2])).startswith("(scene): expected an object, got list [1, 2]")


def test_long_values_are_cut_in_messages():
    d = _example()
    d["references"][0]["unit"] = "x" * 10_000
    message = str(_error(d))
    assert message.startswith("references[0].unit: unknown unit 'xxx")
    assert len(message) < 200


def test_parse_does_not_modify_its_input():
    d = _example()
    before = copy.deepcopy(d)
    _parse(d)
    assert d == before


# ------------------------------------------------------------------------------------------------
# property test: mutated scenes give SceneError or a scene that is really valid


def _bases() -> list[dict]:
    one = simulate_scene(11, setting="outdoor", tier="medium", n_target_annotations=2, n_references=5)
    one["camera"]["focal_length_px"] = 1800.0
    two = _example()
    two["target"]["dimension_lines"] = two["target"]["dimension_lines"][:3]
    return [json.loads(json.dumps(b)) for b in (one, two)]  # no dict shared between two keys


BASES = _bases()
#: Ground-truth keys that are free-form (kept as they are, not validated).
FREE_KEYS = {"setting", "tier", "target_object", "reference_lengths_m", "reference_lines_px",
             "target_corners_px", "notes"}


def _locations(obj, path=()):
    """Every (path, value) in a decoded JSON document, containers included."""
    yield path, obj
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, list) else ()
    for k, v in items:
        yield from _locations(v, path + (k,))


def _path_text(path) -> str:
    out = ""
    for k in path:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else k)
    return out


def _is_free(path) -> bool:
    truth = path.index("ground_truth") if "ground_truth" in path else None
    return truth is not None and len(path) > truth + 1 and path[truth + 1] in FREE_KEYS


ODD_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30), st.just(10**400),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6),
    st.sampled_from(["m", "furlong", "length", "distance", "relative", "direct", "", "NaN"]),
    st.lists(st.floats(-1e4, 1e4), max_size=3), st.builds(lambda: [[0.0, 0.0], [0.0, 0.0]]),
    st.dictionaries(st.sampled_from(["a", "value", "range", "unit"]), st.integers(-3, 3), max_size=2),
)

MUTATIONS = ("delete", "replace", "nonfinite", "reverse", "collapse", "far", "scale", "unit", "measure")


def _is_float(value) -> bool:
    return isinstance(value, float) or isinstance(value, int) and not isinstance(value, bool) and abs(value) < 2**53


def _reference(d: dict, path: tuple) -> dict | None:
    """The reference object that ``path`` points into, if it is still one."""
    if len(path) < 2 or path[0] != "references" or not isinstance(d.get("references"), list):
        return None
    refs = d["references"]
    ok = isinstance(path[1], int) and path[1] < len(refs) and isinstance(refs[path[1]], dict)
    return refs[path[1]] if ok else None


def _mutate(d: dict, data) -> tuple[str, tuple]:
    locations = [p for p, _ in _locations(d) if p and not _is_free(p)]
    path = data.draw(st.sampled_from(locations), label="path")
    kind = data.draw(st.sampled_from(MUTATIONS), label="mutation")
    *head, last = path
    parent = d
    for k in head:
        parent = parent[k]
    value = parent[last]
    if kind == "delete":
        del parent[last]
    elif kind == "replace":
        parent[last] = data.draw(ODD_VALUES, label="value")
    elif kind == "nonfinite":
        parent[last] = data.draw(st.sampled_from([math.nan, math.inf, -math.inf]), label="value")
    elif kind == "reverse" and isinstance(value, list):
        parent[last] = value[::-1]
    elif kind == "collapse" and isinstance(value, list) and len(value) >= 2:
        value[1] = copy.deepcopy(value[0])
    elif kind == "far" and _is_float(value):
        parent[last] = value + data.draw(st.sampled_from([-1e7, -5e3, 5e3, 1e7, 1e300]), label="offset")
    elif kind == "scale" and _is_float(value):
        parent[last] = value * data.draw(st.sampled_from([-1.0, 0.0, 1e-9, 1e9]), label="factor")
    elif kind == "unit" and _reference(d, path) is not None:
        _reference(d, path)["unit"] = data.draw(ODD_VALUES, label="unit")
    elif kind == "measure" and _reference(d, path) is not None:
        key = data.draw(st.sampled_from(["measure", "mode"]), label="key")
        _reference(d, path)[key] = data.draw(
            st.sampled_from(["length", "width", "distance", "direct", "relative", "height", None]), label="v")
    return kind, path


def _assert_really_valid(scene: Scene) -> None:
    """What a scene that parse_scene accepted must satisfy (formats.md)."""
    w, h = scene.image_size
    assert 0 < w <= 10**6 and 0 < h <= 10**6
    assert np.all(np.isfinite(scene.principal_point))
    assert 0 <= scene.principal_point[0] <= w and 0 <= scene.principal_point[1] <= h
    assert scene.focal_length_px is None or 0 < scene.focal_length_px < math.inf
    (t,) = scene.targets
    assert all(0 < x < math.inf for x in t.dimensions)
    c = t.corners
    assert c.shape[1:] == (4, 2) and np.all(np.isfinite(c))
    assert np.all(np.abs(c - [w / 2, h / 2]) <= [w, h])
    assert np.all(np.linalg.norm(c[:, 1:] - c[:, :1], axis=-1) > 0)
    if scene.horizon is not None:
        assert np.all(np.isfinite(scene.horizon)) and np.linalg.norm(np.diff(scene.horizon, axis=0)) > 0
    for r in scene.references:
        assert r.measure in ("length", "width", "distance") and r.mode in ("direct", "relative")
        assert not (r.measure == "distance" and r.mode == "relative")
        assert 0 < r.low <= r.high < math.inf
        assert (r.unit is None) == (r.mode == "relative")
        assert np.all(np.isfinite(r.line)) and np.linalg.norm(r.line[1] - r.line[0]) > 0
        assert np.all(np.abs(r.line - [w / 2, h / 2]) <= [w, h])
        assert r.confidence is None or 0 <= r.confidence <= 1
    if t.ground_truth is not None:
        assert np.all(np.isfinite(t.ground_truth["location_m"])) and t.ground_truth["location_m"][2] > 0
    json.dumps(scene_to_dict(scene), allow_nan=False)


@settings(max_examples=400, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(base=st.sampled_from(range(len(BASES))), n=st.integers(1, 3), data=st.data())
def test_mutated_scenes_raise_only_scene_errors(base, n, data):
    d = copy.deepcopy(BASES[base])
    done = [_mutate(d, data) for _ in range(n)]
    try:
        scene = _parse(d)
    except SceneError as exc:
        message = str(exc)
        assert "\n" not in message
        assert MESSAGE.match(message), message
        assert message == f"{exc.path}: {exc.problem}"
        if n == 1 and done[0][0] == "nonfinite":
            # a non-finite number is reported at exactly its own key path
            assert exc.path == _path_text(done[0][1]), (exc.path, done)
        return
    _assert_really_valid(scene)
    assert not (n == 1 and done[0][0] == "nonfinite"), f"accepted a non-finite value at {done}"


def test_scene_differences_names_each_changed_place_and_ignores_spelling():
    from creference_bayes.io.scene import scene_differences
    raw = _example()
    assert scene_differences(raw, _parse(raw)) == []  # a dict and its parsed Scene are the same
    other = copy.deepcopy(raw)
    other["target"]["dimension_lines"][0]["corners"][0][0] += 0.004
    other["references"][1]["range"] = [7.0, 9.9793]
    del other["horizon"]
    got = scene_differences(raw, other, atol=0.001)
    assert any(g.startswith("scene.targets[0].dimension_lines[0]") for g in got), got
    assert any(g.startswith("scene.references[1].") for g in got), got
    assert "scene.horizon: only in the first scene" in got
    # within atol, or under a dropped key, nothing is reported
    assert scene_differences(raw, other, atol=0.01, drop=("references", "horizon")) == []
