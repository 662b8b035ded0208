"""The boxes of a frame's objects: their vertices in the gravity-aligned camera frame, their
pixels and their ground footprints, for states in :mod:`.frame` order (camera (n, 5), one
object's states (n, 7)). Used by the frame's figures and its advice."""

from __future__ import annotations

import numpy as np

from ..core.geometry import box_vertices, rotation_from_pitch_roll
from .contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, O_YAW

__all__ = ["world_boxes", "image_boxes", "footprint"]

_UNIT_BOX = box_vertices(1.0, 1.0, 1.0)  # (8, 3): bottom face first; scales with (l, h, w) per axis


def world_boxes(objs: np.ndarray, cam_height: np.ndarray) -> np.ndarray:
    """(n, 8, 3) box vertices (bottom face first, metres) in the gravity-aligned camera frame for
    (n, 7) states of one object and (n,) camera heights."""
    l, w, h = objs[:, O_SIZE].T
    v = _UNIT_BOX[None] * np.stack([l, h, w], axis=-1)[:, None, :]  # x along l, y (down) h, z along w
    c, s = np.cos(objs[:, O_YAW])[:, None], np.sin(objs[:, O_YAW])[:, None]
    X = objs[:, 0, None] + c * v[..., 0] + s * v[..., 2]
    Y = (cam_height - objs[:, O_GROUND])[:, None] + v[..., 1]
    Z = objs[:, 1, None] - s * v[..., 0] + c * v[..., 2]
    return np.stack([X, Y, Z], axis=-1)


def image_boxes(cams: np.ndarray, objs: np.ndarray, principal_point) -> np.ndarray:
    """Projected box vertices (n, 8, 2) pixels of one object at (n, 5) cameras and (n, 7) object
    states; NaN where a vertex is less than 5 cm in front of the camera."""
    P = world_boxes(objs, cams[:, C_HEIGHT])
    R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])
    pc = np.einsum("nij,nkj->nki", R, P)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = cams[:, C_FOCAL, None, None] * pc[..., :2] / pc[..., 2:3] + np.asarray(principal_point, float)
    uv[pc[..., 2] <= 0.05] = np.nan
    return uv


def footprint(obj: np.ndarray) -> np.ndarray:
    """(4, 2) ground footprint (x, z), metres, of one (7,) object state."""
    return world_boxes(np.asarray(obj, float)[None], np.zeros(1))[0, :4][:, [0, 2]]
