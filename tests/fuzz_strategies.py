"""Mutation strategies shared by the fuzz tests (test_import_fuzz.py, test_fuzz_readers.py): a valid
seed input, mutated structure-aware (JSON values replaced by other types, keys deleted or added,
lists cut short, elements duplicated; XML attributes and tags changed; CSV cells and rows) and, in
test_fuzz_readers, hostile values (deep nesting, integers beyond Python's 4300-digit limit, NULs,
long strings) and raw byte-level damage (truncation, invalid UTF-8, UTF-16)."""

import copy
import csv
import io
import json
import os
import xml.etree.ElementTree as ET

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: CREFERENCE_FUZZ_EXAMPLES=5000 runs a longer fuzz (and a random one) when looking for crashes.
N_EXAMPLES = int(os.environ.get("CREFERENCE_FUZZ_EXAMPLES", "80"))
#: The slow-marked long fuzz: examples per reader (at least 1000).
N_LONG = max(1000, int(os.environ.get("CREFERENCE_LONG_FUZZ_EXAMPLES", "1000")))


def fuzz_settings(n: int = N_EXAMPLES, derandomize: bool | None = None):
    """Hypothesis settings for ``n`` examples: derandomized up to 150 (a run in CI finds what the last
    one found), random beyond (a long fuzz looks for new crashes)."""
    return settings(max_examples=n, deadline=None, derandomize=n <= 150 if derandomize is None else derandomize,
                    database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much])


FUZZ = fuzz_settings()

#: Keys and texts the importers look for, so that added keys and replaced values hit real branches.
WORDS = ["", "0", "-1", "1e400", "nan", "inf", "2.5", "id", "data", "annotations", "completions", "result",
         "value", "type", "from_name", "to_name", "original_width", "original_height", "image_rotation",
         "x", "y", "vertices", "prevPointId", "closed", "keypointlabels", "vectorlabels", "choices", "number",
         "text", "textarea", "relation", "from_id", "to_id", "points", "lines", "targets", "target", "class",
         "image", "target_id", "image_width", "image_height", "focal_length_px", "horizon", "principal_point",
         "ground_truth", "frame_id", "dimensions_m", "t1 bottom corner", "t4 top of height", "reference start",
         "reference end", "reference", "measure", "mode", "direct", "relative", "unit", "m", "range_low",
         "range_high", "confidence_pct", "was_cancelled", "lead_time", "completed_by", "creference_scene",
         "__undefined__", "Car", "Misc", "camera_id", "camera", "/data/local-files/?d=a/b.png", "http://[::1"]
LEAVES = st.one_of(st.none(), st.booleans(), st.integers(-10**4, 10**4), st.integers(), st.just(10**400),
                   st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8), st.sampled_from(WORDS))
VALUES = st.recursive(LEAVES, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.one_of(st.sampled_from(WORDS), st.text(max_size=4)),
                                                 inner, max_size=4)), max_leaves=6)


# ----------------------------------------------------------------------------------------------
# Hostile values: what a JSON file can hold that a Python value built by hand rarely does


class Raw(str):
    """JSON text put into a document as it is (json.dumps cannot write it: deep nesting, an integer
    of more digits than int() reads)."""


#: Keys of the scene, result and advice formats, beside WORDS.
SCENE_WORDS = ["format", "creference-scene/1", "creference-scene/2", "creference-result/1", "creference-result/2",
               "width", "height", "path", "dimension_lines", "corners", "worker", "seconds", "location_m",
               "yaw_rad", "handedness", "length", "width", "height", "line", "horizon_sd_px", "classes",
               "length_m", "width_m", "height_m", "log_sd", "map", "posterior", "draws", "chain", "objects",
               "provenance", "options", "batch", "key", "source", "scene", "scene_path", "scene_id", "sha256",
               "image_size", "model", "preset", "metrology", "paper", "free", "setup", "orientation", "pitch",
               "roll", "height_m", "ref_scale", "distance_m", "yaw", "z", "ground_m", "size", "known",
               "hdi", "prob", "mean", "sd", "temperature", "focal_length_prior", "camera_height_prior",
               "mounting", "id", "camera_id", "pitch_rad", "roll_rad", "camera_height_m", "range", "value",
               "confidence_pct", "targets", "target", "ratio", "distance"]
HOSTILE_TEXT = st.one_of(
    st.sampled_from(["\x00", "a\x00b", "t0\x00", "../../x", "/etc/passwd", "x" * 300, "é" * 200, "\ud7ff\ufeff",
                     "a/b/c/d/e/f/g/h/i/j/k/l/m/n", "CON", ".", "..", " ", "\n", "\\", "a\nb", "1e999", "-0"]),
    st.text(min_size=256, max_size=2000).filter(lambda s: True),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=12))
HOSTILE_RAW = st.sampled_from([
    Raw("[" * 100_000 + "]" * 100_000), Raw('{"a":' * 50_000 + "1" + "}" * 50_000), Raw("[" * 900 + "]" * 900),
    Raw("9" * 5000), Raw("-" + "1" * 4301), Raw("1" + "0" * 400), Raw("1e999"), Raw("-1e999"), Raw("NaN"),
    Raw("Infinity"), Raw("-Infinity"), Raw("1e-400"), Raw("0.1" + "1" * 5000), Raw("1E+99999999999999999999")])
HOSTILE = st.one_of(VALUES, HOSTILE_TEXT, HOSTILE_RAW, st.sampled_from(SCENE_WORDS),
                    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=9),
                    st.integers(-2**70, 2**70))


def dumps_with_raw(doc) -> str:
    """``doc`` as JSON text, each :class:`Raw` written as the text it holds."""
    raws: list[str] = []

    def swap(node):
        if isinstance(node, Raw):
            raws.append(str(node))
            return f"\x00RAW{len(raws) - 1}\x00"
        if isinstance(node, dict):
            return {swap(k) if isinstance(k, Raw) else k: swap(v) for k, v in node.items()}
        if isinstance(node, list):
            return [swap(v) for v in node]
        return node

    text = json.dumps(swap(doc))
    for i, raw in enumerate(raws):
        text = text.replace(json.dumps(f"\x00RAW{i}\x00"), raw)
    return text


# ----------------------------------------------------------------------------------------------
# JSON


def places(node, path=()):
    """Every place in a JSON document, as a key path."""
    yield path
    if isinstance(node, dict):
        for k, v in node.items():
            yield from places(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from places(v, path + (i,))


def mutate_json(doc, data, values=VALUES, words=WORDS):
    """One mutation of ``doc`` in place: a value replaced (by one of ``values``), deleted, a key or an
    element added, a list or text cut short, another part of the document copied in."""
    path = data.draw(st.sampled_from(list(places(doc))[1:]), label="path")
    *head, last = path
    parent = doc
    for k in head:
        parent = parent[k]
    value = parent[last]
    kind = data.draw(st.sampled_from(["replace", "replace", "delete", "add", "truncate", "copy"]), label="kind")
    if kind == "replace":
        parent[last] = data.draw(values, label="value")
    elif kind == "delete":
        del parent[last]
    elif kind == "add" and isinstance(value, dict):
        value[data.draw(st.sampled_from(words), label="key")] = data.draw(values, label="value")
    elif kind == "add" and isinstance(value, list):
        value.insert(data.draw(st.integers(0, len(value)), label="at"), copy.deepcopy(value[0]) if value
                     and data.draw(st.booleans(), label="copy") else data.draw(values, label="value"))
    elif kind == "truncate" and isinstance(value, (list, str)):
        parent[last] = value[:data.draw(st.integers(0, max(len(value) - 1, 0)), label="length")]
    elif kind == "copy":  # another part of the document in its place: the right shape in the wrong place
        other = data.draw(st.sampled_from(list(places(doc))), label="from")
        node = doc
        for k in other:
            node = node[k]
        parent[last] = copy.deepcopy(node)


def mutated_json(doc, data) -> str:
    """The document mutated 1 to 3 times, as JSON text (the importers' fuzz: no hostile values)."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        mutate_json(doc, data)
    return json.dumps(doc)


def hostile_json(doc, data) -> bytes:
    """The document mutated 1 to 3 times with ordinary and hostile values, as the bytes of a file,
    now and then damaged byte by byte (:func:`damaged`)."""
    doc = copy.deepcopy(doc)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        mutate_json(doc, data, values=HOSTILE, words=WORDS + SCENE_WORDS)
    return damaged(dumps_with_raw(doc).encode("utf-8", "surrogatepass"), data)


# ----------------------------------------------------------------------------------------------
# Bytes


def damaged(raw: bytes, data, p: int = 5) -> bytes:
    """``raw`` as it is, or (one time in ``p``) damaged: cut short, a byte flipped, invalid UTF-8 or a
    NUL put in, re-encoded as UTF-16 or Latin-1, a BOM before it, emptied."""
    if data.draw(st.integers(0, p - 1), label="damage?") != 0:
        return raw
    kind = data.draw(st.sampled_from(["cut", "flip", "invalid", "nul", "utf16", "utf16be", "latin1", "bom", "empty",
                                      "crlf"]), label="damage")
    at = data.draw(st.integers(0, len(raw)), label="at")
    if kind == "cut":
        return raw[:at]
    if kind == "flip" and raw:
        at = min(at, len(raw) - 1)
        return raw[:at] + bytes([raw[at] ^ (1 << data.draw(st.integers(0, 7), label="bit"))]) + raw[at + 1:]
    if kind == "invalid":
        return raw[:at] + data.draw(st.sampled_from([b"\xff", b"\xc3", b"\xed\xa0\x80", b"\x80\x80", b"\xfe\xff"]),
                                    label="bytes") + raw[at:]
    if kind == "nul":
        return raw[:at] + b"\x00" + raw[at:]
    text = raw.decode("utf-8", "replace")
    if kind == "utf16":
        return text.encode("utf-16")
    if kind == "utf16be":
        return text.encode("utf-16-be")
    if kind == "latin1":
        return (text + "é").encode("latin-1", "replace")
    if kind == "bom":
        return b"\xef\xbb\xbf" + raw
    if kind == "crlf":
        return raw.replace(b"\n", b"\r\n").replace(b",", b"\r")
    return b""


# ----------------------------------------------------------------------------------------------
# CSV

CELLS = st.one_of(
    st.sampled_from(["", "0", "-1", "1e400", "-1e400", "nan", "inf", "-inf", "2.5", "1,2,3", "1;2;3", "1.5,2,3",
                     "4 1.7 1.5", "1e-400", "0x10", "１.５", "\x00", "a\x00b", '"', '""', "\n", "\r", "x" * 300,
                     "9" * 5000, "size", "mounting", "reference", "dims", "length", "distance", "Car", "t0", "t1",
                     "cupboard", "table", "bench", "ab12cd34-room.jpg", "../x"]),
    st.text(max_size=10), st.integers().map(str), st.floats().map(str))


def mutated_csv(text: str, data, cells=CELLS) -> bytes:
    """A CSV text with 1 to 3 mutations of its cells and rows (the header is row 0), as bytes, now and
    then damaged (:func:`damaged`)."""
    rows = list(csv.reader(io.StringIO(text, newline="")))
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        if not rows:
            rows.append([])
        r = data.draw(st.integers(0, len(rows) - 1), label="row")
        kind = data.draw(st.sampled_from(["cell", "cell", "cell", "delete_row", "duplicate_row", "cut_row",
                                          "extra_cells", "delete_column", "swap_rows", "empty_row"]), label="kind")
        row = rows[r]
        if kind == "cell" and row:
            row[data.draw(st.integers(0, len(row) - 1), label="col")] = data.draw(cells, label="cell")
        elif kind == "delete_row":
            del rows[r]
        elif kind == "duplicate_row":
            rows.insert(r, list(row))
        elif kind == "cut_row":
            rows[r] = row[:data.draw(st.integers(0, max(len(row) - 1, 0)), label="length")]
        elif kind == "extra_cells":
            rows[r] = row + data.draw(st.lists(cells, min_size=1, max_size=3), label="cells")
        elif kind == "delete_column" and row:
            c = data.draw(st.integers(0, len(row) - 1), label="col")
            rows = [x[:c] + x[c + 1:] for x in rows]
        elif kind == "swap_rows" and len(rows) > 1:
            s = data.draw(st.integers(0, len(rows) - 1), label="other")
            rows[r], rows[s] = rows[s], rows[r]
        elif kind == "empty_row":
            rows.insert(r, [])
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    return damaged(buf.getvalue().encode("utf-8", "surrogatepass"), data)


# ----------------------------------------------------------------------------------------------
# XML (CVAT)

ATTRIBUTE_NAMES = ["name", "width", "height", "label", "points", "id", "target_id", "class", "length_m",
                   "width_m", "height_m", "measure", "mode", "value", "range_low", "range_high", "unit",
                   "confidence_pct", "worker", "object", "camera_id"]
TEXTS = st.one_of(st.sampled_from(WORDS + ATTRIBUTE_NAMES + ["1,2;3,4", "1,2;3,4;5,6;7,8", "0,0;0,0", "1;2",
                                                           "1e999,2;3,4", "nan,1;2,3", "2000", "4000.5"]),
                  st.text(max_size=10), st.integers().map(str), st.floats().map(str))
#: Beside TEXTS, what the long fuzz of test_fuzz_readers puts into attributes (no memory bombs).
HOSTILE_TEXTS = st.one_of(TEXTS, st.sampled_from(["9" * 5000, "1" + "0" * 400, "x" * 300, "a/" * 200,
                                                  "../../x.png", "é" * 200, ";".join(["1,2"] * 2000)]))
TAGS = ["image", "points", "polyline", "box", "polygon", "tag", "attribute", "track", "version", "meta", "x"]


def mutate_xml(root, data, texts=TEXTS):
    elements = list(root.iter())
    parents = {child: parent for parent in elements for child in parent}
    el = data.draw(st.sampled_from(elements[1:]), label="element")
    kind = data.draw(st.sampled_from(["attr", "attr", "text", "drop_attr", "delete", "duplicate", "tag",
                                      "truncate_points"]), label="kind")
    if kind == "attr":
        el.set(data.draw(st.sampled_from(sorted(el.attrib) + ATTRIBUTE_NAMES), label="name"), data.draw(texts))
    elif kind == "text":
        el.text = data.draw(texts, label="text")
    elif kind == "drop_attr" and el.attrib:
        del el.attrib[data.draw(st.sampled_from(sorted(el.attrib)), label="name")]
    elif kind == "delete":
        parents[el].remove(el)
    elif kind == "duplicate":
        parent = parents[el]
        parent.insert(list(parent).index(el), copy.deepcopy(el))
    elif kind == "tag":
        el.tag = data.draw(st.sampled_from(TAGS), label="tag")
    elif kind == "truncate_points" and el.get("points"):
        pts = el.get("points")
        el.set("points", pts[:data.draw(st.integers(0, len(pts) - 1), label="length")])


def mutated_xml(text: bytes, data, texts=TEXTS) -> bytes:
    root = ET.fromstring(text)
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        mutate_xml(root, data, texts)
    out = ET.tostring(root)
    if data.draw(st.integers(0, 19), label="cut") == 0:  # now and then, a file cut short
        out = out[:data.draw(st.integers(0, len(out)), label="at")]
    return out
