"""The service's folder and its background queue: every task it has seen, each frame's posterior
and its advice, kept on disk so that nothing is lost when the service restarts (docs/serve.md).

The folder (a batch folder's layout, :func:`~creference_bayes.workflows.batch.files.layout`, with
the tasks and the advice beside it)::

    DIR/tasks/KEY.json     the task as last seen (its data and every annotation, by id)
    DIR/scenes/KEY.json    the frame's scene, as estimated
    DIR/results/KEY.json   its creference-result/2 with posterior draws (``scene_id.sha256``: the
                           scene it is the result of) and a batch's ``batch`` block: ``creference
                           labels DIR`` reads the folder as a batch folder
    DIR/advice/KEY.json    the next request for that scene
    DIR/errors/KEY.json    why the last job of the task failed
    DIR/projects/ID.xml    each project's labelling config, from /setup

KEY is ``p<project>_t<task>``. The tasks of one project that show one photo (``data.image``) make
one frame, as ``creference import label-studio`` joins them: its scene, result and advice are kept
under the key of its first task (the lowest id), and a task's own ones are removed when it joins
another's frame. A stored result counts for a frame only while its scene is the one the tasks'
annotations make now. One job per task at a time: a job asked for while one of the
same task runs is run once more after it, and a job reads the task as it is when it starts.
"""

from __future__ import annotations

import hashlib
import logging
import queue
import threading
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

from ..io.files import atomic_write_json, atomic_write_text
from ..io.validation import read_json
from ..workflows.batch.dataset import share_scale, shared_scale
from ..workflows.batch.files import layout
from .predictions import Frame, tasks_scene

__all__ = ["FrameStore", "Worker", "task_key"]

log = logging.getLogger("creference.serve")


def task_key(project, task_id: int) -> str:
    """The file name stem of a task: ``p<project>_t<task>`` (``p0`` when the project is unknown)."""
    return f"p{int(project) if project is not None else 0}_t{int(task_id)}"


class FrameStore:
    """The service's folder (module docstring)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        for sub in ("tasks", "scenes", "results", "advice", "errors", "projects"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        #: task key → the photo it shows (None: a frame of its own), :func:`_photo`
        self._photos = {key: _photo(self.task(key)) for key in self.keys()}

    def paths(self, key: str) -> dict[str, Path]:
        return {**layout(self.root, key), "task": self.root / "tasks" / f"{key}.json",
                "advice": self.root / "advice" / f"{key}.json"}

    def _read(self, path: Path):
        try:
            return read_json(path)
        except (OSError, ValueError):
            return None

    # -- tasks ---------------------------------------------------------------------------------
    def task(self, key: str) -> dict | None:
        """The task as last seen (``data`` and ``annotations``), or None."""
        d = self._read(self.paths(key)["task"])
        return d if isinstance(d, dict) else None

    def put_task(self, key: str, task: dict) -> dict:
        """Store a task as Label Studio sent it to /predict: its data and all its annotations."""
        anns = [a for a in task.get("annotations") or [] if isinstance(a, dict)]
        doc = {"id": task["id"], "data": task["data"], "annotations": anns}
        with self._lock:
            if self.task(key) != doc:  # Label Studio asks again and again for the same task
                self._write_task(key, doc)
        return doc

    def _write_task(self, key: str, doc: dict) -> None:
        atomic_write_json(self.paths(key)["task"], doc, indent=None)  # compact: the C encoder, 10 times faster
        self._photos[key] = _photo(doc)

    def members(self, key: str, task: dict | None = None) -> list[str]:
        """The keys of the tasks that make one frame with task ``key`` (``task``: as it is now; else
        as stored): the stored tasks of its project that show the same photo, and itself, in the
        order of their ids; the first is the frame's key. ``[key]`` for a task of no photo."""
        photo = _photo(task if task is not None else self.task(key))
        if photo is None:
            return [key]
        project = key.rsplit("_t", 1)[0]
        with self._lock:
            same = {k for k, p in self._photos.items() if p == photo and k.rsplit("_t", 1)[0] == project}
        return sorted(same | {key}, key=lambda k: int(k.rsplit("_t", 1)[1]))

    def put_annotation(self, key: str, task: dict, annotation: dict) -> dict:
        """Store one created or updated annotation of a task (a webhook's): it replaces the stored
        annotation of the same id; the task's data is the webhook's."""
        with self._lock:
            old = self.task(key) or {}
            anns = [a for a in old.get("annotations", []) if a.get("id") != annotation.get("id")]
            doc = {"id": task["id"], "data": task["data"], "annotations": anns + [annotation]}
            self._write_task(key, doc)
        return doc

    def drop_annotations(self, project, ids) -> list[str]:
        """Remove the annotations of these ids from the stored tasks of a project (every project's
        when it is None); returns the keys of the tasks that changed."""
        ids, changed = {str(i) for i in ids}, []
        prefix = "" if project is None else task_key(project, 0).rsplit("_", 1)[0] + "_"
        with self._lock:
            for key in self.keys():
                task = self.task(key) if key.startswith(prefix) else None
                if task is None:
                    continue
                kept = [a for a in task.get("annotations", []) if str(a.get("id")) not in ids]
                if len(kept) < len(task.get("annotations", [])):
                    self._write_task(key, {**task, "annotations": kept})
                    changed.append(key)
        return changed

    def keys(self) -> list[str]:
        return sorted(p.stem for p in (self.root / "tasks").glob("*.json") if not p.name.startswith("."))

    # -- results -------------------------------------------------------------------------------
    def result(self, key: str, frame: Frame):
        """The stored result of this frame (a :class:`~creference_bayes.pipeline.Result`): of its
        scene, with what it took from a data set (its ``dataset`` block); or None."""
        from ..io.scene import scene_fingerprint
        from ..pipeline import load_result

        path = self.paths(key)["result"]
        d = self._read(path)
        if not isinstance(d, dict) or (d.get("scene_id") or {}).get("sha256") != scene_fingerprint(frame.scene) \
                or d.get("dataset") != frame.dataset:
            return None
        try:
            return load_result(path)
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def advice(self, key: str, fingerprint: str) -> dict | None:
        d = self._read(self.paths(key)["advice"])
        return d if isinstance(d, dict) and d.get("scene_sha256") == fingerprint else None

    def error(self, key: str, fingerprint: str | None = None) -> dict | None:
        d = self._read(self.paths(key)["error"])
        ok = isinstance(d, dict) and (fingerprint is None or d.get("scene_sha256") == fingerprint)
        return d if ok else None

    def put_result(self, key: str, frame: Frame, result, seed: int, settings: dict) -> None:
        """The scene copy, then the result (a Result or its dict) with a batch's ``batch`` block (its source: the copy)
        and the frame's ``rig`` and ``dataset`` blocks, so that ``creference labels`` and ``advise``
        read the folder as a batch folder."""
        from ..workflows.batch import SceneInput
        from ..workflows.batch.files import record_result

        p = self.paths(key)
        d = dict(result if isinstance(result, dict) else result.to_dict())
        d.update({k: v for k, v in (("rig", frame.rig), ("dataset", frame.dataset)) if v})
        record_result(p, SceneInput(key, p["scene"]), frame.scene, d, seed, settings)
        for other in set(frame.members) - {key}:  # a task's own frame, before it joined this one
            for path in self.paths(other).values():
                if path.parent.name != "tasks":
                    path.unlink(missing_ok=True)

    def put_advice(self, key: str, frame: Frame, advice, seconds: dict | None = None) -> None:
        """The next request for the frame; ``seconds``: how long the job's steps took."""
        best = advice.best
        request = best.candidate.description if advice.action == "collect" and best is not None else None
        atomic_write_json(self.paths(key)["advice"], {"scene_sha256": frame.fingerprint, "action": advice.action,
                                                      "reason": advice.reason, "request": request,
                                                      **({"seconds": seconds} if seconds else {})})

    def put_error(self, key: str, fingerprint: str | None, error: str) -> None:
        atomic_write_json(self.paths(key)["error"], {"scene_sha256": fingerprint, "error": error})

    # -- projects ------------------------------------------------------------------------------
    def put_config(self, project: int, config: str) -> None:
        atomic_write_text(self.root / "projects" / f"{int(project)}.xml", config)

    def config(self, project: int | None) -> str | None:
        if project is None:
            return None
        try:
            return (self.root / "projects" / f"{int(project)}.xml").read_text("utf-8")
        except OSError:
            return None

    def state_tag(self) -> str:
        """Eight hex digits that change whenever a result or advice is written: the model version
        says so, and Label Studio asks again for the predictions of an older version."""
        h = hashlib.sha256()
        for sub in ("results", "advice"):
            for p in sorted((self.root / sub).glob("*.json")):
                try:
                    h.update(f"{p.name}:{p.stat().st_mtime_ns}".encode())
                except OSError:
                    continue
        return h.hexdigest()[:8]


def _photo(task: dict | None) -> str | None:
    """The photo a stored task shows (``data.image``), or None: a task of no photo, or a request
    task of ``creference advise`` (a frame of its own)."""
    data = (task or {}).get("data")
    if not isinstance(data, dict) or "creference_scene" in data:
        return None
    image = data.get("image")
    return image if isinstance(image, str) and image else None


class Worker:
    """A background thread that estimates queued frames (module docstring): the posterior
    (:func:`~creference_bayes.estimate`), then the advice's next request; with ``priors``
    (:class:`~.priors.DataSetPriors`), each frame with the data set's."""

    def __init__(self, store: FrameStore, *, image_root=None, seed: int = 0, hdi_prob: float = 0.9,
                 advice_settings=None, sampling: dict | None = None, settle_s: float = 2.0, priors=None):
        self.store, self.image_root, self.seed, self.hdi_prob = store, image_root, seed, hdi_prob
        self.priors = priors
        self.settle_s = settle_s  # the thread waits this long after a task's last submit (its annotations settle)
        self._last: dict[str, float] = {}
        self.advice_settings, self.sampling = advice_settings, sampling
        self._queue: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._queued: set[str] = set()
        self._running: str | None = None
        self._again: set[str] = set()
        self._thread: threading.Thread | None = None

    def start(self, resume: bool = True) -> "Worker":
        """Start the thread; with ``resume``, queue every stored task (a task whose result is up to
        date is passed over at once)."""
        if resume:
            for key in self.store.keys():
                self.submit(key)
        self._thread = threading.Thread(target=self._loop, name="creference-serve-worker", daemon=True)
        self._thread.start()
        return self

    def submit(self, key: str) -> None:
        with self._lock:
            self._last[key] = time.monotonic()
            if key == self._running:
                self._again.add(key)
            elif key not in self._queued:
                self._queued.add(key)
                self._queue.put(key)

    def busy(self, key: str) -> bool:
        with self._lock:
            return key in self._queued or key == self._running

    def pending(self) -> int:
        """Jobs queued or running."""
        with self._lock:
            return len(self._queued) + (self._running is not None)

    def run_pending(self) -> None:
        """Run every queued job in this thread (tests, and a service without its thread)."""
        while True:
            try:
                key = self._queue.get_nowait()
            except queue.Empty:
                return
            self._run(key)

    def _loop(self) -> None:
        while True:
            key = self._queue.get()
            while True:  # more annotations of the task may be on their way: one job for them all
                with self._lock:
                    wait = self._last.get(key, 0.0) + self.settle_s - time.monotonic()
                if wait <= 0:
                    break
                time.sleep(wait)
            self._run(key)

    def _run(self, key: str) -> None:
        with self._lock:
            self._queued.discard(key)
            self._running = key
        try:
            self.run_job(key)
        except Exception as exc:  # a job's failure is recorded, never the end of the thread
            log.error("job %s failed: %s", key, traceback.format_exc())
            self.store.put_error(key, None, " ".join(str(exc).split()) or type(exc).__name__)
        finally:
            with self._lock:  # a job asked for while it ran is queued again before anyone sees it idle
                self._running = None
                if key in self._again:
                    self._again.discard(key)
                    self._queued.add(key)
                    self._queue.put(key)

    def frame(self, key: str, task: dict, alone: Frame | None = None) -> Frame | None:
        """The frame of task ``key`` (``task``: as it is now), joined with the stored tasks of its
        photo (:meth:`FrameStore.members`, :func:`~.predictions.tasks_scene`: None when no
        annotation draws anything yet), with the data set's priors when the service has them.
        ``alone``: the task's frame made alone, used when no other task shares its photo."""
        from dataclasses import replace

        members = self.store.members(key, task)
        if alone is not None and members == [key]:
            frame = alone
        else:
            tasks = [task if k == key else self.store.task(k) for k in members]
            frame = tasks_scene([t for t in tasks if t is not None], self.image_root)
        if frame is None:
            return None
        frame = replace(frame, key=members[0], members=tuple(members))
        return frame if self.priors is None else self.priors.frame(frame.key, frame)

    def run_job(self, key: str) -> None:
        """Estimate the frame of a stored task, unless its result is up to date."""
        from .. import estimate
        from ..workflows.advice import AdviceSettings
        from ..workflows.advice.inputs import advise_result
        from ..workflows.batch import derive_seed
        from .predictions import RequestError

        task = self.store.task(key)
        if task is None:
            return
        try:
            frame = self.frame(key, task)
        except RequestError as exc:
            self.store.put_error(key, None, str(exc))
            return
        if frame is None or self.store.error(frame.key, frame.fingerprint) is not None:
            return
        key = frame.key  # the frame's, when the task shares its photo with others
        seed = derive_seed(self.seed, frame.fingerprint)
        result = self.store.result(key, frame)
        seconds = {}
        if result is None:
            log.info("job %s: sampling the posterior of %d target(s)", key, len(frame.scene.targets))
            with _timed(seconds, "posterior"):
                result = estimate(frame.scene, seed=seed, hdi_prob=self.hdi_prob, sampling=self.sampling,
                                  **frame.kwargs).to_dict()
                scale = shared_scale(frame.dataset or {}, self.seed)
                if scale is not None:  # a held focal length's uncertainty, as a batch's results carry it
                    share_scale(result, **scale)
            settings = {"serve": True, "seed": self.seed, "hdi_prob": self.hdi_prob, "sampling": self.sampling or {}}
            self.store.put_result(key, frame, result, seed, settings)
        if self.store.advice(key, frame.fingerprint) is None:
            with _timed(seconds, "advice"):
                advice = advise_result(result, frame.scene, seed=seed,
                                       settings=self.advice_settings or AdviceSettings())
            self.store.put_advice(key, frame, advice, seconds)
        log.info("job %s: done (%s)", key, ", ".join(f"{k} {v:g} s" for k, v in seconds.items()) or "up to date")


@contextmanager
def _timed(seconds: dict, step: str):
    """Record a job's step in ``seconds``: ``step`` (wall clock) and ``step_cpu`` (the process's CPU
    meanwhile), seconds."""
    t0, c0 = time.perf_counter(), time.process_time()
    yield
    seconds[step], seconds[f"{step}_cpu"] = round(time.perf_counter() - t0, 2), round(time.process_time() - c0, 2)
