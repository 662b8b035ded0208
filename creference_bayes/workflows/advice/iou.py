"""3D IoU of many pairs of ground-standing boxes at once, on NumPy alone.

The advice needs the IoU of an exported box with every posterior draw for each of a few hundred
simulated futures: tens of thousands of pairs per candidate annotation, too many for shapely's
polygon objects (:mod:`creference_bayes.evaluation.iou3d` uses shapely for the labels themselves, and the tests check
this module against it). Both footprints are convex quadrilaterals, so their intersection is the
convex polygon whose corners are the corners of each footprint inside the other and the crossings
of their edges; its area follows from those points sorted by angle around their centroid.
"""

from __future__ import annotations

import numpy as np

from ...evaluation.iou3d import footprints

__all__ = ["convex_intersection_area", "iou_3d_pairs"]

#: Pairs handled per vectorised chunk (bounds the temporary arrays to a few tens of megabytes).
_CHUNK = 20000
_EPS = 1e-12


def _ccw(poly: np.ndarray) -> np.ndarray:
    """(P, 4, 2) quadrilaterals, each turned counter-clockwise (positive signed area)."""
    x, y = poly[..., 0], poly[..., 1]
    signed = np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    return np.where((signed < 0)[:, None, None], poly[:, ::-1], poly)


def _inside(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(P, k) whether each of ``points`` (P, k, 2) lies in the counter-clockwise convex ``poly`` (P, 4, 2)."""
    a = poly[:, None, :, :]                      # (P, 1, 4, 2) edge starts
    e = np.roll(poly, -1, axis=1)[:, None] - a   # (P, 1, 4, 2) edge vectors
    d = points[:, :, None, :] - a                # (P, k, 4, 2)
    cross = e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]
    scale = np.abs(e).sum(axis=-1) * (np.abs(d).sum(axis=-1) + 1.0)
    return np.all(cross >= -1e-9 * scale, axis=-1)


def _crossings(pa: np.ndarray, pb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crossing points of every edge of ``pa`` with every edge of ``pb``: (P, 16, 2) and valid (P, 16)."""
    p = pa[:, :, None, :]
    r = (np.roll(pa, -1, axis=1) - pa)[:, :, None, :]
    q = pb[:, None, :, :]
    s = (np.roll(pb, -1, axis=1) - pb)[:, None, :, :]
    denom = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]) / denom
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / denom
    ok = (np.abs(denom) > _EPS) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    pts = p + np.where(ok, t, 0.0)[..., None] * r
    n = len(pa)
    return pts.reshape(n, 16, 2), ok.reshape(n, 16)


def _area_chunk(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    pa, pb = _ccw(pa), _ccw(pb)
    cross_pts, cross_ok = _crossings(pa, pb)
    pts = np.concatenate([pa, pb, cross_pts], axis=1)                          # (P, 24, 2)
    ok = np.concatenate([_inside(pa, pb), _inside(pb, pa), cross_ok], axis=1)  # (P, 24)
    count = ok.sum(axis=1)
    centre = np.sum(pts * ok[..., None], axis=1) / np.maximum(count, 1)[:, None]
    rel = pts - centre[:, None, :]
    angle = np.where(ok, np.arctan2(rel[..., 1], rel[..., 0]), np.inf)
    order = np.argsort(angle, axis=1)
    rel = np.take_along_axis(rel, order[..., None], axis=1)
    k = np.arange(pts.shape[1])[None, :]
    nxt = np.where(k + 1 < count[:, None], k + 1, 0)
    rel_next = np.take_along_axis(rel, nxt[..., None], axis=1)
    tri = rel[..., 0] * rel_next[..., 1] - rel[..., 1] * rel_next[..., 0]
    area = 0.5 * np.sum(np.where(k < count[:, None], tri, 0.0), axis=1)
    return np.where(count >= 3, np.maximum(area, 0.0), 0.0)


def convex_intersection_area(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """Areas of the intersections of pairs of convex quadrilaterals.

    Parameters
    ----------
    pa, pb : (P, 4, 2) corners in order (either orientation)

    Returns
    -------
    (P,) areas in the squared unit of the corners
    """
    pa, pb = np.asarray(pa, float), np.asarray(pb, float)
    if pa.shape != pb.shape or pa.ndim != 3 or pa.shape[1:] != (4, 2):
        raise ValueError(f"pa, pb: expected two (P, 4, 2) arrays, got {pa.shape} and {pb.shape}")
    out = np.empty(len(pa))
    for start in range(0, len(pa), _CHUNK):
        sl = slice(start, start + _CHUNK)
        out[sl] = _area_chunk(pa[sl], pb[sl])
    return out


def iou_3d_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3D IoU of the boxes ``a[p]`` and ``b[p]`` for every p.

    Parameters
    ----------
    a, b : (P, 7) x, y, z, yaw, length, width, height (metres, radians; bottom centre, y down,
        as :func:`~creference_bayes.evaluation.iou3d.box_iou_3d`)

    Returns
    -------
    (P,) IoU in [0, 1]
    """
    a, b = np.atleast_2d(np.asarray(a, float)), np.atleast_2d(np.asarray(b, float))
    if a.shape != b.shape or a.shape[1:] != (7,):
        raise ValueError(f"a, b: expected two (P, 7) arrays, got {a.shape} and {b.shape}")
    inter_area = convex_intersection_area(footprints(a), footprints(b))
    overlap_h = np.clip(np.minimum(a[:, 1], b[:, 1]) - np.maximum(a[:, 1] - a[:, 6], b[:, 1] - b[:, 6]),
                        0.0, None)
    inter = inter_area * overlap_h
    union = np.prod(a[:, 4:7], axis=1) + np.prod(b[:, 4:7], axis=1) - inter
    return np.clip(inter / union, 0.0, 1.0)
