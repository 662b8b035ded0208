"""An interrupted batch (Ctrl-C, ``timeout -s INT``): the summary and batch.json are written
whenever the run ends, and no multiprocessing resource leaks (no resource_tracker warning)."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import truth_scene

CLI = [sys.executable, "-m", "creference_bayes"]
ENV = {**os.environ, "PYTHONFAULTHANDLER": "1"}
SMALL = ["--min-ess", "100", "--quiet", "--seed", "3"]


def write_scenes(folder, n):
    """``n`` one-target scenes (1 px noise, 3 annotations) as ``scene_0000.json`` … in ``folder``."""
    folder.mkdir(parents=True)
    for k in range(n):
        (folder / f"scene_{k:04d}.json").write_text(json.dumps(truth_scene(k, noise_px=1.0, n_annotations=3)[0]))


def _default_sigint():
    """Ctrl-C's default action in the child: a test run started in the background by a
    non-interactive shell (``cmd &``) inherits SIGINT ignored, and Python then installs no handler
    (the batch, rightly, ran to the end and the FIFO test hung)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for(predicate, proc, timeout=120.0):
    """Poll ``predicate`` until it returns something other than None or False; return that."""
    end = time.monotonic() + timeout
    while (value := predicate()) is None or value is False:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "timed out"
        time.sleep(0.05)
    return value


def _interrupt(proc) -> str:
    """Ctrl-C as a terminal sends it: SIGINT to the whole process group. A batch still running a
    minute later is aborted, and the test fails with where its threads were (the children run
    with ``PYTHONFAULTHANDLER``, which prints them on SIGABRT)."""
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGABRT)
        _, err = proc.communicate(timeout=30)
        pytest.fail(f"the batch did not end within 60 s of Ctrl-C; where it was:\n{err[-6000:]}")
    return err


def _wait_until_blocked_in_read(proc, timeout=10.0):
    """Wait until the batch sleeps in the pipe's read(), where a signal interrupts it.

    A writer can open the FIFO as soon as the batch waits in open(); a SIGINT that arrives after
    that open() returns but before the read() starts is handled by Python's C-level handler
    between the two calls, and the read() that follows then blocks with the KeyboardInterrupt
    still pending: no Python code runs until data arrives (2 of 12 runs hung so on a 2-core
    machine). Where the kernel does not say (no /proc, or an older kernel whose pipe waits all
    read the same), wait a second instead.
    """
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            if "pipe_read" in open(f"/proc/{proc.pid}/wchan").read():
                return
        except OSError:
            break
        time.sleep(0.02)
    time.sleep(1.0)


def _check_folder(out, n_scenes):
    batch = json.loads((out / "batch.json").read_text())
    assert len(batch["scenes"]) == n_scenes
    assert "not run" in {s["status"] for s in batch["scenes"]}
    assert (out / "summary.csv").is_file()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs a named pipe")
def test_interrupt_while_the_scenes_are_read_still_writes_the_summary(tmp_path):
    scenes = tmp_path / "scenes"
    write_scenes(scenes, 2)
    os.mkfifo(scenes / "zz_pipe.json")  # reading it blocks: the batch is stopped while reading
    out = tmp_path / "out"
    proc = subprocess.Popen(CLI + ["batch", str(scenes), "--out", str(out), "--workers", "1", *SMALL],
                            start_new_session=True, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint, env=ENV)
    _wait_for(out.is_dir, proc)

    def reading_the_pipe():  # a writer can open a FIFO without blocking only once a reader has
        try:
            return os.open(scenes / "zz_pipe.json", os.O_WRONLY | os.O_NONBLOCK)
        except OSError:
            return None

    writer = _wait_for(reading_the_pipe, proc)  # held open (no EOF): the batch stays blocked
    _wait_until_blocked_in_read(proc)
    try:
        err = _interrupt(proc)
    finally:
        os.close(writer)
    assert proc.returncode == 130, err
    _check_folder(out, 3)


def test_interrupt_while_scenes_run_writes_the_summary_and_leaks_nothing(tmp_path):
    scenes = tmp_path / "scenes"
    write_scenes(scenes, 5)
    out = tmp_path / "out"
    proc = subprocess.Popen(CLI + ["batch", str(scenes), "--out", str(out), "--workers", "2", *SMALL],
                            start_new_session=True, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint, env=ENV)
    results = out / "results"
    _wait_for(lambda: results.is_dir() and any(results.glob("*.json")), proc)
    err = _interrupt(proc)
    assert proc.returncode == 130, err
    _check_folder(out, 5)
    assert "leaked" not in err and "Traceback" not in err, err
    assert err.strip() == "interrupted", err
