"""The log-posterior over a model's free parameters (method.md §7), on NumPy only.

    log p(s, µ | annotations) = −cost′(s, µ) / T + log prior(s, µ)

with the prior uniform inside the model's :class:`~creference_bayes.models.params.Bounds` (so log prior is 0 inside and
−∞ outside) and T a temperature. Yaw is circular: the cost depends on it through sin and cos
only, so the model's bounds never bound it. On the real line a circular density is periodic and
its total mass infinite: a sampler left to move yaw freely, where the annotations hardly fix it
(one set of lines on a few pixels), diffuses over ever more turns, and an ensemble's moves, which
scale with the walkers' spread, make that spread grow geometrically (10²¹ rad was seen), which
ruins the whitening and the autocorrelation times of every other parameter. ``yaw_center``
therefore cuts the circle open at the antipode of a given yaw (the MAP's): the density lives on
(yaw_center − π, yaw_center + π], which is the same distribution on the circle, and summaries
wrap it as before. A known focal length fixes µ: the posterior is then over the model's free
parameters only (``model.free``).

The posterior conditions on one handedness of the dimension lines, the MAP's: the two are
separate models (no yaw turns one into the other), and the MAP picks the one that fits.

Every non-finite cost (NaN, ±∞, overflow) becomes a log-density of −∞, never an exception, so a
sampler simply rejects such states. States with a box corner behind the camera keep a finite
but enormous cost (``cost.BEHIND_CAMERA_PENALTY`` per metre), which is as good as impossible.

The module also gives a Laplace approximation at the MAP (:func:`laplace_scales`): a
finite-difference Hessian taken at the posterior's own scale, which starts the sampler.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.params import CIRCULAR, N_PARAMS, PARAM_NAMES, YAW

__all__ = ["DEFAULT_TEMPERATURE", "LogPosterior", "Reparametrised", "Laplace", "laplace_scales"]

#: The temperature T of log p = −cost′/T + log prior. One constant so that a calibration
#: (the benchmark's coverage study) can change the default in one place.
DEFAULT_TEMPERATURE = 1.0

#: Fallback per-parameter scales (x, y, z m; yaw rad; µ px; pitch, roll rad) when the cost gives
#: no curvature.
_FALLBACK_SCALE = np.array([0.1, 0.05, 0.2, 0.05, 20.0, 0.01, 0.01])


@dataclass(frozen=True)
class LogPosterior:
    """Vectorised log-posterior of one model, over its free parameters.

    Parameters
    ----------
    model : a model with ``cost((n, 7)) → (n,)``, ``bounds``, ``free`` and ``expand`` (for
        example :class:`~creference_bayes.models.paper.PaperModel`)
    temperature : T > 0; larger T widens the posterior
    yaw_center : rad, or None: yaw is confined to (yaw_center − π, yaw_center + π] (the circle
        cut open opposite this yaw; module docstring); None leaves it unbounded (for optimisers
        and local curvature)

    Calling it with an (n, n_free) array returns the (n,) log-densities (unnormalised).
    """

    model: object
    temperature: float = DEFAULT_TEMPERATURE
    yaw_center: float | None = None

    def __post_init__(self):
        t = self.temperature
        if isinstance(t, bool) or not (isinstance(t, (int, float, np.floating)) and np.isfinite(t) and t > 0):
            raise ValueError(f"temperature: expected a finite number > 0, got {t!r}")
        # bounds of the free parameters; yaw (circular) unbounded, or one turn around yaw_center
        c = self.yaw_center
        if c is not None and not (isinstance(c, (int, float, np.floating)) and np.isfinite(c)):
            raise ValueError(f"yaw_center: expected a finite angle in radians or None, got {c!r}")
        circular = np.isin(np.arange(N_PARAMS), CIRCULAR)
        lo = np.where(circular, -np.inf if c is None else c - np.pi, self.model.bounds.lower)[self.free]
        hi = np.where(circular, np.inf if c is None else c + np.pi, self.model.bounds.upper)[self.free]
        object.__setattr__(self, "_lo", lo)
        object.__setattr__(self, "_hi", hi)

    @property
    def free(self) -> np.ndarray:
        """(7,) bool: which of (x, y, z, yaw, µ, pitch, roll) are sampled."""
        return np.asarray(self.model.free, bool)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in the order of the sampled vector."""
        return tuple(n for n, f in zip(PARAM_NAMES, self.free) if f)

    @property
    def ndim(self) -> int:
        return int(self.free.sum())

    @property
    def yaw_index(self) -> int | None:
        """Position of yaw in the free vector, or None when yaw is fixed."""
        return int(self.free[:YAW].sum()) if self.free[YAW] else None

    def in_support(self, free_params: np.ndarray) -> np.ndarray:
        """(n,) bool: finite and inside the bounds (yaw unbounded, or within a turn of
        ``yaw_center``)."""
        p = np.atleast_2d(np.asarray(free_params, float))
        return np.all((p >= self._lo) & (p <= self._hi) & np.isfinite(p), axis=1)

    def __call__(self, free_params: np.ndarray) -> np.ndarray:
        p = np.atleast_2d(np.asarray(free_params, float))
        out = np.full(len(p), -np.inf)
        ok = self.in_support(p)
        if ok.any():
            q = p if ok.all() else p[ok]
            with np.errstate(all="ignore"):
                cost = np.asarray(self.model.cost(self.model.expand(q)), float)
                lp = -cost / self.temperature
            out[ok] = np.where(np.isfinite(lp), lp, -np.inf)
        return out


@dataclass(frozen=True)
class Reparametrised:
    """A log-posterior in other coordinates q = forward(p): log p(inverse(q)) + log |∂p/∂q|.

    ``coords`` has ``forward``, ``inverse`` and ``log_jacobian`` over (n, n_free) arrays (e.g.
    :class:`~creference_bayes.models.coordinates.HorizonDistance`). Non-finite values, from
    coordinates outside the map's domain, give −∞.
    """

    log_post: LogPosterior
    coords: object

    @property
    def free(self) -> np.ndarray:
        return self.log_post.free

    def __call__(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, float))
        with np.errstate(all="ignore"):
            out = self.log_post(self.coords.inverse(q)) + self.coords.log_jacobian(q)
        return np.where(np.isfinite(out), out, -np.inf)


@dataclass(frozen=True)
class Laplace:
    """A Gaussian approximation of the posterior at a point.

    Attributes
    ----------
    center : (n_free,) the MAP's free parameters
    cov : (n_free, n_free) covariance (−Hessian of log p)⁻¹, or a diagonal fallback
    scale : (n_free,) √diag(cov)
    positive_definite : whether the finite-difference Hessian was positive definite
    """

    center: np.ndarray
    cov: np.ndarray
    scale: np.ndarray
    positive_definite: bool


def laplace_scales(log_post: LogPosterior, center: np.ndarray, *, target_drop: float = 0.5,
                   max_halvings: int = 40) -> Laplace:
    """Laplace approximation of ``log_post`` at ``center`` by finite differences.

    The cost has kinks (the |‖t‖ − ‖C‖| terms of Eq. 5 are an absolute value), so an
    infinitesimal step would measure the curvature of a kink, not the posterior's width. Instead,
    each parameter's step hᵢ is found by a line search so that log p falls by about
    ``target_drop`` along that axis (a conditional half-width), and the Hessian is the secant
    Hessian at those steps. When it is not positive definite (or not finite), the covariance falls
    back to the diagonal (hᵢ/√(2·drop))², the conditional variances along the axes.

    Parameters
    ----------
    log_post : the log-posterior
    center : (n_free,) the point, normally the MAP's free parameters

    Returns
    -------
    Laplace
    """
    x0 = np.asarray(center, float)
    f0 = float(log_post(x0)[0])
    fallback = _FALLBACK_SCALE[log_post.free] * np.maximum(1.0, 0.05 * np.abs(x0))
    if not np.isfinite(f0):
        return Laplace(x0, np.diag(fallback**2), fallback, False)
    h = _axis_steps(log_post, x0, f0, fallback, target_drop, max_halvings)
    H = _secant_hessian(log_post, x0, f0, h)
    if not np.all(np.isfinite(H)):  # a step left the support: near a bound, shorter steps
        inside = _steps_inside(log_post, x0, h)
        if inside is not None:
            H = _secant_hessian(log_post, x0, f0, inside)
    try:
        cov = np.linalg.inv(-H)
        np.linalg.cholesky(cov)
        ok = bool(np.all(np.isfinite(cov)))
    except np.linalg.LinAlgError:
        ok = False
    if not ok:
        cov = np.diag((h / np.sqrt(2.0 * target_drop)) ** 2)
    return Laplace(x0, cov, np.sqrt(np.diag(cov)), ok)


def _axis_steps(log_post, x0, f0, start, drop, max_halvings) -> np.ndarray:
    """Per-axis step where log p has fallen by about ``drop`` (both directions, the smaller).

    A side that leaves the support (log p = −∞: a MAP on the box's bound) says nothing about the
    width and is ignored; the step is then the inner side's. Taking the smaller there shrank the
    step to the 1e-6 of the box by which a MAP on its bound is moved inside, the sampler started
    from a cloud that thin along the ridge, and its warm-up crawled down the ridge for thousands
    of steps (SBC thin scene 12: a MAP at the 60 m bound, a posterior over 34–60 m).

    An axis along which log p never fell by ``drop``/4 inside the support (every step long enough
    to measure a width left it: a MAP in a corner of the support, where only a combination of
    parameters stays inside) keeps at least its ``start`` scale: its width was not measured, and
    the step shrunk to the corner's 1e-6 started the ensemble flat along it (SBC full scene 27:
    a MAP at the roll bound, 1800 warm-up steps instead of 400)."""
    n = len(x0)
    h = start.copy()
    measured = np.zeros(n, bool)
    for _ in range(max_halvings):  # vectorised bracketing: grow or shrink all axes at once
        pts = np.vstack([x0 + np.diag(h), x0 - np.diag(h)])
        lp = log_post(pts)
        inside = lp > -np.inf
        fall = np.where(inside, f0 - lp, -np.inf)
        fall = np.maximum(fall[:n], fall[n:])  # the steeper side inside the support
        fall = np.where(np.isfinite(fall), fall, np.inf)  # NaN, or neither side inside: shrink
        too_far = fall > 4.0 * drop
        too_near = fall < 0.25 * drop
        measured |= np.isfinite(fall) & ~too_near
        if not (too_far.any() or too_near.any()):
            break
        h = np.where(too_far, h / 2.0, np.where(too_near, h * 2.0, h))
    return np.where(measured, h, np.maximum(h, start))


def _steps_inside(log_post, x0, h, max_halvings: int = 6) -> np.ndarray | None:
    """``h`` halved on each axis whose ±step leaves the support until both stay inside, or None
    when that takes more than ``max_halvings`` (the point is on a bound, not near one).

    :func:`_axis_steps` measures a width on the inner side alone, so its step can reach past a
    bound the MAP is near; the central differences of the Hessian would then straddle it. A MAP
    0.3 m inside a bound kept its full Hessian before that rule (steps shrunk to fit) and must
    keep it (tests/test_posterior.py)."""
    n = len(x0)
    h = np.asarray(h, float).copy()
    for _ in range(max_halvings + 1):
        lp = log_post(np.vstack([x0 + np.diag(h), x0 - np.diag(h)]))
        out = ~((lp[:n] > -np.inf) & (lp[n:] > -np.inf))
        if not out.any():
            return h
        h = np.where(out, h / 2.0, h)
    return None


def _secant_hessian(log_post, x0, f0, h) -> np.ndarray:
    """Central-difference Hessian of log p with per-axis steps ``h`` (one batched call). Entries
    from points of zero density are non-finite; the caller then falls back to the diagonal."""
    n = len(x0)
    E = np.diag(h)
    pts = [x0 + E, x0 - E]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    for i, j in pairs:
        pts += [x0 + E[i] + E[j], x0 - E[i] - E[j]]
    f = log_post(np.vstack(pts))
    fp, fm = f[:n], f[n:2 * n]
    with np.errstate(invalid="ignore", over="ignore"):  # −∞ − (−∞): NaN, handled by the caller
        H = np.diag((fp + fm - 2.0 * f0) / h**2)
        for k, (i, j) in enumerate(pairs):
            fpp, fmm = f[2 * n + 2 * k], f[2 * n + 2 * k + 1]
            # f(x+ei+ej) + f(x−ei−ej) − 2 f0 = h_i² H_ii + h_j² H_jj + 2 h_i h_j H_ij
            H[i, j] = H[j, i] = (fpp + fmm - 2.0 * f0 - H[i, i] * h[i]**2 - H[j, j] * h[j]**2) / (2.0 * h[i] * h[j])
    return H
