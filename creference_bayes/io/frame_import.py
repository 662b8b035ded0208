"""What the Label Studio and CVAT importers share for frames (``creference-scene/2``, every target
of one photo in one file): the classes block, the check every converted frame passes, and
comparing two frames (a target's size and the focal length from the ``--targets`` table are
:class:`~.annotation_tools.TargetTable`'s).

A target of a frame needs no size: without one its class's size prior applies (the scene's own
``classes``, a ``--classes`` file given to the importer, or the shipped KITTI classes).
"""

from __future__ import annotations

from typing import Any, Iterable

from ..models.size_priors import SIZE_KEYS, SizePrior
from .annotation_tools import checked_with
from .frame_scene import frame_to_dict, parse_frame
from .scene import scene_differences

__all__ = ["classes_block", "checked_frame", "frame_differences", "is_frame"]


def is_frame(scene: Any) -> bool:
    """Whether a scene (a dict or a parsed scene) is a ``creference-scene/2`` frame."""
    if isinstance(scene, dict):
        return scene.get("format") == "creference-scene/2"
    return getattr(scene, "format", None) == "creference-scene/2"


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

