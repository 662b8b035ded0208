"""The estimate of one target and its ``creference-result/1`` JSON (formats.md)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..models.params import PARAM_NAMES
from .files import atomic_write_text
from .files import read_text

__all__ = ["scene_candidates", "RESULT_FORMAT", "MapEstimate", "Evaluation", "PosteriorSummary", "Diagnostics", "Result", "load_result_dict"]

RESULT_FORMAT = "creference-result/1"


@dataclass(frozen=True)
class MapEstimate:
    """The optimum of a model's cost.

    Attributes
    ----------
    params : (5,) x, y, z (m), yaw (rad, wrapped to [−π, π)), focal length (px)
    handedness : +1 or −1, the dimension-line handedness that fits best
    cost : the model's cost at ``params``
    preset : the optimiser preset used
    seconds : wall time of the optimisation
    n_evaluations : number of cost evaluations (vectorised batches count their rows)
    info : what happened, per handedness (a plain dict)
    """

    params: np.ndarray
    handedness: int
    cost: float
    preset: str
    seconds: float
    n_evaluations: int
    info: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """``{"x": …, "y": …, "z": …, "yaw": …, "focal_length_px": …}`` (formats.md ``map``)."""
        return {k: float(v) for k, v in zip(PARAM_NAMES, self.params)}


@dataclass(frozen=True)
class Evaluation:
    """Comparison with the scene's ground truth.

    ``location_pct_error`` is Eq. 3 for the MAP (and ``posterior_location_pct_error`` for the
    posterior mean, when there is a posterior); ``in_hdi`` says whether each true value lies in
    its credible interval.
    """

    location_pct_error: float
    posterior_location_pct_error: float | None = None
    in_hdi: dict[str, bool] | None = None

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"location_pct_error": self.location_pct_error}
        if self.posterior_location_pct_error is not None:
            d["posterior_location_pct_error"] = self.posterior_location_pct_error
        if self.in_hdi is not None:
            d["in_hdi"] = dict(self.in_hdi)
        return d


def _finite_or_none(v):
    """JSON-safe number: NaN and ±inf become None."""
    if v is None:
        return None
    v = float(v)
    return v if np.isfinite(v) else None


@dataclass(frozen=True)
class PosteriorSummary:
    """Summary of the posterior draws (formats.md ``posterior``).

    Attributes
    ----------
    mean, median, sd : per quantity (x, y, z m; yaw rad; focal_length_px px; distance_m m).
        Yaw's mean is the circular mean in [−π, π) and its sd the circular sd √(−2 ln R̄).
    hdi : per quantity, the highest-density interval [low, high] at ``hdi_prob``; yaw's is an arc
        around its circular mean whose ends may lie outside [−π, π)
    hdi_prob : probability of the intervals
    handedness : the dimension-line handedness the posterior is conditioned on (the MAP's)
    temperature : T of log p = −cost′/T + log prior
    n_draws : draws summarised (all ensembles, after burn-in and thinning)
    draws : a few draws per ensemble (``chain`` index and one list per quantity), for plots
    """

    mean: dict[str, float]
    median: dict[str, float]
    sd: dict[str, float]
    hdi: dict[str, tuple[float, float]]
    hdi_prob: float
    handedness: int
    temperature: float
    n_draws: int
    draws: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        d = {key: {k: _finite_or_none(v) for k, v in getattr(self, key).items()}
             for key in ("mean", "median", "sd")}
        d["hdi"] = {"prob": self.hdi_prob,
                    **{k: [_finite_or_none(lo), _finite_or_none(hi)] for k, (lo, hi) in self.hdi.items()}}
        d.update({"handedness": self.handedness, "temperature": self.temperature,
                  "n_draws": self.n_draws})
        if self.draws:
            d["draws"] = self.draws
        return d


@dataclass(frozen=True)
class Diagnostics:
    """Convergence diagnostics of the sampler (formats.md ``diagnostics``).

    Attributes
    ----------
    n_walkers : walkers in all ensembles together;  n_ensembles : independent ensembles
    n_steps : main-phase steps per walker;  burn_in, thin : steps discarded, thinning kept
    warmup_steps : steps of the (discarded) adaptive warm-up before the main phase
    autocorr_time : integrated autocorrelation time per sampled quantity, steps
    ess_bulk, ess_tail : effective sample sizes (arviz, rank-normalised), per quantity
    r_hat : rank-normalised split R-hat across ensembles, per quantity
    acceptance_fraction : mean over walkers
    converged : chain ≥ 50 τ after burn-in, every R-hat ≤ 1.01, every bulk ESS ≥ the minimum
    warnings : the reasons when not converged, and anything else worth knowing
    seconds : wall time of the sampling
    modes : when the posterior has several modes (found before sampling; the ensembles start
        in different ones), one dict each: ``distance_m``, ``yaw``, ``log_density_below_map``,
        ``laplace_share`` and ``draw_share_per_ensemble``
    """

    n_walkers: int
    n_ensembles: int
    n_steps: int
    burn_in: int
    thin: int
    warmup_steps: int
    autocorr_time: dict[str, float]
    ess_bulk: dict[str, float | None]
    ess_tail: dict[str, float | None]
    r_hat: dict[str, float | None]
    acceptance_fraction: float
    converged: bool
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0
    modes: tuple = ()

    def to_dict(self) -> dict:
        d: dict[str, Any] = {k: getattr(self, k) for k in (
            "n_walkers", "n_ensembles", "n_steps", "burn_in", "thin", "warmup_steps")}
        for key in ("autocorr_time", "ess_bulk", "ess_tail", "r_hat"):
            d[key] = {k: _finite_or_none(v) for k, v in getattr(self, key).items()}
        d.update({"acceptance_fraction": _finite_or_none(self.acceptance_fraction),
                  "converged": bool(self.converged), "warnings": list(self.warnings)})
        if self.modes:
            d["modes"] = [dict(m) for m in self.modes]
        return d


@dataclass(frozen=True)
class Result:
    """Everything estimated for one target.

    Attributes
    ----------
    target : the target's id
    model : the model's name (``paper``, ``metrology``)
    preset : the optimiser preset
    map : the MAP estimate
    scene : the scene file's name, if it came from a file
    posterior : :class:`PosteriorSummary`, or None when not sampled
    diagnostics : :class:`Diagnostics` of the sampler, or None
    references : reference aggregation report with ``pairs_used``/``pairs_skipped``, or None
    evaluation : comparison with ground truth, or None
    warnings : what the user should know (assumed level camera, not converged, …)
    extra : anything else worth keeping in the JSON (keys are added, never renamed)
    scene_id : what identifies the scene the result came from: ``target`` (its id),
        ``image_size`` ([width, height], pixels) and ``sha256`` (:func:`~.scene.scene_fingerprint`)
    """

    target: str
    model: str
    preset: str
    map: MapEstimate
    scene: str | None = None
    posterior: Any = None
    diagnostics: Any = None
    references: Any = None
    evaluation: Evaluation | None = None
    warnings: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)
    scene_id: dict | None = None
    #: the full posterior as an ``arviz.InferenceData`` (not in the JSON; see ``--netcdf``)
    inference_data: Any = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """The ``creference-result/1`` document."""
        d: dict[str, Any] = {"format": RESULT_FORMAT, "scene": self.scene, "target": self.target,
                             "model": self.model, "preset": self.preset, "map": self.map.to_dict(),
                             "handedness": self.map.handedness}
        if self.scene_id is not None:
            d["scene_id"] = dict(self.scene_id)
        if self.posterior is not None:
            d["posterior"] = _plain(self.posterior.to_dict() if hasattr(self.posterior, "to_dict") else self.posterior)
        if self.diagnostics is not None:
            d["diagnostics"] = _plain(self.diagnostics.to_dict() if hasattr(self.diagnostics, "to_dict") else self.diagnostics)
        if self.references is not None:
            d["references"] = _plain(self.references.to_dict() if hasattr(self.references, "to_dict") else self.references)
        if self.evaluation is not None:
            d["evaluation"] = _plain(self.evaluation.to_dict())
        d["warnings"] = list(self.warnings)
        d["timing_s"] = {"map": self.map.seconds}
        if self.diagnostics is not None and hasattr(self.diagnostics, "seconds"):
            d["timing_s"]["posterior"] = self.diagnostics.seconds
        d.update(_plain(self.extra))
        return d

    def to_json(self, path: str | Path | None = None, indent: int = 2) -> str:
        """Serialise; write to ``path`` when given. Returns the JSON text."""
        text = json.dumps(self.to_dict(), indent=indent, allow_nan=False)
        if path is not None:
            atomic_write_text(path, text + "\n")
        return text

    @property
    def location(self) -> np.ndarray:
        """MAP location (x, y, z), metres."""
        return self.map.params[:3].copy()


def _plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays inside dicts and lists to JSON-able Python objects."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def load_result_dict(path: str | Path) -> dict:
    """Read a ``creference-result/1`` JSON file (plain dict), checking its format key."""
    data = json.loads(read_text(path))
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ValueError(f"format: expected {RESULT_FORMAT!r}, got {got!r}")
    return data




def scene_candidates(result: dict, result_path: str | Path) -> list[Path]:
    """Where the scene of a result (either format) may be, in the order to look: the batch
    folder's copy when the result came from ``creference batch`` (``batch.scene_copy``), then the
    file the result names (``scene``) beside the result, in the current folder and among the
    package's shipped scenes. The result file itself is never a candidate (a batch result is
    named like its scene)."""
    from importlib import resources

    result_path = Path(result_path)
    out = []
    batch = result.get("batch") if isinstance(result.get("batch"), dict) else {}
    if batch.get("scene_copy") and batch.get("key"):
        out.append(result_path.parents[len(Path(batch["key"]).parts)] / batch["scene_copy"])
    name = result.get("scene")
    if isinstance(name, str) and name:
        out += [result_path.parent / name, Path.cwd() / name,
                Path(str(resources.files("creference_bayes") / "data" / name))]
    me = result_path.resolve()
    return [p for p in out if p.resolve() != me]
