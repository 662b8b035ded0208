"""A Label Studio task that holds every target of its image → one ``creference-scene/2`` frame
(docs/import.md, "Frames").

A task is a frame when its ``data`` lists ``targets`` (``[{"id", "class", "dimensions_m"}, …]``),
when a region names a target or a class (the per-region fields ``target`` and ``class``), when it
draws a four-point ``target`` line, or when the importer is told so (``--frames``). Each drawn
target is tied to its target by its ``target`` field; a region that names none belongs to the
task's only target. A reference region's ``target`` names the target it is about (a relative
reference: the target it is a ratio to). Sizes come from ``dimensions_m`` in ``data.targets`` or
the ``--targets`` table; without one the target's class's size prior applies.

The tasks imported as frames are grouped by their image (``data.image``): the tasks of one image
(e.g. the one-target layout, a task per target, with ``--frames``) make one frame holding the
targets of all of them (:func:`frame_task_part` per task, :func:`frame_scene` per image).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import PurePosixPath
from typing import Any
from urllib.parse import parse_qs, unquote, urlparse

from .annotation_tools import (ConversionError, TargetScene, TargetTable, _short, _text, number_field,
                               reference_from_fields, safe_name, set_camera_and_horizon)
from .frame_import import checked_frame, classes_block
from .frame_scene import FRAME_FORMAT
from .labelstudio_results import TARGET_LABELS

__all__ = ["FramePart", "frame_task_part", "frame_scene", "url_path", "SHARED_DATA"]

_SIZE = ("length", "width", "height")
_TARGET_KEYS = {"id", "class", "dimensions_m", "ground_truth"}
#: ``data`` fields of the photo (not of one target): the tasks of one image must agree on them.
SHARED_DATA = ("frame_id", "image_path", "focal_length_px", "principal_point", "kitti_p2", "horizon",
               "horizon_sd_px", "classes", "ground_truth")
#: A one-target task's ``ground_truth`` keys that belong to its target; the others are the camera's.
_TARGET_TRUTH = ("location_m", "yaw_rad", "handedness")


@dataclass
class FramePart:
    """What one task contributes to the frame of its image: its drawn targets (id → target with
    ``lines`` and their ``origins``), references (with the regions they come from), horizon lines,
    the image size and the task's ``data`` (its photo fields: :data:`SHARED_DATA`)."""

    where: str
    task: dict
    index: int
    data: dict
    size: tuple[int, int]
    targets: dict
    refs: list
    ref_origins: list
    horizons: list


def frame_task_part(task: dict, index: int, data: dict, items_list: list, size: tuple[int, int], where: str,
                    notes: list[str]) -> FramePart:
    """What a task whose annotations were read into ``items_list``
    (:class:`~.labelstudio_results.AnnotationItems`) gives its image's frame; ``size`` is the
    image's (width, height) px. Raises :class:`ConversionError`."""
    declared, data = _declared(data, task, index, where)
    targets: dict[str, dict] = {tid: {"id": tid, **{k: v for k, v in t.items() if k != "id"}, "lines": [],
                                      "origins": []} for tid, t in declared.items()}
    refs, ref_origins, horizons = [], [], []
    for items in items_list:
        n = len(items.drawings) + len(items.references)
        secs = items.lead_time / n if items.lead_time is not None and n else None
        for d in items.drawings:
            dwhere = f"{where}, {items.name}, {d.region}"
            tid = _resolve(d.target, declared, targets, dwhere)
            t = targets.setdefault(tid, {"id": tid, "lines": [], "origins": []})
            if d.cls is not None:
                if t.get("class") not in (None, d.cls):
                    raise ConversionError(dwhere, f"class {d.cls!r} for target {tid!r}, which is "
                                                  f"{t['class']!r} elsewhere ({t.get('class_from', 'data.targets')})")
                t.setdefault("class_from", f"{items.name}, {d.region}")
                t["class"] = d.cls
            line: dict[str, Any] = {"corners": d.corners}
            line.update({k: v for k, v in (("worker", items.worker), ("seconds", secs)) if v is not None})
            t["lines"].append(line)
            t["origins"].append(f"{items.name}, {d.region}")
        for rid, fields_, seg in items.references:
            rwhere = f"{where}, {items.name}, region {rid!r}"
            ref = reference_from_fields(fields_, seg, rwhere, worker=items.worker, seconds=secs)
            name = _text(fields_.get("target"), rwhere, "target")
            if name is not None:
                ref["target"] = _resolve(name, declared, targets, rwhere)
            refs.append(ref)
            ref_origins.append(f"{items.name}, region {rid!r}")
        horizons.extend(items.horizons)
    for t in targets.values():
        if not t["lines"]:
            notes.append(f"{where}: target {t['id']!r} of data.targets has no dimension lines; left out")
    drawn = {tid: t for tid, t in targets.items() if t["lines"]}
    if not drawn:
        raise ConversionError(where, "no annotation draws a target's dimension lines "
                                     f"({', '.join(repr(x) for x in TARGET_LABELS)}, or a 'target' line)")
    return FramePart(where, task, index, data, size, drawn, refs, ref_origins, horizons)


def frame_scene(parts: list[FramePart], locate, table: TargetTable, classes: dict | None,
                notes: list[str]) -> TargetScene:
    """One frame from the parts of the tasks of one image (several tasks: the one-target layout, a
    task per target); ``locate(data, where)`` gives the frame's ``image.path`` (or None) and the
    image's names for the ``--targets`` table, ``classes`` are the ``--classes`` size priors. The
    tasks must agree on the image's size and on :data:`SHARED_DATA`; a target id is drawn in one
    task only; a relative reference of a task that draws one target is relative to that target."""
    first = parts[0]
    where = first.where if len(parts) == 1 else f"{', '.join(p.where for p in parts)} (one image)"

    def origin(part, text):  # a merged frame's messages name the task too
        return text if len(parts) == 1 else f"{part.where}, {text}"

    for part in parts[1:]:
        if part.size != first.size:
            raise ConversionError(where, f"the image is {first.size[0]}x{first.size[1]} in {first.where} but "
                                         f"{part.size[0]}x{part.size[1]} in {part.where}")
    data = _shared_data(parts, where)
    image_path, image_names = locate(data, where)
    width, height = first.size
    drawn: dict[str, dict] = {}
    origins: dict[str, str] = {}
    refs, ref_origins, horizons = [], [], []
    for part in parts:
        for tid, t in part.targets.items():
            if tid in drawn:
                raise ConversionError(where, f"target {tid!r} is in {drawn[tid]['part'].where} and in "
                                             f"{part.where}; a target id must be unique among the tasks of its image")
            drawn[tid] = {**t, "part": part}
        if len(parts) > 1 and len(part.targets) == 1:  # a one-target task: its ratios are to its target
            refs += [{**r, "target": next(iter(part.targets))} if r["mode"] == "relative" and "target" not in r
                     else r for r in part.refs]
        else:
            refs += part.refs
        ref_origins += [origin(part, o) for o in part.ref_origins]
        horizons += part.horizons
    scene: dict[str, Any] = {"format": FRAME_FORMAT, "image": {"width": width, "height": height}}
    if image_path is not None:
        scene["image"]["path"] = image_path
    camera = {}
    focal = data.get("focal_length_px")
    if focal not in (None, ""):
        camera["focal_length_px"] = number_field(focal, where, "data.focal_length_px", positive=True)
    else:
        table_focal = table.focal(image_names, list(drawn), where)
        if table_focal is not None:
            camera["focal_length_px"] = table_focal
    for key in ("principal_point", "kitti_p2"):
        if data.get(key) is not None:
            camera[key] = data[key]
    set_camera_and_horizon(scene, camera, data, horizons, width, where, notes)
    if data.get("horizon_sd_px") is not None:
        scene["horizon_sd_px"] = data["horizon_sd_px"]
    out_targets = []
    for i, t in enumerate(drawn.values()):
        d: dict[str, Any] = {"id": t["id"]}
        if t.get("class") is not None:
            d["class"] = t["class"]
        dims = table.size(image_names, t["id"], t.get("dimensions_m"), f"{where}, target {t['id']!r}")
        if dims is not None:
            d["dimensions_m"] = dims
        d["dimension_lines"] = t["lines"]
        if t.get("ground_truth") is not None:
            d["ground_truth"] = t["ground_truth"]
        out_targets.append(d)
        part = t["part"]
        origins[f"targets[{i}]"] = origin(part, t.get("class_from") or t["origins"][0])
        origins[f"targets[{i}].ground_truth"] = origin(part, "data.targets")
        origins.update({f"targets[{i}].dimension_lines[{j}]": origin(part, o) for j, o in enumerate(t["origins"])})
    own = classes_block(out_targets, data.get("classes"), classes)
    if own is not None:
        scene["classes"] = own
    scene["targets"] = out_targets
    if refs:
        scene["references"] = refs
    if data.get("ground_truth") is not None:
        scene["ground_truth"] = data["ground_truth"]
    origins = {"camera": "data.focal_length_px / principal_point / kitti_p2", "horizon": "the horizon",
               "horizon_sd_px": "data.horizon_sd_px", "classes": "data.classes / --classes",
               "ground_truth": "data.ground_truth", **origins}
    origins.update({f"references[{k}]": o for k, o in enumerate(ref_origins)})
    return TargetScene(_frame_name(data, first.task, first.index, where), checked_frame(scene, where, origins),
                       where)


def _shared_data(parts: list[FramePart], where: str) -> dict:
    """The photo's ``data`` fields (:data:`SHARED_DATA`, and ``image``) from the tasks of one image:
    each from the tasks that give it, which must agree."""
    out: dict[str, Any] = {"image": parts[0].data.get("image")}
    for key in SHARED_DATA:
        given = [(p.data[key], p.where) for p in parts if p.data.get(key) not in (None, "")]
        for value, pwhere in given[1:]:
            path, a, b = f"data.{key}", given[0][0], value
            while isinstance(a, dict) and isinstance(b, dict) and _canonical(a) != _canonical(b):
                k = next(k for k in {**a, **b} if _canonical(a.get(k, _ABSENT)) != _canonical(b.get(k, _ABSENT)))
                path, a, b = f"{path}.{k}", a.get(k, _ABSENT), b.get(k, _ABSENT)  # down to where they differ
            if _canonical(a) != _canonical(b):
                show = [("not given" if v is _ABSENT else _short(v)) for v in (a, b)]
                raise ConversionError(where, f"{path} is {show[0]} in {given[0][1]} but {show[1]} in "
                                             f"{pwhere} (the tasks of one image share it)")
        if given:
            out[key] = given[0][0]
    return out


_ABSENT = object()


def _canonical(value: Any) -> str:
    """A value as text, for comparing (``_ABSENT``: a key not given)."""
    if value is _ABSENT:
        return "(not given)"
    try:
        return json.dumps(value, sort_keys=True, default=repr)
    except (TypeError, ValueError, RecursionError):  # keys of mixed types, a cycle, too deep: by identity
        return f"{type(value).__name__} at {id(value)}"


def _declared(data: dict, task: dict, index: int, where: str) -> tuple[dict[str, dict], dict]:
    """The targets ``data`` lists, by id (``data.targets``; or, for a one-target task imported as
    a frame, ``target_id`` and ``target_*_m``), and ``data`` with the photo's fields (a one-target
    task's ``ground_truth`` is split: location, yaw and handedness go to its target)."""
    if "targets" not in data:
        keys = ("target_length_m", "target_width_m", "target_height_m")
        if "target_id" not in data and not any(data.get(k) not in (None, "") for k in keys):
            return {}, data
        tid = data.get("target_id", f"task{task.get('id', index)}")
        if isinstance(tid, bool) or not isinstance(tid, (str, int)) or str(tid).strip() == "":
            raise ConversionError(where, f"data.target_id must be text, got {_short(tid)}")
        tid = str(tid).strip()
        given = [k for k in keys if data.get(k) not in (None, "")]
        if given and len(given) < 3:
            raise ConversionError(where, f"data has {given} but not {[k for k in keys if k not in given]}")
        dims = {k[7:-2]: number_field(data[k], where, f"data.{k}", positive=True) for k in keys} if given else None
        entry: dict[str, Any] = {"dimensions_m": dims}
        truth = data.get("ground_truth")
        if isinstance(truth, dict) and "location_m" in truth:
            entry["ground_truth"] = {k: v for k, v in truth.items() if k in _TARGET_TRUTH}
            camera = {k: v for k, v in truth.items() if k in ("focal_length_px", "camera_height_m", "pitch_rad",
                                                                 "roll_rad")}
            data = {**data, "ground_truth": camera or None}
        return {tid: entry}, data
    raw = data["targets"]
    if not isinstance(raw, list) or not raw:
        raise ConversionError(where, f"data.targets must be a non-empty list of targets, got {str(raw)[:60]!r}")
    out: dict[str, dict] = {}
    for i, t in enumerate(raw):
        path = f"data.targets[{i}]"
        if not isinstance(t, dict):
            raise ConversionError(where, f"{path} must be an object with an id, got {str(t)[:60]!r}")
        unknown = sorted(set(t) - _TARGET_KEYS)
        if unknown:
            raise ConversionError(where, f"{path}: unknown key(s) {unknown} (expected {sorted(_TARGET_KEYS)})")
        tid = t.get("id")
        if isinstance(tid, bool) or not isinstance(tid, (str, int)) or str(tid).strip() == "":
            raise ConversionError(where, f"{path}.id must be text, got {tid!r}")
        tid = str(tid).strip()
        if tid in out:
            raise ConversionError(where, f"{path}.id: duplicate id {tid!r}")
        entry: dict[str, Any] = {}
        if t.get("class") not in (None, ""):
            if not isinstance(t["class"], str):
                raise ConversionError(where, f"{path}.class must be text, got {t['class']!r}")
            entry["class"] = t["class"].strip()
        dims = t.get("dimensions_m")
        if dims is not None:
            if not isinstance(dims, dict) or set(dims) != set(_SIZE):
                raise ConversionError(where, f"{path}.dimensions_m must be an object with length, width, "
                                             f"height (m), got {str(dims)[:60]!r}")
            entry["dimensions_m"] = {k: number_field(dims[k], where, f"{path}.dimensions_m.{k}", positive=True)
                                     for k in _SIZE}
        if t.get("ground_truth") is not None:
            entry["ground_truth"] = t["ground_truth"]
        out[tid] = entry
    return out, data


def _resolve(name: str | None, declared: dict, targets: dict, where: str) -> str:
    """The id of the target a region names (``name``), checked against ``data.targets``."""
    if name is None:
        if len(declared) == 1:
            return next(iter(declared))
        known = sorted(declared or targets)
        raise ConversionError(where, "this target's region names no target (fill in its 'target' field"
                                     f"{f'; targets: {known}' if known else ''})")
    if declared and name not in declared:
        raise ConversionError(where, f"target {name!r} is not in data.targets (ids: {sorted(declared)})")
    return name


def _frame_name(data: dict, task: dict, index: int, where: str) -> str:
    """The frame file's stem: ``data.frame_id``, else the image's file name without its
    extension, else ``task<id>``."""
    fid = data.get("frame_id")
    if isinstance(fid, (str, int)) and not isinstance(fid, bool) and str(fid).strip():
        return safe_name(str(fid).strip())
    for key in ("image_path", "image"):
        url = data.get(key)
        if isinstance(url, str) and url:
            stem = PurePosixPath(url_path(url, where)).stem
            if stem:
                return safe_name(stem)
    return safe_name(f"task{task.get('id', index)}")


def url_path(url: str, where: str) -> str:
    """The file an image URL names: for Label Studio's local files (``/data/local-files/?d=dir/a.jpg``)
    the path ``dir/a.jpg``, else the file name of the URL's path."""
    try:
        parsed = urlparse(url)
        local = parse_qs(parsed.query).get("d")
    except ValueError as exc:  # e.g. a malformed IPv6 host
        raise ConversionError(where, f"not a valid URL {_short(url)}: {exc}") from None
    return local[0] if local else PurePosixPath(unquote(parsed.path)).name
