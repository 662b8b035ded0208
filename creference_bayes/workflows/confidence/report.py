"""How well workers' stated confidences hold up: reliability, interval scores, a per-worker view.

From ranges with a known truth (:mod:`creference_bayes.workflows.confidence.data`):

- **reliability**: per stated level, the share of ranges that hold their truth (the realised
  coverage), with a 95 % Wilson interval. A calibrated crowd lies on the diagonal; below it,
  over-confident;
- **interval scores** (Gneiting & Raftery 2007) in log-length, so that a hydrant and a 40 m
  distance count alike: for a range [l, u] stated at confidence c, the truth x and α = 1 − c,
  (log u − log l) + (2/α)(log l − log x)·1{x < l} + (2/α)(log x − log u)·1{x > u}; lower is
  better. By level, by measure and mode, and overall; with a map, also for the *recalibrated*
  range (the same centre, its half-width times q_D((1 + c)/2) / q_D((1 + g(c))/2): the range
  that would hold the truth c of the time if the map is right);
- **workers**: per worker with at least ``min_answers`` ranges, their mean stated confidence,
  realised coverage (Wilson interval) and mean interval score.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.stats import binomtest

from ...core.metrics import interval_score
from ...models.confidence_map import ConfidenceMap, interval_quantile
from .fit import assign_levels

__all__ = ["ReliabilityRow", "ScoreRow", "WorkerRow", "ConfidenceReport", "confidence_report",
           "range_scores", "markdown_report"]


@dataclass(frozen=True)
class ReliabilityRow:
    """One stated level: ``n`` ranges, ``covered`` of them hold the truth, ``coverage`` = covered/n
    with its 95 % Wilson interval ``low``–``high``."""

    level: float
    n: int
    covered: int
    coverage: float
    low: float
    high: float


@dataclass(frozen=True)
class ScoreRow:
    """Interval scores of one slice (``by``: ``level``, ``group`` or ``all``; ``key`` its value):
    mean stated confidence, realised coverage, mean and median score of the stated ranges, and of
    the recalibrated ranges when a map is given."""

    by: str
    key: str
    n: int
    stated: float
    coverage: float
    score_mean: float
    score_median: float
    recal_coverage: float | None = None
    recal_score_mean: float | None = None


@dataclass(frozen=True)
class WorkerRow:
    """One worker: ``n`` ranges, mean stated confidence, realised coverage (Wilson interval), mean score."""

    worker: str
    n: int
    stated: float
    coverage: float
    low: float
    high: float
    score_mean: float


@dataclass(frozen=True)
class ConfidenceReport:
    """Everything ``creference confidence report`` shows (module docstring)."""

    reliability: tuple[ReliabilityRow, ...]
    scores: tuple[ScoreRow, ...]
    workers: tuple[WorkerRow, ...]
    counts: dict
    map_label: str | None = None

    def to_dict(self) -> dict:
        return {"format": "creference-confidence-report/1", "counts": self.counts, "map": self.map_label,
                **{k: [asdict(r) for r in getattr(self, k)] for k in ("reliability", "scores", "workers")}}


def _wilson(k: int, n: int) -> tuple[float, float]:
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


def _recalibrated(ranges, cmap: ConfidenceMap) -> tuple[np.ndarray, np.ndarray]:
    """Log bounds of the recalibrated ranges (module docstring)."""
    m = np.array([r.centre for r in ranges])
    w = np.array([r.half_width for r in ranges])
    c = np.array([r.confidence for r in ranges])
    g = np.array([float(cmap.coverage(r.confidence, r.measure, r.mode)) for r in ranges])
    c = np.clip(c, 0.01, 0.999)
    w2 = w * interval_quantile(c, cmap.dof) / interval_quantile(g, cmap.dof)
    return m - w2, m + w2


def range_scores(ranges) -> np.ndarray:
    """(n,) interval scores of stated ranges with a truth, in log-length (α = 1 − c, c kept
    within [0.01, 0.999] so that a stated 0 % or 100 % scores finitely)."""
    alpha = 1.0 - np.clip([r.confidence for r in ranges], 0.01, 0.999)
    return interval_score(np.log([r.low for r in ranges]), np.log([r.high for r in ranges]),
                          np.log([r.truth for r in ranges]), alpha)


def confidence_report(ranges, counts: dict, *, cmap: ConfidenceMap | None = None, min_answers: int = 5,
                      map_label: str | None = None) -> ConfidenceReport:
    """The report of ``ranges`` (those with a truth are used).

    Parameters
    ----------
    ranges : :class:`~creference_bayes.workflows.confidence.data.StatedRange`
    counts : what the data set holds (:func:`~creference_bayes.workflows.confidence.data.range_counts`), kept in the report
    cmap : a map to recalibrate the ranges with, or None
    min_answers : workers with fewer ranges are not listed
    map_label : how to name the map in the tables
    """
    ranges = [r for r in ranges if r.truth is not None]
    if not ranges:
        raise ValueError("no range with a stated confidence has a known truth: nothing to report")
    conf = np.array([r.confidence for r in ranges])
    covered = np.array([r.covered for r in ranges])
    scores = range_scores(ranges)
    recal = None
    if cmap is not None:
        lo, hi = _recalibrated(ranges, cmap)
        x = np.log([r.truth for r in ranges])
        recal = ((lo <= x) & (x <= hi), interval_score(lo, hi, x, 1.0 - np.clip(conf, 0.01, 0.999)))
    levels, idx = assign_levels(conf)
    rel = []
    for k, lv in enumerate(levels):
        m = idx == k
        n, kk = int(m.sum()), int(covered[m].sum())
        rel.append(ReliabilityRow(float(lv), n, kk, kk / n, *_wilson(kk, n)))
    slices = [("level", f"{lv:.3g}", idx == k) for k, lv in enumerate(levels)]
    slices += [("group", g, np.array([r.group == g for r in ranges])) for g in sorted({r.group for r in ranges})]
    slices.append(("all", "all", np.ones(len(ranges), bool)))
    rows = []
    for by, key, m in slices:
        extra = {} if recal is None else {"recal_coverage": float(recal[0][m].mean()),
                                          "recal_score_mean": float(recal[1][m].mean())}
        rows.append(ScoreRow(by, key, int(m.sum()), float(conf[m].mean()), float(covered[m].mean()),
                             float(scores[m].mean()), float(np.median(scores[m])), **extra))
    workers = []
    names = np.array([r.worker or "" for r in ranges])
    for w in sorted(set(names) - {""}):
        m = names == w
        n, kk = int(m.sum()), int(covered[m].sum())
        if n >= min_answers:
            workers.append(WorkerRow(w, n, float(conf[m].mean()), kk / n, *_wilson(kk, n), float(scores[m].mean())))
    counts = {**counts, "ranges_with_truth": len(ranges),
              "truth": sorted({r.truth_source for r in ranges})}
    return ConfidenceReport(tuple(rel), tuple(rows), tuple(workers), counts, map_label)


def _f(x, d=3) -> str:
    return "" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}f}"


def markdown_report(rep: ConfidenceReport, figures: list[str] = ()) -> str:
    """The report as Markdown (tables and the figures' file names)."""
    c = rep.counts
    out = ["# Stated confidence against realised coverage", "",
           f"{c.get('scenes', 0)} scenes, {c.get('references', 0)} references: {c['ranges_with_truth']} ranges "
           f"with a confidence and a known truth ({', '.join(c['truth'])}); "
           f"{c.get('values_with_confidence', 0)} single values with a confidence (not scored: no interval); "
           f"{c.get('without_confidence', 0)} references without a confidence.", ""]
    out += [f"![{f}]({f})" for f in figures] + ([""] if figures else [])
    out += ["## Reliability", "", "| stated | n | covered | realised coverage | 95 % interval |", "|---|---|---|---|---|"]
    out += [f"| {r.level:.3g} | {r.n} | {r.covered} | {r.coverage:.3f} | {r.low:.3f}–{r.high:.3f} |"
            for r in rep.reliability]
    recal = rep.map_label is not None
    head = "| by | slice | n | mean stated | coverage | mean score | median score |"
    if recal:
        head += f" coverage, recalibrated ({rep.map_label}) | mean score, recalibrated |"
    out += ["", "## Interval scores (log-length; lower is better)", "", head,
            "|" + "---|" * (head.count("|") - 1)]
    for r in rep.scores:
        line = (f"| {r.by} | {r.key} | {r.n} | {r.stated:.3f} | {r.coverage:.3f} | {r.score_mean:.3f} | "
                f"{r.score_median:.3f} |")
        if recal:
            line += f" {_f(r.recal_coverage)} | {_f(r.recal_score_mean)} |"
        out.append(line)
    out += ["", "## Workers", ""]
    if rep.workers:
        out += ["| worker | n | mean stated | coverage | 95 % interval | mean score |", "|---|---|---|---|---|---|"]
        out += [f"| {w.worker} | {w.n} | {w.stated:.3f} | {w.coverage:.3f} | {w.low:.3f}–{w.high:.3f} | "
                f"{w.score_mean:.3f} |" for w in rep.workers]
    else:
        out.append("No worker answered often enough to be shown on their own.")
    return "\n".join(out) + "\n"
