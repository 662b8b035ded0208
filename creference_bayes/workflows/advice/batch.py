"""The advice for a data set: every target of every frame of a batch folder, its verdict and its
best next request, and a plan within a budget of human time (docs/advice.md, "A data set").

Written to ``OUT`` (default ``BATCH_DIR/advice``)::

    advice.json                 every frame's advice (creference-advice/2) and the targets' ranking
                                with their verdicts
    requests.csv                the plan: the requests, most added value per human second first
    label_studio_requests.json  its requests on an object (lines, references, sizes) as Label Studio
                                tasks, each showing its object
    cvat_requests.xml           the same as CVAT for images 1.1 annotations

Each target's ranking row names its request
(:meth:`~creference_bayes.workflows.advice.Advice.requests`); the plan (:meth:`BatchAdvice.plan`)
may ask more than one observation on a target, each valued by what it adds to those already
asked, and the camera's mounting once per camera. Sizes and mountings are answered into the
scenes (:mod:`.answers`); lines and references come back through the importers; ``creference
batch`` then re-estimates the frames that changed.
"""

from __future__ import annotations

import dataclasses
import hashlib
from concurrent.futures import BrokenExecutor, CancelledError
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...io.files import atomic_write_json, atomic_write_text
from ..batch.files import result_paths
from . import Advice, AdviceSettings, Prediction, combined_chance
from .inputs import advise_result, scene_for_result
from .requests import image_name

__all__ = ["REQUEST_COLUMNS", "ObjectAdvice", "Request", "BatchAdvice", "object_seed", "advise_batch", "request_rows",
           "write_batch_advice"]

#: Columns of ``requests.csv``. Shares are of the target's ground distance (percent); HDI gains are
#: summed over the scene's targets (points); ``good_gain`` is the expected number of labels that
#: become good by it beyond the requests above it (over every frame of the camera, for a mounting;
#: with the hdi or location objective, by it alone); ``good_loss`` the expected number of labels good
#: now that it drops below the bar beyond the requests above it; ``location_gain_pts`` the drop of the
#: location sd in points of the distance, summed over the frame's targets.
REQUEST_COLUMNS = ("rank", "key", "target", "image", "camera", "frames", "kind", "measure", "object", "request",
                   "line_px", "seconds", "cumulative_seconds", "good_gain", "good_loss", "good_per_hour", "p_iou_now",
                   "p_iou_expected", "hdi_now_pct", "hdi_expected_pct", "gain_pts", "gain_pts_per_minute",
                   "location_gain_pts", "answer")


@dataclass(frozen=True)
class ObjectAdvice:
    """One target of the batch: its scene's key, image name, scene and advice, its index, its
    request (None when it should get none) and the fingerprint of the scene its result is of."""

    key: str
    image: str
    scene: object
    advice: Advice
    target: int
    request: Prediction | None
    fingerprint: str | None = None

    @property
    def score(self) -> float:
        """What its request is ranked by (the advice's objective; −∞ without one)."""
        return self.request.score(self.advice.settings.objective) if self.request is not None else -np.inf


@dataclass(frozen=True)
class Request:
    """One request of the plan: a target's (``objects``: the :class:`ObjectAdvice` of the target it
    is on, or most helps) or a camera's mounting (``objects``: one per frame of that camera,
    ``predictions`` its prediction in each; ``camera`` its id, None for a frame that names no
    camera), its ``value`` (what the plan chose it by, :meth:`BatchAdvice.plan`), ``seconds`` and
    ``gain``: the good labels it is expected to add to the requests above it in the plan, its
    frame's requests answered together (stated from the futures it was not chosen by), or with the
    hdi or location objective its good labels alone;
    ``loss``: the labels good now it is expected to drop below the bar beyond the requests above
    it (with the hdi or location objective, alone)."""

    objects: tuple[ObjectAdvice, ...]
    predictions: tuple[Prediction, ...]
    value: float
    seconds: float
    camera: str | None = None
    gain: float = 0.0
    loss: float = 0.0

    @property
    def prediction(self) -> Prediction:
        return self.predictions[0]

    @property
    def rate(self) -> float:
        return self.value / self.seconds if self.seconds > 0 else np.inf


@dataclass(frozen=True)
class _Item:
    """A request the plan may take and, with the labels objective, the frames it is answered in
    (key → its prediction there): a target's own frame, or every frame of a camera for a mounting."""

    request: Request
    frames: dict


@dataclass(frozen=True)
class BatchAdvice:
    """Targets in ranked order (requests first), and the results that could not be advised on."""

    objects: tuple[ObjectAdvice, ...]
    skipped: tuple[dict, ...] = ()

    def plan(self, budget_s: float | None = None) -> list[Request]:
        """The requests to send, greedy by value per human second, while that value is worth its
        time (:meth:`~.AdviceSettings.worth`) and their human time stays within ``budget_s`` (a
        request that does not fit is passed over for cheaper ones).

        With the labels objective every observation of every frame that stayed in its frame's
        race (:attr:`~creference_bayes.workflows.advice.Prediction.dropped`) may be asked, each chosen by
        the good labels it adds to the requests already planned, on the futures it is ranked by: a
        label below the bar that requests r₁…r_k would each lift with chance p₁…p_k (alone) counts
        as lifted with chance 1 − Π(1 − pᵢ). Values only fall as the plan grows. What each request
        is stated to add (``gain``: labels below the bar lifted; ``loss``: labels good now
        dropped, which takes no part in the choice) comes from the other futures, by the rule a
        frame's requests are answered by: together, their changes of each label adding
        (:func:`~creference_bayes.workflows.advice.combined_chance`). A request whose stated gain
        is not worth its time is passed over (the two sets of futures disagree on it: it is too
        close to call), so every planned request is stated to be worth its time. A frame no
        request is asked in is not estimated again: its labels keep their verdicts.

        Choosing by the additive rule as well was measured and not kept (docs/studies/advice.md, "Why two
        rules"): greedy then buys changes of a few hundredths that it credits on labels at the
        bar, and a plan on KITTI frames spent 1.6 times the human time for the same labels.

        With the hdi or location objective the plan takes each target's request
        (:meth:`~creference_bayes.workflows.advice.Advice.requests`), valued alone. The mounting is
        asked once per camera, its value summed over every frame of that camera (a frame that
        names no camera is a camera of its own)."""
        items = self._items()
        if not items:
            return []
        settings = items[0].request.objects[0].advice.settings
        labels = settings.objective == "labels"
        advice = {o.key: o.advice for o in self.objects}
        asked = {}  # frame key -> told moments of the requests planned in it
        left = {}   # frame key -> each label's chance that no planned request lifts it alone (ranked)

        def stated(it: _Item) -> tuple[float, float]:
            """(gain, loss): the labels below the bar it lifts and those good now it drops, beyond
            the requests planned, all of a frame's answered together."""
            up = down = 0.0
            for key, p in it.frames.items():
                a, ms = advice[key], asked.get(key, [])
                scale = a.futures_scale()
                d = combined_chance(*scale, ms + [p.moments]) - combined_chance(*scale, ms)
                up, down = up + float(d[~a.good].sum()), down - float(d[a.good].sum())
            return up, down

        def rate(n: int) -> tuple[float, float]:
            it = items[n]
            if labels:
                v = sum(float(np.sum((p.ranking_p_good() * left.get(key, 1.0))[~advice[key].good]))
                        for key, p in it.frames.items())
            else:
                v = it.request.value
            return v, (v / it.request.seconds if it.request.seconds > 0 else np.inf)

        def order(it: _Item) -> tuple:
            o = it.request.objects[0]
            return o.key, o.target, it.request.prediction.candidate.key

        by_frame = {}
        for n, it in enumerate(items):
            for key in it.frames:
                by_frame.setdefault(key, []).append(n)
        values = {n: rate(n) for n in range(len(items))}
        out, total = [], 0.0
        while values:
            if budget_s is not None:  # those that no longer fit never will
                for n in [n for n in values if total + items[n].request.seconds > budget_s]:
                    del values[n]
                if not values:
                    break
            n = min(values, key=lambda n: (-values[n][1], order(items[n])))
            (v, _), it = values.pop(n), items[n]
            if v <= 0 or not settings.worth(v, it.request.seconds):  # the best is not worth it: none is
                break
            if labels:
                gain, loss = stated(it)
                if not settings.worth(gain, it.request.seconds):  # worth it on the futures it was ranked
                    continue  # by, not on the others it is stated from: too close to call, passed over
                for key, p in it.frames.items():
                    asked.setdefault(key, []).append(p.moments)
                    left[key] = left.get(key, 1.0) * (1.0 - p.ranking_p_good())
                for m in {m for key in it.frames for m in by_frame[key] if m in values}:
                    values[m] = rate(m)
            else:
                gain = sum(q.good_gain for q in it.request.predictions)
                loss = sum(q.good_loss for q in it.request.predictions)
            total += it.request.seconds
            out.append(dataclasses.replace(it.request, value=v, gain=gain, loss=loss))
        return out

    def _items(self) -> list[_Item]:
        """Every request the plan may take (:meth:`plan`)."""
        frames = {}
        for o in self.objects:
            frames.setdefault(o.key, {})[o.target] = o
        items, cameras = [], {}
        for key, targets in frames.items():
            first = next(iter(targets.values()))
            objective = first.advice.settings.objective
            below = np.flatnonzero(~first.advice.good)
            if objective == "labels":
                pairs = [(targets[_shown(p, below)], p) for p in first.advice.predictions
                         if p.candidate.kind != "mounting" and not p.dropped]
            else:
                pairs = [(o, o.request) for o in targets.values()
                         if o.request is not None and o.request.candidate.kind != "mounting"]
            for o, p in pairs:
                items.append(_Item(Request((o,), (p,), p.value(objective), p.candidate.seconds, o.scene.camera_id),
                                   {key: p}))
            p = next((p for p in first.advice.predictions if p.candidate.kind == "mounting"), None)
            if p is not None:
                cameras.setdefault(first.scene.camera_id or f"frame:{key}", []).append((first, p, p.value(objective)))
        for camera, of in cameras.items():
            request = Request(tuple(f[0] for f in of), tuple(f[1] for f in of), sum(f[2] for f in of),
                              of[0][1].candidate.seconds, None if camera.startswith("frame:") else camera)
            items.append(_Item(request, {f[0].key: f[1] for f in of}))
        return items


def _shown(p: Prediction, below: np.ndarray) -> int:
    """The target a request is listed under: the one it is asked on, or the one below the bar it
    most likely lifts (a reference elsewhere)."""
    if p.candidate.target is not None:
        return p.candidate.target
    if not len(below):
        return 0
    q = p.ranking_p_good()
    return int(below[np.argmax(q[below])])


def object_seed(seed: int, key: str) -> list[int]:
    """A per-scene seed from the base seed and the scene's key (independent of order)."""
    return [int(seed), int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "little")]


def _advise_one(path: Path, key: str, seed, settings):
    """One scene (run on the engine: a local worker process or a Dask worker thread): (scene,
    Advice, fingerprint), or the reason it cannot be advised on."""
    from ...inference.threads import single_threaded_blas
    from ...io.result import read_result

    try:
        result = read_result(path)
        if "batch" not in result:
            raise ValueError("not a result of creference batch")
        scene = scene_for_result(path, result)
        with single_threaded_blas():
            advice = advise_result(result, scene, seed=object_seed(seed, key), settings=settings)
        return scene, advice, (result.get("scene_id") or {}).get("sha256")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return " ".join(str(exc).split())


#: What the engine raises for a task it lost (Dask's KilledWorker is matched by name: Dask is optional).
_LOST = (BrokenExecutor, CancelledError)


def _advised(bar, key: str, outcome) -> None:
    """One scene advised: the bar's note (a log file's line) says which, and whether it was skipped."""
    bar.set_postfix_str(f"{key} skipped: {outcome}" if isinstance(outcome, str) else f"{key} advised", refresh=False)
    bar.update(1)


def advise_batch(batch_dir: str | Path, *, seed: int = 0, settings: AdviceSettings | None = None,
                 engine=None, workers: int | None = None, progress: bool | str = False) -> BatchAdvice:
    """The advice for every result of a ``creference batch`` folder (module docstring).

    Results that cannot be read, whose scene copy changed or of another model are listed in
    ``skipped`` with the reason. The scenes are advised on ``engine`` as ``creference batch``
    estimates them (:func:`~creference_bayes.workflows.batch.engines.each_completed`; e.g. a
    :class:`~creference_bayes.workflows.batch.engines.DaskEngine`; closed on return), by default
    on ``workers`` local processes (default: the machine's cores; no more than the scenes, and
    this process for one: a worker process would only add its start); each scene's seed derives
    from ``seed`` and its key (:func:`object_seed`), so the numbers depend neither on the engine
    nor on the number of workers.
    """
    from ...inference.progress import progress_bar
    from ..batch.engines import InlineEngine, LocalEngine, default_workers, each_completed

    settings = settings or AdviceSettings()
    abandon = True
    try:
        jobs = {key: (path, key, seed, settings) for key, path in result_paths(batch_dir, check=True).items()}
        if engine is None:
            if workers is not None and workers < 1:
                raise ValueError(f"workers: expected an integer >= 1, got {workers!r}")
            n = min(default_workers() if workers is None else workers, len(jobs))
            engine = LocalEngine(n) if n > 1 else InlineEngine()
        outcome = {}
        with progress_bar(progress, len(jobs), desc="advice", unit="scene") as bar:
            for key, got in each_completed(engine, _advise_one, jobs):
                if isinstance(got, BaseException):
                    if not isinstance(got, _LOST) and type(got).__name__ != "KilledWorker":
                        raise got  # the task's own: a fault to see, as when it ran in this process
                    # the engine's: a worker that died, a cancelled task
                    got = f"the worker failed ({type(got).__name__}: {' '.join(str(got).split())}); rerun to retry"
                outcome[key] = got
                _advised(bar, key, got)
        abandon = False
    finally:
        if engine is not None:
            engine.close(abandon=abandon)
    objects, skipped = [], []
    for key in jobs:
        if isinstance(outcome[key], str):
            skipped.append({"key": key, "reason": outcome[key]})
            continue
        scene, advice, fingerprint = outcome[key]
        objects += [ObjectAdvice(key, image_name(scene, key), scene, advice, i, p, fingerprint)
                    for i, p in enumerate(advice.requests())]
    objects.sort(key=lambda o: (o.request is None, -o.score, o.key, o.target))
    return BatchAdvice(tuple(objects), tuple(skipped))


def request_rows(batch: BatchAdvice, budget_s: float | None = None) -> list[dict]:
    """The rows of ``requests.csv``: the plan (:meth:`BatchAdvice.plan`) in order. A mounting's row
    has no key or target: it is for every frame of its ``camera`` (``frames`` of them)."""
    return _rows(batch.plan(budget_s))


def _rows(plan: list[Request]) -> list[dict]:
    rows, total = [], 0.0
    for r in plan:
        o, p = r.objects[0], r.prediction
        c, now = p.candidate, o.advice.now
        total += r.seconds
        one = c.kind != "mounting"
        i = o.target
        good = r.gain
        rows.append({
            "rank": len(rows) + 1, "key": o.key if one or r.camera is None else "",
            "target": o.advice.targets[i] if one else "", "image": o.image if one or r.camera is None else "",
            "camera": r.camera or "", "frames": len(r.objects), "kind": c.kind, "measure": c.measure or "",
            "object": c.object or "", "request": c.description,
            "line_px": "" if c.line is None else ";".join(f"{u:.2f},{v:.2f}" for u, v in c.line),
            "seconds": f"{r.seconds:g}", "cumulative_seconds": f"{total:g}",
            "good_gain": f"{good:.3f}", "good_loss": f"{r.loss:.3f}", "good_per_hour": f"{good * 3600.0 / r.seconds:.3f}",
            "p_iou_now": f"{now.p_iou[i]:.3f}" if one else "", "p_iou_expected": f"{p.expected.p_iou[i]:.3f}" if one else "",
            "hdi_now_pct": f"{100 * now.hdi_share[i]:.2f}" if one else "",
            "hdi_expected_pct": f"{100 * p.expected.hdi_share[i]:.2f}" if one else "",
            "gain_pts": f"{p.gain_pct:.3f}", "gain_pts_per_minute": f"{p.gain_per_minute:.4f}",
            "location_gain_pts": f"{p.location_gain_pct:.3f}", "answer": ""})
    return rows


def write_batch_advice(batch: BatchAdvice, out: str | Path, *, budget_s: float | None = None,
                       lines: str = "keypoints", image_url_prefix: str | None = None) -> dict[str, Path]:
    """Write the advice files (module docstring) to ``out``; returns their paths by name.
    ``image_url_prefix``: the Label Studio tasks' image URLs (:func:`~.requests.label_studio_requests`)."""
    from ...io.files import atomic_write_csv
    from .requests import cvat_requests, label_studio_requests

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plan = batch.plan(budget_s)
    rows = _rows(plan)
    # every request on an object goes to the labelling tools, each task showing its object (a size
    # is answered there too, its answer put into the scene by --apply, :mod:`.answers`); the
    # camera's mounting, from its calibration, is no crowd task
    requested = [(r.objects[0].key, r.objects[0].scene, r.prediction.candidate) for r in plan
                 if r.prediction.candidate.kind != "mounting"]
    paths = {"advice": out / "advice.json", "requests": out / "requests.csv",
             "label_studio": out / "label_studio_requests.json", "cvat": out / "cvat_requests.xml"}
    scenes = {}
    for o in batch.objects:
        scenes.setdefault(o.key, {"key": o.key, "image": o.image, "scene_sha256": o.fingerprint,
                                  **o.advice.to_dict()})
    atomic_write_json(paths["advice"], {
        "format": "creference-batch-advice/2", "budget_s": budget_s, "scenes": list(scenes.values()),
        "ranking": [{"key": o.key, "target": o.advice.targets[o.target],
                     "request": None if o.request is None else o.request.candidate.key,
                     "good_per_hour": None if o.request is None else o.request.good_per_hour,
                     "gain_pts_per_minute": None if o.request is None else o.request.gain_per_minute,
                     **{k: v for k, v in o.advice.verdicts()[o.target].items() if k != "target"}}
                    for o in batch.objects],
        "skipped": list(batch.skipped)})
    atomic_write_csv(paths["requests"], rows, REQUEST_COLUMNS)
    tasks = label_studio_requests(requested, lines=lines, image_url_prefix=image_url_prefix)
    atomic_write_text(paths["label_studio"], json.dumps(tasks, indent=1) + "\n")
    atomic_write_text(paths["cvat"], cvat_requests(requested))
    return paths
