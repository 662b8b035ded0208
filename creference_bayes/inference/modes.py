"""Finding a posterior's separate modes before sampling it, and a mixture fitted around them.

Heavy-tailed corners let one corner be given up as an outlier and the target move along its
viewing ray, so the posterior can have a second mode that a sampler started at the MAP misses
while every check passes. :func:`find_modes` (the whole vector: explore the tempered density,
climb, merge, weigh by Laplace mass) and :func:`object_modes` (each object given the MAP's
camera) are described in docs/inference.md ("Modes first").
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp

from ..models.contract import O_YAW
from .ensemble import explore
from .map import _newton, derivatives, initial_objects, other_handedness
from .reparam import Coordinates

__all__ = ["Mode", "find_modes", "object_modes", "mode_rows"]

#: Two local maxima closer than this (in the MAP's Laplace-whitened units) are one mode.
SAME_MODE = 1.0
#: Two maxima with no dip deeper than this (nats) on the line between them are one mode.
VALLEY = 0.5
#: Modes whose Laplace mass is under this share of the total are dropped.
MIN_SHARE = 1e-3
#: At most this many modes are kept (the heaviest).
MAX_MODES = 4
#: A set of dimension lines whose corners miss the MAP's by more than this many times the best
#: set's miss (+ 1 px), RMS, may be another reading of its object (:func:`object_modes`).
OUTLIER_SET = 4.0
#: Local maxima more than this many nats below the best are not weighed.
MAX_DROP = 25.0
#: An object's other handedness is sampled too when its optimum comes within this many nats of
#: the MAP's (given the MAP's camera for an object of a frame, :func:`object_modes`; the whole
#: vector's for one object block, :mod:`.whole`).
MIX_MARGIN = 12.0


@dataclass(frozen=True)
class Mode:
    """One local maximum of the log-density: ``center`` (d,), its Laplace covariance ``cov``
    (d, d), the log-density there and its estimated share of the posterior mass (0–1)."""

    center: np.ndarray
    cov: np.ndarray
    log_prob: float
    share: float
    #: (k, 5) how the centre moves with the camera's working coordinates (an object's mode given
    #: the camera, :func:`object_modes`), or None
    shear: np.ndarray | None = None
    #: whether the mode is at its object's other handedness (:func:`object_modes`)
    flipped: bool = False


def find_modes(log_prob, center, cov, *, laplace, rng, circular=None,
               temperature: float = 3.0, n_steps: int = 150, n_walkers: int = 32,
               n_climbs: int = 8, extra_starts=None) -> list[Mode]:
    """The posterior's modes, the one at ``center`` first, then by decreasing share (docs/inference.md,
    "One object block"): a tempered exploration (:func:`.ensemble.explore`: ``temperature``,
    ``n_steps``, ``n_walkers``), ``n_climbs`` L-BFGS-B climbs from spread points of it and from
    ``extra_starts`` (k, d), maxima merged (:func:`_same_modes`) and weighed by Laplace mass.

    ``log_prob``: (n, d) → (n,) (−∞ outside the support); ``center``, ``cov``: the MAP and its
    Laplace covariance; ``laplace``: a point (d,) → its Laplace covariance; ``circular``: indices of
    angles (wrapped to within π of the MAP) or None.
    """
    center = np.asarray(center, float)
    d = len(center)
    coords = Coordinates.affine(center, cov)
    u, lp_u = explore(log_prob, coords, rng, temperature=temperature, n_steps=n_steps,
                      n_walkers=n_walkers)
    starts = list(_spread(u, lp_u, n_climbs))
    if extra_starts is not None and len(extra_starts):  # other optima known already (the MAP's)
        starts += list(coords.forward(np.atleast_2d(np.asarray(extra_starts, float))))

    def neg(uu):  # −log p in the whitened coordinates
        with np.errstate(all="ignore"):
            v = log_prob(coords.inverse(np.atleast_2d(uu)))
        return np.where(np.isfinite(v), -v, 1e300)

    found = [np.zeros(d)] + _climbs(neg, starts)
    p_found = coords.inverse(np.array(found))
    if circular is not None:  # the same state, one turn away: bring it next to the MAP
        k = np.asarray(circular, int)
        p_found[:, k] = center[k] + (p_found[:, k] - center[k] + np.pi) % (2 * np.pi) - np.pi
    lp = np.asarray(log_prob(p_found), float)
    u_found = coords.forward(p_found)
    keep: list[int] = [0]
    seen = [0]  # the maxima merged or kept so far
    for i in np.argsort(-lp):
        if i == 0 or not np.isfinite(lp[i]) or lp[i] < lp[0] - MAX_DROP:
            continue
        near_seen = np.min(np.linalg.norm(u_found[seen] - u_found[i], axis=1)) <= SAME_MODE
        if not near_seen and not _same_modes(neg, u_found[i], u_found[keep]):
            keep.append(int(i))
        seen.append(int(i))
    return _weighed([(p_found[i] if i else center, cov if i == 0 else np.asarray(laplace(p_found[i]), float),
                      lp[i], None) for i in keep], np.ones(d, bool))


def _weighed(found, free: np.ndarray, most: int = MAX_MODES) -> list[Mode]:
    """:class:`Mode` s of maxima (centre, Laplace covariance or None, log-density, shear[, whether
    at the other handedness]), the MAP's first: each weighed by its Laplace mass over the ``free``
    coordinates (none without a positive-definite covariance, e.g. a maximum on a bound); the MAP's
    and at most ``most`` − 1 others by decreasing share, those under :data:`MIN_SHARE` dropped."""
    log_mass = []
    for _, c, lp, *_ in found:
        sign, logdet = np.linalg.slogdet(c[np.ix_(free, free)]) if c is not None else (0.0, 0.0)
        log_mass.append(lp + 0.5 * logdet if sign > 0 else -np.inf)
    log_mass = np.array(log_mass)
    finite = np.isfinite(log_mass)
    if finite.any():
        shares = np.where(finite, np.exp(np.where(finite, log_mass, 0.0) - logsumexp(log_mass[finite])), 0.0)
    else:
        shares = (np.arange(len(found)) == 0).astype(float)
    out = [Mode(x, c, float(lp), float(w), *rest) for (x, c, lp, *rest), w in zip(found, shares)]
    rest = sorted((k for k in out[1:] if k.share >= MIN_SHARE and np.isfinite(k.log_prob)), key=lambda k: -k.share)
    return [out[0]] + rest[:most - 1]


def _same_modes(neg, a: np.ndarray, bs: np.ndarray) -> bool:
    """Whether the maximum ``a`` is one mode with any of the maxima ``bs`` (k, d): close
    (:data:`SAME_MODE`), or no valley deeper than :data:`VALLEY` nats between them, on the straight
    line (in the whitened coordinates) or, where that line leaves a curved ridge, on the path
    through each intermediate cross-section's own maximum (:func:`_pass_heights`); every line's and
    every path's evaluations of ``neg`` made together."""
    bs = np.atleast_2d(bs)
    if np.any(np.linalg.norm(bs - a, axis=1) <= SAME_MODE):
        return True
    t = np.linspace(0.0, 1.0, 7)[:, None]
    v = neg(np.concatenate([a + t * (b - a) for b in bs])).reshape(len(bs), len(t))
    floor = np.maximum(v[:, 0], v[:, -1])
    if np.any(np.max(v[:, 1:-1], axis=1) <= floor + VALLEY):
        return True
    return bool(np.any(_pass_heights(neg, a, bs) <= floor + VALLEY))


def _pass_heights(neg, a: np.ndarray, bs: np.ndarray, n: int = 5) -> np.ndarray:
    """The highest −log p met on the way from ``a`` to each of ``bs`` (k, d) along a bending path:
    the largest, over n evenly spaced planes orthogonal to the segment, of the least −log p in each
    plane (maxima along one curved ridge see a "valley" on the straight line that is only its bend;
    a true valley stays deep in every plane). All k · n planes are climbed together (:func:`_climbs`).
    """
    planes = []
    for b in bs:
        e = (b - a) / np.linalg.norm(b - a)
        basis = np.linalg.svd(np.eye(len(a)) - np.outer(e, e))[0][:, :len(a) - 1]  # ⟂ e
        planes += [(a + t * (b - a), basis) for t in np.linspace(0.0, 1.0, n + 2)[1:-1]]
    through = [lambda y, p0=p0, basis=basis: p0 + np.atleast_2d(y) @ basis.T for p0, basis in planes]
    ys = _climbs(neg, np.zeros((len(planes), len(a) - 1)), through)
    v = neg(np.array([f(y)[0] for f, y in zip(through, ys)]))
    return v.reshape(len(bs), n).max(axis=1)


def _spread(u: np.ndarray, lp: np.ndarray, k: int) -> np.ndarray:
    """k points of ``u`` far apart (farthest-point sampling from the highest), taken from its
    better half by log-density."""
    good = u[lp >= np.quantile(lp, 0.5)]
    g_lp = lp[lp >= np.quantile(lp, 0.5)]
    idx = [int(np.argmax(g_lp))]
    dist = np.linalg.norm(good - good[idx[0]], axis=1)
    for _ in range(min(k, len(good)) - 1):
        j = int(np.argmax(dist))
        idx.append(j)
        dist = np.minimum(dist, np.linalg.norm(good - good[j], axis=1))
    return good[idx]


def _climb(neg, u0: np.ndarray, h: float = 1e-5) -> np.ndarray:
    """A local minimum of ``neg`` from ``u0`` (L-BFGS-B, central differences in one call)."""
    d = len(u0)
    E = h * np.eye(d)

    def fg(u):
        v = neg(np.vstack([u, u + E, u - E]))
        g = (v[1:d + 1] - v[d + 1:]) / (2 * h)
        return float(v[0]), np.where(np.isfinite(g) & (np.abs(g) < 1e200), g, 0.0)

    with np.errstate(all="ignore"):
        res = minimize(fg, u0, jac=True, method="L-BFGS-B", options={"maxiter": 100, "ftol": 1e-7, "gtol": 1e-4})
    return res.x if np.isfinite(res.fun) and res.fun <= fg(u0)[0] else u0


class _Gathered:
    """Evaluations of a vectorised ``f`` asked for by ``n`` threads, made together: a round's call
    waits until every thread still running has asked (one call costs about as much for one point
    as for hundreds)."""

    def __init__(self, f, n: int):
        self.f, self.running, self.asked, self.answers = f, n, {}, {}
        self.cv = threading.Condition()
        self.stopped = False

    def ask(self, k: int, x: np.ndarray) -> np.ndarray:
        with self.cv:
            self.asked[k] = x
            self._answer()
            while k not in self.answers and not self.stopped:
                self.cv.wait()
            out = self.answers.pop(k, None)
        if self.stopped:
            raise _Stopped
        if isinstance(out, BaseException):
            raise out
        return out

    def stop(self) -> None:
        """Every thread's next (or pending) ask raises :class:`_Stopped` (the caller was interrupted)."""
        with self.cv:
            self.stopped = True
            self.cv.notify_all()

    def leave(self) -> None:
        with self.cv:
            self.running -= 1
            self._answer()

    def _answer(self) -> None:
        if not self.asked or len(self.asked) < self.running:
            return
        keys = sorted(self.asked)
        xs = [self.asked.pop(k) for k in keys]
        try:
            with np.errstate(all="ignore"):
                v = np.asarray(self.f(np.concatenate(xs)), float)
            parts = np.split(v, np.cumsum([len(x) for x in xs])[:-1])
        except BaseException as exc:  # every thread waiting gets it
            parts = [exc] * len(keys)
        self.answers.update(zip(keys, parts))
        self.cv.notify_all()


def _climbs(neg, starts, through=None) -> list[np.ndarray]:
    """:func:`_climb` from each of ``starts`` (k, d'), in lockstep: the climbs run in threads whose
    evaluations of ``neg`` are gathered into one vectorised call a round (:class:`_Gathered`), so
    the same maxima cost a few calls instead of one per climb's step. ``through``: per start, the
    map (n, d') → (n, d) from its coordinates to those of ``neg`` (None: the same)."""
    starts = list(np.atleast_2d(starts)) if len(starts) else []
    through = through or [lambda x: np.atleast_2d(x)] * len(starts)
    if len(starts) <= 1:
        return [_climb(lambda x, f=f: neg(f(x)), s) for s, f in zip(starts, through)]
    gathered = _Gathered(neg, len(starts))

    def one(k):
        try:
            return _climb(lambda x: gathered.ask(k, through[k](x)), starts[k])
        finally:
            gathered.leave()

    pool = ThreadPoolExecutor(len(starts))
    try:
        futures = [pool.submit(one, k) for k in range(len(starts))]
        return [f.result() for f in futures]
    except BaseException:  # an interrupt, or a climb's error: the other climbs stop too
        gathered.stop()
        raise
    finally:
        pool.shutdown(wait=True)


class _Stopped(Exception):
    """A lockstep climb stopped because another failed or the caller was interrupted."""


def object_modes(target, wc0: np.ndarray, wo0: np.ndarray, Ao: np.ndarray, temperature: float,
                 max_sets: int = 8) -> list[list[Mode]]:
    """Each object's modes given the MAP's camera (docs/inference.md, "Several object blocks").

    For the k-th set of dimension lines (k < ``max_sets``) of the objects whose k-th set misses
    the MAP's corners by more than :data:`OUTLIER_SET` × (their best set's miss + 1 px), RMS, each
    is placed from that set alone and all are climbed together, the camera held; an end point
    apart from the modes kept (:func:`_same_modes`, in the units of ``Ao`` (m, 7, 7), each object's
    Laplace covariance given the camera) is a new mode, weighed by its Laplace mass given the
    camera. Each object's optimum at its other handedness (:func:`_other_hands`) within
    :data:`MIX_MARGIN` nats of the MAP's is a mode too (``flipped``). ``target`` is the
    :class:`~.moves.BlockTarget` (unsheared at ``wc0``), (wc0 (5,), wo0 (m, 7)) the MAP in working
    coordinates.

    Returns per object its modes, the MAP's first (:class:`Mode`: centre (7,), covariance (7, 7)
    and ``shear`` (7, 5), the centre's regression on the camera).
    """
    model, coords = target.model, target.coords
    m, of = model.n_objects, model.object_free
    cams, objs = coords.from_work(wc0[None], wo0[None])
    cam = cams[0]
    held = model.variant(camera_free=np.zeros(5, bool))
    uv = model.project(cams, objs)[0][0]  # (m, 4, 2) the MAP's corners
    K = min(max_sets, max(len(o.annotations) for o in model.objects))
    miss = np.full((m, K), np.nan)  # each set's RMS distance from them, px
    for i, o in enumerate(model.objects):
        a = o.annotations[:K]
        miss[i, :len(a)] = np.sqrt(np.mean(np.sum((a - uv[i]) ** 2, axis=-1), axis=-1))
    with np.errstate(invalid="ignore"):
        apart = miss > OUTLIER_SET * (np.nanmin(miss, axis=1, keepdims=True) + 1.0)
    ends = []
    for k in np.flatnonzero(apart.any(axis=0)):
        has = apart[:, k]
        corners = np.array([o.annotations[min(k, len(o.annotations) - 1)] for o in model.objects])
        placed = initial_objects(model, cam, handedness=model.handedness, keep_camera=True, corners=corners)[1]
        wo = np.where(has[:, None], coords.to_work(cam[None], placed[None])[1][0], wo0)
        if not np.all(np.isfinite(wo[has])):
            continue
        _, end, _, _ = _newton(held, wc0, wo, temperature)
        end[:, O_YAW] = wo0[:, O_YAW] + (end[:, O_YAW] - wo0[:, O_YAW] + np.pi) % (2 * np.pi) - np.pi
        ends.append(np.where(has[:, None], end, np.nan))
    wc = wc0[None]
    other, wo_f, lp_f, flips = _other_hands(target, wc0, wo0, temperature)
    D_f = None

    def own(i, x):  # object i's log-density given the camera at states x (n, 7), the others at the MAP
        wt = np.repeat(wo0[None], len(x), axis=0)
        wt[:, i] = x
        return target.objects(np.repeat(wc, len(x), axis=0), wt)[0][:, i]

    out = []
    for i in range(m):
        free = of[i]
        L = np.linalg.cholesky(Ao[i][np.ix_(free, free)])
        whiten = lambda x, i=i, L=L, free=free: np.linalg.solve(L, (np.atleast_2d(x) - wo0[i])[:, free].T).T  # noqa: E731

        def neg(z, i=i, L=L, free=free):  # −log p of object i in its whitened coordinates
            x = np.repeat(wo0[i][None], len(np.atleast_2d(z)), axis=0)
            x[:, free] += np.atleast_2d(z) @ L.T
            v = own(i, x)
            return np.where(np.isfinite(v), -v, 1e300)

        found = [wo0[i]]
        for e in ends:
            x = e[i]
            if np.all(np.isfinite(x)) and not _same_modes(neg, whiten(x)[0], whiten(np.array(found))):
                found.append(x)
        lp = own(i, np.array(found))
        modes = [(wo0[i], Ao[i], lp[0], None)]
        for x, v in zip(found[1:], lp[1:]):
            wo = wo0.copy()
            wo[i] = x
            c, b = _given_camera(derivatives(model, wc0, wo, temperature, with_jacobian=True), free, i)
            modes.append((x, c, v, b))
        if flips[i]:  # the other handedness's optimum (every object's there: one set of derivatives)
            if D_f is None:
                D_f = derivatives(other, wc0, wo_f, temperature, with_jacobian=True)
            c, b = _given_camera(D_f, free, i)
            modes.append((wo_f[i], c, lp_f[i], b, True))
        out.append(_weighed(modes, free))
    return out


def _given_camera(D, free: np.ndarray, i: int):
    """Object i's Laplace covariance given the camera (7, 7) from the derivatives ``D`` at a state
    (:func:`~.map.derivatives`; ``free`` (7,) its free coordinates) and its shear (7, 5) (how its
    centre moves with the camera); (None, None) where the density has no maximum there (no
    Laplace mass)."""
    c = np.zeros((7, 7))
    try:
        np.linalg.cholesky(D.H_oo[i][np.ix_(free, free)])
        c[np.ix_(free, free)] = np.linalg.inv(D.H_oo[i][np.ix_(free, free)])
    except np.linalg.LinAlgError:
        return None, None
    return c, -c @ D.H_co[i].T


def _other_hands(target, wc0: np.ndarray, wo0: np.ndarray, temperature: float):
    """Every object at its other handedness, given the MAP's camera: the model there, the optimum
    (m, 7) in working coordinates (:func:`~.map.other_handedness`), each object's log-density there
    given the camera (m,) and whether it is within :data:`MIX_MARGIN` nats of the MAP's (m,)."""
    model = target.model
    m = model.n_objects
    _, wo, _ = other_handedness(model, wc0, wo0, temperature)
    with np.errstate(all="ignore"):
        lp = target.objects(wc0[None], wo[None], np.ones((1, m), bool))[0][0]
        lp0 = target.objects(wc0[None], wo0[None])[0][0]
    return model.variant(handedness=-model.handedness), wo, lp, np.isfinite(lp) & (lp > lp0 - MIX_MARGIN)


def mode_rows(target_id, objs: np.ndarray, lp, modes, near: np.ndarray) -> list[dict]:
    """A row per mode (``objs`` (k, 7) the object's natural parameters there, ``lp`` (k,) the
    log-density, ``near`` (chain, draw) each draw's nearest mode): the object's id, distance and
    yaw, how far below the MAP's the mode's log-density is, its Laplace share of the mass and the
    share of each chain's draws nearest to it (they should agree)."""
    return [{"target": target_id, "distance_m": float(np.hypot(objs[k, 0], objs[k, 1])), "yaw": float(objs[k, O_YAW]),
             "log_density_below_map": float(lp[0] - lp[k]), "laplace_share": float(mode.share),
             "draw_share_per_chain": [float(np.mean(g == k)) for g in near]} for k, mode in enumerate(modes)]
