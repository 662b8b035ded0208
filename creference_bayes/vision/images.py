"""Reading photos (Pillow adapter): every image file the package reads goes through
:func:`open_image`, which refuses what is not a photo before anything is decoded.

A photo is opened only when it is a regular file (a FIFO, a device such as ``/dev/stdin`` or a
folder would block or mislead the reader), and only its header is read before its size is checked
against :data:`MAX_IMAGE_PIXELS`: a few hundred bytes of PNG can declare 10000 × 10000 pixels and
take gigabytes to decode. Whatever an image library raises on a broken, truncated or unknown file
becomes an :class:`ImageError` whose message is one line naming the file.
"""

from __future__ import annotations

import errno
import os
import stat
import struct
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

__all__ = ["MAX_IMAGE_PIXELS", "ImageError", "ImageWarning", "open_image", "image_size", "read_image", "image_bytes"]

#: Largest photo read, in pixels (width × height): a street photo is at most a few tens of
#: megapixels (a 48 MP phone, a 45 MP camera); a larger image is refused, before it is decoded.
MAX_IMAGE_PIXELS = 50_000_000


class ImageError(OSError):
    """An image file that cannot be used: not a regular file, not an image, broken, or larger
    than :data:`MAX_IMAGE_PIXELS`. ``filename`` is the file, ``strerror`` the reason (one line)."""

    def __init__(self, path, problem: str, code: int = errno.EINVAL):
        super().__init__(code, " ".join(str(problem).split()), str(path))

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror}"


class ImageWarning(UserWarning):
    """A photo left out (of a figure) because it cannot be read; the message names the file."""


def _decode_errors() -> tuple:
    from PIL import Image

    return (OSError, ValueError, SyntaxError, EOFError, struct.error, IndexError, KeyError, TypeError,
            ZeroDivisionError, MemoryError, Image.DecompressionBombError)


def _open_regular(path: Path):
    """``path`` opened for binary reading when it is a regular file (opened without blocking, then
    checked: a FIFO or a device is refused, not waited on)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except FileNotFoundError:
        raise ImageError(path, "no such file", errno.ENOENT) from None
    except IsADirectoryError:
        raise ImageError(path, "a folder, not an image file", errno.EISDIR) from None
    except OSError as exc:
        raise ImageError(path, f"cannot be read: {exc.strerror or exc}", exc.errno or errno.EIO) from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = ("a folder" if stat.S_ISDIR(mode) else "a pipe (FIFO)" if stat.S_ISFIFO(mode)
                else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
                else "not a regular file")
        raise ImageError(path, f"{kind}, not an image file")
    if hasattr(os, "set_blocking"):
        os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


@contextmanager
def open_image(path: str | Path, *, max_pixels: int = MAX_IMAGE_PIXELS) -> Iterator:
    """A Pillow image of the file ``path`` with only its header read, once the file was found to
    be a regular file and the image no larger than ``max_pixels``. Errors of the image library in
    the block (decoding, EXIF) are :class:`ImageError` naming the file."""
    from PIL import Image

    path = Path(path)
    errors = _decode_errors()
    too_large = f"more than the limit of {max_pixels / 1e6:g} MP: refused (resize the photo)"
    with _open_regular(path) as f:
        try:
            with warnings.catch_warnings():  # Pillow's own bomb warning: the size is checked here
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                im = Image.open(f)
            with im:
                w, h = im.size
                if w * h > max_pixels:
                    raise ImageError(path, f"the image is {w} x {h} pixels ({w * h / 1e6:.0f} MP), {too_large}")
                yield im
        except ImageError:
            raise
        except Image.DecompressionBombError:  # Pillow refused it on opening, from the header's size
            raise ImageError(path, f"the image is far larger than a photo, {too_large}") from None
        except Image.UnidentifiedImageError:
            raise ImageError(path, "not an image file (format not recognised)") from None
        except errors as exc:
            raise ImageError(path, f"cannot be read as an image ({type(exc).__name__}: {exc})") from None


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of the image file ``path``, from its header (:func:`open_image`'s checks)."""
    with open_image(path) as im:
        return im.size


def read_image(path: str | Path, *, mode: str = "RGB", max_side: int | None = None) -> np.ndarray:
    """The image file ``path`` decoded as an array in Pillow ``mode`` (``"RGB"``: (h, w, 3) uint8,
    ``"L"``: (h, w)), after :func:`open_image`'s checks; with ``max_side``, reduced (aspect kept)
    so that neither side exceeds it (a JPEG is decoded at a reduced scale directly)."""
    with open_image(path) as im:
        if max_side is not None and max(im.size) > max_side:
            im.thumbnail((max_side, max_side))
        return np.asarray(im.convert(mode))


def image_bytes(path: str | Path) -> tuple[bytes, tuple[int, int]]:
    """The bytes of the image file ``path`` and its (width, height), after :func:`open_image`'s
    checks, for another library's decoder (OpenCV's, for the horizon)."""
    with open_image(path) as im:
        size = im.size
    with _open_regular(Path(path)) as f:
        return f.read(), size
