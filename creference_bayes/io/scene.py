"""Scene dataclasses and the ``creference-scene/1`` loader (../shared/docs/formats.md).

Every invalid input raises :class:`SceneError`, a one-line message that starts with the key path
and names the value (``references[2].unit: unknown unit 'furlong' …``); nothing else escapes
:func:`parse_scene` (a property test mutates valid scenes to check it). Unknown keys are not
errors, unless one is a near miss of a known key of the same object (``refrences``: unknown
key; did you mean 'references'?, :func:`near_miss`), which would otherwise silently drop what
the user meant; the others are kept in :attr:`Scene.warnings` and emitted as
:class:`SceneWarning`. ``ground_truth`` is free-form (extra keys are kept without a warning).

Optional keys may also be ``null`` (``camera``, ``horizon``, ``references``, ``ground_truth``,
``camera.principal_point``, ``camera.focal_length_px``), meaning absent. Limits beyond
formats.md: image sides at most :data:`MAX_IMAGE_SIDE` pixels; annotated points within
:data:`IMAGE_MARGIN` image sizes of the image; horizon points within :data:`HORIZON_MARGIN`
image sizes and the horizon no steeper than 45°; the known ground-truth extras
(``camera_height_m``, ``pitch_rad``, ``roll_rad``, ``handedness``) are checked when present.
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..core.units import UNITS_TO_M
from ..models.camera_terms import FocalPrior, OrientationPrior
from .validation import (SceneError, SceneWarning, _check_inside, _check_segment, _dict, _get,
                         _got, _join, _list, _number, _point, _points, _short, _string, _warn_unknown,
                         check_scene_format, near_miss)
from .files import read_bytes

__all__ = [
    "SCENE_FORMAT",
    "SceneError",
    "SceneWarning",
    "DimensionLine",
    "Target",
    "Reference",
    "GroundTruth",
    "Scene",
    "load_scene",
    "parse_scene",
    "scene_to_dict",
    "scene_fingerprint",
    "scene_differences",
    "near_miss",
    "parse_header",
    "read_scene_json",
]

SCENE_FORMAT = "creference-scene/1"
MEASURES = ("length", "width", "distance")
MODES = ("direct", "relative")
#: Image points may lie outside the image by at most this fraction of its size on each side.
IMAGE_MARGIN = 0.5
#: The two horizon points may lie outside the image by at most this many image sizes: a camera
#: pitched steeply down sees its horizon far above the image, but not at 10⁶ pixels.
HORIZON_MARGIN = 20.0
#: Largest image side accepted, pixels (gigapixel panoramas stay below it).
MAX_IMAGE_SIDE = 1_000_000


@dataclass(frozen=True)
class DimensionLine:
    """One annotation of the target: ``corners`` (4, 2) pixels t1..t4 (formats.md)."""

    corners: np.ndarray
    worker: str | None = None
    seconds: float | None = None


@dataclass(frozen=True)
class Target:
    """The target box: sizes in metres and one or more dimension-line annotations."""

    id: str
    length: float
    width: float
    height: float
    dimension_lines: tuple[DimensionLine, ...]

    @property
    def corners(self) -> np.ndarray:
        """All annotations' corners, shape (n_annotation, 4, 2), pixels."""
        return np.stack([d.corners for d in self.dimension_lines])

    @property
    def median_corners(self) -> np.ndarray:
        """Per-corner median over the annotations (paper §7.1.1), shape (4, 2), pixels."""
        return np.median(self.corners, axis=0)


@dataclass(frozen=True)
class Reference:
    """A worker's rough measurement of another object, with the segment drawn for it.

    ``low`` and ``high`` are the stated value or range, converted to metres for direct
    measurements and kept as ratios to the target's length or width for relative ones.
    """

    index: int
    measure: str
    mode: str
    low: float
    high: float
    line: np.ndarray
    is_range: bool
    unit: str | None = None
    object: str | None = None
    worker: str | None = None
    confidence: float | None = None
    seconds: float | None = None
    #: (low, high) exactly as written in the file: in ``unit`` (direct) or as a ratio (relative).
    stated: tuple[float, float] | None = None

    def length_bounds_m(self, target: Target) -> tuple[float, float]:
        """The real length of ``line`` implied by the annotation, in metres: (low, high)."""
        if self.mode == "direct":
            return self.low, self.high
        base = target.length if self.measure == "length" else target.width
        return self.low * base, self.high * base


@dataclass(frozen=True)
class GroundTruth:
    """Evaluation-only truth: bottom-centre location (m, gravity-aligned frame), yaw (rad), µ (px)."""

    location_m: np.ndarray
    yaw_rad: float | None = None
    focal_length_px: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Scene:
    """A validated ``creference-scene/1`` scene. Pixel coordinates: u right, v down, origin top-left."""

    image_width: int
    image_height: int
    target: Target
    principal_point: np.ndarray
    focal_length_px: float | None = None
    horizon: np.ndarray | None = None
    references: tuple[Reference, ...] = ()
    #: Pixel uncertainty of each horizon point (0: the horizon is exact).
    horizon_sd_px: float = 0.0
    #: The scene's own prior on µ (``camera.focal_length_prior``), or None.
    focal_prior: FocalPrior | None = None
    #: The scene's own prior on pitch and roll (``camera.orientation_prior``), or None.
    orientation_prior: OrientationPrior | None = None
    ground_truth: GroundTruth | None = None
    image_path: Path | None = None
    source: Path | None = None
    warnings: tuple[str, ...] = ()

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.image_width, self.image_height


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
        worker=_string(obj.get("worker"), _join(path, "worker")),
        seconds=None if seconds is None else _number(seconds, _join(path, "seconds"), nonneg=True),
    )


def _parse_target(obj: Any, path: str, w: int, h: int, sink: list[str]) -> Target:
    obj = _dict(obj, path)
    _warn_unknown(obj, {"id", "dimensions_m", "dimension_lines"}, path, sink)
    dims_path = _join(path, "dimensions_m")
    dims = _dict(_get(obj, "dimensions_m", path), dims_path)
    _warn_unknown(dims, {"length", "width", "height"}, dims_path, sink)
    size = {k: _number(_get(dims, k, dims_path), _join(dims_path, k), positive=True)
            for k in ("length", "width", "height")}
    lines_path = _join(path, "dimension_lines")
    lines = _list(_get(obj, "dimension_lines", path), lines_path)
    if not lines:
        raise SceneError(lines_path, "expected at least one annotation, got []")
    ident = obj.get("id", "target")
    return Target(
        id=_string(ident, _join(path, "id"), optional=False),
        dimension_lines=tuple(_parse_dimension_line(d, _join(lines_path, i), w, h, sink)
                              for i, d in enumerate(lines)),
        **size,
    )


_REFERENCE_KEYS = {"worker", "object", "measure", "mode", "value", "range", "unit", "line",
                   "confidence", "seconds"}


def _parse_reference(obj: Any, index: int, path: str, w: int, h: int,
                     sink: list[str]) -> Reference:
    obj = _dict(obj, path)
    _warn_unknown(obj, _REFERENCE_KEYS, path, sink)
    measure = _get(obj, "measure", path)
    if not isinstance(measure, str) or measure not in MEASURES:
        raise SceneError(_join(path, "measure"),
                         f"unknown measure {_short(measure)} (expected one of {list(MEASURES)})")
    mode = _get(obj, "mode", path)
    if not isinstance(mode, str) or mode not in MODES:
        raise SceneError(_join(path, "mode"), f"unknown mode {_short(mode)} (expected one of {list(MODES)})")
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
        object=_string(obj.get("object"), _join(path, "object")),
        worker=_string(obj.get("worker"), _join(path, "worker")),
        confidence=None if conf is None else _number(conf, _join(path, "confidence"), lo=0.0, hi=1.0),
        seconds=None if secs is None else _number(secs, _join(path, "seconds"), nonneg=True),
    )


#: Extra ground-truth keys that the simulator writes and the benchmark reads: validated when
#: present (other extra keys are kept as they are).
_GT_EXTRA_NUMBERS = {"camera_height_m": {"positive": True}, "pitch_rad": {}, "roll_rad": {}}


def _parse_ground_truth(obj: Any, path: str) -> GroundTruth:
    obj = _dict(obj, path)
    lpath = _join(path, "location_m")
    loc = _list(_get(obj, "location_m", path), lpath)
    if len(loc) != 3:
        raise SceneError(lpath, f"expected [x, y, z], got {_short(loc)}")
    location = np.array([_number(c, _join(lpath, i)) for i, c in enumerate(loc)])
    if location[2] <= 0:
        raise SceneError(_join(lpath, 2), f"z must be > 0 (in front of the camera), got {_short(loc[2])}")
    yaw = obj.get("yaw_rad")
    focal = obj.get("focal_length_px")
    extra = {k: v for k, v in obj.items() if k not in {"location_m", "yaw_rad", "focal_length_px"}}
    for key, kind in _GT_EXTRA_NUMBERS.items():
        if extra.get(key) is not None:
            _number(extra[key], _join(path, key), **kind)
    if extra.get("handedness") is not None and (
            isinstance(extra["handedness"], bool) or extra["handedness"] not in (1, -1)):
        raise SceneError(_join(path, "handedness"), f"expected 1 or -1, {_got(extra['handedness'])}")
    return GroundTruth(
        location_m=location,
        yaw_rad=None if yaw is None else _number(yaw, _join(path, "yaw_rad")),
        focal_length_px=None if focal is None else _number(focal, _join(path, "focal_length_px"), positive=True),
        extra=extra,
    )


_FOCAL_PRIOR_KEYS = {"median_px", "equivalent_35mm_mm", "log_sd", "dof"}
#: Default log-sd of a focal-length prior a scene states without one.
STATED_FOCAL_LOG_SD = 0.1
_ORIENTATION_PRIOR_KEYS = {"pitch_mean_deg", "pitch_sd_deg", "roll_mean_deg", "roll_sd_deg",
                           "height_median_m", "height_log_sd"}


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
        if key.startswith("height_"):
            kw[key] = _number(obj[key], _join(path, key), positive=True)
            continue
        sd = key.endswith("sd_deg")
        v = _number(obj[key], _join(path, key), positive=sd, lo=None if sd else -90.0, hi=None if sd else 90.0)
        kw[key[:-4]] = math.radians(v)
    return OrientationPrior(**kw)


def parse_scene(data: Any, source: str | Path | None = None) -> Scene:
    """Validate a decoded scene (a dict) and return a :class:`Scene`.

    Parameters
    ----------
    data : dict
        The decoded JSON.
    source : path, optional
        The file it came from; ``image.path`` is resolved relative to it.

    Raises
    ------
    SceneError
        On the first invalid key, naming its path and value.
    """
    sink: list[str] = []
    data = _dict(data, "(scene)")
    fmt = check_scene_format(_get(data, "format", ""))
    if fmt != SCENE_FORMAT:
        raise SceneError("format", f"a {fmt!r} file is a frame: read it with "
                                   "creference_bayes.io.frame_scene.load_frame (or estimate it with "
                                   "creference_bayes.estimate, which takes either)")
    _warn_unknown(data, {"format", "image", "camera", "horizon", "horizon_sd_px", "target",
                         "references", "ground_truth"}, "", sink)
    head = parse_header(data, source, sink)
    w, h = head["image_width"], head["image_height"]
    target = _parse_target(_get(data, "target", ""), "target", w, h, sink)
    refs = data.get("references")
    refs = [] if refs is None else _list(refs, "references")
    references = tuple(_parse_reference(r, i, _join("references", i), w, h, sink)
                       for i, r in enumerate(refs))
    gt = data.get("ground_truth")
    ground_truth = None if gt is None else _parse_ground_truth(gt, "ground_truth")

    for message in sink:
        warnings.warn(message, SceneWarning, stacklevel=2)
    return Scene(target=target, references=references, ground_truth=ground_truth, warnings=tuple(sink), **head)



def parse_header(data: dict, source, sink: list[str]) -> dict:
    """The parts every scene format shares: ``image``, ``camera`` and ``horizon``/``horizon_sd_px``.

    Returns the :class:`Scene` fields they fill (``image_width``, ``image_height``,
    ``principal_point``, ``focal_length_px``, ``horizon``, ``horizon_sd_px``, ``focal_prior``,
    ``orientation_prior``, ``image_path``, ``source``); raises :class:`SceneError` on bad input.
    """
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
    _warn_unknown(camera, {"principal_point", "focal_length_px", "focal_length_prior",
                           "orientation_prior"}, "camera", sink)
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
    return dict(image_width=w, image_height=h, principal_point=principal, focal_length_px=focal,
                horizon=horizon, horizon_sd_px=horizon_sd, focal_prior=focal_prior,
                orientation_prior=orientation_prior, image_path=image_path, source=source)


def load_scene(path: str | Path) -> Scene:
    """Load and validate a ``creference-scene/1`` JSON file.

    Raises
    ------
    SceneError
        If the file is not valid JSON or not a valid scene; the message names the key path.
    FileNotFoundError
        If ``path`` does not exist.
    """
    path = Path(path)
    return parse_scene(read_scene_json(path), source=path)


def read_scene_json(path: Path) -> Any:
    """The decoded JSON of a scene file; :class:`SceneError` (key ``(file)``) when it is not UTF-8
    JSON with finite numbers."""
    path = Path(path)
    raw = read_bytes(path)
    try:
        data = json.loads(raw.decode("utf-8-sig"), parse_constant=_reject_constant)
    except UnicodeDecodeError as exc:
        raise SceneError(str(path), f"not UTF-8 text: byte {exc.start} is {raw[exc.start:exc.start + 1]!r}") from None
    except json.JSONDecodeError as exc:
        raise SceneError(str(path), f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except _ConstantError as exc:
        raise SceneError(str(path), f"non-standard JSON constant {exc.args[0]} (numbers must be finite)") from None
    except RecursionError:
        raise SceneError(str(path), "JSON nested too deeply") from None
    return data


class _ConstantError(Exception):
    pass


def _reject_constant(name: str) -> Any:
    raise _ConstantError(name)


def scene_to_dict(scene: Scene) -> dict:
    """Serialise a :class:`Scene` back to a ``creference-scene/1`` dict (round-trips :func:`parse_scene`)."""
    t = scene.target
    out: dict[str, Any] = {
        "format": SCENE_FORMAT,
        "image": {"width": scene.image_width, "height": scene.image_height},
        "camera": {"principal_point": scene.principal_point.tolist(),
                   "focal_length_px": scene.focal_length_px},
        "target": {
            "id": t.id,
            "dimensions_m": {"length": t.length, "width": t.width, "height": t.height},
            "dimension_lines": [
                {k: v for k, v in (("worker", d.worker), ("corners", d.corners.tolist()),
                                   ("seconds", d.seconds)) if v is not None}
                for d in t.dimension_lines
            ],
        },
    }
    if scene.image_path is not None:
        out["image"]["path"] = _relative_image_path(scene)
    if scene.horizon is not None:
        out["horizon"] = scene.horizon.tolist()
    if scene.horizon_sd_px:
        out["horizon_sd_px"] = scene.horizon_sd_px
    out["camera"].update(camera_priors_to_dict(scene))
    if scene.references:
        out["references"] = [_reference_to_dict(r) for r in scene.references]
    if scene.ground_truth is not None:
        g = scene.ground_truth
        gt: dict[str, Any] = {"location_m": g.location_m.tolist()}
        if g.yaw_rad is not None:
            gt["yaw_rad"] = g.yaw_rad
        if g.focal_length_px is not None:
            gt["focal_length_px"] = g.focal_length_px
        gt.update(g.extra)
        out["ground_truth"] = gt
    return out


def camera_priors_to_dict(scene) -> dict:
    """The ``camera`` block's ``focal_length_prior`` and ``orientation_prior`` of a scene or a
    frame (those it has), as the file gives them."""
    out: dict[str, Any] = {}
    if scene.focal_prior is not None:
        fp = scene.focal_prior
        out["focal_length_prior"] = {"median_px": fp.median_px, "log_sd": fp.log_sd,
                                     **({} if math.isinf(fp.dof) else {"dof": fp.dof})}
    if scene.orientation_prior is not None:
        op = scene.orientation_prior
        out["orientation_prior"] = {
            **{f"{k}_deg": math.degrees(getattr(op, k)) for k in ("pitch_mean", "pitch_sd", "roll_mean", "roll_sd")},
            "height_median_m": op.height_median_m, "height_log_sd": op.height_log_sd}
    return out


def _relative_image_path(scene: Scene) -> str:
    """``image.path`` as the file gave it: relative to the scene file's folder when possible."""
    if scene.source is not None:
        try:
            return str(scene.image_path.relative_to(scene.source.parent))
        except ValueError:
            pass
    return str(scene.image_path)


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
    d["line"] = r.line.tolist()
    for key in ("object", "worker", "confidence", "seconds"):
        value = getattr(r, key)
        if value is not None:
            d[key] = value
    return d


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 (hex) of the scene's content: its canonical ``creference-scene/1`` form.

    Two scenes with the same annotations, camera, horizon, references and ground truth have the
    same fingerprint, whatever the key order, whitespace or file name of their files; any change
    of a value changes it. Results record it (``scene_id.sha256``) so that a result can be checked
    against a scene, and a batch run can tell whether a scene changed since its result was made.
    """
    text = json.dumps(scene_to_dict(scene), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def scene_differences(a: Any, b: Any, atol: float = 1e-9, drop: Iterable[str] = (),
                      normalise=None) -> list[str]:
    """Where two scenes differ, one line each (an empty list: the same scene).

    Both are normalised first (``parse_scene`` then ``scene_to_dict``, warnings silenced), so
    spelling that the format allows either way (defaults, units, key order) does not count.
    Numbers are compared to ``atol`` (pixels or metres, as the key has them) plus 1e-12 relative;
    keys named in ``drop`` (e.g. ``"seconds"``, ``"ground_truth"``) are removed at every depth.
    Used for round trips through annotation tools. ``normalise`` (a scene dict → its canonical
    dict) replaces the version-1 normalisation (frames: ``frame_import.frame_differences``).
    """
    drop = set(drop)

    def norm(d):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if normalise is not None:
                d = normalise(d)
            else:
                d = scene_to_dict(d if isinstance(d, Scene) else parse_scene(d))

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
