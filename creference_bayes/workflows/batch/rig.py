"""The camera rig: what the frames of one camera share (the camera's quantities of the data-set
layer, :mod:`.dataset`; docs/batch.md, "One camera, many frames").

Frames name their camera (``camera.id`` of the scene). A camera keeps its focal length from frame
to frame and, bolted to a vehicle, nearly its mounting: its height above the road and its pitch and
roll. The quantities are declared in :data:`.dataset.SHARED` (``log_focal`` shared; ``log_height``,
``pitch``, ``roll`` spread from frame to frame) and learnt by the data set's mechanism: each frame's
likelihood read from its first pass with its prior divided out exactly (:func:`camera_likelihood`),
the informative frames combined (the focal length's floor, the mounting's least spread), each
frame handed the pool of the others (leave one out). This module is what is the camera's own: which
quantities ``--rig`` pools (:data:`POOLED`), the priors a frame used (:func:`_log_prior`), and how
the pooled values become a frame's focal-length and orientation priors (:func:`rig_priors`,
:func:`apply_rig_estimates`).

Why only informative frames (likelihood sd at most ``max_sd``: log µ 0.25): weak frames are biased;
on KITTI one-object frames the focal length comes out ≈ 40 % low, because the wide pitch prior acts
as an extra ≈ 1/µ prior (the horizon is pinned in pixels, so the pitch's allowed width shrinks as µ
grows); a robust (heavy-tailed) combination does not help, it flattens the weights toward these
frames (docs/studies/rig.md). The focal length's floor (0.03 in log µ, measured on the KITTI
development frames) is the model's bias all frames of a camera share. In ``creference batch`` the
focal length is *held* (:data:`.dataset.SHARED`, :func:`.dataset.hand_back`): each frame takes the
pool of all the camera's frames as its focal length, its uncertainty carried by the result's draws;
:func:`apply_rig` still hands it as a prior (the API of the earlier ``--rig``).

A frame's camera is its scene's ``camera.id``; a scene without one whose photo has EXIF make and
model is named by them (:func:`~creference_bayes.vision.exif.camera_id_from_exif`); a frame with
neither is a camera of its own.

Numbers: log µ and log h are natural logs of pixels and metres; pitch and roll radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .dataset import DISAGREE, FEW_FRAMES, SHARED, Pool, PoolCheck, Reading, divide_prior, likelihood, pool_check

__all__ = ["RIG_CHOICES", "QUANTITIES", "POOLED", "SharedLikelihood", "PoolCheck", "RigEstimate", "RigPool",
           "camera_id_of", "camera_likelihood", "shared_likelihood", "divide_prior", "pool_check", "rig_priors",
           "apply_rig", "apply_rig_estimates", "rig_report", "rig_lines", "FEW_FRAMES", "DISAGREE"]

#: ``--rig`` values: what frames of one camera share (``auto``: the focal length and the mounting,
#: when there is something to learn, :func:`.dataset.plan`)
RIG_CHOICES = ("auto", "none", "focal", "mounting")
#: the camera's quantities: name → camera column of the draws, transform
QUANTITIES = {"log_focal": (0, np.log), "log_height": (3, np.log), "pitch": (1, None), "roll": (2, None)}
#: the quantities each ``--rig`` value pools
POOLED = {"auto": ("log_focal", "log_height", "pitch", "roll"), "none": (), "focal": ("log_focal",),
          "mounting": ("log_focal", "log_height", "pitch", "roll")}
_CAMERA_COLUMNS = {"log_focal": "focal_length_px", "pitch": "pitch", "roll": "roll", "log_height": "height_m"}
#: the widest likelihood (sd) a frame may have and be pooled, by quantity (:data:`.dataset.SHARED`)
MAX_LIKELIHOOD_SD = {n: SHARED[n].max_sd for n in QUANTITIES}
#: the least sd of the pooled focal length (added in quadrature): the model's bias that every frame of
#: a camera shares (docs/studies/rig.md)
SHARED_BIAS_SD = {"log_focal": SHARED["log_focal"].floor}
#: the least spread of the mounting from frame to frame (log h; pitch and roll in radians): a camera on
#: a moving vehicle is never still, and with a few dozen frames the moment estimator is often exactly 0
MIN_SPREAD = {n: SHARED[n].min_spread for n in ("log_height", "pitch", "roll")}


@dataclass(frozen=True)
class SharedLikelihood:
    """One frame's likelihood of each shared quantity, N(mean, 1/precision); absent: not estimated
    there (fixed, not free, or nothing beyond the prior)."""

    key: str
    camera_id: str | None
    mean: dict
    precision: dict


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


def camera_likelihood(result: dict, cams: np.ndarray, given: dict | None = None,
                      log_reweight: np.ndarray | None = None) -> dict:
    """Each camera quantity's likelihood (mean, precision) in one frame, from its draws ``cams``
    (k, 5) and its result's ``camera`` (its ``free`` parameters and the priors of ``setup``): the
    prior divided out of the draws exactly (:func:`.dataset.likelihood`); a quantity the frame
    does not estimate, or cannot say what it knows of, is absent.

    ``given``: quantity name → (mean, sd) of the camera's pooled values of the *other* quantities
    (the mounting): the draws are then also reweighted from the prior the frame used on them to
    these, so that each quantity's likelihood is read as if the frame had known the camera's
    mounting (:func:`.dataset.read_focal_given_orientation`: a weak frame's focal length is biased
    low by the wide pitch prior, docs/studies/rig.md). ``log_reweight``: a further log weight per
    draw (the draws moved to the crowd's tail, :func:`.dataset.tail_reweight`)."""
    free = set(result["camera"].get("free", ()))
    setup = result["camera"].get("setup") or {}
    values = {name: cams[:, col] if fn is None else fn(cams[:, col]) for name, (col, fn) in QUANTITIES.items()
              if _CAMERA_COLUMNS[name] in free}
    out = {}
    for name, v in values.items():
        reweight = log_reweight  # and log N(q; mean, sd²) − log prior_used(q) of the other quantities given
        for other, (mean, sd) in (given or {}).items():
            if other != name and other in values:
                q = values[other]
                used = _log_prior(other, q, setup)
                term = -0.5 * ((q - mean) / sd) ** 2 - (0.0 if used is None else used)
                reweight = term if reweight is None else reweight + term
        lik = likelihood(v, _log_prior(name, v, setup), reweight)
        if lik is not None:
            out[name] = lik
    return out


def shared_likelihood(key: str, camera_id: str | None, result: dict) -> SharedLikelihood:
    """Each camera quantity's likelihood in one frame from the posterior draws its result keeps
    (:func:`camera_likelihood`; none without draws)."""
    from ...io.result import stored_draws

    draws = stored_draws(result)
    lik = camera_likelihood(result, draws.cameras.reshape(-1, 5)) if draws is not None else {}
    return SharedLikelihood(key, camera_id, {n: v[0] for n, v in lik.items()}, {n: v[1] for n, v in lik.items()})


def _rig_estimate(camera_id: str, pooled: dict, keys: tuple) -> RigEstimate | None:
    """A camera's :class:`RigEstimate` from its quantities' pools (name → :class:`.dataset.Pooled` or None)."""
    pooled = {n: e for n, e in pooled.items() if e is not None}
    if not pooled:
        return None
    return RigEstimate(camera_id, {n: e.center for n, e in pooled.items()}, {n: e.var for n, e in pooled.items()},
                       {n: e.tau for n, e in pooled.items()}, {n: e.readings for n, e in pooled.items()}, keys,
                       {n: e.check for n, e in pooled.items()})


class RigPool:
    """The frames' likelihoods of what their camera shares, one :class:`.dataset.Pool` per quantity
    ``rig`` pools, grouped by camera (the frames' ``camera_id``; frames without one are left out)."""

    def __init__(self, frames: list[SharedLikelihood], rig: str):
        if rig not in RIG_CHOICES:
            raise ValueError(f"rig: expected one of {list(RIG_CHOICES)}, got {rig!r}")
        self.rig = rig
        frames = [f for f in frames if f.camera_id is not None]
        self.pools = {name: Pool(SHARED[name], [Reading(f.key, f.camera_id, f.mean[name], f.precision[name])
                                                for f in frames if name in f.precision]) for name in POOLED[rig]}
        #: camera id → its frames' keys
        self.cameras: dict[str, tuple] = {}
        for f in frames:
            self.cameras[f.camera_id] = self.cameras.get(f.camera_id, ()) + (f.key,)

    def estimate(self, camera_id: str, leave_out: str | None = None) -> RigEstimate | None:
        """The camera's pooled quantities without the frame ``leave_out`` (a KEY), or None when it has
        none (:meth:`.dataset.Pool.estimate`: informative frames only; two of them, or one other
        when a frame is left out)."""
        if camera_id not in self.cameras:
            return None
        keys = tuple(k for k in self.cameras[camera_id] if k != leave_out)
        return _rig_estimate(camera_id, {n: p.estimate(camera_id, leave_out) for n, p in self.pools.items()}, keys)

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
    return _with_rig(scene, camera_id, pool.estimate(camera_id, leave_out=key))


def apply_rig_estimates(scene, pooled: dict):
    """``scene`` with the priors of its camera's pools (quantity name → :class:`.dataset.Pooled` or
    None, each leaving the frame out: :meth:`.dataset.DataSet.estimate`) → (scene, :class:`RigEstimate`
    or None), as :func:`apply_rig`."""
    camera_id = camera_id_of(scene)
    keys = tuple(dict.fromkeys(k for e in pooled.values() if e is not None for k in e.keys))
    est = _rig_estimate(camera_id, pooled, keys) if camera_id is not None else None
    return _with_rig(scene, camera_id, est)


def _with_rig(scene, camera_id, est: RigEstimate | None):
    if est is None:
        return scene, None
    focal, orientation = rig_priors(est, scene.orientation_prior)
    own = scene.orientation_prior
    if orientation is not None and own is not None and own.source == "calibration":
        # the other frames' evidence does not replace the answer (advise --apply): for the quantities
        # the rig pooled, the product with it (the others are the calibration's already)
        pooled = {"log_height": "height", "pitch": "pitch", "roll": "roll"}
        orientation = orientation.times(own, [pooled[n] for n in est.center if n in pooled], source="calibration")
    if scene.focal_length_px is not None or (scene.focal_prior is not None and scene.focal_prior.source != "rig"):
        focal = None  # a known focal length needs no prior; the scene's own prior is the user's (an override)
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
