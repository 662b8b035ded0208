"""Label Studio ↔ scene files: the shipped labelling configs and the JSON export → one scene per
task (docs/import.md is the user's guide); scenes → tasks is in :mod:`.labelstudio_export`, one
annotation's results → items in :mod:`.labelstudio_results`, a frame task in
:mod:`.labelstudio_frames`.

A one-target task gives a ``creference-scene/1`` scene: its ``data`` gives the image and the
target's id and size, and each of its annotations is one worker's work on that target (a set of
dimension lines, reference lines with their measurements, optionally the horizon). A task that
holds several targets (``data.targets``, or regions that name their target) gives one
``creference-scene/2`` frame.

Results are matched by their control (``from_name``) and label: keypoints from ``points`` with
the labels :data:`TARGET_LABELS`, ``reference start`` / ``reference end`` (paired by a relation)
and ``horizon``; or, with the vector config, two-point vectors from ``lines`` labelled
``reference`` / ``horizon``. A reference's measurement is in per-region controls (same result id
as the region) named as :data:`~.annotation_tools.REFERENCE_FIELDS`. Coordinates are percent of
``original_width`` / ``original_height`` (or of the task's ``image_width`` / ``image_height``).
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any

from .annotation_tools import (ConversionError, ImportReport, TargetScene, TargetTable, _short,
                               checked_scene, image_file, number_field, read_input, reference_from_fields,
                               set_camera_and_horizon, safe_name, unique_names)
from .labelstudio_export import label_studio_task, label_studio_tasks
from .labelstudio_frames import FramePart, frame_scene, frame_task_part, url_path
from .labelstudio_results import TARGET_LABELS, annotation_items, annotation_result
from .scene import SCENE_FORMAT

__all__ = ["TARGET_LABELS", "LINE_TOOLS", "FRAME_TOOLS", "DATA_FIELDS", "FRAME_DATA_FIELDS", "label_studio_config",
           "read_export", "loads_export", "read_users", "scenes_from_label_studio", "label_studio_task",
           "label_studio_tasks"]

#: The shipped configs, by how reference lines and the horizon are drawn.
LINE_TOOLS = {"keypoints": "label_studio_keypoints.xml", "vectors": "label_studio_vectors.xml"}
#: The shipped frame configs (every target of a photo in one task), likewise.
FRAME_TOOLS = {"keypoints": "label_studio_frame_keypoints.xml", "vectors": "label_studio_frame_vectors.xml"}
#: Task ``data`` fields read by the importer (``image`` is the one the config displays).
DATA_FIELDS = ("image", "target_id", "target_length_m", "target_width_m", "target_height_m",
               "image_width", "image_height", "image_path", "focal_length_px", "principal_point",
               "horizon", "ground_truth")
#: Task ``data`` fields of a frame task (:mod:`.labelstudio_frames`).
FRAME_DATA_FIELDS = ("image", "targets", "frame_id", "image_width", "image_height", "image_path",
                     "focal_length_px", "principal_point", "kitti_p2", "horizon", "horizon_sd_px", "classes",
                     "ground_truth")
_DIMS = ("target_length_m", "target_width_m", "target_height_m")


def label_studio_config(lines: str = "keypoints", frame: bool = False) -> str:
    """The shipped labelling config (XML text); ``lines`` is ``"keypoints"`` or ``"vectors"``;
    ``frame`` gives the config for frames (one task per photo, holding all its targets)."""
    tools = FRAME_TOOLS if frame else LINE_TOOLS
    if lines not in tools:
        raise ValueError(f"lines: expected one of {list(tools)}, got {lines!r}")
    return (resources.files("creference_bayes") / "data" / tools[lines]).read_text("utf-8")


def read_export(path: str | Path) -> Any:
    """Decode a Label Studio JSON export file (raises :class:`ConversionError` naming the file)."""
    return loads_export(read_input(path), str(path))


def loads_export(text: bytes | str, name: str = "(export)") -> Any:
    """Decode the text of a Label Studio JSON export (raises :class:`ConversionError` naming
    ``name``): an integer beyond any float is read as infinite (and refused where a number is
    read), a document nested too deeply is refused."""
    try:
        if isinstance(text, bytes):
            text = text.decode("utf-8-sig")
        return json.loads(text, parse_int=_json_int)
    except UnicodeDecodeError:
        raise ConversionError(name, "not UTF-8 text (expected Label Studio's JSON export)") from None
    except json.JSONDecodeError as exc:
        raise ConversionError(name, f"not valid JSON: {exc.msg} at line {exc.lineno} "
                                    f"column {exc.colno}") from None
    except RecursionError:
        raise ConversionError(name, "JSON nested too deeply") from None


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
                             out_dir: str | Path | None = None, targets: dict | None = None,
                             users: dict[str, str] | None = None, frames: bool = False,
                             classes: dict | None = None) -> ImportReport:
    """Convert a Label Studio JSON export (the decoded list of tasks) to one scene per task: a
    ``creference-scene/1`` scene for a one-target task, a ``creference-scene/2`` frame for a task
    that holds several targets (:mod:`.labelstudio_frames`).

    Parameters
    ----------
    tasks : list
        The export: tasks with ``data`` and ``annotations`` (``completions`` before 1.0).
    image_dir : path, optional
        Where the images are: ``image.path`` is the file of the task's ``image`` URL in this folder
        (:func:`~.annotation_tools.image_file`; unless the task gives ``image_path``).
    out_dir : path, optional
        The folder the scenes will be written to; image paths are made relative to it.
    targets : TargetTable, optional
        Known sizes and focal lengths by image and target
        (:func:`~.annotation_tools.load_target_table`).
    users : dict, optional
        Worker names by user id (:func:`read_users`); otherwise a worker is named by the user id
        in ``completed_by`` (or the e-mail, when the export expands the user).
    frames : bool
        Import every task as a frame, one-target tasks too. The tasks imported as frames are
        grouped by image (``data.image``): one frame per image, holding the targets of all its tasks.
    classes : dict, optional
        Size priors of classes of your own (name → :class:`~..models.size_priors.SizePrior`),
        written into the frames whose size-less targets use them.

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
    table = TargetTable.of(targets)
    found, frame_parts, errors, notes = [], {}, [], []
    for i, task in enumerate(tasks):
        try:
            converted = _task_scene(task, i, image_dir, out_dir, table, users or {}, notes, frames)
        except ConversionError as exc:
            errors.append(exc)
            continue
        if isinstance(converted, FramePart):  # the frame of its image, made once all tasks are read
            image = converted.data.get("image")
            key = image if isinstance(image, str) and image else i
            if key not in frame_parts:
                found.append(key)
            frame_parts.setdefault(key, []).append(converted)
        elif converted is not None:
            found.append(converted)

    def locate(data, where):  # a frame's image.path and the image's names for the table
        return _image_path(data, image_dir, out_dir, where, notes), _image_names(data)

    scenes = []
    for item in found:
        if isinstance(item, TargetScene):
            scenes.append(item)
            continue
        try:
            scenes.append(frame_scene(frame_parts[item], locate, table, classes, notes))
        except ConversionError as exc:
            errors.append(exc)
    kept, clashes = unique_names(scenes)
    notes += table.notes()
    return ImportReport(tuple(kept), tuple(errors + clashes), tuple(notes))


def _task_name(task: Any, index: int) -> str:
    tid = task.get("id") if isinstance(task, dict) else None
    if isinstance(tid, (int, str)) and not isinstance(tid, bool):
        return f"task {tid}"
    return f"task at index {index}"


def _task_scene(task, index, image_dir, out_dir, table, users, notes,
                frames=False) -> TargetScene | FramePart | None:
    """A one-target task's scene, what a frame task gives its image's frame, or None (no annotations)."""
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
    items_list = [annotation_items(ann, k, width, height, where, users, notes) for k, ann in enumerate(anns)]
    if data.get("creference_scene") is None and (frames or "targets" in data or any(i.frame for i in items_list)):
        return frame_task_part(task, index, data, items_list, (width, height), where, notes)

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
    size = table.size(_image_names(data), tid, dims, where, required=True)

    lines, refs, horizons, origins = [], [], [], {}
    for items in items_list:
        n = (items.corners is not None) + len(items.references)
        secs = items.lead_time / n if items.lead_time is not None and n else None
        if items.corners is not None:
            origins[f"target.dimension_lines[{len(lines)}]"] = items.name
            line = {"corners": items.corners}
            line.update({k2: v for k2, v in (("worker", items.worker), ("seconds", secs)) if v is not None})
            lines.append(line)
        for rid, fields_, seg in items.references:
            origins[f"references[{len(refs)}]"] = f"{items.name}, region {rid!r}"
            refs.append(reference_from_fields(fields_, seg, f"{where}, {items.name}, region {rid!r}",
                                              worker=items.worker, seconds=secs))
        horizons.extend(items.horizons)
    if data.get("creference_scene") is not None:  # a request task of creference advise
        return _answered_request(data, lines, refs, origins, image_dir, out_dir, where, notes)
    if not lines:
        raise ConversionError(where, "no annotation draws the target's dimension lines "
                                     f"({', '.join(repr(x) for x in TARGET_LABELS)})")

    scene: dict[str, Any] = {"format": SCENE_FORMAT, "image": {"width": width, "height": height}}
    image_path = _image_path(data, image_dir, out_dir, where, notes)
    if image_path is not None:
        scene["image"]["path"] = image_path
    camera = {}
    focal = data.get("focal_length_px")
    table_focal = table.focal(_image_names(data), [tid], where)
    if focal not in (None, ""):
        camera["focal_length_px"] = number_field(focal, where, "data.focal_length_px", positive=True)
    elif table_focal is not None:
        camera["focal_length_px"] = table_focal
    if data.get("principal_point") is not None:
        camera["principal_point"] = data["principal_point"]
    set_camera_and_horizon(scene, camera, data, horizons, width, where, notes)
    scene["target"] = {"id": tid, "dimensions_m": size, "dimension_lines": lines}
    if refs:
        scene["references"] = refs
    if data.get("ground_truth") is not None:
        scene["ground_truth"] = data["ground_truth"]
    origins.update({"camera": "data.focal_length_px / data.principal_point",
                    "horizon": "the horizon (data.horizon or annotated)",
                    "ground_truth": "data.ground_truth"})
    return TargetScene(safe_name(tid), checked_scene(scene, where, origins), where)


def _answered_request(data, lines, refs, origins, image_dir, out_dir, where, notes) -> TargetScene:
    """A request task (``creference advise``, docs/advice.md) carries the scene it was made for
    in ``data.creference_scene``: its answers are appended to that scene's dimension lines and
    references, so the task imports as the scene with the new annotations."""
    import copy

    base = data["creference_scene"]
    if not isinstance(base, dict) or not isinstance(base.get("target"), dict):
        raise ConversionError(where, "data.creference_scene is not a creference-scene/1 scene")
    for key, value in (("target.dimension_lines", base["target"].get("dimension_lines")),
                       ("references", base.get("references"))):
        if value is not None and not isinstance(value, list):
            raise ConversionError(where, f"data.creference_scene.{key} is not a list: {_short(value)}")
    scene = copy.deepcopy(base)
    target = scene["target"]
    old_lines, old_refs = list(target.get("dimension_lines") or []), list(scene.get("references") or [])
    shift = {"target.dimension_lines": len(old_lines), "references": len(old_refs)}
    moved = {}
    for key, name in origins.items():  # the answers' key paths move behind the scene's own items
        head, _, index = key.rpartition("[")
        moved[f"{head}[{int(index[:-1]) + shift[head]}]"] = name
    target["dimension_lines"] = old_lines + lines
    if old_refs or refs:
        scene["references"] = old_refs + refs
    image_path = _image_path(data, image_dir, out_dir, where, notes)
    if image_path is not None:
        scene.setdefault("image", {})["path"] = image_path
    return TargetScene(safe_name(str(target.get("id", "target"))), checked_scene(scene, where, moved), where)


def _whole(value: Any, where: str, what: str) -> int:
    x = number_field(value, where, what, positive=True)
    if x != int(x):
        raise ConversionError(where, f"{what} must be whole pixels, got {x:g}")
    return int(x)


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
