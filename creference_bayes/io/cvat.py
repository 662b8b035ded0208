"""CVAT for images 1.1 XML ↔ scene files: the shipped label spec, ``annotations.xml`` → one
``creference-scene/2`` scene per image holding all its targets, and scenes → ``annotations.xml``
(docs/import.md is the user's guide).

Labels (``creference_bayes/data/cvat_labels.json``): ``target``, a points shape of the corners
t1..t4 in order (common bottom corner, end of length, end of width, top of height), grouped into
targets by ``target_id`` (may be empty on an image of one target, whose id is then the image's
name), with the target's ``class`` and size (``length_m``/``width_m``/``height_m``, or the
``--targets`` table; else its class's size prior); ``reference``, a two-point polyline with the
measurement in attributes named as :data:`~.annotation_tools.REFERENCE_FIELDS` and the
``target_id`` it names, if any; ``horizon``, a two-point polyline; a ``camera`` tag on the image,
whose ``camera_id`` is the scene's ``camera.id``; a ``setting`` tag, whose ``setting`` is the
scene's ``setting`` (where the photo was taken). Every shape may carry a ``worker`` attribute
(CVAT records no per-shape annotator). Other shapes and labels are ignored with a note.

The XML is not trusted: it is parsed incrementally by ``defusedxml`` with DTDs forbidden (a
``<!DOCTYPE``, and so any ``<!ENTITY``, is refused in any encoding: no entity can expand), only the
elements the importer reads are kept, and a document past :data:`MAX_XML_BYTES` bytes or
:data:`MAX_XML_ELEMENTS` elements is refused.
"""

from __future__ import annotations

import io
import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import resources
from pathlib import Path, PurePosixPath
from typing import Any

from .annotation_tools import (MISSING, REFERENCE_FIELDS, ConversionError, ImportedScene, ImportReport,
                               TargetTable, _whole, checked_scene, classes_block, image_file, mean_horizon,
                               number_field, open_input, reference_from_fields, safe_name, scene_dict,
                               size_fields, unique_names)
from .scene import parse_scene, scene_to_dict

__all__ = ["LABEL_ATTRIBUTES", "MAX_XML_BYTES", "MAX_XML_ELEMENTS", "cvat_label_spec", "read_cvat_xml", "scenes_from_cvat", "cvat_xml"]

TARGET, REFERENCE, HORIZON, CAMERA, SETTING = "target", "reference", "horizon", "camera", "setting"
#: Attributes of each label, in the order they are written.
LABEL_ATTRIBUTES = {
    TARGET: ("target_id", "class", "length_m", "width_m", "height_m", "worker"),
    REFERENCE: ("target_id",) + REFERENCE_FIELDS + ("worker",),
    HORIZON: ("worker",),
    CAMERA: ("camera_id",),
    SETTING: ("setting",),
}
#: The image's tags: label → the attribute that names the photo's ... and what it names
_TAGS = {CAMERA: ("camera_id", "camera"), SETTING: ("setting", "setting")}
_SELECTS = ("class", "measure", "mode", "unit")
_N_POINTS = {TARGET: 4, REFERENCE: 2, HORIZON: 2}


def cvat_label_spec() -> list[dict]:
    """The shipped CVAT label/attribute specification (the JSON of CVAT's "Raw" label editor)."""
    text = (resources.files("creference_bayes") / "data" / "cvat_labels.json").read_text("utf-8")
    return json.loads(text)


def read_cvat_xml(source: str | Path | bytes, *, name: str | None = None) -> ET.Element:
    """Parse a CVAT XML file (a path or the bytes) incrementally, refusing any DTD (so no entity
    can be declared, let alone expanded), a document of more than :data:`MAX_XML_BYTES` bytes or
    :data:`MAX_XML_ELEMENTS` elements. Only what the importer reads is kept: ``<version>``, the
    ``<image>`` elements with their shapes and the shapes' attributes, and an empty ``<track>`` for
    each track (it is only noted); the rest (``<meta>``, deeper or unknown elements) is dropped as
    it is read.

    Returns the ``<annotations>`` element; raises :class:`ConversionError` naming the file (``name``,
    for bytes: where they come from)."""
    if isinstance(source, bytes):
        name, stream = name or "(xml)", io.BytesIO(source)
    else:
        name, stream = name or str(source), open_input(source)
    with stream:
        return _parse(_Capped(stream, name), name)


#: Largest CVAT XML read (bytes, uncompressed): a CVAT task of thousands of images is a few tens
#: of MB; past this it is refused (a small ZIP can unpack to gigabytes).
MAX_XML_BYTES = 64 << 20
#: Most elements read from a CVAT XML: a photo's image with a dozen shapes is about a hundred.
MAX_XML_ELEMENTS = 1_000_000
#: Levels kept below each child of the root (an image's shapes and their attributes; a track is
#: only noted); other children are dropped as they are read.
_KEEP_DEPTH = {"image": 2, "version": 0, "track": 0}


class _Capped:
    """A binary stream that refuses to give more than :data:`MAX_XML_BYTES` bytes."""

    def __init__(self, stream, name: str):
        self.stream, self.name, self.count = stream, name, 0

    def read(self, n: int) -> bytes:
        data = self.stream.read(n)
        self.count += len(data)
        if self.count > MAX_XML_BYTES:
            raise ConversionError(self.name, f"the XML is larger than {MAX_XML_BYTES >> 20} MiB; refused "
                                             "(a CVAT export of thousands of images is a few tens of MB)")
        return data


class _Kept:
    """The parser's target: builds only the elements :data:`_KEEP_DEPTH` keeps, counting all."""

    def __init__(self, name: str):
        self.name, self.count, self.root = name, 0, None
        self.open: list[tuple[ET.Element | None, int, list]] = []  # (element or None: dropped, levels kept, text)

    def start(self, tag, attrib):
        self.count += 1
        if self.count > MAX_XML_ELEMENTS:
            raise ConversionError(self.name, f"more than {MAX_XML_ELEMENTS} XML elements; refused (a CVAT "
                                             "export of thousands of images has far fewer)")
        if not self.open:
            if tag != "annotations":
                raise ConversionError(self.name, f"the root element is <{tag}>, expected <annotations> "
                                                 "(CVAT for images 1.1)")
            self.root = ET.Element(tag, attrib)
            self.open.append((self.root, 1, []))
            return
        parent, levels, _ = self.open[-1]
        levels = _KEEP_DEPTH.get(tag, -1) if len(self.open) == 1 else levels - 1
        el = ET.SubElement(parent, tag, attrib) if levels >= 0 and parent is not None else None
        self.open.append((el, levels, []))

    def data(self, text):
        el, _, texts = self.open[-1] if self.open else (None, 0, None)
        if el is not None:
            texts.append(text)

    def end(self, tag):
        el, _, texts = self.open.pop()
        if el is not None and texts:
            el.text = "".join(texts)

    def close(self):
        return self.root


def _parse(stream, name: str) -> ET.Element:
    from defusedxml import DefusedXmlException
    from defusedxml.ElementTree import DefusedXMLParser

    target = _Kept(name)
    parser = DefusedXMLParser(target=target, forbid_dtd=True)
    try:
        while chunk := stream.read(1 << 16):
            parser.feed(chunk)
        root = parser.close()
    except ConversionError:
        raise
    except ET.ParseError as exc:
        raise ConversionError(name, f"not well-formed XML: {exc}") from None
    except DefusedXmlException:
        raise ConversionError(name, "the XML declares a DTD or entities, which CVAT files never do; "
                                    "refused (entity expansion is unsafe)") from None
    except ValueError as exc:  # e.g. an encoding expat cannot read ("multi-byte encodings are not supported")
        raise ConversionError(name, f"cannot be parsed as XML: {exc}") from None
    return root


# ----------------------------------------------------------------------------------------------
# import


def scenes_from_cvat(root: ET.Element, *, image_dir: str | Path | None = None,
                     out_dir: str | Path | None = None, targets: Any = None,
                     classes: dict | None = None) -> ImportReport:
    """Convert a parsed CVAT for images 1.1 document (``root``, the ``<annotations>`` of
    :func:`read_cvat_xml`) to one ``creference-scene/2`` scene per image (module docstring).

    ``image_dir``: where the images are; ``image.path`` is the image's file in this folder
    (:func:`~.annotation_tools.image_file`). ``out_dir``: the folder the scenes will be written to;
    image paths are made relative to it. ``targets``: known sizes (m) and focal lengths (px) by
    image and target, a :class:`~.annotation_tools.TargetTable`
    (:func:`~.annotation_tools.load_target_table`) or a dict. ``classes``: size priors of classes of
    your own (name → :class:`~..models.size_priors.SizePrior`), written into the scenes whose
    size-less targets use them.

    Returns an :class:`ImportReport`: an image that cannot be converted is in ``errors``, its
    message naming the image and the shape (``shape 3`` is the image's fourth shape element).
    """
    notes: list[str] = []
    version = (root.findtext("version") or "").strip()
    if version and version != "1.1":
        notes.append(f"CVAT XML version {version!r}; read as 1.1")
    if root.find("track") is not None:
        notes.append("<track> elements ignored (export the task as 'CVAT for images', not video)")
    table = TargetTable.of(targets)
    scenes, errors, unannotated = [], [], 0
    for i, image in enumerate(root.findall("image")):
        try:
            scene = _image_scene(image, i, image_dir, out_dir, table, classes, notes)
        except ConversionError as exc:
            errors.append(exc)
            continue
        if scene is not None:
            scenes.append(scene)
        else:
            unannotated += 1
    kept, clashes = unique_names(scenes)
    notes += table.notes()
    return ImportReport(tuple(kept), tuple(errors + clashes), tuple(notes), unannotated)


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


def _image_scene(image: ET.Element, i: int, image_dir, out_dir, table: TargetTable, classes: dict | None,
                 notes: list[str]) -> ImportedScene | None:
    """The scene of the ``i``-th ``<image>``, or None (no target annotated); raises
    :class:`ConversionError` naming the image and the shape."""
    name = image.get("name") or f"#{image.get('id', i)}"
    where = f"image {name!r}"
    width = _whole(image.get("width"), where, "width")
    height = _whole(image.get("height"), where, "height")
    shapes = {TARGET: [], REFERENCE: [], HORIZON: []}
    tags: dict[str, list] = {label: [] for label in _TAGS}
    for k, el in enumerate(list(image)):
        label = el.get("label")
        if label in _TAGS and el.tag == "tag":
            tags[label].append((k, el))
        elif label in _TAGS:
            notes.append(f"{where}, shape {k}: <{el.tag}> {label!r} ignored (the {label} is a tag on the image)")
        elif label not in shapes:
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
        return None
    stem = PurePosixPath(name).stem or f"image{i}"
    groups: dict[str, list] = {}
    for s in shapes[TARGET]:
        groups.setdefault(s.attrs.get("target_id", ""), []).append(s)
    if "" in groups and len(groups) > 1:  # among named targets, most likely a forgotten id
        raise ConversionError(groups[""][0].where, f"this target shape has no target_id, and the image has "
                                                   f"several targets ({sorted(k for k in groups if k)}); "
                                                   "give every target shape its target_id")
    ids = {key: key or stem for key in groups}
    targets, origins = [], {}
    for j, (key, tshapes) in enumerate(groups.items()):
        found: dict[str, str] = {}
        for s in tshapes:
            cls = s.attrs.get("class", "")
            if cls and found and cls not in found:
                a, da = next(iter(found.items()))
                raise ConversionError(s.where, f"class {cls!r} here but {a!r} on {da} of the same target")
            if cls:
                found.setdefault(cls, s.desc)
        t: dict[str, Any] = {"id": ids[key]}
        if found:
            t["class"] = next(iter(found))
        dims = table.size([name], ids[key], _shape_dims(tshapes), f"{where}, target {ids[key]!r}",
                          required=not found)
        if dims is not None:
            t["dimensions_m"] = dims
        t["dimension_lines"] = [{"corners": s.pts, **({"worker": s.attrs["worker"]} if s.attrs.get("worker") else {})}
                                for s in tshapes]
        targets.append(t)
        origins[f"targets[{j}]"] = tshapes[0].desc
        origins.update({f"targets[{j}].dimension_lines[{k}]": s.desc for k, s in enumerate(tshapes)})
    refs = []
    for k, s in enumerate(shapes[REFERENCE]):
        key = s.attrs.get("target_id", "")
        if key and key not in groups:
            have = sorted(k2 for k2 in groups if k2) or "none"
            raise ConversionError(s.where, f"reference for target {key!r}, but no target shape on this "
                                           f"image has that target_id (they have {have})")
        if not key and s.attrs.get("mode") == "relative" and len(groups) > 1:
            raise ConversionError(s.where, "a relative reference needs a target_id on an image with several "
                                           f"targets ({sorted(groups)})")
        ref = reference_from_fields({f: s.attrs.get(f) for f in REFERENCE_FIELDS}, s.pts, s.where,
                                    worker=s.attrs.get("worker") or None)
        if key:
            ref["target"] = ids[key]
        refs.append(ref)
        origins[f"references[{k}]"] = s.desc
    path = None if image_dir is None else image_file(image_dir, name, out_dir, where, notes)
    camera_id = _tag_name(tags, CAMERA, where)
    focal = table.focal([name], [t["id"] for t in targets], where)
    camera = {k: v for k, v in (("id", camera_id), ("focal_length_px", focal)) if v is not None}
    horizon = mean_horizon([s.pts for s in shapes[HORIZON]], width, where) if shapes[HORIZON] else None
    own = classes_block(targets, None, classes)
    scene = scene_dict((width, height), path, camera, horizon=horizon, classes=own, targets=targets,
                       references=refs or None, setting=_tag_name(tags, SETTING, where))
    base = safe_name(str(PurePosixPath(name).with_suffix(""))) if PurePosixPath(name).stem else stem
    return ImportedScene(base, checked_scene(scene, where, origins), where)


def _tag_name(tags: dict, label: str, where: str) -> str | None:
    """What the image's ``label`` tags (``tags[label]``: ``(index, element)``) name, the camera or
    the setting (:data:`_TAGS`): their attribute, which must be filled in and the same on every such
    tag; None without a tag."""
    attr, what = _TAGS[label]
    found: dict[str, str] = {}
    for k, el in tags[label]:
        desc = f"shape {k} (tag {label!r})"
        values = [(a.text or "").strip() for a in el.findall("attribute") if a.get("name") == attr]
        if len(values) > 1:
            raise ConversionError(f"{where}, {desc}", f"attribute {attr!r} is given twice")
        if not values or values[0] in MISSING:
            got = f"no {attr} attribute" if not values else f"an empty {attr} {values[0]!r}"
            raise ConversionError(f"{where}, {desc}", f"a {label} tag with {got}: fill in the {what}'s name "
                                                      "(or delete the tag)")
        if found and values[0] not in found:
            other, odesc = next(iter(found.items()))
            raise ConversionError(where, f"{attr} {other!r} on {odesc} but {values[0]!r} on {desc}: one photo "
                                         f"has one {what}")
        found.setdefault(values[0], desc)
    return next(iter(found), None)


def _shape_dims(tshapes) -> dict[str, float] | None:
    """A target's size (m) from its shapes' ``length_m``/``width_m``/``height_m`` attributes (all
    three or none; shapes that give them must agree), or None."""
    dims = None
    for shape in tshapes:
        these = size_fields(shape.attrs, shape.where)
        if these is None:
            continue
        if dims is not None and any(not math.isclose(dims[k], these[k], rel_tol=1e-9) for k in dims):
            raise ConversionError(shape.where, f"target size {these} differs from {dims} on another shape")
        dims = these
    return dims


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
        for key in ("name", "color", "type"):
            ET.SubElement(lab, key).text = spec[key]
        attrs = ET.SubElement(lab, "attributes")
        for a in spec["attributes"]:
            ae = ET.SubElement(attrs, "attribute")
            texts = {**a, "mutable": str(bool(a["mutable"])), "values": "\n".join(a["values"])}
            for key in ("name", "mutable", "input_type", "default_value", "values"):
                ET.SubElement(ae, key).text = texts[key]
    return meta


def _shape_el(parent, tag: str, label: str, pts, values: dict) -> None:
    el = ET.SubElement(parent, tag, {"label": label, "source": "manual", "occluded": "0",
                                     "points": ";".join(f"{u:.2f},{v:.2f}" for u, v in pts),
                                     "z_order": "0"})
    for name in LABEL_ATTRIBUTES[label]:
        value = values.get(name)
        text = ("__undefined__" if name in _SELECTS else "") if value is None else (
            f"{value:.15g}" if isinstance(value, float) else str(value))  # 15 digits read back the same
        ET.SubElement(el, "attribute", {"name": name}).text = text


def cvat_xml(scenes, *, image_names=None) -> str:
    """CVAT for images 1.1 XML (text) holding the scenes' annotations (:class:`~.scene.Scene` or
    scene dicts of either format), with the labels of the module docstring.

    Scenes on the same image name share one ``<image>`` (their size, horizon and camera id must
    agree, their target ids must differ). The image name is ``image_names[i]``, else the file name
    of ``image.path``, else ``<first target id>.jpg``. Coordinates have two decimals, as CVAT
    writes them. Left out (CVAT cannot hold them): ``seconds``, the rest of the camera,
    ``horizon_sd_px``, the ground truth, the scene's own ``classes``.

    Raises ``ValueError`` when scenes sharing an image disagree (on its size, horizon or camera
    id), and for a reference without a line (a target's own size, a distance between two targets):
    it has no shape.
    """
    scenes = [scene_to_dict(parse_scene(s) if isinstance(s, dict) else s) for s in scenes]
    names = list(image_names) if image_names is not None else [None] * len(scenes)
    if len(names) != len(scenes):
        raise ValueError(f"image_names: expected {len(scenes)} names, got {len(names)}")
    images: dict[str, list] = {}
    for d, name in zip(scenes, names):
        name = name or (PurePosixPath(d["image"]["path"]).name if d["image"].get("path")
                        else f"{safe_name(d['targets'][0]['id'])}.jpg")
        images.setdefault(name, []).append(d)
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    root.append(_meta(len(images)))
    for i, (name, group) in enumerate(images.items()):
        w, h = group[0]["image"]["width"], group[0]["image"]["height"]
        horizons = {json.dumps(d.get("horizon")) for d in group}
        camera_ids = {(d.get("camera") or {}).get("id") for d in group}
        settings = {d.get("setting") for d in group}
        if any((d["image"]["width"], d["image"]["height"]) != (w, h) for d in group) or len(horizons) > 1:
            raise ValueError(f"scenes on image {name!r} disagree on its size or horizon")
        if len(camera_ids) > 1:
            raise ValueError(f"scenes on image {name!r} disagree on its camera id "
                             f"({sorted(map(repr, camera_ids))}); one photo has one camera")
        if len(settings) > 1:
            raise ValueError(f"scenes on image {name!r} disagree on its setting ({sorted(map(repr, settings))}); "
                             "one photo has one setting")
        ids = [t["id"] for d in group for t in d["targets"]]
        if len(set(ids)) < len(ids):
            raise ValueError(f"scenes on image {name!r} share a target id ({ids}); give each target its own")
        img = ET.SubElement(root, "image", {"id": str(i), "name": name, "width": str(w), "height": str(h)})
        for d in group:
            for t in d["targets"]:
                size = {f"{k}_m": float(v) for k, v in (t.get("dimensions_m") or {}).items()}
                for dl in t["dimension_lines"]:
                    _shape_el(img, "points", TARGET, dl["corners"],
                              {"target_id": t["id"], "class": t.get("class"), **size, "worker": dl.get("worker")})
            for j, r in enumerate(d.get("references", [])):
                if "line" not in r:
                    raise ValueError(f"references[{j}]: a {r['measure']} of {r.get('target') or r.get('targets')!r} "
                                     "without a line cannot be written as a CVAT shape")
                vals = {"target_id": r.get("target"), "object": r.get("object"), "measure": r["measure"],
                        "mode": r["mode"], "unit": r.get("unit"), "worker": r.get("worker")}
                if "range" in r:
                    vals["range_low"], vals["range_high"] = map(float, r["range"])
                else:
                    vals["value"] = float(r["value"])
                if r.get("confidence") is not None:
                    vals["confidence_pct"] = round(100.0 * r["confidence"], 10)
                _shape_el(img, "polyline", REFERENCE, r["line"], vals)
        if group[0].get("horizon") is not None:
            _shape_el(img, "polyline", HORIZON, group[0]["horizon"], {})
        for label, value in ((CAMERA, next(iter(camera_ids))), (SETTING, next(iter(settings)))):
            if value is not None:
                tag = ET.SubElement(img, "tag", {"label": label, "source": "manual"})
                ET.SubElement(tag, "attribute", {"name": _TAGS[label][0]}).text = value
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
