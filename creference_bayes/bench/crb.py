"""The Cramér–Rao bound on every target's location error at the true state (benchmark.md, "the limit").

For any scene (one target or many) the parameters are the model's free ones (:mod:`~creference_bayes.
models.contract`; pitch and roll derived from an exact horizon and µ when the model says so; the
crowd's scale is not a parameter: the workers' error is given). An unbiased estimator's covariance
is at least F⁻¹, F the Fisher information at the truth, summed over:

- dimension lines: object i's Kᵢ annotations observe its four projected corners with Gaussian
  noise σ per coordinate, F = Σᵢ (Kᵢ / σ²) Jᵢᵀ Jᵢ (Jᵢ by central differences);
- references (the metrology model's reading, :meth:`~creference_bayes.models.metrology.
  MetrologyModel.predicted_log_lengths`): each a log-length with a worker's log-error of sd σ_m
  plus, for a line, its endpoints' pixel noise σ_r to first order
  (:func:`~creference_bayes.models.metrology.linear_line_variances`): F = Σⱼ ∇ⱼ ∇ⱼᵀ / (σ_m² + vⱼ).
  For "paper" workers (log-error s·t_ν) σ_m² = (ν + 3)s² / (ν + 1), the inverse Fisher
  information of a Student-t location (:func:`measurement_log_sd`);
- a measured horizon (pitch and roll free): its two points' offsets, with the model's variance;
- with ``priors``, the Bayesian (van Trees) bound: the Hessian of the negative log-prior at the
  truth (never the location prior: the location is the fixed unknown whose error is bounded),
  except for the ground offsets, whose Student-t prior of ν degrees of freedom and scale s(d)
  (:meth:`~creference_bayes.models.contract.Model.ground_neg_log_prior`) adds its expected
  information (ν + 1) / ((ν + 3) s²) (1 / s² for a normal): a t's Hessian at an offset in its
  tails is negative.

Each target's location (x, camera height − ground, z) is linear in the parameters; its (3, 3)
covariance C gives the RMS error √tr C and the median of ‖e‖, e ~ N(0, C) (Monte Carlo, fixed
seed), in percent of the true distance (paper Eq. 3), comparable to an estimator's error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.camera_terms import horizon_offsets
from ..models.contract import C_FOCAL, C_HEIGHT, C_SCALE, CAMERA_NAMES, O_GROUND, O_X, O_Z, OBJECT_NAMES
from ..models.metrology import linear_line_variances

__all__ = ["Bound", "cramer_rao", "scene_bound", "measurement_log_sd"]

#: Draws used for the median of ‖e‖ under N(0, C).
N_MEDIAN_DRAWS = 20000
#: Object parameter → (row of the location (x, y, z), coefficient); y = camera height − ground.
_LOCATION_ROWS = {O_X: (0, 1.0), O_Z: (2, 1.0), O_GROUND: (1, -1.0)}


@dataclass(frozen=True)
class Bound:
    """The bound for one scene.

    Attributes
    ----------
    names : the free parameters (``camera.<name>``, ``<target index>.<name>``)
    cov : (k, k) F⁻¹ over them (inf where F is singular)
    location_cov : (m, 3, 3) each target's (x, y, z) block, m²
    median_pct, rmse_pct : (m,) the median of ‖e‖ and √tr C over ‖GT‖, percent (Eq. 3)
    median_m, distance_sd_m : (m,) the median of ‖e‖ and the sd of the ground distance, metres
    singular : whether F was singular (the bound is then infinite)
    """

    names: tuple[str, ...]
    cov: np.ndarray
    location_cov: np.ndarray
    median_pct: np.ndarray
    rmse_pct: np.ndarray
    median_m: np.ndarray
    distance_sd_m: np.ndarray
    singular: bool = False


def measurement_log_sd(model: str) -> float:
    """Equivalent log-sd of a worker's measurement for a simulator noise model (module docstring)."""
    from .simulate import PAPER_NOISE, _percent

    if model == "none":
        return 0.0
    if _percent(model) is not None:
        return _percent(model)
    if model == "paper":
        nu, s = PAPER_NOISE["dof"], PAPER_NOISE["scale"]
        return float(np.sqrt((nu + 3.0) * s**2 / (nu + 1.0)))
    raise ValueError(f"measurement model: unknown {model!r} (expected none, a percentage such as 10% or paper)")


class _Free:
    """The free parameters at the truth: states moved along them, their finite differences."""

    def __init__(self, model, camera, objects):
        self.model, self.camera, self.objects = model, model.complete_camera(np.asarray(camera, float)[None])[0], \
            np.asarray(objects, float)
        cf = model.camera_free.copy()
        cf[C_SCALE] = False
        self.cam = np.flatnonzero(cf)
        self.obj = [(i, j) for i in range(model.n_objects) for j in np.flatnonzero(model.object_free[i])]
        self.names = tuple([f"camera.{CAMERA_NAMES[j]}" for j in self.cam]
                           + [f"{i}.{OBJECT_NAMES[j]}" for i, j in self.obj])
        values = np.concatenate([self.camera[self.cam], [self.objects[i, j] for i, j in self.obj]])
        self.scale = np.maximum(1.0, np.abs(values))

    @property
    def n(self) -> int:
        return len(self.names)

    def states(self, delta: np.ndarray):
        """(k, n) moves of the free parameters → completed cameras (k, 5) and objects (k, m, 7)."""
        delta = np.atleast_2d(delta)
        cams = np.repeat(self.camera[None], len(delta), axis=0)
        objs = np.repeat(self.objects[None], len(delta), axis=0)
        kc = len(self.cam)
        cams[:, self.cam] += delta[:, :kc]
        for k, (i, j) in enumerate(self.obj):
            objs[:, i, j] += delta[:, kc + k]
        return self.model.complete_camera(cams), objs

    def jacobian(self, fun, step: float = 1e-6) -> np.ndarray:
        """∂fun/∂free (q, n) of ``fun(cams, objs) → (k, q)`` by central differences."""
        h = step * self.scale
        f = fun(*self.states(np.vstack([np.diag(h), -np.diag(h)])))
        f = f.reshape(2 * self.n, -1)
        return ((f[:self.n] - f[self.n:]) / (2 * h[:, None])).T

    def hessian(self, fun, step: float = 1e-4) -> np.ndarray:
        """∂²fun/∂free² (n, n) of a scalar ``fun(cams, objs) → (k,)`` by central differences."""
        h = step * self.scale
        E = np.diag(h)
        a, b = np.triu_indices(self.n)
        moves = np.concatenate([E[a] + E[b], E[a] - E[b], -E[a] + E[b], -E[a] - E[b]])
        v = fun(*self.states(moves)).reshape(4, -1)
        H = np.zeros((self.n, self.n))
        H[a, b] = (v[0] - v[1] - v[2] + v[3]) / (4 * h[a] * h[b])
        return H + np.triu(H, 1).T


def cramer_rao(model, camera, objects, sigma_px: float, *, reference_log_sd: float | None = None,
               reference_sigma_px: float = 0.0, priors: bool = True, seed: int = 0) -> Bound:
    """The bound at the true ``camera`` (5,) and ``objects`` (m, 7) (module docstring).

    Parameters
    ----------
    model : the scene's model (:mod:`~creference_bayes.models.contract`), its handedness the truth's
    sigma_px : σ of each corner coordinate, pixels (0 gives a zero bound)
    reference_log_sd : σ_m of the workers' log-error (:func:`measurement_log_sd`), or None to
        leave the model's references out
    reference_sigma_px : σ_r, pixel noise of each reference endpoint coordinate
    priors : add the priors' information (the Bayesian bound); False for the data alone
    seed : of the Monte Carlo median
    """
    free = _Free(model, camera, objects)
    cam, objs = free.camera, free.objects
    m, n = model.n_objects, free.n
    loc = np.column_stack([objs[:, O_X], cam[C_HEIGHT] - objs[:, O_GROUND], objs[:, O_Z]])
    norm = np.linalg.norm(loc, axis=1)
    if sigma_px == 0:
        zero = np.zeros(m)
        return Bound(free.names, np.zeros((n, n)), np.zeros((m, 3, 3)), zero, zero, zero, zero)
    J = free.jacobian(lambda c, o: model.project(c, o)[0]).reshape(m, 8, n)
    counts = np.array([len(o.annotations) for o in model.objects], float)
    F = np.einsum("i,ian,iak->nk", counts / sigma_px**2, J, J)
    refs = getattr(model, "references", ())
    if reference_log_sd is not None and len(refs):
        g = free.jacobian(model.predicted_log_lengths)
        var = np.full(len(refs), reference_log_sd**2)
        lines = np.array([r.line is not None for r in refs])
        if lines.any():
            var[lines] += linear_line_variances(np.array([r.line for r in refs if r.line is not None]),
                                                model.principal_point, cam, reference_sigma_px)
        F += (g.T / np.maximum(var, 1e-12)) @ g  # exact references: (nearly) infinite information
    hz = model.camera_terms.horizon
    if hz is not None and model.orientation == "free":
        Jh = free.jacobian(lambda c, o: horizon_offsets(hz.points, c, model.principal_point))
        F += Jh.T @ Jh / (hz.sd_px**2 + (cam[C_FOCAL] * np.tan(model.ground_tilt_sd_rad)) ** 2)
    if priors:
        F += free.hessian(lambda c, o: model.camera_neg_log_prior(c) + np.sum(
            model.object_neg_log_prior(c, o) - model.location.neg_log(o[..., O_X], o[..., O_Z])
            - model.ground_neg_log_prior(o), axis=1))
        nu, s = model.ground_dof, model.ground_scale(objs[None])[0]
        share = 1.0 if np.isinf(nu) else (nu + 1.0) / (nu + 3.0)
        kc = len(free.cam)
        for k, (i, j) in enumerate(free.obj):
            if j == O_GROUND:
                F[kc + k, kc + k] += share / s[i] ** 2
    try:
        cov = np.linalg.inv(F)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        inf = np.full(m, np.inf)
        return Bound(free.names, np.full((n, n), np.inf), np.full((m, 3, 3), np.inf), inf, inf, inf, inf, True)
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((N_MEDIAN_DRAWS, 3))
    loc_cov, med, dsd = np.zeros((m, 3, 3)), np.zeros(m), np.zeros(m)
    kc = len(free.cam)
    for i in range(m):
        A = np.zeros((3, n))  # (x, y, z) of target i as linear functions of the free parameters
        for k, (oi, j) in enumerate(free.obj):
            if oi == i and j in _LOCATION_ROWS:
                A[_LOCATION_ROWS[j][0], kc + k] = _LOCATION_ROWS[j][1]
        if C_HEIGHT in free.cam:
            A[1, list(free.cam).index(C_HEIGHT)] = 1.0
        C = A @ cov @ A.T
        w, V = np.linalg.eigh(C)
        e = (z * np.sqrt(np.maximum(w, 0.0))) @ V.T
        loc_cov[i], med[i] = C, np.median(np.linalg.norm(e, axis=1))
        u = np.array([objs[i, O_X], 0.0, objs[i, O_Z]]) / np.hypot(objs[i, O_X], objs[i, O_Z])
        dsd[i] = float(np.sqrt(u @ C @ u))
    rmse = np.sqrt(np.trace(loc_cov, axis1=1, axis2=2))
    return Bound(free.names, cov, loc_cov, 100 * med / norm, 100 * rmse / norm, med, dsd)


def scene_bound(scene, sigma_px: float, *, reference_log_sd: float | None = None, reference_sigma_px: float = 0.0,
                priors: bool = True, seed: int = 0) -> Bound:
    """:func:`cramer_rao` of a simulated scene (:mod:`.simulate`) at its ground truth: its true
    state and handedness, and its references on their true lines; its metrology model decides
    the free parameters (a focal length stated or not, the horizon exact, measured or absent)."""
    from dataclasses import replace

    from ..pipeline import build_model
    from .simulate import true_state

    true_lines = scene.ground_truth.get("reference_lines_px") or []
    refs = tuple(r if r.line is None or r.index >= len(true_lines) else replace(r, line=np.asarray(true_lines[r.index]))
                 for r in scene.references)
    model, _ = build_model(replace(scene, references=refs), use_references=reference_log_sd is not None)
    model.handedness = np.array([t.ground_truth["handedness"] for t in scene.targets], float)
    camera, objects = true_state(scene)
    return cramer_rao(model, camera, objects, sigma_px, reference_log_sd=reference_log_sd,
                      reference_sigma_px=reference_sigma_px, priors=priors, seed=seed)
