"""Label quality from posterior draws: 3D IoU of boxes that stand on the ground, the probability
that an exported box overlaps the true one enough, and reliability tables (docs/labels.md).

A box is (x, y, z, yaw, length, width, height) in the gravity-aligned frame G: bottom centre
(x, y, z) metres, y down, yaw about y (radians), so its footprint is a rotated rectangle in the
(x, z) ground plane and its vertical extent [y − height, y]. Its 3D IoU with another such box is
the footprints' intersection area (shapely) times the height overlap, over the union volume.

If the posterior is calibrated, the true box is like one more draw, so the share of draws whose
IoU with the exported box is ≥ t is the probability that the exported box's true IoU is ≥ t:
:func:`label_quality` computes it; :func:`reliability_table` checks it against ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SHAPELY_INSTALL_HINT", "IOU_THRESHOLDS", "footprints", "box_iou_3d", "LabelQuality",
           "label_quality", "reliability_table"]

SHAPELY_INSTALL_HINT = "label geometry needs shapely: pip install 'shapely>=2'"
#: The IoU thresholds of the label quality (KITTI's moderate car threshold is 0.7, 0.5 for others).
IOU_THRESHOLDS = (0.5, 0.7)


def _shapely():
    try:
        import shapely
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise ImportError(SHAPELY_INSTALL_HINT) from exc
    return shapely


def footprints(boxes: np.ndarray) -> np.ndarray:
    """Ground-plane corners (x, z) of boxes, shape (n, 4, 2), metres, counter-clockwise.

    Parameters
    ----------
    boxes : (n, 7) x, y, z, yaw, length, width, height
    """
    b = np.atleast_2d(np.asarray(boxes, float))
    c, s = np.cos(b[:, 3]), np.sin(b[:, 3])
    # object x axis in G's (x, z) is (cos, −sin), object z axis (sin, cos): Ry(yaw) of core.geometry
    ax = np.stack([c, -s], axis=-1) * (b[:, 4:5] / 2)
    az = np.stack([s, c], axis=-1) * (b[:, 5:6] / 2)
    centre = b[:, [0, 2]]
    return np.stack([centre - ax - az, centre + ax - az, centre + ax + az, centre - ax + az], axis=1)


def box_iou_3d(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """3D IoU of one box with each of ``boxes``.

    Parameters
    ----------
    box : (7,) x, y, z, yaw, length, width, height (metres, radians)
    boxes : (n, 7) the same

    Returns
    -------
    (n,) IoU in [0, 1]
    """
    shapely = _shapely()
    box = np.asarray(box, float).reshape(7)
    boxes = np.atleast_2d(np.asarray(boxes, float))
    a = shapely.polygons(footprints(box[None])[0])
    polys = shapely.polygons(footprints(boxes))
    inter_area = shapely.area(shapely.intersection(a, polys))
    top_a, top_b = box[1] - box[6], boxes[:, 1] - boxes[:, 6]
    overlap_h = np.clip(np.minimum(box[1], boxes[:, 1]) - np.maximum(top_a, top_b), 0.0, None)
    inter = inter_area * overlap_h
    vol_a, vol_b = np.prod(box[4:7]), np.prod(boxes[:, 4:7], axis=1)
    return np.clip(inter / (vol_a + vol_b - inter), 0.0, 1.0)


@dataclass(frozen=True)
class LabelQuality:
    """How well the exported box can be trusted.

    Attributes
    ----------
    p_iou : threshold → posterior probability that the exported box's 3D IoU with the true box
        is ≥ the threshold (the share of draws)
    iou_mean, iou_median : of the exported box with the draws
    n_draws : draws used
    """

    p_iou: dict[float, float]
    iou_mean: float
    iou_median: float
    n_draws: int

    def to_dict(self) -> dict:
        return {**{f"p_iou_ge_{t:g}": p for t, p in self.p_iou.items()},
                "iou_mean": self.iou_mean, "iou_median": self.iou_median, "n_draws": self.n_draws}


def label_quality(exported: np.ndarray, draws: np.ndarray, thresholds=IOU_THRESHOLDS) -> LabelQuality:
    """Quality of the box ``exported`` (7,) given posterior ``draws`` (n, 7) of the box."""
    iou = box_iou_3d(exported, draws)
    if iou.size == 0:
        raise ValueError("draws: expected at least one posterior draw, got none")
    return LabelQuality(p_iou={float(t): float(np.mean(iou >= t)) for t in thresholds},
                        iou_mean=float(iou.mean()), iou_median=float(np.median(iou)), n_draws=int(iou.size))


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
    p = np.asarray(predicted, float)
    y = np.asarray(observed, bool)
    if p.shape != y.shape or p.ndim != 1:
        raise ValueError(f"predicted and observed: expected two (n,) arrays, got {p.shape} and {y.shape}")
    if np.any((p < 0) | (p > 1) | ~np.isfinite(p)):
        raise ValueError("predicted: expected probabilities in [0, 1]")
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
