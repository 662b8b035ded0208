"""The Cramér–Rao bound on location error at the true pose (benchmark.md, "the limit").

For unbiased estimators of θ = (x, y, z, yaw, µ[, pitch, roll]) (µ dropped when the focal length
is known; pitch and roll included when there is no exact horizon, otherwise they follow from the
horizon and µ and the chain rule carries their change into µ's column), the covariance is at least
F⁻¹, F the Fisher information of the annotations at the true θ:

- target annotations: each of n annotations observes the four projected corners C_µ(x_s) with
  independent Gaussian noise σ_t per pixel coordinate, so F_t = (n / σ_t²) Σᵢ Jᵢᵀ Jᵢ, Jᵢ the
  (2, k) Jacobian of corner i's projection (central differences; the projection is smooth);
- references (the metrology model's view, :mod:`~creference_bayes.models.metrology`): each
  reference measures its segment's real length ℓ_j(µ, h, pitch, roll). A worker's log-error ε with log-sd σ_m and the
  endpoints' pixel noise σ_r (propagated to log ℓ_j to first order) give, for the linearised
  Gaussian model, F_r = Σ_j ∇log ℓ_j ∇log ℓ_jᵀ / (σ_m² + σ_line,j²). For the heavy-tailed
  "paper" workers (log-error s·t_ν) the equivalent σ_m² is 1/I = (ν + 3)s² / (ν + 1), the inverse
  Fisher information of a Student-t location (the clip of the simulator is ignored);
- a horizon measured with σ_h pixels per point (when pitch and roll are free): F_h = J_hᵀ J_h / σ_h²,
  J_h the Jacobian of the two points' offsets from the predicted horizon.

The location's covariance is the (x, y, z) block of F⁻¹. It is reported as the RMS error
√tr C and as the median of ‖e‖ for e ~ N(0, C) (Monte Carlo with a fixed seed), both in metres and
as a percentage of the true distance ‖GT‖ (paper Eq. 3), comparable to an estimator's error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.cost import project_params
from ..core.geometry import Camera, dimension_corners, horizon_from_rotation, rotation_from_pitch_roll
from ..models.camera_terms import horizon_offsets
from ..models.metrology import ground_lengths
from ..models.params import FOCAL, N_PARAMS, PARAM_NAMES, PITCH, ROLL

__all__ = ["CramerRao", "projection_jacobian", "log_length_gradient", "line_log_sd",
           "measurement_log_sd", "cramer_rao", "cramer_rao_scene"]

#: Draws used for the median of ‖e‖ under N(0, C).
N_MEDIAN_DRAWS = 20000
#: Central-difference steps per parameter (x, y, z in m; yaw rad; µ px; pitch, roll rad), relative
#: to max(1, |θ|).
_STEP = np.array([1e-6, 1e-6, 1e-6, 1e-7, 1e-6, 1e-7, 1e-7])


@dataclass(frozen=True)
class CramerRao:
    """The bound for one scene.

    Attributes
    ----------
    cov : (k, k) F⁻¹ over the free parameters ``names`` (inf where F is singular)
    names : the free parameters
    location_cov : (3, 3) the (x, y, z) block, m²
    rmse_m, median_m : √tr C and the median of ‖e‖, metres
    rmse_pct, median_pct : the same over ‖GT‖, percent (Eq. 3)
    singular : whether F was singular (the bound is then infinite)
    """

    cov: np.ndarray
    names: tuple[str, ...]
    location_cov: np.ndarray
    rmse_m: float
    median_m: float
    rmse_pct: float
    median_pct: float
    singular: bool = False

    def to_dict(self) -> dict:
        return {"names": list(self.names), "rmse_m": self.rmse_m, "median_m": self.median_m,
                "rmse_pct": self.rmse_pct, "median_pct": self.median_pct, "singular": self.singular,
                "sd": {n: float(np.sqrt(self.cov[i, i])) for i, n in enumerate(self.names)}}


def _steps(params: np.ndarray) -> np.ndarray:
    return _STEP * np.maximum(1.0, np.abs(params))


def _filled(params: np.ndarray, camera: Camera, orientation_free: bool) -> np.ndarray:
    """(n, 7) vectors with pitch and roll from the camera's horizon and µ unless they are free."""
    p = np.atleast_2d(np.array(params, float))
    if not orientation_free:
        p[:, PITCH], p[:, ROLL] = camera.pitch_roll(p[:, FOCAL])
    return p


def _jacobian(fun, params: np.ndarray, camera: Camera, orientation_free: bool) -> np.ndarray:
    """Central-difference Jacobian (len(fun), 7) of ``fun((n, 7)) → (n, k)`` at ``params``; the
    pitch and roll columns are zero unless they are free (their change is in µ's column)."""
    p = _filled(params, camera, orientation_free)[0]
    h = _steps(p)
    pts = _filled(np.vstack([p + np.diag(h), p - np.diag(h)]), camera, orientation_free)
    f = fun(pts)
    J = ((f[:N_PARAMS] - f[N_PARAMS:]) / (2.0 * h[:, None])).T
    if not orientation_free:
        J[:, [PITCH, ROLL]] = 0.0
    return J


def projection_jacobian(params: np.ndarray, obj_corners: np.ndarray, camera: Camera,
                        orientation_free: bool = False) -> np.ndarray:
    """∂(u₁, v₁, …, u₄, v₄)/∂(x, y, z, yaw, µ, pitch, roll) at ``params``, shape (8, 7), pixels
    per unit (pitch and roll columns zero unless ``orientation_free``)."""
    pp = camera.principal_point
    return _jacobian(lambda q: project_params(q, obj_corners, pp)[0].reshape(len(q), -1), params,
                     camera, orientation_free)


def log_length_gradient(lines: np.ndarray, camera: Camera, params: np.ndarray,
                        orientation_free: bool = False) -> np.ndarray:
    """∂ log ℓ_j / ∂(x, y, z, yaw, µ, pitch, roll) of ground segments, shape (m, 7) (x, z and yaw
    columns are zero: a reference does not depend on the target's place)."""
    lines = np.asarray(lines, float)
    return _jacobian(lambda q: np.log(ground_lengths(lines, camera.principal_point, q)), params,
                     camera, orientation_free)


def line_log_sd(lines: np.ndarray, camera: Camera, params: np.ndarray, sigma_px: float,
                orientation_free: bool = False) -> np.ndarray:
    """SD of log ℓ_j caused by Gaussian noise σ (pixels) on each endpoint coordinate, shape (m,)."""
    lines = np.asarray(lines, float)
    if sigma_px == 0 or len(lines) == 0:
        return np.zeros(len(lines))
    full, eps = _filled(params, camera, orientation_free), 1e-3
    var = np.zeros(len(lines))
    for k in range(4):  # the four endpoint coordinates
        d = np.zeros(4)
        d[k] = eps
        plus = ground_lengths(lines + d.reshape(2, 2), camera.principal_point, full)[0]
        minus = ground_lengths(lines - d.reshape(2, 2), camera.principal_point, full)[0]
        var += ((np.log(plus) - np.log(minus)) / (2 * eps)) ** 2
    return sigma_px * np.sqrt(var)


def measurement_log_sd(model: str) -> float:
    """Equivalent log-sd of a worker's measurement for a simulator noise model (see the module doc)."""
    from .simulate import PAPER_NOISE

    if model == "none":
        return 0.0
    if model in ("10%", "40%"):
        return 0.1 if model == "10%" else 0.4
    if model == "paper":
        nu, s = PAPER_NOISE["dof"], PAPER_NOISE["scale"]
        return float(np.sqrt((nu + 3.0) * s**2 / (nu + 1.0)))
    raise ValueError(f"measurement model: unknown {model!r} (expected none, 10%, 40% or paper)")


def cramer_rao(params: np.ndarray, obj_corners: np.ndarray, camera: Camera, *, sigma_px: float,
               n_annotations: int, reference_lines: np.ndarray | None = None,
               reference_log_sd: float = 0.0, reference_sigma_px: float = 0.0,
               focal_known: bool = False, orientation_free: bool = False,
               horizon_sd_px: float | None = None, image_width: float = 2880.0) -> CramerRao:
    """The bound at the true ``params`` for the given noise.

    Parameters
    ----------
    params : (7,) true x, y, z (m), yaw (rad), µ (px), pitch, roll (rad); (5,) is accepted when
        the orientation follows from ``camera``'s horizon
    obj_corners : (4, 3) object-frame corners of the annotated handedness
    camera : principal point and, unless ``orientation_free``, the horizon
    sigma_px : σ_t of each corner coordinate, pixels (0 gives a zero bound)
    n_annotations : annotations of the target
    reference_lines : (m, 2, 2) true reference segments, pixels, or None for target only
    reference_log_sd : σ_m, the worker's log-error (see :func:`measurement_log_sd`)
    reference_sigma_px : σ_r, pixel noise of each reference endpoint coordinate
    focal_known : drop µ from the parameters
    orientation_free : pitch and roll are parameters (no exact horizon)
    horizon_sd_px : with ``orientation_free``, a horizon measured with this uncertainty per point
        (its two points at u = 0 and u = ``image_width``); None for no horizon at all
    """
    p = np.zeros(N_PARAMS)
    p[:len(params)] = np.asarray(params, float)
    p = _filled(p, camera, orientation_free)[0]
    free = np.ones(N_PARAMS, bool)
    free[FOCAL] = not focal_known
    free[[PITCH, ROLL]] = orientation_free
    names = tuple(n for n, f in zip(PARAM_NAMES, free) if f)
    gt_norm = float(np.linalg.norm(p[:3]))
    if sigma_px == 0:
        zero = np.zeros((free.sum(), free.sum()))
        return CramerRao(zero, names, np.zeros((3, 3)), 0.0, 0.0, 0.0, 0.0)
    J = projection_jacobian(p, obj_corners, camera, orientation_free)[:, free]
    F = n_annotations / sigma_px**2 * (J.T @ J)
    if reference_lines is not None and len(reference_lines):
        lines = np.asarray(reference_lines, float)
        g = log_length_gradient(lines, camera, p, orientation_free)[:, free]
        var = reference_log_sd**2 + line_log_sd(lines, camera, p, reference_sigma_px, orientation_free) ** 2
        var = np.maximum(var, 1e-12)  # exact references: (nearly) infinite information
        F = F + (g.T / var) @ g
    if orientation_free and horizon_sd_px is not None:
        R = rotation_from_pitch_roll(p[PITCH], p[ROLL])
        pts = horizon_from_rotation(R, p[FOCAL], camera.principal_point, image_width)
        Jh = _jacobian(lambda q: horizon_offsets(pts, q, camera.principal_point), p, camera, True)[:, free]
        F = F + Jh.T @ Jh / horizon_sd_px**2
    try:
        cov = np.linalg.inv(F)
        singular = not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0)
    except np.linalg.LinAlgError:
        singular = True
    if singular:
        cov = np.full_like(F, np.inf)
        return CramerRao(cov, names, np.full((3, 3), np.inf), np.inf, np.inf, np.inf, np.inf, True)
    C = cov[:3, :3]
    rmse = float(np.sqrt(np.trace(C)))
    e = np.random.default_rng(0).multivariate_normal(np.zeros(3), C, N_MEDIAN_DRAWS, method="eigh")
    med = float(np.median(np.linalg.norm(e, axis=1)))
    return CramerRao(cov, names, C, rmse, med, 100 * rmse / gt_norm, 100 * med / gt_norm)


def cramer_rao_scene(scene, *, n_annotations: int = 5, references: bool = False,
                     n_references: int | None = None, sigma_px: float | None = None,
                     orientation_free: bool | None = None, horizon_sd_px: float | None = None) -> CramerRao:
    """The bound for a simulated scene, from its ground truth and its noise tier.

    Parameters
    ----------
    scene : a :class:`~creference_bayes.scene.Scene` made by :mod:`~.simulate` (its ground truth
        carries the tier, handedness, camera height and true reference segments)
    n_annotations : target annotations the estimators get
    references : include the references (the metrology model's information)
    n_references : how many of them (default all)
    sigma_px : override the tier's σ_t
    orientation_free : pitch and roll unknown (default: when the scene has no horizon)
    horizon_sd_px : a horizon measured with this uncertainty (with ``orientation_free``)
    """
    from .simulate import TIERS, true_params

    gt = scene.ground_truth
    if gt is None or "tier" not in gt.extra:
        raise ValueError("scene: needs simulated ground truth (ground_truth.tier, handedness, …)")
    tier = TIERS[gt.extra["tier"]]
    t = scene.target
    params = true_params(scene)
    free_orientation = scene.horizon is None if orientation_free is None else orientation_free
    corners = dimension_corners(t.length, t.width, t.height, int(gt.extra["handedness"]))
    lines = None
    if references:
        lines = np.asarray(gt.extra["reference_lines_px"], float)[:n_references]
    camera = Camera.from_scene(scene)
    if free_orientation:  # the true orientation, not one derived from a horizon
        camera = Camera(camera.principal_point, None, camera.focal_length_px)
    return cramer_rao(params, corners, camera, orientation_free=free_orientation,
                      horizon_sd_px=horizon_sd_px, image_width=scene.image_width,
                      sigma_px=tier.target_px if sigma_px is None else sigma_px,
                      n_annotations=n_annotations, reference_lines=lines,
                      reference_log_sd=measurement_log_sd(tier.measurement),
                      reference_sigma_px=tier.reference_px,
                      focal_known=scene.focal_length_px is not None)
