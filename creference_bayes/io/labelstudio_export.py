"""Scenes → Label Studio tasks: the opposite of the import, for round trips and for sending
pre-annotated tasks (``predictions``) back to the crowd. A scene, whatever its number of targets,
becomes one task holding all of them (docs/import.md)."""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

from .labelstudio_results import (CONTROL_VALUE, IMAGE, LINES, POINTS, REF_END, REF_START, REFERENCE,
                                  TARGET, TARGET_LABELS, TARGET_LINES)
from .scene import Scene, parse_scene, scene_to_dict

__all__ = ["label_studio_task", "label_studio_tasks", "task_data", "CAMERA_ID", "CAMERA_DATA", "PHOTO_DATA"]

#: The configs' names, by how lines are drawn (the same keys as ``LINE_TOOLS``).
_LINE_TOOLS = ("keypoints", "vectors")
#: Drawn size of an exported keypoint, percent of the image width (Label Studio's ``value.width``).
_POINT_SIZE = 0.5
#: The ``data`` field of the camera's name, the scene's ``camera.id`` (frames with the same id share
#: a camera: ``creference batch --rig``).
CAMERA_ID = "camera_id"
#: A scene's ``camera`` keys, carried as task ``data`` fields of the same name.
CAMERA_DATA = ("focal_length_px", "principal_point", "kitti_p2", "kitti_calib", "focal_length_prior",
               "orientation_prior")
#: The scene's other keys of the photo (not of one target), carried as ``data`` fields.
PHOTO_DATA = ("horizon", "horizon_sd_px", "classes", "ground_truth", "setting")


def task_data(d: dict, image_url: str | None = None) -> dict:
    """The task ``data`` of a scene (a ``creference-scene/2`` dict, as ``scene_to_dict`` writes
    it): ``image`` (``image_url``, else the scene's image path), the image size, ``targets`` (id,
    class, known size in metres, ground truth), the camera (:data:`CAMERA_DATA`, and its ``id`` as
    :data:`CAMERA_ID`) and the photo's fields (:data:`PHOTO_DATA`)."""
    data: dict[str, Any] = {"image": image_url or d["image"].get("path", ""), "image_width": d["image"]["width"],
                            "image_height": d["image"]["height"],
                            "targets": [{k: t[k] for k in ("id", "class", "dimensions_m", "ground_truth") if k in t}
                                        for t in d["targets"]]}
    if d["image"].get("path"):
        data["image_path"] = d["image"]["path"]
    camera = d.get("camera") or {}
    if camera.get("id") is not None:
        data[CAMERA_ID] = camera["id"]
    data.update({k: camera[k] for k in CAMERA_DATA if camera.get(k) is not None})
    data.update({k: d[k] for k in PHOTO_DATA if d.get(k) is not None})
    return data


def label_studio_task(scene: Scene | dict, *, task_id: int = 1, lines: str = "keypoints",
                      image_url: str | None = None, as_predictions: bool = False) -> dict:
    """A Label Studio task (``data`` + ``annotations``) holding a scene (a :class:`Scene` or a
    scene dict of either format), for the shipped configs.

    ``data`` is :func:`task_data`. Each worker's work becomes one annotation (``completed_by`` =
    the worker, ``lead_time`` = the sum of its items' seconds when all have them) holding the
    worker's dimension lines of every target and the worker's references; a worker's second set
    of lines of a target goes to a second annotation. Each target's regions name it in their
    ``target`` field: four keypoints, or with ``lines="vectors"`` one four-point ``target`` line;
    a reference keeps its ``target``. Coordinates are percent of the image size, at full float
    precision. With ``as_predictions`` the annotations are written as ``predictions`` (pre-labels
    shown to workers). ``ValueError`` for an unknown ``lines``, and for a reference without a line
    (a target's own size, a distance between two targets): a task holds drawn regions only.
    """
    if lines not in _LINE_TOOLS:
        raise ValueError(f"lines: expected one of {list(_LINE_TOOLS)}, got {lines!r}")
    d = scene_to_dict(parse_scene(scene) if isinstance(scene, dict) else scene)
    w, h = d["image"]["width"], d["image"]["height"]
    for i, r in enumerate(d.get("references", [])):
        if "line" not in r:
            raise ValueError(f"references[{i}]: a {r['measure']} of {r.get('target') or r.get('targets')!r} without "
                             "a line cannot be written to a Label Studio task (a task holds drawn regions only)")
    groups: OrderedDict = OrderedDict()
    for j, t in enumerate(d["targets"]):
        for i, dl in enumerate(t["dimension_lines"]):
            groups.setdefault(dl.get("worker") or f"\0dims{j}:{i}", []).append(("dims", {**dl, "target": t["id"]}))
    for i, ref in enumerate(d.get("references", [])):
        groups.setdefault(ref.get("worker") or f"\0ref{i}", []).append(("ref", ref))
    annotations = []
    for key, items in groups.items():
        for chunk in _chunks(items):
            n = len(annotations) + 1
            result: list[dict] = []
            for k, (kind, item) in enumerate(chunk):
                rid = f"{task_id}_{n}_{k}"
                result += (_target_results(rid, item, w, h, lines) if kind == "dims"
                           else _reference_results(rid, item, w, h, lines))
            ann: dict[str, Any] = {"id": task_id * 1000 + n, "result": result}
            if not key.startswith("\0"):
                ann["completed_by"] = key
            secs = [x[1].get("seconds") for x in chunk]
            if all(s is not None for s in secs):
                ann["lead_time"] = float(sum(secs))
            annotations.append(ann)
    task: dict[str, Any] = {"id": task_id, "data": task_data(d, image_url)}
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


def _chunks(items) -> list[list]:
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


def _region(rid, typ, from_name, w, h, value) -> dict:
    return {"id": rid, "type": typ, "from_name": from_name, "to_name": IMAGE,
            "original_width": w, "original_height": h, "image_rotation": 0, "value": value}


def _point_result(rid, label, p, w, h):
    return _region(rid, "keypointlabels", POINTS, w, h, {"x": 100.0 * p[0] / w, "y": 100.0 * p[1] / h,
                                                          "width": _POINT_SIZE, "keypointlabels": [label]})


def _vector_result(rid, label, from_name, points, w, h) -> dict:
    verts = [{"id": f"{rid}_v{i}", "x": 100.0 * p[0] / w, "y": 100.0 * p[1] / h,
              "prevPointId": None if i == 0 else f"{rid}_v{i - 1}", "isBezier": False}
             for i, p in enumerate(points)]
    return _region(rid, "vectorlabels", from_name, w, h,
                   {"vertices": verts, "closed": False, "vectorlabels": [label]})


def _control(rid, name, typ, value):
    key = CONTROL_VALUE[typ]
    return {"id": rid, "type": typ, "from_name": name, "to_name": IMAGE,
            "value": {key: value if typ == "number" else [value]}}


def _target_results(rid, item, w, h, lines) -> list[dict]:
    """One set of a target's dimension lines, its regions naming the target."""
    if lines == "vectors":
        return [_vector_result(rid, TARGET, TARGET_LINES, item["corners"], w, h),
                _control(rid, "target", "textarea", item["target"])]
    out = []
    for i, p in enumerate(item["corners"]):
        out += [_point_result(f"{rid}_t{i + 1}", TARGET_LABELS[i], p, w, h),
                _control(f"{rid}_t{i + 1}", "target", "textarea", item["target"])]
    return out


def _reference_results(rid, item, w, h, lines) -> list[dict]:
    """One reference line with its measurement fields (and the target it names)."""
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
