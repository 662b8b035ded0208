"""MAP estimation: the paper's basin hopping (preset ``paper``) and a better default.

Presets
-------
``paper``
    The system study's optimiser (paper §5.1.1, §6.1, §7.1): L-BFGS-B (``ftol`` 1e-8, SciPy's
    finite-difference gradient) inside monotonic basin hopping (T = 0: a new minimum is kept only
    when it is the lowest seen) whose steps are uniform random restarts within the bounds;
    200 restarts, bounds −10≤x≤10, −5≤y≤5, 1≤z≤50, −π≤θ≤π, 100≤µ≤3000. The paper has one
    corner convention; here the restarts are split evenly between the two handednesses so that the
    total work is the paper's.
``paper-controlled``
    The same with the controlled study's 100 restarts and bounds (paper §6.1).
``default``
    A global start (:func:`theta_scan`: for every yaw on a 1° grid and both handednesses, the
    projection equations are linear in (µx', µy', z', µ), method.md §6; pitch from the horizon
    depends on µ, so the solve is iterated a few times; when pitch and roll are free parameters,
    the scan runs on a 5° yaw grid for every (pitch, roll) of :data:`ORIENTATION_GRID_DEG`), then,
    from the best few starts, a Levenberg–Marquardt-style reprojection fit and an L-BFGS-B
    refinement of the model's cost with a vectorised central-difference gradient, over wide
    bounds.

Models with a pilot (the metrology model's reference scales, fixed at a pilot estimate) get it set
at each handedness's first optimum, and are refined once more from there with it.
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import basinhopping, least_squares, minimize

from ..core.cost import reprojection_residuals
from ..io.result import MapEstimate
from ..models.params import YAW, Bounds, wrap_angle
from .newton import trust_newton
from .scan import best_per_pitch, pick_starts, scan, theta_scan

__all__ = ["PRESETS", "SKIP_MARGIN", "optimize_map", "theta_scan", "preset_bounds"]

PRESETS = ("default", "paper", "paper-controlled")
_PAPER_RESTARTS = {"paper": 200, "paper-controlled": 100}
#: Typical magnitude of each parameter, used to scale the optimiser's variables.
_SCALE = np.array([1.0, 1.0, 1.0, 1.0, 1000.0, 0.1, 0.1])


def preset_bounds(preset: str, image_width: int, image_height: int) -> Bounds:
    """The bounds a preset optimises within."""
    _check_preset(preset)
    if preset == "paper":
        return Bounds.paper_system()
    if preset == "paper-controlled":
        return Bounds.paper_controlled()
    return Bounds.default(image_width, image_height)


def _check_preset(preset: str) -> None:
    if preset not in PRESETS:
        raise ValueError(f"preset: unknown preset {preset!r} (expected one of {list(PRESETS)})")


class _Counter:
    """Wraps the cost a model's MAP minimises (``map_cost`` when it has one: the MAP in log
    coordinates, models/location_prior.py; else ``cost``) over free parameters and counts
    evaluations."""

    def __init__(self, model):
        self.model = model
        self.cost = getattr(model, "map_cost", model.cost)
        self.n = 0

    def __call__(self, free: np.ndarray) -> np.ndarray:
        free = np.atleast_2d(free)
        self.n += len(free)
        return self.cost(self.model.expand(free))

    def scalar(self, free: np.ndarray) -> float:
        return float(self(free)[0])


def optimize_map(models: Sequence, preset: str = "default", rng=None,
                 progress: Callable[[str], None] | None = None,
                 restarts: int | None = None, progress_bar: bool = False) -> MapEstimate:
    """Minimise the cost of each model (one per handedness) and keep the best.

    Parameters
    ----------
    models : models with ``cost``, ``bounds``, ``free``, ``expand``, ``handedness``, and for the
        default preset ``camera``, ``observed`` and ``obj_corners``
    preset : one of :data:`PRESETS`
    rng : seed or ``numpy.random.Generator`` (only the ``paper`` presets draw random numbers)
    restarts : total random restarts of the ``paper`` presets, split between the handednesses
        (None: the paper's 200 or 100); must be None for the default preset
    progress_bar : show a bar of the ``paper`` presets' restarts on standard error (the default
        preset takes a fraction of a second and has none)
    """
    _check_preset(preset)
    if restarts is not None:
        if preset == "default":
            raise ValueError("restarts: the default preset has no random restarts")
        if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
            raise ValueError(f"restarts: expected an integer >= 1, got {restarts!r}")
    rng = np.random.default_rng(rng)
    t0 = time.perf_counter()
    best, info, n_eval = None, {}, 0
    per_model = max(1, (_PAPER_RESTARTS.get(preset, 1) if restarts is None else restarts) // len(models))
    bar = None
    if progress_bar and preset != "default":
        from .progress import progress_bar as _bar

        bar = _bar(True, per_model * len(models), desc=f"{preset} restarts", unit="restart")

    def tick(*_) -> None:  # called for each local minimum, the first one included (SciPy ≥ 1.6);
        bar.update(1)  # basinhopping stops when its callback returns True: return None
    if preset == "default":
        runs = _default_all(models)
    else:
        runs = []
        for model in models:
            counter = _Counter(model)
            x, f, detail = _paper(model, counter, per_model, rng, callback=None if bar is None else tick)
            if hasattr(model, "set_pilot"):  # fix the model's pilot-dependent scales here, refine again
                model.set_pilot(model.expand(x)[0])
                x = _refine(model, counter, x, reprojection=False)
                f = counter.scalar(x)
                detail["pilot"] = True
            runs.append((model, x, f, detail, counter.n))
    for model, x, f, detail, n in runs:
        n_eval += n
        info[f"handedness_{model.handedness:+d}"] = {"cost": f, **detail}
        if best is None or f < best[1]:
            best = (model, f, x)
        if progress:
            progress(f"handedness {model.handedness:+d}: cost {f:.4f}")
    if bar is not None:
        bar.close()
    model, f, x = best
    params = model.expand(x)[0]
    params[YAW] = wrap_angle(params[YAW])
    return MapEstimate(params=params, handedness=model.handedness, cost=float(f), preset=preset,
                       seconds=time.perf_counter() - t0, n_evaluations=n_eval, info=info)


# ------------------------------------------------------------------------------------------------
# the paper's optimiser


class _RandomRestart:
    """basinhopping step: a fresh uniform draw within the bounds (the paper's random restarts)."""

    def __init__(self, lo, hi, rng):
        self.lo, self.hi, self.rng = lo, hi, rng

    def __call__(self, x):
        return self.rng.uniform(self.lo, self.hi)


def _paper(model, counter: _Counter, restarts: int, rng, callback=None) -> tuple[np.ndarray, float, dict]:
    lo, hi = model.bounds.lower[model.free], model.bounds.upper[model.free]
    res = basinhopping(
        counter.scalar, rng.uniform(lo, hi), niter=restarts - 1, T=0.0,
        take_step=_RandomRestart(lo, hi, rng), rng=rng, callback=callback,
        minimizer_kwargs={"method": "L-BFGS-B", "bounds": list(zip(lo, hi)),
                          "options": {"ftol": 1e-8}},
    )
    return np.asarray(res.x), float(res.fun), {"restarts": restarts}


# ------------------------------------------------------------------------------------------------
# the default optimiser

#: A handedness whose best start costs this much more than the other's refined optimum is not
#: refined itself (its cost is then reported from its start, an upper bound).
SKIP_MARGIN = 25.0


def _default_all(models, n_starts: int = 3) -> list:
    """The default preset for every model (handedness): cheap fits from the scan's starts for all,
    then the full refinement of the best, and of another only when its best start comes within
    :data:`SKIP_MARGIN` of that optimum. Models with a pilot get it set at their best start,
    before the refinement. Returns (model, x, cost, detail, evaluations) per model."""
    prepared = []
    for k, model in enumerate(models):
        counter = _Counter(model)
        x, detail = _default_start(model, counter, n_starts)
        if hasattr(model, "set_pilot"):
            model.set_pilot(model.expand(x)[0])
            detail["pilot"] = True
        prepared.append((counter.scalar(x), k, model, counter, x, detail))
    prepared.sort(key=lambda item: item[0])
    runs, best_f = [], np.inf
    for f0, k, model, counter, x, detail in prepared:
        if f0 <= best_f + SKIP_MARGIN:
            x = _refine(model, counter, x, reprojection=False)
            f = counter.scalar(x)
            best_f = min(best_f, f)
        else:
            f, detail["refined"] = f0, False
        runs.append((k, (model, x, f, detail, counter.n)))
    return [run for _, run in sorted(runs, key=lambda r: r[0])]


def _default_start(model, counter: _Counter, n_starts: int) -> tuple[np.ndarray, dict]:
    """The best of the cheap fits from the scan's starts (free parameters) and what happened."""
    free = model.free
    cands = scan(model)
    finite = np.all(np.isfinite(cands), axis=1)
    lo, hi = model.bounds.lower, model.bounds.upper
    cands[finite] = np.clip(cands[finite], lo, hi)
    costs = np.full(len(cands), np.inf)
    costs[finite] = counter(cands[finite][:, free])
    starts = pick_starts(cands, costs, n_starts)
    if model.orientation_free:  # and the best candidate at every pitch of the grid: a far target
        starts += best_per_pitch(cands, costs, exclude=starts)  # pins its pitch only weakly
    if not starts:  # nothing usable from the scan: fall back to the centre of the bounds
        cands = np.array([np.where(np.isfinite(lo + hi), (lo + hi) / 2, 0.0)])
        cands[0, 2] = np.clip(10.0, lo[2], hi[2])
        starts = [0]
    # a cheap first fit from every start, and the model's full cost decides which one to refine:
    # a reprojection least-squares fit from the best few and, for smooth costs, a few Newton
    # steps on the cost itself from all. (With pitch and roll free, seven parameters fit the four
    # corners of the target alone almost exactly in many ways, so the reprojection fit may land
    # far from the cost's optimum when the target pins the camera only weakly; either can win.)
    smooth = getattr(model, "smooth", False)
    fitted = [_refine(model, counter, cands[i, free], polish=False, max_newton=0) for i in starts[:n_starts]]
    if smooth:
        fitted += [_refine(model, counter, cands[i, free], reprojection=False, max_newton=8, polish=False)
                   for i in starts]
    if not smooth:  # the paper model: refine each and keep the best (its kinks make starts matter)
        fitted = [_refine(model, counter, x, reprojection=False) for x in fitted]
    costs = counter(np.array(fitted))
    return fitted[int(np.argmin(costs))], {"scan_starts": len(starts), "scan_candidates": int(finite.sum())}


def _refine(model, counter: _Counter, x0: np.ndarray, reprojection: bool = True,
            polish: bool = True, max_newton: int = 150) -> np.ndarray:
    """From ``x0`` (free parameters): a least-squares fit of the reprojection of the per-corner
    median (``reprojection``), then a minimisation of the model's cost: trust-region Newton (at
    most ``max_newton`` iterations) for smooth costs, then L-BFGS-B (``polish``)."""
    free = model.free
    scale = _SCALE[free]
    lo, hi = model.bounds.lower[free], model.bounds.upper[free]
    yaw_free = free[YAW]
    lo_s, hi_s = lo / scale, hi / scale
    if yaw_free:  # yaw is circular: do not let its bound stop the optimiser
        iy = int(np.sum(free[:YAW]))
        lo_s[iy], hi_s[iy] = -np.inf, np.inf
    z0 = np.clip(x0 / scale, lo_s, hi_s)

    # 1. reprojection least squares (smooth, fast) from the closed-form start
    if reprojection:
        def resid(z):  # (n, d) → (n, 12): corner residuals (px) and a steep penalty behind the camera
            full = model.expand(np.atleast_2d(z) * scale)
            counter.n += len(full)
            _, r, depth = reprojection_residuals(full, model.observed, model.obj_corners, model.camera)
            return np.concatenate([r.reshape(len(full), -1), 1e3 * np.minimum(depth - 1e-3, 0.0)], axis=1)

        def jac(z):  # central differences, all rows in one vectorised call
            h = 1e-6 * np.eye(len(z))
            r = resid(np.vstack([z + h, z - h]))
            return ((r[:len(z)] - r[len(z):]) / 2e-6).T

        try:  # MINPACK's Levenberg–Marquardt (fast; no bounds: the result is clipped to them)
            z_ls = least_squares(lambda z: resid(z)[0], z0, jac=jac, method="lm", x_scale=1.0,
                                 max_nfev=200).x
            if np.all(np.isfinite(z_ls)):
                z0 = np.clip(z_ls, lo_s, hi_s)
        except ValueError:
            pass

    # 2. the model's own cost: trust-region Newton for smooth costs, then (or else) L-BFGS-B
    maxiter = 500
    if getattr(model, "smooth", False) and max_newton:
        z0 = trust_newton(lambda z: counter(z * scale), z0, lo_s, hi_s, max_iter=max_newton)
        maxiter = 30  # a polish with L-BFGS-B's own stopping rule
    if not polish:
        return z0 * scale
    eps = 1e-6

    def fun_grad(z):
        pts = np.vstack([z, z + eps * np.eye(len(z)), z - eps * np.eye(len(z))])
        f = counter(pts * scale)
        n = len(z)
        return f[0], (f[1:n + 1] - f[n + 1:]) / (2 * eps)

    res = minimize(fun_grad, z0, jac=True, method="L-BFGS-B", bounds=list(zip(lo_s, hi_s)),
                   options={"ftol": 1e-13, "gtol": 1e-9, "maxiter": maxiter})
    return res.x * scale
