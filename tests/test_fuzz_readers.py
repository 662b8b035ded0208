"""Every reader of outside data, fuzzed (issue 61): the scene JSON, Label Studio exports (one target a
task, and frames of several) and its --users file, CVAT exports (XML and ZIP), the --targets CSV, the
--classes file, requests.csv answers (advise --apply), imported scenes merged (advise --merge) and
result files given to plot, advise and labels. Each starts from a valid seed, is mutated
(fuzz_strategies: structure-aware with hostile values, and byte by byte) and is read the way the
command line reads it. Whatever the input:

* the reader succeeds or refuses with the package's own input error (SceneError, ConversionError, the
  command line's UsageError); the command line exits 0 or 2 with no traceback;
* nothing is written outside the command's --out (the input files unchanged, byte for byte and mode
  for mode; advise --apply and --merge write the batch's own scene files, and only those).

The default run takes N_EXAMPLES (80) examples a reader through its library function, derandomized,
and fewer through the whole command; the slow-marked ``*_long`` tests take N_LONG (>= 1000) a reader,
random (``pytest -m slow tests/test_fuzz_readers.py``). No posterior is sampled in a loop: results are
made once, by a fixture."""

import contextlib
import csv
import hashlib
import io
import json
import os
import shutil
import stat
import tempfile
import zipfile
from pathlib import Path
from unittest import mock

import pytest
from conftest import truth_scene
from hypothesis import given
from hypothesis import strategies as st

from fuzz_strategies import (HOSTILE_TEXTS, N_EXAMPLES, N_LONG, damaged, fuzz_settings, hostile_json, mutated_csv,
                             mutated_xml)
from test_import_fuzz import CVAT_SCENES, CVAT_XML, LS_EXPORT, LS_SCENES
from test_import_labelstudio import KAYAK
from test_labels import ThreadEngine

from creference_bayes.cli.estimate import load_classes
from creference_bayes.cli.imports import _read_cvat
from creference_bayes.cli.main import UsageError, example_scene_path, main
from creference_bayes.io.annotation_tools import ConversionError, load_target_table, write_scenes
from creference_bayes.io.cvat import scenes_from_cvat
from creference_bayes.io.labelstudio import read_export, read_users, scenes_from_label_studio
from creference_bayes.io.scene import SceneError, load_scene
from creference_bayes.pipeline import build_model
from creference_bayes.workflows.advice.batch import REQUEST_COLUMNS
from creference_bayes.workflows.batch import BatchSettings, run_batch

#: Examples a reader through the whole command line in the default run (each builds the parser and
#: more); the long fuzz takes N_LONG through it too.
N_CLI = max(1, N_EXAMPLES // 3)
#: Examples through the commands that rebuild a model from a result (plot, advise, labels: 0.1-0.3 s each).
N_HEAVY = max(1, N_EXAMPLES // 8)
#: Examples whose scene is estimated (the MAP: about 2 s each) in the default and the long run.
N_MAP, N_MAP_LONG = 3, 30

EXAMPLE = json.loads(example_scene_path().read_text())
MULTI, _ = truth_scene(7, m=3, noise_px=1.0, n_annotations=2, n_refs=2, horizon="sd", sizes_known=False)
MULTI["camera"]["id"] = "rig/front"
USERS = [{"id": 1, "username": "ann", "email": "ann@example.com"}, {"id": 2, "email": "bo@example.com"},
         {"id": 3, "username": "", "first_name": "Cy"}]
TARGETS_CSV = ("target_id,length_m,width_m,height_m,focal_length_px,image\n"
               "cupboard,1.2,0.5,2.0,,\n"
               "table,1.6,0.8,0.75,1800,street.png\n"
               ",,,,1500,ab12cd34-room.jpg\n"
               "bench,1.5,0.6,0.8,,\n"
               "t0,4.2,1.7,1.5,,\n")
CLASSES = {"Kayak": KAYAK, "Car": {"length_m": 4.2, "width_m": 1.8, "height_m": 1.5, "log_sd": 0.1},
           "Crate": {"length_m": 0.6, "width_m": 0.4, "height_m": 0.4}}


# ----------------------------------------------------------------------------------------------
# The sandbox: inputs written into a fresh folder, every file of the fixture's tree checked after


def _tree(root: Path) -> dict:
    """Every path under ``root``: (kind, mode, sha256 of the content)."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st_ = os.lstat(p)
            digest = hashlib.sha256(p.read_bytes()).hexdigest() if stat.S_ISREG(st_.st_mode) else None
            out[p] = (stat.S_IFMT(st_.st_mode), stat.S_IMODE(st_.st_mode), digest)
    return out


class Sandbox:
    """The session's fixture folder: seeds, results, a batch. ``example()`` gives a fresh folder
    ``in`` (for the inputs) and the ``out`` path beside it; ``check`` asserts that only ``out`` (and
    the ``writable`` files) changed, then restores the writable files and removes the example."""

    def __init__(self, root: Path):
        self.root = root
        self.cwd = os.getcwd()
        self._restore: dict[Path, bytes] = {}

    def writable(self, paths):
        """Files a command may rewrite (advise --apply, --merge: the batch's scene files), restored after."""
        for p in paths:
            self._restore[Path(p)] = Path(p).read_bytes()

    @contextlib.contextmanager
    def example(self):
        """A fresh example folder; the temporary folder (tempfile's, TMPDIR) moved into the fixture's
        tree meanwhile, so that a temporary file left behind is a write outside --out."""
        work = Path(tempfile.mkdtemp(dir=self.root / "work"))
        (work / "in").mkdir()
        (self.root / "tmp").mkdir(exist_ok=True)
        self._work = work
        try:
            with mock.patch.object(tempfile, "tempdir", str(self.root / "tmp")), \
                    mock.patch.dict(os.environ, {"TMPDIR": str(self.root / "tmp")}):
                yield work / "in", work / "out"
        finally:
            shutil.rmtree(work, ignore_errors=True)
            for p, data in self._restore.items():
                if not p.exists() or p.read_bytes() != data:
                    p.write_bytes(data)

    def snapshot(self):
        self._before = (_tree(self.root), sorted(os.listdir(self.cwd)))

    def check(self, allowed=()):
        """Nothing changed but ``out`` and the ``allowed`` files (the writable ones); multiprocessing's
        own folder (tmp/pymp-*, removed when the process ends) aside."""
        tree, cwd = _tree(self.root), sorted(os.listdir(self.cwd))
        out, allowed = self._work / "out", set(map(Path, allowed))
        changed = {p for p in set(tree) | set(self._before[0]) if tree.get(p) != self._before[0].get(p)}
        outside = sorted(str(p) for p in changed if p != out and out not in p.parents and p not in allowed
                         and not (p.is_relative_to(self.root / "tmp")
                                  and p.relative_to(self.root / "tmp").parts[0].startswith("pymp-")))
        assert not outside, f"written outside --out: {outside[:5]}"
        assert cwd == self._before[1], f"the current folder changed: {set(cwd) ^ set(self._before[1])}"


def _write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def _refused(call, *errors):
    """``call()``: its value, or None when it refused with one of the package's ``errors``. Any
    other exception is the finding: it goes up to hypothesis, which shrinks it."""
    try:
        return call()
    except errors:
        return None


def _cli(argv, statuses=(0, 2)) -> int:
    """``creference ARGV`` in this process: an exit status in ``statuses``, nothing on standard error
    that looks like a traceback; the exception, when one escapes, goes up to hypothesis."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            status = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse (a usage error of the command line itself)
            status = exc.code
    text = err.getvalue()
    assert "Traceback" not in text, text[-3000:]
    assert status in statuses, (status, text[-2000:])
    if status == 2:
        assert "error:" in text, text[-2000:]
    return status


# ----------------------------------------------------------------------------------------------
# Seeds made once: results (MAP only, and a short posterior), a batch with its requests.csv


class Seeds:
    """The fuzz's fixture folder and the seeds made once, each when first asked for (a test of the
    scene reader makes no batch)."""

    def __init__(self, root: Path):
        self.root = root
        (root / "work").mkdir()
        self.box = Sandbox(root)
        self.scene = root / "made" / "example_scene.json"
        self.scene.parent.mkdir()
        shutil.copy(example_scene_path(), self.scene)
        self._cache = {}

    def __getitem__(self, name):
        if name in ("scene", "box", "root"):
            return getattr(self, name)
        if name not in self._cache:
            self._cache.update(self._results() if name in ("map", "post") else self._batch())
        return self._cache[name]

    def _results(self):
        """A result of the example scene: the MAP only, and a short posterior."""
        made, quiet = self.scene.parent, ["--quiet", "--seed", "1"]
        assert main(["estimate", str(self.scene), "--no-posterior", "--out", str(made / "map.json")] + quiet) == 0
        assert main(["estimate", str(self.scene), "--min-ess", "30", "--max-steps", "200",
                     "--out", str(made / "post.json")] + quiet) == 0
        return {k: json.loads((made / f"{k}.json").read_text()) for k in ("map", "post")}

    def _batch(self):
        """A batch of two frames of one camera (a short posterior each), advised once; its requests.csv
        with every row answered, and rows of each answer kind added."""
        root = self.root
        sources = root / "sources"
        sources.mkdir()
        for i in range(2):
            s, _ = truth_scene(20 + i, m=2, noise_px=1.0, n_annotations=2, sizes_known=False, focal_known=True)
            s["camera"]["id"] = "rig-A"
            s["targets"][0]["class"] = "Car"
            (sources / f"f{i}.json").write_text(json.dumps(s))
        batch = root / "batch"
        report = run_batch([sources], batch, ThreadEngine(),
                           BatchSettings(seed=0, sampling={"min_ess": 30, "max_steps": 200, "warmup": 100}))
        assert report.ok, report.errors
        assert main(["advise", str(batch), "--draws", "50", "--futures", "10", "--min-good-per-hour", "0", "--workers", "1",
                     "--quiet"]) == 0
        rows = list(csv.DictReader((batch / "advice" / "requests.csv").read_text().splitlines()))
        answers = {"size": "4.1,1.7,1.5", "mounting": "1.6,6,1", "reference": "12.5"}
        for r in rows:
            r["answer"] = answers.get(r["kind"], "done") if not r.get("line_px") else "seen"
        keys = sorted(p.stem for p in (batch / "results").glob("*.json"))
        targets = [t["id"] for t in json.loads((sources / "f0.json").read_text())["targets"]]
        extra = [{"rank": "90", "key": keys[0], "target": targets[0], "kind": "size", "answer": "4.2,1.8,1.5"},
                 {"rank": "91", "key": keys[0], "target": "", "camera": "rig-A", "kind": "mounting",
                  "answer": "1.5,5,0"},
                 {"rank": "92", "key": keys[1], "target": targets[1], "kind": "reference", "measure": "length",
                  "answer": "4.0"},
                 {"rank": "93", "key": keys[1], "target": targets[0], "kind": "reference", "measure": "distance",
                  "object": targets[1], "answer": "6"}]
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=REQUEST_COLUMNS, lineterminator="\n", restval="")
        w.writeheader()
        w.writerows([{k: r.get(k, "") for k in REQUEST_COLUMNS} for r in rows] + extra)
        self.box.writable(sorted(sources.glob("*.json")))
        return {"batch": batch, "keys": keys, "requests": buf.getvalue(), "sources": sorted(sources.glob("*.json")),
                "batch_results": {k: json.loads((batch / "results" / f"{k}.json").read_text()) for k in keys}}


@pytest.fixture(scope="module")
def ctx(tmp_path_factory):
    return Seeds(tmp_path_factory.mktemp("fuzz"))


def fuzz(body, n=N_EXAMPLES, n_long=N_LONG):
    """The default test (``n`` examples, derandomized) and its slow-marked long fuzz (``n_long``) of
    ``body(data, ctx)``."""
    def make(count, slow):
        @fuzz_settings(count)
        @given(data=st.data())
        def test(data, ctx):
            body(data, ctx)
        test.__doc__ = body.__doc__
        return pytest.mark.slow(test) if slow else test
    return make(n, False), make(n_long, True)


# ----------------------------------------------------------------------------------------------
# Scene files: load_scene (estimate, batch, advise), then the model built as estimate builds it


def _scene_bytes(data):
    seed = data.draw(st.sampled_from([EXAMPLE, MULTI]), label="seed")
    return hostile_json(seed, data)


def _scene_file(data, ctx):
    """A mutated scene file is read and its model built, or refused with SceneError."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "scene.json", _scene_bytes(data))
        box.snapshot()
        scene = _refused(lambda: load_scene(path), SceneError)
        if scene is not None:
            _refused(lambda: build_model(scene), SceneError)
        box.check()


def _scene_cli(data, ctx):
    """creference estimate on a mutated scene file, stopped before the MAP (--no-posterior with
    --netcdf is refused once the scene is read): exit 2, no traceback, nothing written."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "scene.json", _scene_bytes(data))
        box.snapshot()
        _cli(["estimate", path, "--no-posterior", "--netcdf", out / "post.nc", "--quiet"], statuses=(2,))
        box.check()


def _scene_map(data, ctx):
    """creference estimate --no-posterior --out on a mutated scene file: the MAP, a result, or exit 2."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "scene.json", _scene_bytes(data))
        box.snapshot()
        _cli(["estimate", path, "--no-posterior", "--quiet", "--out", out / "result.json"])
        box.check()


test_scene_files, test_scene_files_long = fuzz(_scene_file)
test_scene_files_cli, test_scene_files_cli_long = fuzz(_scene_cli, N_CLI)
test_scene_files_estimated, test_scene_files_estimated_long = fuzz(_scene_map, N_MAP, N_MAP_LONG)


# ----------------------------------------------------------------------------------------------
# Label Studio exports (one target a task, and frames of several) and --users


def _ls_bytes(data):
    return hostile_json(data.draw(st.sampled_from([LS_EXPORT, LS_SCENES]), label="seed"), data)


def _label_studio(data, ctx):
    """A mutated Label Studio export: read_export, scenes_from_label_studio and write_scenes as
    `creference import label-studio` calls them, or ConversionError."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "export.json", _ls_bytes(data))
        box.snapshot()
        report = _refused(lambda: scenes_from_label_studio(read_export(path), out_dir=out), ConversionError)
        if report is not None:
            write_scenes(report.scenes, out)
        box.check()


def _label_studio_cli(data, ctx):
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "export.json", _ls_bytes(data))
        box.snapshot()
        _cli(["import", "label-studio", path, "--out", out, "--quiet"])
        box.check()


def _users(data, ctx):
    """A mutated --users file (GET /api/users) is read, or ConversionError; then used by an import."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "users.json", hostile_json(USERS, data))
        box.snapshot()
        users = _refused(lambda: read_users(path), ConversionError)
        if users is not None:
            report = _refused(lambda: scenes_from_label_studio(LS_EXPORT, out_dir=out, users=users), ConversionError)
            if report is not None:
                write_scenes(report.scenes, out)
        box.check()


test_label_studio_exports, test_label_studio_exports_long = fuzz(_label_studio)
test_label_studio_exports_cli, test_label_studio_exports_cli_long = fuzz(_label_studio_cli, N_CLI)
test_label_studio_users, test_label_studio_users_long = fuzz(_users)


# ----------------------------------------------------------------------------------------------
# CVAT exports: annotations.xml (one target an image, and frames of several), and the ZIP holding it


def _cvat_bytes(data):
    xml = mutated_xml(data.draw(st.sampled_from([CVAT_XML, CVAT_SCENES]), label="seed"), data, HOSTILE_TEXTS)
    xml = damaged(xml, data)
    if data.draw(st.integers(0, 4), label="zip?") == 0:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            z.writestr(data.draw(st.sampled_from(["annotations.xml", "task/annotations.xml", "other.xml"]),
                                 label="member"), xml)
        return "export.zip", damaged(buf.getvalue(), data)
    return "annotations.xml", xml


def _cvat(data, ctx):
    """A mutated CVAT export: read (XML or ZIP), converted (with --classes: the several-target seed has a
    class of its own) and written as `creference import cvat` does, or ConversionError."""
    box = ctx["box"]
    with box.example() as (inp, out):
        name, raw = _cvat_bytes(data)
        path = _write(inp / name, raw)
        box.snapshot()
        classes = load_classes(_write(inp / "classes.json", json.dumps(CLASSES).encode()))
        report = _refused(lambda: scenes_from_cvat(_read_cvat(str(path)), out_dir=out, classes=classes),
                          ConversionError)
        if report is not None:
            write_scenes(report.scenes, out)
        box.check(allowed=[inp / "classes.json"])


def _cvat_cli(data, ctx):
    box = ctx["box"]
    with box.example() as (inp, out):
        name, raw = _cvat_bytes(data)
        path = _write(inp / name, raw)
        classes = _write(inp / "classes.json", json.dumps(CLASSES).encode())
        box.snapshot()
        _cli(["import", "cvat", path, "--out", out, "--classes", classes, "--quiet"])
        box.check()


test_cvat_exports, test_cvat_exports_long = fuzz(_cvat)
test_cvat_exports_cli, test_cvat_exports_cli_long = fuzz(_cvat_cli, N_CLI)


# ----------------------------------------------------------------------------------------------
# --targets CSV and --classes JSON (import; --classes also estimate, batch)


def _targets(data, ctx):
    """A mutated --targets table: load_target_table, then used by both importers, or ConversionError."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "targets.csv", mutated_csv(TARGETS_CSV, data))
        box.snapshot()
        table = _refused(lambda: load_target_table(path), ConversionError)
        if table is not None:
            for run in (lambda: scenes_from_label_studio(LS_SCENES, out_dir=out, targets=table),
                        lambda: scenes_from_cvat(_read_cvat(str(_cvat_seed(inp))), out_dir=out, targets=table)):
                report = _refused(run, ConversionError)
                if report is not None:
                    write_scenes(report.scenes, out)
        box.check(allowed=[inp / "annotations.xml"])


def _cvat_seed(inp):
    return _write(inp / "annotations.xml", CVAT_XML)


def _targets_cli(data, ctx):
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "targets.csv", mutated_csv(TARGETS_CSV, data))
        export = _write(inp / "export.json", json.dumps(LS_SCENES).encode())
        box.snapshot()
        _cli(["import", "label-studio", export, "--targets", path, "--out", out, "--quiet"])
        box.check()


def _classes(data, ctx):
    """A mutated --classes file: load_classes as estimate, batch and import read it (UsageError, or
    SceneError naming the file when it is no JSON to read: both exit status 2), then a scene read and a CVAT export converted with it."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "classes.json", hostile_json(CLASSES, data))
        box.snapshot()
        classes = _refused(lambda: load_classes(str(path)), UsageError, SceneError)
        if classes is not None:
            scene = _refused(lambda: load_scene(ctx["scene"], classes=classes), SceneError)
            if scene is not None:
                _refused(lambda: build_model(scene, classes=classes), SceneError)
            report = _refused(lambda: scenes_from_cvat(_read_cvat_bytes(CVAT_SCENES), out_dir=out, classes=classes),
                              ConversionError)
            if report is not None:
                write_scenes(report.scenes, out)
        box.check()


def _read_cvat_bytes(raw):
    from creference_bayes.io.cvat import read_cvat_xml
    return read_cvat_xml(raw)


def _classes_cli(data, ctx):
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "classes.json", hostile_json(CLASSES, data))
        export = _write(inp / "annotations.xml", CVAT_SCENES)
        box.snapshot()
        _cli(["import", "cvat", export, "--classes", path, "--out", out, "--quiet"])
        box.check()


test_targets_csv, test_targets_csv_long = fuzz(_targets)
test_targets_csv_cli, test_targets_csv_cli_long = fuzz(_targets_cli, N_CLI)
test_classes_files, test_classes_files_long = fuzz(_classes)
test_classes_files_cli, test_classes_files_cli_long = fuzz(_classes_cli, N_CLI)


# ----------------------------------------------------------------------------------------------
# requests.csv answers (advise BATCH --apply) and imported scenes (advise BATCH --merge): they write
# the batch's own scene files, and nothing else


def _apply(data, ctx):
    """creference advise BATCH --apply on a mutated requests.csv: exit 0 or 2, no traceback, only the
    batch's scene files rewritten."""
    box = ctx["box"]
    with box.example() as (inp, out):
        path = _write(inp / "requests.csv", mutated_csv(ctx["requests"], data))
        box.snapshot()
        _cli(["advise", ctx["batch"], "--apply", path, "--quiet"])
        box.check(allowed=ctx["sources"])


def _merge(data, ctx):
    """creference advise BATCH --merge on a folder of mutated imported scenes: exit 0 or 2, no traceback,
    only the batch's scene files rewritten."""
    box = ctx["box"]
    with box.example() as (inp, out):
        for i, key in enumerate(data.draw(st.lists(st.sampled_from(ctx["keys"]), min_size=1, max_size=2,
                                                   unique=True), label="frames")):
            seed = json.loads(ctx["sources"][ctx["keys"].index(key)].read_text())
            _write(inp / "imported" / f"{key}.json", hostile_json(seed, data))
        box.snapshot()
        _cli(["advise", ctx["batch"], "--merge", inp / "imported", "--quiet"])
        box.check(allowed=ctx["sources"])


test_requests_csv_answers, test_requests_csv_answers_long = fuzz(_apply, N_CLI)
test_merged_scenes, test_merged_scenes_long = fuzz(_merge, N_CLI)


# ----------------------------------------------------------------------------------------------
# Result files given to plot, advise and labels


def _result_bytes(data, ctx, seeds=("map", "post", "batch")):
    which = data.draw(st.sampled_from(seeds), label="seed")
    seed = ctx["batch_results"][ctx["keys"][0]] if which == "batch" else ctx[which]
    return which, hostile_json(seed, data)


def _no_figures(*args, **kwargs):
    return {}


def _plot(data, ctx):
    """creference plot on a mutated result (the figures themselves not drawn: the result read, its
    scene found, the model rebuilt, the draws or the Laplace approximation made): exit 0 or 2."""
    box = ctx["box"]
    with box.example() as (inp, out):
        which, raw = _result_bytes(data, ctx)
        path = _write(inp / "result.json", raw)
        scene = ctx["batch"] / "scenes" / f"{ctx['keys'][0]}.json" if which == "batch" else ctx["scene"]
        explicit = ["--scene", scene] if data.draw(st.booleans(), label="--scene") else []
        box.snapshot()
        with mock.patch("creference_bayes.vision.plotting.scene_figures", _no_figures):
            _cli(["plot", path, "--out", out, "--quiet"] + explicit)
        box.check()


def _plot_drawn(data, ctx):
    """creference plot on a mutated result, the figures drawn (PNG at 10 dpi)."""
    box = ctx["box"]
    with box.example() as (inp, out):
        which, raw = _result_bytes(data, ctx, ("map", "post"))
        path = _write(inp / "result.json", raw)
        box.snapshot()
        _cli(["plot", path, "--scene", ctx["scene"], "--out", out, "--quiet", "--dpi", "10"])
        box.check()


def _advise_result(data, ctx):
    """creference advise on a mutated result file (cheap settings: 50 draws, 10 futures): exit 0 or 2."""
    box = ctx["box"]
    with box.example() as (inp, out):
        which, raw = _result_bytes(data, ctx)
        path = _write(inp / "result.json", raw)
        scene = ctx["batch"] / "scenes" / f"{ctx['keys'][0]}.json" if which == "batch" else ctx["scene"]
        explicit = ["--scene", scene] if data.draw(st.booleans(), label="--scene") else []
        kinds = data.draw(st.sampled_from(["size", "mounting", "size,mounting", "reference"]), label="--requests")
        box.snapshot()
        _cli(["advise", path, "--draws", "50", "--futures", "10", "--requests", kinds, "--quiet",
              "--out", out / "advice.json"] + explicit)
        box.check()


def _batch_with(data, ctx, inp):
    """A copy of the batch folder, one of its results mutated."""
    batch = inp / "batch"
    shutil.copytree(ctx["batch"], batch, ignore=shutil.ignore_patterns("advice"))
    key = data.draw(st.sampled_from(ctx["keys"]), label="key")
    _write(batch / "results" / f"{key}.json", hostile_json(ctx["batch_results"][key], data))
    return batch


def _labels(data, ctx):
    """creference labels on a batch folder with a mutated result: exit 0 or 2, only --out written."""
    box = ctx["box"]
    with box.example() as (inp, out):
        batch = _batch_with(data, ctx, inp)
        box.snapshot()
        _cli(["labels", batch, "--out", out, "--no-figure", "--quiet", "--draws", "10"])
        box.check()


def _advise_batch(data, ctx):
    """creference advise on a batch folder with a mutated result (cheap settings): exit 0 or 2."""
    box = ctx["box"]
    with box.example() as (inp, out):
        batch = _batch_with(data, ctx, inp)
        box.snapshot()
        _cli(["advise", batch, "--draws", "50", "--futures", "10", "--requests", "size", "--quiet", "--workers", "1",
              "--out", out])
        box.check()


#: A batch.json with what ``creference batch`` learns of frames that share a camera (the shape
#: :meth:`~creference_bayes.workflows.batch.dataset.DataSet.summary` writes), for ``plot BATCH_DIR``.
DATASET_BATCH = {
    "format": "creference-batch/2", "settings": {}, "scenes": [],
    "dataset": {
        "focal_length_px": {"shared_by": "camera", "kind": "shared", "groups": {"rig/front": {
            "median": 1392.4, "log_sd": 0.033, "floor_log_sd": 0.03, "held": True, "frames": 3, "frames_offered": 3,
            "n_eff": 1.8, "top3_share": 1.0, "frames_median": 1402.0, "disagreement": -0.42,
            "warnings": ["the pool rests on few frames"],
            "values": [{"frame": "f0", "value": 2080.0, "low": 1990.0, "high": 2170.0, "used": True},
                       {"frame": "f1", "value": 1420.0, "low": 1300.0, "high": 1550.0, "used": True},
                       {"frame": "f2", "value": 1390.0, "low": 1380.0, "high": 1400.0, "used": False}]}}},
        "pitch_deg": {"shared_by": "camera", "kind": "spread", "groups": {"rig/front": {
            "mean": 5.99, "sd": 0.23, "spread_sd": 0.5, "frames": 3, "frames_offered": 3, "n_eff": 2.5,
            "top3_share": 1.0, "frames_median": 6.1, "disagreement": -0.01, "warnings": [],
            "values": [{"frame": "f0", "value": 5.2, "low": 4.9, "high": 5.5, "used": True},
                       {"frame": "f1", "value": 6.5, "low": None, "high": None, "used": True}]}}},
        "ref_dof": {"shared_by": "crowd", "kind": "choice", "groups": {"crowd": {"dof": 2.0}}},
        "corner_scale_px": {"shared_by": "crowd", "kind": "residuals", "groups": {"crowd": {
            "sd": 7.6, "dof": 300.0, "frames": 2, "fitted_at_px": 8.9, "log_sd": 0.041, "spread_sd": 6.07,
            "spread_dof": 4.3, "spread_log_sd": 0.383,
            "values": [{"frame": "f0", "value": 4.1, "low": 3.0, "high": 5.6, "used": True},
                       {"frame": "f1", "value": 11.0, "low": 8.1, "high": 15.0, "used": True}]}}}}}


def _plot_dataset(data, ctx):
    """creference plot on a batch folder with a mutated batch.json (the data set's figure, PNG at 10
    dpi): exit 0 or 2, only --out written."""
    box = ctx["box"]
    with box.example() as (inp, out):
        _write(inp / "batch.json", hostile_json(DATASET_BATCH, data))
        box.snapshot()
        _cli(["plot", inp, "--out", out, "--quiet", "--dpi", "10"])
        box.check()


test_results_plot, test_results_plot_long = fuzz(_plot, N_HEAVY)
test_results_plot_drawn, test_results_plot_drawn_long = fuzz(_plot_drawn, 1, 20)
test_dataset_plot, test_dataset_plot_long = fuzz(_plot_dataset, N_HEAVY, 200)
test_results_advise, test_results_advise_long = fuzz(_advise_result, N_HEAVY)
test_results_in_a_batch_labels, test_results_in_a_batch_labels_long = fuzz(_labels, N_HEAVY)
test_results_in_a_batch_advise, test_results_in_a_batch_advise_long = fuzz(_advise_batch, N_HEAVY)
