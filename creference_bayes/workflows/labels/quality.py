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

from ...evaluation.iou3d import SHAPELY_INSTALL_HINT, box_iou_3d, footprints
from ...evaluation.reliability import reliability_table

__all__ = ["SHAPELY_INSTALL_HINT", "IOU_THRESHOLDS", "footprints", "box_iou_3d", "LabelQuality",
           "label_quality", "reliability_table"]

#: The IoU thresholds of the label quality (KITTI's moderate car threshold is 0.7, 0.5 for others).
IOU_THRESHOLDS = (0.5, 0.7)


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
