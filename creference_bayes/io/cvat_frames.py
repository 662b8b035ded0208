"""A CVAT image holding every target of its photo ↔ one ``creference-scene/2`` frame
(docs/import.md, "Frames").

An image is a frame when one of its ``target`` shapes carries a ``class`` attribute (or the
importer is told so: ``--frames``). Its ``target`` shapes are grouped by ``target_id`` (an image
with a single target may leave it empty: its id is then the image's name); a target's ``class``
and its size (``length_m``/``width_m``/``height_m``, or the ``--targets`` table) come from its
shapes, and without a size its class's size prior applies. A ``reference`` with a ``target_id`` names that
target in the frame; a direct one without is a ground segment of the photo, kept once.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import PurePosixPath
from typing import Any

from .annotation_tools import (REFERENCE_FIELDS, ConversionError, TargetScene, TargetTable, mean_horizon,
                               reference_from_fields, safe_name)
from .cvat import HORIZON, REFERENCE, TARGET, _shape_dims, _shape_el, reference_shape, target_groups
from .frame_import import checked_frame, classes_block
from .frame_scene import FRAME_FORMAT

__all__ = ["frame_image_scene", "frame_image_shapes"]


def frame_image_scene(name: str, i: int, width: int, height: int, shapes: dict, image_path: str | None,
                      table: TargetTable, classes: dict | None) -> TargetScene:
    """One frame from the parsed shapes of the ``i``-th image, ``name`` (``shapes``: label → list
    of ``_Shape``); ``image_path`` is its ``image.path`` (or None). Raises
    :class:`ConversionError` naming the image and the shape."""
    where = f"image {name!r}"
    stem = PurePosixPath(name).stem or f"image{i}"
    groups = target_groups(shapes[TARGET])
    ids = {key: key or stem for key in groups}
    targets, origins = [], {}
    for j, (key, tshapes) in enumerate(groups.items()):
        tid = ids[key]
        twhere = f"{where}, target {tid!r}"
        found: dict[str, str] = {}
        for s in tshapes:
            cls = s.attrs.get("class", "")
            if cls and found and cls not in found:
                a, da = next(iter(found.items()))
                raise ConversionError(s.where, f"class {cls!r} here but {a!r} on {da} of the same target")
            if cls:
                found.setdefault(cls, s.desc)
        t: dict[str, Any] = {"id": tid}
        if found:
            t["class"] = next(iter(found))
        dims = table.size([name], tid, _shape_dims(tshapes), twhere)
        if dims is not None:
            t["dimensions_m"] = dims
        t["dimension_lines"] = [{"corners": s.pts, **({"worker": s.attrs["worker"]} if s.attrs.get("worker") else {})}
                                for s in tshapes]
        targets.append(t)
        origins[f"targets[{j}]"] = tshapes[0].desc
        origins.update({f"targets[{j}].dimension_lines[{k}]": s.desc for k, s in enumerate(tshapes)})
    refs = []
    for k, s in enumerate(shapes[REFERENCE]):
        ref = reference_from_fields({f: s.attrs.get(f) for f in REFERENCE_FIELDS}, s.pts, s.where,
                                    worker=s.attrs.get("worker") or None)
        key = s.attrs.get("target_id", "")
        if key:
            if key not in groups:
                have = sorted(k2 for k2 in groups if k2) or "none"
                raise ConversionError(s.where, f"reference for target {key!r}, but no target shape on this "
                                               f"image has that target_id (they have {have})")
            ref["target"] = ids[key]
        elif ref["mode"] == "relative" and len(groups) > 1:
            raise ConversionError(s.where, "a relative reference needs a target_id on an image with several "
                                           f"targets ({sorted(groups)})")
        refs.append(ref)
        origins[f"references[{k}]"] = s.desc
    scene: dict[str, Any] = {"format": FRAME_FORMAT, "image": {"width": width, "height": height}}
    if image_path is not None:
        scene["image"]["path"] = image_path
    focal = table.focal([name], [t["id"] for t in targets], where)
    if focal is not None:
        scene["camera"] = {"focal_length_px": focal}
    if shapes[HORIZON]:
        scene["horizon"] = mean_horizon([s.pts for s in shapes[HORIZON]], width, where)
    own = classes_block(targets, None, classes)
    if own:
        scene["classes"] = own
    scene["targets"] = targets
    if refs:
        scene["references"] = refs
    base = safe_name(str(PurePosixPath(name).with_suffix(""))) if PurePosixPath(name).stem else stem
    return TargetScene(base, checked_frame(scene, where, origins), where)


def frame_image_shapes(img: ET.Element, d: dict) -> None:
    """Add a frame's shapes (``d``: a ``creference-scene/2`` dict as ``frame_to_dict`` writes it) to
    its ``<image>``: each target's dimension lines as ``target`` points with its id, class and
    known size; each reference as a ``reference`` polyline (with its target's id); the horizon.
    A reference without a line (a target's own size) has no shape: :class:`ValueError`."""
    for t in d["targets"]:
        size = {f"{k}_m": float(v) for k, v in (t.get("dimensions_m") or {}).items()}
        for dl in t["dimension_lines"]:
            _shape_el(img, "points", TARGET, dl["corners"],
                      {"target_id": t["id"], "class": t.get("class"), **size, "worker": dl.get("worker")})
    for i, r in enumerate(d.get("references", [])):
        if "line" not in r:
            raise ValueError(f"references[{i}]: a measurement of target {r.get('target')!r}'s own "
                             f"{r['measure']} (no line) cannot be written as a CVAT shape")
        reference_shape(img, r, r.get("target"))
    if d.get("horizon") is not None:
        _shape_el(img, "polyline", HORIZON, d["horizon"], {})
