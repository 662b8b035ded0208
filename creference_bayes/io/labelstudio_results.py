"""One Label Studio annotation's ``result`` list → what it contributes to a scene: the targets'
four corners, the reference lines with their per-region fields, the horizon lines (pixels).

Regions are keypoints (``keypointlabels``) or vectors (``vectorlabels``: two-point reference and
horizon lines, four-point ``target`` lines t1..t4); a per-region control's result has the region's
id; keypoint reference lines are paired by relations (``from_id`` → ``to_id``). A target's regions
may name it with the per-region ``target`` field and give its ``class`` (:data:`TARGET_FIELDS`).
Nothing in the list is trusted: every problem raises a
:class:`~.annotation_tools.ConversionError` naming the task and the region.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from .annotation_tools import REFERENCE_FIELDS, ConversionError, _short, _text, number_field

__all__ = ["TARGET_LABELS", "REF_START", "REF_END", "REFERENCE", "HORIZON", "TARGET", "POINTS", "LINES",
           "TARGET_LINES", "IMAGE", "CONTROL_VALUE", "TARGET_FIELDS", "Drawing", "AnnotationItems",
           "annotation_items", "annotation_result"]

#: Keypoint labels of the target's corners t1..t4, in order.
TARGET_LABELS = ("t1 bottom corner", "t2 end of length", "t3 end of width", "t4 top of height")
REF_START, REF_END, REFERENCE, HORIZON = "reference start", "reference end", "reference", "horizon"
#: The label of a four-point target vector (t1, t2, t3, t4 in drawing order; vectors config).
TARGET = "target"
POINTS, LINES, TARGET_LINES, IMAGE = "points", "lines", "targets", "image"
#: Per-region fields that tie a region to a target: its id, and its class.
TARGET_FIELDS = ("target", "class")
#: The key holding a per-region control's value, by result type.
CONTROL_VALUE = {"number": "number", "choices": "choices", "textarea": "text"}


@dataclass
class _Region:
    kind: str            # "keypoint" or "vector"
    label: str
    points: list         # [[u, v], ...] pixels


@dataclass(frozen=True)
class Drawing:
    """One target drawn in one annotation: the region that names it (for messages), the target
    it names and its class (None when not given), its corners t1..t4 (pixels)."""

    region: str
    target: str | None
    cls: str | None
    corners: list


@dataclass
class AnnotationItems:
    """What one annotation contributes: ``drawings`` every target it draws (:class:`Drawing`),
    ``references`` as (region id, fields, [[u, v], [u, v]]) pixels, ``horizons`` as two-point
    lines; ``lead_time`` in seconds; ``name`` for messages."""

    name: str
    worker: str | None
    lead_time: float | None
    references: list = field(default_factory=list)
    horizons: list = field(default_factory=list)
    drawings: list = field(default_factory=list)


def _worker(completed_by: Any, users: dict[str, str]) -> str | None:
    if isinstance(completed_by, dict):
        uid = completed_by.get("id")
        completed_by = users.get(str(uid)) or completed_by.get("email") or uid
    if completed_by is None or isinstance(completed_by, bool):
        return None
    return users.get(str(completed_by), str(completed_by))


def _label(value: dict, key: str, where: str) -> str:
    labels = value.get(key)
    if not isinstance(labels, list) or len(labels) != 1 or not isinstance(labels[0], str):
        raise ConversionError(where, f"expected exactly one label in {key}, got {labels!r}")
    return " ".join(labels[0].split()).lower()


def _pixel(p: Any, width: int, height: int, where: str) -> list[float]:
    if not isinstance(p, dict):
        raise ConversionError(where, f"expected a point with x and y, got {p!r}")
    x = number_field(p.get("x"), where, "x (percent)")
    y = number_field(p.get("y"), where, "y (percent)")
    return [x / 100.0 * width, y / 100.0 * height]


def _vertices(value: dict, where: str) -> list:
    """A vector's vertices in drawing order (following ``prevPointId`` when every vertex has it)."""
    verts = value.get("vertices")
    if not isinstance(verts, list) or not all(isinstance(v, dict) for v in verts):
        raise ConversionError(where, f"expected a list of vertices, got {verts!r}"[:120])
    ids = [v.get("id") for v in verts]
    if all(isinstance(i, str) for i in ids) and len(set(ids)) == len(ids):
        nxt: dict = {}
        for j, v in enumerate(verts):
            prev = v.get("prevPointId")
            if prev is not None and not isinstance(prev, str):
                raise ConversionError(where, f"vertex {j} ({v['id']!r}): prevPointId is not a vertex id: "
                                             f"{_short(prev)}")
            nxt.setdefault(prev, []).append(v)
        chain, cur = [], nxt.get(None, [None])[0]
        while cur is not None and len(chain) < len(verts):
            chain.append(cur)
            cur = (nxt.get(cur["id"]) or [None])[0]
        if len(chain) == len(verts) and len(nxt.get(None, [])) == 1:
            return chain
    return verts  # no usable chain (e.g. the SDK writes null ids): the list order


def annotation_result(ann: dict, k: int, where: str) -> tuple[str, list]:
    """The name of annotation ``ann`` (the ``k``-th of its task) for messages, and its ``result``
    list (none: empty); a ``result`` that is not a list is a :class:`ConversionError`."""
    aid = ann.get("id", k)
    aname = f"annotation {aid if isinstance(aid, (int, str)) and not isinstance(aid, bool) else k}"
    result = ann.get("result")
    if result is None:
        return aname, []
    if not isinstance(result, list):
        raise ConversionError(f"{where}, {aname}", f"'result' is not a list: {_short(result)}")
    return aname, result


def annotation_items(ann, k, width, height, where, users, notes) -> AnnotationItems:
    """Read annotation ``ann`` (the ``k``-th of its task) on a ``width`` x ``height`` image.

    ``where`` names the task in messages, ``users`` maps user ids to worker names, and notes
    about ignored results are appended to ``notes``. Raises :class:`ConversionError`.
    """
    if not isinstance(ann, dict):
        raise ConversionError(f"{where}, annotation {k}", f"expected an object, got {type(ann).__name__}")
    aname, result = annotation_result(ann, k, where)
    awhere = f"{where}, {aname}"
    lead = ann.get("lead_time")
    lead = None if lead is None else number_field(lead, awhere, "lead_time", lo=0.0, hi=math.inf)
    items = AnnotationItems(aname, _worker(ann.get("completed_by"), users), lead)

    regions: dict[str, _Region] = {}
    controls: dict[str, dict[str, Any]] = {}
    relations = []
    for j, r in enumerate(result):
        if not isinstance(r, dict):
            raise ConversionError(awhere, f"result {j} is not an object")
        typ = r.get("type")
        if not isinstance(typ, str):
            raise ConversionError(awhere, f"result {j}: 'type' is not text: {_short(typ)}")
        if typ == "relation":
            relations.append((str(r.get("from_id")), str(r.get("to_id"))))
            continue
        rid = r.get("id")
        if isinstance(rid, bool) or not isinstance(rid, (str, int)):
            raise ConversionError(awhere, f"result {j} ({typ}) has no region id")
        rid = str(rid)
        rwhere = f"{awhere}, region {rid!r}"
        value = r.get("value")
        if not isinstance(value, dict):
            raise ConversionError(rwhere, f"'value' is not an object: {value!r}"[:120])
        if typ in ("keypointlabels", "vectorlabels"):
            if rid in regions:
                raise ConversionError(rwhere, "two regions have this id")
            if typ == "keypointlabels":
                regions[rid] = _Region("keypoint", _label(value, typ, rwhere),
                                       [_pixel(value, width, height, rwhere)])
            else:
                if value.get("closed") is True:
                    raise ConversionError(rwhere, "a closed vector (a polygon) is not a line")
                regions[rid] = _Region("vector", _label(value, typ, rwhere),
                                       [_pixel(v, width, height, rwhere) for v in _vertices(value, rwhere)])
        elif typ in CONTROL_VALUE:
            name = r.get("from_name")
            if name not in REFERENCE_FIELDS and name not in TARGET_FIELDS:
                notes.append(f"{rwhere}: {typ} '{name}' is not a field the importer knows; ignored")
                continue
            if name in controls.setdefault(rid, {}):
                raise ConversionError(rwhere, f"'{name}' is given twice")
            controls[rid][name] = value.get(CONTROL_VALUE[typ])
        else:
            notes.append(f"{rwhere}: result type {typ!r} ignored")
    _roles(regions, controls, relations, items, where, awhere)
    return items


def _roles(regions, controls, relations, items: AnnotationItems, where: str, awhere: str) -> None:
    corner_points: list[tuple[str, int]] = []
    target_lines: list[str] = []
    starts, ends, hpoints = [], [], []
    for rid, reg in regions.items():
        rwhere = f"{awhere}, region {rid!r}"
        if reg.kind == "keypoint":
            if reg.label in TARGET_LABELS:
                corner_points.append((rid, TARGET_LABELS.index(reg.label)))
            elif reg.label in (REF_START, REF_END, HORIZON):
                {REF_START: starts, REF_END: ends, HORIZON: hpoints}[reg.label].append(rid)
            else:
                raise ConversionError(rwhere, f"unknown keypoint label {reg.label!r}")
        elif reg.label == TARGET:
            if len(reg.points) != 4:
                raise ConversionError(rwhere, f"target line has {len(reg.points)} points, expected 4 "
                                              "(t1, t2, t3, t4 in this order)")
            target_lines.append(rid)
        else:
            if reg.label not in (REFERENCE, HORIZON):
                raise ConversionError(rwhere, f"unknown line label {reg.label!r} (expected "
                                              f"'{REFERENCE}' or '{HORIZON}')")
            if len(reg.points) != 2:
                raise ConversionError(rwhere, f"{reg.label} line has {len(reg.points)} points, expected 2")
            if reg.label == HORIZON:
                items.horizons.append(reg.points)
            else:
                items.references.append((rid, controls.get(rid, {}), reg.points))
    _drawings(regions, controls, corner_points, target_lines, items, awhere)
    if hpoints:
        if len(hpoints) != 2:
            raise ConversionError(awhere, f"{len(hpoints)} points labelled 'horizon', expected 2")
        items.horizons.append([regions[r].points[0] for r in hpoints])
    for start, end in _pairs(starts, ends, relations, regions, where, awhere):
        fields_ = dict(controls.get(start, {}))
        for key, val in controls.get(end, {}).items():
            if key in fields_ and fields_[key] != val:
                raise ConversionError(f"{awhere}, region {end!r}", f"'{key}' is {val!r} here but "
                                      f"{fields_[key]!r} on its reference start {start!r}")
            fields_[key] = val
        items.references.append((start, fields_, [regions[start].points[0], regions[end].points[0]]))
    refs = set(starts) | set(ends) | {r for r, g in regions.items() if g.label == REFERENCE}
    drawn = {r for r, _ in corner_points} | set(target_lines)
    for rid in controls:
        if rid not in regions:
            raise ConversionError(f"{awhere}, region {rid!r}", f"reference fields {sorted(controls[rid])} "
                                  "belong to no region of this annotation")
        rwhere, label = f"{awhere}, region {rid!r}", regions[rid].label
        if rid in drawn:
            bad = sorted(k for k in controls[rid] if k not in TARGET_FIELDS)
            if bad:
                kind = "line" if regions[rid].kind == "vector" else "point"
                raise ConversionError(rwhere, f"a {label!r} {kind} carries reference fields {bad}")
        elif rid in refs:
            if _text(controls[rid].get("class"), rwhere, "class") is not None:
                raise ConversionError(rwhere, "a reference carries a 'class' (a class belongs to a target)")
        elif controls[rid]:
            raise ConversionError(rwhere, f"a {label!r} point carries reference fields {sorted(controls[rid])}")


def _drawings(regions, controls, corner_points, target_lines, items: AnnotationItems, awhere: str) -> None:
    """Group the corner points by the target they name (module docstring) and add every target
    drawn (points or a target line) to ``items.drawings``."""
    def name_of(rid):
        return _text(controls.get(rid, {}).get("target"), f"{awhere}, region {rid!r}", "target")

    named = list(dict.fromkeys(n for n in (name_of(r) for r, _ in corner_points) if n is not None))
    groups: dict[str | None, dict[int, str]] = {}
    for rid, i in corner_points:
        name = name_of(rid)
        if name is None and named:
            if len(named) > 1:
                raise ConversionError(f"{awhere}, region {rid!r}", f"a {TARGET_LABELS[i]!r} point names no "
                                      f"target, and this annotation draws several ({named}); give it its target")
            name = named[0]
        group = groups.setdefault(name, {})
        if i in group:
            which = "the target once" if name is None else f"each target once (target {name!r})"
            raise ConversionError(awhere, f"two points labelled {TARGET_LABELS[i]!r} (regions {group[i]!r} "
                                          f"and {rid!r}); an annotation draws {which}")
        group[i] = rid
    for name, group in groups.items():
        missing = [TARGET_LABELS[i] for i in range(4) if i not in group]
        if missing:
            of = "" if name is None else f" of target {name!r}"
            raise ConversionError(awhere, f"target corner(s) {missing}{of} missing (the dimension lines "
                                          "need all four points)")
        rids = [group[i] for i in range(4)]
        items.drawings.append(Drawing(f"region {rids[0]!r}", name, _class_of(rids, controls, awhere),
                                      [regions[r].points[0] for r in rids]))
    for rid in target_lines:
        name = name_of(rid)
        if name is not None and name in groups:
            raise ConversionError(f"{awhere}, region {rid!r}", f"target {name!r} is drawn twice in this "
                                                               "annotation")
        items.drawings.append(Drawing(f"region {rid!r}", name, _class_of([rid], controls, awhere),
                                      [list(p) for p in regions[rid].points]))


def _class_of(rids, controls, awhere) -> str | None:
    """The class the regions of one drawn target give (they must agree), or None."""
    found: dict[str, str] = {}
    for rid in rids:
        cls = _text(controls.get(rid, {}).get("class"), f"{awhere}, region {rid!r}", "class")
        if cls is not None:
            found.setdefault(cls, rid)
    if len(found) > 1:
        (a, ra), (b, rb) = list(found.items())[:2]
        raise ConversionError(f"{awhere}, region {rb!r}", f"class {b!r} here but {a!r} on region {ra!r} "
                                                          "of the same target")
    return next(iter(found), None)


def _pairs(starts, ends, relations, regions, where, awhere):
    """(start, end) region ids of the keypoint reference lines, paired by relations (linear in
    their number: membership is looked up in sets)."""
    partner: dict[str, str] = {}
    pairs = []
    is_start, is_end = set(starts), set(ends)
    for a, b in relations:
        for rid in (a, b):
            if rid not in regions:
                raise ConversionError(awhere, f"a relation links {a!r} and {b!r}, but {rid!r} is no "
                                              "region of this annotation")
        if a in is_end and b in is_start:
            a, b = b, a
        if not (a in is_start and b in is_end):
            raise ConversionError(f"{awhere}, region {a!r}", f"a relation links {regions[a].label!r} to "
                                  f"{regions[b].label!r}; relations must link a 'reference start' "
                                  "to a 'reference end'")
        for rid in (a, b):
            if rid in partner:
                raise ConversionError(f"{awhere}, region {rid!r}", f"{regions[rid].label!r} is linked "
                                      "to two points (a reference line has two ends)")
        partner[a], partner[b] = b, a
        pairs.append((a, b))
    if not relations and len(starts) == 1 and len(ends) == 1:
        return [(starts[0], ends[0])]
    for rid in starts + ends:
        if rid not in partner:
            other = REF_END if rid in is_start else REF_START
            raise ConversionError(f"{awhere}, region {rid!r}", f"{regions[rid].label!r} is not linked "
                                  f"to a '{other}' (draw a relation between the two ends)")
    return pairs

