"""Is a predicted probability what it says? Reliability tables and the Brier score.

Used for the labels' quality P(IoU ≥ t) (docs/labels.md) against the IoU each label really
has: among labels with P(IoU ≥ 0.7) ≈ p, a share ≈ p should have IoU ≥ 0.7.
"""

from __future__ import annotations

import numpy as np

__all__ = ["reliability_table", "brier_score"]


def _check(predicted, observed) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(predicted, float)
    y = np.asarray(observed, bool)
    if p.shape != y.shape or p.ndim != 1:
        raise ValueError(f"predicted and observed: expected two (n,) arrays, got {p.shape} and {y.shape}")
    if np.any(~np.isfinite(p) | (p < 0) | (p > 1)):
        raise ValueError("predicted: expected probabilities in [0, 1]")
    return p, y


def reliability_table(predicted, observed, n_bins: int = 10) -> list[dict]:
    """Predicted probabilities against observed outcomes, in equal-width bins of [0, 1].

    Parameters
    ----------
    predicted : (n,) probabilities
    observed : (n,) bools (the event happened)
    n_bins : bins; a probability of exactly 1 falls in the last one

    Returns
    -------
    One dict per non-empty bin: ``low``, ``high``, ``count``, ``mean_predicted``,
    ``observed_share`` and ``se`` (the binomial standard error of the share at the mean predicted
    probability: how far the share may stray from it by chance alone when calibrated)
    """
    p, y = _check(predicted, observed)
    idx = np.minimum((p * n_bins).astype(int), n_bins - 1)
    rows = []
    for b in range(n_bins):
        sel = idx == b
        if not sel.any():
            continue
        m = float(p[sel].mean())
        rows.append({"low": b / n_bins, "high": (b + 1) / n_bins, "count": int(sel.sum()),
                     "mean_predicted": m, "observed_share": float(y[sel].mean()),
                     "se": float(np.sqrt(m * (1 - m) / sel.sum()))})
    return rows


def brier_score(predicted, observed) -> float:
    """Mean squared difference between the probabilities and the outcomes (0 or 1); lower is better.

    Parameters
    ----------
    predicted : (n,) probabilities, n ≥ 1
    observed : (n,) bools
    """
    p, y = _check(predicted, observed)
    if p.size == 0:
        raise ValueError("predicted: expected at least one probability, got none")
    return float(np.mean((p - y) ** 2))
