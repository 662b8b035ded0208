"""What the Label Studio and CVAT converters share: errors that name the task and the region, the
reference fields a worker fills in, the checks every converted scene passes, and writing scenes.

An annotation tool's export is not trusted: every field is type-checked here or in the tool's
module, and every scene is validated by :func:`~creference_bayes.io.scene.parse_scene` before it
is written. A problem in one task (Label Studio) or image (CVAT) skips that unit only; the others
are converted (:class:`ImportReport`).
"""

from __future__ import annotations

import csv
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..core.units import UNITS_TO_M
from .files import atomic_write_json
from .scene import MEASURES, MODES, SceneError, parse_scene

__all__ = ["ConversionError", "TargetScene", "ImportReport", "REFERENCE_FIELDS", "MISSING",
           "reference_from_fields", "number_field", "mean_horizon", "checked_scene",
           "safe_name", "unique_names", "relative_image_path", "load_target_table",
           "apply_target_table", "write_scenes", "fmt_number"]

#: The per-reference fields, as named in the shipped Label Studio config and CVAT label spec.
REFERENCE_FIELDS = ("object", "measure", "mode", "value", "range_low", "range_high", "unit",
                    "confidence_pct")

#: Attribute values that mean "not filled in" (CVAT writes ``__undefined__`` for an unset select).
MISSING = ("", "__undefined__")


class ConversionError(ValueError):
    """A task or image that cannot be converted. ``where`` names it (and the region, if any)."""

    def __init__(self, where: str, problem: str):
        self.where = where
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{where}: {self.problem}" if where else self.problem)


@dataclass(frozen=True)
class TargetScene:
    """One converted target: ``name`` (the file stem), the ``creference-scene/1`` dict, where from."""

    name: str
    scene: dict
    source: str


@dataclass(frozen=True)
class ImportReport:
    """Scenes converted, units skipped (with the reason) and notes (things ignored or assumed)."""

    scenes: tuple[TargetScene, ...]
    errors: tuple[ConversionError, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when nothing was skipped."""
        return not self.errors

    def to_dict(self) -> dict:
        return {"scenes": [{"name": s.name, "source": s.source} for s in self.scenes],
                "errors": [str(e) for e in self.errors], "notes": list(self.notes)}


def _short(value: Any, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def number_field(value: Any, where: str, what: str, *, positive: bool = False,
                 lo: float | None = None, hi: float | None = None) -> float:
    """A finite number from a tool's field (a JSON number, or text such as ``"1.25"``)."""
    if isinstance(value, str):
        text = value.strip()
        try:
            x = float(text)
        except ValueError:
            raise ConversionError(where, f"{what} is not a number: {_short(value)}") from None
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        x = float(value)
    else:
        raise ConversionError(where, f"{what} is not a number: {_short(value)}")
    if not math.isfinite(x):
        raise ConversionError(where, f"{what} is not a finite number: {_short(value)}")
    if positive and x <= 0:
        raise ConversionError(where, f"{what} must be positive, got {x:g}")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ConversionError(where, f"{what} must be in [{lo:g}, {hi:g}], got {x:g}")
    return x


def _text(value: Any, where: str, what: str) -> str | None:
    """A filled-in text field, or None when empty or unset."""
    if value is None:
        return None
    if isinstance(value, (list, tuple)):  # Label Studio: choices / text are lists
        if len(value) == 0:
            return None
        if len(value) != 1:
            raise ConversionError(where, f"{what} has {len(value)} values {_short(list(value))}, "
                                         "expected one")
        value = value[0]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str):
        raise ConversionError(where, f"{what} is not text: {_short(value)}")
    value = value.strip()
    return None if value in MISSING else value


def reference_from_fields(fields: dict, line: list, where: str, *, worker: str | None = None,
                          seconds: float | None = None) -> dict:
    """A scene reference from the fields a worker filled in for one reference line.

    Parameters
    ----------
    fields : dict
        Some of :data:`REFERENCE_FIELDS`; unset fields are absent, None or empty.
        ``confidence_pct`` is in percent (0–100), as workers enter it.
    line : [[u, v], [u, v]]
        The line's end points, pixels.
    where : str
        Names the task and region in error messages.

    Returns
    -------
    dict, a ``references[]`` entry of ``creference-scene/1``.
    """
    measure = _text(fields.get("measure"), where, "measure")
    if measure is None:
        raise ConversionError(where, f"reference has no measure (expected one of {list(MEASURES)})")
    if measure not in MEASURES:
        raise ConversionError(where, f"unknown measure {measure!r} (expected one of {list(MEASURES)})")
    mode = _text(fields.get("mode"), where, "mode")
    if mode is None:
        raise ConversionError(where, f"reference has no mode (expected one of {list(MODES)})")
    if mode not in MODES:
        raise ConversionError(where, f"unknown mode {mode!r} (expected one of {list(MODES)})")
    if measure == "distance" and mode == "relative":
        raise ConversionError(where, "a distance cannot be relative (it is not a ratio to the target)")

    raw = {k: fields.get(k) for k in ("value", "range_low", "range_high")}
    given = {k: v for k, v in raw.items() if _text(v, where, k) is not None}
    nums = {k: number_field(v, where, k.replace("_", " "), positive=True) for k, v in given.items()}
    ref: dict[str, Any] = {"measure": measure, "mode": mode}
    if "value" in nums:
        if "range_low" in nums or "range_high" in nums:
            raise ConversionError(where, f"both a value ({nums['value']:g}) and a range given "
                                         "(expected one of them)")
        ref["value"] = nums["value"]
    elif "range_low" in nums and "range_high" in nums:
        low, high = nums["range_low"], nums["range_high"]
        if low > high:
            raise ConversionError(where, f"range low {low:g} > high {high:g}")
        ref["range"] = [low, high]
    elif nums:
        (key, x), = nums.items()
        raise ConversionError(where, f"a range needs both low and high, got only {key.replace('_', ' ')} {x:g}")
    else:
        raise ConversionError(where, "reference has no value and no range")

    unit = _text(fields.get("unit"), where, "unit")
    if mode == "direct":
        if unit is None:
            raise ConversionError(where, f"a direct measurement needs a unit (one of {list(UNITS_TO_M)})")
        if unit not in UNITS_TO_M:
            raise ConversionError(where, f"unknown unit {unit!r} (expected one of {list(UNITS_TO_M)})")
        ref["unit"] = unit
    elif unit is not None:
        raise ConversionError(where, f"a relative measurement takes no unit, got {unit!r}")
    ref["line"] = [[float(u), float(v)] for u, v in line]
    conf = fields.get("confidence_pct")
    if _text(conf, where, "confidence") is not None:
        ref["confidence"] = number_field(conf, where, "confidence (%)", lo=0.0, hi=100.0) / 100.0
    obj = _text(fields.get("object"), where, "object")
    for key, value in (("object", obj), ("worker", worker), ("seconds", seconds)):
        if value is not None:
            ref[key] = value
    return ref


def mean_horizon(lines: Iterable, width: int, where: str) -> list[list[float]]:
    """One horizon from several annotated ones: each line through its two points is evaluated at
    the image's left and right edges (u = 0 and u = width) and the heights are averaged.

    Returns ``[[0, v_left], [width, v_right]]`` (pixels).
    """
    lefts, rights = [], []
    for pts in lines:
        (u0, v0), (u1, v1) = pts
        if abs(u1 - u0) < 1e-9:
            raise ConversionError(where, f"a vertical horizon line at u = {u0:g} cannot be used")
        slope = (v1 - v0) / (u1 - u0)
        lefts.append(v0 - slope * u0)
        rights.append(v0 + slope * (width - u0))
    return [[0.0, float(np.mean(lefts))], [float(width), float(np.mean(rights))]]


def set_camera_and_horizon(scene: dict, camera: dict, data: dict, horizons: list, width: float, where: str,
                           notes: list) -> None:
    """The scene's ``camera`` block (when not empty) and horizon: the task's ``data.horizon``
    before the annotated horizon lines (their mean; a note says when they are ignored)."""
    if camera:
        scene["camera"] = camera
    if data.get("horizon") is not None:
        scene["horizon"] = data["horizon"]
        if horizons:
            notes.append(f"{where}: data.horizon used; {len(horizons)} annotated horizon line(s) ignored")
    elif horizons:
        scene["horizon"] = mean_horizon(horizons, width, where)


def checked_scene(scene: dict, where: str, origins: dict[str, str] | None = None) -> dict:
    """Validate a converted scene with :func:`parse_scene`; a failure becomes a
    :class:`ConversionError` naming ``where`` and, through ``origins`` (a key-path prefix such as
    ``references[2]`` → ``region 'a1b2'``), the region the bad value came from."""
    return checked_with(parse_scene, scene, where, origins)


def checked_with(parse, scene: dict, where: str, origins: dict[str, str] | None = None) -> dict:
    """``scene`` after ``parse(scene)`` accepted it (warnings silenced); a :class:`SceneError`
    becomes a :class:`ConversionError` naming ``where`` and the region of the longest matching
    ``origins`` prefix (the last one that matches)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            parse(scene)
    except SceneError as exc:
        origin = None
        for prefix, name in (origins or {}).items():
            if exc.path == prefix or exc.path.startswith(prefix + ".") or exc.path.startswith(prefix + "["):
                origin = name
        place = f"{where}, {origin}" if origin else where
        raise ConversionError(place, f"{exc.path}: {exc.problem}") from None
    return scene


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_name(text: str) -> str:
    """A file stem from a target id or image name: other characters become ``_``."""
    name = _UNSAFE.sub("_", str(text)).strip("._") or "target"
    return name[:120]


def fmt_number(x: float) -> str:
    """A number as short text that reads back to the same float where it matters (15 digits)."""
    return f"{float(x):.15g}"


_TABLE_COLUMNS = ("target_id", "length_m", "width_m", "height_m")


def load_target_table(path: str | Path) -> dict[str, dict[str, float]]:
    """Known target sizes from a CSV file with the header ``target_id,length_m,width_m,height_m``
    (an optional ``focal_length_px`` column gives a known focal length).

    Returns ``{target_id: {"length": m, "width": m, "height": m[, "focal_length_px": px]}}``.
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.DictReader(f)
        missing = [c for c in _TABLE_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ConversionError(str(path), f"missing column(s) {missing}; expected a header "
                                             f"{','.join(_TABLE_COLUMNS)}[,focal_length_px]")
        table: dict[str, dict[str, float]] = {}
        for i, row in enumerate(reader, start=2):
            where = f"{path.name} line {i}"
            tid = (row.get("target_id") or "").strip()
            if not tid:
                raise ConversionError(where, "empty target_id")
            if tid in table:
                raise ConversionError(where, f"target_id {tid!r} appears twice")
            entry = {k[:-2]: number_field(row.get(k), where, k, positive=True)
                     for k in _TABLE_COLUMNS[1:]}
            focal = (row.get("focal_length_px") or "").strip()
            if focal:
                entry["focal_length_px"] = number_field(focal, where, "focal_length_px", positive=True)
            table[tid] = entry
    return table


def apply_target_table(target_id: str, dims: dict[str, float] | None,
                       table: dict[str, dict[str, float]] | None, where: str
                       ) -> tuple[dict[str, float], float | None]:
    """The target's size (m) and known focal length (px, or None) from the tool's own fields
    (``dims``, possibly None) and the ``--targets`` table; the two must agree when both give it."""
    row = (table or {}).get(target_id)
    if dims is None and row is None:
        hint = " or in the --targets table" if table is not None else " (or pass --targets FILE.csv)"
        raise ConversionError(where, f"no size for target {target_id!r}: give length, width and "
                                     f"height in metres in the export{hint}")
    if dims is not None and row is not None:
        for k in ("length", "width", "height"):
            if not math.isclose(dims[k], row[k], rel_tol=1e-9):
                raise ConversionError(where, f"target {target_id!r}: {k} {dims[k]:g} m in the export "
                                             f"but {row[k]:g} m in the --targets table")
    size = dict(dims if dims is not None else {k: row[k] for k in ("length", "width", "height")})
    return size, (row or {}).get("focal_length_px")


def write_scenes(scenes: Iterable[TargetScene], out_dir: str | Path) -> list[Path]:
    """Write each scene to ``out_dir/<name>.json`` atomically (temporary file, then rename)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for s in scenes:
        path = out / f"{s.name}.json"
        atomic_write_json(path, s.scene)
        paths.append(path)
    return paths


def unique_names(scenes: list[TargetScene]) -> tuple[list[TargetScene], list[ConversionError]]:
    """Drop (and report) a scene whose file name an earlier scene already took."""
    seen: dict[str, str] = {}
    kept, errors = [], []
    for s in scenes:
        key = s.name.lower()  # case-insensitive file systems
        if key in seen:
            errors.append(ConversionError(s.source, f"file name {s.name + '.json'!r} is already used "
                                                    f"by {seen[key]} (target ids must be unique)"))
            continue
        seen[key] = s.source
        kept.append(s)
    return kept, errors


def relative_image_path(image: str | Path, out_dir: str | Path | None) -> str:
    """``image`` as the scene's ``image.path``: relative to the output folder when possible."""
    if out_dir is None:
        return str(image)
    try:
        return os.path.relpath(Path(image).resolve(), Path(out_dir).resolve())
    except ValueError:  # another drive (Windows)
        return str(Path(image).resolve())
