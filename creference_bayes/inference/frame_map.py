"""The MAP of a frame: every object's pose and size and the shared camera, jointly.

1. **Start.** For each camera of a small grid (pitch, and µ when it is unknown; roll 0, or the
   measured horizon's), every object is placed by a closed-form solve: for a fixed yaw and
   handedness, the projection equations of its four annotated corners (per-corner median) are
   linear in its bottom centre (x, y, z) given the camera, so a 5° yaw grid × both handednesses is
   one batched least-squares solve per object. The objects' y gives the camera height (the median
   over objects, their ground offsets the rest). The camera whose objects fit best starts.
2. **Joint Newton.** Levenberg–Marquardt steps on the negative log-posterior in working
   coordinates (:mod:`.frame_coords`: each object anchored to the image). Given the camera the objects are independent, so the
   Hessian is an *arrowhead*: a camera block, one block per object and their couplings. Its
   derivatives come from one batched set of finite differences whose cost does not grow with the
   number of objects (a perturbation of an object coordinate is applied to every object at
   once: each object's term sees only its own), and the step is solved through the Schur
   complement of the camera block: O(m) work for m objects.
3. **Continuation.** When annotations agree to a pixel or better, the cost is so sharp that far
   from the optimum only the Student-t tails are felt; a first pass with σ raised to 3 px finds
   the basin, the second refines with the real σ.
4. **Line noise** of the references is fixed at the first optimum (the pilot) and the optimum
   refined from there, as the single-target model does.

The result carries the arrowhead Hessian at the optimum (:class:`Arrowhead`), which the sampler
uses for its proposals and its camera–object shear.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..models.frame import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, FrameModel
from .frame_coords import FD_STEPS, FrameCoords

__all__ = ["Arrowhead", "FrameMAP", "optimize_frame", "derivatives", "initial_objects"]

_YAW_GRID = np.radians(np.arange(0.0, 360.0, 5.0))
_PITCH_GRID = np.radians([-10.0, -4.0, 0.0, 4.0, 10.0, 20.0, 35.0])
_FOCAL_GRID = (0.5, 0.7, 1.0, 1.4, 2.0)
#: Corner scale (px) of the first, smoother pass when the annotations agree more closely than this.
_SMOOTH_SIGMA_PX = 3.0


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

    def covariance_blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The Laplace approximation by blocks: the camera's marginal covariance (5, 5), each
        object's covariance given the camera (m, 7, 7), and the shear B (m, 7, 5) with
        E[o | c] = o* + B (c − c*). With objects coupled by distance references, each object's
        covariance is the one given the camera *and the other objects* (what a step of one object
        sees), the camera's and the shear from the whole inverse."""
        if len(self.pairs):
            cov = np.linalg.inv(self.dense())
            Sc = cov[:5, :5]
            B = (cov[5:, :5] @ np.linalg.inv(Sc)).reshape(-1, 7, 5)
            return Sc, np.linalg.inv(self.H_oo), B
        A_inv = np.linalg.inv(self.H_oo)
        B = -np.einsum("mij,mcj->mic", A_inv, self.H_co)
        S = self.H_cc - np.einsum("mcj,mjd->cd", self.H_co, -B)
        return np.linalg.inv(S), A_inv, B


@dataclass(frozen=True)
class FrameMAP:
    """The optimum: camera (5,), objects (m, 7), handedness (m,), its negative log-posterior, the
    arrowhead Hessian there, and ``info`` (iterations, seconds, starts tried)."""

    camera: np.ndarray
    objects: np.ndarray
    handedness: np.ndarray
    value: float
    hessian: Arrowhead
    info: dict = field(default_factory=dict)


def _solve_objects(model: FrameModel, cam: np.ndarray, handedness: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form placement of every object for one camera and one handedness over the yaw grid.

    Returns the best (x, y, z) (m, 3), yaw (m,) and the mean reprojection error (m,) pixels.
    """
    from ..core.geometry import rotation_from_pitch_roll
    from ..models.frame import object_corners

    mu = cam[C_FOCAL]
    R = rotation_from_pitch_roll(cam[C_PITCH], cam[C_ROLL])
    obs = np.array([np.median(o.annotations, axis=0) for o in model.objects]) - model.principal_point  # (m, 4, 2)
    sizes = np.array([o.initial_sizes for o in model.objects])
    p = object_corners(sizes, np.full(len(sizes), handedness))  # (m, 4, 3)
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


def initial_objects(model: FrameModel, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Objects placed for one camera: (camera with its height set, objects (m, 7), handedness
    (m,), the total reprojection error in pixels)."""
    sols = [_solve_objects(model, cam, h) for h in (1, -1)]
    pick = np.where(sols[0][2] <= sols[1][2], 0, 1)
    t = np.where(pick[:, None] == 0, sols[0][0], sols[1][0])
    yaw = np.where(pick == 0, sols[0][1], sols[1][1])
    err = np.where(pick == 0, sols[0][2], sols[1][2])
    cam = cam.copy()
    h = float(np.median(t[:, 1])) if np.all(np.isfinite(t[:, 1])) else cam[C_HEIGHT]
    cam[C_HEIGHT] = float(np.clip(h, 0.3, 20.0)) if h > 0 else cam[C_HEIGHT]
    objs = np.zeros((model.n_objects, 7))
    objs[:, 0], objs[:, 1], objs[:, 2] = t[:, 0], np.maximum(t[:, 2], 0.2), yaw
    objs[:, O_SIZE] = [o.initial_sizes for o in model.objects]
    if model.ground_sd_m > 0:
        with np.errstate(invalid="ignore"):
            g = np.clip(cam[C_HEIGHT] - t[:, 1], -1.0, 1.0)
        # an object whose own placement is unusable stands on the camera's ground plane: its
        # bottom must stay below the camera (else it has no ray to the ground and zero density)
        g[~np.isfinite(g) | (cam[C_HEIGHT] - g < 0.2)] = 0.0
        objs[:, O_GROUND] = g
    return cam, objs, np.where(pick == 0, 1, -1), float(np.sum(err))


def _camera_starts(model: FrameModel) -> list[np.ndarray]:
    side = float(max(model.image_size))
    terms = model.camera_terms
    if model.focal_length_px is not None:
        focals = [model.focal_length_px]
    else:
        mid = terms.focal.median_px if terms.focal is not None else 30.0 / 43.27 * float(np.hypot(*model.image_size))
        focals = [mid * k for k in _FOCAL_GRID if 0.1 * side <= mid * k <= 10 * side]
    starts = []
    for mu in focals:
        cam = np.array([mu, 0.0, 0.0, 1.6, 0.5])
        if model.orientation == "free":
            hz = terms.horizon
            if hz is not None:
                from ..core.geometry import horizon_line, pitch_roll_from_horizon

                p, r = pitch_roll_from_horizon(horizon_line(hz.points), mu, model.principal_point)
                starts.append(np.array([mu, float(p), float(r), 1.6, 0.5]))
            for pitch in _PITCH_GRID:
                starts.append(np.array([mu, pitch, 0.0, 1.6, 0.5]))
        else:
            starts.append(model.complete_camera(cam)[0])
    return starts


def derivatives(model: FrameModel, wc: np.ndarray, wo: np.ndarray, temperature: float = 1.0,
                with_jacobian: bool = False) -> Arrowhead:
    """Gradient and arrowhead Hessian of the negative log-posterior at (wc (5,), wo (m, 7)) in
    working coordinates, by central differences batched over every object at once.

    ``with_jacobian`` adds −log |∂natural/∂working| (the density the sampler targets)."""
    coords = FrameCoords(model)
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
        else:  # the MAP's objective (FrameModel.map_objective)
            fo = fo - model.map_log_jacobian(objs)
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


def _add_pairs(model: FrameModel, coords: FrameCoords, wc, wo, temperature: float, D: Arrowhead) -> None:
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


def _total(model: FrameModel, wc: np.ndarray, wo: np.ndarray, temperature: float) -> float:
    cams, objs = FrameCoords(model).from_work(wc[None], wo[None])
    return float(model.map_objective(cams, objs, temperature)[0])


def _newton(model: FrameModel, wc, wo, temperature: float, max_iter: int = 60, tol: float = 1e-7):
    """Levenberg–Marquardt on the arrowhead system; returns (wc, wo, value, iterations)."""
    f = _total(model, wc, wo, temperature)
    lam = 1e-3
    it = 0
    for it in range(1, max_iter + 1):
        D = derivatives(model, wc, wo, temperature)
        improved = False
        for _ in range(12):
            step = D.solve(lam * (1.0 + np.abs(D.H_cc).max()) * 1e-6 + lam)
            if step is None:
                lam *= 10.0
                continue
            dc, do = step
            dc = np.clip(dc, -0.5, 0.5)
            do = np.clip(do, -0.5, 0.5)
            nc, no = wc + dc, wo + do
            fn = _total(model, nc, no, temperature)
            if np.isfinite(fn) and fn < f:
                improved = True
                done = f - fn < tol * max(1.0, abs(f))
                wc, wo, f = nc, no, fn
                lam = max(lam / 5.0, 1e-9)
                break
            lam *= 8.0
        if not improved or done:
            break
    return wc, wo, f, it


def optimize_frame(model: FrameModel, *, temperature: float = 1.0, n_refine: int = 2) -> FrameMAP:
    """The frame's MAP (module docstring). Sets the model's handedness per object and its pilot."""
    t0 = time.perf_counter()
    candidates = []
    for cam in _camera_starts(model):
        cam, objs, hand, err = initial_objects(model, cam)
        model.handedness = hand.astype(float)
        value = float(model.map_objective(cam[None], objs[None], temperature)[0])
        candidates.append((value, err, cam, objs, hand))
    candidates.sort(key=lambda c: (not np.isfinite(c[0]), c[0] if np.isfinite(c[0]) else c[1]))
    best = None
    iters = refined = 0
    sigma = model.sigma.copy()
    for value, err, cam, objs, hand in candidates:
        if refined >= n_refine and best is not None and np.isfinite(best[0]):
            break
        model.handedness = hand.astype(float)
        wc, wo = (a[0] for a in FrameCoords(model).to_work(cam[None], objs[None]))
        if np.any(sigma < _SMOOTH_SIGMA_PX):  # continuation: a smoother cost first (far from the
            model.sigma = np.maximum(sigma, _SMOOTH_SIGMA_PX)  # optimum a tiny σ leaves only t-tails)
            wc, wo, f, it = _newton(model, wc, wo, temperature)
            model.sigma = sigma
            iters += it
        wc, wo, f, it = _newton(model, wc, wo, temperature)
        iters += it
        refined += 1
        if best is None or f < best[0]:
            best = (f, wc, wo, hand)
    f, wc, wo, hand = best
    if not np.isfinite(f):
        raise RuntimeError(f"no start of the frame's optimiser reached a finite posterior density "
                           f"({len(candidates)} starts tried)")
    model.handedness = hand.astype(float)
    cams, _ = FrameCoords(model).from_work(wc[None], wo[None])
    if len(model.references):
        model.set_pilot(cams[0])
        wc, wo, f, it = _newton(model, wc, wo, temperature)
        iters += it
    D = derivatives(model, wc, wo, temperature)
    cams, objs = FrameCoords(model).from_work(wc[None], wo[None])
    objs[0, :, 2] = (objs[0, :, 2] + np.pi) % (2 * np.pi) - np.pi
    return FrameMAP(cams[0], objs[0], hand, f, D,
                    {"iterations": iters, "starts": len(candidates), "seconds": time.perf_counter() - t0})
