"""The second model, ``metrology``: references as measurement likelihoods (method.md §7).

Given the focal length µ, the camera's pitch and roll and its height h (= the target's y, since
the box stands on the ground), every annotated ground segment has a definite real length: its
endpoints' viewing rays meet the ground Y = h at two points of the gravity-aligned frame G, and

    ℓ(µ, pitch, roll, h) = h · ‖ d_p / d_p,y − d_q / d_q,y ‖

with d = Rᵀ K⁻¹ (u, v, 1) the ray of a pixel and R = Rz(roll)·Rx(pitch) (pitch and roll follow
from an exact horizon and µ, or are parameters of their own). So each reference is a noisy
*measurement* of a function of the parameters, instead of one side of a pairwise bound:

- a single value v:  log v = log ℓ + s_j·ε,  ε ~ Student-t(ν)      (heavy-tailed in log-length)
- a range [lo, hi]:  the worker's value lies somewhere in it: P = T_ν((log hi − log ℓ)/s_j)
  − T_ν((log lo − log ℓ)/s_j)                                     (interval-censored)

Relative values (ratios to the target's length or width) are converted to metres with the target's
known size, as everywhere else. ν = :data:`REF_DOF` gives the heavy tails of the paper's crowd
workers (Table 2: median error ≈ 60 %, a long right tail).

The crowd's error scale s is not assumed: it is shared by the scene's references and integrated
out over a grid (:data:`REF_SCALE_GRID`, from 0.5 % to 300 %, with a log-normal prior of median
:data:`REF_SCALE_MEDIAN` and log-sd :data:`REF_SCALE_LOG_SD`), so the likelihood of the references
is Σ_k w_k Π_j p(v_j | ℓ_j, s_k). A scene whose references agree with each other and with the
target (careful workers, or exact values) puts its weight on small s and lets the references pin
the depth–focal-length ridge; a scene of wild guesses puts it on large s and leans on the target.
A fixed scale (the option ``ref_scale``) gives the plain product.

Stated confidence. With a confidence map g (the option ``confidence_map``,
:mod:`.confidence_map`), a range [lo, hi] stated with a confidence c is read as the worker's
central interval at the calibrated coverage g(c): its log-centre m = (log lo + log hi)/2 is a
measurement of log ℓ with its own scale s_c = w / q_D((1 + g(c))/2) (w the log half-width, q_D the
map's normal or Student-t quantile), m = log ℓ + s_c·ε, ε ~ D. These terms sit outside the
crowd-scale mixture (the worker has said how accurate they are), and are widened by line noise
like the others. References without a confidence, single values (a confidence needs an interval
to be about) and ranges whose ends are equal keep the treatment above; without a map
(``confidence_map=None``, the option ``none``) every reference does.

Line noise. The drawn segment is itself noisy, and a segment far away (close to the horizon) turns
a few pixels into a large length error, so each reference's scale is widened by its line noise:
s_j² = s² + v_j, v_j = σ_line² Σ_i (∂ log ℓ_j / ∂p_i)² over its four endpoint coordinates p_i,
with σ_line = :data:`REF_LINE_FACTOR` × the target's corner scale σ unless given. A segment only a
few σ_line long also reads *long* (the noise adds length on average); with the option
``line_reading="corrected"`` the model reads log ℓ_j − shift_j instead, the reading inverted for
that median bias, and v_j at least the above (:func:`segment_reading`). Variances and shifts are
taken once, at a *pilot* estimate (:meth:`MetrologyModel.set_pilot`: the optimiser sets it at its
first optimum and refines from there), and then held fixed. Recomputing them at every parameter
value (as this model did before) makes each reference's normalising constant −log s_j a function
of (µ, h, pitch, roll), which rewards states where the lines look insensitive, independently of
what the workers said: with exact references that pull alone moved the optimum by up to 5 % of
the distance. With fixed scales, exact data put every term's minimum at the truth.

The target's annotations enter jointly rather than through a per-corner median: each corner of each
annotation is a bivariate Student-t(:data:`TARGET_DOF`) observation of the projected corner, with a
scale σ estimated from the annotations' own spread (pooled standard deviation around the per-corner
mean, at least :data:`MIN_TARGET_SIGMA_PX`, which only noise-free or copied annotations reach;
:data:`DEFAULT_TARGET_SIGMA_PX` with a single annotation). The heavy tails keep one careless
annotation from dragging the fit.

The cost is the negative log-likelihood up to a constant, plus the camera terms (priors on µ,
pitch and roll, a horizon measurement: :mod:`.camera_terms`). It is a proper log-posterior, so the
posterior's temperature for this model is 1 (:data:`DEFAULT_TEMPERATURE`). The camera must be
above the ground, so the lower bound of y is raised to :data:`MIN_CAMERA_HEIGHT_M`. With an exact
horizon, references with an endpoint on or above it measure nothing and are left out (counted in
:attr:`MetrologyModel.reference_status`); when pitch and roll are free, a ray at or above the
state's horizon is taken to meet the ground very far away (:data:`MIN_RAY_DOWN`), so such a state
explains the worker's value badly but finitely.

The model offers the same interface as :class:`~creference_bayes.models.paper.PaperModel`:
``cost(params (n, 7)) → (n,)``, ``bounds``, ``free``, ``expand``, ``handedness``, ``camera``,
``observed`` (the per-corner median, used only to start the optimiser), ``obj_corners``, ``name``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import stdtr

from ..core.cost import BEHIND_CAMERA_PENALTY, project_params
from ..core.geometry import Camera, dimension_corners, rotation_from_pitch_roll
from ..core.metrology import GroundFrame
from .camera_terms import CameraTerms
from .confidence_map import ConfidenceMap
from .params import FOCAL, PITCH, ROLL, Bounds, FreeParameters

__all__ = [
    "TARGET_DOF", "MIN_TARGET_SIGMA_PX", "DEFAULT_TARGET_SIGMA_PX", "REF_SCALE", "REF_DOF",
    "REF_SCALE_GRID", "REF_SCALE_MEDIAN", "REF_SCALE_LOG_SD",
    "REF_LINE_FACTOR", "LINE_READINGS", "DEFAULT_LINE_READING", "READ_DRAWS", "READ_SCALES",
    "MIN_CAMERA_HEIGHT_M", "MIN_HORIZON_PX", "MIN_RAY_DOWN", "DEFAULT_TEMPERATURE",
    "ReferenceMeasurement", "MetrologyModel", "estimate_target_sigma", "ground_lengths",
    "linear_line_variances", "segment_reading", "t_interval",
]

#: Degrees of freedom of the bivariate Student-t of a target corner.
TARGET_DOF = 4.0
#: Floor of the estimated corner scale, pixels. Real crowd annotations spread by a pixel or more,
#: so the floor only matters when annotations agree exactly (noise-free or copied): it is then
#: well above the 0.003 px that coordinates stored to 0.01 px keep.
MIN_TARGET_SIGMA_PX = 0.05
#: Corner scale when there is a single annotation (no spread to estimate it from), pixels.
DEFAULT_TARGET_SIGMA_PX = 5.0
#: Scale s and degrees of freedom ν of a worker's error in log-length (see the module docstring).
REF_SCALE = 0.75
REF_DOF = 2.0
#: The grid over which the crowd's error scale s is integrated out, and its prior (log-normal).
REF_SCALE_GRID = np.geomspace(0.005, 3.0, 8)
REF_SCALE_MEDIAN = 0.5
REF_SCALE_LOG_SD = 1.0
#: Pixel noise of a reference's endpoints, as a multiple of the target's corner scale σ.
REF_LINE_FACTOR = 2.0
#: Endpoint step of the central differences of log-length at the pilot, pixels.
_LINE_STEP_PX = 0.5
#: How a reference's drawn segment is read (the option ``line_reading``): ``linear`` (default) as
#: drawn, its noise linearised at the pilot; ``corrected`` less the lengthening its noise brings
#: (:func:`segment_reading`; method.md, "Line noise").
LINE_READINGS = ("linear", "corrected")
DEFAULT_LINE_READING = "linear"
#: Noise draws and segment scales λ of the reading's inversion (:func:`segment_reading`).
READ_DRAWS = 128
READ_SCALES = np.geomspace(1.0 / 128.0, 2.0, 20)
#: Smallest downward component of a unit-depth viewing ray (d_y, with d_z ≈ 1): rays closer to
#: the horizon than this meet the ground at about h / MIN_RAY_DOWN, i.e. 1000 camera heights away.
MIN_RAY_DOWN = 1e-3
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
    confidence : the worker's stated confidence in [0, 1], or None
    measure, mode : the reference's measure and mode (a confidence map may differ by them)
    """

    index: int
    line: np.ndarray
    low: float
    high: float
    is_range: bool
    confidence: float | None = None
    measure: str | None = None
    mode: str | None = None

    @classmethod
    def from_reference(cls, ref, target) -> "ReferenceMeasurement":
        low, high = ref.length_bounds_m(target)
        return cls(ref.index, np.asarray(ref.line, float), float(low), float(high), bool(ref.is_range),
                   None if ref.confidence is None else float(ref.confidence), ref.measure, ref.mode)


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


def ground_lengths(lines: np.ndarray, principal_point, full: np.ndarray) -> np.ndarray:
    """Real lengths of ground segments for a batch of parameter vectors.

    Parameters
    ----------
    lines : (m, 2, 2) segment endpoints, pixels
    principal_point : (2,) pixels
    full : (n, 7) parameter vectors; µ, pitch, roll and the camera height h = y are used

    Returns
    -------
    (n, m) lengths, metres. A ray at or above the horizon is taken to meet the ground
    at 1 / :data:`MIN_RAY_DOWN` camera heights (a huge, finite length).
    """
    full = np.atleast_2d(np.asarray(full, float))
    pts = np.asarray(lines, float).reshape(-1, 2) - np.asarray(principal_point, float)  # (2m, 2)
    R = rotation_from_pitch_roll(full[:, PITCH], full[:, ROLL])  # (n, 3, 3)
    # ray in G: Rᵀ K⁻¹ (u, v, 1) = ((u − cx) R[0] + (v − cy) R[1]) / µ + R[2]  (rows of R)
    d = (pts @ R[:, :2, :]) / full[:, FOCAL, None, None] + R[:, None, 2, :]  # (n, 2m, 3)
    down = np.maximum(d[..., 1], MIN_RAY_DOWN)
    gx, gz = d[..., 0] / down, d[..., 2] / down  # ground point per unit camera height
    return full[:, 1, None] * np.hypot(gx[:, 1::2] - gx[:, 0::2], gz[:, 1::2] - gz[:, 0::2])


def linear_line_variances(lines: np.ndarray, principal_point, full: np.ndarray, sigma: float) -> np.ndarray:
    """σ² |∇ log ℓ|² of each segment at one parameter vector: its reading's variance in log-length
    from end-point noise σ (pixels, per coordinate), linearised by central differences over its
    four end-point coordinates; (m,), zeros for σ = 0 and where the reading is not finite."""
    lines = np.asarray(lines, float).reshape(-1, 2, 2)
    if not len(lines) or sigma == 0:
        return np.zeros(len(lines))
    steps = np.eye(4).reshape(4, 1, 2, 2) * _LINE_STEP_PX  # one end-point coordinate each
    with np.errstate(divide="ignore", invalid="ignore"):
        plus, minus = (np.log(ground_lengths((lines[None] + sign * steps).reshape(-1, 2, 2), principal_point,
                                             np.asarray(full, float).reshape(1, -1)))[0].reshape(4, -1)
                       for sign in (1.0, -1.0))
        var = sigma**2 * np.sum(((plus - minus) / (2 * _LINE_STEP_PX)) ** 2, axis=0)
    return np.where(np.isfinite(var), var, 0.0)


def segment_reading(lines: np.ndarray, principal_point, full: np.ndarray, sigma: float, *,
                    draws: int = READ_DRAWS) -> tuple[np.ndarray, np.ndarray]:
    """How the drawn segments' log-lengths read the true ones, at one parameter vector.

    A segment drawn with end-point noise σ reads long when it is only a few σ long: the noise adds
    length on average, and the ground map is convex towards the horizon. For each segment the
    reading is inverted: among the segments d(λ) = c + λ·(ends − c) (c its midpoint, λ on
    :data:`READ_SCALES`), the one whose noisy readings (``draws`` draws of N(0, σ²) on each end-point
    coordinate, the same draws for every λ and segment, seeded: deterministic) have the drawn
    segment's reading as their median. Its exact log-length is the corrected reading, and

    - ``shift`` = log ℓ(drawn) − log ℓ(d(λ*)), the median bias of the reading in log-length
      (about 0 for a segment many σ long, up to log 128 for one no longer than its noise);
    - ``var`` = σ² |∇ log ℓ(d(λ*))|² × ρ², the linearised variance at d(λ*), times the squared
      ratio ρ of the spreads (half the 16–84 % range) of the *corrected* noisy readings and of
      their linearisation, on the same draws: ρ = 1 for a segment many σ long (the two agree
      draw by draw), larger where the reading stops following the segment; and never less than
      the linearised variance at the drawn segment itself, σ² |∇ log ℓ(drawn)|². (The inversion
      keeps the drawn segment's direction, which noise of the segment's own size has turned: for a
      segment under about 5σ the corrected reading is centred but its errors are heavier-tailed
      than a normal of this variance.)

    Parameters
    ----------
    lines : (m, 2, 2) drawn segments, pixels
    principal_point : (2,) pixels
    full : (7,) parameter vector (µ, pitch, roll and the camera height y are used)
    sigma : end-point noise, pixels (per coordinate)

    Returns
    -------
    (shift (m,), var (m,)) in log-length; zeros for σ = 0 or no segment, and for a segment whose
    reading is not finite.
    """
    lines = np.asarray(lines, float).reshape(-1, 2, 2)
    m = len(lines)
    shift, var = np.zeros(m), np.zeros(m)
    if m == 0 or sigma == 0:
        return shift, var
    full = np.asarray(full, float).reshape(1, -1)

    def log_len(segs):  # (..., m, 2, 2) → (..., m)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(ground_lengths(segs.reshape(-1, 2, 2), principal_point, full))[0].reshape(segs.shape[:-2])

    half = np.random.default_rng(20261125).standard_normal(((draws + 1) // 2, 1, 2, 2))
    noise = sigma * np.concatenate([half, -half])[:draws]  # antithetic: a linear reading's median is exact
    centre = lines.mean(axis=1, keepdims=True)
    lam = np.append(READ_SCALES, 1.0)
    segs = centre[None] + lam[:, None, None, None] * (lines - centre)[None]            # (L, m, 2, 2)
    exact = log_len(segs)                                                               # (L, m)
    median = np.median(log_len(segs[:, None] + noise[None]), axis=1)                    # (L, m)
    r0, exact, median = exact[-1], exact[:-1], median[:-1]
    drawn_var = linear_line_variances(lines, principal_point, full, sigma)
    steps = np.eye(4).reshape(4, 1, 2, 2) * _LINE_STEP_PX
    for j in range(m):
        g, e = np.maximum.accumulate(median[:, j]), exact[:, j]
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(e)) and np.isfinite(r0[j])):
            continue
        g = g + 1e-12 * np.arange(len(g))  # strictly increasing for the interpolation
        log_lam = np.interp(r0[j], g, np.log(READ_SCALES))
        star = centre[j] + np.exp(log_lam) * (lines[j] - centre[j])                     # (2, 2)
        truth = float(np.interp(log_lam, np.log(READ_SCALES), e))
        grad = (log_len(star[None] + steps) - log_len(star[None] - steps))[:, 0] / (2 * _LINE_STEP_PX)
        noisy = log_len(star[None, None] + noise)[:, 0]                                  # (D,)
        corrected = np.interp(noisy, g, e)
        linear = truth + noise.reshape(draws, 4) @ grad
        q = np.percentile(np.stack([corrected, linear]), [16, 84], axis=1)
        spread, spread_lin = 0.5 * (q[1] - q[0])
        lin_var = sigma**2 * float(grad @ grad)
        if np.isfinite(lin_var) and spread_lin > 0:
            shift[j] = r0[j] - truth
            var[j] = max(lin_var * (spread / spread_lin) ** 2, drawn_var[j])
    return shift, var


@dataclass
class MetrologyModel(FreeParameters):
    """The measurement-likelihood model for one handedness of the dimension lines.

    Parameters
    ----------
    camera : Camera (principal point, exact horizon or None, known focal length or None)
    annotations : (n_annotation, 4, 2) every annotation's corners t1..t4, pixels
    dimensions : (length, width, height) of the target, metres
    handedness : +1 or −1
    bounds : Bounds (y's lower bound is raised to :data:`MIN_CAMERA_HEIGHT_M`; µ is fixed when
        the camera's focal length is known)
    references : the references to use (empty for target-only)
    target_sigma : corner scale, pixels; None to estimate it (:func:`estimate_target_sigma`)
    target_dof, ref_dof : see the module constants
    ref_scale : a fixed crowd error scale s in log-length; None (default) integrates it out over
        :data:`REF_SCALE_GRID` (module docstring)
    ref_line_sigma : pixel noise of the references' endpoints (None: :data:`REF_LINE_FACTOR` × σ)
    orientation_free : pitch and roll are parameters; else they follow from ``camera``
    camera_terms : priors on µ, pitch, roll and a horizon measurement (:mod:`.camera_terms`)
    confidence_map : how ranges stated with a confidence are read (module docstring), or None
        to ignore confidences
    line_reading : one of :data:`LINE_READINGS`: read each reference's segment as drawn
        (``linear``, the default) or less the lengthening its line noise brings (``corrected``)
    """

    camera: Camera
    annotations: np.ndarray
    dimensions: tuple[float, float, float]
    handedness: int
    bounds: Bounds
    references: tuple[ReferenceMeasurement, ...] = ()
    target_sigma: float | None = None
    target_dof: float = TARGET_DOF
    ref_scale: float | None = None
    ref_dof: float = REF_DOF
    ref_line_sigma: float | None = None
    orientation_free: bool = False
    camera_terms: CameraTerms = field(default_factory=CameraTerms)
    confidence_map: ConfidenceMap | None = None
    line_reading: str = DEFAULT_LINE_READING
    name: str = field(default="metrology", init=False)
    #: The cost is smooth (no kinks): the optimiser may use Newton steps on it.
    smooth: bool = field(default=True, init=False)
    #: The posterior's temperature for this model (the pipeline uses it when none is given).
    default_temperature: float = field(default=DEFAULT_TEMPERATURE, init=False)

    def __post_init__(self):
        ann = np.asarray(self.annotations, float)
        if ann.ndim == 2:
            ann = ann[None]
        if ann.ndim != 3 or ann.shape[1:] != (4, 2):
            raise ValueError(f"annotations: expected shape (n, 4, 2), got {ann.shape}")
        self.annotations = ann
        if self.line_reading not in LINE_READINGS:
            raise ValueError(f"line_reading: expected one of {list(LINE_READINGS)}, got {self.line_reading!r}")
        for key in ("target_dof", "ref_scale", "ref_dof"):
            v = getattr(self, key)
            if v is None and key == "ref_scale":
                continue
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{key}: expected a finite number > 0, got {v!r}")
        if self.ref_scale is None:
            grid = REF_SCALE_GRID
            log_w = -0.5 * ((np.log(grid) - np.log(REF_SCALE_MEDIAN)) / REF_SCALE_LOG_SD) ** 2
        else:
            grid, log_w = np.array([float(self.ref_scale)]), np.zeros(1)
        self._scale_grid, self._log_w = grid, log_w - np.logaddexp.reduce(log_w)
        #: whether target_sigma is the sets' pooled sd (two or more sets, no scale given)
        self.target_sigma_from_spread = self.target_sigma is None and len(ann) >= 2
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
        self.free = self._free_mask()
        self._split_references()

    def _split_references(self) -> None:
        usable, status = [], {}
        frame = None if self.orientation_free else GroundFrame.from_camera(self.camera)
        for r in self.references:
            if frame is not None and frame.distance(r.line).min() < MIN_HORIZON_PX:
                status[r.index] = "endpoint_above_horizon"
            else:
                usable.append(r)
                status[r.index] = "used"
        self.reference_status = status
        self._lines = np.array([r.line for r in usable]).reshape(-1, 2, 2)
        self.reference_indices = np.array([r.index for r in usable], int)
        self._log_low = np.log([r.low for r in usable])
        self._log_high = np.log([r.high for r in usable])
        self._is_range = np.array([r.is_range for r in usable], bool)
        stated = self._read_confidences(usable)
        self._single = np.flatnonzero(~self._is_range)
        self._range = np.flatnonzero(self._is_range & ~stated)
        self.pilot = None
        self._line_shift = np.zeros(len(usable))
        self._set_line_var(np.zeros(len(usable)))

    def _read_confidences(self, usable) -> np.ndarray:
        """Which usable references are ranges read through the confidence map, (m,) bool; their
        log-centres and scales s_c (module docstring)."""
        cmap = self.confidence_map
        stated = np.array([cmap is not None and r.is_range and r.confidence is not None and r.high > r.low
                           for r in usable], bool)
        self._stated = np.flatnonzero(stated)
        half = 0.5 * (self._log_high - self._log_low)
        self._stated_centre = 0.5 * (self._log_high + self._log_low)[self._stated]
        self._stated_scale = np.array([float(cmap.scale(usable[j].confidence, half[j], usable[j].measure,
                                                        usable[j].mode)) for j in self._stated])
        return stated

    @property
    def line_variances(self) -> np.ndarray:
        """(m,) σ_line² |∇ log ℓ_j|² of the usable references (in the order of
        :attr:`reference_indices`), at the pilot; zeros before :meth:`set_pilot`."""
        return self._line_var.copy()

    @property
    def line_shifts(self) -> np.ndarray:
        """(m,) the median lengthening of each usable reference's reading by its line noise, in
        log-length, at the pilot (:func:`segment_reading`); the model reads log ℓ_j − shift_j.
        Zeros before :meth:`set_pilot` and with ``line_reading="linear"``."""
        return self._line_shift.copy()

    def reference_log_lengths(self, params: np.ndarray) -> np.ndarray:
        """(n, m) the corrected readings log ℓ_j − shift_j of the usable references at (n, 7)
        parameter vectors (−inf or nan where a length is 0 or undefined)."""
        params = np.atleast_2d(np.asarray(params, float))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(ground_lengths(self._lines, self.camera.principal_point, params)) - self._line_shift

    @property
    def n_stated_ranges(self) -> int:
        """References read through the confidence map (ranges with a confidence, below the horizon)."""
        return len(self._stated)

    def _set_line_var(self, line_var: np.ndarray) -> None:
        """σ_line² |∇ log ℓ_j|² per reference, and what the likelihood precomputes from it."""
        self._line_var = line_var
        scales = self.reference_scales  # (m, K)
        self._inv_scales = 1.0 / scales
        self._log_scale_sum = np.log(scales[self._single]).sum(axis=0)  # the singles' normalisers
        sd = np.sqrt(self._stated_scale**2 + line_var[self._stated])
        self._stated_inv_sd, self._stated_log_sd_sum = 1.0 / sd, float(np.log(sd).sum())

    def set_pilot(self, full: np.ndarray) -> None:
        """Fix each reference's line noise at the (7,) parameter vector ``full`` (module docstring):
        its variance (:func:`linear_line_variances`), or with ``line_reading="corrected"`` its
        reading's shift and variance (:func:`segment_reading`).

        The optimiser calls it at its first optimum; the posterior then uses these values.
        """
        full = np.asarray(full, float).reshape(1, -1)
        self.pilot = full[0].copy()
        if not len(self._lines) or self.ref_line_sigma == 0:
            return
        at = np.concatenate([full[0, :1], [max(full[0, 1], MIN_CAMERA_HEIGHT_M)], full[0, 2:]])
        if self.line_reading == "corrected":
            self._line_shift, line_var = segment_reading(self._lines, self.camera.principal_point, at,
                                                         self.ref_line_sigma)
        else:
            line_var = linear_line_variances(self._lines, self.camera.principal_point, at, self.ref_line_sigma)
        self._set_line_var(line_var)

    @property
    def reference_scales(self) -> np.ndarray:
        """(m, K) the scales s_jk = √(s_k² + σ_line² |∇ log ℓ_j|²) of the usable references in
        log-length, for each crowd scale s_k of the grid (K = 1 with a fixed ``ref_scale``); the
        rows of ranges read through the confidence map hold their own √(s_c² + σ_line² |∇ log ℓ_j|²)
        in every column."""
        out = np.sqrt(self._scale_grid[None, :] ** 2 + self._line_var[:, None])
        out[self._stated] = np.sqrt(self._stated_scale**2 + self._line_var[self._stated])[:, None]
        return out

    def crowd_scale_weights(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The posterior weights of the crowd scale grid at (n, 7) parameter vectors: (grid (K,),
        weights (n, K)) — what the references say about how accurate their workers were (the
        ranges read through the confidence map say nothing about it)."""
        per_k = self._log_w - self._reference_terms(self.reference_log_lengths(params))
        return self._scale_grid.copy(), np.exp(per_k - np.logaddexp.reduce(per_k, axis=1, keepdims=True))

    @classmethod
    def from_scene(cls, scene, handedness: int, *, camera: Camera, bounds: Bounds | None = None,
                   use_references: bool = True, orientation_free: bool = False,
                   camera_terms: CameraTerms | None = None, **options) -> "MetrologyModel":
        """The model of ``scene`` for one handedness, with the estimate's ``camera``;
        ``options`` are the settings above."""
        unknown = set(options) - {"target_sigma", "target_dof", "ref_scale", "ref_dof", "ref_line_sigma",
                                  "confidence_map", "line_reading"}
        if unknown:
            raise ValueError(f"metrology model: unknown option(s) {sorted(unknown)}")
        t = scene.target
        refs = tuple(ReferenceMeasurement.from_reference(r, t) for r in scene.references) if use_references else ()
        return cls(camera=camera, annotations=t.corners,
                   dimensions=(t.length, t.width, t.height), handedness=handedness,
                   bounds=bounds or Bounds.default(scene.image_width, scene.image_height),
                   references=refs, orientation_free=orientation_free,
                   camera_terms=camera_terms or CameraTerms(), **options)

    @property
    def n_references_used(self) -> int:
        return len(self._lines)

    # -- the cost --------------------------------------------------------------------------------
    def cost(self, params: np.ndarray) -> np.ndarray:
        """Negative log-posterior (up to a constant) for (n, 7) parameter vectors, shape (n,)."""
        params = np.atleast_2d(np.asarray(params, float))
        projected, depth = project_params(params, self.obj_corners, self.camera.principal_point)
        total = self._target_nll(projected) + BEHIND_CAMERA_PENALTY * np.sum(np.maximum(0.0, 1e-3 - depth), axis=-1)
        if len(self._lines):
            h = np.maximum(params[:, 1], MIN_CAMERA_HEIGHT_M)
            full = params if np.all(params[:, 1] == h) else np.column_stack([params[:, :1], h, params[:, 2:]])
            total = total + self._reference_nll(self.reference_log_lengths(full))
        return total + self.camera_terms.neg_log(params, self.camera.principal_point,
                                                 focal_free=bool(self.free[FOCAL]),
                                                 orientation_free=self.orientation_free) \
            + self.scale_prior_neg_log(params)

    def target_nll(self, params: np.ndarray) -> np.ndarray:
        """The target annotations' part of :meth:`cost`, shape (n,)."""
        projected, _ = project_params(params, self.obj_corners, self.camera.principal_point)
        return self._target_nll(projected)

    def reference_nll(self, params: np.ndarray) -> np.ndarray:
        """The references' part of :meth:`cost`, shape (n,)."""
        params = np.atleast_2d(np.asarray(params, float))
        if not len(self._lines):
            return np.zeros(len(params))
        return self._reference_nll(self.reference_log_lengths(params))

    def _target_nll(self, projected: np.ndarray) -> np.ndarray:
        r2 = np.sum((self.annotations[None] - projected[:, None]) ** 2, axis=-1)  # (n, A, 4)
        nu = self.target_dof
        return 0.5 * (nu + 2.0) * np.sum(np.log1p(r2 / (nu * self.target_sigma**2)), axis=(1, 2))

    def _reference_nll(self, log_len: np.ndarray) -> np.ndarray:
        """−log Σ_k w_k Π_j p(v_j | ℓ_j, s_k) for (n, m) log-lengths, shape (n,), plus the terms
        of the ranges read through the confidence map (outside the mixture)."""
        if self._stated.size and not (self._single.size or self._range.size):
            out = self._stated_nll(log_len)
            return np.where(np.isfinite(out), out, 1e300)
        per_k = self._log_w - self._reference_terms(log_len)  # (n, K)
        top = per_k.max(axis=1)
        with np.errstate(invalid="ignore"):
            # clipped at −600: smaller terms add nothing, and exp into subnormals is slow
            rel = np.maximum(per_k - top[:, None], -600.0)
            out = -(top + np.log(np.exp(rel).sum(axis=1)))
            if self._stated.size:
                out = out + self._stated_nll(log_len)
        return np.where(np.isfinite(out), out, 1e300)

    def _stated_nll(self, log_len: np.ndarray) -> np.ndarray:
        """Σ_j −log p(m_j | ℓ_j) of the ranges read through the confidence map, (n, m) → (n,):
        normal or Student-t (the map's ``dof``) in log-length, constants depending on neither the
        parameters nor the data dropped."""
        z = (self._stated_centre - log_len[:, self._stated]) * self._stated_inv_sd
        dof = self.confidence_map.dof
        if dof is None:
            return 0.5 * np.sum(z * z, axis=1) + self._stated_log_sd_sum
        return (0.5 * (dof + 1.0)) * np.sum(np.log1p(z * z / dof), axis=1) + self._stated_log_sd_sum

    def _reference_terms(self, log_len: np.ndarray) -> np.ndarray:
        """Σ_j −log p(v_j | ℓ_j, s_k) for (n, m) log-lengths, shape (n, K).

        Singles: −log of the t density in log-length (its ν-only constant dropped); ranges: −log of
        the t probability of the stated interval. The scales s_jk are fixed (the grid and the
        pilot's line noise), so the normalisers log s_jk depend on k only and are precomputed.
        """
        nu = self.ref_dof
        inv = self._inv_scales  # (m, K)
        out = np.broadcast_to(self._log_scale_sum, (len(log_len), inv.shape[1])).copy()
        single = self._single
        if single.size:
            z = (self._log_low[single, None] - log_len[:, single, None]) * inv[single]
            out += (0.5 * (nu + 1.0)) * np.log1p(z * z * (1.0 / nu)).sum(axis=1)
        r = self._range
        if r.size:
            a = (self._log_low[r, None] - log_len[:, r, None]) * inv[r]
            b = (self._log_high[r, None] - log_len[:, r, None]) * inv[r]
            p = t_interval(nu, a, b)
            out -= np.log(np.maximum(p, 1e-300)).sum(axis=1)
        return out


def t_interval(nu: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """T_ν(hi) − T_ν(lo), the Student-t probability of [lo, hi] (lo ≤ hi, elementwise), to full
    relative precision far out in either tail.

    An interval in the upper half is mirrored into the lower one (T(b) − T(a) = T(−a) − T(−b)),
    where the tail G(x) = T₂(x) = 1/(r(r − x)), r = √(x² + 2), x ≤ 0, is exact for ν = 2; other ν
    use scipy's ``stdtr``.
    """
    flip = (lo + hi) > 0
    lo, hi = np.where(flip, -hi, lo), np.where(flip, -lo, hi)
    if nu != 2.0:
        return stdtr(nu, hi) - stdtr(nu, lo)
    ah = -np.abs(hi)
    rh, rl = np.sqrt(ah * ah + 2.0), np.sqrt(lo * lo + 2.0)
    g_hi, g_lo = 1.0 / (rh * (rh - ah)), 1.0 / (rl * (rl - lo))
    return np.where(hi <= 0, g_hi, 1.0 - g_hi) - g_lo
