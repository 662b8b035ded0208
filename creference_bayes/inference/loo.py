"""Leave-one-out weights for posterior draws: Pareto-smoothed importance sampling (arviz adapter).

Draws from p(θ | all data) become draws from p(θ | all data but one observation) when weighted by
1 / p(y_j | θ, …): the log ratio is −(the observation's log-likelihood term). Pareto smoothing
(Vehtari et al. 2024) stabilises the largest weights, and its shape k̂ says whether the weights
can be trusted (k̂ > 0.7: no; refit without the observation instead).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["PARETO_K_MAX", "psis_weights"]

#: Above this Pareto shape the smoothed weights are unreliable (Vehtari et al. 2024).
PARETO_K_MAX = 0.7


def psis_weights(log_ratios: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised Pareto-smoothed importance weights and their Pareto shapes.

    Parameters
    ----------
    log_ratios : (n_obs, n_draws) log importance ratios (for leave-one-out: minus each
        observation's log-likelihood term at each draw)

    Returns
    -------
    weights : (n_obs, n_draws), each row summing to 1
    k : (n_obs,) Pareto shape estimates
    """
    import arviz as az

    lr = np.atleast_2d(np.asarray(log_ratios, float))
    if not np.all(np.isfinite(lr)):
        raise ValueError("log_ratios: expected finite numbers")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # arviz warns about k̂ itself; the caller decides
        lw, k = az.psislw(lr.copy(), reff=1.0)
    lw = np.asarray(lw, float)
    w = np.exp(lw - lw.max(axis=1, keepdims=True))
    return w / w.sum(axis=1, keepdims=True), np.atleast_1d(np.asarray(k, float))
