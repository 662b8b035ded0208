"""The model contract: what every model of a scene offers the optimiser, the sampler and the rest.

A scene is one photo with one or more targets (a one-target scene is a frame of one). Every model
of it has the same parameters, in named blocks: one **camera** block shared by every object,

    camera = (focal_length_px, pitch, roll, height_m, ref_scale)      px, rad, rad, m, 1

and one **object** block per target,

    object = (x, z, yaw, length_m, width_m, height_m, ground_m)        m, m, rad, m, m, m, m

(:data:`CAMERA_NAMES`, :data:`OBJECT_NAMES`). States are arrays ``cams (n, 5)`` and
``objs (n, m, 7)`` for n states of a scene with m objects. A parameter is *free* (sampled) or
*fixed* (a known focal length, a known size, no crowd scale to estimate, …); pitch and roll may be
*derived* from an exact horizon and µ (:meth:`Model.complete_camera`).

A model implements the log-likelihood of each observation: :meth:`Model.object_nll` (each
object's own, given the camera, (n, m)), :meth:`Model.camera_nll` (the camera's alone, (n,)),
:meth:`Model.pair_nll` (those coupling two objects, (n, P)) and
:meth:`Model.pointwise_log_likelihood` (each on its own); optionally :meth:`Model.set_pilot`.
:class:`Model` does the rest: geometry, bounds and free masks, the priors, the posterior
``log p = log-likelihood / T + log-prior`` (the temperature never widens the priors), the MAP's
objective and starting cameras. Given the camera, objects are independent except through the
pair terms, which the optimiser and the sampler exploit (:mod:`creference_bayes.inference`).

Geometry
    The gravity-aligned camera frame has x right, y down, z forward; the reference ground plane is
    y = ``height_m`` (the camera's height above it). An object's bottom centre is
    (x, height_m − ground_m, z): ``ground_m`` is how far its own ground lies above the reference
    plane (fixed at 0 in a one-object scene, where the plane is defined by the object). Its prior
    is a Student-t whose scale grows with the object's ground distance d = √(x² + z²) from the
    camera: s(d) = √(``ground_sd_m``² + (``ground_sd_per_m`` · d)²), ``ground_dof`` degrees of
    freedom (:meth:`Model.ground_neg_log_prior`): the camera stands on the road, and the road
    departs from the plane under the camera more the farther it is. Its box turns by ``yaw``
    about y and its dimension lines follow :func:`object_corners` with the object's handedness.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..core.geometry import pitch_roll_from_horizon, rotation_from_pitch_roll
from .camera_terms import CameraTerms, OrientationPrior, horizon_offsets
from .location_prior import LocationPrior
from .size_priors import SizePrior

__all__ = ["CAMERA_NAMES", "CAMERA_UNITS", "OBJECT_NAMES", "OBJECT_UNITS", "C_FOCAL", "C_PITCH", "C_ROLL",
           "C_HEIGHT", "C_SCALE", "O_X", "O_Z", "O_YAW", "O_SIZE", "O_GROUND", "MAX_PITCH", "MAX_ROLL",
           "DEFAULT_GROUND_SD_M", "DEFAULT_GROUND_SD_PER_M", "DEFAULT_GROUND_DOF", "DEFAULT_GROUND_TILT_SD_RAD",
           "REF_SCALE_MEDIAN", "REF_SCALE_LOG_SD",
           "OBJECT_REPORT", "CAPABILITIES", "FIT_STATE", "ObjectData", "Bounds", "Model", "object_corners",
           "object_report"]

CAMERA_NAMES = ("focal_length_px", "pitch", "roll", "height_m", "ref_scale")
CAMERA_UNITS = ("px", "rad", "rad", "m", "1")
OBJECT_NAMES = ("x", "z", "yaw", "length_m", "width_m", "height_m", "ground_m")
OBJECT_UNITS = ("m", "m", "rad", "m", "m", "m", "m")
C_FOCAL, C_PITCH, C_ROLL, C_HEIGHT, C_SCALE = range(5)
O_X, O_Z, O_YAW = 0, 1, 2
O_SIZE = slice(3, 6)
O_GROUND = 6
#: Largest pitch and roll a camera may have, radians (beyond them the ground is not in view).
MAX_PITCH = float(np.radians(80.0))
MAX_ROLL = float(np.radians(45.0))
#: An object's ground offset from the camera's ground plane: a Student-t of ``DEFAULT_GROUND_DOF``
#: degrees of freedom and scale √(``DEFAULT_GROUND_SD_M``² + (``DEFAULT_GROUND_SD_PER_M`` · d)²),
#: metres, at ground distance d metres. Fitted by maximum likelihood to the KITTI development
#: frames' objects, each against the plane through the others of its frame (157 objects in the 23
#: frames of four or more; the fit on the even frames predicts the odd ones and back;
#: docs/overview.md, "Uneven ground"): 5.6 cm beside the camera, 10 cm at 50 m, tails heavier
#: than a normal's.
DEFAULT_GROUND_SD_M = 0.056
DEFAULT_GROUND_SD_PER_M = 0.0017
DEFAULT_GROUND_DOF = 2.0
#: Tilt of the ground plane from level, radians (the same KITTI fits: 1.1° across, 0.6° along).
DEFAULT_GROUND_TILT_SD_RAD = float(np.radians(1.0))
#: The crowd's error scale in log-length: log-normal prior, median and log-sd (models that use one).
REF_SCALE_MEDIAN = 0.5
REF_SCALE_LOG_SD = 1.0
#: What a model may offer beyond the contract, by name, and what each promises. A model lists its
#: own in :attr:`Model.capabilities`; the optimiser, the results and the commands read them there,
#: never the model's name or which attributes it happens to have.
CAPABILITIES = {
    "corner_sigma": "a corner scale `sigma` (pixels: one number, or (m,) one per object) that the MAP's "
                    "first pass may raise for a smoother objective",
    "object_sigma": "`sigma` is (m,), each object's own corner scale; results report it (`sigma_px`)",
    "reference_likelihood": "the workers' references are measurements in the likelihood: `all_references`, "
                            "`references` (those used), `reference_status` (index → used, or why not), "
                            "`n_stated_ranges`; the pointwise `references` are (n, k), one per reference used",
    "reference_bounds": "the references bound each object's ground position: `reference_reports` and "
                        "`constraints` (one per object, or None); the pointwise `references` are (n, m), "
                        "one per object",
    "confidence_map": "a range stated with a confidence is read through `confidence_map`",
}
#: The per-fit attributes an optimiser may set on its own copy of a model (:meth:`Model.variant`):
#: each object's handedness (m,) ±1, the corner scale ``sigma`` (pixels, a model with
#: ``corner_sigma``), ``softness_px`` (pixels) and ``camera_free`` (5,) bool; a ``pilot`` camera
#: (5,) goes through :meth:`Model.set_pilot`.
FIT_STATE = ("handedness", "sigma", "softness_px", "camera_free", "pilot")
#: Behind-the-camera penalty per metre.
_BEHIND = 1e6


#: What results report of each object, in order: its bottom centre (x, y, z), yaw, sizes, ground
#: offset and its ground distance √(x² + z²) from the camera's foot point (m, rad).
OBJECT_REPORT = ("x", "y", "z", "yaw", "length_m", "width_m", "height_m", "ground_m", "distance_m")


def object_report(cams: np.ndarray, objs: np.ndarray, yaw_centre=None) -> np.ndarray:
    """(…, m, 9) the quantities of :data:`OBJECT_REPORT` for cameras (…, 5) and objects (…, m, 7):
    y is the camera height less the object's ground offset; yaw on the arc of ±π around
    ``yaw_centre`` (m,) when given."""
    y = cams[..., C_HEIGHT, None] - objs[..., O_GROUND]
    yaw = objs[..., O_YAW]
    if yaw_centre is not None:
        yaw = yaw_centre + (yaw - yaw_centre + np.pi) % (2 * np.pi) - np.pi
    return np.stack([objs[..., O_X], y, objs[..., O_Z], yaw, objs[..., 3], objs[..., 4], objs[..., 5],
                     objs[..., O_GROUND], np.hypot(objs[..., O_X], objs[..., O_Z])], axis=-1)


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
    """One target as a model sees it.

    Attributes
    ----------
    id : the target's id
    annotations : (K, 4, 2) corners t1..t4 of its K annotations, pixels
    corner_median : (4, 2) their per-corner median, pixels (set from ``annotations``)
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
        object.__setattr__(self, "corner_median", np.median(a, axis=0))  # (4, 2) per-corner median, px
        if self.sizes is None and self.size_prior is None:
            raise ValueError(f"target {self.id!r}: needs known sizes or a size prior")

    @property
    def initial_sizes(self) -> np.ndarray:
        return np.asarray(self.sizes if self.sizes is not None else self.size_prior.median_m, float)


@dataclass(frozen=True)
class Bounds:
    """A box for the parameters: camera (5,) and object (7,) lower and upper bounds, in
    :data:`CAMERA_NAMES` and :data:`OBJECT_NAMES` order (yaw is circular and never bounded).
    The prior is truncated to it. :meth:`Model.default_bounds` are wide; the paper's presets and
    simulation-based calibration give their own."""

    camera_lower: np.ndarray
    camera_upper: np.ndarray
    object_lower: np.ndarray
    object_upper: np.ndarray

    def __post_init__(self):
        for name, n in (("camera_lower", 5), ("camera_upper", 5), ("object_lower", 7), ("object_upper", 7)):
            v = np.asarray(getattr(self, name), float).reshape(n)
            object.__setattr__(self, name, v)
        if np.any(self.camera_lower > self.camera_upper) or np.any(self.object_lower > self.object_upper):
            raise ValueError("bounds: a lower bound above its upper bound")

    @classmethod
    def wide(cls, image_size) -> "Bounds":
        """The default box: wide enough to matter only where nothing else does."""
        side = float(max(image_size))
        return cls(np.array([0.1 * side, -MAX_PITCH, -MAX_ROLL, 0.05, 0.005]),
                   np.array([10 * side, MAX_PITCH, MAX_ROLL, 50.0, 3.0]),
                   np.array([-500.0, 0.1, -np.inf, 0.01, 0.01, 0.01, -5.0]),
                   np.array([500.0, 1000.0, np.inf, 100.0, 100.0, 100.0, 5.0]))

    @classmethod
    def box(cls, image_size, *, x=None, z=None, focal_px=None, pitch=None, roll=None, height=None) -> "Bounds":
        """:meth:`wide` with some ranges replaced: each a (low, high) pair (metres, pixels, radians)."""
        b = cls.wide(image_size)
        cl, cu, ol, ou = b.camera_lower.copy(), b.camera_upper.copy(), b.object_lower.copy(), b.object_upper.copy()
        for rng, arrays, k in ((focal_px, (cl, cu), C_FOCAL), (pitch, (cl, cu), C_PITCH), (roll, (cl, cu), C_ROLL),
                               (height, (cl, cu), C_HEIGHT), (x, (ol, ou), O_X), (z, (ol, ou), O_Z)):
            if rng is not None:
                arrays[0][k], arrays[1][k] = rng
        return cls(cl, cu, ol, ou)


class Model:
    """The contract (module docstring), and everything models share.

    Parameters
    ----------
    principal_point : (2,) pixels
    image_size : (width, height) pixels
    objects : the targets
    camera_terms : priors on µ, pitch and roll, the height prior, a horizon measurement, the
        location prior
    orientation : ``free`` (pitch and roll are parameters), ``horizon`` (derived from
        ``horizon_line`` and µ) or ``level`` (both 0)
    horizon_line : (3,) the exact horizon for ``horizon``
    focal_length_px : a known focal length, or None
    ground_sd_m : the scale of an object's ground offset beside the camera, metres (0: every offset
        fixed at 0, one plane; forced to 0 with one object)
    ground_sd_per_m : how the offset's scale grows with the ground distance, metres per metre
    ground_dof : the offset prior's Student-t degrees of freedom (``inf``: a normal)
    ground_tilt_sd_rad : the ground's tilt from level, widening a measured horizon
    bounds : a :class:`Bounds` box (None: :meth:`Bounds.wide`)
    default_temperature : the posterior's T when the caller gives none
    """

    name = "model"
    #: What the model offers beyond the contract (names of :data:`CAPABILITIES`).
    capabilities: frozenset = frozenset()
    #: The options a user may set (keywords of the model, recorded in a result's provenance), and
    #: those of them whose values are words, not numbers.
    options: tuple[str, ...] = ()
    word_options: tuple[str, ...] = ()
    #: Whether the objective is smooth (no kinks): the optimiser may finish with Newton steps alone.
    smooth = True
    #: A model that is not smooth rounds its kinks over this many pixels while it is > 0 (the MAP's
    #: search starts on the rounded objective, then polishes on the exact one).
    softness_px = 0.0
    #: The crowd scale's log-normal prior (median, log-sd; :data:`REF_SCALE_MEDIAN`,
    #: :data:`REF_SCALE_LOG_SD`); a model with references may be given another
    #: (``ref_scale_median``, ``ref_scale_log_sd``, :class:`~.metrology.MetrologyModel`).
    ref_scale_median = REF_SCALE_MEDIAN
    ref_scale_log_sd = REF_SCALE_LOG_SD

    def __init__(self, principal_point, image_size, objects, *, camera_terms: CameraTerms | None = None,
                 orientation: str = "free", horizon_line=None, focal_length_px: float | None = None,
                 ground_sd_m: float = DEFAULT_GROUND_SD_M, ground_sd_per_m: float = DEFAULT_GROUND_SD_PER_M,
                 ground_dof: float = DEFAULT_GROUND_DOF, ground_tilt_sd_rad: float = DEFAULT_GROUND_TILT_SD_RAD,
                 bounds: Bounds | None = None, default_temperature: float = 1.0):
        if orientation not in ("free", "horizon", "level"):
            raise ValueError(f"orientation: expected free, horizon or level, got {orientation!r}")
        if orientation == "horizon" and horizon_line is None:
            raise ValueError("orientation 'horizon' needs horizon_line")
        if not objects:
            raise ValueError("a scene needs at least one target")
        self.principal_point = np.asarray(principal_point, float)
        self.image_size = tuple(int(v) for v in image_size)
        self.objects = tuple(objects)
        self.camera_terms = camera_terms or CameraTerms()
        self.orientation = orientation
        self.horizon_line = None if horizon_line is None else np.asarray(horizon_line, float)
        self.focal_length_px = focal_length_px
        for key, v, unit in (("ground_sd_m", ground_sd_m, "metres"), ("ground_sd_per_m", ground_sd_per_m, "metres"),
                             ("ground_tilt_sd_rad", ground_tilt_sd_rad, "radians")):
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{key}: expected a finite number >= 0 ({unit}), got {v!r}")
        if not (ground_dof > 0):
            raise ValueError(f"ground_dof: expected a number > 0 (inf: a normal), got {ground_dof!r}")
        self.ground_sd_m = 0.0 if len(self.objects) == 1 else float(ground_sd_m)
        self.ground_sd_per_m, self.ground_dof = float(ground_sd_per_m), float(ground_dof)
        self.ground_tilt_sd_rad = float(ground_tilt_sd_rad)
        self.default_temperature = float(default_temperature)
        self.location = self.camera_terms.location or LocationPrior()
        self.height_prior = self.camera_terms.orientation or OrientationPrior()
        self.handedness = np.array([o.handedness for o in self.objects], float)
        self.pilot = None
        self.bounds = bounds or Bounds.wide(self.image_size)
        self.camera_lower, self.camera_upper = self.bounds.camera_lower.copy(), self.bounds.camera_upper.copy()
        self.object_lower, self.object_upper = self.bounds.object_lower.copy(), self.bounds.object_upper.copy()
        self._set_masks()

    @classmethod
    def has_ground_offsets(cls, n_objects: int) -> bool:
        """Whether a user's model of a scene of ``n_objects`` targets has ground offsets under a
        ground-offset prior of their choosing (its :attr:`options` include ``ground_sd_m``): one
        object defines the ground plane itself (:meth:`__init__` fixes its offset)."""
        return "ground_sd_m" in cls.options and n_objects > 1

    def variant(self, **state) -> "Model":
        """A copy of this model at another per-fit state (keys of :data:`FIT_STATE`): what an
        optimiser or sampler changes while it fits lives in its own copy, and this model is never
        changed. ``ValueError`` naming a key that is not per-fit state."""
        unknown = sorted(set(state) - set(FIT_STATE))
        if unknown:
            raise ValueError(f"variant: {unknown[0]!r} is not per-fit state (expected some of {list(FIT_STATE)})")
        if "sigma" in state and "corner_sigma" not in self.capabilities:
            raise ValueError(f"variant: sigma: the {self.name} model has no corner scale")
        new = copy.copy(self)
        new.__dict__ = {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in self.__dict__.items()}
        pilot = state.pop("pilot", None)
        for key, value in state.items():
            setattr(new, key, np.array(value, bool if key == "camera_free" else float) if np.ndim(value) else value)
        if pilot is not None and not (self.pilot is not None and np.array_equal(pilot, self.pilot)):
            new.set_pilot(pilot)  # (what a model fixes at its pilot depends on that camera alone)
        return new

    def at_handedness(self, handedness: np.ndarray) -> "Model":
        """A view of this model at other handednesses, to evaluate only: ``handedness`` (m,), or
        (n, m) for a call on exactly n rows, each row's own (draws of a target sampled at both).
        It shares every other array with this model (nothing may be changed through it)."""
        new = copy.copy(self)
        new.handedness = np.asarray(handedness, float)
        return new

    # -- blocks, bounds, fixed values ------------------------------------------------------------
    @property
    def has_ref_scale(self) -> bool:
        """Whether ``ref_scale`` is a free parameter (the model has one and observations to fix it)."""
        return False

    def _set_masks(self) -> None:
        cf = np.ones(5, bool)
        if self.focal_length_px is not None:
            cf[C_FOCAL] = False
        if self.orientation != "free":
            cf[[C_PITCH, C_ROLL]] = False
        cf[C_SCALE] = self.has_ref_scale
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

    def complete_camera(self, cams: np.ndarray) -> np.ndarray:
        """(n, 5) camera vectors with the fixed and derived entries filled in (µ when known, pitch
        and roll from an exact horizon or level, the crowd scale when it is not estimated)."""
        cams = np.array(np.atleast_2d(cams), float)
        if self.focal_length_px is not None:
            cams[:, C_FOCAL] = self.focal_length_px
        if self.orientation == "horizon":
            cams[:, C_PITCH], cams[:, C_ROLL] = pitch_roll_from_horizon(self.horizon_line, cams[:, C_FOCAL],
                                                                        self.principal_point)
        elif self.orientation == "level":
            cams[:, C_PITCH] = cams[:, C_ROLL] = 0.0
        if not self.camera_free[C_SCALE]:
            cams[:, C_SCALE] = self.ref_scale_median
        return cams

    def ref_scale_neg_log(self, s) -> np.ndarray:
        """The crowd scale's negative log-prior at ``s`` (log-length units), up to a constant: its
        log-normal (:attr:`ref_scale_median`, :attr:`ref_scale_log_sd`) as a density in s."""
        s = np.asarray(s, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return 0.5 * ((np.log(s) - np.log(self.ref_scale_median)) / self.ref_scale_log_sd) ** 2 + np.log(s)

    def in_bounds(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """(n,) bool: every camera and object parameter inside its bounds (yaw is circular)."""
        ok = np.all((cams >= self.camera_lower) & (cams <= self.camera_upper), axis=1)
        with np.errstate(invalid="ignore"):
            inside = (objs >= self.object_lower) & (objs <= self.object_upper)
        inside[..., O_YAW] = np.isfinite(objs[..., O_YAW])
        return ok & np.all(inside, axis=(1, 2))

    # -- geometry ---------------------------------------------------------------------------------
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
        zz = np.maximum(zc, 1e-6)
        f = cams[:, C_FOCAL, None, None]
        uv = np.stack([f * xc / zz + self.principal_point[0], f * yc / zz + self.principal_point[1]], axis=-1)
        return uv, zc

    @staticmethod
    def behind(depth: np.ndarray) -> np.ndarray:
        """(n, m) the behind-the-camera penalty of each object: 10⁶ per metre that a corner lies
        closer than 1 mm in front of the camera (keeps the objective finite for the optimiser)."""
        return _BEHIND * np.sum(np.maximum(0.0, 1e-3 - depth), axis=-1)

    # -- what each model implements ----------------------------------------------------------------
    def object_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each object's own observations given the camera, (n, m)."""
        raise NotImplementedError

    def camera_nll(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of the observations of the camera alone, (n,): here a measured
        horizon; models add theirs."""
        return self.horizon_nll(cams)

    @property
    def pairs(self) -> np.ndarray:
        """(P, 2) the objects each pair term couples (none by default)."""
        return np.zeros((0, 2), int)

    def pair_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each observation that couples two objects, (n, P)."""
        return np.zeros((len(cams), 0))

    def pointwise_log_likelihood(self, cams: np.ndarray, objs: np.ndarray) -> dict[str, np.ndarray]:
        """Log-likelihood of each observation (name → (n, …)), for the result's ``log_likelihood``."""
        raise NotImplementedError

    def set_pilot(self, camera: np.ndarray) -> None:
        """Fix what the model takes at a first optimum (here only the camera is recorded)."""
        self.pilot = np.asarray(camera, float).copy()

    @property
    def needs_pilot(self) -> bool:
        """Whether :meth:`set_pilot` changes the objective (the optimiser then refines once more)."""
        return False

    # -- shared observations and priors -------------------------------------------------------------
    def horizon_nll(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of a measured horizon, (n,) (zeros when there is none): its two
        points lie N(0, σ²) (or a bivariate Student-t of that scale) from the predicted horizon,
        σ² = σ_h² + (µ tan τ)², τ the ground plane's tilt from level (``ground_tilt_sd_rad``): a
        level horizon says where gravity is, the camera's pitch and roll are relative to the ground."""
        hz = self.camera_terms.horizon
        if hz is None or self.orientation != "free":
            return np.zeros(len(cams))
        d = horizon_offsets(hz.points, cams, self.principal_point)
        var = hz.sd_px**2 + (cams[:, C_FOCAL] * np.tan(self.ground_tilt_sd_rad)) ** 2
        r2 = np.sum(d * d, axis=1) / var
        if hz.dof is None:
            return 0.5 * r2 + np.log(var)
        return 0.5 * (hz.dof + 2.0) * np.log1p(r2 / hz.dof) + np.log(var)

    @property
    def ground_options(self) -> dict:
        """The ground's settings as keywords of this class (to build a model like this one)."""
        return dict(ground_sd_m=self.ground_sd_m, ground_sd_per_m=self.ground_sd_per_m, ground_dof=self.ground_dof,
                    ground_tilt_sd_rad=self.ground_tilt_sd_rad)

    def ground_scale(self, objs: np.ndarray) -> np.ndarray:
        """(n, m) the scale of each object's ground-offset prior at its ground distance d, metres:
        √(``ground_sd_m``² + (``ground_sd_per_m`` · d)²)."""
        d = np.hypot(objs[..., O_X], objs[..., O_Z])
        return np.sqrt(self.ground_sd_m**2 + (self.ground_sd_per_m * d) ** 2)

    def ground_neg_log_prior(self, objs: np.ndarray) -> np.ndarray:
        """(n, m) −log density of each object's ground offset g given its place (0 when the offsets
        are fixed): g / s(d) is a Student-t of ``ground_dof`` degrees of freedom (a normal when it is
        infinite), s(d) from :meth:`ground_scale`; the log s(d) term is kept, since d is a parameter."""
        if self.ground_sd_m <= 0:
            return np.zeros(objs.shape[:-1])
        s = self.ground_scale(objs)
        r2 = (objs[..., O_GROUND] / s) ** 2
        nu = self.ground_dof
        core = 0.5 * r2 if np.isinf(nu) else 0.5 * (nu + 1.0) * np.log1p(r2 / nu)
        return core + np.log(s)

    def object_neg_log_prior(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """Negative log-prior of each object block, (n, m): the class size prior (free sizes only;
        a density over the sizes), the ground offset's (:meth:`ground_neg_log_prior`) and the
        location prior's (:mod:`.location_prior`), inside the bounds."""
        with np.errstate(divide="ignore", invalid="ignore"):
            log_s = np.log(objs[..., O_SIZE])
        z = (log_s - self._size_mu) * self._size_inv_sd
        out = np.sum((0.5 * z * z + log_s) * self._size_on, axis=-1)
        out = out + self.ground_neg_log_prior(objs)
        return out + self.location.neg_log(objs[..., O_X], objs[..., O_Z])

    def map_log_jacobian(self, objs: np.ndarray) -> np.ndarray:
        """log |∂z/∂log z| = log z of each object (n, m) when the MAP is taken in log coordinates
        (the location prior says: :attr:`.location_prior.LocationPrior.map_in_log_coordinates`),
        zeros otherwise."""
        if not self.location.map_in_log_coordinates:
            return np.zeros(objs.shape[:-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(objs[..., O_Z])

    def camera_log_jacobian(self, cams: np.ndarray) -> np.ndarray:
        """(n,) log |∂(µ, h)/∂(log µ, log h)| of the free positive camera parameters, when the MAP
        is taken in log coordinates (zeros otherwise): the MAP is the mode of the density in the
        coordinates the sampler and the priors use."""
        if not self.location.map_in_log_coordinates:
            return np.zeros(len(cams))
        cf = self.camera_free
        with np.errstate(divide="ignore", invalid="ignore"):
            return (np.log(cams[:, C_FOCAL]) * cf[C_FOCAL] + np.log(cams[:, C_HEIGHT]) * cf[C_HEIGHT])

    def camera_neg_log_prior(self, cams: np.ndarray) -> np.ndarray:
        """Negative log-prior of the camera block, (n,): focal length, pitch and roll, camera height
        and the crowd's error scale (each only when it is free)."""
        out = np.zeros(len(cams))
        t = self.camera_terms
        if t.focal is not None and self.camera_free[C_FOCAL]:
            out += t.focal.neg_log(cams[:, C_FOCAL])
        p = self.height_prior
        if self.orientation == "free":
            out += (0.5 * ((cams[:, C_PITCH] - p.pitch_mean) / p.pitch_sd) ** 2
                    + 0.5 * ((cams[:, C_ROLL] - p.roll_mean) / p.roll_sd) ** 2)
        h = cams[:, C_HEIGHT]
        if self.use_height_prior:
            out += 0.5 * ((np.log(h) - np.log(p.height_median_m)) / p.height_log_sd) ** 2 + np.log(h)
        elif self.location.map_in_log_coordinates and self.camera_free[C_HEIGHT]:
            out += np.log(h)  # scale-invariant: uniform in log h (flat would lean far along the ridge)
        if t.focal is None and self.camera_free[C_FOCAL] and self.location.map_in_log_coordinates:
            out += np.log(cams[:, C_FOCAL])  # no focal prior: uniform in log µ, likewise
        if self.camera_free[C_SCALE]:
            out += self.ref_scale_neg_log(cams[:, C_SCALE])
        return out

    # -- the posterior ------------------------------------------------------------------------------
    def object_terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of each object block, (n, m): nll / T + prior."""
        return self.object_nll(cams, objs) / temperature + self.object_neg_log_prior(cams, objs)

    def camera_term(self, cams: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of the camera block alone, (n,)."""
        return self.camera_nll(cams) / temperature + self.camera_neg_log_prior(cams)

    def pair_terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """−log posterior contribution of each pair term, (n, P): nll / T (no prior)."""
        return self.pair_nll(cams, objs) / temperature

    def terms(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0):
        """All three at once, (camera (n,), objects (n, m), pairs (n, P)): :meth:`camera_term`,
        :meth:`object_terms` and :meth:`pair_terms` (a model may share their work)."""
        return (self.camera_term(cams, temperature), self.object_terms(cams, objs, temperature),
                self.pair_terms(cams, objs, temperature))

    def neg_log_posterior(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """(n,) −log p(camera, objects | annotations) up to a constant; +inf outside the bounds."""
        cams = self.complete_camera(cams)
        with np.errstate(all="ignore"):
            c, o, p = self.terms(cams, objs, temperature)
            out = c + o.sum(axis=1) + p.sum(axis=1)
        return np.where(self.in_bounds(cams, objs) & np.isfinite(out), out, np.inf)

    def map_objective(self, cams: np.ndarray, objs: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """(n,) what the MAP minimises: −log of the posterior density over (log µ, log h, x,
        log z, …) when the location prior takes the MAP in log coordinates, i.e.
        :meth:`neg_log_posterior` − Σ log z − log µ − log h (the free ones); else
        :meth:`neg_log_posterior` itself."""
        cams = self.complete_camera(cams)
        with np.errstate(all="ignore"):
            return (self.neg_log_posterior(cams, objs, temperature) - self.map_log_jacobian(objs).sum(axis=-1)
                    - self.camera_log_jacobian(cams))

    # -- starting points --------------------------------------------------------------
    def focal_guess(self) -> float:
        """A focal length to start from, pixels: the known one, the prior's median, else a 30 mm
        equivalent lens."""
        if self.focal_length_px is not None:
            return float(self.focal_length_px)
        f = self.camera_terms.focal
        return float(f.median_px) if f is not None else 30.0 / 43.27 * float(np.hypot(*self.image_size))
