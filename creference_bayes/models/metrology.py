"""The ``metrology`` model: every annotation a measurement (method.md, "The metrology model"), for
any number of objects. It implements the model contract (:mod:`.contract`).

Dimension lines
    Every corner of every annotation of an object is a bivariate Student-t (ν = :data:`TARGET_DOF`)
    around the projected corner, with the object's scale σᵢ (:func:`target_sigmas`). All
    annotations enter jointly; the heavy tails keep one careless annotation from dragging the fit.
References (:class:`ReferenceTerm`)
    Given µ, pitch, roll and the camera height h, a ground segment has a definite real length,
    ℓ = h · ‖ d_p / d_p,y − d_q / d_q,y ‖ with d = Rᵀ K⁻¹ (u, v, 1) the ray of a pixel
    (:func:`ground_lengths`). A worker's value or range measures such a length (``ground``), its
    ratio to a target's length or width (``relative``), a target's own size (``size``) or the
    ground distance between two targets (``distance``, the one term coupling two objects). Each is
    a Student-t (ν = :data:`REF_DOF`) measurement in log-length, a range interval-censored, with
    the crowd's error scale ``ref_scale`` (a camera parameter, log-normal prior:
    :data:`~.contract.REF_SCALE_MEDIAN`, :data:`~.contract.REF_SCALE_LOG_SD`, unless the options
    ``ref_scale_median`` and ``ref_scale_log_sd`` give another, for a crowd measured elsewhere).
Line noise
    Each reference's scale is widened by its line noise, s_j² = s² + v_j, v_j = σ_line² |∇ log ℓ_j|²
    over its endpoint coordinates, σ_line = :data:`REF_LINE_FACTOR` × the median σᵢ unless given;
    with ``line_reading="corrected"`` the reading's median bias is removed too
    (:func:`segment_reading`). Both are taken once, at a *pilot* camera
    (:meth:`MetrologyModel.set_pilot`), and held fixed: recomputed at every state, the normaliser
    −log s_j would reward states where the lines look insensitive.
Stated confidence
    With a confidence map g (:mod:`.confidence_map`), a range stated with confidence c is read as
    the worker's central interval at coverage g(c): its log-centre measures the log-length with
    its own scale s_c = w / q_D((1 + g(c))/2) (w the log half-width), widened by line noise.
The horizon
    With an exact horizon, references with an endpoint on or above it are left out
    (:attr:`MetrologyModel.reference_status`); with pitch and roll free, a ray at or above the
    state's horizon meets the ground very far away (:data:`MIN_RAY_DOWN`): bad but finite.

It is a proper likelihood: the posterior's temperature is 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import stdtr

from ..core.geometry import rotation_from_pitch_roll
from ..core.metrology import GroundFrame
from .confidence_map import ConfidenceMap
from .contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, C_SCALE, O_X, O_Z, Model

__all__ = ["TARGET_DOF", "MIN_TARGET_SIGMA_PX", "DEFAULT_TARGET_SIGMA_PX", "REF_DOF", "REF_LINE_FACTOR",
           "LINE_READINGS", "MIN_RAY_DOWN", "MIN_CAMERA_HEIGHT_M", "MIN_HORIZON_PX", "ReferenceTerm",
           "MetrologyModel", "corner_spread", "target_sigmas", "ground_lengths", "linear_line_variances", "segment_reading",
           "t_interval"]

#: Degrees of freedom of the bivariate Student-t of a target corner.
TARGET_DOF = 4.0
#: Floor of the estimated corner scale, pixels (only annotations that agree exactly reach it).
MIN_TARGET_SIGMA_PX = 0.05
#: Corner scale when no object of the scene has two annotations, pixels.
DEFAULT_TARGET_SIGMA_PX = 5.0
#: Degrees of freedom of a worker's error in log-length.
REF_DOF = 2.0
#: Pixel noise of a reference's endpoints, as a multiple of the objects' corner scale σ.
REF_LINE_FACTOR = 2.0
#: How a reference's drawn segment is read (``line_reading``): ``linear`` (default) as drawn,
#: its noise linearised at the pilot; ``corrected`` less the lengthening its noise brings.
LINE_READINGS = ("linear", "corrected")
#: Endpoint step of the central differences of log-length at the pilot, pixels.
_LINE_STEP_PX = 0.5
#: Noise draws and segment scales λ of the reading's inversion (:func:`segment_reading`).
READ_DRAWS = 128
READ_SCALES = np.geomspace(1.0 / 128.0, 2.0, 20)
#: Smallest downward component of a unit-depth viewing ray: rays closer to the horizon meet the
#: ground at about h / MIN_RAY_DOWN, i.e. 1000 camera heights away.
MIN_RAY_DOWN = 1e-3
#: Lowest camera height the model allows, metres.
MIN_CAMERA_HEIGHT_M = 0.05
#: Reference endpoints closer than this to an exact horizon (or above it) are unusable, pixels.
MIN_HORIZON_PX = 1.0


@dataclass(frozen=True)
class ReferenceTerm:
    """A worker's measurement, as the model reads it.

    ``kind`` is ``ground`` (the real length of the ground segment ``line``, metres), ``relative``
    (that length divided by target ``owner``'s length or width, ``size_index`` 0 or 1), ``size``
    (target ``owner``'s length, width or height, ``size_index`` 0–2, metres; no line) or
    ``distance`` (the ground distance between the bottom centres of targets ``owner`` and
    ``other``, metres; no line). ``low``/``high`` are the stated value (equal) or range;
    ``confidence`` the worker's stated confidence (0–1) or None; ``measure`` and ``mode`` the
    scene's (a confidence map may differ by them).
    """

    index: int
    kind: str
    low: float
    high: float
    is_range: bool
    line: np.ndarray | None = None
    owner: int | None = None
    size_index: int | None = None
    other: int | None = None
    confidence: float | None = None
    measure: str | None = None
    mode: str | None = None

    def __post_init__(self):
        if self.kind not in ("ground", "relative", "size", "distance"):
            raise ValueError(f"reference {self.index}: unknown kind {self.kind!r}")
        lineless = self.kind in ("size", "distance")
        if lineless != (self.line is None):
            raise ValueError(f"reference {self.index}: a {self.kind} reference {'has no' if lineless else 'needs a'} line")
        if self.kind == "distance":
            if self.owner is None or self.other is None or self.owner == self.other:
                raise ValueError(f"reference {self.index}: a distance reference names two different targets")
        elif self.kind != "ground" and (self.owner is None or self.size_index is None):
            raise ValueError(f"reference {self.index}: a {self.kind} reference names a target and a size")


def corner_spread(annotation_sets) -> tuple[np.ndarray, np.ndarray]:
    """Each object's sum of squared corner deviations from its per-corner mean (px²) and its
    degrees of freedom (8 coordinates per annotation beyond the first)."""
    ss = np.array([np.sum((np.asarray(a, float) - np.mean(a, axis=0)) ** 2) for a in annotation_sets])
    return ss, np.array([8.0 * (len(a) - 1) for a in annotation_sets])


def target_sigmas(annotation_sets, corner_scale: tuple[float, float] | None = None) -> np.ndarray:
    """Corner scale σᵢ (pixels) of each object: the pooled standard deviation of its own
    annotations around their per-corner mean when it has two or more; with a single annotation,
    the pooled spread over the scene's objects that have several (the same crowd on the same photo)
    and ``corner_scale`` = (sd px, degrees of freedom), what other frames of the data set found
    (``creference batch``), or :data:`DEFAULT_TARGET_SIGMA_PX` when neither has any. At least
    :data:`MIN_TARGET_SIGMA_PX`."""
    ss, dof = corner_spread(annotation_sets)
    sd, n = (0.0, 0.0) if corner_scale is None else (float(corner_scale[0]), float(corner_scale[1]))
    pooled = np.sqrt((ss.sum() + n * sd**2) / (dof.sum() + n)) if dof.sum() + n > 0 else DEFAULT_TARGET_SIGMA_PX
    own = np.sqrt(ss / np.where(dof > 0, dof, 1.0))
    return np.maximum(np.where(dof > 0, own, pooled), MIN_TARGET_SIGMA_PX)


def ground_lengths(lines: np.ndarray, principal_point, cams: np.ndarray) -> np.ndarray:
    """Real lengths of ground segments for a batch of cameras.

    Parameters
    ----------
    lines : (k, 2, 2) segment endpoints, pixels
    principal_point : (2,) pixels
    cams : (n, 5) cameras (:mod:`.contract` order; µ, pitch, roll and the height are used)

    Returns
    -------
    (n, k) lengths, metres. A ray at or above the horizon is taken to meet the ground at
    1 / :data:`MIN_RAY_DOWN` camera heights (a huge, finite length).
    """
    cams = np.atleast_2d(np.asarray(cams, float))
    pts = np.asarray(lines, float).reshape(-1, 2) - np.asarray(principal_point, float)  # (2k, 2)
    R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])  # (n, 3, 3)
    # ray in G: Rᵀ K⁻¹ (u, v, 1) = ((u − cx) R[0] + (v − cy) R[1]) / µ + R[2]  (rows of R)
    d = (pts @ R[:, :2, :]) / cams[:, C_FOCAL, None, None] + R[:, None, 2, :]  # (n, 2k, 3)
    down = np.maximum(d[..., 1], MIN_RAY_DOWN)
    gx, gz = d[..., 0] / down, d[..., 2] / down  # ground point per unit camera height
    return cams[:, C_HEIGHT, None] * np.hypot(gx[:, 1::2] - gx[:, 0::2], gz[:, 1::2] - gz[:, 0::2])


def _log_lengths(lines, principal_point, camera) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(ground_lengths(lines.reshape(-1, 2, 2), principal_point, np.asarray(camera, float)[None]))[0]


def linear_line_variances(lines: np.ndarray, principal_point, camera: np.ndarray, sigma: float) -> np.ndarray:
    """σ² |∇ log ℓ|² of each segment at one camera (5,): its reading's variance in log-length from
    end-point noise σ (pixels, per coordinate), linearised by central differences over its four
    end-point coordinates; (k,), zeros for σ = 0 and where the reading is not finite."""
    lines = np.asarray(lines, float).reshape(-1, 2, 2)
    if not len(lines) or sigma == 0:
        return np.zeros(len(lines))
    steps = np.eye(4).reshape(4, 1, 2, 2) * _LINE_STEP_PX  # one end-point coordinate each
    plus, minus = (_log_lengths(lines[None] + sign * steps, principal_point, camera).reshape(4, -1)
                   for sign in (1.0, -1.0))
    with np.errstate(invalid="ignore"):
        var = sigma**2 * np.sum(((plus - minus) / (2 * _LINE_STEP_PX)) ** 2, axis=0)
    return np.where(np.isfinite(var), var, 0.0)


def segment_reading(lines: np.ndarray, principal_point, camera: np.ndarray, sigma: float, *,
                    draws: int = READ_DRAWS) -> tuple[np.ndarray, np.ndarray]:
    """How the drawn segments' log-lengths read the true ones, at one camera (5,).

    A segment drawn with end-point noise σ reads long when it is only a few σ long: the noise adds
    length on average, and the ground map is convex towards the horizon. For each segment the
    reading is inverted: among the segments d(λ) = c + λ·(ends − c) (c its midpoint, λ on
    :data:`READ_SCALES`), the one whose noisy readings (``draws`` antithetic draws of N(0, σ²) on
    each end-point coordinate, seeded: deterministic) have the drawn segment's reading as their
    median. Returns ``shift`` = log ℓ(drawn) − log ℓ(d(λ*)) (k,), the median bias of the reading,
    and ``var`` (k,), the linearised variance at d(λ*) times the squared ratio of the spreads of the
    corrected readings and of their linearisation, never less than the linearised variance at the
    drawn segment. Zeros for σ = 0 and where a reading is not finite (method.md, "Line noise").
    """
    lines = np.asarray(lines, float).reshape(-1, 2, 2)
    m = len(lines)
    shift, var = np.zeros(m), np.zeros(m)
    if m == 0 or sigma == 0:
        return shift, var

    def log_len(segs):  # (..., m, 2, 2) → (..., m)
        return _log_lengths(segs, principal_point, camera).reshape(segs.shape[:-2])

    half = np.random.default_rng(20261125).standard_normal(((draws + 1) // 2, 1, 2, 2))
    noise = sigma * np.concatenate([half, -half])[:draws]  # antithetic: a linear reading's median is exact
    centre = lines.mean(axis=1, keepdims=True)
    lam = np.append(READ_SCALES, 1.0)
    segs = centre[None] + lam[:, None, None, None] * (lines - centre)[None]            # (L, m, 2, 2)
    exact = log_len(segs)                                                               # (L, m)
    median = np.median(log_len(segs[:, None] + noise[None]), axis=1)                    # (L, m)
    r0, exact, median = exact[-1], exact[:-1], median[:-1]
    drawn_var = linear_line_variances(lines, principal_point, camera, sigma)
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


class MetrologyModel(Model):
    """The measurement-likelihood model (module docstring) of a scene.

    Parameters
    ----------
    principal_point, image_size, objects : as :class:`~.contract.Model`
    references : the workers' measurements (:class:`ReferenceTerm`)
    target_dof, ref_dof : Student-t degrees of freedom
    target_sigma : one corner scale for every object, pixels (None: :func:`target_sigmas`)
    corner_scale : (sd px, degrees of freedom) of the crowd's corner scale from other frames, pooled
        for the objects with a single annotation (:func:`target_sigmas`), or None
    ref_line_sigma : pixel noise of reference lines (None: :data:`REF_LINE_FACTOR` × the median σᵢ)
    confidence_map : how ranges stated with a confidence are read, or None (confidences ignored)
    line_reading : one of :data:`LINE_READINGS`
    ref_scale_median, ref_scale_log_sd : the crowd scale's log-normal prior (its median, in
        log-length, and its log-sd; None: :data:`~.contract.REF_SCALE_MEDIAN`,
        :data:`~.contract.REF_SCALE_LOG_SD`)
    kw : the contract's options (:class:`~.contract.Model`)
    """

    name = "metrology"
    capabilities = frozenset({"corner_sigma", "object_sigma", "reference_likelihood", "confidence_map"})
    options = ("target_dof", "ref_dof", "target_sigma", "ref_line_sigma", "line_reading", "ground_sd_m",
               "ground_sd_per_m", "ground_dof", "ground_tilt_sd_rad", "ref_scale_median", "ref_scale_log_sd")
    word_options = ("line_reading",)

    def __init__(self, principal_point, image_size, objects, references=(), *, target_dof: float = TARGET_DOF,
                 ref_dof: float = REF_DOF, target_sigma: float | None = None, ref_line_sigma: float | None = None,
                 corner_scale: tuple[float, float] | None = None, confidence_map: ConfidenceMap | None = None,
                 line_reading: str = "linear", ref_scale_median: float | None = None,
                 ref_scale_log_sd: float | None = None, **kw):
        if line_reading not in LINE_READINGS:
            raise ValueError(f"line_reading: expected one of {list(LINE_READINGS)}, got {line_reading!r}")
        if ref_scale_median is not None:
            self.ref_scale_median = ref_scale_median
        if ref_scale_log_sd is not None:
            self.ref_scale_log_sd = ref_scale_log_sd
        for key, v in (("target_dof", target_dof), ("ref_dof", ref_dof), ("ref_scale_median", self.ref_scale_median),
                       ("ref_scale_log_sd", self.ref_scale_log_sd)):
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{key}: expected a finite number > 0, got {v!r}")
        self.ref_scale_median, self.ref_scale_log_sd = float(self.ref_scale_median), float(self.ref_scale_log_sd)
        self.target_dof, self.ref_dof = float(target_dof), float(ref_dof)
        self.confidence_map, self.line_reading = confidence_map, line_reading
        self.all_references = tuple(references)
        super().__init__(principal_point, image_size, objects, **kw)
        lo, hi = self.camera_lower[C_SCALE], self.camera_upper[C_SCALE]
        if not lo <= self.ref_scale_median <= hi:
            raise ValueError(f"ref_scale_median: expected within the crowd scale's bounds [{lo:g}, {hi:g}] "
                             f"(log-length), got {self.ref_scale_median:g}")
        self.camera_lower[C_HEIGHT] = max(self.camera_lower[C_HEIGHT], MIN_CAMERA_HEIGHT_M)
        m, kmax = self.n_objects, max(len(o.annotations) for o in self.objects)
        ann = np.zeros((m, kmax, 4, 2))
        self.ann_mask = np.zeros((m, kmax))
        for i, o in enumerate(self.objects):
            ann[i, :len(o.annotations)] = o.annotations
            self.ann_mask[i, :len(o.annotations)] = 1.0
        # the annotations' u and v apart, (m, K, 4) each: what the likelihood's hot loop reads
        self._ann_u, self._ann_v = np.ascontiguousarray(ann[..., 0]), np.ascontiguousarray(ann[..., 1])
        if target_sigma is None:
            self.sigma = target_sigmas([o.annotations for o in self.objects], corner_scale)
        elif np.isfinite(target_sigma) and target_sigma > 0:
            self.sigma = np.full(m, float(target_sigma))
        else:
            raise ValueError(f"target_sigma: expected a finite number > 0, got {target_sigma!r}")
        self.ref_line_sigma = REF_LINE_FACTOR * float(np.median(self.sigma)) if ref_line_sigma is None else ref_line_sigma
        if not (np.isfinite(self.ref_line_sigma) and self.ref_line_sigma >= 0):
            raise ValueError(f"ref_line_sigma: expected a finite number >= 0, got {ref_line_sigma!r}")
        self._split_references()

    @property
    def has_ref_scale(self) -> bool:
        return any(not self._stated_by_map(r) for r in self._usable())

    # -- references ------------------------------------------------------------------------------
    def _usable(self) -> list[ReferenceTerm]:
        """The references the model reads: with an exact horizon, those whose endpoints lie below it."""
        if self.orientation != "horizon":
            return list(self.all_references)
        frame = GroundFrame(self.horizon_line, self.principal_point)
        return [r for r in self.all_references if r.line is None or frame.distance(r.line).min() >= MIN_HORIZON_PX]

    def _stated_by_map(self, r: ReferenceTerm) -> bool:
        return (self.confidence_map is not None and r.is_range and r.confidence is not None and r.high > r.low)

    def _split_references(self) -> None:
        refs = self.references = tuple(self._usable())
        used = {r.index for r in refs}
        #: index → "used" or "endpoint_above_horizon"
        self.reference_status = {r.index: "used" if r.index in used else "endpoint_above_horizon"
                                 for r in self.all_references}
        self.ref_kind = np.array([r.kind for r in refs], object)
        self.ref_log_low = np.log([r.low for r in refs]) if refs else np.zeros(0)
        self.ref_log_high = np.log([r.high for r in refs]) if refs else np.zeros(0)
        self.ref_is_range = np.array([r.is_range for r in refs], bool)
        self.ref_owner = np.array([-1 if r.owner is None else r.owner for r in refs], int)
        self.ref_size = np.array([-1 if r.size_index is None else r.size_index for r in refs], int)
        self.ref_other = np.array([-1 if r.other is None else r.other for r in refs], int)
        self._distance = self.ref_kind == "distance" if refs else np.zeros(0, bool)
        self._pairs = np.stack([self.ref_owner[self._distance], self.ref_other[self._distance]], axis=1).reshape(-1, 2)
        self._with_line = np.array([r.line is not None for r in refs], bool)
        self._lines = np.array([r.line for r in refs if r.line is not None]).reshape(-1, 2, 2)
        # ranges read through the confidence map: their log-centre and own scale s_c
        self._stated = np.array([self._stated_by_map(r) for r in refs], bool)
        half = 0.5 * (self.ref_log_high - self.ref_log_low)
        self._stated_scale = np.zeros(len(refs))
        for j in np.flatnonzero(self._stated):
            r = refs[j]
            self._stated_scale[j] = float(self.confidence_map.scale(r.confidence, half[j], r.measure, r.mode))
        self.ref_line_var = np.zeros(len(refs))
        self.ref_shift = np.zeros(len(refs))
        self._set_masks()

    @property
    def pairs(self) -> np.ndarray:
        return self._pairs

    @property
    def n_references_used(self) -> int:
        return len(self.references)

    @property
    def n_stated_ranges(self) -> int:
        """References read through the confidence map."""
        return int(self._stated.sum())

    @property
    def needs_pilot(self) -> bool:
        return bool(len(self._lines)) and self.ref_line_sigma > 0

    def set_pilot(self, camera: np.ndarray) -> None:
        """Fix every reference line's noise (and, with ``line_reading="corrected"``, its reading's
        shift) at the (5,) camera ``camera`` (module docstring)."""
        super().set_pilot(camera)
        if not len(self._lines) or self.ref_line_sigma == 0:
            return
        at = self.complete_camera(self.pilot[None])[0]
        at[C_HEIGHT] = max(at[C_HEIGHT], MIN_CAMERA_HEIGHT_M)
        if self.line_reading == "corrected":
            shift, var = segment_reading(self._lines, self.principal_point, at, self.ref_line_sigma)
            self.ref_shift[self._with_line] = shift
        else:
            var = linear_line_variances(self._lines, self.principal_point, at, self.ref_line_sigma)
        self.ref_line_var[self._with_line] = var

    def predicted_log_lengths(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """(n, k) what each reference measures at the states, in log-length (the corrected reading
        for line references)."""
        n = len(cams)
        pred = np.zeros((n, len(self.references)))
        with np.errstate(divide="ignore", invalid="ignore"):
            if len(self._lines):
                pred[:, self._with_line] = np.log(ground_lengths(self._lines, self.principal_point, cams))
                pred[:, self._with_line] -= self.ref_shift[self._with_line]
            owned = (self.ref_owner >= 0) & ~self._distance
            if owned.any():
                log_size = np.log(objs[:, self.ref_owner[owned], 3 + self.ref_size[owned]])
                rel = self.ref_kind[owned] == "relative"
                idx = np.flatnonzero(owned)
                pred[:, idx[rel]] -= log_size[:, rel]
                pred[:, idx[~rel]] = log_size[:, ~rel]
            if self._distance.any():
                a, b = objs[:, self._pairs[:, 0]], objs[:, self._pairs[:, 1]]
                pred[:, self._distance] = np.log(np.hypot(a[..., O_X] - b[..., O_X], a[..., O_Z] - b[..., O_Z]))
        return pred

    def reference_nll_matrix(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each reference, (n, k)."""
        pred = self.predicted_log_lengths(cams, objs)
        nu = self.ref_dof
        crowd = np.sqrt(cams[:, C_SCALE, None] ** 2 + self.ref_line_var[None])  # (n, k)
        own = np.sqrt(self._stated_scale ** 2 + self.ref_line_var)[None]
        s = np.where(self._stated[None], own, crowd)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            lo = (self.ref_log_low[None] - pred) / s
            hi = (self.ref_log_high[None] - pred) / s
            single = -(0.5 * (nu + 1.0)) * np.log1p(lo * lo / nu) - np.log(s)
            ll = np.where(self.ref_is_range[None], np.log(np.maximum(t_interval(nu, lo, hi), 1e-300)), single)
            if self._stated.any():
                z = 0.5 * (lo + hi)  # the log-centre's offset, in its own scales
                dof = self.confidence_map.dof
                stated = (-0.5 * z * z if dof is None else -(0.5 * (dof + 1.0)) * np.log1p(z * z / dof)) - np.log(s)
                ll = np.where(self._stated[None], stated, ll)
        return np.where(np.isfinite(ll), -ll, 1e300)

    def _split_nll(self, nll: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add each object's own references' negative log-likelihood (of ``nll`` (n, k)) to ``obj``
        (n, m) in place; returns the camera's part (n,) and the distance references' (n, P)."""
        owned = (self.ref_owner >= 0) & ~self._distance
        for j in np.flatnonzero(owned):
            obj[:, self.ref_owner[j]] += nll[:, j]
        return nll[:, ~owned & ~self._distance].sum(axis=1), nll[:, self._distance]

    # -- the contract ----------------------------------------------------------------------------
    def _annotation_terms(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, m, K) each annotation's negative log-likelihood (the normalising log σᵢ² included;
        zero for missing ones) and (n, m, 4) the corners' depths."""
        uv, depth = self.project(cams, objs)
        # The MAP's and the sampler's hot loop: u and v apart, in place, and the sum over the four
        # corners written out (numpy's reduce is slow on short axes); the same numbers as
        # log1p(|annotation − projection|² / (ν σ²)) summed over the corners.
        r2 = self._ann_u[None] - uv[:, :, None, :, 0]  # (n, m, K, 4)
        dv = self._ann_v[None] - uv[:, :, None, :, 1]
        r2 *= r2
        dv *= dv
        r2 += dv
        nu = self.target_dof
        r2 /= (nu * self.sigma**2)[None, :, None, None]
        c = np.log1p(r2, out=r2)
        per = 0.5 * (nu + 2.0) * (c[..., 0] + c[..., 1] + c[..., 2] + c[..., 3]) + 4.0 * np.log(self.sigma**2)[None, :, None]
        return per * self.ann_mask[None], depth

    def object_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        per, depth = self._annotation_terms(cams, objs)
        out = per.sum(axis=-1) + self.behind(depth)
        if len(self.references):
            part = np.zeros(out.shape)
            self._split_nll(self.reference_nll_matrix(cams, objs), part)
            out = out + part
        return out

    def camera_nll(self, cams: np.ndarray) -> np.ndarray:
        out = self.horizon_nll(cams)
        ground = self.ref_owner < 0
        if ground.any():
            out = out + self.reference_nll_matrix(cams, np.ones((len(cams), self.n_objects, 7)))[:, ground].sum(axis=1)
        return out

    def pair_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        if not self._distance.any():
            return np.zeros((len(cams), 0))
        return self.reference_nll_matrix(cams, objs)[:, self._distance]

    def terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0):
        """:meth:`~.contract.Model.terms`, the references' likelihood computed once for all three."""
        per, depth = self._annotation_terms(cams, objs)
        cam, obj, pair = self.horizon_nll(cams), per.sum(axis=-1) + self.behind(depth), np.zeros((len(cams), 0))
        if len(self.references):
            cam_part, pair = self._split_nll(self.reference_nll_matrix(cams, objs), obj)
            cam = cam + cam_part
        return (cam / temperature + self.camera_neg_log_prior(cams),
                obj / temperature + self.object_neg_log_prior(cams, objs), pair / temperature)

    def pointwise_log_likelihood(self, cams: np.ndarray, objs: np.ndarray) -> dict[str, np.ndarray]:
        """``annotations`` (n, m, K) (zero for missing ones), ``references`` (n, k), ``horizon`` (n,)."""
        cams = self.complete_camera(cams)
        refs = (-self.reference_nll_matrix(cams, objs) if len(self.references)
                else np.zeros((len(cams), 0)))
        return {"annotations": -self._annotation_terms(cams, objs)[0], "references": refs,
                "horizon": -self.horizon_nll(cams)}
