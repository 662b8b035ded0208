"""The ``creference`` command: exit status, one-line errors, the result file (formats.md)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from creference_bayes.cli.main import example_scene_path, main
from creference_bayes.bench.simulate import simulate_scene


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
    ('{"format": "creference-scene/1"', "error: (file): not valid JSON"),
    ('{"format": "creference-scene/1", "x": NaN}', "error: (file): non-standard JSON constant NaN"),
    ('{"format": "creference-scene/0"}', "error: format: expected 'creference-scene/1', got 'creference-scene/0'"),
    ("[]", "error: (scene): expected an object, got list []"),
])
def test_broken_files_exit_2(tmp_path, capsys, content, start):
    status = main(["estimate", str(_write(tmp_path / "s.json", content))])
    err = capsys.readouterr().err
    assert status == 2
    assert err.strip().splitlines() == [err.strip()]
    assert err.startswith(start), err


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
    assert main(["estimate", str(scene), "--out", str(out), "--seed", "3", "--no-posterior"]) == 0
    printed = capsys.readouterr()
    assert "location error (Eq. 3)" in printed.out and "MAP" in printed.out
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/1"
    assert data["scene"] == "scene.json" and data["target"] == "target"
    assert set(data["map"]) == {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll"}
    assert all(math.isfinite(v) for v in data["map"].values())
    err = data["evaluation"]["location_pct_error"]
    assert 0 <= err < 1.0  # noise-free scene: the estimate is close to the truth


def test_estimate_without_ground_truth_has_no_evaluation(tmp_path, capsys):
    d = _noise_free_scene()
    del d["ground_truth"]
    out = tmp_path / "result.json"
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--out", str(out), "--quiet",
                 "--no-posterior"]) == 0
    assert capsys.readouterr().out == ""
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/1"
    assert set(data["map"]) == {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll"}
    assert "evaluation" not in data


def test_unknown_keys_are_reported_not_fatal(tmp_path, capsys):
    d = _noise_free_scene()
    d["refrences"] = d.pop("references")
    assert main(["estimate", str(_write(tmp_path / "scene.json", d)), "--quiet", "--no-posterior"]) == 0
    assert "warning: refrences: unknown key ignored" in capsys.readouterr().err
