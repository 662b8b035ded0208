"""What the rest of a scene says about each stated range's true value (for a fit without truth).

For a range j, the posterior of what it measures given all the *other* annotations of its scene
(every target's dimension lines and the other references, whatever their kind: ground segments,
relative ones, a target's own size, the distance between two targets) is what a worker's range
can be scored against when no ground truth exists. It is computed from one posterior per scene:

1. estimate the scene with every reference, confidences ignored (the map ``none``: the other
   references then need no confidence map, so nothing the fit is to find is assumed);
2. for each range, weight the draws by 1 / its likelihood term: draws from p(θ | all) weighted so
   become draws from p(θ | all but j). Pareto smoothing (Vehtari et al. 2024) stabilises the
   largest weights, and its shape k̂ says whether they can be trusted; when not
   (k̂ > :data:`PARETO_K_MAX`: the range moved the posterior a lot), the scene is estimated again
   without it;
3. take what the range measures at each draw (the model's reading of it:
   :meth:`~creference_bayes.models.metrology.MetrologyModel.predicted_log_lengths`), and resample
   to :data:`N_DRAWS` equally weighted draws of its log.

The range's line noise at the pilot (σ_line² |∇ log ℓ_j|², the metrology model's; 0 without a
line) goes with it: a worker's range is about the object, the drawn line adds its own error.
"""

from __future__ import annotations

import contextlib
import dataclasses
import warnings

import numpy as np

from ...io.scene import Scene
from ...pipeline import estimate
from .data import StatedRange, stated_ranges

__all__ = ["N_DRAWS", "PARETO_K_MAX", "RangePrediction", "predict_ranges", "predict_data_set"]

#: Draws of log ℓ kept per range.
N_DRAWS = 400
#: Above this Pareto shape the smoothed weights are unreliable (Vehtari et al. 2024).
PARETO_K_MAX = 0.7


@dataclasses.dataclass(frozen=True)
class RangePrediction:
    """A stated range and the leave-one-out posterior of what it measures.

    Attributes
    ----------
    range : the :class:`~creference_bayes.workflows.confidence.data.StatedRange`
    log_length : (N_DRAWS,) equally weighted draws of its log given the other annotations, in the
        range's unit
    line_var : σ_line² |∇ log ℓ_j|², the line's own noise in log-length (variance; 0 without a line)
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


def _resample(values: np.ndarray, weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """:data:`N_DRAWS` equally weighted draws by systematic resampling."""
    cum = np.cumsum(weights)
    cum /= cum[-1]
    u = (rng.uniform() + np.arange(N_DRAWS)) / N_DRAWS
    return values[np.minimum(np.searchsorted(cum, u), len(values) - 1)]


def _posterior(scene: Scene, rng, sampling, key: str):
    """(model, cameras (n, 5), objects (n, m, 7), converged) of the scene's posterior, map ``none``."""
    result = estimate(scene, seed=rng, confidence_map="none", sampling=sampling, keep_draws=0)
    if result.draws is None:
        raise RuntimeError(f"{key}: the posterior could not be sampled ({'; '.join(result.warnings)})")
    m = result.model
    cams = m.complete_camera(result.draws.cameras.reshape(-1, 5))
    return m, cams, result.draws.objects.reshape(len(cams), m.n_objects, 7), bool(result.converged)


def predict_ranges(scene: Scene, key: str = "scene", *, seed=0, sampling: dict | None = None) -> tuple[
        list[RangePrediction], dict]:
    """The leave-one-out posterior of every usable range with a confidence in ``scene``.

    Parameters
    ----------
    scene : the scene (its ground truth, if any, is not used)
    key : the scene's key in the data set
    seed : seed of the estimates and the resampling
    sampling : sampler settings for the estimates

    Returns
    -------
    predictions, info (``ranges``, ``refits``, ``skipped`` (ranges the model leaves out: an
    endpoint above an exact horizon), ``converged``)
    """
    rng = np.random.default_rng(seed)
    ranges = stated_ranges([(key, scene)], use_truth=False)
    info = {"ranges": len(ranges), "refits": 0, "skipped": 0, "converged": True}
    if not ranges:
        return [], info
    from ...inference.summary import psis_weights  # the arviz adapter, imported when used

    model, cams, objs, info["converged"] = _posterior(scene, rng, sampling, key)
    column = {t.index: j for j, t in enumerate(model.references)}
    loglik = model.pointwise_log_likelihood(cams, objs)["references"]  # (n, k)
    pred = model.predicted_log_lengths(cams, objs)
    out = []
    for r in ranges:
        j = column.get(r.index)
        if j is None:
            info["skipped"] += 1
            continue
        weights, k = psis_weights(-loglik[:, j])
        these, w, refit = pred[:, j], weights[0], not k[0] <= PARETO_K_MAX
        if refit:
            info["refits"] += 1
            keep = [i for i, x in enumerate(scene.references) if x.index != r.index]
            without = dataclasses.replace(scene, references=tuple(scene.references[i] for i in keep),
                                          reference_targets=tuple(scene.reference_targets[i] for i in keep))
            _, c2, o2, _ = _posterior(without, rng, sampling, key)
            these = model.predicted_log_lengths(c2, o2)[:, j]
            w = np.full(len(these), 1.0 / len(these))
        out.append(RangePrediction(r, _resample(these, w, rng), float(model.ref_line_var[j]), float(k[0]), refit))
    return out, info


def _predict_job(job: tuple) -> tuple:
    """:func:`predict_ranges` for a process pool: ``job`` is (key, scene, seed, sampling); returns
    (key, predictions, info) or (key, None, the error): one scene's failure does not stop the others."""
    key, scene, seed, sampling = job
    from ...inference.threads import single_threaded_blas

    try:
        with warnings.catch_warnings(), single_threaded_blas():
            warnings.simplefilter("ignore")
            return (key, *predict_ranges(scene, key, seed=seed, sampling=sampling))
    except Exception as exc:
        return key, None, f"{type(exc).__name__}: {exc}"


def predict_data_set(scenes, *, seed: int = 0, sampling: dict | None = None, workers: int = 1,
                     progress: bool | str = False) -> tuple[list[RangePrediction], dict, dict[str, str]]:
    """:func:`predict_ranges` for every scene of a data set, in ``workers`` local processes.

    Parameters
    ----------
    scenes : (key, Scene) pairs
    seed : base seed; each scene's derives from it and the scene's content (as in a batch)
    sampling : sampler settings for the estimates
    workers : processes (1: in this process)
    progress : a bar on standard error (True), a line per scene (``"lines"``) or nothing (False),
        as :func:`~creference_bayes.inference.progress.progress_mode` chooses

    Returns
    -------
    predictions (in the order of ``scenes``), totals of the scenes' info, errors (key → message)
    """
    from ...inference.progress import progress_bar
    from ...io.scene import scene_fingerprint
    from ..batch import derive_seed
    from ..batch.engines import LocalEngine

    jobs = [(k, s, derive_seed(seed, scene_fingerprint(s)), sampling) for k, s in scenes
            if any(r.is_range and r.confidence is not None for r in s.references)]
    with contextlib.ExitStack() as stack:
        run = map if workers <= 1 else stack.enter_context(LocalEngine(workers)).executor.map
        bar = stack.enter_context(progress_bar(progress, len(jobs), desc="leave-one-out", unit="scene"))
        done = []
        for key, found, info in run(_predict_job, jobs):
            bar.set_postfix_str(f"{key}: " + ("failed" if found is None else f"{len(found)} range(s)"))
            bar.update()
            done.append((key, found, info))
    preds, errors = [], {}
    totals = {"scenes": len(jobs), "ranges": 0, "refits": 0, "skipped": 0, "not_converged": 0}
    for key, found, info in done:
        if found is None:
            errors[key] = info
            continue
        preds += found
        for k in ("ranges", "refits", "skipped"):
            totals[k] += info[k]
        totals["not_converged"] += not info["converged"]
    return preds, totals, errors
