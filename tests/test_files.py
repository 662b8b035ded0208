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


def test_atomic_writes_keep_a_symlink_a_link_and_update_the_file_it_points_to(tmp_path):
    from creference_bayes.io.files import atomic_write_set

    (tmp_path / "data").mkdir()
    real, link = tmp_path / "data" / "scene.json", tmp_path / "scene.json"
    real.write_text("old\n")
    link.symlink_to(real)
    atomic_write_text(link, "new\n")
    assert link.is_symlink() and link.resolve() == real and real.read_text() == "new\n"
    with atomic_path(link) as tmp:
        assert tmp.parent == real.parent  # beside the file replaced: a rename within one folder
        tmp.write_text("by name\n")
    assert link.is_symlink() and real.read_text() == "by name\n"
    assert atomic_write_set({link: b"set\n"}) == [link]
    assert link.is_symlink() and real.read_text() == "set\n"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["data", "scene.json", "scene.json"]


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o444])
def test_atomic_writes_keep_the_mode_of_the_file_they_replace(tmp_path, mode):
    import stat

    from creference_bayes.io.files import atomic_write_bytes, atomic_write_set

    path = tmp_path / "f.json"
    path.write_text("{}")
    path.chmod(mode)
    for write in (lambda: atomic_write_text(path, "a"), lambda: atomic_write_bytes(path, b"b"),
                  lambda: atomic_write_json(path, [1]), lambda: atomic_write_set({path: b"c"})):
        write()
        assert stat.S_IMODE(path.stat().st_mode) == mode
    assert path.read_text() == "c"
