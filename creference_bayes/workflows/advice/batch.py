"""The advice for a data set: every target of every scene of a batch folder, ranked by the
expected gain per minute of its best next observation, and the request list for the crowd
(docs/advice.md, "A data set").

Written to ``OUT`` (default ``BATCH_DIR/advice``)::

    advice.json                 every scene's advice (creference-advice/2) and the targets' ranking
    requests.csv                one request per target that should get one, best first
    label_studio_requests.json  the requests as Label Studio tasks
    cvat_requests.xml           the requests as CVAT for images 1.1 annotations

A target's request is the best-ranked observation of its scene that is asked on it or on no
target (a reference elsewhere that helps every target), each at most once per scene
(:meth:`~creference_bayes.workflows.advice.Advice.requests`). Targets whose precision target is
met, or whose best gain is below ``min_gain``, get none. After the
requests are collected and the scenes estimated again, the advice is worth recomputing.
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

__all__ = ["REQUEST_COLUMNS", "ObjectAdvice", "BatchAdvice", "object_seed", "advise_batch", "request_rows",
           "write_batch_advice"]

#: Columns of ``requests.csv``. Shares are of the target's ground distance (percent); gains are
#: summed over the scene's targets (points).
REQUEST_COLUMNS = ("rank", "key", "target", "image", "kind", "measure", "object", "request", "line_px", "seconds",
                   "cumulative_seconds", "hdi_now_pct", "hdi_expected_pct", "gain_pts", "gain_pts_per_minute",
                   "p_iou_now", "p_iou_expected")


@dataclass(frozen=True)
class ObjectAdvice:
    """One target of the batch: its scene's key, image name, scene and advice, its index, and its
    request (None when it should get none)."""

    key: str
    image: str
    scene: object
    advice: Advice
    target: int
    request: Prediction | None

    @property
    def score(self) -> float:
        """The request's expected gain per minute (−∞ without one)."""
        return self.request.gain_per_minute if self.request is not None else -np.inf


@dataclass(frozen=True)
class BatchAdvice:
    """Targets in ranked order (requests first), and the results that could not be advised on."""

    objects: tuple[ObjectAdvice, ...]
    skipped: tuple[dict, ...] = ()

    @property
    def requests(self) -> tuple[ObjectAdvice, ...]:
        return tuple(o for o in self.objects if o.request is not None)


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
        return scene, advise_result(result, scene, seed=object_seed(seed, key), settings=settings)
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
        scene, advice = outcome[key]
        objects += [ObjectAdvice(key, image_name(scene, key), scene, advice, i, p)
                    for i, p in enumerate(advice.requests())]
    objects.sort(key=lambda o: (o.request is None, -o.score, o.key, o.target))
    return BatchAdvice(tuple(objects), tuple(skipped))


def request_rows(batch: BatchAdvice, budget_s: float | None = None) -> list[dict]:
    """The rows of ``requests.csv``: the requests in ranked order, while their cumulative human
    time stays within ``budget_s`` (all of them without a budget)."""
    rows, total = [], 0.0
    for o in batch.requests:
        p, now, i = o.request, o.advice.now, o.target
        c = p.candidate
        if budget_s is not None and total + c.seconds > budget_s:
            break
        total += c.seconds
        rows.append({
            "rank": len(rows) + 1, "key": o.key, "target": o.advice.targets[i], "image": o.image, "kind": c.kind,
            "measure": c.measure or "", "object": c.object or "", "request": c.description,
            "line_px": "" if c.line is None else ";".join(f"{u:.2f},{v:.2f}" for u, v in c.line),
            "seconds": f"{c.seconds:g}", "cumulative_seconds": f"{total:g}",
            "hdi_now_pct": f"{100 * now.hdi_share[i]:.2f}", "hdi_expected_pct": f"{100 * p.expected.hdi_share[i]:.2f}",
            "gain_pts": f"{p.gain_pct:.3f}", "gain_pts_per_minute": f"{p.gain_per_minute:.4f}",
            "p_iou_now": f"{now.p_iou[i]:.3f}", "p_iou_expected": f"{p.expected.p_iou[i]:.3f}"})
    return rows


def write_batch_advice(batch: BatchAdvice, out: str | Path, *, budget_s: float | None = None,
                       lines: str = "keypoints") -> dict[str, Path]:
    """Write the advice files (module docstring) to ``out``; returns their paths by name."""
    from .requests import cvat_requests, label_studio_requests

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = request_rows(batch, budget_s)
    chosen = {(r["key"], r["target"]) for r in rows}
    requested = [(o.key, o.scene, o.request.candidate) for o in batch.requests
                 if (o.key, o.advice.targets[o.target]) in chosen]
    paths = {"advice": out / "advice.json", "requests": out / "requests.csv",
             "label_studio": out / "label_studio_requests.json", "cvat": out / "cvat_requests.xml"}
    scenes = {}
    for o in batch.objects:
        scenes.setdefault(o.key, {"key": o.key, "image": o.image, **o.advice.to_dict()})
    atomic_write_json(paths["advice"], {
        "format": "creference-batch-advice/2", "budget_s": budget_s, "scenes": list(scenes.values()),
        "ranking": [{"key": o.key, "target": o.advice.targets[o.target],
                     "request": None if o.request is None else o.request.candidate.key,
                     "gain_pts_per_minute": None if o.request is None else o.request.gain_per_minute}
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
