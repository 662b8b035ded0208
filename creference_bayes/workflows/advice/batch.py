"""The advice for a data set: every target of every frame of a batch folder, its verdict and its
best next request, and a plan within a budget of human time (docs/advice.md, "A data set").

Written to ``OUT`` (default ``BATCH_DIR/advice``)::

    advice.json                 every frame's advice (creference-advice/2) and the targets' ranking
                                with their verdicts
    requests.csv                the plan: the requests, best value per human second first
    label_studio_requests.json  its line and reference requests as Label Studio tasks
    cvat_requests.xml           the same as CVAT for images 1.1 annotations

A target's request is the best-ranked observation of its frame that is asked on it or on no
target, each at most once per frame
(:meth:`~creference_bayes.workflows.advice.Advice.requests`); a target whose label is good (or,
with the hdi objective, whose precision target is met), or whose best request is not worth its
time, gets none. The camera's mounting is planned once per camera (:meth:`BatchAdvice.plan`).
Sizes and mountings are answered into the scenes (:mod:`.answers`); lines and references come
back through the importers. After the answers are in, ``creference batch`` re-estimates the
frames that changed and the advice is worth recomputing.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...io.files import atomic_write_json, atomic_write_text
from . import Advice, AdviceSettings, Prediction
from .inputs import advise_result, scene_for_result
from .requests import image_name

__all__ = ["REQUEST_COLUMNS", "ObjectAdvice", "Request", "BatchAdvice", "object_seed", "advise_batch", "request_rows",
           "write_batch_advice"]

#: Columns of ``requests.csv``. Shares are of the target's ground distance (percent); HDI gains are
#: summed over the scene's targets (points); ``good_gain`` is the expected number of labels that
#: become good (over every frame of the camera, for a mounting).
REQUEST_COLUMNS = ("rank", "key", "target", "image", "camera", "frames", "kind", "measure", "object", "request",
                   "line_px", "seconds", "cumulative_seconds", "good_gain", "good_per_hour", "p_iou_now",
                   "p_iou_expected", "hdi_now_pct", "hdi_expected_pct", "gain_pts", "gain_pts_per_minute", "answer")


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
    """One request of the plan: a target's (``objects``: its :class:`ObjectAdvice`) or a camera's
    mounting (``objects``: one per frame of that camera, ``predictions`` its prediction in each;
    ``camera`` its id, None for a frame that names no camera), its ``value`` (expected good
    labels, or HDI points with the hdi objective, :meth:`~.Prediction.value`) and ``seconds``."""

    objects: tuple[ObjectAdvice, ...]
    predictions: tuple[Prediction, ...]
    value: float
    seconds: float
    camera: str | None = None

    @property
    def prediction(self) -> Prediction:
        return self.predictions[0]

    @property
    def rate(self) -> float:
        return self.value / self.seconds if self.seconds > 0 else np.inf


@dataclass(frozen=True)
class BatchAdvice:
    """Targets in ranked order (requests first), and the results that could not be advised on."""

    objects: tuple[ObjectAdvice, ...]
    skipped: tuple[dict, ...] = ()

    @property
    def requests(self) -> tuple[ObjectAdvice, ...]:
        return tuple(o for o in self.objects if o.request is not None)

    def plan(self, budget_s: float | None = None) -> list[Request]:
        """The requests to send, best value per human second first, while their human time stays
        within ``budget_s`` (a request that does not fit is passed over for cheaper ones after it).

        A target's request is its scene's choice (:meth:`~creference_bayes.workflows.advice.Advice.requests`);
        the mounting is asked once per camera, its value summed over every frame of that camera (a
        frame that names no camera is a camera of its own). Each request is valued as if it were
        the only one (the plan is greedy: a frame's requests are not weighed together)."""
        items, cameras = [], {}
        for o in self.requests:
            if o.request.candidate.kind != "mounting":
                items.append(Request((o,), (o.request,), o.request.value(o.advice.settings.objective),
                                     o.request.candidate.seconds, o.scene.camera_id))
        seen = set()
        for o in self.objects:
            if o.key in seen:
                continue
            seen.add(o.key)
            p = next((p for p in o.advice.predictions if p.candidate.kind == "mounting"), None)
            if p is not None:
                cameras.setdefault(o.scene.camera_id or f"frame:{o.key}", []).append((o, p))
        for camera, frames in cameras.items():
            settings = frames[0][0].advice.settings
            value = sum(p.value(settings.objective) for _, p in frames)
            seconds = frames[0][1].candidate.seconds
            if value > 0 and settings.worth(value, seconds):
                items.append(Request(tuple(o for o, _ in frames), tuple(p for _, p in frames), value, seconds,
                                     None if camera.startswith("frame:") else camera))
        items.sort(key=lambda r: (-r.rate, r.objects[0].key, r.objects[0].target))
        out, total = [], 0.0
        for r in items:
            if budget_s is not None and total + r.seconds > budget_s:
                continue
            total += r.seconds
            out.append(r)
        return out


def object_seed(seed: int, key: str) -> list[int]:
    """A per-scene seed from the base seed and the scene's key (independent of order)."""
    return [int(seed), int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "little")]


def _advise_one(path: Path, key: str, seed, settings):
    """One scene (run in a worker process with ``workers`` > 1): (scene, Advice), or the reason it
    cannot be advised on."""
    from ...io.result import load_result

    try:
        result = load_result(path)
        if "batch" not in result:
            raise ValueError("not a result of creference batch")
        scene = scene_for_result(path, result)
        return scene, advise_result(result, scene, seed=object_seed(seed, key), settings=settings), \
            (result.get("scene_id") or {}).get("sha256")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return " ".join(str(exc).split())


def advise_batch(batch_dir: str | Path, *, seed: int = 0, settings: AdviceSettings | None = None,
                 workers: int = 1, progress: bool = False) -> BatchAdvice:
    """The advice for every result of a ``creference batch`` folder (module docstring).

    Results that cannot be read, whose scene copy changed or of another model are listed in
    ``skipped`` with the reason. With ``workers`` > 1 the scenes are advised on in that many local
    processes; each scene's seed derives from ``seed`` and its key (:func:`object_seed`), so the
    numbers do not depend on ``workers``.
    """
    from ...inference.progress import progress_bar

    settings = settings or AdviceSettings()
    root = Path(batch_dir) / "results"
    if not root.is_dir():
        raise FileNotFoundError(2, "not a batch folder (no results/ inside)", str(batch_dir))
    jobs = {}
    for path in sorted(root.rglob("*.json")):
        key = path.relative_to(root).with_suffix("").as_posix()
        if not any(part.startswith(".") for part in key.split("/")):  # a killed write's temporary file
            jobs[key] = (path, key, seed, settings)
    outcome = {}
    with progress_bar(progress, len(jobs), desc="advice", unit="scene") as bar:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import as_completed

            from ..batch.engines import LocalEngine

            with LocalEngine(workers) as engine:
                futures = {engine.executor.submit(_advise_one, *job): key for key, job in jobs.items()}
                for f in as_completed(futures):
                    outcome[futures[f]] = f.result()
                    bar.update(1)
        else:
            for key, job in jobs.items():
                outcome[key] = _advise_one(*job)
                bar.update(1)
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
        good = sum(q.good_gain for q in r.predictions)
        rows.append({
            "rank": len(rows) + 1, "key": o.key if one or r.camera is None else "",
            "target": o.advice.targets[i] if one else "", "image": o.image if one or r.camera is None else "",
            "camera": r.camera or "", "frames": len(r.objects), "kind": c.kind, "measure": c.measure or "",
            "object": c.object or "", "request": c.description,
            "line_px": "" if c.line is None else ";".join(f"{u:.2f},{v:.2f}" for u, v in c.line),
            "seconds": f"{r.seconds:g}", "cumulative_seconds": f"{total:g}",
            "good_gain": f"{good:.3f}", "good_per_hour": f"{good * 3600.0 / r.seconds:.3f}",
            "p_iou_now": f"{now.p_iou[i]:.3f}" if one else "", "p_iou_expected": f"{p.expected.p_iou[i]:.3f}" if one else "",
            "hdi_now_pct": f"{100 * now.hdi_share[i]:.2f}" if one else "",
            "hdi_expected_pct": f"{100 * p.expected.hdi_share[i]:.2f}" if one else "",
            "gain_pts": f"{p.gain_pct:.3f}", "gain_pts_per_minute": f"{p.gain_per_minute:.4f}", "answer": ""})
    return rows


def write_batch_advice(batch: BatchAdvice, out: str | Path, *, budget_s: float | None = None,
                       lines: str = "keypoints") -> dict[str, Path]:
    """Write the advice files (module docstring) to ``out``; returns their paths by name."""
    from .requests import cvat_requests, label_studio_requests

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plan = batch.plan(budget_s)
    rows = _rows(plan)
    # the crowd's requests (lines and references) go to the labelling tools; a size or a mounting
    # is put into the scene (:mod:`.answers`)
    requested = [(r.objects[0].key, r.objects[0].scene, r.prediction.candidate) for r in plan
                 if r.prediction.candidate.kind in ("dims", "reference")]
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
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=REQUEST_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(paths["requests"], buf.getvalue())
    atomic_write_text(paths["label_studio"], json.dumps(label_studio_requests(requested, lines=lines), indent=1) + "\n")
    atomic_write_text(paths["cvat"], cvat_requests(requested))
    return paths
