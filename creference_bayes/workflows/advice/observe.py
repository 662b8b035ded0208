"""Simulating one more annotation under the model's own noise model, and its importance weights.

Both kinds take the *current* model (the metrology model of the scene for the posterior's
handedness, its pilot at the MAP) and give, for M simulated annotations and N posterior draws,
the (M, N) log-ratios log p_new(θ_j) − log p_old(θ_j) of the posteriors with and without the
i-th simulated annotation (docs/advice.md, "How the advice is computed"):

- **Target dimension lines** (:class:`TargetObservation`): the four corners projected at the
  simulating draw plus bivariate Student-t(ν) noise that scatters as the scene's sets do
  (:func:`simulation_scale`: the model's corner scale σ with one set, its pooled sd as an sd
  with two or more), stored to 0.01 px. Adding
  a set changes σ itself (it is estimated from the annotations' spread) and with it the pixel
  noise of every reference line (σ_line = factor · σ), so the ratio is the difference of the
  full costs of the models built from the scene with and without the set.
- **A reference** (:class:`ReferenceObservation`): at the simulating draw, a crowd error scale
  s_k from its posterior given the scene's references (the grid weights
  ``crowd_scale_weights``), then log v = log ℓ(θ) − shift + s_jk·ε, ε ~ t(ν), with s_jk² = s_k² +
  v_line, both at the pilot, as the model reads a reference (the shift, the reading's lengthening
  by line noise, is 0 unless the model's ``line_reading`` is ``corrected``); stated as a range with the
  scene's share of ranges and its median precision. Since the crowd scale is shared, the ratio is
  log Σ_k π_k(θ) p(v | θ, s_k), with π_k(θ) the grid's posterior weights at θ: exact, and cheap
  (the tests check it against the cost difference of the two models).

Held fixed: the pilot (the line-noise derivatives are taken at the current MAP; a full
re-estimate would take them at its own first optimum) and the camera setup (the horizon, the
priors: adding an annotation does not change them).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ...core.cost import project_params
from ...io.scene import DimensionLine, Reference
from ...models.metrology import MIN_CAMERA_HEIGHT_M, ground_lengths, t_interval
from ...pipeline import build_models

__all__ = ["ModelContext", "TargetObservation", "ReferenceObservation", "observation_for", "simulation_scale"]

#: Crowd-scale grid points with less weight than this at every draw add nothing to the likelihood
#: of a new reference and are skipped (a relative error below 10⁻⁹ · K).
_NEGLIGIBLE = 1e-9
#: Largest simulated error of a stated length, in log-length (a factor 10⁴).
_MAX_LOG_ERROR = float(np.log(1e4))


@dataclass
class ModelContext:
    """What every simulation of one scene shares.

    Attributes
    ----------
    scene : the current scene
    setup : its camera setup (:func:`~creference_bayes.camera_setup.setup_camera`)
    handedness : the posterior's handedness
    pilot : (7,) the parameter vector the models' line-noise derivatives are taken at (the MAP)
    model : the current model, pilot set
    options : metrology model settings the models are built with (as ``estimate``'s, e.g.
        ``line_reading``); the defaults when empty
    """

    scene: object
    setup: object
    handedness: int
    pilot: np.ndarray
    model: object = None
    options: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if self.model is None:
            self.model = self.model_of(self.scene)

    def model_of(self, scene):
        """The metrology model of ``scene`` for this handedness, with the pilot set."""
        model = next(m for m in build_models(scene, self.setup, **self.options) if m.handedness == self.handedness)
        model.set_pilot(self.pilot)
        return model


def simulation_scale(model) -> float:
    """The Student-t scale (pixels) a simulated set of dimension lines is drawn with: one that
    scatters as the scene's sets do.

    With one set the model's corner scale is a stated t scale (5 px by default) and is used as
    it is. With two or more it is the sets' pooled standard deviation, which the model takes as
    its t scale (a wider likelihood: docs/method.md); a t(ν) of that scale scatters
    √(ν / (ν − 2)) times more than the sets did (√2 at ν = 4). Drawn with it, a future set is
    noisier than any seen and the advice under-predicted what one more brings (on the model's
    own scenes from two sets on: 0.49 points predicted against 1.86 realised from three or more,
    docs/advice.md); so the scale is the pooled sd · √((ν − 2) / ν), whose t(ν) has that sd.
    """
    sigma = float(model.target_sigma)
    nu = float(model.target_dof)
    if getattr(model, "target_sigma_from_spread", False) and nu > 2.0:
        return sigma * float(np.sqrt((nu - 2.0) / nu))
    return sigma


class TargetObservation:
    """One more set of target dimension lines (module docstring)."""

    def __init__(self, ctx: ModelContext, seconds: float | None = None):
        self.ctx = ctx
        self.dof = float(ctx.model.target_dof)
        self.sigma = simulation_scale(ctx.model)
        self.seconds = seconds
        self.corners = None

    def simulate(self, rng, outer: np.ndarray) -> None:
        """Draw one annotation per row of ``outer`` (M, 7) and keep them (:attr:`corners`, (M, 4, 2))."""
        m = self.ctx.model
        projected, _ = project_params(outer, m.obj_corners, m.camera.principal_point)
        z = rng.standard_normal(projected.shape)
        g = rng.chisquare(self.dof, size=projected.shape[:2])
        # coordinates stored to 0.01 px, as annotation tools store them
        self.corners = np.round(projected + self.sigma * z * np.sqrt(self.dof / g)[..., None], 2)

    def __len__(self) -> int:
        return 0 if self.corners is None else len(self.corners)

    def scene_with(self, i: int):
        """The scene with the i-th simulated annotation added."""
        scene = self.ctx.scene
        t = scene.target
        line = DimensionLine(corners=self.corners[i], worker="advice", seconds=self.seconds)
        return dataclasses.replace(scene, target=dataclasses.replace(
            t, dimension_lines=t.dimension_lines + (line,)))

    def log_ratio(self, inner: np.ndarray, base_cost: np.ndarray | None = None, crowd=None) -> np.ndarray:
        """(M, N) log p_new − log p_old at the draws ``inner`` (N, 7), up to a constant per row;
        ``base_cost`` is the current model's cost at ``inner`` (``crowd`` is not used)."""
        c0 = self.ctx.model.cost(inner) if base_cost is None else base_cost
        out = np.empty((len(self), len(inner)))
        for i in range(len(self)):
            out[i] = -(self.ctx.model_of(self.scene_with(i)).cost(inner) - c0)
        return np.where(np.isfinite(out), out, -np.inf)


class ReferenceObservation:
    """One more reference on a given segment (module docstring).

    Parameters
    ----------
    ctx : the scene's :class:`ModelContext`
    line : (2, 2) the segment, pixels
    measure, object : what it measures (for the scene with the simulated reference)
    range_share, range_precision : how it is stated (:class:`~creference_bayes.workflows.advice.candidates.FormatMix`)
    seconds : recorded with the simulated reference
    """

    def __init__(self, ctx: ModelContext, line, *, measure: str, object: str | None = None,
                 range_share: float = 0.0, range_precision: float = 0.25, seconds: float | None = None):
        self.ctx = ctx
        self.line = np.asarray(line, float).reshape(2, 2)
        self.measure, self.object, self.seconds = measure, object, seconds
        self.range_share, self.range_precision = float(range_share), float(range_precision)
        probe = ctx.model_of(self._scene_plus(1.0, 1.0, False))
        self.usable = probe.n_references_used == ctx.model.n_references_used + 1
        self.dof = float(ctx.model.ref_dof)
        # the new reference's scales s_jk over the crowd-scale grid (the model orders the usable
        # references as the scene does, so the new one is last)
        self.scales = probe.reference_scales[-1] if self.usable else None
        # and the lengthening of its reading by line noise, which the model takes off
        self.shift = float(probe.line_shifts[-1]) if self.usable else 0.0
        self.log_low = self.log_high = self.is_range = None

    def _scene_plus(self, low: float, high: float, is_range: bool):
        scene = self.ctx.scene
        ref = Reference(index=len(scene.references), measure=self.measure, mode="direct", low=low,
                        high=high, line=self.line, is_range=is_range, unit="m", object=self.object,
                        worker="advice", seconds=self.seconds, stated=(low, high))
        return dataclasses.replace(scene, references=scene.references + (ref,))

    def __len__(self) -> int:
        return 0 if self.log_low is None else len(self.log_low)

    def scene_with(self, i: int):
        """The scene with the i-th simulated reference added."""
        return self._scene_plus(float(np.exp(self.log_low[i])), float(np.exp(self.log_high[i])),
                                bool(self.is_range[i]))

    def log_lengths(self, full: np.ndarray) -> np.ndarray:
        """log ℓ − shift of the segment at (n, 7) draws, metres: the model's corrected reading (the
        camera height clipped as the model does)."""
        full = np.array(full, float)
        full[:, 1] = np.maximum(full[:, 1], MIN_CAMERA_HEIGHT_M)
        with np.errstate(divide="ignore"):
            return np.log(ground_lengths(self.line[None], self.ctx.model.camera.principal_point, full)[:, 0]) - self.shift

    def simulate(self, rng, outer: np.ndarray) -> None:
        """Draw one stated value or range per row of ``outer`` (M, 7)."""
        if not self.usable:
            raise ValueError("the segment is unusable for the model (an end on or above the horizon)")
        m = len(outer)
        _, pi = self.ctx.model.crowd_scale_weights(outer)                      # (M, K)
        k = (rng.uniform(size=(m, 1)) > np.cumsum(pi, axis=1)).sum(axis=1)
        k = np.minimum(k, pi.shape[1] - 1)
        eps = rng.standard_t(self.dof, size=m)
        # no worker is off by more than a factor 10⁴ (t₂ tails would give 0 or ∞ after rounding)
        log_v = self.log_lengths(outer) + np.clip(self.scales[k] * eps, -_MAX_LOG_ERROR, _MAX_LOG_ERROR)
        self.is_range = rng.uniform(size=m) < self.range_share
        half = np.log1p(self.range_precision / 2), np.log1p(-min(self.range_precision, 1.9) / 2)
        self.log_low = np.where(self.is_range, log_v + half[1], log_v)
        self.log_high = np.where(self.is_range, log_v + half[0], log_v)
        # values as a worker states them (4 significant digits), never zero
        self.log_low = np.log(np.array([float(f"{v:.4g}") for v in np.exp(self.log_low)]))
        self.log_high = np.log(np.array([float(f"{v:.4g}") for v in np.exp(self.log_high)]))

    def log_ratio(self, inner: np.ndarray, base_cost=None, crowd: np.ndarray | None = None) -> np.ndarray:
        """(M, N) log Σ_k π_k(θ_j) p(new_i | θ_j, s_k), up to a constant per row.

        ``crowd`` : the (N, K) crowd-scale weights at ``inner``, if already computed. Grid points
        whose weight is below :data:`_NEGLIGIBLE` at every draw are left out of the sum.
        """
        log_len = self.log_lengths(inner)                                      # (N,)
        pi = self.ctx.model.crowd_scale_weights(inner)[1] if crowd is None else crowd
        active = pi.max(axis=0) >= _NEGLIGIBLE
        pi = pi[:, active]                                                     # (N, K')
        inv = 1.0 / self.scales[active]                                        # (K',)
        nu = self.dof
        out = np.empty((len(self), len(inner)))
        for rows, ranged in ((np.flatnonzero(~self.is_range), False), (np.flatnonzero(self.is_range), True)):
            if not rows.size:
                continue
            lo = (self.log_low[rows, None, None] - log_len[None, :, None]) * inv   # (r, N, K')
            if ranged:
                hi = (self.log_high[rows, None, None] - log_len[None, :, None]) * inv
                p = np.maximum(t_interval(nu, lo, hi), 0.0)
            else:  # the t density in log-length, its ν-only constant dropped (polynomial tails: no underflow)
                p = inv * (1.0 + lo * lo / nu) ** (-0.5 * (nu + 1.0))
            with np.errstate(divide="ignore"):
                out[rows] = np.log(np.einsum("rnk,nk->rn", p, pi))
        return np.where(np.isfinite(out), out, -np.inf)


def observation_for(candidate, ctx: ModelContext, mix):
    """The observation of a :class:`~creference_bayes.workflows.advice.candidates.Candidate`, given the scene's format ``mix``."""
    if candidate.kind == "target":
        return TargetObservation(ctx, seconds=candidate.seconds)
    return ReferenceObservation(ctx, candidate.line, measure=candidate.measure, object=candidate.object,
                                range_share=mix.range_share, range_precision=mix.range_precision,
                                seconds=candidate.seconds)
