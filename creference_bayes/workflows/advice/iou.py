"""3D IoU of many pairs of ground-standing boxes at once, on NumPy alone.

The advice needs the IoU of an exported box with every posterior draw for each of a few hundred
simulated futures: tens of thousands of pairs per candidate annotation, too many for shapely's
polygon objects (:mod:`creference_bayes.evaluation.iou3d` uses shapely for the labels themselves, and the tests check
this module against it). Both footprints are convex quadrilaterals, so their intersection is the
convex polygon bounded by the parts of each footprint's edges inside the other; its area is the sum
over those parts of their ends' cross products (Green's theorem), each edge clipped to the other's
half-planes, with no sorting of corners.
"""

from __future__ import annotations

import numpy as np

from ...evaluation.iou3d import footprints

__all__ = ["convex_intersection_area", "iou_3d_pairs", "iou_3d_at_least"]

#: Pairs handled per vectorised chunk (bounds the temporary arrays to a few tens of megabytes).
_CHUNK = 20000
_EPS = 1e-12


def _ccw(poly: np.ndarray) -> np.ndarray:
    """(P, 4, 2) quadrilaterals, each turned counter-clockwise (positive signed area)."""
    x, y = poly[..., 0], poly[..., 1]
    signed = np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    return np.where((signed < 0)[:, None, None], poly[:, ::-1], poly)


def _clipped_edges(pa: np.ndarray, pb: np.ndarray, keep_on_line: bool) -> np.ndarray:
    """(P,) twice the signed area the edges of ``pa`` contribute to the boundary of ``pa`` ∩ ``pb``
    (both (P, 4, 2), counter-clockwise): each edge clipped to the half-planes of ``pb`` (Cyrus–Beck),
    the part left contributing p × q for its ends p, q (Green's theorem).

    An edge on a line of ``pb`` belongs to the boundary once: kept when ``keep_on_line`` and the two
    run the same way (a shared side: the edges of the other polygon on it are dropped), dropped
    when they run opposite ways (the polygons touch from outside)."""
    r = np.roll(pa, -1, axis=1) - pa                        # (P, 4, 2) edge vectors of pa
    e = (np.roll(pb, -1, axis=1) - pb)[:, None]             # (P, 1, 4, 2) edge vectors of pb
    def side(x):  # (P, 4, 4): how far the points x (P, 4, 2) are inside each half-plane of pb
        d = x[:, :, None, :] - pb[:, None]
        return e[..., 0] * d[..., 1] - e[..., 1] * d[..., 0]
    f0, f1 = side(pa), side(pa + r)
    scale = np.abs(e).sum(axis=-1) * (np.abs(pa).sum(axis=-1)[:, :, None] + np.abs(r).sum(axis=-1)[:, :, None] + 1.0)
    on_line = (np.abs(f0) <= 1e-9 * scale) & (np.abs(f1) <= 1e-9 * scale)
    same_way = np.sum(r[:, :, None, :] * e, axis=-1) > 0
    df = f1 - f0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -f0 / df
    free = on_line & same_way & keep_on_line
    lo = np.max(np.where((df > 0) & ~free, t, 0.0), axis=2).clip(0.0, 1.0)
    hi = np.min(np.where((df < 0) & ~free, t, 1.0), axis=2).clip(0.0, 1.0)
    empty = np.any(((df == 0) & (f0 < 0) | on_line) & ~free, axis=2) | (lo >= hi)
    p, q = pa + lo[..., None] * r, pa + hi[..., None] * r
    return np.sum(np.where(empty, 0.0, p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]), axis=1)


def _area_chunk(pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    centre = pa.mean(axis=1, keepdims=True)  # a common origin near both, for precision
    pa, pb = _ccw(pa - centre), _ccw(pb - centre)
    area = 0.5 * (_clipped_edges(pa, pb, True) + _clipped_edges(pb, pa, False))
    return np.maximum(area, 0.0)


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


def iou_3d_at_least(a: np.ndarray, b: np.ndarray, threshold: float) -> np.ndarray:
    """Whether the 3D IoU of ``a[p]`` and ``b[p]`` is at least ``threshold``, for every p (boxes as
    :func:`iou_3d_pairs`): :func:`iou_3d_pairs` ≥ ``threshold``, computed only for the pairs two
    bounds leave open. In ``a``'s frame, the footprints' intersection lies in ``a``'s footprint cut
    by the rectangle that bounds ``b``'s (the upper bound), and holds ``a``'s footprint cut by the
    rectangle of ``a``'s axes inside ``b``'s, centred on it (the lower bound: its half-sides p, q
    put its corners on ``b``'s sides, p·|cos δ| + q·|sin δ| = l/2 and p·|sin δ| + q·|cos δ| = w/2
    for ``b`` turned by δ); each times the heights' overlap, over the union it would leave. With
    the posterior's boxes about nine in ten of the pairs at or above the bar are decided by the
    lower bound."""
    a, b = np.atleast_2d(np.asarray(a, float)), np.atleast_2d(np.asarray(b, float))
    if a.shape != b.shape or a.shape[1:] != (7,):
        raise ValueError(f"a, b: expected two (P, 7) arrays, got {a.shape} and {b.shape}")
    c, s = np.cos(a[:, 3]), np.sin(a[:, 3])
    dx, dz = b[:, 0] - a[:, 0], b[:, 2] - a[:, 2]
    along, across = dx * c - dz * s, dx * s + dz * c              # b's centre in a's frame
    turn = b[:, 3] - a[:, 3]
    ct, st = np.abs(np.cos(turn)), np.abs(np.sin(turn))
    oh = np.clip(np.minimum(a[:, 1], b[:, 1]) - np.maximum(a[:, 1] - a[:, 6], b[:, 1] - b[:, 6]), 0.0, None)
    volumes = np.prod(a[:, 4:7], axis=1) + np.prod(b[:, 4:7], axis=1)

    def overlap(half_l, half_w):  # a's footprint cut by the rectangle of half-sides (half_l, half_w) at b's centre
        ox = np.clip(np.minimum(a[:, 4] / 2, along + half_l) - np.maximum(-a[:, 4] / 2, along - half_l), 0.0, None)
        oz = np.clip(np.minimum(a[:, 5] / 2, across + half_w) - np.maximum(-a[:, 5] / 2, across - half_w), 0.0, None)
        return ox * oz

    outer = np.minimum(overlap((ct * b[:, 4] + st * b[:, 5]) / 2, (st * b[:, 4] + ct * b[:, 5]) / 2),
                       np.minimum(a[:, 4] * a[:, 5], b[:, 4] * b[:, 5])) * oh
    det = ct * ct - st * st
    with np.errstate(divide="ignore", invalid="ignore"):
        half = np.stack([b[:, 4] * ct - b[:, 5] * st, b[:, 5] * ct - b[:, 4] * st]) / (2.0 * det)
    half = np.where((det > 0) & np.all(half > 0, axis=0), half, 0.0)
    inner = overlap(*half) * oh
    with np.errstate(divide="ignore", invalid="ignore"):
        out = inner >= threshold * (volumes - inner) * (1.0 + 1e-9)
        open_ = ~out & (outer >= threshold * (volumes - outer) * (1.0 - 1e-9))
    if open_.any():
        out[open_] = iou_3d_pairs(a[open_], b[open_]) >= threshold
    return out
