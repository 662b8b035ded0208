"""What the Label Studio and CVAT converters share: errors that name the task and the region, the
reference fields a worker fills in, the ``--targets`` table, the classes block, the check every
converted scene passes, and writing scenes.

An annotation tool's export is not trusted: every field is type-checked here or in the tool's
module, and every scene is validated by :func:`~creference_bayes.io.scene.parse_scene` before it
is written. A problem in one task (Label Studio) or image (CVAT) skips that unit only; the others
are converted (:class:`ImportReport`).
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Iterable

import numpy as np

from ..core.jsonfile import read_capped
from ..core.units import UNITS_TO_M
from ..models.size_priors import SIZE_KEYS, SizePrior
from .files import atomic_write_json
from .scene import MEASURES, MODES, SCENE_FORMAT, SceneError, parse_quietly, prior_entry

__all__ = ["ConversionError", "ImportedScene", "ImportReport", "REFERENCE_FIELDS", "MISSING",
           "reference_from_fields", "number_field", "mean_horizon", "checked_scene", "classes_block",
           "safe_name", "unique_names", "image_file", "size_fields", "open_input",
           "read_input", "MAX_TABLE_BYTES", "TableRow", "TargetTable", "load_target_table", "write_scenes"]

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
class ImportedScene:
    """One converted photo: ``name`` (the file stem), the ``creference-scene/2`` dict, where from
    (the task(s) or the image)."""

    name: str
    scene: dict
    source: str


@dataclass(frozen=True)
class ImportReport:
    """Scenes converted, units skipped (with the reason), notes (things ignored or assumed) and
    how many tasks or images were passed over with nothing annotated yet."""

    scenes: tuple[ImportedScene, ...]
    errors: tuple[ConversionError, ...] = ()
    notes: tuple[str, ...] = ()
    unannotated: int = 0

    @property
    def ok(self) -> bool:
        """True when nothing was skipped."""
        return not self.errors

    def to_dict(self) -> dict:
        return {"scenes": [{"name": s.name, "source": s.source} for s in self.scenes],
                "errors": [str(e) for e in self.errors], "notes": list(self.notes), "unannotated": self.unannotated}


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
        try:
            x = float(value)
        except OverflowError:  # an integer beyond any float
            x = math.inf
    else:
        raise ConversionError(where, f"{what} is not a number: {_short(value)}")
    if not math.isfinite(x):
        raise ConversionError(where, f"{what} is not a finite number: {_short(value)}")
    if positive and x <= 0:
        raise ConversionError(where, f"{what} must be positive, got {x:g}")
    if (lo is not None and x < lo) or (hi is not None and x > hi):
        raise ConversionError(where, f"{what} must be in [{lo:g}, {hi:g}], got {x:g}")
    return x


def size_fields(cells: dict, where: str) -> dict[str, float] | None:
    """A target's size (m) from the text fields ``length_m``, ``width_m``, ``height_m`` (all three
    or none filled in), or None."""
    given = {k: cells[f"{k}_m"] for k in SIZE_KEYS if cells.get(f"{k}_m")}
    if given and len(given) < 3:
        raise ConversionError(where, f"give all of length_m, width_m and height_m or none, got "
                                     f"{ {k + '_m': v for k, v in given.items()} }")
    return {k: number_field(v, where, f"{k}_m", positive=True) for k, v in given.items()} or None


def _whole(value: Any, where: str, what: str) -> int:
    """A positive whole number of pixels from a tool's field."""
    x = number_field(value, where, what, positive=True)
    if x != int(x):
        raise ConversionError(where, f"{what} must be whole pixels, got {x:g}")
    return int(x)


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
    """A scene's ``references[]`` entry from the ``fields`` a worker filled in for one reference
    line (some of :data:`REFERENCE_FIELDS`; unset ones absent, None or empty; ``confidence_pct`` in
    percent, 0–100, as workers enter it), its end points ``line`` ([[u, v], [u, v]] pixels), and
    its ``worker`` and ``seconds``; ``where`` names the task and region in error messages."""
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
    """One horizon ``[[0, v_left], [width, v_right]]`` (pixels) from several annotated ones: each
    line through its two points is evaluated at u = 0 and u = width and the heights are averaged."""
    lefts, rights = [], []
    for pts in lines:
        (u0, v0), (u1, v1) = pts
        if abs(u1 - u0) < 1e-9:
            raise ConversionError(where, f"a vertical horizon line at u = {u0:g} cannot be used")
        slope = (v1 - v0) / (u1 - u0)
        lefts.append(v0 - slope * u0)
        rights.append(v0 + slope * (width - u0))
    return [[0.0, float(np.mean(lefts))], [float(width), float(np.mean(rights))]]


def scene_dict(size: tuple[int, int], image_path: str | None, camera: dict, **parts) -> dict:
    """A ``creference-scene/2`` dict with its keys in the file's order: ``image`` (``size`` in
    pixels, and its ``path`` unless None), ``camera`` unless empty, then ``parts`` (``horizon``,
    ``classes``, ``targets``, ``references``, …) in the order given, but for those that are None."""
    scene: dict[str, Any] = {"format": SCENE_FORMAT, "image": {"width": size[0], "height": size[1]}}
    if image_path is not None:
        scene["image"]["path"] = image_path
    if camera:
        scene["camera"] = camera
    return scene | {k: v for k, v in parts.items() if v is not None}


def checked_scene(scene: dict, where: str, origins: dict[str, str] | None = None) -> dict:
    """``scene`` after :func:`parse_scene` accepted it (warnings silenced) and it was found
    writable (JSON with finite numbers only: what :func:`write_scenes` writes). A
    :class:`SceneError`, or a value that cannot be written, becomes a :class:`ConversionError`
    naming ``where`` and, through ``origins`` (a key-path prefix such as
    ``targets[1].dimension_lines[0]`` → ``annotation 7, region 'a1'``; the last matching prefix
    wins), the region the bad value came from."""
    def fail(path, problem):
        origin = None
        for prefix, name in (origins or {}).items():
            if path == prefix or path.startswith(prefix + ".") or path.startswith(prefix + "["):
                origin = name
        raise ConversionError(f"{where}, {origin}" if origin else where, f"{path}: {problem}") from None

    try:
        parse_quietly(scene)
    except SceneError as exc:
        fail(exc.path, exc.problem)
    bad = _unwritable(scene)
    if bad is not None:
        fail(bad[0], f"{_short(bad[1])} cannot be written (a scene file holds finite numbers, text, "
                     "lists and objects)")
    return scene


def classes_block(targets: list[dict], own: Any, extra: dict[str, SizePrior] | None) -> dict | None:
    """A scene's ``classes``: its own (from the export, as given) plus the classes of a
    ``--classes`` file that its size-less targets use and its own do not define."""
    out = dict(own) if isinstance(own, dict) else own
    if extra:
        used = [t["class"] for t in targets if t.get("dimensions_m") is None and t.get("class") in extra]
        add = {c: prior_entry(extra[c]) for c in dict.fromkeys(used) if not (isinstance(out, dict) and c in out)}
        if add:
            out = {**(out or {}), **add}
    return out or None


def _unwritable(obj: Any) -> tuple[str, Any] | None:
    """The key path and value of the first thing in ``obj`` that JSON with finite numbers cannot
    hold (None: it can); iterative, so a deeply nested value cannot exhaust the stack."""
    stack = [("", obj, 0)]
    while stack:
        path, value, depth = stack.pop()
        if depth > 200:
            return path, "(nested more than 200 levels deep)"
        if isinstance(value, dict):
            for k, v in reversed(list(value.items())):
                if not isinstance(k, str):
                    return path, k
                stack.append((f"{path}.{k}" if path else k, v, depth + 1))
        elif isinstance(value, (list, tuple)):
            stack.extend((f"{path}[{i}]", v, depth + 1) for i, v in reversed(list(enumerate(value))))
        elif isinstance(value, float) and not math.isfinite(value):
            return path, value
        elif not (value is None or isinstance(value, (str, int, float))):
            return path, value
    return None


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_name(text: str) -> str:
    """A file stem from a target id or image name: other characters become ``_``."""
    name = _UNSAFE.sub("_", str(text)).strip("._") or "target"
    return name[:120]


def open_input(path: str | Path):
    """``path`` opened for reading (binary); a missing, unreadable or folder path is a
    :class:`ConversionError` naming it."""
    try:
        return open(path, "rb")
    except OSError as exc:
        raise _input_error(path, exc) from None


def _input_error(path: str | Path, exc: OSError) -> ConversionError:
    if isinstance(exc, FileNotFoundError):
        return ConversionError(str(path), "no such file (it does not exist)")
    if isinstance(exc, IsADirectoryError):
        return ConversionError(str(path), "is a folder, expected a file")
    return ConversionError(str(path), f"cannot be read: {exc.strerror or exc}")


#: Largest ``--targets`` table read (bytes): a row is a few dozen bytes.
MAX_TABLE_BYTES = 64 << 20


def read_input(path: str | Path, limit: int) -> bytes:
    """The bytes of an input file of at most ``limit`` bytes (:func:`open_input`'s errors; a larger
    file is a :class:`ConversionError` naming it and the limit)."""
    try:
        return read_capped(path, limit, ConversionError)
    except OSError as exc:
        raise _input_error(path, exc) from None


_TABLE_COLUMNS = ("target_id", "length_m", "width_m", "height_m")


@dataclass(frozen=True, eq=False)  # rows are told apart by identity (a row is used, or not)
class TableRow:
    """One row of the ``--targets`` table: where it is (``"t.csv line 3"``), the image it is for
    (None: every image), the target id (None: a camera-only row of its image), the target's size
    (m) and the focal length (px), each None when the row does not give it."""

    line: str
    image: str | None
    target_id: str | None
    size: dict[str, float] | None
    focal_length_px: float | None


class TargetTable:
    """The ``--targets`` table, for one import: known sizes and focal lengths by image and target.

    A row with an ``image`` applies to the targets of that image only (the image's name in the
    export, or just its file name); a row without one applies to the target id on every image
    (and a note says so when that is more than one image). A row with an image and no target id
    gives the image's focal length only. :meth:`notes` reports rows applied to several images and
    image rows that matched no image.
    """

    def __init__(self, rows: Iterable[TableRow]):
        self.rows = tuple(rows)
        self._index: dict[tuple, TableRow] = {}
        for r in self.rows:
            other = self._index.setdefault((r.image, r.target_id), r)
            if other is not r:
                what = " and ".join(f"{k} {v!r}" for k, v in (("image", r.image), ("target_id", r.target_id))
                                    if v is not None)
                raise ConversionError(r.line, f"{what} appears twice (also {other.line})")
        self._used: dict[TableRow, dict[str, None]] = {}

    @classmethod
    def of(cls, table: Any) -> "TargetTable":
        """A fresh table for one import (its own record of which rows were used) from a
        :class:`TargetTable`, a ``{target_id: {"length", "width", "height"[, "focal_length_px"]}}``
        dict (every image), or None (an empty table)."""
        if table is None or isinstance(table, TargetTable):
            return cls(() if table is None else table.rows)
        return cls(TableRow(f"targets[{tid!r}]", None, tid,
                            {k: row[k] for k in SIZE_KEYS} if "length" in row else None,
                            row.get("focal_length_px")) for tid, row in table.items())

    def row(self, images: list[str], target_id: str | None, where: str) -> TableRow | None:
        """The row for ``target_id`` on the image named ``images`` (its names in the export; the
        first names it in notes): the image's own row, else the row without an image, else None."""
        names = dict.fromkeys(n for name in images for n in (name, PurePosixPath(name).name) if n)
        found = list(dict.fromkeys(self._index[(n, target_id)] for n in names if (n, target_id) in self._index))
        if len(found) > 1:
            raise ConversionError(where, f"the --targets rows {found[0].line} and {found[1].line} both match "
                                         f"this image (image {found[0].image!r} and {found[1].image!r})")
        row = found[0] if found else self._index.get((None, target_id))
        if row is not None:
            self._used.setdefault(row, {})[images[0] if images else ""] = None
        return row

    def size(self, images: list[str], target_id: str, dims: dict[str, float] | None, where: str,
             required: bool = False) -> dict[str, float] | None:
        """The target's size (m): the export's ``dims`` or its row's (they must agree when both
        give one), or None (``required``, for a target without a class: a :class:`ConversionError`)."""
        row = self.row(images, target_id, where)
        given = row.size if row is not None else None
        if dims is not None and given is not None:
            for k in SIZE_KEYS:
                if not math.isclose(dims[k], given[k], rel_tol=1e-9):
                    raise ConversionError(where, f"target {target_id!r}: {k} {dims[k]:g} m in the export "
                                                 f"but {given[k]:g} m in the --targets table ({row.line})")
        size = dims if dims is not None else given
        if size is None and required:
            hint = " or in the --targets table" if self.rows else " (or pass --targets FILE.csv)"
            raise ConversionError(where, f"no size for target {target_id!r}: give length, width and "
                                         f"height in metres in the export{hint}, or its class")
        return None if size is None else dict(size)

    def focal(self, images: list[str], target_ids: Iterable[str], where: str) -> float | None:
        """The known focal length (px) of an image: its camera-only row's and its targets' rows'
        (one camera: the rows that give one must agree), or None."""
        found: dict[float, TableRow] = {}
        for tid in (None, *target_ids):
            row = self.row(images, tid, where)
            if row is not None and row.focal_length_px is not None:
                found.setdefault(row.focal_length_px, row)
        if len(found) > 1:
            (a, ra), (b, rb) = list(found.items())[:2]
            raise ConversionError(where, f"the --targets table gives focal lengths {a:g} px ({ra.line}) and "
                                         f"{b:g} px ({rb.line}) for one photo (one camera)")
        return next(iter(found), None)

    def notes(self) -> list[str]:
        """What the user should know about this import's use of the table (see the class)."""
        shared = [(r, list(self._used[r])) for r in self.rows
                  if r.image is None and len(self._used.get(r, ())) > 1]
        unused = [r for r in self.rows if r.image is not None and r not in self._used]
        out = []
        if shared:
            r, imgs = shared[0]
            more = f" (and {len(shared) - 1} more row(s) like it)" if len(shared) > 1 else ""
            out.append(f"{r.line}: target {r.target_id!r} has no image and was applied on {len(imgs)} images "
                       f"({', '.join(map(repr, imgs[:3]))}{', ...' if len(imgs) > 3 else ''}){more}; if these "
                       "are different objects, give the rows an image column")
        if unused:
            lines = ", ".join(f"{r.line} (image {r.image!r})" for r in unused[:3])
            out.append(f"--targets: no image of the export matches {lines}"
                       f"{f' and {len(unused) - 3} more row(s)' if len(unused) > 3 else ''}; not used")
        return out


def load_target_table(path: str | Path) -> TargetTable:
    """The ``--targets`` table from a CSV file with the header
    ``target_id,length_m,width_m,height_m`` and the optional columns ``image`` and
    ``focal_length_px`` (other columns are ignored). A row gives a target's size (all three or
    none), a focal length, or both; a row with an image and an empty ``target_id`` gives that
    image's focal length only."""
    path = Path(path)
    try:
        text = read_input(path, MAX_TABLE_BYTES).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ConversionError(str(path), "not UTF-8 text (expected a CSV file)") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    try:
        fields = reader.fieldnames or []
        missing = [c for c in _TABLE_COLUMNS if c not in fields]
        if missing:
            raise ConversionError(str(path), f"missing column(s) {missing}; expected a header "
                                             f"{','.join(_TABLE_COLUMNS)}[,focal_length_px][,image]")
        rows = []
        for row in reader:
            where = f"{path.name} line {reader.line_num}"
            cell = {k: v.strip() if isinstance(v, str) else "" for k, v in row.items() if isinstance(k, str)}
            if not any(cell.values()):
                continue
            image, tid = cell.get("image") or None, cell.get("target_id") or None
            size = size_fields(cell, where)
            focal = (number_field(cell["focal_length_px"], where, "focal_length_px", positive=True)
                     if cell.get("focal_length_px") else None)
            if tid is None and (image is None or size is not None):
                raise ConversionError(where, "empty target_id (only a camera-only row, an image with a "
                                             "focal_length_px, may leave it empty)")
            if size is None and focal is None:
                raise ConversionError(where, f"the row for target {tid!r} gives no size and no focal_length_px")
            rows.append(TableRow(where, image, tid, size, focal))
    except csv.Error as exc:
        raise ConversionError(f"{path.name} line {reader.line_num}", f"not a valid CSV row: {exc}") from None
    return TargetTable(rows)


def image_file(image_dir: str | Path, name: str, out_dir: str | Path | None, where: str,
               notes: list[str]) -> str | None:
    """A scene's ``image.path`` for the image the export names ``name`` (a relative path such as
    ``street/000007.png``), in ``image_dir``: ``DIR/street/000007.png`` when that file exists, else
    the name with its leading folders dropped (``DIR/000007.png``). When no such file exists, a
    note names the image and the path is ``DIR/<file name>``; None when ``name`` has no file name.
    The path is relative to ``out_dir`` when there is one (and it can be)."""
    if "\0" in name:
        raise ConversionError(where, f"the image's name {_short(name)} holds a NUL character")
    parts = [p for p in PurePosixPath(name).parts if p not in ("/", ".", "..")]
    if not parts:
        notes.append(f"{where}: no file name in {name!r}; image.path not set")
        return None
    candidates = [Path(image_dir, *parts[i:]) for i in range(len(parts))]
    try:
        found = next((c for c in candidates if c.is_file()), None)
        if found is None:
            found = candidates[-1]
            notes.append(f"{where}: no image file {' or '.join(str(c) for c in candidates)}; image.path set to "
                         f"{str(found)!r} all the same (estimate cannot use the photo until it is there)")
        if out_dir is None:
            return str(found)
        try:
            return os.path.relpath(found.resolve(), Path(out_dir).resolve())
        except ValueError:  # another drive (Windows)
            return str(found.resolve())
    except OSError as exc:  # a name longer than the file system takes, …: this image only
        raise ConversionError(where, f"the image's name {_short(name)} cannot be looked up in the image folder: "
                                     f"{exc.strerror or exc}") from None


def write_scenes(scenes: Iterable[ImportedScene], out_dir: str | Path, overwrite: bool = False
                 ) -> tuple[list[tuple[ImportedScene, Path, str]], list[ConversionError]]:
    """Write each scene to ``out_dir/<name>.json`` atomically (temporary file, then rename).

    A file already there that holds another scene (edited by hand, or another export's) is kept
    and its scene refused (a :class:`ConversionError` naming the file) unless ``overwrite``.
    Returns (scene, path, ``"wrote"``, ``"replaced"`` or ``"unchanged"``) of each scene written
    and the refusals."""
    from .validation import read_json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done, refused = [], []
    for s in scenes:
        path = out / f"{s.name}.json"
        how = "wrote"
        if path.exists():
            try:
                same = read_json(path) == s.scene
            except (OSError, ValueError):
                same = False
            if not same and not overwrite:
                refused.append(ConversionError(str(path), f"exists and is not the scene of {s.source} (edited by "
                                                          "hand?); kept it: pass --overwrite to replace it"))
                continue
            how = "unchanged" if same else "replaced"
        if how != "unchanged":
            atomic_write_json(path, s.scene)
        done.append((s, path, how))
    return done, refused


def unique_names(scenes: list[ImportedScene]) -> tuple[list[ImportedScene], list[ConversionError]]:
    """Drop (and report) a scene whose file name an earlier scene already took."""
    seen: dict[str, str] = {}
    kept, errors = [], []
    for s in scenes:
        key = s.name.lower()  # case-insensitive file systems
        if key in seen:
            errors.append(ConversionError(s.source, f"file name {s.name + '.json'!r} is already used "
                                                    f"by {seen[key]} (each photo needs a name of its own)"))
            continue
        seen[key] = s.source
        kept.append(s)
    return kept, errors
