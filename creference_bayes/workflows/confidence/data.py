"""The ranges stated with a confidence in a data set of scenes, and what is known of their truth.

A range is taken as the model reads its reference (:func:`~creference_bayes.pipeline.reference_terms`):
in metres, or as a ratio to a target's length or width when it is relative to a target of unknown
size. Its *truth*, in the same unit, is

- the measured object's true length when the ground truth states it (``reference_lengths_m``,
  metres, one per reference, in the scene's truth or a version-1 file's, as the simulator writes
  it): what the worker was asked about. The drawn segment's own error is the line noise the
  metrology model adds to each reference; scoring against the segment would count it twice;
- else, for a target's own size or the distance between two targets, the targets' truth
  (``dimensions_m`` or their known size; ``location_m``, bottom centres in the gravity-aligned
  camera frame: the distance is √(Δx² + Δz²));
- else, for a drawn segment, its real length under the true camera (``focal_length_px``,
  ``pitch_rad``, ``roll_rad``, ``camera_height_m``: :func:`~creference_bayes.models.metrology.ground_lengths`),
  the best there is for a real photo. It includes the drawing error, so the realised coverage is
  a little lower than the worker's own (most for lines close to the horizon);

divided by the target's true size for a relative range; else there is none (the range can enter
a fit without ground truth only). Scenes come from files and folders, as for ``creference batch``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from ...io.scene import Scene, SceneError, SceneWarning, load_scene
from ...models.confidence_map import group_key
from ...models.metrology import ground_lengths
from ...pipeline import reference_terms

__all__ = ["StatedRange", "load_scenes", "reference_truths", "stated_ranges", "range_counts"]

_SIZES = ("length", "width", "height")


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
    low, high : the range, in the unit the model reads it (module docstring)
    truth : the real value it should hold, same unit, or None
    truth_source : ``"object"`` (the measured object's own truth) or ``"segment"`` (the drawn
        segment under the true camera), or None
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
        return asdict(self)


def load_scenes(inputs) -> list[tuple[str, Scene]]:
    """(key, scene) of every scene file of ``inputs`` (files and folders); an invalid scene raises
    :class:`~creference_bayes.io.scene.SceneError` with its file's path."""
    from ..batch import discover_scenes

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


def _positive(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def _true_size(target, k: int) -> float | None:
    """A target's true length, width or height (``k`` 0–2), metres: its truth, else its known size."""
    dims = (target.ground_truth or {}).get("dimensions_m") or {}
    known = None if target.dimensions is None else target.dimensions[k]
    return _positive(dims.get(_SIZES[k], known)) if isinstance(dims, dict) else _positive(known)


def _true_distance(a, b) -> float | None:
    try:
        (xa, _, za), (xb, _, zb) = ((t.ground_truth or {})["location_m"] for t in (a, b))
    except (KeyError, TypeError, ValueError):
        return None
    return _positive(math.hypot(xa - xb, za - zb))


def reference_truths(scene: Scene, terms=None) -> list[tuple[float | None, str | None]]:
    """(truth, source) of every reference of ``scene`` (module docstring; the source is
    ``"object"`` or ``"segment"``), in the unit of its
    :class:`~creference_bayes.models.metrology.ReferenceTerm` (``terms``: the scene's by default)."""
    terms = reference_terms(scene) if terms is None else terms
    gt = scene.ground_truth or {}
    stated = None
    for truth in (gt, *(t.ground_truth or {} for t in scene.targets)):  # a version-1 file's is its target's
        v = truth.get("reference_lengths_m")
        if stated is None and isinstance(v, list) and len(v) == len(scene.references) and all(map(_positive, v)):
            stated = v
    camera = [_positive(gt.get("focal_length_px", scene.focal_length_px)), gt.get("pitch_rad"), gt.get("roll_rad"),
              _positive(gt.get("camera_height_m")), 0.0]
    out = []
    for t in terms:
        value, source = None, "object"
        if stated is not None:
            value = float(stated[t.index])
        elif t.kind == "size":
            value = _true_size(scene.targets[t.owner], t.size_index)
        elif t.kind == "distance":
            value = _true_distance(scene.targets[t.owner], scene.targets[t.other])
        elif None not in camera:
            value = _positive(ground_lengths(t.line[None], scene.principal_point, np.array(camera, float))[0, 0])
            source = "segment"
        if value is not None and t.kind == "relative":
            size = _true_size(scene.targets[t.owner], t.size_index)
            value = None if size is None else value / size
        out.append((None, None) if value is None else (value, source))
    return out


def stated_ranges(scenes, *, use_truth: bool = True) -> list[StatedRange]:
    """Every range with a confidence in ``scenes`` ((key, Scene) pairs), with its truth when
    known (and ``use_truth``). Ranges whose ends are equal are left out (the model reads them
    without the map)."""
    out = []
    for key, scene in scenes:
        terms = reference_terms(scene)
        truths = reference_truths(scene, terms) if use_truth else [(None, None)] * len(terms)
        for r, t, (truth, source) in zip(scene.references, terms, truths):
            if t.is_range and t.confidence is not None and t.high > t.low:
                out.append(StatedRange(key, t.index, r.worker, t.measure, t.mode, float(t.confidence),
                                       float(t.low), float(t.high), truth, source))
    return out


def range_counts(scenes) -> dict[str, int]:
    """How many references of each kind the scenes hold (for the reports' notes)."""
    refs = [r for _, scene in scenes for r in scene.references]
    stated = [r for r in refs if r.confidence is not None]
    return {"scenes": len(scenes), "references": len(refs),
            "ranges_with_confidence": sum(r.is_range for r in stated),
            "values_with_confidence": sum(not r.is_range for r in stated),
            "without_confidence": len(refs) - len(stated)}
