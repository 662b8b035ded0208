"""Which annotations the advice can weigh for a scene, what each costs, and in which format mix
a new reference would come (docs/advice.md, "What can be simulated").

- **One more set of target dimension lines** (always).
- **One more reference of a measure already drawn on an object**: a second worker draws about the
  same segment, so the new reference uses the segment already drawn (the per-endpoint median when
  several workers drew it). References belong to the same drawn segment when they name the same
  object and measure and their endpoints agree within :data:`SAME_SEGMENT_FRACTION` of the
  segment's length (at least :data:`SAME_SEGMENT_MIN_PX`), in either direction.
- **A distance to an object whose length or width is drawn**: the line from the image's bottom
  edge straight up to the segment's end nearer the bottom (the nearer corner on the ground), as
  the paper's distance task draws it; skipped when a distance to that point is already drawn.
- Not simulatable: a length or width of an object that only has a distance (the scene holds no
  segment along it), and references on objects the scene does not mention.

The cost of each kind is the median of the scene's recorded ``seconds`` for that kind, else the
paper's average task times (§7.2.2: :data:`PAPER_TARGET_SECONDS`, :data:`PAPER_REFERENCE_SECONDS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PAPER_TARGET_SECONDS", "PAPER_REFERENCE_SECONDS", "PAPER_RANGE_PRECISION",
           "SAME_SEGMENT_FRACTION", "SAME_SEGMENT_MIN_PX", "Candidate", "FormatMix", "candidates",
           "annotation_seconds", "format_mix"]

#: The paper's average task times (§7.2.2), seconds.
PAPER_TARGET_SECONDS = 183.5
PAPER_REFERENCE_SECONDS = 64.4
#: A stated range's precision (high − low) / mid-point when the scene has no range (paper Table 3).
PAPER_RANGE_PRECISION = 0.25
#: Two drawn segments are the same when each endpoint lies within this fraction of the segment's
#: length of the other's (or within :data:`SAME_SEGMENT_MIN_PX`).
SAME_SEGMENT_FRACTION = 0.15
SAME_SEGMENT_MIN_PX = 10.0


@dataclass(frozen=True)
class Candidate:
    """One annotation the advice weighs.

    Attributes
    ----------
    key : a short unique name (``target``, ``ref1-width``, ``ref1-distance``: ``ref1`` is the
        first drawn segment, counting from 1, numbered in the order of the scene's references)
    kind : ``"target"`` (a set of dimension lines) or ``"reference"``
    measure : ``length``, ``width`` or ``distance`` (None for the target)
    object : the object's name as the scene gives it (None when it gives none)
    line : (2, 2) the segment the new reference is drawn on, pixels (None for the target)
    based_on : indices of the scene's references whose segment it repeats or starts from
    seconds : what one such annotation costs, seconds
    new_segment : the segment is not drawn in the scene yet (a distance to the end of a length or
        width segment); False when it repeats a drawn one
    """

    key: str
    kind: str
    measure: str | None
    object: str | None
    line: np.ndarray | None
    based_on: tuple[int, ...]
    seconds: float
    new_segment: bool = False

    @property
    def description(self) -> str:
        """What to ask the crowd for, in words."""
        if self.kind == "target":
            return "one more set of target dimension lines"
        refs = ", ".join(f"references[{i}]" for i in self.based_on)
        name = self.object or "the object"
        if self.new_segment:
            return f"distance to {name} (image bottom to the near end of {refs})"
        return f"{self.measure} {'to' if self.measure == 'distance' else 'of'} {name} (as {refs})"

    def to_dict(self) -> dict:
        return {"key": self.key, "kind": self.kind, "measure": self.measure, "object": self.object,
                "line": None if self.line is None else np.round(self.line, 2).tolist(),
                "based_on": list(self.based_on), "seconds": self.seconds,
                "new_segment": self.new_segment, "description": self.description}


@dataclass(frozen=True)
class FormatMix:
    """How a new reference would be stated, from the scene's references.

    Attributes
    ----------
    range_share : share of the scene's references stated as a range (else a single value)
    range_precision : (high − low) / mid-point of a stated range: the median of the scene's ranges,
        else :data:`PAPER_RANGE_PRECISION`
    relative_share : share stated relative to the target (reported; the model converts them to
        metres with the target's size, so it does not change the simulation)
    """

    range_share: float
    range_precision: float
    relative_share: float

    def to_dict(self) -> dict:
        return {"range_share": self.range_share, "range_precision": self.range_precision,
                "relative_share": self.relative_share}


def annotation_seconds(scene) -> dict[str, float]:
    """Cost per kind, seconds: ``{"target": …, "reference": …}`` (module docstring)."""
    def median(values, default):
        values = [v for v in values if v is not None and v > 0]
        return float(np.median(values)) if values else default

    return {"target": median([d.seconds for d in scene.target.dimension_lines], PAPER_TARGET_SECONDS),
            "reference": median([r.seconds for r in scene.references], PAPER_REFERENCE_SECONDS)}


def format_mix(scene) -> FormatMix:
    """The scene's mix of formats (:class:`FormatMix`)."""
    refs = scene.references
    if not refs:
        return FormatMix(0.0, PAPER_RANGE_PRECISION, 0.0)
    ranges = [r for r in refs if r.is_range]
    prec = [(r.high - r.low) / (0.5 * (r.high + r.low)) for r in ranges]
    return FormatMix(range_share=len(ranges) / len(refs),
                     range_precision=float(np.median(prec)) if prec else PAPER_RANGE_PRECISION,
                     relative_share=sum(r.mode == "relative" for r in refs) / len(refs))


def _tolerance(line: np.ndarray) -> float:
    return max(SAME_SEGMENT_MIN_PX, SAME_SEGMENT_FRACTION * float(np.hypot(*(line[1] - line[0]))))


def _aligned(line: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
    """``line`` with its endpoints in the order of ``ref`` when it is the same segment, else None."""
    tol = _tolerance(ref)
    for cand in (line, line[::-1]):
        if np.all(np.hypot(*(cand - ref).T) <= tol):
            return cand
    return None


@dataclass
class _Group:
    object: str | None
    measure: str
    lines: list
    indices: list

    @property
    def line(self) -> np.ndarray:
        return np.median(np.stack(self.lines), axis=0)


def _groups(scene) -> list[_Group]:
    groups: list[_Group] = []
    for r in scene.references:
        line = np.asarray(r.line, float)
        for g in groups:
            if r.object is not None and g.object == r.object and g.measure == r.measure:
                aligned = _aligned(line, g.lines[0])
                if aligned is not None:
                    g.lines.append(aligned)
                    g.indices.append(r.index)
                    break
        else:
            groups.append(_Group(r.object, r.measure, [line], [r.index]))
    return groups


def candidates(scene) -> list[Candidate]:
    """The annotations the advice can weigh for ``scene`` (module docstring), the target first."""
    secs = annotation_seconds(scene)
    out = [Candidate("target", "target", None, None, None, (), secs["target"])]
    groups = _groups(scene)
    distance_ends = [(g.object, _object_end(g.line)) for g in groups if g.measure == "distance"]
    for k, g in enumerate(groups, start=1):
        line = g.line
        out.append(Candidate(f"ref{k}-{g.measure}", "reference", g.measure, g.object, line,
                             tuple(g.indices), secs["reference"]))
        if g.measure == "distance":
            continue
        near = line[int(np.argmax(line[:, 1]))]  # the end lower in the image: nearer on the ground
        bottom = np.array([min(max(near[0], 0.0), float(scene.image_width)), scene.image_height - 1.0])
        if np.hypot(*(near - bottom)) < SAME_SEGMENT_MIN_PX:
            continue  # the object touches the bottom edge: no distance to draw
        tol = _tolerance(np.array([bottom, near]))
        if any(obj == g.object and obj is not None and np.hypot(*(end - near)) <= tol
               for obj, end in distance_ends):
            continue  # that distance is drawn already (its own candidate repeats it)
        distance_ends.append((g.object, near))
        out.append(Candidate(f"ref{k}-distance", "reference", "distance", g.object,
                             np.array([bottom, near]), tuple(g.indices), secs["reference"], True))
    return out


def _object_end(line: np.ndarray) -> np.ndarray:
    """The end of a distance line at the object: the one farther from the image's bottom edge."""
    return line[int(np.argmin(line[:, 1]))]
