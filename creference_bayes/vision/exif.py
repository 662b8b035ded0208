"""The focal length of a photo from its EXIF tags (Pillow adapter).

Two routes, in order:

1. ``FocalLengthIn35mmFilm`` (tag 0xA405): a 35 mm-equivalent focal length f35 (mm) means the
   field of view of a lens of f35 on a 36 × 24 mm frame, so µ = f35 / 43.27 mm × the image
   diagonal in pixels (the equivalence is defined on the diagonal).
2. ``FocalLength`` (0x920A) with ``FocalPlaneXResolution`` (0xA20E) and
   ``FocalPlaneResolutionUnit`` (0xA210): pixels per millimetre of the sensor, so
   µ = f × pixels/mm, scaled from the EXIF image width (``ExifImageWidth``, 0xA002, else the
   file's own width) to the scene's width.

Both assume the scene's image is the full frame the camera recorded, possibly resized: a crop
narrows the field of view and makes µ too small. That is why the prior built from it has a
width (``EXIF_LOG_SD`` in :mod:`~creference_bayes.models.camera_terms`) and heavy tails, and why
the pipeline warns when the annotations disagree with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..models.camera_terms import FULL_FRAME_DIAGONAL_MM

__all__ = ["ExifFocal", "focal_from_exif"]

_EXIF_IFD = 0x8769
_F35, _FOCAL, _FP_XRES, _FP_UNIT, _EXIF_WIDTH = 0xA405, 0x920A, 0xA20E, 0xA210, 0xA002
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


def focal_from_exif(path: str | Path, image_size: tuple[int, int]) -> ExifFocal | None:
    """µ (pixels) for an image of ``image_size`` (width, height) from the EXIF of ``path``.

    Returns None when the file has no usable tags or cannot be read as an image (the caller
    reports an unreadable image elsewhere).
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            file_width = im.size[0]
    except (OSError, UnidentifiedImageError, ValueError):
        return None
    sub = dict(exif.get_ifd(_EXIF_IFD)) if exif else {}
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
