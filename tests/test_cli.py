"""The ``creference`` command: exit status, one-line errors, the result file (formats.md)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from creference_bayes.cli.main import example_scene_path, main
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.result import OBJECT_REPORT
from creference_bayes.models.contract import CAMERA_NAMES
from conftest import truth_scene


def _write(path: Path, data) -> Path:
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def _example() -> dict:
    return json.loads(example_scene_path().read_text())


def _bad_unit_scene(tmp_path) -> Path:
    d = _example()
    d["references"][2].update(mode="direct", unit="furlong")
    return _write(tmp_path / "bad.json", d)


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "creference_bayes", *map(str, args)],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def test_invalid_scene_in_a_real_process_exits_2_with_one_line(tmp_path):
    proc = _run("estimate", _bad_unit_scene(tmp_path))
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: references[2].unit: unknown unit 'furlong'")
    assert proc.stdout == ""


def test_console_script_missing_file_exits_2(tmp_path):
    script = Path(sys.executable).with_name("creference")
    if not script.exists():
        pytest.skip("the creference console script is not installed next to this interpreter")
    proc = subprocess.run([str(script), "estimate", str(tmp_path / "nope.json")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [f"error: {tmp_path / 'nope.json'}: no such file"]


@pytest.mark.parametrize("content, start", [
    ('{"format": "creference-scene/1"', "error: {path}: not valid JSON"),
    ('{"format": "creference-scene/1", "x": NaN}', "error: {path}: non-standard JSON constant NaN"),
    ('{"format": "creference-scene/0"}', "error: format: expected 'creference-scene/1' or 'creference-scene/2', got 'creference-scene/0'"),
    ("[]", "error: (scene): expected an object, got list []"),
])
def test_broken_files_exit_2(tmp_path, capsys, content, start):
    path = _write(tmp_path / "s.json", content)
    status = main(["estimate", str(path)])
    err = capsys.readouterr().err
    assert status == 2
    assert err.strip().splitlines() == [err.strip()]
    assert err.startswith(start.format(path=path)), err


@pytest.mark.parametrize("mutate, start", [
    (lambda d: d["references"][0].update(range=[15, 10]), "error: references[0].range: low 15 > high 10"),
    (lambda d: d["target"]["dimensions_m"].pop("height"), "error: target.dimensions_m.height: missing required key"),
    (lambda d: d["image"].update(width="wide"), "error: image.width: expected a number, got str 'wide'"),
])
def test_invalid_scene_exits_2(tmp_path, capsys, mutate, start):
    d = _example()
    mutate(d)
    assert main(["estimate", str(_write(tmp_path / "s.json", d))]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(start), err


def test_missing_file_and_directory_exit_2(tmp_path, capsys):
    assert main(["estimate", str(tmp_path / "nope.json")]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path / 'nope.json'}: no such file\n"
    assert main(["estimate", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path}: ") and len(err.strip().splitlines()) == 1


def test_unknown_preset_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["estimate", str(example_scene_path()), "--preset", "fast"])
    assert info.value.code == 2
    assert "invalid choice: 'fast'" in capsys.readouterr().err


def _noise_free_scene() -> dict:
    return simulate_scene(4, setting="indoor", tier="none", principal_offset=0.1, n_target_annotations=1,
                          decimals=None)


def test_estimate_writes_result_with_evaluation(tmp_path, capsys):
    scene = _write(tmp_path / "scene.json", _noise_free_scene())
    out = tmp_path / "result.json"
    # segments drawn exactly: read as drawn (the default reading assumes the crowd's pixel noise at
    # their end points, which moves a noise-free scene's estimate by about 1 %)
    assert main(["estimate", str(scene), "--out", str(out), "--seed", "3", "--no-posterior",
                 "--option", "line_reading=linear"]) == 0
    printed = capsys.readouterr()
    assert "location error against the ground truth: MAP" in printed.out
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/2"
    assert data["scene"] == "scene.json" and [o["id"] for o in data["objects"]] == ["target"]
    assert set(data["camera"]["map"]) == set(CAMERA_NAMES)
    assert set(data["objects"][0]["map"]) == set(OBJECT_REPORT)
    assert all(math.isfinite(v) for v in data["objects"][0]["map"].values())
    err = data["objects"][0]["evaluation"]["location_pct_error"]
    assert 0 <= err < 1.0  # noise-free scene: the estimate is close to the truth


def test_estimate_without_ground_truth_has_no_evaluation(tmp_path, capsys):
    d = _noise_free_scene()
    del d["ground_truth"]
    for t in d["targets"]:
        del t["ground_truth"]
    out = tmp_path / "result.json"
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--out", str(out), "--quiet",
                 "--no-posterior"]) == 0
    assert capsys.readouterr().out == ""
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/2"
    assert "evaluation" not in data["objects"][0] and "evaluation" not in data["camera"]


@pytest.mark.parametrize("model, preset", [("paper", "default"),
                                           pytest.param("metrology", "paper-controlled", marks=pytest.mark.slow)])
def test_every_model_and_preset_takes_a_scene_of_several_objects(tmp_path, capsys, monkeypatch, model, preset):
    import creference_bayes.inference.map as map_

    monkeypatch.setattr(map_, "_PAPER_RESTARTS", {"paper": 2, "paper-controlled": 2})  # the paper's 100: minutes
    d, _ = truth_scene(2, m=2, noise_px=1.0, n_annotations=2, n_refs=2)
    out = tmp_path / "result.json"
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--model", model, "--preset", preset,
                 "--no-posterior", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert (data["model"], data["preset"]) == (model, preset) and len(data["objects"]) == 2
    table = capsys.readouterr().out
    assert [line.split()[0] for line in table.splitlines() if line[:3] == "  t" and line[3].isdigit()] == ["t0", "t1"]


def test_netcdf_holds_the_posterior_of_every_object(tmp_path, capsys):
    d, _ = truth_scene(4, m=2, noise_px=1.0, n_annotations=3)
    out, nc = tmp_path / "result.json", tmp_path / "post.nc"
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--out", str(out), "--netcdf", str(nc),
                 "--min-ess", "50", "--hdi-prob", "0.8"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and f"wrote {nc}" in printed and "80% HDI" in printed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["post.nc", "result.json", "scene.json"]  # no temporary
    from creference_bayes.inference.summary import az

    idata = az.from_netcdf(nc)
    assert list(idata.posterior["x"].coords["object"].values) == ["t0", "t1"]
    data = json.loads(out.read_text())
    assert data["hdi_prob"] == 0.8 and data["draws"]["n"] > 0
    assert [o["posterior"]["hdi"]["prob"] for o in data["objects"]] == [0.8, 0.8]


def test_a_misspelt_key_exits_2_naming_the_suggestion(tmp_path):
    d = _noise_free_scene()
    d["refrences"] = d.pop("references")
    proc = _run("estimate", _write(tmp_path / "scene.json", d), "--no-posterior")
    assert proc.returncode == 2
    assert proc.stderr == "error: refrences: unknown key; did you mean 'references'?\n"
    assert proc.stdout == ""


def test_unknown_keys_are_reported_once_not_fatal(tmp_path, capsys):
    d = _noise_free_scene()
    d["notes"] = "drawn by hand"
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--no-posterior"]) == 0
    captured = capsys.readouterr()
    everything = captured.out + captured.err
    assert captured.err.count("warning: notes: unknown key ignored") == 1
    assert everything.count("notes: unknown key ignored") == 1


def test_an_unreadable_image_gives_one_clear_note_and_no_opencv_noise(tmp_path):
    d = _example()
    del d["horizon"]
    d["image"]["path"] = "missing.png"
    proc = _run("estimate", _write(tmp_path / "scene.json", d), "--no-posterior", cwd=tmp_path)
    assert proc.returncode == 0
    assert proc.stderr == ""  # in particular no "[ WARN:0@…] … findDecoder" from OpenCV
    notes = [line for line in proc.stdout.splitlines() if "missing.png" in line]
    assert notes == [f"note: no horizon, and image.path '{tmp_path / 'missing.png'}' could not be read "
                     "(no such file): pitch and roll estimated from the annotations (and the orientation prior)"]


def test_simulate_refuses_a_non_empty_folder_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "scenes"
    assert main(["simulate", str(out), "--n", "2", "--quiet"]) == 0
    first = (out / "scene_0000.json").read_text()
    (out / "scene_0000.json").write_text("mine")
    assert main(["simulate", str(out), "--n", "2", "--seed", "5", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {out}: the folder is not empty") and "--overwrite" in err
    assert (out / "scene_0000.json").read_text() == "mine"  # untouched
    assert main(["simulate", str(out), "--n", "2", "--quiet", "--overwrite"]) == 0
    assert (out / "scene_0000.json").read_text() == first


# ------------------------------------------------------------------------------------------------
# plot: the scene must be the result's


@pytest.fixture(scope="module")
def map_result(tmp_path_factory):
    """A MAP-only result of the example scene, and a copy of the scene next to it."""
    folder = tmp_path_factory.mktemp("plot")
    scene = _write(folder / "scene.json", _example())
    out = folder / "result.json"
    assert main(["estimate", str(scene), "--out", str(out), "--no-posterior", "--quiet"]) == 0
    return folder, scene, out


def _plot(result, *extra):
    return subprocess.run([sys.executable, "-m", "creference_bayes", "plot", str(result), *map(str, extra)],
                          capture_output=True, text=True, timeout=120)


def test_plot_refuses_another_scene(map_result, tmp_path):
    folder, _, result = map_result
    other = _write(tmp_path / "other.json", _noise_free_scene())
    proc = _plot(result, "--scene", other, "--out", tmp_path / "figs")
    assert proc.returncode == 2
    assert proc.stderr == (f"error: --scene {other}: not the scene this result was estimated from "
                           "(target 'target', the result's is 'tv-stand')\n")
    assert not (tmp_path / "figs").exists()


def test_plot_refuses_an_edited_scene(map_result, tmp_path):
    folder, _, result = map_result
    d = _example()
    d["references"][0]["range"] = [0.7, 0.9]
    edited = _write(tmp_path / "edited.json", d)
    proc = _plot(result, "--scene", edited, "--out", tmp_path / "figs")
    assert proc.returncode == 2
    assert len(proc.stderr.splitlines()) == 1
    assert "same targets and image size but different content" in proc.stderr


def test_plot_finds_its_scene_beside_it_and_writes_atomically(map_result, tmp_path):
    folder, scene, result = map_result
    assert main(["plot", str(result), "--out", str(tmp_path / "a"), "--quiet", "--dpi", "30"]) == 0
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["boxes.png", "pairs.png", "top_view.png"]
    assert main(["plot", str(result), "--scene", str(scene), "--out", str(tmp_path / "b"), "--quiet",
                 "--format", "svg"]) == 0
    assert (tmp_path / "b" / "boxes.svg").read_text().lstrip().startswith("<?xml")


# ------------------------------------------------------------------------------------------------
# help and the console table


def _actions():
    """(command, action) for every argument of every command, the top level included."""
    import argparse

    from creference_bayes.cli.main import build_parser

    parser = build_parser()
    yield "creference", parser, parser._actions
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, p in sub.choices.items():
        yield name, p, p._actions


def test_every_argument_of_every_command_has_help():
    missing = [f"{name} {a.dest}" for name, _, actions in _actions() for a in actions
               if a.help is None or not str(a.help).strip()]
    assert not missing, f"arguments without help: {missing}"


def test_every_command_has_a_description_and_demo_says_its_scene_is_synthetic():
    parsers = {name: p for name, p, _ in _actions()}
    assert all(p.description for p in parsers.values()), [n for n, p in parsers.items() if not p.description]
    assert "synthetic" in parsers["demo"].description


def _every_parser():
    """(name, parser) of every command and every command of a command (``import cvat``, …)."""
    import argparse

    for name, p, actions in _actions():
        if name == "creference":
            continue
        yield name, p
        for a in actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub_name, sub in a.choices.items():
                    yield f"{name} {sub_name}", sub


def test_every_command_shows_at_most_twelve_everyday_options():
    """Research and comparison switches live in the "advanced options" section; every other option,
    -h counted, is what a newcomer reads first (the main section and any other group)."""
    from creference_bayes.cli.main import ADVANCED, MAX_MAIN_OPTIONS

    assert MAX_MAIN_OPTIONS == 12
    too_many = {}
    for name, p in _every_parser():
        everyday = [a.option_strings[0] for g in p._action_groups if g.title != ADVANCED
                    for a in g._group_actions if a.option_strings]
        main_section = [a for g in p._action_groups if g.title == "options" for a in g._group_actions
                        if a.option_strings]
        assert len(main_section) <= len(everyday)
        if len(everyday) > MAX_MAIN_OPTIONS:
            too_many[name] = everyday
    assert not too_many, too_many


def test_the_advanced_options_of_estimate_batch_and_advise():
    """The research switches the issue named are advanced; the everyday ones are not."""
    from creference_bayes.cli.main import ADVANCED

    parsers = dict(_every_parser())

    def advanced(name):
        return {a.option_strings[0] for g in parsers[name]._action_groups if g.title == ADVANCED
                for a in g._group_actions}

    for name in ("estimate", "demo", "batch"):
        assert {"--preset", "--model", "--temperature", "--location-prior", "--orientation", "--focal-prior",
                "--option", "--confidence-map"} <= advanced(name), name
        assert not {"--out", "--seed", "--quiet", "--distance-range", "--no-posterior"} & advanced(name), name
    assert {"--own-scale", "--rig"} <= advanced("batch") and "--dataset" not in advanced("batch")
    assert {"--futures", "--rank", "--option"} <= advanced("advise")
    assert not {"--budget", "--workers", "--draws", "--distance-range", "--apply", "--merge"} & advanced("advise")
    assert {"--temperature", "--paper-restarts"} <= advanced("bench")


def test_no_help_text_narrates_history():
    """The help says what the code does: no dates, no "old behaviour", no commit hashes."""
    import re

    date = re.compile(r"20[0-9][0-9]-[01][0-9]-[0-3][0-9]")
    words = re.compile(r"old behaviou?r|earlier default|before 20[0-9][0-9]|until 20[0-9][0-9]", re.I)
    commit = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
    bad = {}
    for name, p in [("creference", next(_actions())[1]), *_every_parser()]:
        text = " ".join(p.format_help().split())
        found = date.findall(text) + words.findall(text) + commit.findall(text)
        if found:
            bad[name] = found
    assert not bad, bad


def test_every_model_option_key_is_explained_in_the_user_guide():
    """--option's help lists the keys and points to docs/user_guide.md, Model options: a line each."""
    import re

    from creference_bayes.pipeline import MODEL_OPTIONS

    guide = (Path(__file__).resolve().parents[1] / "docs" / "user_guide.md").read_text()
    section = guide.split("\n## Model options", 1)[1].split("\n## ", 1)[0]
    rows = set(re.findall(r"^\| `([a-z_]+)` \|", section, re.M))
    keys = {k for ks in MODEL_OPTIONS.values() for k in ks}
    assert keys <= rows, sorted(keys - rows)
    for name, p in _every_parser():
        if name in ("estimate", "demo", "batch"):
            text = " ".join(p.format_help().split())
            assert "Model options" in text and all(k in text for k in keys), name


def test_bench_help_and_readme_agree_on_timings():
    from creference_bayes.cli.bench import BENCH_TIMES

    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text() + (root / "docs" / "overview.md").read_text()
    help_text = {name: p.format_help() for name, p, _ in _actions()}["bench"]
    for size, words in BENCH_TIMES.items():
        readme_lines = [line for line in readme.splitlines() if f"creference bench --{size}" in line]
        assert readme_lines and all(words in line for line in readme_lines), (size, readme_lines)
        assert words in " ".join(help_text.split())


def _fake_result(n_objects=2, posterior=True):
    """A creference-result/2 dict with round numbers (the tables' input)."""
    cam = {"focal_length_px": 1200.0, "pitch": 0.1, "roll": -0.02, "height_m": 1.5, "ref_scale": 0.5}
    objects = []
    for i in range(n_objects):
        m = {"x": 1.0 + i, "y": 1.5, "z": 4.0, "yaw": 0.5, "length_m": 4.2, "width_m": 1.7, "height_m": 1.5,
             "ground_m": 0.0, "distance_m": float(np.hypot(1.0 + i, 4.0))}
        o = {"id": f"car{i}", "class": "Car", "map": m}
        if posterior:
            o["posterior"] = {"hdi": {"distance_m": [m["distance_m"] - 0.25, m["distance_m"] + 0.5], "prob": 0.9}}
        objects.append(o)
    camera = {"map": cam, "free": ["focal_length_px", "pitch", "height_m"], "setup": {"orientation": "free"}}
    if posterior:
        camera["posterior"] = {"mean": {"focal_length_px": 1210.0, "pitch": 0.1, "height_m": 1.51},
                               "hdi": {"focal_length_px": [1100.0, 1300.0], "pitch": [0.09, 0.11],
                                       "height_m": [1.4, 1.6], "prob": 0.9}}
    return {"camera": camera, "objects": objects, "seconds": 1.0, "hdi_prob": 0.9, "references": {}}


def test_format_tables_has_a_camera_row_per_quantity_and_an_object_row_per_object():
    from creference_bayes.cli.estimate import format_tables

    lines = format_tables(_fake_result()).splitlines()
    focal = next(line for line in lines if line.strip().startswith("focal length px"))
    assert focal.split()[3:] == ["1200.0", "1210.0", "[1100.0,", "1300.0]"]
    pitch = next(line for line in lines if line.strip().startswith("pitch deg"))
    assert pitch.split()[2:5] == [f"{np.degrees(0.1):.2f}", f"{np.degrees(0.1):.2f}", f"[{np.degrees(0.09):.2f},"]
    roll = next(line for line in lines if line.strip().startswith("roll deg"))
    assert roll.split()[2:] == [f"{np.degrees(-0.02):.2f}", "(fixed)"]
    rows = [line.split() for line in lines if line.startswith("  car")]
    assert [r[0] for r in rows] == ["car0", "car1"]
    assert rows[1][2:5] == [f"{np.hypot(2.0, 4.0):.2f}", "2.00", "4.00"]
    assert rows[1][-2:] == [f"[{np.hypot(2.0, 4.0) - 0.25:.2f},", f"{np.hypot(2.0, 4.0) + 0.5:.2f}]"]


def test_format_tables_align_their_columns_with_and_without_a_posterior():
    from creference_bayes.cli.estimate import format_tables

    for posterior in (True, False):
        lines = format_tables(_fake_result(3, posterior)).splitlines()
        cam = lines[2:lines.index("")]
        assert len(cam) == 4  # the fake reads no references: no crowd scale row
        assert all(line[27] != " " and line[28:29] in ("", " ") for line in cam)  # the MAPs end in one column
        if posterior:
            hdi = [line.index("[") for line in cam[:4] if "[" in line]
            assert len(set(hdi)) == 1 and len(hdi) == 3
        head = next(line for line in lines if line.strip().startswith("target"))
        rows = [line for line in lines if line.startswith("  car")]
        assert {len(line) for line in rows} == {len(head)}  # every object row as wide as the header


@pytest.mark.parametrize("horizon, fixed", [(None, "focal_length_px (given in the scene)"),
                                            ("exact", "focal_length_px (given in the scene), pitch and roll "
                                                      "(from the exact horizon)")])
def test_estimate_tables_say_what_fixed_each_quantity_and_leave_out_a_crowd_scale_not_used(
        tmp_path, capsys, horizon, fixed):
    """Issue 64: a scene without a horizon was told its focal length was fixed by the exact horizon,
    and a scene without references printed a crowd scale '(not used)'."""
    scene, _ = truth_scene(3, noise_px=1.0, n_annotations=3, focal_known=True, horizon=horizon)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    assert main(["estimate", str(path), "--max-steps", "300", "--min-ess", "50"]) == 0
    out = capsys.readouterr().out
    assert "crowd scale" not in out and "not used" not in out  # no references: the model has no crowd scale
    (line,) = [line for line in out.splitlines() if line.startswith("truth inside")]
    assert line.endswith(f"; not checked (fixed, no spread in the posterior): {fixed}")
    focal = next(line for line in out.splitlines() if line.strip().startswith("focal length px"))
    assert "(given in the scene)" in focal
    if horizon is None:
        assert "horizon" not in line


def test_estimate_tables_show_the_crowd_scale_when_references_are_read(tmp_path, capsys):
    scene, _ = truth_scene(3, noise_px=1.0, n_annotations=3, n_refs=2)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(scene))
    assert main(["estimate", str(path), "--no-posterior"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("crowd scale"))
    assert len(row.split()) == 3 and float(row.split()[2]) > 0  # its MAP, nothing said 'not used'


def test_a_horizon_found_in_the_photo_from_one_vanishing_point_says_so_in_the_singular(monkeypatch):
    import types

    import creference_bayes.vision.horizon as horizon
    from creference_bayes.camera_setup import _orientation

    found = types.SimpleNamespace(points=np.array([[0.0, 500.0], [1000.0, 500.0]]), sd_px=2.0, dof=4.0,
                                  method="LSD", vanishing_points=np.zeros((1, 3)), confidence=0.5,
                                  __bool__=lambda self: True)
    monkeypatch.setattr(horizon, "estimate_horizon", lambda *a, **k: found)
    scene = types.SimpleNamespace(horizon=None, horizon_sd_px=0.0, image_path=Path("photo.jpg"),
                                  principal_point=(500.0, 400.0), image_size=(1000, 800))
    notes = []
    _orientation(scene, "auto", notes)
    assert "1 vanishing point," in notes[0]
