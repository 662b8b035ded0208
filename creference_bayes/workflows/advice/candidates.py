"""Which observations the advice can weigh for a scene, what each costs, and in which format mix
a new reference would come (docs/advice.md, "What can be simulated", lists every kind).

Per target: one more set of its dimension lines (``ID:dims``); a worker's distance to it
(``ID:distance``, from the image's bottom edge straight up to its nearest bottom corner at the
MAP, as the paper's distance task draws it; left out when that corner is outside the image or on
its bottom edge); its length (``ID:length``) and its size from a catalogue (``ID:size``,
:mod:`.answers`) when its size has a prior, no catalogue answer yet and its class is one a catalogue
lists (:data:`~.answers.CATALOGUE_CLASSES`); its distance to the
nearest other target (``ID~ID2:distance``, bottom centres) unless the scene has one. Once for the
scene: the camera's mounting (``camera:mounting``, :mod:`.answers`), unless a calibration is in
already. Per group of the scene's references (the same object and measure, endpoints within
:data:`SAME_SEGMENT_FRACTION` of the segment's length, at least :data:`SAME_SEGMENT_MIN_PX`,
either direction): one more of the same (``refK-MEASURE``, on the per-endpoint median segment)
and, for a length or width segment, a distance to its object (``refK-distance``, up to the
segment's lower end) unless one is drawn already.

A kind costs the median of the scene's recorded ``seconds`` for it, else the paper's average task
times (§7.2.2: :data:`PAPER_TARGET_SECONDS`, :data:`PAPER_REFERENCE_SECONDS`); a size and a
mounting cost :data:`~.answers.SIZE_SECONDS` and :data:`~.answers.MOUNTING_SECONDS`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...models.boxes import image_boxes
from ...models.contract import O_SIZE, O_X, O_Z
from ...models.metrology import ReferenceTerm
from ...pipeline import reference_terms
from .answers import MOUNTING_SD, MOUNTING_SECONDS, SIZE_SECONDS, catalogue_lists
from .observe import MountingObservation

__all__ = ["PAPER_TARGET_SECONDS", "PAPER_REFERENCE_SECONDS", "PAPER_RANGE_PRECISION", "SAME_SEGMENT_FRACTION",
           "SAME_SEGMENT_MIN_PX", "Candidate", "FormatMix", "candidates", "annotation_seconds", "format_mix",
           "object_name"]

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
    """One observation the advice weighs.

    Attributes
    ----------
    key : a short unique name (module docstring)
    kind : ``"dims"`` (a set of dimension lines), ``"reference"``, ``"size"`` (from a catalogue) or
        ``"mounting"`` (the camera's, from its calibration)
    target : index of the target it is asked on (its dimension lines, its distance, its size), or
        None for a reference on another object or the mounting (they help every target through
        the camera)
    target_id : that target's id, or None
    measure : ``length``, ``width``, ``height`` or ``distance`` (None for dimension lines)
    object : the object's name as the scene's references give it (a target's id for its own)
    line : (2, 2) the segment to measure, pixels (None for dimension lines, sizes and distances
        between targets)
    term : the reference as the model reads it (its value left to the simulation), or None
    based_on : indices of the scene's references it repeats or starts from
    seconds : what one such observation costs, seconds
    new_segment : a segment not drawn in the scene yet
    target_name, object_name : the target and the object as the request's text names them
        (:func:`object_name`; default: ``target_id`` and ``object``)
    """

    key: str
    kind: str
    target: int | None
    target_id: str | None
    measure: str | None
    object: str | None
    line: np.ndarray | None
    term: ReferenceTerm | None
    based_on: tuple[int, ...]
    seconds: float
    new_segment: bool = False
    target_name: str | None = None
    object_name: str | None = None

    @property
    def description(self) -> str:
        """What to ask the crowd for, in words."""
        refs = ", ".join(f"references[{i}]" for i in self.based_on)
        target, obj = self.target_name or self.target_id, self.object_name or self.object
        if self.kind == "dims":
            return f"one more set of dimension lines on {target}"
        if self.kind == "size":
            return f"the size of {target} from a catalogue (a worker names its make and model)"
        if self.kind == "mounting":
            return "the camera's mounting (height, pitch, roll) from its calibration"
        if self.term.kind == "distance":
            as_refs = f" (as {refs})" if refs else ""
            return f"distance between {target} and {obj} (bottom centres){as_refs}"
        if self.based_on and not self.new_segment:
            to = "to" if self.measure == "distance" else "of"
            return f"{self.measure} {to} {obj or 'the object'} (as {refs})"
        if self.based_on:
            return f"distance to {obj or 'the object'} (image bottom to the near end of {refs})"
        if self.measure == "distance":
            return f"distance to {target} (image bottom to its nearest bottom corner)"
        return f"{self.measure} of {target}"

    def to_dict(self) -> dict:
        return {"key": self.key, "kind": self.kind, "target": self.target_id, "measure": self.measure,
                "object": self.object, "line": None if self.line is None else np.round(self.line, 2).tolist(),
                "based_on": list(self.based_on), "seconds": self.seconds, "new_segment": self.new_segment,
                "description": self.description}


@dataclass(frozen=True)
class FormatMix:
    """How a new reference would be stated, from the scene's references: ``range_share`` of them as
    a range (else a single value) of precision (high − low) / mid-point ``range_precision`` (the
    median of the scene's ranges, else :data:`PAPER_RANGE_PRECISION`); ``relative_share`` stated
    relative to a target (reported only: the model converts them, so the simulation is the same)."""

    range_share: float
    range_precision: float
    relative_share: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def object_name(target) -> str:
    """A target as the advice's texts name it: its class and id (``Car 0``), or its id alone when
    it has no class or the id names the class already."""
    cls, tid = target.cls, target.id
    return tid if not cls or cls.casefold() in tid.casefold() else f"{cls} {tid}"


def annotation_seconds(scene) -> dict[str, float]:
    """Cost per kind, seconds: ``{"dims": …, "reference": …}`` (module docstring)."""
    def median(values, default):
        values = [v for v in values if v is not None and v > 0]
        return float(np.median(values)) if values else default

    return {"dims": median([d.seconds for t in scene.targets for d in t.dimension_lines], PAPER_TARGET_SECONDS),
            "reference": median([r.seconds for r in scene.references], PAPER_REFERENCE_SECONDS)}


def format_mix(scene) -> FormatMix:
    """The scene's mix of formats (:class:`FormatMix`)."""
    refs = scene.references
    if not refs:
        return FormatMix(0.0, PAPER_RANGE_PRECISION, 0.0)
    prec = [(r.high - r.low) / (0.5 * (r.high + r.low)) for r in refs if r.is_range]
    return FormatMix(range_share=len(prec) / len(refs),
                     range_precision=float(np.median(prec)) if prec else PAPER_RANGE_PRECISION,
                     relative_share=sum(r.mode == "relative" for r in refs) / len(refs))


def _tolerance(line: np.ndarray) -> float:
    return max(SAME_SEGMENT_MIN_PX, SAME_SEGMENT_FRACTION * float(np.hypot(*(line[1] - line[0]))))


def _aligned(line: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
    """``line`` with its endpoints in the order of ``ref`` when it is the same segment, else None."""
    for cand in (line, line[::-1]):
        if np.all(np.hypot(*(cand - ref).T) <= _tolerance(ref)):
            return cand
    return None


def _groups(scene, terms) -> list[dict]:
    """The scene's references grouped by what they measure (module docstring), in scene order."""
    groups: list[dict] = []
    for r, term in zip(scene.references, terms):
        line = None if r.line is None else np.asarray(r.line, float)
        what = (term.kind, term.owner, term.other, term.size_index, r.measure, r.object)
        for g in groups:
            if g["what"] == what and (line is None or (r.object is not None and
                                                       (aligned := _aligned(line, g["lines"][0])) is not None)):
                if line is not None:
                    g["lines"].append(aligned)
                g["indices"].append(r.index)
                break
        else:
            groups.append({"what": what, "term": term, "measure": r.measure, "object": r.object,
                           "lines": [] if line is None else [line], "indices": [r.index]})
    return groups


def _bottom_line(scene, end: np.ndarray) -> np.ndarray | None:
    """The paper's distance segment from the image's bottom edge straight up to ``end``, or None
    when ``end`` is within :data:`SAME_SEGMENT_MIN_PX` of that edge."""
    bottom = np.array([min(max(end[0], 0.0), float(scene.image_width)), scene.image_height - 1.0])
    return None if np.hypot(*(end - bottom)) < SAME_SEGMENT_MIN_PX else np.array([bottom, end])


def candidates(scene, model, camera: np.ndarray, objects: np.ndarray) -> tuple[list[Candidate], list[str]]:
    """The observations the advice can weigh for ``scene`` (module docstring) and notes on those
    left out, given its ``model`` and the MAP ``camera`` (5,), ``objects`` (m, 7)."""
    secs = annotation_seconds(scene)
    ids = [t.id for t in scene.targets]
    names = [object_name(t) for t in scene.targets]
    out, notes = [], []
    terms = reference_terms(scene)
    groups = _groups(scene, terms)
    ground = lambda line: ReferenceTerm(0, "ground", 1.0, 1.0, False, line=line)  # noqa: E731
    reference = lambda key, target, **kw: out.append(Candidate(  # noqa: E731
        key, "reference", target, None if target is None else ids[target], seconds=secs["reference"],
        target_name=None if target is None else names[target], **kw))
    for g in groups:
        g["line"] = np.median(np.stack(g["lines"]), axis=0) if g["lines"] else None
    distance_ends = [(g["object"], g["line"][int(np.argmin(g["line"][:, 1]))])  # the end at the object
                     for g in groups if g["line"] is not None and g["measure"] == "distance"]
    for k, g in enumerate(groups, start=1):
        term, line = g["term"], g["line"]
        owner = term.owner if term.kind != "ground" else None
        name = ids[term.other] if term.kind == "distance" else g["object"] or (None if owner is None else ids[owner])
        said = names[term.other] if term.kind == "distance" else g["object"] or (None if owner is None else names[owner])
        reference(f"ref{k}-{g['measure']}", owner, measure=g["measure"], object=name, line=line,
                  term=dataclasses.replace(term, line=line), based_on=tuple(g["indices"]), object_name=said)
        if line is None or g["measure"] == "distance":
            continue
        near = line[int(np.argmax(line[:, 1]))]  # the end lower in the image: nearer on the ground
        seg = _bottom_line(scene, near)
        if seg is None or any(obj == g["object"] and obj is not None and np.hypot(*(end - near)) <= _tolerance(seg)
                              for obj, end in distance_ends):
            continue  # the object touches the bottom edge, or that distance is drawn already
        distance_ends.append((g["object"], near))
        reference(f"ref{k}-distance", None, measure="distance", object=g["object"], line=seg, term=ground(seg),
                  based_on=tuple(g["indices"]), new_segment=True)
    ground_xz = objects[:, [O_X, O_Z]]
    pairs = {tuple(sorted((g["term"].owner, g["term"].other))) for g in groups if g["term"].kind == "distance"}
    for i, tid in enumerate(ids):
        out.append(Candidate(f"{tid}:dims", "dims", i, tid, None, tid, None, None, (), secs["dims"],
                             target_name=names[i], object_name=names[i]))
        box = image_boxes(camera[None], objects[i][None], scene.principal_point)[0, :4]  # bottom face
        near = box[int(np.nanargmax(box[:, 1]))] if np.any(np.isfinite(box[:, 1])) else None
        seg = None if near is None or not (0 <= near[0] <= scene.image_width) else _bottom_line(scene, near)
        if seg is None:
            notes.append(f"{tid}:distance: left out: its nearest bottom corner is outside the image or on its "
                         "bottom edge")
        else:
            reference(f"{tid}:distance", i, measure="distance", object=tid, line=seg, term=ground(seg),
                      based_on=(), new_segment=True, object_name=names[i])
        if model.object_free[i, O_SIZE].any():
            reference(f"{tid}:length", i, measure="length", object=tid, line=None, object_name=names[i],
                      term=ReferenceTerm(0, "size", 1.0, 1.0, False, owner=i, size_index=0), based_on=())
        catalogued = scene.targets[i].size_prior is not None and scene.targets[i].size_prior.source == "catalogue"
        if (model.object_free[i, O_SIZE].any() and model.objects[i].size_prior is not None and not catalogued
                and catalogue_lists(scene.targets[i].cls)):  # not for a person or a Misc object
            out.append(Candidate(f"{tid}:size", "size", i, tid, "size", tid, None, None, (), SIZE_SECONDS,
                                 target_name=names[i], object_name=names[i]))
        if len(ids) > 1:
            gap = np.hypot(*(ground_xz - ground_xz[i]).T)
            gap[i] = np.inf
            j = int(np.argmin(gap))
            if (min(i, j), max(i, j)) not in pairs:
                pairs.add((min(i, j), max(i, j)))
                reference(f"{tid}~{ids[j]}:distance", i, measure="distance", object=ids[j], line=None,
                          term=ReferenceTerm(0, "distance", 1.0, 1.0, False, owner=i, other=j), based_on=(),
                          object_name=names[j])
    calibrated = scene.orientation_prior is not None and scene.orientation_prior.source == "calibration"
    # not with a fixed pose (an exact horizon), nor asked again once the calibration's answer is in
    if MountingObservation(model, MOUNTING_SD).usable and not calibrated:
        out.append(Candidate("camera:mounting", "mounting", None, None, "mounting", None, None, None, (),
                             MOUNTING_SECONDS))
    return out, notes
