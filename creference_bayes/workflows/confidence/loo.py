"""What the rest of a scene says about each stated range's true length (for a fit without truth).

For a range j, the posterior of its real length given all the *other* annotations (the target's
and the other references) is what a worker's range can be scored against when no ground truth
exists. It is computed from one posterior per scene:

1. estimate the scene with every reference, confidences ignored (the map ``none``: the other
   references then need no confidence map, so nothing the fit is to find is assumed);
2. for each range, weight the draws by 1 / its likelihood term (leave-one-out importance
   sampling, Pareto-smoothed: :mod:`~creference_bayes.inference.loo`); when the smoothed weights
   are unreliable (Pareto k̂ > 0.7: the range moved the posterior a lot), estimate the scene
   again without it;
3. push the (weighted) draws through ``ground_lengths`` of the range's drawn line, and resample
   them to :data:`N_DRAWS` equally weighted draws of log ℓ_j.

The range's line noise at the MAP (σ_line² |∇ log ℓ_j|², the metrology model's) goes with it: a
worker's range is about the object, the drawn line adds its own error.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings

import numpy as np

from ...camera_setup import setup_camera
from ...inference.loo import PARETO_K_MAX, psis_weights
from ...io.scene import Scene, parse_scene, scene_to_dict
from ...models.metrology import ground_lengths
from ...models.params import PARAM_NAMES
from ...pipeline import build_models, estimate
from .data import StatedRange, stated_ranges

__all__ = ["N_DRAWS", "RangePrediction", "predict_ranges", "predict_scene_job", "scene_job", "predict_data_set"]

#: Draws of log ℓ kept per range.
N_DRAWS = 400


@dataclasses.dataclass(frozen=True)
class RangePrediction:
    """A stated range and the leave-one-out posterior of its real length.

    Attributes
    ----------
    range : the :class:`~creference_bayes.workflows.confidence.data.StatedRange`
    log_length : (N_DRAWS,) equally weighted draws of log ℓ_j given the other annotations
    line_var : σ_line² |∇ log ℓ_j|², the line's own noise in log-length (variance)
    pareto_k : the Pareto shape of its leave-one-out weights
    refit : whether the scene was estimated again without the range (k̂ too large)
    """

    range: StatedRange
    log_length: np.ndarray
    line_var: float
    pareto_k: float
    refit: bool

    def to_dict(self) -> dict:
        return {"range": self.range.to_dict(), "log_length": self.log_length.tolist(),
                "line_var": self.line_var, "pareto_k": self.pareto_k, "refit": self.refit}

    @classmethod
    def from_dict(cls, d: dict) -> "RangePrediction":
        return cls(StatedRange(**d["range"]), np.asarray(d["log_length"], float), float(d["line_var"]),
                   float(d["pareto_k"]), bool(d["refit"]))


def _draws(result) -> np.ndarray:
    """(n, 7) full parameter vectors of a result's posterior draws."""
    post = result.inference_data.posterior
    return np.column_stack([np.asarray(post[name]).ravel() for name in PARAM_NAMES])


def _resample(values: np.ndarray, weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """:data:`N_DRAWS` equally weighted draws by systematic resampling."""
    cum = np.cumsum(weights)
    cum /= cum[-1]
    u = (rng.uniform() + np.arange(N_DRAWS)) / N_DRAWS
    return values[np.minimum(np.searchsorted(cum, u), len(values) - 1)]


def predict_ranges(scene: Scene, key: str = "scene", *, seed=0, sampling: dict | None = None) -> tuple[
        list[RangePrediction], dict]:
    """The leave-one-out length posterior of every usable range with a confidence in ``scene``.

    Parameters
    ----------
    scene : the scene (its ground truth, if any, is not used)
    key : the scene's key in the data set
    seed : seed of the estimates and the resampling
    sampling : sampler settings for the estimates

    Returns
    -------
    predictions, info (``ranges``, ``refits``, ``skipped`` (ranges above the horizon),
    ``converged``)
    """
    rng = np.random.default_rng(seed)
    ranges = {r.index: r for r in stated_ranges([(key, scene)], use_truth=False)}
    info = {"ranges": len(ranges), "refits": 0, "skipped": 0, "converged": True}
    if not ranges:
        return [], info
    result = estimate(scene, seed=rng, confidence_map="none", sampling=sampling)
    if result.inference_data is None:
        raise RuntimeError(f"{key}: the posterior could not be sampled ({'; '.join(result.warnings)})")
    info["converged"] = bool(result.diagnostics.converged)
    setup = setup_camera(scene)
    models = build_models(scene, setup, model="metrology")
    model = next(m for m in models if m.handedness == result.map.handedness)
    model.set_pilot(result.map.params)
    draws = _draws(result)
    full_nll = model.reference_nll(draws)
    line_var = dict(zip(model.reference_indices.tolist(), model.line_variances.tolist()))
    out = []
    for index, r in ranges.items():
        if index not in line_var:  # above the horizon: the model does not use it
            info["skipped"] += 1
            continue
        without = dataclasses.replace(scene, references=tuple(x for x in scene.references if x.index != index))
        reduced = next(m for m in build_models(without, setup, model="metrology")
                       if m.handedness == result.map.handedness)
        reduced.set_pilot(result.map.params)
        weights, k = psis_weights((full_nll - reduced.reference_nll(draws))[None])
        these, w, refit = draws, weights[0], False
        if not k[0] <= PARETO_K_MAX:
            refit = True
            info["refits"] += 1
            again = estimate(without, seed=rng, confidence_map="none", sampling=sampling)
            these, w = _draws(again), None
        line = scene.references[index].line[None]
        log_len = np.log(ground_lengths(line, scene.principal_point, these)[:, 0])
        w = np.full(len(log_len), 1.0 / len(log_len)) if w is None else w
        out.append(RangePrediction(r, _resample(log_len, w, rng), float(line_var[index]), float(k[0]), refit))
    return out, info


def predict_scene_job(job: dict) -> dict:
    """:func:`predict_ranges` for a process pool: ``job`` holds the scene's ``key``, its
    ``data`` (scene dict), ``seed`` and ``sampling``; returns plain dicts (or the error)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = parse_scene(job["data"])
            preds, info = predict_ranges(scene, job["key"], seed=job["seed"], sampling=job.get("sampling"))
        return {"ok": True, "key": job["key"], "predictions": [p.to_dict() for p in preds], "info": info}
    except Exception as exc:  # one scene's failure is reported, the others go on
        return {"ok": False, "key": job["key"], "error": f"{type(exc).__name__}: {exc}"}


def scene_job(key: str, scene: Scene, seed: int, sampling: dict | None = None) -> dict:
    """The job of :func:`predict_scene_job` for a scene."""
    return {"key": key, "data": scene_to_dict(scene), "seed": seed, "sampling": sampling}


def predict_data_set(scenes, *, seed: int = 0, sampling: dict | None = None, workers: int = 1,
                     progress: bool = False) -> tuple[list[RangePrediction], dict, dict[str, str]]:
    """:func:`predict_ranges` for every scene of a data set, in ``workers`` local processes.

    Parameters
    ----------
    scenes : (key, Scene) pairs
    seed : base seed; each scene's derives from it and the scene's content (as in a batch)
    sampling : sampler settings for the estimates
    workers : processes (1: in this process)
    progress : a tqdm bar on standard error

    Returns
    -------
    predictions (in the order of ``scenes``), totals of the scenes' info, errors (key → message)
    """
    from tqdm.auto import tqdm

    from ...io.scene import scene_fingerprint
    from ..batch import derive_seed
    from ..batch.engines import LocalEngine

    jobs = [scene_job(k, s, derive_seed(seed, scene_fingerprint(s)), sampling) for k, s in scenes
            if any(r.is_range and r.confidence is not None for r in s.references)]
    results: dict[str, dict] = {}
    bar = tqdm(total=len(jobs), unit="scene", desc="leave-one-out", disable=not progress, file=sys.stderr)
    try:
        if workers <= 1:
            for job in jobs:
                results[job["key"]] = predict_scene_job(job)
                bar.update(1)
        else:
            import concurrent.futures as cf

            with LocalEngine(workers) as engine:
                futures = [engine.executor.submit(predict_scene_job, job) for job in jobs]
                for fut in cf.as_completed(futures):
                    res = fut.result()
                    results[res["key"]] = res
                    bar.update(1)
    finally:
        bar.close()
    preds, totals, errors = [], {"scenes": len(jobs), "ranges": 0, "refits": 0, "skipped": 0,
                                 "not_converged": 0}, {}
    for job in jobs:
        res = results[job["key"]]
        if not res["ok"]:
            errors[job["key"]] = res["error"]
            continue
        preds += [RangePrediction.from_dict(d) for d in res["predictions"]]
        for k in ("ranges", "refits", "skipped"):
            totals[k] += res["info"][k]
        totals["not_converged"] += not res["info"]["converged"]
    return preds, totals, errors
