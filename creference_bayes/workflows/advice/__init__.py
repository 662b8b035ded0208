"""Whether one more annotation is worth its human time, and which (docs/advice.md).

For the posterior draws of a scene (one target or many), each observation the scene allows
(:mod:`.candidates`) is weighed by preposterior simulation under the model's own noise model
(:mod:`.observe`): a draw is taken as the truth, the new observation is simulated from it, the
other draws are reweighted by its likelihood (leave-one-out: the simulating draw is left out), and
the posterior after it is summarised; the average over draws is the expected posterior after that
observation. Each future's HDI is set against the present's as the same weights see it: a
shortest interval estimated from weighted draws is too narrow, the more so the fewer the
effective draws (about 6 % at some 50 effective draws of 1000, and a second set of dimension
lines from one set typically keeps 5–10 % of 600), which would count as a narrowing of every
future whose weights are uneven. So each future's width is scaled by the present on all draws
over the present under that future's weights shuffled over the draws (the same effective sample,
nothing of what the observation says; :func:`~.update.shuffled_hdi`). What is reported, per
target, now and expected after each observation:

- the width of the ``hdi_prob`` HDI of its ground distance (metres, and as a share of the
  distance: the gain and the precision target use the share, so targets near and far compare
  fairly);
- the posterior sd of its location, √(var x + var y + var z), metres;
- the label quality P(IoU ≥ ``iou_threshold``) of its posterior-mean box.

The gain of an observation is the narrowing of every target's HDI share, in percentage points
of its distance, summed over the scene's targets (for one target, its own), per minute of the
observation's cost; the observations are ranked by it. Weights whose effective sample size
collapses (fewer than :data:`~.update.MIN_ESS` or :data:`~.update.MIN_ESS_FRACTION` of the
draws) are replaced by a tempered resample-move run to the new posterior
(:func:`~.update.tempered_update`, in the sampler's working coordinates), counted in ``fallbacks``.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ...models.contract import C_HEIGHT, C_SCALE, O_GROUND, O_SIZE, O_X, O_YAW, O_Z
from .candidates import Candidate, candidates as scene_candidates, format_mix
from .observe import DimsObservation, ReferenceObservation
from .update import (MIN_ESS, MIN_ESS_FRACTION, location_sd, normalise, p_iou, shuffled_hdi, tempered_update,
                     weighted_hdi)

__all__ = ["AdviceSettings", "Outlook", "Prediction", "Advice", "advise"]


@dataclass(frozen=True)
class AdviceSettings:
    """How the advice is computed and what it recommends.

    Attributes
    ----------
    n_draws : posterior draws used (evenly thinned from all there are)
    n_futures : simulated observations per candidate (the outer average)
    hdi_prob : probability of the distance's HDI
    target_hdi_width : stop when every target's HDI is at most this share of its distance
        (0.10 = 10 %)
    min_gain : stop when the best expected gain is below this, percentage points of the distance
        per minute of human time
    iou_threshold : label quality is P(IoU ≥ this)
    iou_pairs : resampled draws per simulated future for the label quality
    """

    n_draws: int = 600
    n_futures: int = 150
    hdi_prob: float = 0.9
    target_hdi_width: float = 0.10
    min_gain: float = 0.5
    iou_threshold: float = 0.7
    iou_pairs: int = 16

    def __post_init__(self):
        for key, ok, what in (
                ("n_draws", self.n_draws >= 50, "an integer >= 50"),
                ("n_futures", 10 <= self.n_futures, "an integer >= 10"),
                ("hdi_prob", 0.0 < self.hdi_prob < 1.0, "a probability in (0, 1)"),
                ("target_hdi_width", self.target_hdi_width >= 0.0, "a share >= 0"),
                ("min_gain", self.min_gain >= 0.0, "a number >= 0"),
                ("iou_threshold", 0.0 < self.iou_threshold < 1.0, "a number in (0, 1)"),
                ("iou_pairs", self.iou_pairs >= 1, "an integer >= 1")):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and ok):
                raise ValueError(f"{key}: expected {what}, got {value!r}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Outlook:
    """Every target's posterior precision, now or expected after one more observation: (m,)
    arrays, one entry per target.

    Attributes
    ----------
    hdi_width_m : width of the distance's HDI, metres
    hdi_share : that width over the posterior median distance
    distance_m : posterior median distance, metres
    location_sd_m : √(var x + var y + var z), metres
    p_iou : P(IoU ≥ threshold) of the posterior-mean box
    """

    hdi_width_m: np.ndarray
    hdi_share: np.ndarray
    distance_m: np.ndarray
    location_sd_m: np.ndarray
    p_iou: np.ndarray

    def to_dict(self) -> dict:
        return {k: [round(float(x), 6) for x in v] for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Prediction:
    """The expected effect of one candidate observation.

    Attributes
    ----------
    candidate : the observation
    expected : the expected :class:`Outlook` after it
    gain_pct : the current minus the expected HDI shares, percentage points, summed over targets
    gain_se_pct : Monte Carlo standard error of ``gain_pct`` (from the simulated observations and
        from the finite set of draws)
    gain_per_minute : ``gain_pct`` per minute of the observation's cost
    ess_median : median effective sample size of the reweighted draws, as a share of the draws
    fallbacks : simulated futures whose weights collapsed and were recomputed (of ``n_futures``)
    """

    candidate: Candidate
    expected: Outlook
    gain_pct: float
    gain_se_pct: float
    gain_per_minute: float
    ess_median: float
    fallbacks: int

    def to_dict(self) -> dict:
        return {"candidate": self.candidate.to_dict(), "expected": self.expected.to_dict(),
                "gain_pct": self.gain_pct, "gain_se_pct": self.gain_se_pct, "gain_per_minute": self.gain_per_minute,
                "ess_median": self.ess_median, "fallbacks": self.fallbacks}


@dataclass(frozen=True)
class Advice:
    """The advice for a scene: every target's present, every candidate's prediction (best
    expected gain per minute first), a recommendation (``action`` ``collect`` or ``stop``, and
    ``reason``), ``notes`` on candidates left out, what produced it (``settings``, ``seed``,
    ``source``: ``posterior`` draws or ``laplace`` draws of the approximation at the MAP) and its
    wall time (``seconds``, without the estimate)."""

    targets: tuple[str, ...]
    now: Outlook
    predictions: tuple[Prediction, ...]
    action: str
    reason: str
    settings: AdviceSettings
    seed: object = None
    notes: tuple[str, ...] = ()
    seconds: float = 0.0
    source: str = "posterior"
    format_mix: dict = field(default_factory=dict)
    n_weighed: int = 0  #: the draws the advice weighed (at most ``settings.n_draws``: all there were)

    @property
    def best(self) -> Prediction | None:
        return self.predictions[0] if self.predictions else None

    def requests(self) -> list[Prediction | None]:
        """Each target's request: the best-ranked observation asked on it or on no target (a
        reference elsewhere, which helps every target), each at most once; None for a target whose
        precision target is met or whose best gain is below ``min_gain``."""
        taken, out = set(), []
        for i, share in enumerate(self.now.hdi_share):
            pick = None if share <= self.settings.target_hdi_width else next(
                (p for p in self.predictions if p.candidate.target in (i, None) and p.candidate.key not in taken), None)
            pick = pick if pick is not None and pick.gain_per_minute >= self.settings.min_gain else None
            if pick is not None:
                taken.add(pick.candidate.key)
            out.append(pick)
        return out

    def to_dict(self) -> dict:
        best = self.best
        return {"format": "creference-advice/2", "targets": list(self.targets), "now": self.now.to_dict(),
                "source": self.source, "action": self.action, "reason": self.reason,
                "recommended": best.candidate.key if self.action == "collect" and best else None,
                "requests": [None if p is None else p.candidate.key for p in self.requests()],
                "predictions": [p.to_dict() for p in self.predictions], "format_mix": dict(self.format_mix),
                "notes": list(self.notes), "settings": self.settings.to_dict(), "seed": self.seed,
                "draws_weighed": self.n_weighed, "seconds": self.seconds}


class _Draws:
    """The thinned draws and, per target, what the outlook summarises: distances (N, m),
    bottom centres (N, m, 3) and boxes (N, m, 7)."""

    def __init__(self, cams, objs):
        self.cams, self.objs = cams, objs
        self.dist = np.hypot(objs[..., O_X], objs[..., O_Z])
        y = cams[:, C_HEIGHT, None] - objs[..., O_GROUND]
        self.loc = np.stack([objs[..., O_X], y, objs[..., O_Z]], axis=-1)
        self.boxes = np.concatenate([self.loc, objs[..., O_YAW, None], objs[..., O_SIZE]], axis=-1)

    def outlooks(self, weights: np.ndarray, settings: AdviceSettings, rng, iou_pairs: int | None = None) -> dict:
        """Per row of weights (M, N) and target: HDI width, share and median of the distance,
        location sd, label quality; each (M, m)."""
        width, median = weighted_hdi(self.dist, weights, settings.hdi_prob)
        return {"hdi_width_m": width, "hdi_share": width / median, "distance_m": median,
                "location_sd_m": np.stack([location_sd(loc, weights) for loc in self.loc.transpose(1, 0, 2)], axis=1),
                "p_iou": p_iou(self.boxes, weights, settings.iou_threshold, rng, iou_pairs or settings.iou_pairs)}


def advise(model, scene, cams: np.ndarray, objs: np.ndarray, *, camera_map: np.ndarray, objects_map: np.ndarray,
           options: dict | None = None, temperature: float = 1.0, seed=None, settings: AdviceSettings | None = None,
           candidates: list[Candidate] | None = None, mixes: dict | None = None, source: str = "posterior",
           progress: bool = False) -> Advice:
    """The advice for ``scene`` given posterior draws of its metrology ``model``.

    Parameters
    ----------
    model : the scene's :class:`~creference_bayes.models.metrology.MetrologyModel` with the MAP's
        handedness and pilot (:func:`~creference_bayes.pipeline.rebuild_model`)
    scene : the scene
    cams, objs : (n, 5) and (n, m, 7) posterior draws (at least 20)
    camera_map, objects_map : (5,) and (m, 7) the MAP (where the candidates' segments are drawn)
    options : the estimate's model options (``provenance.options``); the models of the futures are
        built with them
    temperature : the posterior's temperature
    seed : int or Generator; the same seed gives the same advice
    settings : :class:`AdviceSettings`
    candidates : the observations to weigh (default: all the scene allows, :mod:`.candidates`)
    mixes : :class:`~.candidates.FormatMix` by candidate key, for references to be stated otherwise
        than the scene's are (default: the scene's mix for all)
    source : where the draws come from, ``posterior`` or ``laplace`` (reported)
    progress : a progress bar over the candidates on standard error
    """
    from ...inference.progress import progress_bar

    t0 = time.perf_counter()
    settings = settings or AdviceSettings()
    options = dict(options or {})
    rng = np.random.default_rng(seed)
    cams, objs = np.atleast_2d(np.asarray(cams, float)), np.asarray(objs, float)
    if len(cams) < 20 or objs.shape != (len(cams), model.n_objects, 7):
        raise ValueError(f"draws: expected at least 20 draws of a camera (5,) and {model.n_objects} objects "
                         f"(7,), got shapes {cams.shape} and {objs.shape}")
    if not (np.all(np.isfinite(cams)) and np.all(np.isfinite(objs))):
        raise ValueError("draws: expected finite posterior draws, got NaN or infinity")
    keep = np.unique(np.linspace(0, len(cams) - 1, min(settings.n_draws, len(cams))).round().astype(int))
    draws = _Draws(model.complete_camera(cams[keep]), objs[keep])
    n = len(keep)
    outer = np.unique(np.linspace(0, n - 1, min(settings.n_futures, n)).round().astype(int))
    # the present from every draw (one row: the label quality against all of them)
    now = Outlook(**{k: v[0] for k, v in draws.outlooks(np.full((1, n), 1.0 / n), settings, rng, n).items()})
    base = model.neg_log_posterior(draws.cams, draws.objs, temperature)
    notes = []
    if candidates is None:
        candidates, notes = scene_candidates(scene, model, np.asarray(camera_map, float),
                                             np.asarray(objects_map, float))
    mix = format_mix(scene)
    seeds = rng.integers(2**63, size=len(candidates))
    predictions = []
    with progress_bar(progress, len(candidates), desc="advice", unit="observation") as bar:
        for cand, s in zip(candidates, seeds):
            m = (mixes or {}).get(cand.key, mix)
            obs = (DimsObservation(model, cand.target, options, temperature) if cand.kind == "dims" else
                   ReferenceObservation(model, cand.term, options, range_share=m.range_share,
                                        range_precision=m.range_precision, temperature=temperature))
            if not obs.usable:
                notes.append(f"{cand.key}: not simulated: an end of its segment is on or above the horizon")
            else:
                predictions.append(_predict(obs, cand, draws, outer, base, now, settings, np.random.default_rng(s),
                                            temperature))
            bar.update(1)
    predictions.sort(key=lambda p: -p.gain_per_minute)
    action, reason = _recommend(now, predictions, settings, [t.id for t in scene.targets])
    return Advice(targets=tuple(t.id for t in scene.targets), now=now, predictions=tuple(predictions), action=action,
                  reason=reason, settings=settings, seed=seed if isinstance(seed, (int, type(None))) else None,
                  notes=tuple(notes), seconds=time.perf_counter() - t0, source=source, format_mix=mix.to_dict(),
                  n_weighed=n)


def _predict(obs, cand, draws: _Draws, outer, base, now: Outlook, settings, rng, temperature) -> Prediction:
    cams = obs.scale_draws(draws.cams, rng) if obs.needs_scale else draws.cams
    obs.simulate(rng, cams[outer], draws.objs[outer])
    log_w = obs.log_ratio(cams, draws.objs, base)
    log_w[np.arange(len(outer)), outer] = -np.inf  # leave the simulating draw out
    weights, ess = normalise(log_w)
    rows = draws.outlooks(weights, settings, rng)
    n = len(cams)
    collapsed = np.flatnonzero(ess < max(MIN_ESS, MIN_ESS_FRACTION * n))
    for i in collapsed:  # recompute those futures with the fallback
        one = _Draws(*_moved(obs, i, cams, draws.objs, rng, temperature)).outlooks(np.full((1, n), 1.0 / n),
                                                                                  settings, rng)
        for k in rows:
            rows[k][i] = one[k][0]
    # Each future against the present at its own weights (module docstring): scaled by the present
    # on all draws over that; fallback futures are equally weighted draws, as the present is.
    same = np.ones(len(outer), bool)
    same[collapsed] = False
    width, share = shuffled_hdi(draws.dist, weights, settings.hdi_prob, rng)
    rows["hdi_width_m"] = rows["hdi_width_m"] * np.where(same[:, None], now.hdi_width_m / width, 1.0)
    rows["hdi_share"] = rows["hdi_share"] * np.where(same[:, None], now.hdi_share / share, 1.0)
    expected = Outlook(**{k: v.mean(axis=0) for k, v in rows.items()})
    gains = 100.0 * np.sum(now.hdi_share - rows["hdi_share"], axis=1)
    gain = float(np.mean(gains))
    se_outer = np.std(gains, ddof=1) / np.sqrt(len(gains))
    se_inner = _split_se(draws.dist, weights[same], settings.hdi_prob, rng)
    return Prediction(candidate=cand, expected=expected, gain_pct=gain, gain_se_pct=float(np.hypot(se_outer, se_inner)),
                      gain_per_minute=gain / (cand.seconds / 60.0) if cand.seconds > 0 else math.inf,
                      ess_median=float(np.median(ess) / n), fallbacks=int(len(collapsed)))


def _moved(obs, i: int, cams: np.ndarray, objs: np.ndarray, rng, temperature: float):
    """The draws moved to the posterior after the i-th simulated observation by the tempered update
    (:func:`~.update.tempered_update`), in the working coordinates of the sampler
    (:mod:`~creference_bayes.inference.coords`: each object anchored to the image, so that the
    blocks barely correlate and random-walk moves go further than in natural coordinates), over
    the new model's free parameters; ``max(8, d)`` moves a stage for d of them, at most 32 (a
    random walk's mixing time grows with the dimension; 8 was chosen for one target)."""
    from ...inference.coords import CAMERA_LOG, WorkingCoords

    new = obs.model_with(i)
    coords = WorkingCoords(new)
    cf, of = new.camera_free, new.object_free
    logs = CAMERA_LOG & cf
    wc, wo = coords.to_work(cams, objs)

    def unpack(x):
        c, o = np.repeat(wc[:1], len(x), axis=0), np.repeat(wo[:1], len(x), axis=0)
        c[:, cf], o[:, of] = x[:, :cf.sum()], x[:, cf.sum():]
        return c, o

    def density(model, scale_prior: bool):  # log-posterior density in working coordinates
        def f(x):
            c, o = unpack(x)
            cn, on, jac = coords.from_work_jacobian(c, o)
            with np.errstate(all="ignore"):
                out = -model.neg_log_posterior(cn, on, temperature) + c[:, logs].sum(axis=1) + jac.sum(axis=1)
                if scale_prior:
                    out = out - _scale_prior(cn[:, C_SCALE])
            return np.where(np.isfinite(out), out, -np.inf)
        return f

    x = np.concatenate([wc[:, cf], wo[:, of]], axis=1)
    moved, _ = tempered_update(density(obs.model, obs.needs_scale), density(new, False), x, rng,
                               n_moves=int(min(32, max(8, x.shape[1]))))
    return coords.from_work(*unpack(moved))


def _scale_prior(s: np.ndarray) -> np.ndarray:
    """The crowd scale's negative log-prior (as
    :meth:`~creference_bayes.models.contract.Model.camera_neg_log_prior` has it)."""
    from ...models.contract import REF_SCALE_LOG_SD, REF_SCALE_MEDIAN

    with np.errstate(divide="ignore", invalid="ignore"):
        return 0.5 * ((np.log(s) - np.log(REF_SCALE_MEDIAN)) / REF_SCALE_LOG_SD) ** 2 + np.log(s)


def _split_se(dist: np.ndarray, weights: np.ndarray, prob: float, rng, n_splits: int = 3) -> float:
    """Standard error of the expected gain (points) from the finite set of draws: the gain computed
    on two random halves of the draws differs by about twice it (each half's variance is double).
    ``dist`` (N, m) the targets' distances."""
    if not len(weights):
        return 0.0
    n = len(dist)
    sq = []
    for _ in range(n_splits):
        half = rng.permutation(n) < n // 2
        g = []
        for part in (half, ~half):
            w = weights[:, part]
            total = w.sum(axis=1, keepdims=True)
            ok = total[:, 0] > 0
            width, median = weighted_hdi(dist[part], w[ok] / total[ok], prob)
            now_w, now_m = weighted_hdi(dist[part], np.full((1, part.sum()), 1.0 / part.sum()), prob)
            g.append(100.0 * np.sum(now_w[0] / now_m[0] - np.mean(width / median, axis=0)))
        sq.append((g[0] - g[1]) ** 2 / 4.0)
    return float(np.sqrt(np.mean(sq)))


def _recommend(now: Outlook, predictions: list[Prediction], settings: AdviceSettings, ids) -> tuple[str, str]:
    share, goal = 100.0 * now.hdi_share, 100.0 * settings.target_hdi_width
    widest = int(np.argmax(share))
    which = "" if len(ids) == 1 else f" (widest: {ids[widest]})"
    if np.all(now.hdi_share <= settings.target_hdi_width):
        return "stop", (f"precision target met: the {settings.hdi_prob:.0%} HDI of the distance is at most "
                        f"{share[widest]:.1f} % of it{which} (target {goal:g} %)")
    if not predictions:
        return "stop", "no annotation of this scene can be simulated"
    best = predictions[0]
    if best.gain_per_minute < settings.min_gain:
        return "stop", (f"the best expected gain, {best.gain_per_minute:.2f} points of the distance per "
                        f"minute ({best.candidate.description}), is below the minimum {settings.min_gain:g}")
    return "collect", (f"collect {best.candidate.description} next: expected HDI {share[widest]:.1f} % → "
                       f"{100 * best.expected.hdi_share[widest]:.1f} % of the distance{which}, "
                       f"{best.gain_per_minute:.2f} points per minute")
