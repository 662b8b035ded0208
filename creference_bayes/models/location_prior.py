"""The prior on the target's location on the ground, and the coordinates the MAP is taken in.

Why not flat (method.md, "The location prior: uniform in log depth")
    One set of dimension lines of a far target leaves a *ridge*: (z, µ) → (λz, λµ) at the same x
    and camera height changes the image only through perspective, so the annotations pin µ/z, x
    and y but hardly λ. In the sampler's coordinates (logarithms of z and µ) the posterior's weight
    at scale λ is the prior's density times the Jacobian z·µ: a prior flat in (x, z) gives a weight
    growing like λ that runs to the far bound, and p(x, z) ∝ 1/d² leans near. The prior neutral
    to the ridge's symmetry is uniform in log z at each lateral offset,

        p(x, z) ∝ 1/z        (``log-depth``),

    under which the focal-length prior (and what perspective says) decides where on the ridge
    the target is. It is proper within the bounds (z from 0.1 to 1000 m).

The MAP in the same coordinates
    A density's maximum moves with the coordinates, so the MAP is taken in the logarithms of the
    positive parameters (y, z, µ) the sampler works in (:meth:`LocationPrior.map_in_log_coordinates`):
    the MAP is then the mode of the density that is sampled.

``flat``: a flat prior in (x, z) and the MAP in the parameters themselves (the paper's presets:
the paper's method has no prior). ``inverse-square``, p(x, z) ∝ 1/d² with the MAP in log
coordinates, is there for comparison.

A distance range (``distance_m``)
    What a data set knows and one photo does not: where its targets stand (a street camera's
    objects between 3 and 80 m, a room's within 10 m). Inside the range the prior is the kind's;
    outside, it falls as a half-normal in the log of the ground distance d = √(x² + z²), of sd
    :data:`RANGE_SOFTNESS` (a soft edge: a stated range is approximate, and a sampler must not
    meet a wall).

A fitted population (``population``)
    What a data set learns of where its targets stand (``creference batch``'s data-set layer,
    workflows/batch/dataset.py): a log-normal factor in the ground distance d, median
    ``population[0]`` m and log-sd ``population[1]``, on the kind's own density,

        p(x, z) ∝ N(log d; log median, log_sd²) · p_kind(x, z)      (log-depth: / z),

    so that a wide population is the kind's prior again (under 1/d², the area element's, a wide
    population leaned near as the inverse-square prior does: on thin outdoor designs the
    population came 0.15 too near in log distance, docs/studies/method.md). The data set reads
    each target's evidence on log d relative to the kind's density (its draws weighted by
    p_kind / p, the prior it was estimated under: :meth:`relative_log_prior`), so this is the
    prior those readings combine under.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LOCATION_PRIORS", "DEFAULT_LOCATION_PRIOR", "LocationPrior"]

#: The location priors: ``log-depth`` (p(x, z) ∝ 1/z, the MAP in log coordinates), ``flat`` and,
#: for comparison, ``inverse-square`` (p(x, z) ∝ 1/d², d = √(x² + z²), the MAP in log coordinates).
LOCATION_PRIORS = ("log-depth", "flat", "inverse-square")
DEFAULT_LOCATION_PRIOR = "log-depth"
#: How softly a distance range's edges fall: the sd of the half-normal in log distance outside it
#: (0.05: 5 % beyond an edge costs half a nat)
RANGE_SOFTNESS = 0.05


@dataclass(frozen=True)
class LocationPrior:
    """The prior on the target's ground position (x, z), metres (module docstring).

    Attributes
    ----------
    kind : one of :data:`LOCATION_PRIORS`
    distance_m : (low, high) the range of ground distances, metres, the targets stand in, or None
        (module docstring)
    population : (median m, log-sd) of a log-normal factor in the ground distance on the kind's
        density, or None (module docstring)
    """

    kind: str = DEFAULT_LOCATION_PRIOR
    distance_m: tuple[float, float] | None = None
    population: tuple[float, float] | None = None

    def __post_init__(self):
        if self.kind not in LOCATION_PRIORS:
            raise ValueError(f"location prior: expected one of {list(LOCATION_PRIORS)}, got {self.kind!r}")
        if self.distance_m is not None:
            if isinstance(self.distance_m, (str, bytes)):
                raise ValueError(f"distance_range: expected (low, high) in metres, got the text {self.distance_m!r}")
            try:
                lo, hi = (float(v) for v in self.distance_m)
            except (TypeError, ValueError):
                raise ValueError(f"distance_range: expected (low, high) in metres, got {self.distance_m!r}") from None
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
                raise ValueError(f"distance_range: expected 0 < low < high metres, got {self.distance_m!r}")
            object.__setattr__(self, "distance_m", (lo, hi))
        if self.population is not None:
            try:
                median, log_sd = (float(v) for v in self.population)
            except (TypeError, ValueError):
                raise ValueError(f"population: expected (median m, log-sd), got {self.population!r}") from None
            if not (np.isfinite(median) and np.isfinite(log_sd) and median > 0 and log_sd > 0):
                raise ValueError(f"population: expected a median > 0 m and a log-sd > 0, got {self.population!r}")
            object.__setattr__(self, "population", (median, log_sd))

    @property
    def map_in_log_coordinates(self) -> bool:
        """Whether the MAP is the mode in log coordinates of the positive parameters."""
        return self.kind != "flat"

    def neg_log(self, x, z) -> np.ndarray | float:
        """−log p(x, z) up to a constant, for ground coordinates ``x``, ``z`` in metres (any
        shape; z > 0 inside every preset's bounds)."""
        x, z = np.asarray(x, float), np.asarray(z, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (0.0 if self.kind == "flat" else np.log(x * x + z * z) if self.kind == "inverse-square"
                   else np.log(z))
            if self.population is not None:
                out = out + 0.5 * ((0.5 * np.log(x * x + z * z) - np.log(self.population[0])) / self.population[1]) ** 2
            if self.distance_m is not None:
                log_d = 0.5 * np.log(x * x + z * z)
                lo, hi = np.log(self.distance_m)
                out = out + 0.5 * ((np.maximum(lo - log_d, 0.0) + np.maximum(log_d - hi, 0.0)) / RANGE_SOFTNESS) ** 2
        return out

    def relative_log_prior(self, x, z) -> np.ndarray:
        """log p(x, z) − log p_kind(x, z): the prior relative to its kind's own density (its range
        and population; 0 without them), what a data set's reading divides out (module docstring)."""
        return LocationPrior(self.kind).neg_log(x, z) - self.neg_log(x, z)

    def to_dict(self) -> dict:
        return {"kind": self.kind, **({"distance_m": list(self.distance_m)} if self.distance_m else {}),
                **({"population": list(self.population)} if self.population else {})}
