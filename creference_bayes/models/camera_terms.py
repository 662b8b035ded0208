"""What is known about the camera besides the annotations: priors on µ, pitch and roll, and a
horizon measured with an uncertainty (docs/method.md, "Priors"). The models read them as priors
(untempered) and observations of their camera block (cameras (n, 5), :mod:`.contract`).

Focal length
    ``log µ ~ Student-t_ν(log m, s)``: heavy tails, so that a wrong prior (a cropped photo, a
    mis-read EXIF tag) is overruled by the annotations. The density is over µ itself (the Jacobian
    1/µ included). Sources, in order: the scene's ``camera.focal_length_prior``; the image's EXIF
    (log-sd :data:`EXIF_LOG_SD`); a weakly informative default (:func:`default_focal_prior`).
Pitch, roll and the camera height (only when pitch and roll are free, i.e. no exact horizon)
    By default pitch ~ N(0°, 15°), roll ~ N(0°, 10°) and log h ~ N(log 1.6 m, 0.6)
    (:data:`DEFAULT_ORIENTATION_PRIOR`; a balcony or a drone needs the scene's
    ``camera.orientation_prior``). Without a horizon the data trade pitch against height and
    depth, and the posterior's tail would run to cameras tens of metres up. The height's prior is
    log-normal on purpose: polynomial tails in log h times the Jacobian 1/h grow without bound as
    h → 0. With an exact horizon the data pin the height and no prior is applied.
Horizon measurement
    A horizon known up to σ pixels: each of its two points lies at a signed distance N(0, σ²) from
    the horizon (µ, pitch, roll) predict, ``−sin(roll)(u − cx) + cos(roll)(v − cy) + µ tan(pitch)``
    for a pixel (u, v), positive below (:func:`~creference_bayes.core.geometry.horizon_line`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .location_prior import LocationPrior

__all__ = ["FULL_FRAME_DIAGONAL_MM", "EXIF_LOG_SD", "DEFAULT_FOCAL_35MM", "DEFAULT_FOCAL_LOG_SD",
           "DEFAULT_FOCAL_DOF", "FocalPrior", "OrientationPrior", "DEFAULT_ORIENTATION_PRIOR",
           "HorizonMeasurement", "CameraTerms", "default_focal_prior", "horizon_offsets"]

#: Diagonal of a 36 × 24 mm frame: the 35 mm-equivalent focal length scales with it.
FULL_FRAME_DIAGONAL_MM = float(np.hypot(36.0, 24.0))
#: log-sd of a focal-length prior read from EXIF: the tag is exact for the lens, but a crop, a
#: digital zoom or a resize with a crop changes the field of view (about ±10 %).
EXIF_LOG_SD = 0.1
#: The weakly informative default: 35 mm-equivalent focal length 26 mm, the median of a population
#: of real cameras (``REAL_CAMERAS`` in :mod:`creference_bayes.bench.simulate`: phones' main,
#: ultra-wide and telephoto cameras, zoom and action cameras, and the car-mounted cameras of KITTI,
#: nuScenes and Cityscapes, with their sources; its log-sd is 0.46–0.47 for photos and 0.24 for
#: street cameras), log-sd 0.5 and 3 degrees of freedom, so that 13 mm (an ultra-wide phone camera)
#: and 85 mm (a portrait lens) lie within about 1.4 and 2.4 scales and a 300 mm telephoto is still
#: possible. KITTI's camera (24 mm on its 1242 × 375 images) sits 0.16 scales below the median.
DEFAULT_FOCAL_35MM = 26.0
DEFAULT_FOCAL_LOG_SD = 0.5
DEFAULT_FOCAL_DOF = 3.0


def _check_positive(name: str, value: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
    return v


@dataclass(frozen=True)
class FocalPrior:
    """``log µ ~ Student-t_dof(log median_px, log_sd)`` (``dof`` = inf: a normal).

    Attributes
    ----------
    median_px : the prior median of µ, pixels
    log_sd : scale in log µ (0.1 ≈ ±10 %)
    dof : degrees of freedom (inf for a log-normal)
    source : where it came from (``scene``, ``exif``, ``default``), for the report
    """

    median_px: float
    log_sd: float
    dof: float = DEFAULT_FOCAL_DOF
    source: str = "scene"

    def __post_init__(self):
        _check_positive("focal prior median_px", self.median_px)
        _check_positive("focal prior log_sd", self.log_sd)
        if not self.dof > 0:
            raise ValueError(f"focal prior dof: expected a number > 0 or inf, got {self.dof!r}")

    @classmethod
    def from_35mm(cls, focal_35mm: float, image_size, **kw) -> "FocalPrior":
        """The prior for a 35 mm-equivalent focal length (mm) on an image of (width, height) px."""
        diag = float(np.hypot(*image_size))
        return cls(_check_positive("focal_35mm", focal_35mm) / FULL_FRAME_DIAGONAL_MM * diag, **kw)

    def z(self, focal) -> np.ndarray:
        """Standardised log-offset (log µ − log median) / log_sd."""
        return (np.log(np.asarray(focal, float)) - np.log(self.median_px)) / self.log_sd

    def neg_log(self, focal) -> np.ndarray:
        """−log p(µ) up to a constant, for µ in pixels (any shape)."""
        z = self.z(focal)
        core = 0.5 * z**2 if np.isinf(self.dof) else 0.5 * (self.dof + 1.0) * np.log1p(z**2 / self.dof)
        return core + np.log(np.asarray(focal, float))

    def interval(self, prob: float = 0.99) -> tuple[float, float]:
        """Central prior interval of µ (pixels) holding ``prob``."""
        from scipy import stats

        q = stats.t.ppf(0.5 + prob / 2, self.dof) if np.isfinite(self.dof) else stats.norm.ppf(0.5 + prob / 2)
        return (float(self.median_px * np.exp(-q * self.log_sd)), float(self.median_px * np.exp(q * self.log_sd)))

    def to_dict(self) -> dict:
        return {"median_px": self.median_px, "log_sd": self.log_sd,
                "dof": None if np.isinf(self.dof) else self.dof, "source": self.source}


def default_focal_prior(image_size) -> FocalPrior:
    """The weakly informative default prior for an image of (width, height) pixels."""
    return FocalPrior.from_35mm(DEFAULT_FOCAL_35MM, image_size, log_sd=DEFAULT_FOCAL_LOG_SD,
                                dof=DEFAULT_FOCAL_DOF, source="default")


@dataclass(frozen=True)
class OrientationPrior:
    """Priors on the camera's pose when there is no exact horizon: independent normals on pitch
    and roll (radians; pitch > 0 looks down) and a log-normal on its height above the floor
    (median ``height_median_m`` metres, log-sd ``height_log_sd``). ``source``: ``"calibration"``
    when a mounting from the camera's calibration was put in (:mod:`~creference_bayes.workflows.advice.answers`),
    else None."""

    pitch_mean: float = 0.0
    pitch_sd: float = float(np.radians(15.0))
    roll_mean: float = 0.0
    roll_sd: float = float(np.radians(10.0))
    height_median_m: float = 1.6
    height_log_sd: float = 0.6
    source: str | None = None

    def __post_init__(self):
        for key in ("pitch_sd", "roll_sd", "height_median_m", "height_log_sd"):
            _check_positive(f"orientation prior {key}", getattr(self, key))

    def neg_log(self, pitch, roll, height) -> np.ndarray:
        """−log p up to a constant; the height's density is over h itself (Jacobian 1/h)."""
        h = np.maximum(np.asarray(height, float), 1e-300)
        z = (np.log(h) - np.log(self.height_median_m)) / self.height_log_sd
        return (0.5 * ((np.asarray(pitch) - self.pitch_mean) / self.pitch_sd) ** 2
                + 0.5 * ((np.asarray(roll) - self.roll_mean) / self.roll_sd) ** 2
                + 0.5 * z**2 + np.log(h))

    def times(self, other: "OrientationPrior", names=("height", "pitch", "roll"),
              source: str | None = None) -> "OrientationPrior":
        """The product of this prior and ``other`` (normal densities in log height, pitch and roll)
        for the quantities ``names``; the others stay this prior's. ``source`` labels the product."""
        def product(m0, s0, m1, s1):
            w0, w1 = s0 ** -2, s1 ** -2
            return float((w0 * m0 + w1 * m1) / (w0 + w1)), float((w0 + w1) ** -0.5)

        kw = {"source": source}
        if "height" in names:
            log_h, sd = product(math.log(self.height_median_m), self.height_log_sd,
                                math.log(other.height_median_m), other.height_log_sd)
            kw.update(height_median_m=math.exp(log_h), height_log_sd=sd)
        for n in ("pitch", "roll"):
            if n in names:
                mean, sd = product(getattr(self, f"{n}_mean"), getattr(self, f"{n}_sd"),
                                   getattr(other, f"{n}_mean"), getattr(other, f"{n}_sd"))
                kw.update({f"{n}_mean": mean, f"{n}_sd": sd})
        return replace(self, **kw)

    def to_dict(self) -> dict:
        out = {k: float(np.degrees(getattr(self, k))) for k in ("pitch_mean", "pitch_sd", "roll_mean", "roll_sd")}
        return {**out, "height_median_m": self.height_median_m, "height_log_sd": self.height_log_sd,
                **({"source": self.source} if self.source else {})}


DEFAULT_ORIENTATION_PRIOR = OrientationPrior()


def horizon_offsets(points: np.ndarray, cams: np.ndarray, principal_point) -> np.ndarray:
    """Signed distances (pixels, positive below) of image points from the predicted horizon.

    Parameters
    ----------
    points : (k, 2) pixels
    cams : (n, 5) cameras (:mod:`.contract` order: µ, pitch and roll are used)
    principal_point : (2,) pixels

    Returns
    -------
    (n, k) pixels
    """
    p = np.asarray(points, float) - np.asarray(principal_point, float)
    cams = np.atleast_2d(cams)
    mu, pitch, roll = cams[:, 0, None], cams[:, 1, None], cams[:, 2, None]
    return -np.sin(roll) * p[:, 0] + np.cos(roll) * p[:, 1] + mu * np.tan(pitch)


@dataclass(frozen=True)
class HorizonMeasurement:
    """A horizon line through two image points, each known up to ``sd_px`` (pixels).

    ``source`` is ``scene`` (a stated ``horizon_sd_px``) or ``image`` (estimated from the photo).
    ``dof`` None: the two offsets are independent N(0, sd_px²); a number ν: they follow a bivariate
    Student-t with ν degrees of freedom and scale ``sd_px`` (heavy tails: the image estimate is
    sometimes far off, method.md "The horizon from a photo").
    """

    points: np.ndarray
    sd_px: float
    source: str = "scene"
    dof: float | None = None

    def __post_init__(self):
        _check_positive("horizon sd_px", self.sd_px)
        if self.dof is not None:
            _check_positive("horizon dof", self.dof)
        object.__setattr__(self, "points", np.asarray(self.points, float).reshape(2, 2))

    def to_dict(self) -> dict:
        out = {"points": self.points.tolist(), "sd_px": self.sd_px, "source": self.source}
        if self.dof is not None:
            out["dof"] = self.dof
        return out


@dataclass(frozen=True)
class CameraTerms:
    """The camera priors, the horizon measurement and the location prior of one scene (any may
    be None).

    ``orientation`` and ``horizon`` apply only when pitch and roll are free parameters;
    ``focal`` only when µ is free; ``location`` (:class:`~.location_prior.LocationPrior`, the
    prior on the target's ground position) always; None is flat.
    """

    focal: FocalPrior | None = None
    orientation: OrientationPrior | None = None
    horizon: HorizonMeasurement | None = None
    location: LocationPrior | None = None

    def to_dict(self) -> dict:
        """``{"focal_prior", "orientation_prior", "horizon", "location_prior"}``, each a dict or None."""
        return {f"{k}_prior" if k != "horizon" else k: None if getattr(self, k) is None else getattr(self, k).to_dict()
                for k in ("focal", "orientation", "horizon", "location")}
