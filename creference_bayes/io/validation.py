"""Validating decoded JSON, one value at a time, with errors that name the key path and the value.

The helpers of the scene loader (:mod:`.scene`) and the tool importers: every check raises
:class:`SceneError`, whose message starts with the offending key path (``references[2].unit``)
and quotes the value (cut to :data:`MAX_REPR` characters, so a message stays one line).
"""

from __future__ import annotations

import math
import unicodedata
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core import jsonfile
from ..core.jsonfile import MAX_INT_DIGITS, MAX_JSON_BYTES, MAX_JSON_DEPTH, json_depth

__all__ = ["SceneError", "SceneWarning", "near_miss", "read_json", "loads_json", "json_depth", "MAX_REPR",
           "MIN_SEGMENT_PX", "NEAR_MISS_EDITS", "MAX_JSON_BYTES", "MAX_JSON_DEPTH", "MAX_INT_DIGITS"]

#: Longest ``repr`` of an offending value quoted in an error message.
MAX_REPR = 60
#: Segments shorter than this (pixels) count as zero-length.
MIN_SEGMENT_PX = 1e-6
#: An unknown key this many edits (or fewer) from a known key of the same object is taken for a
#: typo of it and rejected (:func:`near_miss`); keys farther from every known key only warn.
NEAR_MISS_EDITS = 2


class SceneError(ValueError):
    """An invalid scene. ``path`` is the offending key path, e.g. ``references[2].unit``."""

    def __init__(self, path: str, problem: str):
        self.path = path
        self.problem = " ".join(str(problem).split())  # always one line
        super().__init__(f"{path}: {self.problem}" if path else self.problem)


class SceneWarning(UserWarning):
    """Something in a scene was ignored or assumed (unknown keys, for example)."""


def _short(value: Any) -> str:
    """``repr(value)``, cut to :data:`MAX_REPR` characters (a message stays one short line)."""
    try:
        text = repr(value)
    except RecursionError:  # nested too deeply to print (decoded JSON has no cycles)
        return f"a {type(value).__name__} nested too deeply to print"
    except ValueError:  # an integer of more digits than Python prints
        text = f"an integer of about {value.bit_length() * 0.30103:.0f} digits"
    return text if len(text) <= MAX_REPR else text[:MAX_REPR - 3] + "..."


def _got(value: Any) -> str:
    return f"got {'null' if value is None else type(value).__name__} {_short(value)}"


def _get(obj: dict, key: str, path: str) -> Any:
    if key not in obj:
        raise SceneError(_join(path, key), "missing required key")
    return obj[key]


def _join(path: str, key: Any) -> str:
    if isinstance(key, int) and not isinstance(key, bool):
        return f"{path}[{key}]"
    key = key if isinstance(key, str) and key.isprintable() and key else _short(key)
    return f"{path}.{key}" if path else key


def _dict(value: Any, path: str) -> dict:
    if not isinstance(value, dict):
        raise SceneError(path, f"expected an object, {_got(value)}")
    return value


def _list(value: Any, path: str) -> list:
    if not isinstance(value, list):
        raise SceneError(path, f"expected a list, {_got(value)}")
    return value


def _number(value: Any, path: str, *, positive: bool = False, nonneg: bool = False,
            lo: float | None = None, hi: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(path, f"expected a number, {_got(value)}")
    try:
        x = float(value)
    except OverflowError:  # an integer too large for a float
        x = math.inf
    if not math.isfinite(x):
        raise SceneError(path, f"expected a finite number, got {_short(value)}")
    if positive and x <= 0:
        raise SceneError(path, f"expected a positive number, got {_short(value)}")
    if nonneg and x < 0:
        raise SceneError(path, f"expected a number >= 0, got {_short(value)}")
    if lo is not None and x < lo or hi is not None and x > hi:
        raise SceneError(path, f"expected a number in [{lo}, {hi}], got {_short(value)}")
    return x


def _string(value: Any, path: str, *, optional: bool = True) -> str | None:
    if value is None and optional:
        return None
    if not isinstance(value, str):
        raise SceneError(path, f"expected a string, {_got(value)}")
    return value


def _name(value: Any, path: str, *, optional: bool = True) -> str | None:
    """A name (a target's id or class, a worker, a camera): a string without control characters
    (NUL, line breaks, tabs, …) or lone surrogates, as names end up in file names, CSV files, KITTI
    label files and NetCDF variables."""
    value = _string(value, path, optional=optional)
    bad = next((c for c in value or "" if unicodedata.category(c) in ("Cc", "Cs")), None)
    if bad is not None:
        raise SceneError(path, f"control character U+{ord(bad):04X} in {_short(value)}: names end up in "
                               "file names and tables, give plain text")
    return value


def _point(value: Any, path: str) -> np.ndarray:
    p = _list(value, path)
    if len(p) != 2:
        raise SceneError(path, f"expected a point [u, v], got {_short(p)}")
    return np.array([_number(c, _join(path, j)) for j, c in enumerate(p)])


def _points(value: Any, path: str, n: int) -> np.ndarray:
    pts = _list(value, path)
    if len(pts) != n:
        raise SceneError(path, f"expected {n} points, got {len(pts)}: {_short(pts)}")
    return np.array([_point(p, _join(path, i)) for i, p in enumerate(pts)])


def _check_inside(pts: np.ndarray, path: str, width: int, height: int, margin: float) -> None:
    mx, my = margin * width, margin * height
    for i, (u, v) in enumerate(pts):
        if not (-mx <= u <= width + mx and -my <= v <= height + my):
            raise SceneError(_join(path, i),
                             f"point [{u:g}, {v:g}] is far outside the {width}x{height} image")


def _check_segment(a: np.ndarray, b: np.ndarray, path: str, what: str = "line") -> None:
    if np.hypot(*(b - a)) < MIN_SEGMENT_PX:
        raise SceneError(path, f"zero-length {what} from [{a[0]:g}, {a[1]:g}] to [{b[0]:g}, {b[1]:g}]")


def _edit_distance(a: str, b: str) -> int:
    """Optimal-string-alignment distance: insertions, deletions, substitutions and swaps of two
    neighbouring characters each cost 1 (``heigth`` is one edit from ``height``)."""
    prev2, prev = None, list(range(len(b) + 1))
    for i in range(1, len(a) + 1):
        cur = [i] + [0] * len(b)
        for j in range(1, len(b) + 1):
            cur[j] = min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (a[i - 1] != b[j - 1]))
            if i > 1 and j > 1 and a[i - 1] == b[j - 2] and a[i - 2] == b[j - 1]:
                cur[j] = min(cur[j], prev2[j - 2] + 1)
        prev2, prev = prev, cur
    return prev[-1]


def near_miss(key: str, known) -> str | None:
    """The known key that ``key`` is most likely a typo of, or None.

    Keys are compared in lower case with ``-`` and spaces read as ``_``. A near miss is at most
    :data:`NEAR_MISS_EDITS` edits away (insertions, deletions, substitutions, swaps of neighbours;
    one edit only for known keys of up to 7 characters, so neither ``note`` nor ``order`` is taken
    for ``mode`` or ``worker``), or a known key with a few characters added or dropped at one end
    (``focal_length`` for ``focal_length_px``: at most a third of the known key).
    """
    def norm(k: str) -> str:
        return k.lower().replace("-", "_").replace(" ", "_")

    k = norm(key)
    best, best_d = None, None
    for cand in sorted(known):
        c = norm(cand)
        limit = 1 if len(c) <= 7 else NEAR_MISS_EDITS
        d = _edit_distance(k, c)
        end = (c.startswith(k) or c.endswith(k) or k.startswith(c) or k.endswith(c)) and \
            min(len(k), len(c)) >= 4 and abs(len(k) - len(c)) <= len(c) / 3
        if (d <= limit or end) and (best_d is None or d < best_d):
            best, best_d = cand, d
    return best


def _warn_unknown(obj: dict, known: set[str], path: str, sink: list[str]) -> None:
    """Unknown keys: an error when one is a near miss of a known key (:func:`near_miss`), else a
    warning in ``sink``."""
    for key in obj:
        if key in known:
            continue
        guess = near_miss(key, known) if isinstance(key, str) else None
        if guess is not None:
            raise SceneError(_join(path, key), f"unknown key; did you mean {guess!r}?")
        sink.append(f"{_join(path, key)}: unknown key ignored")


#: The scene formats this package reads.
SCENE_FORMATS = ("creference-scene/1", "creference-scene/2")


def check_scene_format(value: Any) -> str:
    """The ``format`` of a scene, or :class:`SceneError` saying what was expected and, for a result
    file or a newer version of the format, what to do."""
    shown = " or ".join(repr(f) for f in SCENE_FORMATS)
    if isinstance(value, str) and value.startswith("creference-result/"):
        raise SceneError("format", f"expected a scene ({shown}), got the result file format {value!r}: "
                                   "give the scene the result was made from")
    if isinstance(value, str) and value.startswith("creference-scene/") and value not in SCENE_FORMATS:
        raise SceneError("format", f"expected {shown}, got {value!r}: a format version this release of "
                                   "creference_bayes does not know (a newer release may)")
    if value not in SCENE_FORMATS:
        raise SceneError("format", f"expected {shown}, got {_short(value)}")
    return value


def read_json(path: str | Path, *, max_depth: int | None = MAX_JSON_DEPTH,
              parse_int: Callable[[str], Any] | None = None) -> Any:
    """The decoded JSON of a file from outside the process (a scene, a result, a tool's export, a
    classes file, …): :func:`creference_bayes.core.jsonfile.read_json` (its limits and refusals),
    refusals as :class:`SceneError` naming the file. Missing or unreadable files raise ``OSError``
    naming the file."""
    return jsonfile.read_json(path, SceneError, max_depth=max_depth, parse_int=parse_int)


def loads_json(raw: bytes | str, name: str, *, max_depth: int | None = MAX_JSON_DEPTH,
               parse_int: Callable[[str], Any] | None = None) -> Any:
    """:func:`read_json` of bytes or text (``name``: what the errors name)."""
    return jsonfile.loads_json(raw, name, SceneError, max_depth=max_depth, parse_int=parse_int)
