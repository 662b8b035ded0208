"""Answers to the advice's requests, put into a scene: one more set of dimension lines, a target's
size from a catalogue, the camera's mounting from its calibration (docs/requests.md).

Lines and references on a segment come back through the importers (a Label Studio or CVAT
export, imported again, gives the scenes with the new annotations). What is not drawn is written
in ``requests.csv``'s ``answer`` column and put into the scene files by :func:`apply_answers`
(``creference advise BATCH_DIR --apply requests.csv``): a target's own length, or the distance
between two targets, as a reference without a segment (:func:`with_measurement`); a size or a
mounting as a prior the estimate then uses:

- a size: the target's own ``size_prior`` (docs/scene_format.md), the product of the size prior
  it had (its class's) and the catalogue's size with spread :data:`CATALOGUE_LOG_SD`;
- a mounting: the camera's ``orientation_prior``, the product of the one it had and the
  calibration's height, pitch and roll with spreads :data:`MOUNTING_SD`.

An answer replaces an earlier answer of its kind instead of multiplying into it (a second
catalogue size of the same car, or the same ``requests.csv`` applied twice, is the same fact, not
new evidence): a size is multiplied into the class's prior, a mounting into the scene's prior
from before any calibration (the default one). An answer far outside what the prior allows (a
size in millimetres, a height in centimetres) is refused, naming the unit expected.

The advice weighs a request by the same product (:mod:`.observe`), so what it predicts is what the
estimate will do with the answer.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

import numpy as np

from ...models.camera_terms import DEFAULT_ORIENTATION_PRIOR, OrientationPrior
from ...models.size_priors import SizePrior

__all__ = ["CATALOGUE_LOG_SD", "CATALOGUE_CLASSES", "catalogue_lists", "SIZE_SECONDS", "MOUNTING_SD", "MOUNTING_SECONDS", "MAX_SIZE_SD",
           "MOUNTING_HEIGHT_RANGE_M", "MAX_MOUNTING_ANGLE_DEG", "ANSWER_FORMS", "with_dimension_lines", "with_size",
           "with_mounting", "with_measurement", "apply_answers", "SAME_POINT_PX", "merge_annotations"]

#: A size from a catalogue (a worker names the make and model): the spread of its log-length,
#: -width and -height. Our assumption: one model name covers trims and years a few percent apart.
CATALOGUE_LOG_SD = 0.03
#: The shipped classes (KITTI's, ``creference_bayes/data/cvat_labels.json``) whose objects a
#: catalogue lists by make and model: the vehicles. A Pedestrian, Person_sitting, Cyclist (the
#: rider's box is not the bicycle's) or Misc object is asked no size; a class a scene defines
#: itself is (the package cannot tell what a catalogue lists for it).
CATALOGUE_CLASSES = ("Car", "Van", "Truck", "Tram")
#: Human seconds for a size from a catalogue: the paper has no such task; its nearest is the
#: reference task (one worker, one object, one statement), 64.4 s on average (§7.2.2).
SIZE_SECONDS = 64.4
#: A mounting from the rig's calibration: the spread of log height, pitch and roll (radians) it
#: leaves per frame. A vehicle's camera keeps its height to about 2 % and its pitch and roll to
#: about 0.5° from frame to frame (the spreads examples/kitti_study.py's ``--camera known`` uses).
MOUNTING_SD = {"log_height": 0.02, "pitch": math.radians(0.5), "roll": math.radians(0.5)}
#: Human seconds for a camera's mounting: an engineer reading the rig's calibration, once per
#: camera. Our assumption (15 minutes); every frame of that camera shares the answer.
MOUNTING_SECONDS = 900.0
#: A catalogue size this many of its class prior's standard deviations (in log-size) from the
#: prior's median is refused (a size in millimetres or centimetres, or another object's).
MAX_SIZE_SD = 8.0
#: The camera heights (metres) and the largest pitch and roll (degrees) a mounting answer may state.
MOUNTING_HEIGHT_RANGE_M = (0.1, 30.0)
MAX_MOUNTING_ANGLE_DEG = 60.0


def catalogue_lists(cls: str | None) -> bool:
    """Whether a size from a catalogue can be asked for an object of class ``cls``
    (:data:`CATALOGUE_CLASSES`; classes match as the size priors do, whatever their case)."""
    from ...models.size_priors import KITTI_SIZE_PRIORS

    shipped = {c.casefold() for c in KITTI_SIZE_PRIORS}
    return cls is None or cls.casefold() not in shipped or cls.casefold() in {c.casefold() for c in CATALOGUE_CLASSES}


def _target(scene, target_id: str) -> int:
    ids = [t.id for t in scene.targets]
    if target_id not in ids:
        raise ValueError(f"target: no target {target_id!r} in the scene (targets: {ids})")
    return ids.index(target_id)


def _product(mean0, sd0, mean1, sd1):
    """The product of two normal densities: its mean and sd."""
    w0, w1 = 1.0 / np.square(sd0), 1.0 / np.square(sd1)
    return (w0 * mean0 + w1 * mean1) / (w0 + w1), 1.0 / np.sqrt(w0 + w1)


def with_dimension_lines(scene, target_id: str, corners, *, worker: str | None = None, seconds: float | None = None):
    """``scene`` with one more set of dimension lines on ``target_id``: ``corners`` (4, 2) pixels,
    the corner and the far ends of the length, width and height lines (docs/scene_format.md)."""
    from ...io.scene import DimensionLine

    i = _target(scene, target_id)
    corners = np.asarray(corners, float)
    if corners.shape != (4, 2) or not np.all(np.isfinite(corners)):
        raise ValueError(f"corners: expected (4, 2) finite pixels, got {corners.tolist()!r}")
    t = scene.targets[i]
    t = dataclasses.replace(t, dimension_lines=(*t.dimension_lines, DimensionLine(corners, worker, seconds)))
    return dataclasses.replace(scene, targets=scene.targets[:i] + (t,) + scene.targets[i + 1:])


def with_size(scene, target_id: str, size_m, *, log_sd: float = CATALOGUE_LOG_SD, classes=None):
    """``scene`` with a size of ``target_id`` from a catalogue: ``size_m`` (length, width, height)
    metres, known to ``log_sd`` in log-size. Its size prior becomes the product of the one it had
    (its own, else its class's: the scene's classes, ``classes``, the shipped ones) and this."""
    i = _target(scene, target_id)
    t = scene.targets[i]
    size = np.asarray(size_m, float)
    if size.shape != (3,) or not np.all(np.isfinite(size) & (size > 0)):
        raise ValueError(f"size_m: expected (length, width, height) > 0 metres, got {np.ravel(size_m).tolist()!r}")
    if not (math.isfinite(log_sd) and log_sd > 0):
        raise ValueError(f"log_sd: expected a number > 0, got {log_sd!r}")
    if t.dimensions is not None:
        raise ValueError(f"target {target_id!r}: its size is known already (dimensions_m)")
    # an earlier catalogue answer is replaced, not multiplied into (the same fact twice)
    prior = (t.size_prior if t.size_prior is not None and t.size_prior.source != "catalogue"
             else scene.size_prior(t.cls, classes))
    if prior is not None:
        z = np.abs(np.log(size) - np.log(prior.median_m)) / np.asarray(prior.log_sd)
        if np.max(z) > MAX_SIZE_SD:
            expected = ", ".join(f"{v:.2g}" for v in prior.median_m)
            raise ValueError(f"target {target_id!r}: size {np.ravel(size_m).tolist()} m is {np.max(z):.0f} "
                             f"standard deviations from its prior (median {expected} m): metres expected, "
                             "and the size of this object")
    mean, sd = np.log(size), np.full(3, float(log_sd))
    if prior is not None:
        mean, sd = _product(np.log(prior.median_m), np.asarray(prior.log_sd), mean, sd)
    t = dataclasses.replace(t, size_prior=SizePrior(tuple(np.exp(mean)), tuple(sd), source="catalogue"))
    return dataclasses.replace(scene, targets=scene.targets[:i] + (t,) + scene.targets[i + 1:])


def with_mounting(scene, height_m: float, pitch_rad: float, roll_rad: float = 0.0, *, sd: dict | None = None):
    """``scene`` with its camera's mounting from a calibration: height above the ground (metres),
    pitch (radians, > 0 looks down) and roll, with spreads ``sd`` (default :data:`MOUNTING_SD`).
    Its orientation prior becomes the product of the one it had (else the default) and this."""
    sd = {**MOUNTING_SD, **(sd or {})}
    for key, v in (("height_m", height_m), ("pitch_rad", pitch_rad), ("roll_rad", roll_rad)):
        if not (isinstance(v, numbers.Real) and math.isfinite(v)) or (key == "height_m" and v <= 0):
            raise ValueError(f"{key}: expected a finite number{' > 0' if key == 'height_m' else ''}, got {v!r}")
    lo, hi = MOUNTING_HEIGHT_RANGE_M
    if not lo <= height_m <= hi:
        raise ValueError(f"height {height_m:g} m: expected metres, between {lo:g} and {hi:g}")
    for key, v in (("pitch", pitch_rad), ("roll", roll_rad)):
        if abs(math.degrees(v)) > MAX_MOUNTING_ANGLE_DEG:
            raise ValueError(f"{key} {math.degrees(v):g}°: expected degrees, at most {MAX_MOUNTING_ANGLE_DEG:g} "
                             "either way")
    p = scene.orientation_prior or DEFAULT_ORIENTATION_PRIOR
    if p.source == "calibration":  # an earlier calibration is replaced, not multiplied into
        p = DEFAULT_ORIENTATION_PRIOR
    calibration = OrientationPrior(pitch_mean=pitch_rad, pitch_sd=sd["pitch"], roll_mean=roll_rad, roll_sd=sd["roll"],
                                   height_median_m=height_m, height_log_sd=sd["log_height"])
    return dataclasses.replace(scene, orientation_prior=p.times(calibration, source="calibration"))


#: ``requests.csv``'s ``answer`` column, per kind: what to write there. A reference request without
#: a segment (a target's own length, the distance between two targets) is answered there too;
#: one on a segment comes back drawn, through an importer.
ANSWER_FORMS = {"size": "length,width,height in metres (the catalogue's)",
                "mounting": "height in metres,pitch in degrees,roll in degrees (the calibration's; pitch > 0 looks down)",
                "reference": "the length or distance in metres (a request without a segment)"}


def with_measurement(scene, measure: str, value_m: float, target_id: str, other_id: str | None = None,
                     *, worker: str | None = None):
    """``scene`` with a worker's measurement that needs no segment: ``target_id``'s own ``measure``
    (``length``, ``width`` or ``height``), or with ``other_id`` the ground distance between the two
    targets' bottom centres (``measure`` ``distance``), ``value_m`` metres (docs/scene_format.md,
    references that name targets). The same measurement already in the scene is not added again."""
    from ...io.scene import parse_scene, scene_to_dict

    ids = [t.id for t in scene.targets]
    for tid in (target_id, other_id):
        if tid is not None and tid not in ids:
            raise ValueError(f"target: no target {tid!r} in the scene (targets: {ids})")
    if not (isinstance(value_m, numbers.Real) and math.isfinite(value_m) and value_m > 0):
        raise ValueError(f"value: expected a length > 0 in metres, got {value_m!r}")
    ref = {"measure": measure, "mode": "direct", "value": float(value_m), "unit": "m"}
    ref.update({"targets": [target_id, other_id]} if other_id is not None else {"target": target_id})
    if worker:
        ref["worker"] = worker
    d = scene_to_dict(scene)
    same = {k: v for k, v in ref.items() if k != "worker"}
    if any({k: r.get(k) for k in same} == same for r in d.get("references") or []):
        return scene
    d["references"] = [*(d.get("references") or []), ref]
    return parse_scene(d, source=scene.source)


def _numbers(text: str, n: int, where: str) -> list[float]:
    parts = [p.strip() for p in str(text).replace(";", ",").split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: expected {n} numbers separated by commas, got {text!r}")
    return values


@dataclasses.dataclass(frozen=True)
class _SceneFile:
    """A user's scene file as read: its path, its decoded JSON document and its scene."""

    path: object
    doc: dict
    scene: object


def _user_scene(batch_dir, key: str, result_path) -> _SceneFile:
    """The scene file frame ``key``'s result (``result_path``) names as its ``batch.source``, read,
    once it is checked to be the scene the result was estimated from: the result's targets and
    image size, and its fingerprint (``scene_id.sha256``) or, when answers went in since (its
    fingerprint changed), the batch's copy of it with annotations added (:func:`_answered_since`).
    ValueError naming the result and the path otherwise."""
    from pathlib import Path

    from ...io.result import canonical_sha256, scene_mismatch
    from ...io.scene import parse_quietly, read_scene_json
    from ...io.validation import SceneError, read_json

    try:
        result = read_json(result_path)
    except SceneError as exc:  # not UTF-8 or not JSON: a write killed half-way, or not a result
        raise ValueError(f"{result_path}: not a result file ({exc.problem})") from None
    source = (result.get("batch") or {}).get("source") if isinstance(result, dict) else None
    if not isinstance(source, str) or not source:
        raise ValueError(f"{result_path}: no batch.source (the scene file it was estimated from): "
                         "not a result of creference batch")
    path = Path(source)
    doc = read_scene_json(path)
    scene = parse_quietly(doc, source=path)
    why = scene_mismatch(result, scene, canonical_sha256(doc))
    unhashed = {**result, "scene_id": {k: v for k, v in (result.get("scene_id") or {}).items() if k != "sha256"}}
    if why and not scene_mismatch(unhashed, scene) and _answered_since(batch_dir, key, result, scene):
        why = None
    if why:
        raise ValueError(f"{result_path}: its batch.source {path} is not the scene it was estimated from ({why}), "
                         "nor that scene with annotations added; nothing written")
    return _SceneFile(path, doc, scene)


def _has_line(lines: list, corners) -> bool:
    """Whether a set of dimension lines (scene dicts) like ``corners`` is among ``lines``: every
    corner within :data:`SAME_POINT_PX`."""
    corners = np.asarray(corners, float)
    return any(float(np.max(np.abs(corners - np.asarray(h["corners"], float)))) <= SAME_POINT_PX for h in lines)


def _answered_since(batch_dir, key: str, result: dict, scene) -> bool:
    """Whether ``scene`` is the batch's copy of frame ``key`` (``scenes/KEY.json``, the scene the
    result records by its fingerprint) with annotations added since: the same image file name and
    every dimension line and reference of the copy in it. (What the batch put into its copy, a
    pooled corner scale or a rig's priors, and the priors answers put in do not count.)"""
    from pathlib import PurePath

    from ...io.result import canonical_sha256
    from ...io.scene import SceneError, parse_quietly, read_scene_json, scene_to_dict
    from ..batch.files import layout

    try:
        data = read_scene_json(layout(batch_dir, key)["scene"])
        if canonical_sha256(data) != (result.get("scene_id") or {}).get("sha256"):
            return False
        was = scene_to_dict(parse_quietly(data))
    except (OSError, SceneError):
        return False
    now = scene_to_dict(scene)
    if PurePath(was["image"].get("path") or "").name != PurePath(now["image"].get("path") or "").name:
        return False
    lines = {t["id"]: t["dimension_lines"] for t in now["targets"]}
    return (all(t["id"] in lines and _has_line(lines[t["id"]], d["corners"])
                for t in was["targets"] for d in t["dimension_lines"])
            and all(any(_same_reference(r, q) for q in now.get("references") or [])
                    for r in was.get("references") or []))


def _edited(file: _SceneFile, new, what: str) -> dict:
    """``file``'s own document with what the scene ``new`` (its scene with answers put in) adds:
    the dimension lines and references appended, a target's ``size_prior`` and the camera's
    ``orientation_prior`` set; every other key, the format version and the key order as they were.
    ValueError naming the file when its format cannot hold the answers (``what``)."""
    import copy

    from ...io.scene import SceneError, parse_quietly, scene_fingerprint, scene_to_dict

    was, now = scene_to_dict(file.scene), scene_to_dict(new)
    doc = copy.deepcopy(file.doc)
    v1 = file.scene.format == "creference-scene/1"
    for t, a, b in zip([doc["target"]] if v1 else doc["targets"], was["targets"], now["targets"]):
        lines = b["dimension_lines"][len(a["dimension_lines"]):]
        if lines:
            t["dimension_lines"] = [*(t.get("dimension_lines") or []), *lines]
        if b.get("size_prior") != a.get("size_prior"):
            t["size_prior"] = b["size_prior"]
    if now["camera"].get("orientation_prior") != was["camera"].get("orientation_prior"):
        doc.setdefault("camera", {})["orientation_prior"] = now["camera"]["orientation_prior"]
    refs = (now.get("references") or [])[len(was.get("references") or []):]
    if refs:
        doc["references"] = [*(doc.get("references") or []), *refs]
    try:
        same = scene_fingerprint(parse_quietly(doc, source=file.path)) == scene_fingerprint(new)
    except SceneError:
        same = False
    if not same:
        raise ValueError(f"{file.path}: a {file.scene.format} file cannot hold {what}: make it a creference-scene/2 "
                         "file (docs/scene_format.md) and run creference batch on it; nothing written")
    return doc


def _write(files: dict, scenes: dict, what: dict) -> None:
    """Write every scene file (``files``: path → :class:`_SceneFile`) whose scene in ``scenes``
    (path → scene with the answers) differs from the one read, as one set: each one's document
    prepared and checked (:func:`_edited`; ``what`` path → what went in) before any is written,
    then all written (:func:`~creference_bayes.io.files.atomic_write_set`: all or none, each
    keeping its mode)."""
    import json

    from ...io.files import atomic_write_set
    from ...io.scene import scene_fingerprint

    texts = {}
    for path, file in files.items():
        if scene_fingerprint(scenes[path]) != scene_fingerprint(file.scene):
            doc = _edited(file, scenes[path], "; ".join(what.get(path, [])))
            texts[path] = (json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode("utf-8")
    atomic_write_set(texts)


def apply_answers(batch_dir, rows, notes: list | None = None, *, write: bool = True) -> list[tuple[str, str, bool]]:
    """Put the answered size, mounting and segment-less measurement requests of ``rows``
    (``requests.csv``'s rows, dicts; a row is answered when its ``answer`` is filled in,
    :data:`ANSWER_FORMS`) into the user's scene files the batch ``batch_dir`` was made from (each
    result's ``batch.source``, checked to be the result's scene: :func:`_user_scene`). A mounting
    with a ``camera`` goes to every frame of that camera. Each file keeps its other keys, format
    version and mode; the files that change are written as one set, all or none (:func:`_write`),
    and a file no answer changes is not written. Returns (scene file, what was put in, whether it
    changed the file: False when the file held it already, the row it answers) per answer and file
    (a camera's mounting: one per frame of the camera); an answered row of a request
    that is drawn (lines, a reference on a segment: they come back through an importer) is said in
    ``notes``. ``creference batch`` then re-estimates the frames whose scenes changed. Raises
    ValueError naming the row and the value on a bad answer, the file on an answer its format
    cannot hold; nothing is written then. ``write=False``: the same checks and return, nothing
    written (which answers are not in the scene files yet)."""
    from ...io.scene import scene_fingerprint
    from ..batch.files import result_paths

    results = result_paths(batch_dir, check=True)
    read, files, scenes, done = {}, {}, {}, []

    def scene_of(key, where):
        if key not in results:
            raise ValueError(f"{where}: key {key!r} is not a result of {batch_dir}")
        if key not in read:
            file = read[key] = _user_scene(batch_dir, key, results[key])
            files.setdefault(file.path, file)
            scenes.setdefault(file.path, file.scene)
        return read[key].path

    def put(source, where, what, change, *args, **kwargs):
        before = scenes[source]
        try:
            scenes[source] = change(before, *args, **kwargs)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        done.append((source, what, scene_fingerprint(scenes[source]) != scene_fingerprint(before), where))

    for n, row in enumerate(rows, start=1):
        kind, answer = row.get("kind"), (row.get("answer") or "").strip()
        where = f"requests row {row.get('rank', n)} ({kind})"
        if not answer:
            continue
        if kind not in ANSWER_FORMS or (kind == "reference" and row.get("line_px")):
            if notes is not None:
                notes.append(f"{where}: answered, but only sizes, mountings and measurements without a segment are "
                             "put in from requests.csv; drawn lines and segments come back as annotations (a Label "
                             "Studio or CVAT export, imported)")
            continue
        if kind == "reference":
            source = scene_of(row.get("key"), where)
            value = _numbers(answer, 1, where)[0]
            measure, other = row.get("measure"), row.get("object") if row.get("measure") == "distance" else None
            what = f"distance {row.get('target')}–{other}" if other else f"{row.get('target')}: {measure}"
            put(source, where, f"{what} {value:g} m", with_measurement, measure, value, row.get("target"), other,
                worker=row.get("worker") or None)
            continue
        if kind == "size":
            source = scene_of(row.get("key"), where)
            size = _numbers(answer, 3, where)
            put(source, where, f"{row.get('target')}: size {size} m", with_size, row.get("target"), size)
            continue
        height, pitch, roll = _numbers(answer, 3, where)
        if row.get("camera"):
            keys = [key for key in results if scenes[scene_of(key, where)].camera_id == row["camera"]]
            if not keys:
                raise ValueError(f"{where}: no frame of camera {row['camera']!r} in {batch_dir}")
        else:
            keys = [row.get("key")]
        for key in keys:
            put(scene_of(key, where), where, f"mounting {height:g} m, pitch {pitch:g}°, roll {roll:g}°",
                with_mounting, height, math.radians(pitch), math.radians(roll))
    what = {}
    for source, text, _, _ in done:
        what.setdefault(source, []).append(text)
    if write:
        _write(files, scenes, what)
    return [(str(source), text, changed, row) for source, text, changed, row in done]


#: Two drawn points closer than this (pixels) are the same annotation (files round to 0.01 px).
SAME_POINT_PX = 0.05


def _same_reference(a: dict, b: dict) -> bool:
    """Whether two references of scene dicts are the same measurement (not who or when): the same
    measure, mode, unit, value or range and targets, and segments within :data:`SAME_POINT_PX`."""
    def key(ref):
        rng = ref.get("range")
        value = tuple(round(float(v), 6) for v in rng) if rng is not None else round(float(ref.get("value", 0.0)), 6)
        return (ref.get("measure"), ref.get("mode"), ref.get("unit"), value, ref.get("target"),
                tuple(ref.get("targets") or ()))

    la, lb = a.get("line"), b.get("line")
    if key(a) != key(b) or (la is None) != (lb is None):
        return False
    return la is None or float(np.max(np.abs(np.asarray(la, float) - np.asarray(lb, float)))) <= SAME_POINT_PX


def merge_annotations(batch_dir, scenes, notes: list | None = None) -> list[tuple[str, str, bool]]:
    """Put the annotations of ``scenes`` (imported scene files: a Label Studio or CVAT export of
    the advice's requests, through ``creference import``) that the user's scene files of the batch
    do not hold yet into those files (each result's ``batch.source``, checked to be the result's
    scene: :func:`_user_scene`). An imported scene is the frame whose full key its file name is
    (the key with characters other than letters, digits, ``.``, ``_`` and ``-`` as ``_``, as the
    Label Studio import names the answered requests of a frame), else the frame whose image file
    name it has (as CVAT names images: the scene's ``image.path``, else that file-safe key and
    ``.jpg``); a name or image two frames share is refused, naming their keys. Its targets' dimension lines and its
    references that the frame's scene lacks (the same within :data:`SAME_POINT_PX` and the same
    values) are appended, and nothing else of the user's file changes (its other keys, format
    version and mode, its truth, priors, the answers put in by :func:`apply_answers`). A scene
    that is no frame of the batch, or a target the frame does not have, is said in ``notes``.
    Returns (scene file, what was added, True, its number) per annotation added; the files changed are
    written as one set, all or none (:func:`_write`). ValueError naming the file otherwise, and
    nothing written."""
    from pathlib import Path, PurePath

    from ...io.annotation_tools import safe_name
    from ...io.scene import load_scene, parse_scene, scene_to_dict
    from ..batch.files import result_paths
    from .requests import image_name

    notes = notes if notes is not None else []
    read = {key: _user_scene(batch_dir, key, path) for key, path in result_paths(batch_dir, check=True).items()}
    by_name, by_image = {}, {}
    for key, file in read.items():
        by_name.setdefault(safe_name(key), []).append(key)
        by_image.setdefault(image_name(file.scene, key), []).append(key)
    changed, done = {}, []
    for path in scenes:
        path = Path(path)
        new = load_scene(path)
        keys = by_name.get(path.stem) or (by_image.get(PurePath(str(new.image_path)).name, [])
                                          if new.image_path is not None else [])
        if not keys:
            notes.append(f"{path}: no frame of {batch_dir} has this name or image; skipped")
            continue
        if len(keys) > 1:
            raise ValueError(f"{path}: its name or image is that of frames {', '.join(map(repr, keys))} of "
                             f"{batch_dir}; which one it answers is not known; nothing written")
        key = keys[0]
        d = changed.get(key) or scene_to_dict(read[key].scene)
        mine = {t["id"]: t for t in d["targets"]}
        added = []
        for t in scene_to_dict(new)["targets"]:
            if t["id"] not in mine:
                notes.append(f"{path}: target {t['id']!r} is not in frame {key!r}; left out")
                continue
            for line in t["dimension_lines"]:
                if not _has_line(mine[t["id"]]["dimension_lines"], line["corners"]):
                    mine[t["id"]]["dimension_lines"].append(line)
                    added.append(f"{t['id']}: a set of dimension lines")
        for ref in scene_to_dict(new).get("references") or []:
            if not any(_same_reference(ref, r) for r in d.get("references") or []):
                d["references"] = [*(d.get("references") or []), ref]
                added.append(f"a reference ({ref.get('measure')})")
        if added:
            changed[key] = d
            done += [(read[key].path, what) for what in added]
    files = {read[key].path: read[key] for key in changed}
    merged = {read[key].path: parse_scene(d, source=read[key].path) for key, d in changed.items()}
    what = {}
    for source, text in done:
        what.setdefault(source, []).append(text)
    _write(files, merged, what)
    return [(str(source), text, True, k) for k, (source, text) in enumerate(done)]
