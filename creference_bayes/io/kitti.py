"""KITTI 3D object labels, calib files and uncertainty sidecars (docs/labels.md).

Frame: the labels live in the package's gravity-aligned camera frame G (x right, y down along
gravity, z forward and horizontal, origin at the camera centre), which plays the part of KITTI's
rectified camera frame: ``R0_rect`` is the identity and ``P2 = K·[R | 0]`` with R = Rz(roll)·Rx(pitch)
the camera's rotation (:mod:`creference_bayes.core.geometry`). Tooling that projects a label's
corners with ``P2 @ [X; 1]`` thus lands where the package's own projection does, and
``rotation_y`` stays a yaw about gravity even for a pitched, rolled camera.

KITTI's box convention (x along the length, z along the width, y up the height with the location
at the bottom centre, ``Ry(rotation_y)``) is the package's own (``core.geometry.box_vertices`` and
``yaw_matrix``), so ``rotation_y`` is the estimate's yaw and ``location`` its (x, y, z).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.geometry import box_points, box_vertices
from .files import atomic_write_json, atomic_write_text

__all__ = ["KittiObject", "OCCLUDED_UNKNOWN", "SIDECAR_FORMAT", "SIDECAR_FORMATS", "projection_matrix",
           "project_with", "box_2d", "kitti_object", "format_label", "format_calib", "write_label_file",
           "write_calib_file", "write_sidecar", "wrap_pi", "VELO_TO_CAM", "CALIB_LINES"]

#: The uncertainty sidecar beside a label file (docs/labels.md; the layout is documented in
#: :mod:`creference_bayes.workflows.labels.kitti`).
SIDECAR_FORMAT = "creference-kitti-uncertainty/2"
#: The sidecar formats read (``/1`` and ``/2``; each object has ``line`` and ``quality`` in
#: both).
SIDECAR_FORMATS = ("creference-kitti-uncertainty/1", SIDECAR_FORMAT)

#: KITTI's occlusion code for "unknown" (the devkit's readme: 0 visible … 2 largely occluded, 3 unknown).
OCCLUDED_UNKNOWN = 3

#: A virtual lidar frame on G with KITTI's lidar axes (x forward, y left, z up): the standard axis
#: permutation, so that tools that go through Tr_velo_to_cam see a gravity-aligned "lidar".
VELO_TO_CAM = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0]])


def wrap_pi(theta):
    """Wrap radians to [−π, π)."""
    return (np.asarray(theta, float) + np.pi) % (2.0 * np.pi) - np.pi


def projection_matrix(focal: float, principal_point, R: np.ndarray | None) -> np.ndarray:
    """P = K·[R | 0], shape (3, 4): pixels from homogeneous points of G (R None: level camera)."""
    K = np.array([[focal, 0.0, principal_point[0]], [0.0, focal, principal_point[1]], [0.0, 0.0, 1.0]])
    R = np.eye(3) if R is None else np.asarray(R, float)
    return np.hstack([K @ R, np.zeros((3, 1))])


def project_with(P: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project (k, 3) points of G with a (3, 4) matrix: (k, 2) pixels and (k,) depths."""
    h = np.hstack([points, np.ones((len(points), 1))]) @ np.asarray(P, float).T
    return h[:, :2] / h[:, 2:3], h[:, 2]


def box_2d(uv: np.ndarray, depth: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float]:
    """The 2D box (left, top, right, bottom) of projected corners, clipped to the image, and the
    truncation: the share of the unclipped box outside the image (1 when a corner is behind the camera)."""
    left, top = uv.min(axis=0)
    right, bottom = uv.max(axis=0)
    clipped = np.clip([left, top, right, bottom], 0, [width - 1, height - 1, width - 1, height - 1])
    if np.any(depth <= 0):
        return clipped, 1.0
    area = max(right - left, 1e-12) * max(bottom - top, 1e-12)
    inside = max(clipped[2] - clipped[0], 0.0) * max(clipped[3] - clipped[1], 0.0)
    return clipped, float(np.clip(1.0 - inside / area, 0.0, 1.0))


@dataclass(frozen=True)
class KittiObject:
    """One line of a KITTI label file (the devkit's 15 values and a score).

    Attributes
    ----------
    type : class name (no whitespace)
    truncated : 0 … 1, the share of the projected box outside the image
    occluded : 0, 1, 2 or 3 (unknown)
    alpha : observation angle, rotation_y − atan2(x, z), radians in [−π, π)
    bbox : (left, top, right, bottom) pixels
    dimensions : (h, w, l) metres
    location : (x, y, z) metres, the bottom centre of the box in G
    rotation_y : yaw about G's y axis (gravity), radians in [−π, π)
    score : the label's quality (e.g. P(IoU ≥ 0.7))
    """

    type: str
    truncated: float
    occluded: int
    alpha: float
    bbox: tuple[float, float, float, float]
    dimensions: tuple[float, float, float]
    location: tuple[float, float, float]
    rotation_y: float
    score: float

    def __post_init__(self):
        if not self.type or any(c.isspace() for c in self.type):
            raise ValueError(f"type: a KITTI class name has no whitespace, got {self.type!r}")

    def to_line(self) -> str:
        nums = [self.truncated, self.occluded, self.alpha, *self.bbox, *self.dimensions,
                *self.location, self.rotation_y, self.score]
        fmt = ["{:.2f}", "{:d}", "{:.4f}", *["{:.2f}"] * 4, *["{:.4f}"] * 7, "{:.4f}"]
        return " ".join([self.type] + [f.format(v) for f, v in zip(fmt, nums)])

    def to_dict(self) -> dict:
        return {"type": self.type, "truncated": self.truncated, "occluded": self.occluded,
                "alpha": self.alpha, "bbox": list(self.bbox), "dimensions_hwl": list(self.dimensions),
                "location": list(self.location), "rotation_y": self.rotation_y, "score": self.score}


def kitti_object(type_: str, pose: np.ndarray, size_lwh, P2: np.ndarray, image_size, score: float) -> KittiObject:
    """The KITTI label of a box at ``pose`` = (x, y, z, yaw) of G with sizes (length, width, height).

    The 2D box is that of the 8 corners projected with ``P2``, clipped to ``image_size`` = (width, height).
    """
    x, y, z, yaw = (float(v) for v in pose[:4])
    length, width, height = (float(v) for v in size_lwh)
    corners = box_points(np.array([x, y, z, yaw]), box_vertices(length, width, height))
    uv, depth = project_with(P2, corners)
    bbox, truncated = box_2d(uv, depth, *image_size)
    ry = float(wrap_pi(yaw))
    return KittiObject(type=type_, truncated=truncated, occluded=OCCLUDED_UNKNOWN,
                       alpha=float(wrap_pi(ry - np.arctan2(x, z))), bbox=tuple(map(float, bbox)),
                       dimensions=(height, width, length), location=(x, y, z), rotation_y=ry,
                       score=float(score))


def format_label(objects) -> str:
    """The label file's text: one line per object."""
    return "".join(o.to_line() + "\n" for o in objects)


#: The lines of a KITTI calib file, in the devkit's order.
CALIB_LINES = ("P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo")


def format_calib(P2: np.ndarray, lines: dict | None = None) -> str:
    """A KITTI calib file with ``P2``. The other lines are ``lines`` (name → numbers: a real
    calibration's, e.g. a KITTI folder's, kept as they were) where given, else those of one camera:
    P0, P1, P3 = P2, R0_rect = I and the virtual lidar :data:`VELO_TO_CAM` (with no lidar, a
    lidar tool then sees a gravity-aligned "lidar" on the camera)."""
    def row(name, m):
        return f"{name}: " + " ".join(f"{v:.12e}" for v in np.asarray(m, float).ravel()) + "\n"
    P2 = np.asarray(P2, float)
    own = {"P0": P2, "P1": P2, "P2": P2, "P3": P2, "R0_rect": np.eye(3), "Tr_velo_to_cam": VELO_TO_CAM,
           "Tr_imu_to_velo": np.eye(4)[:3]}
    given = {k: v for k, v in (lines or {}).items() if k != "P2"}
    names = list(CALIB_LINES) + [k for k in given if k not in CALIB_LINES]
    return "".join(row(k, given.get(k, own.get(k))) for k in names)


def write_label_file(path: str | Path, objects) -> Path:
    """Write :func:`format_label` to ``path`` atomically."""
    return atomic_write_text(path, format_label(objects))


def write_calib_file(path: str | Path, P2: np.ndarray, lines: dict | None = None) -> Path:
    """Write :func:`format_calib` to ``path`` atomically."""
    return atomic_write_text(path, format_calib(P2, lines))


def write_sidecar(path: str | Path, doc: dict) -> Path:
    """Write an uncertainty sidecar (:data:`SIDECAR_FORMAT`) to ``path`` atomically."""
    return atomic_write_json(path, doc, inline_numbers=True)
