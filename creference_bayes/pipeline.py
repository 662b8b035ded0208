"""The public entry point: :func:`estimate` one scene's target, from scene to :class:`Result`.

Data flow (one way): scene → camera/horizon → references → model per handedness → MAP →
(posterior) → result. Each stage lives in its own module; this one only wires them.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from .core.geometry import HANDEDNESS, Camera, horizon_line
from .core.metrics import location_percentage_error
from .models.paper import CALIBRATED_SIGMA_PX, CALIBRATED_TEMPERATURE, PaperModel
from .inference.optimize import optimize_map, preset_bounds
from .io.result import Evaluation, Result
from .io.scene import Scene, load_scene, scene_fingerprint

__all__ = ["MODELS", "estimate", "build_models"]

MODELS = ("paper", "metrology")
#: The default model. The benchmark (docs/benchmark_results.md) found the metrology model as good
#: as the paper's cost or better in every noise tier (paired per scene: 8 of 8 medium-tier scenes,
#: 5 of 8 high, a tie in the low tier; high-tier mean error 12 % against 218 %) and, unlike it,
#: calibrated at T = 1 (90 % regions cover the true distance in 88 % of noisy scenes).
DEFAULT_MODEL = "metrology"


def build_models(scene: Scene, *, model: str = "paper", preset: str = "default",
                 camera: Camera | None = None, constraints=None, use_references: bool = True,
                 **options) -> list:
    """One model per handedness for ``scene``.

    Parameters
    ----------
    model : one of :data:`MODELS`
    preset : optimiser preset; it decides the bounds
    camera : the camera (defaults to the scene's; pass one with an estimated horizon)
    constraints : soft constraints from the references (paper model), or None
    use_references : whether the metrology model uses the scene's references (the paper model
        uses ``constraints`` instead)
    options : model settings (``sigma`` for the paper model, default
        :data:`~creference_bayes.models.paper.CALIBRATED_SIGMA_PX` with the default preset and the paper's 100 px with the
        paper presets; ``target_sigma``, ``target_dof``, ``ref_scale``, ``ref_dof`` for the
        metrology model)
    """
    if model not in MODELS:
        raise ValueError(f"model: unknown model {model!r} (expected one of {list(MODELS)})")
    bounds = preset_bounds(preset, scene.image_width, scene.image_height)
    if model == "metrology":
        from .models.metrology import MetrologyModel

        return [MetrologyModel.from_scene(scene, h, bounds=bounds, camera=camera,
                                          use_references=use_references, **options) for h in HANDEDNESS]
    unknown = set(options) - {"sigma"}
    if unknown:
        raise ValueError(f"model options: unknown option(s) {sorted(unknown)} for model {model!r}")
    if preset == "default":  # calibrated posterior; the paper presets keep the paper's σ and T = 1
        options = {"sigma": CALIBRATED_SIGMA_PX, "default_temperature": CALIBRATED_TEMPERATURE, **options}
    return [PaperModel.from_scene(scene, h, bounds=bounds, constraints=constraints,
                                  camera=camera, **options) for h in HANDEDNESS]


def estimate(scene: Scene | str | Path, *, preset: str = "default", model: str = DEFAULT_MODEL,
             use_references: bool = True, seed=None, posterior: bool = True, restarts: int | None = None,
             temperature: float | None = None, hdi_prob: float = 0.9, sampling: dict | None = None,
             progress: bool = False, **options) -> Result:
    """Estimate the target's 3D location in one scene.

    Parameters
    ----------
    scene : a :class:`Scene` or a path to a ``creference-scene/1`` file
    preset : ``default`` (θ scan + local refinement), ``paper`` or ``paper-controlled``
    model : the likelihood model
    use_references : use the scene's reference annotations when it has any
    seed : int or Generator; the same seed gives the same result
    restarts : random restarts of the ``paper`` presets (None: the paper's count); the default
        preset has none
    posterior : sample the posterior after the MAP (method.md §7)
    temperature : T of log p = −cost′/T + log prior (default: the model's own, 1 for the
        metrology model and for the paper presets, :data:`~creference_bayes.models.paper.CALIBRATED_TEMPERATURE` for the
        paper model with the default preset)
    hdi_prob : probability of the reported highest-density intervals
    sampling : sampler settings (:class:`~creference_bayes.sampling.SamplerSettings` fields,
        e.g. ``{"min_ess": 2000}``); unknown keys are rejected
    progress : show progress bars on standard error (the ``paper`` presets' restarts, the
        sampler's warm-up and sampling)

    Returns
    -------
    Result
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    rng = np.random.default_rng(seed)
    warnings = list(scene.warnings)
    camera, notes, horizon_estimate = _camera_step(scene)
    warnings += notes
    references = _references_step(scene, camera, preset, use_references)
    models = build_models(scene, model=model, preset=preset, camera=camera,
                          constraints=references.constraints if model == "paper" else None,
                          use_references=use_references, **options)
    if model == "metrology":
        references = dataclasses.replace(references, used_as="likelihood",
                                         in_likelihood=models[0].n_references_used)
    map_est = optimize_map(models, preset=preset, rng=rng, restarts=restarts, progress_bar=progress)
    evaluation = None
    if scene.ground_truth is not None:
        evaluation = Evaluation(location_pct_error=float(
            location_percentage_error(map_est.params[:3], scene.ground_truth.location_m)))
    post = diag = idata = None
    if posterior:
        post, diag, idata, notes = _posterior_step(
            models, map_est, scene, rng, temperature=temperature, hdi_prob=hdi_prob,
            sampling=sampling, progress=progress)
        warnings += notes
        if evaluation is not None and post is not None:
            from .inference.summary import evaluate_posterior

            err, inside = evaluate_posterior(post, scene.ground_truth, list(diag.r_hat))
            evaluation = dataclasses.replace(evaluation, posterior_location_pct_error=err,
                                             in_hdi=inside)
    return Result(target=scene.target.id, model=model, preset=preset, map=map_est,
                  scene=scene.source.name if scene.source else None, evaluation=evaluation,
                  warnings=tuple(warnings), posterior=post, diagnostics=diag,
                  inference_data=idata, references=references,
                  extra={} if horizon_estimate is None else {"horizon_estimate": horizon_estimate.to_dict()},
                  scene_id={"target": scene.target.id, "image_size": [scene.image_width, scene.image_height],
                            "sha256": scene_fingerprint(scene)})


def _camera_step(scene: Scene):
    """The camera, with the horizon estimated from the image when the scene gives none.

    Returns the camera, notes for the result's warnings and the horizon estimate (or None).
    """
    camera = Camera.from_scene(scene)
    if scene.horizon is not None:
        return camera, [], None
    level = "assumed a level camera (horizon through the principal point)"
    if scene.image_path is None:
        return camera, [f"no horizon and no image: {level}"], None
    from .vision.horizon import estimate_horizon

    try:
        est = estimate_horizon(scene.image_path, principal_point=scene.principal_point,
                               scene_size=scene.image_size)
    except (OSError, ValueError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        return camera, [f"no horizon, and image.path {str(scene.image_path)!r} could not be read "
                        f"({why}): {level}"], None
    if not est:
        return camera, [f"no horizon, and none found in the image ({est.reason}): {level}"], est
    camera = dataclasses.replace(camera, horizon=horizon_line(est.points))
    return camera, [f"no horizon given: estimated from the image ({est.method} segments, "
                    f"{len(est.vanishing_points)} vanishing points, confidence {est.confidence:.2f})"], est


def _references_step(scene: Scene, camera: Camera, preset: str, use_references: bool):
    """Pairs of references → soft constraints, as a :class:`ReferenceReport`.

    The paper model's cost uses the constraints; for the metrology model the pairs are only
    reported (for comparison and for the top-view plot).
    """
    from .core.metrology import ReferenceReport, aggregate_references

    if not use_references:
        return ReferenceReport(len(scene.references), enabled=False)
    bounds = preset_bounds(preset, scene.image_width, scene.image_height)
    return aggregate_references(scene, camera, focal_range_px=(bounds.lower[4], bounds.upper[4]))


def _posterior_step(models, map_est, scene, rng, *, temperature, hdi_prob, sampling, progress):
    """Sample the posterior of the MAP's handedness from the MAP, and summarise it.

    Returns the :class:`~creference_bayes.io.result.PosteriorSummary`, the :class:`~creference_bayes.io.result.Diagnostics` (whose
    ``seconds`` cover the whole step), the InferenceData and notes for the result's warnings.
    """
    from .inference.posterior import DEFAULT_TEMPERATURE, LogPosterior, laplace_scales
    from .inference.sampling import SamplerSettings, SamplingError, sample
    from .inference.summary import posterior_arrays, summarise, to_inference_data

    t0 = time.perf_counter()
    settings = SamplerSettings.from_options(sampling)
    model = next(m for m in models if m.handedness == map_est.handedness)
    if temperature is None:  # a model may bring its own (metrology: a proper likelihood, T = 1)
        temperature = getattr(model, "default_temperature", DEFAULT_TEMPERATURE)
    log_post = LogPosterior(model, temperature)
    center = map_est.params[model.free]
    laplace = laplace_scales(log_post, center)
    try:
        chains = sample(log_post, center, laplace.cov, settings=settings, rng=rng,
                        log_mask=model.bounds.lower[model.free] > 0, progress=progress)
    except SamplingError as exc:  # e.g. a MAP with zero posterior density: report, do not crash
        return None, None, None, [f"posterior not sampled: {exc}"]
    fixed, free = model.bounds.lower, model.free
    arrays = posterior_arrays(chains, fixed, free)
    post, diag = summarise(chains, fixed, free, hdi_prob=hdi_prob, min_ess=settings.min_ess,
                           tau_multiple=settings.tau_multiple, handedness=map_est.handedness,
                           temperature=temperature, arrays=arrays)
    idata = to_inference_data(chains, fixed, free, scene=scene, attrs={
        "model": model.name, "handedness": map_est.handedness, "temperature": temperature,
        "hdi_prob": hdi_prob})
    notes = []
    if not diag.converged:
        notes.append("posterior not converged: " + "; ".join(diag.warnings))
    other = [v["cost"] for k, v in map_est.info.items()
             if k.startswith("handedness_") and k != f"handedness_{map_est.handedness:+d}"]
    if other and min(other) - map_est.cost < 2.0 * temperature:
        notes.append(f"the other handedness of the dimension lines fits almost as well (cost "
                     f"{min(other) - map_est.cost:+.2f}); the posterior is conditioned on "
                     f"handedness {map_est.handedness:+d}")
    return post, dataclasses.replace(diag, seconds=time.perf_counter() - t0), idata, notes
