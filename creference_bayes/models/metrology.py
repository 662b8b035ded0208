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
    A reference's segment is drawn with pixel noise σ_line at each end point (:data:`REF_LINE_FACTOR`
    × the median σᵢ unless given). With ``line_reading="marginal"`` (the default) its true end
    points are marginalised (:func:`marginal_reading`): the reading's error, large and skewed near
    the horizon, is kept as bins (e_b, v_b) of equal probability and the stated value's likelihood
    is the bins' mean of the Student-t around log ℓ_j − e_b with scale √(s² + v_b)
    (:func:`reading_log_likelihood`). ``linear`` reads the segment as drawn with s_j² = s² + v_j,
    v_j = σ_line² |∇ log ℓ_j|² over its endpoint coordinates; ``corrected`` removes the reading's
    median bias too (:func:`segment_reading`). Each is taken at a *pilot* camera
    (:meth:`MetrologyModel.set_pilot`: the optimiser's optimum, then the sampler's warm-up median,
    :func:`~creference_bayes.inference.sampler._repilot`), and held fixed for every state:
    recomputed at every state, the normaliser −log s_j would reward states where the lines look
    insensitive.
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
from scipy.special import gammaln, i0e, stdtr

from ..core.geometry import rotation_from_pitch_roll
from ..core.metrology import GroundFrame
from .confidence_map import ConfidenceMap
from .contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, C_SCALE, O_X, O_Z, Model

__all__ = ["TARGET_DOF", "MIN_TARGET_SIGMA_PX", "DEFAULT_TARGET_SIGMA_PX", "REF_DOF", "REF_LINE_FACTOR",
           "LINE_READINGS", "MIN_RAY_DOWN", "MIN_CAMERA_HEIGHT_M", "MIN_HORIZON_PX", "ReferenceTerm",
           "MetrologyModel", "corner_spread", "target_sigmas", "ground_lengths", "linear_line_variances", "segment_reading",
           "marginal_reading", "segment_floor", "reading_log_likelihood",
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
#: How a reference's drawn segment is read (``line_reading``): ``marginal`` (default) its true end
#: points marginalised (:func:`marginal_reading`); ``linear`` as drawn, its noise linearised at
#: the pilot; ``corrected`` less the median lengthening its noise brings (:func:`segment_reading`).
LINE_READINGS = ("marginal", "linear", "corrected")
#: Endpoint step of the central differences of log-length at the pilot, pixels.
_LINE_STEP_PX = 0.5
#: Noise draws and segment scales λ of the reading's inversion (:func:`segment_reading`).
READ_DRAWS = 128
READ_SCALES = np.geomspace(1.0 / 128.0, 2.0, 20)
#: True segments drawn per reference line and bins of its error in the ``marginal`` reading
#: (:func:`marginal_reading`).
MARGINAL_DRAWS = 1024
READ_NODES = 8
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


def _ground_rays(points: np.ndarray, principal_point, cams: np.ndarray) -> np.ndarray:
    """(n, p, 3) the viewing rays Rᵀ K⁻¹ (u, v, 1) of (p, 2) pixels for (n, 5) cameras; their
    second component is the ray's downward part (≤ 0 at or above the horizon)."""
    pts = np.asarray(points, float).reshape(-1, 2) - np.asarray(principal_point, float)
    R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])  # (n, 3, 3)
    # ray in G: Rᵀ K⁻¹ (u, v, 1) = ((u − cx) R[0] + (v − cy) R[1]) / µ + R[2]  (rows of R)
    return (pts @ R[:, :2, :]) / cams[:, C_FOCAL, None, None] + R[:, None, 2, :]


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
    return cams[:, C_HEIGHT, None] * _unit_lengths(_ground_rays(lines, principal_point, cams))


def _unit_lengths(rays: np.ndarray) -> np.ndarray:
    """(n, k) ground lengths per unit camera height of the segments whose end points' rays are
    (n, 2k, 3) (:func:`_ground_rays`; see :func:`ground_lengths` for rays at the horizon)."""
    down = np.maximum(rays[..., 1], MIN_RAY_DOWN)
    gx, gz = rays[..., 0] / down, rays[..., 2] / down  # ground point per unit camera height
    return np.hypot(gx[..., 1::2] - gx[..., 0::2], gz[..., 1::2] - gz[..., 0::2])


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


def marginal_reading(lines: np.ndarray, principal_point, camera: np.ndarray, sigma: float, *,
                     floor_px: float | None = None, draws: int = MARGINAL_DRAWS,
                     nodes: int = READ_NODES) -> tuple[np.ndarray, np.ndarray]:
    """The error of each drawn segment's reading, its true end points marginalised, at one camera (5,).

    A drawn end point is its true one off by N(0, σ²) per coordinate (σ in pixels). The true end
    points are two ground points, a priori anywhere on the ground and at any separation ℓ on a
    log scale, in any direction: density ∝ 1 / (ℓ² + ℓ₀²) per unit of ground area of each point
    (ℓ₀ the ground length of ``floor_px`` pixels along the image's rows at the drawn segment's
    midpoint; None: σ, the shortest σ pixels show there, below which lengths are not told apart;
    a crowd's own floor is learnt from its drawn lengths, :func:`segment_floor`). Their posterior
    given the drawn end points is sampled by importance: ``draws`` true segments drawn around the
    drawn one (antithetic, seeded: deterministic), each weighted by that
    prior in pixels, 1 / ((ℓ² + ℓ₀²) w₁³ w₂³) (w the downward part of an end point's ray, whose
    cube is the ground map's area scale; zero at or above the horizon). The reading's error
    e = log ℓ(drawn) − log ℓ(true) is then summarised by ``nodes`` bins of equal probability:
    ``shift`` (k, nodes) each bin's mean, ``var`` (k, nodes) its variance (log-length², together
    the law of total variance). Near the horizon e is large, skewed and heavy-tailed (a short
    segment drawn with noise reads long, and a few pixels of a row mean metres of ground); far
    from it, small and normal. Zeros for σ = 0; a segment whose weights are not finite is read
    linearly (no shift, :func:`linear_line_variances` in every bin).
    """
    lines = np.asarray(lines, float).reshape(-1, 2, 2)
    m = len(lines)
    shift, var = np.zeros((m, nodes)), np.zeros((m, nodes))
    if m == 0 or sigma == 0:
        return shift, var
    cam = np.asarray(camera, float)[None]
    half = np.random.default_rng(20261202).standard_normal(((draws + 1) // 2, 1, 2, 2))
    true = lines[None] + sigma * np.concatenate([half, -half])[:draws]                   # (D, m, 2, 2)
    rays = _ground_rays(true, principal_point, cam)[0]                                   # (D·m·2, 3)
    down = rays[:, 1].reshape(draws, m, 2)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        drawn = _unit_lengths(_ground_rays(lines, principal_point, cam)[0])                   # (m,)
        length = _unit_lengths(rays).reshape(draws, m)
        mid = lines.mean(axis=1)
        step = [0.5 * (sigma if floor_px is None else floor_px), 0.0]
        across = np.stack([mid - step, mid + step], axis=1)
        floor = _unit_lengths(_ground_rays(across, principal_point, cam)[0])
        w = np.where(np.all(down > MIN_RAY_DOWN, axis=-1),
                     1.0 / ((length**2 + floor**2) * np.prod(np.maximum(down, MIN_RAY_DOWN), axis=-1) ** 3), 0.0)
        error = np.log(drawn) - np.log(length)
        order = np.argsort(error, axis=0)
        error, w = np.take_along_axis(error, order, 0), np.take_along_axis(w, order, 0)
        cum = np.cumsum(w, axis=0) / w.sum(axis=0)                                          # (D, m)
        # each draw's share of each bin of equal probability: the overlap of its step of the
        # cumulative weight with the bin
        edges = np.arange(nodes + 1) / nodes
        prev = np.vstack([np.zeros((1, m)), cum[:-1]])
        share = np.clip(np.minimum(cum[..., None], edges[1:]) - np.maximum(prev[..., None], edges[:-1]), 0, None)
        mass = share.sum(axis=0)                                                             # (m, nodes)
        shift = np.einsum("dmk,dm->mk", share, error) / mass
        var = np.einsum("dmk,dmk->mk", share, (error[..., None] - shift[None]) ** 2) / mass
    bad = ~(np.all(np.isfinite(shift), axis=1) & np.all(np.isfinite(var), axis=1))
    if bad.any():
        shift[bad] = 0.0
        var[bad] = linear_line_variances(lines[bad], principal_point, camera, sigma)[:, None]
    return shift, var


def segment_floor(lengths_px: np.ndarray, sigma: float, counts: np.ndarray | None = None) -> float:
    """A crowd's floor ℓ₀ of the :func:`marginal_reading` prior, pixels, learnt from its drawn
    segments' lengths (``lengths_px``, drawn with end-point noise ``sigma`` px).

    In units of σ, a drawn segment's vector is its true one plus N(0, 2σ²) per coordinate, so its
    length r given the true length t is Rice(t, √2); the true lengths' law is the reading's prior,
    q(t) = t / (t² + c²) / Z on [0, T] (log-uniform above the floor c; Z = ½ log(1 + T²/c²), T = 1.5 ×
    the longest drawn and at least :data:`_FLOOR_NEAR` + 12). A length r is read through the Rice
    up to :data:`_FLOOR_NEAR`, and as q(r) beyond, where q hardly changes over the noise (its log's
    slope at most 1/r). The floor returned is c σ with c the maximum of the drawn lengths'
    likelihood (0.05–50): a crowd that seldom draws segments a few σ long gets a high floor, one
    whose segments are often no longer than their noise a low one. ``counts``: how many segments
    each length stands for (default 1). NaN when there are no segments or σ is not positive.
    """
    r = np.asarray(lengths_px, float).ravel()
    n = np.ones(len(r)) if counts is None else np.asarray(counts, float).ravel()
    ok = np.isfinite(r) & (n > 0)
    r, n = r[ok], n[ok]
    if not len(r) or not sigma > 0:
        return float("nan")
    r = np.maximum(r / sigma, 1e-3)
    top = max(1.5 * r.max(), _FLOOR_NEAR + 12.0)
    near = r <= _FLOOR_NEAR
    t = np.linspace(0.0, _FLOOR_NEAR + 12.0, 1201)
    rn = r[near][:, None]
    rice = (rn / 2.0) * np.exp(-((rn - t) ** 2) / 4.0) * i0e(rn * t / 2.0) * (t[1] - t[0])   # Rice(r; t, √2) dt

    def nll(log_c):
        c2 = np.exp(2 * log_c)
        z = 0.5 * np.log1p(top**2 / c2)
        p = np.empty(len(r))
        p[near] = rice @ (t / (t**2 + c2)) / z
        p[~near] = r[~near] / (r[~near] ** 2 + c2) / z
        return -n @ np.log(p)

    from scipy.optimize import minimize_scalar  # the optimiser only here: reading a model needs none

    return float(sigma * np.exp(minimize_scalar(nll, bounds=(np.log(0.05), np.log(50.0)), method="bounded").x))


#: Drawn lengths (in σ) up to this are read through the Rice convolution (:func:`segment_floor`).
_FLOOR_NEAR = 30.0


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


def reading_log_likelihood(pred, scale, log_low, log_high, is_range, nu: float, node_shift, node_var,
                           own_scale=None, own_dof: float | None = None) -> np.ndarray:
    """Log-likelihood of stated values or ranges given what the references measure, the reading's
    error marginalised over its bins (:attr:`MetrologyModel.ref_node_shift`).

    Bin b is a Student-t (ν = ``nu``) of log-length around ``pred`` − ``node_shift``[b] with scale
    √(``scale``² + ``node_var``[b]) (a range: its probability, interval-censored); the
    likelihood is the bins' mean. Where ``own_scale`` is finite (ranges read through a confidence
    map), the range's log-centre is a measurement with that scale instead, Student-t of ``own_dof``
    (None: normal). A value's density leaves out its constant (the same for every state); the
    bins' mean of a probability or density is floored at 1e-300 (values and ranges are averaged as
    densities and probabilities, with no logarithm per bin).

    Parameters
    ----------
    pred : (n, k) log-lengths (:meth:`MetrologyModel.predicted_log_lengths`)
    scale : (n, 1) or (n, k) the crowd's scale, log-length
    log_low, log_high, is_range : (k,) the stated values (equal) or ranges, log-length
    node_shift, node_var : (k, K) the reading's error bins
    own_scale : (k,) or None

    Returns
    -------
    (n, k) log-likelihoods (NaN where ``pred`` is)
    """
    pred, node_shift, node_var = np.asarray(pred, float), np.asarray(node_shift, float), np.asarray(node_var, float)
    log_low, log_high = np.asarray(log_low, float), np.asarray(log_high, float)
    n, k = pred.shape
    stated = np.zeros(k, bool) if own_scale is None else np.isfinite(own_scale)
    ranged = np.asarray(is_range, bool) & ~stated
    # References of one bin repeat it; when every reference has one, one bin is read.
    bins = node_shift.shape[1] if (np.ptp(node_shift, axis=-1).any() or np.ptp(node_var, axis=-1).any()) else 1
    node_shift, node_var = node_shift[:, :bins], node_var[:, :bins]
    out = np.empty((n, k))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
        s = np.sqrt(np.asarray(scale, float)[..., None] ** 2 + node_var)                        # (n, k, K)
        loc = pred[..., None] - node_shift
        if stated.any():  # the range's centre, a measurement of its own scale (normal: in the log domain)
            sc = np.sqrt(np.asarray(own_scale, float)[stated, None] ** 2 + node_var[stated])
            z = (0.5 * (log_low[stated] + log_high[stated])[:, None] - loc[:, stated]) / sc
            log_p = (-0.5 * z * z if own_dof is None else -(0.5 * (own_dof + 1.0)) * np.log1p(z * z / own_dof)) - np.log(sc)
            top = np.max(log_p, axis=-1)
            out[:, stated] = top + np.log(np.mean(np.exp(log_p - top[..., None]), axis=-1))
        # values and ranges: each bin's density or probability, their mean over the bins
        cols = ~stated
        z = (log_low[cols, None] - loc[:, cols]) / s[:, cols]
        of_range = ranged[cols]
        p = np.empty_like(z)
        t = 1.0 + z[:, ~of_range] ** 2 / nu
        p[:, ~of_range] = (1.0 / (t * np.sqrt(t)) if nu == 2.0 else t ** (-0.5 * (nu + 1.0))) / s[:, cols & ~ranged]
        if of_range.any():
            p[:, of_range] = t_interval(nu, z[:, of_range], (log_high[ranged, None] - loc[:, ranged]) / s[:, ranged])
        out[:, cols] = np.log(np.maximum(p.sum(axis=-1) * (1.0 / bins), 1e-300))
    return out


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
    read_floor_px : the floor of the ``marginal`` reading's prior of a segment's length, pixels
        (None: ``ref_line_sigma``; a crowd's, learnt from its drawn lengths: :func:`segment_floor`)
    confidence_map : how ranges stated with a confidence are read, or None (confidences ignored)
    line_reading : one of :data:`LINE_READINGS`
    ref_scale_median, ref_scale_log_sd : the crowd scale's log-normal prior (its median, in
        log-length, and its log-sd; None: :data:`~.contract.REF_SCALE_MEDIAN`,
        :data:`~.contract.REF_SCALE_LOG_SD`)
    kw : the contract's options (:class:`~.contract.Model`)
    """

    name = "metrology"
    capabilities = frozenset({"corner_sigma", "object_sigma", "reference_likelihood", "confidence_map"})
    options = ("target_dof", "ref_dof", "target_sigma", "ref_line_sigma", "read_floor_px", "line_reading",
               "ground_sd_m",
               "ground_sd_per_m", "ground_dof", "ground_tilt_sd_rad", "ref_scale_median", "ref_scale_log_sd")
    word_options = ("line_reading",)

    def __init__(self, principal_point, image_size, objects, references=(), *, target_dof: float = TARGET_DOF,
                 ref_dof: float = REF_DOF, target_sigma: float | None = None, ref_line_sigma: float | None = None,
                 read_floor_px: float | None = None,
                 corner_scale: tuple[float, float] | None = None, confidence_map: ConfidenceMap | None = None,
                 line_reading: str = "marginal", ref_scale_median: float | None = None,
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
        #: the crowd's corner scale from other frames it was built with (None: none)
        self.corner_scale = None if corner_scale is None else (float(corner_scale[0]), float(corner_scale[1]))
        if target_sigma is None:
            self.sigma = target_sigmas([o.annotations for o in self.objects], corner_scale)
        elif np.isfinite(target_sigma) and target_sigma > 0:
            self.sigma = np.full(m, float(target_sigma))
        else:
            raise ValueError(f"target_sigma: expected a finite number > 0, got {target_sigma!r}")
        self.ref_line_sigma = REF_LINE_FACTOR * float(np.median(self.sigma)) if ref_line_sigma is None else ref_line_sigma
        if not (np.isfinite(self.ref_line_sigma) and self.ref_line_sigma >= 0):
            raise ValueError(f"ref_line_sigma: expected a finite number >= 0, got {ref_line_sigma!r}")
        if read_floor_px is not None and not (np.isfinite(read_floor_px) and read_floor_px > 0):
            raise ValueError(f"read_floor_px: expected a finite number > 0, got {read_floor_px!r}")
        self.read_floor_px = None if read_floor_px is None else float(read_floor_px)
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
        #: the reading's error beyond ``ref_shift``, in bins of equal probability (k, K): each
        #: bin's mean offset and variance, log-length (one bin unless ``line_reading="marginal"``)
        self.ref_node_shift = np.zeros((len(refs), 1))
        self.ref_node_var = np.zeros((len(refs), 1))
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
        """Fix every reference line's reading error at the (5,) camera ``camera`` (module
        docstring): its shift, spread and (``marginal``) shape."""
        super().set_pilot(camera)
        if not len(self._lines) or self.ref_line_sigma == 0:
            return
        at = self.complete_camera(self.pilot[None])[0]
        at[C_HEIGHT] = max(at[C_HEIGHT], MIN_CAMERA_HEIGHT_M)
        lines = self._with_line
        if self.line_reading == "marginal":
            nodes, var = marginal_reading(self._lines, self.principal_point, at, self.ref_line_sigma,
                                          floor_px=self.read_floor_px)
            centre = nodes.mean(axis=1)
            self.ref_shift[lines] = centre
            self.ref_node_shift = np.zeros((len(self.references), nodes.shape[1]))
            self.ref_node_var = np.zeros_like(self.ref_node_shift)
            self.ref_node_shift[lines], self.ref_node_var[lines] = nodes - centre[:, None], var
            self.ref_line_var[lines] = np.mean(var + (nodes - centre[:, None]) ** 2, axis=1)
            return
        if self.line_reading == "corrected":
            shift, var = segment_reading(self._lines, self.principal_point, at, self.ref_line_sigma)
            self.ref_shift[lines] = shift
        else:
            var = linear_line_variances(self._lines, self.principal_point, at, self.ref_line_sigma)
        self.ref_line_var[lines] = var
        self.ref_node_var[lines, 0] = var

    def predicted_log_lengths(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """(n, k) what each reference measures at the states, in log-length (for a line, its
        reading less its shift: the mean true log-length with ``marginal``)."""
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
        own = np.where(self._stated, self._stated_scale, np.nan)
        ll = reading_log_likelihood(self.predicted_log_lengths(cams, objs), cams[:, C_SCALE, None], self.ref_log_low,
                                    self.ref_log_high, self.ref_is_range, self.ref_dof, self.ref_node_shift,
                                    self.ref_node_var, own, None if self.confidence_map is None else self.confidence_map.dof)
        return np.where(np.isfinite(ll), -ll, 1e300)

    def reference_log_densities(self, cams: np.ndarray, objs: np.ndarray, dofs, scale_factors=(1.0,)) -> np.ndarray:
        """(S, D, n, k) each reference's log-likelihood read with a Student-t of each of ``dofs``
        (D) degrees of freedom and the crowd's scale × each of ``scale_factors`` (S), normalised
        so that tails compare: a stated value's density in log-length with its constant, a range's
        probability; NaN for a range read through a confidence map (its tail is the map's) and
        where the reading is undefined."""
        stated = self._stated
        own = np.where(stated, self._stated_scale, np.nan)
        pred = self.predicted_log_lengths(cams, objs)
        value = ~np.asarray(self.ref_is_range, bool) & ~stated
        out = np.empty((len(scale_factors), len(dofs), *pred.shape))
        for a, c in enumerate(scale_factors):
            for b, nu in enumerate(map(float, dofs)):
                ll = reading_log_likelihood(pred, c * cams[:, C_SCALE, None], self.ref_log_low, self.ref_log_high,
                                            self.ref_is_range, nu, self.ref_node_shift, self.ref_node_var, own, None)
                const = gammaln(0.5 * (nu + 1.0)) - gammaln(0.5 * nu) - 0.5 * np.log(nu * np.pi)
                out[a, b] = np.where(stated | ~np.isfinite(ll), np.nan, ll + np.where(value, const, 0.0))
        return out

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

    def annotation_nll(self, uv: np.ndarray, i: int) -> np.ndarray:
        """(n,) object ``i``'s part of :meth:`_annotation_terms` summed over its sets (the normalising
        log σᵢ² included), its corners projected at ``uv`` (n, 4, 2) pixels (:meth:`project`): for a
        caller that changes one object's sets or σᵢ and not the projection."""
        ann = np.asarray(self.objects[i].annotations, float)                  # (K, 4, 2)
        nu, s2 = float(self.target_dof), float(self.sigma[i]) ** 2
        r2 = np.sum(np.square(ann[None] - np.asarray(uv, float)[:, None]), axis=-1)   # (n, K, 4)
        return 0.5 * (nu + 2.0) * np.sum(np.log1p(r2 / (nu * s2)), axis=(1, 2)) + 4.0 * np.log(s2) * len(ann)

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
