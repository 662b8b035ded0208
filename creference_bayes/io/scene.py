"""Scene files and the one scene in memory: a photo with one or more annotated targets.

``creference-scene/1`` (one ``target``) and ``creference-scene/2`` (``targets``) files
(docs/scene_format.md) both become one :class:`Scene`, validated by one set of rules;
:func:`scene_to_dict` writes version 2. A version-1 file is a scene of one target (id ``target``
when it has none) whose ground truth is split between the target and the camera.

Every invalid input raises :class:`SceneError`, a one-line message that starts with the key path
and names the value; nothing else escapes :func:`parse_scene`. An unknown key is an error when it
is a near miss of a known key (:func:`near_miss`: it would silently drop what the user meant),
else a :class:`SceneWarning` kept in :attr:`Scene.warnings`. Ground truth is free-form; its known
keys are checked. Optional keys may be ``null`` (absent). Limits beyond the format:
:data:`MAX_IMAGE_SIDE`, :data:`IMAGE_MARGIN`, :data:`HORIZON_MARGIN`, a horizon no steeper than 45°.
"""

from __future__ import annotations

import math
import unicodedata
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..core.units import UNITS_TO_M
from ..models.camera_terms import FocalPrior, OrientationPrior
from ..models.size_priors import KITTI_SIZE_PRIORS, SIZE_KEYS, SizePrior, size_priors_from_dict
from .result import canonical_sha256
from .validation import (SCENE_FORMATS, SceneError, SceneWarning, _check_inside, _check_segment, _dict,
                         _get, _got, _join, _list, _name, _number, _point, _points, _short, _string,
                         _warn_unknown, check_scene_format, near_miss, read_json)

__all__ = ["SCENE_FORMAT", "SCENE_FORMATS", "SceneError", "SceneWarning", "DimensionLine", "Target", "Reference",
           "Scene", "load_scene", "parse_scene", "scene_to_dict", "scene_fingerprint", "scene_differences",
           "near_miss", "read_scene_json", "find_size_prior", "with_classes", "MAX_TARGETS", "MAX_ANNOTATIONS",
           "MAX_REFERENCES"]

#: The format :func:`scene_to_dict` writes.
SCENE_FORMAT = SCENE_FORMATS[-1]
MEASURES = ("length", "width", "distance")
MODES = ("direct", "relative")
#: Image points may lie outside the image by at most this fraction of its size on each side.
IMAGE_MARGIN = 0.5
#: The two horizon points may lie outside the image by at most this many image sizes: a camera
#: pitched steeply down sees its horizon far above the image, but not at 10⁶ pixels.
HORIZON_MARGIN = 20.0
#: Largest image side accepted, pixels (gigapixel panoramas stay below it).
MAX_IMAGE_SIDE = 1_000_000
#: Most targets in a scene. A KITTI frame has up to about 30 objects; the MAP's cost grows faster
#: than linearly with the targets (100 targets with one distance reference take about a minute
#: without the posterior), so a scene of more is refused rather than left to run for hours.
MAX_TARGETS = 100
#: Most annotations (``dimension_lines``) of one target: crowds of 5-20 workers, with room to spare.
MAX_ANNOTATIONS = 500
#: Most references in a scene: a few per target from each worker, with room to spare.
MAX_REFERENCES = 2000
#: The longest ``setting`` name (it names a group in tables and file keys).
MAX_SETTING_CHARS = 100
_TOP_KEYS = {1: {"format", "image", "camera", "horizon", "horizon_sd_px", "corner_scale", "target", "references",
                 "ground_truth", "setting"},
             2: {"format", "image", "camera", "horizon", "horizon_sd_px", "corner_scale", "classes", "targets",
                 "references", "ground_truth", "setting"}}
#: Camera ground-truth keys (the rest of a version-1 ``ground_truth`` is the target's).
_CAMERA_TRUTH = ("focal_length_px", "camera_height_m", "pitch_rad", "roll_rad")


@dataclass(frozen=True)
class DimensionLine:
    """One annotation of the target: ``corners`` (4, 2) pixels t1..t4 (formats.md)."""

    corners: np.ndarray
    worker: str | None = None
    seconds: float | None = None


@dataclass(frozen=True)
class Target:
    """One target: its id, class (or None), annotations, known sizes (m: length, width, height) or
    None (a size prior applies), ground truth (``location_m``, ``yaw_rad``, ``dimensions_m``,
    ``handedness``, …) or None, and its own size prior (a size known up to a spread, as a catalogue
    gives it), which takes the place of its class's, or None."""

    id: str
    cls: str | None
    dimension_lines: tuple[DimensionLine, ...]
    dimensions: tuple[float, float, float] | None = None
    ground_truth: dict | None = None
    size_prior: SizePrior | None = None

    @property
    def corners(self) -> np.ndarray:
        """(K, 4, 2) every annotation's corners, pixels."""
        return np.stack([d.corners for d in self.dimension_lines])

    @property
    def median_corners(self) -> np.ndarray:
        """Per-corner median over the annotations (paper §7.1.1), (4, 2) pixels."""
        return np.median(self.corners, axis=0)


@dataclass(frozen=True)
class Reference:
    """A worker's rough measurement, with the segment drawn for it (None for a target's own size
    or the distance between two targets).

    ``low`` and ``high`` are the stated value or range, converted to metres for direct
    measurements and kept as ratios to a target's length or width for relative ones; ``stated``
    is (low, high) exactly as written in the file.
    """

    index: int
    measure: str
    mode: str
    low: float
    high: float
    line: np.ndarray | None
    is_range: bool
    unit: str | None = None
    object: str | None = None
    worker: str | None = None
    confidence: float | None = None
    seconds: float | None = None
    stated: tuple[float, float] | None = None


@dataclass(frozen=True)
class Scene:
    """A validated scene (module docstring). Pixel coordinates: u right, v down, origin top-left.

    Attributes
    ----------
    image_width, image_height : pixels
    principal_point : (2,) pixels
    targets : the targets (at least one)
    references : the workers' references
    reference_targets : for each reference, the index of the target it names, or None; a pair of
        indices for a distance between two targets
    classes : the scene's own size priors (class name → ``SizePrior``)
    focal_length_px : a known focal length, or None
    horizon : (2, 2) two points of the horizon, or None;  horizon_sd_px : their uncertainty (0: exact)
    focal_prior, orientation_prior : the scene's own priors on the camera, or None
    ground_truth : the camera's truth (``focal_length_px``, ``camera_height_m``, ``pitch_rad``,
        ``roll_rad``, …) or None
    image_path, source : the photo and the scene file, or None
    warnings : what was ignored (unknown keys)
    format : the file's format
    kitti_p2, kitti_calib : KITTI's P2 (3, 4) and the calib file's other lines of a scene made
        from a KITTI folder (labels go back into its frame)
    camera_id : which camera took the photo (``camera.id``), or None: frames with the same id share
        the camera's focal length and mounting (``creference batch --rig``)
    corner_scale : (sd px, degrees of freedom): the crowd's corner scale that other frames of the
        data set show (``corner_scale``; ``creference batch`` writes it), or None
    setting : where the photo was taken, as the data set names it (``setting``: "indoor", "street",
        …), or None: frames of one setting share where their targets stand (``creference batch``'s
        distance population; without it, the frames of a camera id, or the whole data set)
    """

    image_width: int
    image_height: int
    principal_point: np.ndarray
    targets: tuple[Target, ...]
    references: tuple[Reference, ...] = ()
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
    format: str = SCENE_FORMAT
    kitti_p2: np.ndarray | None = None
    kitti_calib: dict | None = None
    camera_id: str | None = None
    corner_scale: tuple[float, float] | None = None
    setting: str | None = None

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
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
    found = [t[cls] for t in tables if cls in t]
    found += [p for t in tables for name, p in t.items() if name.casefold() == cls.casefold()]
    return found[0] if found else None


# ----------------------------------------------------------------------------------------------
# parsing


def _parse_dimension_line(obj: Any, path: str, w: int, h: int, sink: list[str]) -> DimensionLine:
    obj = _dict(obj, path)
    _warn_unknown(obj, {"worker", "corners", "seconds"}, path, sink)
    cpath = _join(path, "corners")
    corners = _points(_get(obj, "corners", path), cpath, 4)
    _check_inside(corners, cpath, w, h, IMAGE_MARGIN)
    for k, name in ((1, "length"), (2, "width"), (3, "height")):
        _check_segment(corners[0], corners[k], cpath, f"{name} line")
    seconds = obj.get("seconds")
    return DimensionLine(
        corners=corners,
        worker=_name(obj.get("worker"), _join(path, "worker")),
        seconds=None if seconds is None else _number(seconds, _join(path, "seconds"), nonneg=True),
    )


_REFERENCE_KEYS = {"worker", "object", "measure", "mode", "value", "range", "unit", "line",
                   "confidence", "seconds"}


def _choice(obj: dict, key: str, path: str, options: tuple[str, ...]) -> str:
    """The required text ``obj[key]``, one of ``options``."""
    value = _get(obj, key, path)
    if not isinstance(value, str) or value not in options:
        raise SceneError(_join(path, key), f"unknown {key} {_short(value)} (expected one of {list(options)})")
    return value


def _target_index(name: Any, path: str, ids: dict[str, int]) -> int:
    """The index of the target whose id a reference names."""
    name = _string(name, path)
    if name not in ids:
        raise SceneError(path, f"no target with id {_short(name)} (targets: {sorted(ids)})")
    return ids[name]


def _parse_reference(obj: Any, index: int, path: str, w: int, h: int,
                     sink: list[str]) -> Reference:
    obj = _dict(obj, path)
    _warn_unknown(obj, _REFERENCE_KEYS, path, sink)
    measure = _choice(obj, "measure", path, MEASURES)
    mode = _choice(obj, "mode", path, MODES)
    if measure == "distance" and mode == "relative":
        raise SceneError(_join(path, "mode"),
                         "'relative' is not valid for measure 'distance' (paper §4.1.3)")

    has_value, has_range = "value" in obj, "range" in obj
    if has_value and has_range:
        raise SceneError(path, f"both 'value' {_short(obj['value'])} and 'range' "
                               f"{_short(obj['range'])} given (expected exactly one)")
    if not (has_value or has_range):
        raise SceneError(path, "missing required key 'value' or 'range'")
    if has_value:
        low = high = _number(obj["value"], _join(path, "value"), positive=True)
    else:
        rpath = _join(path, "range")
        rng = _list(obj["range"], rpath)
        if len(rng) != 2:
            raise SceneError(rpath, f"expected [low, high], got {_short(rng)}")
        low = _number(rng[0], _join(rpath, 0), positive=True)
        high = _number(rng[1], _join(rpath, 1), positive=True)
        if low > high:
            raise SceneError(rpath, f"low {_short(rng[0])} > high {_short(rng[1])}")
    stated = (low, high)

    unit = obj.get("unit")
    upath = _join(path, "unit")
    if mode == "direct":
        if "unit" not in obj:
            raise SceneError(upath, "missing required key (a direct measurement needs a unit)")
        if not isinstance(unit, str) or unit not in UNITS_TO_M:
            raise SceneError(upath, f"unknown unit {_short(unit)} (expected one of {sorted(UNITS_TO_M)})")
        low, high = low * UNITS_TO_M[unit], high * UNITS_TO_M[unit]
    elif unit is not None:
        raise SceneError(upath, f"a relative measurement takes no unit, got {_short(unit)}")

    line = _points(_get(obj, "line", path), _join(path, "line"), 2)
    _check_inside(line, _join(path, "line"), w, h, IMAGE_MARGIN)
    _check_segment(line[0], line[1], _join(path, "line"))
    conf = obj.get("confidence")
    secs = obj.get("seconds")
    return Reference(
        index=index, measure=measure, mode=mode, low=low, high=high, line=line,
        is_range=has_range, unit=unit, stated=stated,
        object=_name(obj.get("object"), _join(path, "object")),
        worker=_name(obj.get("worker"), _join(path, "worker")),
        confidence=None if conf is None else _number(conf, _join(path, "confidence"), lo=0.0, hi=1.0),
        seconds=None if secs is None else _number(secs, _join(path, "seconds"), nonneg=True),
    )


_FOCAL_PRIOR_KEYS = {"median_px", "equivalent_35mm_mm", "log_sd", "dof"}
#: Default log-sd of a focal-length prior a scene states without one.
STATED_FOCAL_LOG_SD = 0.1
_ORIENTATION_PRIOR_KEYS = {"pitch_mean_deg", "pitch_sd_deg", "roll_mean_deg", "roll_sd_deg",
                           "height_median_m", "height_log_sd", "source"}


def _parse_focal_prior(obj: Any, path: str, size: tuple[int, int], sink: list[str]) -> FocalPrior | None:
    """``{"median_px": µ}`` or ``{"equivalent_35mm_mm": f}``, with optional ``log_sd`` (default
    :data:`STATED_FOCAL_LOG_SD`) and ``dof`` (default: a log-normal)."""
    if obj is None:
        return None
    obj = _dict(obj, path)
    _warn_unknown(obj, _FOCAL_PRIOR_KEYS, path, sink)
    given = [k for k in ("median_px", "equivalent_35mm_mm") if obj.get(k) is not None]
    if len(given) != 1:
        raise SceneError(path, "expected exactly one of 'median_px' and 'equivalent_35mm_mm', got "
                               f"{_short(sorted(given))}")
    log_sd = obj.get("log_sd")
    log_sd = STATED_FOCAL_LOG_SD if log_sd is None else _number(log_sd, _join(path, "log_sd"), positive=True)
    dof = obj.get("dof")
    dof = math.inf if dof is None else _number(dof, _join(path, "dof"), positive=True)
    value = _number(obj[given[0]], _join(path, given[0]), positive=True)
    if given[0] == "median_px":
        return FocalPrior(value, log_sd, dof, source="scene")
    return FocalPrior.from_35mm(value, size, log_sd=log_sd, dof=dof, source="scene")


def _parse_orientation_prior(obj: Any, path: str, sink: list[str]) -> OrientationPrior | None:
    """Degrees: ``pitch_mean_deg``, ``pitch_sd_deg``, ``roll_mean_deg``, ``roll_sd_deg``; the
    camera height's ``height_median_m`` (metres) and ``height_log_sd``. Each optional: the default
    prior's values otherwise."""
    if obj is None:
        return None
    obj = _dict(obj, path)
    _warn_unknown(obj, _ORIENTATION_PRIOR_KEYS, path, sink)
    kw = {}
    for key in sorted(_ORIENTATION_PRIOR_KEYS):
        if obj.get(key) is None:
            continue
        if key == "source":  # "calibration": a mounting was put in (creference advise --apply)
            kw["source"] = _string(obj[key], _join(path, key))
            continue
        if key.startswith("height_"):
            kw[key] = _number(obj[key], _join(path, key), positive=True)
            continue
        sd = key.endswith("sd_deg")
        v = _number(obj[key], _join(path, key), positive=sd, lo=None if sd else -90.0, hi=None if sd else 90.0)
        kw[key[:-4]] = math.radians(v)
    return OrientationPrior(**kw)


def _parse_dims(obj: Any, dpath: str, sink: list[str]) -> tuple[float, float, float]:
    """A target's ``dimensions_m`` object: (length, width, height) metres."""
    obj = _dict(obj, dpath)
    _warn_unknown(obj, set(SIZE_KEYS), dpath, sink)
    return tuple(_number(_get(obj, k, dpath), _join(dpath, k), positive=True) for k in SIZE_KEYS)


def _parse_lines(obj: dict, path: str, w: int, h: int, sink: list[str]) -> tuple[DimensionLine, ...]:
    """A target's ``dimension_lines`` (at least one)."""
    lpath = _join(path, "dimension_lines")
    lines = _list(_get(obj, "dimension_lines", path), lpath)
    if not lines:
        raise SceneError(lpath, "expected at least one annotation, got []")
    _at_most(lines, MAX_ANNOTATIONS, lpath, "annotations of one target")
    return tuple(_parse_dimension_line(d, _join(lpath, i), w, h, sink) for i, d in enumerate(lines))


def _parse_target(obj: Any, path: str, w: int, h: int, sink: list[str]) -> Target:
    obj = _dict(obj, path)
    _warn_unknown(obj, {"id", "class", "dimensions_m", "size_prior", "dimension_lines", "ground_truth"}, path, sink)
    ident = _name(_get(obj, "id", path), _join(path, "id"), optional=False)
    cls = _name(obj.get("class"), _join(path, "class"))
    dims = obj.get("dimensions_m")
    if dims is not None:
        dims = _parse_dims(dims, _join(path, "dimensions_m"), sink)
    lines = _parse_lines(obj, path, w, h, sink)
    gt = obj.get("ground_truth")
    if gt is not None:
        gt = _parse_target_truth(gt, _join(path, "ground_truth"))
    prior = obj.get("size_prior")
    if prior is not None:
        if dims is not None:
            raise SceneError(_join(path, "size_prior"), "a target with 'dimensions_m' (a known size) takes no size prior")
        try:
            prior = size_priors_from_dict({"size_prior": prior}, path, source="scene")["size_prior"]
        except ValueError as exc:  # its message begins with the key path
            where, _, what = str(exc).partition(": ")
            raise SceneError(where, what) from None
    return Target(ident, cls, lines, dims, gt, prior)


def _free_form(value: Any, path: str) -> Any:
    """A free-form value of a ground truth: plain JSON (strings, booleans, null, finite numbers,
    lists and objects of them), else :class:`SceneError` naming where."""
    if isinstance(value, dict):
        return {k: _free_form(v, _join(path, k)) for k, v in value.items()}
    if isinstance(value, list):
        return [_free_form(v, _join(path, i)) for i, v in enumerate(value)]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        _number(value, path)  # finite
        return value
    if value is None or isinstance(value, (str, bool)):
        return value
    raise SceneError(path, f"expected a JSON value, got {_short(value)}")


def _parse_target_truth(obj: Any, path: str) -> dict:
    obj = _free_form(_dict(obj, path), path)
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
        out["dimensions_m"] = {k: _number(_get(d, k, dpath), _join(dpath, k), positive=True) for k in SIZE_KEYS}
    if obj.get("handedness") is not None and (isinstance(obj["handedness"], bool) or obj["handedness"] not in (1, -1)):
        raise SceneError(_join(path, "handedness"), f"expected 1 or -1, {_got(obj['handedness'])}")
    return out


def _parse_target_reference(obj: Any, index: int, path: str, w: int, h: int, ids: dict[str, int],
                           sink: list[str]) -> tuple[Reference, int | None]:
    obj = _dict(obj, path)
    if "targets" in obj:
        return _parse_distance_reference(obj, index, path, w, h, ids, sink)
    target = obj.get("target")
    owner = None if target is None else _target_index(target, _join(path, "target"), ids)
    rest = {k: v for k, v in obj.items() if k != "target"}
    if "line" in rest:
        ref = _parse_reference(rest, index, path, w, h, sink)
        if ref.mode == "relative":
            if owner is None and len(ids) > 1:
                raise SceneError(_join(path, "target"), "a relative reference in a scene of several targets must "
                                                        "name the target it is relative to")
            owner = 0 if owner is None else owner
        return ref, owner
    # a measurement of a target's own size: no line
    if owner is None:
        raise SceneError(_join(path, "line"), "missing required key (a reference without a line must name a "
                                              "target whose size it measures)")
    measure = _get(rest, "measure", path)
    if measure not in SIZE_KEYS:
        raise SceneError(_join(path, "measure"), f"a target's own size is its length, width or height, got {_short(measure)}")
    return _lineless(rest, measure, index, path, w, h, sink), owner


def _lineless(rest: dict, measure: str, index: int, path: str, w: int, h: int, sink: list[str]) -> Reference:
    """A direct reference without a line (a target's own size, a distance between two targets):
    its value, range, unit and fields read as :func:`_parse_reference` reads a line's."""
    if rest.get("mode", "direct") != "direct":
        what = "a distance" if measure == "distance" else "a target's own size"
        raise SceneError(_join(path, "mode"), f"{what} must be 'direct' (with a unit), "
                                              f"got {_short(rest['mode'])}")
    fake = {**rest, "measure": "length", "mode": "direct", "line": [[0, h - 1], [1, h - 1]]}
    ref = _parse_reference(fake, index, path, w, h, sink)
    return replace(ref, measure=measure, line=None)


def _parse_distance_reference(obj: dict, index: int, path: str, w: int, h: int, ids: dict[str, int],
                              sink: list[str]) -> tuple[Reference, tuple[int, int]]:
    """A worker's distance on the ground between two targets (bottom centre to bottom centre):
    ``{"targets": [id, id], "measure": "distance", "value"/"range", "unit"}``."""
    tpath = _join(path, "targets")
    names = _list(obj["targets"], tpath)
    if len(names) != 2:
        raise SceneError(tpath, f"a distance is between two targets, got {len(names)} ids ({_short(names)})")
    owners = [_target_index(name, _join(tpath, k), ids) for k, name in enumerate(names)]
    if owners[0] == owners[1]:
        raise SceneError(_join(tpath, 1), f"a distance is between two different targets, got {_short(names[1])} twice")
    for key in ("line", "target"):
        if key in obj:
            raise SceneError(_join(path, key), f"a distance between two targets has no {key!r} (it is measured "
                                               "between their bottom centres)")
    if obj.get("measure", "distance") != "distance":
        raise SceneError(_join(path, "measure"), f"a reference naming two targets measures their 'distance', "
                                                 f"got {_short(obj.get('measure'))}")
    rest = {k: v for k, v in obj.items() if k != "targets"}
    return _lineless(rest, "distance", index, path, w, h, sink), (owners[0], owners[1])


def _parse_v1_target(obj: Any, w: int, h: int, sink: list[str]) -> Target:
    """A version-1 ``target``: its id (``target`` when it has none) and its required sizes."""
    obj = _dict(obj, "target")
    _warn_unknown(obj, {"id", "dimensions_m", "dimension_lines"}, "target", sink)
    size = _parse_dims(_get(obj, "dimensions_m", "target"), "target.dimensions_m", sink)
    return Target(_name(obj.get("id", "target"), "target.id", optional=False), None,
                  _parse_lines(obj, "target", w, h, sink), size)


def _parse_v1_truth(obj: Any) -> tuple[dict | None, dict | None]:
    """A version-1 ``ground_truth`` split into the target's (location, yaw, handedness and any
    other key) and the camera's (:data:`_CAMERA_TRUTH`)."""
    obj = _free_form(_dict(obj, "ground_truth"), "ground_truth")
    target = {k: v for k, v in obj.items() if k not in _CAMERA_TRUTH}
    target = _parse_target_truth({**target, "location_m": _get(obj, "location_m", "ground_truth")}, "ground_truth")
    return target, _camera_truth({k: obj[k] for k in _CAMERA_TRUTH if obj.get(k) is not None}) or None


def _camera_truth(gt: dict) -> dict:
    """``gt`` with the camera's truth (:data:`_CAMERA_TRUTH`) checked: numbers, positive but for the angles."""
    for key in _CAMERA_TRUTH:
        if gt.get(key) is not None:
            gt[key] = _number(gt[key], _join("ground_truth", key), positive=key not in ("pitch_rad", "roll_rad"))
    return gt


def _at_most(items: list, limit: int, path: str, what: str) -> None:
    if len(items) > limit:
        raise SceneError(path, f"{len(items)} {what}, more than the {limit} a scene may have "
                               "(docs/scene_format.md, Limits)")


def parse_scene(data: Any, source: str | Path | None = None, classes: dict[str, SizePrior] | None = None) -> Scene:
    """Validate a decoded scene file (``data``, a dict, either format) and return a :class:`Scene`;
    :class:`SceneError` on the first invalid key, naming its path and value.

    ``source``: the file it came from (``image.path`` is resolved relative to it). ``classes``: size
    priors of the user's own classes (a classes file), which a target's class may name besides the
    scene's own and the shipped KITTI classes.
    """
    sink: list[str] = []
    data = _dict(data, "(scene)")
    fmt = check_scene_format(_get(data, "format", ""))
    version = SCENE_FORMATS.index(fmt) + 1
    other = 3 - version
    clash = sorted(set(data) & (_TOP_KEYS[other] - _TOP_KEYS[version]))  # "targets" in a version-1 scene, say
    if clash:
        fix = ('set "format": "creference-scene/2" (a list of targets, each with an id)' if version == 1 else
               'write the one target as "targets": [ … ] (with an id), or set "format": "creference-scene/1"')
        raise SceneError(clash[0], f"a key of {SCENE_FORMATS[other - 1]!r}, but the scene's format is {fmt!r}: {fix}")
    _warn_unknown(data, _TOP_KEYS[version], "", sink)
    head = _parse_header(data, source, sink)
    w, h = head["image_width"], head["image_height"]
    own_classes = {}
    if version == 2 and data.get("classes") is not None:
        try:
            own_classes = size_priors_from_dict(data["classes"], "classes", "scene")
        except (ValueError, OverflowError) as exc:
            path, _, msg = str(exc).partition(": ")
            raise SceneError(path, msg) from None
    if version == 1:
        targets = (_parse_v1_target(_get(data, "target", ""), w, h, sink),)
    else:
        raw = _list(_get(data, "targets", ""), "targets")
        if not raw:
            raise SceneError("targets", "expected at least one target, got []")
        _at_most(raw, MAX_TARGETS, "targets", "targets")
        targets = tuple(_parse_target(t, _join("targets", i), w, h, sink) for i, t in enumerate(raw))
    ids: dict[str, int] = {}
    for i, t in enumerate(targets):
        if t.id in ids:
            raise SceneError(_join(_join("targets", i), "id"), f"duplicate id {_short(t.id)} (also targets[{ids[t.id]}])")
        ids[t.id] = i
        if t.dimensions is None and t.cls is None and t.size_prior is None:
            raise SceneError(_join("targets", i), "needs 'dimensions_m', a 'size_prior' or a 'class' with a size prior")
        if t.dimensions is None and t.size_prior is None and find_size_prior(t.cls, own_classes, classes) is None:
            known = sorted(set(own_classes) | set(classes or {}) | set(KITTI_SIZE_PRIORS))
            guess = near_miss(t.cls, known) if isinstance(t.cls, str) else None
            raise SceneError(_join(_join("targets", i), "class"),
                             f"no size prior for class {_short(t.cls)} and no 'dimensions_m'"
                             + (f"; did you mean {guess!r}?" if guess else
                                f" (classes: {known}; add it under 'classes' or give a classes file)"))
    refs_raw = data.get("references")
    refs_raw = [] if refs_raw is None else _list(refs_raw, "references")
    _at_most(refs_raw, MAX_REFERENCES, "references", "references")
    if version == 1:
        parsed = []
        for i, r in enumerate(refs_raw):
            ref = _parse_reference(r, i, _join("references", i), w, h, sink)
            parsed.append((ref, 0 if ref.mode == "relative" else None))
    else:
        parsed = [_parse_target_reference(r, i, _join("references", i), w, h, ids, sink) for i, r in enumerate(refs_raw)]
    gt = data.get("ground_truth")
    if gt is not None and version == 1:
        target_truth, gt = _parse_v1_truth(gt)
        targets = (Target(targets[0].id, None, targets[0].dimension_lines, targets[0].dimensions, target_truth),)
    elif gt is not None:
        gt = _camera_truth(_free_form(_dict(gt, "ground_truth"), "ground_truth"))
    for message in sink:
        warnings.warn(message, SceneWarning, stacklevel=2)
    return Scene(targets=targets, references=tuple(r for r, _ in parsed), reference_targets=tuple(o for _, o in parsed),
                 classes=own_classes, ground_truth=gt, warnings=tuple(sink), format=fmt, **head)


def parse_quietly(data: Any, source: str | Path | None = None) -> Scene:
    """:func:`parse_scene` with its warnings silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(data, source=source)


def _parse_header(data: dict, source, sink: list[str]) -> dict:
    """The :class:`Scene` fields (by name) of the parts every scene format shares: ``image``,
    ``camera`` and ``horizon``/``horizon_sd_px``; :class:`SceneError` on bad input."""
    image = _dict(_get(data, "image", ""), "image")
    _warn_unknown(image, {"width", "height", "path"}, "image", sink)
    width_f = _number(_get(image, "width", "image"), "image.width", positive=True)
    height_f = _number(_get(image, "height", "image"), "image.height", positive=True)
    for key, value in (("width", width_f), ("height", height_f)):
        if value != int(value):
            raise SceneError(f"image.{key}", f"expected whole pixels, got {value!r}")
        if value > MAX_IMAGE_SIDE:
            raise SceneError(f"image.{key}", f"expected at most {MAX_IMAGE_SIDE} pixels, got {value:g}")
    w, h = int(width_f), int(height_f)
    img_path = _string(image.get("path"), "image.path")
    source = Path(source) if source is not None else None
    image_path = None
    if img_path is not None:
        image_path = Path(img_path)
        if not image_path.is_absolute() and source is not None:
            image_path = source.parent / image_path

    camera = data.get("camera")
    camera = {} if camera is None else _dict(camera, "camera")
    _warn_unknown(camera, {"id", "principal_point", "focal_length_px", "focal_length_prior", "orientation_prior",
                           "kitti_p2", "kitti_calib"}, "camera", sink)
    camera_id = _name(camera.get("id"), "camera.id")
    if camera_id is not None and not camera_id.strip():
        raise SceneError("camera.id", f"expected a camera's name, got {camera_id!r}")
    kitti_p2 = _parse_p2(camera.get("kitti_p2"), "camera.kitti_p2")
    kitti_calib = _parse_calib(camera.get("kitti_calib"), "camera.kitti_calib")
    if kitti_calib is not None and kitti_p2 is None:
        raise SceneError("camera.kitti_calib", "KITTI calib lines without 'kitti_p2' (the camera's P2)")
    pp = camera.get("principal_point")
    if pp is None:
        principal = np.array([w / 2.0, h / 2.0])
    else:
        principal = _point(pp, "camera.principal_point")
        if not (0 <= principal[0] <= w and 0 <= principal[1] <= h):
            raise SceneError("camera.principal_point",
                             f"[{principal[0]:g}, {principal[1]:g}] lies outside the {w}x{h} image")
    focal = camera.get("focal_length_px")
    focal = None if focal is None else _number(focal, "camera.focal_length_px", positive=True)
    focal_prior = _parse_focal_prior(camera.get("focal_length_prior"), "camera.focal_length_prior",
                                     (w, h), sink)
    orientation_prior = _parse_orientation_prior(camera.get("orientation_prior"),
                                                 "camera.orientation_prior", sink)

    horizon = data.get("horizon")
    if horizon is not None:
        horizon = _points(horizon, "horizon", 2)
        _check_inside(horizon, "horizon", w, h, margin=HORIZON_MARGIN)
        _check_segment(horizon[0], horizon[1], "horizon")
        if abs(horizon[1, 0] - horizon[0, 0]) < abs(horizon[1, 1] - horizon[0, 1]):
            raise SceneError("horizon", "a horizon steeper than 45 degrees is not supported, got "
                                        f"{_short(horizon.round(2).tolist())}")
    horizon_sd = data.get("horizon_sd_px")
    horizon_sd = 0.0 if horizon_sd is None else _number(horizon_sd, "horizon_sd_px", nonneg=True)
    if horizon_sd > 0 and horizon is None:
        raise SceneError("horizon_sd_px", f"an uncertainty {horizon_sd:g} px without a horizon")
    corner_scale = data.get("corner_scale")
    if corner_scale is not None:
        corner_scale = _dict(corner_scale, "corner_scale")
        _warn_unknown(corner_scale, {"sd_px", "dof"}, "corner_scale", sink)
        corner_scale = (_number(_get(corner_scale, "sd_px", "corner_scale"), "corner_scale.sd_px", positive=True),
                        _number(_get(corner_scale, "dof", "corner_scale"), "corner_scale.dof", positive=True))
    setting = _name(data.get("setting"), "setting")
    if setting is not None:
        setting = setting.strip()  # "street " and "street" are one setting
        if not setting or len(setting) > MAX_SETTING_CHARS or any(unicodedata.category(c) == "Cf" for c in setting):
            why = (f"at most {MAX_SETTING_CHARS} characters" if len(setting) > MAX_SETTING_CHARS else
                   "no invisible formatting characters" if setting else "not empty")
            raise SceneError("setting", f"expected the name of where the photo was taken ({why}), "
                                        f"got {_short(data['setting'])}")
    return dict(setting=setting, image_width=w, image_height=h, principal_point=principal, focal_length_px=focal,
                corner_scale=corner_scale, horizon=horizon, horizon_sd_px=horizon_sd, focal_prior=focal_prior,
                orientation_prior=orientation_prior, image_path=image_path, source=source, kitti_p2=kitti_p2,
                kitti_calib=kitti_calib, camera_id=camera_id)


def load_scene(path: str | Path, classes: dict[str, SizePrior] | None = None) -> Scene:
    """Load and validate a scene file (either format; ``classes`` as :func:`parse_scene`).
    Raises :class:`SceneError` (naming the key path) if the file is not valid JSON or not a valid
    scene, ``FileNotFoundError`` if ``path`` does not exist."""
    path = Path(path)
    return parse_scene(read_scene_json(path), source=path, classes=classes)


def with_classes(scene: Scene, classes: dict[str, SizePrior] | None) -> Scene:
    """``scene`` with the entries of ``classes`` (a classes file) that its targets take their size
    prior from added to its own classes (its own win, as in :meth:`Scene.size_prior`): written out
    (:func:`scene_to_dict`), it needs no classes file to be read again."""
    used = {}
    for t in scene.targets:
        if t.dimensions is None and t.size_prior is None and classes:
            prior = scene.size_prior(t.cls, classes)
            used.update({name: p for name, p in classes.items() if p is prior})
    return replace(scene, classes={**used, **scene.classes}) if used else scene


def read_scene_json(path: Path) -> Any:
    """The decoded JSON of a scene file (:func:`~.validation.read_json`: :class:`SceneError` naming
    the file when it is not UTF-8 JSON with finite numbers, nested too deeply, …)."""
    return read_json(path)


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


def _reference_to_dict(r: Reference) -> dict:
    if r.stated is not None:
        low, high = r.stated
    else:
        scale = UNITS_TO_M[r.unit] if r.mode == "direct" else 1.0
        low, high = r.low / scale, r.high / scale
    d: dict[str, Any] = {"measure": r.measure, "mode": r.mode}
    if r.is_range:
        d["range"] = [low, high]
    else:
        d["value"] = low
    if r.unit is not None:
        d["unit"] = r.unit
    if r.line is not None:
        d["line"] = r.line.tolist()
    for key in ("object", "worker", "confidence", "seconds"):
        value = getattr(r, key)
        if value is not None:
            d[key] = value
    return d


def prior_entry(p: SizePrior) -> dict:
    """A size prior as a ``classes`` entry (``length_m``, ``width_m``, ``height_m``, ``log_sd``)."""
    return {k: v for k, v in p.to_dict().items() if k != "source"}


def scene_to_dict(scene: Scene) -> dict:
    """A :class:`Scene` as a ``creference-scene/2`` dict (round-trips :func:`parse_scene`)."""
    out: dict[str, Any] = {"format": SCENE_FORMAT, "image": {"width": scene.image_width, "height": scene.image_height},
                           "camera": {"principal_point": np.asarray(scene.principal_point).tolist()}}
    if scene.camera_id is not None:
        out["camera"]["id"] = scene.camera_id
    if scene.image_path is not None:
        out["image"]["path"] = str(scene.image_path if scene.source is None else
                                   _relative(scene.image_path, scene.source.parent))
    if scene.focal_length_px is not None:
        out["camera"]["focal_length_px"] = scene.focal_length_px
    if scene.kitti_p2 is not None:
        out["camera"]["kitti_p2"] = np.asarray(scene.kitti_p2).tolist()
    if scene.kitti_calib is not None:
        out["camera"]["kitti_calib"] = {k: list(v) for k, v in scene.kitti_calib.items()}
    fp, op = scene.focal_prior, scene.orientation_prior
    if fp is not None:
        out["camera"]["focal_length_prior"] = {"median_px": fp.median_px, "log_sd": fp.log_sd,
                                               **({} if math.isinf(fp.dof) else {"dof": fp.dof})}
    if op is not None:
        angles = ("pitch_mean", "pitch_sd", "roll_mean", "roll_sd")
        out["camera"]["orientation_prior"] = {**{f"{k}_deg": math.degrees(getattr(op, k)) for k in angles},
                                              "height_median_m": op.height_median_m,
                                              "height_log_sd": op.height_log_sd,
                                              **({"source": op.source} if op.source else {})}
    if scene.horizon is not None:
        out["horizon"] = np.asarray(scene.horizon).tolist()
        if scene.horizon_sd_px:
            out["horizon_sd_px"] = scene.horizon_sd_px
    if scene.corner_scale is not None:
        out["corner_scale"] = {"sd_px": scene.corner_scale[0], "dof": scene.corner_scale[1]}
    if scene.setting is not None:
        out["setting"] = scene.setting
    if scene.classes:
        out["classes"] = {k: prior_entry(p) for k, p in scene.classes.items()}
    out["targets"] = []
    for t in scene.targets:
        d: dict[str, Any] = {"id": t.id}
        if t.cls is not None:
            d["class"] = t.cls
        if t.dimensions is not None:
            d["dimensions_m"] = dict(zip(SIZE_KEYS, t.dimensions))
        if t.size_prior is not None:
            d["size_prior"] = t.size_prior.to_dict()
        d["dimension_lines"] = [{k: v for k, v in (("worker", a.worker), ("corners", a.corners.tolist()),
                                                   ("seconds", a.seconds)) if v is not None}
                                for a in t.dimension_lines]
        if t.ground_truth is not None:
            d["ground_truth"] = t.ground_truth
        out["targets"].append(d)
    refs = []
    for r, owner in zip(scene.references, scene.reference_targets):
        d = _reference_to_dict(r)
        if isinstance(owner, tuple):
            d["targets"] = [scene.targets[k].id for k in owner]
        elif owner is not None:
            d["target"] = scene.targets[owner].id
        refs.append(d)
    if refs:
        out["references"] = refs
    if scene.ground_truth is not None:
        out["ground_truth"] = scene.ground_truth
    return out


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 (hex) of a scene's content, its canonical form (:func:`scene_to_dict`): the same
    whatever the key order, whitespace, file name or format version of its file; any change of a
    value changes it. Results record it (``scene_id.sha256``) so that a result can be checked
    against a scene, and a batch can tell whether a scene changed since its result was made."""
    return canonical_sha256(scene_to_dict(scene))


def scene_differences(a: Any, b: Any, atol: float = 1e-9, drop: Iterable[str] = ()) -> list[str]:
    """Where two scenes differ, one line each (an empty list: the same scene).

    Both are normalised first (``parse_scene`` then ``scene_to_dict``, warnings silenced), so
    spelling that the format allows either way (defaults, units, key order) does not count.
    Numbers are compared to ``atol`` (pixels or metres, as the key has them) plus 1e-12 relative;
    keys named in ``drop`` (e.g. ``"seconds"``, ``"ground_truth"``) are removed at every depth.
    Used for round trips through annotation tools.
    """
    drop = set(drop)

    def norm(d):
        d = scene_to_dict(d if isinstance(d, Scene) else parse_quietly(d))

        def strip(x):
            if isinstance(x, dict):
                return {k: strip(v) for k, v in x.items() if k not in drop}
            return [strip(v) for v in x] if isinstance(x, list) else x
        return strip(d)

    out: list[str] = []

    def walk(x, y, path):
        if isinstance(x, dict) and isinstance(y, dict):
            for k in sorted(set(x) | set(y)):
                if k not in x or k not in y:
                    out.append(f"{path}.{k}: only in the {'first' if k in x else 'second'} scene")
                else:
                    walk(x[k], y[k], f"{path}.{k}")
        elif isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
            for i, (p, q) in enumerate(zip(x, y)):
                walk(p, q, f"{path}[{i}]")
        elif (isinstance(x, (int, float)) and isinstance(y, (int, float))
              and not isinstance(x, bool) and not isinstance(y, bool)):
            if not abs(x - y) <= atol + 1e-12 * abs(y):
                out.append(f"{path}: {x!r} != {y!r}")
        elif x != y:
            out.append(f"{path}: {str(x)[:60]} != {str(y)[:60]}")

    walk(norm(a), norm(b), "scene")
    return out


def _relative(path: Path, base: Path) -> Path:
    try:
        return path.relative_to(base)
    except ValueError:
        return path
