"""The annotations the frame's advice weighs (docs/advice.md#frames): for every object one more
set of dimension lines (``dims``), a worker's distance to it (``distance``: from the image's
bottom edge straight up to its nearest bottom corner at the MAP) and, with a class size prior, a
worker's statement of its length (``length``); and what each costs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...models.frame_boxes import frame_boxes_2d
from .candidates import PAPER_REFERENCE_SECONDS, PAPER_TARGET_SECONDS, SAME_SEGMENT_MIN_PX

__all__ = ["FrameCandidate", "frame_candidates", "frame_seconds"]


@dataclass(frozen=True)
class FrameCandidate:
    """One annotation the frame's advice weighs: ``kind`` ``dims``, ``distance`` or ``length`` on
    object ``index`` (id ``object``); ``line`` (2, 2) pixels for a distance; its cost in seconds."""

    kind: str
    index: int
    object: str
    seconds: float
    line: np.ndarray | None = None

    @property
    def key(self) -> str:
        return f"{self.object}:{self.kind}"

    @property
    def description(self) -> str:
        return {"dims": f"one more set of dimension lines on {self.object}",
                "distance": f"distance to {self.object} (image bottom to its nearest bottom corner)",
                "length": f"length of {self.object}"}[self.kind]

    def to_dict(self) -> dict:
        return {"key": self.key, "kind": self.kind, "object": self.object, "seconds": self.seconds,
                "line": None if self.line is None else np.round(self.line, 2).tolist(),
                "description": self.description}


def frame_seconds(frame) -> dict[str, float]:
    """Cost per kind, seconds: the median of the frame's recorded ``seconds`` of its dimension lines
    (``dims``) and of its references (``reference``), else the paper's averages (183.5 s, 64.4 s)."""
    def median(values, default):
        values = [v for v in values if v is not None and v > 0]
        return float(np.median(values)) if values else default

    return {"dims": median([d.seconds for t in frame.targets for d in t.dimension_lines], PAPER_TARGET_SECONDS),
            "reference": median([r.seconds for r in frame.references], PAPER_REFERENCE_SECONDS)}


def frame_candidates(model, frame, camera, objects, secs) -> tuple[list[FrameCandidate], list[str]]:
    """The candidates of every object (module docstring of :mod:`.frame`) at the MAP ``camera``
    (5,) and ``objects`` (m, 7), and notes on those left out; ``secs`` from :func:`frame_seconds`."""
    out, notes = [], []
    w, h = frame.image_width, frame.image_height
    for i, o in enumerate(model.objects):
        out.append(FrameCandidate("dims", i, o.id, secs["dims"]))
        box = frame_boxes_2d(camera[None], objects[i][None], frame.principal_point)[0, :4]  # bottom face
        near = box[int(np.nanargmax(box[:, 1]))] if np.any(np.isfinite(box[:, 1])) else None
        if near is None or not np.all(np.isfinite(near)) or not (0 <= near[0] <= w):
            notes.append(f"{o.id}:distance: left out: its nearest bottom corner is outside the image")
        elif near[1] >= h - 1 - SAME_SEGMENT_MIN_PX:
            notes.append(f"{o.id}:distance: left out: the object touches the image's bottom edge")
        else:
            out.append(FrameCandidate("distance", i, o.id, secs["reference"],
                                      np.array([[near[0], h - 1.0], [near[0], near[1]]])))
        if model.object_free[i, 3]:
            out.append(FrameCandidate("length", i, o.id, secs["reference"]))
    return out, notes
