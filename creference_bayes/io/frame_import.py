"""What the Label Studio and CVAT importers share for frames (``creference-scene/2``, every target
of one photo in one file): a target's size from the export or the ``--targets`` table, the
classes block, the check every converted frame passes, and comparing two frames.

A target of a frame needs no size: without one its class's size prior applies (the scene's own
``classes``, a ``--classes`` file given to the importer, or the shipped KITTI classes).
"""

from __future__ import annotations

import math
from typing import Any, Iterable

from ..models.size_priors import SIZE_KEYS, SizePrior
from .annotation_tools import ConversionError, checked_with
from .frame_scene import frame_to_dict, parse_frame
from .scene import scene_differences

__all__ = ["frame_size", "frame_focal", "classes_block", "checked_frame", "frame_differences", "is_frame"]


def is_frame(scene: Any) -> bool:
    """Whether a scene (a dict or a parsed scene) is a ``creference-scene/2`` frame."""
    if isinstance(scene, dict):
        return scene.get("format") == "creference-scene/2"
    return getattr(scene, "format", None) == "creference-scene/2"


def frame_size(target_id: str, dims: dict[str, float] | None, table: dict | None,
               where: str) -> dict[str, float] | None:
    """A frame target's known size (m): the export's ``dims`` or the ``--targets`` table's row
    (they must agree when both give it), or None (its class's size prior applies)."""
    row = (table or {}).get(target_id)
    if dims is not None and row is not None:
        for k in SIZE_KEYS:
            if not math.isclose(dims[k], row[k], rel_tol=1e-9):
                raise ConversionError(where, f"target {target_id!r}: {k} {dims[k]:g} m in the export "
                                             f"but {row[k]:g} m in the --targets table")
    if dims is not None:
        return dict(dims)
    return None if row is None else {k: row[k] for k in SIZE_KEYS}


def frame_focal(target_ids: Iterable[str], table: dict | None, where: str) -> float | None:
    """The focal length (px) the ``--targets`` table gives for a frame's targets (they share one
    camera, so the rows that give one must agree), or None."""
    found = {}
    for tid in target_ids:
        f = ((table or {}).get(tid) or {}).get("focal_length_px")
        if f is not None:
            found.setdefault(f, tid)
    if len(found) > 1:
        (a, ta), (b, tb) = list(found.items())[:2]
        raise ConversionError(where, f"the --targets table gives focal lengths {a:g} px ({ta!r}) and "
                                     f"{b:g} px ({tb!r}) for targets of one photo (one camera)")
    return next(iter(found), None)


def classes_block(targets: list[dict], own: Any, extra: dict[str, SizePrior] | None) -> dict | None:
    """The frame's ``classes``: its own (from the export, as given) plus the classes of a
    ``--classes`` file that its size-less targets use and its own do not define."""
    out = dict(own) if isinstance(own, dict) else own
    if extra:
        used = [t["class"] for t in targets if t.get("dimensions_m") is None and t.get("class") in extra]
        add = {c: {**{f"{k}_m": v for k, v in zip(SIZE_KEYS, extra[c].median_m)}, "log_sd": list(extra[c].log_sd)}
               for c in dict.fromkeys(used) if not (isinstance(out, dict) and c in out)}
        if add:
            out = {**(out or {}), **add}
    return out or None


def checked_frame(scene: dict, where: str, origins: dict[str, str] | None = None) -> dict:
    """Validate a converted frame with :func:`~.frame_scene.parse_frame`; a failure becomes a
    :class:`ConversionError` naming ``where`` and, through ``origins`` (a key-path prefix such as
    ``targets[1].dimension_lines[0]`` → ``annotation 7, region 'a1'``; later, longer prefixes
    win), the region the bad value came from."""
    return checked_with(parse_frame, scene, where, origins)


def frame_differences(a: Any, b: Any, atol: float = 1e-9, drop: Iterable[str] = ()) -> list[str]:
    """Where two frames differ, one line each (an empty list: the same frame); both are
    normalised by ``parse_frame`` then ``frame_to_dict`` (see ``scene_differences``)."""
    def normalise(d):
        return frame_to_dict(d if not isinstance(d, dict) else parse_frame(d))

    return scene_differences(a, b, atol=atol, drop=drop, normalise=normalise)

