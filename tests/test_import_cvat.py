"""CVAT import/export: a hand-written CVAT for images 1.1 file, images of several targets, round
trips of scenes of one and several targets, the shipped label spec, untrusted XML, the --targets
table, --image-dir, and the bad-input messages (naming the image and the shape)."""

import json
import re
import zipfile
from pathlib import Path

import pytest
from test_import_labelstudio import KAYAK, tool_scene

from creference_bayes.cli import main
from creference_bayes.io.annotation_tools import REFERENCE_FIELDS, ConversionError, load_target_table
from creference_bayes.io.cvat import (LABEL_ATTRIBUTES, cvat_label_spec, cvat_xml, read_cvat_xml,
                                      scenes_from_cvat)
from creference_bayes.models.size_priors import KITTI_SIZE_PRIORS, size_priors_from_dict

DATA = Path(__file__).parent / "data"
XML = DATA / "cvat_annotations.xml"


def _convert(text, **kw):
    return scenes_from_cvat(read_cvat_xml(text if isinstance(text, bytes) else text.encode()), **kw)


def test_xml_file_gives_the_hand_written_scenes(assert_same_scene):
    report = scenes_from_cvat(read_cvat_xml(XML))
    scenes = {s.name: s.scene for s in report.scenes}
    assert sorted(scenes) == ["living_room", "photos_street"]
    assert_same_scene(scenes["living_room"], {
        "format": "creference-scene/2", "image": {"width": 4000, "height": 3000},
        "horizon": [[0, 1200], [4000, 1260]],
        "targets": [
            {"id": "cupboard", "dimensions_m": {"length": 1.2, "width": 0.5, "height": 2.0},
             "dimension_lines": [
                 {"worker": "w1", "corners": [[1600, 2400], [2000, 2340], [1520, 2280], [1600, 1500]]},
                 {"worker": "w2", "corners": [[1640.5, 2430.25], [2040, 2370], [1480, 2250], [1640, 1470]]}]},
            {"id": "lamp", "dimensions_m": {"length": 0.4, "width": 0.4, "height": 1.6},
             "dimension_lines": [{"worker": "w1", "corners": [[3000, 2000], [3100, 1990], [2950, 1980], [3000, 1700]]}]}],
        "references": [
            {"measure": "length", "mode": "direct", "value": 80, "unit": "in", "object": "sofa",  # no target_id:
             "confidence": 0.6, "worker": "w3", "line": [[400, 2700], [1200, 2760]]},          # a ground segment
            {"measure": "width", "mode": "relative", "range": [0.9, 1.2], "target": "cupboard",
             "line": [[3000, 2850], [3400, 2820]]}]})
    assert_same_scene(scenes["photos_street"], {
        "format": "creference-scene/2", "image": {"width": 2000, "height": 1000},
        "targets": [{"id": "street", "dimensions_m": {"length": 1.6, "width": 0.8, "height": 0.75},
                     "dimension_lines": [{"corners": [[1000, 700], [1200, 700], [900, 650], [1000, 400]]}]}],
        "references": [{"measure": "distance", "mode": "direct", "range": [10, 15], "unit": "ft",
                        "line": [[400, 999], [500, 750]]}]})
    assert [str(e) for e in report.errors] == [
        "image 'bad.jpg', shape 1 (polyline 'reference'): reference line has 3 points, expected 2"]
    assert "image 'living_room.jpg', shape 6: label 'person' ignored" in report.notes
    assert "image 'empty.jpg': no target annotated; skipped" in report.notes


def test_cli_reads_the_xml_or_the_zip_and_exits_2_on_the_bad_image(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "street.png").write_bytes(b"")  # found under its name in the task
    zpath = tmp_path / "task.zip"
    with zipfile.ZipFile(zpath, "w") as z:
        z.write(XML, "annotations.xml")
    for source in (XML, zpath):
        out = tmp_path / source.suffix[1:]
        assert main(["import", "cvat", str(source), "--out", str(out), "--image-dir", str(tmp_path)]) == 2
        assert sorted(p.name for p in out.iterdir()) == ["living_room.json", "photos_street.json"]
        street = json.loads((out / "photos_street.json").read_text())
        assert street["image"]["path"] == "../photos/street.png"
    assert "error: image 'bad.jpg', shape 1 (polyline 'reference')" in capsys.readouterr().err


def test_print_labels_is_the_shipped_spec(capsys):
    assert main(["import", "cvat", "--print-labels"]) == 0
    spec = json.loads(capsys.readouterr().out)
    assert spec == cvat_label_spec()
    assert {lab["name"]: tuple(a["name"] for a in lab["attributes"]) for lab in spec} == LABEL_ATTRIBUTES
    assert set(REFERENCE_FIELDS) < set(LABEL_ATTRIBUTES["reference"])
    assert {lab["name"]: lab["type"] for lab in spec} == {"target": "points", "reference": "polyline",
                                                          "horizon": "polyline", "camera": "tag", "setting": "tag"}
    for lab in spec:
        for a in lab["attributes"]:
            # an unset select must stay unset (CVAT's sentinel), not default to its first value
            if a["input_type"] == "select":
                assert a["default_value"] == a["values"][0] == "__undefined__"
            else:
                assert a["input_type"] == "text" and a["default_value"] == ""
    (target,) = [lab for lab in spec if lab["name"] == "target"]
    (cls,) = [a for a in target["attributes"] if a["name"] == "class"]
    assert set(cls["values"][1:]) == set(KITTI_SIZE_PRIORS)


# ----------------------------------------------------------------------------------------------
# round trips: scenes → CVAT XML → import → the same scenes (to CVAT's 0.01 px)

#: What CVAT cannot carry: the camera, the horizon's sd, seconds, the ground truth.
_LOST = ("camera", "horizon_sd_px", "seconds", "ground_truth")
_CLASSES = size_priors_from_dict({"Kayak": KAYAK}, source="file")


@pytest.mark.parametrize("seed", [0, 1])
def test_round_trip_through_cvat_xml(seed, assert_same_scene):
    scenes = [tool_scene(seed, m=3), tool_scene(seed + 10, m=1), tool_scene(seed + 20, m=5)]
    text = cvat_xml(scenes, image_names=["a.png", "b/c.png", "d.png"])
    report = _convert(text, classes=_CLASSES)  # the scene's own classes come back from --classes
    assert report.ok, report.errors
    assert [s.name for s in report.scenes] == ["a", "b_c", "d"]
    for s, want in zip(report.scenes, scenes):
        assert_same_scene(s.scene, want, atol=0.005, drop=_LOST)
        if "classes" not in want:
            assert "classes" not in s.scene


def test_scenes_on_one_image_become_one_scene(assert_same_scene):
    """Two scene files of one photo (e.g. version-1 files, one per target) share its <image> and
    import as one scene holding both targets."""
    a, b = tool_scene(3, m=1), tool_scene(3, m=2)
    b["targets"] = b["targets"][1:]
    b["references"] = [r for r in b["references"] if r.get("target") != "t0"]
    text = cvat_xml([a, b], image_names=["room.jpg", "room.jpg"])
    assert len(re.findall(r"<image ", text)) == 1
    (s,) = _convert(text).scenes
    both = {**a, "targets": a["targets"] + b["targets"], "references": a["references"] + b["references"]}
    assert_same_scene(s.scene, both, atol=0.005, drop=_LOST)


def test_export_refuses_what_it_cannot_write():
    a, b = tool_scene(0, m=1), tool_scene(1, m=1)
    b["horizon"][1][1] += 5.0
    with pytest.raises(ValueError, match="disagree on its size or horizon"):
        cvat_xml([a, b], image_names=["x.jpg", "x.jpg"])
    with pytest.raises(ValueError, match=r"share a target id \(\['t0', 't0'\]\)"):
        cvat_xml([a, {**a, "references": []}], image_names=["x.jpg", "x.jpg"])
    a["references"].append({"measure": "height", "mode": "direct", "value": 1.8, "unit": "m", "target": "t0"})
    with pytest.raises(ValueError, match=r"references\[4\]: a height of 't0' without a line"):
        cvat_xml([a])


# ----------------------------------------------------------------------------------------------
# images of several targets: classes, sizes, references naming their target


def _target(tid, cls="", pts="1000,700;1200,700;900,650;1000,400", size=None):
    attrs = f'<attribute name="target_id">{tid}</attribute><attribute name="class">{cls}</attribute>'
    if size:
        attrs += "".join(f'<attribute name="{k}_m">{v}</attribute>' for k, v in zip(("length", "width", "height"), size))
    return f'<points label="target" points="{pts}">{attrs}</points>'


def test_an_image_of_several_targets_is_one_scene():
    doc = _doc(_target("car1", "Car"), _target("car1", "Car", "1010,705;1210,700;905,650;1000,405"),
               _target("post", "", "300,700;320,700;300,690;300,300", size=(0.2, 0.2, 3.0)),
               _ref("car1", "relative", unit=""), _ref("", "direct", "5", "m"),
               '<polyline label="horizon" points="0,300;2000,320"></polyline>', name="street.png")
    report = _convert(doc)
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.name == "street"
    d = s.scene
    assert [(t["id"], t.get("class"), t.get("dimensions_m"), len(t["dimension_lines"])) for t in d["targets"]] == [
        ("car1", "Car", None, 2), ("post", None, {"length": 0.2, "width": 0.2, "height": 3.0}, 1)]
    assert d["targets"][0]["dimension_lines"][1]["corners"] == [[1010, 705], [1210, 700], [905, 650], [1000, 405]]
    assert [(r["mode"], r.get("target")) for r in d["references"]] == [("relative", "car1"), ("direct", None)]
    assert d["horizon"] == [[0.0, 300.0], [2000.0, 320.0]]


# ----------------------------------------------------------------------------------------------
# bad input


_HEAD = '<?xml version="1.0"?><annotations><version>1.1</version><meta><task/></meta>'
_TARGET = ('<points label="target" points="1000,700;1200,700;900,650;1000,400">'
           '<attribute name="target_id">{tid}</attribute><attribute name="length_m">1.6</attribute>'
           '<attribute name="width_m">0.8</attribute><attribute name="height_m">0.75</attribute></points>')
_REF = ('<polyline label="reference" points="{pts}"><attribute name="target_id">{tid}</attribute>'
        '<attribute name="measure">length</attribute><attribute name="mode">{mode}</attribute>'
        '<attribute name="value">{value}</attribute><attribute name="unit">{unit}</attribute></polyline>')


def _doc(*shapes, name="im.jpg", size='width="2000" height="1000"'):
    return f'{_HEAD}<image id="0" name="{name}" {size}>{"".join(shapes)}</image></annotations>'


def _ref(tid="", mode="direct", value="2", unit="m", pts="100,900;300,920"):
    return _REF.format(tid=tid, mode=mode, value=value, unit=unit, pts=pts)


@pytest.mark.parametrize("doc, message", [
    (_doc(_TARGET.format(tid="a"), _TARGET.format(tid="b"), _ref(mode="relative", unit="__undefined__")),
     "image 'im.jpg', shape 2 (polyline 'reference'): a relative reference needs a target_id"),
    (_doc(_TARGET.format(tid="a"), _ref(tid="c")),
     "image 'im.jpg', shape 1 (polyline 'reference'): reference for target 'c', but no target shape"),
    (_doc(_TARGET.format(tid="a"), _TARGET.format(tid="")),
     "image 'im.jpg', shape 1 (points 'target'): this target shape has no target_id, and the image has several "
     "targets (['a']); give every target shape its target_id"),
    (_doc(_TARGET.format(tid=""), _ref(value="2 m")), "shape 1 (polyline 'reference'): value is not a number: '2 m'"),
    (_doc(_TARGET.format(tid=""), _ref(unit="furlong")), "unknown unit 'furlong'"),
    (_doc(_TARGET.format(tid=""), _ref(pts="100,900;1O0,950")), "a coordinate is not a number: '1O0'"),
    (_doc(_TARGET.format(tid=""), _ref(pts="100,900,3;300,920")), "malformed point '100,900,3'"),
    (_doc(_TARGET.format(tid="").replace("1000,400", "1000,400;5,5")),
     "shape 0 (points 'target'): target has 5 points, expected 4 (t1..t4)"),
    (_doc(_TARGET.format(tid="").replace("0.8<", "0.9<"), _TARGET.format(tid="")),
     "shape 1 (points 'target'): target size"),
    (_doc(_TARGET.format(tid=""), size='width="2000"'), "image 'im.jpg': height is not a number: None"),
    (_doc(_ref()), "image 'im.jpg': references or a horizon but no target shape"),
    (_doc(_TARGET.format(tid="").replace("1000,400", "1000,-900")),
     "image 'im.jpg', shape 0 (points 'target'): targets[0].dimension_lines[0].corners[3]: point [1000, -900]"),
    (_doc(_TARGET.format(tid=""), '<polyline label="horizon" points="5,0;5,900"/>'),
     "a vertical horizon line at u = 5 cannot be used"),
    (_doc(_target("a", "Car"), _target("a", "Van")), "shape 1 (points 'target'): class 'Van' here but 'Car' on shape 0"),
    (_doc(_target("a", "Spaceship")), "shape 0 (points 'target'): targets[0].class: no size prior for class 'Spaceship'"),
    (_doc(_target("a", "Car"), _TARGET.format(tid="b"), _ref(tid="b", unit="__undefined__")),
     "image 'im.jpg', shape 2 (polyline 'reference'): a direct measurement needs a unit"),
])
def test_bad_image_is_reported_with_image_and_shape(doc, message):
    report = _convert(doc)
    assert report.scenes == ()
    (err,) = report.errors
    assert message in str(err), str(err)


def test_one_bad_image_does_not_skip_the_others():
    bad = _doc(_TARGET.format(tid="a"), _ref(tid="a", unit="__undefined__"))
    good = _doc(_TARGET.format(tid="b"), name="b.jpg")
    two = bad.replace("</annotations>", good[good.index("<image "):])
    report = _convert(two)
    assert [s.name for s in report.scenes] == ["b"]
    (err,) = report.errors
    assert str(err).startswith("image 'im.jpg', shape 1 (polyline 'reference'): a direct measurement needs a unit")


def test_sizes_from_the_targets_table(tmp_path):
    bare = _TARGET.format(tid="sofa").replace("1.6", "").replace("0.8", "").replace("0.75", "")
    report = _convert(_doc(bare))
    assert "no size for target 'sofa'" in str(report.errors[0])
    csv = tmp_path / "t.csv"
    csv.write_text("target_id,length_m,width_m,height_m\nsofa,2.1,0.9,0.8\n")
    (s,) = _convert(_doc(bare), targets=load_target_table(csv)).scenes
    assert s.scene["targets"][0]["dimensions_m"] == {"length": 2.1, "width": 0.9, "height": 0.8}


@pytest.mark.parametrize("table, message", [
    ("id,length_m\n", "missing column(s) ['target_id', 'width_m', 'height_m']"),
    ("target_id,length_m,width_m,height_m\na,1,1,0\n", "t.csv line 2: height_m must be positive, got 0"),
    ("target_id,length_m,width_m,height_m\na,1,1,1\na,1,1,1\n", "t.csv line 3: target_id 'a' appears twice"),
])
def test_bad_targets_table(tmp_path, table, message):
    csv = tmp_path / "t.csv"
    csv.write_text(table)
    with pytest.raises(ConversionError, match=re.escape(message)):
        load_target_table(csv)


def test_xml_with_entities_is_refused_before_parsing():
    bomb = ('<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
            '<!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>'
            '<annotations>&lol2;</annotations>')
    with pytest.raises(ConversionError, match="declares a DTD or entities"):
        read_cvat_xml(bomb.encode())


_ENTITY_DOC = ('<?xml version="1.0" encoding="{enc}"?>\n<!DOCTYPE annotations [<!ENTITY who "the crowd">]>\n'
               '<annotations><version>1.1</version><image id="0" name="a.jpg" width="10" height="10">'
               '<tag label="camera"><attribute name="camera_id">&who;</attribute></tag></image></annotations>')


@pytest.mark.parametrize("enc", ["utf-8", "utf-16"])
@pytest.mark.parametrize("doc", [_ENTITY_DOC, '<?xml version="1.0" encoding="{enc}"?><!DOCTYPE annotations>'
                                               '<annotations><version>1.1</version></annotations>'])
def test_a_dtd_is_refused_by_the_parser_in_any_encoding(tmp_path, capsys, enc, doc):
    """Not a pattern on the raw bytes: a UTF-16 document (no ASCII '<!DOCTYPE' in it) is refused
    too, with or without an internal entity."""
    data = doc.format(enc=enc).encode(enc)
    assert (b"<!DOCTYPE" in data) == (enc == "utf-8")
    with pytest.raises(ConversionError, match="declares a DTD or entities"):
        read_cvat_xml(data)
    path = tmp_path / "annotations.xml"
    path.write_bytes(data)
    assert main(["import", "cvat", str(path), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {path}: the XML declares a DTD or entities, which CVAT "
                                               "files never do; refused (entity expansion is unsafe)")
    assert not (tmp_path / "o").exists()


def test_an_encoding_the_parser_cannot_read_is_one_line():
    data = '<?xml version="1.0" encoding="utf-16-le"?><annotations/>'.encode("utf-16-le")
    with pytest.raises(ConversionError, match=r"^\(xml\): cannot be parsed as XML: multi-byte encodings"):
        read_cvat_xml(data)


def test_only_what_the_importer_reads_is_kept_of_the_xml():
    meta = "<meta><task>" + "<label><name>x</name><attributes><attribute/></attributes></label>" * 500 + "</task></meta>"
    text = XML.read_text().replace("<version>1.1</version>", "<version>1.1</version>" + meta + "<junk><a/><b/></junk>")
    root = read_cvat_xml(text.encode())
    assert [el.tag for el in root] == ["version"] + ["image"] * len(root.findall("image"))
    assert {s.name for s in scenes_from_cvat(root).scenes} == {"living_room", "photos_street"}
    deep = read_cvat_xml(b'<annotations><track id="1"><box/><box/></track><image name="a" width="1" height="1">'
                         b'<points label="target"><attribute name="k">v<x><y/></x></attribute></points></image>'
                         b'</annotations>')
    assert [len(el) for el in deep] == [0, 1]  # a track only noted; nothing below an attribute
    assert deep.find("image/points/attribute").text == "v"


def test_an_xml_of_too_many_elements_or_bytes_is_refused(tmp_path, capsys, monkeypatch):
    from creference_bayes.io import cvat

    monkeypatch.setattr(cvat, "MAX_XML_ELEMENTS", 100)
    many = b"<annotations>" + b"<x/>" * 100 + b"</annotations>"  # the root and 100 more
    with pytest.raises(ConversionError, match=r"^\(xml\): more than 100 XML elements; refused"):
        read_cvat_xml(many)
    read_cvat_xml(many.replace(b"<x/>", b"", 1))
    monkeypatch.setattr(cvat, "MAX_XML_BYTES", 1 << 20)
    path = tmp_path / "annotations.xml"
    path.write_bytes(b"<annotations>" + b" " * (1 << 20) + b"</annotations>")
    with pytest.raises(ConversionError, match=r"annotations.xml: the XML is larger than 1 MiB; refused"):
        read_cvat_xml(path)
    zpath = tmp_path / "task.zip"
    with zipfile.ZipFile(zpath, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("annotations.xml", path.read_bytes())
    assert zpath.stat().st_size < 5000
    assert main(["import", "cvat", str(zpath), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {zpath}: annotations.xml unpacks to {(1 << 20) + 27} bytes, "
                                               "more than 1 MiB; refused (a CVAT export of thousands of images is "
                                               "a few tens of MB)")
    with zipfile.ZipFile(zpath, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("annotations.xml", many)
    assert main(["import", "cvat", str(zpath), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {zpath}: annotations.xml: more than 100 XML elements; "
                                               "refused (a CVAT export of thousands of images has far fewer)")


@pytest.mark.parametrize("text, message", [
    ("<annotations><image", "not well-formed XML"),
    ("<dataset/>", "the root element is <dataset>, expected <annotations>"),
])
def test_not_a_cvat_file(tmp_path, text, message, capsys):
    path = tmp_path / "a.xml"
    path.write_text(text)
    with pytest.raises(ConversionError, match=message):
        read_cvat_xml(path)
    assert main(["import", "cvat", str(path), "--out", str(tmp_path / "o")]) == 2
    assert message in capsys.readouterr().err


def test_zip_without_annotations_xml(tmp_path, capsys):
    zpath = tmp_path / "task.zip"
    with zipfile.ZipFile(zpath, "w") as z:
        z.writestr("images/a.jpg", b"")
    assert main(["import", "cvat", str(zpath), "--out", str(tmp_path / "o")]) == 2
    assert "expected one annotations.xml in the ZIP, found 0" in capsys.readouterr().err


def test_cli_checks_its_options_first(tmp_path, capsys):
    bad = tmp_path / "t.csv"
    bad.write_text("id,size\n")
    out = tmp_path / "o"
    assert main(["import", "cvat", str(XML), "--out", str(out), "--targets", str(bad)]) == 2
    assert main(["import", "cvat", str(XML), "--out", str(out), "--image-dir", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "error: --targets: " in err and "t.csv: missing column(s)" in err and "is not a folder" in err
    assert not out.exists()


# ----------------------------------------------------------------------------------------------
# the --targets table: rows keyed by image and target, camera-only rows


def _table(tmp_path, text):
    csv = tmp_path / "t.csv"
    csv.write_text(text)
    return load_target_table(csv)


def _image(name, *shapes):
    return f'<image id="0" name="{name}" width="2000" height="1000">{"".join(shapes)}</image>'


def _two_images(tid="1"):
    """Two images, each with one size-less target of the same id (KITTI-style ids per image)."""
    bare = _TARGET.format(tid=tid).replace("1.6", "").replace("0.8", "").replace("0.75", "")
    misc = bare.replace('<attribute name="target_id">', '<attribute name="class">Misc</attribute>'
                                                       '<attribute name="target_id">')
    return (f'{_HEAD}{_image("drive/a.png", misc)}{_image("drive/b.png", misc)}</annotations>').encode()


def test_a_targets_row_with_an_image_applies_to_that_image_only(tmp_path):
    table = _table(tmp_path, "image,target_id,length_m,width_m,height_m\na.png,1,4.2,1.8,1.5\n")
    report = scenes_from_cvat(read_cvat_xml(_two_images()), targets=table)
    assert report.ok, report.errors
    a, b = (s.scene["targets"][0] for s in report.scenes)
    assert a["dimensions_m"] == {"length": 4.2, "width": 1.8, "height": 1.5}
    assert "dimensions_m" not in b and b["class"] == "Misc"  # its class's size prior applies
    assert not any("t.csv" in n for n in report.notes)


def test_a_targets_row_without_an_image_applies_everywhere_and_says_so(tmp_path):
    table = _table(tmp_path, "target_id,length_m,width_m,height_m\n1,4.2,1.8,1.5\n")
    report = scenes_from_cvat(read_cvat_xml(_two_images()), targets=table)
    assert [s.scene["targets"][0]["dimensions_m"]["length"] for s in report.scenes] == [4.2, 4.2]
    (note,) = [n for n in report.notes if "t.csv" in n]
    assert note.startswith("t.csv line 2: target '1' has no image and was applied on 2 images "
                           "('drive/a.png', 'drive/b.png')"), note


def test_a_targets_row_may_give_only_a_focal_length(tmp_path):
    table = _table(tmp_path, "image,target_id,length_m,width_m,height_m,focal_length_px\n"
                             ",sofa,,,,2100\n"        # every image with a target 'sofa'
                             "im.jpg,,,,,2100\n")     # the camera of im.jpg, no target
    (s,) = _convert(_doc(_TARGET.format(tid="sofa")), targets=table).scenes
    assert s.scene["camera"] == {"focal_length_px": 2100.0}
    assert s.scene["targets"][0]["dimensions_m"] == {"length": 1.6, "width": 0.8, "height": 0.75}  # the export's
    (s,) = _convert(_doc(_TARGET.format(tid="lamp")), targets=table).scenes  # the image's own row
    assert s.scene["camera"] == {"focal_length_px": 2100.0}
    (s,) = _convert(_doc(_TARGET.format(tid="lamp"), name="other.jpg"), targets=table).scenes
    assert "camera" not in s.scene
    bare = _TARGET.format(tid="sofa").replace("1.6", "").replace("0.8", "").replace("0.75", "")
    (err,) = _convert(_doc(bare), targets=table).errors  # a focal length is no size
    assert "no size for target 'sofa'" in str(err)


def test_targets_rows_of_one_photo_must_agree_on_the_focal_length(tmp_path):
    table = _table(tmp_path, "image,target_id,length_m,width_m,height_m,focal_length_px\n"
                             "im.jpg,,,,,2100\nim.jpg,sofa,,,,1900\n")
    (err,) = _convert(_doc(_TARGET.format(tid="sofa")), targets=table).errors
    assert str(err) == ("image 'im.jpg': the --targets table gives focal lengths 2100 px "
                        "(t.csv line 2) and 1900 px (t.csv line 3) for one photo (one camera)")


def test_a_targets_row_naming_no_image_of_the_export_is_noted(tmp_path):
    table = _table(tmp_path, "image,target_id,length_m,width_m,height_m\nim.jgp,sofa,2,1,1\n")
    report = _convert(_doc(_TARGET.format(tid="sofa")), targets=table)
    assert report.ok
    assert "--targets: no image of the export matches t.csv line 2 (image 'im.jgp'); not used" in report.notes


@pytest.mark.parametrize("table, message", [
    ("target_id,length_m,width_m,height_m\na,1,,1\n", "t.csv line 2: give all of length_m, width_m and height_m"),
    ("target_id,length_m,width_m,height_m\na,,,\n", "t.csv line 2: the row for target 'a' gives no size and no "
                                                    "focal_length_px"),
    ("image,target_id,length_m,width_m,height_m\nx.png,,1,1,1\n", "t.csv line 2: empty target_id"),
    ("image,target_id,length_m,width_m,height_m\nx.png,a,1,1,1\nx.png,a,2,1,1\n",
     "t.csv line 3: image 'x.png' and target_id 'a' appears twice (also t.csv line 2)"),
    ("target_id,length_m,width_m,height_m,focal_length_px\na,1,1,1,wide\n",
     "focal_length_px is not a number: 'wide'"),
])
def test_bad_targets_table_rows(tmp_path, table, message):
    with pytest.raises(ConversionError, match=re.escape(message)):
        _table(tmp_path, table)


def test_a_targets_table_that_is_not_text(tmp_path, capsys):
    bad = tmp_path / "t.csv"
    bad.write_bytes(b"target_id,length_m,width_m,height_m\n\xff\xfe,1,1,1\n")
    assert main(["import", "cvat", str(XML), "--out", str(tmp_path / "o"), "--targets", str(bad)]) == 2
    assert "error: --targets: " in capsys.readouterr().err


# ----------------------------------------------------------------------------------------------
# --image-dir: the image under its name in the task, else by its file name; a note when missing


def test_image_dir_finds_the_image_by_its_file_name(tmp_path):
    images = tmp_path / "image_2"
    images.mkdir()
    doc = _doc(_TARGET.format(tid=""), name="street/000007.png")
    (images / "000007.png").write_bytes(b"")
    report = _convert(doc, image_dir=images, out_dir=tmp_path / "out")
    (s,) = report.scenes
    assert s.scene["image"]["path"] == "../image_2/000007.png"
    assert not any("image file" in n for n in report.notes)
    (images / "street").mkdir()
    (images / "street" / "000007.png").write_bytes(b"")  # the full name wins when it exists
    (s,) = _convert(doc, image_dir=images, out_dir=tmp_path / "out").scenes
    assert s.scene["image"]["path"] == "../image_2/street/000007.png"


def test_image_dir_without_the_image_says_so(tmp_path):
    images = tmp_path / "image_2"
    images.mkdir()
    report = _convert(_doc(_TARGET.format(tid=""), name="street/000007.png"), image_dir=images,
                      out_dir=tmp_path / "out")
    (s,) = report.scenes
    assert s.scene["image"]["path"] == "../image_2/000007.png"
    (note,) = [n for n in report.notes if "image file" in n]
    assert note.startswith(f"image 'street/000007.png': no image file {images / 'street' / '000007.png'} or "
                           f"{images / '000007.png'}"), note


# ----------------------------------------------------------------------------------------------
# what docs/import.md says: other shapes are ignored with a note (an unnamed target among named ones
# is refused: test_bad_image_is_reported_with_image_and_shape, and the frames' test)


@pytest.mark.parametrize("tag", ["box", "polygon", "tag"])
def test_a_target_drawn_with_another_shape_is_ignored_with_a_note(tag):
    other = f'<{tag} label="target" points="1,2;3,4;5,6;7,8"><attribute name="target_id">x</attribute></{tag}>'
    report = _convert(_doc(_TARGET.format(tid="sofa"), other))
    assert report.ok, report.errors
    (s,) = report.scenes
    (t,) = s.scene["targets"]
    assert t["id"] == "sofa" and len(t["dimension_lines"]) == 1
    assert f"image 'im.jpg', shape 1: <{tag}> 'target' ignored (a target is drawn as points or a polyline)" \
        in report.notes


# ----------------------------------------------------------------------------------------------
# input files that are missing or cannot be read


@pytest.mark.parametrize("name", ["missing.zip", "missing.xml"])
def test_a_missing_export_says_it_does_not_exist(tmp_path, capsys, name):
    path = tmp_path / name
    assert main(["import", "cvat", str(path), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {path}: no such file (it does not exist)"


def test_an_unreadable_export_names_the_file(tmp_path, capsys, monkeypatch):
    import builtins

    path = tmp_path / "task.zip"
    path.write_bytes(b"PK")
    real_open = builtins.open

    def refusing_open(file, *args, **kwargs):
        if str(file) == str(path):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", refusing_open)
    assert main(["import", "cvat", str(path), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {path}: cannot be read: Permission denied"


def test_a_broken_zip_names_the_file(tmp_path, capsys):
    path = tmp_path / "task.zip"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("annotations.xml", "<annotations>" + "<image/>" * 1000 + "</annotations>")
    data = bytearray(path.read_bytes())
    data[60:90] = b"\0" * 30  # inside the compressed annotations.xml
    path.write_bytes(bytes(data))
    assert main(["import", "cvat", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {path}: cannot read the ZIP: "), err


# ----------------------------------------------------------------------------------------------
# the camera's name: a `camera` tag's camera_id → camera.id (frames of one camera: creference batch --rig)


def _camera(value, extra=""):
    attr = "" if value is None else f'<attribute name="camera_id">{value}</attribute>'
    return f'<tag label="camera" source="manual">{attr}{extra}</tag>'


def test_a_setting_tag_is_the_scenes_setting_and_goes_back_out(tmp_path):
    """A ``setting`` tag on the image names where the photo was taken (the scene's ``setting``:
    the data set's distance population is pooled per setting); tags of one image must agree, an
    empty one is refused naming it; scenes → XML writes it back."""
    tag = '<tag label="setting" source="manual"><attribute name="setting">{}</attribute></tag>'
    (s,) = _convert(_doc(_TARGET.format(tid="sofa"), tag.format(" living room "), _camera("cam1"))).scenes
    assert s.scene["setting"] == "living room" and s.scene["camera"] == {"id": "cam1"}
    (err,) = _convert(_doc(_TARGET.format(tid="sofa"), tag.format(""))).errors
    assert str(err).startswith("image 'im.jpg', shape 1 (tag 'setting'): a setting tag with an empty setting ''")
    (err,) = _convert(_doc(_TARGET.format(tid="sofa"), tag.format("kitchen"), tag.format("street"))).errors
    assert str(err).startswith("image 'im.jpg': setting 'kitchen' on shape 1 (tag 'setting') but 'street' on "
                               "shape 2 (tag 'setting'): one photo has one setting")
    back = read_cvat_xml(cvat_xml([s.scene]).encode())
    (again,) = scenes_from_cvat(back).scenes
    assert again.scene["setting"] == "living room"


def test_a_camera_tag_is_the_scene_camera_id(tmp_path):
    report = _convert(_doc(_TARGET.format(tid="sofa"), _camera("  dashcam left ")))
    assert report.ok, report.errors
    (s,) = report.scenes
    assert s.scene["camera"] == {"id": "dashcam left"}
    # with a focal length from the --targets table, and the same id on a second tag
    table = _table(tmp_path, "image,target_id,length_m,width_m,height_m,focal_length_px\nim.jpg,,,,,2100\n")
    (s,) = _convert(_doc(_camera("cam1"), _TARGET.format(tid="sofa"), _camera("cam1")), targets=table).scenes
    assert s.scene["camera"] == {"id": "cam1", "focal_length_px": 2100.0}
    (s,) = _convert(_doc(_TARGET.format(tid="sofa"))).scenes  # no tag: no camera id
    assert "camera" not in s.scene


@pytest.mark.parametrize("tags, message", [
    ((_camera(""),), "image 'im.jpg', shape 1 (tag 'camera'): a camera tag with an empty camera_id ''"),
    ((_camera("  "),), "image 'im.jpg', shape 1 (tag 'camera'): a camera tag with an empty camera_id ''"),
    ((_camera("__undefined__"),),
     "image 'im.jpg', shape 1 (tag 'camera'): a camera tag with an empty camera_id '__undefined__'"),
    ((_camera(None),), "image 'im.jpg', shape 1 (tag 'camera'): a camera tag with no camera_id attribute"),
    ((_camera("a", '<attribute name="camera_id">b</attribute>'),),
     "image 'im.jpg', shape 1 (tag 'camera'): attribute 'camera_id' is given twice"),
    ((_camera("cam1"), _camera("cam2")),
     "image 'im.jpg': camera_id 'cam1' on shape 1 (tag 'camera') but 'cam2' on shape 2 (tag 'camera'): "
     "one photo has one camera"),
])
def test_a_bad_camera_tag_names_the_image_the_tag_and_the_value(tags, message):
    bad = _doc(_TARGET.format(tid="a"), *tags)
    good = _doc(_TARGET.format(tid="b"), name="b.jpg")
    report = _convert(bad.replace("</annotations>", good[good.index("<image "):]))
    assert [s.name for s in report.scenes] == ["b"], "the other image is still converted"
    (err,) = report.errors
    assert str(err).startswith(message), str(err)


def test_a_camera_label_on_a_shape_is_ignored_with_a_note():
    box = '<box label="camera" xtl="1" ytl="2" xbr="3" ybr="4"><attribute name="camera_id">x</attribute></box>'
    report = _convert(_doc(_TARGET.format(tid="sofa"), box))
    assert report.ok, report.errors
    assert "camera" not in report.scenes[0].scene
    assert "image 'im.jpg', shape 1: <box> 'camera' ignored (the camera is a tag on the image)" in report.notes


def test_the_camera_id_round_trips_through_cvat_xml():
    a, b = tool_scene(0, m=1), tool_scene(1, m=1)
    a["camera"] = {**a.get("camera", {}), "id": "rig/front"}
    text = cvat_xml([a, b], image_names=["a.png", "b.png"])
    assert text.count('<tag label="camera"') == 1
    sa, sb = _convert(text, classes=_CLASSES).scenes
    assert sa.scene["camera"] == {"id": "rig/front"} and "camera" not in sb.scene
    with pytest.raises(ValueError, match="disagree on its camera id"):
        cvat_xml([a, {**a, "camera": {"id": "rig/rear"}, "targets": [{**a["targets"][0], "id": "u0"}],
                      "references": []}], image_names=["x.png", "x.png"])


def test_an_image_name_too_long_for_the_file_system_skips_that_image_only(tmp_path, capsys):
    long = "drive/" + "x" * 300 + ".png"  # one component past the 255 bytes of a file name
    bare = _TARGET.format(tid="1")
    path = tmp_path / "annotations.xml"
    path.write_bytes(f'{_HEAD}{_image("drive/a.png", bare)}{_image(long, bare)}</annotations>'.encode())
    report = scenes_from_cvat(read_cvat_xml(path), image_dir=tmp_path)
    assert [s.name for s in report.scenes] == ["drive_a"]
    (err,) = report.errors
    assert str(err).startswith(f"image '{long[:30]}") and "cannot be looked up in the image folder: " in str(err)
    out = tmp_path / "o"
    assert main(["import", "cvat", str(path), "--out", str(out), "--image-dir", str(tmp_path), "--quiet"]) == 2
    assert [p.name for p in out.iterdir()] == ["drive_a.json"]
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: image 'drive/xxx") and line.endswith("File name too long")
