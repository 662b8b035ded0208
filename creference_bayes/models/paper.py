"""The ``paper`` model: the paper's cost′ (Eq. 5 plus Eq. 10–11) as a model of the contract.

For each object, Eq. 5 on the per-corner median of its annotations,

    Σᵢ −log N(‖tᵢ − C(xᵢ)‖; 0, σ²) + | ‖tᵢ‖ − ‖C(xᵢ)‖ |

(the second term compares the norms of raw pixel coordinates, origin top-left, as the paper prints
it), plus the capped sigmoid penalties (Eq. 6–7) that keep its ground position (x, z) within the
bounds every usable pair of references implies (Eq. 8–11; :mod:`creference_bayes.core.metrology`).
The cost is read as a negative log-likelihood at a temperature: σ = :data:`CALIBRATED_SIGMA_PX`,
T = :data:`CALIBRATED_TEMPERATURE` with the default preset (calibrated: docs/studies/benchmark.md,
calibration sweep), the paper's σ = 100 px and T = 1 with its presets. The camera priors and the
location prior are the contract's and enter untempered. Objects stand on one ground plane (no
ground offsets): the paper's method knows no uneven ground.
"""

from __future__ import annotations

import numpy as np

from ..core.cost import PAPER_SIGMA_PX, SoftConstraints, soft_constraint_cost
from .contract import O_X, O_Z, Model

__all__ = ["CALIBRATED_SIGMA_PX", "CALIBRATED_TEMPERATURE", "PaperModel"]

#: σ (pixels) and temperature T of the paper model's posterior with the ``default`` preset: with
#: the paper's σ = 100 px no temperature calibrates it (docs/studies/benchmark.md, calibration
#: sweep). The ``paper`` presets keep the paper's σ = 100 px and T = 1.
CALIBRATED_SIGMA_PX = 2.0
CALIBRATED_TEMPERATURE = 3.0


class PaperModel(Model):
    """The paper's cost′ for every object of a scene (module docstring).

    Parameters
    ----------
    principal_point, image_size, objects : as :class:`~.contract.Model`
    constraints : per object, the soft bounds on its (x, z) from pairs of references, or None
    sigma : σ of Eq. 5, pixels
    reference_reports : per object, how its references were aggregated
        (:class:`~creference_bayes.core.metrology.ReferenceReport`: pairs used and skipped, why),
        or empty
    kw : the contract's options (``ground_sd_m`` is 0: one ground plane)
    """

    name = "paper"
    capabilities = frozenset({"corner_sigma", "reference_bounds"})
    options = ("sigma", "on")
    word_options = ("on",)
    smooth = False

    def __init__(self, principal_point, image_size, objects, constraints=None, *, sigma: float = PAPER_SIGMA_PX,
                 reference_reports=(), **kw):
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"sigma: expected a finite number > 0, got {sigma!r}")
        self.sigma = float(sigma)
        kw["ground_sd_m"] = 0.0
        super().__init__(principal_point, image_size, objects, **kw)
        self.constraints: tuple[SoftConstraints | None, ...] = tuple(constraints or (None,) * self.n_objects)
        if len(self.constraints) != self.n_objects:
            raise ValueError(f"constraints: one per object expected, got {len(self.constraints)} for {self.n_objects}")
        self.reference_reports = tuple(reference_reports)
        self.observed = np.array([o.corner_median for o in self.objects])  # (m, 4, 2)
        self._norms = np.linalg.norm(self.observed, axis=-1)

    def _eq5(self, cams: np.ndarray, objs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, m) Eq. 5 of each object and (n, m) its behind-the-camera penalty."""
        uv, depth = self.project(cams, objs)
        r2 = np.sum((self.observed[None] - uv) ** 2, axis=-1)
        nll = 0.5 * r2 / self.sigma**2 + np.log(self.sigma * np.sqrt(2.0 * np.pi))
        gap = np.abs(self._norms[None] - np.linalg.norm(uv, axis=-1))
        if self.softness_px > 0:  # rounded: √(g² + s²) − s
            gap = np.hypot(gap, self.softness_px) - self.softness_px
        return np.sum(nll + gap, axis=-1), self.behind(depth)

    def _bounds_terms(self, objs: np.ndarray) -> np.ndarray:
        """(n, m) each object's sigmoid penalties (Eq. 10–11) on its ground position."""
        out = np.zeros(objs.shape[:2])
        for i, c in enumerate(self.constraints):
            if c is not None and c.n_pairs:
                xz = np.zeros((len(objs), 3))
                xz[:, 0], xz[:, 2] = objs[:, i, O_X], objs[:, i, O_Z]
                out[:, i] = soft_constraint_cost(xz, c)
        return out

    def object_nll(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        eq5, behind = self._eq5(cams, objs)
        return eq5 + behind + self._bounds_terms(objs)

    def pointwise_log_likelihood(self, cams: np.ndarray, objs: np.ndarray) -> dict[str, np.ndarray]:
        """``annotations`` (n, m, 1): −Eq. 5 of each object's median annotation; ``references``
        (n, m): −its penalties from the pairs of references; ``horizon`` (n,)."""
        cams = self.complete_camera(cams)
        eq5, _ = self._eq5(cams, objs)
        return {"annotations": -eq5[..., None], "references": -self._bounds_terms(objs),
                "horizon": -self.horizon_nll(cams)}
