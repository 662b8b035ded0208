"""The estimate of one target and its ``creference-result/1`` JSON (formats.md)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .optimize import MapEstimate

__all__ = ["RESULT_FORMAT", "Evaluation", "Result", "load_result_dict"]

RESULT_FORMAT = "creference-result/1"


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
    posterior : posterior summary (mean, median, sd, hdi dicts), or None when not sampled
    diagnostics : sampler diagnostics (a dict matching formats.md), or None
    references : reference aggregation report with ``pairs_used``/``pairs_skipped``, or None
    evaluation : comparison with ground truth, or None
    warnings : what the user should know (assumed level camera, not converged, …)
    extra : anything else worth keeping in the JSON (keys are added, never renamed)
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

    def to_dict(self) -> dict:
        """The ``creference-result/1`` document."""
        d: dict[str, Any] = {"format": RESULT_FORMAT, "scene": self.scene, "target": self.target,
                             "model": self.model, "preset": self.preset, "map": self.map.to_dict(),
                             "handedness": self.map.handedness}
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
        d.update(_plain(self.extra))
        return d

    def to_json(self, path: str | Path | None = None, indent: int = 2) -> str:
        """Serialise; write to ``path`` when given. Returns the JSON text."""
        text = json.dumps(self.to_dict(), indent=indent, allow_nan=False)
        if path is not None:
            Path(path).write_text(text + "\n")
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
    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ValueError(f"format: expected {RESULT_FORMAT!r}, got {got!r}")
    return data


