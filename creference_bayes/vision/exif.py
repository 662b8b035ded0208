"""The focal length of a photo from its EXIF tags (read through the Pillow adapter :mod:`.images`).

Two routes, in order:

1. ``FocalLengthIn35mmFilm`` (tag 0xA405): a 35 mm-equivalent focal length f35 (mm) means the
   field of view of a lens of f35 on a 36 × 24 mm frame, so µ = f35 / 43.27 mm × the image
   diagonal in pixels (the equivalence is defined on the diagonal).
2. ``FocalLength`` (0x920A) with ``FocalPlaneXResolution`` (0xA20E) and
   ``FocalPlaneResolutionUnit`` (0xA210): pixels per millimetre of the sensor, so
   µ = f × pixels/mm, scaled from the EXIF image width (``ExifImageWidth``, 0xA002, else the
   file's own width) to the scene's width.

Both assume the scene's image is the full frame the camera recorded, possibly resized (a crop
makes µ too small): hence the width and heavy tails of the prior built from it (``EXIF_LOG_SD`` in
:mod:`~creference_bayes.models.camera_terms`) and the pipeline's warning when the annotations
disagree with it.

:func:`camera_id_from_exif` names the camera that took a photo (make, model, body serial number,
focal length), for frames with no ``camera.id`` of their own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..models.camera_terms import FULL_FRAME_DIAGONAL_MM

__all__ = ["ExifFocal", "focal_from_exif", "camera_id_from_exif"]

_EXIF_IFD = 0x8769
_F35, _FOCAL, _FP_XRES, _FP_UNIT, _EXIF_WIDTH = 0xA405, 0x920A, 0xA20E, 0xA210, 0xA002
_MAKE, _MODEL, _SERIAL = 0x010F, 0x0110, 0xA431  # IFD0's Make and Model; the Exif IFD's BodySerialNumber
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}  # inch, cm, mm, µm


@dataclass(frozen=True)
class ExifFocal:
    """A focal length read from EXIF.

    Attributes
    ----------
    focal_px : µ for the scene's image size, pixels
    route : ``"35mm"`` or ``"focal_plane"`` (module docstring)
    tags : the tag values used (plain numbers)
    """

    focal_px: float
    route: str
    tags: dict


def _number(value) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if np.isfinite(v) and v > 0 else None


def _read_exif(path):
    """(IFD0's tags, the Exif IFD's tags, the file's width), or None when not readable as an image
    (:func:`~.images.open_image`: also a FIFO or device, or an image past the size limit)."""
    from .images import open_image

    try:
        with open_image(path) as im:
            exif = im.getexif()
            return exif, dict(exif.get_ifd(_EXIF_IFD)) if exif else {}, im.size[0]
    except OSError:  # ImageError included
        return None


def focal_from_exif(path: str | Path, image_size: tuple[int, int]) -> ExifFocal | None:
    """µ (pixels) for an image of ``image_size`` (width, height) from the EXIF of ``path``.

    Returns None when the file has no usable tags or cannot be read as an image (the caller
    reports an unreadable image elsewhere).
    """
    read = _read_exif(path)
    if read is None:
        return None
    exif, sub, file_width = read
    tags = {**{k: v for k, v in exif.items() if isinstance(k, int)}, **sub} if exif else {}
    width, height = image_size
    f35 = _number(tags.get(_F35))
    if f35 is not None:
        return ExifFocal(f35 / FULL_FRAME_DIAGONAL_MM * float(np.hypot(width, height)), "35mm",
                         {"FocalLengthIn35mmFilm": f35})
    focal, xres = _number(tags.get(_FOCAL)), _number(tags.get(_FP_XRES))
    unit = tags.get(_FP_UNIT, 2)
    if focal is None or xres is None or unit not in _UNIT_MM:
        return None
    exif_width = _number(tags.get(_EXIF_WIDTH)) or float(file_width)
    mu = focal * xres / _UNIT_MM[unit] * (width / exif_width)
    return ExifFocal(mu, "focal_plane", {"FocalLength": focal, "FocalPlaneXResolution": xres,
                                         "FocalPlaneResolutionUnit": unit, "ExifImageWidth": exif_width})


def _exif_text(value) -> str | None:
    """An EXIF text tag as clean text (NUL padding and runs of blanks removed), or None when
    missing or empty."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if not isinstance(value, str):
        return None
    text = re.sub(r"\s+", " ", value.replace("\0", " ")).strip()
    return text or None


def camera_id_from_exif(path: str | Path) -> str | None:
    """A name for the camera that took the photo at ``path``, from its EXIF tags, to stand for a
    scene's ``camera.id`` when the scene gives none: frames with the same name share a camera.

    The name is ``"exif:"``, the make (left out when the model starts with it) and model, ``#`` and
    the body's serial number when recorded, and the focal length in millimetres (rounded to
    0.01 mm, when given), e.g. ``exif:Canon EOS 80D #0123456789 35mm``, ``exif:Apple iPhone 12
    4.2mm``. A zoom lens at another focal length is another camera for the estimate, and two bodies
    of one model are two cameras; two bodies without a serial number get the same name (give such
    frames a ``camera.id`` of their own when they are not on one mounting).

    Returns None when the photo has no ``Model`` tag, or cannot be read as an image.
    """
    read = _read_exif(path)
    if read is None:
        return None
    exif, sub, _ = read
    make, model = _exif_text(exif.get(_MAKE)), _exif_text(exif.get(_MODEL))
    if model is None:
        return None
    words = [model]
    if make is not None and not model.lower().startswith(make.split()[0].lower()):
        words.insert(0, make)
    serial = _exif_text(sub.get(_SERIAL))
    if serial is not None:
        words.append(f"#{serial}")
    focal = _number(sub.get(_FOCAL))
    if focal is not None:
        words.append(f"{round(focal, 2):g}mm")
    return "exif:" + " ".join(words)
