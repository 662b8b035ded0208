"""The paper's error measures (§3.2, docs/paper.md, "Metrics"). All return percentages and broadcast.

Eq. 1  percentage error        |m − GT| / |GT| × 100
Eq. 2  range percentage error  the error of the range's centre (l + u)/2
Eq. 3  location error          ‖m − GT‖₂ / ‖GT‖₂ × 100 for 3D locations
Eq. 4  range precision         (u − l) / ((l + u)/2) × 100
"""

from __future__ import annotations

import numpy as np

__all__ = ["percentage_error", "range_percentage_error", "location_percentage_error", "range_precision",
           "interval_score"]


def _check_gt(gt) -> np.ndarray:
    gt = np.asarray(gt, dtype=float)
    if np.any(gt == 0):
        raise ValueError(f"ground truth must be non-zero for a percentage error, got {gt!r}")
    return gt


def percentage_error(estimate, ground_truth) -> np.ndarray:
    """Eq. 1: |m − GT| / |GT| × 100.

    Parameters
    ----------
    estimate, ground_truth : float or array (broadcast), same unit; GT non-zero

    Returns
    -------
    float array of the broadcast shape, percent
    """
    gt = _check_gt(ground_truth)
    return np.abs(np.asarray(estimate, float) - gt) / np.abs(gt) * 100.0


def range_percentage_error(low, high, ground_truth) -> np.ndarray:
    """Eq. 2: the error of the range's centre, |(l + u)/2 − GT| / |GT| × 100 (percent)."""
    return percentage_error((np.asarray(low, float) + np.asarray(high, float)) / 2.0, ground_truth)


def location_percentage_error(estimate, ground_truth) -> np.ndarray:
    """Eq. 3: ‖m − GT‖₂ / ‖GT‖₂ × 100.

    Parameters
    ----------
    estimate, ground_truth : (..., 3) locations, metres (broadcast over the leading axes)

    Returns
    -------
    (...) percent
    """
    est, gt = np.asarray(estimate, float), np.asarray(ground_truth, float)
    if est.shape[-1:] != (3,) or gt.shape[-1:] != (3,):
        raise ValueError(f"locations must have 3 coordinates, got shapes {est.shape} and {gt.shape}")
    norm = np.linalg.norm(gt, axis=-1)
    if np.any(norm == 0):
        raise ValueError("ground-truth location must be non-zero")
    return np.linalg.norm(est - gt, axis=-1) / norm * 100.0


def range_precision(low, high) -> np.ndarray:
    """Eq. 4: (u − l) / ((l + u)/2) × 100 (percent); the centre must be non-zero."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    centre = (low + high) / 2.0
    if np.any(centre == 0):
        raise ValueError("range centre must be non-zero")
    return (high - low) / centre * 100.0


def interval_score(low, high, truth, alpha) -> np.ndarray:
    """The interval score of a central (1 − α) interval [l, u] for the truth x (Gneiting & Raftery
    2007, Eq. 43; lower is better):

        (u − l) + (2/α)(l − x)·1{x < l} + (2/α)(x − u)·1{x > u},

    in the units of its arguments (pass logs for a score in log-length).

    Parameters
    ----------
    low, high, truth : arrays of one shape (broadcast), low ≤ high
    alpha : 1 − the interval's nominal coverage, in (0, 1)
    """
    low, high, truth = (np.asarray(a, float) for a in (low, high, truth))
    alpha = np.asarray(alpha, float)
    if np.any(~((alpha > 0) & (alpha < 1))):
        raise ValueError(f"alpha: expected values in (0, 1), got {alpha}")
    if np.any(low > high):
        raise ValueError("interval: low > high")
    return ((high - low) + (2.0 / alpha) * np.maximum(low - truth, 0.0)
            + (2.0 / alpha) * np.maximum(truth - high, 0.0))
