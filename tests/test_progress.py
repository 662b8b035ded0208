"""Progress bars: on standard error when asked, never changing a result, plain text everywhere."""

import subprocess
import sys

import numpy as np
import pytest

from creference_bayes.cli.main import example_scene_path
from creference_bayes.inference.map import optimize
from creference_bayes.io.scene import load_scene
from creference_bayes.pipeline import build_model


class _Recorder:
    """Stands in for a tqdm bar: records its total and every update (``made``: every bar made)."""

    made: list = []

    def __init__(self, enabled, total=None, desc=None, **kwargs):
        self.enabled, self.total, self.n, self.closed, self.desc = enabled, total, 0, False, desc
        _Recorder.last = self
        _Recorder.made.append(self)

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


@pytest.mark.slow  # the paper preset's restarts, twice (about 15 s)
def test_paper_restarts_bar_shows_on_stderr_and_changes_nothing(capsys, monkeypatch):
    import creference_bayes.inference.progress as progress

    scene = load_scene(example_scene_path())
    model = lambda: build_model(scene, model="paper", preset="paper")[0]  # a fresh one: the MAP sets its pilot
    quiet = optimize(model(), preset="paper", rng=4, restarts=6)
    assert capsys.readouterr().err == ""
    shown = optimize(model(), preset="paper", rng=4, restarts=6, progress=True)
    assert "paper restarts" in capsys.readouterr().err
    np.testing.assert_array_equal(quiet.camera, shown.camera)
    np.testing.assert_array_equal(quiet.objects, shown.objects)

    monkeypatch.setattr(progress, "progress_bar", _Recorder)
    counted = optimize(model(), preset="paper", rng=4, restarts=6, progress=True)
    bar = _Recorder.last
    assert bar.total == 6 and bar.n == 6 and bar.closed  # every restart counted, none cut short
    np.testing.assert_array_equal(quiet.camera, counted.camera)


def test_bench_scenes_bar_and_lines(monkeypatch):
    import creference_bayes.inference.progress as progress
    from creference_bayes.bench.runner import BenchConfig, run_bench

    tiny = BenchConfig(name="tiny", scenes=(("none", "indoor", 1),), ref_counts=(0,),
                       posterior_ref_counts=(), paper_restarts=2, pair_scenes=0, camera_studies=False)
    lines = []
    monkeypatch.setattr(progress, "progress_bar", _Recorder)
    monkeypatch.setattr(_Recorder, "made", [])  # the bars of this run only
    run_bench(tiny, seed=0, progress=lines.append, progress_bar=True)
    (bar,) = [b for b in _Recorder.made if b.desc == "bench scenes"]
    assert (bar.enabled, bar.total, bar.n, bar.closed) == (True, 1, 1, True)
    assert not any(b.enabled for b in _Recorder.made if b is not bar)  # one bar: the estimators' are off
    assert [line.split(":")[0] for line in lines] == ["none-indoor-00"]


def test_progress_bars_never_load_the_notebook_flavour_of_tqdm():
    """tqdm.auto in a Jupyter kernel without ipywidgets warns (TqdmWarning) on import."""
    code = ("import sys\n"
            "from creference_bayes.inference import ensemble\n"
            "from creference_bayes.inference.progress import progress_bar\n"
            "with progress_bar(True, 2, desc='sampling', unit='step') as bar:\n"
            "    bar.update(2)\n"
            "progress_bar(True, 1, desc='restarts').close()\n"
            "print(sorted(m for m in sys.modules if m in ('tqdm.auto', 'tqdm.autonotebook', 'tqdm.notebook')))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
    assert "sampling" in proc.stderr  # the bars were drawn, on standard error


def test_progress_mode_is_a_bar_on_a_terminal_and_lines_elsewhere():
    import io

    from creference_bayes.inference.progress import LineBar, progress_bar, progress_mode

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    assert progress_mode(False, Terminal()) is True and progress_mode(False, io.StringIO()) == "lines"
    assert progress_mode(True, Terminal()) is False and progress_mode(True, io.StringIO()) is False
    assert isinstance(progress_bar("lines", 3, desc="advice", unit="scene"), LineBar)


def test_line_bar_prints_a_line_per_update_with_its_note(capsys):
    from creference_bayes.inference.progress import progress_bar

    with progress_bar("lines", 3, desc="advice", unit="scene", initial=1) as bar:
        bar.update(1)
        bar.set_postfix_str("k2 done", refresh=False)
        bar.update(1)
    assert capsys.readouterr().err.splitlines() == ["advice 2/3 scenes (0 s)", "advice 3/3: k2 done (0 s)"]
