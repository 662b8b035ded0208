"""The frame model: every object of one photo, one shared camera (docs/frames.md).

The model's contract
--------------------
Parameters come in named blocks: one **camera** block shared by all objects,

    camera = (focal_length_px, pitch, roll, height_m, ref_scale)      px, rad, rad, m, 1

and one **object** block per target,

    object = (x, z, yaw, length_m, width_m, height_m, ground_m)        m, m, rad, m, m, m, m

(:data:`CAMERA_NAMES`, :data:`OBJECT_NAMES`). Arrays are ``cams (n, 5)`` and ``objs (n, m, 7)``
for n states of a frame with m objects. A parameter is *free* (sampled) or *fixed* (a known
focal length, a known size, no references so no crowd scale, …); pitch and roll may also be
*derived* from an exact horizon and µ (:meth:`FrameModel.complete_camera`).

The posterior is ``log p = log-likelihood / T + log-prior``: the likelihood and the priors are
separate methods (:meth:`FrameModel.object_nll`, :meth:`FrameModel.camera_nll`,
:meth:`FrameModel.object_neg_log_prior`, :meth:`FrameModel.camera_neg_log_prior`), so a
temperature widens what the annotations say and never the priors. Given the camera, objects are
independent: every object term depends on the camera and its own block only, which is what lets
the optimiser and the sampler scale with the number of objects. The one exception is a worker's
distance between two targets: a *pair* term (:meth:`FrameModel.pair_terms`) of the two objects'
blocks and the crowd's scale.

Geometry
    The gravity-aligned camera frame has x right, y down, z forward; the reference ground plane is
    y = ``height_m`` (the camera's height above it). An object's bottom centre is
    (x, height_m − ground_m, z): ``ground_m`` is how far its own ground lies above the reference
    plane (real roads are not flat; prior N(0, ``ground_sd_m``²), fixed at 0 in a one-object
    frame, where the plane is defined by the object). Its box turns by ``yaw`` about y and its
    dimension lines follow :func:`~creference_bayes.core.geometry.dimension_corners` with the
    object's handedness. The camera's pitch and roll are relative to the reference plane.

Likelihood
    * Dimension lines: every corner of every annotation is a bivariate Student-t (ν = 4) around
      the projected corner, with the object's scale σᵢ (the spread of its own annotations, or the
      frame's pooled spread when it has a single annotation; :func:`target_sigmas`).
    * References (:class:`FrameReference`): a worker's value or range for the real length of a
      ground segment (``ground``), a ratio of a segment to a target's length or width
      (``relative``), a target's own length, width or height (``size``), or the ground distance
      between the bottom centres of two targets (``distance``; the one term that couples two
      objects given the camera); each a Student-t
      (ν = 2) measurement in log-length with the crowd's scale ``ref_scale`` (a camera parameter
      with a log-normal prior, median 0.5, log-sd 1), widened by the segment's line noise at a
      pilot estimate (as the metrology model, method.md).
    * The horizon, when measured (from the photo or stated with an uncertainty): its two points
      lie N(0, σ²) from the predicted horizon (a bivariate Student-t of the same scale when the
      measurement says so: the photo's estimate has heavy tails), σ² = σ_h² + (µ tan τ)², τ the
      ground plane's tilt
      from level (``ground_tilt_sd_rad``): a level horizon says where gravity is, the camera's
      pitch and roll are relative to the road.

Priors
    Focal length, pitch, roll and camera height as the single-target model
    (:mod:`.camera_terms`); sizes from the class (:mod:`.size_priors`); ground offsets normal;
    each object's location ``log-depth`` (p(x, z) ∝ 1/z: uniform in log depth, the single-target
    default and its reasons in :mod:`.location_prior`) or ``flat`` in (x, z), inside the bounds.

The MAP
    is taken in log depth (:meth:`FrameModel.map_objective`): the mode of the density over
    (x, log z), so that a prior in 1/z and the Jacobian z of log z cancel and the MAP does not
    depend on the choice between the two priors (as the single-target MAP in log coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.geometry import rotation_from_pitch_roll, pitch_roll_from_horizon
from .camera_terms import CameraTerms, OrientationPrior, horizon_offsets
from .metrology import (DEFAULT_TARGET_SIGMA_PX, MIN_TARGET_SIGMA_PX, REF_DOF, REF_LINE_FACTOR,
                        REF_SCALE_LOG_SD, REF_SCALE_MEDIAN, TARGET_DOF, ground_lengths,
                        linear_line_variances, t_interval)
from .params import MAX_PITCH, MAX_ROLL
from .size_priors import SizePrior

__all__ = ["CAMERA_NAMES", "CAMERA_UNITS", "OBJECT_NAMES", "OBJECT_UNITS", "C_FOCAL", "C_PITCH", "C_ROLL",
           "C_HEIGHT", "C_SCALE", "O_X", "O_Z", "O_YAW", "O_SIZE", "O_GROUND", "DEFAULT_GROUND_SD_M",
           "DEFAULT_GROUND_TILT_SD_RAD", "FRAME_LOCATION_PRIORS", "ObjectData", "FrameReference", "FrameModel", "target_sigmas",
           "object_corners"]

CAMERA_NAMES = ("focal_length_px", "pitch", "roll", "height_m", "ref_scale")
CAMERA_UNITS = ("px", "rad", "rad", "m", "1")
OBJECT_NAMES = ("x", "z", "yaw", "length_m", "width_m", "height_m", "ground_m")
OBJECT_UNITS = ("m", "m", "rad", "m", "m", "m", "m")
C_FOCAL, C_PITCH, C_ROLL, C_HEIGHT, C_SCALE = range(5)
O_X, O_Z, O_YAW = 0, 1, 2
O_SIZE = slice(3, 6)
O_GROUND = 6
#: Spread of an object's ground around the frame's plane, metres: on 51 KITTI frames, the bottoms
#: of the labelled objects (4 or more a frame) scatter about a fitted plane with a standard
#: deviation of 0.075 m (90th percentile 0.12 m, largest 0.23 m); see docs/frames.md.
DEFAULT_GROUND_SD_M = 0.08
#: Tilt of the ground plane from level, radians: the same fits tilt by 1.1° (across) and 0.6°
#: (along the road) in standard deviation from KITTI's level rectified camera.
DEFAULT_GROUND_TILT_SD_RAD = float(np.radians(1.0))
#: Location priors of a frame's objects (module docstring); the first is the default.
FRAME_LOCATION_PRIORS = ("log-depth", "flat")
#: Behind-the-camera penalty per metre (as the single-target models).
_BEHIND = 1e6


def object_corners(sizes: np.ndarray, handedness: np.ndarray) -> np.ndarray:
    """Object-frame dimension-line corners c1..c4 for variable sizes.

    Parameters
    ----------
    sizes : (..., m, 3) length, width, height, metres
    handedness : (m,) ±1

    Returns
    -------
    (..., m, 4, 3) metres (object frame: x along the length, y down, z along the width)
    """
    l, w, h = sizes[..., 0], sizes[..., 1], sizes[..., 2]
    s = np.asarray(handedness, float)
    out = np.zeros(sizes.shape[:-1] + (4, 3))
    out[..., :, 0] = -0.5 * l[..., None]
    out[..., :, 2] = (-0.5 * s * w)[..., None]
    out[..., 1, 0] += l
    out[..., 2, 2] += s * w
    out[..., 3, 1] = -h
    return out


@dataclass(frozen=True)
class ObjectData:
    """One target of a frame as the model sees it.

    Attributes
    ----------
    id : the target's id
    annotations : (K, 4, 2) corners t1..t4 of its K annotations, pixels
    handedness : +1 or −1
    sizes : (3,) known length, width, height (m), or None when the size prior applies
    size_prior : the class's prior (used when ``sizes`` is None)
    cls : the class name, or None
    """

    id: str
    annotations: np.ndarray
    handedness: int = 1
    sizes: tuple[float, float, float] | None = None
    size_prior: SizePrior | None = None
    cls: str | None = None

    def __post_init__(self):
        a = np.asarray(self.annotations, float)
        if a.ndim != 3 or a.shape[1:] != (4, 2) or len(a) == 0:
            raise ValueError(f"target {self.id!r}: annotations must have shape (K, 4, 2), got {a.shape}")
        object.__setattr__(self, "annotations", a)
        if self.sizes is None and self.size_prior is None:
            raise ValueError(f"target {self.id!r}: needs known sizes or a size prior")

    @property
    def initial_sizes(self) -> np.ndarray:
        return np.asarray(self.sizes if self.sizes is not None else self.size_prior.median_m, float)


@dataclass(frozen=True)
class FrameReference:
    """A worker's measurement, as the frame model reads it.

    ``kind`` is ``ground`` (the real length of the ground segment ``line``, metres), ``relative``
    (that length divided by target ``owner``'s length or width, ``size_index`` 0 or 1), ``size``
    (target ``owner``'s length, width or height, ``size_index`` 0–2, metres; no line) or
    ``distance`` (the distance on the ground between the bottom centres of targets ``owner`` and
    ``other``, metres; no line). ``low``/``high`` are the stated value (equal) or range.
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


def target_sigmas(annotation_sets) -> np.ndarray:
    """Corner scale σᵢ (pixels) of each object: the pooled standard deviation of its own
    annotations around their per-corner mean when it has two or more; with a single annotation,
    the frame's pooled spread over the objects that have several (the same crowd on the same photo),
    or :data:`~.metrology.DEFAULT_TARGET_SIGMA_PX` when none has. At least
    :data:`~.metrology.MIN_TARGET_SIGMA_PX`."""
    ss = np.array([np.sum((a - a.mean(axis=0)) ** 2) for a in annotation_sets])
    dof = np.array([8.0 * (len(a) - 1) for a in annotation_sets])
    pooled = np.sqrt(ss.sum() / dof.sum()) if dof.sum() > 0 else DEFAULT_TARGET_SIGMA_PX
    own = np.sqrt(ss / np.where(dof > 0, dof, 1.0))
    return np.maximum(np.where(dof > 0, own, pooled), MIN_TARGET_SIGMA_PX)


@dataclass
class FrameModel:
    """The joint model of one frame (module docstring for the contract).

    Parameters
    ----------
    principal_point : (2,) pixels
    image_size : (width, height) pixels
    objects : the targets
    references : the workers' measurements
    camera_terms : priors on µ, pitch and roll, the height prior, a horizon measurement
    orientation : ``free`` (pitch and roll are parameters), ``horizon`` (derived from
        ``horizon_line`` and µ) or ``level`` (both 0)
    horizon_line : (3,) the exact horizon for ``horizon``
    focal_length_px : a known focal length, or None
    ground_sd_m : prior sd of the objects' ground offsets (0: fixed at 0; forced to 0 with one object)
    ground_tilt_sd_rad : the ground's tilt from level, widening a measured horizon
    target_dof, ref_dof : Student-t degrees of freedom
    ref_line_sigma : pixel noise of reference lines (None: 2 × the median σᵢ)
    location_prior : ``log-depth`` (p ∝ 1/z per object) or ``flat``
    """

    principal_point: np.ndarray
    image_size: tuple[int, int]
    objects: tuple[ObjectData, ...]
    references: tuple[FrameReference, ...] = ()
    camera_terms: CameraTerms = field(default_factory=CameraTerms)
    orientation: str = "free"
    horizon_line: np.ndarray | None = None
    focal_length_px: float | None = None
    ground_sd_m: float = DEFAULT_GROUND_SD_M
    ground_tilt_sd_rad: float = DEFAULT_GROUND_TILT_SD_RAD
    target_dof: float = TARGET_DOF
    ref_dof: float = REF_DOF
    ref_line_sigma: float | None = None
    height_prior: OrientationPrior = field(default_factory=OrientationPrior)
    location_prior: str = FRAME_LOCATION_PRIORS[0]
    name: str = field(default="frame", init=False)

    def __post_init__(self):
        if self.location_prior not in FRAME_LOCATION_PRIORS:
            raise ValueError(f"location_prior: expected one of {list(FRAME_LOCATION_PRIORS)}, got {self.location_prior!r}")
        if self.orientation not in ("free", "horizon", "level"):
            raise ValueError(f"orientation: expected free, horizon or level, got {self.orientation!r}")
        if self.orientation == "horizon" and self.horizon_line is None:
            raise ValueError("orientation 'horizon' needs horizon_line")
        if not self.objects:
            raise ValueError("a frame needs at least one target")
        self.principal_point = np.asarray(self.principal_point, float)
        m = len(self.objects)
        if m == 1:
            self.ground_sd_m = 0.0
        kmax = max(len(o.annotations) for o in self.objects)
        self.ann = np.zeros((m, kmax, 4, 2))
        self.ann_mask = np.zeros((m, kmax))
        for i, o in enumerate(self.objects):
            self.ann[i, :len(o.annotations)] = o.annotations
            self.ann_mask[i, :len(o.annotations)] = 1.0
        self.sigma = target_sigmas([o.annotations for o in self.objects])
        self.handedness = np.array([o.handedness for o in self.objects], float)
        if self.ref_line_sigma is None:
            self.ref_line_sigma = REF_LINE_FACTOR * float(np.median(self.sigma))
        self._set_bounds_and_masks()
        self._split_references()

    # -- blocks, bounds, fixed values ------------------------------------------------------------
    def _set_bounds_and_masks(self) -> None:
        side = float(max(self.image_size))
        self.camera_lower = np.array([0.1 * side, -MAX_PITCH, -MAX_ROLL, 0.05, 0.005])
        self.camera_upper = np.array([10 * side, MAX_PITCH, MAX_ROLL, 50.0, 3.0])
        self.object_lower = np.array([-500.0, 0.1, -np.inf, 0.01, 0.01, 0.01, -5.0])
        self.object_upper = np.array([500.0, 1000.0, np.inf, 100.0, 100.0, 100.0, 5.0])
        cf = np.ones(5, bool)
        if self.focal_length_px is not None:
            cf[C_FOCAL] = False
        if self.orientation != "free":
            cf[[C_PITCH, C_ROLL]] = False
        cf[C_SCALE] = bool(self.references)
        self.camera_free = cf
        of = np.ones((len(self.objects), 7), bool)
        for i, o in enumerate(self.objects):
            if o.sizes is not None:
                of[i, O_SIZE] = False
        of[:, O_GROUND] = self.ground_sd_m > 0
        self.object_free = of
        self.sizes_known = ~of[:, O_SIZE].any(axis=1)
        self._size_mu = np.array([o.size_prior.log_median if o.sizes is None else np.zeros(3) for o in self.objects])
        self._size_inv_sd = np.array([1.0 / np.asarray(o.size_prior.log_sd) if o.sizes is None else np.zeros(3)
                                      for o in self.objects])
        self._size_on = np.array([[o.sizes is None] * 3 for o in self.objects], float)
        # the height prior: always, unless an exact horizon and known sizes pin the scale
        self.use_height_prior = self.orientation == "free" or not bool(np.all(self.sizes_known))

    @property
    def n_objects(self) -> int:
        return len(self.objects)

    @property
    def n_free(self) -> int:
        return int(self.camera_free.sum() + self.object_free.sum())

    def complete_camera(self, cams: np.ndarray) -> np.ndarray:
        """(n, 5) camera vectors with the fixed and derived entries filled in (µ when known, pitch
        and roll from an exact horizon or level, the crowd scale when there are no references)."""
        cams = np.array(np.atleast_2d(cams), float)
        if self.focal_length_px is not None:
            cams[:, C_FOCAL] = self.focal_length_px
        if self.orientation == "horizon":
            cams[:, C_PITCH], cams[:, C_ROLL] = pitch_roll_from_horizon(self.horizon_line, cams[:, C_FOCAL],
                                                                        self.principal_point)
        elif self.orientation == "level":
            cams[:, C_PITCH] = cams[:, C_ROLL] = 0.0
        if not self.camera_free[C_SCALE]:
            cams[:, C_SCALE] = REF_SCALE_MEDIAN
        return cams

    def in_bounds(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """(n,) bool: every camera and object parameter inside its bounds (yaw is circular)."""
        ok = np.all((cams >= self.camera_lower) & (cams <= self.camera_upper), axis=1)
        with np.errstate(invalid="ignore"):
            inside = (objs >= self.object_lower) & (objs <= self.object_upper)
        inside[..., O_YAW] = np.isfinite(objs[..., O_YAW])
        return ok & np.all(inside, axis=(1, 2))

    # -- references ------------------------------------------------------------------------------
    def _split_references(self) -> None:
        refs = self.references
        self.ref_kind = np.array([r.kind for r in refs], object)
        self.ref_log_low = np.log([r.low for r in refs]) if refs else np.zeros(0)
        self.ref_log_high = np.log([r.high for r in refs]) if refs else np.zeros(0)
        self.ref_is_range = np.array([r.is_range for r in refs], bool)
        self.ref_owner = np.array([-1 if r.owner is None else r.owner for r in refs], int)
        self.ref_size = np.array([-1 if r.size_index is None else r.size_index for r in refs], int)
        self.ref_other = np.array([-1 if r.other is None else r.other for r in refs], int)
        self._distance = self.ref_kind == "distance" if refs else np.zeros(0, bool)
        #: (P, 2) the targets each distance reference couples (in reference order)
        self.pairs = np.stack([self.ref_owner[self._distance], self.ref_other[self._distance]], axis=1).reshape(-1, 2)
        self._with_line = np.array([r.line is not None for r in refs], bool)
        self._lines = np.array([r.line for r in refs if r.line is not None]).reshape(-1, 2, 2)
        self._line_pos = np.cumsum(self._with_line) - 1
        self.ref_line_var = np.zeros(len(refs))
        self.pilot = None

    def set_pilot(self, camera: np.ndarray) -> None:
        """Fix every reference line's noise in log-length at the (5,) camera ``camera`` (the
        optimiser's first optimum; method.md, "Line noise")."""
        self.pilot = np.asarray(camera, float).copy()
        if not len(self._lines) or self.ref_line_sigma == 0:
            return
        self.ref_line_var = np.zeros(len(self.references))
        self.ref_line_var[self._with_line] = linear_line_variances(
            self._lines, self.principal_point, self.as_single_params(self.pilot[None])[0], self.ref_line_sigma)

    def ground_lengths(self, lines: np.ndarray, cams: np.ndarray) -> np.ndarray:
        """(n, k) real lengths (m) of (k, 2, 2) ground segments for (n, 5) cameras."""
        return ground_lengths(lines, self.principal_point, self.as_single_params(cams))

    @staticmethod
    def as_single_params(cams: np.ndarray) -> np.ndarray:
        """(n, 7) single-target parameter vectors holding the (n, 5) cameras' height, µ, pitch, roll."""
        full = np.zeros((len(cams), 7))
        full[:, 1], full[:, 4], full[:, 5], full[:, 6] = cams[:, C_HEIGHT], cams[:, C_FOCAL], cams[:, C_PITCH], cams[:, C_ROLL]
        return full

    def reference_nll_matrix(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each reference, (n, k)."""
        n = len(cams)
        pred = np.zeros((n, len(self.references)))
        if len(self._lines):
            with np.errstate(divide="ignore", invalid="ignore"):
                pred[:, self._with_line] = np.log(self.ground_lengths(self._lines, cams))
        owned = (self.ref_owner >= 0) & ~self._distance
        if owned.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                log_size = np.log(objs[:, self.ref_owner[owned], 3 + self.ref_size[owned]])
            rel = self.ref_kind[owned] == "relative"
            idx = np.flatnonzero(owned)
            pred[:, idx[rel]] -= log_size[:, rel]
            pred[:, idx[~rel]] = log_size[:, ~rel]
        if self._distance.any():
            pred[:, self._distance] = self.log_pair_distances(objs)
        s = np.sqrt(cams[:, C_SCALE, None] ** 2 + self.ref_line_var[None])  # (n, k)
        nu = self.ref_dof
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            lo = (self.ref_log_low[None] - pred) / s
            single = -(0.5 * (nu + 1.0)) * np.log1p(lo * lo / nu) - np.log(s)
            hi = (self.ref_log_high[None] - pred) / s
            rng = np.log(np.maximum(t_interval(nu, lo, hi), 1e-300))
        ll = np.where(self.ref_is_range[None], rng, single)
        return np.where(np.isfinite(ll), -ll, 1e300)

    def log_pair_distances(self, objs: np.ndarray) -> np.ndarray:
        """(n, P) log of the ground distance (m) between the bottom centres of each coupled pair."""
        a, b = objs[:, self.pairs[:, 0]], objs[:, self.pairs[:, 1]]
        with np.errstate(divide="ignore"):
            return np.log(np.hypot(a[..., O_X] - b[..., O_X], a[..., O_Z] - b[..., O_Z]))

    def _reference_nll(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(camera part (n,), per object part (n, m)) of the references' negative log-likelihood;
        distance references (which couple two objects) are in neither (:meth:`pair_nll`)."""
        n, m = len(cams), self.n_objects
        obj_part = np.zeros((n, m))
        if not len(self.references):
            return np.zeros(n), obj_part
        nll = self.reference_nll_matrix(cams, objs)
        owned = (self.ref_owner >= 0) & ~self._distance
        for j in np.flatnonzero(owned):
            obj_part[:, self.ref_owner[j]] += nll[:, j]
        return nll[:, ~owned & ~self._distance].sum(axis=1), obj_part

    def pair_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each distance reference, (n, P): the terms that couple two
        objects (zero columns when there are none). They depend on the camera only through the
        crowd's scale."""
        if not self._distance.any():
            return np.zeros((len(cams), 0))
        return self.reference_nll_matrix(cams, objs)[:, self._distance]

    # -- the object terms ------------------------------------------------------------------------
    def project(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Projected dimension-line corners (n, m, 4, 2) pixels and their depths (n, m, 4) metres."""
        corners = object_corners(objs[..., O_SIZE], self.handedness)  # (n, m, 4, 3)
        yaw = objs[..., O_YAW]
        c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
        px, py, pz = corners[..., 0], corners[..., 1], corners[..., 2]
        X = objs[..., O_X, None] + c * px + s * pz
        Y = (cams[:, C_HEIGHT, None] - objs[..., O_GROUND])[..., None] + py
        Z = objs[..., O_Z, None] - s * px + c * pz
        R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])[:, None, None]  # (n,1,1,3,3)
        xc = R[..., 0, 0] * X + R[..., 0, 1] * Y + R[..., 0, 2] * Z
        yc = R[..., 1, 0] * X + R[..., 1, 1] * Y + R[..., 1, 2] * Z
        zc = R[..., 2, 0] * X + R[..., 2, 1] * Y + R[..., 2, 2] * Z
        depth = zc
        zz = np.maximum(zc, 1e-6)
        f = cams[:, C_FOCAL, None, None]
        uv = np.stack([f * xc / zz + self.principal_point[0], f * yc / zz + self.principal_point[1]], axis=-1)
        return uv, depth

    def _annotation_terms(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uv, depth = self.project(cams, objs)
        r2 = np.sum((self.ann[None] - uv[:, :, None]) ** 2, axis=-1)  # (n, m, K, 4)
        nu = self.target_dof
        s2 = (nu * self.sigma**2)[None, :, None, None]
        per = 0.5 * (nu + 2.0) * np.sum(np.log1p(r2 / s2), axis=-1) + 4.0 * np.log(self.sigma**2)[None, :, None]
        behind = _BEHIND * np.sum(np.maximum(0.0, 1e-3 - depth), axis=-1)  # (n, m)
        return per * self.ann_mask[None], behind

    def annotation_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """The dimension lines' negative log-likelihood per annotation, (n, m, K) (zero where an
        object has fewer than K annotations); the normalising log σᵢ² terms are included."""
        return self._annotation_terms(cams, objs)[0]

    def object_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each object's observations given the camera, (n, m): its
        dimension lines and the references that name it (a box corner behind the camera adds
        10⁶ per metre, as the single-target models)."""
        per, behind = self._annotation_terms(cams, objs)
        out = per.sum(axis=-1) + behind
        if len(self.references):
            out = out + self._reference_nll(cams, objs)[1]
        return out

    def object_neg_log_prior(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-prior of each object block, (n, m): the class size prior (free sizes only;
        a density over the sizes), the ground offset's normal prior and the location's (log z for
        ``log-depth``, nothing for ``flat``; both inside the bounds)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            log_s = np.log(objs[..., O_SIZE])
        z = (log_s - self._size_mu) * self._size_inv_sd
        out = np.sum((0.5 * z * z + log_s) * self._size_on, axis=-1)
        if self.ground_sd_m > 0:
            out = out + 0.5 * (objs[..., O_GROUND] / self.ground_sd_m) ** 2
        return out + self.map_log_jacobian(objs)

    def map_log_jacobian(self, objs: np.ndarray) -> np.ndarray:
        """log |∂z/∂log z| = log z of each object (n, m) for ``log-depth`` (the MAP's coordinates,
        module docstring), zeros for ``flat``."""
        if self.location_prior != "log-depth":
            return np.zeros(objs.shape[:-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(objs[..., O_Z])

    def map_objective(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """(n,) what the MAP minimises: −log of the posterior density over (camera, x, log z, …),
        i.e. :meth:`neg_log_posterior` − Σ log z under ``log-depth`` (module docstring)."""
        with np.errstate(all="ignore"):
            return self.neg_log_posterior(cams, objs, temperature) - self.map_log_jacobian(objs).sum(axis=-1)

    # -- the camera terms ------------------------------------------------------------------------
    def camera_nll(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of the camera-only observations, (n,): references on ground
        segments and a measured horizon (module docstring)."""
        out = self.horizon_nll(cams)
        ground = self.ref_owner < 0
        if ground.any():  # (distance references have owners: they are pair terms)
            out = out + self.reference_nll_matrix(cams, np.ones((len(cams), self.n_objects, 7)))[:, ground].sum(axis=1)
        return out

    def camera_neg_log_prior(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-prior of the camera block, (n,): focal length, pitch and roll, camera height
        and the crowd's error scale (each only when it is free)."""
        out = np.zeros(len(cams))
        t = self.camera_terms
        if t.focal is not None and self.camera_free[C_FOCAL]:
            out += t.focal.neg_log(cams[:, C_FOCAL])
        if self.orientation == "free":
            p = t.orientation or self.height_prior
            out += (0.5 * ((cams[:, C_PITCH] - p.pitch_mean) / p.pitch_sd) ** 2
                    + 0.5 * ((cams[:, C_ROLL] - p.roll_mean) / p.roll_sd) ** 2)
        if self.use_height_prior:
            p = t.orientation or self.height_prior
            h = cams[:, C_HEIGHT]
            out += 0.5 * ((np.log(h) - np.log(p.height_median_m)) / p.height_log_sd) ** 2 + np.log(h)
        if self.camera_free[C_SCALE]:
            s = cams[:, C_SCALE]
            out += 0.5 * ((np.log(s) - np.log(REF_SCALE_MEDIAN)) / REF_SCALE_LOG_SD) ** 2 + np.log(s)
        return out

    # -- the posterior ---------------------------------------------------------------------------
    def object_terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of each object block, (n, m): nll / T + prior."""
        return self.object_nll(cams, objs) / temperature + self.object_neg_log_prior(cams, objs)

    def camera_term(self, cams: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of the camera block alone, (n,)."""
        return self.camera_nll(cams) / temperature + self.camera_neg_log_prior(cams)

    def pair_terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of each pair of objects a distance reference couples,
        (n, P): nll / T (no prior)."""
        return self.pair_nll(cams, objs) / temperature

    def neg_log_posterior(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """(n,) −log p(camera, objects | annotations) up to a constant; +inf outside the bounds."""
        cams = self.complete_camera(cams)
        with np.errstate(all="ignore"):
            out = self.camera_term(cams, temperature) + self.object_terms(cams, objs, temperature).sum(axis=1)
            if len(self.pairs):
                out = out + self.pair_terms(cams, objs, temperature).sum(axis=1)
        return np.where(self.in_bounds(cams, objs) & np.isfinite(out), out, np.inf)

    def horizon_nll(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of a measured horizon, (n,) (zeros when there is none)."""
        hz = self.camera_terms.horizon
        if hz is None or self.orientation != "free":
            return np.zeros(len(cams))
        d = horizon_offsets(hz.points, cams[:, [0, 0, 0, 0, C_FOCAL, C_PITCH, C_ROLL]], self.principal_point)
        var = hz.sd_px**2 + (cams[:, C_FOCAL] * np.tan(self.ground_tilt_sd_rad)) ** 2
        r2 = np.sum(d * d, axis=1) / var
        if hz.dof is None:
            return 0.5 * r2 + np.log(var)
        return 0.5 * (hz.dof + 2.0) * np.log1p(r2 / hz.dof) + np.log(var)

    def pointwise_log_likelihood(self, cams: np.ndarray, objs: np.ndarray) -> dict[str, np.ndarray]:
        """Log-likelihood of each observation: ``annotations`` (n, m, K) (zero for missing ones),
        ``references`` (n, k), ``horizon`` (n,)."""
        cams = self.complete_camera(cams)
        refs = (-self.reference_nll_matrix(cams, objs) if len(self.references)
                else np.zeros((len(cams), 0)))
        return {"annotations": -self.annotation_nll(cams, objs), "references": refs,
                "horizon": -self.horizon_nll(cams)}

    # -- simulation ------------------------------------------------------------------------------
    def simulate_annotations(self, camera: np.ndarray, objects: np.ndarray, n_annotations: int,
                             noise_px: float, rng=None) -> np.ndarray:
        """Dimension lines drawn around the projection of a true state: (m, K, 4, 2) pixels, every
        corner moved by N(0, noise_px²) per coordinate and rounded to 0.01 px."""
        rng = np.random.default_rng(rng)
        uv, _ = self.project(self.complete_camera(camera), np.asarray(objects, float)[None])
        noisy = uv[0][:, None] + rng.normal(0.0, noise_px, (self.n_objects, n_annotations, 4, 2))
        return np.round(noisy, 2)
