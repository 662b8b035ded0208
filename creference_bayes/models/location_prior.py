"""The prior on the target's location on the ground, and the coordinates the MAP is taken in.

Why not flat
    One set of dimension lines of a far target leaves a *ridge*: moving the camera back and
    zooming in, (z, µ) → (λz, λµ) at the same lateral offset x and camera height y, changes the
    image only through perspective (the box's depth extent against its distance), so the
    annotations pin µ/z, x and y but hardly λ. Along the ridge, in the sampler's coordinates
    (x, log y, log z, log µ, …; :mod:`creference_bayes.inference.reparam`), the likelihood's
    cross-section keeps its size, so the posterior's weight at scale λ is the prior's density
    there times the Jacobian z·µ of the logarithms. A prior flat in (x, z) with the focal prior
    f(log µ)/µ (:class:`~.camera_terms.FocalPrior`) gives f(log µ)·z: a weight growing like λ,
    which beats the focal prior's polynomial tails and runs to the far bound. A 2D scale-invariant
    prior, p(x, z) ∝ 1/d², gives f(log µ)·z/d² ≈ f(log µ)/z: it leans near as much (tried,
    method.md). The ridge's symmetry scales z (and µ) but not x, so the prior neutral to it is
    uniform in log z at each lateral offset,

        p(x, z) ∝ 1/z        (``log-depth``),

    under which the weight along the ridge is f(log µ) alone: the focal-length prior (and what
    perspective says) decides where on the ridge the target is, the location prior does not. It is
    proper within the bounds (z from 0.1 to 1000 m: ln 10⁴ ≈ 9.2 units of log depth; the data's
    reach is narrower, and the bounds only matter where nothing else does).

The MAP in the same coordinates
    A density's maximum moves when the coordinates change, by the logarithm of the Jacobian. The
    sampler works in logarithms of the positive parameters (y, z, µ); the MAP is taken in those
    same coordinates (:meth:`LocationPrior.map_in_log_coordinates`; the models'
    ``map_cost``), so that the MAP is the mode of the very density that is sampled and the priors
    are densities in the coordinates they are stated in (log µ, log h, log z). Without this the
    MAP of the flat prior sat near the *near* end of the ridge (its density f(log µ)/µ falls
    along it) while the posterior's mass sat at the far end.

``flat`` keeps the earlier behaviour: a flat prior in (x, z) and the MAP in the parameters
themselves (the paper's presets use it: the paper's method as published has no prior).
``inverse-square``, p(x, z) ∝ 1/d² with the MAP in log coordinates, is there for comparison
(method.md: it leans near).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LOCATION_PRIORS", "DEFAULT_LOCATION_PRIOR", "LocationPrior"]

#: The location priors: ``log-depth`` (p(x, z) ∝ 1/z, the MAP in log coordinates), ``flat`` and,
#: for comparison, ``inverse-square`` (p(x, z) ∝ 1/d², d = √(x² + z²), the MAP in log coordinates).
LOCATION_PRIORS = ("log-depth", "flat", "inverse-square")
DEFAULT_LOCATION_PRIOR = "log-depth"


@dataclass(frozen=True)
class LocationPrior:
    """The prior on the target's ground position (x, z), metres (module docstring).

    Attributes
    ----------
    kind : one of :data:`LOCATION_PRIORS`
    """

    kind: str = DEFAULT_LOCATION_PRIOR

    def __post_init__(self):
        if self.kind not in LOCATION_PRIORS:
            raise ValueError(f"location prior: expected one of {list(LOCATION_PRIORS)}, got {self.kind!r}")

    @property
    def map_in_log_coordinates(self) -> bool:
        """Whether the MAP is the mode in log coordinates of the positive parameters."""
        return self.kind != "flat"

    def neg_log(self, x, z) -> np.ndarray | float:
        """−log p(x, z) up to a constant, for ground coordinates ``x``, ``z`` in metres (any
        shape; z > 0 inside every preset's bounds)."""
        if self.kind == "flat":
            return 0.0
        x, z = np.asarray(x, float), np.asarray(z, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.kind == "inverse-square":
                return np.log(x * x + z * z)
            return np.log(z)

    def to_dict(self) -> dict:
        return {"kind": self.kind}
