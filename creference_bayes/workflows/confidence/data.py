"""The ranges with a stated confidence in a data set, and what is known about their truth.

A range's *truth* is the real length it should have held:

- the object's true dimension, when the scene's ground truth gives it
  (``ground_truth.reference_lengths_m``, as the simulator writes it); this is what the worker was
  asked about, and what a confidence map is about. The drawn segment is a second, separate
  error (the line's pixel noise), which the metrology model already adds to each reference's
  scale; scoring against the drawn segment would count it twice;
- else the drawn segment's real length under the true camera (ground truth with focal length,
  pitch, roll and camera height: :func:`~creference_bayes.models.metrology.ground_lengths`), the
  best available for a real photo with a calibrated camera. It includes the drawing error, so the
  realised coverage is a little lower than the worker's own (most for lines close to the horizon);
- else none: the range can only enter a fit without ground truth.

Scenes come from files and folders (every ``*.json`` below a folder), as for ``creference batch``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ...io.scene import Scene, SceneError, SceneWarning, load_scene
from ...models.confidence_map import group_key
from ...models.metrology import ground_lengths
from ..batch import discover_scenes

__all__ = ["StatedRange", "load_scenes", "true_lengths", "stated_ranges", "range_counts"]


@dataclass(frozen=True)
class StatedRange:
    """One range stated with a confidence.

    Attributes
    ----------
    scene : the scene's key (its file's path relative to the input folder, without ``.json``)
    index : the reference's index in the scene
    worker : the worker's id, or None
    measure, mode : the reference's measure and mode
    confidence : the stated confidence c in [0, 1]
    low, high : the range, metres
    truth : the real length it should hold, metres, or None (module docstring)
    truth_source : ``"object"`` (the object's true dimension), ``"segment"`` (the drawn segment
        under the true camera) or None
    """

    scene: str
    index: int
    worker: str | None
    measure: str
    mode: str
    confidence: float
    low: float
    high: float
    truth: float | None = None
    truth_source: str | None = None

    @property
    def group(self) -> str:
        return group_key(self.measure, self.mode)

    @property
    def centre(self) -> float:
        """The log-centre m = (log low + log high)/2."""
        return 0.5 * (math.log(self.low) + math.log(self.high))

    @property
    def half_width(self) -> float:
        """The log half-width w = (log high − log low)/2."""
        return 0.5 * (math.log(self.high) - math.log(self.low))

    @property
    def covered(self) -> bool | None:
        """Whether the range holds its truth (None without one)."""
        return None if self.truth is None else bool(self.low <= self.truth <= self.high)

    def to_dict(self) -> dict:
        return {"scene": self.scene, "index": self.index, "worker": self.worker, "measure": self.measure,
                "mode": self.mode, "confidence": self.confidence, "low": self.low, "high": self.high,
                "truth": self.truth, "truth_source": self.truth_source}


def load_scenes(inputs) -> list[tuple[str, Scene]]:
    """(key, scene) of every scene file of ``inputs`` (files and folders); an invalid scene raises
    :class:`~creference_bayes.io.scene.SceneError` with its file's path."""
    out = []
    for si in discover_scenes(inputs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            try:
                out.append((si.key, load_scene(si.path)))
            except SceneError as exc:  # say which file of the folder
                if exc.path.startswith(str(si.path)):
                    raise
                raise SceneError(f"{si.path}: {exc.path}", exc.problem) from None
    return out


def true_lengths(scene: Scene) -> tuple[np.ndarray | None, str | None]:
    """(m,) the truth of every reference of ``scene`` (module docstring) and its source, or
    (None, None)."""
    gt = scene.ground_truth
    if gt is None or not scene.references:
        return None, None
    lengths = gt.extra.get("reference_lengths_m")
    if isinstance(lengths, list) and len(lengths) == len(scene.references):
        try:
            a = np.array(lengths, float)
        except (TypeError, ValueError):
            a = None
        if a is not None and np.all(np.isfinite(a) & (a > 0)):
            return a, "object"
    needed = (gt.focal_length_px, gt.extra.get("pitch_rad"), gt.extra.get("roll_rad"), gt.extra.get("camera_height_m"))
    if any(v is None for v in needed):
        return None, None
    f, pitch, roll, h = (float(v) for v in needed)
    full = np.array([0.0, h, 1.0, 0.0, f, pitch, roll])
    lines = np.stack([r.line for r in scene.references])
    return ground_lengths(lines, scene.principal_point, full)[0], "segment"


def stated_ranges(scenes, *, use_truth: bool = True) -> list[StatedRange]:
    """Every range with a confidence in ``scenes`` ((key, Scene) pairs), with its truth when
    known (and ``use_truth``). Relative ranges are converted to metres with the target's size;
    ranges whose ends are equal are left out (the model reads them without the map)."""
    out = []
    for key, scene in scenes:
        truth, source = true_lengths(scene) if use_truth else (None, None)
        for r in scene.references:
            if not r.is_range or r.confidence is None:
                continue
            low, high = r.length_bounds_m(scene.target)
            if not high > low:  # read as a single value by the model: no interval to score
                continue
            t = None if truth is None else float(truth[r.index])
            out.append(StatedRange(key, r.index, r.worker, r.measure, r.mode, float(r.confidence),
                                   float(low), float(high), t, source if t is not None else None))
    return out


def range_counts(scenes) -> dict[str, int]:
    """How many references of each kind the scenes hold (for the reports' notes)."""
    counts = {"scenes": 0, "references": 0, "ranges_with_confidence": 0, "values_with_confidence": 0,
              "without_confidence": 0}
    for _, scene in scenes:
        counts["scenes"] += 1
        for r in scene.references:
            counts["references"] += 1
            if r.confidence is None:
                counts["without_confidence"] += 1
            elif r.is_range:
                counts["ranges_with_confidence"] += 1
            else:
                counts["values_with_confidence"] += 1
    return counts
