"""The second model, ``metrology``: references as measurement likelihoods (method.md §7).

Given the focal length µ, the horizon and the camera height h (= the target's y, since the box
stands on the ground), every annotated ground segment has a definite real length: its endpoints'
viewing rays meet the ground Y = h at two points of the gravity-aligned frame G, and

    ℓ(µ, h) = h · g(µ),     g(µ) = ‖ d_p / d_p,y − d_q / d_q,y ‖

with d = Rᵀ K⁻¹ (u, v, 1) the ray of a pixel (R from the horizon and µ). So each reference is a
noisy *measurement* of a function of the parameters, instead of one side of a pairwise bound:

- a single value v:  log v = log ℓ + s·ε,  ε ~ Student-t(ν)         (heavy-tailed in log-length)
- a range [lo, hi]:  the worker's value lies somewhere in it: P = T_ν((log hi − log ℓ)/s)
  − T_ν((log lo − log ℓ)/s)                                        (interval-censored)

Relative values (ratios to the target's length or width) are converted to metres with the target's
known size, as everywhere else. The defaults s = :data:`REF_SCALE`, ν = :data:`REF_DOF` describe
the paper's crowd workers (Table 2: median error ≈ 60 %, heavy right tail), not one noise tier.
The drawn segment is itself noisy, and a segment far away (close to the horizon) turns a few pixels
into a large length error, so each reference's scale is widened by its line noise:
s_j² = s² + σ_line² Σ_k (∂ log ℓ_j / ∂p_k)² over its four endpoint coordinates p_k (forward
differences of 0.5 px, recomputed for every (µ, h)), with σ_line = :data:`REF_LINE_FACTOR` × the
target's corner scale σ (lines are drawn by the same crowd on the same photo) unless given.

The target's annotations enter jointly rather than through a per-corner median: each corner of each
annotation is a bivariate Student-t(:data:`TARGET_DOF`) observation of the projected corner, with a
scale σ estimated from the annotations' own spread (pooled standard deviation around the per-corner
mean, at least :data:`MIN_TARGET_SIGMA_PX`; :data:`DEFAULT_TARGET_SIGMA_PX` with a single
annotation). The heavy tails keep one careless annotation from dragging the fit.

The cost is the negative log-likelihood up to a constant (a proper likelihood, so the posterior's
temperature for this model is 1: :data:`DEFAULT_TEMPERATURE`). The camera must be above the
ground, so the lower bound of y is raised to :data:`MIN_CAMERA_HEIGHT_M`. References with an
endpoint on or above the horizon measure nothing and are left out (counted in
:attr:`MetrologyModel.reference_status`).

The model offers the same interface as :class:`~creference_bayes.model.PaperModel`:
``cost(params (n, 5)) → (n,)``, ``bounds``, ``free``, ``expand``, ``handedness``, ``camera``,
``observed`` (the per-corner median, used only to start the optimiser), ``obj_corners``, ``name``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import stdtr

from ..core.cost import BEHIND_CAMERA_PENALTY
from ..core.geometry import Camera, box_points, dimension_corners, project
from ..core.metrology import GroundFrame
from .params import FOCAL, Bounds, FreeParameters

__all__ = [
    "TARGET_DOF", "MIN_TARGET_SIGMA_PX", "DEFAULT_TARGET_SIGMA_PX", "REF_SCALE", "REF_DOF",
    "REF_LINE_FACTOR", "MIN_CAMERA_HEIGHT_M", "MIN_HORIZON_PX", "DEFAULT_TEMPERATURE",
    "ReferenceMeasurement", "MetrologyModel", "estimate_target_sigma", "ground_lengths",
]

#: Degrees of freedom of the bivariate Student-t of a target corner.
TARGET_DOF = 4.0
#: Floor of the estimated corner scale, pixels (annotation resolution).
MIN_TARGET_SIGMA_PX = 1.0
#: Corner scale when there is a single annotation (no spread to estimate it from), pixels.
DEFAULT_TARGET_SIGMA_PX = 5.0
#: Scale s and degrees of freedom ν of a worker's error in log-length (see the module docstring).
REF_SCALE = 0.75
REF_DOF = 2.0
#: Pixel noise of a reference's endpoints, as a multiple of the target's corner scale σ.
REF_LINE_FACTOR = 2.0
#: Endpoint step of the forward differences of log-length, pixels.
_LINE_STEP_PX = 0.5
#: Lowest camera height the model allows, metres.
MIN_CAMERA_HEIGHT_M = 0.05
#: Reference endpoints closer than this to the horizon (or above it) are unusable, pixels.
MIN_HORIZON_PX = 1.0
#: The posterior temperature for this model: its cost is a proper negative log-likelihood.
DEFAULT_TEMPERATURE = 1.0


@dataclass(frozen=True)
class ReferenceMeasurement:
    """One reference as the metrology model sees it.

    Attributes
    ----------
    index : the reference's index in the scene
    line : (2, 2) endpoints, pixels
    low, high : the stated length in metres (equal for a single value)
    is_range : whether ``[low, high]`` is an interval
    """

    index: int
    line: np.ndarray
    low: float
    high: float
    is_range: bool

    @classmethod
    def from_reference(cls, ref, target) -> "ReferenceMeasurement":
        low, high = ref.length_bounds_m(target)
        return cls(ref.index, np.asarray(ref.line, float), float(low), float(high), bool(ref.is_range))


def estimate_target_sigma(corners: np.ndarray) -> float:
    """Corner scale σ (pixels) from several annotations of the same corners.

    Parameters
    ----------
    corners : (n_annotation, 4, 2) pixels

    Returns
    -------
    The pooled per-coordinate standard deviation around the per-corner mean (n − 1 degrees of
    freedom per coordinate), at least :data:`MIN_TARGET_SIGMA_PX`; :data:`DEFAULT_TARGET_SIGMA_PX`
    for a single annotation.
    """
    c = np.asarray(corners, float)
    if c.ndim != 3 or c.shape[1:] != (4, 2):
        raise ValueError(f"corners: expected shape (n, 4, 2), got {c.shape}")
    n = len(c)
    if n < 2:
        return DEFAULT_TARGET_SIGMA_PX
    ss = np.sum((c - c.mean(axis=0)) ** 2)
    return float(max(np.sqrt(ss / (8 * (n - 1))), MIN_TARGET_SIGMA_PX))


def ground_lengths(lines: np.ndarray, camera: Camera, focal: np.ndarray, height: np.ndarray,
                   rotation: np.ndarray | None = None) -> np.ndarray:
    """Real lengths of ground segments for a batch of (µ, h).

    Parameters
    ----------
    lines : (m, 2, 2) segment endpoints, pixels (all below the horizon)
    camera : its principal point and horizon
    focal : (n,) µ, pixels
    height : (n,) camera height h, metres
    rotation : (n, 3, 3) R for ``focal`` if already computed (None: from ``camera``)

    Returns
    -------
    (n, m) lengths, metres
    """
    focal = np.atleast_1d(np.asarray(focal, float))
    height = np.atleast_1d(np.asarray(height, float))
    pts = np.asarray(lines, float).reshape(-1, 2) - camera.principal_point  # (2m, 2)
    d = np.concatenate([pts[None] / focal[:, None, None], np.ones((len(focal), len(pts), 1))], axis=-1)
    R = camera.rotation(focal) if rotation is None and camera.horizon is not None else rotation
    if R is not None:
        d = np.einsum("nji,npj->npi", R, d)  # Rᵀ d per row
    with np.errstate(divide="ignore", invalid="ignore"):
        ground = d / d[..., 1:2]  # ray scaled to unit height below the camera
    seg = ground[:, 1::2] - ground[:, 0::2]  # (n, m, 3)
    return height[:, None] * np.linalg.norm(seg, axis=-1)


@dataclass
class MetrologyModel(FreeParameters):
    """The measurement-likelihood model for one handedness of the dimension lines.

    Parameters
    ----------
    camera : Camera
    annotations : (n_annotation, 4, 2) every annotation's corners t1..t4, pixels
    dimensions : (length, width, height) of the target, metres
    handedness : +1 or −1
    bounds : Bounds (y's lower bound is raised to :data:`MIN_CAMERA_HEIGHT_M`; µ is fixed when
        the camera's focal length is known)
    references : the references to use (empty for target-only)
    target_sigma : corner scale, pixels; None to estimate it (:func:`estimate_target_sigma`)
    target_dof, ref_scale, ref_dof : see the module constants
    ref_line_sigma : pixel noise of the references' endpoints (None: :data:`REF_LINE_FACTOR` × σ)
    """

    camera: Camera
    annotations: np.ndarray
    dimensions: tuple[float, float, float]
    handedness: int
    bounds: Bounds
    references: tuple[ReferenceMeasurement, ...] = ()
    target_sigma: float | None = None
    target_dof: float = TARGET_DOF
    ref_scale: float = REF_SCALE
    ref_dof: float = REF_DOF
    ref_line_sigma: float | None = None
    name: str = field(default="metrology", init=False)
    #: The posterior's temperature for this model (the pipeline uses it when none is given).
    default_temperature: float = field(default=DEFAULT_TEMPERATURE, init=False)

    def __post_init__(self):
        ann = np.asarray(self.annotations, float)
        if ann.ndim == 2:
            ann = ann[None]
        if ann.ndim != 3 or ann.shape[1:] != (4, 2):
            raise ValueError(f"annotations: expected shape (n, 4, 2), got {ann.shape}")
        self.annotations = ann
        for key in ("target_dof", "ref_scale", "ref_dof"):
            v = getattr(self, key)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{key}: expected a finite number > 0, got {v!r}")
        if self.target_sigma is None:
            self.target_sigma = estimate_target_sigma(ann)
        elif not (np.isfinite(self.target_sigma) and self.target_sigma > 0):
            raise ValueError(f"target_sigma: expected a finite number > 0, got {self.target_sigma!r}")
        if self.ref_line_sigma is None:
            self.ref_line_sigma = REF_LINE_FACTOR * self.target_sigma
        elif not (np.isfinite(self.ref_line_sigma) and self.ref_line_sigma >= 0):
            raise ValueError(f"ref_line_sigma: expected a finite number >= 0, got {self.ref_line_sigma!r}")
        self.observed = np.median(ann, axis=0)
        self.obj_corners = dimension_corners(*self.dimensions, self.handedness)
        lo, hi = self.bounds.lower.copy(), self.bounds.upper.copy()
        lo[1] = max(lo[1], MIN_CAMERA_HEIGHT_M)
        hi[1] = max(hi[1], lo[1])
        bounds = Bounds(lo, hi)
        if self.camera.focal_length_px is not None:
            bounds = bounds.with_fixed(FOCAL, self.camera.focal_length_px)
        self.bounds = bounds
        self.free = self.bounds.lower < self.bounds.upper
        self._split_references()

    def _split_references(self) -> None:
        usable, status = [], {}
        frame = GroundFrame.from_camera(self.camera)
        for r in self.references:
            if frame.distance(r.line).min() < MIN_HORIZON_PX:
                status[r.index] = "endpoint_above_horizon"
            else:
                usable.append(r)
                status[r.index] = "used"
        self.reference_status = status
        self._lines = np.array([r.line for r in usable]).reshape(-1, 2, 2)
        steps = [np.zeros((2, 2))] + [np.eye(4)[k].reshape(2, 2) * _LINE_STEP_PX for k in range(4)]
        self._lines_all = np.concatenate([self._lines + d for d in steps])  # (5m, 2, 2)
        self._log_low = np.log([r.low for r in usable])
        self._log_high = np.log([r.high for r in usable])
        self._is_range = np.array([r.is_range for r in usable], bool)

    @classmethod
    def from_scene(cls, scene, handedness: int, *, bounds: Bounds | None = None,
                   camera: Camera | None = None, use_references: bool = True,
                   **options) -> "MetrologyModel":
        """The model of ``scene`` for one handedness; ``options`` are the settings above."""
        unknown = set(options) - {"target_sigma", "target_dof", "ref_scale", "ref_dof", "ref_line_sigma"}
        if unknown:
            raise ValueError(f"metrology model: unknown option(s) {sorted(unknown)}")
        t = scene.target
        refs = tuple(ReferenceMeasurement.from_reference(r, t) for r in scene.references) if use_references else ()
        return cls(camera=camera or Camera.from_scene(scene), annotations=t.corners,
                   dimensions=(t.length, t.width, t.height), handedness=handedness,
                   bounds=bounds or Bounds.default(scene.image_width, scene.image_height),
                   references=refs, **options)

    @property
    def n_references_used(self) -> int:
        return len(self._lines)

    # -- the cost --------------------------------------------------------------------------------
    def cost(self, params: np.ndarray) -> np.ndarray:
        """Negative log-likelihood (up to a constant) for (n, 5) parameter vectors, shape (n,)."""
        params = np.atleast_2d(np.asarray(params, float))
        mu = params[:, FOCAL]
        R = self.camera.rotation(mu)
        projected, depth = project(box_points(params, self.obj_corners), R, mu, self.camera.principal_point)
        total = self._target_nll(projected) + BEHIND_CAMERA_PENALTY * np.sum(np.maximum(0.0, 1e-3 - depth), axis=-1)
        if len(self._lines):
            h = np.maximum(params[:, 1], MIN_CAMERA_HEIGHT_M)
            log_len, scale = self._log_lengths(mu, h, R)
            total = total + self._reference_nll(log_len, scale)
        return total

    def _log_lengths(self, mu, h, R) -> tuple[np.ndarray, np.ndarray]:
        """(n, m) log real lengths of the usable references and their scales s_j."""
        m = len(self._lines)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_all = np.log(ground_lengths(self._lines_all, self.camera, mu, h, R)).reshape(len(mu), 5, m)
        log_len = log_all[:, 0]
        if self.ref_line_sigma == 0:
            return log_len, np.full_like(log_len, self.ref_scale)
        grad2 = np.sum(((log_all[:, 1:] - log_len[:, None]) / _LINE_STEP_PX) ** 2, axis=1)
        return log_len, np.sqrt(self.ref_scale**2 + self.ref_line_sigma**2 * grad2)

    def target_nll(self, params: np.ndarray) -> np.ndarray:
        """The target annotations' part of :meth:`cost`, shape (n,)."""
        params = np.atleast_2d(np.asarray(params, float))
        projected, _ = self.camera.project(box_points(params, self.obj_corners), params[:, FOCAL])
        return self._target_nll(projected)

    def _target_nll(self, projected: np.ndarray) -> np.ndarray:
        r2 = np.sum((self.annotations[None] - projected[:, None]) ** 2, axis=-1)  # (n, A, 4)
        nu = self.target_dof
        return 0.5 * (nu + 2.0) * np.sum(np.log1p(r2 / (nu * self.target_sigma**2)), axis=(1, 2))

    def _reference_nll(self, log_len: np.ndarray, scale) -> np.ndarray:
        """Reference terms for (n, m) log-lengths and scales s_j (array or scalar), shape (n,).
        Singles: −log of the t density in log-length (its ν-only constant dropped); ranges: −log P."""
        nu = self.ref_dof
        s = np.broadcast_to(np.asarray(scale, float), log_len.shape)
        out = np.zeros(len(log_len))
        single = ~self._is_range
        if single.any():
            z = (self._log_low[single] - log_len[:, single]) / s[:, single]
            out += np.sum(0.5 * (nu + 1.0) * np.log1p(z**2 / nu) + np.log(s[:, single]), axis=1)
        if self._is_range.any():
            a = (self._log_low[self._is_range] - log_len[:, self._is_range]) / s[:, self._is_range]
            b = (self._log_high[self._is_range] - log_len[:, self._is_range]) / s[:, self._is_range]
            flip = (a + b) > 0  # use the lower tail for accuracy: T(b) − T(a) = T(−a) − T(−b)
            lo, hi = np.where(flip, -b, a), np.where(flip, -a, b)
            p = stdtr(nu, hi) - stdtr(nu, lo)
            out -= np.sum(np.log(np.maximum(p, 1e-300)), axis=1)
        return np.where(np.isfinite(out), out, 1e300)

