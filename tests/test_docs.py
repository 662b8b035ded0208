"""The user documentation: links resolve inside the repository, the example scenes are valid, every
command line of a page parses, every key of a real result is documented, the figure script runs,
and the snippets of docs/labels.md run on the sidecars `creference labels` writes."""

import json
import re
import shlex
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _text(path: Path) -> str:
    """The Markdown without its fenced code blocks and inline code (no links live there)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", path.read_text()))


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = heading.replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", path.read_text()).splitlines():
        m = re.match(r"#{1,6}\s+(.*)", line)
        if m:
            s = _slug(m.group(1))
            out.add(s if s not in seen else f"{s}-{seen[s]}")
            seen[s] = seen.get(s, 0) + 1
    return out


def _links(path: Path):
    for m in LINK.finditer(_text(path)):
        target = m.group(1)
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        yield target


def test_the_documentation_exists():
    names = {p.name for p in DOCS}
    assert {"README.md", "scene_format.md", "result_format.md", "method.md", "user_guide.md"} <= names


USER_PAGES = sorted((ROOT / "docs").glob("*.md"))  # docs/studies/ and docs/benchmark/ hold the measurements
DATED = re.compile(r"\b20\d\d-[01]\d(-[0-3]\d)?\b|\b(until|before|since) (Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)")


@pytest.mark.parametrize("page", USER_PAGES, ids=lambda p: p.name)
def test_a_user_page_is_short_and_undated(page):
    """A user page says how to do something or what something is: under 400 lines, and no dates
    (history is in CHANGELOG.md, measurements in docs/studies/)."""
    lines = page.read_text().splitlines()
    assert len(lines) < 400, f"{page.name}: {len(lines)} lines"
    dated = [f"{page.name}:{i}: {line.strip()}" for i, line in enumerate(lines, 1) if DATED.search(line)]
    assert not dated, dated


def test_the_date_check_finds_a_dated_line():
    assert DATED.search("the prior until 2026-11-27 was wider") and DATED.search("as before Nov 28")
    assert not DATED.search("a camera kitti-38b73e5675, 2026 frames, 10-20 m")


def _broken(doc: Path, root: Path = ROOT) -> list[str]:
    """The relative links of ``doc`` that do not resolve: a file outside ``root`` or missing, or
    an ``#anchor`` that no heading of the Markdown file it points to has."""
    bad = []
    for target in _links(doc):
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.is_relative_to(root):
            bad.append(f"{target}: outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"{target}: no heading #{anchor} in {dest.name}")
    return bad


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_inside_the_repository(doc):
    bad = _broken(doc)
    assert not bad, f"{doc.relative_to(ROOT)}: " + "; ".join(bad)


def test_the_link_checker_catches_broken_links(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n[ok](#title) [gone](missing.md) [anchor](#nope) `[code](x.md)`\n"
                    "```\n[fenced](y.md)\n```\n![img](pic.png) [web](https://example.org)\n")
    (tmp_path / "pic.png").write_bytes(b"")
    assert list(_links(page)) == ["#title", "missing.md", "#nope", "pic.png"]
    assert _anchors(page) == {"title"}
    assert _broken(page, tmp_path) == ["missing.md: no such file", "#nope: no heading #nope in page.md"]


def test_the_link_checker_follows_anchors_into_other_pages(tmp_path):
    """An anchor of another page is checked against that page's headings, by GitHub's slugs:
    lower case, punctuation and backticks dropped, spaces to hyphens, repeats numbered; a heading
    in a code block is none."""
    root = tmp_path / "repo"
    (root / "docs").mkdir(parents=True)
    (root / "docs" / "other.md").write_text(
        "# The JSON (`creference-advice/2`)\n## Speed, as measured\n## Speed, as measured\n"
        "```\n# not a heading\n```\n")
    page = root / "docs" / "page.md"
    page.write_text("[a](other.md#the-json-creference-advice2) [b](other.md#speed-as-measured) "
                    "[c](other.md#speed-as-measured-1) [d](other.md#not-a-heading) [e](other.md#gone) "
                    "[f](../../outside.md) [g](../docs/other.md)\n")
    (tmp_path / "outside.md").write_text("# Outside\n")
    assert _broken(page, root) == ["other.md#not-a-heading: no heading #not-a-heading in other.md",
                                       "other.md#gone: no heading #gone in other.md",
                                       "../../outside.md: outside the repository"]


# ------------------------------------------------------------------------------------------------
# command lines: every `creference …` line of a fenced shell block parses with the real parser


def _command_lines(path: Path) -> list[str]:
    """The ``creference …`` commands of the page's ```bash blocks: comments and redirections
    dropped, continued lines joined, ``[--optional parts]`` unwrapped, one command per ``&&`` /
    ``;`` / ``|`` part."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(), re.S):
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = re.sub(r"\s#.*$", "", line).replace("[", "").replace("]", "")
            line = re.sub(r"\s\d?(>>?|<)&?\s*\S+", "", line)  # redirections
            for part in re.split(r"&&|;|\|", line):
                part = re.sub(r"\$\(?\w+\)?", "0", re.sub(r"^\s*(do|then)\s+", "", part)).strip()
                if part.startswith("creference "):
                    out.append(part)
    return out


def _parse_error(parser, line: str) -> str | None:
    """None when ``line`` parses, else argparse's message."""
    argv = shlex.split(line)[1:]
    try:
        from contextlib import redirect_stderr
        from io import StringIO

        err = StringIO()
        with redirect_stderr(err):
            parser.parse_args(argv)
    except SystemExit as exc:
        return None if exc.code == 0 else err.getvalue().strip().splitlines()[-1]
    return None


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_documented_command_line_parses(doc):
    from creference_bayes.cli.main import build_parser

    parser = build_parser()
    bad = [f"{line!r}: {err}" for line in _command_lines(doc) if (err := _parse_error(parser, line))]
    assert not bad, f"{doc.relative_to(ROOT)}: " + "; ".join(bad)


def test_the_command_line_check_catches_a_removed_option(tmp_path):
    from creference_bayes.cli.main import build_parser

    page = tmp_path / "page.md"
    page.write_text("```bash\ncreference batch scenes/ --out b/ --max-iterations 5   # old\n"
                    "creference estimate-frame f.json\n"
                    "creference import cvat a.xml --out s/ [--targets t.csv] && creference labels b/ --out l/\n"
                    "creference import label-studio --print-config > c.xml 2>&1\n```\n")
    lines = _command_lines(page)
    assert lines == ["creference batch scenes/ --out b/ --max-iterations 5", "creference estimate-frame f.json",
                     "creference import cvat a.xml --out s/ --targets t.csv", "creference labels b/ --out l/",
                     "creference import label-studio --print-config"]
    parser = build_parser()
    assert [_parse_error(parser, line) is None for line in lines] == [False, False, True, True, True]


# ------------------------------------------------------------------------------------------------
# example scenes


def _json_blocks(path: Path) -> list:
    return [json.loads(b) for b in re.findall(r"```json\n(.*?)```", path.read_text(), re.S)]


def _parse(d):
    from creference_bayes.io.scene import parse_scene

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the documented examples carry no unknown keys
        return parse_scene(d)


@pytest.mark.parametrize("name", ["scene_format.md", "user_guide.md"])
def test_documented_scenes_are_valid(name):
    scenes = [b for b in _json_blocks(ROOT / "docs" / name) if isinstance(b, dict) and "format" in b]
    assert scenes, f"docs/{name} shows no example scene"
    for d in scenes:
        scene = _parse(d)
        assert scene.targets


def test_the_ten_documented_reference_formats_are_valid_and_distinct():
    blocks = _json_blocks(ROOT / "docs" / "scene_format.md") + _json_blocks(ROOT / "docs" / "reference_formats.md")
    full = next(b for b in blocks if isinstance(b, dict) and "format" in b)
    refs = [b for b in blocks if isinstance(b, dict) and "measure" in b and "format" not in b]
    kinds = {(r["measure"], r["mode"], "range" in r) for r in refs}
    assert len(refs) == len(kinds) >= 10
    for ref in refs:
        scene = _parse({**full, "references": [ref]})
        assert len(scene.references) == 1


# ------------------------------------------------------------------------------------------------
# the result format: every key a real result writes is named in docs/result_format.md

#: Blocks whose keys are names of the user's or the scene's own (parameters, targets, classes,
#: sampler options, skip reasons): their children are not documented one by one.
DYNAMIC = {"ess_bulk", "r_hat", "autocorr_time", "options", "sampling", "classes", "skipped_reasons"}


def _keys(x) -> set[str]:
    out: set[str] = set()
    if isinstance(x, dict):
        for k, v in x.items():
            out.add(k)
            if k not in DYNAMIC:
                out |= _keys(v)
    elif isinstance(x, list):
        for v in x:
            out |= _keys(v)
    return out


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Real results with every optional block: the demo's (posterior, evaluation, NetCDF), a street
    scene of two targets under class priors and a free camera (block sampler), and the paper
    model's (pairwise bounds)."""
    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.cli.main import main

    folder = tmp_path_factory.mktemp("result")
    assert main(["demo", "--out", str(folder / "demo.json"), "--netcdf", str(folder / "post.nc"), "--quiet",
                 "--min-ess", "100"]) == 0
    assert main(["demo", "--out", str(folder / "paper.json"), "--model", "paper", "--no-posterior", "--quiet"]) == 0
    street = simulate_scene(5, setting="street", tier="low", n_objects=2, sizes="prior", horizon="none")
    (folder / "street.json").write_text(json.dumps(street))
    assert main(["estimate", str(folder / "street.json"), "--out", str(folder / "street_result.json"), "--quiet",
                 "--min-ess", "50"]) == 0
    return [json.loads((folder / f).read_text()) for f in ("demo.json", "street_result.json", "paper.json")]


def test_every_key_of_a_result_is_documented(results):
    doc = (ROOT / "docs" / "result_format.md").read_text()
    documented = set(re.findall(r"`([A-Za-z_0-9.]+)`", doc))
    keys = set().union(*(_keys(r) for r in results)) | {"horizon_estimate"}  # with a horizon from the photo
    assert {"posterior", "evaluation", "draws", "diagnostics", "ground_m", "pairs_used"} <= keys  # all blocks seen
    missing = sorted(k for k in keys if k not in documented)
    assert not missing, f"keys of creference-result/2 missing from docs/result_format.md: {missing}"


def test_the_key_collector_skips_only_named_blocks():
    assert _keys({"a": {"b": 1, "ess_bulk": {"t0.x": 1}}, "c": [{"d": 2}]}) == {"a", "b", "ess_bulk", "c", "d"}


def test_every_key_of_an_advice_file_is_documented(tmp_path):
    """docs/advice.md names every key of the creference-advice/2 file `creference advise --out`
    writes (on the demo's result: posterior draws, one target)."""
    from creference_bayes.cli.main import main

    assert main(["demo", "--out", str(tmp_path / "result.json"), "--quiet", "--min-ess", "100"]) == 0
    assert main(["advise", str(tmp_path / "result.json"), "--out", str(tmp_path / "advice.json"), "--quiet",
                 "--draws", "100", "--futures", "20"]) == 0
    advice = json.loads((tmp_path / "advice.json").read_text())
    assert advice["format"] == "creference-advice/2" and advice["predictions"]
    doc = (ROOT / "docs" / "advice.md").read_text()
    documented = set(re.findall(r"`([A-Za-z_0-9.]+)`", doc))
    missing = sorted(k for k in _keys(advice) if k not in documented)
    assert not missing, f"keys of creference-advice/2 missing from docs/advice.md: {missing}"


def test_the_task_fields_import_md_documents_are_the_ones_the_importer_reads():
    """Every `data` field of docs/import.md's task table and example tasks is one the Label Studio
    importer reads, and every field it reads is in the table."""
    from creference_bayes.io.labelstudio import DATA_FIELDS

    text = (ROOT / "docs" / "import.md").read_text()
    table = text.split("A task's `data`:", 1)[1].split("\n\n", 2)[1]
    documented = {f for row in table.splitlines()[2:] for f in re.findall(r"`([a-z_0-9]+)`", row.split("|")[1])}
    assert documented == set(DATA_FIELDS) - {"creference_scene"}  # a request task's field: advice.md
    tasks = [t for b in _json_blocks(ROOT / "docs" / "import.md") if isinstance(b, list)
             for t in b if isinstance(t, dict) and "image" in t]
    assert tasks and all(set(t) <= set(DATA_FIELDS) for t in tasks)
    assert all(set(x) <= {"id", "class", "dimensions_m", "ground_truth"} for t in tasks for x in t.get("targets", []))


def test_figure_script_draws_the_handedness_figure(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "docs" / "figures" / "make_figures.py"),
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "handedness.png").stat().st_size > 10_000


# ------------------------------------------------------------------------------------------------
# docs/labels.md: every Python snippet runs as printed, on the sidecars `creference labels` writes


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    """A folder as docs/labels.md has it: `labels/` from `creference labels` on a batch of two
    simulated scenes without images: scene_0000, one target of known size; scene_0001, three
    street targets whose sizes are left to their classes' priors."""
    from creference_bayes.bench.simulate import write_scenes
    from creference_bayes.cli.main import main
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    root = tmp_path_factory.mktemp("labels_doc")
    write_scenes(root / "one", 1, seed=2, tier="low")
    write_scenes(root / "street", 1, seed=4, tier="low", setting="street", n_objects=3, sizes="prior")
    (root / "scenes").mkdir()
    (root / "one" / "scene_0000.json").rename(root / "scenes" / "scene_0000.json")
    (root / "street" / "scene_0000.json").rename(root / "scenes" / "scene_0001.json")
    settings = BatchSettings(seed=3, sampling={"n_walkers": 24, "min_ess": 100,
                                               "n_chains": 4, "warmup": 100, "max_steps": 400})
    report = run_batch([root / "scenes"], root / "batch", LocalEngine(1), settings)
    assert report.ok, report.errors
    assert main(["labels", str(root / "batch"), "--out", str(root / "labels"), "--quiet"]) == 0
    return root


def test_every_python_snippet_of_labels_md_runs_on_the_sidecars_labels_writes(labelled, monkeypatch):
    """The bird's-eye snippet runs as printed on a one-target sidecar (known size: draws without
    sizes) and, with the file name changed, on a sidecar of three targets under class priors (draws
    with their own sizes), and its `spatial` is what it says: the share of the drawn footprints
    (shapely, KITTI's box convention) holding each point."""
    import numpy as np
    import shapely

    from creference_bayes.evaluation.iou3d import footprints

    blocks = _python_blocks(ROOT / "docs" / "labels.md")
    assert blocks
    monkeypatch.chdir(labelled)
    seen = []
    for code in blocks:
        source = code.split('open("', 1)[1].split('"', 1)[0]
        assert source == "labels/uncertainty/scene_0000.json"
        for name in ("scene_0000", "scene_0001"):
            ns: dict = {}
            exec(compile(code.replace("scene_0000", name), "docs/labels.md", "exec"), ns)
            d, spatial, X, Z = ns["d"], ns["spatial"], ns["X"], ns["Z"]
            seen.append((name, "length" in d))
            n = d["n"]
            length, width = np.asarray(ns["lengths"], float), np.asarray(ns["widths"], float)
            boxes = np.column_stack([d["x"], np.zeros(n), d["z"], d["rotation_y"], length, width, np.ones(n)])
            polygons = shapely.polygons(footprints(boxes))
            assert spatial.shape == X.shape and 0 <= spatial.min() and spatial.max() <= 1 and spatial.max() > 0
            rng = np.random.default_rng(0)
            partial = np.flatnonzero((spatial.ravel() > 0) & (spatial.ravel() < 1))
            cells = np.concatenate([rng.choice(partial, min(60, len(partial)), replace=False),
                                    rng.choice(spatial.size, 40, replace=False)])
            for c in cells:
                share = shapely.covers(polygons, shapely.points(X.ravel()[c], Z.ravel()[c])).mean()
                assert abs(share - spatial.ravel()[c]) <= 1.0 / n + 1e-9
    assert ("scene_0000", False) in seen and ("scene_0001", True) in seen  # both kinds of draws


def test_the_sidecar_is_the_one_layout_labels_md_describes(labelled):
    """docs/labels.md's table of the sidecar names every key of a real sidecar and its objects."""
    doc = (ROOT / "docs" / "labels.md").read_text()
    documented = set(re.findall(r"`([A-Za-z_0-9.]+)`", doc))
    for name in ("scene_0000", "scene_0001"):
        side = json.loads((labelled / "labels" / "uncertainty" / f"{name}.json").read_text())
        assert side["format"] == "creference-kitti-uncertainty/2"
        keys = set(side) | set(side["camera"]) | {k for o in side["objects"] for k in o}
        missing = sorted(k for k in keys if k not in documented)
        assert not missing, f"{name}: sidecar keys missing from docs/labels.md: {missing}"


# ------------------------------------------------------------------------------------------------
# docs/commands.md: every command and every option of the real parsers, as make_commands.py writes it


def test_commands_md_lists_every_command_and_option():
    """docs/commands.md has a section per command and names every one of its options; rerun
    `python docs/figures/make_commands.py` when a parser changes."""
    import argparse
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_commands", ROOT / "docs" / "figures" / "make_commands.py")
    make = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make)
    doc = (ROOT / "docs" / "commands.md").read_text()
    sections = dict(re.findall(r"^## ([^\n]+)\n(.*?)(?=^## |\Z)", doc, re.M | re.S))
    missing = []
    for name, parser in make.commands(make.build_parser()):
        if name not in sections:
            missing.append(name)
            continue
        for action in parser._actions:
            if action.option_strings and action.help != argparse.SUPPRESS and "--help" not in action.option_strings:
                if f"`{max(action.option_strings, key=len)}" not in sections[name]:
                    missing.append(f"{name} {max(action.option_strings, key=len)}")
    assert not missing, f"docs/commands.md misses {missing}: run python docs/figures/make_commands.py"
