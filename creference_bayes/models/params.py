"""The parameter space shared by the models: names, units, box bounds, free/fixed/derived handling.

A *model* is what the optimiser and the sampler see: a vectorised ``cost(params)`` over full
parameter vectors of shape (n, 7) = (x, y, z, yaw, µ, pitch, roll), the box :class:`Bounds`, and
which parameters are free. µ is fixed when the scene gives the focal length. The camera's pitch
and roll are either *derived* (a horizon given as exact: they follow from it and µ, method.md §1)
or *free* (no horizon, or a horizon with an uncertainty): :meth:`FreeParameters.expand` fills the
derived ones in, so every cost sees complete vectors and builds the camera rotation from them.
The priors on µ, pitch and roll and the horizon measurement live in :mod:`.camera_terms`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PARAM_NAMES", "PARAM_UNITS", "N_PARAMS", "YAW", "FOCAL", "PITCH", "ROLL", "CIRCULAR", "Bounds",
           "FreeParameters", "wrap_angle"]

#: Order of the parameter vector.
PARAM_NAMES = ("x", "y", "z", "yaw", "focal_length_px", "pitch", "roll")
PARAM_UNITS = ("m", "m", "m", "rad", "px", "rad", "rad")
N_PARAMS = len(PARAM_NAMES)
YAW = 3
FOCAL = 4
PITCH = 5
ROLL = 6
#: Angles that are circular (never bounded for the sampler; summarised on the circle).
CIRCULAR = (YAW,)
#: Largest |pitch| and |roll| (radians) any bounds allow when they are free parameters.
MAX_PITCH = np.radians(80.0)
MAX_ROLL = np.radians(45.0)


def wrap_angle(theta):
    """Wrap radians to [−π, π)."""
    return (np.asarray(theta) + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Bounds:
    """Box bounds on (x, y, z, yaw, µ, pitch, roll): metres, metres, metres, radians, pixels,
    radians, radians.

    The posterior's prior is uniform inside them, times the camera priors of :mod:`.camera_terms`
    (yaw is circular and is never bounded there). Every preset allows a pitch within
    ±:data:`MAX_PITCH` and a roll within ±:data:`MAX_ROLL` when they are free.
    """

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if lo.shape != (N_PARAMS,) or hi.shape != (N_PARAMS,):
            raise ValueError(f"Bounds: expected {N_PARAMS} lower and {N_PARAMS} upper values, got "
                             f"{lo.shape} and {hi.shape}")
        bad = np.flatnonzero(~(lo <= hi))
        if bad.size:
            i = bad[0]
            raise ValueError(f"Bounds.{PARAM_NAMES[i]}: lower {lo[i]!r} > upper {hi[i]!r}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @classmethod
    def paper_controlled(cls) -> "Bounds":
        """The controlled study's bounds (paper §6.1)."""
        return cls(np.array([-10, -10, 1, -np.pi, 100.0, -MAX_PITCH, -MAX_ROLL]),
                   np.array([10, 10, 100, np.pi, 2000.0, MAX_PITCH, MAX_ROLL]))

    @classmethod
    def paper_system(cls) -> "Bounds":
        """The system study's bounds (paper §7.1)."""
        return cls(np.array([-10, -5, 1, -np.pi, 100.0, -MAX_PITCH, -MAX_ROLL]),
                   np.array([10, 5, 50, np.pi, 3000.0, MAX_PITCH, MAX_ROLL]))

    @classmethod
    def default(cls, image_width: int, image_height: int) -> "Bounds":
        """Wide bounds for any scene: |x| ≤ 500 m, |y| ≤ 50 m, 0.1 ≤ z ≤ 1000 m, µ within
        0.1–10 × the image's larger side (fields of view from about 6° to 170°)."""
        m = float(max(image_width, image_height))
        return cls(np.array([-500, -50, 0.1, -np.pi, 0.1 * m, -MAX_PITCH, -MAX_ROLL]),
                   np.array([500, 50, 1000, np.pi, 10 * m, MAX_PITCH, MAX_ROLL]))

    def with_fixed(self, index: int, value: float) -> "Bounds":
        lo, hi = self.lower.copy(), self.upper.copy()
        lo[index] = hi[index] = value
        return Bounds(lo, hi)

    def contains(self, params: np.ndarray) -> np.ndarray:
        """(n,) bool: inside the bounds, yaw ignored (circular)."""
        p = np.atleast_2d(params)
        keep = np.ones(N_PARAMS, bool)
        keep[list(CIRCULAR)] = False
        return np.all((p[:, keep] >= self.lower[keep]) & (p[:, keep] <= self.upper[keep]), axis=1)


class FreeParameters:
    """Free, fixed and derived parameters, shared by the models, for the optimiser and the sampler.

    Needs ``bounds`` (:class:`Bounds`), ``free`` ((7,) bool), ``camera``
    (:class:`~creference_bayes.core.geometry.Camera`) and ``orientation_free`` (bool). A parameter is
    free when it is sampled; otherwise it is fixed at ``bounds.lower`` (µ when known), except pitch
    and roll when they are derived from the horizon and µ (``orientation_free`` False).
    """

    bounds: Bounds
    free: np.ndarray
    camera: object
    orientation_free: bool

    def _free_mask(self) -> np.ndarray:
        """(7,) free parameters: those with lower < upper, pitch and roll only when free."""
        free = self.bounds.lower < self.bounds.upper
        if not self.orientation_free:
            free[[PITCH, ROLL]] = False
        return free

    @property
    def derived(self) -> np.ndarray:
        """(7,) bool: parameters computed from others (pitch and roll from a given horizon)."""
        d = np.zeros(N_PARAMS, bool)
        if not self.orientation_free:
            d[[PITCH, ROLL]] = True
        return d

    def _log_coordinates(self) -> bool:
        terms = getattr(self, "camera_terms", None)
        return terms is not None and terms.map_in_log_coordinates

    def _positive(self) -> np.ndarray:
        """(7,) bool: free parameters that are always positive (lower bound > 0)."""
        return self.free & (self.bounds.lower > 0)

    def scale_prior_neg_log(self, params: np.ndarray) -> np.ndarray | float:
        """−log of the scale-invariant priors p(θ) ∝ 1/θ, for (n, 7) vectors: (n,) or 0.0.

        Under a location prior that takes the MAP in log coordinates
        (:attr:`~.camera_terms.CameraTerms.map_in_log_coordinates`), every positive free
        parameter without an informative prior of its own is uniform in its logarithm: µ without
        a focal-length prior and the camera height y without the height prior (an exact
        horizon). (Flat in µ or y would lean to the far end of the ridges they lie on, as the flat
        location prior did: :mod:`.location_prior`.) The depth z has its own
        (:class:`~.location_prior.LocationPrior`).
        """
        if not self._log_coordinates():
            return 0.0
        terms = self.camera_terms
        mask = np.zeros(N_PARAMS, bool)
        mask[FOCAL] = terms.focal is None
        mask[1] = not (self.orientation_free and terms.orientation is not None)
        mask &= self._positive()
        if not mask.any():
            return 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.sum(np.log(np.atleast_2d(params)[:, mask]), axis=1)

    def map_cost(self, params: np.ndarray) -> np.ndarray:
        """The cost the MAP minimises, for (n, 7) vectors, shape (n,).

        The model's ``cost`` itself, or, when its camera terms take the MAP in log coordinates
        (:attr:`~.camera_terms.CameraTerms.map_in_log_coordinates`), the cost minus
        T·Σ log θᵢ over the free parameters that are always positive (:meth:`_positive`: y for
        the metrology model, z, µ), T the model's default temperature: the MAP is then the mode of
        the density in the coordinates the sampler works in and the priors are stated in
        (:mod:`.location_prior`). With the scale-invariant priors of
        :meth:`scale_prior_neg_log` and the location prior's 1/z, the Jacobian cancels them: the
        MAP is the maximum of the likelihood times the informative priors alone (focal length,
        pose, height).
        """
        params = np.atleast_2d(np.asarray(params, float))
        cost = self.cost(params)
        if not self._log_coordinates():
            return cost
        with np.errstate(divide="ignore", invalid="ignore"):
            jac = np.sum(np.log(params[:, self._positive()]), axis=1)
        return cost - getattr(self, "default_temperature", 1.0) * jac

    def expand(self, free_params: np.ndarray) -> np.ndarray:
        """(n, n_free) free parameters → (n, 7) full vectors (derived pitch and roll filled in)."""
        free_params = np.atleast_2d(free_params)
        full = np.tile(self.bounds.lower, (len(free_params), 1))
        full[:, self.free] = free_params
        if not self.orientation_free:
            full[:, PITCH], full[:, ROLL] = self.camera.pitch_roll(full[:, FOCAL])
        return full
