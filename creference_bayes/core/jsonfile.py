"""Reading JSON from outside the process, bounded: a file's size, its nesting and its integers are
limited, and every refusal is one error naming the file (the caller's error class: the scene
loader's ``SceneError``, a confidence map's ``ConfidenceMapError``). Standard library only, so that
every layer of the package reads outside JSON the same way.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

__all__ = ["MAX_JSON_BYTES", "MAX_JSON_DEPTH", "MAX_INT_DIGITS", "read_json", "read_capped", "loads_json", "json_depth"]

#: Largest JSON file read from outside (bytes): far above any scene, result or tool export.
MAX_JSON_BYTES = 1 << 30
#: Deepest nesting of lists and objects in a JSON file read from outside. A scene is 6 deep, a
#: result or a Label Studio export about 8; far deeper input only costs recursion later.
MAX_JSON_DEPTH = 64
#: Most digits of a JSON integer: more is refused, not read as an integer no float holds (a float
#: ends near 1.8e308) or Python cannot print (its limit is 4300 digits).
MAX_INT_DIGITS = 300

#: ``error(name, problem)``: the exception a refusal raises (``name``: the file).
ErrorClass = Callable[[str, str], Exception]


def read_json(path: str | Path, error: ErrorClass, *, max_depth: int | None = MAX_JSON_DEPTH,
              parse_int: Callable[[str], Any] | None = None) -> Any:
    """The decoded JSON of the file ``path``; ``error(path, problem)`` raised when it is larger than
    :data:`MAX_JSON_BYTES`, not UTF-8 (a BOM is allowed), not JSON, uses ``NaN``/``Infinity``, nests
    deeper than ``max_depth`` (None: as deep as the decoder goes) or has an integer of more than
    :data:`MAX_INT_DIGITS` digits (``parse_int``: read integers otherwise). Missing or unreadable
    files raise ``OSError`` naming the file."""
    raw = read_capped(path, MAX_JSON_BYTES, error)
    return loads_json(raw, str(path), error, max_depth=max_depth, parse_int=parse_int)


def read_capped(path: str | Path, limit: int, error: ErrorClass) -> bytes:
    """The bytes of the file ``path``, never more than ``limit`` + 1 read: ``error(path, problem)``
    raised when it is larger than ``limit`` bytes. Missing or unreadable files raise ``OSError``
    naming the file (a failed read too, not only a failed open)."""
    try:
        with open(path, "rb") as f:
            raw = f.read(limit + 1)
    except OSError as exc:
        if exc.filename is None:
            raise type(exc)(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise
    if len(raw) > limit:
        raise error(str(path), f"larger than {limit} bytes; refused")
    return raw


def loads_json(raw: bytes | str, name: str, error: ErrorClass, *, max_depth: int | None = MAX_JSON_DEPTH,
               parse_int: Callable[[str], Any] | None = None) -> Any:
    """:func:`read_json` of bytes or text (``name``: what the errors name)."""
    def constant(text):
        raise error(name, f"non-standard JSON constant {text} (numbers must be finite)")

    def integer(text):
        if len(text.lstrip("-")) > MAX_INT_DIGITS:
            raise error(name, f"an integer of {len(text.lstrip('-'))} digits (at most {MAX_INT_DIGITS})")
        return int(text)

    try:
        text = raw.decode("utf-8-sig") if isinstance(raw, bytes) else raw.removeprefix("\ufeff")
        data = json.loads(text, parse_constant=constant, parse_int=parse_int or integer)
    except UnicodeDecodeError as exc:
        raise error(name, f"not UTF-8 text: byte {exc.start} is {raw[exc.start:exc.start + 1]!r}") from None
    except json.JSONDecodeError as exc:
        raise error(name, f"not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except RecursionError:
        raise error(name, "JSON nested too deeply") from None
    if max_depth is not None and json_depth(data) > max_depth:
        raise error(name, f"JSON nested more than {max_depth} deep")
    return data


def json_depth(value: Any) -> int:
    """How deep lists and objects nest in decoded JSON (a number or string: 0, ``[]``: 1), found
    without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (list, dict)):
            deepest = max(deepest, d)
            stack.extend((c, d + 1) for c in (v.values() if isinstance(v, dict) else v)
                         if isinstance(c, (list, dict)))
    return deepest
