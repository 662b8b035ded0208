"""One Label Studio annotation's ``result`` list → what it contributes to a scene: the target's four
corners, the reference lines with their per-region fields, the horizon lines (pixels).

Regions are keypoints (``keypointlabels``) or two-point vectors (``vectorlabels``); a per-region
control's result has the region's id; keypoint reference lines are paired by relations
(``from_id`` → ``to_id``). Nothing in the list is trusted: every problem raises a
:class:`~.annotation_tools.ConversionError` naming the task and the region.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from .annotation_tools import REFERENCE_FIELDS, ConversionError, number_field

__all__ = ["TARGET_LABELS", "REF_START", "REF_END", "REFERENCE", "HORIZON", "POINTS", "LINES", "IMAGE",
           "CONTROL_VALUE", "AnnotationItems", "annotation_items"]

#: Keypoint labels of the target's corners t1..t4, in order.
TARGET_LABELS = ("t1 bottom corner", "t2 end of length", "t3 end of width", "t4 top of height")
REF_START, REF_END, REFERENCE, HORIZON = "reference start", "reference end", "reference", "horizon"
POINTS, LINES, IMAGE = "points", "lines", "image"
#: The key holding a per-region control's value, by result type.
CONTROL_VALUE = {"number": "number", "choices": "choices", "textarea": "text"}


@dataclass
class _Region:
    kind: str            # "keypoint" or "vector"
    label: str
    points: list         # [[u, v], ...] pixels


@dataclass
class AnnotationItems:
    """What one annotation contributes: ``corners`` t1..t4 as a (4, 2) list in pixels (None when
    it does not draw the target), ``references`` as (region id, fields, [[u, v], [u, v]]),
    ``horizons`` as two-point lines; ``lead_time`` in seconds; ``name`` for messages."""

    name: str
    worker: str | None
    lead_time: float | None
    corners: list | None = None
    references: list = field(default_factory=list)   # (region id, fields, line)
    horizons: list = field(default_factory=list)


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
        for v in verts:
            nxt.setdefault(v.get("prevPointId"), []).append(v)
        chain, cur = [], nxt.get(None, [None])[0]
        while cur is not None and len(chain) < len(verts):
            chain.append(cur)
            cur = (nxt.get(cur["id"]) or [None])[0]
        if len(chain) == len(verts) and len(nxt.get(None, [])) == 1:
            return chain
    return verts  # no usable chain (e.g. the SDK writes null ids): the list order


def annotation_items(ann, k, width, height, where, users, notes) -> AnnotationItems:
    """Read annotation ``ann`` (the ``k``-th of its task) on a ``width`` x ``height`` image.

    ``where`` names the task in messages, ``users`` maps user ids to worker names, and notes
    about ignored results are appended to ``notes``. Raises :class:`ConversionError`.
    """
    if not isinstance(ann, dict):
        raise ConversionError(f"{where}, annotation {k}", f"expected an object, got {type(ann).__name__}")
    aname = f"annotation {ann.get('id', k)}"
    awhere = f"{where}, {aname}"
    result = ann.get("result") or []
    if not isinstance(result, list):
        raise ConversionError(awhere, f"'result' is not a list: {type(result).__name__}")
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
            if name not in REFERENCE_FIELDS:
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
    corners: dict[int, str] = {}
    starts, ends, hpoints = [], [], []
    for rid, reg in regions.items():
        rwhere = f"{awhere}, region {rid!r}"
        if reg.kind == "keypoint":
            if reg.label in TARGET_LABELS:
                i = TARGET_LABELS.index(reg.label)
                if i in corners:
                    raise ConversionError(awhere, f"two points labelled {reg.label!r} (regions "
                                                  f"{corners[i]!r} and {rid!r}); an annotation draws the "
                                                  "target once")
                corners[i] = rid
            elif reg.label in (REF_START, REF_END, HORIZON):
                {REF_START: starts, REF_END: ends, HORIZON: hpoints}[reg.label].append(rid)
            else:
                raise ConversionError(rwhere, f"unknown keypoint label {reg.label!r}")
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
    if corners:
        missing = [TARGET_LABELS[i] for i in range(4) if i not in corners]
        if missing:
            raise ConversionError(awhere, f"target corner(s) {missing} missing (the dimension lines "
                                          "need all four points)")
        items.corners = [regions[corners[i]].points[0] for i in range(4)]
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
    used = set(starts) | set(ends) | {r for r, g in regions.items() if g.label == REFERENCE}
    for rid in controls:
        if rid not in regions:
            raise ConversionError(f"{awhere}, region {rid!r}", f"reference fields {sorted(controls[rid])} "
                                  "belong to no region of this annotation")
        if rid not in used and controls[rid]:
            raise ConversionError(f"{awhere}, region {rid!r}", f"a {regions[rid].label!r} point carries "
                                  f"reference fields {sorted(controls[rid])}")


def _pairs(starts, ends, relations, regions, where, awhere):
    """(start, end) region ids of the keypoint reference lines, paired by relations."""
    partner: dict[str, str] = {}
    pairs = []
    for a, b in relations:
        for rid in (a, b):
            if rid not in regions:
                raise ConversionError(awhere, f"a relation links {a!r} and {b!r}, but {rid!r} is no "
                                              "region of this annotation")
        if a in ends and b in starts:
            a, b = b, a
        if not (a in starts and b in ends):
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
            other = REF_END if rid in starts else REF_START
            raise ConversionError(f"{awhere}, region {rid!r}", f"{regions[rid].label!r} is not linked "
                                  f"to a '{other}' (draw a relation between the two ends)")
    return pairs

