"""The camera rig: what the frames of one camera share, estimated from all of them
(``creference batch --rig``; docs/batch.md, "One camera, many frames").

Frames name their camera (``camera.id`` of the scene). A camera keeps its focal length from frame
to frame and, bolted to a vehicle, nearly its mounting: its height above the road and its pitch and
roll. Two-pass empirical Bayes:

1. every frame is estimated alone (its own priors);
2. from each frame's posterior draws, for each shared quantity q (log µ; with the mounting also
   log h, pitch and roll), the mean and variance; dividing out the prior that frame used (a Laplace
   step at the posterior mean: the prior's gradient and curvature there) leaves the frame's
   likelihood of q as a normal N(mᵢ, 1/Pᵢ). A frame whose posterior is mostly its prior (Pᵢ below a
   tenth of its posterior precision) tells nothing and is left out;
3. the frames of one camera are combined, and every frame is estimated again with a prior made
   from the *other* frames of its camera (leave one out: a frame's own annotations count once):

   - the focal length is one value per camera: the precision-weighted mean M of the mᵢ, with
     variance 1/ΣPᵢ multiplied by the Birge ratio Σ Pᵢ (mᵢ − M)² / (n − 1) when the frames disagree
     more than their precisions allow (a frame's likelihood that the normal describes badly must
     not make the rig over-sure);
   - the mounting varies from frame to frame around the camera's (a moving vehicle pitches, the road
     is uneven): qᵢ ~ N(M, τ²) with τ² from the DerSimonian–Laird moment estimator (at least
     :data:`MIN_SPREAD`), and the frame's prior N(M₋ᵢ, τ² + V₋ᵢ).

A frame's camera is its scene's ``camera.id``; a scene without one whose photo has EXIF make and
model is named by them (:func:`~creference_bayes.vision.exif.camera_id_from_exif`); a frame with
neither is a camera of its own.

Numbers: log µ and log h are natural logs of pixels and metres; pitch and roll radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["RIG_CHOICES", "QUANTITIES", "SharedLikelihood", "RigEstimate", "RigPool", "camera_id_of",
           "shared_likelihood", "rig_priors", "apply_rig", "rig_report"]

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
class RigEstimate:
    """A camera's pooled quantities: ``center`` M, ``var`` V (of M), ``tau`` (the spread between
    frames; 0 for the focal length), ``frames`` (how many frames informed it) per quantity name."""

    camera_id: str
    center: dict
    var: dict
    tau: dict
    frames: dict
    keys: tuple


def camera_id_of(scene) -> str | None:
    """The camera a frame names: ``camera.id``, else its photo's EXIF make, model and focal length,
    else None (a camera of its own)."""
    if scene.camera_id is not None:
        return scene.camera_id
    if scene.image_path is not None and scene.image_path.is_file():
        from ...vision.exif import camera_id_from_exif

        return camera_id_from_exif(scene.image_path)
    return None


def _prior_terms(name: str, q: float, setup: dict) -> tuple[float, float] | None:
    """The gradient and curvature (−d²/dq²) of the log prior the frame used at q, or None when no
    prior was applied to q (then the posterior is the likelihood)."""
    if name == "log_focal":
        p = setup.get("focal_prior")
        if not p:
            return None
        s, dof = float(p["log_sd"]), p.get("dof")
        r = q - math.log(float(p["median_px"]))
        if dof is None:  # a log-normal
            return -r / s**2, 1.0 / s**2
        nu = float(dof)
        a = nu * s * s + r * r
        return -(nu + 1.0) * r / a, (nu + 1.0) * (nu * s * s - r * r) / a**2
    p = setup.get("orientation_prior")
    if not p:
        return None
    if name == "log_height":
        mean, sd = math.log(float(p["height_median_m"])), float(p["height_log_sd"])
    else:  # the result records degrees
        mean, sd = math.radians(float(p[f"{name}_mean"])), math.radians(float(p[f"{name}_sd"]))
    return -(q - mean) / sd**2, 1.0 / sd**2


def shared_likelihood(key: str, camera_id: str | None, result: dict) -> SharedLikelihood:
    """Each shared quantity's likelihood in one frame, from its result (``creference-result/2``
    with draws: the camera's ``free`` parameters and the priors of ``camera.setup``)."""
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
            m, var = float(np.mean(v)), float(np.var(v, ddof=1))
            if not (var > 0 and np.isfinite(var)):
                continue
            post = 1.0 / var
            terms = _prior_terms(name, m, setup)
            grad, curv = (0.0, 0.0) if terms is None else terms
            lik = post - curv
            if not lik >= MIN_INFORMATION * post:
                continue
            mean[name], precision[name] = m - grad / lik, lik  # the likelihood's mode: ∇log L(m) = −∇log π(m)
    return SharedLikelihood(key, camera_id, mean, precision)


def _combine(m: np.ndarray, p: np.ndarray, kind: str, floor: float = 0.0) -> tuple[float, float, float]:
    """(M, V, τ) of likelihoods N(mᵢ, 1/pᵢ) (module docstring); τ at least ``floor``."""
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
        #: camera id → (its frames' keys, quantity → (keys, means, precisions) of the informative frames)
        self.cameras = {cam: (tuple(f.key for f in group),
                              {name: (np.array([f.key for f in group if name in f.precision], dtype=object),
                                      np.array([f.mean[name] for f in group if name in f.precision]),
                                      np.array([f.precision[name] for f in group if name in f.precision]))
                               for name in POOLED[rig]})
                        for cam, group in sorted(by_camera.items())}

    def estimate(self, camera_id: str, leave_out: str | None = None) -> RigEstimate | None:
        """The camera's pooled quantities without the frame ``leave_out`` (a KEY), or None when it has
        none. A quantity needs two informative frames (one when a frame is left out: then the others
        are the evidence)."""
        if camera_id not in self.cameras:
            return None
        keys, quantities = self.cameras[camera_id]
        center, var, tau, count = {}, {}, {}, {}
        for name, (k, m, p) in quantities.items():
            keep = k != leave_out
            if keep.sum() < (1 if leave_out is not None else 2):
                continue
            center[name], var[name], tau[name] = _combine(m[keep], p[keep], QUANTITIES[name][2],
                                                          MIN_SPREAD.get(name, 0.0))
            count[name] = int(keep.sum())
        if not center:
            return None
        return RigEstimate(camera_id, center, var, tau, count, tuple(x for x in keys if x != leave_out))


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


def rig_report(est: RigEstimate | None) -> dict | None:
    """A :class:`RigEstimate` as a result's ``rig`` block: each pooled quantity's centre and
    standard deviation in natural units (focal length px, height m, pitch and roll degrees), the
    spread between frames and the number of frames."""
    if est is None:
        return None
    out = {"camera_id": est.camera_id, "frames": len(est.keys)}
    for name, c in est.center.items():
        sd = math.sqrt(est.var[name])
        if name == "log_focal":
            out["focal_length_px"] = {"median": round(math.exp(c), 2), "log_sd": round(sd, 4), "frames": est.frames[name]}
        elif name == "log_height":
            out["height_m"] = {"median": round(math.exp(c), 3), "log_sd": round(sd, 4),
                               "spread_log_sd": round(est.tau[name], 4), "frames": est.frames[name]}
        else:
            out[f"{name}_deg"] = {"mean": round(math.degrees(c), 3), "sd": round(math.degrees(sd), 3),
                                  "spread_sd": round(math.degrees(est.tau[name]), 3), "frames": est.frames[name]}
    return out
