"""What the estimate knows about the camera before it looks at the annotations: built once per
estimate and passed to every model.

The decision, in :func:`setup_camera`:

- **Orientation** (``orientation="auto"``): a horizon given without an uncertainty fixes pitch and
  roll for every µ; a horizon with ``horizon_sd_px`` > 0 is a *measurement*: pitch and roll become
  parameters with the orientation prior, and the horizon a likelihood term; no horizon but an
  image: the horizon estimated from the image is such a measurement, with the estimator's own
  uncertainty (``HorizonEstimate.sd_px``); no horizon at all: pitch and roll are parameters with
  their prior alone, identified by the dimension lines and the references. ``"level"`` assumes a
  level camera when there is no horizon (kept for comparison); ``"free"`` makes pitch and roll
  parameters even with an exact horizon (which then enters with :data:`GIVEN_HORIZON_SD_PX`).
- **Focal-length prior** (``focal_prior="auto"``, only when µ is not known): the scene's
  ``camera.focal_length_prior``, else the image's EXIF, else the weak default
  (:func:`~creference_bayes.models.camera_terms.default_focal_prior`); ``"default"`` skips the
  first two, ``"none"`` keeps the flat prior within the bounds.
- **Location prior** (``location_prior``): ``"log-depth"`` (uniform in log depth, the MAP in log
  coordinates: :mod:`~creference_bayes.models.location_prior`) or ``"flat"`` (the paper presets').
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .core.geometry import Camera, horizon_line
from .models.camera_terms import (DEFAULT_ORIENTATION_PRIOR, EXIF_LOG_SD, CameraTerms, FocalPrior,
                                  HorizonMeasurement, OrientationPrior, default_focal_prior)
from .models.location_prior import DEFAULT_LOCATION_PRIOR, LocationPrior

__all__ = ["ORIENTATIONS", "FOCAL_PRIORS", "GIVEN_HORIZON_SD_PX", "CameraSetup", "setup_camera"]

ORIENTATIONS = ("auto", "free", "level")
FOCAL_PRIORS = ("auto", "default", "none")
#: Pixel uncertainty of a given horizon when ``orientation="free"`` is forced on it.
GIVEN_HORIZON_SD_PX = 1.0
#: Degrees of freedom of a prior read from EXIF (heavy tails: a crop should not drag the fit).
EXIF_DOF = 4.0


@dataclass(frozen=True)
class CameraSetup:
    """The camera of one estimate.

    Attributes
    ----------
    camera : principal point, the exact horizon (None when pitch and roll are free or level) and
        the known focal length (or None)
    orientation : ``"horizon"`` (derived from an exact horizon), ``"free"`` or ``"level"``
    terms : the priors and the horizon measurement
    notes : what the result's warnings should say
    horizon_estimate : the image-based estimate (``vision.horizon.HorizonEstimate``) or None
    aggregation_camera : the camera the paper's pairwise aggregation of references uses (it needs
        a horizon line: the exact one, the measured one, or a level camera)
    """

    camera: Camera
    orientation: str
    terms: CameraTerms
    notes: tuple[str, ...] = ()
    horizon_estimate: object = None
    aggregation_camera: Camera | None = None

    def to_dict(self) -> dict:
        return {"orientation": self.orientation, **self.terms.to_dict()}


def setup_camera(scene, *, orientation: str = "auto", focal_prior: str | FocalPrior = "auto",
                 orientation_prior: OrientationPrior | None = None,
                 location_prior: str | LocationPrior = DEFAULT_LOCATION_PRIOR,
                 image_horizon: dict | None = None) -> CameraSetup:
    """Decide the camera of ``scene`` (module docstring).

    Parameters
    ----------
    scene : :class:`~creference_bayes.io.scene.Scene`
    orientation : one of :data:`ORIENTATIONS`
    focal_prior : one of :data:`FOCAL_PRIORS`, or a :class:`FocalPrior`
    orientation_prior : prior on pitch and roll when they are free (default: the scene's
        ``camera.orientation_prior``, else
        :data:`~creference_bayes.models.camera_terms.DEFAULT_ORIENTATION_PRIOR`)
    location_prior : a name of :data:`~creference_bayes.models.location_prior.LOCATION_PRIORS` or a
        :class:`~creference_bayes.models.location_prior.LocationPrior`
    image_horizon : what an earlier estimate from the scene's image found (a result's
        ``camera.setup.horizon_estimate``): used instead of estimating it again, where it is a whole
        record (its points, scale and tail; or none found); anything else is estimated again
    """
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation: expected one of {list(ORIENTATIONS)}, got {orientation!r}")
    if not isinstance(focal_prior, FocalPrior) and focal_prior not in FOCAL_PRIORS:
        raise ValueError(f"focal_prior: expected one of {list(FOCAL_PRIORS)} or a FocalPrior, got {focal_prior!r}")
    location = location_prior if isinstance(location_prior, LocationPrior) else LocationPrior(location_prior)
    pp = np.asarray(scene.principal_point, float)
    base = Camera(pp, None, scene.focal_length_px)
    notes: list[str] = []
    mode, measured, estimate = _orientation(scene, orientation, notes, image_horizon)
    camera = dataclasses.replace(base, horizon=horizon_line(scene.horizon)) if mode == "horizon" else base
    prior = orientation_prior or getattr(scene, "orientation_prior", None) or DEFAULT_ORIENTATION_PRIOR
    terms = CameraTerms(focal=_focal_prior(scene, focal_prior, notes),
                        orientation=prior if mode == "free" else None,
                        horizon=measured if mode == "free" else None, location=location)
    agg_points = scene.horizon if scene.horizon is not None else (None if measured is None else measured.points)
    aggregation = dataclasses.replace(base, horizon=None if agg_points is None else horizon_line(agg_points))
    return CameraSetup(camera, mode, terms, tuple(notes), estimate, aggregation)


def _orientation(scene, orientation: str, notes: list[str], image_horizon: dict | None = None):
    """(mode, horizon measurement or None, image estimate or None)."""
    sd = float(getattr(scene, "horizon_sd_px", 0.0) or 0.0)
    if scene.horizon is not None:
        if orientation == "free" or sd > 0:
            return "free", HorizonMeasurement(scene.horizon, sd if sd > 0 else GIVEN_HORIZON_SD_PX, "scene"), None
        return "horizon", None, None
    if orientation == "level":
        notes.append("no horizon: assumed a level camera (horizon through the principal point), "
                     "as asked (orientation 'level')")
        return "level", None, None
    free = "pitch and roll estimated from the annotations (and the orientation prior)"
    if scene.image_path is None:
        notes.append(f"no horizon and no image: {free}")
        return "free", None, None
    recorded = _recorded_horizon(image_horizon)
    if recorded is not None:  # found before: the same measurement (or the same lack of one)
        return "free", recorded or None, None
    from .vision.horizon import estimate_horizon

    try:
        est = estimate_horizon(scene.image_path, principal_point=scene.principal_point,
                               scene_size=scene.image_size)
    except (OSError, ValueError) as exc:
        notes.append(f"no horizon, and image.path {str(scene.image_path)!r} could not be read "
                     f"({getattr(exc, 'strerror', None) or exc}): {free}")
        return "free", None, None
    if not est:
        notes.append(f"no horizon, and none found in the image ({est.reason}): {free}")
        return "free", None, est
    notes.append(f"no horizon given: estimated from the image ({est.method} segments, "
                 f"{len(est.vanishing_points)} vanishing point{'s' if len(est.vanishing_points) != 1 else ''}, scale {est.sd_px:.1f} px (heavy-tailed), confidence "
                 f"{est.confidence:.2f}) and used as a measurement; pitch and roll estimated with it")
    return "free", HorizonMeasurement(est.points, est.sd_px, "image", dof=est.dof), est


def _recorded_horizon(record) -> HorizonMeasurement | bool | None:
    """An earlier image estimate's record (:meth:`~.vision.horizon.HorizonEstimate.to_dict`) as the
    measurement it was used as; False where it found none; None where it is not a whole record
    (points (2, 2), a scale and a tail, finite and positive; a record from outside may be anything)."""
    if not isinstance(record, dict):
        return None
    if record.get("points") is None:
        return False if isinstance(record.get("reason"), str) and record.get("reason") else None
    try:
        points = np.asarray(record["points"], float).reshape(2, 2)
        sd, dof = float(record["sd_px"]), float(record["dof"])
    except (KeyError, TypeError, ValueError):
        return None
    if not (np.all(np.isfinite(points)) and np.isfinite(sd) and sd > 0 and np.isfinite(dof) and dof > 0):
        return None
    return HorizonMeasurement(points, sd, "image", dof=dof)


def _focal_prior(scene, choice, notes: list[str]) -> FocalPrior | None:
    if scene.focal_length_px is not None or choice == "none":
        return None
    if isinstance(choice, FocalPrior):
        return choice
    if choice == "auto":
        stated = getattr(scene, "focal_prior", None)
        if stated is not None:
            return stated
        if scene.image_path is not None:
            from .vision.exif import focal_from_exif

            exif = focal_from_exif(scene.image_path, scene.image_size)
            if exif is not None:
                notes.append(f"focal length prior from the image's EXIF ({exif.route}): "
                             f"{exif.focal_px:.0f} px ± {EXIF_LOG_SD:.0%}")
                return FocalPrior(exif.focal_px, EXIF_LOG_SD, EXIF_DOF, source="exif")
    return default_focal_prior(scene.image_size)
