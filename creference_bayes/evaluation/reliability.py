"""Is a predicted probability what it says? Reliability tables, the Brier score, and bootstrap
intervals of a mean over clusters (labels of one frame share its camera; designs of one scene its
target).

Used for the labels' quality P(IoU ≥ t) (docs/labels.md) against the IoU each label really
has: among labels with P(IoU ≥ 0.7) ≈ p, a share ≈ p should have IoU ≥ 0.7.
"""

from __future__ import annotations

import numpy as np

__all__ = ["reliability_table", "brier_score", "cluster_bootstrap"]


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


def cluster_bootstrap(values, clusters, *, level: float = 0.95, n_boot: int = 2000,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Percentile bootstrap interval of the mean of each column of ``values``, resampling whole
    clusters (with replacement, as many as there are), so that values that share a cause (the
    objects of one frame share its camera) count as one draw, not as many.

    Parameters
    ----------
    values : (n,) or (n, k) numbers (bools count as 0 and 1)
    clusters : (n,) the cluster of each row (any hashable labels)
    level : the interval's probability, in (0, 1)
    n_boot : bootstrap replicates
    seed : the replicates' seed (the same seed, the same interval)

    Returns
    -------
    (low, high), each of shape (k,) (a float each for 1-d ``values``)
    """
    v = np.asarray(values, float)
    flat = v.ndim == 1
    v = v[:, None] if flat else v
    labels = np.asarray(clusters)
    if v.ndim != 2 or labels.shape != (v.shape[0],) or v.shape[0] == 0:
        raise ValueError(f"values and clusters: expected (n,) or (n, k) values and (n,) clusters with n ≥ 1, "
                         f"got {np.shape(values)} and {labels.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("values: expected finite numbers")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: expected a probability in (0, 1), got {level!r}")
    _, idx = np.unique(labels, return_inverse=True)
    m = int(idx.max()) + 1
    sums = np.stack([np.bincount(idx, weights=col, minlength=m) for col in v.T], axis=1)
    counts = np.bincount(idx, minlength=m).astype(float)
    rng = np.random.default_rng(seed)
    weights = np.stack([np.bincount(rng.integers(m, size=m), minlength=m) for _ in range(int(n_boot))])
    means = (weights @ sums) / (weights @ counts)[:, None]
    tail = 50.0 * (1.0 - level)
    low, high = np.percentile(means, [tail, 100.0 - tail], axis=0)
    return (float(low[0]), float(high[0])) if flat else (low, high)
