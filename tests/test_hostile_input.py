"""Hostile and unlucky input (issue 61): JSON from outside read by one reader with bounds, one bad
unit (a scene of a batch, a task of an export) refused by name while the others go on, ids that
end up in file names, result fields the commands index into, CSV cells a spreadsheet would run,
files already in an output folder, and scene size limits."""

import csv
import json

import pytest
from conftest import truth_scene
from fuzz_strategies import FUZZ
from hypothesis import given
from hypothesis import strategies as st

from creference_bayes.cli.main import main
from creference_bayes.io.scene import SceneError, load_scene
from creference_bayes.io.validation import MAX_INT_DIGITS, MAX_JSON_DEPTH, json_depth, read_json

DEEP = json.loads("[" * 500 + "]" * 500)


def _scene(seed=1, **options) -> dict:
    scene, _ = truth_scene(seed, m=1, noise_px=1.0, n_annotations=2, **options)
    return scene


def _deep_scene() -> dict:
    scene = _scene()
    scene["targets"][0]["ground_truth"]["note"] = DEEP
    return scene


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


# --- 1. one reader of outside JSON ----------------------------------------------------------------

def test_json_depth_is_found_without_recursion():
    assert json_depth(1) == 0 and json_depth([]) == 1 and json_depth({"a": [1, {"b": []}]}) == 4
    assert json_depth(json.loads("[" * 900 + "]" * 900)) == 900


@pytest.mark.parametrize("content, problem", [
    (json.dumps(_deep_scene()), f"JSON nested more than {MAX_JSON_DEPTH} deep"),
    ('{"format": "creference-scene/2", "x": ' + "7" * 5000 + "}", f"an integer of 5000 digits (at most {MAX_INT_DIGITS})"),
    ('{"format": "creference-scene/2", "x": -' + "7" * 401 + "}", "an integer of 401 digits"),
    ("[" * 5000 + "]" * 5000, "JSON nested too deeply"),
    ('{"x": NaN}', "non-standard JSON constant NaN"),
], ids=["deep", "big-int", "big-negative-int", "too-deep-to-decode", "nan"])
def test_a_hostile_scene_is_a_scene_error_naming_the_file(tmp_path, content, problem):
    path = tmp_path / "s.json"
    path.write_text(content)
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert str(err.value).startswith(f"{path}: ") and problem in str(err.value)


def test_the_reader_takes_a_bom_and_refuses_other_encodings(tmp_path):
    path = tmp_path / "c.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps({"a": 1}).encode())
    assert read_json(path) == {"a": 1}
    path.write_bytes('{"a": "é"}'.encode("latin-1"))
    with pytest.raises(SceneError, match=r"c\.json: not UTF-8 text: byte 7"):
        read_json(path)


@pytest.mark.parametrize("content", [
    json.dumps(_deep_scene()), '{"format": "creference-scene/2", "n": ' + "1" * 5000 + "}"], ids=["deep", "big-int"])
def test_estimate_refuses_a_hostile_scene_in_one_line(tmp_path, capsys, content):
    path = tmp_path / "s.json"
    path.write_text(content)
    assert main(["estimate", str(path), "--no-posterior", "--quiet"]) == 2
    assert _one_error_line(capsys).startswith(f"error: {path}: ")


@pytest.mark.parametrize("content, problem", [
    (b'{"car": "\xff"}', "not UTF-8 text"), (b"[" * 5000 + b"]" * 5000, "nested too deeply"),
    (b'{"car": {"length": ' + b"9" * 5000 + b"}}", "an integer of 5000 digits")], ids=["latin-1", "deep", "big-int"])
def test_a_hostile_classes_file_is_refused_in_one_line(tmp_path, capsys, content, problem):
    scene, classes = tmp_path / "s.json", tmp_path / "classes.json"
    scene.write_text(json.dumps(_scene()))
    classes.write_bytes(content)
    assert main(["estimate", str(scene), "--classes", str(classes), "--no-posterior", "--quiet"]) == 2
    line = _one_error_line(capsys)
    assert line.startswith(f"error: {classes}: ") and problem in line


def test_a_batch_reports_a_scene_that_fails_to_load_and_estimates_the_others(tmp_path, capsys):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "deep.json").write_text(json.dumps(_deep_scene()))
    (scenes / "huge.json").write_text('{"format": "creference-scene/2", "n": ' + "1" * 5000 + "}")
    (scenes / "good.json").write_text(json.dumps(_scene()))
    out = tmp_path / "out"
    status = main(["batch", str(scenes), "--out", str(out), "--no-posterior", "--workers", "1", "--quiet"])
    assert status != 0
    assert "Traceback" not in capsys.readouterr().err
    rows = {r["scene"]: r for r in csv.DictReader((out / "summary.csv").read_text().splitlines())}
    assert rows["good"]["status"] == "ok" and rows["good"]["map_distance_m"]
    assert rows["deep"]["status"] == "failed" and "nested more than" in rows["deep"]["error"]
    assert rows["huge"]["status"] == "failed" and "5000 digits" in rows["huge"]["error"]


def test_one_deeply_nested_label_studio_task_is_refused_by_name_and_the_rest_imported(tmp_path, capsys):
    from pathlib import Path

    tasks = json.loads((Path(__file__).parent / "data" / "label_studio_export.json").read_text())
    data = tasks[1]["data"]  # task 18: the street, one table
    for key in ("target_id", "target_length_m", "target_width_m", "target_height_m"):
        data.pop(key)
    data["targets"] = [{"id": "table", "dimensions_m": {"length": 1.6, "width": 0.8, "height": 0.75},
                        "ground_truth": {"location_m": [0, 1, 5], "note": DEEP}}]
    export = tmp_path / "export.json"
    export.write_text(json.dumps(tasks))
    out = tmp_path / "scenes"
    assert main(["import", "label-studio", str(export), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"error: task 18: nested more than {MAX_JSON_DEPTH} deep; refused" in err.splitlines()
    assert (out / "ab12cd34-room.json").is_file() and not (out / "street.json").exists()


# --- 2. control characters in names ------------------------------------------------------------

@pytest.mark.parametrize("where, value, key", [
    (("targets", 0, "id"), "a\x00b", "targets[0].id"),
    (("targets", 0, "class"), "Car\n", "targets[0].class"),
    (("targets", 0, "dimension_lines", 1, "worker"), "w\t1", "targets[0].dimension_lines[1].worker"),
    (("camera", "id"), "cam\x1b[31m", "camera.id"),
    (("targets", 0, "id"), "t\ud800", "targets[0].id"),
], ids=["nul-id", "newline-class", "tab-worker", "escape-camera", "surrogate-id"])
def test_control_characters_in_names_are_refused_naming_key_and_value(tmp_path, where, value, key):
    scene = _scene()
    obj = scene
    for k in where[:-1]:
        obj = obj[k]
    obj[where[-1]] = value
    path = tmp_path / "s.json"
    path.write_text(json.dumps(scene))
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert err.value.path == key
    assert f"control character U+{ord(next(c for c in value if not c.isprintable() or ord(c) >= 0xd800)):04X}" in str(err.value)
    assert repr(value)[:20] in str(err.value)


def test_a_nul_in_a_target_id_is_refused_before_anything_is_written(tmp_path, capsys):
    scene = _scene()
    scene["targets"][0]["id"] = "a\x00b"
    path, out, nc = tmp_path / "s.json", tmp_path / "r.json", tmp_path / "p.nc"
    path.write_text(json.dumps(scene))
    assert main(["estimate", str(path), "--out", str(out), "--netcdf", str(nc), "--quiet"]) == 2
    assert _one_error_line(capsys).startswith("error: targets[0].id: control character U+0000 in 'a\\x00b'")
    assert not out.exists() and not nc.exists()


# --- 3. result files given to plot / advise -------------------------------------------------------

@pytest.mark.parametrize("command", ["plot", "advise"])
@pytest.mark.parametrize("batch, key", [
    ({"key": "/".join("abcdefghijklmn"), "scene_copy": "scenes/s0.json"}, "batch.key"),
    ({"key": 7, "scene_copy": "scenes/s0.json"}, "batch.key"),
    ({"key": "s0", "scene_copy": ["scenes/s0.json"]}, "batch.scene_copy"),
    ({"key": "s0", "scene_copy": "../../s0.json"}, "batch.scene_copy"),
    (["s0"], "batch"),
], ids=["14-parts", "number", "list-copy", "outside-copy", "list"])
def test_a_result_with_bad_batch_fields_is_refused_in_one_line(tmp_path, capsys, command, batch, key):
    import shutil
    from pathlib import Path

    folder = tmp_path / "b"
    shutil.copytree(Path(__file__).parent / "data" / "batch_v1", folder)
    path = folder / "results" / "s0.json"
    result = json.loads(path.read_text())
    result["batch"] = batch
    path.write_text(json.dumps(result))
    assert main([command, str(path), "--out", str(tmp_path / "o.png" if command == "plot" else tmp_path / "a.json"),
                 "--quiet"]) == 2
    assert _one_error_line(capsys).startswith(f"error: {path}: {key}: ")


@pytest.mark.parametrize("hdi", ["\x00", {"distance_m": ["a", 3]}, {"distance_m": [1.0, float("inf")]}, [1, 2]],
                         ids=["nul-string", "text-bound", "infinite", "list"])
def test_advise_reads_past_a_results_shown_hdi_that_is_not_one(tmp_path, capsys, hdi):
    """The estimate's HDI of a distance is only shown beside the advice: a result whose
    ``objects[0].posterior.hdi`` is something else is advised as the intact one, without it."""
    import creference_bayes as cb
    from creference_bayes.cli import example_scene_path

    result = cb.estimate(example_scene_path(), seed=0, sampling={"min_ess": 100}, keep_draws=200)
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    result.save(good)
    d = json.loads(good.read_text())
    assert d["objects"][0]["posterior"]["hdi"]["distance_m"]  # the intact file shows it
    d["objects"][0]["posterior"]["hdi"] = hdi
    bad.write_text(json.dumps(d))
    if "Infinity" in bad.read_text():  # not JSON: refused, in one line saying why
        assert main(["advise", str(bad), "--scene", str(example_scene_path())]) == 2
        assert _one_error_line(capsys) == f"error: {bad}: non-standard JSON constant Infinity (numbers must be finite)"
        bad.write_text(json.dumps(d).replace("Infinity", "1e999"))  # read as JSON, a number too large
    outs = []
    for path in (good, bad):
        assert main(["advise", str(path), "--draws", "50", "--futures", "10", "--scene", str(example_scene_path()),
                     "--out", str(tmp_path / f"{path.stem}.advice.json")]) == 0
        outs.append(capsys.readouterr().out)
    assert "the estimate's, on all its draws" in outs[0] and "the estimate's, on all its draws" not in outs[1]
    advice = [json.loads((tmp_path / f"{n}.advice.json").read_text()) for n in ("good", "bad")]
    assert advice[0]["predictions"] == advice[1]["predictions"]


# --- 4. CSV cells a spreadsheet would run --------------------------------------------------------

def test_csv_cells_that_a_spreadsheet_would_run_are_escaped_and_read_back_exactly(tmp_path):
    from creference_bayes.io.files import atomic_write_csv, csv_cell, read_csv_rows

    assert csv_cell("\r=a") == "'\r=a" and csv_cell(-1.5) == -1.5
    values = ['=HYPERLINK("http://x","y")', "+cmd", "-x", "@SUM(A1)", "\tz", "'quoted", "'=b",
              "-1.5", "+2", "-3e-4", "plain", "a-b", ""]
    path = atomic_write_csv(tmp_path / "t.csv", [{"v": v, "n": -2.5} for v in values], ["v", "n"])
    raw = [row["v"] for row in csv.DictReader(path.open(newline=""))]
    assert raw[:7] == ["'" + v for v in values[:7]]
    assert raw[7:] == values[7:]  # numbers stay numbers, plain text stays as it is
    rows = read_csv_rows(path.read_bytes().decode())
    assert [r["v"] for r in rows] == values and {r["n"] for r in rows} == {"-2.5"}


_CSV_PIECES = ["\r", "\n", "\r\n", '"', ",", "'", "=", "+", "-", "@", "\t", "-1.5", "1e3", " ", "a", "é", "\x00"]


@given(cells=st.lists(st.one_of(st.lists(st.sampled_from(_CSV_PIECES), max_size=6).map("".join), st.text(max_size=8)),
                      min_size=1, max_size=4))
@FUZZ
def test_any_text_cell_round_trips_through_the_csv_writer_and_reader(tmp_path, cells):
    """A worker's free text (a lone carriage return or newline in it, quotes, a formula's first
    character, a number as text) comes back exactly, one row per row written."""
    from creference_bayes.io.files import atomic_write_csv, read_csv_rows, read_text

    rows = [{"text": c, "n": i} for i, c in enumerate(cells)]
    path = atomic_write_csv(tmp_path / "t.csv", rows, ["text", "n"])
    assert read_csv_rows(read_text(path)) == [{"text": c, "n": str(i)} for i, c in enumerate(cells)]
    assert len(list(csv.reader(path.open(newline="", encoding="utf-8")))) == len(cells) + 1  # a spreadsheet's rows


def test_a_formula_in_a_target_id_lands_escaped_in_the_batch_summary(tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    scene = _scene()
    scene["targets"][0]["id"] = '=HYPERLINK("http://evil","click")'
    (scenes / "s.json").write_text(json.dumps(scene))
    out = tmp_path / "out"
    assert main(["batch", str(scenes), "--out", str(out), "--no-posterior", "--workers", "1", "--quiet"]) == 0
    row = next(csv.DictReader((out / "summary.csv").open(newline="")))
    assert row["target"] == "'" + scene["targets"][0]["id"]
    assert float(row["map_distance_m"]) > 0



# --- 6. scene size limits ---------------------------------------------------------------------

@pytest.mark.parametrize("what", ["targets", "annotations", "references"])
def test_a_scene_beyond_a_size_limit_is_refused_naming_count_and_limit(what):
    from creference_bayes.io.scene import MAX_ANNOTATIONS, MAX_REFERENCES, MAX_TARGETS, parse_scene

    scene = _scene()
    if what == "targets":
        t = scene["targets"][0]
        scene["targets"] = [dict(t, id=f"t{i}") for i in range(MAX_TARGETS + 1)]
        scene.pop("references", None)
        key, n, limit = "targets", MAX_TARGETS + 1, MAX_TARGETS
    elif what == "annotations":
        lines = scene["targets"][0]["dimension_lines"]
        scene["targets"][0]["dimension_lines"] = (lines * MAX_ANNOTATIONS)[:MAX_ANNOTATIONS + 1]
        key, n, limit = "targets[0].dimension_lines", MAX_ANNOTATIONS + 1, MAX_ANNOTATIONS
    else:
        ref = {"target": "t0", "measure": "height", "value": 1.7, "unit": "m"}
        scene["references"] = [ref] * (MAX_REFERENCES + 1)
        key, n, limit = "references", MAX_REFERENCES + 1, MAX_REFERENCES
    with pytest.raises(SceneError) as err:
        parse_scene(scene)
    assert err.value.path == key and f"{n} " in err.value.problem and f"the {limit} a scene may have" in err.value.problem


def test_a_scene_at_the_limits_loads():
    from creference_bayes.io.scene import MAX_TARGETS, parse_scene

    scene = _scene()
    scene["targets"] = [dict(scene["targets"][0], id=f"t{i}") for i in range(MAX_TARGETS)]
    scene.pop("references", None)
    assert len(parse_scene(scene).targets) == MAX_TARGETS


# --- 5. files already in --out ----------------------------------------------------------------

def test_import_keeps_a_hand_edited_scene_unless_overwrite_and_says_what_it_replaced(tmp_path, capsys):
    from pathlib import Path

    export = Path(__file__).parent / "data" / "label_studio_export.json"
    out = tmp_path / "scenes"
    main(["import", "label-studio", str(export), "--out", str(out)])
    street, room = out / "street.json", out / "ab12cd34-room.json"
    written = street.read_text()
    capsys.readouterr()
    main(["import", "label-studio", str(export), "--out", str(out)])  # the same again: nothing replaced
    assert "unchanged " + str(street) in capsys.readouterr().out and street.read_text() == written
    edited = json.loads(written)
    edited["targets"][0]["dimensions_m"]["length"] = 1.7
    street.write_text(json.dumps(edited))
    assert main(["import", "label-studio", str(export), "--out", str(out)]) == 2
    io = capsys.readouterr()
    assert f"error: {street}: exists and is not the scene of task 18 (edited by hand?); kept it: pass --overwrite " \
           "to replace it" in io.err.splitlines()
    assert json.loads(street.read_text()) == edited and room.is_file()
    main(["import", "label-studio", str(export), "--out", str(out), "--overwrite"])
    io = capsys.readouterr()
    assert f"replaced {street} (task 18)" in io.out.splitlines() and "(1 replaced)" in io.out
    assert street.read_text() == written


def test_labels_removes_only_its_own_files_of_frames_no_longer_in_the_batch(tmp_path, capsys):
    import shutil
    from pathlib import Path

    from creference_bayes.io.result import canonical_sha256

    batch = tmp_path / "batch"
    shutil.copytree(Path(__file__).parent / "data" / "batch_v1", batch)
    scene = json.loads((batch / "scenes" / "s0.json").read_text())
    scene["image"]["path"] = "images/photo_018.png"  # another photo: its own label files
    (batch / "scenes" / "s1.json").write_text(json.dumps(scene))
    result = json.loads((batch / "results" / "s0.json").read_text())
    result["batch"].update(key="s1", scene_copy="scenes/s1.json")
    result["scene_id"]["sha256"] = canonical_sha256(scene)
    (batch / "results" / "s1.json").write_text(json.dumps(result))
    out = tmp_path / "labels"
    assert main(["labels", str(batch), "--out", str(out), "--no-figure", "--quiet"]) == 0
    ours = ["calib/photo_018.txt", "label_2/photo_018.txt", "uncertainty/photo_018.json"]
    assert all((out / rel).is_file() for rel in ours)
    (out / "label_2" / "mine.txt").write_text("a user's file\n")  # never ours
    (out / "calib" / "photo_018.txt").write_text("edited by hand\n")  # ours, but changed since
    (batch / "results" / "s1.json").unlink()  # the frame leaves the batch
    capsys.readouterr()
    assert main(["labels", str(batch), "--out", str(out), "--no-figure"]) == 0
    io = capsys.readouterr()
    assert not (out / "label_2" / "photo_018.txt").exists() and not (out / "uncertainty" / "photo_018.json").exists()
    assert (out / "label_2" / "mine.txt").read_text() == "a user's file\n"
    assert (out / "calib" / "photo_018.txt").read_text() == "edited by hand\n"
    assert (out / "label_2" / "photo_017.txt").is_file()
    assert ("removed 2 file(s) this command wrote for images no longer in the batch: label_2/photo_018.txt, "
            "uncertainty/photo_018.json") in io.out
    assert "warning: calib/photo_018.txt: of an image no longer in the batch, but changed since" in io.err


def test_a_result_edited_by_hand_is_refused_by_name_by_every_command_that_reads_it(tmp_path):
    """A result whose MAP, ids or draws are not what the package writes (found by the readers'
    fuzz: a string for a MAP value, a draw of 310 digits) is a one-line error naming the file and the
    key, not a TypeError or OverflowError deep in plot, advise or labels."""
    from creference_bayes.io.result import read_result, result_problem

    result = tmp_path / "r.json"
    good = {"format": "creference-result/2",
            "camera": {"map": {"focal_length_px": 700.0, "pitch": 0.0, "roll": 0.0, "height_m": 1.6,
                               "ref_scale": 0.5}},
            "objects": [{"id": "t0", "map": {"x": 1.0, "y": 1.6, "z": 10.0, "yaw": 0.0, "length_m": 4.0,
                                             "width_m": 1.8, "height_m": 1.5, "ground_m": 0.0}}]}
    assert result_problem(good) is None
    bad = [({**good, "objects": [{"id": "t0", "map": {**good["objects"][0]["map"], "x": "near"}}]}, "objects[0].map.x"),
           ({**good, "objects": ["t0"]}, "objects[0]"),
           ({**good, "camera": {"map": {**good["camera"]["map"], "pitch": None}}}, "camera.map.pitch"),
           ({**good, "objects": [{**good["objects"][0], "posterior": {"sd": "creference-result/2"}}]},
            "objects[0].posterior"),  # the long fuzz: labels read the distance's sd from it
           ({**good, "draws": {"n": 2, "camera": {"focal_length_px": 1}, "objects": []}}, "draws"),
           ({**good, "camera": {**good["camera"], "free": 0}}, "camera.free"),  # the long fuzz: labels
           ({**good, "camera": {**good["camera"], "free": ["pitch", "zoom"]}}, "camera.free")]
    for d, key in bad:
        result.write_text(json.dumps(d))
        with pytest.raises(ValueError) as err:
            read_result(result)
        assert str(err.value).startswith(f"{result}: {key}") and len(str(err.value).splitlines()) == 1
    d = {**good, "draws": {"n": 1, "camera": {k: 1 for k in good["camera"]["map"]}, "objects": [
        {k: 1 for k in good["objects"][0]["map"]}]}}
    d["draws"]["camera"]["focal_length_px"] = 10 ** 299  # read as JSON: an integer no float holds
    text = json.dumps(d).replace(str(10 ** 299), "1" + "0" * 309)
    result.write_text(text)
    with pytest.raises(ValueError) as err:
        read_result(result)
    assert str(result) in str(err.value)

# --- 7. hardening found in review ---------------------------------------------------------------

@pytest.mark.parametrize("where", ["../outside.json", "absolute"])
def test_labels_refuses_a_scene_copy_outside_the_batch_folder(tmp_path, capsys, where):
    """A result edited by hand whose ``batch.scene_copy`` leaves the batch folder: that frame is
    skipped with a line naming the result and the path, not read (here it would label)."""
    import shutil
    from pathlib import Path

    batch = tmp_path / "batch"
    shutil.copytree(Path(__file__).parent / "data" / "batch_v1", batch)
    shutil.copy(batch / "scenes" / "s0.json", tmp_path / "outside.json")  # a scene the result is of
    copy = str(tmp_path / "outside.json") if where == "absolute" else where
    path = batch / "results" / "s0.json"
    result = json.loads(path.read_text())
    result["batch"]["scene_copy"] = copy
    path.write_text(json.dumps(result))
    assert main(["labels", str(batch), "--out", str(tmp_path / "labels"), "--no-figure", "--quiet"]) == 2
    line = _one_error_line(capsys)
    assert f"{path}: batch.scene_copy: {copy[:40]!r}"[:-1] in line and "is outside the batch folder" in line, line
    assert not (tmp_path / "labels" / "label_2").exists()


@pytest.mark.parametrize("which", ["export", "targets"])
def test_an_import_input_beyond_its_size_limit_is_refused_naming_file_and_limit(tmp_path, capsys, monkeypatch,
                                                                                 which):
    import creference_bayes.io.annotation_tools as tools
    import creference_bayes.io.labelstudio as ls

    export = tmp_path / "export.json"
    export.write_text(json.dumps([{"id": 1, "data": {"image": "x.jpg"}, "annotations": []}]))
    table = tmp_path / "t.csv"
    table.write_text("target_id,length_m,width_m,height_m\ncar,4.5,1.8,1.5\n")
    big = export if which == "export" else table
    limit = big.stat().st_size - 1  # one byte short
    monkeypatch.setattr(ls if which == "export" else tools, "MAX_JSON_BYTES" if which == "export" else "MAX_TABLE_BYTES",
                        limit, raising=False)
    assert main(["import", "label-studio", str(export), "--out", str(tmp_path / "o"), "--targets", str(table),
                 "--quiet"]) == 2
    line = _one_error_line(capsys)
    assert str(big) in line and f"larger than {limit} bytes" in line, line
