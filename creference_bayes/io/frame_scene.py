"""``creference-scene/2``: a frame, every target of one photo (docs/scene_format.md).

A frame scene has the ``image``, ``camera``, ``horizon`` and ``horizon_sd_px`` of a
``creference-scene/1`` scene, and instead of one ``target``:

* ``targets``: a list; each has an ``id`` (unique), a ``class``, its ``dimension_lines`` and,
  optionally, its known ``dimensions_m`` (without them, the class's size prior applies) and its
  ``ground_truth`` (``location_m``, ``yaw_rad``, ``dimensions_m``, ``handedness``);
* ``classes`` (optional): size priors for classes of the scene's own, or replacing the shipped
  KITTI classes (``{"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4, "log_sd": 0.1}}``);
* ``references``: as in version 1, plus ``target`` (the id of a target): a ``relative`` reference
  is a ratio to that target's length or width; a reference without a ``line`` is a worker's
  measurement of that target's own ``length``, ``width`` or ``height``; a reference with
  ``targets`` (two ids) and ``measure: "distance"`` is the distance on the ground between their
  bottom centres;
* ``ground_truth`` (optional): the camera's ``focal_length_px``, ``camera_height_m``,
  ``pitch_rad`` and ``roll_rad``.

A ``creference-scene/1`` file loads as a one-target frame (:func:`frame_from_scene`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..models.size_priors import KITTI_SIZE_PRIORS, SizePrior, size_priors_from_dict
from .scene import (DimensionLine, Reference, Scene, _parse_dimension_line, _parse_reference, camera_priors_to_dict,
                    parse_header, parse_scene, read_scene_json)
from .validation import SceneError, SceneWarning, check_scene_format, _dict, _get, _join, _list, _number, _short, _string, _warn_unknown

__all__ = ["FRAME_FORMAT", "FrameTarget", "FrameScene", "parse_frame", "load_frame", "frame_from_scene",
           "frame_to_dict", "frame_fingerprint", "find_size_prior"]

FRAME_FORMAT = "creference-scene/2"
_TOP_KEYS = {"format", "image", "camera", "horizon", "horizon_sd_px", "classes", "targets", "references",
             "ground_truth"}
_SIZE_NAMES = ("length", "width", "height")


@dataclass(frozen=True)
class FrameTarget:
    """One target of a frame: its id, class, annotations, known sizes (m) or None, truth or None."""

    id: str
    cls: str | None
    dimension_lines: tuple[DimensionLine, ...]
    dimensions: tuple[float, float, float] | None = None
    ground_truth: dict | None = None

    @property
    def corners(self) -> np.ndarray:
        """(K, 4, 2) every annotation's corners, pixels."""
        return np.stack([d.corners for d in self.dimension_lines])


@dataclass(frozen=True)
class FrameScene:
    """A validated frame (module docstring). Field names shared with :class:`~.scene.Scene` mean
    the same thing, so the camera set-up reads either."""

    image_width: int
    image_height: int
    principal_point: np.ndarray
    targets: tuple[FrameTarget, ...]
    references: tuple[Reference, ...] = ()
    #: For each reference, the index of the target it names, or None; a pair of indices for a
    #: distance between two targets.
    reference_targets: tuple[int | tuple[int, int] | None, ...] = ()
    classes: dict[str, SizePrior] = field(default_factory=dict)
    focal_length_px: float | None = None
    horizon: np.ndarray | None = None
    horizon_sd_px: float = 0.0
    focal_prior: Any = None
    orientation_prior: Any = None
    ground_truth: dict | None = None
    image_path: Path | None = None
    source: Path | None = None
    warnings: tuple[str, ...] = ()
    format: str = FRAME_FORMAT
    #: KITTI's P2 (3, 4) when the frame came from a KITTI folder: labels go back into its frame.
    kitti_p2: np.ndarray | None = None
    #: The KITTI calib file's other lines (name → numbers), written back beside the labels.
    kitti_calib: dict | None = None

    @property
    def image_size(self) -> tuple[int, int]:
        return self.image_width, self.image_height

    def size_prior(self, cls: str | None, extra: dict[str, SizePrior] | None = None) -> SizePrior | None:
        """The size prior of a class: the scene's own classes, then ``extra`` (a file given on the
        command line), then the shipped KITTI classes. Class names match whatever their case
        (``car`` is KITTI's ``Car``, as KITTI's evaluation reads them)."""
        return find_size_prior(cls, self.classes, extra)


def find_size_prior(cls: str | None, *tables: dict[str, SizePrior] | None) -> SizePrior | None:
    """The size prior of class ``cls`` from the first of ``tables`` (then the shipped KITTI
    classes) that has it: an exact name first, else one that differs only in case."""
    if cls is None:
        return None
    tables = [t for t in tables if t] + [KITTI_SIZE_PRIORS]
    for table in tables:
        if cls in table:
            return table[cls]
    folded = cls.casefold()
    for table in tables:
        for name, prior in table.items():
            if name.casefold() == folded:
                return prior
    return None


def _parse_frame_target(obj: Any, path: str, w: int, h: int, sink: list[str]) -> FrameTarget:
    obj = _dict(obj, path)
    _warn_unknown(obj, {"id", "class", "dimensions_m", "dimension_lines", "ground_truth"}, path, sink)
    ident = _string(_get(obj, "id", path), _join(path, "id"), optional=False)
    cls = _string(obj.get("class"), _join(path, "class"))
    dims = obj.get("dimensions_m")
    if dims is not None:
        dpath = _join(path, "dimensions_m")
        dims = _dict(dims, dpath)
        _warn_unknown(dims, set(_SIZE_NAMES), dpath, sink)
        dims = tuple(_number(_get(dims, k, dpath), _join(dpath, k), positive=True) for k in _SIZE_NAMES)
    lpath = _join(path, "dimension_lines")
    lines = _list(_get(obj, "dimension_lines", path), lpath)
    if not lines:
        raise SceneError(lpath, "expected at least one annotation, got []")
    gt = obj.get("ground_truth")
    if gt is not None:
        gt = _parse_target_truth(gt, _join(path, "ground_truth"))
    return FrameTarget(ident, cls, tuple(_parse_dimension_line(d, _join(lpath, i), w, h, sink)
                                         for i, d in enumerate(lines)), dims, gt)


def _parse_target_truth(obj: Any, path: str) -> dict:
    obj = _dict(obj, path)
    lpath = _join(path, "location_m")
    loc = _list(_get(obj, "location_m", path), lpath)
    if len(loc) != 3:
        raise SceneError(lpath, f"expected [x, y, z], got {_short(loc)}")
    out = dict(obj)
    out["location_m"] = [_number(v, _join(lpath, i)) for i, v in enumerate(loc)]
    if out["location_m"][2] <= 0:
        raise SceneError(_join(lpath, 2), f"z must be > 0 (in front of the camera), got {_short(loc[2])}")
    if obj.get("yaw_rad") is not None:
        out["yaw_rad"] = _number(obj["yaw_rad"], _join(path, "yaw_rad"))
    if obj.get("dimensions_m") is not None:
        dpath = _join(path, "dimensions_m")
        d = _dict(obj["dimensions_m"], dpath)
        out["dimensions_m"] = {k: _number(_get(d, k, dpath), _join(dpath, k), positive=True) for k in _SIZE_NAMES}
    if obj.get("handedness") is not None and (isinstance(obj["handedness"], bool) or obj["handedness"] not in (1, -1)):
        raise SceneError(_join(path, "handedness"), f"expected 1 or -1, got {_short(obj['handedness'])}")
    return out


def _parse_frame_reference(obj: Any, index: int, path: str, w: int, h: int, ids: dict[str, int],
                           sink: list[str]) -> tuple[Reference, int | None]:
    obj = _dict(obj, path)
    if "targets" in obj:
        return _parse_distance_reference(obj, index, path, w, h, ids, sink)
    target = obj.get("target")
    owner = None
    if target is not None:
        name = _string(target, _join(path, "target"))
        if name not in ids:
            raise SceneError(_join(path, "target"), f"no target with id {_short(name)} (targets: {sorted(ids)})")
        owner = ids[name]
    rest = {k: v for k, v in obj.items() if k != "target"}
    if "line" in rest:
        ref = _parse_reference(rest, index, path, w, h, sink)
        if ref.mode == "relative":
            if owner is None and len(ids) > 1:
                raise SceneError(_join(path, "target"), "a relative reference in a frame of several targets must "
                                                        "name the target it is relative to")
            owner = 0 if owner is None else owner
        return ref, owner
    # a measurement of a target's own size: no line
    if owner is None:
        raise SceneError(_join(path, "line"), "missing required key (a reference without a line must name a "
                                              "target whose size it measures)")
    measure = _get(rest, "measure", path)
    if measure not in _SIZE_NAMES:
        raise SceneError(_join(path, "measure"), f"a target's own size is its length, width or height, got {_short(measure)}")
    if rest.get("mode", "direct") != "direct":
        raise SceneError(_join(path, "mode"), f"a target's own size must be 'direct' (with a unit), got {_short(rest.get('mode'))}")
    fake = {**rest, "measure": "length", "mode": "direct", "line": [[0, h - 1], [1, h - 1]]}
    ref = _parse_reference(fake, index, path, w, h, sink)
    return Reference(index=index, measure=measure, mode="direct", low=ref.low, high=ref.high,
                     line=None, is_range=ref.is_range, unit=ref.unit, object=ref.object, worker=ref.worker,
                     confidence=ref.confidence, seconds=ref.seconds, stated=ref.stated), owner


def _parse_distance_reference(obj: dict, index: int, path: str, w: int, h: int, ids: dict[str, int],
                              sink: list[str]) -> tuple[Reference, tuple[int, int]]:
    """A worker's distance on the ground between two targets (bottom centre to bottom centre):
    ``{"targets": [id, id], "measure": "distance", "value"/"range", "unit"}``."""
    tpath = _join(path, "targets")
    names = _list(obj["targets"], tpath)
    if len(names) != 2:
        raise SceneError(tpath, f"a distance is between two targets, got {len(names)} ids ({_short(names)})")
    owners = []
    for k, name in enumerate(names):
        name = _string(name, _join(tpath, k))
        if name not in ids:
            raise SceneError(_join(tpath, k), f"no target with id {_short(name)} (targets: {sorted(ids)})")
        owners.append(ids[name])
    if owners[0] == owners[1]:
        raise SceneError(_join(tpath, 1), f"a distance is between two different targets, got {_short(names[1])} twice")
    for key in ("line", "target"):
        if key in obj:
            raise SceneError(_join(path, key), f"a distance between two targets has no {key!r} (it is measured "
                                               "between their bottom centres)")
    if obj.get("measure", "distance") != "distance":
        raise SceneError(_join(path, "measure"), f"a reference naming two targets measures their 'distance', "
                                                 f"got {_short(obj.get('measure'))}")
    if obj.get("mode", "direct") != "direct":
        raise SceneError(_join(path, "mode"), f"a distance must be 'direct' (with a unit), got {_short(obj.get('mode'))}")
    rest = {k: v for k, v in obj.items() if k != "targets"}
    fake = {**rest, "measure": "length", "mode": "direct", "line": [[0, h - 1], [1, h - 1]]}
    ref = _parse_reference(fake, index, path, w, h, sink)
    return Reference(index=index, measure="distance", mode="direct", low=ref.low, high=ref.high,
                     line=None, is_range=ref.is_range, unit=ref.unit, object=ref.object, worker=ref.worker,
                     confidence=ref.confidence, seconds=ref.seconds, stated=ref.stated), (owners[0], owners[1])


def parse_frame(data: Any, source: str | Path | None = None,
                classes: dict[str, SizePrior] | None = None) -> FrameScene:
    """Validate a decoded ``creference-scene/2`` dict (or a version-1 one, as a one-target frame)
    and return a :class:`FrameScene`; :class:`SceneError` names the key path of the first problem.
    ``classes``: size priors of the user's own classes (a classes file), which a target's class may
    name besides the scene's own and the shipped KITTI classes."""
    extra_classes = classes
    data = _dict(data, "(scene)")
    if check_scene_format(_get(data, "format", "")) == "creference-scene/1":
        return frame_from_scene(parse_scene(data, source))
    sink: list[str] = []
    _warn_unknown(data, _TOP_KEYS, "", sink)
    kitti_p2 = kitti_calib = None
    if isinstance(data.get("camera"), dict) and ("kitti_p2" in data["camera"] or "kitti_calib" in data["camera"]):
        camera = dict(data["camera"])
        kitti_p2 = _parse_p2(camera.pop("kitti_p2", None), "camera.kitti_p2")
        kitti_calib = _parse_calib(camera.pop("kitti_calib", None), "camera.kitti_calib")
        if kitti_calib is not None and kitti_p2 is None:
            raise SceneError("camera.kitti_calib", "KITTI calib lines without 'kitti_p2' (the camera's P2)")
        data = {**data, "camera": camera}
    head = parse_header(data, source, sink)
    w, h = head["image_width"], head["image_height"]
    classes = {}
    if data.get("classes") is not None:
        try:
            classes = size_priors_from_dict(data["classes"], "classes", "scene")
        except ValueError as exc:
            path, _, msg = str(exc).partition(": ")
            raise SceneError(path, msg) from None
    targets_raw = _list(_get(data, "targets", ""), "targets")
    if not targets_raw:
        raise SceneError("targets", "expected at least one target, got []")
    targets = tuple(_parse_frame_target(t, _join("targets", i), w, h, sink) for i, t in enumerate(targets_raw))
    ids: dict[str, int] = {}
    for i, t in enumerate(targets):
        if t.id in ids:
            raise SceneError(_join(_join("targets", i), "id"), f"duplicate id {_short(t.id)} (also targets[{ids[t.id]}])")
        ids[t.id] = i
    for i, t in enumerate(targets):
        if t.dimensions is None and t.cls is None:
            raise SceneError(_join("targets", i), "needs 'dimensions_m' or a 'class' with a size prior")
        if t.dimensions is None and find_size_prior(t.cls, classes, extra_classes) is None:
            known = sorted(set(classes) | set(extra_classes or {}) | set(KITTI_SIZE_PRIORS))
            raise SceneError(_join(_join("targets", i), "class"),
                             f"no size prior for class {_short(t.cls)} and no 'dimensions_m' (classes: {known}; "
                             "add it under 'classes' or give a classes file)")
    refs_raw = data.get("references")
    refs_raw = [] if refs_raw is None else _list(refs_raw, "references")
    parsed = [_parse_frame_reference(r, i, _join("references", i), w, h, ids, sink) for i, r in enumerate(refs_raw)]
    gt = data.get("ground_truth")
    gt = None if gt is None else dict(_dict(gt, "ground_truth"))
    for message in sink:
        warnings.warn(message, SceneWarning, stacklevel=2)
    return FrameScene(targets=targets, references=tuple(r for r, _ in parsed),
                      reference_targets=tuple(o for _, o in parsed), classes=classes, ground_truth=gt,
                      warnings=tuple(sink), kitti_p2=kitti_p2, kitti_calib=kitti_calib, **head)


def _parse_calib(value: Any, path: str) -> dict[str, list[float]] | None:
    """``camera.kitti_calib``: the calib file's other lines, name → numbers."""
    if value is None:
        return None
    value = _dict(value, path)
    out = {}
    for name, numbers in value.items():
        if not name or any(c.isspace() or c == ":" for c in name) or name == "P2":
            raise SceneError(_join(path, name), "expected a calib line's name (no spaces, not P2: that is kitti_p2)")
        lpath = _join(path, name)
        out[name] = [_number(v, _join(lpath, i)) for i, v in enumerate(_list(numbers, lpath))]
        if not out[name]:
            raise SceneError(lpath, "expected numbers, got []")
    return out


def _parse_p2(value: Any, path: str) -> np.ndarray | None:
    if value is None:
        return None
    rows = _list(value, path)
    if len(rows) != 3:
        raise SceneError(path, f"expected 3 rows of 4 numbers (KITTI's P2), got {len(rows)} rows")
    out = np.array([[_number(v, _join(_join(path, i), j)) for j, v in enumerate(_list(r, _join(path, i)))]
                    for i, r in enumerate(rows)], dtype=object)
    if out.ndim != 2 or out.shape != (3, 4):
        raise SceneError(path, f"expected 3 rows of 4 numbers (KITTI's P2), got {_short(value)}")
    return out.astype(float)


def load_frame(path: str | Path, classes: dict[str, SizePrior] | None = None) -> FrameScene:
    """Load a ``creference-scene/2`` (or ``/1``) file as a :class:`FrameScene` (``classes``: as
    :func:`parse_frame`)."""
    path = Path(path)
    return parse_frame(read_scene_json(path), source=path, classes=classes)


def frame_from_scene(scene: Scene) -> FrameScene:
    """A version-1 scene as a one-target frame: its target keeps its known size; relative
    references are relative to it."""
    t = scene.target
    gt = None
    if scene.ground_truth is not None:
        g = scene.ground_truth
        gt = {"location_m": g.location_m.tolist(), **({"yaw_rad": g.yaw_rad} if g.yaw_rad is not None else {}),
              **{k: v for k, v in g.extra.items() if k == "handedness"}}
    cam_gt = None
    if scene.ground_truth is not None:
        g = scene.ground_truth
        cam_gt = {k: v for k, v in {"focal_length_px": g.focal_length_px, **g.extra}.items()
                  if k in ("focal_length_px", "camera_height_m", "pitch_rad", "roll_rad") and v is not None}
    target = FrameTarget(t.id, None, t.dimension_lines, (t.length, t.width, t.height), gt)
    return FrameScene(image_width=scene.image_width, image_height=scene.image_height,
                      principal_point=scene.principal_point, targets=(target,), references=scene.references,
                      reference_targets=tuple(0 if r.mode == "relative" else None for r in scene.references),
                      focal_length_px=scene.focal_length_px, horizon=scene.horizon,
                      horizon_sd_px=scene.horizon_sd_px, focal_prior=scene.focal_prior,
                      orientation_prior=scene.orientation_prior, ground_truth=cam_gt, image_path=scene.image_path,
                      source=scene.source, warnings=scene.warnings, format="creference-scene/1")


def frame_to_dict(frame: FrameScene) -> dict:
    """A :class:`FrameScene` as a ``creference-scene/2`` dict (round-trips :func:`parse_frame`)."""
    from .scene import _reference_to_dict

    out: dict[str, Any] = {"format": FRAME_FORMAT, "image": {"width": frame.image_width, "height": frame.image_height},
                           "camera": {"principal_point": np.asarray(frame.principal_point).tolist()}}
    if frame.image_path is not None:
        out["image"]["path"] = str(frame.image_path if frame.source is None else
                                   _relative(frame.image_path, frame.source.parent))
    if frame.focal_length_px is not None:
        out["camera"]["focal_length_px"] = frame.focal_length_px
    if frame.kitti_p2 is not None:
        out["camera"]["kitti_p2"] = np.asarray(frame.kitti_p2).tolist()
    if frame.kitti_calib is not None:
        out["camera"]["kitti_calib"] = {k: list(v) for k, v in frame.kitti_calib.items()}
    out["camera"].update(camera_priors_to_dict(frame))
    if frame.horizon is not None:
        out["horizon"] = np.asarray(frame.horizon).tolist()
        if frame.horizon_sd_px:
            out["horizon_sd_px"] = frame.horizon_sd_px
    if frame.classes:
        out["classes"] = {k: {f"{n}_m": v for n, v in zip(_SIZE_NAMES, p.median_m)} | {"log_sd": list(p.log_sd)}
                          for k, p in frame.classes.items()}
    out["targets"] = []
    for t in frame.targets:
        d: dict[str, Any] = {"id": t.id}
        if t.cls is not None:
            d["class"] = t.cls
        if t.dimensions is not None:
            d["dimensions_m"] = dict(zip(_SIZE_NAMES, t.dimensions))
        d["dimension_lines"] = [{k: v for k, v in (("worker", a.worker), ("corners", a.corners.tolist()),
                                                   ("seconds", a.seconds)) if v is not None}
                                for a in t.dimension_lines]
        if t.ground_truth is not None:
            d["ground_truth"] = t.ground_truth
        out["targets"].append(d)
    refs = []
    for r, owner in zip(frame.references, frame.reference_targets):
        if r.line is None:
            d = {"measure": r.measure, "mode": "direct"}
            low, high = r.stated
            d.update({"range": [low, high]} if r.is_range else {"value": low})
            d["unit"] = r.unit
            for key in ("object", "worker", "confidence", "seconds"):
                if getattr(r, key) is not None:
                    d[key] = getattr(r, key)
        else:
            d = _reference_to_dict(r)
        if isinstance(owner, tuple):
            d["targets"] = [frame.targets[k].id for k in owner]
        elif owner is not None:
            d["target"] = frame.targets[owner].id
        refs.append(d)
    if refs:
        out["references"] = refs
    if frame.ground_truth is not None:
        out["ground_truth"] = frame.ground_truth
    return out


def frame_fingerprint(frame: FrameScene) -> str:
    """SHA-256 (hex) of a frame's content, its canonical form (:func:`frame_to_dict`): as
    :func:`~.scene.scene_fingerprint` for version 1, the same whatever the key order, whitespace or
    file name; any change of a value changes it. Frame results record it (``scene_id.sha256``)."""
    import hashlib
    import json

    text = json.dumps(frame_to_dict(frame), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _relative(path: Path, base: Path) -> Path:
    try:
        return path.relative_to(base)
    except ValueError:
        return path
