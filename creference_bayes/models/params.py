"""The parameter space shared by the models: names, units, box bounds, free/fixed handling.

A *model* is what the optimiser and the sampler see: a vectorised ``cost(params)`` over full
parameter vectors of shape (n, 5), the box :class:`Bounds`, and which parameters are free (µ is
fixed when the scene gives the focal length).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PARAM_NAMES", "PARAM_UNITS", "YAW", "FOCAL", "Bounds", "FreeParameters", "wrap_angle"]

#: Order of the parameter vector.
PARAM_NAMES = ("x", "y", "z", "yaw", "focal_length_px")
PARAM_UNITS = ("m", "m", "m", "rad", "px")
YAW = 3
FOCAL = 4


def wrap_angle(theta):
    """Wrap radians to [−π, π)."""
    return (np.asarray(theta) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Bounds:
    """Box bounds on (x, y, z, yaw, µ): metres, metres, metres, radians, pixels.

    The posterior's prior is uniform inside them (yaw is circular and is never bounded there).
    """

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if lo.shape != (5,) or hi.shape != (5,):
            raise ValueError(f"Bounds: expected 5 lower and 5 upper values, got {lo.shape} and {hi.shape}")
        bad = np.flatnonzero(~(lo <= hi))
        if bad.size:
            i = bad[0]
            raise ValueError(f"Bounds.{PARAM_NAMES[i]}: lower {lo[i]!r} > upper {hi[i]!r}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @classmethod
    def paper_controlled(cls) -> "Bounds":
        """The controlled study's bounds (paper §6.1)."""
        return cls(np.array([-10, -10, 1, -np.pi, 100.0]), np.array([10, 10, 100, np.pi, 2000.0]))

    @classmethod
    def paper_system(cls) -> "Bounds":
        """The system study's bounds (paper §7.1)."""
        return cls(np.array([-10, -5, 1, -np.pi, 100.0]), np.array([10, 5, 50, np.pi, 3000.0]))

    @classmethod
    def default(cls, image_width: int, image_height: int) -> "Bounds":
        """Wide bounds for any scene: |x| ≤ 500 m, |y| ≤ 50 m, 0.1 ≤ z ≤ 1000 m, µ within
        0.1–10 × the image's larger side (fields of view from about 6° to 170°)."""
        m = float(max(image_width, image_height))
        return cls(np.array([-500, -50, 0.1, -np.pi, 0.1 * m]), np.array([500, 50, 1000, np.pi, 10 * m]))

    def with_fixed(self, index: int, value: float) -> "Bounds":
        lo, hi = self.lower.copy(), self.upper.copy()
        lo[index] = hi[index] = value
        return Bounds(lo, hi)

    def contains(self, params: np.ndarray) -> np.ndarray:
        """(n,) bool: inside the bounds, yaw ignored (circular)."""
        p = np.atleast_2d(params)
        keep = np.ones(5, bool)
        keep[YAW] = False
        return np.all((p[:, keep] >= self.lower[keep]) & (p[:, keep] <= self.upper[keep]), axis=1)


class FreeParameters:
    """Free/fixed parameter handling shared by the models, for the optimiser and the sampler.

    Needs ``bounds`` (:class:`Bounds`) and ``free`` ((5,) bool: lower < upper).
    """

    bounds: Bounds
    free: np.ndarray

    @property
    def fixed_values(self) -> np.ndarray:
        """(5,) the full vector's values where not free (µ when known); NaN elsewhere."""
        return np.where(self.free, np.nan, self.bounds.lower)

    def expand(self, free_params: np.ndarray) -> np.ndarray:
        """(n, n_free) free parameters → (n, 5) full vectors."""
        free_params = np.atleast_2d(free_params)
        full = np.tile(self.bounds.lower, (len(free_params), 1))
        full[:, self.free] = free_params
        return full
