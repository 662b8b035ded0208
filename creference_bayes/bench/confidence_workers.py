"""Simulated workers who state a range and a confidence, with a known true confidence map.

Each worker w has an own error scale σ_w (the sd of their error in log-length). For a reference of
true length x the worker's best guess is v = x·exp(σ_w ε), ε ~ N(0, 1); they pick a confidence c
from :attr:`ConfidentWorkers.levels` and state the range v·exp(±w) of log half-width

    w = κ · σ_w · z((1 + c)/2) · exp(τ η),      η ~ N(0, 1),

z the standard normal quantile. A worker who knew their own accuracy (τ = 0) and were calibrated
(κ = 1) would state exactly their central c-interval. κ < 1 makes intervals too narrow
(over-confident: with κ = 0.5 a stated 90 % holds the truth about 60 % of the time, as the
literature reports for people's "90 %" intervals), κ > 1 too wide (under-confident); τ is how
well workers know their own accuracy (it spreads the widths and gives the standardised errors
slightly heavier tails than a normal). The range holds the truth when |σ_w ε| < w, so the true map
does not depend on σ_w:

    g(c) = E_η[ 2 Φ(κ z((1 + c)/2) e^{τη}) − 1 ],

computed by Gauss–Hermite quadrature (:meth:`ConfidentWorkers.true_coverage`).

The pool of workers is fixed once (:meth:`ConfidentWorkers.pool`, its own seed) and shared by the
scenes of a data set, so workers answer several times across scenes (the per-worker view of
``creference confidence report``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

__all__ = ["TRUE_MAPS", "STATED_LEVELS", "ConfidentWorkers"]

#: Named true maps: the width factor κ (module docstring).
TRUE_MAPS = {"calibrated": 1.0, "over": 0.5, "under": 1.6}
#: The confidences workers choose from (a slider in steps, as annotation tools offer).
STATED_LEVELS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)


@dataclass(frozen=True)
class ConfidentWorkers:
    """A pool of workers stating ranges with a confidence (module docstring).

    Attributes
    ----------
    ids : (n,) worker ids
    scales : (n,) each worker's error scale σ_w, sd of the log error
    width_factor : κ (1 calibrated, < 1 over-confident, > 1 under-confident)
    width_jitter : τ, the log-sd of a worker's misjudgement of their own accuracy
    levels : the stated confidences, chosen uniformly
    """

    ids: tuple[str, ...]
    scales: tuple[float, ...]
    width_factor: float = TRUE_MAPS["over"]
    width_jitter: float = 0.25
    levels: tuple[float, ...] = STATED_LEVELS

    def __post_init__(self):
        if len(self.ids) != len(self.scales) or not self.ids:
            raise ValueError(f"ids and scales: expected equal, non-zero lengths, got {len(self.ids)} and "
                             f"{len(self.scales)}")
        if not all(math.isfinite(s) and s > 0 for s in self.scales):
            raise ValueError(f"scales: expected numbers > 0, got {self.scales}")
        if not (math.isfinite(self.width_factor) and self.width_factor > 0):
            raise ValueError(f"width_factor: expected a number > 0, got {self.width_factor!r}")
        if not (math.isfinite(self.width_jitter) and self.width_jitter >= 0):
            raise ValueError(f"width_jitter: expected a number >= 0, got {self.width_jitter!r}")
        if not self.levels or not all(0.0 < c < 1.0 for c in self.levels):
            raise ValueError(f"levels: expected confidences in (0, 1), got {self.levels}")

    @classmethod
    def pool(cls, true_map: str | float = "over", *, n_workers: int = 40, scale_median: float = 0.25,
             scale_log_sd: float = 0.5, seed=0, **kw) -> "ConfidentWorkers":
        """``n_workers`` workers with log-normal error scales (median ``scale_median``, log-sd
        ``scale_log_sd``) drawn from ``seed``; ``true_map`` a key of :data:`TRUE_MAPS` or κ;
        ``kw``: ``width_jitter``, ``levels``."""
        if isinstance(true_map, str):
            if true_map not in TRUE_MAPS:
                raise ValueError(f"true map: expected one of {list(TRUE_MAPS)} or a width factor, got {true_map!r}")
            true_map = TRUE_MAPS[true_map]
        if n_workers < 1:
            raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
        rng = np.random.default_rng(seed)
        scales = scale_median * np.exp(scale_log_sd * rng.standard_normal(n_workers))
        return cls(tuple(f"w{i + 1:03d}" for i in range(n_workers)), tuple(float(s) for s in scales),
                   width_factor=float(true_map), **kw)

    def true_coverage(self, c) -> np.ndarray:
        """The true map g(c): how often a range stated at confidence ``c`` holds the truth."""
        c = np.asarray(c, float)
        nodes, weights = np.polynomial.hermite_e.hermegauss(60)  # ∫ f(η) φ(η) dη
        weights = weights / weights.sum()
        half = self.width_factor * ndtri(0.5 * (1.0 + c))[..., None] * np.exp(self.width_jitter * nodes)
        return np.sum((2.0 * ndtr(half) - 1.0) * weights, axis=-1)

    def state(self, rng: np.random.Generator) -> tuple[str, float, float, float]:
        """One statement: (worker id, low factor, high factor, confidence), the range being
        [x·low, x·high] for a true length x."""
        k = int(rng.integers(len(self.ids)))
        c = float(self.levels[rng.integers(len(self.levels))])
        sigma = self.scales[k]
        centre = sigma * rng.standard_normal()
        half = self.width_factor * sigma * float(ndtri(0.5 * (1.0 + c))) * math.exp(
            self.width_jitter * rng.standard_normal())
        return self.ids[k], math.exp(centre - half), math.exp(centre + half), c
