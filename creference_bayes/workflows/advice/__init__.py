"""Whether one more annotation is worth its human time, and which (docs/advice.md).

For the current posterior of a target, each annotation the scene allows
(:mod:`creference_bayes.workflows.advice.candidates`) is weighed by preposterior simulation under the model's own noise
model: a draw of the parameters is taken as the truth, the new annotation is simulated from it
(:mod:`creference_bayes.workflows.advice.observe`), the other draws are reweighted by what it says (leave-one-out: the
simulating draw is left out), and the posterior after it is summarised; the average over draws
is the expected posterior after that annotation. Each future's HDI is set against the present's
as the same weights see it: a shortest interval estimated from weighted draws is too narrow, the
more so the fewer the effective draws (about 6 % at some 50 effective draws of 1000, and a
second set of dimension lines from one set typically keeps 5–10 % of 600), which would count as
a narrowing of every future whose weights are uneven. So each future's width is scaled by the
present on all draws over the present under that future's weights shuffled over the draws (the
same effective sample, nothing of what the annotation says;
:func:`~creference_bayes.workflows.advice.update.shuffled_hdi`), and the gain
is still now − expected. What is reported, per annotation:

- the expected width of the ``hdi_prob`` HDI of the ground distance (metres, and as a share of
  the distance: the ranking and the precision target use the share, so objects near and far
  compare fairly);
- the expected posterior sd of the location, √(var x + var y + var z), metres;
- the expected label quality P(IoU ≥ ``iou_threshold``) of the posterior-mean box;
- the expected gain (current share minus expected share, in percentage points of the distance)
  per minute of the annotation's cost.

Weights whose effective sample size collapses (fewer than
:data:`~creference_bayes.workflows.advice.update.MIN_ESS` or :data:`~creference_bayes.workflows.advice.update.MIN_ESS_FRACTION` of the draws) are
replaced by a tempered resample-move run to the new posterior (:func:`~creference_bayes.workflows.advice.update.tempered_update`),
and counted in ``fallbacks``.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ...inference.posterior import LogPosterior
from .candidates import Candidate, candidates as scene_candidates, format_mix
from .observe import ModelContext, observation_for
from .update import (MIN_ESS, MIN_ESS_FRACTION, location_sd, normalise, p_iou,
                            shuffled_hdi, tempered_update, weighted_hdi)

__all__ = ["AdviceSettings", "Outlook", "Prediction", "Advice", "advise_posterior"]


@dataclass(frozen=True)
class AdviceSettings:
    """How the advice is computed and what it recommends.

    Attributes
    ----------
    n_draws : posterior draws used (evenly thinned from all there are)
    n_futures : simulated annotations per candidate (the outer average)
    hdi_prob : probability of the distance's HDI
    target_hdi_width : stop when the HDI is at most this share of the distance (0.10 = 10 %)
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
    """Posterior precision, now or expected after one more annotation.

    Attributes
    ----------
    hdi_width_m : width of the distance's HDI, metres
    hdi_share : that width over the posterior median distance
    distance_m : posterior median distance, metres
    location_sd_m : √(var x + var y + var z), metres
    p_iou : P(IoU ≥ threshold) of the posterior-mean box
    """

    hdi_width_m: float
    hdi_share: float
    distance_m: float
    location_sd_m: float
    p_iou: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Prediction:
    """The expected effect of one candidate annotation.

    Attributes
    ----------
    candidate : the annotation
    expected : the expected :class:`Outlook` after it
    gain_pct : current minus expected HDI share, percentage points of the distance
    gain_se_pct : Monte Carlo standard error of ``gain_pct`` (from the simulated annotations and
        from the finite set of draws)
    gain_per_minute : ``gain_pct`` per minute of the annotation's cost
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
                "gain_pct": self.gain_pct, "gain_se_pct": self.gain_se_pct,
                "gain_per_minute": self.gain_per_minute, "ess_median": self.ess_median,
                "fallbacks": self.fallbacks}


@dataclass(frozen=True)
class Advice:
    """The advice for one target: the present, every candidate's prediction, a recommendation.

    Attributes
    ----------
    target : the target's id
    now : the current :class:`Outlook`
    predictions : best expected gain per minute first
    action : ``"collect"`` or ``"stop"``
    reason : why, in one sentence
    best : the recommended (or best) prediction, or None when nothing can be simulated
    settings, seed : what produced it
    notes : candidates left out and why
    seconds : wall time of the advice (without the estimate)
    """

    target: str
    now: Outlook
    predictions: tuple[Prediction, ...]
    action: str
    reason: str
    settings: AdviceSettings
    seed: object = None
    notes: tuple[str, ...] = ()
    seconds: float = 0.0
    format_mix: dict = field(default_factory=dict)

    @property
    def best(self) -> Prediction | None:
        return self.predictions[0] if self.predictions else None

    def to_dict(self) -> dict:
        best = self.best
        return {"format": "creference-advice/1", "target": self.target, "now": self.now.to_dict(),
                "action": self.action, "reason": self.reason,
                "recommended": best.candidate.key if self.action == "collect" and best else None,
                "predictions": [p.to_dict() for p in self.predictions],
                "format_mix": dict(self.format_mix), "notes": list(self.notes),
                "settings": self.settings.to_dict(), "seed": self.seed, "seconds": self.seconds}


def _outlooks(full: np.ndarray, weights: np.ndarray, sizes, settings: AdviceSettings, rng,
              iou_pairs: int | None = None) -> dict:
    """Per row of weights: HDI width and median of the distance, location sd, label quality
    (from ``iou_pairs`` resampled draws per row, default ``settings.iou_pairs``)."""
    dist = np.hypot(full[:, 0], full[:, 2])
    width, median = weighted_hdi(dist, weights, settings.hdi_prob)
    return {"hdi_width_m": width, "distance_m": median, "hdi_share": width / median,
            "location_sd_m": location_sd(full, weights),
            "p_iou": p_iou(full, weights, sizes, settings.iou_threshold, rng, iou_pairs or settings.iou_pairs)}


def _mean_outlook(rows: dict) -> Outlook:
    return Outlook(**{k: float(np.mean(v)) for k, v in rows.items()})


def advise_posterior(scene, draws: np.ndarray, *, handedness: int, map_params, setup=None, seed=None,
                     settings: AdviceSettings | None = None, candidates: list[Candidate] | None = None,
                     mixes: dict | None = None, progress: bool = False,
                     model_options: dict | None = None) -> Advice:
    """The advice for ``scene``'s target given posterior draws of the metrology model.

    Parameters
    ----------
    scene : the scene the posterior is of
    draws : (n, 7) posterior draws (x, y, z, yaw, focal_length_px, pitch, roll)
    handedness : the posterior's handedness (the MAP's)
    map_params : (7,) the MAP (the models' pilot)
    setup : the camera setup (:func:`~creference_bayes.camera_setup.setup_camera`; built if None)
    seed : int or Generator; the same seed gives the same advice
    settings : :class:`AdviceSettings`
    candidates : the annotations to weigh (default: all the scene allows)
    mixes : :class:`~creference_bayes.workflows.advice.candidates.FormatMix` by candidate key, for references to be stated
        otherwise than the scene's references are (default: the scene's mix for all)
    progress : a progress bar over the candidates on standard error
    model_options : metrology model settings the posterior was made with (``estimate``'s, e.g.
        ``line_reading="corrected"``); the models are rebuilt with them (default: the defaults)
    """
    t0 = time.perf_counter()
    settings = settings or AdviceSettings()
    if int(handedness) not in (1, -1):
        raise ValueError(f"handedness: expected 1 or -1, got {handedness!r}")
    if setup is None:
        from ...camera_setup import setup_camera

        setup = setup_camera(scene)
    rng = np.random.default_rng(seed)
    ctx = ModelContext(scene, setup, int(handedness), np.asarray(map_params, float),
                       options=dict(model_options or {}))
    model = ctx.model
    draws = np.atleast_2d(np.asarray(draws, float))
    if draws.shape[1:] != (7,) or len(draws) < 20:
        raise ValueError(f"draws: expected at least 20 posterior draws of 7 parameters, got shape {draws.shape}")
    if not np.all(np.isfinite(draws)):
        raise ValueError("draws: expected finite posterior draws, got NaN or infinity")
    keep = np.unique(np.linspace(0, len(draws) - 1, min(settings.n_draws, len(draws))).round().astype(int))
    inner = model.expand(draws[keep][:, model.free])  # fixed and derived parameters as the model has them
    n = len(inner)
    outer_idx = np.unique(np.linspace(0, n - 1, min(settings.n_futures, n)).round().astype(int))
    sizes = (scene.target.length, scene.target.width, scene.target.height)
    # the present from every draw (one row: the label quality against all of them)
    now = _mean_outlook(_outlooks(inner, np.full((1, n), 1.0 / n), sizes, settings, rng, iou_pairs=n))
    base_cost = model.cost(inner)
    crowd = model.crowd_scale_weights(inner)[1]
    mix = format_mix(scene)
    cands = scene_candidates(scene) if candidates is None else list(candidates)
    seeds = rng.integers(2**63, size=len(cands))
    predictions, notes = [], []
    from ...inference.progress import progress_bar

    with progress_bar(progress, len(cands), desc="advice", unit="annotation") as bar:
        for cand, s in zip(cands, seeds):
            pred = _predict(ctx, cand, (mixes or {}).get(cand.key, mix), inner, outer_idx,
                            (base_cost, crowd), sizes, now, settings, np.random.default_rng(s), notes)
            if pred is not None:
                predictions.append(pred)
            bar.update(1)
    predictions.sort(key=lambda p: -p.gain_per_minute)
    action, reason = _recommend(now, predictions, settings)
    return Advice(target=scene.target.id, now=now, predictions=tuple(predictions), action=action,
                  reason=reason, settings=settings, seed=seed if isinstance(seed, (int, type(None))) else None,
                  notes=tuple(notes), seconds=time.perf_counter() - t0, format_mix=mix.to_dict())


def _predict(ctx, cand, mix, inner, outer_idx, cached, sizes, now, settings, rng, notes):
    obs = observation_for(cand, ctx, mix)
    if getattr(obs, "usable", True) is False:
        notes.append(f"{cand.key}: not simulated: an end of its segment is on or above the horizon")
        return None
    obs.simulate(rng, inner[outer_idx])
    log_w = obs.log_ratio(inner, *cached)
    log_w[np.arange(len(outer_idx)), outer_idx] = -np.inf  # leave the simulating draw out
    weights, ess = normalise(log_w)
    rows = _outlooks(inner, weights, sizes, settings, rng)
    collapsed = np.flatnonzero(ess < max(MIN_ESS, MIN_ESS_FRACTION * len(inner)))
    for i in collapsed:  # recompute that future with the fallback
        new_model = ctx.model_of(obs.scene_with(i))
        old_lp, new_lp = LogPosterior(ctx.model), LogPosterior(new_model)
        moved, _ = tempered_update(old_lp, new_lp, inner[:, ctx.model.free], rng)
        full = new_model.expand(moved)
        one = _outlooks(full, np.full((1, len(full)), 1.0 / len(full)), sizes, settings, rng)
        for k in rows:
            rows[k][i] = one[k][0]
    # Each future against the present at its own weights (module docstring): scaled by the present
    # on all draws over that; fallback futures are equally weighted draws, as the present is.
    same_draws = np.ones(len(outer_idx), bool)
    same_draws[collapsed] = False
    present = shuffled_hdi(np.hypot(inner[:, 0], inner[:, 2]), weights, settings.hdi_prob, rng)
    rows["hdi_width_m"] = rows["hdi_width_m"] * np.where(same_draws, now.hdi_width_m / present[0], 1.0)
    rows["hdi_share"] = rows["hdi_share"] * np.where(same_draws, now.hdi_share / present[1], 1.0)
    expected = _mean_outlook(rows)
    gains = 100.0 * (now.hdi_share - rows["hdi_share"])
    gain = float(np.mean(gains))
    se_outer = np.std(gains, ddof=1) / np.sqrt(len(gains))
    keep = np.setdiff1d(np.arange(len(gains)), collapsed)
    se_inner = _split_se(inner, weights[keep], settings.hdi_prob, rng)
    return Prediction(candidate=cand, expected=expected, gain_pct=gain,
                      gain_se_pct=float(np.hypot(se_outer, se_inner)),
                      gain_per_minute=gain / (cand.seconds / 60.0) if cand.seconds > 0 else math.inf,
                      ess_median=float(np.median(ess) / len(inner)), fallbacks=int(len(collapsed)))


def _split_se(full: np.ndarray, weights: np.ndarray, prob: float, rng, n_splits: int = 3) -> float:
    """Standard error of the expected gain (points) from the finite set of draws: the gain computed
    on two random halves of the draws differs by about twice it (each half's variance is double)."""
    if not len(weights):
        return 0.0
    dist = np.hypot(full[:, 0], full[:, 2])
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
            g.append(100.0 * (now_w[0] / now_m[0] - np.mean(width / median)))
        sq.append((g[0] - g[1]) ** 2 / 4.0)
    return float(np.sqrt(np.mean(sq)))


def _recommend(now: Outlook, predictions: list[Prediction], settings: AdviceSettings) -> tuple[str, str]:
    share = 100.0 * now.hdi_share
    goal = 100.0 * settings.target_hdi_width
    if now.hdi_share <= settings.target_hdi_width:
        return "stop", (f"precision target met: the {settings.hdi_prob:.0%} HDI of the distance is "
                        f"{share:.1f} % of it (target {goal:g} %)")
    if not predictions:
        return "stop", "no annotation of this scene can be simulated"
    best = predictions[0]
    if best.gain_per_minute < settings.min_gain:
        return "stop", (f"the best expected gain, {best.gain_per_minute:.2f} points of the distance per "
                        f"minute ({best.candidate.description}), is below the minimum {settings.min_gain:g}")
    return "collect", (f"collect {best.candidate.description} next: expected HDI {share:.1f} % → "
                       f"{100 * best.expected.hdi_share:.1f} % of the distance, "
                       f"{best.gain_per_minute:.2f} points per minute")
