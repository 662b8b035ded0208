"""Scenes → Label Studio tasks: the opposite of the import, for round trips and for sending
pre-annotated tasks (``predictions``) back to the crowd. A ``creference-scene/2`` frame becomes
one task holding all its targets (:func:`label_studio_frame_task`)."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

from .frame_import import is_frame
from .frame_scene import frame_to_dict, parse_frame
from .labelstudio_results import (CONTROL_VALUE, IMAGE, LINES, POINTS, REF_END, REF_START, REFERENCE,
                                  TARGET, TARGET_LABELS, TARGET_LINES)
from .scene import Scene, parse_scene, scene_to_dict

__all__ = ["label_studio_task", "label_studio_tasks", "label_studio_frame_task"]

#: The configs' names, by how reference lines are drawn (the same keys as ``LINE_TOOLS``).
_LINE_TOOLS = ("keypoints", "vectors")
#: Drawn size of an exported keypoint, percent of the image width (Label Studio's ``value.width``).
_POINT_SIZE = 0.5


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
    if lines not in _LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(_LINE_TOOLS)}, got {lines!r}")
    if is_frame(scene):
        return label_studio_frame_task(scene, task_id=task_id, lines=lines, image_url=image_url,
                                       as_predictions=as_predictions)
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
            annotations.append(_annotation(task_id * 1000 + n, key, chunk,
                                           _results(chunk, f"{task_id}_{n}", w, h, lines)))
    return _task(task_id, data, annotations, as_predictions)


def _annotation(ann_id: int, key: str, chunk, result: list[dict]) -> dict:
    """One annotation: its results, its worker (``key``, unless a placeholder starting with NUL)
    and its lead time when every item of ``chunk`` states its seconds."""
    ann: dict[str, Any] = {"id": ann_id, "result": result}
    if not key.startswith("\0"):
        ann["completed_by"] = key
    secs = [x[1].get("seconds") for x in chunk]
    if all(s is not None for s in secs):
        ann["lead_time"] = float(sum(secs))
    return ann


def _task(task_id: int, data: dict, annotations: list[dict], as_predictions: bool) -> dict:
    """A task with its annotations, or with them as predictions."""
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
    key = CONTROL_VALUE[typ]
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
        out += _reference_results(rid, item, w, h, lines)
    return out


def _reference_results(rid, item, w, h, lines) -> list[dict]:
    """One reference line with its measurement fields (and its ``target``, in a frame)."""
    out: list[dict] = []
    (a, b) = item["line"]
    if lines == "keypoints":
        out += [_point_result(f"{rid}_s", REF_START, a, w, h), _point_result(f"{rid}_e", REF_END, b, w, h),
                {"type": "relation", "from_id": f"{rid}_s", "to_id": f"{rid}_e",
                 "direction": "right", "labels": []}]
        rid = f"{rid}_s"
    else:
        out.append(_vector_result(rid, REFERENCE, LINES, (a, b), w, h))
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
    if item.get("target") is not None:
        out.append(_control(rid, "target", "textarea", item["target"]))
    return out


def _vector_result(rid, label, from_name, points, w, h) -> dict:
    verts = [{"id": f"{rid}_v{i}", "x": 100.0 * p[0] / w, "y": 100.0 * p[1] / h,
              "prevPointId": None if i == 0 else f"{rid}_v{i - 1}", "isBezier": False}
             for i, p in enumerate(points)]
    return {"id": rid, "type": "vectorlabels", "from_name": from_name, "to_name": IMAGE,
            "original_width": w, "original_height": h, "image_rotation": 0,
            "value": {"vertices": verts, "closed": False, "vectorlabels": [label]}}


# ----------------------------------------------------------------------------------------------
# frames


def label_studio_frame_task(frame, *, task_id: int = 1, lines: str = "keypoints", image_url: str | None = None,
                            as_predictions: bool = False) -> dict:
    """A Label Studio task holding a whole ``creference-scene/2`` frame (a dict or a
    :class:`~.frame_scene.FrameScene`), for the frame configs (``--print-config --frame``).

    ``data.targets`` lists the targets (id, class, known size, ground truth); each worker's work
    becomes one annotation holding that worker's dimension lines of every target (a second set of
    lines of one target goes to a second annotation), each target's regions naming it in their
    ``target`` field: four keypoints, or with ``lines="vectors"`` one four-point ``target`` line.
    References keep their ``target``. A worker's measurement of a target's own size (a reference
    without a line) has no region to hold it: :class:`ValueError`.
    """
    if lines not in _LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(_LINE_TOOLS)}, got {lines!r}")
    d = frame_to_dict(parse_frame(frame) if isinstance(frame, dict) else frame)
    w, h = d["image"]["width"], d["image"]["height"]
    for i, r in enumerate(d.get("references", [])):
        if "line" not in r:
            raise ValueError(f"references[{i}]: a measurement of target {r.get('target')!r}'s own {r['measure']} "
                             "(no line) cannot be written to a Label Studio task")
    data: dict[str, Any] = {"image": image_url or d["image"].get("path", ""), "image_width": w, "image_height": h,
                            "targets": [{k: t[k] for k in ("id", "class", "dimensions_m", "ground_truth") if k in t}
                                        for t in d["targets"]]}
    if d["image"].get("path"):
        data["image_path"] = d["image"]["path"]
    cam = d.get("camera") or {}
    for key in ("focal_length_px", "principal_point", "kitti_p2"):
        if cam.get(key) is not None:
            data[key] = cam[key]
    for key in ("horizon", "horizon_sd_px", "classes", "ground_truth"):
        if d.get(key) is not None:
            data[key] = d[key]
    groups: OrderedDict = OrderedDict()
    for t in d["targets"]:
        for i, dl in enumerate(t["dimension_lines"]):
            groups.setdefault(dl.get("worker") or f"\0dims{t['id']}{i}", []).append(("dims", {**dl, "target": t["id"]}))
    for i, ref in enumerate(d.get("references", [])):
        groups.setdefault(ref.get("worker") or f"\0ref{i}", []).append(("ref", ref))
    annotations = []
    for key, items in groups.items():
        for chunk in _frame_chunks(items):
            n = len(annotations) + 1
            result: list[dict] = []
            for k, (kind, item) in enumerate(chunk):
                rid = f"{task_id}_{n}_{k}"
                result += (_target_results(rid, item, w, h, lines) if kind == "dims"
                           else _reference_results(rid, item, w, h, lines))
            annotations.append(_annotation(task_id * 1000 + n, key, chunk, result))
    return _task(task_id, data, annotations, as_predictions)


def _frame_chunks(items) -> list[list]:
    """One worker's items as annotations: the k-th annotation holds the worker's k-th set of lines
    of every target; the references go with the first."""
    seen: dict[str, int] = {}
    chunks: list[list] = [[]]
    for kind, item in items:
        if kind == "dims":
            k = seen.get(item["target"], 0)
            seen[item["target"]] = k + 1
            while len(chunks) <= k:
                chunks.append([])
            chunks[k].append((kind, item))
    chunks[0] += [x for x in items if x[0] == "ref"]
    return [c for c in chunks if c]


def _target_results(rid, item, w, h, lines) -> list[dict]:
    if lines == "vectors":
        return [_vector_result(rid, TARGET, TARGET_LINES, item["corners"], w, h),
                _control(rid, "target", "textarea", item["target"])]
    out = []
    for i, p in enumerate(item["corners"]):
        out += [_point_result(f"{rid}_t{i + 1}", TARGET_LABELS[i], p, w, h),
                _control(f"{rid}_t{i + 1}", "target", "textarea", item["target"])]
    return out
