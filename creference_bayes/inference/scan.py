"""The default optimiser's global start: closed-form poses over a grid of yaws (method.md §6), for
the camera orientation a horizon gives or for a grid of (pitch, roll), and the choice of starts.
"""

from __future__ import annotations

import numpy as np

from ..core.geometry import rotation_from_pitch_roll, yaw_matrix
from ..models.params import FOCAL, YAW, Bounds, wrap_angle

__all__ = ["ORIENTATION_GRID_DEG", "N_THETA", "N_THETA_GRID", "theta_scan", "scan", "pick_starts",
           "best_per_pitch"]

#: The (pitch, roll) grid of the start when they are free parameters, degrees: wide enough for
#: photos pitched from 20° up to 50° down and rolled by ±10°; the refinement does the rest.
ORIENTATION_GRID_DEG = (np.arange(-20.0, 51.0, 10.0), np.array([-8.0, 0.0, 8.0]))
#: Yaw steps of the scan: 1° with a horizon (one orientation), 5° over the orientation grid.
N_THETA, N_THETA_GRID = 360, 72


def theta_scan(observed: np.ndarray, obj_corners: np.ndarray, bounds: Bounds, principal_point,
               *, camera=None, orientations: np.ndarray | None = None, n_theta: int = N_THETA,
               n_iter: int = 4) -> np.ndarray:
    """Closed-form poses for every yaw on a grid (method.md §6), for one or many camera orientations.

    For fixed yaw θ and camera rotation R, with T' = R·(x, y, z) and qᵢ = R·Ry(θ)·oᵢ, the
    projection ũᵢ·(T'z + qᵢz) = µ·(T'x + qᵢx) (and the same in v) is linear in
    (µT'x, µT'y, T'z, µ), or in T' alone when µ is known.

    Parameters
    ----------
    observed : (4, 2) corners t1..t4, pixels
    obj_corners : (4, 3) object-frame corners, metres
    bounds : the µ bounds (a known µ when lower = upper)
    principal_point : (2,) pixels
    camera : orientation from its horizon (or a level camera): R depends on µ, so the solve is
        repeated ``n_iter`` times with R from the previous µ
    orientations : (k, 2) fixed (pitch, roll) candidates, radians, instead of ``camera``

    Returns
    -------
    (k · n_theta, 7) candidate parameter vectors (pitch and roll filled in); rows that put the box
    behind the camera or give a non-positive µ are NaN.
    """
    thetas = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
    if orientations is None:
        pitch = roll = np.zeros(n_theta)
        th = thetas
    else:
        o = np.asarray(orientations, float).reshape(-1, 2)
        pitch, roll = np.repeat(o[:, 0], n_theta), np.repeat(o[:, 1], n_theta)
        th = np.tile(thetas, len(o))
    n = len(th)
    offsets = np.einsum("nij,kj->nki", yaw_matrix(th), obj_corners)  # (n, 4, 3) in G
    d = observed - np.asarray(principal_point, float)  # (4, 2) centred pixels
    lo, hi = bounds.lower[FOCAL], bounds.upper[FOCAL]
    known = lo == hi
    mu = np.full(n, lo if known else np.sqrt(lo * hi))
    derived = orientations is None and camera is not None and camera.horizon is not None
    for _ in range(n_iter if derived else 1):
        if derived:
            pitch, roll = camera.pitch_roll(mu)
        R = rotation_from_pitch_roll(pitch, roll)
        q = np.einsum("nij,nkj->nki", R, offsets)
        A, b = _linear_system(q, d, mu if known else None)
        w = _solve_scaled(A, b)
        if known:
            t_cam = w
        else:
            mu = np.clip(w[:, 3], lo, hi)
            t_cam = np.column_stack([w[:, 0] / w[:, 3], w[:, 1] / w[:, 3], w[:, 2]])
    if derived:
        pitch, roll = camera.pitch_roll(mu)
    t = np.einsum("nji,nj->ni", R, t_cam)  # Rᵀ T'
    params = np.column_stack([t, th, mu, pitch, roll])
    with np.errstate(invalid="ignore"):
        depth_ok = np.all((q[..., 2] + t_cam[:, None, 2]) > 0, axis=1)
    bad = ~depth_ok | ~np.all(np.isfinite(params), axis=1)
    if not known:
        bad |= w[:, 3] <= 0
    params[bad] = np.nan
    return params


def _linear_system(q: np.ndarray, d: np.ndarray, mu_known):
    n = len(q)
    A = np.zeros((n, 8, 4 if mu_known is None else 3))
    b = np.zeros((n, 8))
    for axis, rows in ((0, slice(0, 4)), (1, slice(4, 8))):
        du = d[:, axis]  # (4,)
        if mu_known is None:  # unknowns (µT'x, µT'y, T'z, µ)
            A[:, rows, axis] = -1.0
            A[:, rows, 2] = du
            A[:, rows, 3] = -q[..., axis]
            b[:, rows] = -du * q[..., 2]
        else:  # unknowns (T'x, T'y, T'z)
            A[:, rows, axis] = -mu_known[:, None]
            A[:, rows, 2] = du
            b[:, rows] = -du * q[..., 2] + mu_known[:, None] * q[..., axis]
    return A, b


def _solve_scaled(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched least squares with column scaling (the columns mix pixels and metres)."""
    s = np.linalg.norm(A, axis=1, keepdims=True)
    s[s == 0] = 1.0
    w = np.einsum("nij,nj->ni", np.linalg.pinv(A / s), b)
    return w / s[:, 0, :]


def pick_starts(candidates: np.ndarray, costs: np.ndarray, k: int, min_sep: float = np.radians(10)):
    order = np.argsort(np.where(np.isfinite(costs), costs, np.inf))
    chosen: list[int] = []
    for i in order:
        if not np.isfinite(costs[i]) or len(chosen) == k:
            break
        if all(abs(wrap_angle(candidates[i, YAW] - candidates[j, YAW])) > min_sep for j in chosen):
            chosen.append(i)
    return chosen


def best_per_pitch(candidates: np.ndarray, costs: np.ndarray, exclude=()) -> list[int]:
    """Index of the cheapest finite candidate for each distinct pitch (column 5), best first."""
    out = []
    for pitch in np.unique(candidates[np.isfinite(costs), 5]):
        idx = np.flatnonzero((candidates[:, 5] == pitch) & np.isfinite(costs))
        best = int(idx[np.argmin(costs[idx])])
        if best not in exclude:
            out.append(best)
    return sorted(out, key=lambda i: costs[i])


def scan(model) -> np.ndarray:
    """Candidate starts of the default preset for ``model`` (:func:`theta_scan`)."""
    pp = model.camera.principal_point
    if not model.orientation_free:
        return theta_scan(model.observed, model.obj_corners, model.bounds, pp, camera=model.camera)
    pitches, rolls = np.radians(np.meshgrid(*ORIENTATION_GRID_DEG, indexing="ij"))
    grid = np.column_stack([pitches.ravel(), rolls.ravel()])
    return theta_scan(model.observed, model.obj_corners, model.bounds, pp, orientations=grid,
                      n_theta=N_THETA_GRID)
