"""The advice for a data set: every object of a batch folder, ranked by the expected gain per
minute of its best next annotation, and the request list for the crowd (docs/advice.md).

Written to ``OUT`` (default ``BATCH_DIR/advice``)::

    advice.json                 every object's advice (creference-advice/1), in ranked order
    requests.csv                one request per object that should get one, best first
    label_studio_requests.json  the requests as Label Studio tasks
    cvat_requests.xml           the requests as CVAT for images 1.1 annotations

One request per object: the best next annotation. After it is collected and the object
re-estimated, the advice is worth recomputing (the best next one may then be another).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path, PurePath

import numpy as np

from ...io.files import atomic_write_json, atomic_write_text
from . import Advice, AdviceSettings
from .inputs import _with_batch_image, advise_result

__all__ = ["REQUEST_COLUMNS", "ObjectAdvice", "BatchAdvice", "object_seed", "advise_batch",
           "request_rows", "write_batch_advice"]

#: Columns of ``requests.csv``. Shares and gains are of the ground distance, percent / points.
REQUEST_COLUMNS = ("rank", "key", "target", "image", "kind", "measure", "object", "request",
                   "line_px", "seconds", "cumulative_seconds", "hdi_now_pct", "hdi_expected_pct",
                   "gain_pts", "gain_pts_per_minute", "p_iou_now", "p_iou_expected")


@dataclass(frozen=True)
class ObjectAdvice:
    """One object of the batch: its key, image name, scene and advice."""

    key: str
    image: str
    scene: object
    advice: Advice

    @property
    def score(self) -> float:
        """The best expected gain per minute (−∞ when nothing can be simulated)."""
        best = self.advice.best
        return best.gain_per_minute if best is not None else -np.inf


@dataclass(frozen=True)
class BatchAdvice:
    """Objects in ranked order (requests first), and the results that could not be advised on."""

    objects: tuple[ObjectAdvice, ...]
    skipped: tuple[dict, ...] = ()

    @property
    def requests(self) -> tuple[ObjectAdvice, ...]:
        return tuple(o for o in self.objects if o.advice.action == "collect")


def object_seed(seed: int, key: str) -> list[int]:
    """A per-object seed from the base seed and the object's key (independent of order)."""
    return [int(seed), int.from_bytes(hashlib.sha256(key.encode("utf-8")).digest()[:8], "little")]


def _image_name(scene, key: str) -> str:
    return PurePath(str(scene.image_path)).name if scene.image_path is not None else PurePath(key).name


def _advise_one(result: dict, scene, seed, settings):
    """One object (run in a worker process with ``workers`` > 1): its Advice, or the reason it
    cannot be advised on."""
    try:
        return advise_result(result, scene, seed=seed, settings=settings)
    except ValueError as exc:
        return " ".join(str(exc).split())


def advise_batch(batch_dir: str | Path, *, seed: int = 0, settings: AdviceSettings | None = None,
                 workers: int = 1, progress: bool = False) -> BatchAdvice:
    """The advice for every result of a ``creference batch`` folder with posterior draws.

    Results without draws, whose scene copy changed, or of another model are listed in
    ``skipped`` with the reason. With ``workers`` > 1 the objects are advised on in that many
    local processes; each object's seed derives from ``seed`` and its key
    (:func:`object_seed`), so the numbers do not depend on ``workers``.
    """
    from ...inference.progress import progress_bar
    from ..labels import load_batch

    inputs, skipped = load_batch(batch_dir)
    skipped = list(skipped)
    scenes = {inp.key: _with_batch_image(inp.scene, inp.result) for inp in inputs}
    jobs = [(inp.result, scenes[inp.key], object_seed(seed, inp.key), settings) for inp in inputs]
    with progress_bar(progress, len(inputs), desc="advice", unit="object") as bar:
        if workers > 1 and len(jobs) > 1:
            from concurrent.futures import as_completed

            from ..batch.engines import LocalEngine

            with LocalEngine(workers) as engine:
                futures = {engine.executor.submit(_advise_one, *job): inp.key for job, inp in zip(jobs, inputs)}
                outcome = {}
                for f in as_completed(futures):
                    outcome[futures[f]] = f.result()
                    bar.update(1)
        else:
            outcome = {}
            for job, inp in zip(jobs, inputs):
                outcome[inp.key] = _advise_one(*job)
                bar.update(1)
    objects = []
    for inp in inputs:
        got = outcome[inp.key]
        if isinstance(got, str):
            skipped.append({"key": inp.key, "reason": got})
        else:
            objects.append(ObjectAdvice(inp.key, _image_name(scenes[inp.key], inp.key), scenes[inp.key], got))
    objects.sort(key=lambda o: (o.advice.action != "collect", -o.score, o.key))
    return BatchAdvice(tuple(objects), tuple(skipped))


def request_rows(batch: BatchAdvice, budget_s: float | None = None) -> list[dict]:
    """The rows of ``requests.csv``: the requests in ranked order, while their cumulative human
    time stays within ``budget_s`` (all of them without a budget)."""
    rows, total = [], 0.0
    for o in batch.requests:
        p, now = o.advice.best, o.advice.now
        c = p.candidate
        if budget_s is not None and total + c.seconds > budget_s:
            break
        total += c.seconds
        rows.append({
            "rank": len(rows) + 1, "key": o.key, "target": o.advice.target, "image": o.image,
            "kind": c.kind, "measure": c.measure or "", "object": c.object or "", "request": c.description,
            "line_px": "" if c.line is None else ";".join(f"{u:.2f},{v:.2f}" for u, v in c.line),
            "seconds": f"{c.seconds:g}", "cumulative_seconds": f"{total:g}",
            "hdi_now_pct": f"{100 * now.hdi_share:.2f}", "hdi_expected_pct": f"{100 * p.expected.hdi_share:.2f}",
            "gain_pts": f"{p.gain_pct:.3f}", "gain_pts_per_minute": f"{p.gain_per_minute:.4f}",
            "p_iou_now": f"{now.p_iou:.3f}", "p_iou_expected": f"{p.expected.p_iou:.3f}"})
    return rows


def write_batch_advice(batch: BatchAdvice, out: str | Path, *, budget_s: float | None = None,
                       lines: str = "keypoints") -> dict[str, Path]:
    """Write the advice files (module docstring) to ``out``; returns their paths by name."""
    from .requests import cvat_requests, label_studio_requests

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = request_rows(batch, budget_s)
    chosen = {r["key"] for r in rows}
    requested = [o for o in batch.requests if o.key in chosen]
    paths = {"advice": out / "advice.json", "requests": out / "requests.csv",
             "label_studio": out / "label_studio_requests.json", "cvat": out / "cvat_requests.xml"}
    atomic_write_json(paths["advice"], {
        "format": "creference-batch-advice/1", "budget_s": budget_s,
        "objects": [{"key": o.key, "image": o.image, **o.advice.to_dict()} for o in batch.objects],
        "skipped": list(batch.skipped)})
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=REQUEST_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_text(paths["requests"], buf.getvalue())
    atomic_write_text(paths["label_studio"], json.dumps(
        label_studio_requests([(o.key, o.scene, o.advice.best.candidate) for o in requested], lines=lines),
        indent=1) + "\n")
    atomic_write_text(paths["cvat"], cvat_requests([(o.key, o.scene, o.advice.best.candidate) for o in requested]))
    return paths
