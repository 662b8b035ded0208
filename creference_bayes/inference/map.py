"""The MAP of a scene: every object's pose and size and the shared camera, jointly.

Presets (:data:`PRESETS`; docs/inference.md, "Finding the MAP", step by step): ``default``,
closed-form starts from a grid of cameras, then Levenberg–Marquardt steps in working coordinates
(:mod:`.coords`) on the arrowhead Hessian (solved through the camera block's Schur complement),
with σ continuation, the pilot, handedness flips (:func:`_flips`) and an L-BFGS-B polish;
``paper`` and ``paper-controlled``, the paper's L-BFGS-B inside basin hopping with uniform random
restarts within :func:`preset_bounds`. The result carries the arrowhead Hessian at the optimum
(:class:`Arrowhead`), which the sampler uses for its proposals and its camera–object shear.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import basinhopping, least_squares, minimize

from ..models.contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, O_YAW, Bounds, Model
from .coords import CAMERA_LOG, FD_STEPS, WorkingCoords, explored_whole

__all__ = ["PRESETS", "Arrowhead", "MapState", "FlatState", "optimize", "refine", "derivatives", "initial_objects",
           "preset_bounds"]

_YAW_GRID = np.radians(np.arange(0.0, 360.0, 5.0))
_PITCH_GRID = np.radians([-10.0, -4.0, 0.0, 4.0, 10.0, 20.0, 35.0])
_FOCAL_GRID = (0.5, 0.7, 1.0, 1.4, 2.0)
#: Corner scale (px) of the first, smoother pass when the annotations agree more closely than this.
_SMOOTH_SIGMA_PX = 3.0
#: How far (pixels) a non-smooth model rounds its kinks in the first rounds of Newton steps.
_SOFTNESS_PX = (1.0, 0.1, 0.01)
#: Largest Newton decrement gᵀH⁻¹g / 2 (nats: how much a full Newton step would still gain) Newton's
#: end point may have; beyond it (or with a Hessian not positive definite) the optimum is finished
#: by L-BFGS-B.
_DECREMENT_TOL = 1e-3


@dataclass
class Arrowhead:
    """Gradient and Hessian of the negative log-posterior in working coordinates, by blocks.

    Attributes
    ----------
    value : the negative log-posterior
    g_c : (5,) camera gradient;  g_o : (m, 7) object gradients
    H_cc : (5, 5);  H_co : (m, 5, 7);  H_oo : (m, 7, 7)
    Rows and columns of fixed parameters are zero with a 1 on the diagonal.
    """

    value: float
    g_c: np.ndarray
    g_o: np.ndarray
    H_cc: np.ndarray
    H_co: np.ndarray
    H_oo: np.ndarray
    #: (P, 2) objects coupled by a distance reference, and (P, 7, 7) ∂²/∂oᵢ∂oⱼ of each pair
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), int))
    H_pair: np.ndarray = field(default_factory=lambda: np.zeros((0, 7, 7)))

    def dense(self, lam: float = 0.0) -> np.ndarray:
        """The whole Hessian (5 + 7m, 5 + 7m), camera first, plus ``lam`` on the diagonal."""
        m = len(self.H_oo)
        H = np.zeros((5 + 7 * m, 5 + 7 * m))
        H[:5, :5] = self.H_cc
        for i in range(m):
            sl = slice(5 + 7 * i, 12 + 7 * i)
            H[:5, sl] = self.H_co[i]
            H[sl, :5] = self.H_co[i].T
            H[sl, sl] = self.H_oo[i]
        for (i, j), Hij in zip(self.pairs, self.H_pair):
            si, sj = slice(5 + 7 * i, 12 + 7 * i), slice(5 + 7 * j, 12 + 7 * j)
            H[si, sj] += Hij
            H[sj, si] += Hij.T
        return H + lam * np.eye(len(H))

    def decrease(self, dc: np.ndarray, do: np.ndarray) -> float:
        """How much the quadratic model (this gradient and Hessian) says the step (Δc (5,),
        Δo (m, 7)) lowers the objective (nats)."""
        co = np.einsum("c,mcj,mj->", dc, self.H_co, do)
        quad = dc @ self.H_cc @ dc + 2.0 * co + np.einsum("mi,mij,mj->", do, self.H_oo, do)
        for (i, j), Hij in zip(self.pairs, self.H_pair):
            quad += 2.0 * do[i] @ Hij @ do[j]
        return float(-(self.g_c @ dc + np.sum(self.g_o * do) + 0.5 * quad))

    def solve(self, lam: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
        """The (damped) Newton step (Δc (5,), Δo (m, 7)), or None when the Hessian is not
        positive definite. Through the Schur complement of the camera block (O(m)); with objects
        coupled by distance references, one dense solve."""
        if len(self.pairs):
            try:
                H = self.dense(lam)
                L = np.linalg.cholesky(H)
                g = np.concatenate([self.g_c, self.g_o.ravel()])
                step = -np.linalg.solve(L.T, np.linalg.solve(L, g))
                return step[:5], step[5:].reshape(-1, 7)
            except np.linalg.LinAlgError:
                return None
        try:
            A = self.H_oo + lam * np.eye(7)
            np.linalg.cholesky(A)
            Ainv_oc = np.linalg.solve(A, np.transpose(self.H_co, (0, 2, 1)))  # (m, 7, 5)
            Ainv_g = np.linalg.solve(A, self.g_o[..., None])[..., 0]  # (m, 7)
            S = self.H_cc + lam * np.eye(5) - np.einsum("mcj,mjd->cd", self.H_co, Ainv_oc)
            rhs = -(self.g_c - np.einsum("mcj,mj->c", self.H_co, Ainv_g))
            np.linalg.cholesky(S)
            dc = np.linalg.solve(S, rhs)
            do = -(Ainv_g + np.einsum("mjc,c->mj", Ainv_oc, dc))
            return dc, do
        except np.linalg.LinAlgError:
            return None


@dataclass(frozen=True)
class MapState:
    """The optimum: camera (5,), objects (m, 7), handedness (m,), its negative log-posterior, the
    arrowhead Hessian there, and ``info`` (iterations, seconds, starts tried). With ``pilot`` (the
    camera (5,) of the first optimum, where the model fixes what it takes there, or None) it is the
    fit's state: :meth:`fitted` is the model at it."""

    camera: np.ndarray
    objects: np.ndarray
    handedness: np.ndarray
    value: float
    hessian: Arrowhead
    info: dict = field(default_factory=dict)
    #: other local optima the search reached: (camera (5,), objects (m, 7), handedness (m,)), best first
    others: tuple = ()
    pilot: np.ndarray | None = None

    def fitted(self, model: Model) -> Model:
        """``model`` at this fit: a copy with the optimum's handedness and pilot (``model`` is not
        changed; :meth:`~creference_bayes.models.contract.Model.variant`)."""
        return model.variant(handedness=self.handedness, pilot=self.pilot)


def _solve_objects(model: Model, cam: np.ndarray, handedness, corners=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form placement of every object for one camera and one handedness (±1, or (m,)) over
    the yaw grid, from each object's per-corner median annotation or ``corners`` (m, 4, 2) px.

    Returns the best (x, y, z) (m, 3), yaw (m,) and the mean reprojection error (m,) pixels.
    """
    from ..core.geometry import rotation_from_pitch_roll
    from ..models.contract import object_corners

    mu = cam[C_FOCAL]
    R = rotation_from_pitch_roll(cam[C_PITCH], cam[C_ROLL])
    obs = (np.array([o.corner_median for o in model.objects]) if corners is None else corners) - model.principal_point
    sizes = np.array([o.initial_sizes for o in model.objects])
    p = object_corners(sizes, np.broadcast_to(handedness, len(sizes)))  # (m, 4, 3)
    c, s = np.cos(_YAW_GRID), np.sin(_YAW_GRID)
    Ry = np.zeros((len(_YAW_GRID), 3, 3))
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 1, 1], Ry[:, 2, 0], Ry[:, 2, 2] = c, s, 1.0, -s, c
    q = np.einsum("ij,yjk,mck->ymci", R, Ry, p)  # (Y, m, 4, 3): R Ry p
    u, v = obs[None, ..., 0], obs[None, ..., 1]  # (1, m, 4)
    # (u r3 − µ r1)·t = µ q_x − u q_z ;  (v r3 − µ r2)·t = µ q_y − v q_z
    Au = u[..., None] * R[2] - mu * R[0]
    Av = v[..., None] * R[2] - mu * R[1]
    A = np.concatenate([np.broadcast_to(Au, q.shape), np.broadcast_to(Av, q.shape)], axis=2)  # (Y, m, 8, 3)
    b = np.concatenate([mu * q[..., 0] - u * q[..., 2], mu * q[..., 1] - v * q[..., 2]], axis=2)
    AtA = np.einsum("ymki,ymkj->ymij", A, A) + 1e-9 * np.eye(3)
    t = np.linalg.solve(AtA, np.einsum("ymki,ymk->ymi", A, b)[..., None])[..., 0]  # (Y, m, 3)
    pc = np.einsum("ij,ymj->ymi", R, t)[:, :, None, :] + q
    z = np.maximum(pc[..., 2], 1e-6)
    err = np.hypot(mu * pc[..., 0] / z - u, mu * pc[..., 1] / z - v).mean(axis=-1)
    err = np.where(pc[..., 2].min(axis=-1) > 0.05, err, np.inf)
    best = np.argmin(err, axis=0)
    idx = np.arange(len(sizes))
    return t[best, idx], _YAW_GRID[best], err[best, idx]


def initial_objects(model: Model, cam: np.ndarray, handedness: np.ndarray | None = None,
                    keep_camera: bool = False, corners=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Objects placed for one camera: (camera with its height set from them, unless
    ``keep_camera``; objects (m, 7); handedness (m,); the total reprojection error in pixels). Each
    object takes the handedness that fits its annotations (their per-corner median, or
    ``corners`` (m, 4, 2) px) better, or the one ``handedness`` (m,) gives."""
    sols = [_solve_objects(model, cam, h, corners) for h in (1, -1)]
    pick = np.where(sols[0][2] <= sols[1][2], 0, 1) if handedness is None else np.where(handedness > 0, 0, 1)
    t = np.where(pick[:, None] == 0, sols[0][0], sols[1][0])
    yaw = np.where(pick == 0, sols[0][1], sols[1][1])
    err = np.where(pick == 0, sols[0][2], sols[1][2])
    cam = cam.copy()
    h = float(np.median(t[:, 1])) if np.all(np.isfinite(t[:, 1])) else cam[C_HEIGHT]
    if not keep_camera:
        cam[C_HEIGHT] = float(np.clip(h, 0.3, 20.0)) if h > 0 else cam[C_HEIGHT]
        cam[C_HEIGHT] = float(np.clip(cam[C_HEIGHT], model.camera_lower[C_HEIGHT], model.camera_upper[C_HEIGHT]))
    objs = np.zeros((model.n_objects, 7))
    objs[:, 0], objs[:, 1], objs[:, 2] = t[:, 0], np.maximum(t[:, 2], 0.2), yaw
    lo, hi = model.object_lower[:2], model.object_upper[:2]
    pad = 1e-3 * np.where(np.isfinite(hi - lo), hi - lo, 0.0)  # inside, so that the working coordinates'
    objs[:, :2] = np.clip(objs[:, :2], lo + pad, hi - pad)  # round trip and differences stay in the box
    objs[:, O_SIZE] = [o.initial_sizes for o in model.objects]
    if model.ground_sd_m > 0:
        with np.errstate(invalid="ignore"):
            g = np.clip(cam[C_HEIGHT] - t[:, 1], -1.0, 1.0)
        # an object whose own placement is unusable stands on the camera's ground plane: its
        # bottom must stay below the camera (else it has no ray to the ground and zero density)
        g[~np.isfinite(g) | (cam[C_HEIGHT] - g < 0.2)] = 0.0
        objs[:, O_GROUND] = g
    return cam, objs, np.where(pick == 0, 1, -1), float(np.sum(err))


def _camera_starts(model: Model) -> list[np.ndarray]:
    """Cameras to place the objects from: a grid of µ around the prior's (when unknown) and, when
    pitch and roll are free, of pitch (and the measured horizon's pitch and roll); inside the
    model's bounds."""
    side = float(max(model.image_size))
    terms = model.camera_terms
    mid = model.focal_guess()
    focals = [mid] if model.focal_length_px is not None else \
        [mid * k for k in _FOCAL_GRID if 0.1 * side <= mid * k <= 10 * side] or [mid]
    starts = []
    for mu in focals:
        if model.orientation == "free":
            hz = terms.horizon
            if hz is not None:
                from ..core.geometry import horizon_line, pitch_roll_from_horizon

                p, r = pitch_roll_from_horizon(horizon_line(hz.points), mu, model.principal_point)
                starts.append(np.array([mu, float(p), float(r), 1.6, model.ref_scale_median]))
            starts += [np.array([mu, pitch, 0.0, 1.6, model.ref_scale_median]) for pitch in _PITCH_GRID]
        else:
            starts.append(model.complete_camera(np.array([mu, 0.0, 0.0, 1.6, model.ref_scale_median]))[0])
    lo, hi = model.camera_lower, model.camera_upper
    out = []
    for c in starts:
        c = model.complete_camera(np.clip(c, lo, hi)[None])[0]
        if not any(np.allclose(c, o) for o in out):
            out.append(c)
    return out


def derivatives(model: Model, wc: np.ndarray, wo: np.ndarray, temperature: float = 1.0,
                with_jacobian: bool = False) -> Arrowhead:
    """Gradient and arrowhead Hessian of the negative log-posterior at (wc (5,), wo (m, 7)) in
    working coordinates, by central differences batched over every object at once.

    ``with_jacobian`` adds −log |∂natural/∂working| (the density the sampler targets)."""
    coords = WorkingCoords(model)
    h = FD_STEPS
    P = _stencil(h)  # (n, 12)
    WC = wc[None] + P[:, :5] * model.camera_free
    WO = wo[None] + P[:, None, 5:] * model.object_free[None]
    cams, objs = coords.from_work(WC, WO)
    with np.errstate(all="ignore"):
        fo = model.object_terms(cams, objs, temperature)  # (n, m)
        fc = model.camera_term(cams, temperature)  # (n,)
        if with_jacobian:
            jc, jo = coords.log_jacobian(WC, WO)
            fo, fc = fo - jo, fc - jc
        else:  # the MAP's objective (Model.map_objective)
            fo, fc = fo - model.map_log_jacobian(objs), fc - model.camera_log_jacobian(cams)
    value = float(fc[0] + fo[0].sum())
    F = np.concatenate([fc[:, None], fo], axis=1)  # (n, 1 + m): camera term, then each object's
    grad, H = _second_differences(F, h)
    Hc, Ho = H[0], H[1:]
    g_c = (grad[:5, 0] + grad[:5, 1:].sum(axis=1)) * model.camera_free
    g_o = grad[5:, 1:].T * model.object_free
    H_cc = Hc[:5, :5] + Ho[:, :5, :5].sum(axis=0)
    cf = model.camera_free
    H_cc = np.where(np.outer(cf, cf), H_cc, np.eye(5))
    of = model.object_free
    H_co = Ho[:, :5, 5:] * cf[None, :, None] * of[:, None, :]
    H_oo = np.where(of[:, :, None] & of[:, None, :], Ho[:, 5:, 5:], np.eye(7)[None])
    bad = ~np.all(np.isfinite(H_oo), axis=(1, 2))
    H_oo[bad] = np.eye(7)
    out = Arrowhead(value, np.nan_to_num(g_c), np.nan_to_num(g_o), np.nan_to_num(H_cc), np.nan_to_num(H_co), H_oo)
    if len(model.pairs):
        _add_pairs(model, coords, wc, wo, temperature, out)
    return out


def _stencil(h: np.ndarray) -> np.ndarray:
    """Points of a central-difference gradient and Hessian with steps ``h`` (d,): the centre,
    ±hₐ, then +(hₐ + h_b) and −(hₐ + h_b) for a < b; (1 + 2d + d(d − 1), d)."""
    d = len(h)
    E = np.diag(h)
    pairs = [(a, b) for a in range(d) for b in range(a + 1, d)]
    return np.array([np.zeros(d)] + list(E) + list(-E) + [E[a] + E[b] for a, b in pairs]
                    + [-E[a] - E[b] for a, b in pairs])


def _second_differences(F: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (d, k) and Hessians (k, d, d) of k functions from their values F (n, k) at
    :func:`_stencil` ``(h)``."""
    d = len(h)
    pairs = [(a, b) for a in range(d) for b in range(a + 1, d)]
    f0, fp, fm = F[0], F[1:1 + d], F[1 + d:1 + 2 * d]
    grad = (fp - fm) / (2 * h[:, None])
    diag = (fp + fm - 2 * f0) / h[:, None] ** 2  # (d, k)
    base = 1 + 2 * d
    fpp, fmm = F[base:base + len(pairs)], F[base + len(pairs):]
    H = np.zeros((F.shape[1], d, d))
    for k, (a, b) in enumerate(pairs):
        H[:, a, b] = H[:, b, a] = (fpp[k] + fmm[k] - 2 * f0 - diag[a] * h[a] ** 2 - diag[b] * h[b] ** 2) / (2 * h[a] * h[b])
    idx = np.arange(d)
    H[:, idx, idx] = diag.T
    return grad, H


def _add_pairs(model: Model, coords: WorkingCoords, wc, wo, temperature: float, D: Arrowhead) -> None:
    """Add the distance references' terms to ``D``: each pair's gradient and Hessian over
    (camera, oᵢ, oⱼ) by central differences, its blocks added where they belong and the
    cross-object block kept in ``D.H_pair``."""
    h = np.concatenate([FD_STEPS[:5], FD_STEPS[5:], FD_STEPS[5:]])  # (19,)
    P = _stencil(h)
    free = np.concatenate([model.camera_free, np.zeros(14, bool)])
    cf, of = model.camera_free, model.object_free
    D.pairs = model.pairs.copy()
    D.H_pair = np.zeros((len(model.pairs), 7, 7))
    D.value = float(D.value + model.pair_terms(*coords.from_work(wc[None], wo[None]), temperature)[0].sum())
    for p, (i, j) in enumerate(model.pairs):
        free[5:12], free[12:] = of[i], of[j]
        Q = P * free
        WC = wc[None] + Q[:, :5]
        WO = np.repeat(wo[None], len(Q), axis=0)
        WO[:, i] += Q[:, 5:12]
        WO[:, j] += Q[:, 12:]
        with np.errstate(all="ignore"):
            f = model.pair_terms(*coords.from_work(WC, WO), temperature)[:, p]
        g, H = _second_differences(f[:, None], h)
        g = np.nan_to_num(np.where(free, g[:, 0], 0.0))
        H = np.nan_to_num(H[0] * np.outer(free, free))
        D.g_c = D.g_c + g[:5] * cf
        D.g_o[i] += g[5:12]
        D.g_o[j] += g[12:]
        D.H_cc = D.H_cc + H[:5, :5]
        D.H_co[i] += H[:5, 5:12]
        D.H_co[j] += H[:5, 12:]
        D.H_oo[i] += H[5:12, 5:12]
        D.H_oo[j] += H[12:, 12:]
        D.H_pair[p] = H[5:12, 12:]


def _total(model: Model, wc: np.ndarray, wo: np.ndarray, temperature: float) -> float:
    cams, objs = WorkingCoords(model).from_work(wc[None], wo[None])
    return float(model.map_objective(cams, objs, temperature)[0])


def _camera_box(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """The camera's bounds in working coordinates (logarithms of the positive ones)."""
    lo, hi = model.camera_lower.astype(float), model.camera_upper.astype(float)
    with np.errstate(divide="ignore"):
        lo[CAMERA_LOG], hi[CAMERA_LOG] = np.log(lo[CAMERA_LOG]), np.log(hi[CAMERA_LOG])
    fixed = ~model.camera_free  # fixed entries are never moved: no bound applies
    margin = 1e-10  # inside, after the round trip through exp
    return np.where(fixed, -np.inf, lo + margin), np.where(fixed, np.inf, hi - margin)


def _hold(D: Arrowhead, wc: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> Arrowhead:
    """``D`` with every camera parameter on its bound whose gradient pushes out held there (its
    gradient zero, its rows and columns of the Hessian the identity's: the active set)."""
    held = ((wc <= lo) & (D.g_c > 0)) | ((wc >= hi) & (D.g_c < 0))
    if held.any():
        D.g_c[held] = 0.0
        D.H_cc[held, :] = D.H_cc[:, held] = 0.0
        D.H_cc[held, held] = 1.0
        D.H_co[:, held, :] = 0.0
    return D


def _newton(model: Model, wc, wo, temperature: float, max_iter: int = 60, tol: float = 1e-7):
    """Levenberg–Marquardt on the arrowhead system, each step clipped to a trust radius in every
    working coordinate (docs/inference.md, "Finding the MAP", step 3); returns (wc, wo, value,
    iterations)."""
    f = _total(model, wc, wo, temperature)
    lam, radius = 1e-3, 0.5
    it = 0
    lo, hi = _camera_box(model)
    for it in range(1, max_iter + 1):
        D = _hold(derivatives(model, wc, wo, temperature), wc, lo, hi)
        improved = False
        for _ in range(12):
            step = D.solve(lam * (1.0 + np.abs(D.H_cc).max()) * 1e-6 + lam)
            if step is None:
                lam *= 10.0
                continue
            clipped = max(np.abs(step[0]).max(), np.abs(step[1]).max(initial=0.0)) > radius
            nc = np.clip(wc + np.clip(step[0], -radius, radius), lo, hi)  # projected onto the camera's box
            no = wo + np.clip(step[1], -radius, radius)
            fn = _total(model, nc, no, temperature)
            if np.isfinite(fn) and fn < f:
                improved = True
                done = f - fn < tol * max(1.0, abs(f))
                gain = (f - fn) / max(D.decrease(nc - wc, no - wo), 1e-300)  # of what the quadratic model says
                if clipped and gain > 0.75:
                    radius = min(2.0 * radius, 4.0)
                elif gain < 0.25:
                    radius = max(radius / 2.0, 0.5)
                wc, wo, f = nc, no, fn
                lam = max(lam / 5.0, 1e-9)
                break
            radius = max(radius / 2.0, 0.5)
            lam *= 8.0
        if not improved or done:
            break
    return wc, wo, f, it


PRESETS = ("default", "paper", "paper-controlled")
_PAPER_RESTARTS = {"paper": 200, "paper-controlled": 100}


def preset_bounds(preset: str, image_size) -> Bounds | None:
    """The box a preset optimises and samples within: the paper's for its presets (x, camera
    height, z, µ as §6.1 and §7.1 give them; the camera at least 5 cm above the ground), None
    (the model's own) for ``default``."""
    if preset not in PRESETS:
        raise ValueError(f"preset: unknown preset {preset!r} (expected one of {list(PRESETS)})")
    if preset == "default":
        return None
    z, height, focal = ((1.0, 50.0), (0.05, 5.0), (100.0, 3000.0)) if preset == "paper" else \
        ((1.0, 100.0), (0.05, 10.0), (100.0, 2000.0))
    return Bounds.box(image_size, x=(-10.0, 10.0), z=z, height=height, focal_px=focal)


class FlatState:
    """The free natural parameters of a model as one flat vector: the camera's free entries, then
    each object's (row by row). ``pack`` (cams (n, 5), objs (n, m, 7)) → (n, d); ``unpack`` the
    reverse, fixed entries taken from a template state."""

    def __init__(self, model: Model, camera: np.ndarray, objects: np.ndarray):
        self.model, self.camera, self.objects = model, np.asarray(camera, float), np.asarray(objects, float)
        self.cf, self.of = model.camera_free, model.object_free
        self.lower = np.concatenate([model.camera_lower[self.cf],
                                     np.broadcast_to(model.object_lower, self.of.shape)[self.of]])
        self.upper = np.concatenate([model.camera_upper[self.cf],
                                     np.broadcast_to(model.object_upper, self.of.shape)[self.of]])
        yaw = np.zeros(self.of.shape, bool)
        yaw[:, O_YAW] = True
        self.circular = np.concatenate([np.zeros(int(self.cf.sum()), bool), yaw[self.of]])

    def pack(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        cams, objs = np.atleast_2d(cams), np.asarray(objs, float).reshape(len(np.atleast_2d(cams)), -1, 7)
        return np.concatenate([cams[:, self.cf], objs[:, self.of]], axis=1)

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.atleast_2d(x)
        kc = int(self.cf.sum())
        cams = np.repeat(self.camera[None], len(x), axis=0)
        objs = np.repeat(self.objects[None], len(x), axis=0)
        cams[:, self.cf] = x[:, :kc]
        objs[:, self.of] = x[:, kc:]
        return self.model.complete_camera(cams), objs


def _lbfgsb(model: Model, flat: FlatState, x0: np.ndarray, temperature: float, *, ftol: float,
            maxiter: int = 500) -> tuple[np.ndarray, float]:
    """L-BFGS-B on the MAP objective over the flat free parameters (scaled to their typical size,
    yaw unbounded), with a vectorised central-difference gradient."""
    scale = np.maximum(np.abs(x0), 0.1)
    lo, hi = flat.lower / scale, flat.upper / scale
    lo[flat.circular], hi[flat.circular] = -np.inf, np.inf
    eps = 1e-6

    def fun_grad(z):  # central differences, one-sided on a bound (the box is the prior's support)
        up, down = np.minimum(z + eps, hi), np.maximum(z - eps, lo)
        pts = np.vstack([z, np.where(np.eye(len(z), dtype=bool), up, z), np.where(np.eye(len(z), dtype=bool), down, z)])
        f = model.map_objective(*flat.unpack(pts * scale), temperature)
        f = np.where(np.isfinite(f), f, 1e300)
        return f[0], (f[1:len(z) + 1] - f[len(z) + 1:]) / (up - down)

    res = minimize(fun_grad, np.clip(x0 / scale, lo, hi), jac=True, method="L-BFGS-B",
                   bounds=list(zip(lo, hi)), options={"ftol": ftol, "gtol": 1e-9, "maxiter": maxiter})
    return res.x * scale, float(res.fun)


def _paper(model: Model, temperature: float, restarts: int, rng, bar) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Basin hopping with random restarts (module docstring): (camera, objects, handedness, info)."""
    start = max(_camera_starts(model), key=lambda c: -initial_objects(model, c)[3])
    cam, objs, hand, _ = initial_objects(model, start)
    best = None
    per = max(1, restarts // 2)
    for h in (hand, -hand):
        fit = model.variant(handedness=h)
        flat = FlatState(fit, cam, objs)
        lo, hi = flat.lower.copy(), flat.upper.copy()
        lo[flat.circular], hi[flat.circular] = -np.pi, np.pi

        def f(x):
            v = float(fit.map_objective(*flat.unpack(x), temperature)[0])
            return v if np.isfinite(v) else 1e300

        res = basinhopping(f, rng.uniform(lo, hi), niter=per - 1, T=0.0, rng=rng,
                           take_step=lambda x: rng.uniform(lo, hi),
                           callback=None if bar is None else (lambda *_: bar.update(1) and None),  # True stops it
                           minimizer_kwargs={"method": "L-BFGS-B", "bounds": list(zip(lo, hi)),
                                             "options": {"ftol": 1e-8}})
        if best is None or res.fun < best[0]:
            best = (float(res.fun), flat.unpack(res.x), h)
    value, (cams, objs), hand = best
    return cams[0], objs[0], hand, {"restarts": per * 2}


def optimize(model: Model, *, preset: str = "default", temperature: float = 1.0, rng=None,
             restarts: int | None = None, progress: bool = False, n_refine: int = 2) -> MapState:
    """The MAP of ``model`` at ``temperature`` (module docstring), with each object's handedness and
    the pilot camera (:meth:`MapState.fitted` is the model at them; ``model`` is not changed).

    ``preset``: one of :data:`PRESETS`; ``rng``, ``restarts``, ``progress`` (a bar of the
    restarts): the paper presets' random restarts (None: the paper's number); ``n_refine``: starts
    of the default preset refined by Newton steps.
    """
    if preset not in PRESETS:
        raise ValueError(f"preset: unknown preset {preset!r} (expected one of {list(PRESETS)})")
    if restarts is not None:
        if preset == "default":
            raise ValueError("restarts: the default preset has no random restarts")
        if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
            raise ValueError(f"restarts: expected an integer >= 1, got {restarts!r}")
    t0 = time.perf_counter()
    others = ()
    if preset == "default":
        cam, objs, hand, pilot, info = _default(model, temperature, n_refine)
        others = info.pop("others")
    else:
        from .progress import progress_bar

        n = _PAPER_RESTARTS[preset] if restarts is None else restarts
        with progress_bar(progress, 2 * max(1, n // 2), desc=f"{preset} restarts", unit="restart") as bar:
            cam, objs, hand, info = _paper(model, temperature, n, np.random.default_rng(rng), bar)
        pilot = cam
    fit = model.variant(handedness=hand, pilot=pilot)
    info = {**info, "preset": preset, "seconds": time.perf_counter() - t0}
    return _state(fit, cam, objs, temperature, info, others)


def _state(fit: Model, cam, objs, temperature: float, info: dict, others: tuple = ()) -> MapState:
    """The MapState at (cam, objs) of ``fit``, the model at the fit's handedness and pilot."""
    wc, wo = (a[0] for a in WorkingCoords(fit).to_work(cam[None], objs[None]))
    D = derivatives(fit, wc, wo, temperature)
    objs = objs.copy()
    objs[:, O_YAW] = (objs[:, O_YAW] + np.pi) % (2 * np.pi) - np.pi
    value = float(fit.map_objective(cam[None], objs[None], temperature)[0])
    return MapState(fit.complete_camera(cam[None])[0], objs, fit.handedness.astype(int), value, D, info, others,
                    None if fit.pilot is None else fit.pilot.copy())


def refine(model: Model, current: MapState, camera: np.ndarray, objects: np.ndarray,
           handedness: np.ndarray | None = None, *, temperature: float = 1.0) -> MapState:
    """The optimum reached from another start (camera (5,), objects (m, 7): a mode the sampler's
    search found; ``handedness`` (m,): its handedness, None: ``current``'s), if it is better than
    ``current``; else ``current``. The pilot of ``current`` is kept."""
    fit = current.fitted(model)
    if handedness is not None:
        fit = fit.variant(handedness=np.asarray(handedness, float))
    coords = WorkingCoords(fit)
    wc, wo = (a[0] for a in coords.to_work(camera[None], objects[None]))
    wc, wo, f, it = _newton(fit, wc, wo, temperature)
    if not f < current.value:
        return current
    cams, objs = coords.from_work(wc[None], wo[None])
    return _state(fit, cams[0], objs[0], temperature,
                  {**current.info, "iterations": current.info.get("iterations", 0) + it,
                   "from_sampler_mode_search": True},
                  current.others if np.array_equal(fit.handedness, current.handedness)
                  else ((current.camera, current.objects, current.handedness),) + current.others)


#: An object whose fit with the other handedness (the camera held) comes within this many nats of
#: its fit now is tried again with the camera free too.
FLIP_MARGIN = 25.0
#: At most this many objects are tried so.
MAX_FLIPS = 4


def _flips(model: Model, wc, wo, f: float, temperature: float):
    """The other handedness of each object, tried at the optimum (docs/inference.md, "Finding the
    MAP", step 7: within :data:`FLIP_MARGIN` nats with the camera held, at most :data:`MAX_FLIPS`,
    each flip kept when the whole objective improves). ``model`` is the fit's model; returns (the
    model at the handedness kept, wc, wo, value, iterations)."""
    coords = WorkingCoords(model)
    held, wof, iters = other_handedness(model, wc, wo, temperature)
    per_f = _object_values(held, WorkingCoords(held), wc, wof, temperature)
    gap = per_f - _object_values(model, coords, wc, wo, temperature)
    for i in [k for k in np.argsort(gap) if gap[k] < FLIP_MARGIN][:MAX_FLIPS]:
        hand = model.handedness
        trial = model.variant(handedness=np.where(np.arange(len(hand)) == i, -hand, hand))
        start = wo.copy()
        start[i] = wof[i]
        wc2, wo2, f2, it = _newton(trial, wc, start, temperature)
        iters += it
        if f2 < f:
            model, wc, wo, f = trial, wc2, wo2, f2
    return model, wc, wo, f, iters


def other_handedness(model: Model, wc, wo, temperature: float):
    """Every object at its other handedness, the camera held at ``wc`` (step 7): each placed from
    its annotations with the sizes of ``wo``, then Newton steps. Returns the model there (the camera
    held), the objects' working coordinates (m, 7) and the iterations (none where a placement is
    not finite)."""
    coords = WorkingCoords(model)
    cams, objs = coords.from_work(wc[None], wo[None])
    h0 = model.handedness
    _, flipped, _, _ = initial_objects(model, cams[0], handedness=-h0, keep_camera=True)
    flipped[:, O_SIZE] = objs[0, :, O_SIZE]
    wof = coords.to_work(cams, flipped[None])[1][0]
    held = model.variant(handedness=-h0, camera_free=np.zeros(5, bool))
    if not np.all(np.isfinite(wof)):
        return held, wof, 0
    _, wof, _, iters = _newton(held, wc, wof, temperature)
    return held, wof, iters


def _object_values(model: Model, coords: WorkingCoords, wc, wo, temperature: float) -> np.ndarray:
    """(m,) each object's part of the MAP objective at working coordinates (wc, wo)."""
    cams, objs = coords.from_work(wc[None], wo[None])
    with np.errstate(all="ignore"):
        v = (model.object_terms(cams, objs, temperature) - model.map_log_jacobian(objs))[0]
    return np.where(np.isfinite(v), v, np.inf)


def _corner_fits(model: Model, starts, temperature: float) -> list:
    """For a model whose objective has kinks (the paper's): from each start (value, error, camera,
    objects, handedness), a least-squares fit of the projected corners to each object's per-corner
    median annotation (smooth; with exact lines it lands on the truth, where the kinks' V has its
    tip), then L-BFGS-B on the objective. Returns (value, camera, objects, handedness) of each."""
    obs = np.array([o.corner_median for o in model.objects])  # (m, 4, 2)
    out = []
    base = model
    for _, _, cam, objs, hand in starts:
        model = base.variant(handedness=hand)
        flat = FlatState(model, cam, objs)
        x0 = flat.pack(cam[None], objs[None])[0]
        scale = np.maximum(np.abs(x0), 0.1)

        def resid(z):  # (n, d) → (n, r): corner residuals (px), a steep penalty behind the camera
            uv, depth = model.project(*flat.unpack(np.atleast_2d(z) * scale))
            n = len(uv)
            return np.concatenate([(uv - obs).reshape(n, -1), 1e3 * np.minimum(depth - 1e-3, 0.0).reshape(n, -1)], 1)

        def jac(z):  # central differences, every column in one call
            r = resid(np.vstack([z + 1e-6 * np.eye(len(z)), z - 1e-6 * np.eye(len(z))]))
            return ((r[:len(z)] - r[len(z):]) / 2e-6).T

        with np.errstate(all="ignore"):
            try:
                z = least_squares(lambda z: resid(z)[0], x0 / scale, jac=jac, method="lm", max_nfev=200).x
            except ValueError:
                continue
        if not np.all(np.isfinite(z)):
            continue
        x, _ = _lbfgsb(model, flat, z * scale, temperature, ftol=1e-13)
        c, o = flat.unpack(x)
        f = float(model.map_objective(c, o, temperature)[0])
        if np.isfinite(f):
            out.append((f, c[0], o[0], hand.copy()))
    return out


def _default(model: Model, temperature: float, n_refine: int):
    """The default preset (module docstring): (camera, objects, handedness, pilot camera, info).
    Every start and pass is a copy of ``model`` at its own state (:meth:`Model.variant`)."""
    candidates = []
    both = explored_whole(model)  # one object block sets the camera: both handednesses from the start
    for start in _camera_starts(model):
        placed = [initial_objects(model, start)]
        if both:
            placed.append(initial_objects(model, start, handedness=-placed[0][2]))
        for cam, objs, hand, err in placed:
            value = float(model.variant(handedness=hand).map_objective(cam[None], objs[None], temperature)[0])
            candidates.append((value, err, cam, objs, hand))
    candidates.sort(key=lambda c: (not np.isfinite(c[0]), c[0] if np.isfinite(c[0]) else c[1]))
    # the best starts, and the best of every other handedness (one object block: refine both)
    firsts = {}
    for k, c in enumerate(candidates if both else ()):  # several: flips decide (_flips)
        firsts.setdefault(tuple(c[4]), k)
    chosen = sorted(set(range(min(n_refine, len(candidates)))) | set(firsts.values()))
    iters = 0
    reached = []
    smoother = "corner_sigma" in model.capabilities and np.any(np.asarray(model.sigma) < _SMOOTH_SIGMA_PX)
    for k in chosen:
        value, err, cam, objs, hand = candidates[k]
        fit = model.variant(handedness=hand)
        wc, wo = (a[0] for a in WorkingCoords(fit).to_work(cam[None], objs[None]))
        if smoother or not model.smooth:  # continuation: a smoother cost first (far from the optimum
            wide = fit.variant(sigma=np.maximum(model.sigma, _SMOOTH_SIGMA_PX)) if smoother else fit  # a tiny σ
            for soft in (0.0,) if model.smooth else _SOFTNESS_PX:  # leaves only t-tails; kinks stop Newton:
                wc, wo, f, it = _newton(wide.variant(softness_px=soft), wc, wo, temperature)  # rounded ever less)
                iters += it
        wc, wo, f, it = _newton(fit, wc, wo, temperature)
        iters += it
        reached.append((f, wc, wo, hand))
    f, wc, wo, hand = min(reached, key=lambda r: r[0])  # the first of the best
    if not np.isfinite(f):
        raise RuntimeError(f"no start of the optimiser reached a finite posterior density "
                           f"({len(candidates)} starts tried)")
    coords = WorkingCoords(model)
    pilot = coords.from_work(wc[None], wo[None])[0][0]
    fit = model.variant(handedness=hand, pilot=pilot)
    if fit.needs_pilot:
        wc, wo, f, it = _newton(fit, wc, wo, temperature)
        iters += it
    fit, wc, wo, f, it = _flips(fit, wc, wo, f, temperature)
    iters += it
    cams, objs = coords.from_work(wc[None], wo[None])
    cam, objs = cams[0], objs[0]
    D = _hold(derivatives(fit, wc, wo, temperature), wc, *_camera_box(fit))
    step = D.solve()
    stalled = step is None or -0.5 * (D.g_c @ step[0] + np.sum(D.g_o * step[1])) > _DECREMENT_TOL
    if stalled or not model.smooth:  # kinks, or Newton stopped short (a Hessian not positive where
        flat = FlatState(fit, cam, objs)  # a very sharp likelihood bends): L-BFGS-B needs none
        x, _ = _lbfgsb(fit, flat, flat.pack(cam[None], objs[None])[0], temperature, ftol=1e-13)
        c2, o2 = flat.unpack(x)
        if fit.map_objective(c2, o2, temperature)[0] < fit.map_objective(cam[None], objs[None], temperature)[0]:
            cam, objs = c2[0], o2[0]
    hand = fit.handedness
    if not model.smooth:  # kinks: the best of this and the fits of the projected corners (below)
        best_fit = (fit.map_objective(cam[None], objs[None], temperature)[0], cam, objs, hand)
        for found in _corner_fits(fit, [candidates[k] for k in chosen], temperature):
            best_fit = min(best_fit, found, key=lambda b: b[0])
        _, cam, objs, hand = best_fit
    others = []
    for f_, wc_, wo_, hand_ in sorted(reached, key=lambda r: r[0]):
        if np.isfinite(f_) and not (np.allclose(wc_, wc) and np.allclose(wo_, wo)):
            c_, o_ = coords.from_work(wc_[None], wo_[None])
            others.append((c_[0], o_[0], np.asarray(hand_, int)))
    return cam, objs, np.asarray(hand).astype(int), pilot, {"iterations": iters, "starts": len(candidates),
                                                          "polished": bool(stalled), "others": tuple(others)}
