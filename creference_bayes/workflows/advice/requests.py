"""The request list as files a labelling tool takes: Label Studio tasks and CVAT for images XML
(docs/requests.md says how the answers come back).

- **Label Studio**: one task per request, without annotations (the community edition takes a task
  with one out of the labelling queue). Its ``data`` holds the scene's task data
  (:func:`~creference_bayes.io.labelstudio_export.task_data`), the request's fields
  (:func:`request_fields`) and the whole current scene (``creference_scene``), into which the
  importer puts the answers. A reference request on a segment carries the segment as a
  prediction (keypoints or a vector, with its measure, object and target filled in); any other
  request (more lines, a size, a target's length, the distance between two targets) carries its
  target's dimension lines (each corner's median over the sets, named by the target's id; both
  targets for a distance between them), so that a worker sees which object of the photo is meant.
- **CVAT**: the scenes' annotations (:func:`~creference_bayes.io.cvat.cvat_xml`) plus, for a
  reference request on a segment, a ``reference`` polyline on it with ``target_id``, ``object``
  and ``measure`` set, the value left empty and ``worker`` = ``requested``; other requests add
  nothing (the request's text says what to draw).
"""

from __future__ import annotations

import dataclasses

import xml.etree.ElementTree as ET
from pathlib import PurePath

import numpy as np

from ...io.annotation_tools import safe_name
from ...io.cvat import LABEL_ATTRIBUTES, cvat_xml
from ...io.labelstudio_export import _target_results, task_data
from ...io.labelstudio_results import CONTROL_VALUE, IMAGE, LINES, POINTS, REF_END, REF_START, REFERENCE
from ...io.scene import scene_to_dict

__all__ = ["REQUEST_WORKER", "request_fields", "label_studio_requests", "cvat_requests", "image_name"]

#: The ``worker`` of a pre-drawn request shape (CVAT) or prediction (Label Studio).
REQUEST_WORKER = "requested"
_POINT_SIZE = 0.5


def image_name(scene, key: str) -> str:
    """The image's file name; when the scene names none, the frame's full key made file-safe
    (:func:`~creference_bayes.io.annotation_tools.safe_name`) with ``.jpg``: ``a/cam1`` and
    ``b/cam1`` are ``a_cam1.jpg`` and ``b_cam1.jpg``, and the import names their scenes as
    ``advise --merge`` looks for them."""
    return PurePath(str(scene.image_path)).name if scene.image_path is not None else f"{safe_name(key)}.jpg"


def request_fields(key: str, candidate) -> dict:
    """The task ``data`` fields that describe one request."""
    return {"request": candidate.description, "request_kind": candidate.kind, "request_measure": candidate.measure,
            "request_object": candidate.object, "request_target": candidate.target_id,
            "request_line_px": None if candidate.line is None else [[round(float(u), 2), round(float(v), 2)]
                                                                   for u, v in candidate.line],
            "request_key": key, "request_candidate": candidate.key}


def _segment_results(rid: str, candidate, width: int, height: int, lines: str) -> list[dict]:
    """The segment to measure, as Label Studio results (keypoints + relation, or a vector)."""
    common = {"to_name": IMAGE, "original_width": width, "original_height": height, "image_rotation": 0}
    xy = lambda p: {"x": 100.0 * p[0] / width, "y": 100.0 * p[1] / height}  # noqa: E731
    if lines == "keypoints":
        out = [{"id": f"{rid}_{tag}", "type": "keypointlabels", "from_name": POINTS, **common,
                "value": {**xy(p), "width": _POINT_SIZE, "keypointlabels": [label]}}
               for tag, label, p in (("s", REF_START, candidate.line[0]), ("e", REF_END, candidate.line[1]))]
        out.append({"type": "relation", "from_id": f"{rid}_s", "to_id": f"{rid}_e", "direction": "right", "labels": []})
        rid = f"{rid}_s"
    else:
        verts = [{"id": f"{rid}_v{i}", **xy(p), "prevPointId": None if i == 0 else f"{rid}_v0", "isBezier": False}
                 for i, p in enumerate(candidate.line)]
        out = [{"id": rid, "type": "vectorlabels", "from_name": LINES, **common,
                "value": {"vertices": verts, "closed": False, "vectorlabels": [REFERENCE]}}]
    for name, typ, value in (("measure", "choices", candidate.measure), ("object", "textarea", candidate.object),
                             ("target", "textarea", candidate.target_id)):
        if value:
            out.append({"id": rid, "type": typ, "from_name": name, "to_name": IMAGE,
                        "value": {CONTROL_VALUE[typ]: [value]}})
    return out


def _object_results(rid: str, scene, candidate, lines: str) -> list[dict]:
    """The request's target (and, for a distance between two targets, the other) as Label Studio
    results: its dimension lines, each corner the median over its sets (module docstring)."""
    others = [candidate.term.other] if candidate.term is not None and candidate.term.kind == "distance" else []
    out = []
    for k, i in enumerate([candidate.target, *others]):
        t = scene.targets[i]
        if not t.dimension_lines:
            continue
        corners = np.median([d.corners for d in t.dimension_lines], axis=0)
        out += _target_results(f"{rid}_{k}", {"corners": corners.tolist(), "target": t.id},
                               scene.image_width, scene.image_height, lines)
    return out


def _without_truth(d: dict) -> dict:
    """A scene dict without its ground truth: a task's data is shown in the labelling tool."""
    d = {k: v for k, v in d.items() if k != "ground_truth"}
    d["targets"] = [{k: v for k, v in t.items() if k != "ground_truth"} for t in d["targets"]]
    return d


def label_studio_requests(requests, *, lines: str = "keypoints", start_id: int = 1,
                          image_url_prefix: str | None = None) -> list[dict]:
    """Label Studio tasks for ``requests``, a list of (key, scene, candidate) (module docstring).

    A task's ``image`` is ``image_url_prefix`` followed by the image's file name
    (:func:`image_name`), the URL the labelling tool loads it from (e.g. ``/data/local-files/?d=frames/``
    for Label Studio's local files); without a prefix, the scene's image path. The scene in a task
    (its data and ``creference_scene``) leaves out any ground truth: workers could see it."""
    tasks = []
    for k, (key, scene, cand) in enumerate(requests):
        task_id = start_id + k
        d = _without_truth(scene_to_dict(scene))
        url = None if image_url_prefix is None else f"{image_url_prefix}{image_name(scene, key)}"
        task = {"id": task_id, "data": {**task_data(d, url), **request_fields(key, cand), "creference_scene": d}}
        if cand.kind == "reference" and cand.line is not None:
            result = _segment_results(f"request{task_id}", cand, scene.image_width, scene.image_height, lines)
        else:
            result = _object_results(f"request{task_id}", scene, cand, lines) if cand.target is not None else []
        if result:
            task["predictions"] = [{"model_version": "creference-advice", "result": result}]
        tasks.append(task)
    return tasks


def cvat_requests(requests) -> str:
    """CVAT for images 1.1 XML for ``requests``, a list of (key, scene, candidate) (module docstring):
    one image per scene, with every request on it."""
    scenes = {}
    for key, scene, _ in requests:  # a reference without a segment (an answered length) has no CVAT shape
        scenes.setdefault(key, dataclasses.replace(scene, references=tuple(r for r in scene.references
                                                                            if r.line is not None)))
    names = {key: image_name(scene, key) for key, scene in scenes.items()}
    root = ET.fromstring(cvat_xml(list(scenes.values()), image_names=list(names.values())).split("\n", 1)[1])
    images = {img.get("name"): img for img in root.findall("image")}
    for key, scene, cand in requests:
        if cand.kind != "reference" or cand.line is None:
            continue
        values = {"target_id": cand.target_id or scene.targets[0].id, "object": cand.object, "measure": cand.measure,
                  "worker": REQUEST_WORKER}
        el = ET.SubElement(images[names[key]], "polyline", {
            "label": "reference", "source": "manual", "occluded": "0", "z_order": "0",
            "points": ";".join(f"{u:.2f},{v:.2f}" for u, v in cand.line)})
        for attr in LABEL_ATTRIBUTES["reference"]:
            value = values.get(attr)
            ET.SubElement(el, "attribute", {"name": attr}).text = (
                value if value is not None else ("__undefined__" if attr in ("measure", "mode", "unit") else ""))
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
