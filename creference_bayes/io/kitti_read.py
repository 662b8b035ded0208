"""Reading KITTI 3D object label files: ground truth (15 values a line) and detections or labels
(16: a score at the end), with one-line errors naming the file, the line and the value.

The columns (KITTI's devkit readme): type, truncated, occluded, alpha, 2D box (left, top, right,
bottom; pixels), dimensions (h, w, l; metres), location (x, y, z; metres, the bottom centre of the
box in the rectified camera frame, y down), rotation_y (radians), and for detections the score.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from .files import read_text

__all__ = ["COLUMNS", "LabelFileError", "KittiLabels", "read_kitti_labels", "kitti_boxes"]

#: The columns of a line, in order (``score`` only in detections).
COLUMNS = ("type", "truncated", "occluded", "alpha", "left", "top", "right", "bottom", "h", "w", "l",
           "x", "y", "z", "rotation_y", "score")
#: The type whose boxes mark regions left unlabelled (its 3D values are placeholders).
DONT_CARE = "dontcare"


class LabelFileError(ValueError):
    """A label file that cannot be read: the message names the file, the line and the value."""


@dataclass(frozen=True)
class KittiLabels:
    """The objects of one label file, as arrays (n objects).

    Attributes
    ----------
    path : the file
    line : (n,) 1-based line numbers
    type : n class names
    truncated : (n,) 0 … 1 (−1 for DontCare)
    occluded : (n,) int 0, 1, 2, 3 (−1 for DontCare)
    alpha : (n,) radians
    bbox : (n, 4) left, top, right, bottom, pixels
    dimensions : (n, 3) h, w, l, metres
    location : (n, 3) x, y, z, metres
    rotation_y : (n,) radians
    score : (n,) scores, or None for ground truth
    """

    path: Path
    line: np.ndarray
    type: list[str]
    truncated: np.ndarray
    occluded: np.ndarray
    alpha: np.ndarray
    bbox: np.ndarray
    dimensions: np.ndarray
    location: np.ndarray
    rotation_y: np.ndarray
    score: np.ndarray | None

    def __len__(self) -> int:
        return len(self.type)

    @property
    def dont_care(self) -> np.ndarray:
        """(n,) bool: the DontCare regions."""
        return np.array([t.lower() == DONT_CARE for t in self.type], bool)

    @property
    def height_px(self) -> np.ndarray:
        """(n,) bottom − top of the 2D box, pixels."""
        return self.bbox[:, 3] - self.bbox[:, 1]


def read_kitti_labels(path: str | Path, *, scores: bool) -> KittiLabels:
    """Read one label file ``path``: with ``scores``, detections or labels (16 values a line, the
    last a score), else ground truth (15 values; a 16th, if present, is ignored).

    Raises ``FileNotFoundError`` (no such file) and :class:`LabelFileError` (a line with the wrong
    number of values, a value that is not a finite number, an occlusion that is not an integer, or
    a box other than DontCare without a positive size).
    """
    path = Path(path)
    text = read_text(path)
    need = 16 if scores else 15
    rows, lines, types = [], [], []
    for no, raw in enumerate(text.splitlines(), start=1):
        fields = raw.split()
        if not fields:
            continue
        where = f"{path}:{no}"
        if len(fields) < need or len(fields) > 16:
            what = "16 values (the last a score)" if scores else "15 values (16 with a score)"
            raise LabelFileError(f"{where}: expected {what}, got {len(fields)}: {raw.strip()!r}")
        values = []
        for name, field in zip(COLUMNS[1:need], fields[1:need]):
            try:
                v = float(field)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise LabelFileError(f"{where}: {name}: expected a finite number, got {field!r}")
            if name == "occluded" and v != int(v):
                raise LabelFileError(f"{where}: occluded: expected an integer, got {field!r}")
            values.append(v)
        if fields[0].lower() != DONT_CARE:
            for name, v in zip(("h", "w", "l"), values[7:10]):
                if v <= 0:
                    raise LabelFileError(f"{where}: {name}: expected a positive size in metres, got {v:g}")
        rows.append(values)
        lines.append(no)
        types.append(fields[0])
    a = np.array(rows, float).reshape(-1, need - 1)
    return KittiLabels(path=path, line=np.array(lines, int), type=types, truncated=a[:, 0],
                       occluded=a[:, 1].astype(int), alpha=a[:, 2], bbox=a[:, 3:7], dimensions=a[:, 7:10],
                       location=a[:, 10:13], rotation_y=a[:, 13], score=a[:, 14] if scores else None)


def kitti_boxes(labels: KittiLabels) -> np.ndarray:
    """The labels' 3D boxes as (n, 7) x, y, z, rotation_y, length, width, height (the layout of
    :mod:`creference_bayes.evaluation.iou3d`)."""
    h, w, l = labels.dimensions.T
    return np.column_stack([labels.location, labels.rotation_y, l, w, h])
