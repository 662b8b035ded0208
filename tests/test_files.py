"""Atomic writes (io/files.py) and the scene fingerprint that results record."""

import json

import pytest

from creference_bayes.cli import example_scene_path
from creference_bayes.io.files import atomic_path, atomic_write_json, atomic_write_text
from creference_bayes.io.scene import load_scene, parse_scene, scene_fingerprint


def test_atomic_write_replaces_whole_file_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "sub" / "out.json"
    atomic_write_json(p, {"a": 1})
    atomic_write_text(p, "second\n")
    assert p.read_text() == "second\n"
    assert sorted(x.name for x in p.parent.iterdir()) == ["out.json"]


def test_failed_write_keeps_the_old_file(tmp_path):
    p = tmp_path / "out.txt"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(p) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert p.read_text() == "old"
    assert [x.name for x in tmp_path.iterdir()] == ["out.txt"]


def test_atomic_json_refuses_nan(tmp_path):
    with pytest.raises(ValueError):
        atomic_write_json(tmp_path / "x.json", {"v": float("nan")})
    assert not any(tmp_path.iterdir())


def test_fingerprint_ignores_key_order_and_sees_value_changes():
    d = json.loads(example_scene_path().read_text())
    base = scene_fingerprint(parse_scene(d))
    assert base == scene_fingerprint(load_scene(example_scene_path()))
    reordered = dict(reversed(list(d.items())))
    assert scene_fingerprint(parse_scene(reordered)) == base
    d["target"]["dimension_lines"][0]["corners"][0][0] += 0.01
    assert scene_fingerprint(parse_scene(d)) != base
