"""The paper's costs, vectorised over a batch of parameter vectors (docs/paper.md).

Parameter vectors are ``(x, y, z, yaw, focal_length_px, pitch, roll)``: metres, metres, metres,
radians, pixels, radians, radians; a batch has shape (n, 7) and every cost
returns shape (n,). The camera rotation is built from the vectors' pitch and roll
(:func:`~.geometry.rotation_from_pitch_roll`), so the costs need only the principal point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import Camera, box_points, project, rotation_from_pitch_roll

__all__ = [
    "PAPER_SIGMA_PX",
    "PAPER_SHARPNESS",
    "PAPER_CAP",
    "BEHIND_CAMERA_PENALTY",
    "SoftConstraints",
    "target_cost",
    "sigmoid_penalty",
    "soft_constraint_cost",
]

#: σ of Eq. 5, pixels (paper §6.1).
PAPER_SIGMA_PX = 100.0
#: Sharpness a and cap M of Eq. 7 (paper §6.1).
PAPER_SHARPNESS = 8.0
PAPER_CAP = 50.0
#: Cost added per metre that a box corner lies behind the camera (keeps the cost finite and
#: continuous for the optimiser; the posterior treats such states as impossible).
BEHIND_CAMERA_PENALTY = 1e6


def target_cost(params: np.ndarray, observed: np.ndarray, obj_corners: np.ndarray,
                camera: Camera, sigma: float = PAPER_SIGMA_PX) -> np.ndarray:
    """Eq. 5: Σᵢ −log N(‖tᵢ − C_µ(x_s)ᵢ‖; 0, σ²) + | ‖tᵢ‖ − ‖C_µ(x_s)ᵢ‖ |.

    The second term compares the norms of raw pixel coordinates (origin top-left), as the paper
    prints it. Corners behind the camera add :data:`BEHIND_CAMERA_PENALTY` per metre.

    Parameters
    ----------
    params : (n, 7) or (7,)
    observed : (4, 2) annotated corners t1..t4, pixels
    obj_corners : (4, 3) object-frame corners matching t1..t4 (:func:`~.geometry.dimension_corners`)

    Returns
    -------
    (n,) cost, dimensionless (a negative log-density up to the temperature)
    """
    params = np.atleast_2d(params)
    R = rotation_from_pitch_roll(params[:, 5], params[:, 6])
    projected, depth = project(box_points(params, obj_corners), R, params[:, 4], camera.principal_point)
    r2 = np.sum((observed - projected) ** 2, axis=-1)
    nll = 0.5 * r2 / sigma**2 + np.log(sigma * np.sqrt(2.0 * np.pi))
    norm_gap = np.abs(np.linalg.norm(observed, axis=-1) - np.linalg.norm(projected, axis=-1))
    behind = BEHIND_CAMERA_PENALTY * np.sum(np.maximum(0.0, 1e-3 - depth), axis=-1)
    return np.sum(nll + norm_gap, axis=-1) + behind


def sigmoid_penalty(x: np.ndarray, low: np.ndarray, high: np.ndarray,
                    a: float = PAPER_SHARPNESS, cap: float = PAPER_CAP) -> np.ndarray:
    """Eq. 6–7: P(x; l, u) = S(l − x) + S(x − u), S(r) = min((r + 1) / (1 + exp(−a r)), M).

    The paper prints ``max`` in Eq. 7, but its text makes M a cap that keeps the penalty from
    dominating the objective; this is ``min`` (docs/paper.md, departure 2). Broadcasts ``x`` (n, 1) against
    bounds (m,) to (n, m).
    """
    def s(r):
        return np.minimum((r + 1.0) * _expit(a * r), cap)

    return s(low - x) + s(x - high)


def _expit(t: np.ndarray) -> np.ndarray:
    # 1 / (1 + exp(-t)) without overflow warnings
    return 0.5 * (1.0 + np.tanh(0.5 * t))


@dataclass(frozen=True)
class SoftConstraints:
    """Bounds on the target's ground position from pairs of references (Eq. 10–11).

    Attributes
    ----------
    x_bounds, z_bounds : (m, 2) arrays, metres; one row [l, u] per usable pair
    on : ``"xz"`` penalises x and z separately (default); ``"distance"`` penalises the ground
        distance √(x² + z²) against the bounds in ``distance_bounds`` instead
    distance_bounds : (m, 2) arrays, metres (used when ``on == "distance"``)
    a, cap : sharpness and cap of Eq. 7
    """

    x_bounds: np.ndarray
    z_bounds: np.ndarray
    distance_bounds: np.ndarray | None = None
    on: str = "xz"
    a: float = PAPER_SHARPNESS
    cap: float = PAPER_CAP

    def __post_init__(self):
        if self.on not in ("xz", "distance"):
            raise ValueError(f"SoftConstraints.on: expected 'xz' or 'distance', got {self.on!r}")
        if self.on == "distance" and self.distance_bounds is None:
            raise ValueError("SoftConstraints.distance_bounds: required when on='distance'")

    @property
    def n_pairs(self) -> int:
        return len(self.x_bounds)


def soft_constraint_cost(params: np.ndarray, constraints: SoftConstraints | None) -> np.ndarray:
    """Σ over pairs of P(x; lˣ, uˣ) + P(z; lᶻ, uᶻ) (Eq. 10–11), shape (n,)."""
    params = np.atleast_2d(params)
    if constraints is None or constraints.n_pairs == 0:
        return np.zeros(len(params))
    c = constraints
    if c.on == "distance":
        d = np.hypot(params[:, 0], params[:, 2])[:, None]
        return sigmoid_penalty(d, c.distance_bounds[:, 0], c.distance_bounds[:, 1], c.a, c.cap).sum(-1)
    px = sigmoid_penalty(params[:, :1], c.x_bounds[:, 0], c.x_bounds[:, 1], c.a, c.cap)
    pz = sigmoid_penalty(params[:, 2:3], c.z_bounds[:, 0], c.z_bounds[:, 1], c.a, c.cap)
    return px.sum(-1) + pz.sum(-1)
