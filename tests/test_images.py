"""Photos are read through one adapter (creference_bayes.vision.images): regular files only, the
size judged from the header before anything is decoded, every image library's error one line
naming the file."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from creference_bayes.cli.main import example_scene_path
from creference_bayes.vision.images import MAX_IMAGE_PIXELS, ImageError, image_size, read_image


def _big_png(path, side):
    """A PNG of side x side black pixels: a few hundred kB on disk, side² bytes decoded."""
    Image.new("L", (side, side)).save(path, optimize=True)
    return path


def _scene_with_image(tmp_path, image_name):
    d = json.loads(example_scene_path().read_text())
    d.pop("horizon", None)
    d["image"]["path"] = image_name
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    return path


def _run(*args, cwd, timeout=120, limit_bytes=None):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    pre = None
    if limit_bytes is not None:
        import resource

        def pre():
            resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))
    return subprocess.run([sys.executable, "-m", "creference_bayes", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout, preexec_fn=pre)


def test_an_image_past_the_limit_is_refused_from_its_header(tmp_path):
    path = _big_png(tmp_path / "bomb.png", 10000)  # 100 MP: 100 MB decoded, ~100 kB on disk
    assert path.stat().st_size < 200_000 and 10000 ** 2 > MAX_IMAGE_PIXELS
    for read in (image_size, read_image):
        with pytest.raises(ImageError) as info:
            read(path)
        assert str(info.value) == (f"{path}: the image is 10000 x 10000 pixels (100 MP), more than the limit of "
                                   "50 MP: refused (resize the photo)")


def test_an_image_pillow_calls_a_bomb_is_refused_too(tmp_path):
    path = _big_png(tmp_path / "bomb.png", 14000)  # past Pillow's own limit: its error, mapped
    with pytest.raises(ImageError, match=r"bomb.png: the image is far larger than a photo, more than the limit"):
        image_size(path)


@pytest.mark.parametrize("content, problem", [
    (b"not an image at all", "not an image file (format not recognised)"),
    (b"", "not an image file (format not recognised)"),
])
def test_a_file_that_is_no_image_is_one_line_naming_it(tmp_path, content, problem):
    path = tmp_path / "photo.png"
    path.write_bytes(content)
    with pytest.raises(ImageError) as info:
        read_image(path)
    assert str(info.value) == f"{path}: {problem}"


def test_a_truncated_image_is_one_line_naming_it(tmp_path):
    path = tmp_path / "cut.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (200, 300, 3), dtype=np.uint8)).save(path)
    path.write_bytes(path.read_bytes()[:2000])
    with pytest.raises(ImageError, match=r"^.*cut.png: cannot be read as an image \(OSError: .*truncated"):
        read_image(path)
    assert image_size(path) == (300, 200)  # the header alone is whole


def test_a_small_photo_reads_and_is_reduced_on_request(tmp_path):
    path = tmp_path / "p.png"
    Image.new("RGB", (300, 200), (10, 20, 30)).save(path)
    assert image_size(path) == (300, 200)
    a = read_image(path)
    assert a.shape == (200, 300, 3) and tuple(a[0, 0]) == (10, 20, 30)
    assert read_image(path, mode="L", max_side=150).shape == (100, 150)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "photo.png"
    os.mkfifo(fifo)
    with pytest.raises(ImageError, match=r"photo.png: a pipe \(FIFO\), not an image file"):
        image_size(fifo)
    with pytest.raises(ImageError, match=r"^/dev/null: a device, not an image file"):
        read_image("/dev/null")
    with pytest.raises(ImageError, match=r"a folder, not an image file"):
        image_size(tmp_path)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_estimate_with_a_fifo_as_the_photo_notes_it_and_does_not_hang(tmp_path):
    os.mkfifo(tmp_path / "photo.png")
    proc = _run("estimate", _scene_with_image(tmp_path, "photo.png"), "--no-posterior", cwd=tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "photo.png' could not be read (a pipe (FIFO), not an image file)" in proc.stdout


def test_estimate_with_a_decompression_bomb_as_the_photo_stays_small(tmp_path):
    """Under a 1.5 GB address-space cap (the bomb decoded would take about 2.6 GB): a note, no
    traceback."""
    _big_png(tmp_path / "bomb.png", 10000)
    proc = _run("estimate", _scene_with_image(tmp_path, "bomb.png"), "--no-posterior", cwd=tmp_path,
                limit_bytes=int(1.5 * 2 ** 30) if sys.platform.startswith("linux") else None)
    assert proc.returncode == 0, proc.stderr[-500:]
    assert "Traceback" not in proc.stderr
    assert ("bomb.png' could not be read (the image is 10000 x 10000 pixels (100 MP), more than the limit of 50 MP: "
            "refused (resize the photo))") in proc.stdout


def test_the_figures_draw_a_reduced_photo_and_warn_about_one_they_cannot_read(tmp_path):
    from types import SimpleNamespace

    from creference_bayes.vision.images import ImageWarning
    from creference_bayes.vision.plotting import PHOTO_MAX_SIDE, _load_image

    Image.new("RGB", (PHOTO_MAX_SIDE * 2, PHOTO_MAX_SIDE), (200, 100, 0)).save(tmp_path / "wide.png")
    photo = _load_image(SimpleNamespace(image_path=tmp_path / "wide.png"))
    assert photo.shape == (PHOTO_MAX_SIDE // 2, PHOTO_MAX_SIDE, 3)
    _big_png(tmp_path / "bomb.png", 10000)
    with pytest.warns(ImageWarning, match=r"bomb.png: the image is 10000 x 10000 pixels .* the figures are drawn "
                                          "without the photo"):
        assert _load_image(SimpleNamespace(image_path=tmp_path / "bomb.png")) is None
