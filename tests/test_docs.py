"""The user documentation: links resolve inside the repository, examples are valid, every key of
a real result is documented, the figure script runs."""

import json
import re
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


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_inside_the_repository(doc):
    bad = []
    for target in _links(doc):
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.is_relative_to(ROOT):
            bad.append(f"{target}: outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"{target}: no heading #{anchor} in {dest.name}")
    assert not bad, f"{doc.relative_to(ROOT)}: " + "; ".join(bad)


def test_the_link_checker_catches_broken_links(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# Title\n[ok](#title) [gone](missing.md) [anchor](#nope) `[code](x.md)`\n"
                    "```\n[fenced](y.md)\n```\n![img](pic.png) [web](https://example.org)\n")
    (tmp_path / "pic.png").write_bytes(b"")
    assert list(_links(page)) == ["#title", "missing.md", "#nope", "pic.png"]
    assert _anchors(page) == {"title"}


def _json_blocks(path: Path) -> list:
    return [json.loads(b) for b in re.findall(r"```json\n(.*?)```", path.read_text(), re.S)]


def _parse(d):
    from creference_bayes.io.scene import parse_scene

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the documented examples carry no unknown keys
        if d.get("format") == "creference-scene/2":
            from creference_bayes.io.frame_scene import parse_frame

            return parse_frame(d)
        return parse_scene(d)


@pytest.mark.parametrize("name", ["scene_format.md", "user_guide.md"])
def test_documented_scenes_are_valid(name):
    scenes = [b for b in _json_blocks(ROOT / "docs" / name) if "format" in b]
    assert scenes
    for d in scenes:
        _parse(d)


def test_the_ten_documented_reference_formats_are_valid_and_distinct():
    blocks = _json_blocks(ROOT / "docs" / "scene_format.md")
    full = next(b for b in blocks if "format" in b)
    refs = [b for b in blocks if "measure" in b]
    kinds = {(r["measure"], r["mode"], "range" in r) for r in refs}
    assert len(refs) == len(kinds) == 10
    for ref in refs:
        scene = _parse({**full, "references": [ref]})
        assert len(scene.references) == 1


@pytest.fixture(scope="module")
def full_result(tmp_path_factory):
    """A real result with every optional block: posterior, evaluation, NetCDF path."""
    from creference_bayes.cli.main import main

    folder = tmp_path_factory.mktemp("result")
    out = folder / "result.json"
    assert main(["demo", "--out", str(out), "--netcdf", str(folder / "post.nc"), "--quiet",
                 "--min-ess", "200"]) == 0
    return json.loads(out.read_text())


def test_every_key_of_a_result_is_documented(full_result):
    doc = (ROOT / "docs" / "result_format.md").read_text()
    documented = set(re.findall(r"`([a-z_0-9]+)`", doc))
    keys = set(full_result) | {"horizon_estimate"}
    for block in ("map", "scene_id", "posterior", "diagnostics", "references", "evaluation", "timing_s"):
        keys |= set(full_result[block])
    keys |= set(full_result["references"]["pairs"][0]) | {"reason", "x", "z", "focal_length_px",
                                                           "camera_height_m", "pixel_sensitivity"}
    missing = sorted(k for k in keys if k not in documented)
    assert not missing, f"keys of creference-result/1 missing from docs/result_format.md: {missing}"


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
    """A folder as docs/labels.md has it: `labels/` from `creference labels` on a batch of one
    simulated one-target scene (scene_0000) and one simulated frame (frame_0000), no images."""
    import numpy as np

    from creference_bayes.bench.frame_simulate import simulate_frame
    from creference_bayes.bench.runner import write_scenes
    from creference_bayes.cli.main import main
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    root = tmp_path_factory.mktemp("labels_doc")
    write_scenes(root / "scenes", 1, seed=2, tier="low")
    frame = simulate_frame(np.random.default_rng(4), n_objects=2, n_annotations=3)
    (root / "scenes" / "frame_0000.json").write_text(json.dumps(frame))
    settings = BatchSettings(seed=3, sampling={"n_ensembles": 2, "n_walkers": 16, "tau_multiple": 20, "min_ess": 100},
                             frame_sampling={"n_chains": 4, "warmup": 100, "chunk": 100, "max_iterations": 200,
                                             "min_ess": 20})
    report = run_batch([root / "scenes"], root / "batch", LocalEngine(1), settings)
    assert report.ok, report.errors
    assert main(["labels", str(root / "batch"), "--out", str(root / "labels"), "--quiet"]) == 0
    return root


def test_every_python_snippet_of_labels_md_runs_on_the_sidecars_labels_writes(labelled, monkeypatch):
    """The bird's-eye snippets run as printed (one on a one-target sidecar, one on a frame's, whose
    draws are KITTI boxes with rotation_y and estimated sizes), and their `spatial` is what it
    says: the share of the drawn footprints (shapely, KITTI's box convention) holding each point."""
    import numpy as np
    import shapely

    from creference_bayes.evaluation.iou3d import footprints

    blocks = _python_blocks(ROOT / "docs" / "labels.md")
    assert len(blocks) >= 2
    sources = set()
    monkeypatch.chdir(labelled)
    for code in blocks:
        ns: dict = {}
        exec(compile(code, "docs/labels.md", "exec"), ns)
        sources.add(code.split('open("', 1)[1].split('"', 1)[0])
        d, spatial, X, Z = ns["d"], ns["spatial"], ns["X"], ns["Z"]
        n = d["n"]
        yaw = np.asarray(d.get("yaw", d.get("rotation_y")), float)
        if "dim" in ns:
            length, width = np.full(n, ns["dim"]["l"]), np.full(n, ns["dim"]["w"])
        else:
            length, width = np.asarray(ns["lengths"], float), np.asarray(ns["widths"], float)
        boxes = np.column_stack([d["x"], np.zeros(n), d["z"], yaw, length, width, np.ones(n)])
        polygons = shapely.polygons(footprints(boxes))
        assert spatial.shape == X.shape and 0 <= spatial.min() and spatial.max() <= 1 and spatial.max() > 0
        rng = np.random.default_rng(0)
        partial = np.flatnonzero((spatial.ravel() > 0) & (spatial.ravel() < 1))
        cells = np.concatenate([rng.choice(partial, min(60, len(partial)), replace=False),
                                rng.choice(spatial.size, 40, replace=False)])
        for c in cells:
            share = shapely.covers(polygons, shapely.points(X.ravel()[c], Z.ravel()[c])).mean()
            assert abs(share - spatial.ravel()[c]) <= 1.0 / n + 1e-9
    assert sources == {"labels/uncertainty/scene_0000.json", "labels/uncertainty/frame_0000.json"}
    frame = json.loads((labelled / "labels" / "uncertainty" / "frame_0000.json").read_text())
    draws = frame["objects"][0]["draws"]
    assert "dimensions_m" not in frame["objects"][0] and {"rotation_y", "length", "width"} <= set(draws)
