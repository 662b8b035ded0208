"""The batch folder's files for one scene: where they are, when a result is up to date, and how
a result or an error is recorded (atomically, the scene copy before its result)."""

from __future__ import annotations

from pathlib import Path

from ... import __version__
from ...io.files import atomic_write_json
from ...io.scene import scene_to_dict
from ...io.validation import read_json

__all__ = ["ERROR_FORMAT", "layout", "result_paths", "up_to_date", "record_error", "record_result"]

ERROR_FORMAT = "creference-batch-error/1"


def layout(out: str | Path, key: str) -> dict[str, Path]:
    """The batch folder's files for ``key``: ``result``, ``scene`` (the copy) and ``error``."""
    out = Path(out)
    return {"result": out / "results" / f"{key}.json", "scene": out / "scenes" / f"{key}.json",
            "error": out / "errors" / f"{key}.json"}


def result_paths(batch_dir: str | Path, *, check: bool = False) -> dict[str, Path]:
    """KEY → path of every result in a batch folder's ``results/``, sorted; the hidden temporary
    file of a write that was killed (io/files.py) left out. With ``check``, FileNotFoundError
    saying whether the folder is missing or is not a batch folder (no ``results/``)."""
    root = Path(batch_dir) / "results"
    if check and not root.is_dir():
        why = "not a batch folder (no results/ inside)" if Path(batch_dir).is_dir() else "no such folder"
        raise FileNotFoundError(2, why, str(batch_dir))
    paths = {p.relative_to(root).with_suffix("").as_posix(): p for p in sorted(root.rglob("*.json"))}
    return {k: p for k, p in paths.items() if not any(part.startswith(".") for part in k.split("/"))}


def up_to_date(paths: dict, fingerprint: str, settings: dict, ground: dict | None = None) -> bool:
    """Whether the stored result is the scene's as it is now, made with these settings and, unless
    ``ground`` is None, under this ground prior (:func:`~creference_bayes.pipeline.expected_ground`;
    a result that records none is taken as made under
    :data:`~creference_bayes.pipeline.UNRECORDED_GROUND`)."""
    from ...pipeline import UNRECORDED_GROUND

    try:
        d = read_json(paths["result"])
        return (d.get("scene_id", {}).get("sha256") == fingerprint
                and d.get("batch", {}).get("settings") == settings
                and (ground is None or (d.get("provenance", {}).get("ground") or UNRECORDED_GROUND) == ground))
    except (OSError, ValueError, AttributeError):
        return False


def record_error(paths: dict, si, stage: str, error: str, tb: str | None = None) -> None:
    """Write ``errors/KEY.json`` for the scene input ``si`` (and drop its stale result and copy)."""
    for stale in ("result", "scene"):  # a result of an older version of the scene is not its result
        paths[stale].unlink(missing_ok=True)
    doc = {"format": ERROR_FORMAT, "key": si.key, "source": str(si.path.resolve()), "stage": stage,
           "error": error}
    if tb:
        doc["traceback"] = tb
    atomic_write_json(paths["error"], doc)


def record_result(paths: dict, si, scene, result: dict, seed: int, settings: dict) -> None:
    """Write the scene copy, then the result with its ``batch`` block; drop an old error record."""
    atomic_write_json(paths["scene"], scene_to_dict(scene))  # first the copy, then the result
    result["batch"] = {"key": si.key, "source": str(si.path.resolve()),
                       "scene_copy": f"scenes/{si.key}.json",
                       "seed": seed, "settings": settings, "creference_version": __version__}
    atomic_write_json(paths["result"], result, inline_numbers="draws" in result)
    paths["error"].unlink(missing_ok=True)
