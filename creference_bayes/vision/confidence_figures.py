"""Figures of stated confidence (matplotlib, imported with this module only): the reliability
diagram and the per-worker view of ``creference confidence report``."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

__all__ = ["reliability_figure", "workers_figure"]

_COLOURS = ("#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2")


def reliability_figure(rows, maps: dict | None = None, *, true_map=None, fig: Figure | None = None) -> Figure:
    """Stated confidence against realised coverage, with 95 % intervals and the number of ranges
    per level; fitted maps drawn over it with their bands.

    Parameters
    ----------
    rows : :class:`~creference_bayes.workflows.confidence.report.ReliabilityRow` (may be empty when
        only maps are drawn)
    maps : label → :class:`~creference_bayes.models.confidence_map.ConfidenceMap` (pooled curves)
    true_map : optional callable c → g(c), drawn as a dashed line (simulated data)
    fig : a figure to draw on (default: a new one)
    """
    if fig is None:
        fig = Figure(figsize=(5.2, 5.6), layout="constrained")
    ax, axn = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3.2, 1]})
    ax.plot([0, 1], [0, 1], color="grey", lw=1, label="calibrated (g(c) = c)")
    c = np.linspace(0.0, 1.0, 201)
    if true_map is not None:
        ax.plot(c, true_map(c), color="black", ls="--", lw=1.2, label="true map")
    for colour, (label, cmap) in zip(_COLOURS, (maps or {}).items()):
        curve = cmap.pooled
        if curve is None:
            continue
        cc = np.linspace(curve.levels[0], curve.levels[-1], 201)
        lo, hi = curve.band(cc)
        ax.fill_between(cc, lo, hi, color=colour, alpha=0.18, lw=0)
        ax.plot(cc, curve(cc), color=colour, lw=1.6,
                label=f"{label} ({cmap.interval_prob:.0%} band)")
    if rows:
        lv, cov = (np.array([getattr(r, k) for r in rows]) for k in ("level", "coverage"))
        yerr = np.vstack([cov - [r.low for r in rows], [r.high for r in rows] - cov])
        ax.errorbar(lv, cov, yerr=yerr, fmt="o", color="#d62728", capsize=3, ms=5,
                    label="realised coverage (95 % Wilson)")
        axn.bar(lv, [r.n for r in rows], width=0.025, color="#d62728", alpha=0.7)
    ax.set(xlim=(0, 1), ylim=(0, 1), ylabel="share of ranges holding the truth",
           title="reliability of stated ranges")
    ax.legend(loc="upper left", fontsize="small")
    axn.set(xlabel="stated confidence c", ylabel="ranges")
    return fig


def workers_figure(rows, fig: Figure | None = None) -> Figure:
    """Per worker: mean stated confidence against realised coverage (95 % Wilson interval), the
    marker's area growing with the worker's number of ranges.

    Parameters
    ----------
    rows : :class:`~creference_bayes.workflows.confidence.report.WorkerRow`
    fig : a figure to draw on (default: a new one)
    """
    if fig is None:
        fig = Figure(figsize=(5.0, 4.4), layout="constrained")
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1], color="grey", lw=1, label="calibrated")
    if rows:
        s, cov = (np.array([getattr(r, k) for r in rows]) for k in ("stated", "coverage"))
        n = np.array([r.n for r in rows], float)
        ax.errorbar(s, cov, yerr=np.vstack([cov - [r.low for r in rows], [r.high for r in rows] - cov]),
                    fmt="none", ecolor="#bbbbbb", lw=0.8)
        ax.scatter(s, cov, s=12 + 88 * n / n.max(), color="#1f77b4", alpha=0.8, zorder=3,
                   label=f"{len(rows)} workers (area ∝ ranges, up to {int(n.max())})")
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="worker's mean stated confidence",
           ylabel="worker's realised coverage", title="workers")
    ax.legend(loc="upper left", fontsize="small")
    return fig
