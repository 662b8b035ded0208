"""The public entry point: :func:`estimate` one scene's target, from scene to :class:`Result`.

Data flow (one way): scene → camera (built once: :mod:`.camera_setup`) → references → model per
handedness → MAP → (posterior) → result. Each stage lives in its own module; this one only wires
them.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .camera_setup import CameraSetup, setup_camera
from .core.geometry import HANDEDNESS
from .core.metrics import location_percentage_error
from .models.paper import CALIBRATED_SIGMA_PX, CALIBRATED_TEMPERATURE, PaperModel
from .inference.optimize import optimize_map, preset_bounds
from .io.result import Evaluation, Result
from .inference.threads import single_threaded_blas
from .io.scene import Scene, parse_scene, read_scene_json, scene_fingerprint

__all__ = ["MODELS", "DEFAULT_MODEL", "estimate", "build_models", "reprojection_check"]

MODELS = ("paper", "metrology")
#: The default model. The benchmark (docs/benchmark_results.md) found the metrology model as good
#: as the paper's cost or better in every noise tier (paired per scene: 8 of 8 medium-tier scenes,
#: 5 of 8 high, a tie in the low tier; high-tier mean error 12 % against 218 %) and, unlike it,
#: calibrated at T = 1 (90 % regions cover the true distance in 88 % of noisy scenes).
DEFAULT_MODEL = "metrology"


def build_models(scene: Scene, setup: CameraSetup, *, model: str = DEFAULT_MODEL, preset: str = "default",
                 constraints=None, use_references: bool = True, bounds=None, **options) -> list:
    """One model per handedness for ``scene``, all sharing the estimate's camera ``setup``.

    Parameters
    ----------
    scene : the scene
    setup : the camera, its orientation mode and priors (:func:`~.camera_setup.setup_camera`)
    model : one of :data:`MODELS`
    preset : optimiser preset; it decides the bounds
    constraints : soft constraints from the references (paper model), or None
    use_references : whether the metrology model uses the scene's references (the paper model
        uses ``constraints`` instead)
    bounds : a :class:`~creference_bayes.models.params.Bounds` box instead of the preset's (the
        prior is truncated to it: simulation-based calibration estimates within the box its
        scenes are drawn from)
    options : model settings (``sigma`` for the paper model, default
        :data:`~creference_bayes.models.paper.CALIBRATED_SIGMA_PX` with the default preset and the
        paper's 100 px with the paper presets; ``target_sigma``, ``target_dof``, ``ref_scale``,
        ``ref_dof``, ``ref_line_sigma`` and ``confidence_map`` (a
        :class:`~creference_bayes.models.confidence_map.ConfidenceMap` or None) for the metrology
        model)
    """
    if model not in MODELS:
        raise ValueError(f"model: unknown model {model!r} (expected one of {list(MODELS)})")
    if bounds is None:
        bounds = preset_bounds(preset, scene.image_width, scene.image_height)
    common = dict(camera=setup.camera, bounds=bounds, orientation_free=setup.orientation_free,
                  camera_terms=setup.terms)
    if model == "metrology":
        from .models.metrology import MetrologyModel

        return [MetrologyModel.from_scene(scene, h, use_references=use_references, **common, **options)
                for h in HANDEDNESS]
    unknown = set(options) - {"sigma"}
    if unknown:
        raise ValueError(f"model options: unknown option(s) {sorted(unknown)} for model {model!r}")
    if preset == "default":  # calibrated posterior; the paper presets keep the paper's σ and T = 1
        options = {"sigma": CALIBRATED_SIGMA_PX, "default_temperature": CALIBRATED_TEMPERATURE, **options}
    return [PaperModel.from_scene(scene, h, constraints=constraints, **common, **options) for h in HANDEDNESS]


def estimate(scene: Scene | str | Path, *, preset: str = "default", model: str = DEFAULT_MODEL,
             use_references: bool = True, seed=None, posterior: bool = True, restarts: int | None = None,
             temperature: float | None = None, hdi_prob: float = 0.9, sampling: dict | None = None,
             progress: bool = False, orientation: str = "auto", focal_prior="auto",
             orientation_prior=None, confidence_map="default", location_prior="auto", bounds=None,
             **options) -> Result:
    """Estimate the target's 3D location in one scene.

    Parameters
    ----------
    scene : a :class:`Scene`, a path to a scene file or such a file's content as a dict
        (validated by :func:`~creference_bayes.io.scene.parse_scene`). A ``creference-scene/2``
        frame is estimated whole (:func:`~creference_bayes.frame_pipeline.estimate_frame`, whose
        :class:`~creference_bayes.io.frame_result.FrameResult` is returned; ``classes`` and the
        frame model's options go in ``options``)
    preset : ``default`` (θ scan + local refinement), ``paper`` or ``paper-controlled``
    model : the likelihood model
    use_references : use the scene's reference annotations when it has any
    seed : int or Generator; the same seed gives the same result
    restarts : random restarts of the ``paper`` presets (None: the paper's count); the default
        preset has none
    posterior : sample the posterior after the MAP (method.md §7)
    temperature : T of log p = −cost′/T + log prior (default: the model's own, 1 for the
        metrology model and for the paper presets,
        :data:`~creference_bayes.models.paper.CALIBRATED_TEMPERATURE` for the paper model with the
        default preset)
    hdi_prob : probability of the reported highest-density intervals
    sampling : sampler settings (:class:`~creference_bayes.inference.sampling.SamplerSettings`
        fields, e.g. ``{"min_ess": 2000}``); unknown keys are rejected
    progress : show progress bars on standard error (the ``paper`` presets' restarts, the
        sampler's warm-up and sampling)
    orientation : ``auto``, ``free`` or ``level``: how pitch and roll are treated
        (:func:`~.camera_setup.setup_camera`)
    focal_prior : ``auto``, ``default``, ``none`` or a
        :class:`~creference_bayes.models.camera_terms.FocalPrior`
    orientation_prior : a :class:`~creference_bayes.models.camera_terms.OrientationPrior`, or None
        for the scene's or the default
    confidence_map : how the metrology model reads ranges stated with a confidence: ``"none"``
        (ignored), ``"identity"``, the path of a map file or a
        :class:`~creference_bayes.models.confidence_map.ConfidenceMap`; ``"default"`` is
        :data:`~creference_bayes.models.confidence_map.DEFAULT_CONFIDENCE_MAP` (docs/confidence.md).
        The paper model turns ranges into bounds and has no use for a confidence: with it, any
        map other than ``"default"`` or ``"none"`` is an error
    location_prior : ``"auto"`` (``"log-depth"`` with the default preset, ``"flat"`` with the
        paper presets, whose method has no prior), ``"log-depth"`` or ``"flat"``
        (:mod:`~creference_bayes.models.location_prior`, method.md "Priors")
    bounds : a :class:`~creference_bayes.models.params.Bounds` box instead of the preset's
        (:func:`build_models`)
    options : model settings (:func:`build_models`)

    Returns
    -------
    Result
    """
    if not isinstance(scene, Scene):
        source = None if isinstance(scene, Mapping) else Path(scene)
        data = scene if source is None else read_scene_json(source)
        if isinstance(data, Mapping) and data.get("format") == "creference-scene/2":
            from .frame_pipeline import estimate_frame  # a whole frame: every target, one camera

            if model != DEFAULT_MODEL or preset != "default" or restarts is not None or bounds is not None:
                raise ValueError("model, preset, restarts and bounds apply to single-target scenes; a "
                                 "creference-scene/2 frame uses the frame model")
            if location_prior != "auto":
                options = {**options, "location_prior": location_prior}
            return estimate_frame(data if source is None else source, seed=seed, posterior=posterior,
                                  hdi_prob=hdi_prob, sampling=sampling, progress=progress,
                                  orientation=orientation, focal_prior=focal_prior,
                                  orientation_prior=orientation_prior, use_references=use_references,
                                  temperature=1.0 if temperature is None else temperature, **options)
        scene = parse_scene(data, source)
    with single_threaded_blas():
        return _estimate(scene, preset=preset, model=model, use_references=use_references, seed=seed,
                         posterior=posterior, restarts=restarts, temperature=temperature,
                         hdi_prob=hdi_prob, sampling=sampling, progress=progress,
                         orientation=orientation, focal_prior=focal_prior,
                         orientation_prior=orientation_prior, confidence_map=confidence_map,
                         location_prior=location_prior, bounds=bounds, **options)


def _estimate(scene: Scene, *, preset, model, use_references, seed, posterior, restarts, temperature,
              hdi_prob, sampling, progress, orientation, focal_prior, orientation_prior, confidence_map,
              location_prior, bounds, **options) -> Result:
    rng = np.random.default_rng(seed)
    if isinstance(location_prior, str) and location_prior == "auto":
        location_prior = "log-depth" if preset == "default" else "flat"
    setup = setup_camera(scene, orientation=orientation, focal_prior=focal_prior,
                         orientation_prior=orientation_prior, location_prior=location_prior)
    warnings = list(scene.warnings) + list(setup.notes)
    references = _references_step(scene, setup, preset, use_references)
    cmap = _confidence_map(model, confidence_map)
    if model == "metrology":
        options = {**options, "confidence_map": cmap}
    models = build_models(scene, setup, model=model, preset=preset,
                          constraints=references.constraints if model == "paper" else None,
                          use_references=use_references, bounds=bounds, **options)
    if model == "metrology":
        references = dataclasses.replace(references, used_as="likelihood",
                                         in_likelihood=models[0].n_references_used)
    map_est = optimize_map(models, preset=preset, rng=rng, restarts=restarts, progress_bar=progress)
    warnings += _focal_prior_check(setup, map_est)
    warnings += reprojection_check(scene, setup, map_est)
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
    extra = {"camera": setup.to_dict(), "confidence": _confidence_summary(scene, models, cmap)}
    if setup.horizon_estimate is not None:
        extra["horizon_estimate"] = setup.horizon_estimate.to_dict()
    return Result(target=scene.target.id, model=model, preset=preset, map=map_est,
                  scene=scene.source.name if scene.source else None, evaluation=evaluation,
                  warnings=tuple(warnings), posterior=post, diagnostics=diag,
                  inference_data=idata, references=references, extra=extra,
                  scene_id={"target": scene.target.id, "image_size": [scene.image_width, scene.image_height],
                            "sha256": scene_fingerprint(scene)})


def _confidence_map(model: str, value):
    """The confidence map the model reads ranges with (None: confidences ignored)."""
    from .models.confidence_map import ConfidenceMap, resolve_confidence_map

    if model == "paper":
        if value is None or (isinstance(value, str) and value in ("default", "none")):
            return None
        shown = value.source or value.kind if isinstance(value, ConfidenceMap) else value
        raise ValueError(f"confidence_map: the paper model turns ranges into bounds and does not read "
                         f"stated confidences, got {shown!r} (use the metrology model, or 'none')")
    return resolve_confidence_map(value)


def _confidence_summary(scene: Scene, models, cmap) -> dict:
    """The result's ``confidence`` block: the map and how many ranges it read."""
    from .models.confidence_map import describe_confidence_map

    stated = sum(r.is_range and r.confidence is not None for r in scene.references)
    read = getattr(models[0], "n_stated_ranges", 0) if cmap is not None else 0
    return {"map": describe_confidence_map(cmap), "ranges_with_confidence": int(stated),
            "read_with_map": int(read)}


#: The MAP's box is reported as missing the annotations when the RMS distance of its projected
#: corners t1..t4 from the annotations' per-corner median exceeds this many times the
#: annotations' own spread (docs/user_guide.md, "When the box misses the annotations").
REPROJECTION_WARN_FACTOR = 3.0
#: Floor of that spread, pixels: identical (copied or noise-free) annotations have none.
REPROJECTION_MIN_SPREAD_PX = 1.0


def reprojection_check(scene: Scene, setup: CameraSetup, map_est) -> list[str]:
    """A warning when the MAP's box visibly misses the target's annotations.

    The MAP's reprojection error is the RMS over t1..t4 of the distance (pixels) between the
    projected corner and the annotations' per-corner median; the annotations' spread is the RMS
    distance of one annotation's corner from their consensus, √2 σ with σ the pooled
    per-coordinate sd (:func:`~.models.metrology.estimate_target_sigma`; 5 px for a single
    annotation), at least :data:`REPROJECTION_MIN_SPREAD_PX`. Warns when the error exceeds
    :data:`REPROJECTION_WARN_FACTOR` times the spread.
    """
    from .core.cost import project_params
    from .core.geometry import dimension_corners
    from .models.metrology import estimate_target_sigma

    t = scene.target
    obj = dimension_corners(t.length, t.width, t.height, map_est.handedness)
    uv, _ = project_params(map_est.params[None], obj, setup.camera.principal_point)
    error = float(np.sqrt(np.mean(np.sum((uv[0] - t.median_corners) ** 2, axis=-1))))
    spread = max(np.sqrt(2.0) * estimate_target_sigma(t.corners), REPROJECTION_MIN_SPREAD_PX)
    if not np.isfinite(error) or error > REPROJECTION_WARN_FACTOR * spread:
        return [f"the MAP's box misses the target's annotations: its corners are {error:.1f} px (RMS) "
                f"from the annotations' median, over {REPROJECTION_WARN_FACTOR:g} times the annotations' "
                f"own spread ({spread:.1f} px); the estimate is not supported by the annotations (try "
                "the default model and preset, or check the dimension lines and the target's size)"]
    return []


def _focal_prior_check(setup: CameraSetup, map_est) -> list[str]:
    """A warning when the MAP's µ lies outside the 99 % interval of an informative focal prior."""
    prior = setup.terms.focal
    if prior is None or prior.source == "default":
        return []
    lo, hi = prior.interval(0.99)
    mu = float(map_est.params[4])
    if lo <= mu <= hi:
        return []
    return [f"the annotations disagree with the {prior.source} focal length prior: MAP "
            f"{mu:.0f} px, prior median {prior.median_px:.0f} px (99 % interval {lo:.0f}–{hi:.0f}); "
            "was the image cropped or resized?"]


def _references_step(scene: Scene, setup: CameraSetup, preset: str, use_references: bool):
    """Pairs of references → soft constraints, as a :class:`ReferenceReport`.

    The paper model's cost uses the constraints; for the metrology model the pairs are only
    reported (for comparison and for the top-view plot). The pairwise aggregation needs a horizon:
    the exact or measured one, else a level camera (:attr:`CameraSetup.aggregation_camera`).
    """
    from .core.metrology import ReferenceReport, aggregate_references

    if not use_references:
        return ReferenceReport(len(scene.references), enabled=False)
    bounds = preset_bounds(preset, scene.image_width, scene.image_height)
    return aggregate_references(scene, setup.aggregation_camera,
                                focal_range_px=(bounds.lower[4], bounds.upper[4]))


def _reported_names(model) -> list[str]:
    """Names of :func:`_reported`'s columns."""
    from .models.params import PARAM_NAMES

    return [n for n, f in zip(PARAM_NAMES, model.free) if not f] + ["distance_m"]


def _reported(model, coords, q: np.ndarray) -> np.ndarray:
    """(n, k) quantities the result reports that the sampler does not sample itself, from its
    coordinates ``q``: the fixed or derived parameters (pitch and roll from µ and a horizon;
    constant ones, even to rounding only, get τ = 1) and the distance. The sampler's stopping rule watches their
    autocorrelation times too (a derived quantity can mix more slowly than any parameter)."""
    full = model.expand(q if coords is None else coords.inverse(q))
    free = np.asarray(model.free, bool)
    return np.column_stack([full[:, ~free], np.hypot(full[:, 0], full[:, 2])])


def _posterior_step(models, map_est, scene, rng, *, temperature, hdi_prob, sampling, progress):
    """Sample the posterior of the MAP's handedness from the MAP, and summarise it.

    Returns the :class:`~creference_bayes.io.result.PosteriorSummary`, the :class:`~creference_bayes.io.result.Diagnostics` (whose
    ``seconds`` cover the whole step), the InferenceData and notes for the result's warnings.
    """
    from .inference.posterior import DEFAULT_TEMPERATURE, LogPosterior, Reparametrised, laplace_scales
    from .inference.modes import find_modes
    from .inference.sampling import SamplerSettings, SamplingError, sample
    from .inference.summary import posterior_arrays, summarise, to_inference_data
    from .models.coordinates import Chained, HorizonDistance, ImageRay
    from .models.params import YAW

    t0 = time.perf_counter()
    settings = SamplerSettings.from_options(sampling)
    model = next(m for m in models if m.handedness == map_est.handedness)
    if temperature is None:  # a model may bring its own (metrology: a proper likelihood, T = 1)
        temperature = getattr(model, "default_temperature", DEFAULT_TEMPERATURE)
    # yaw on one turn around the MAP's, not the whole real line (a periodic density there is
    # improper, and an ensemble diffuses over turns where the annotations hardly fix yaw)
    yaw_map = float(map_est.params[YAW]) if model.free[YAW] else None
    log_post = LogPosterior(model, temperature, yaw_center=yaw_map)
    # pitch → log of the target's distance below the horizon; x, y → the target's image offsets
    coords = Chained.of(HorizonDistance.from_model(model), ImageRay.from_model(model))
    target = log_post if coords is None else Reparametrised(log_post, coords)
    center = map_est.params[model.free]
    lo, hi = log_post._lo, log_post._hi  # a MAP on a bound: start just inside it (the round trip
    span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)  # through the sampler's coordinates
    center = np.clip(center, lo + 1e-6 * span, hi - 1e-6 * span)  # must not leave the support)
    center = center if coords is None else coords.forward(center[None])[0]
    laplace = laplace_scales(target, center)
    log_mask = model.bounds.lower[model.free] > 0
    modes = []
    try:
        if settings.mode_search:  # other modes: the ensembles start in them, the proposal covers them
            modes = find_modes(target, center, laplace.cov, laplace=lambda c: laplace_scales(target, c).cov,
                               rng=_side_stream(rng), log_mask=log_mask, circular=log_post.yaw_index,
                               temperature=settings.explore_temperature, n_steps=settings.explore_steps)
        chains = sample(target, center, laplace.cov, settings=settings, rng=rng, log_mask=log_mask,
                        progress=progress, modes=[(m.center, m.cov) for m in modes[1:]],
                        derived=functools.partial(_reported, model, coords))
        chains.info["derived_tau"] = dict(zip(_reported_names(model), chains.info["derived_tau"]))
    except SamplingError as exc:  # e.g. a MAP with zero posterior density: report, do not crash
        return None, None, None, [f"posterior not sampled: {exc}"]
    if coords is not None:  # back to the model's parameters
        q = chains.chain.reshape(-1, chains.chain.shape[-1])
        chains = dataclasses.replace(
            chains, chain=coords.inverse(q).reshape(chains.chain.shape),
            log_prob=chains.log_prob - coords.log_jacobian(q).reshape(chains.log_prob.shape))
    arrays = posterior_arrays(chains, model.expand)
    post, diag = summarise(chains, model.expand, free=model.free, hdi_prob=hdi_prob, min_ess=settings.min_ess,
                           tau_multiple=settings.tau_multiple, handedness=map_est.handedness,
                           temperature=temperature, arrays=arrays)
    if len(modes) > 1:
        diag = dataclasses.replace(diag, modes=_mode_report(modes, model, coords, log_post, chains))
    idata = to_inference_data(chains, model.expand, scene=scene, arrays=arrays, attrs={
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


def _mode_report(modes, model, coords, log_post, chains) -> tuple[dict, ...]:
    """The diagnostics' ``modes``: where each mode found before sampling is, how much lower its
    log-density is than the MAP's, its Laplace share of the mass, and the share of each
    ensemble's draws nearest to it."""
    centers = np.array([m.center for m in modes])
    free = centers if coords is None else coords.inverse(centers)
    full = model.expand(free)
    lp = log_post(free)
    shares = chains.info.get("mode_shares")
    out = []
    for k, m in enumerate(modes):
        out.append({"distance_m": float(np.hypot(full[k, 0], full[k, 2])), "yaw": float(full[k, 3]),
                    "log_density_below_map": float(lp[0] - lp[k]), "laplace_share": m.share,
                    "draw_share_per_ensemble": None if shares is None else [g[k] for g in shares]})
    return tuple(out)


def _side_stream(rng: np.random.Generator) -> np.random.Generator:
    """A generator independent of ``rng`` that leaves ``rng`` untouched (the mode search's): a
    posterior with one mode gets exactly the draws it got without the search."""
    seq = rng.bit_generator.seed_seq
    return np.random.default_rng(np.random.SeedSequence(
        seq.entropy, spawn_key=tuple(seq.spawn_key) + (2**31 + 19,), pool_size=seq.pool_size))
