"""CVAT for images 1.1 XML ↔ ``creference-scene/1``: the shipped label spec, ``annotations.xml`` → one
scene per target, and scenes → ``annotations.xml`` (docs/import.md is the user's guide).

Labels (``creference_bayes/data/cvat_labels.json``): ``target`` — a points shape with the four
corners t1..t4 in order (common bottom corner, end of length, end of width, top of height);
``reference`` — a two-point polyline with the measurement in attributes named as
:data:`~.annotation_tools.REFERENCE_FIELDS`; ``horizon`` — a two-point polyline. Every shape may
carry a ``worker`` attribute (CVAT records no per-shape annotator). A shape belongs to the target
named by its ``target_id`` attribute; on an image with one target the attribute may be empty,
and a direct reference without one is shared by all targets of its image. The target's size is
in its shapes' ``length_m``/``width_m``/``height_m`` attributes or in a ``--targets`` table.
Other shapes (boxes, polygons, …, tags) and other labels are ignored with a note.

The XML is not trusted: documents with a DTD (``<!DOCTYPE``/``<!ENTITY``) are refused before
parsing, so no entity can expand.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any

from .annotation_tools import (MISSING, REFERENCE_FIELDS, ConversionError, ImportReport,
                               TargetScene, TargetTable, checked_scene, fmt_number, image_file,
                               mean_horizon, number_field, read_input, reference_from_fields,
                               safe_name, unique_names)
from .scene import SCENE_FORMAT, parse_scene, scene_to_dict

__all__ = ["LABEL_ATTRIBUTES", "cvat_label_spec", "read_cvat_xml", "scenes_from_cvat", "cvat_xml"]

TARGET, REFERENCE, HORIZON = "target", "reference", "horizon"
#: Attributes of each label, in the order they are written.
LABEL_ATTRIBUTES = {
    TARGET: ("target_id", "class", "length_m", "width_m", "height_m", "worker"),
    REFERENCE: ("target_id",) + REFERENCE_FIELDS + ("worker",),
    HORIZON: ("worker",),
}
_SELECTS = ("class", "measure", "mode", "unit")
_N_POINTS = {TARGET: 4, REFERENCE: 2, HORIZON: 2}
_DTD = re.compile(rb"<!\s*(DOCTYPE|ENTITY)", re.IGNORECASE)


def cvat_label_spec() -> list[dict]:
    """The shipped CVAT label/attribute specification (the JSON of CVAT's "Raw" label editor)."""
    text = (resources.files("creference_bayes") / "data" / "cvat_labels.json").read_text("utf-8")
    return json.loads(text)


def read_cvat_xml(source: str | Path | bytes) -> ET.Element:
    """Parse a CVAT XML file (a path or the bytes), refusing DTDs and entity declarations."""
    name = "(xml)"
    if not isinstance(source, bytes):
        name = str(source)
        source = read_input(source)
    if _DTD.search(source):
        raise ConversionError(name, "the XML declares a DTD or entities, which CVAT files never "
                                    "do; refused (entity expansion is unsafe)")
    try:
        root = ET.fromstring(source)
    except ET.ParseError as exc:
        raise ConversionError(name, f"not well-formed XML: {exc}") from None
    if root.tag != "annotations":
        raise ConversionError(name, f"the root element is <{root.tag}>, expected <annotations> "
                                    "(CVAT for images 1.1)")
    return root


# ----------------------------------------------------------------------------------------------
# import


def scenes_from_cvat(root: ET.Element, *, image_dir: str | Path | None = None,
                     out_dir: str | Path | None = None, targets: TargetTable | None = None,
                     frames: bool = False, classes: dict | None = None) -> ImportReport:
    """Convert a parsed CVAT for images 1.1 document to one scene per target, or one
    ``creference-scene/2`` frame per image whose targets carry a ``class`` (:mod:`.cvat_frames`).

    Parameters
    ----------
    root : Element
        ``<annotations>`` from :func:`read_cvat_xml`.
    image_dir : path, optional
        Where the images are; ``image.path`` is the image's file in this folder
        (:func:`~.annotation_tools.image_file`: its name in the task, else its file name; a note
        says when neither exists).
    out_dir : path, optional
        The folder the scenes will be written to; image paths are made relative to it.
    targets : TargetTable, optional
        Known sizes and focal lengths by image and target
        (:func:`~.annotation_tools.load_target_table`).
    frames : bool
        Import every image as a frame, also those whose targets carry no ``class``.
    classes : dict, optional
        Size priors of classes of your own (name → :class:`~..models.size_priors.SizePrior`),
        written into the frames whose size-less targets use them.

    Returns
    -------
    ImportReport
        An image (or one target of it) that cannot be converted is in ``errors``; its message
        names the image and the shape (``shape 3`` is the image's fourth shape element).
    """
    notes: list[str] = []
    version = (root.findtext("version") or "").strip()
    if version and version != "1.1":
        notes.append(f"CVAT XML version {version!r}; read as 1.1")
    if root.find("track") is not None:
        notes.append("<track> elements ignored (export the task as 'CVAT for images', not video)")
    table = TargetTable.of(targets)
    scenes, errors = [], []
    for i, image in enumerate(root.findall("image")):
        found, errs = _image_scenes(image, i, image_dir, out_dir, table, notes, frames, classes)
        scenes += found
        errors += errs
    kept, clashes = unique_names(scenes)
    notes += table.notes()
    return ImportReport(tuple(kept), tuple(errors + clashes), tuple(notes))


def _whole(value: Any, where: str, what: str) -> int:
    x = number_field(value, where, what, positive=True)
    if x != int(x):
        raise ConversionError(where, f"{what} must be whole pixels, got {x:g}")
    return int(x)


def _points(text: Any, where: str) -> list[list[float]]:
    if not isinstance(text, str) or not text.strip():
        raise ConversionError(where, "no points attribute")
    pts = []
    for pair in text.strip().split(";"):
        xy = pair.split(",")
        if len(xy) != 2:
            raise ConversionError(where, f"malformed point {pair!r} in points {text[:60]!r} "
                                         "(expected 'x0,y0;x1,y1;...')")
        pts.append([number_field(c, where, "a coordinate") for c in xy])
    return pts


@dataclass(frozen=True)
class _Shape:
    where: str    # image and shape, for messages
    desc: str     # the shape alone: "shape 3 (polyline 'reference')"
    pts: list
    attrs: dict


def _shape(el: ET.Element, k: int, where: str) -> _Shape:
    label = el.get("label")
    desc = f"shape {k} ({el.tag} {label!r})"
    swhere = f"{where}, {desc}"
    pts = _points(el.get("points"), swhere)
    if len(pts) != _N_POINTS[label]:
        what = {TARGET: "target has", REFERENCE: "reference line has", HORIZON: "horizon has"}[label]
        extra = " (t1..t4)" if label == TARGET else ""
        raise ConversionError(swhere, f"{what} {len(pts)} points, expected {_N_POINTS[label]}{extra}")
    attrs: dict[str, str] = {}
    for a in el.findall("attribute"):
        name = a.get("name")
        if name in attrs:
            raise ConversionError(swhere, f"attribute {name!r} is given twice")
        text = (a.text or "").strip()
        attrs[name] = "" if text in MISSING else text
    return _Shape(swhere, desc, pts, attrs)


def _image_scenes(image, i, image_dir, out_dir, table, notes, frames=False, classes=None):
    name = image.get("name") or f"#{image.get('id', i)}"
    where = f"image {name!r}"
    try:
        width = _whole(image.get("width"), where, "width")
        height = _whole(image.get("height"), where, "height")
        shapes = {TARGET: [], REFERENCE: [], HORIZON: []}
        for k, el in enumerate(list(image)):
            label = el.get("label")
            if label not in shapes:
                notes.append(f"{where}, shape {k}: label {label!r} ignored")
            elif el.tag not in ("points", "polyline"):
                notes.append(f"{where}, shape {k}: <{el.tag}> {label!r} ignored (a {label} is drawn as "
                             "points or a polyline)")
            else:
                shapes[label].append(_shape(el, k, where))
        if not shapes[TARGET]:
            if shapes[REFERENCE] or shapes[HORIZON]:
                raise ConversionError(where, "references or a horizon but no target shape")
            notes.append(f"{where}: no target annotated; skipped")
            return [], []
        image_path = image_file(image_dir, name, out_dir, where, notes) if image_dir is not None else None
        if frames or any(s.attrs.get("class") for s in shapes[TARGET]):
            from .cvat_frames import frame_image_scene

            return [frame_image_scene(name, i, width, height, shapes, image_path, table, classes)], []
        groups = target_groups(shapes[TARGET])
        horizon = (mean_horizon([s.pts for s in shapes[HORIZON]], width, where)
                   if shapes[HORIZON] else None)
        refs_of = {key: [s for s in shapes[REFERENCE] if _belongs(s, key, groups)] for key in groups}
    except ConversionError as exc:
        return [], [exc]

    stem = PurePosixPath(name).stem or f"image{i}"
    base = safe_name(str(PurePosixPath(name).with_suffix(""))) if PurePosixPath(name).stem else stem
    scenes, errors = [], []
    for key, tshapes in groups.items():
        tid = key or stem
        twhere = where if key == "" else f"{where}, target {tid!r}"
        try:
            refs = refs_of[key]
            scene = _target_scene(name, tid, tshapes, refs, horizon, width, height, twhere, table)
            if image_path is not None:
                scene["image"]["path"] = image_path
            origins = {f"target.dimension_lines[{j}]": s.desc for j, s in enumerate(tshapes)}
            origins.update({f"references[{j}]": s.desc for j, s in enumerate(refs)})
            checked_scene(scene, twhere, origins)
            scenes.append(TargetScene(safe_name(base if key == "" else f"{base}_{tid}"), scene, twhere))
        except ConversionError as exc:
            errors.append(exc)
    return scenes, errors


def target_groups(tshapes: list[_Shape]) -> dict[str, list[_Shape]]:
    """An image's target shapes by ``target_id``. The id may be empty only on an image with a
    single target (its id is then the image's name): among named targets, an unnamed shape is most
    likely one whose id was forgotten, so it is refused rather than made a target of its own."""
    groups: dict[str, list] = {}
    for s in tshapes:
        groups.setdefault(s.attrs.get("target_id", ""), []).append(s)
    if "" in groups and len(groups) > 1:
        raise ConversionError(groups[""][0].where, f"this target shape has no target_id, and the image has "
                                                   f"several targets ({sorted(k for k in groups if k)}); "
                                                   "give every target shape its target_id")
    return groups


def _belongs(shape: _Shape, key: str, groups: dict) -> bool:
    """Whether a reference shape belongs to the target ``key`` (see the module docstring)."""
    ref_key = shape.attrs.get("target_id", "")
    if ref_key:
        if ref_key not in groups:
            have = sorted(k for k in groups if k) or "none"
            raise ConversionError(shape.where, f"reference for target {ref_key!r}, but no target shape "
                                               f"on this image has that target_id (they have {have})")
        return ref_key == key
    if len(groups) == 1:
        return True
    if shape.attrs.get("mode") == "relative":
        raise ConversionError(shape.where, "a relative reference needs a target_id on an image with "
                                           f"several targets ({sorted(groups)})")
    return True  # a direct reference without target_id: shared by every target of the image


def _shape_dims(tshapes) -> dict[str, float] | None:
    """A target's size (m) from its shapes' ``length_m``/``width_m``/``height_m`` attributes (all
    three or none; shapes that give them must agree), or None."""
    dims = None
    for shape in tshapes:
        swhere, attrs = shape.where, shape.attrs
        given = {k: attrs.get(f"{k}_m", "") for k in ("length", "width", "height")}
        if not any(given.values()):
            continue
        if not all(given.values()):
            raise ConversionError(swhere, f"give all of length_m, width_m and height_m or none, got "
                                          f"{ {k + '_m': v for k, v in given.items() if v} }")
        these = {k: number_field(v, swhere, f"{k}_m", positive=True) for k, v in given.items()}
        if dims is not None and any(not math.isclose(dims[k], these[k], rel_tol=1e-9) for k in dims):
            raise ConversionError(swhere, f"target size {these} differs from {dims} on another shape")
        dims = these
    return dims


def _target_scene(name, tid, tshapes, refs, horizon, width, height, where, table) -> dict:
    size = table.size([name], tid, _shape_dims(tshapes), where, required=True)
    focal = table.focal([name], [tid], where)
    lines = []
    for shape in tshapes:
        line = {"corners": shape.pts}
        if shape.attrs.get("worker"):
            line["worker"] = shape.attrs["worker"]
        lines.append(line)
    scene: dict[str, Any] = {"format": SCENE_FORMAT, "image": {"width": width, "height": height}}
    if focal is not None:
        scene["camera"] = {"focal_length_px": focal}
    if horizon is not None:
        scene["horizon"] = horizon
    scene["target"] = {"id": tid, "dimensions_m": size, "dimension_lines": lines}
    references = [reference_from_fields({k: s.attrs.get(k) for k in REFERENCE_FIELDS}, s.pts, s.where,
                                        worker=s.attrs.get("worker") or None)
                  for s in refs]
    if references:
        scene["references"] = references
    return scene


# ----------------------------------------------------------------------------------------------
# export


def _meta(n_images: int) -> ET.Element:
    meta = ET.Element("meta")
    task = ET.SubElement(meta, "task")
    for key, value in (("id", "0"), ("name", "creference"), ("size", str(n_images)),
                       ("mode", "annotation"), ("overlap", "0")):
        ET.SubElement(task, key).text = value
    labels = ET.SubElement(task, "labels")
    for spec in cvat_label_spec():
        lab = ET.SubElement(labels, "label")
        ET.SubElement(lab, "name").text = spec["name"]
        ET.SubElement(lab, "color").text = spec["color"]
        ET.SubElement(lab, "type").text = spec["type"]
        attrs = ET.SubElement(lab, "attributes")
        for a in spec["attributes"]:
            ae = ET.SubElement(attrs, "attribute")
            ET.SubElement(ae, "name").text = a["name"]
            ET.SubElement(ae, "mutable").text = "True" if a["mutable"] else "False"
            ET.SubElement(ae, "input_type").text = a["input_type"]
            ET.SubElement(ae, "default_value").text = a["default_value"]
            ET.SubElement(ae, "values").text = "\n".join(a["values"])
    return meta


def reference_shape(img, r: dict, target_id) -> None:
    """A scene's reference ``r`` (with a line) as a ``reference`` polyline of ``img``, tied to
    ``target_id``."""
    vals = {"target_id": target_id, "object": r.get("object"), "measure": r["measure"],
            "mode": r["mode"], "unit": r.get("unit"), "worker": r.get("worker")}
    if "range" in r:
        vals["range_low"], vals["range_high"] = map(float, r["range"])
    else:
        vals["value"] = float(r["value"])
    if r.get("confidence") is not None:
        vals["confidence_pct"] = round(100.0 * r["confidence"], 10)
    _shape_el(img, "polyline", REFERENCE, r["line"], vals)


def _shape_el(parent, tag: str, label: str, pts, values: dict) -> None:
    el = ET.SubElement(parent, tag, {"label": label, "source": "manual", "occluded": "0",
                                     "points": ";".join(f"{u:.2f},{v:.2f}" for u, v in pts),
                                     "z_order": "0"})
    for name in LABEL_ATTRIBUTES[label]:
        value = values.get(name)
        text = ("__undefined__" if name in _SELECTS else "") if value is None else (
            fmt_number(value) if isinstance(value, float) else str(value))
        ET.SubElement(el, "attribute", {"name": name}).text = text


def cvat_xml(scenes, *, image_names=None) -> str:
    """CVAT for images 1.1 XML (text) holding the scenes' annotations.

    Scenes on the same image name share one ``<image>``; their horizons must agree. A
    ``creference-scene/2`` frame has its image to itself (every target with its ``class``). The
    image name is ``image_names[i]``, else the file name of ``image.path``, else
    ``<(first) target id>.jpg``.
    Coordinates are written with two decimals, as CVAT writes them. Not representable in CVAT and
    therefore left out: ``seconds``, the camera, the ground truth, a frame's own ``classes``.
    """
    from .frame_import import is_frame
    from .frame_scene import frame_to_dict, parse_frame

    scenes = [(frame_to_dict(parse_frame(s) if isinstance(s, dict) else s) if is_frame(s) else
               scene_to_dict(parse_scene(s) if isinstance(s, dict) else s)) for s in scenes]
    names = list(image_names) if image_names is not None else [None] * len(scenes)
    if len(names) != len(scenes):
        raise ValueError(f"image_names: expected {len(scenes)} names, got {len(names)}")
    images: dict[str, list] = {}
    for d, name in zip(scenes, names):
        first = d["targets"][0]["id"] if "targets" in d else d["target"]["id"]
        name = name or (PurePosixPath(d["image"]["path"]).name if d["image"].get("path")
                        else f"{safe_name(first)}.jpg")
        images.setdefault(name, []).append(d)
        if len(images[name]) > 1 and any("targets" in x for x in images[name]):
            raise ValueError(f"image {name!r}: a frame holds every target of its image; it cannot share "
                             "the image with another scene")
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    root.append(_meta(len(images)))
    for i, (name, group) in enumerate(images.items()):
        w, h = group[0]["image"]["width"], group[0]["image"]["height"]
        horizons = {json.dumps(d.get("horizon")) for d in group}
        if any((d["image"]["width"], d["image"]["height"]) != (w, h) for d in group) or len(horizons) > 1:
            raise ValueError(f"scenes on image {name!r} disagree on its size or horizon")
        img = ET.SubElement(root, "image", {"id": str(i), "name": name, "width": str(w), "height": str(h)})
        if "targets" in group[0]:
            from .cvat_frames import frame_image_shapes

            frame_image_shapes(img, group[0])
            continue
        for d in group:
            t = d["target"]
            size = {f"{k}_m": float(v) for k, v in t["dimensions_m"].items()}
            for dl in t["dimension_lines"]:
                _shape_el(img, "points", TARGET, dl["corners"],
                          {"target_id": t["id"], **size, "worker": dl.get("worker")})
            for r in d.get("references", []):
                reference_shape(img, r, t["id"])
        if group[0].get("horizon") is not None:
            _shape_el(img, "polyline", HORIZON, group[0]["horizon"], {})
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
