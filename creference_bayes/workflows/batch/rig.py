"""The camera rig: what the frames of one camera share, estimated from all of them
(``creference batch --rig``; docs/batch.md, "One camera, many frames").

Frames name their camera (``camera.id`` of the scene). A camera keeps its focal length from frame
to frame and, bolted to a vehicle, nearly its mounting: its height above the road and its pitch and
roll. Two-pass empirical Bayes:

1. every frame is estimated alone (its own priors);
2. from each frame's posterior draws, for each shared quantity q (log µ; with the mounting also
   log h, pitch and roll), the prior that frame used is divided out exactly: the draws reweighted
   by 1/prior(q) (self-normalised importance weights) have the frame's likelihood of q as their
   distribution; its weighted mean and variance make it a normal N(mᵢ, 1/Pᵢ). (A Laplace step at
   the posterior mean would not do: on weak frames, whose posterior is far from normal, it leaves
   the likelihood biased low by half, docs/studies/rig.md.) A frame cannot say what it knows when
   the weights' effective sample size is below :data:`MIN_WEIGHT_ESS` of its draws (its prior
   was far narrower than its likelihood), or when Pᵢ is below :data:`MIN_INFORMATION` of its
   posterior precision (its posterior is mostly its prior);
3. the frames of one camera are combined, and every frame is estimated again with a prior made
   from the *other* frames of its camera (leave one out: a frame's own annotations count once).
   Only *informative* frames are pooled: likelihood sd at most :data:`MAX_LIKELIHOOD_SD` (log µ:
   0.25). Weak frames are biased: on KITTI one-object frames the focal length comes out ≈ 40 %
   low, because the wide pitch prior acts as an extra ≈ 1/µ prior (the horizon is pinned in
   pixels, so the pitch's allowed width shrinks as µ grows); a robust (heavy-tailed) combination
   does not help, it flattens the weights toward these frames (docs/studies/rig.md).

   - the focal length is one value per camera: the precision-weighted mean M of the mᵢ, with
     variance 1/ΣPᵢ multiplied by the Birge ratio Σ Pᵢ (mᵢ − M)² / (n − 1) when the frames disagree
     more than their precisions allow (a frame's likelihood that the normal describes badly must
     not make the rig over-sure), plus :data:`SHARED_BIAS_SD`² (a floor in quadrature: the model's
     bias that all frames of a camera share, which no number of frames averages away; 0.04 in log
     µ, measured on the KITTI development frames, docs/studies/rig.md);
   - the mounting varies from frame to frame around the camera's (a moving vehicle pitches, the road
     is uneven): qᵢ ~ N(M, τ²) with τ² from the DerSimonian–Laird moment estimator (at least
     :data:`MIN_SPREAD`), and the frame's prior N(M₋ᵢ, τ² + V₋ᵢ). These get no floor of their own:
     the frame's prior is already never narrower than :data:`MIN_SPREAD` (τ² is added to V₋ᵢ), and
     no bias of the mounting shared by frames has been measured;

4. every pooled quantity is checked against its frames (:class:`PoolCheck`): the effective number
   of frames n_eff = (ΣPᵢ)²/ΣPᵢ², the share of the weight the three most precise frames carry, and
   the disagreement D = (M − median of the mᵢ) / √(sd of that median² + V) (the median's sd by a
   seeded bootstrap; V without the floor, a bias the frames share moves both alike). The pool
   "rests on few frames" when n_eff < :data:`MIN_EFFECTIVE_FRAMES` or the top three carry more
   than :data:`MAX_TOP3_SHARE`; "the pool and the frames disagree" when |D| > :data:`MAX_DISAGREEMENT`.
   ``batch`` prints these warnings and every frame's ``rig`` block records them.

A frame's camera is its scene's ``camera.id``; a scene without one whose photo has EXIF make and
model is named by them (:func:`~creference_bayes.vision.exif.camera_id_from_exif`); a frame with
neither is a camera of its own.

Numbers: log µ and log h are natural logs of pixels and metres; pitch and roll radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["RIG_CHOICES", "QUANTITIES", "SharedLikelihood", "PoolCheck", "RigEstimate", "RigPool", "camera_id_of",
           "shared_likelihood", "divide_prior", "pool_check", "rig_priors", "apply_rig", "rig_report",
           "rig_lines"]

#: ``--rig`` values: what frames of one camera share
RIG_CHOICES = ("none", "focal", "mounting")
#: the shared quantities: name → (camera column of the draws, transform, pooled as "shared" or "spread")
QUANTITIES = {"log_focal": (0, np.log, "shared"), "log_height": (3, np.log, "spread"),
              "pitch": (1, None, "spread"), "roll": (2, None, "spread")}
#: the quantities each ``--rig`` value pools
POOLED = {"none": (), "focal": ("log_focal",), "mounting": ("log_focal", "log_height", "pitch", "roll")}
_CAMERA_COLUMNS = {"log_focal": "focal_length_px", "pitch": "pitch", "roll": "roll", "log_height": "height_m"}
#: a frame whose likelihood precision is below this share of its posterior precision tells nothing
MIN_INFORMATION = 0.1
#: the least effective sample size of a frame's importance weights 1/prior, as a share of its draws,
#: for its likelihood to be read from them (on the KITTI development frames the least was 0.35)
MIN_WEIGHT_ESS = 0.1
#: the widest likelihood (sd) a frame may have and be pooled: log µ 0.25 (measured: weaker frames
#: are biased low, docs/studies/rig.md); log h the same; pitch and roll 2° (not measured: a frame
#: that knows its pitch only to 2° knows little beyond the default prior's horizon)
MAX_LIKELIHOOD_SD = {"log_focal": 0.25, "log_height": 0.25, "pitch": math.radians(2.0), "roll": math.radians(2.0)}
#: the least sd of a pooled "shared" quantity (added in quadrature): the model's bias that every
#: frame of a camera shares. log µ: 0.04, from the halves of the KITTI development frames
#: (√mean(e² − V) of half-pools: 0.024 with this rule, 0.042 with the rule before; the real case of
#: issue 62, 8 % low with sd 0.020, needed ≥ 0.036; docs/studies/rig.md)
SHARED_BIAS_SD = {"log_focal": 0.04}
#: a pool is said to rest on few frames below this effective number of frames (ΣP)²/ΣP² ...
MIN_EFFECTIVE_FRAMES = 5.0
#: ... or when its three most precise frames carry more than this share of the weight
MAX_TOP3_SHARE = 0.6
#: the pool and its frames disagree when |D| (module docstring, step 4) is above this
MAX_DISAGREEMENT = 2.0
#: bootstrap resamples for the sd of the frames' median (seeded: the same frames, the same numbers)
BOOTSTRAP = 500
FEW_FRAMES = "the pool rests on few frames"
DISAGREE = "the pool and the frames disagree"
#: the least spread of the mounting from frame to frame (log h; pitch and roll in radians): a camera
#: on a moving vehicle is never still, and with a few dozen frames the moment estimator is often
#: exactly 0, which would make every frame's prior as narrow as the pooled mean's uncertainty
MIN_SPREAD = {"log_height": 0.03, "pitch": math.radians(0.5), "roll": math.radians(0.5)}


@dataclass(frozen=True)
class SharedLikelihood:
    """One frame's likelihood of each shared quantity, N(mean, 1/precision); absent: not estimated
    there (fixed, not free, or nothing beyond the prior)."""

    key: str
    camera_id: str | None
    mean: dict
    precision: dict


@dataclass(frozen=True)
class PoolCheck:
    """How a pooled quantity rests on its frames (module docstring, step 4): ``used`` informative
    frames of ``offered`` (the frames that estimated it), ``n_eff``, ``top3_share``, the frames'
    ``median`` (the same units as the pool), the disagreement ``d`` and the ``warnings``."""

    used: int
    offered: int
    n_eff: float
    top3_share: float
    median: float
    d: float
    warnings: tuple


@dataclass(frozen=True)
class RigEstimate:
    """A camera's pooled quantities: ``center`` M, ``var`` V (of M; a shared quantity's with its
    floor :data:`SHARED_BIAS_SD`), ``tau`` (the spread between frames; 0 for the focal length),
    ``frames`` (how many frames informed it), ``check`` (:class:`PoolCheck`) per quantity name."""

    camera_id: str
    center: dict
    var: dict
    tau: dict
    frames: dict
    keys: tuple
    check: dict = field(default_factory=dict)


def camera_id_of(scene) -> str | None:
    """The camera a frame names: ``camera.id``, else its photo's EXIF make, model and focal length,
    else None (a camera of its own)."""
    if scene.camera_id is not None:
        return scene.camera_id
    if scene.image_path is not None and scene.image_path.is_file():
        from ...vision.exif import camera_id_from_exif

        return camera_id_from_exif(scene.image_path)
    return None


def _log_prior(name: str, q: np.ndarray, setup: dict) -> np.ndarray | None:
    """The log prior (up to a constant) the frame used, at the values ``q`` of quantity ``name``,
    or None when no prior was applied to q (then the posterior is the likelihood)."""
    if name == "log_focal":
        p = setup.get("focal_prior")
        if not p:
            return None
        s, dof = float(p["log_sd"]), p.get("dof")
        r = q - math.log(float(p["median_px"]))
        if dof is None or not math.isfinite(float(dof)):  # a log-normal
            return -0.5 * (r / s) ** 2
        nu = float(dof)
        return -0.5 * (nu + 1.0) * np.log1p(r * r / (nu * s * s))
    p = setup.get("orientation_prior")
    if not p:
        return None
    if name == "log_height":
        mean, sd = math.log(float(p["height_median_m"])), float(p["height_log_sd"])
    else:  # the result records degrees
        mean, sd = math.radians(float(p[f"{name}_mean"])), math.radians(float(p[f"{name}_sd"]))
    return -0.5 * ((q - mean) / sd) ** 2


def divide_prior(q: np.ndarray, log_prior: np.ndarray | None) -> tuple[float, float, float] | None:
    """The likelihood of a quantity from posterior draws ``q`` and the log prior at them: the draws
    reweighted by 1/prior (self-normalised importance weights) → (mean, variance, effective sample
    size of the weights), or None when the weights' effective sample size is below
    :data:`MIN_WEIGHT_ESS` of the draws or the variance is not positive."""
    q = np.asarray(q, dtype=float)
    if log_prior is None:
        w = np.full(len(q), 1.0 / len(q))
    else:
        lw = -np.asarray(log_prior, dtype=float)
        w = np.exp(lw - lw.max())
        w /= w.sum()
    ess = 1.0 / float((w**2).sum())
    if not (len(q) > 1 and ess >= MIN_WEIGHT_ESS * len(q)):
        return None
    mean = float((w * q).sum())
    var = float((w * (q - mean) ** 2).sum()) / (1.0 - 1.0 / ess)  # unbiased for reliability weights
    if not (var > 0 and np.isfinite(var)):
        return None
    return mean, var, ess


def shared_likelihood(key: str, camera_id: str | None, result: dict) -> SharedLikelihood:
    """Each shared quantity's likelihood in one frame, from its result (``creference-result/2``
    with draws: the camera's ``free`` parameters and the priors of ``camera.setup``): the prior
    divided out of the draws exactly (:func:`divide_prior`)."""
    from ...io.result import stored_draws

    draws = stored_draws(result)
    mean, precision = {}, {}
    if draws is not None:
        cams = draws.cameras.reshape(-1, 5)
        free = set(result["camera"].get("free", ()))
        setup = result["camera"].get("setup") or {}
        for name, (col, fn, _) in QUANTITIES.items():
            if _CAMERA_COLUMNS[name] not in free:
                continue
            v = cams[:, col] if fn is None else fn(cams[:, col])
            post = float(np.var(v, ddof=1))
            lik = divide_prior(v, _log_prior(name, v, setup))
            if lik is None or not (post > 0 and np.isfinite(post)) or not 1.0 / lik[1] >= MIN_INFORMATION / post:
                continue
            mean[name], precision[name] = lik[0], 1.0 / lik[1]
    return SharedLikelihood(key, camera_id, mean, precision)


def _combine(m: np.ndarray, p: np.ndarray, kind: str, floor: float = 0.0) -> tuple[float, float, float]:
    """(M, V, τ) of likelihoods N(mᵢ, 1/pᵢ) (module docstring), V without a shared quantity's
    floor; τ at least ``floor`` (a spread quantity's :data:`MIN_SPREAD`)."""
    w = p.sum()
    center = float((p * m).sum() / w)
    n = len(m)
    q = float((p * (m - center) ** 2).sum())
    if kind == "shared":
        return center, (1.0 / w) * max(1.0, q / (n - 1) if n > 1 else 1.0), 0.0
    tau2 = max(0.0, (q - (n - 1)) / (w - (p**2).sum() / w)) if n > 1 else 0.0
    tau2 = max(tau2, floor**2)
    ws = 1.0 / (1.0 / p + tau2)
    center = float((ws * m).sum() / ws.sum())
    return center, float(1.0 / ws.sum()), math.sqrt(tau2)


def pool_check(m: np.ndarray, p: np.ndarray, center: float, var: float, offered: int) -> PoolCheck:
    """How the pool (``center``, ``var`` without a floor) of the informative frames' likelihoods
    N(mᵢ, 1/pᵢ) rests on them (module docstring, step 4); ``offered``: the frames that estimated
    the quantity, informative or not."""
    n = len(m)
    n_eff = float(p.sum() ** 2 / (p**2).sum())
    top3 = float(np.sort(p)[::-1][:3].sum() / p.sum())
    median = float(np.median(m))
    rng = np.random.default_rng(0)
    sd_median = float(np.std(np.median(m[rng.integers(0, n, (BOOTSTRAP, n))], axis=1))) if n > 1 else 0.0
    d = (center - median) / math.sqrt(sd_median**2 + var)
    warnings = []
    if n_eff < MIN_EFFECTIVE_FRAMES or top3 > MAX_TOP3_SHARE:
        warnings.append(FEW_FRAMES)
    if abs(d) > MAX_DISAGREEMENT:
        warnings.append(DISAGREE)
    return PoolCheck(n, offered, n_eff, top3, median, d, tuple(warnings))


class RigPool:
    """The frames' likelihoods grouped by camera and quantity once, as arrays: each frame's
    leave-one-out rig is then one vectorised combination over its camera's frames (a batch of n
    frames costs O(n) per frame in NumPy, not O(n) Python work per frame and quantity)."""

    def __init__(self, frames: list[SharedLikelihood], rig: str):
        if rig not in RIG_CHOICES:
            raise ValueError(f"rig: expected one of {list(RIG_CHOICES)}, got {rig!r}")
        self.rig = rig
        by_camera: dict[str, list[SharedLikelihood]] = {}
        for f in frames:
            if f.camera_id is not None:
                by_camera.setdefault(f.camera_id, []).append(f)
        #: camera id → (its frames' keys, quantity → (keys, means, precisions) of the frames that estimated it)
        self.cameras = {cam: (tuple(f.key for f in group),
                              {name: (np.array([f.key for f in group if name in f.precision], dtype=object),
                                      np.array([f.mean[name] for f in group if name in f.precision]),
                                      np.array([f.precision[name] for f in group if name in f.precision]))
                               for name in POOLED[rig]})
                        for cam, group in sorted(by_camera.items())}

    def estimate(self, camera_id: str, leave_out: str | None = None) -> RigEstimate | None:
        """The camera's pooled quantities without the frame ``leave_out`` (a KEY), or None when it has
        none. Only informative frames are pooled (likelihood sd at most :data:`MAX_LIKELIHOOD_SD`);
        a quantity needs two of them (one when a frame is left out: then the others are the
        evidence)."""
        if camera_id not in self.cameras:
            return None
        keys, quantities = self.cameras[camera_id]
        center, var, tau, count, check = {}, {}, {}, {}, {}
        for name, (k, m, p) in quantities.items():
            offered = k != leave_out
            keep = offered & (p >= MAX_LIKELIHOOD_SD[name] ** -2)
            if keep.sum() < (1 if leave_out is not None else 2):
                continue
            kind = QUANTITIES[name][2]
            c, v, tau[name] = _combine(m[keep], p[keep], kind, MIN_SPREAD.get(name, 0.0))
            check[name] = pool_check(m[keep], p[keep], c, v, int(offered.sum()))
            center[name], var[name] = c, v + (SHARED_BIAS_SD.get(name, 0.0) ** 2 if kind == "shared" else 0.0)
            count[name] = int(keep.sum())
        if not center:
            return None
        return RigEstimate(camera_id, center, var, tau, count, tuple(x for x in keys if x != leave_out), check)

    def summary(self) -> dict:
        """Each camera's pool of all its frames as a ``rig`` block (:func:`rig_report`); cameras
        with nothing pooled are left out."""
        return {cam: rig_report(est) for cam in self.cameras if (est := self.estimate(cam)) is not None}


def rig_priors(est: RigEstimate, base_orientation=None):
    """The focal-length prior and the orientation prior a frame gets from its camera's
    :class:`RigEstimate` (either None when the rig does not give it). Quantities the rig did not
    pool keep ``base_orientation``'s (default: the package's default orientation prior)."""
    from ...models.camera_terms import DEFAULT_ORIENTATION_PRIOR, FocalPrior

    focal = None
    if "log_focal" in est.center:
        focal = FocalPrior(math.exp(est.center["log_focal"]), math.sqrt(est.var["log_focal"]), math.inf,
                           source="rig")
    spread = {n: math.sqrt(est.var[n] + est.tau[n] ** 2) for n in ("log_height", "pitch", "roll") if n in est.center}
    orientation = None
    if spread:
        kw = {}
        if "log_height" in spread:
            kw.update(height_median_m=math.exp(est.center["log_height"]), height_log_sd=spread["log_height"])
        for n in ("pitch", "roll"):
            if n in spread:
                kw.update({f"{n}_mean": est.center[n], f"{n}_sd": spread[n]})
        orientation = replace(base_orientation or DEFAULT_ORIENTATION_PRIOR, **kw)
    return focal, orientation


def apply_rig(scene, frames: list[SharedLikelihood] | RigPool, rig: str, key: str):
    """``scene`` (frame KEY) with the priors its camera's other frames give (leave one out), and the
    :class:`RigEstimate` used (None: the scene names no camera, or its camera has no other
    informative frame; the scene is returned as it is). ``frames``: the frames' likelihoods, or
    a :class:`RigPool` of them (built once for a whole batch)."""
    camera_id = camera_id_of(scene)
    if camera_id is None or rig == "none":
        return scene, None
    pool = frames if isinstance(frames, RigPool) else RigPool(frames, rig)
    est = pool.estimate(camera_id, leave_out=key)
    if est is None:
        return scene, None
    focal, orientation = rig_priors(est, scene.orientation_prior)
    own = scene.orientation_prior
    if orientation is not None and own is not None and own.source == "calibration":
        # the other frames' evidence does not replace the answer (advise --apply): for the quantities
        # the rig pooled, the product with it (the others are the calibration's already)
        pooled = {"log_height": "height", "pitch": "pitch", "roll": "roll"}
        orientation = orientation.times(own, [pooled[n] for n in est.center if n in pooled], source="calibration")
    if scene.focal_length_px is not None:  # a known focal length needs no prior
        focal = None
    if focal is None and orientation is None:
        return scene, None
    changes = {"focal_prior": focal} if focal is not None else {}
    if orientation is not None:
        changes["orientation_prior"] = orientation
    return replace(scene, camera_id=camera_id, **changes), est


def _check_block(check: PoolCheck, scale, digits: int) -> dict:
    return {"frames_offered": check.offered, "n_eff": round(check.n_eff, 1),
            "top3_share": round(check.top3_share, 2), "frames_median": round(scale(check.median), digits),
            "disagreement": round(check.d, 2), "warnings": list(check.warnings)}


def rig_report(est: RigEstimate | None) -> dict | None:
    """A :class:`RigEstimate` as a result's ``rig`` block: each pooled quantity's centre and
    standard deviation in natural units (focal length px, height m, pitch and roll degrees; the
    sd as stated, with the floor, and the floor), the spread between frames, the number of
    informative frames used (``frames``) of those that estimated it (``frames_offered``), n_eff,
    the top three frames' share of the weight, the frames' median, the disagreement D and the
    warnings (module docstring, step 4); ``warnings`` at the top: every quantity's, named."""
    if est is None:
        return None
    out = {"camera_id": est.camera_id, "frames": len(est.keys)}
    warnings = []
    for name, c in est.center.items():
        sd = math.sqrt(est.var[name])
        check = est.check.get(name)
        if name == "log_focal":
            block = {"median": round(math.exp(c), 2), "log_sd": round(sd, 4),
                     "floor_log_sd": SHARED_BIAS_SD.get(name, 0.0), "frames": est.frames[name]}
            key, scale, digits = "focal_length_px", math.exp, 2
        elif name == "log_height":
            block = {"median": round(math.exp(c), 3), "log_sd": round(sd, 4),
                     "spread_log_sd": round(est.tau[name], 4), "frames": est.frames[name]}
            key, scale, digits = "height_m", math.exp, 3
        else:
            block = {"mean": round(math.degrees(c), 3), "sd": round(math.degrees(sd), 3),
                     "spread_sd": round(math.degrees(est.tau[name]), 3), "frames": est.frames[name]}
            key, scale, digits = f"{name}_deg", math.degrees, 3
        if check is not None:
            block.update(_check_block(check, scale, digits))
            warnings += [f"{key}: {w}" for w in check.warnings]
        out[key] = block
    out["warnings"] = warnings
    return out


def rig_lines(summary: dict) -> list[str]:
    """``batch``'s printout of :meth:`RigPool.summary`: one line a camera's focal length, then a
    line for each warning."""
    lines = []
    for cam, block in summary.items():
        f = block.get("focal_length_px")
        if f is not None:
            lines.append(f"rig {cam}: focal length {f['median']:g} px, log-sd {f['log_sd']:.3f} "
                         f"(floor {f['floor_log_sd']:g}), {f['frames']} of {f['frames_offered']} frames, "
                         f"n_eff {f['n_eff']:g}, top-3 share {f['top3_share']:g}, D {f['disagreement']:+.2f}")
        lines += [f"warning: rig {cam}: {w}" for w in block["warnings"]]
    return lines
