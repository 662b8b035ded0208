"""Independent multiple-try Metropolis (I-MTM): the acceptance step, on NumPy only.

Shared by the block sweeps' independence steps (:class:`.moves.IndependenceSweep`) and the ensemble's
independence move (:class:`.moves.IndependenceMove`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["multiple_try_pick"]


def multiple_try_pick(log_w_tries: np.ndarray, log_w_current: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """One independent multiple-try Metropolis step (I-MTM; Martino 2018, "A review of multiple
    try MCMC algorithms for signal processing", Digital Signal Processing 75, section 4.1).

    Given k tries y₁…y_k drawn independently from a proposal q and the current state x, with
    importance weights w = π / q (``log_w_tries`` (…, k), ``log_w_current`` (…)), pick try j with
    probability w(y_j) / Σ w and accept it with probability
    min(1, Σⱼ w(yⱼ) / (Σⱼ w(yⱼ) − w(y_picked) + w(x))). The chain keeps π invariant; with k = 1
    this is the ordinary independence Metropolis–Hastings step. Tries of zero density (−inf or
    NaN) have zero weight. Returns (picked index (…), accepted (…) bool).
    """
    log_w_tries = np.asarray(log_w_tries, float)
    log_w_tries = np.where(np.isnan(log_w_tries), -np.inf, log_w_tries)
    top = np.max(log_w_tries, axis=-1)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(invalid="ignore", under="ignore", over="ignore"):
        w = np.exp(log_w_tries - top[..., None])
        w_cur = np.exp(np.asarray(log_w_current, float) - top)
    total = w.sum(axis=-1)
    u = rng.uniform(size=total.shape) * total
    j = np.minimum(np.sum(np.cumsum(w, axis=-1) <= u[..., None], axis=-1), w.shape[-1] - 1)
    picked = np.take_along_axis(w, j[..., None], axis=-1)[..., 0]
    with np.errstate(invalid="ignore", over="ignore"):
        ok = (total > 0) & (rng.uniform(size=total.shape) * (total - picked + w_cur) < total)
    return j, ok
