"""Simulating one more observation under the model's own noise model, and its importance weights.

Each kind takes the *current* model of the scene (the metrology model, the MAP's handedness and
pilot) and gives, for M simulated observations and N posterior draws (cameras (N, 5), objects
(N, m, 7)), the (M, N) log-ratios log p_new − log p_old of the posteriors with and without the
i-th simulated observation (docs/advice_method.md):

- **A set of dimension lines on target i** (:class:`DimsObservation`): its four corners projected
  at the simulating draw plus bivariate Student-t(ν) noise that scatters as the scene's sets do
  (:func:`simulation_scale`), stored to 0.01 px. A set changes the corner scales σ and with them
  every reference line's noise, so the ratio is the difference of the full negative
  log-posteriors with and without it (:func:`grown`).
- **A reference** (:class:`ReferenceObservation`, any
  :class:`~creference_bayes.models.metrology.ReferenceTerm`): at the simulating draw, log v = the
  model's reading of it − e_b + √(s² + v_b)·ε, ε ~ t(ν), s the draw's crowd scale and (e_b, v_b)
  a bin of the segment's reading error at the pilot drawn at random (the model's own reading,
  :func:`~creference_bayes.models.metrology.reading_log_likelihood`); stated as a range with the
  scene's share of ranges and median precision. It changes nothing else, so the ratio is its own
  likelihood. A scene without references has no crowd scale yet: its draws get one from the
  scale's prior.
- **A size from a catalogue** (:class:`SizeObservation`) and **the camera's mounting**
  (:class:`MountingObservation`): the draw's log-size (or log-height, pitch and roll) plus normal
  noise of the answer's spread; the answer enters as a prior (:mod:`.answers`), so the ratio is
  its normal log-density (not tempered); quantities the model holds fixed are left out.

Held fixed: the pilot (the line noise at the current MAP) and the camera set-up (horizon, priors).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ...models.contract import C_HEIGHT, C_PITCH, C_ROLL, C_SCALE, O_SIZE
from ...models.metrology import MetrologyModel, ReferenceTerm, reading_log_likelihood

__all__ = ["grown", "at_hands", "simulation_scale", "DimsObservation", "ReferenceObservation", "SizeObservation",
           "MountingObservation"]

#: Largest simulated error of a stated length, in log-length (a factor 10⁴).
_MAX_LOG_ERROR = float(np.log(1e4))


def grown(model: MetrologyModel, options: dict, *, annotations: dict | None = None, references=()) -> MetrologyModel:
    """``model`` with more observations: ``annotations`` {target index: (4, 2) corners} appended to
    those targets' sets and ``references`` (:class:`ReferenceTerm`) to its references; the same
    camera set-up, settings (``options``: the estimate's model options), crowd's corner scale from
    the data set, handedness and pilot. Built from the model, not the scene, so the camera set-up
    (an image's horizon) is not redone."""
    objects = list(model.objects)
    for i, corners in (annotations or {}).items():
        objects[i] = dataclasses.replace(objects[i], annotations=np.concatenate(
            [objects[i].annotations, np.asarray(corners, float)[None]]))
    fixed = {k: options[k] for k in ("target_sigma", "ref_line_sigma") if options.get(k) is not None}
    new = MetrologyModel(model.principal_point, model.image_size, objects, model.all_references + tuple(references),
                         target_dof=model.target_dof, ref_dof=model.ref_dof, confidence_map=model.confidence_map,
                         line_reading=model.line_reading, read_floor_px=model.read_floor_px,
                         ref_scale_median=model.ref_scale_median,
                         ref_scale_log_sd=model.ref_scale_log_sd, camera_terms=model.camera_terms,
                         orientation=model.orientation, horizon_line=model.horizon_line,
                         focal_length_px=model.focal_length_px, **model.ground_options, bounds=model.bounds,
                         default_temperature=model.default_temperature, corner_scale=model.corner_scale, **fixed)
    new.handedness = np.array(model.handedness, float)
    if model.pilot is not None:
        new.set_pilot(model.pilot)
    return new


def at_hands(model: MetrologyModel, hands: np.ndarray | None) -> MetrologyModel:
    """``model`` at each row's handedness ``hands`` ((n, m) ±1, a target sampled at both: each
    draw's own), to be evaluated on exactly those n rows; ``model`` itself for None."""
    return model if hands is None else model.at_handedness(hands)


def simulation_scale(model: MetrologyModel, i: int, options: dict) -> float:
    """The Student-t scale (pixels) a simulated set of dimension lines on target ``i`` is drawn
    with: one that scatters as the scene's sets do.

    A stated corner scale (the default 5 px, or the estimate's ``target_sigma``) is a t scale and
    is used as it is. A scale estimated from sets' spread is their sd, and a t(ν) of that scale
    scatters √(ν / (ν − 2)) times more than the sets did, which made the advice under-predict
    what one more set brings (docs/advice_method.md); so the scale is sd · √((ν − 2) / ν). A
    spread read from the scene's own sets is one, and so is the data set's (the scene's
    ``corner_scale``: what ``creference batch`` read from other frames' sets, or their residuals).
    """
    sigma, nu = float(model.sigma[i]), float(model.target_dof)
    from_spread = options.get("target_sigma") is None and (
        any(len(o.annotations) > 1 for o in model.objects) or model.corner_scale is not None)
    if from_spread and nu > 2.0:
        return sigma * float(np.sqrt((nu - 2.0) / nu))
    return sigma


class DimsObservation:
    """One more set of dimension lines on target ``i`` (module docstring)."""

    usable = True
    needs_scale = False

    def __init__(self, model: MetrologyModel, i: int, options: dict, temperature: float = 1.0):
        self.model, self.i, self.options, self.temperature = model, int(i), options, float(temperature)
        self.sigma = simulation_scale(model, self.i, options)
        self.corners = np.zeros((0, 4, 2))

    def simulate(self, rng, cams: np.ndarray, objs: np.ndarray, hands: np.ndarray | None = None) -> None:
        """One set per draw (M, 5), (M, m, 7) at its handedness (``hands`` (M, m), None: the
        model's); kept in :attr:`corners` (M, 4, 2)."""
        uv = at_hands(self.model, hands).project(cams, objs)[0][:, self.i]
        nu = self.model.target_dof
        g = rng.chisquare(nu, size=uv.shape[:2])
        # coordinates stored to 0.01 px, as annotation tools store them
        self.corners = np.round(uv + self.sigma * rng.standard_normal(uv.shape) * np.sqrt(nu / g)[..., None], 2)

    def model_with(self, k: int) -> MetrologyModel:
        """The model with the k-th simulated set."""
        return grown(self.model, self.options, annotations={self.i: self.corners[k]})

    def log_ratio(self, cams: np.ndarray, objs: np.ndarray, base: np.ndarray, hands: np.ndarray | None = None) -> np.ndarray:
        """(M, N) log p_new − log p_old at the draws (at their handedness ``hands`` (N, m), None:
        the model's); ``base`` (N,) the current model's negative log-posterior there.

        The two posteriors differ in the annotation terms of target i (its new set, its σᵢ) and of
        every object whose σ the new set changes (the pooled scale of those with one set) and, where
        the scene has references and the new σs move the reference lines' noise (``ref_line_sigma``),
        in the references': the difference is computed on those terms alone where the references'
        noise stays (the corners projected once for every future), on the whole posterior otherwise."""
        model = at_hands(self.model, hands)
        refs = len(self.model.all_references) > 0
        uv, old = None, {}
        out = np.empty((len(self.corners), len(cams)))
        for k in range(len(self.corners)):
            new = self.model_with(k)
            if refs and new.ref_line_sigma != self.model.ref_line_sigma:
                out[k] = base - at_hands(new, hands).neg_log_posterior(cams, objs, self.temperature)
                continue
            if uv is None:
                uv = model.project(cams, objs)[0]
            changed = np.flatnonzero((new.sigma != self.model.sigma) | (np.arange(len(new.sigma)) == self.i))
            delta = 0.0
            for j in changed:
                if j not in old:
                    old[j] = self.model.annotation_nll(uv[:, j], j)
                delta = delta + new.annotation_nll(uv[:, j], j) - old[j]
            out[k] = -delta / self.temperature
        return np.where(np.isfinite(out), out, -np.inf)


class ReferenceObservation:
    """One more reference like ``term`` (its value to be simulated; module docstring), stated as a
    range with probability ``range_share`` of relative precision ``range_precision``."""

    def __init__(self, model: MetrologyModel, term: ReferenceTerm, options: dict, *, range_share: float = 0.0,
                 range_precision: float = 0.25, temperature: float = 1.0):
        self.model, self.options, self.temperature = model, options, float(temperature)
        self.term = dataclasses.replace(term, index=len(model.all_references), low=1.0, high=1.0, is_range=False,
                                        confidence=None)
        self.range_share, self.range_precision = float(range_share), float(range_precision)
        self.probe = grown(model, options, references=[self.term])
        self.usable = self.probe.n_references_used == model.n_references_used + 1
        #: the scene has no crowd scale yet; this reference makes it a parameter
        self.needs_scale = bool(self.probe.camera_free[C_SCALE] and not model.camera_free[C_SCALE])
        #: the new reference's reading error (:attr:`~creference_bayes.models.metrology.MetrologyModel.ref_node_shift`)
        self.node_shift = self.probe.ref_node_shift[-1] if self.usable else np.zeros(1)
        self.node_var = self.probe.ref_node_var[-1] if self.usable else np.zeros(1)
        self.log_low = self.log_high = np.zeros(0)
        self.is_range = np.zeros(0, bool)

    def scale_draws(self, cams: np.ndarray, rng) -> np.ndarray:
        """``cams`` with crowd scales drawn from their prior (truncated to the bounds), for a scene
        without references (:attr:`needs_scale`)."""
        lo, hi = self.probe.camera_lower[C_SCALE], self.probe.camera_upper[C_SCALE]
        median, log_sd = self.probe.ref_scale_median, self.probe.ref_scale_log_sd
        s = np.exp(np.log(median) + log_sd * rng.standard_normal(len(cams)))
        while np.any(bad := (s < lo) | (s > hi)):
            s[bad] = np.exp(np.log(median) + log_sd * rng.standard_normal(int(bad.sum())))
        out = np.array(cams, float)
        out[:, C_SCALE] = s
        return out

    def reading(self, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
        """(N,) what the reference measures at the draws, in log-length (the model's reading)."""
        return self.probe.predicted_log_lengths(cams, objs)[:, -1]

    def simulate(self, rng, cams: np.ndarray, objs: np.ndarray, hands=None) -> None:
        """One stated value or range per draw (M, 5), (M, m, 7) (a reference reads no corner: any
        ``hands``)."""
        m = len(cams)
        b = rng.integers(len(self.node_shift), size=m)
        scale = np.sqrt(cams[:, C_SCALE] ** 2 + self.node_var[b])
        eps = rng.standard_t(self.model.ref_dof, size=m)
        # no worker is off by more than a factor 10⁴ (t₂ tails would give 0 or ∞ after rounding)
        log_v = self.reading(cams, objs) - self.node_shift[b] + np.clip(scale * eps, -_MAX_LOG_ERROR, _MAX_LOG_ERROR)
        self.is_range = rng.uniform(size=m) < self.range_share
        half = np.log1p(self.range_precision / 2), np.log1p(-min(self.range_precision, 1.9) / 2)
        # values as a worker states them (4 significant digits), never zero
        stated = lambda v: np.log(np.array([float(f"{x:.4g}") for x in np.exp(v)]))  # noqa: E731
        self.log_low = stated(np.where(self.is_range, log_v + half[1], log_v))
        self.log_high = stated(np.where(self.is_range, log_v + half[0], log_v))

    def model_with(self, k: int) -> MetrologyModel:
        """The model with the k-th simulated reference."""
        term = dataclasses.replace(self.term, low=float(np.exp(self.log_low[k])), high=float(np.exp(self.log_high[k])),
                                   is_range=bool(self.is_range[k]))
        return grown(self.model, self.options, references=[term])

    def log_ratio(self, cams: np.ndarray, objs: np.ndarray, base=None, hands=None) -> np.ndarray:
        """(M, N) the simulated references' log-likelihoods at the draws (over the temperature), as
        the model reads a reference (:meth:`~creference_bayes.models.metrology.MetrologyModel.reference_nll_matrix`)."""
        m = len(self.log_low)
        pred = np.repeat(self.reading(cams, objs)[:, None], m, axis=1)                  # (N, M)
        out = reading_log_likelihood(pred, cams[:, C_SCALE, None], self.log_low, self.log_high, self.is_range,
                                     self.model.ref_dof, np.broadcast_to(self.node_shift, (m, len(self.node_shift))),
                                     np.broadcast_to(self.node_var, (m, len(self.node_var)))).T / self.temperature
        return np.where(np.isfinite(out), out, -np.inf)


class _PriorObservation:
    """An answer that enters as a normal prior on some quantities q(draw) (module docstring):
    subclasses give :meth:`quantities` (N, d) and :attr:`sd` (d,)."""

    needs_scale = False

    def __init__(self, model: MetrologyModel):
        self.model = model
        self.values = np.zeros((0, len(self.sd)))

    @property
    def usable(self) -> bool:
        return len(self.sd) > 0

    def simulate(self, rng, cams: np.ndarray, objs: np.ndarray, hands=None) -> None:
        """One answer per draw (M, 5), (M, m, 7) (no corner: any ``hands``); kept in :attr:`values` (M, d)."""
        q = self.quantities(cams, objs)
        self.values = q + self.sd * rng.standard_normal(q.shape)

    def columns(self) -> np.ndarray:
        """(p,) where each quantity's working coordinate sits among the model's free parameters
        (the camera's, then each object's, as the samplers order them): a quantity is that
        coordinate plus what the others give (a size: the log-depth), so in the coordinates with the
        quantities in its place the density is the same (a unit Jacobian)."""
        cf, of = self.model.camera_free, self.model.object_free
        return np.array([int(cf[:c].sum()) if i is None else int(cf.sum() + of[:i].sum() + of[i, :c].sum())
                         for i, c in self._coordinates()], int)

    def moving(self) -> np.ndarray:
        """(d,) bool over the model's free parameters: those the answer moves directly, the camera's
        and its own object's (given the camera, the other objects do not depend on it)."""
        cf, of = self.model.camera_free, self.model.object_free
        own = np.zeros(of.shape, bool)
        for i, _ in self._coordinates():
            if i is not None:
                own[i] = of[i]
        return np.concatenate([np.ones(int(cf.sum()), bool), own[of]])

    def log_ratio(self, cams: np.ndarray, objs: np.ndarray, base=None, hands=None, values=None) -> np.ndarray:
        """(M, N) the simulated answers' (or ``values``') log-densities at the draws."""
        values = self.values if values is None else values
        z = (values[:, None, :] - self.quantities(cams, objs)[None]) / self.sd
        with np.errstate(invalid="ignore"):
            out = -0.5 * np.sum(z * z, axis=-1)
        return np.where(np.isfinite(out), out, -np.inf)


class SizeObservation(_PriorObservation):
    """Target ``i``'s size from a catalogue, log-sd ``log_sd`` (module docstring)."""

    def __init__(self, model: MetrologyModel, i: int, log_sd: float):
        self.i = int(i)
        self.free = np.asarray(model.object_free[self.i, O_SIZE], bool)
        self.sd = np.full(int(self.free.sum()), float(log_sd))
        super().__init__(model)

    def quantities(self, cams, objs):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(objs[:, self.i, O_SIZE][:, self.free])

    def _coordinates(self):  # (object or None, entry) of each quantity's working coordinate
        return [(self.i, c) for c in np.arange(7)[O_SIZE][self.free]]


class MountingObservation(_PriorObservation):
    """The camera's height, pitch and roll from its calibration, spreads ``sd`` ({"log_height",
    "pitch", "roll"}; module docstring)."""

    def __init__(self, model: MetrologyModel, sd: dict):
        cf = model.camera_free
        self.parts = [(C_HEIGHT, "log_height")] if model.use_height_prior and cf[C_HEIGHT] else []
        if model.orientation == "free":
            self.parts += [(c, n) for c, n in ((C_PITCH, "pitch"), (C_ROLL, "roll")) if cf[c]]
        self.sd = np.array([sd[n] for _, n in self.parts], float)
        super().__init__(model)

    def quantities(self, cams, objs):
        cols = [cams[:, c] for c, _ in self.parts]
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.parts and self.parts[0][0] == C_HEIGHT:
                cols[0] = np.log(cols[0])
        return np.stack(cols, axis=1) if cols else np.zeros((len(cams), 0))

    def _coordinates(self):
        return [(None, c) for c, _ in self.parts]
