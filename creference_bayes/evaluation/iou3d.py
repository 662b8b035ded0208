"""3D and bird's-eye-view overlap of boxes standing on the ground (shapely, imported here only).

A box is (x, y, z, yaw, length, width, height) in a camera frame with y down (KITTI's rectified
camera frame, or the package's gravity-aligned frame G): bottom centre (x, y, z) metres, yaw about
y (radians; KITTI's ``rotation_y``), so its footprint is a rotated rectangle in the (x, z) ground
plane and its vertical extent is [y − height, y]. The 3D overlap is the footprints' intersection
area times the overlap of the vertical extents; the bird's-eye overlap is the footprints' alone.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SHAPELY_INSTALL_HINT", "METRICS", "footprints", "box_iou_3d", "overlaps"]

SHAPELY_INSTALL_HINT = "label geometry needs shapely: pip install 'shapely>=2'"
#: The overlaps :func:`overlaps` computes: 3D boxes and their ground footprints (bird's-eye view).
METRICS = ("3d", "bev")


def _shapely():
    try:
        import shapely
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise ImportError(SHAPELY_INSTALL_HINT) from exc
    return shapely


def footprints(boxes: np.ndarray) -> np.ndarray:
    """Ground-plane corners (x, z) of boxes, shape (n, 4, 2), metres, counter-clockwise.

    Parameters
    ----------
    boxes : (n, 7) x, y, z, yaw, length, width, height
    """
    b = np.atleast_2d(np.asarray(boxes, float))
    c, s = np.cos(b[:, 3]), np.sin(b[:, 3])
    # object x axis in (x, z) is (cos, −sin), object z axis (sin, cos): Ry(yaw) of core.geometry
    ax = np.stack([c, -s], axis=-1) * (b[:, 4:5] / 2)
    az = np.stack([s, c], axis=-1) * (b[:, 5:6] / 2)
    centre = b[:, [0, 2]]
    return np.stack([centre - ax - az, centre + ax - az, centre + ax + az, centre - ax + az], axis=1)


def _intersection_areas(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, m) intersection areas (m²) of the footprints of boxes ``a`` (n, 7) and ``b`` (m, 7)."""
    shapely = _shapely()
    pa = shapely.polygons(footprints(a)) if len(a) else np.empty(0, object)
    pb = shapely.polygons(footprints(b)) if len(b) else np.empty(0, object)
    if not len(pa) or not len(pb):
        return np.zeros((len(pa), len(pb)))
    return shapely.area(shapely.intersection(pa[:, None], pb[None, :]))


def overlaps(a: np.ndarray, b: np.ndarray, metric: str = "3d", normalise: str = "union") -> np.ndarray:
    """Pairwise overlap of boxes ``a`` with boxes ``b``.

    Parameters
    ----------
    a : (n, 7) x, y, z, yaw, length, width, height (metres, radians)
    b : (m, 7) the same
    metric : ``"3d"`` (volumes) or ``"bev"`` (ground footprints)
    normalise : ``"union"``: intersection over union (IoU); ``"first"``: intersection over the
        volume (area) of the box of ``a`` (how KITTI's devkit measures a detection inside a
        DontCare region)

    Returns
    -------
    (n, m) overlaps in [0, 1]; 0 where the denominator is not positive
    """
    if metric not in METRICS:
        raise ValueError(f"metric: expected one of {list(METRICS)}, got {metric!r}")
    if normalise not in ("union", "first"):
        raise ValueError(f"normalise: expected 'union' or 'first', got {normalise!r}")
    a = np.asarray(a, float).reshape(-1, 7)
    b = np.asarray(b, float).reshape(-1, 7)
    inter = _intersection_areas(a, b)
    size_a, size_b = a[:, 4] * a[:, 5], b[:, 4] * b[:, 5]
    if metric == "3d":
        top = np.maximum((a[:, 1] - a[:, 6])[:, None], (b[:, 1] - b[:, 6])[None, :])
        bottom = np.minimum(a[:, 1][:, None], b[:, 1][None, :])
        inter = inter * np.clip(bottom - top, 0.0, None)
        size_a, size_b = size_a * a[:, 6], size_b * b[:, 6]
    if normalise == "union":
        denom = size_a[:, None] + size_b[None, :] - inter
    else:
        denom = np.broadcast_to(size_a[:, None], inter.shape)
    out = np.zeros(inter.shape)
    np.divide(inter, denom, out=out, where=denom > 0)
    return np.clip(out, 0.0, 1.0)


def box_iou_3d(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(n,) 3D IoU in [0, 1] of one ``box`` (7,) with each of ``boxes`` (n, 7), both
    x, y, z, yaw, length, width, height (metres, radians)."""
    return overlaps(np.asarray(box, float).reshape(1, 7), boxes, "3d")[0]
