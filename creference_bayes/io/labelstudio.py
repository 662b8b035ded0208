"""Label Studio ↔ scene files: the shipped labelling configs and the JSON export → one
``creference-scene/2`` scene per photo (docs/import.md is the user's guide); scenes → tasks is in
:mod:`.labelstudio_export`, one annotation's results → items in :mod:`.labelstudio_results`.

A task's ``data`` gives the image and, optionally, its targets: ``targets`` (``[{"id", "class",
"dimensions_m", "ground_truth"}, …]``), or one target as ``target_id`` and ``target_*_m`` (its
``ground_truth`` split between target and camera, as in ``creference-scene/1``); else the regions
name the targets (their per-region ``target`` field; a region that names none belongs to the
task's only target, ``task<id>`` when none is named). Each annotation is one worker's work. A
target's size comes from the task or the ``--targets`` table, else its class's size prior.

The tasks of one image (``data.image``) make one scene: they must agree on the image's size and
the photo's fields (:data:`SHARED_DATA`), and a target is drawn in one task only. A request task of
``creference advise`` (``data.creference_scene``) is the scene it carries with the answers added;
the answered request tasks of one frame (one ``data.request_key``) make one scene, named after it.
Coordinates are percent of ``original_width`` / ``original_height`` (or of the task's
``image_width`` / ``image_height``).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import parse_qs, unquote, urlparse

from ..models.size_priors import SIZE_KEYS
from .annotation_tools import (ConversionError, ImportedScene, ImportReport, TargetTable, _short, _text, _whole,
                               checked_scene, classes_block, image_file, number_field, read_input,
                               mean_horizon, reference_from_fields, safe_name, scene_dict, unique_names)
from .labelstudio_export import (CAMERA_DATA, CAMERA_ID, PHOTO_DATA, label_studio_task, label_studio_tasks,
                                 task_data)
from .labelstudio_results import TARGET_LABELS, annotation_items, annotation_result
from .scene import _CAMERA_TRUTH, SceneError, parse_quietly, scene_to_dict
from .validation import MAX_JSON_BYTES, MAX_JSON_DEPTH, json_depth, loads_json

__all__ = ["TARGET_LABELS", "LINE_TOOLS", "DATA_FIELDS", "SHARED_DATA", "label_studio_config", "read_export",
           "loads_export", "read_users", "scenes_from_label_studio", "label_studio_task", "label_studio_tasks",
           "url_path"]

#: The shipped configs, by how targets, reference lines and the horizon are drawn.
LINE_TOOLS = {"keypoints": "label_studio_keypoints.xml", "vectors": "label_studio_vectors.xml"}
#: ``data`` fields of the photo (not of one target): the tasks of one image must agree on them.
SHARED_DATA = ("frame_id", "image_path", CAMERA_ID, *CAMERA_DATA, *PHOTO_DATA)
#: Task ``data`` fields read by the importer (``image`` is the one the configs display).
DATA_FIELDS = ("image", "targets", "target_id", "target_length_m", "target_width_m", "target_height_m",
               "image_width", "image_height", "creference_scene", *SHARED_DATA)
_DIMS = tuple(f"target_{k}_m" for k in SIZE_KEYS)
_TARGET_KEYS = {"id", "class", "dimensions_m", "ground_truth"}


def label_studio_config(lines: str = "keypoints") -> str:
    """The shipped labelling config (XML text); ``lines`` is ``"keypoints"`` (every Label Studio
    version) or ``"vectors"`` (targets, reference lines and the horizon as lines)."""
    if lines not in LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(LINE_TOOLS)}, got {lines!r}")
    return (resources.files("creference_bayes") / "data" / LINE_TOOLS[lines]).read_text("utf-8")


def read_export(path: str | Path) -> Any:
    """Decode a Label Studio JSON export file of at most :data:`MAX_JSON_BYTES` bytes (raises
    :class:`ConversionError` naming the file)."""
    return loads_export(read_input(path, MAX_JSON_BYTES), str(path))


def loads_export(text: bytes | str, name: str = "(export)") -> Any:
    """Decode the text of a Label Studio JSON export (raises :class:`ConversionError` naming
    ``name``): an integer beyond any float is read as infinite (and refused where a number is
    read), a document nested deeper than the decoder goes is refused (a task nested too deeply is
    refused alone, by :func:`scenes_from_label_studio`)."""
    try:
        return loads_json(text, name, max_depth=None, parse_int=_json_int)
    except SceneError as exc:
        raise ConversionError(name, exc.problem) from None


def _json_int(text: str) -> int | float:
    """A JSON integer; one with more digits than any float holds is read as a float (infinite),
    not as an integer Python refuses to convert or that overflows a float later."""
    return int(text) if len(text) <= 400 else float(text)


def read_users(path: str | Path) -> dict[str, str]:
    """Worker names by Label Studio user id, from the JSON of ``GET /api/users`` (a list of users
    with ``id`` and ``username``/``email``) or a plain ``{"id": "name"}`` object."""
    users = read_export(path)
    if isinstance(users, dict):
        return {str(k): str(v) for k, v in users.items()}
    if not isinstance(users, list):
        raise ConversionError(str(path), "expected the list of users from GET /api/users")
    out = {}
    for u in users:
        if not isinstance(u, dict) or "id" not in u:
            raise ConversionError(str(path), f"expected users with an 'id', got {u!r}"[:120])
        out[str(u["id"])] = str(u.get("username") or u.get("email") or u["id"])
    return out


def scenes_from_label_studio(tasks: Any, *, image_dir: str | Path | None = None,
                             out_dir: str | Path | None = None, targets: Any = None,
                             users: dict[str, str] | None = None, classes: dict | None = None) -> ImportReport:
    """Convert a Label Studio JSON export (``tasks``: the decoded list of tasks with ``data`` and
    ``annotations``, ``completions`` before 1.0) to one ``creference-scene/2`` scene per image: the
    tasks of one image make one scene holding their targets (module docstring).

    ``image_dir``: where the images are; ``image.path`` is the file of the task's ``image`` URL in
    this folder (:func:`~.annotation_tools.image_file`; unless the task gives ``image_path``).
    ``out_dir``, ``targets``, ``classes``: as :func:`~.cvat.scenes_from_cvat`. ``users``: worker
    names by user id (:func:`read_users`); otherwise a worker is named by the user id in
    ``completed_by`` (or the e-mail, when the export expands the user).

    Returns an :class:`ImportReport`: a task or image that cannot be converted is in ``errors`` (its
    message names the task and the region), the others are in ``scenes``.
    """
    if isinstance(tasks, dict) and "data" in tasks:
        tasks = [tasks]
    if not isinstance(tasks, list):
        raise ConversionError("(export)", f"expected a list of tasks (Label Studio's JSON export), "
                                          f"got {type(tasks).__name__}")
    table = TargetTable.of(targets)
    groups: dict[Any, list[_TaskPart]] = {}
    errors, notes, unannotated = [], [], 0
    for i, task in enumerate(tasks):
        try:
            part = _task_part(task, i, users or {}, notes)
        except ConversionError as exc:
            errors.append(exc)
            continue
        if part is None:
            unannotated += 1
        else:
            image = part.data.get("image")
            raw = part.task["data"]
            request = raw.get("request_key") if "creference_scene" in raw else None
            if request is not None:  # the answered requests of one frame make one scene: the frame's
                key = ("request", str(request))
            else:
                key = image if isinstance(image, str) and image and "creference_scene" not in part.data else i
            groups.setdefault(key, []).append(part)
    scenes = []
    for key, parts in groups.items():
        try:
            if isinstance(key, tuple):
                parts = [_merged_requests(parts, key[1])]
            scenes.append(_image_scene(parts, image_dir, out_dir, table, classes, notes))
        except ConversionError as exc:
            errors.append(exc)
    kept, clashes = unique_names(scenes)
    notes += table.notes()
    return ImportReport(tuple(kept), tuple(errors + clashes), tuple(notes), unannotated)


@dataclass
class _TaskPart:
    """What one task gives the scene of its image: its drawn targets (id → the target's
    ``class``, ``dimensions_m``, ``ground_truth``, ``lines`` and their ``origins``), references
    (and the regions they come from), horizon lines, the image size (px) and the task's ``data``."""

    where: str
    task: dict
    index: int
    data: dict
    size: tuple[int, int]
    targets: dict
    refs: list
    ref_origins: list
    horizons: list


def _task_name(task: Any, index: int) -> str:
    tid = task.get("id") if isinstance(task, dict) else None
    if isinstance(tid, (int, str)) and not isinstance(tid, bool):
        return f"task {tid}"
    return f"task at index {index}"


def _task_part(task: Any, index: int, users: dict, notes: list[str]) -> _TaskPart | None:
    """What a task gives the scene of its image, or None (no annotations yet)."""
    where = _task_name(task, index)
    if not isinstance(task, dict):
        raise ConversionError(where, f"expected a task object, got {type(task).__name__}")
    if json_depth(task) > MAX_JSON_DEPTH:
        raise ConversionError(where, f"nested more than {MAX_JSON_DEPTH} deep; refused")
    data = task.get("data")
    if not isinstance(data, dict):
        if "annotations" not in task and "completions" not in task:
            raise ConversionError(where, "no 'data' and no 'annotations': is this Label Studio's "
                                         "JSON export (not JSON-MIN or CSV)?")
        raise ConversionError(where, "'data' is missing or not an object")
    anns = task.get("annotations", task.get("completions", []))
    if not isinstance(anns, list):
        raise ConversionError(where, f"'annotations' is not a list: {type(anns).__name__}")
    anns = [a for a in anns if not (isinstance(a, dict) and a.get("was_cancelled") is True)]
    if not any(not isinstance(a, dict) or a.get("result") for a in anns):
        notes.append(f"{where}: no annotations yet; skipped")
        return None
    width, height = _image_size(anns, data, where)
    items_list = [annotation_items(ann, k, width, height, where, users, notes) for k, ann in enumerate(anns)]
    named = any(d.target is not None for items in items_list for d in items.drawings)
    declared, data, refs, ref_origins = _declared(data, task, index, named, where)
    data = _camera_id(data, where)
    targets = {tid: {**t, "id": tid, "lines": list(t.get("lines", [])), "origins": list(t.get("origins", []))}
               for tid, t in declared.items()}
    horizons = []
    for items in items_list:
        n = len(items.drawings) + len(items.references)
        secs = items.lead_time / n if items.lead_time is not None and n else None
        for d in items.drawings:
            dwhere = f"{where}, {items.name}, {d.region}"
            tid = _resolve(d.target, declared, targets, dwhere)
            t = targets.setdefault(tid, {"id": tid, "lines": [], "origins": []})
            if d.cls is not None:
                if t.get("class") not in (None, d.cls):
                    raise ConversionError(dwhere, f"class {d.cls!r} for target {t['id']!r}, which is "
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
    drawn = {tid: t for tid, t in targets.items() if t["lines"]}
    if not drawn:
        raise ConversionError(where, "no annotation draws a target's dimension lines "
                                     f"({', '.join(repr(x) for x in TARGET_LABELS)}, or a 'target' line)")
    notes += [f"{where}: target {tid!r} has no dimension lines; left out" for tid in targets if tid not in drawn]
    if len(drawn) == 1:  # the relative references of a task that draws one target are ratios to it
        refs = [{**r, "target": next(iter(drawn))} if r["mode"] == "relative" and "target" not in r else r
                for r in refs]
    return _TaskPart(where, task, index, data, (width, height), drawn, refs, ref_origins, horizons)


def _declared(data: dict, task: dict, index: int, named: bool, where: str) -> tuple[dict, dict, list, list]:
    """The targets a task declares, by id (``data.targets``; ``target_id`` and ``target_*_m``; the
    scene of a request task; else, when no region names a target, ``task<id>``), ``data`` with the
    photo's fields, and the references (and their origins) the task starts from."""
    if data.get("creference_scene") is not None:
        return _request(data, where)
    if "targets" not in data:
        if "target_id" not in data and named and not any(data.get(k) not in (None, "") for k in _DIMS):
            return {}, data, [], []
        tid = data.get("target_id", f"task{task.get('id', index)}")
        if isinstance(tid, bool) or not isinstance(tid, (str, int)) or str(tid).strip() == "":
            raise ConversionError(where, f"data.target_id must be text, got {_short(tid)}")
        given = [k for k in _DIMS if data.get(k) not in (None, "")]
        if given and len(given) < 3:
            raise ConversionError(where, f"data has {given} but not {[k for k in _DIMS if k not in given]}")
        entry: dict[str, Any] = {"dimensions_m": {k: number_field(data[f"target_{k}_m"], where, f"data.target_{k}_m",
                                                                  positive=True) for k in SIZE_KEYS} if given else None}
        truth = data.get("ground_truth")
        if isinstance(truth, dict) and "location_m" in truth:  # a one-target truth: the target's and the camera's
            entry["ground_truth"] = {k: v for k, v in truth.items() if k not in _CAMERA_TRUTH}
            entry["truth_from"] = "data.ground_truth"
            data = {**data, "ground_truth": {k: v for k, v in truth.items() if k in _CAMERA_TRUTH} or None}
        return {str(tid).strip(): entry}, data, [], []
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
        entry = {"truth_from": path}
        if t.get("class") not in (None, ""):
            if not isinstance(t["class"], str):
                raise ConversionError(where, f"{path}.class must be text, got {t['class']!r}")
            entry["class"] = t["class"].strip()
        dims = t.get("dimensions_m")
        if dims is not None:
            if not isinstance(dims, dict) or set(dims) != set(SIZE_KEYS):
                raise ConversionError(where, f"{path}.dimensions_m must be an object with length, width, "
                                             f"height (m), got {str(dims)[:60]!r}")
            entry["dimensions_m"] = {k: number_field(dims[k], where, f"{path}.dimensions_m.{k}", positive=True)
                                     for k in SIZE_KEYS}
        if t.get("ground_truth") is not None:
            entry["ground_truth"] = t["ground_truth"]
        out[tid] = entry
    return out, data, [], []


def _camera_id(data: dict, where: str) -> dict:
    """``data`` with its ``camera_id`` (the camera's name: the scene's ``camera.id``) checked and
    stripped; a value that is not text, or empty text, is a :class:`ConversionError` naming the
    task and the value."""
    value = data.get(CAMERA_ID)
    if value is None:
        return data
    if not isinstance(value, str) or not value.strip():
        problem = (f"must be the camera's name (text), got {_short(value)}" if not isinstance(value, str)
                   else "is empty text ''" if not value else "is blank text (only whitespace)")
        raise ConversionError(where, f"data.{CAMERA_ID} {problem}: give the camera's name, or leave the field out "
                                     "(or null) for a photo of no known camera")
    return {**data, CAMERA_ID: value.strip()}


def _request(data: dict, where: str) -> tuple[dict, dict, list, list]:
    """A request task (``creference advise``, docs/requests.md) carries the scene it was made for in
    ``data.creference_scene`` (either format): its targets with their dimension lines, its
    references and its photo's fields; the task's answers are appended to them."""
    try:
        base = scene_to_dict(parse_quietly(data["creference_scene"]))
    except SceneError as exc:
        raise ConversionError(where, f"data.creference_scene: {exc}") from None
    data = {**{k: v for k, v in data.items() if k not in SHARED_DATA and k != "targets"},
            **{k: v for k, v in task_data(base).items() if k != "image"}}
    declared = {}
    for t in base["targets"]:
        lines = t["dimension_lines"]
        declared[t["id"]] = {**{k: t[k] for k in ("class", "dimensions_m", "ground_truth") if k in t},
                             "lines": lines, "origins": ["data.creference_scene"] * len(lines),
                             "truth_from": "data.creference_scene"}
    refs = base.get("references", [])
    return declared, data, list(refs), ["data.creference_scene"] * len(refs)


def _merged_requests(parts: list[_TaskPart], key: str) -> _TaskPart:
    """One part for the answered request tasks of one frame (``data.request_key``): the scene they
    were made for, once, with every task's answers appended, named after the frame's key (so
    that importing into the scenes folder the batch was made from writes over that frame's
    file). The tasks must carry the same scene: one round of requests."""
    first = parts[0]
    where = ", ".join(p.where for p in parts) + f" (the requests of {key!r})"
    snapshot = first.task["data"]["creference_scene"]
    for part in parts[1:]:
        if part.task["data"]["creference_scene"] != snapshot:
            raise ConversionError(where, f"{part.where} was made for another state of {key!r} than {first.where} "
                                         "(requests of two rounds): import one round's export at a time")
    own = "data.creference_scene"
    targets = {tid: {**t, "lines": list(t["lines"]), "origins": list(t["origins"])} for tid, t in first.targets.items()}
    refs, ref_origins = list(first.refs), list(first.ref_origins)
    for part in parts[1:]:  # what each further task adds to the scene they share
        for tid, t in part.targets.items():
            new = [(line, o) for line, o in zip(t["lines"], t["origins"]) if o != own]
            if tid not in targets:
                targets[tid] = {**t, "lines": [], "origins": []}
            targets[tid]["lines"] += [line for line, _ in new]
            targets[tid]["origins"] += [f"{part.where}, {o}" for _, o in new]
        added = [(r, o) for r, o in zip(part.refs, part.ref_origins) if o != own]
        refs += [r for r, _ in added]
        ref_origins += [f"{part.where}, {o}" for _, o in added]
    data = {**first.data}
    if data.get("frame_id") in (None, ""):
        data["frame_id"] = key  # the full key (a/cam1 and b/cam1 are two frames): advise --merge finds it by it
    return dataclasses.replace(first, where=where, data=data, targets=targets, refs=refs, ref_origins=ref_origins,
                               horizons=[h for p in parts for h in p.horizons])


def _resolve(name: str | None, declared: dict, targets: dict, where: str) -> str:
    """The id of the target a region names (``name``; None: the task's only target), checked
    against the declared targets (any id when the task declares none)."""
    if name is None:
        if len(declared) == 1:
            return next(iter(declared))
        known = sorted(declared or targets)
        raise ConversionError(where, "this target's region names no target (fill in its 'target' field"
                                     f"{f'; targets: {known}' if known else ''})")
    if declared and name not in declared:
        raise ConversionError(where, f"target {name!r} is not in data.targets (ids: {sorted(declared)})")
    return name


def _image_scene(parts: list[_TaskPart], image_dir, out_dir, table: TargetTable, classes: dict | None,
                 notes: list[str]) -> ImportedScene:
    """The scene of one image from the parts of its tasks (module docstring)."""
    first = parts[0]
    where = first.where if len(parts) == 1 else f"{', '.join(p.where for p in parts)} (one image)"

    def origin(part, text):  # a merged scene's messages name the task too
        return text if len(parts) == 1 else f"{part.where}, {text}"

    for part in parts[1:]:
        if part.size != first.size:
            raise ConversionError(where, f"the image is {first.size[0]}x{first.size[1]} in {first.where} but "
                                         f"{part.size[0]}x{part.size[1]} in {part.where}")
    data = _shared_data(parts, where)
    image_path, image_names = _image_path(data, image_dir, out_dir, where, notes), _image_names(data)
    drawn: dict[str, dict] = {}
    refs, ref_origins, horizons = [], [], []
    for part in parts:
        for tid, t in part.targets.items():
            if tid in drawn:
                raise ConversionError(where, f"target {tid!r} is in {drawn[tid]['part'].where} and in "
                                             f"{part.where}; a target id must be unique among the tasks of its image")
            drawn[tid] = {**t, "part": part}
        refs += part.refs
        ref_origins += [origin(part, o) for o in part.ref_origins]
        horizons += part.horizons
    camera = {k: data[k] for k in CAMERA_DATA if data.get(k) is not None}
    if data.get(CAMERA_ID) is not None:
        camera = {"id": data[CAMERA_ID], **camera}
    if data.get("focal_length_px") not in (None, ""):
        camera["focal_length_px"] = number_field(data["focal_length_px"], where, "data.focal_length_px", positive=True)
    else:
        camera.pop("focal_length_px", None)
        table_focal = table.focal(image_names, list(drawn), where)
        if table_focal is not None:
            camera["focal_length_px"] = table_focal
    horizon = data.get("horizon")
    if horizon is not None and horizons:
        notes.append(f"{where}: data.horizon used; {len(horizons)} annotated horizon line(s) ignored")
    elif horizons:
        horizon = mean_horizon(horizons, first.size[0], where)
    out_targets, origins = [], {}
    for i, t in enumerate(drawn.values()):
        dims = table.size(image_names, t["id"], t.get("dimensions_m"), f"{where}, target {t['id']!r}",
                          required=t.get("class") is None)
        d = {"id": t["id"], "class": t.get("class"), "dimensions_m": dims, "dimension_lines": t["lines"],
             "ground_truth": t.get("ground_truth")}
        out_targets.append({k: v for k, v in d.items() if v is not None})
        part = t["part"]
        origins[f"targets[{i}]"] = origin(part, t.get("class_from") or t["origins"][0])
        origins[f"targets[{i}].ground_truth"] = origin(part, t.get("truth_from", "data.targets"))
        origins.update({f"targets[{i}].dimension_lines[{j}]": origin(part, o) for j, o in enumerate(t["origins"])})
    scene = scene_dict(first.size, image_path, camera, horizon=horizon,
                       horizon_sd_px=data.get("horizon_sd_px"),
                       classes=classes_block(out_targets, data.get("classes"), classes), targets=out_targets,
                       references=refs or None, ground_truth=data.get("ground_truth"), setting=data.get("setting"))
    origins = {"camera": "data.camera_id / focal_length_px / principal_point / kitti_p2", "horizon": "the horizon",
               "horizon_sd_px": "data.horizon_sd_px", "classes": "data.classes / --classes", "setting": "data.setting",
               "ground_truth": "data.ground_truth", **origins}
    origins.update({f"references[{k}]": o for k, o in enumerate(ref_origins)})
    return ImportedScene(_scene_name(data, first.task, first.index, where), checked_scene(scene, where, origins),
                         where)


def _shared_data(parts: list[_TaskPart], where: str) -> dict:
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


def _scene_name(data: dict, task: dict, index: int, where: str) -> str:
    """The scene file's stem: ``data.frame_id``, else the image's file name without its
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


def _image_size(anns: list, data: dict, where: str) -> tuple[int, int]:
    """(width, height): the results' original size, else the task's ``image_width/height``."""
    seen: dict[tuple[int, int], str] = {}
    for k, ann in enumerate(anns):
        if not isinstance(ann, dict):
            continue  # refused by annotation_items
        aname, result = annotation_result(ann, k, where)
        for r in result:
            if not isinstance(r, dict) or r.get("type") == "relation":
                continue
            rwhere = f"{where}, {aname}, region {_short(r.get('id'))}"
            rot = r.get("image_rotation")
            if rot not in (None, 0, 0.0):
                raise ConversionError(rwhere, f"image_rotation {_short(rot)} is not supported "
                                              "(annotate the image unrotated)")
            ow, oh = r.get("original_width"), r.get("original_height")
            if ow is None and oh is None:
                continue
            size = (_whole(ow, rwhere, "original_width"), _whole(oh, rwhere, "original_height"))
            seen.setdefault(size, rwhere)
    if len(seen) > 1:
        (a, wa), (b, wb) = list(seen.items())[:2]
        raise ConversionError(where, f"results disagree on the image size: {a[0]}x{a[1]} ({wa}) "
                                     f"and {b[0]}x{b[1]} ({wb})")
    has_data = [data.get(k) not in (None, "") for k in ("image_width", "image_height")]
    if any(has_data) and not all(has_data):
        raise ConversionError(where, "data gives only one of image_width and image_height")
    data_size = ((_whole(data["image_width"], where, "data.image_width"),
                  _whole(data["image_height"], where, "data.image_height")) if all(has_data) else None)
    if seen:
        size = next(iter(seen))
        if data_size is not None and data_size != size:
            raise ConversionError(where, f"the results' original size {size[0]}x{size[1]} differs from "
                                         f"data.image_width x image_height {data_size[0]}x{data_size[1]}")
        return size
    if data_size is None:
        raise ConversionError(where, "no image size: the results have no original_width/"
                                     "original_height and data has no image_width/image_height")
    return data_size


def _image_path(data: dict, image_dir, out_dir, where: str, notes: list) -> str | None:
    """The scene's ``image.path``: ``data.image_path`` as it is, else (with ``image_dir``) the file of
    ``data.image`` in ``image_dir`` (for local files ``?d=dir/a.jpg``: ``dir/a.jpg``, else ``a.jpg``)."""
    path = data.get("image_path")
    if path not in (None, ""):
        if not isinstance(path, str):
            raise ConversionError(where, f"data.image_path must be text, got {_short(path)}")
        if "\0" in path:
            raise ConversionError(where, f"data.image_path {_short(path)} holds a NUL character (no file has "
                                         "such a name)")
        return path
    url = data.get("image")
    if image_dir is None or not isinstance(url, str) or not url:
        return None
    local = url_path(url, where)
    if not PurePosixPath(local).name:
        raise ConversionError(where, f"no file name in data.image {_short(url)}")
    return image_file(image_dir, local, out_dir, where, notes)


def _image_names(data: dict) -> list[str]:
    """The names of a task's image, for the ``--targets`` table's ``image`` column: ``data.image``,
    the file path in it, ``data.image_path``."""
    names = []
    for key in ("image", "image_path"):
        value = data.get(key)
        if isinstance(value, str) and value:
            names.append(value)
            if key == "image":
                try:
                    names.append(url_path(value, ""))
                except ConversionError:
                    pass
    return list(dict.fromkeys(names))
