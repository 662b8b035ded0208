"""What a data set teaches each frame: the quantities frames share, each declared once and learned
through one mechanism (``creference batch``, on by default; docs/batch.md, "What the data set
teaches each frame"; issue 62).

A shared quantity is a :class:`Shared`: its name, who shares it (``shared_by``: the frames of one
camera, the data set's crowd, or the frames of one *setting*: the scene's ``setting``, else its
camera id, else the whole data set), whether the frames share one value (``"shared"``) or draw
theirs around a common one (``"spread"``), and the bounds of what is pooled. :data:`SHARED`
declares them all:

==================  ==========  ======  ===============================================================
quantity            shared_by   kind    a frame reads it from / is handed it back as
==================  ==========  ======  ===============================================================
focal length        camera      shared  first pass, log µ / held: the frame's focal length (step 3)
camera height       camera      spread  first pass, log h / the orientation prior's height
pitch, roll         camera      spread  first pass / the orientation prior's pitch and roll
reference scale     crowd       spread  first pass, log s / the ``ref_scale_median``, ``_log_sd`` options
target distance     setting     spread  first pass, each target's log d / the location prior's population
corner scale        crowd       shared  the annotations (sets of one object), else the first pass's
                                        residuals (each frame's own where frames spread) / the
                                        scene's corner scale
segment floor       crowd       shared  the references' drawn lengths / ``read_floor_px``
reference tail      crowd       shared  first pass, each reference's leave-one-out density / ``ref_dof``
==================  ==========  ======  ===============================================================

The mechanism, the same for every quantity:

1. **Read** (:func:`read_readings`): every frame is estimated alone first (a MAP, ``first_pass/``);
   its draws (the Laplace approximation at the MAP, or the posterior's when the result keeps them)
   are reweighted by 1/prior, the prior the frame used divided out exactly
   (:func:`divide_prior`), and the weighted mean and variance make each reading a normal
   likelihood N(mᵢ, 1/Pᵢ) (a target's distance: one reading per target). A reading whose
   weights' effective sample size is below :data:`MIN_WEIGHT_ESS` of the draws, or whose
   precision is below :data:`MIN_INFORMATION` of the posterior's (its posterior is its prior), is
   not made.
2. **Combine** (:class:`Pool`): a group's informative readings (sd at most ``max_sd``): a
   "shared" quantity's precision-weighted mean, its variance inflated by the Birge ratio and a
   floor (``floor``, the model's bias shared by a group's frames) in quadrature; a "spread"
   quantity's DerSimonian–Laird mean and spread τ (at least ``min_spread``). Each pool is checked
   against its readings (:class:`PoolCheck`).
3. **Hand back, leaving the frame out**: each frame gets the pool of the *other* frames of its
   group (its own annotations count once): a shared value as N(M₋ᵢ, V₋ᵢ), a spread one as
   N(M₋ᵢ, V₋ᵢ + τ²) (the next frame's value, or the next target's distance). A shared quantity
   declared ``held`` (the focal length: a camera has one) is instead the frame's own value, the
   pool of *all* its group's frames (each frame's evidence counted once, inside the pool: as a
   prior, a frame's own weak, noisy evidence would move it again), and the pool's whole
   uncertainty V (statistical ⊕ floor) rides on each result as one scale its group's frames share
   (:func:`share_scale`: each kept draw's focal length and depths × exp(ε_d), ε_d ~ N(0, V), the
   same ε_d in every frame of the camera). The crowd's corner scale and segment floor are read
   from the annotations themselves, no first pass (:func:`~.corner_scales`: sums of squares
   pooled; :func:`~.segment_floors`: the floor of the reading's prior of a segment's length,
   fitted to the drawn lengths); where no object is annotated twice, the corner scale is read
   from the first pass's residuals instead (:func:`read_corner_residuals`, the other frames'
   squares over their degrees of freedom: :meth:`DataSet.corner_scale_of`). The crowd's
   reference tail (the Student-t degrees of freedom its stated values are read with) is not a
   mean but a choice among :data:`TAIL_DOFS` (:class:`TailPool`): each reference of the first
   pass is scored by its leave-one-out predictive density under each (:func:`read_tail`), the
   other frames' scores are summed, and a frame is handed the tail they favour when it beats the
   model's own by more than twice the standard error of the difference (arviz's ``compare``
   rule), else the model's own. The tail is chosen first (from all frames); every other reading
   is then made from draws reweighted to it (:func:`tail_reweight`), as the crowd's scale, say,
   is a scale of that tail.

A quantity is learnt when there is something to learn (:func:`plan`): frames sharing a camera id
that lack a focal length or a calibrated mounting; frames with references (their crowd's scale);
two frames and no object annotated twice (the corner scale, from the residuals);
:data:`MIN_POPULATION_FRAMES` frames of one setting with :data:`MIN_POPULATION_TARGETS` targets
for a population. What a user sets by hand (``--distance-range``, the ``ref_scale`` options, a
scene's own focal length or focal prior, its corner scale) wins and is recorded as an override.

Numbers: log µ, log h, log s and log d are natural logs of pixels, metres, the crowd scale and
metres; pitch and roll radians (the blocks print degrees).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

__all__ = ["Shared", "SHARED", "Reading", "PoolCheck", "Pooled", "Pool", "DataSet", "divide_prior",
           "combine", "pool_check", "read_readings", "read_focal_given_orientation", "plan", "dataset_lines",
           "scale_depths", "shared_scale", "share_scale", "tail_reweight",
           "DATASET_CHOICES", "REF_TAIL", "TAIL_DOFS", "TailPool", "read_tail",
           "MIN_POPULATION_FRAMES", "MIN_POPULATION_TARGETS"]

#: ``--dataset``: learn what frames share (``auto``: what there is something to learn of) or nothing
DATASET_CHOICES = ("auto", "none")
#: The first pass is fitted again at the crowd's corner scale its residuals read when that is this
#: factor or more from the default it was fitted at (:meth:`DataSet.refit_at`)
REFIT_FACTOR = 1.25
#: a reading whose precision is below this share of its posterior precision tells nothing
MIN_INFORMATION = 0.1
#: the least effective sample size of a reading's importance weights 1/prior, as a share of its draws
#: (below it the frame's prior was far narrower than its likelihood: the draws cannot show the latter)
MIN_WEIGHT_ESS = 0.1
#: ... and, with a reweighting to other frames' pool of another quantity
#: (:func:`read_focal_given_orientation`), the least effective number of draws of all the weights
MIN_REWEIGHTED_ESS = 40
#: draws of the Laplace approximation a frame is read from when its result keeps none
LAPLACE_DRAWS = 4000
#: a population of target distances is fitted from at least this many other frames of a setting ...
MIN_POPULATION_FRAMES = 5
#: ... and this many informative targets among them (module docstring of :class:`Shared`)
MIN_POPULATION_TARGETS = 10
#: a pool is said to rest on few frames below this effective number of readings (ΣP)²/ΣP² ...
MIN_EFFECTIVE_FRAMES = 5.0
#: ... or when its three most precise readings carry more than this share of the weight
MAX_TOP3_SHARE = 0.6
#: the pool and its readings disagree when |D| (:func:`pool_check`) is above this
MAX_DISAGREEMENT = 2.0
#: bootstrap resamples for the sd of the readings' median (seeded: the same readings, the same numbers)
BOOTSTRAP = 500
FEW_FRAMES = "the pool rests on few frames"
DISAGREE = "the pool and the frames disagree"
TWO_POPULATIONS = ("the readings look like two populations (a mixture fits them better by BIC): not handed "
                   "back; give each frame its scene's 'setting' (where it was taken)")
#: ... said instead of a setting the scenes name: its frames are one population by the user's word, so
#: the pool is handed back, as one population wide enough for both modes
TWO_MODES = "the readings have two modes (a mixture fits them better by BIC): handed back as one wide population"


@dataclass(frozen=True)
class Shared:
    """A quantity frames share, declared once (module docstring).

    Attributes
    ----------
    name : the pooled scale's name (``log_focal``: log µ px; ``pitch``: radians; ...)
    label : the result's block key, in natural units (``focal_length_px``, ``pitch_deg``, ...)
    shared_by : ``"camera"`` (frames of one ``camera.id``), ``"crowd"`` (the data set's annotators),
        ``"setting"`` (frames of one setting, :func:`_setting`: the scene's ``setting``, else its
        camera id, else the whole data set)
    kind : ``"shared"`` (one value) or ``"spread"`` (each frame's, or target's, around a common one)
    natural : ``"log"`` (shown as exp: a median and a log-sd) or ``"angle"`` (radians shown in degrees)
    max_sd : the widest reading (sd, pooled scale) that is pooled (weaker ones are biased, docs/studies/rig.md)
    floor : a shared quantity's least sd, added in quadrature (a bias its group's frames share)
    min_spread : a spread quantity's least τ
    min_frames : other informative frames a frame's leave-one-out pool needs (a pool of all frames: one more)
    min_readings : informative readings (targets) a pool needs
    one_population : a spread quantity that is handed back only when its group's readings look like
        one population: when two normal components fit them better by BIC (:func:`two_populations`),
        the pool carries :data:`TWO_POPULATIONS` and no frame is handed it (frames of two settings
        under one group: indoor and outdoor photos without camera ids); a group that is a setting the
        scenes name is one population by the user's word, handed back with :data:`TWO_MODES`
    held : a shared quantity the frames take as given: each frame is handed the pool of *all* its
        group's frames (its own evidence counts once, inside the pool) as its value, and its result
        carries the pool's whole uncertainty (statistical ⊕ floor) as one scale its group's frames
        share (:func:`share_scale`); else a frame gets the others' pool as a prior
    """

    name: str
    label: str
    shared_by: str
    kind: str
    natural: str = "log"
    max_sd: float = math.inf
    floor: float = 0.0
    min_spread: float = 0.0
    min_frames: int = 1
    min_readings: int = 1
    held: bool = False
    one_population: bool = False


#: Every quantity the data-set layer learns (module docstring). The camera's: measured in
#: docs/studies/rig.md (the focal length's max_sd 0.25; its floor 0.03, measured on the KITTI
#: development frames: the excess of disjoint blocks' squared errors over their stated variances is
#: ≈ 0, 0.03 its bootstrap 84th percentile, examples/focal_floor.py; held: "A shared value handed
#: back as shared"; the mounting's thresholds not measured against truth). The crowd's reference
#: scale: a crowd's scale varies between frames (other annotators, other lines), at least 10 % (not
#: measured). Target distances: every reading, however weak (a far target reads weaker than a near
#: one: keeping only readings of sd ≤ 0.25 kept 36 of 80 thin outdoor targets, 0.15 nearer in log
#: distance than all 80, and the population followed; docs/studies/method.md), a population at
#: least 10 % wide in log distance.
SHARED = {s.name: s for s in (
    Shared("log_focal", "focal_length_px", "camera", "shared", max_sd=0.25, floor=0.03, held=True),
    Shared("log_height", "height_m", "camera", "spread", max_sd=0.25, min_spread=0.03),
    Shared("pitch", "pitch_deg", "camera", "spread", "angle", max_sd=math.radians(2.0), min_spread=math.radians(0.5)),
    Shared("roll", "roll_deg", "camera", "spread", "angle", max_sd=math.radians(2.0), min_spread=math.radians(0.5)),
    Shared("log_ref_scale", "ref_scale", "crowd", "spread", min_spread=0.1, min_frames=2),
    Shared("log_distance", "distance_m", "setting", "spread", min_spread=0.1, one_population=True,
           min_frames=MIN_POPULATION_FRAMES, min_readings=MIN_POPULATION_TARGETS),
)}
#: what a frame's focal length is read given (the others' pool of it): the orientation
GIVEN = ("pitch", "roll")
#: the corner scale (sd px, degrees of freedom) is read from the annotations (:func:`~.corner_scales`)
#: or, where no object is annotated twice, from the first pass's residuals (:func:`read_corner_residuals`)
CORNER_SCALE = Shared("corner_scale", "corner_scale_px", "crowd", "shared")
#: ... and the floor of the marginal reading's prior of a segment's length (px), from the drawn
#: references (:func:`~.segment_floors`)
SEGMENT_FLOOR = Shared("segment_floor", "segment_floor_px", "crowd", "shared")
#: ... and the tail of its stated values (Student-t degrees of freedom), chosen by the references'
#: leave-one-out predictive density in the first pass (:class:`TailPool`)
REF_TAIL = Shared("ref_dof", "ref_dof", "crowd", "shared")
#: the tails a crowd's references are scored under (Student-t degrees of freedom; 30: nearly normal,
#: the lightest offered: a crowd that looks normal is still read with a little robustness)
TAIL_DOFS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.0, 30.0)
#: ... each with the first pass's crowd scale times these (the scale a tail fits best differs
#: from the one it was drawn under; the best of them is taken for each tail)
TAIL_SCALES = (0.5, 0.7, 1.0, 1.4, 2.0)
#: draws of a frame's first pass its references are scored with
TAIL_DRAWS = 400
#: the fewest references of the other frames a tail is chosen from
MIN_TAIL_REFERENCES = 20


@dataclass(frozen=True)
class Reading:
    """One frame's likelihood N(mean, 1/precision) of a shared quantity (one target's, for a
    distance), in its ``group`` (a camera id, ``"crowd"``, a setting)."""

    key: str
    group: str
    mean: float
    precision: float


@dataclass(frozen=True)
class PoolCheck:
    """How a pool rests on its readings (:func:`pool_check`): ``used`` informative readings of
    ``offered``, ``n_eff``, ``top3_share``, the readings' ``median`` (pooled scale), the
    disagreement ``d`` and the ``warnings``."""

    used: int
    offered: int
    n_eff: float
    top3_share: float
    median: float
    d: float
    warnings: tuple


@dataclass(frozen=True)
class Pooled:
    """A group's pooled value of a quantity: ``center`` M, ``var`` V of M (a shared quantity's with
    its floor), ``tau`` (the spread; 0 for a shared one), ``frames`` (informative frames),
    ``readings`` (informative readings) and the ``check``."""

    quantity: Shared
    group: str
    center: float
    var: float
    tau: float
    frames: int
    readings: int
    check: PoolCheck
    #: the frames of the group the pool was offered (the one left out excepted), in order
    keys: tuple = ()

    @property
    def prior_sd(self) -> float:
        """The sd of the prior a frame is handed: √(V + τ²)."""
        return math.sqrt(self.var + self.tau**2)

    def block(self) -> dict:
        """The pool in natural units, as a result's ``dataset`` block and ``batch``'s table show it."""
        q, c = self.quantity, self.check
        if q.natural == "log":
            out = {"median": _sig(math.exp(self.center)), "log_sd": round(math.sqrt(self.var), 4)}
            if q.kind == "spread":
                out["spread_log_sd"] = round(self.tau, 4)
            median = _sig(math.exp(c.median))
        else:
            out = {"mean": round(math.degrees(self.center), 3), "sd": round(math.degrees(math.sqrt(self.var)), 3),
                   "spread_sd": round(math.degrees(self.tau), 3)}
            median = round(math.degrees(c.median), 3)
        if q.floor:
            out["floor_log_sd"] = q.floor
        if q.held:  # every frame's value, its uncertainty carried by the results (module docstring, step 3)
            out["held"] = True
        out.update(frames=self.frames, frames_offered=c.offered, n_eff=round(c.n_eff, 1),
                   top3_share=round(c.top3_share, 2), frames_median=median, disagreement=round(c.d, 2),
                   warnings=list(c.warnings))
        if self.readings != self.frames:
            out["readings"] = self.readings
        return out


def _sig(v: float) -> float:
    return float(f"{v:.6g}")


def divide_prior(q: np.ndarray, log_prior: np.ndarray | None,
                 log_reweight: np.ndarray | None = None) -> tuple[float, float, float] | None:
    """The likelihood of a quantity from draws ``q`` and the log prior at them: the draws
    reweighted by 1/prior (self-normalised importance weights) → (mean, variance, effective sample
    size of the weights), or None when the weights' effective sample size is below
    :data:`MIN_WEIGHT_ESS` of the draws or the variance is not positive. ``log_reweight``: a further
    log weight at each draw (the draws moved to another prior of other quantities); then the
    weights' effective sample size must also be :data:`MIN_REWEIGHTED_ESS` or more."""
    q = np.asarray(q, dtype=float)

    def normalised(lw):
        w = np.exp(lw - lw.max())
        return w / w.sum()

    own = np.zeros(len(q)) if log_prior is None else -np.asarray(log_prior, dtype=float)
    w = normalised(own)
    ess = 1.0 / float((w**2).sum())
    if not (len(q) > 1 and ess >= MIN_WEIGHT_ESS * len(q)):
        return None
    if log_reweight is not None:
        w = normalised(own + np.asarray(log_reweight, dtype=float))
        ess = 1.0 / float((w**2).sum())
        if not ess >= MIN_REWEIGHTED_ESS:
            return None
    mean = float((w * q).sum())
    var = float((w * (q - mean) ** 2).sum()) / (1.0 - 1.0 / ess)  # unbiased for reliability weights
    if not (var > 0 and np.isfinite(var)):
        return None
    return mean, var, ess


def likelihood(q: np.ndarray, log_prior: np.ndarray | None,
               log_reweight: np.ndarray | None = None) -> tuple[float, float] | None:
    """A reading (mean, precision) from draws ``q`` with the prior divided out (:func:`divide_prior`),
    or None when it cannot be read or has less than :data:`MIN_INFORMATION` of the posterior's
    precision."""
    post = float(np.var(q, ddof=1)) if len(q) > 1 else 0.0
    lik = divide_prior(q, log_prior, log_reweight)
    if lik is None or not (post > 0 and np.isfinite(post)) or not 1.0 / lik[1] >= MIN_INFORMATION / post:
        return None
    return lik[0], 1.0 / lik[1]


def combine(m: np.ndarray, p: np.ndarray, kind: str, min_spread: float = 0.0) -> tuple[float, float, float]:
    """(M, V, τ) of readings N(mᵢ, 1/pᵢ) (module docstring, step 2), V without a floor."""
    w = p.sum()
    center = float((p * m).sum() / w)
    n = len(m)
    q = float((p * (m - center) ** 2).sum())
    if kind == "shared":
        return center, (1.0 / w) * max(1.0, q / (n - 1) if n > 1 else 1.0), 0.0
    tau2 = max(0.0, (q - (n - 1)) / (w - (p**2).sum() / w)) if n > 1 else 0.0
    tau2 = max(tau2, min_spread**2)
    ws = 1.0 / (1.0 / p + tau2)
    center = float((ws * m).sum() / ws.sum())
    return center, float(1.0 / ws.sum()), math.sqrt(tau2)


def pool_check(m: np.ndarray, p: np.ndarray, center: float, var: float, offered: int) -> PoolCheck:
    """How a pool (``center``, ``var`` without a floor) rests on its informative readings
    N(mᵢ, 1/pᵢ): n_eff = (ΣPᵢ)²/ΣPᵢ², the three most precise readings' share of the weight, and
    the disagreement D = (M − median of the mᵢ) / √(sd of that median² + V) (the median's sd by a
    seeded bootstrap; V without the floor, a bias the readings share moves both alike). Warnings:
    "rests on few frames" when n_eff < :data:`MIN_EFFECTIVE_FRAMES` or the top three carry more than
    :data:`MAX_TOP3_SHARE`; "disagree" when |D| > :data:`MAX_DISAGREEMENT`. ``offered``: the
    readings made, informative or not."""
    n = len(m)
    n_eff = float(p.sum() ** 2 / (p**2).sum())
    top3 = float(np.sort(p)[::-1][:3].sum() / p.sum())
    median = float(np.median(m))
    rng = np.random.default_rng(0)
    sd_median = float(np.std(np.median(m[rng.integers(0, n, (BOOTSTRAP, n))], axis=1))) if n > 1 else 0.0
    d = (center - median) / math.sqrt(sd_median**2 + var)
    warns = []
    if n_eff < MIN_EFFECTIVE_FRAMES or top3 > MAX_TOP3_SHARE:
        warns.append(FEW_FRAMES)
    if abs(d) > MAX_DISAGREEMENT:
        warns.append(DISAGREE)
    return PoolCheck(n, offered, n_eff, top3, median, d, tuple(warns))


def two_populations(m: np.ndarray, p: np.ndarray, min_each: int = MIN_POPULATION_TARGETS) -> bool:
    """Whether readings N(mᵢ, 1/pᵢ) look like two populations: the maximum likelihood of a mixture
    of two random-effects normals, π N(μ₁, τ₁² + 1/pᵢ) + (1 − π) N(μ₂, τ₂² + 1/pᵢ), beats that of
    one, N(μ, τ² + 1/pᵢ), by more than BIC's price of its three more parameters, (3/2) log n, and
    each component holds ``min_each`` readings or more (min(π, 1 − π) n: fewer are no population,
    as a population of one needs as many; fewer than 10 readings: never). Seeded starts: the same
    readings, the same answer."""
    from scipy.optimize import minimize
    from scipy.special import expit, logsumexp

    m, v = np.asarray(m, float), 1.0 / np.asarray(p, float)
    n = len(m)
    if n < 10:
        return False

    def nll1(t):
        s2 = v + math.exp(2.0 * t[1])
        return 0.5 * float(np.sum(np.log(2.0 * math.pi * s2) + (m - t[0]) ** 2 / s2))

    def nll2(t):
        w = expit(t[4])
        parts = []
        for mu, log_tau, share in ((t[0], t[2], w), (t[1], t[3], 1.0 - w)):
            s2 = v + math.exp(2.0 * log_tau)
            parts.append(math.log(max(share, 1e-300)) - 0.5 * (np.log(2.0 * math.pi * s2) + (m - mu) ** 2 / s2))
        return -float(np.sum(logsumexp(np.stack(parts), axis=0)))

    spread = max(float(np.std(m)), 1e-3)
    options = {"xatol": 1e-4, "fatol": 1e-6, "maxiter": 8000}  # a BIC decision: 1e-6 nats are nothing
    one = minimize(nll1, [float(np.median(m)), math.log(spread)], method="Nelder-Mead", options=options)
    best = min((minimize(nll2, [*np.quantile(m, [lo, hi]), math.log(spread / 2), math.log(spread / 2), 0.0],
                         method="Nelder-Mead", options=options) for lo, hi in ((0.25, 0.75), (0.1, 0.6), (0.4, 0.9))),
               key=lambda f: f.fun)
    share = float(expit(best.x[4]))
    return bool(2.0 * (one.fun - best.fun) > 3.0 * math.log(n) and min(share, 1.0 - share) * n >= min_each)


def scale_draws(cams: np.ndarray, objs: np.ndarray, log_k) -> tuple[np.ndarray, np.ndarray]:
    """Copies of the draws, cameras (n, 5) and objects (n, m, 7), with draw d's focal length (px)
    and every object's depth z (m) multiplied by exp(``log_k``) (a natural log, one number or (n,)):
    :func:`scale_depths` on arrays (its docstring says why this is the focal length's whole effect).
    ValueError: a log_k not finite."""
    from ...models.contract import C_FOCAL, O_Z

    cams, objs = np.array(cams, float), np.array(objs, float)
    k = np.exp(np.broadcast_to(np.asarray(log_k, float), (len(cams),)))
    if not np.all(np.isfinite(k)):
        raise ValueError(f"scale_depths: log_k must be finite, got {log_k!r}")
    cams[:, C_FOCAL] *= k
    objs[:, :, O_Z] *= k[:, None]
    return cams, objs


def shared_log_k(block: dict | None, base_seed: int, n: int) -> np.ndarray | None:
    """(n,) the factors (natural logs) by which a frame's draws carry the held values' shared
    uncertainty (:func:`shared_scale` of its ``dataset`` block), or None when it took none: the
    same numbers :func:`share_scale` multiplies a result's kept draws by."""
    scale = shared_scale(block or {}, base_seed)
    if scale is None:
        return None
    return np.random.default_rng(scale["seed"]).normal(0.0, scale["log_sd"], int(n))


def scale_depths(result: dict, log_k, log_k_map: float = 0.0) -> dict:
    """``result`` (a ``creference-result/2`` dict, changed in place and returned) as if its camera's
    focal length were exp(``log_k``) times what it used: every kept draw's focal length (px) and
    every object's depth z (m) multiplied by exp(log_k) (``log_k``: a natural log, one number or
    one per kept draw), the MAP's by exp(``log_k_map``), the posterior summaries recomputed from the
    kept draws, each object's ``evaluation`` dropped. ValueError: no kept draws, or a log_k not finite.

    Why this is the focal length's whole effect: with the image fixed, µ → kµ maps a point at
    depth z to kz with x and y (the height) unchanged (u − c = µx/z). Checked on KITTI frames: the
    MAP depth moves as k^0.9 (the size and location priors pull back a little), x within 0.16 m,
    yaw within 0.015 rad, sizes within 4 % (docs/studies/rig.md, "A shared value handed back as
    shared")."""
    from ...io.result import _posterior_block, _summary, camera_posterior, stored_draws
    from ...models.contract import C_FOCAL, CAMERA_NAMES, O_Z, OBJECT_REPORT, object_report

    kept = stored_draws(result)
    if kept is None:
        raise ValueError("scale_depths: the result keeps no posterior draws")
    cams, objs = scale_draws(kept.cameras[0], kept.objects[0], log_k)
    draws = result["draws"]
    draws["camera"]["focal_length_px"] = np.round(cams[:, C_FOCAL], 6).tolist()
    for o, col in zip(draws["objects"], np.moveaxis(objs[:, :, O_Z], 1, 0)):
        o["z"] = np.round(col, 6).tolist()
    prob = float(result.get("hdi_prob", 0.9))
    camera = result["camera"]
    camera["map"]["focal_length_px"] = _sig(camera["map"]["focal_length_px"] * math.exp(log_k_map))
    camera["posterior"] = camera_posterior(cams, prob, [n in camera["free"] or n == "focal_length_px"
                                                        for n in CAMERA_NAMES])
    table = object_report(cams, objs)
    for i, o in enumerate(result["objects"]):
        o["map"]["z"] = _sig(o["map"]["z"] * math.exp(log_k_map))
        o["map"]["distance_m"] = _sig(math.hypot(o["map"]["x"], o["map"]["z"]))
        o["posterior"] = _posterior_block(OBJECT_REPORT, _summary(table[:, i], prob), prob)
        o.pop("evaluation", None)  # against the truth of the depths before (evaluate reads the labels)
    return result


class Pool:
    """One quantity's readings grouped once, as arrays: a frame's leave-one-out pool is then one
    vectorised combination over its group's readings. ``named``: the groups that are settings the
    scenes name (each one population, whatever its readings look like)."""

    def __init__(self, quantity: Shared, readings: list[Reading], named: frozenset = frozenset()):
        self.quantity = quantity
        groups: dict[str, list[Reading]] = {}
        for r in readings:
            groups.setdefault(r.group, []).append(r)
        #: group → (keys, means, precisions) of its readings
        self.groups = {g: (np.array([r.key for r in rs], dtype=object), np.array([r.mean for r in rs]),
                           np.array([r.precision for r in rs])) for g, rs in sorted(groups.items())}
        #: group → whether its informative readings look like two populations (``one_population``
        #: quantities; decided once on all of them, as a property of the group)
        self.mixed = {g: quantity.one_population and two_populations(
                          m[p >= quantity.max_sd**-2], p[p >= quantity.max_sd**-2], quantity.min_readings)
                      for g, (_, m, p) in self.groups.items()}
        self.named = frozenset(named)

    def estimate(self, group: str, leave_out: str | None = None) -> Pooled | None:
        """The group's pool without the frame ``leave_out`` (a KEY: all its readings), or None when
        its informative readings are too few: ``min_frames`` other frames for a frame's pool, one
        more for the pool of all frames, and ``min_readings`` readings."""
        if group not in self.groups:
            return None
        q = self.quantity
        keys, m, p = self.groups[group]
        offered = keys != leave_out
        keep = offered & (p >= q.max_sd**-2)
        frames = len(set(keys[keep]))
        if frames < q.min_frames + (leave_out is None) or keep.sum() < max(q.min_readings, 1):
            return None
        center, var, tau = combine(m[keep], p[keep], q.kind, q.min_spread)
        check = pool_check(m[keep], p[keep], center, var, int(offered.sum()))
        if self.mixed[group]:  # D measures the readings against one centre: said of two, it says nothing more
            check = replace(check, warnings=tuple(w for w in check.warnings if w != DISAGREE) + (
                TWO_MODES if group in self.named else TWO_POPULATIONS,))
        if q.kind == "shared":
            var += q.floor**2
        return Pooled(q, group, center, var, tau, frames, int(keep.sum()), check, tuple(dict.fromkeys(keys[offered])))

    def values(self, group: str) -> list[dict]:
        """Every reading of the group in natural units, as ``batch.json`` keeps them for the data
        set's figure (:func:`~creference_bayes.vision.dataset_figures.dataset_figure`): ``frame``,
        ``value`` and its one-sd interval ``low``, ``high``, and whether the pool ``used`` it."""
        q = self.quantity
        keys, m, p = self.groups[group]
        sd = 1.0 / np.sqrt(p)

        def natural(x):  # (a reading too weak to bound: None)
            with np.errstate(over="ignore"):
                v = float(np.exp(x) if q.natural == "log" else np.degrees(x))
            return _sig(v) if math.isfinite(v) else None

        return [{"frame": str(k), "value": natural(v), "low": natural(v - s), "high": natural(v + s),
                 "used": bool(pi >= q.max_sd**-2)} for k, v, s, pi in zip(keys, m, sd, p)]


def _draws(result: dict, scene):
    """A first-pass result's model and draws: cameras (k, 5), objects (k, m, 7): those it keeps,
    else :data:`LAPLACE_DRAWS` of the Laplace approximation at its MAP (seeded)."""
    from ...pipeline import rebuild_model, result_draws

    model = rebuild_model(result, scene)
    cams, objs, _ = result_draws(result, model, n=LAPLACE_DRAWS, seed=0)
    return model, cams, objs


def _setting(camera_id: str | None, setting: str | None = None) -> str:
    """A frame's group of a ``"setting"`` quantity: the ``setting`` its scene names, else its camera
    id, else ``"data set"`` (every frame that names neither)."""
    return setting if setting is not None else camera_id if camera_id is not None else "data set"


def read_readings(key: str, scene, result: dict, camera_id: str | None, draws=None,
                  log_reweight: np.ndarray | None = None) -> dict[str, list[Reading]]:
    """Every reading of one frame's first-pass result (module docstring, step 1): quantity name →
    readings (a camera's quantities, the crowd's reference scale, each target's log distance).
    ``draws``: the result's (cameras, objects) when already drawn (:func:`_draws`);
    ``log_reweight``: a log weight per draw moving them to another model (:func:`tail_reweight`)."""
    from ...models.contract import C_SCALE, O_X, O_Z, REF_SCALE_LOG_SD, REF_SCALE_MEDIAN
    from ...models.location_prior import LocationPrior
    from .rig import camera_likelihood

    cams, objs = draws if draws is not None else _draws(result, scene)[1:]
    out: dict[str, list[Reading]] = {}
    if camera_id is not None:
        for name, (mean, precision) in camera_likelihood(result, cams, log_reweight=log_reweight).items():
            out[name] = [Reading(key, camera_id, mean, precision)]
    prov = result.get("provenance") or {}
    free = set(result["camera"].get("free", ()))
    if "ref_scale" in free:  # the log-normal prior the frame used, as a density in log s
        opts = prov.get("options") or {}
        median = float(opts.get("ref_scale_median", REF_SCALE_MEDIAN))
        log_sd = float(opts.get("ref_scale_log_sd", REF_SCALE_LOG_SD))
        q = np.log(cams[:, C_SCALE])
        lik = likelihood(q, -0.5 * ((q - math.log(median)) / log_sd) ** 2, log_reweight)
        if lik is not None:
            out["log_ref_scale"] = [Reading(key, "crowd", *lik)]
    location = LocationPrior(prov.get("location_prior", "flat"), prov.get("distance_range_m"),
                             prov.get("location_population"))
    readings = []
    for j in range(objs.shape[1]):
        x, z = objs[:, j, O_X], objs[:, j, O_Z]
        # weights p_kind/p: the evidence on log d relative to the kind's density (location_prior.py)
        lik = likelihood(0.5 * np.log(x * x + z * z), location.relative_log_prior(x, z), log_reweight)
        if lik is not None:
            readings.append(Reading(key, _setting(camera_id, scene.setting), *lik))
    if readings:
        out["log_distance"] = readings
    return out


def read_focal_given_orientation(ds: "DataSet", key: str, result: dict, cams: np.ndarray,
                                 log_reweight: np.ndarray | None = None) -> Reading | None:
    """Frame ``key``'s focal-length reading as if it had known its camera's orientation: its draws
    reweighted from the wide default pitch and roll prior it was estimated under to the pool of the
    other frames' (N(M₋ᵢ, V₋ᵢ + τ²), :data:`GIVEN`), with its focal prior divided out
    (:func:`.rig.camera_likelihood`). Why: with a pitch free within ±15°, a frame that pins the
    horizon in pixels leaves a pitch width shrinking as 1/µ, an extra ≈ 1/µ prior that biases a
    weak frame's focal length low (docs/studies/rig.md); the camera's pitch, which every frame
    knows well, takes it away. Not the height: its pool leans 2 % high on KITTI, which the focal
    length would follow. None: no reading (as :func:`read_readings`)."""
    from .rig import camera_likelihood

    camera_id = ds.camera_of.get(key)
    if camera_id is None:
        return None
    given = {n: (e.center, e.prior_sd) for n in GIVEN if (e := ds.estimate(n, key)) is not None}
    lik = camera_likelihood(result, cams, given, log_reweight).get("log_focal")
    return None if lik is None else Reading(key, camera_id, *lik)


def _results(frames, folder):
    """(KEY, camera id, scene, result) of every frame of ``frames`` ((KEY, camera id) pairs) with a
    result in the batch folder ``folder``."""
    from ...io.result import read_result
    from ...io.scene import SceneWarning, load_scene
    from .files import layout

    for key, camera_id in frames:
        paths = layout(folder, key)
        if paths["result"].exists():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = load_scene(paths["scene"])
            yield key, camera_id, scene, read_result(paths["result"])


def read_corner_residuals(model, result: dict, cams: np.ndarray, objs: np.ndarray) -> tuple[float, float] | None:
    """A frame's reading of its crowd's corner scale from its dimension lines alone: (squares px²,
    degrees of freedom), such that the crowd's sd per corner coordinate is √(Σ squares / Σ degrees
    of freedom) over frames, as :func:`~.corner_scales` reads it from objects annotated twice.

    The squares are those of its annotations' corners around their projection at the MAP, less
    what the priors' pull adds to them; the degrees of freedom N − Σ λ(2 − λ), N the corner
    coordinates and λ ∈ [0, 1] the eigenvalues of A = F Σ, the share of each fitted direction that
    the lines decide (F the lines' information at the MAP: per coordinate of object i's sets, the
    mean over its corners of the weight the fit gives a corner, (ν + 2) / (ν σᵢ² + |r|²) for a
    bivariate Student-t at the corner's residual r, as iteratively reweighted least squares has it
    at the MAP; Σ the posterior covariance of the free parameters from the draws ``cams``,
    ``objs``, in working coordinates, where a Laplace approximation's draws are Gaussian). For a
    linear model fitted with noise variance s² whose parameters are drawn from its prior, the
    expected squares are s² Σ λ(1 − λ) + σ² (N − Σ λ(2 − λ)), σ the true noise: the first term is
    taken off (s² the mean over objects of one over that weight, the fit's). A crowd noisier than
    the fit's scale leaves its corners far out, where the fit weighs them little: at the weight a
    corner has at no residual, (ν + 2) / (ν σᵢ²), the lines would seem to decide more than they do
    (on KITTI frames an 8 px crowd fitted at 5 px would read 9.2 px, not 8.8: docs/studies/kitti.md).
    None without a dimension line or free parameter."""
    from ...inference.coords import WorkingCoords
    from ...models.contract import C_SCALE
    from ...pipeline import map_state

    sets = [np.asarray(o.annotations, float) for o in model.objects]
    if not sets or not all(a.ndim == 3 and len(a) for a in sets):
        return None
    cam, obj = map_state(result)
    coords = WorkingCoords(model)  # the draws are Gaussian there (a Laplace approximation's are)
    wc, wo = coords.to_work(cam[None], obj[None])
    dc, do = coords.to_work(cams, objs)
    free_c = model.camera_free.copy()
    free_c[C_SCALE] = False
    ci, oi = np.flatnonzero(free_c), np.argwhere(model.object_free)
    x0 = np.concatenate([wc[0, ci], wo[0, oi[:, 0], oi[:, 1]]])
    n = len(x0)
    draws = np.column_stack([dc[:, ci], do[:, oi[:, 0], oi[:, 1]]])
    if n == 0 or not np.all(np.isfinite(draws)) or not np.all(np.isfinite(x0)):
        return None
    sigma = np.cov(draws, rowvar=False).reshape(n, n)
    h = 1e-6 * np.maximum(1.0, np.abs(x0))
    moves = np.vstack([np.diag(h), -np.diag(h)])
    mc = np.repeat(wc, 2 * n, axis=0)
    mo = np.repeat(wo, 2 * n, axis=0)
    mc[:, ci] += moves[:, :len(ci)]
    mo[:, oi[:, 0], oi[:, 1]] += moves[:, len(ci):]
    uv = model.project(*coords.from_work(mc, mo))[0].reshape(2 * n, len(sets), 8)
    jac = (uv[:n] - uv[n:]) / (2.0 * h[:, None, None])                         # (n, m, 8)
    if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(sigma))):  # a step over the horizon
        return None
    nu = float(getattr(model, "target_dof", np.inf))
    at = model.project(cam[None], obj[None])[0][0]                             # (m, 4, 2)
    s2 = np.asarray(model.sigma, float) ** 2
    # each corner's weight in the fit, (ν + 2) / (ν σᵢ² + |r|²) (the Student-t's at its residual r, as
    # iteratively reweighted least squares has it at the MAP; (ν + 2) / (ν σᵢ²) at r = 0), averaged per object
    w = np.array([np.mean((nu + 2.0) / (nu * s2[i] + np.sum((a - at[i]) ** 2, axis=-1))) if np.isfinite(nu)
                  else 1.0 / s2[i] for i, a in enumerate(sets)])
    weight = np.array([len(a) for a in sets]) * w
    info = np.einsum("i,nia,kia->nk", weight, jac, jac)
    f, u = np.linalg.eigh(info)
    root = u * np.sqrt(np.clip(f, 0.0, None))  # F = root rootᵀ: A's eigenvalues are those of rootᵀ Σ root
    share = np.clip(np.linalg.eigvalsh(root.T @ sigma @ root), 0.0, 1.0)  # each in [0, 1] (a repaired Laplace)
    dof = sum(s.size for s in sets) - float(np.sum(share * (2.0 - share)))
    # what the priors' pull adds to the squares when the truth is drawn from them, at the fit's scale
    prior_part = float(np.mean(1.0 / w)) * float(np.sum(share * (1.0 - share)))
    squares = float(sum(np.sum((a - at[i]) ** 2) for i, a in enumerate(sets))) - prior_part
    if not (np.isfinite(squares) and np.isfinite(dof)) or dof <= 0:
        return None
    return max(squares, 0.0), dof


#: the fewest frames' residual readings whose spread (:func:`scale_spread`) is read
MIN_SPREAD_FRAMES = 10
#: ... each sᵢ² at least this share of their median (limma's floor) ...
MIN_SPREAD_SHARE = 1e-5
#: ... and their spread beyond the χ² noise's at least this many of its standard errors (from the
#: readings' fourth moment: one outlying frame makes a large one, and is no spread)
SPREAD_Z = 1.5


class ScaleSpread:
    """:func:`scale_spread` of a data set's residual readings (KEY → (squares, dof)), and of all
    of them but one frame's (:meth:`leave_out`), from sums: each frame's in constant time."""

    def __init__(self, readings: dict):
        from scipy.special import digamma, polygamma

        keys = list(readings)
        s2 = np.array([readings[k][0] for k in keys], float)
        d = np.array([readings[k][1] for k in keys], float)
        ok = (s2 >= 0) & (d >= 0.5) & np.isfinite(s2) & np.isfinite(d)
        s2 = np.where(ok, s2 / np.where(ok, d, 1.0), np.nan)
        floor = MIN_SPREAD_SHARE * float(np.nanmedian(s2)) if ok.any() else 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.log(np.maximum(s2, floor)) - digamma(d / 2.0) + np.log(d / 2.0)
        self.index = {k: i for i, k in enumerate(keys)}
        self.ok = ok
        #: (k, readings) e¹…e⁴ and trigamma(dᵢ/2) of each reading (0 for one not made)
        self.terms = np.where(ok, np.stack([e, e**2, e**3, e**4, polygamma(1, np.where(ok, d, 1.0) / 2.0)]), 0.0)
        self.sums = self.terms.sum(axis=1)

    def leave_out(self, key: str | None) -> tuple[float, float] | None:
        """(s₀² px², d₀) of every reading but ``key``'s (all with None), or None (one scale)."""
        n, sums = int(self.ok.sum()), self.sums
        i = self.index.get(key)
        if i is not None and self.ok[i]:
            n, sums = n - 1, sums - self.terms[:, i]
        if n < MIN_SPREAD_FRAMES:
            return None
        m1, r2, r3, r4, tri = sums / n
        m2 = max(r2 - m1**2, 0.0)
        m4 = max(r4 - 4 * m1 * r3 + 6 * m1**2 * r2 - 3 * m1**4, 0.0)
        var = m2 * n / (n - 1)
        se = math.sqrt(max(m4 - (n - 3) / (n - 1) * m2**2, 0.0) / n)  # of the sample variance
        excess = var - tri
        return _inverse_chi2_prior(m1, excess) if excess > SPREAD_Z * se else None


def _log_sd_of_scale(dof: float) -> float:
    """The sd of log s of a scale read on ``dof`` degrees of freedom (s² ~ σ² χ²(dof)/dof):
    √trigamma(dof/2) / 2; the spread of the frames' log σ under a scaled inverse-χ² prior of d₀ the same."""
    from scipy.special import polygamma

    return math.sqrt(float(polygamma(1, dof / 2.0))) / 2.0


def _inverse_chi2_prior(mean_e: float, excess: float) -> tuple[float, float] | None:
    """(s₀², d₀) from the mean of the readings' e and their variance beyond the χ² noise's (Smyth
    2004, section 6.2): trigamma(d₀/2) = excess by Newton's method, as limma's trigammaInverse;
    None when the excess is not positive."""
    from scipy.special import digamma, polygamma

    if not excess > 0:
        return None
    y = 0.5 + 1.0 / excess
    for _ in range(50):
        tri = float(polygamma(1, y))
        step = tri * (1.0 - tri / excess) / float(polygamma(2, y))
        y += step
        if -step / y < 1e-8:
            break
    d0 = 2.0 * y
    return float(np.exp(mean_e + digamma(d0 / 2.0) - np.log(d0 / 2.0))), d0


def scale_spread(squares: np.ndarray, dofs: np.ndarray) -> tuple[float, float] | None:
    """Whether frames' corner scales spread, from their residual readings (squares px², degrees of
    freedom dᵢ: :func:`read_corner_residuals`): the scaled inverse-χ² prior of the frames' true
    variances, (s₀² px², d₀), that makes each sᵢ² = squaresᵢ / dᵢ an F-distributed reading, fitted by
    the moments of eᵢ = log sᵢ² − digamma(dᵢ/2) + log(dᵢ/2) (Smyth 2004, "Linear models and empirical
    Bayes methods for assessing differential expression in microarray experiments", SAGMB 3(1),
    section 6.2), each sᵢ² at least :data:`MIN_SPREAD_SHARE` of their median. None when the eᵢ spread
    no more than their χ² noise does, by :data:`SPREAD_Z` standard errors of their variance (one
    scale: d₀ infinite), or with fewer than :data:`MIN_SPREAD_FRAMES` readings of at least half a
    degree of freedom."""
    return ScaleSpread({i: (float(q), float(d)) for i, (q, d) in enumerate(zip(squares, dofs))}).leave_out(None)


def _reads_tails(model) -> bool:
    """Whether ``model`` has references read with a Student-t of its ``ref_dof``."""
    return "reference_likelihood" in getattr(model, "capabilities", ()) and bool(len(model.references))


def read_tail(model, cams: np.ndarray, objs: np.ndarray) -> np.ndarray | None:
    """A frame's reading of its crowd's tail: (k, :data:`TAIL_SCALES`, :data:`TAIL_DOFS`) each of
    its references' leave-one-out log predictive density under each tail and scale factor
    (:meth:`~creference_bayes.models.metrology.MetrologyModel.reference_log_densities`), from
    :data:`TAIL_DRAWS` of its draws (evenly spaced): the draws weighted by 1 / the reference's
    likelihood under the model's own tail (importance sampling leave-one-out, the weights
    truncated at √S times their mean, Ionides 2008). None: no reference a tail reads."""
    if not _reads_tails(model):
        return None
    take = np.unique(np.linspace(0, len(cams) - 1, min(TAIL_DRAWS, len(cams))).astype(int))
    ll = model.reference_log_densities(cams[take], objs[take], TAIL_DOFS, TAIL_SCALES)  # (S, D, n, k)
    own = model.reference_log_densities(cams[take], objs[take], (model.ref_dof,))[0, 0]
    read = np.isfinite(own).all(axis=0) & np.isfinite(ll).all(axis=(0, 1, 2))
    if not read.any():
        return None
    lw = -own[:, read]
    w = np.exp(lw - lw.max(axis=0))
    w = np.minimum(w, math.sqrt(len(w)) * w.mean(axis=0))
    w /= w.sum(axis=0)
    ll = ll[..., read]
    top = ll.max(axis=2, keepdims=True)
    return np.moveaxis(top[:, :, 0] + np.log(np.sum(w * np.exp(ll - top), axis=2)), -1, 0)


def tail_reweight(model, cams: np.ndarray, objs: np.ndarray, dof: float) -> np.ndarray | None:
    """Log weights (k,) moving a frame's draws from its model's own tail to ``dof`` degrees of
    freedom: the sum over its references of the log-likelihood ratio
    (:meth:`~creference_bayes.models.metrology.MetrologyModel.reference_log_densities`); None
    without references a tail reads."""
    if not _reads_tails(model):
        return None
    ll = model.reference_log_densities(cams, objs, (model.ref_dof, dof))[0]
    ratio = np.where(np.isfinite(ll).all(axis=0), ll[1] - ll[0], 0.0).sum(axis=-1)
    return ratio if np.isfinite(ratio).all() and ratio.any() else None


class TailPool:
    """The crowd's tail from the frames' readings (:func:`read_tail`): KEY → (k, scales, tails)."""

    def __init__(self, readings: dict, own_dof: float):
        self.own_dof = float(own_dof)
        keys = [k for k, r in readings.items() for _ in range(len(r))]
        self.keys = np.array(keys, dtype=object)
        self.scores = (np.concatenate([r for r in readings.values()]) if keys
                       else np.zeros((0, len(TAIL_SCALES), len(TAIL_DOFS))))

    def estimate(self, leave_out: str | None = None) -> dict | None:
        """The tail a frame is handed from the others' references (all with ``leave_out`` None),
        or None with fewer than :data:`MIN_TAIL_REFERENCES`: each tail at its best scale factor;
        the best tail when its summed score beats the model's own by more than twice the standard
        error of the difference, else the model's own. ``dof``, ``favoured`` (the best), the
        score's ``gain`` over the model's own and its ``se`` (nats), ``references``, ``frames``."""
        keep = self.keys != leave_out
        n = int(keep.sum())
        if n < MIN_TAIL_REFERENCES:
            return None
        sc = self.scores[keep]
        scale = sc.sum(axis=0).argmax(axis=0)                        # each tail's best scale factor
        per = sc[:, scale, np.arange(len(TAIL_DOFS))]                # (n, tails)
        best = int(per.sum(axis=0).argmax())
        own = int(np.argmin(np.abs(np.log(TAIL_DOFS) - math.log(self.own_dof))))
        d = per[:, best] - per[:, own]
        gain, se = float(d.sum()), float(math.sqrt(n * d.var()))
        return {"dof": TAIL_DOFS[best] if gain > 2.0 * se else self.own_dof, "favoured": TAIL_DOFS[best],
                "gain": round(gain, 1), "se": round(se, 1), "references": n,
                "frames": len(set(self.keys[keep]))}


@dataclass
class DataSet:
    """The pools of every quantity a batch learns, from its first pass (:meth:`from_first_pass`).

    Attributes
    ----------
    pools : quantity name → :class:`Pool`
    learn : the quantity names learnt (:func:`plan`)
    camera_of : KEY → the frame's camera id (None: a camera of its own)
    setting_of : KEY → the ``setting`` the frame's scene names (:func:`_setting`), where it names one
    tail : the crowd's reference tail (:class:`TailPool`), when ``ref_dof`` is learnt
    residuals : KEY → the frame's reading of the corner scale (:func:`read_corner_residuals`),
        when ``corner_scale`` is learnt
    fitted_at_px : the corner scale the residuals' first pass was fitted at again
        (:meth:`refit_at`), or None: at the default
    """

    pools: dict
    learn: tuple
    camera_of: dict = field(default_factory=dict)
    setting_of: dict = field(default_factory=dict)
    tail: TailPool | None = None
    residuals: dict = field(default_factory=dict)
    fitted_at_px: float | None = None

    @classmethod
    def from_first_pass(cls, frames, folder, learn: tuple, *, focal_given_orientation: bool = True,
                        settings: dict | None = None) -> "DataSet":
        """Read every first-pass result in the batch folder ``folder`` of ``frames`` ((KEY, camera
        id) pairs; a frame without a result is left out: its groups learn from the others).
        ``settings``: KEY → the ``setting`` every frame's scene names (None: read from the scenes
        with a result; a frame whose first pass failed is then grouped by its camera).

        With ``focal_given_orientation`` (the default) each frame's focal length is read given the
        other frames' pool of its camera's pitch and roll (:func:`read_focal_given_orientation`),
        whether or not ``learn`` hands those back: without ``pitch`` and ``roll`` in ``learn``
        (``--rig focal``) their pools serve the reading only and are not kept. False: each
        frame's focal length read alone (its own prior divided out; ``examples/dataset_pool.py``
        compares the two)."""
        tail = None
        if REF_TAIL.name in learn:  # the tail first: the other readings are read under it
            tails, own_dof = {}, None
            for key, _, scene, result in _results(frames, folder):
                model, cams, objs = _draws(result, scene)
                if (t := read_tail(model, cams, objs)) is not None:
                    tails[key], own_dof = t, model.ref_dof
            tail = TailPool(tails, own_dof) if tails else None
        dof = None if tail is None or (est := tail.estimate()) is None or est["dof"] == tail.own_dof else est["dof"]
        given = focal_given_orientation and "log_focal" in learn
        read = tuple(learn) + tuple(n for n in GIVEN if given and n not in learn)
        readings: dict[str, list[Reading]] = {name: [] for name in read if name in SHARED}
        kept, residuals, named = {}, {}, dict(settings or {})
        for key, camera_id, scene, result in _results(frames, folder):
            if settings is None and scene.setting is not None:
                named[key] = scene.setting
            model, cams, objs = _draws(result, scene)
            if CORNER_SCALE.name in learn and (r := read_corner_residuals(model, result, cams, objs)) is not None:
                residuals[key] = r
            # a frame estimated under the model's own tail, read as if under the crowd's (its draws
            # reweighted by the references' likelihood ratio): the crowd's scale is a tail's scale
            reweight = None if dof is None else tail_reweight(model, cams, objs, dof)
            kept[key] = (result, cams, reweight)
            for name, rs in read_readings(key, scene, result, camera_id, (cams, objs), reweight).items():
                if name in readings:
                    readings[name] += rs
        declared = frozenset(named.values())
        ds = cls({name: Pool(SHARED[name], rs, declared) for name, rs in readings.items()}, tuple(learn),
                 {key: camera_id for key, camera_id in frames}, named, tail, residuals)
        if given:
            focal = []
            for key, (result, cams, reweight) in kept.items():
                r = read_focal_given_orientation(ds, key, result, cams, reweight)
                if r is not None:
                    focal.append(r)
            ds.pools["log_focal"] = Pool(SHARED["log_focal"], focal)
            for name in set(read) - set(learn):  # read for the focal length only, not handed back
                del ds.pools[name]
        return ds

    def refit_at(self) -> float | None:
        """The corner scale (px) to fit the first pass again at, to read the crowd's from its
        residuals there: the pool of the residuals, where it is :data:`REFIT_FACTOR` or more from
        the default the first pass was fitted at; else None. A crowd much noisier than the fit's
        scale leaves its corners in the Student-t's tails, where the fit weighs them little, and a
        much more careful one fits inside a scale that is too wide: either way the residuals read
        the crowd less well than a fit at its own scale does (docs/studies/kitti.md)."""
        from ...models.metrology import DEFAULT_TARGET_SIGMA_PX

        if self.fitted_at_px is not None or (pooled := self.corner_scale_of(None)) is None:
            return None
        return pooled[0] if abs(math.log(pooled[0] / DEFAULT_TARGET_SIGMA_PX)) >= math.log(REFIT_FACTOR) else None

    def with_residuals_from(self, frames, folder, fitted_at_px: float) -> "DataSet":
        """This data set with the corner scale read from the residuals of the first pass fitted
        again at ``fitted_at_px`` in the batch folder ``folder`` (:meth:`refit_at`)."""
        residuals = {}
        for key, _, scene, result in _results(frames, folder):
            model, cams, objs = _draws(result, scene)
            if (r := read_corner_residuals(model, result, cams, objs)) is not None:
                residuals[key] = r
        return replace(self, residuals=residuals, fitted_at_px=fitted_at_px)

    @cached_property
    def _residual_totals(self) -> tuple[float, float]:
        """Σ squares and Σ degrees of freedom of every frame's :attr:`residuals`."""
        return sum(r[0] for r in self.residuals.values()), sum(r[1] for r in self.residuals.values())

    def corner_scale_of(self, key: str | None) -> tuple[float, float] | None:
        """The crowd's corner scale frame ``key`` is handed (all frames' with None): (sd px,
        degrees of freedom) from the other frames' residuals (:func:`read_corner_residuals`), the sd
        rounded to two significant digits and at least the model's floor, the degrees of freedom
        to one (as :func:`~.corner_scales`); None without another frame's reading.

        Where the other frames' scales spread (:func:`scale_spread`: a crowd whose frames were
        drawn by more and less careful workers), a frame with its own reading is handed its own
        scale: the others' prior s₀², d₀ updated by its squares and degrees of freedom,
        s² = (d₀ s₀² + squares) / (d₀ + dof) on d₀ + dof degrees of freedom (Smyth's moderated
        variance); where they look like one scale, the others' pool."""
        from ...models.metrology import MIN_TARGET_SIGMA_PX

        own = self.residuals.get(key, (0.0, 0.0))
        squares, dof = (t - o for t, o in zip(self._residual_totals, own))  # a sum once, not once per frame
        if len(self.residuals) - (key in self.residuals) < 1 or dof <= 0:
            return None
        variance = max(squares, 0.0) / dof
        if key is not None and (spread := self.scale_spread_of(key)) is not None:
            variance, dof = (spread[1] * spread[0] + own[0]) / (spread[1] + own[1]), spread[1] + own[1]
        return max(float(f"{math.sqrt(variance):.2g}"), MIN_TARGET_SIGMA_PX), float(f"{dof:.1g}")

    @cached_property
    def _spread_sums(self) -> "ScaleSpread":
        return ScaleSpread(self.residuals)

    def _residual_values(self) -> list[dict]:
        """Each frame's reading of the corner scale, √(squares / dof) px with its one-sd interval,
        as ``batch.json`` keeps the other quantities' readings (:meth:`Pool.values`)."""
        out = []
        for key, (squares, dof) in self.residuals.items():
            if squares > 0 and dof >= 0.5:
                s, half = math.sqrt(squares / dof), _log_sd_of_scale(dof)
                out.append({"frame": str(key), "value": _sig(s), "low": _sig(s * math.exp(-half)),
                            "high": _sig(s * math.exp(half)), "used": True})
        return out

    def scale_spread_of(self, key: str | None) -> tuple[float, float] | None:
        """:func:`scale_spread` of every frame's residual reading but ``key``'s (all with None)."""
        return self._spread_sums.leave_out(key)

    def tail_of(self, key: str | None) -> dict | None:
        """The crowd's tail frame ``key`` is handed (:meth:`TailPool.estimate`, leaving it out; all
        frames' with None), or None."""
        return None if self.tail is None else self.tail.estimate(key)

    def group_of(self, name: str, key: str) -> str | None:
        by = SHARED[name].shared_by
        camera_id = self.camera_of.get(key)
        return ("crowd" if by == "crowd" else _setting(camera_id, self.setting_of.get(key)) if by == "setting"
                else camera_id)

    def estimate(self, name: str, key: str, leave_out: bool = True) -> Pooled | None:
        """The pool frame ``key`` is handed of quantity ``name`` (its group's, leaving it out)."""
        group = self.group_of(name, key)
        if name not in self.pools or group is None:
            return None
        return self.pools[name].estimate(group, key if leave_out else None)

    def summary(self) -> dict:
        """Every group's pool of all its frames: quantity label → group → block (:meth:`Pooled.block`)
        and its readings (``values``, :meth:`Pool.values`)."""
        out = {}
        for name, pool in self.pools.items():
            members: dict[str, int] = {}
            for key in self.camera_of:
                if (g := self.group_of(name, key)) is not None:
                    members[g] = members.get(g, 0) + 1
            blocks = {g: {**est.block(), "group_frames": members.get(g, est.frames), "values": pool.values(g)}
                      for g in pool.groups if (est := pool.estimate(g)) is not None}
            if blocks:
                out[SHARED[name].label] = {"shared_by": SHARED[name].shared_by, "kind": SHARED[name].kind,
                                           "groups": blocks}
        if (tail := self.tail_of(None)) is not None:
            out[REF_TAIL.label] = {"shared_by": "crowd", "kind": "choice", "groups": {"crowd": tail}}
        if (scale := self.corner_scale_of(None)) is not None:
            spread = self.scale_spread_of(None)
            out[CORNER_SCALE.label] = {"shared_by": "crowd", "kind": "residuals", "groups": {"crowd": {
                "sd": scale[0], "dof": scale[1], "frames": len(self.residuals), "fitted_at_px": self.fitted_at_px,
                "log_sd": round(_log_sd_of_scale(scale[1]), 4),
                **({} if spread is None else {"spread_sd": _sig(math.sqrt(spread[0])), "spread_dof": _sig(spread[1]),
                                              "spread_log_sd": round(_log_sd_of_scale(spread[1]), 4)}),
                "values": self._residual_values()}}}
        return out

    def not_learnt(self) -> list[str]:
        """What the batch set out to learn (:attr:`learn`) and could not, a line each (and a
        ``setting`` named as the group of frames that name none: one group for both): a quantity
        no frame read, or a group whose readings are too few or too weak to pool
        (:meth:`Pool.estimate`), with how many were informative and how many a pool needs."""
        lines = []
        named = set(self.setting_of.values())
        unnamed = {_setting(c) for k, c in self.camera_of.items() if k not in self.setting_of}
        if "log_distance" in self.learn:
            lines += [f"distance_m of {g}: the setting {g!r} is also the group of frames that name no setting "
                      f"({'camera ' + repr(g) if g != 'data set' else 'neither setting nor camera'}): they share "
                      "one population; rename the setting if they should not" for g in sorted(named & unnamed)]
        if CORNER_SCALE.name in self.learn and self.corner_scale_of(None) is None:
            lines.append(f"{CORNER_SCALE.label}: not learnt: no frame's dimension lines could be read")
        for name in self.learn:
            if name not in SHARED:
                continue
            q, pool = SHARED[name], self.pools.get(name)
            if pool is None or not pool.groups:
                lines.append(f"{q.label}: not learnt: no frame could read it")
                continue
            for group, (keys, _, p) in pool.groups.items():
                if pool.estimate(group) is not None or len(set(keys)) < q.min_frames + 1:
                    continue  # pooled, or a group too small to pool whatever it read (a camera of one frame)
                good = p >= q.max_sd**-2
                bar = f"{math.degrees(q.max_sd):g}°" if q.natural == "angle" else f"{q.max_sd:g} in log"
                need = f"{q.min_frames + 1} frames" + (f" and {q.min_readings} readings" if q.min_readings > 1 else "")
                read = f" ({int(good.sum())} readings)" if q.min_readings > 1 else ""
                lines.append(f"{q.label} of {group}: not learnt: {len(set(keys[good]))} of {len(set(keys))} frames"
                             f"{read} read it within an sd of {bar}, {need} needed")
        return lines


def plan(scenes, settings) -> tuple[str, ...]:
    """The quantities a batch of ``scenes`` learns from a first pass (module docstring): empty with
    ``settings.dataset == "none"``; the camera's (``settings.rig``) when two frames share a camera
    id and one of them lacks a focal length or a calibrated mounting; the reference scale when two
    frames have references and neither ``ref_scale`` option is set; the corner scale from the first
    pass's residuals when two frames lack one and no object is annotated twice (the metrology model,
    ``pool_scale``, no ``target_sigma`` option); the references' tail when the frames
    have more than :data:`MIN_TAIL_REFERENCES` references and no ``ref_dof`` is set; the distance population when a
    setting has :data:`MIN_POPULATION_FRAMES` + 1 frames with :data:`MIN_POPULATION_TARGETS`
    targets and no ``distance_range`` is set (the default preset's location prior only)."""
    from .rig import POOLED, camera_id_of

    if settings.dataset == "none":
        return ()
    learn = []
    cameras: dict[str, list] = {}
    for s in scenes:
        cameras.setdefault(camera_id_of(s), []).append(s)
    if any(cam is not None and len(group) >= 2 and any(
            s.focal_length_px is None or s.orientation_prior is None or s.orientation_prior.source != "calibration"
            for s in group) for cam, group in cameras.items()):
        learn += [n for n in POOLED[settings.rig]]
    if (settings.model == "metrology" and settings.use_references
            and not {"ref_scale_median", "ref_scale_log_sd"} & set(settings.options)
            and sum(bool(s.references) for s in scenes) >= SHARED["log_ref_scale"].min_frames + 1):
        learn.append("log_ref_scale")
    if (settings.model == "metrology" and settings.use_references and "ref_dof" not in settings.options
            and sum(len(s.references) for s in scenes) > MIN_TAIL_REFERENCES):
        learn.append(REF_TAIL.name)
    if (settings.model == "metrology" and settings.pool_scale and "target_sigma" not in settings.options
            and not any(len(t.corners) > 1 for s in scenes for t in s.targets)
            and sum(s.corner_scale is None and bool(s.targets) for s in scenes) >= 2):
        learn.append(CORNER_SCALE.name)  # no object annotated twice: the crowd's scale from the residuals
    if settings.distance_range is None and settings.preset == "default" and settings.location_prior in ("auto", "log-depth"):
        settings_groups: dict[str, list] = {}
        for cam, group in cameras.items():
            for s in group:
                settings_groups.setdefault(_setting(cam, s.setting), []).append(s)
        if any(len(g) > MIN_POPULATION_FRAMES and sum(len(s.targets) for s in g) >= MIN_POPULATION_TARGETS
               for g in settings_groups.values()):
            learn.append("log_distance")
    return tuple(learn)


def overrides(scene, settings) -> dict:
    """What the user set by hand for this frame, which the data set does not replace: block label → why."""
    out = {}
    if scene.focal_length_px is not None:
        out["focal_length_px"] = "the scene's own focal length"
    elif scene.focal_prior is not None and getattr(scene.focal_prior, "source", None) != "rig":
        out["focal_length_px"] = "the scene's own focal-length prior"
    if {"ref_scale_median", "ref_scale_log_sd"} & set(settings.options):
        out["ref_scale"] = "--option " + ", ".join(f"{k}={settings.options[k]:g}" for k in
                                                   ("ref_scale_median", "ref_scale_log_sd") if k in settings.options)
    if "ref_dof" in settings.options:
        out[REF_TAIL.label] = f"--option ref_dof={settings.options['ref_dof']:g}"
    if settings.distance_range is not None:
        out["distance_m"] = "--distance-range {:g},{:g}".format(*settings.distance_range)
    return out


def hand_back(ds: DataSet, key: str, scene, settings):
    """Frame ``key``'s priors from the others (module docstring, step 3): → (scene, estimate keyword
    arguments to change, its ``dataset`` block, its camera's ``rig`` block or None)."""
    from dataclasses import replace

    from ...models.location_prior import LocationPrior
    from .rig import apply_rig_estimates, rig_report

    block: dict = {}
    kwargs: dict = {}
    own = overrides(scene, settings)
    camera = [n for n in ds.learn if n in SHARED and SHARED[n].shared_by == "camera"]
    scene, rig_est = apply_rig_estimates(scene, {n: ds.estimate(n, key) for n in camera if not SHARED[n].held})
    rig = rig_report(rig_est)
    if rig_est is not None:
        for name in rig_est.center:
            block[SHARED[name].label] = {"from": "data set", "shared_by": "camera", "group": rig_est.camera_id,
                                         **rig[SHARED[name].label]}
    focal = ds.estimate("log_focal", key, leave_out=False) if "log_focal" in camera else None
    if focal is not None and SHARED["log_focal"].held and "focal_length_px" not in own:
        # held: the camera's one value, the pool of all its frames; its uncertainty rides on the result
        scene = replace(scene, camera_id=focal.group, focal_length_px=_sig(math.exp(focal.center)), focal_prior=None)
        statistical = math.sqrt(max(focal.var - focal.quantity.floor**2, 0.0))
        block["focal_length_px"] = {"from": "data set", "shared_by": "camera", "group": focal.group, **focal.block(),
                                    "statistical_log_sd": round(statistical, 4),
                                    "shared_scale_log_sd": round(math.sqrt(focal.var), 4)}
    ref = ds.estimate("log_ref_scale", key) if "log_ref_scale" in ds.learn else None
    if ref is not None and "ref_scale" not in own:
        kwargs["ref_scale_median"] = _sig(math.exp(ref.center))
        kwargs["ref_scale_log_sd"] = round(ref.prior_sd, 4)
        block["ref_scale"] = {"from": "data set", "shared_by": "crowd", "group": ref.group, **ref.block()}
    tail = ds.tail_of(key)
    if tail is not None and REF_TAIL.label not in own:
        if tail["dof"] != ds.tail.own_dof:
            kwargs["ref_dof"] = tail["dof"]
        block[REF_TAIL.label] = {"from": "data set", "shared_by": "crowd", **tail}
    dist = ds.estimate("log_distance", key) if "log_distance" in ds.learn else None
    if dist is not None and TWO_POPULATIONS in dist.check.warnings and "distance_m" not in own:
        block["distance_m"] = {"from": "the frame", "group": dist.group, "why": TWO_POPULATIONS}
    elif dist is not None and "distance_m" not in own:
        kind = settings.location_prior if settings.location_prior != "auto" else "log-depth"
        kwargs["location_prior"] = LocationPrior(kind, population=(_sig(math.exp(dist.center)), round(dist.prior_sd, 4)))
        block["distance_m"] = {"from": "data set", "shared_by": "setting", "group": dist.group, **dist.block()}
    residual = ds.corner_scale_of(key) if CORNER_SCALE.name in ds.learn and scene.corner_scale is None else None
    if residual is not None:  # no object of the data set annotated twice: the others' residuals
        scene = replace(scene, corner_scale=residual)
        block["corner_scale_px"] = {"from": "data set", "shared_by": "crowd", "sd": residual[0], "dof": residual[1],
                                    "read": "the first pass's residuals", "fitted_at_px": ds.fitted_at_px}
        if ds.scale_spread_of(key) is not None:
            block["corner_scale_px"]["own"] = ("the others' spread updated by the frame's own residuals"
                                               if key in ds.residuals else "the others' spread (no residuals of its own)")
    elif scene.corner_scale is not None:
        block["corner_scale_px"] = {"from": "data set" if settings.pool_scale else "the scene",
                                    "shared_by": "crowd", "sd": scene.corner_scale[0], "dof": scene.corner_scale[1]}
    for label, why in own.items():
        block[label] = {"from": "override", "why": why}
    return scene, kwargs, block, rig


def shared_scale(block: dict, base_seed: int) -> dict | None:
    """The scale a frame's result carries for the held values it took (:func:`hand_back`'s
    ``block``): ``{"log_sd", "seed"}``, the seed one per group (the camera's frames draw the same
    factors: one scale, shared), or None when it took none. ``log_sd``: natural log of px."""
    import hashlib

    took = block.get("focal_length_px") or {}
    if "shared_scale_log_sd" not in took:
        return None
    digest = hashlib.sha256(f"creference-shared-scale:{int(base_seed)}:{took['group']}".encode()).hexdigest()
    return {"log_sd": float(took["shared_scale_log_sd"]), "seed": int(digest[:15], 16)}


def share_scale(result: dict, log_sd: float, seed: int) -> dict:
    """``result`` (changed in place) carrying a held focal length's uncertainty: kept draw d's focal
    length and depths multiplied by exp(ε_d), ε_d ~ N(0, ``log_sd``²) drawn with ``seed`` (the
    same for every frame of a camera: one scale its frames share), the MAP left as it is
    (:func:`scale_depths`). A result without draws (``--no-posterior``) is returned as it is."""
    if not result.get("draws"):
        return result
    eps = np.random.default_rng(seed).normal(0.0, float(log_sd), int(result["draws"]["n"]))
    return scale_depths(result, eps)


def dataset_lines(summary: dict) -> list[str]:
    """``batch``'s printout of :meth:`DataSet.summary`: a table row per quantity and group, then a
    line per warning."""
    rows, warns = [], []
    for label, entry in summary.items():
        for group, b in entry["groups"].items():
            if entry["kind"] == "residuals":  # the corner scale from the first pass's residuals
                at = b.get("fitted_at_px")
                read = "from the residuals" + (f" at {at:g} px" if at is not None else "")
                spread = (f"; frames spread: each its own, from {b['spread_sd']:.2g} px on {b['spread_dof']:.2g} dof"
                          if "spread_dof" in b else "")
                rows.append(f"  {label:<16} {entry['shared_by']:<8} {group[:24]:<24} {format(b['sd'], 'g') + ' px':>10}  "
                            f"{read:<28} {str(b['frames']) + ' frames':<18} dof {b['dof']:g}{spread}")
                continue
            if entry["kind"] == "choice":  # the crowd's tail (:meth:`TailPool.estimate`)
                rows.append(f"  {label:<16} {entry['shared_by']:<8} {group[:24]:<24} {'t' + format(b['dof'], 'g'):>10}  "
                            f"{'favoured t' + format(b['favoured'], 'g'):<28} "
                            f"{str(b['references']) + ' refs (' + str(b['frames']) + ' frames)':<18} "
                            f"score {b['gain']:+.1f} ± {b['se']:.1f} nats")
                continue
            if "median" in b:
                value = f"{b['median']:g}" + (" held" if b.get("held") else "")
                sd = f"log-sd {b['log_sd']:.3f}" + (f" spread {b['spread_log_sd']:.3f}" if "spread_log_sd" in b else "")
            else:
                value = f"{b['mean']:.2f}°"
                sd = f"sd {b['sd']:.2f}° spread {b['spread_sd']:.2f}°"
            used = f"{b['frames']}/{b['frames_offered']}" if "readings" not in b else \
                f"{b['readings']}/{b['frames_offered']} ({b['frames']} frames)"
            if "readings" not in b and b.get("group_frames", 0) > b["frames_offered"]:
                used += f" of {b['group_frames']}"
            rows.append(f"  {label:<16} {entry['shared_by']:<8} {group[:24]:<24} {value:>10}  {sd:<28} "
                        f"{used:<18} n_eff {b['n_eff']:g}  D {b['disagreement']:+.2f}")
            warns += [f"warning: data set: {label} of {group}: {w}" for w in b["warnings"]]
    if not rows:
        return []
    head = f"  {'quantity':<16} {'by':<8} {'group':<24} {'pooled':>10}  {'uncertainty':<28} {'used/offered':<18} agreement"
    legend = ("  (held: every frame of the group takes the pooled value; spread: how far frames stray around it; "
              "used/offered of N: the frames whose reading is pooled / that could read it apart from their own "
              "prior, of the group's N (a frame whose own prior decides it, a calibrated mounting say, or whose first "
              "pass failed offers none); "
              "n_eff: the frames the pool rests on, counted by their weights; D: the pool less the frames' own "
              "median, in the pool's standard deviations)")
    return ["data set (what the frames share; each frame took the others'):", head, *rows, legend, *warns]
