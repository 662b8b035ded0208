"""Which object and which annotation next, for a frame (docs/advice.md, "Frames").

A frame has many objects and one camera, so the single target's preposterior simulation (one
re-weighting per simulated outcome and candidate) would be slow. The frame's advice predicts
instead from the Laplace approximation at the MAP (:mod:`~creference_bayes.inference.frame_laplace`,
working coordinates): one more observation adds its expected (Fisher) information to the
negative log-posterior's Hessian, and the predicted posterior sd of every object's distance and
of the camera follow from the new Hessian by the delta method. An observation on object i
touches the camera block, object i's block and their coupling only, so the Hessian stays an
arrowhead and every prediction costs a few small inversions.

Candidates, for every object i:

- ``dims``: one more set of dimension lines. Its information is κ/σᵢ² Jᵀ J / T, J (8 × 12) the
  Jacobian of object i's four projected corners with respect to the camera's and object i's
  working coordinates, σᵢ the object's corner scale (the model's), T the temperature and κ the
  expected curvature of the Student-t corner term per coordinate, (ν + 2) / ν / (1 + q)²,
  q = |r|² / (ν σᵢ²), for a new corner r ~ N(0, σᵢ² I) (:func:`expected_curvature`: 0.83 for
  ν = 4; 0.75 if the corners followed the Student-t itself). Not the frame's own residuals at the
  MAP (:func:`corner_curvature`, reported): those are fitted, the more so the fewer sets an object
  has (one set is fitted almost exactly, κ → 1.5), and a new set is not.
- ``distance``: a worker's distance to object i, drawn as the paper's distance task: from the
  image's bottom edge straight up to the object's nearest bottom corner (at the MAP). The
  segment's real length depends on the camera only; its information is
  (ν + 1) / (ν + 3) / (s² + v) g gᵀ / T, g the gradient of the segment's log-length, s the
  crowd's scale at the MAP (ν = ``ref_dof``, the Fisher information of a Student-t location) and
  v the segment's line noise in log-length (as the model's references). Left out when the corner
  is within 10 px of the bottom edge.
- ``length``: a worker's statement of object i's length (objects with a class size prior only),
  the same information with g the gradient of log length and no line noise.

A new reference is taken as a single value with the present crowd scale (when the frame has no
references yet the scale is the prior's median, 0.5, and a first reference would make it a
parameter: its predicted information is then an upper bound). The predicted width of an object's
90 % interval after the annotation is the present one times the ratio of the predicted sds
(the present one is the result's posterior HDI when it has one, else the Laplace approximation's
normal interval). Gain: the sum over the frame's objects of the narrowing of each object's
interval in points of its distance (the single target's measure, summed), per minute of the
annotation's cost (:func:`frame_seconds`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import norm

from ...inference.frame_laplace import block_variances, frame_laplace, laplace_blocks, work_gradients
from ...inference.frame_map import Arrowhead
from ...models.frame import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, C_SCALE
from ...models.metrology import linear_line_variances
from . import AdviceSettings
from .frame_candidates import FrameCandidate, frame_candidates, frame_seconds
from .frame_table import frame_advice_table

__all__ = ["FrameCandidate", "FramePrediction", "FrameAdvice", "advise_frame", "frame_seconds",
           "corner_curvature", "expected_curvature", "frame_advice_table"]

_CAMERA_REPORT = ((C_FOCAL, "focal_length_px", True), (C_PITCH, "pitch", False), (C_ROLL, "roll", False),
                  (C_HEIGHT, "height_m", True))


@dataclass(frozen=True)
class FramePrediction:
    """The predicted effect of one candidate: every object's distance sd and interval width after
    it (m), the camera's sds after it, the frame's gain (points) and the gain per minute and per
    second of human time."""

    candidate: FrameCandidate
    distance_sd_m: np.ndarray
    width_m: np.ndarray
    camera_sd: dict
    gain_pct: float
    gain_per_minute: float

    @property
    def gain_per_second(self) -> float:
        return self.gain_per_minute / 60.0

    def to_dict(self) -> dict:
        return {"candidate": self.candidate.to_dict(), "distance_sd_m": _list(self.distance_sd_m),
                "width_m": _list(self.width_m), "camera_sd": dict(self.camera_sd), "gain_pct": _r(self.gain_pct),
                "gain_per_minute": _r(self.gain_per_minute), "gain_per_second": _r(self.gain_per_second)}


def _r(v, nd=6):
    return None if v is None or not np.isfinite(v) else round(float(v), nd)


def _list(a, nd=6):
    return [_r(v, nd) for v in np.asarray(a, float)]


@dataclass(frozen=True)
class FrameAdvice:
    """The advice for a frame: the present (per object: MAP distance, distance sd and interval
    width; the camera's sds), every candidate's prediction (best gain per minute first), and the
    recommendation (``action`` ``collect`` or ``stop``, ``reason``)."""

    objects: tuple[str, ...]
    distance_m: np.ndarray
    distance_sd_m: np.ndarray
    width_m: np.ndarray
    width_source: str
    camera_sd: dict
    predictions: tuple[FramePrediction, ...]
    action: str
    reason: str
    settings: AdviceSettings
    curvature: float
    notes: tuple[str, ...] = ()
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def best(self) -> FramePrediction | None:
        return self.predictions[0] if self.predictions else None

    @property
    def share(self) -> np.ndarray:
        return self.width_m / self.distance_m

    def to_dict(self) -> dict:
        best = self.best
        return {"format": "creference-frame-advice/1",
                "now": {"objects": list(self.objects), "distance_m": _list(self.distance_m),
                        "distance_sd_m": _list(self.distance_sd_m), "width_m": _list(self.width_m),
                        "width_share": _list(self.share), "width_source": self.width_source,
                        "camera_sd": dict(self.camera_sd)},
                "action": self.action, "reason": self.reason,
                "recommended": best.candidate.key if self.action == "collect" and best else None,
                "predictions": [p.to_dict() for p in self.predictions], "curvature": _r(self.curvature),
                "curvature_at_map": _r(self.extra.get("curvature_at_map")),
                "notes": list(self.notes), "settings": self.settings.to_dict(), "seconds": round(self.seconds, 3)}


def corner_curvature(model, camera: np.ndarray, objects: np.ndarray) -> float:
    """κ: the mean curvature per coordinate of the Student-t corner term, in units of 1/σᵢ², over
    every annotated corner of the frame at the given state (module docstring)."""
    uv, _ = model.project(model.complete_camera(np.asarray(camera, float)[None]), np.asarray(objects, float)[None])
    r2 = np.sum((model.ann - uv[0][:, None]) ** 2, axis=-1)  # (m, K, 4)
    nu = model.target_dof
    q = r2 / (nu * model.sigma[:, None, None] ** 2)
    k = (nu + 2.0) / nu / (1.0 + q) ** 2
    mask = np.broadcast_to(model.ann_mask[..., None], k.shape) > 0
    return float(k[mask].mean())


def expected_curvature(nu: float) -> float:
    """κ(ν) = E[(ν + 2) / ν / (1 + X / ν)²] for X = |r|² / σ² ~ χ²₂ (a Gaussian corner): the
    expected curvature per coordinate of the Student-t corner term, in units of 1/σ²."""
    from scipy.integrate import quad

    return float(quad(lambda x: 0.5 * np.exp(-0.5 * x) * (nu + 2.0) / nu / (1.0 + x / nu) ** 2, 0.0, np.inf)[0])


def _reference_information(model, lap, cand: FrameCandidate, temperature: float):
    """(g_c (5,), g_o (7,), weight): the candidate reference's gradient in working coordinates and
    its Fisher weight."""
    nu = model.ref_dof
    fisher = (nu + 1.0) / (nu + 3.0)
    s = float(lap.camera[C_SCALE])
    if cand.kind == "distance":
        line = cand.line[None]

        def log_len(cams, objs):
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.log(model.ground_lengths(line, cams))[:, 0]
            return np.broadcast_to(v[:, None, None], (len(cams), model.n_objects, 1))

        g_c, _ = work_gradients(model, lap.wc, lap.wo, log_len)
        var = s**2 + _line_variance(model, cand.line, lap.camera)
        return g_c[cand.index, 0], np.zeros(7), fisher / var / temperature

    def log_length(cams, objs):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(objs[..., 3:4])

    g_c, g_o = work_gradients(model, lap.wc, lap.wo, log_length)
    return g_c[cand.index, 0], g_o[cand.index, 0], fisher / s**2 / temperature


def _line_variance(model, line: np.ndarray, camera: np.ndarray) -> float:
    """A segment's noise in log-length at ``camera``, as the frame model takes it at its pilot
    (:func:`~creference_bayes.models.metrology.linear_line_variances`)."""
    return float(linear_line_variances(line[None], model.principal_point, model.as_single_params(camera[None])[0],
                                       model.ref_line_sigma)[0])


def advise_frame(model, frame, camera: np.ndarray, objects: np.ndarray, *, width_now=None,
                 settings: AdviceSettings | None = None, temperature: float = 1.0,
                 curvature: float | None = None) -> FrameAdvice:
    """The advice for a frame at its MAP (module docstring).

    Parameters
    ----------
    model : the frame's :class:`~creference_bayes.models.frame.FrameModel`, with the MAP's
        handedness and pilot (:func:`~creference_bayes.frame_pipeline.rebuild_model`)
    frame : its :class:`~creference_bayes.io.frame_scene.FrameScene`
    camera : (5,) and objects : (m, 7) the MAP
    width_now : (m,) the present width of each distance's interval, metres (the posterior's HDI),
        or None for the Laplace approximation's
    settings : :class:`~creference_bayes.workflows.advice.AdviceSettings` (``hdi_prob``,
        ``target_hdi_width``, ``min_gain`` are used)
    temperature : the estimate's temperature
    curvature : κ of a new set of dimension lines (default :func:`expected_curvature` of the
        model's ν; (ν + 2) / ν is that of a set exactly on the MAP's corners, which the tests use)
    """
    t0 = time.perf_counter()
    settings = settings or AdviceSettings()
    lap = frame_laplace(model, camera, objects, temperature=temperature)
    m = model.n_objects
    H = lap.hessian

    def dist(cams, objs):
        return np.hypot(objs[..., 0], objs[..., 1])[..., None]

    gd_c, gd_o = (g[:, 0] for g in work_gradients(model, lap.wc, lap.wo, dist))

    def outlook(Hn: Arrowhead):
        Sc, Ao, B, ok = laplace_blocks(model, Hn)
        sd = np.sqrt(np.maximum(block_variances(Sc, Ao, B, gd_c, gd_o), 0.0))
        cam = {}
        for j, name, log in _CAMERA_REPORT:
            if model.camera_free[j]:
                v = math.sqrt(max(Sc[j, j], 0.0))
                cam[name] = _r(v * lap.camera[j] if log else v)
        return sd, cam, ok

    sd_now, cam_now, ok = outlook(H)
    notes = [] if ok else ["the Hessian at the MAP is not positive definite: its negative curvatures "
                           "were taken with their absolute value (a rough prediction)"]
    d_map = np.hypot(lap.objects[:, 0], lap.objects[:, 1])
    z = float(norm.ppf(0.5 + settings.hdi_prob / 2))
    if width_now is None:
        width, source = 2 * z * sd_now, "laplace"
    else:
        width, source = np.asarray(width_now, float), "posterior"
    kappa = expected_curvature(model.target_dof) if curvature is None else float(curvature)
    fitted = corner_curvature(model, lap.camera, lap.objects)
    g_uv = work_gradients(model, lap.wc, lap.wo, lambda c, o: model.project(c, o)[0].reshape(len(c), m, 8))
    cands, more = frame_candidates(model, frame, lap.camera, lap.objects, frame_seconds(frame))
    notes += more
    preds = []
    for cand in cands:
        i = cand.index
        if cand.kind == "dims":
            J = np.concatenate([g_uv[0][i], g_uv[1][i]], axis=1)  # (8, 12)
            dF = kappa / model.sigma[i] ** 2 / temperature * J.T @ J
        else:
            gc, go, wgt = _reference_information(model, lap, cand, temperature)
            g = np.concatenate([gc, go])
            if not np.all(np.isfinite(g)):
                notes.append(f"{cand.key}: left out: its gradient is not finite")
                continue
            dF = wgt * np.outer(g, g)
        Hn = Arrowhead(H.value, H.g_c, H.g_o, H.H_cc + dF[:5, :5], H.H_co.copy(), H.H_oo.copy(), H.pairs, H.H_pair)
        Hn.H_co[i] += dF[:5, 5:]
        Hn.H_oo[i] += dF[5:, 5:]
        sd_after, cam_after, _ = outlook(Hn)
        ratio = np.where(sd_now > 0, sd_after / np.where(sd_now > 0, sd_now, 1.0), 1.0)
        w_after = width * np.minimum(ratio, 1.0)
        gain = float(100.0 * np.sum((width - w_after) / d_map))
        preds.append(FramePrediction(cand, sd_after, w_after, cam_after, gain,
                                     gain / (cand.seconds / 60.0) if cand.seconds > 0 else math.inf))
    preds.sort(key=lambda p: -p.gain_per_minute)
    action, reason = _recommend(width / d_map, preds, settings, [o.id for o in model.objects])
    return FrameAdvice(tuple(o.id for o in model.objects), d_map, sd_now, width, source, cam_now, tuple(preds),
                       action, reason, settings, kappa, tuple(notes), time.perf_counter() - t0,
                       {"curvature_at_map": fitted})


def _recommend(share, preds, settings: AdviceSettings, ids) -> tuple[str, str]:
    goal = settings.target_hdi_width
    if np.all(share <= goal):
        return "stop", (f"precision target met: every object's {settings.hdi_prob:.0%} interval of the distance "
                        f"is at most {100 * goal:g} % of it (widest: {ids[int(np.argmax(share))]}, "
                        f"{100 * share.max():.1f} %)")
    if not preds:
        return "stop", "no annotation of this frame can be weighed"
    best = preds[0]
    if best.gain_per_minute < settings.min_gain:
        return "stop", (f"the best predicted gain, {best.gain_per_minute:.2f} points per minute "
                        f"({best.candidate.description}), is below the minimum {settings.min_gain:g}")
    return "collect", (f"collect {best.candidate.description} next: {best.gain_pct:.1f} points of the "
                       f"objects' distances in all, {best.gain_per_minute:.2f} points per minute")
