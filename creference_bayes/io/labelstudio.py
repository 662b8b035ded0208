"""Label Studio ↔ ``creference-scene/1``: the shipped labelling configs, the JSON export → one scene
per target, and scenes → Label Studio tasks (docs/import.md is the user's guide).

One task is one target: its ``data`` gives the image and the target's id and size, and each of its
annotations is one worker's work on that target (a set of dimension lines, reference lines with
their measurements, optionally the horizon). Several targets on one image are several tasks.

Results are matched by their control (``from_name``) and label: keypoints from ``points`` with
the labels :data:`TARGET_LABELS`, ``reference start`` / ``reference end`` (paired by a relation)
and ``horizon``; or, with the vector config, two-point vectors from ``lines`` labelled
``reference`` / ``horizon``. A reference's measurement is in per-region controls (same result id
as the region) named as :data:`~.annotation_tools.REFERENCE_FIELDS`. Coordinates are percent of
``original_width`` / ``original_height`` (or of the task's ``image_width`` / ``image_height``).
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import unquote, urlparse

from .annotation_tools import (REFERENCE_FIELDS, ConversionError, ImportReport, TargetScene,
                               apply_target_table, checked_scene, mean_horizon, number_field,
                               reference_from_fields, relative_image_path, safe_name, unique_names)
from .scene import SCENE_FORMAT, Scene, parse_scene, scene_to_dict

__all__ = ["TARGET_LABELS", "LINE_TOOLS", "DATA_FIELDS", "label_studio_config", "read_export", "read_users",
           "scenes_from_label_studio", "label_studio_task", "label_studio_tasks"]

#: Keypoint labels of the target's corners t1..t4, in order.
TARGET_LABELS = ("t1 bottom corner", "t2 end of length", "t3 end of width", "t4 top of height")
REF_START, REF_END, REFERENCE, HORIZON = "reference start", "reference end", "reference", "horizon"
POINTS, LINES, IMAGE = "points", "lines", "image"
#: The shipped configs, by how reference lines and the horizon are drawn.
LINE_TOOLS = {"keypoints": "label_studio_keypoints.xml", "vectors": "label_studio_vectors.xml"}
#: Task ``data`` fields read by the importer (``image`` is the one the config displays).
DATA_FIELDS = ("image", "target_id", "target_length_m", "target_width_m", "target_height_m",
               "image_width", "image_height", "image_path", "focal_length_px", "principal_point",
               "horizon", "ground_truth")
_CONTROL_VALUE = {"number": "number", "choices": "choices", "textarea": "text"}
_DIMS = ("target_length_m", "target_width_m", "target_height_m")
#: Drawn size of an exported keypoint, percent of the image width (Label Studio's ``value.width``).
_POINT_SIZE = 0.5


def label_studio_config(lines: str = "keypoints") -> str:
    """The shipped labelling config (XML text); ``lines`` is ``"keypoints"`` or ``"vectors"``."""
    if lines not in LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(LINE_TOOLS)}, got {lines!r}")
    return (resources.files("creference_bayes") / "data" / LINE_TOOLS[lines]).read_text("utf-8")


def read_export(path: str | Path) -> Any:
    """Decode a Label Studio JSON export file (raises :class:`ConversionError` naming the file)."""
    path = Path(path)
    try:
        return json.loads(path.read_bytes().decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise ConversionError(str(path), "not UTF-8 text (expected Label Studio's JSON export)") from None
    except json.JSONDecodeError as exc:
        raise ConversionError(str(path), f"not valid JSON: {exc.msg} at line {exc.lineno} "
                                         f"column {exc.colno}") from None
    except RecursionError:
        raise ConversionError(str(path), "JSON nested too deeply") from None


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


# ----------------------------------------------------------------------------------------------
# import


@dataclass
class _Region:
    kind: str            # "keypoint" or "vector"
    label: str
    points: list         # [[u, v], ...] pixels


@dataclass
class _Items:
    """What one annotation contributes."""

    name: str
    worker: str | None
    lead_time: float | None
    corners: list | None = None
    references: list = field(default_factory=list)   # (region id, fields, line)
    horizons: list = field(default_factory=list)


def scenes_from_label_studio(tasks: Any, *, image_dir: str | Path | None = None,
                             out_dir: str | Path | None = None, targets: dict | None = None,
                             users: dict[str, str] | None = None) -> ImportReport:
    """Convert a Label Studio JSON export (the decoded list of tasks) to one scene per task.

    Parameters
    ----------
    tasks : list
        The export: tasks with ``data`` and ``annotations`` (``completions`` before 1.0).
    image_dir : path, optional
        Where the images are: ``image.path`` becomes this folder joined with the file name of the
        task's ``image`` URL (unless the task gives ``image_path``).
    out_dir : path, optional
        The folder the scenes will be written to; image paths are made relative to it.
    targets : dict, optional
        Known sizes by target id (:func:`~.annotation_tools.load_target_table`).
    users : dict, optional
        Worker names by user id (:func:`read_users`); otherwise a worker is named by the user id
        in ``completed_by`` (or the e-mail, when the export expands the user).

    Returns
    -------
    ImportReport
        A task that cannot be converted is in ``errors`` (its message names the task and the
        region) and the others are in ``scenes``.
    """
    if isinstance(tasks, dict) and "data" in tasks:
        tasks = [tasks]
    if not isinstance(tasks, list):
        raise ConversionError("(export)", f"expected a list of tasks (Label Studio's JSON export), "
                                          f"got {type(tasks).__name__}")
    scenes, errors, notes = [], [], []
    for i, task in enumerate(tasks):
        try:
            converted = _task_scene(task, i, image_dir, out_dir, targets, users or {}, notes)
        except ConversionError as exc:
            errors.append(exc)
            continue
        if converted is not None:
            scenes.append(converted)
    kept, clashes = unique_names(scenes)
    return ImportReport(tuple(kept), tuple(errors + clashes), tuple(notes))


def _task_name(task: Any, index: int) -> str:
    tid = task.get("id") if isinstance(task, dict) else None
    if isinstance(tid, (int, str)) and not isinstance(tid, bool):
        return f"task {tid}"
    return f"task at index {index}"


def _task_scene(task, index, image_dir, out_dir, targets, users, notes) -> TargetScene | None:
    where = _task_name(task, index)
    if not isinstance(task, dict):
        raise ConversionError(where, f"expected a task object, got {type(task).__name__}")
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

    if "target_id" in data:
        tid = data["target_id"]
        if isinstance(tid, bool) or not isinstance(tid, (str, int)) or str(tid).strip() == "":
            raise ConversionError(where, f"data.target_id must be text, got {tid!r}")
        tid = str(tid).strip()
    else:
        tid = f"task{task.get('id', index)}"
    given = [k for k in _DIMS if data.get(k) not in (None, "")]
    if given and len(given) < 3:
        raise ConversionError(where, f"data has {given} but not {[k for k in _DIMS if k not in given]}")
    dims = ({k[7:-2]: number_field(data[k], where, f"data.{k}", positive=True) for k in _DIMS}
            if given else None)
    size, table_focal = apply_target_table(tid, dims, targets, where)

    lines, refs, horizons, origins = [], [], [], {}
    for k, ann in enumerate(anns):
        items = _annotation_items(ann, k, width, height, where, users, notes)
        n = (items.corners is not None) + len(items.references)
        secs = items.lead_time / n if items.lead_time is not None and n else None
        if items.corners is not None:
            origins[f"target.dimension_lines[{len(lines)}]"] = items.name
            line = {"corners": items.corners}
            line.update({k2: v for k2, v in (("worker", items.worker), ("seconds", secs)) if v is not None})
            lines.append(line)
        for rid, fields_, seg in items.references:
            origins[f"references[{len(refs)}]"] = f"region {rid!r}"
            refs.append(reference_from_fields(fields_, seg, f"{where}, region {rid!r}",
                                              worker=items.worker, seconds=secs))
        horizons.extend(items.horizons)
    if not lines:
        raise ConversionError(where, "no annotation draws the target's dimension lines "
                                     f"({', '.join(repr(x) for x in TARGET_LABELS)})")

    scene: dict[str, Any] = {"format": SCENE_FORMAT, "image": {"width": width, "height": height}}
    image_path = _image_path(data, image_dir, out_dir, where)
    if image_path is not None:
        scene["image"]["path"] = image_path
    camera = {}
    focal = data.get("focal_length_px")
    if focal not in (None, ""):
        camera["focal_length_px"] = number_field(focal, where, "data.focal_length_px", positive=True)
    elif table_focal is not None:
        camera["focal_length_px"] = table_focal
    if data.get("principal_point") is not None:
        camera["principal_point"] = data["principal_point"]
    if camera:
        scene["camera"] = camera
    if data.get("horizon") is not None:
        scene["horizon"] = data["horizon"]
        if horizons:
            notes.append(f"{where}: data.horizon used; {len(horizons)} annotated horizon line(s) ignored")
    elif horizons:
        scene["horizon"] = mean_horizon(horizons, width, where)
    scene["target"] = {"id": tid, "dimensions_m": size, "dimension_lines": lines}
    if refs:
        scene["references"] = refs
    if data.get("ground_truth") is not None:
        scene["ground_truth"] = data["ground_truth"]
    origins.update({"camera": "data.focal_length_px / data.principal_point",
                    "horizon": "the horizon (data.horizon or annotated)",
                    "ground_truth": "data.ground_truth"})
    return TargetScene(safe_name(tid), checked_scene(scene, where, origins), where)


def _whole(value: Any, where: str, what: str) -> int:
    x = number_field(value, where, what, positive=True)
    if x != int(x):
        raise ConversionError(where, f"{what} must be whole pixels, got {x:g}")
    return int(x)


def _image_size(anns: list, data: dict, where: str) -> tuple[int, int]:
    """(width, height): the results' original size, else the task's ``image_width/height``."""
    seen: dict[tuple[int, int], str] = {}
    for ann in anns:
        for r in (ann.get("result") if isinstance(ann, dict) else None) or []:
            if not isinstance(r, dict) or r.get("type") == "relation":
                continue
            rwhere = f"{where}, region {r.get('id')!r}"
            rot = r.get("image_rotation")
            if rot not in (None, 0, 0.0):
                raise ConversionError(rwhere, f"image_rotation {rot!r} is not supported "
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


def _image_path(data: dict, image_dir, out_dir, where: str) -> str | None:
    path = data.get("image_path")
    if path not in (None, ""):
        if not isinstance(path, str):
            raise ConversionError(where, f"data.image_path must be text, got {path!r}")
        return path
    url = data.get("image")
    if image_dir is None or not isinstance(url, str) or not url:
        return None
    name = PurePosixPath(unquote(urlparse(url).path)).name
    if not name:
        raise ConversionError(where, f"no file name in data.image {url!r}")
    return relative_image_path(Path(image_dir) / name, out_dir)


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
    if verts and all("prevPointId" in v and "id" in v for v in verts):
        nxt = {v["prevPointId"]: v for v in verts}
        chain, cur = [], nxt.get(None)
        while cur is not None and len(chain) <= len(verts):
            chain.append(cur)
            cur = nxt.get(cur["id"])
        if len(chain) == len(verts):
            return chain
    return verts


def _annotation_items(ann, k, width, height, where, users, notes) -> _Items:
    if not isinstance(ann, dict):
        raise ConversionError(f"{where}, annotation {k}", f"expected an object, got {type(ann).__name__}")
    aname = f"annotation {ann.get('id', k)}"
    awhere = f"{where}, {aname}"
    result = ann.get("result") or []
    if not isinstance(result, list):
        raise ConversionError(awhere, f"'result' is not a list: {type(result).__name__}")
    lead = ann.get("lead_time")
    lead = None if lead is None else number_field(lead, awhere, "lead_time", lo=0.0, hi=math.inf)
    items = _Items(aname, _worker(ann.get("completed_by"), users), lead)

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
        rwhere = f"{where}, region {rid!r}"
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
        elif typ in _CONTROL_VALUE:
            name = r.get("from_name")
            if name not in REFERENCE_FIELDS:
                notes.append(f"{rwhere}: {typ} '{name}' is not a field the importer knows; ignored")
                continue
            if name in controls.setdefault(rid, {}):
                raise ConversionError(rwhere, f"'{name}' is given twice")
            controls[rid][name] = value.get(_CONTROL_VALUE[typ])
        else:
            notes.append(f"{rwhere}: result type {typ!r} ignored")
    _roles(regions, controls, relations, items, where, awhere)
    return items


def _roles(regions, controls, relations, items: _Items, where: str, awhere: str) -> None:
    corners: dict[int, str] = {}
    starts, ends, hpoints = [], [], []
    for rid, reg in regions.items():
        rwhere = f"{where}, region {rid!r}"
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
                raise ConversionError(f"{where}, region {end!r}", f"'{key}' is {val!r} here but "
                                      f"{fields_[key]!r} on its reference start {start!r}")
            fields_[key] = val
        items.references.append((start, fields_, [regions[start].points[0], regions[end].points[0]]))
    used = set(starts) | set(ends) | {r for r, g in regions.items() if g.label == REFERENCE}
    for rid in controls:
        if rid not in regions:
            raise ConversionError(f"{where}, region {rid!r}", f"reference fields {sorted(controls[rid])} "
                                  "belong to no region of this annotation")
        if rid not in used and controls[rid]:
            raise ConversionError(f"{where}, region {rid!r}", f"a {regions[rid].label!r} point carries "
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
            raise ConversionError(f"{where}, region {a!r}", f"a relation links {regions[a].label!r} to "
                                  f"{regions[b].label!r}; relations must link a 'reference start' "
                                  "to a 'reference end'")
        for rid in (a, b):
            if rid in partner:
                raise ConversionError(f"{where}, region {rid!r}", f"{regions[rid].label!r} is linked "
                                      "to two points (a reference line has two ends)")
        partner[a], partner[b] = b, a
        pairs.append((a, b))
    if not relations and len(starts) == 1 and len(ends) == 1:
        return [(starts[0], ends[0])]
    for rid in starts + ends:
        if rid not in partner:
            other = REF_END if rid in starts else REF_START
            raise ConversionError(f"{where}, region {rid!r}", f"{regions[rid].label!r} is not linked "
                                  f"to a '{other}' (draw a relation between the two ends)")
    return pairs


# ----------------------------------------------------------------------------------------------
# export


def _normalised(scene: Scene | dict) -> dict:
    if isinstance(scene, dict):
        scene = parse_scene(scene)
    return scene_to_dict(scene)


def label_studio_task(scene: Scene | dict, *, task_id: int = 1, lines: str = "keypoints",
                      image_url: str | None = None, as_predictions: bool = False) -> dict:
    """A Label Studio task (``data`` + ``annotations``) holding one scene's annotations.

    Each worker's work becomes one annotation (``completed_by`` = the worker name, ``lead_time`` =
    the sum of its items' seconds when all have them); a worker's second set of dimension lines
    goes to a second annotation. The horizon, camera, image size and ground truth go to ``data``.
    With ``as_predictions`` the annotations are written as ``predictions`` instead (pre-labels
    shown to workers). Coordinates are percent of the image size, at full float precision.
    """
    if lines not in LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(LINE_TOOLS)}, got {lines!r}")
    d = _normalised(scene)
    w, h = d["image"]["width"], d["image"]["height"]
    t = d["target"]
    data: dict[str, Any] = {"image": image_url or d["image"].get("path", ""), "target_id": t["id"],
                            **{f"target_{k}_m": v for k, v in t["dimensions_m"].items()},
                            "image_width": w, "image_height": h}
    if d["image"].get("path"):
        data["image_path"] = d["image"]["path"]
    cam = d.get("camera") or {}
    if cam.get("focal_length_px") is not None:
        data["focal_length_px"] = cam["focal_length_px"]
    if cam.get("principal_point") is not None:
        data["principal_point"] = cam["principal_point"]
    for key in ("horizon", "ground_truth"):
        if d.get(key) is not None:
            data[key] = d[key]

    groups: OrderedDict = OrderedDict()
    for i, dl in enumerate(t["dimension_lines"]):
        groups.setdefault(dl.get("worker") or f"\0dims{i}", []).append(("dims", dl))
    for i, ref in enumerate(d.get("references", [])):
        groups.setdefault(ref.get("worker") or f"\0ref{i}", []).append(("ref", ref))
    annotations = []
    for key, items in groups.items():
        dims = [x for x in items if x[0] == "dims"]
        chunks = [[dims[0]] + [x for x in items if x[0] == "ref"]] if dims else [items]
        chunks += [[x] for x in dims[1:]]
        for chunk in chunks:
            n = len(annotations) + 1
            ann: dict[str, Any] = {"id": task_id * 1000 + n,
                                   "result": _results(chunk, f"{task_id}_{n}", w, h, lines)}
            if not key.startswith("\0"):
                ann["completed_by"] = key
            secs = [x[1].get("seconds") for x in chunk]
            if all(s is not None for s in secs):
                ann["lead_time"] = float(sum(secs))
            annotations.append(ann)
    task: dict[str, Any] = {"id": task_id, "data": data}
    if as_predictions:
        task["predictions"] = [{"model_version": "creference", "result": a["result"]} for a in annotations]
    else:
        task["annotations"] = annotations
    return task


def label_studio_tasks(scenes, *, lines: str = "keypoints", image_urls=None,
                       start_id: int = 1, as_predictions: bool = False) -> list[dict]:
    """Tasks for several scenes (ids ``start_id``, ``start_id + 1``, …); see :func:`label_studio_task`."""
    scenes = list(scenes)
    urls = list(image_urls) if image_urls is not None else [None] * len(scenes)
    if len(urls) != len(scenes):
        raise ValueError(f"image_urls: expected {len(scenes)} URLs, got {len(urls)}")
    return [label_studio_task(s, task_id=start_id + i, lines=lines, image_url=u,
                              as_predictions=as_predictions)
            for i, (s, u) in enumerate(zip(scenes, urls))]


def _point_result(rid, label, p, w, h):
    return {"id": rid, "type": "keypointlabels", "from_name": POINTS, "to_name": IMAGE,
            "original_width": w, "original_height": h, "image_rotation": 0,
            "value": {"x": 100.0 * p[0] / w, "y": 100.0 * p[1] / h, "width": _POINT_SIZE,
                      "keypointlabels": [label]}}


def _control(rid, name, typ, value):
    key = _CONTROL_VALUE[typ]
    return {"id": rid, "type": typ, "from_name": name, "to_name": IMAGE,
            "value": {key: value if typ == "number" else [value]}}


def _results(chunk, prefix, w, h, lines) -> list[dict]:
    out: list[dict] = []
    for k, (kind, item) in enumerate(chunk):
        rid = f"{prefix}_{k}"
        if kind == "dims":
            out += [_point_result(f"{rid}_t{i + 1}", TARGET_LABELS[i], p, w, h)
                    for i, p in enumerate(item["corners"])]
            continue
        (a, b) = item["line"]
        if lines == "keypoints":
            out += [_point_result(f"{rid}_s", REF_START, a, w, h), _point_result(f"{rid}_e", REF_END, b, w, h),
                    {"type": "relation", "from_id": f"{rid}_s", "to_id": f"{rid}_e",
                     "direction": "right", "labels": []}]
            rid = f"{rid}_s"
        else:
            verts = [{"id": f"{rid}_v{i}", "x": 100.0 * p[0] / w, "y": 100.0 * p[1] / h,
                      "prevPointId": None if i == 0 else f"{rid}_v0", "isBezier": False}
                     for i, p in enumerate((a, b))]
            out.append({"id": rid, "type": "vectorlabels", "from_name": LINES, "to_name": IMAGE,
                        "original_width": w, "original_height": h, "image_rotation": 0,
                        "value": {"vertices": verts, "closed": False, "vectorlabels": [REFERENCE]}})
        out += [_control(rid, "measure", "choices", item["measure"]),
                _control(rid, "mode", "choices", item["mode"])]
        if "range" in item:
            out += [_control(rid, "range_low", "number", item["range"][0]),
                    _control(rid, "range_high", "number", item["range"][1])]
        else:
            out.append(_control(rid, "value", "number", item["value"]))
        if item.get("unit"):
            out.append(_control(rid, "unit", "choices", item["unit"]))
        if item.get("confidence") is not None:
            out.append(_control(rid, "confidence_pct", "number", round(100.0 * item["confidence"], 10)))
        if item.get("object"):
            out.append(_control(rid, "object", "textarea", item["object"]))
    return out
