"""Whether one more annotation is worth its human time, and which (docs/advice_method.md).

For the posterior draws of a scene (one target or many), each observation the scene allows
(:mod:`.candidates`) is weighed by preposterior simulation under the model's own noise model
(:mod:`.observe`): a draw is taken as the truth, the observation is simulated from it and the other
draws are reweighted by its likelihood (leave-one-out); the average over draws is the expected
posterior after it. A shortest interval from weighted draws is too narrow, the more so the fewer
the effective draws, so each future's HDI is scaled by the present on all draws over the present
under that future's weights shuffled over the draws (:func:`~.update.shuffled_hdi`). Reported per
target, now and expected after each observation: the width of the ``hdi_prob`` HDI of its ground
distance (metres, and as a share of the distance, so targets near and far compare fairly), the
posterior sd of its location √(var x + var y + var z) (metres), and the label quality
P(IoU ≥ ``iou_threshold``) in the labels' frame (now: the MAP box against the draws, as ``creference
labels`` states it; after: the reweighted posterior-mean box's, moved by the difference of the two
now).

``settings.objective`` says which gain ranks the requests:

- **labels** (the default): the expected number of the scene's labels that become good, a label
  being good when its P(IoU ≥ ``iou_threshold``) ≥ ``min_quality`` (as ``creference labels
  --score-iou --min-quality`` has it), per human hour. Per future, a target's P(IoU ≥ t) is
  estimated from ``iou_pairs`` resampled draws (less, for reweighted draws, the bias the same
  weights shuffled over the draws show); a label's chance of reaching the bar is the share of its
  futures at or above it once that estimate's binomial noise is taken out (:func:`good_chance`),
  the futures' mean change shrunk by its standard error (:func:`combined_chance`, the rule by
  which requests answered together are combined), so that neither the noise nor a change that
  says nothing counts. Labels that are good now count
  for nothing in the ranking (the advice says they are good); their chance of falling below the
  bar when the frame is estimated again is stated beside the gain (``good_loss``). Requests are
  ranked on half of the futures (:meth:`Prediction.value`) and their ``good_gain``, ``good_loss``
  and ``p_good`` stated from the other half, so that the chosen requests' gains are not flattered
  by the noise that chose them;
- **hdi**: the narrowing of every target's HDI share, in percentage points of its distance, summed
  over the targets, per minute;
- **location**: the drop of every target's location sd √(var x + var y + var z), in percentage
  points of its distance, summed over the targets, per minute. It stops as **hdi** does. Of the
  three it is the one whose adaptive policy reaches the paper's design of five sets of lines and
  five references at three quarters of its human time on paper-like scenes as well as outdoors
  (docs/studies/advice.md, "The adaptive policy").

:meth:`Advice.verdicts` says per target what would lift its label to the bar. Futures whose
effective sample size collapses (below :data:`~.update.MIN_ESS` or :data:`~.update.MIN_ESS_FRACTION`
of the draws) are recomputed on draws moved to the new posterior (:func:`_moved`), counted in
``fallbacks``.

The requests are raced (docs/advice_method.md, "The race"): each is weighed on every
``race_every``-th future first, and on each next share only while it might still change the plan
or a label's verdict at the bounds of the futures it has (:func:`_contenders`); one that left
early is ``dropped``, ranked after the others and asked by no plan.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ...inference.threads import single_threaded_blas
from ...models.contract import C_HEIGHT, C_SCALE, CAMERA_NAMES, O_GROUND, O_X, O_Z
from .candidates import Candidate, candidates as scene_candidates, format_mix, object_name
from .answers import CATALOGUE_LOG_SD, MOUNTING_SD
from .fallback import block_sweeps
from .observe import DimsObservation, MountingObservation, ReferenceObservation, SizeObservation, at_hands
from .update import (MIN_ESS, MIN_ESS_FRACTION, gaussian_transport, informative, location_sd, normalise, p_iou,
                     shuffled_hdi, tempered_update, weighted_hdi)

__all__ = ["OBJECTIVES", "KINDS", "AdviceSettings", "Outlook", "Prediction", "Advice", "advise", "good_chance", "combined_chance",
           "futures_scale",
           "Moments", "rank_key"]

#: What the advice ranks requests by (:class:`AdviceSettings`).
OBJECTIVES = ("labels", "hdi", "location")
#: The kinds of request (:class:`~.candidates.Candidate`).
KINDS = ("dims", "reference", "size", "mounting")
#: Resamples of the futures behind a good-label gain's standard error.
_BOOTSTRAPS = 20
#: Draws a collapsed future is recomputed on (:func:`_moved`), evenly thinned from those weighed
#: (its HDI is read against the present's on the same draws): the fallbacks' cost grows with them
#: (docs/studies/advice.md, "Speed of the advice on a frame").
FALLBACK_DRAWS = 250
#: A prior answer's carried draws (:func:`_moved`) are kept, weighted, where their effective sample
#: size is at least this share of them; below it they start the block sweeps (docs/studies/advice.md,
#: "The fallback's transport").
TRANSPORT_ESS_SHARE = 0.1
#: The race (:func:`advise`) is run when each of its rounds holds at least this many futures.
RACE_MIN_FUTURES = 20
#: The standard errors of a request's bounds in the race (:func:`_bounds`, :func:`_contenders`).
RACE_Z = 2.0


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
    objective : how requests are ranked and when to stop: ``"labels"`` (expected labels that
        become good, a label being good when its P(IoU ≥ ``iou_threshold``) ≥ ``min_quality``, per
        human hour), ``"hdi"`` (narrowing of the distances' HDIs per minute) or ``"location"`` (drop of
        the locations' sd per minute; both in points of the distance)
    min_quality : the label quality a good label has (``labels --min-quality``)
    min_good_per_hour : with the labels objective, stop when the best request is expected to make
        fewer labels good than this per human hour
    kinds : the kinds of request to weigh (of :data:`KINDS`: a team whose crowd draws no
        references leaves ``reference`` out)
    race_every : the race's rounds: the first weighs every request on every ``race_every``-th
        simulated future (odd, so that each round holds futures of both halves), each of the others
        the next share only for the requests that might still be worth asking or lift a label
        (:func:`advise`); 1: every request on all of them
    """

    n_draws: int = 600
    n_futures: int = 150
    hdi_prob: float = 0.9
    target_hdi_width: float = 0.10
    min_gain: float = 0.5
    iou_threshold: float = 0.7
    iou_pairs: int = 16
    objective: str = "labels"
    min_quality: float = 0.5
    min_good_per_hour: float = 1.0
    kinds: tuple[str, ...] = ("dims", "reference", "size", "mounting")
    race_every: int = 3

    def __post_init__(self):
        for key, ok, what in (
                ("n_draws", self.n_draws >= 50, "an integer >= 50"),
                ("n_futures", 10 <= self.n_futures, "an integer >= 10"),
                ("hdi_prob", 0.0 < self.hdi_prob < 1.0, "a probability in (0, 1)"),
                ("target_hdi_width", self.target_hdi_width >= 0.0, "a share >= 0"),
                ("min_gain", self.min_gain >= 0.0, "a number >= 0"),
                ("iou_threshold", 0.0 < self.iou_threshold < 1.0, "a number in (0, 1)"),
                ("iou_pairs", self.iou_pairs >= 1, "an integer >= 1"),
                ("min_quality", 0.0 < self.min_quality <= 1.0, "a probability in (0, 1]"),
                ("min_good_per_hour", self.min_good_per_hour >= 0.0, "a number >= 0"),
                ("race_every", isinstance(self.race_every, int) and self.race_every >= 1 and self.race_every % 2 == 1,
                 "an odd integer >= 1")):
            value = getattr(self, key)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and ok):
                raise ValueError(f"{key}: expected {what}, got {value!r}")
        bad = [k for k in self.kinds if k not in KINDS]
        if bad or not self.kinds:
            raise ValueError(f"kinds: expected some of {list(KINDS)}, got {list(self.kinds)!r}")
        object.__setattr__(self, "kinds", tuple(self.kinds))
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective: expected one of {list(OBJECTIVES)}, got {self.objective!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    def worth(self, value: float, seconds: float) -> bool:
        """Whether a request of ``value`` (:meth:`Prediction.value`) is worth ``seconds`` of human
        time: ``min_good_per_hour`` good labels per hour, or ``min_gain`` points per minute (HDI or
        location sd, by the objective)."""
        if self.objective == "labels":
            return value * 3600.0 >= self.min_good_per_hour * seconds
        return value * 60.0 >= self.min_gain * seconds


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
    p_iou : P(IoU ≥ threshold) of the label (module docstring)
    """

    hdi_width_m: np.ndarray
    hdi_share: np.ndarray
    distance_m: np.ndarray
    location_sd_m: np.ndarray
    p_iou: np.ndarray

    def to_dict(self) -> dict:
        return {k: [round(float(x), 6) for x in v] for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Moments:
    """What one request is expected to do to each label's P(IoU ≥ t), on the scale of its futures
    (the posterior-mean box's): (m,) arrays.

    Attributes
    ----------
    change : the futures' mean minus the present
    change_se : its Monte Carlo standard error (the futures' scatter and the bias correction's)
    spread : the variance of the futures' P(IoU ≥ t) (the fitted beta's, :func:`good_chance`)
    """

    change: np.ndarray
    change_se: np.ndarray
    spread: np.ndarray

    def to_dict(self) -> dict:
        return {k: [round(float(x), 6) for x in v] for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "Moments":
        return cls(**{k: np.asarray(d[k], float) for k in ("change", "change_se", "spread")})

    def shrunk(self) -> np.ndarray:
        """(m,) ``change`` shrunk by its standard error, Δ · Δ² / (Δ² + se²): a change within its
        own noise counts for little (:func:`combined_chance`)."""
        d2, s2 = self.change ** 2, self.change_se ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(d2 > 0, self.change * d2 / (d2 + s2), 0.0)


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
    location_gain_pct : the current minus the expected location sd (:class:`Outlook`) as a share of
        the current distance, percentage points, summed over targets
    ess_median : median effective sample size of the reweighted draws, as a share of the draws
    fallbacks : simulated futures whose weights collapsed and were recomputed (of ``n_futures``)
    p_good : (m,) each target's chance that its label is good after it (module docstring)
    good_gain : the expected number of labels below the bar now that reach it (``p_good`` summed
        over them)
    good_gain_se : its Monte Carlo standard error
    good_per_hour : ``good_gain`` per human hour of the observation's cost
    good_loss : the expected number of labels good now that fall below the bar when the frame is
        estimated again with it (``1 − p_good`` summed over them). It is stated, not ranked by: the
        requests are ranked by the labels they lift (module docstring)
    moments : :class:`Moments` of each label's future after it, from the futures ``p_good`` is
        stated from; ``rank_moments`` from those the requests are ranked by. Requests answered
        together are combined by them (:func:`combined_chance`; ``p_good`` is that of it alone)
    futures : the simulated futures it was weighed on
    dropped : it left the race before its last round (:func:`advise`): weighed on fewer futures, as
        one that could change neither the plan nor a label's verdict
    """

    candidate: Candidate
    expected: Outlook
    gain_pct: float
    gain_se_pct: float
    gain_per_minute: float
    ess_median: float
    fallbacks: int
    p_good: np.ndarray = field(default_factory=lambda: np.zeros(0))
    good_gain: float = 0.0
    good_gain_se: float = 0.0
    good_per_hour: float = 0.0
    rank_p_good: np.ndarray | None = None
    rank_good_gain: float | None = None
    good_loss: float = 0.0
    moments: Moments | None = None
    rank_moments: Moments | None = None
    location_gain_pct: float = 0.0
    futures: int = 0
    dropped: bool = False

    def to_dict(self) -> dict:
        return {"candidate": self.candidate.to_dict(), "expected": self.expected.to_dict(),
                "gain_pct": self.gain_pct, "gain_se_pct": self.gain_se_pct, "gain_per_minute": self.gain_per_minute,
                "location_gain_pct": self.location_gain_pct,
                "p_good": [round(float(x), 6) for x in self.p_good], "good_gain": self.good_gain,
                "good_gain_se": self.good_gain_se, "good_per_hour": self.good_per_hour, "good_loss": self.good_loss,
                "rank_good_gain": self.rank_good_gain,
                "rank_p_good": None if self.rank_p_good is None else [round(float(x), 6) for x in self.rank_p_good],
                "moments": None if self.moments is None else self.moments.to_dict(),
                "rank_moments": None if self.rank_moments is None else self.rank_moments.to_dict(),
                "ess_median": self.ess_median, "fallbacks": self.fallbacks, "futures": self.futures,
                "dropped": self.dropped}

    def value(self, objective: str) -> float:
        """What the requests are chosen by: good labels (from the futures that rank, where they
        were kept apart from those ``good_gain`` is stated from: module docstring), HDI points or
        location-sd points summed over the targets."""
        if objective == "hdi":
            return self.gain_pct
        if objective == "location":
            return self.location_gain_pct
        return self.good_gain if self.rank_good_gain is None else self.rank_good_gain

    def score(self, objective: str) -> float:
        """What the requests are ranked by: :meth:`value` per human hour (labels), or points per
        minute (hdi, location)."""
        if objective == "hdi":
            return self.gain_per_minute
        per = 3600.0 if objective == "labels" else 60.0
        return self.value(objective) * per / self.candidate.seconds if self.candidate.seconds > 0 else math.inf

    def ranking_p_good(self) -> np.ndarray:
        """(m,) the chances the verdicts pick a request by (``p_good`` stated from other futures)."""
        return self.p_good if self.rank_p_good is None else self.rank_p_good


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
    #: (m,) each label's P(IoU ≥ t) less its posterior-mean box's, the scale the futures are on
    #: (:class:`Moments`); None: no difference
    shift: np.ndarray | None = None
    #: (m,) the targets as the texts name them (their class and id, :func:`~.candidates.object_name`);
    #: empty: their ids
    names: tuple[str, ...] = ()

    @property
    def labels(self) -> tuple[str, ...]:
        """The targets as the texts name them (:attr:`names`, else the ids)."""
        return self.names or self.targets

    def futures_scale(self) -> tuple[np.ndarray, np.ndarray]:
        """(base, bar), each (m,): the present and the bar on the futures' scale
        (:func:`combined_chance`)."""
        return futures_scale(self.now.p_iou, self.shift, self.settings.min_quality)

    @property
    def best(self) -> Prediction | None:
        return self.predictions[0] if self.predictions else None

    @property
    def good(self) -> np.ndarray:
        """(m,) whether each target's label is good now: P(IoU ≥ ``iou_threshold``) ≥ ``min_quality``."""
        return self.now.p_iou >= self.settings.min_quality

    def _needs(self, i: int) -> bool:
        if self.settings.objective == "labels":
            return not self.good[i]
        return self.now.hdi_share[i] > self.settings.target_hdi_width

    def _worth(self, p: Prediction) -> bool:
        """Whether ``p`` is worth asking: not dropped in the race (:func:`advise`) and worth its
        time (:meth:`AdviceSettings.worth`)."""
        return not p.dropped and self.settings.worth(p.value(self.settings.objective), p.candidate.seconds)

    def requests(self) -> list[Prediction | None]:
        """Each target's request: the best-ranked observation asked on it or on no target (a
        reference elsewhere or the mounting, which help every target), each at most once; None for
        a target that needs none (its label is good, or with the HDI objective its precision
        target is met) or whose best request is not worth its time (``min_good_per_hour``,
        ``min_gain``)."""
        taken, out = set(), []
        for i in range(len(self.targets)):
            pick = None if not self._needs(i) else next(
                (p for p in self.predictions if p.candidate.target in (i, None) and p.candidate.key not in taken), None)
            pick = pick if pick is not None and self._worth(pick) else None
            if pick is not None:
                taken.add(pick.candidate.key)
            out.append(pick)
        return out

    def verdicts(self) -> list[dict]:
        """Per target, what would lift its label to the bar (``min_quality``): ``verdict`` is
        ``good`` (it is already), ``lift`` (a request that is more likely than not to lift it:
        ``best``) or ``none`` (no single request is); ``p_now``, the best request's ``p_expected``
        (expected P(IoU ≥ t) after it) and ``chance`` (that it reaches the bar), and ``text``."""
        s, out = self.settings, []
        t, q = f"P(IoU ≥ {s.iou_threshold:g})", s.min_quality
        for i, tid in enumerate(self.targets):  # the key is the id; the texts name the request's object
            p_now = float(self.now.p_iou[i])
            row = {"target": tid, "p_now": p_now, "verdict": "good", "best": None, "p_expected": None,
                   "chance": None, "text": f"good: {t} {p_now:.2f} ≥ {q:g}"}
            mine = [p for p in self.predictions if p.candidate.target in (i, None)]
            if not self.good[i] and mine:
                best = max(mine, key=lambda p: (round(float(p.ranking_p_good()[i]), 3), float(p.expected.p_iou[i]),
                                                -p.candidate.seconds))
                dims = next((p for p in mine if p.candidate.kind == "dims" and p.candidate.target == i), None)
                chance, p_exp = float(best.p_good[i]), float(best.expected.p_iou[i])
                lifts = chance >= 0.5
                row.update(verdict="lift" if lifts else "none", best=best.candidate.key, p_expected=p_exp,
                           chance=chance)
                head = (f"{best.candidate.description} would lift it" if lifts else
                        f"no single request lifts it; the best, {best.candidate.description}, gives")
                row["text"] = f"{head}: {t} {p_now:.2f} → {p_exp:.2f} (chance {chance:.2f} of ≥ {q:g})"
                if dims is not None and dims is not best:
                    row["text"] += (f"; more dimension lines: {t} {p_now:.2f} → {float(dims.expected.p_iou[i]):.2f} "
                                    f"(chance {float(dims.p_good[i]):.2f})")
            elif not self.good[i]:
                row.update(verdict="none", text=f"below the bar ({t} {p_now:.2f} < {q:g}); no request can be simulated")
            out.append(row)
        return out

    def to_dict(self) -> dict:
        best = self.best
        return {"format": "creference-advice/2", "targets": list(self.targets), "now": self.now.to_dict(),
                "source": self.source, "action": self.action, "reason": self.reason,
                "recommended": best.candidate.key if self.action == "collect" and best else None,
                "requests": [None if p is None else p.candidate.key for p in self.requests()],
                "verdicts": self.verdicts(),
                "predictions": [p.to_dict() for p in self.predictions], "format_mix": dict(self.format_mix),
                "notes": list(self.notes), "settings": self.settings.to_dict(), "seed": self.seed,
                "draws_weighed": self.n_weighed, "seconds": self.seconds,
                "shift": None if self.shift is None else [round(float(x), 6) for x in self.shift]}


class _Draws:
    """The thinned draws and, per target, what the outlook summarises: distances (N, m),
    bottom centres (N, m, 3) and boxes (N, m, 7) in the labels' frame (``creference labels``':
    a KITTI scene's camera frame), so that a future's P(IoU ≥ t) is the one the labels will state.
    In the ground's frame a box moves with the camera's height and pitch, which the image does not
    tie down; in the camera's frame the image pins its direction. On KITTI frames the ground's
    frame understated the present's label quality by 0.07 on average, and a mounting, which pins
    height and pitch, took that away: the advice promised it as a gain (docs/studies/advice.md)."""

    def __init__(self, cams, objs, scene, hands=None):
        from ..labels.kitti import kitti_poses

        self.cams, self.objs, self.scene = cams, objs, scene
        self.hands = hands  # (N, m) each draw's handedness where it varies (None: the model's)
        self.dist = np.hypot(objs[..., O_X], objs[..., O_Z])
        self.order = np.argsort(self.dist, axis=0).T  # each target's draws by distance, sorted once for every HDI
        y = cams[:, C_HEIGHT, None] - objs[..., O_GROUND]
        self.loc = np.stack([objs[..., O_X], y, objs[..., O_Z]], axis=-1)
        self.boxes = kitti_poses(scene, cams, objs)

    def outlooks(self, weights: np.ndarray, settings: AdviceSettings, rng, iou_pairs: int | None = None,
                 read: np.ndarray | None = None, unread: Outlook | None = None) -> dict:
        """Per row of weights (M, N) and target: HDI width, share and median of the distance,
        location sd, label quality; each (M, m). ``read`` (m,) the targets whose distance is read
        from the weights (default: all); the others' HDI and median are ``unread``'s (the present,
        where the weights say nothing about their distance: :func:`~.update.informative`)."""
        if read is None:
            width, median = weighted_hdi(self.dist, weights, settings.hdi_prob, self.order)
        else:
            width, median = (np.tile(x, (len(weights), 1)) for x in (unread.hdi_width_m, unread.distance_m))
            width[:, read], median[:, read] = weighted_hdi(self.dist[:, read], weights, settings.hdi_prob,
                                                           self.order[read])
        return {"hdi_width_m": width, "hdi_share": width / median, "distance_m": median,
                "location_sd_m": np.stack([location_sd(loc, weights) for loc in self.loc.transpose(1, 0, 2)], axis=1),
                "p_iou": p_iou(self.boxes, weights, settings.iou_threshold, rng, iou_pairs or settings.iou_pairs)}


@single_threaded_blas()  # its fits and small solves: a threaded BLAS only spins (inference/threads.py)
def advise(model, scene, cams: np.ndarray, objs: np.ndarray, *, camera_map: np.ndarray, objects_map: np.ndarray,
           options: dict | None = None, temperature: float = 1.0, seed=None, settings: AdviceSettings | None = None,
           candidates: list[Candidate] | None = None, mixes: dict | None = None, source: str = "posterior",
           progress: bool = False, label_draws: tuple[np.ndarray, np.ndarray] | None = None,
           hands: np.ndarray | None = None, workers: int = 1) -> Advice:
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
    label_draws : (cameras, objects) the labels' quality now is stated from, when not ``cams`` and
        ``objs`` (a held focal length's shared scale: :func:`~.inputs.advise_result`)
    hands : (n, m) each draw's handedness (±1) where the posterior sampled a target at both
        (:attr:`~creference_bayes.inference.chains.Draws.handedness`); every draw is weighed, and
        its futures simulated, at its own (None: the model's)
    workers : processes forked from this one that weigh the requests at once (:class:`_Forked`;
        the same advice whatever their number)
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
    if hands is not None:
        hands = np.asarray(hands, float)
        if hands.shape != (len(cams), model.n_objects) or not np.all(np.isin(hands, (-1.0, 1.0))):
            raise ValueError(f"hands: expected ({len(cams)}, {model.n_objects}) values of 1 or -1, got shape "
                             f"{hands.shape}")
    keep = np.unique(np.linspace(0, len(cams) - 1, min(settings.n_draws, len(cams))).round().astype(int))
    if hands is not None:
        hands = None if np.all(hands[keep] == model.handedness) else hands[keep]
    draws = _Draws(model.complete_camera(cams[keep]), objs[keep], scene, hands)
    n = len(keep)
    outer = np.unique(np.linspace(0, n - 1, min(settings.n_futures, n)).round().astype(int))
    # the present from every draw (one row: the label quality against all of them)
    now = Outlook(**{k: v[0] for k, v in draws.outlooks(np.full((1, n), 1.0 / n), settings, rng, n).items()})
    # the label's quality as creference labels states it (its MAP box against the draws); a future's
    # is its posterior-mean box's, moved by what separates the two now
    label_p = _label_quality(scene, camera_map, objects_map, *(label_draws or (cams, objs)), settings.iou_threshold)
    shift = label_p - now.p_iou
    now = dataclasses.replace(now, p_iou=label_p)
    base = at_hands(model, draws.hands).neg_log_posterior(draws.cams, draws.objs, temperature)
    if not np.all(np.isfinite(base)):  # outside the model's bounds: not a draw of this scene's posterior
        bad = int(keep[np.flatnonzero(~np.isfinite(base))[0]])
        camera = ", ".join(f"{k} {v:.4g}" for k, v in zip(CAMERA_NAMES, cams[bad]))
        raise ValueError(f"draws: {int(np.sum(~np.isfinite(base)))} of the {n} draws weighed lie outside the model's "
                         f"bounds (draw {bad}: camera {camera}); they are not draws of this scene's posterior")
    _check_placeable(model, draws, keep)
    notes = []
    if candidates is None:
        candidates, notes = scene_candidates(scene, model, np.asarray(camera_map, float),
                                             np.asarray(objects_map, float))
        candidates = [c for c in candidates if c.kind in settings.kinds]
    if (any(c.kind == "dims" for c in candidates) and "target_sigma" not in options and scene.corner_scale is None
            and all(len(t.corners) == 1 for t in scene.targets)):
        from ...models.metrology import DEFAULT_TARGET_SIGMA_PX

        notes.append(f"the crowd's corner scale is assumed ({DEFAULT_TARGET_SIGMA_PX:g} px): no object has two sets of "
                     "lines, here or (creference batch) elsewhere in the data set, and what new lines are worth "
                     "depends on it")
    if model.location.distance_m is not None and any(c.kind == "reference" for c in candidates):
        lo, hi = model.location.distance_m
        notes.append(f"estimated with a distance range ({lo:g}–{hi:g} m), which does part of a reference's work: a "
                     "reference may realise less than stated (about half on simulated outdoor scenes, nothing with a "
                     "heavy-tailed crowd; docs/studies/advice.md, 'A range as a user would state it')")
    mix = format_mix(scene)
    seeds = rng.integers(2**63, size=len(candidates))
    weighings = []
    for cand, s in zip(candidates, seeds):
        m = (mixes or {}).get(cand.key, mix)
        obs = (DimsObservation(model, cand.target, options, temperature) if cand.kind == "dims" else
               SizeObservation(model, cand.target, CATALOGUE_LOG_SD) if cand.kind == "size" else
               MountingObservation(model, MOUNTING_SD) if cand.kind == "mounting" else
               ReferenceObservation(model, cand.term, options, range_share=m.range_share,
                                    range_precision=m.range_precision, temperature=temperature))
        if obs.usable:
            weighings.append(_Weighing(obs, cand, draws, outer, base, np.random.default_rng(s), temperature))
        else:
            notes.append(f"{cand.key}: not simulated: an end of its segment is on or above the horizon")
    # the race (module docstring): every request on every race_every-th future first, then round by
    # round on the next share only those that might still change the plan or a label's verdict
    positions = np.arange(len(outer))
    rounds = [positions[k::settings.race_every] for k in range(settings.race_every)]
    if len(rounds[-1]) < RACE_MIN_FUTURES:
        rounds = [positions]
    with progress_bar(progress, len(weighings) * len(rounds), desc="advice", unit="observation") as bar, \
            _Forked(weighings, workers) as pool:
        alive = np.ones(len(weighings), bool)
        for k, pos in enumerate(rounds):
            if k:  # those out of the race stay out
                alive &= _contenders(weighings, now, shift, settings, pool.bounds)
            pool.weigh(np.flatnonzero(alive), pos, now, settings, bar, (now, shift) if k + 1 < len(rounds) else None)
            bar.update(int(np.sum(~alive)))
        predictions = pool.predictions(now, shift, settings, len(outer))
    predictions.sort(key=rank_key(settings.objective))
    names = tuple(object_name(t) for t in scene.targets)
    action, reason = _recommend(now, predictions, settings, names)
    return Advice(targets=tuple(t.id for t in scene.targets), now=now, predictions=tuple(predictions), action=action,
                  reason=reason, settings=settings, seed=seed if isinstance(seed, (int, type(None))) else None,
                  notes=tuple(notes), seconds=time.perf_counter() - t0, source=source, format_mix=mix.to_dict(),
                  n_weighed=n, shift=shift, names=names)


#: The weighings a forked worker process of :class:`_Forked` inherits (None in other processes).
_FORKED: list | None = None


class _Forked:
    """The race's requests weighed in ``workers`` processes forked from this one, each inheriting
    every weighing (its model, draws and simulated outcomes); per round a worker weighs its share
    and sends back each one's new futures, which random state it left and whose distances it reads,
    so that the weighings are the same as in one process, and the advice the same whatever the
    workers. One worker, or a system other than Linux (where a forked process may hang in the
    system's BLAS): the requests one after another here."""

    def __init__(self, weighings: list, workers: int):
        import multiprocessing

        self.weighings, self.pool = weighings, None
        self.workers = min(int(workers), len(weighings))
        #: each weighing's :func:`_bounds` after its last round, where a worker computed them
        self.bounds: list[dict | None] = [None] * len(weighings)
        if self.workers > 1 and sys.platform.startswith("linux"):  # fork is safe with NumPy's BLAS there
            from concurrent.futures import ProcessPoolExecutor

            global _FORKED
            _FORKED = weighings  # inherited at each fork (the pool forks its workers as it needs them)
            self.pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("fork"),
                                            initializer=_forked_ready)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        global _FORKED
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)
            _FORKED = None
        return False

    def _shares(self, idx: np.ndarray) -> list[np.ndarray]:
        """``idx`` in about four jobs a worker: requests differ in cost (a size's fallbacks, a
        reference's), and a worker done early takes the next job."""
        return [part for part in np.array_split(np.asarray(idx, int), 4 * self.workers) if len(part)]

    def weigh(self, idx: np.ndarray, pos: np.ndarray, now, settings, bar, race=None) -> None:
        """Weigh the futures at ``pos`` of the weighings ``idx``; ``race`` (now, shift): a worker
        also gives each one's :func:`_bounds` for the next round (:func:`_contenders`)."""
        if self.pool is None:
            for i in idx:
                self.weighings[i].weigh(pos, now, settings)
                bar.update(1)
            return
        ws = self.weighings  # the futures so far go along only where the bounds need them
        jobs = [self.pool.submit(_weigh_forked, [(i, ws[i].parts if race else [], ws[i].read,
                                                  ws[i].rng.bit_generator.state) for i in share], pos, now, settings, race)
                for share in self._shares(idx)]
        for job in jobs:
            for i, part, read, state, bounds in _result(job):
                w = ws[i]
                w.parts.append(part)
                w.read, w.rng.bit_generator.state = read, state
                self.bounds[i] = bounds
                bar.update(1)

    def predictions(self, now, shift, settings, n_futures: int) -> list:
        """Every weighing's :class:`Prediction`."""
        if self.pool is None:
            return [_prediction(w, now, shift, settings, n_futures) for w in self.weighings]
        shares = self._shares(np.arange(len(self.weighings)))
        jobs = [self.pool.submit(_predict_forked, [(i, self.weighings[i].parts, self.weighings[i].read,
                                                    self.weighings[i].rng.bit_generator.state) for i in share],
                                 now, shift, settings, n_futures) for share in shares]
        return [p for job in jobs for p in _result(job)]


def _result(job):
    """A worker's answer; an OSError naming what to do when a worker process died (killed, out of
    memory), which the command line reports as a message."""
    from concurrent.futures.process import BrokenProcessPool

    try:
        return job.result()
    except BrokenProcessPool as exc:
        raise OSError(f"an advice worker process ended before it answered ({exc}); run with --workers 1 "
                      "to weigh the requests in this process") from None


def _forked_ready() -> None:
    if _FORKED is None:
        raise RuntimeError("an advice worker started without the weighings (not forked)")


def _weigh_forked(jobs, pos, now, settings, race) -> list:
    """In a worker of :class:`_Forked`: weigh each (index, futures so far, read, random state) of
    ``jobs``, and with ``race`` (now, shift) its bounds for the next round."""
    out = []
    for i, parts, read, state in jobs:
        w = _FORKED[i]
        w.parts, w.read, w.rng.bit_generator.state = list(parts), read, state
        w.weigh(pos, now, settings)
        out.append((i, w.parts[-1], w.read, w.rng.bit_generator.state,
                    None if race is None else _bounds(w, race[0], race[1], settings)))
    return out


def _predict_forked(jobs, now, shift, settings, n_futures: int) -> list:
    """In a worker of :class:`_Forked`: the prediction of each (index, futures, read, random state)."""
    out = []
    for i, parts, read, state in jobs:
        w = _FORKED[i]
        w.parts, w.read, w.rng.bit_generator.state = parts, read, state
        out.append(_prediction(w, now, shift, settings, n_futures))
    return out


def _check_placeable(model, draws: _Draws, keep: np.ndarray) -> None:
    """Raise a :class:`ValueError` naming the first draw whose object the sampler's coordinates
    cannot place (its bottom at or above the horizon, where a camera step or an answer's fallback
    would turn it into NaN): a file's draws that no sampler of this model gave."""
    from ...inference.coords import WorkingCoords

    coords = WorkingCoords(model)
    with np.errstate(all="ignore"):
        back = coords.from_work(*coords.to_work(draws.cams, draws.objs))[1]
    bad = ~np.all(np.isfinite(back), axis=-1)                                   # (n, m)
    if bad.any():
        row, obj = (int(x[0]) for x in np.nonzero(bad))
        o = draws.objs[row, obj]
        raise ValueError(f"draws: {int(bad.any(axis=1).sum())} of the {len(bad)} draws weighed place an object where "
                         f"the camera cannot see its bottom (draw {int(keep[row])}: {model.objects[obj].id} at x "
                         f"{o[O_X]:.4g} m, z {o[O_Z]:.4g} m, ground offset {o[O_GROUND]:.4g} m, the camera "
                         f"{draws.cams[row, C_HEIGHT]:.4g} m high); they are not draws of this scene's posterior")


def rank_key(objective: str):
    """The sort key of predictions, best first: those weighed on every future before those that
    left the race (:attr:`Prediction.dropped`), then the objective's score (:meth:`Prediction.score`),
    then the other objective's, then the candidate's key. Good labels per hour are compared to three
    decimals, so that chances of a few millionths (nothing, read from simulated outcomes) do not
    decide the order; HDI points per minute are compared as they are (a request worth 0.003 points
    a minute is worth 10 % more than one worth 0.0027)."""
    other = "hdi" if objective == "labels" else "labels"

    def key(p):
        s = p.score(objective)
        return p.dropped, -(round(s, 3) if objective == "labels" else s), -p.score(other), p.candidate.key

    return key


def good_chance(p_hat: np.ndarray, n_eff: np.ndarray, bar: np.ndarray) -> np.ndarray:
    """(c,) the chance that a label's P(IoU ≥ t), read as ``p_hat`` (M, c) over M simulated
    futures from shares of ``n_eff`` (M,) effective draws each, is at least ``bar`` (c,).

    The futures' shares scatter by what the observation would say and by the estimator's own
    binomial noise (an sd up to 0.12 at 16 draws). Counting each against the bar would count that
    noise as labels lost above the bar and gained below it, so per column the spread of the
    futures' true P(IoU ≥ t) is fitted as a beta distribution by the beta-binomial likelihood of
    the shares (k = p_hat · n_eff of n_eff), and the chance is that beta's mass at or above
    ``bar``. Its concentration is capped at Σ n_eff − 1, where its spread is the standard error
    of the futures' mean: a label at the bar is not called good or bad on a mean known to a few
    points.
    """
    from scipy.special import betainc

    a, b = _fit_futures(p_hat, n_eff)
    return 1.0 - betainc(a, b, np.clip(np.asarray(bar, float), 0.0, 1.0))


def _fit_futures(p_hat: np.ndarray, n_eff: np.ndarray, start=None) -> tuple[np.ndarray, np.ndarray]:
    """(a, b), each (c,): the beta of :func:`good_chance`, the beta-binomial maximum likelihood of
    each column with its concentration a + b at most the cap. ``n_eff`` (M,) for every column, or
    (M, c) each column's own; ``start`` (a, b) where the fit starts (default: the columns' means at
    a concentration of 20).

    Each column is fitted on its own by Newton's method in (logit mean, log concentration), the
    concentration held at the cap where the likelihood would raise it further, each step halved
    until the likelihood does not fall: about ten steps (docs/studies/advice.md, "Speed of the
    advice on a frame": a joint L-BFGS-B fit took 30 to 600 steps and stopped short on many columns).
    """
    from scipy.special import digamma, gammaln

    p = np.clip(np.atleast_2d(np.asarray(p_hat, float)), 0.0, 1.0)
    n = np.asarray(n_eff, float)
    n = (n.reshape(-1, 1) if n.ndim == 1 else n) * np.ones_like(p)
    k, m_fut = p * n, p.shape[0]
    v_max, v_min = np.log(np.maximum(n.sum(axis=0) - 1.0, 1.0)), np.log(2e-3)
    if start is None:
        mu, conc = np.clip(p.mean(axis=0), 0.02, 0.98), np.full(p.shape[1], 20.0)
    else:
        a, b = (np.clip(x, 1e-3, 1e6) for x in start)
        mu, conc = np.clip(a / (a + b), 1e-6, 1.0 - 1e-6), a + b
    x = np.stack([np.log(mu / (1.0 - mu)), np.clip(np.log(conc), v_min, v_max)])  # (2, c): logit mean, log conc

    def beta(x):
        mu, conc = 1.0 / (1.0 + np.exp(-x[0])), np.exp(x[1])
        return mu * conc, (1.0 - mu) * conc, mu, conc

    def nll(x, cols):
        a, b, _, _ = beta(x)
        kk, nn = k[:, cols], n[:, cols]
        return -((gammaln(kk + a) + gammaln(nn - kk + b) - gammaln(nn + a + b)).sum(axis=0)
                 - m_fut * (gammaln(a) + gammaln(b) - gammaln(a + b)))

    trigamma = _trigamma

    def newton_step(x, cols):  # the step, and whether the column is done (its gradient within bounds ~0)
        a, b, mu, conc = beta(x)
        kk, nn = k[:, cols], n[:, cols]
        s = nn + a + b
        d_s, d_ab, t_s, t_ab = digamma(s).sum(axis=0), digamma(a + b), trigamma(s).sum(axis=0), trigamma(a + b)
        ga = -(digamma(kk + a).sum(axis=0) - d_s - m_fut * (digamma(a) - d_ab))      # d nll / da, db
        gb = -(digamma(nn - kk + b).sum(axis=0) - d_s - m_fut * (digamma(b) - d_ab))
        haa = -(trigamma(kk + a).sum(axis=0) - t_s - m_fut * (trigamma(a) - t_ab))
        hbb = -(trigamma(nn - kk + b).sum(axis=0) - t_s - m_fut * (trigamma(b) - t_ab))
        hab = t_s - m_fut * t_ab
        q = conc * mu * (1.0 - mu)                      # da/du = q = −db/du; da/dv = a, db/dv = b
        g = np.stack([q * (ga - gb), a * ga + b * gb])
        huu = q * q * (haa - 2.0 * hab + hbb) + q * (1.0 - 2.0 * mu) * (ga - gb)
        huv = g[0] + q * (a * (haa - hab) + b * (hab - hbb))
        hvv = g[1] + a * a * haa + 2.0 * a * b * hab + b * b * hbb
        free = ~(((x[1] >= v_max[cols] - 1e-12) & (g[1] < 0)) | ((x[1] <= v_min + 1e-12) & (g[1] > 0)))
        g[1] = np.where(free, g[1], 0.0)
        det = huu * hvv - huv ** 2
        both = free & (huu > 0) & (det > 0)
        step = np.where(both, np.stack([huv * g[1] - hvv * g[0], huv * g[0] - huu * g[1]]) / np.where(both, det, 1.0),
                        np.stack([np.where(huu > 0, -g[0] / np.where(huu > 0, huu, 1.0), -np.sign(g[0])),
                                  -np.sign(g[1])]))
        step *= np.minimum(1.0, 3.0 / np.maximum(np.max(np.abs(step), axis=0), 1e-300))
        return step, np.max(np.abs(g), axis=0) < 1e-8

    f = nll(x, slice(None))
    active = np.ones(p.shape[1], bool)
    for _ in range(100):
        cols = np.flatnonzero(active)
        if not len(cols):
            break
        step, done = newton_step(x[:, cols], cols)
        t, bad = np.where(done, 0.0, 1.0), done
        for _ in range(30):  # halved until the likelihood does not fall
            new = x[:, cols] + t * step
            new[1] = np.clip(new[1], v_min, v_max[cols])
            fn = nll(new, cols)
            bad = ~done & ~(fn <= f[cols] + 1e-12 * np.abs(f[cols]))
            if not np.any(bad):
                break
            t = np.where(bad, t / 2.0, t)
        ok = ~done & ~bad
        x[:, cols[ok]], f[cols[ok]] = new[:, ok], fn[ok]
        active[cols[done | bad]] = False
    a, b, _, _ = beta(x)
    return a, b


def _trigamma(x) -> np.ndarray:
    """ψ′(x), the trigamma function, for x > 0 (array): x raised to at least 10 by ψ′(x) = ψ′(x + 1)
    + 1/x², then its asymptotic series to the x⁻¹¹ term (relative error below 1e-12). Several times
    faster than ``scipy.special.polygamma(1, x)`` (a Hurwitz zeta), which the beta fits of the
    advice call thousands of times."""
    y = np.array(x, float, order="C")  # C order: ravel() is a view, written through
    acc = np.zeros(y.shape)
    small = np.flatnonzero(y.ravel() < 10.0)
    if small.size:
        ys = y.ravel()[small]
        shift = np.ceil(10.0 - ys)
        add = np.zeros(ys.shape)
        with np.errstate(divide="ignore"):
            for k in range(int(shift.max())):
                z = ys + k
                add += np.where(k < shift, 1.0 / (z * z), 0.0)
        acc.ravel()[small] = add
        y.ravel()[small] = ys + shift
    r = 1.0 / y
    r2 = r * r
    return acc + r + r2 * (0.5 + r * (1 / 6 + r2 * (-1 / 30 + r2 * (1 / 42 + r2 * (-1 / 30 + r2 * (5 / 66))))))


def futures_scale(p_iou, shift, min_quality: float) -> tuple[np.ndarray, np.ndarray]:
    """(base, bar), each (m,): labels' P(IoU ≥ t) ``p_iou`` and the bar ``min_quality`` moved onto
    the futures' scale by ``shift`` (:attr:`Advice.shift`, None: no difference), as an advice and
    its JSON (``now.p_iou``, ``shift``, ``settings.min_quality``) give them."""
    p_iou = np.asarray(p_iou, float)
    shift = np.zeros(len(p_iou)) if shift is None else np.asarray(shift, float)
    return p_iou - shift, min_quality - shift


def combined_chance(base: np.ndarray, bar: np.ndarray, moments: list[Moments]) -> np.ndarray:
    """(m,) each label's chance to be at or above ``bar`` after the requests of ``moments`` are
    answered together, from the present ``base`` (both (m,), on the futures' scale).

    The requests' effects on a label add: its future P(IoU ≥ t) is taken as a beta of mean
    ``base`` + Σ shrunk changes (:meth:`Moments.shrunk`) and variance Σ spreads (capped at 0.9 of a
    beta's largest). Measured on KITTI frames (docs/studies/advice.md, "Why two rules"), the
    alternative rule, a label lifted once any one request would lift it (1 − Π(1 − pᵢ)), says that
    a set of lines on every object would lift 7.9 labels and drop none; 3 rose and 3 fell. The
    shrinkage keeps the small, noisy changes a request makes to the other labels of its frame from
    adding up to a lift that is only noise.
    """
    from scipy.special import betainc

    base, bar = np.asarray(base, float), np.asarray(bar, float)
    if not moments:
        return (base >= bar).astype(float)
    mean = np.clip(base + np.sum([m.shrunk() for m in moments], axis=0), 1e-4, 1.0 - 1e-4)
    var = np.minimum(np.sum([m.spread for m in moments], axis=0), 0.9 * mean * (1.0 - mean))
    c = np.minimum(mean * (1.0 - mean) / np.maximum(var, 1e-12) - 1.0, 1e6)
    return 1.0 - betainc(mean * c, (1.0 - mean) * c, np.clip(bar, 0.0, 1.0))


def _label_quality(scene, camera_map, objects_map, cams, objs, threshold: float) -> np.ndarray:
    """(m,) each label's P(IoU ≥ ``threshold``) as ``creference labels`` computes it: its box at
    the MAP against the boxes of all the draws (not only those weighed), in the labels' frame."""
    from ..labels.kitti import kitti_poses
    from ..labels.quality import box_iou_3d

    box = kitti_poses(scene, np.asarray(camera_map, float)[None], np.asarray(objects_map, float)[None])[0]
    samples = kitti_poses(scene, cams, objs)
    return np.array([np.mean(box_iou_3d(box[i], samples[:, i]) >= threshold) for i in range(len(box))])


class _Weighing:
    """One request's simulated futures, weighed a share at a time (:func:`advise`'s race): per
    future, its reweighted outlook (each HDI against the present at its own weights), its effective
    sample size and, for a future that was not recomputed, its weights and its label quality under
    the same weights shuffled over the draws. :func:`_prediction` summarises those weighed so far."""

    def __init__(self, obs, cand, draws: _Draws, outer, base, rng, temperature: float):
        self.obs, self.cand, self.draws, self.outer, self.base = obs, cand, draws, outer, base
        self.rng, self.temperature = rng, temperature
        # a scene without references: the draws' crowd scales, drawn once for all the futures
        self.cams = obs.scale_draws(draws.cams, rng) if obs.needs_scale else draws.cams
        self.parts: list[dict] = []
        self.read: np.ndarray | None = None  # (m,) the targets whose distances its futures read (the first share's)

    def weigh(self, pos: np.ndarray, now: Outlook, settings: AdviceSettings) -> None:
        """Weigh the futures at positions ``pos`` of ``outer``. The first share decides whose
        distances are read (:func:`~.update.informative`, the request's own target's always): the
        others' HDIs stay the present's (``now``)."""
        obs, draws, rng, cams = self.obs, self.draws, self.rng, self.cams
        outer = self.outer[pos]
        hands = draws.hands
        obs.simulate(rng, cams[outer], draws.objs[outer], None if hands is None else hands[outer])
        log_w = obs.log_ratio(cams, draws.objs, self.base, hands=hands)
        log_w[np.arange(len(outer)), outer] = -np.inf  # leave the simulating draw out
        weights, ess = normalise(log_w)
        if self.read is None:
            self.read = informative(draws.dist, weights)
            if self.cand.target is not None:
                self.read[self.cand.target] = True
        read = self.read
        rows = draws.outlooks(weights, settings, rng, read=read, unread=now)
        n = len(cams)
        collapsed = np.flatnonzero(ess < max(MIN_ESS, MIN_ESS_FRACTION * n))
        # Each future against the present at its own weights (module docstring): scaled by the present
        # on all draws over that. The fallback futures are recomputed on FALLBACK_DRAWS of the draws
        # (evenly thinned), moved together, each with its weights: scaled by the present on those
        # draws over that at the same weights.
        same = np.ones(len(outer), bool)
        same[collapsed] = False
        # the unread targets' present over itself (each future's HDI against the present at its own weights)
        width, share = np.tile(now.hdi_width_m, (len(outer), 1)), np.tile(now.hdi_share, (len(outer), 1))
        width[:, read], share[:, read] = shuffled_hdi(draws.dist[:, read], weights, settings.hdi_prob, rng,
                                                      order=draws.order[read])  # the rng drawn as for every target
        moved_ess = np.full(len(outer), np.inf)  # a recomputed future's effective draws (inf: equally weighted)
        if len(collapsed):
            sub = np.unique(np.linspace(0, n - 1, min(FALLBACK_DRAWS, n)).round().astype(int))
            mc, mo, mw = _moved(obs, collapsed, cams[sub], draws.objs[sub], rng, self.temperature,
                                None if hands is None else hands[sub])
            width[np.ix_(collapsed, read)], share[np.ix_(collapsed, read)] = shuffled_hdi(
                draws.dist[sub][:, read], mw, settings.hdi_prob, rng)
            moved_ess[collapsed] = np.where(np.all(mw == mw[:, :1], axis=1), np.inf, 1.0 / np.sum(mw * mw, axis=1))
            for i, c, o, w in zip(collapsed, mc, mo, mw):
                one = _Draws(c, o, draws.scene).outlooks(w[None], settings, rng, read=read, unread=now)
                for k in rows:
                    rows[k][i] = one[k][0]
        rows["hdi_width_m"] = rows["hdi_width_m"] * now.hdi_width_m / width
        rows["hdi_share"] = rows["hdi_share"] * now.hdi_share / share
        # a reweighted future's label quality is read on its few effective draws around their own
        # mean box, which flatters it: the same weights shuffled over the draws show by how much
        shuffled = p_iou(draws.boxes, rng.permuted(weights[same], axis=1), settings.iou_threshold, rng,
                         settings.iou_pairs) if np.any(same) else np.zeros((0, len(now.p_iou)))
        self.parts.append(dict(rows, pos=pos, ess=ess, same=same, moved_ess=moved_ess, weights=weights[same],
                               shuffled=shuffled))

    def futures(self) -> dict:
        """Every per-future array of the futures weighed so far, in the order of their positions."""
        parts = self.parts
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        order = np.argsort(out["pos"], kind="stable")
        for k in ("weights", "shuffled"):  # rows of the futures not recomputed, in the same order
            out[k] = out[k][np.argsort(out["pos"][out["same"]], kind="stable")]
        out = {k: v if k in ("weights", "shuffled") else v[order] for k, v in out.items()}
        out["read"] = self.read
        return out


def _labels_part(f: dict, now: Outlook, shift, settings: AdviceSettings):
    """(p_hat, n_eff, shuffle_var, present, bar) of the futures ``f`` (:meth:`_Weighing.futures`):
    each future's label quality less the bias its weights show shuffled (a recomputed future's
    draws are equally weighted, as the present's are), its effective draws, and the present and the
    bar on the futures' scale."""
    same = f["same"]
    p_hat = f["p_iou"].copy()
    n_eff = 1.0 / (1.0 / settings.iou_pairs + 1.0 / f["moved_ess"])  # a recomputed future's (its own weights)
    present, bar = futures_scale(now.p_iou, shift, settings.min_quality)  # on the futures' scale
    shuffle_var = np.zeros(len(present))
    shuffled = f["shuffled"]
    if len(shuffled):
        p_hat[same] -= shuffled.mean(axis=0) - present
        n_eff[same] = 1.0 / (1.0 / settings.iou_pairs + 1.0 / f["ess"][same])
        shuffle_var = shuffled.var(axis=0, ddof=1) / len(shuffled) if len(shuffled) > 1 else shuffle_var
    return p_hat, n_eff, shuffle_var, present, bar


def _moments(parts: tuple, idx: np.ndarray, cols=slice(None), start: Moments | None = None) -> Moments:
    """The :class:`Moments` of the futures ``idx`` (their labels ``cols``) from the ``parts`` of
    :func:`_labels_part`; ``idx`` (B, M), B resamples of the futures: each entry (B, c), their
    betas fitted together from ``start`` (the moments of the same labels on all the futures)."""
    p_hat, n_eff, shuffle_var, present, _ = parts
    p = p_hat[:, cols][np.atleast_2d(idx)]                                      # (B, M, c)
    n_sets, m_fut, c = p.shape
    init = None
    if start is not None:  # the beta of ``start``, for each resample
        mean = np.clip(start.change + present[cols], 1e-3, 1.0 - 1e-3)
        conc = mean * (1.0 - mean) / np.maximum(start.spread, 1e-12) - 1.0
        init = np.tile(mean * conc, n_sets), np.tile((1.0 - mean) * conc, n_sets)
    a, b = _fit_futures(p.transpose(1, 0, 2).reshape(m_fut, -1), np.repeat(n_eff[np.atleast_2d(idx)].T, c, axis=1),
                        init)
    a, b = a.reshape(n_sets, c), b.reshape(n_sets, c)
    mean = a / (a + b)
    se2 = p.var(axis=1, ddof=1) / m_fut + shuffle_var[cols]
    out = Moments(mean - present[cols], np.sqrt(se2), mean * (1.0 - mean) / (a + b + 1.0))
    return out if np.ndim(idx) == 2 else Moments(*(x[0] for x in (out.change, out.change_se, out.spread)))


def _prediction(w: _Weighing, now: Outlook, shift, settings: AdviceSettings, n_futures: int) -> Prediction:
    """The prediction of the futures ``w`` weighed (module docstring): the ranking from the even
    positions, what it states from the odd ones."""
    f, cand, rng, dist = w.futures(), w.cand, w.rng, w.draws.dist
    rows = {k: f[k] for k in ("hdi_width_m", "hdi_share", "distance_m", "location_sd_m", "p_iou")}
    expected = Outlook(**{k: v.mean(axis=0) for k, v in rows.items()})
    expected = dataclasses.replace(expected, p_iou=np.clip(expected.p_iou + shift, 0.0, 1.0))
    gains = 100.0 * np.sum(now.hdi_share - rows["hdi_share"], axis=1)
    gain = float(np.mean(gains))
    se_outer = np.std(gains, ddof=1) / np.sqrt(len(gains))
    se_inner = _split_se(dist[:, f["read"]], f["weights"], settings.hdi_prob, rng)  # the others' gains are none
    # labels below the bar now that reach it (module docstring): each label's future is the fitted
    # spread of its futures' P(IoU ≥ t) (:func:`good_chance`), summarised by its moments, and its
    # chance is that at or above the bar by the rule requests are combined by
    # (:func:`combined_chance`), the label's (its MAP box's) quality being its mean box's moved by
    # ``shift``.
    p_hat, n_eff, shuffle_var, present, bar = parts = _labels_part(f, now, shift, settings)
    below = now.p_iou < settings.min_quality
    rank, told = np.flatnonzero(f["pos"] % 2 == 0), np.flatnonzero(f["pos"] % 2 == 1)
    m_told, m_rank = _moments(parts, told), _moments(parts, rank)
    p_told, p_rank = (combined_chance(present, bar, [m]) for m in (m_told, m_rank))
    good_gain = float(np.sum(p_told[below]))
    start = Moments(m_told.change[below], m_told.change_se[below], m_told.spread[below])
    boots = combined_chance(present[below], bar[below], [_moments(
        parts, rng.choice(told, size=(_BOOTSTRAPS, len(told))), below, start)]).sum(axis=1) if np.any(below) else [0., 0.]
    return Prediction(candidate=cand, expected=expected, gain_pct=gain, gain_se_pct=float(np.hypot(se_outer, se_inner)),
                      gain_per_minute=gain / (cand.seconds / 60.0) if cand.seconds > 0 else math.inf,
                      ess_median=float(np.median(f["ess"]) / len(dist)), fallbacks=int(np.sum(~f["same"])),
                      p_good=p_told, good_gain=good_gain, good_gain_se=float(np.std(boots, ddof=1)),
                      good_per_hour=good_gain * 3600.0 / cand.seconds if cand.seconds > 0 else math.inf,
                      rank_p_good=p_rank, rank_good_gain=float(np.sum(p_rank[below])),
                      good_loss=float(np.sum(1.0 - p_told[~below])), moments=m_told, rank_moments=m_rank,
                      location_gain_pct=float(100.0 * np.sum((now.location_sd_m - expected.location_sd_m)
                                                             / now.distance_m)),
                      futures=len(f["pos"]), dropped=len(f["pos"]) < n_futures)


def _bounds(w: _Weighing, now: Outlook, shift, settings: AdviceSettings) -> dict:
    """What the futures ``w`` weighed so far say the request might be worth at most and at least:
    ``chance`` (lower, upper), each (m,), every label's chance of reaching the bar (0 for those at
    it now), its change unshrunk (:meth:`Moments.shrunk` shrinks it less on more futures) minus or
    plus :data:`RACE_Z` standard errors; ``value`` (lower, upper), the labels' summed (labels) or
    the HDI or location-sd points' mean over the futures minus or plus :data:`RACE_Z` standard
    errors; ``score`` the values per hour (labels) or minute (:meth:`Prediction.score`)."""
    f, objective, m = w.futures(), settings.objective, len(now.p_iou)
    below = now.p_iou < settings.min_quality
    chance = np.zeros((2, m))
    if np.any(below):
        parts = _labels_part(f, now, shift, settings)
        mo = _moments(parts, np.arange(len(f["pos"])), below)
        for k, sign in enumerate((-1.0, 1.0)):
            bound = Moments(mo.change + sign * RACE_Z * mo.change_se, 0.0 * mo.change_se, mo.spread)
            chance[k, below] = combined_chance(parts[3][below], parts[4][below], [bound])
    if objective == "labels":
        value = chance.sum(axis=1)
    else:
        per_future = 100.0 * (np.sum(now.hdi_share - f["hdi_share"], axis=1) if objective == "hdi" else
                              np.sum((now.location_sd_m - f["location_sd_m"]) / now.distance_m, axis=1))
        value = per_future.mean() + np.array([-1.0, 1.0]) * RACE_Z * per_future.std(ddof=1) / np.sqrt(len(per_future))
    seconds = w.cand.seconds
    per = 3600.0 if objective == "labels" else 60.0
    # the other objective's score, which orders requests of the same score (:func:`rank_key`)
    other = (chance.mean(axis=0).sum() * 3600.0 if objective == "hdi" else
             100.0 * np.mean(np.sum(now.hdi_share - f["hdi_share"], axis=1)) * 60.0)
    return {"chance": chance, "value": value, "score": value * per / seconds if seconds > 0 else np.full(2, math.inf),
            "other": other / seconds if seconds > 0 else math.inf}


def _contenders(weighings: list[_Weighing], now: Outlook, shift, settings: AdviceSettings,
                known: list | None = None) -> np.ndarray:
    """Which requests stay in the race (:func:`advise`), by the bounds of the rounds so far
    (:func:`_bounds`): those that might be worth asking (the upper value) and, so, top the ranking
    or be the request of a target that needs one (:meth:`Advice.requests`) ahead of the best of
    that target's own requests at its lower score; those that might be a label's verdict
    (:meth:`Advice.verdicts`): lift it (an upper chance of a half) ahead of the best chance of
    lifting it at the lower bound; the first by the lower score; and the mounting, which a batch's
    plan values over every frame of its camera (:meth:`~.batch.BatchAdvice.plan`). ``known``: each
    weighing's bounds where a worker computed them already (None: computed here)."""
    if not weighings:
        return np.zeros(0, bool)
    bounds = [_bounds(w, now, shift, settings) if b is None else b
              for w, b in zip(weighings, known or [None] * len(weighings))]
    m = len(now.p_iou)
    needs = (now.p_iou < settings.min_quality if settings.objective == "labels" else
             now.hdi_share > settings.target_hdi_width)
    low = np.array([b["score"][0] for b in bounds])
    targets = [w.cand.target for w in weighings]
    own_best = np.array([max((lo for lo, t in zip(low, targets) if t == i), default=-math.inf) for i in range(m)])
    served = [np.arange(m) if t is None else np.array([t]) for t in targets]
    chance_best = np.max([np.where(np.isin(np.arange(m), sv), b["chance"][0], 0.0) for b, sv in zip(bounds, served)],
                         axis=0, initial=0.0)
    keep = np.zeros(len(weighings), bool)
    # the first of the ranking at the lower bound is weighed on every future (compared as rank_key does)
    first = [round(x, 3) if settings.objective == "labels" else x for x in low]
    keep[max(range(len(low)), key=lambda k: (first[k], bounds[k]["other"]))] = True
    for k, (w, b, sv) in enumerate(zip(weighings, bounds, served)):
        high, lifts = b["score"][1], b["chance"][1]
        if settings.worth(b["value"][1], w.cand.seconds) and (
                high >= low.max() or np.any(needs[sv] & (high >= own_best[sv]))):
            keep[k] = True
        elif np.any(lifts[sv] >= np.maximum(0.5, chance_best[sv])):
            keep[k] = True
        elif w.cand.kind == "mounting":  # a batch's plan values it over every frame of its camera
            keep[k] = True
    return keep


def _moved(obs, i, cams: np.ndarray, objs: np.ndarray, rng, temperature: float, hands: np.ndarray | None = None):
    """The draws moved to the posterior after the i-th simulated observation, with their weights.

    An answer that enters as a normal prior (a size, a mounting) carries the draws by an affine map
    (:func:`~.update.gaussian_transport`: what the answer's normal conditioning would do to them,
    in the sampler's working coordinates with the answer's quantities in place of theirs) and
    weighs them by the new posterior over the old: one evaluation of the posterior per draw, and
    draws of the new posterior at those weights, whatever its shape. Where the weights leave fewer
    than :data:`TRANSPORT_ESS_SHARE` of the draws counting (a posterior far from normal along the
    answer), the carried draws start the sampler's block sweeps (:func:`~.fallback.block_sweeps`),
    equally weighted after them. An annotation is moved by the tempered update
    (:func:`~.update.tempered_update`), ``max(8, d)`` random-walk steps a stage for d parameters, at
    most 32 (mixing slows with d).

    ``i`` an index: (cams (N, 5), objs (N, m, 7), weights (N,)); an array of F indices: (F, N, 5),
    (F, N, m, 7), (F, N), the futures of a prior answer moved together in one pass.
    ``hands`` (N, m): each draw's handedness, which it keeps (None: the model's)."""
    from ...inference.coords import WorkingCoords

    if np.ndim(i) == 0:
        c, o, w = _moved(obs, np.array([i]), cams, objs, rng, temperature, hands)
        return c[0], o[0], w[0]
    idx = np.asarray(i, int)
    if hasattr(obs, "model_with"):  # an annotation: a new model, the tempered update
        out = [_moved_one(obs, k, cams, objs, rng, temperature, hands) for k in idx]
        return (np.array([c for c, _ in out]), np.array([o for _, o in out]),
                np.full((len(idx), len(cams)), 1.0 / len(cams)))
    model = obs.model
    coords = WorkingCoords(model)
    wc, wo = coords.to_work(cams, objs)
    x = np.concatenate([wc[:, model.camera_free], wo[:, model.object_free]], axis=1)
    unpack, density = _working(model, coords, wc, wo, temperature)
    old = density(model, obs.needs_scale, natural=True)
    values = obs.values[idx]                                                        # (F, p)
    n_sets, (n, d) = len(idx), x.shape
    rows = None if hands is None else np.tile(hands, (n_sets, 1))  # every set's rows, set after set
    # the answer's quantities in place of their working coordinates (obs.columns: the same density)
    cols = obs.columns()
    log_x, c0, o0 = old(x, hands)
    z = x.copy()
    z[:, cols] = obs.quantities(c0, o0)
    camera = np.arange(d) < int(model.camera_free.sum())
    zt = gaussian_transport(z, cols, values, obs.sd, moves=obs.moving(), follow=camera)
    y = zt.copy()
    with np.errstate(invalid="ignore"):  # back to working coordinates (a size's log-depth does not move with it)
        y[..., cols] -= obs.quantities(*coords.from_work(*unpack(zt.reshape(-1, d)))).reshape(n_sets, n, -1) - zt[..., cols]
    log_y, c, o = old(y.reshape(-1, d), rows)
    answer = (values[:, None, :] - zt[..., cols]) / obs.sd
    with np.errstate(invalid="ignore"):
        log_w = log_y.reshape(n_sets, n) - 0.5 * np.sum(answer * answer, axis=-1) - log_x
    weights, ess = normalise(np.where(np.isfinite(log_w), log_w, -np.inf))
    c, o = c.reshape(n_sets, n, -1), o.reshape(n_sets, n, *o.shape[1:])
    lost = ~np.isfinite(log_y.reshape(n_sets, n))  # carried out of the support: weight 0, the draw kept
    c, o = np.where(lost[..., None], cams, c), np.where(lost[..., None, None], objs, o)
    weak = np.flatnonzero(ess < TRANSPORT_ESS_SHARE * n)
    if len(weak):
        start = np.where(lost[weak][..., None], x, y[weak])
        moved = block_sweeps(obs, values[weak], wc[0], wo[0], start, rng, temperature,
                             hands=None if hands is None else np.tile(hands, (len(weak), 1)))
        cw, ow = coords.from_work(*unpack(moved.reshape(-1, d)))
        c[weak], o[weak] = cw.reshape(len(weak), n, -1), ow.reshape(len(weak), n, *ow.shape[1:])
        weights[weak] = 1.0 / n
    return c, o, weights


def _n_moves(d: int) -> int:
    """The random-walk steps of :func:`_moved` in d dimensions (its docstring)."""
    return int(min(32, max(8, d)))


def _working(model, coords, wc: np.ndarray, wo: np.ndarray, temperature: float):
    """(unpack, density) in the working coordinates of ``model``'s free parameters: ``unpack``
    (n, d) → full working cameras and objects (the fixed entries of the first draw), ``density``
    (a model, whether the crowd scale's prior enters) → the log-posterior density (n, d) → (n,)
    (``natural``: → (density, cameras, objects), the draws' natural values beside it), each row at
    its handedness where a second argument (n, m) gives them."""
    from ...inference.coords import CAMERA_LOG

    cf, of = model.camera_free, model.object_free
    logs = CAMERA_LOG & cf

    def unpack(x):
        c, o = np.repeat(wc[:1], len(x), axis=0), np.repeat(wo[:1], len(x), axis=0)
        c[:, cf], o[:, of] = x[:, :cf.sum()], x[:, cf.sum():]
        return c, o

    def density(m, scale_prior: bool, natural: bool = False):  # log-posterior density in working coordinates
        def f(x, hands=None):
            c, o = unpack(x)
            cn, on, jac = coords.from_work_jacobian(c, o)
            with np.errstate(all="ignore"):
                out = (-at_hands(m, hands).neg_log_posterior(cn, on, temperature) + c[:, logs].sum(axis=1)
                       + jac.sum(axis=1))
                if scale_prior:
                    out = out - m.ref_scale_neg_log(cn[:, C_SCALE])
            out = np.where(np.isfinite(out), out, -np.inf)
            return (out, cn, on) if natural else out
        return f

    return unpack, density


def _moved_one(obs, i: int, cams: np.ndarray, objs: np.ndarray, rng, temperature: float, hands=None):
    """:func:`_moved` for one future of an annotation (a set of lines, a reference): the tempered
    update to the model with it (each draw's handedness, ``hands`` (N, m) or None, carried along)."""
    from ...inference.coords import WorkingCoords

    new = obs.model_with(i)
    coords = WorkingCoords(new)
    wc, wo = coords.to_work(cams, objs)
    x = np.concatenate([wc[:, new.camera_free], wo[:, new.object_free]], axis=1)
    unpack, density = _working(new, coords, wc, wo, temperature)
    moved, _ = tempered_update(density(obs.model, obs.needs_scale), density(new, False), x, rng,
                               n_moves=_n_moves(x.shape[1]), labels=hands)
    return coords.from_work(*unpack(moved))


def _split_se(dist: np.ndarray, weights: np.ndarray, prob: float, rng, n_splits: int = 3) -> float:
    """Standard error of the expected gain (points) from the finite set of draws: the gain computed
    on two random halves of the draws differs by about twice it (each half's variance is double).
    ``dist`` (N, m) the targets' distances. Both halves, and the present beside the futures, are
    read in one call of :func:`~.update.weighted_hdi` where the halves are of a size."""
    if not len(weights):
        return 0.0
    n, c = dist.shape

    def rows_of(part):  # the futures' weights on ``part`` and, last, the present's; the futures with weight there
        w = weights[:, part]
        total = w.sum(axis=1)
        ok = total > 0
        w = np.where(ok[:, None], w / np.where(ok, total, 1.0)[:, None], 1.0 / part.sum())
        return np.vstack([w, np.full((1, part.sum()), 1.0 / part.sum())]), ok

    sq = []
    for _ in range(n_splits):
        half = rng.permutation(n) < n // 2
        (wa, ok_a), (wb, ok_b) = rows_of(half), rows_of(~half)
        if len(wa[0]) == len(wb[0]):
            each = np.concatenate([np.broadcast_to(wa, (c,) + wa.shape), np.broadcast_to(wb, (c,) + wb.shape)])
            width, median = weighted_hdi(np.hstack([dist[half], dist[~half]]), each, prob)
            read = [(width[:, :c] / median[:, :c], ok_a), (width[:, c:] / median[:, c:], ok_b)]
        else:
            read = [(np.divide(*weighted_hdi(dist[part], w, prob)), ok) for part, w, ok in
                    ((half, wa, ok_a), (~half, wb, ok_b))]
        g = [100.0 * np.sum(share[-1] - np.mean(share[:-1][ok], axis=0)) for share, ok in read]
        sq.append((g[0] - g[1]) ** 2 / 4.0)
    return float(np.sqrt(np.mean(sq)))


def _recommend(now: Outlook, predictions: list[Prediction], settings: AdviceSettings, ids) -> tuple[str, str]:
    if settings.objective == "labels":
        return _recommend_labels(now, predictions, settings, ids)
    share, goal = 100.0 * now.hdi_share, 100.0 * settings.target_hdi_width
    widest = int(np.argmax(share))
    which = "" if len(ids) == 1 else f" (widest: {ids[widest]})"
    if np.all(now.hdi_share <= settings.target_hdi_width):
        return "stop", (f"precision target met: the {settings.hdi_prob:.0%} HDI of the distance is at most "
                        f"{share[widest]:.1f} % of it{which} (target {goal:g} %)")
    if not predictions:
        return "stop", "no annotation of this scene can be simulated"
    best, what = predictions[0], "" if settings.objective == "hdi" else "location-sd "
    rate = best.score(settings.objective)
    if rate < settings.min_gain:
        return "stop", (f"the best expected gain, {rate:.2f} {what}points of the distance per "
                        f"minute ({best.candidate.description}), is below the minimum {settings.min_gain:g}")
    if settings.objective == "location":
        sd, new = 100 * now.location_sd_m / now.distance_m, 100 * best.expected.location_sd_m / now.distance_m
        i = int(np.argmax(sd - new))
        on = "" if len(ids) == 1 else f" ({ids[i]})"
        return "collect", (f"collect {best.candidate.description} next: expected location sd {sd[i]:.1f} % → "
                           f"{new[i]:.1f} % of the distance{on}, {rate:.2f} points per minute")
    return "collect", (f"collect {best.candidate.description} next: expected HDI {share[widest]:.1f} % → "
                       f"{100 * best.expected.hdi_share[widest]:.1f} % of the distance{which}, "
                       f"{rate:.2f} points per minute")


def _recommend_labels(now: Outlook, predictions: list[Prediction], settings: AdviceSettings, ids):
    t, q = f"P(IoU ≥ {settings.iou_threshold:g})", settings.min_quality
    below = np.flatnonzero(now.p_iou < q)
    if not len(below):
        low = int(np.argmin(now.p_iou))
        return "stop", (f"label quality met: every label has {t} ≥ {q:g} (lowest {now.p_iou[low]:.2f}"
                        f"{'' if len(ids) == 1 else f', {ids[low]}'})")
    if not predictions:
        return "stop", "no annotation of this scene can be simulated"
    best = predictions[0]
    said = f"{len(below)} of {len(ids)} label{'s' if len(ids) != 1 else ''} below {t} {q:g}"
    if not settings.worth(best.value("labels"), best.candidate.seconds):  # decided on the ranking futures
        # the gain as the table states it (from the futures it was not ranked by), then, when it reads
        # otherwise, the one the decision is made on (module docstring)
        low = f"below the minimum {settings.min_good_per_hour:g}"
        told, ranked = (f"{best.good_gain:.2f}", f"{best.good_per_hour:.2f}"), \
            (f"{best.value('labels'):.2f}", f"{best.score('labels'):.2f}")
        judged = f", {low}" if told == ranked else (
            f"; judged on the other half of the simulated outcomes, those that rank the requests, it makes "
            f"{ranked[0]}, {ranked[1]} per human hour, {low}")
        return "stop", (f"{said}; the best request, {best.candidate.description}, is expected to make "
                        f"{told[0]} ± {best.good_gain_se:.2f} of them good, {told[1]} per human hour{judged}: see "
                        "the verdicts for what would lift them")
    i = int(below[np.argmax(best.p_good[below])])
    on = "" if len(ids) == 1 else f"{ids[i]}: "
    return "collect", (f"collect {best.candidate.description} next: expected {best.good_gain:.2f} more good "
                       f"label{'s' if best.good_gain != 1 else ''} ({best.good_per_hour:.2f} per human hour; {said}); "
                       f"{on}{t} {now.p_iou[i]:.2f} → {best.expected.p_iou[i]:.2f}")
