"""A Label Studio task that holds every target of its image → one ``creference-scene/2`` frame
(docs/import.md, "Frames").

A task is a frame when its ``data`` lists ``targets`` (``[{"id", "class", "dimensions_m"}, …]``),
when a region names a target or a class (the per-region fields ``target`` and ``class``), when it
draws a four-point ``target`` line, or when the importer is told so (``--frames``). Each drawn
target is tied to its target by its ``target`` field; a region that names none belongs to the
task's only target. A reference region's ``target`` names the target it is about (a relative
reference: the target it is a ratio to). Sizes come from ``dimensions_m`` in ``data.targets`` or
the ``--targets`` table; without one the target's class's size prior applies.
"""

from __future__ import annotations

from pathlib import PurePosixPath
from typing import Any
from urllib.parse import parse_qs, unquote, urlparse

from .annotation_tools import (ConversionError, TargetScene, _text, number_field, set_camera_and_horizon,
                               reference_from_fields, safe_name)
from .frame_import import checked_frame, classes_block, frame_focal, frame_size
from .frame_scene import FRAME_FORMAT
from .labelstudio_results import TARGET_LABELS

__all__ = ["frame_task_scene"]

_SIZE = ("length", "width", "height")
_TARGET_KEYS = {"id", "class", "dimensions_m", "ground_truth"}


def frame_task_scene(task: dict, index: int, data: dict, items_list: list, size: tuple[int, int], where: str, *,
                     image_path: str | None, table: dict | None, classes: dict | None,
                     notes: list[str]) -> TargetScene:
    """One frame from a task whose annotations were read into ``items_list``
    (:class:`~.labelstudio_results.AnnotationItems`); ``size`` is the image's (width, height) px,
    ``image_path`` the scene's ``image.path`` (or None), ``table`` the ``--targets`` sizes and
    ``classes`` the ``--classes`` size priors. Raises :class:`ConversionError`."""
    width, height = size
    declared = _declared(data, task, index, where)
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

    drawn = [t for t in targets.values() if t["lines"]]
    for t in targets.values():
        if not t["lines"]:
            notes.append(f"{where}: target {t['id']!r} of data.targets has no dimension lines; left out")
    if not drawn:
        raise ConversionError(where, "no annotation draws a target's dimension lines "
                                     f"({', '.join(repr(x) for x in TARGET_LABELS)}, or a 'target' line)")
    scene: dict[str, Any] = {"format": FRAME_FORMAT, "image": {"width": width, "height": height}}
    if image_path is not None:
        scene["image"]["path"] = image_path
    camera = {}
    focal = data.get("focal_length_px")
    if focal not in (None, ""):
        camera["focal_length_px"] = number_field(focal, where, "data.focal_length_px", positive=True)
    else:
        table_focal = frame_focal([t["id"] for t in drawn], table, where)
        if table_focal is not None:
            camera["focal_length_px"] = table_focal
    for key in ("principal_point", "kitti_p2"):
        if data.get(key) is not None:
            camera[key] = data[key]
    set_camera_and_horizon(scene, camera, data, horizons, width, where, notes)
    if data.get("horizon_sd_px") is not None:
        scene["horizon_sd_px"] = data["horizon_sd_px"]
    out_targets = []
    for t in drawn:
        d: dict[str, Any] = {"id": t["id"]}
        if t.get("class") is not None:
            d["class"] = t["class"]
        dims = frame_size(t["id"], t.get("dimensions_m"), table, f"{where}, target {t['id']!r}")
        if dims is not None:
            d["dimensions_m"] = dims
        d["dimension_lines"] = t["lines"]
        if t.get("ground_truth") is not None:
            d["ground_truth"] = t["ground_truth"]
        out_targets.append(d)
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
               "ground_truth": "data.ground_truth"}
    for i, t in enumerate(drawn):
        origins[f"targets[{i}]"] = t.get("class_from") or t["origins"][0]
        origins[f"targets[{i}].ground_truth"] = "data.targets"
        origins.update({f"targets[{i}].dimension_lines[{j}]": o for j, o in enumerate(t["origins"])})
    origins.update({f"references[{k}]": o for k, o in enumerate(ref_origins)})
    return TargetScene(_frame_name(data, task, index), checked_frame(scene, where, origins), where)


def _declared(data: dict, task: dict, index: int, where: str) -> dict[str, dict]:
    """The targets ``data`` lists, by id (``data.targets``; or, for a one-target task imported as
    a frame, ``target_id`` and ``target_*_m``)."""
    if "targets" not in data:
        keys = ("target_length_m", "target_width_m", "target_height_m")
        if "target_id" not in data and not any(data.get(k) not in (None, "") for k in keys):
            return {}
        tid = str(data.get("target_id", f"task{task.get('id', index)}")).strip()
        given = [k for k in keys if data.get(k) not in (None, "")]
        if given and len(given) < 3:
            raise ConversionError(where, f"data has {given} but not {[k for k in keys if k not in given]}")
        dims = {k[7:-2]: number_field(data[k], where, f"data.{k}", positive=True) for k in keys} if given else None
        return {tid: {"dimensions_m": dims}}
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
    return out


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


def _frame_name(data: dict, task: dict, index: int) -> str:
    """The frame file's stem: ``data.frame_id``, else the image's file name without its
    extension, else ``task<id>``."""
    fid = data.get("frame_id")
    if isinstance(fid, (str, int)) and not isinstance(fid, bool) and str(fid).strip():
        return safe_name(str(fid).strip())
    for key in ("image_path", "image"):
        url = data.get(key)
        if isinstance(url, str) and url:
            parsed = urlparse(url)
            local = parse_qs(parsed.query).get("d")
            stem = PurePosixPath(unquote(local[0] if local else parsed.path)).stem
            if stem:
                return safe_name(stem)
    return safe_name(f"task{task.get('id', index)}")
