"""Figures of a label export (matplotlib, imported with this module only): label quality across
the data set and, with ground truth, reliability diagrams of the quality."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

__all__ = ["quality_figure", "reliability_figure"]


def quality_figure(scores, threshold: float, *, score_label: str = "P(IoU ≥ 0.7)",
                   reliability: dict | None = None, fig: Figure | None = None) -> Figure:
    """Histogram of the labels' quality with the threshold below which objects go back for more
    annotations; one reliability diagram per IoU threshold when ground truth is known.

    Parameters
    ----------
    scores : (n,) the labels' quality (probabilities)
    threshold : the user's minimum quality
    score_label : what the score is
    reliability : IoU threshold → rows of :func:`~creference_bayes.workflows.labels.quality.reliability_table`
    fig : a figure to draw on (default: a new one)
    """
    scores = np.asarray(scores, float)
    panels = 1 + len(reliability or {})
    if fig is None:
        fig = Figure(figsize=(4.2 * panels, 3.6), layout="constrained")
    axes = fig.subplots(1, panels, squeeze=False)[0]
    ax = axes[0]
    ax.hist(scores, bins=np.linspace(0, 1, 21), color="#1f77b4", edgecolor="white")
    ax.axvline(threshold, color="#d62728", ls="--",
               label=f"minimum {threshold:g}: {int(np.sum(scores < threshold))} of {scores.size} below")
    ax.set(xlabel=f"label quality {score_label}", ylabel="objects", xlim=(0, 1))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts
    ax.legend(loc="upper left", fontsize="small")
    for ax, (t, rows) in zip(axes[1:], (reliability or {}).items()):
        _reliability_panel(ax, t, rows)
    return fig


def _reliability_panel(ax, t: float, rows: list[dict], title: str | None = None) -> None:
    """Observed share against mean predicted P(IoU ≥ t) per bin, with the ±2 se band of a
    calibrated forecast; each bin's count is written above the panel, at the bin's centre (on a
    secondary axis, where it overlaps neither the data nor the tick labels)."""
    pred, obs, se = (np.array([r[k] for r in rows]) for k in ("mean_predicted", "observed_share", "se"))
    ax.plot([0, 1], [0, 1], color="grey", lw=1, label="calibrated")
    yerr = np.vstack([np.minimum(2 * se, pred), np.minimum(2 * se, 1 - pred)])  # within [0, 1]
    ax.errorbar(pred, pred, yerr=yerr, fmt="none", ecolor="grey", capsize=3,
                label="±2 se if calibrated")
    ax.plot(pred, obs, "o-", color="#d62728", label="observed", clip_on=False, zorder=3)
    ax.set(xlim=(0, 1), ylim=(0, 1))
    counts = ax.secondary_xaxis("top")
    centres = [(r["low"] + r["high"]) / 2 for r in rows]
    counts.set_xticks(centres, [str(r["count"]) for r in rows])
    narrow = min((r["high"] - r["low"] for r in rows), default=0.1)
    counts.tick_params(length=3, labelsize=7 if narrow >= 0.1 else 6, pad=2.5)
    counts.set_xlabel("labels in each bin", fontsize=7, labelpad=2)
    ax.set(xlabel=f"predicted P(IoU ≥ {t:g})", ylabel=f"share with true IoU ≥ {t:g}")
    if title:
        ax.set_title(title, fontsize="medium")
    ax.legend(loc="best", fontsize="small")


def reliability_figure(reliability: dict, fig: Figure | None = None) -> Figure:
    """One reliability diagram per IoU threshold t: the labels' P(IoU ≥ t) against the IoU they
    have with the reference boxes.

    Parameters
    ----------
    reliability : t → {``rows``: :func:`~creference_bayes.evaluation.reliability.reliability_table`
        rows, ``brier``: the Brier score, ``count``: labels}
    fig : a figure to draw on (default: a new one)
    """
    if not reliability:
        raise ValueError("reliability: expected at least one threshold with labels, got none")
    if fig is None:
        fig = Figure(figsize=(4.2 * len(reliability), 3.8), layout="constrained")
    axes = fig.subplots(1, len(reliability), squeeze=False)[0]
    for ax, (t, r) in zip(axes, reliability.items()):
        _reliability_panel(ax, t, r["rows"], f"{r['count']} labels, Brier score {r['brier']:.3f}")
    return fig
