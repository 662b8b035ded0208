"""Progress bars: on standard error when asked, never changing a result, plain text everywhere."""

import subprocess
import sys

import numpy as np

from creference_bayes.cli.main import example_scene_path
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.io.scene import load_scene
from creference_bayes.camera_setup import setup_camera
from creference_bayes.pipeline import build_models


class _Recorder:
    """Stands in for a tqdm bar: records its total and every update."""

    def __init__(self, enabled, total=None, **kwargs):
        self.enabled, self.total, self.n, self.closed = enabled, total, 0, False
        _Recorder.last = self

    def update(self, n=1):
        self.n += n
        return True  # as tqdm does when it redraws: a callback must not pass this on

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def external_write_mode(self, file=None):
        import contextlib

        return contextlib.nullcontext()


def test_paper_restarts_bar_shows_on_stderr_and_changes_nothing(capsys, monkeypatch):
    import creference_bayes.inference.progress as progress

    scene = load_scene(example_scene_path())
    models = build_models(scene, setup_camera(scene), model="paper", preset="paper")
    quiet = optimize_map(models, preset="paper", rng=4, restarts=6)
    assert capsys.readouterr().err == ""
    shown = optimize_map(models, preset="paper", rng=4, restarts=6, progress_bar=True)
    assert "paper restarts" in capsys.readouterr().err
    np.testing.assert_array_equal(quiet.params, shown.params)
    assert quiet.n_evaluations == shown.n_evaluations

    monkeypatch.setattr(progress, "progress_bar", _Recorder)
    counted = optimize_map(models, preset="paper", rng=4, restarts=6, progress_bar=True)
    bar = _Recorder.last
    assert bar.total == 6 and bar.n == 6 and bar.closed  # every restart counted, none cut short
    assert counted.info == quiet.info


def test_bench_scenes_bar_and_lines(monkeypatch):
    import creference_bayes.inference.progress as progress
    from creference_bayes.bench.runner import BenchConfig, run_bench

    tiny = BenchConfig(name="tiny", scenes=(("none", "indoor", 1),), ref_counts=(0,),
                       posterior_ref_counts=(), paper_restarts=2, pair_scenes=0)
    lines = []
    monkeypatch.setattr(progress, "progress_bar", _Recorder)
    run_bench(tiny, seed=0, progress=lines.append, progress_bar=True)
    assert (_Recorder.last.enabled, _Recorder.last.total, _Recorder.last.n) == (True, 1, 1)
    assert _Recorder.last.closed
    assert [line.split(":")[0] for line in lines] == ["none-indoor-00"]


def test_progress_bars_never_load_the_notebook_flavour_of_tqdm():
    """tqdm.auto in a Jupyter kernel without ipywidgets warns (TqdmWarning) on import."""
    code = ("import sys\n"
            "from creference_bayes.inference import sampling\n"
            "from creference_bayes.inference.progress import progress_bar\n"
            "with sampling._progress_bar(True, 2) as bar:\n"
            "    bar.update(2)\n"
            "progress_bar(True, 1, desc='restarts').close()\n"
            "print(sorted(m for m in sys.modules if m in ('tqdm.auto', 'tqdm.autonotebook', 'tqdm.notebook')))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
    assert "sampling" in proc.stderr  # the bars were drawn, on standard error
