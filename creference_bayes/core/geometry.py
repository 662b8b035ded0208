"""Camera, box and projection (method.md §1), on NumPy only and vectorised over a batch.

Frames
------
Gravity-aligned frame G: origin at the camera centre, X right, Y down (along gravity), Z forward
and horizontal. The ground is the plane Y = h (camera height h, metres). The camera rotation R
takes G to camera coordinates, ``Pc = R @ P``; R = Rz(roll) @ Rx(pitch), pitch > 0 looking down,
roll > 0 turning the image's horizon clockwise (v grows to the right of the principal point).

Pixels: u right, v down, origin top-left; K = [[µ, 0, cx], [0, µ, cy], [0, 0, 1]].

Target pose s = (x, y, z, yaw): the bottom-centre of the box in G and its yaw about Y,
``P = (x, y, z) + Ry(yaw) @ p_obj`` with Ry(θ) = [[cos θ, 0, sin θ], [0, 1, 0], [−sin θ, 0, cos θ]].
Object axes: x along the length, z along the width, −Y up the height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "HANDEDNESS",
    "Camera",
    "horizon_line",
    "horizon_from_rotation",
    "pitch_roll_from_horizon",
    "rotation_from_pitch_roll",
    "yaw_matrix",
    "dimension_corners",
    "box_vertices",
    "box_points",
    "project",
]

#: The two handednesses of a dimension-line annotation: +1 when the width line turns
#: counter-clockwise from the length line seen from above, −1 otherwise (method.md §1).
HANDEDNESS = (1, -1)

#: Depth (metres, camera frame) below which a point counts as behind the camera.
MIN_DEPTH = 1e-6


def horizon_line(points: np.ndarray) -> np.ndarray:
    """Homogeneous horizon line (a, b, c) through two image points.

    Normalised so that a² + b² = 1 and ``(a, b, c) @ (u, v, 1)`` is the signed distance in
    pixels from the horizon, positive below it (on the ground side).

    Parameters
    ----------
    points : (2, 2) array, pixels
    """
    p = np.asarray(points, dtype=float)
    line = np.cross(np.append(p[0], 1.0), np.append(p[1], 1.0))
    line = line / np.hypot(line[0], line[1])
    return -line if line[1] < 0 else line


def rotation_from_pitch_roll(pitch, roll) -> np.ndarray:
    """R = Rz(roll) @ Rx(pitch), shape (..., 3, 3), for angles in radians of any shape."""
    pitch, roll = np.broadcast_arrays(np.asarray(pitch, float), np.asarray(roll, float))
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    R = np.zeros(pitch.shape + (3, 3))
    # Rz(r) @ Rx(p) with Rx(p) = [[1,0,0],[0,cp,-sp],[0,sp,cp]], Rz(r) = [[cr,-sr,0],[sr,cr,0],[0,0,1]]
    R[..., 0, 0] = cr
    R[..., 0, 1] = -sr * cp
    R[..., 0, 2] = sr * sp
    R[..., 1, 0] = sr
    R[..., 1, 1] = cr * cp
    R[..., 1, 2] = -cr * sp
    R[..., 2, 1] = sp
    R[..., 2, 2] = cp
    return R


def pitch_roll_from_horizon(line: np.ndarray, focal, principal_point) -> tuple[np.ndarray, np.ndarray]:
    """Pitch and roll (radians) implied by a horizon line and focal length(s).

    The ground normal in camera coordinates is n ∝ Kᵀ l (method.md §1); R's second column is n.

    Parameters
    ----------
    line : (3,) homogeneous horizon line, as from :func:`horizon_line`
    focal : float or array, pixels
    principal_point : (2,) pixels
    """
    focal = np.asarray(focal, dtype=float)
    a, b, c = line
    d0 = a * principal_point[0] + b * principal_point[1] + c  # signed distance of c from the horizon
    n = np.stack(np.broadcast_arrays(focal * a, focal * b, np.full_like(focal, d0)), axis=-1)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    pitch = np.arcsin(np.clip(n[..., 2], -1.0, 1.0))
    roll = np.arctan2(-n[..., 0], n[..., 1])
    return pitch, roll


def horizon_from_rotation(R: np.ndarray, focal: float, principal_point, width: float) -> np.ndarray:
    """Two points (at u = 0 and u = width) of the horizon seen by a camera with rotation R.

    Returns
    -------
    (2, 2) array, pixels
    """
    K = np.array([[focal, 0, principal_point[0]], [0, focal, principal_point[1]], [0, 0, 1.0]])
    line = np.linalg.solve(K.T, R[:, 1])  # l ∝ K^-T n
    a, b, c = line
    return np.array([[0.0, -c / b], [width, -(c + a * width) / b]])


def yaw_matrix(theta) -> np.ndarray:
    """Ry(θ), shape (..., 3, 3)."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    R = np.zeros(theta.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 2] = s
    R[..., 1, 1] = 1.0
    R[..., 2, 0] = -s
    R[..., 2, 2] = c
    return R


def dimension_corners(length: float, width: float, height: float, handedness: int = 1) -> np.ndarray:
    """Object-frame points c1..c4 of a dimension-line annotation, shape (4, 3), metres.

    c1 is a bottom corner, c2 the end of the length line, c3 the end of the width line, c4 the
    top of the height line. ``handedness`` (+1 or −1) picks which side the width line goes to;
    no yaw turns one into the other.
    """
    if handedness not in HANDEDNESS:
        raise ValueError(f"handedness must be +1 or -1, got {handedness!r}")
    hl, hw = length / 2.0, width / 2.0
    s = float(handedness)
    c1 = np.array([-hl, 0.0, -s * hw])
    return np.array([c1, c1 + [length, 0, 0], c1 + [0, 0, s * width], c1 + [0, -height, 0]])


def box_vertices(length: float, width: float, height: float) -> np.ndarray:
    """The 8 object-frame vertices, shape (8, 3): bottom face first (counter-clockwise), then top."""
    hl, hw = length / 2.0, width / 2.0
    bottom = np.array([[-hl, 0, -hw], [hl, 0, -hw], [hl, 0, hw], [-hl, 0, hw]])
    top = bottom + [0, -height, 0]
    return np.vstack([bottom, top])


def box_points(params: np.ndarray, obj_points: np.ndarray) -> np.ndarray:
    """Object points placed at pose(s) ``params[..., :4] = (x, y, z, yaw)``.

    Parameters
    ----------
    params : (..., >=4) array; (x, y, z) metres, yaw radians
    obj_points : (k, 3) object-frame points, metres

    Returns
    -------
    (..., k, 3) points in G, metres
    """
    params = np.asarray(params, dtype=float)
    Ry = yaw_matrix(params[..., 3])
    return params[..., None, :3] + np.einsum("...ij,kj->...ki", Ry, obj_points)


def project(points: np.ndarray, R: np.ndarray | None, focal, principal_point) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection C_µ(P) of points in G.

    Parameters
    ----------
    points : (..., k, 3) metres, gravity-aligned frame
    R : (..., 3, 3) or None (level camera)
    focal : float or (...) array, pixels
    principal_point : (2,) pixels

    Returns
    -------
    uv : (..., k, 2) pixels. Points behind the camera are projected as if at ``MIN_DEPTH``.
    depth : (..., k) camera-frame depth, metres (≤ 0 behind the camera)
    """
    pc = points if R is None else np.einsum("...ij,...kj->...ki", R, points)
    depth = pc[..., 2]
    z = np.maximum(depth, MIN_DEPTH)
    f = np.asarray(focal, dtype=float)[..., None, None]
    uv = f * pc[..., :2] / z[..., None] + np.asarray(principal_point, dtype=float)
    return uv, depth


@dataclass(frozen=True)
class Camera:
    """Intrinsics and gravity of one photo.

    Parameters
    ----------
    principal_point : (2,) pixels
    horizon : (3,) homogeneous horizon line (:func:`horizon_line`) or None for a level camera
    focal_length_px : known focal length in pixels, or None when it is estimated
    """

    principal_point: np.ndarray
    horizon: np.ndarray | None = None
    focal_length_px: float | None = None

    @classmethod
    def from_scene(cls, scene) -> "Camera":
        """The camera of a :class:`~creference_bayes.scene.Scene` (level when it has no horizon)."""
        line = None if scene.horizon is None else horizon_line(scene.horizon)
        return cls(np.asarray(scene.principal_point, float), line, scene.focal_length_px)

    def rotation(self, focal) -> np.ndarray | None:
        """R for focal length(s) ``focal`` (pixels): shape (..., 3, 3), or None if level."""
        if self.horizon is None:
            return None
        pitch, roll = pitch_roll_from_horizon(self.horizon, focal, self.principal_point)
        return rotation_from_pitch_roll(pitch, roll)

    def project(self, points: np.ndarray, focal) -> tuple[np.ndarray, np.ndarray]:
        """Project (..., k, 3) points in G with focal length(s) ``focal``; see :func:`project`."""
        return project(points, self.rotation(focal), focal, self.principal_point)

    def ray(self, pixels: np.ndarray, focal: float) -> np.ndarray:
        """Unit-free viewing rays in G through (n, 2) pixels, shape (n, 3)."""
        pixels = np.atleast_2d(np.asarray(pixels, float))
        d = np.column_stack([(pixels - self.principal_point) / focal, np.ones(len(pixels))])
        R = self.rotation(focal)
        return d if R is None else d @ R  # Rᵀ d for each row

    def backproject_to_ground(self, pixels: np.ndarray, focal: float, height: float) -> np.ndarray:
        """Intersect the rays through (n, 2) pixels with the ground Y = ``height`` (metres).

        Returns (n, 3) points in G, metres; rows for pixels on or above the horizon are NaN-free
        but marked invalid by a non-positive Z (use :meth:`is_below_horizon` first).
        """
        d = self.ray(pixels, focal)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[:, 1] > 0, height / np.where(d[:, 1] > 0, d[:, 1], 1.0), -1.0)
        return d * t[:, None]

    def is_below_horizon(self, pixels: np.ndarray, focal: float) -> np.ndarray:
        """Boolean (n,): whether each pixel sees the ground (ray points downward)."""
        return self.ray(pixels, focal)[:, 1] > 0
