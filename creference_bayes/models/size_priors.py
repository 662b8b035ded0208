"""Priors on an object's size from its class: log-normal length, width and height.

When a target's dimensions are not known, its class says roughly how big it is: ``log L``,
``log W`` and ``log H`` are independent normals around the class's typical size. The shipped
classes are KITTI's (:data:`KITTI_SIZE_PRIORS`, sources below); a scene (its ``classes`` block) or
a file given on the command line may add classes or replace these.

Sources of the shipped numbers
    Medians: the mean dimensions of each class over KITTI's 7481 training frames, as published
    with Frustum PointNets (Qi et al., CVPR 2018, ``g_type_mean_size``; the same figures are used by
    most monocular detectors). Spreads (standard deviations of log-size): Car from the published
    training-set standard deviations (0.43, 0.10, 0.14 m), the other classes from the per-class
    spread of 51 public KITTI training frames (000000–000050), widened where that sample is small
    (fewer than 10 objects) so that the prior is not surer than the data behind it. docs/overview.md
    lists them.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass

import numpy as np

__all__ = ["SizePrior", "KITTI_SIZE_PRIORS", "size_priors_from_dict", "SIZE_KEYS"]

#: The order of sizes everywhere: length, width, height (metres).
SIZE_KEYS = ("length", "width", "height")


@dataclass(frozen=True)
class SizePrior:
    """Independent log-normal priors on (length, width, height).

    Attributes
    ----------
    median_m : (3,) median length, width and height, metres
    log_sd : (3,) standard deviations of their logarithms (0.1 ≈ ±10 %)
    source : where the numbers come from, for the report
    """

    median_m: tuple[float, float, float]
    log_sd: tuple[float, float, float]
    source: str = "kitti"

    def __post_init__(self):
        med = tuple(float(v) for v in self.median_m)
        sd = tuple(float(v) for v in self.log_sd)
        for name, values in (("median_m", med), ("log_sd", sd)):
            if len(values) != 3:
                raise ValueError(f"size prior {name}: expected 3 values (length, width, height), got {values!r}")
            for key, v in zip(SIZE_KEYS, values):
                if not (math.isfinite(v) and v > 0):
                    raise ValueError(f"size prior {name}.{key}: expected a finite number > 0, got {v!r}")
        object.__setattr__(self, "median_m", med)
        object.__setattr__(self, "log_sd", sd)

    @property
    def log_median(self) -> np.ndarray:
        return np.log(np.asarray(self.median_m))

    def to_dict(self) -> dict:
        return {**{f"{k}_m": v for k, v in zip(SIZE_KEYS, self.median_m)},
                "log_sd": list(self.log_sd), "source": self.source}


def _kitti(l, w, h, sl, sw, sh) -> SizePrior:
    return SizePrior((l, w, h), (sl, sw, sh), "kitti")


#: KITTI's classes (module docstring for the sources). Medians (m): length, width, height.
KITTI_SIZE_PRIORS: dict[str, SizePrior] = {
    "Car": _kitti(3.883, 1.629, 1.526, 0.11, 0.06, 0.09),
    "Van": _kitti(5.068, 1.901, 2.205, 0.15, 0.10, 0.14),
    "Truck": _kitti(10.136, 2.585, 3.252, 0.40, 0.10, 0.18),
    "Pedestrian": _kitti(0.844, 0.661, 1.763, 0.27, 0.25, 0.07),
    "Person_sitting": _kitti(0.801, 0.598, 1.275, 0.30, 0.30, 0.15),
    "Cyclist": _kitti(1.763, 0.597, 1.737, 0.15, 0.20, 0.07),
    "Tram": _kitti(16.172, 2.532, 3.531, 0.35, 0.08, 0.08),
    "Misc": _kitti(3.643, 1.543, 1.923, 0.50, 0.40, 0.40),
}


def _positive_number(v) -> bool:
    """A finite number > 0 (an integer too large for a float is not: it would overflow)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v) and v > 0
    except OverflowError:
        return False


def size_priors_from_dict(data, path: str = "classes", source: str = "scene") -> dict[str, SizePrior]:
    """Classes from a ``{"Name": {"length_m", "width_m", "height_m", "log_sd"}}`` mapping.

    ``log_sd`` is one number or three (length, width, height); it defaults to 0.2. Raises
    ``ValueError`` with the key path (``classes.Kayak.length_m: …``) on bad input.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected an object mapping class names to sizes, got {type(data).__name__}")
    out = {}
    for name, spec in data.items():
        p = f"{path}.{name}"
        if not isinstance(spec, dict):
            raise ValueError(f"{p}: expected an object with length_m, width_m, height_m, got {spec!r}")
        unknown = sorted(set(spec) - {"length_m", "width_m", "height_m", "log_sd", "source"})
        if unknown:
            raise ValueError(f"{p}: unknown key(s) {unknown} (expected length_m, width_m, height_m, log_sd)")
        med = []
        for key in SIZE_KEYS:
            v = spec.get(f"{key}_m")
            if not _positive_number(v):
                raise ValueError(f"{p}.{key}_m: expected a number > 0, got {reprlib.repr(v)}")
            med.append(float(v))
        sd = spec.get("log_sd", 0.2)
        sd = [sd] * 3 if isinstance(sd, (int, float)) and not isinstance(sd, bool) else sd
        if not (isinstance(sd, list) and len(sd) == 3 and all(_positive_number(v) for v in sd)):
            raise ValueError(f"{p}.log_sd: expected a number > 0 or three of them, got {reprlib.repr(spec.get('log_sd'))}")
        out[str(name)] = SizePrior(tuple(med), tuple(float(v) for v in sd), str(spec.get("source", source)))
    return out
