"""Running scenes on an engine: the task a worker runs (:func:`run_scene`) and the loop that
keeps every worker busy, enforces the time limit and records each outcome as it arrives."""

from __future__ import annotations

import concurrent.futures as cf
import time
import traceback
from collections import deque

from ...pipeline import estimate
from .dataset import share_scale
from .files import layout, record_error, record_result

__all__ = ["run_scene", "one_line", "Runner", "progress_bar"]


def run_scene(job: dict) -> dict:
    """Estimate one scene (runs in a worker: a local process or a Dask worker thread).

    ``job`` holds the ``scene`` (a :class:`~creference_bayes.io.scene.Scene`), its ``seed`` and the
    settings' ``estimate`` (an :class:`~creference_bayes.pipeline.EstimateSettings`). Never raises for a failed estimate: returns
    ``{"ok": True, "result": …}`` or ``{"ok": False, "stage", "error", "traceback"}``.
    """
    try:
        result = estimate(job["scene"], job["estimate"], seed=job["seed"]).to_dict()
        if job.get("shared_scale"):  # a held value's uncertainty, one scale the camera's frames share (dataset.py)
            share_scale(result, **job["shared_scale"])
        if job.get("rig"):  # the rig the frame's camera priors came from (rig.py)
            result["rig"] = job["rig"]
        if job.get("dataset"):  # what the frame took from the data set, and how sure that was (dataset.py)
            result["dataset"] = job["dataset"]
        return {"ok": True, "result": result}
    except Exception as exc:  # isolate the failure: the batch goes on
        return {"ok": False, "stage": "estimate", "error": one_line(exc), "traceback": traceback.format_exc()}


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def progress_bar(total: int, failed: int, enabled: bool, desc: str = "batch"):
    """Scenes to do (those that failed to load count as done and failed from the start); ``desc``
    names the pass (``first pass``: the data set's, :func:`.._first_pass`)."""
    from ...inference.progress import progress_bar as bar

    return bar(enabled, total, desc=desc, unit="scene", initial=failed, leave=True,
               postfix={"failed": failed})


class Runner:
    """Keeps ``engine.slots()`` jobs in flight, records each outcome as it arrives."""

    def __init__(self, out, engine, settings, time_limit, status, errors, bar, on_event):
        self.out, self.engine, self.settings, self.time_limit = out, engine, settings, time_limit
        self.status, self.errors, self.bar, self.on_event = status, errors, bar, on_event
        self.running: dict[cf.Future, tuple] = {}  # future -> (scene input, job, start)
        self.abandoned: set[cf.Future] = set()  # over the time limit, maybe running: hold a slot
        self.n_failed = sum(s == "failed" for s in status.values())
        self.n_targets = 0  # estimated in this run

    def run(self, todo: deque) -> None:
        while todo or self.running:
            self._fill(todo)
            done, _ = cf.wait(set(self.running) | self.abandoned, timeout=self._timeout(),
                              return_when=cf.FIRST_COMPLETED)
            for fut in done:
                self._collect(fut)
            self._enforce_time_limit()
            if todo and self.abandoned and not self.running and self.engine.can_stop_tasks:
                self.engine.renew()  # only abandoned tasks hold the slots: end them
                self.abandoned.clear()

    def _fill(self, todo: deque) -> None:
        while todo and len(self.running) + len(self.abandoned) < self.engine.slots():
            si, job = todo.popleft()
            fut = self.engine.executor.submit(run_scene, job)
            self.running[fut] = (si, job, time.monotonic())

    def _timeout(self) -> float | None:
        if self.time_limit is None or not self.running:
            return None
        first = min(start for *_, start in self.running.values())
        return max(0.0, first + self.time_limit - time.monotonic())

    def _collect(self, fut: cf.Future) -> None:
        if fut in self.abandoned:
            self.abandoned.discard(fut)
            return
        if fut not in self.running:  # already failed with a broken pool
            return
        si, job, start = self.running.pop(fut)
        try:
            res = fut.result()
        except cf.BrokenExecutor as exc:  # a worker process died: every task in the pool is lost
            self._finish(si, False, "worker", f"a worker process died ({one_line(exc)}); rerun to retry", start=start)
            for other, (osi, _job, ostart) in list(self.running.items()):
                self._finish(osi, False, "worker", "lost with a worker process that died; rerun to retry", start=ostart)
            self.running.clear()
            self.abandoned.clear()
            self.engine.renew()
            return
        except cf.CancelledError:
            self._finish(si, False, "worker", "the task was cancelled by the engine; rerun to retry", start=start)
            return
        except Exception as exc:  # raised by the engine itself (e.g. Dask's KilledWorker)
            self._finish(si, False, "worker", one_line(exc), traceback.format_exc(), start=start)
            return
        if res["ok"]:
            record_result(layout(self.out, si.key), si, job["scene"], res["result"], job["seed"],
                          job.get("ident", self.settings))
            self.n_targets += len(res["result"]["objects"])
            converged = (res["result"].get("diagnostics") or {}).get("converged", True)
            self._finish(si, True, start=start, converged=converged)
        else:
            self._finish(si, False, res["stage"], res["error"], res.get("traceback"), start=start)

    def _enforce_time_limit(self) -> None:
        if self.time_limit is None:
            return
        now = time.monotonic()
        for fut, (si, *_rest, start) in list(self.running.items()):
            if now - start >= self.time_limit and not fut.done():
                del self.running[fut]
                if not fut.cancel():
                    self.abandoned.add(fut)
                self._finish(si, False, "time limit", f"TimeLimit: no result within "
                             f"{self.time_limit:g} s; the computation was abandoned", start=start)

    def _finish(self, si, ok: bool, stage=None, error=None, tb=None, *, start=None, converged=True) -> None:
        if not ok:
            self.n_failed += 1
            self.errors[si.key] = error
            record_error(layout(self.out, si.key), si, stage, error, tb)
        self.status[si.key] = "done" if ok else "failed"
        # the scene, how it ended and its time: after the bar on a terminal, a line each in a log file
        how = ("estimated" if converged else "estimated, not converged") if ok else f"failed ({stage})"
        took = f" in {time.monotonic() - start:.1f} s" if start is not None else ""
        self.bar.set_postfix_str(f"{si.key} {how}{took}; {self.n_failed} failed", refresh=False)
        self.bar.update(1)
        if self.on_event:
            self.on_event(si.key, self.status[si.key])
