"""Estimate a whole frame: every target of one photo with one shared camera (docs/frames.md).

Data flow, one way: frame scene → camera set-up (:mod:`.camera_setup`, as for one target) →
:class:`~.models.frame.FrameModel` → MAP (:mod:`.inference.frame_map`) → posterior
(:mod:`.inference.frame_sampler`) → :class:`~.io.frame_result.FrameResult`. The result records
how it was made (:attr:`FrameResult.provenance`), and :func:`rebuild_model` makes the same model
again from a result and its scene in one call.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .camera_setup import setup_camera

from .io.frame_scene import FrameScene, load_frame, parse_frame
from .models.frame import DEFAULT_GROUND_SD_M, DEFAULT_GROUND_TILT_SD_RAD, FrameModel, FrameReference, ObjectData
from .models.size_priors import SizePrior

__all__ = ["estimate_frame", "build_frame_model", "rebuild_model", "map_state", "frame_draws", "FRAME_OPTIONS"]

#: Model options a user may set (the result's provenance records them).
FRAME_OPTIONS = ("ground_sd_m", "ground_tilt_sd_rad", "target_dof", "ref_dof", "ref_line_sigma", "location_prior")


def build_frame_model(frame: FrameScene, *, orientation: str = "auto", focal_prior="auto",
                      orientation_prior=None, classes: dict[str, SizePrior] | None = None,
                      use_references: bool = True, **options) -> tuple[FrameModel, object]:
    """The frame's model and its camera set-up.

    Parameters
    ----------
    frame : the frame
    orientation, focal_prior, orientation_prior : how the camera is treated
        (:func:`~.camera_setup.setup_camera`)
    classes : size priors from a file given by the user (the scene's own ``classes`` win)
    use_references : use the workers' references
    options : model settings (:data:`FRAME_OPTIONS`): ``ground_sd_m`` (m), ``ground_tilt_sd_rad``,
        ``target_dof``, ``ref_dof``, ``ref_line_sigma`` (px), ``location_prior`` (``log-depth``,
        the default, or ``flat``: :mod:`~.models.frame`)
    """
    unknown = sorted(set(options) - set(FRAME_OPTIONS))
    if unknown:
        raise ValueError(f"frame model: unknown option(s) {unknown} (expected some of {list(FRAME_OPTIONS)})")
    setup = setup_camera(frame, orientation=orientation, focal_prior=focal_prior, orientation_prior=orientation_prior)
    objects = []
    for t in frame.targets:
        prior = None if t.dimensions is not None else frame.size_prior(t.cls, classes)
        objects.append(ObjectData(t.id, t.corners, 1, t.dimensions, prior, t.cls))
    refs = []
    if use_references:
        for r, owner in zip(frame.references, frame.reference_targets):
            refs.append(_frame_reference(r, owner, frame))
    mode = {"free": "free", "horizon": "horizon", "level": "level"}[setup.orientation]
    model = FrameModel(np.asarray(frame.principal_point, float), frame.image_size, tuple(objects), tuple(refs),
                       camera_terms=setup.terms, orientation=mode,
                       horizon_line=setup.camera.horizon if mode == "horizon" else None,
                       focal_length_px=frame.focal_length_px,
                       ground_sd_m=options.get("ground_sd_m", DEFAULT_GROUND_SD_M),
                       ground_tilt_sd_rad=options.get("ground_tilt_sd_rad", DEFAULT_GROUND_TILT_SD_RAD),
                       **{k: options[k] for k in ("target_dof", "ref_dof", "ref_line_sigma", "location_prior")
                          if k in options})
    return model, setup


def _frame_reference(r, owner, frame: FrameScene) -> FrameReference:
    sizes = ("length", "width", "height")
    if isinstance(owner, tuple):
        return FrameReference(r.index, "distance", r.low, r.high, r.is_range, None, owner[0], None, owner[1])
    if r.line is None:
        return FrameReference(r.index, "size", r.low, r.high, r.is_range, None, owner, sizes.index(r.measure))
    if r.mode == "relative":
        t = frame.targets[owner]
        k = sizes.index(r.measure)
        if t.dimensions is not None:  # a known size: a plain ground length
            return FrameReference(r.index, "ground", r.low * t.dimensions[k], r.high * t.dimensions[k],
                                  r.is_range, np.asarray(r.line, float))
        return FrameReference(r.index, "relative", r.low, r.high, r.is_range, np.asarray(r.line, float), owner, k)
    return FrameReference(r.index, "ground", r.low, r.high, r.is_range, np.asarray(r.line, float))


def estimate_frame(frame: FrameScene | str | Path, *, seed=None, posterior: bool = True,
                   temperature: float = 1.0, hdi_prob: float = 0.9, sampling: dict | None = None,
                   progress: bool = False, orientation: str = "auto", focal_prior="auto",
                   orientation_prior=None, classes: dict[str, SizePrior] | None = None,
                   use_references: bool = True, keep_draws: int | None = None, **options) -> "FrameResult":
    """Estimate every target of a frame and the shared camera.

    Parameters
    ----------
    frame : a :class:`~.io.frame_scene.FrameScene`, the path of a ``creference-scene/2`` (or
        ``/1``) file, or such a file's content as a dict
    seed : int or Generator; the same seed gives the same result
    posterior : sample the posterior after the MAP
    temperature : T of log p = log-likelihood / T + log-prior (priors are never tempered)
    hdi_prob : probability of the reported highest-density intervals
    sampling : sampler settings (:class:`~.inference.frame_sampler.FrameSamplerSettings` fields)
    progress : a progress bar on standard error while sampling
    orientation, focal_prior, orientation_prior, classes, use_references, options : the model
        (:func:`build_frame_model`)
    keep_draws : posterior draws the result keeps (``draws``, evenly spaced; 0: none); default
        :data:`~.io.frame_result.RESULT_DRAWS`
    """
    from .inference.frame_map import optimize_frame
    from .io.frame_result import RESULT_DRAWS, FrameResult
    from .inference.threads import single_threaded_blas

    if isinstance(frame, Mapping):  # a decoded scene file
        frame = parse_frame(frame, classes=classes)
    elif not isinstance(frame, FrameScene):
        frame = load_frame(frame, classes=classes)
    if not (np.isfinite(temperature) and temperature > 0):
        raise ValueError(f"temperature: expected a finite number > 0, got {temperature!r}")
    rng = np.random.default_rng(seed)
    with single_threaded_blas():
        t0 = time.perf_counter()
        model, setup = build_frame_model(frame, orientation=orientation, focal_prior=focal_prior,
                                         orientation_prior=orientation_prior, classes=classes,
                                         use_references=use_references, **options)
        map_est = optimize_frame(model, temperature=temperature)
        draws = diag = None
        if posterior:
            from .inference.frame_sampler import FrameSamplerSettings, sample_frame

            settings = FrameSamplerSettings.from_options(sampling)
            draws, diag = sample_frame(model, map_est, settings=settings, rng=rng, temperature=temperature,
                                       progress=progress)
        recorded = {"location_prior": model.location_prior, **options}
        provenance = {"model": "frame", "options": {k: recorded[k] for k in sorted(recorded)},
                      "orientation": orientation, "focal_prior": focal_prior if isinstance(focal_prior, str) else "given",
                      "use_references": use_references, "temperature": temperature, "hdi_prob": hdi_prob,
                      "seed": seed if isinstance(seed, (int, type(None))) else "generator",
                      "sampling": dict(sampling or {}), "classes": {k: v.to_dict() for k, v in (classes or {}).items()}}
        return FrameResult.build(frame, model, setup, map_est, draws, diag, hdi_prob=hdi_prob,
                                 provenance=provenance, seconds=time.perf_counter() - t0,
                                 keep_draws=RESULT_DRAWS if keep_draws is None else int(keep_draws))


def rebuild_model(result, frame: FrameScene | str | Path) -> FrameModel:
    """The model a result was made with, from the result (or its dict) and its scene, in one call:
    the same camera set-up, classes, options and each target's handedness."""
    from .models.size_priors import size_priors_from_dict

    d = result if isinstance(result, dict) else result.to_dict()
    if not isinstance(frame, FrameScene):
        frame = load_frame(frame)
    prov = d["provenance"]
    # results made before frames had a location prior were made with a flat one
    options = {"location_prior": "flat", **prov["options"]}
    classes = size_priors_from_dict(prov.get("classes") or {}, "provenance.classes", "file") if prov.get("classes") else None
    model, _ = build_frame_model(frame, orientation=prov["orientation"],
                                 focal_prior=prov["focal_prior"] if prov["focal_prior"] != "given" else "auto",
                                 classes=classes, use_references=prov["use_references"], **options)
    model.handedness = np.array([o["handedness"] for o in d["objects"]], float)
    if d.get("pilot_camera") is not None:
        model.set_pilot(np.array(d["pilot_camera"], float))
    return model


def map_state(result) -> tuple[np.ndarray, np.ndarray]:
    """The MAP of a ``creference-result/2`` (or its dict) as model arrays: camera (5,) and
    objects (m, 7) (:mod:`~.models.frame` order)."""
    from .models.frame import CAMERA_NAMES, OBJECT_NAMES

    d = result if isinstance(result, dict) else result.to_dict()
    camera = np.array([d["camera"]["map"][k] for k in CAMERA_NAMES], float)
    objects = np.array([[o["map"][k] for k in OBJECT_NAMES] for o in d["objects"]], float)
    return camera, objects


def frame_draws(result, model: FrameModel, *, n: int = 2000, seed=0) -> tuple[np.ndarray, np.ndarray, str]:
    """Posterior draws of a frame result: those it keeps (``draws``: ``cameras`` (N, 5) and
    ``objects`` (N, m, 7)) when it has them, else ``n`` draws of the Laplace approximation at its
    MAP (:mod:`~.inference.frame_laplace`) of the rebuilt ``model``.

    Returns cameras (k, 5), objects (k, m, 7) and where they came from (``"posterior"`` or
    ``"laplace"``).
    """
    from .inference.frame_laplace import frame_laplace
    from .io.frame_result import stored_draws

    d = result if isinstance(result, dict) else result.to_dict()
    kept = stored_draws(d)  # a malformed ``draws`` raises ValueError naming the key
    if kept is not None and kept.objects.shape[2] == model.n_objects:
        return kept.cameras.reshape(-1, 5), kept.objects.reshape(-1, model.n_objects, 7), "posterior"
    camera, objects = map_state(d)
    lap = frame_laplace(model, camera, objects, temperature=float(d["provenance"].get("temperature", 1.0)))
    cams, objs = lap.draws(n, seed)
    return cams, objs, "laplace"
