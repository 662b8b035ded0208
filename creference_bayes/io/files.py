"""Writing files so that nothing is ever half-written: a temporary file beside the target, then an
atomic rename (``os.replace``). A reader sees the old file or the new one, never a mix, and a
process killed mid-write leaves at most a ``.tmp`` file behind, never a truncated result.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import os
import re
import secrets
import stat
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator

__all__ = ["atomic_write_text", "atomic_write_bytes", "atomic_write_json", "atomic_write_csv", "atomic_write_set",
           "atomic_path", "read_bytes", "read_text", "read_csv_rows", "csv_cell"]


def read_bytes(path: str | Path) -> bytes:
    """The bytes of a file. An error while reading (not only while opening) names the file:
    ``Path.read_bytes`` raises a bare ``OSError`` (``Input/output error``, no file name) when the
    read itself fails. (A file from outside with a size limit: :func:`~creference_bayes.core.jsonfile.read_capped`.)"""
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as exc:
        if exc.filename is None:
            raise type(exc)(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


def read_text(path: str | Path, encoding: str = "utf-8") -> str:
    """The text of a file (:func:`read_bytes`; a ``UnicodeDecodeError`` as from ``Path.read_text``)."""
    return read_bytes(path).decode(encoding)


@contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """A temporary path beside ``path``; renamed onto ``path`` when the block ends without error.

    For writers that want a file name (``fig.savefig``, ``InferenceData.to_netcdf``). The
    temporary name keeps ``path``'s suffix (or ``suffix``) so that such writers pick the right
    format. On an exception the temporary file is removed and ``path`` is untouched. A ``path``
    that is a symbolic link stays one: the file it points to is replaced (:func:`_target`); a file
    replaced keeps its mode (:func:`_new_temporary`).
    """
    path = _target(Path(path))
    tmp = _new_temporary(path, suffix or path.suffix)
    try:
        yield tmp
        _replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _target(path: Path) -> Path:
    """The file a write to ``path`` replaces: ``path``, or the file a symbolic link there points
    to (so that the user's link stays a link); checked not to be a folder, its folder made."""
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a folder, expected a file", str(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _replaced_mode(path: Path) -> int | None:
    """The permission bits of the file at ``path`` a write replaces (None: no file there)."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        return None


def _new_temporary(path: Path, suffix: str) -> Path:
    """Create an empty, new file beside ``path`` with the mode of the file it is to replace (a file
    only its owner may read stays so, also while the data go in), else the mode a plain
    ``open(path, "w")`` gives (0666 less the umask; ``tempfile.mkstemp`` would make it 0600, and
    the rename keeps that). It stays writable by its owner until :func:`_replace`."""
    mode = _replaced_mode(path)
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}{suffix}"
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666 if mode is None else 0o600))
        except FileExistsError:
            continue
        if mode is not None:
            os.chmod(tmp, mode | stat.S_IWUSR)
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(path))  # pragma: no cover


def _replace(tmp: Path, path: Path) -> None:
    """Rename ``tmp`` onto ``path``, with the mode of the file it replaces."""
    mode = _replaced_mode(path)
    if mode is not None and mode != stat.S_IMODE(tmp.stat().st_mode):
        os.chmod(tmp, mode)
    os.replace(tmp, path)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file, fsync, rename). Returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return path


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically. Returns the path."""
    return atomic_write_bytes(path, text.encode(encoding))


#: A JSON list of numbers only, as ``json.dumps(indent=…)`` spreads it over lines.
_NUMBER_LIST = re.compile(r"\[\s+(-?[0-9][-+0-9.eE]*(?:,\s+-?[0-9][-+0-9.eE]*)*)\s+\]")


def atomic_write_json(path: str | Path, data: Any, indent: int | None = 2, inline_numbers: bool = False) -> Path:
    """Write ``data`` as JSON (finite numbers only, a final newline) to ``path`` atomically.

    ``inline_numbers``: with ``indent``, a list of numbers only goes on one line (posterior draws:
    a result of a few hundred draws per quantity stays readable and about half the size)."""
    text = json.dumps(data, indent=indent, allow_nan=False)
    if inline_numbers and indent is not None:
        text = _NUMBER_LIST.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)
    return atomic_write_text(path, text + "\n")


def atomic_write_set(files: dict) -> list[Path]:
    """Write several files as one set (``files``: path → bytes): each in full (fsync) to a hidden
    temporary file beside it (:func:`_new_temporary`: with the mode of the file it replaces), and
    only when every one is written, each renamed over its file (a symbolic link: over the file it
    points to). An error while writing any of them (disk full, no permission) removes the
    temporary files and leaves every file as it was. Returns the paths."""
    tmps: dict[Path, tuple[Path, Path]] = {}
    try:
        for path, data in files.items():
            target = _target(Path(path))
            tmp = _new_temporary(target, target.suffix)
            tmps[Path(path)] = (tmp, target)
            with open(tmp, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        for tmp, target in tmps.values():
            _replace(tmp, target)
    except BaseException:
        for tmp, _ in tmps.values():
            tmp.unlink(missing_ok=True)
        raise
    return list(tmps)


#: First characters that make a spreadsheet read a cell as a formula (OWASP's CSV injection list),
#: and the quote that marks a cell escaped.
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "'")
_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?")


def _formula_like(text: str) -> bool:
    return text.startswith(_FORMULA_START) and not _NUMBER.fullmatch(text)


def csv_cell(value: Any) -> Any:
    """A CSV cell that a spreadsheet shows as text: a text beginning with ``=``, ``+``, ``-``,
    ``@``, a tab or a carriage return (a formula to a spreadsheet: a worker-typed target id
    ``=HYPERLINK(…)``), or with ``'``, gets a leading ``'``; a number (``-1.5``) stays a number.
    :func:`read_csv_rows` undoes it."""
    return "'" + value if isinstance(value, str) and _formula_like(value) else value


def atomic_write_csv(path: str | Path, rows: Iterable[dict], columns: Iterable[str]) -> Path:
    """Write ``rows`` (dicts by column) as CSV with a header, every cell through :func:`csv_cell`,
    atomically. Returns the path."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\r\n")  # quotes a lone \r (RFC 4180)
    writer.writeheader()
    writer.writerows({k: csv_cell(v) for k, v in row.items()} for row in rows)
    return atomic_write_text(path, buf.getvalue())


def read_csv_rows(text: str) -> list[dict]:
    """The rows of a CSV this package wrote (:func:`atomic_write_csv`), each a dict by column,
    the cells escaped by :func:`csv_cell` restored."""
    return [{k: v[1:] if isinstance(v, str) and v.startswith("'") and _formula_like(v[1:]) else v
             for k, v in row.items()} for row in csv.DictReader(io.StringIO(text, newline=""))]
