"""Sampling coordinates in which a model's posterior is nearly Gaussian.

When pitch is a free parameter, a far target's posterior lies along a curved ridge: the depth z,
the camera height h, the focal length µ and the pitch trade against each other through the
target's distance below the horizon in the image, D = −sin(roll)(u − cx) + cos(roll)(v − cy) +
µ tan(pitch) (pixels, at the target's bottom centre (u, v)): z ≈ h µ / D. In (log h, log z,
log µ, log D) that ridge is a straight line, which the sampler's affine coordinates follow, while
in pitch it bends (on a 41 m target the plain parametrisation mixed with autocorrelation times of
hundreds of steps). :class:`HorizonDistance` replaces pitch by log D in the sampled vector; the
others are unchanged (the sampler takes logarithms of the positive ones itself).

With few annotations the posterior also runs along the target's viewing ray, where x and y grow
with z. :class:`ImageRay` replaces x and y by the target's offsets in the image from the
principal point, µx/z and µy/z, which the annotations pin and which stay put along the ray.
:class:`Chained` applies one set of coordinates after another (the pipeline chains the two).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import FOCAL, PITCH, ROLL

__all__ = ["HorizonDistance"]


def _focal_fields(model) -> dict:
    """``i_focal`` (µ's position in the model's free vector, or None when µ is fixed) and
    ``focal`` (the fixed µ, pixels, or None), as the coordinate classes keep them."""
    free = np.asarray(model.free, bool)
    if free[FOCAL]:
        return {"i_focal": int(np.cumsum(free)[FOCAL] - 1), "focal": None}
    return {"i_focal": None, "focal": float(model.bounds.lower[FOCAL])}


def _focal(v: np.ndarray, i_focal: int | None, focal: float | None) -> np.ndarray:
    """(n,) µ of each row of ``v`` (n, k): its column, or the fixed value."""
    return v[:, i_focal] if i_focal is not None else np.full(len(v), focal)


@dataclass(frozen=True)
class HorizonDistance:
    """Free parameters ↔ sampling coordinates with pitch replaced by log D (module docstring).

    Attributes
    ----------
    point : (2,) the target's bottom centre in the image, pixels
    principal_point : (2,) pixels
    i_pitch, i_roll, i_focal : positions of pitch, roll and µ in the free vector (i_focal None
        when µ is fixed, then ``focal`` is used)
    focal : the fixed µ, pixels (when ``i_focal`` is None)
    """

    point: np.ndarray
    principal_point: np.ndarray
    i_pitch: int
    i_roll: int
    i_focal: int | None
    focal: float | None = None

    @classmethod
    def from_model(cls, model) -> "HorizonDistance | None":
        """The coordinates for a model whose pitch and roll are free, else None. The target's
        bottom centre is the midpoint of the length and width lines' ends (t2, t3) of the
        per-corner median annotation: the centre of the box's bottom face."""
        free = np.asarray(model.free, bool)
        if not (getattr(model, "orientation_free", False) and free[PITCH] and free[ROLL]):
            return None
        pos = np.cumsum(free) - 1
        obs = np.asarray(model.observed, float)
        return cls(point=0.5 * (obs[1] + obs[2]), principal_point=np.asarray(model.camera.principal_point, float),
                   i_pitch=int(pos[PITCH]), i_roll=int(pos[ROLL]), **_focal_fields(model))

    def _mu(self, v: np.ndarray) -> np.ndarray:
        return _focal(v, self.i_focal, self.focal)

    def _offset(self, roll: np.ndarray) -> np.ndarray:
        """The part of D that does not depend on pitch, pixels."""
        du, dv = self.point - self.principal_point
        return -np.sin(roll) * du + np.cos(roll) * dv

    def forward(self, p: np.ndarray) -> np.ndarray:
        """(n, k) free parameters → sampling coordinates; NaN where the target's bottom is not
        below the horizon (D ≤ 0: no ground point there)."""
        p = np.atleast_2d(np.asarray(p, float))
        q = p.copy()
        d = self._offset(p[:, self.i_roll]) + self._mu(p) * np.tan(p[:, self.i_pitch])
        with np.errstate(invalid="ignore", divide="ignore"):
            q[:, self.i_pitch] = np.where(d > 0, np.log(d), np.nan)
        return q

    def inverse(self, q: np.ndarray) -> np.ndarray:
        """Sampling coordinates (n, k) → free parameters."""
        q = np.atleast_2d(np.asarray(q, float))
        p = q.copy()
        with np.errstate(over="ignore"):
            d = np.exp(q[:, self.i_pitch])
        p[:, self.i_pitch] = np.arctan((d - self._offset(q[:, self.i_roll])) / self._mu(q))
        return p

    def log_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(n,) log |∂p/∂q|: ∂pitch/∂log D = D cos²(pitch) / µ."""
        q = np.atleast_2d(np.asarray(q, float))
        with np.errstate(over="ignore", divide="ignore"):
            d = np.exp(q[:, self.i_pitch])
            t = (d - self._offset(q[:, self.i_roll])) / self._mu(q)
            return np.log(d) - np.log1p(t * t) - np.log(self._mu(q))


@dataclass(frozen=True)
class ImageRay:
    """Free parameters ↔ sampling coordinates with x and y replaced by the image offsets of the
    target's reference point from the principal point, U = µ x / z and V = µ y / z (pixels).

    Why: the annotations pin where the target is in the image to a few pixels, not how far away
    it is. With few of them (one set of lines on a far target) the posterior stretches along the
    viewing ray, where x and y grow in proportion to z: in the sampler's (x, y, log z, log µ)
    that ray is an exponential curve, which an affine map and a mixture proposal cannot follow
    (an outdoor scene seen once, 17–999 m: walkers stuck for up to 570 steps in the ray's far
    part, τ ≈ 850 steps, the 20 000-step cap). In (U, V, log z, log µ) the ray is a straight
    line: U and V hardly move, and log z trades linearly against log µ.

    Attributes
    ----------
    i_x, i_y, i_z : positions of x, y and z in the free vector
    i_focal : position of µ in it, or None when µ is fixed (then ``focal`` is used)
    focal : the fixed µ, pixels
    """

    i_x: int
    i_y: int
    i_z: int
    i_focal: int | None
    focal: float | None = None

    @classmethod
    def from_model(cls, model) -> "ImageRay | None":
        """The coordinates for a model whose x, y and z are free and z > 0, else None."""
        free = np.asarray(model.free, bool)
        if not (free[:3].all() and model.bounds.lower[2] > 0):
            return None
        pos = np.cumsum(free) - 1
        return cls(i_x=int(pos[0]), i_y=int(pos[1]), i_z=int(pos[2]), **_focal_fields(model))

    def _scale(self, v: np.ndarray) -> np.ndarray:
        """z / µ, metres per pixel at the target's depth."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return v[:, self.i_z] / _focal(v, self.i_focal, self.focal)

    def forward(self, p: np.ndarray) -> np.ndarray:
        """(n, k) free parameters → sampling coordinates."""
        p = np.atleast_2d(np.asarray(p, float))
        q = p.copy()
        s = self._scale(p)
        with np.errstate(divide="ignore", invalid="ignore"):
            q[:, self.i_x], q[:, self.i_y] = p[:, self.i_x] / s, p[:, self.i_y] / s
        return q

    def inverse(self, q: np.ndarray) -> np.ndarray:
        """Sampling coordinates (n, k) → free parameters."""
        q = np.atleast_2d(np.asarray(q, float))
        p = q.copy()
        s = self._scale(q)
        p[:, self.i_x], p[:, self.i_y] = q[:, self.i_x] * s, q[:, self.i_y] * s
        return p

    def log_jacobian(self, q: np.ndarray) -> np.ndarray:
        """(n,) log |∂p/∂q| = 2 log(z / µ): x and y scale with z / µ, the rest is unchanged."""
        q = np.atleast_2d(np.asarray(q, float))
        with np.errstate(divide="ignore", invalid="ignore"):
            return 2.0 * np.log(self._scale(q))


@dataclass(frozen=True)
class Chained:
    """Coordinates applied one after the other: ``forward`` through ``first`` then ``second``.
    Each must leave the parameters the other reads unchanged or read them consistently; the log
    Jacobians add."""

    first: object
    second: object

    @staticmethod
    def of(*coords) -> "object | None":
        """The chain of the given coordinates that are not None (None when all are)."""
        out = None
        for c in coords:
            if c is not None:
                out = c if out is None else Chained(out, c)
        return out

    def forward(self, p: np.ndarray) -> np.ndarray:
        return self.second.forward(self.first.forward(p))

    def inverse(self, q: np.ndarray) -> np.ndarray:
        return self.first.inverse(self.second.inverse(q))

    def log_jacobian(self, q: np.ndarray) -> np.ndarray:
        return self.second.log_jacobian(q) + self.first.log_jacobian(self.second.inverse(q))
