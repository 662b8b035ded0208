"""The posterior of any scene: one driver, its kernels composed by the model's blocks.

docs/inference.md, "Sampling and summaries", describes the kernels, the warm-up and the stopping
rule. One object block (:func:`.coords.explored_whole`): the whole free vector by the ensemble
kernel (:mod:`.whole`, :mod:`.ensemble`), pitch as log D (:class:`.coords.HorizonDistance`),
after a search for the joint modes; otherwise block sweeps (:mod:`.blocks`, :mod:`.moves`) in
sheared working coordinates, after a search for each object's modes. Either way a chain is one
independent unit, ``lp`` is the log-density in working coordinates, and :func:`.chains.run_chains`
stops every kernel by bulk ESS and rank R-hat. Everything random comes from ``rng``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..models.contract import C_HEIGHT, CAMERA_NAMES, O_GROUND, O_YAW, OBJECT_NAMES, Model
from .blocks import Blocks
from .chains import Draws, SamplerSettings, SamplingError, run_chains
from .coords import WorkingCoords, explored_whole
from .diagnostics import ess_bulk_rhat
from .laplace import laplace_blocks
from .map import MapState, derivatives
from .progress import progress_bar
from .whole import Whole

__all__ = ["SamplerSettings", "Draws", "Diagnostics", "SamplingError", "sample", "run_chains"]


@dataclass(frozen=True)
class Diagnostics:
    """How the sampler did, in one shape whatever its moves: per checked quantity bulk ESS and R-hat
    (dicts keyed by ``camera.<name>`` and ``<target id>.<name>``), steps, acceptance rates (``all``:
    the share of a walker's steps that moved it; ``camera``, ``objects``: of those blocks' proposals
    accepted; moves of the whole vector give ``all`` for each), ``converged`` and the reasons when
    it is not, seconds, the modes found before sampling (None: one) and, where both handednesses
    of a target were sampled, each one's share of the draws (None: the MAP's alone)."""

    n_chains: int
    warmup: int
    iterations: int
    thin: int
    ess_bulk: dict
    r_hat: dict
    acceptance: dict
    converged: bool
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0
    info: dict = field(default_factory=dict)
    #: draws each chain holds (a chain of the ensemble kernel lays its walkers end to end)
    draws_per_chain: int = 0

    def to_dict(self) -> dict:
        r = lambda d: {k: (None if v is None or not np.isfinite(v) else round(float(v), 4)) for k, v in d.items()}
        return {"sampler": "emcee", "n_chains": self.n_chains, "warmup": self.warmup, "iterations": self.iterations,
                "thin": self.thin, "draws_per_chain": self.draws_per_chain, "min_ess_bulk": _extreme(_checked(self.ess_bulk), min, 1),
                "max_r_hat": _extreme(_checked(self.r_hat), max, 4), "ess_bulk": r(self.ess_bulk), "r_hat": r(self.r_hat),
                "acceptance": {k: round(float(v), 3) for k, v in self.acceptance.items()},
                "converged": self.converged, "warnings": list(self.warnings), "seconds": round(self.seconds, 3),
                "modes": self.info.get("mode_report") or None, "handedness": self.info.get("handedness_share")}


def _checked(d: dict) -> dict:
    """The quantities the stopping rule checks (all but :data:`REPORTED_ONLY`)."""
    return {k: v for k, v in d.items() if k.rpartition(".")[2] not in REPORTED_ONLY}


def _extreme(d, pick, nd):
    v = [x for x in d.values() if x is not None and np.isfinite(x)]
    return round(float(pick(v)), nd) if v else None


def sample(model: Model, map_est: MapState, *, settings: SamplerSettings | None = None, rng=None,
           temperature: float = 1.0, progress: bool = False) -> tuple[Draws, Diagnostics]:
    """Sample the posterior of ``model`` from its MAP (module docstring): the ensemble kernel for one
    object block, block sweeps for several, under one warm-up and one stopping rule.

    Returns the draws (natural parameters) and the diagnostics. Raises :class:`SamplingError`
    when the MAP has zero posterior density. The model is sampled at the MAP's handedness (and,
    for one object block, at the other's too where it comes near: :mod:`.whole`) and at a
    pilot moved to the warm-up's posterior median (:func:`_repilot`, ``info["pilot"]`` of the
    diagnostics); ``model`` itself is not changed.
    """
    t0 = time.perf_counter()
    s = settings or SamplerSettings()
    rng = np.random.default_rng(rng)
    model = map_est.fitted(model)
    start = _laplace_start(model, map_est, temperature)
    kernel = (Whole if explored_whole(model) else Blocks)(model, start, s, rng, temperature, map_est)

    with progress_bar(progress, s.warmup + s.max_steps, desc="sampling", unit="step") as bar:
        warm = kernel.tune(bar, _repilot(model))
        kept, lp, it, thin, diag = run_chains(kernel, kernel.kept, lambda *a: _columns(model, map_est, *a), s, bar)
    draws = Draws(kept[0], kept[1], lp, kept[2] if len(kept) > 2 else None)
    warn = [] if diag["ok"] else [f"not converged after {it} steps: " + "; ".join(diag["why"])]
    if not start[-1]:
        warn.append("the Laplace approximation at the MAP was not positive definite (its blocks were repaired)")
    acceptance = dict(zip(("all", "camera", "objects"), kernel.acceptance()))
    info = kernel.report(draws)
    if model.needs_pilot:
        info["pilot"] = model.pilot.copy()
    return draws, Diagnostics(kernel.n_chains, warm, it, thin, *_with_y(model, draws, diag["ess_bulk"], diag["r_hat"]),
                              acceptance, diag["ok"], tuple(warn), time.perf_counter() - t0, info,
                              int(draws.cameras.shape[1]))


def _repilot(model: Model):
    """What moves the model's pilot (the camera at which each drawn segment's reading is fixed,
    e.g. :meth:`.metrology.MetrologyModel.set_pilot`) to the median camera of warm-up draws, called
    by the kernels after each warm-up segment; None for a model without a pilot. ``model`` is the
    sampler's own copy.

    The MAP's camera is a poor pilot where the posterior is wide in focal length: the MAP moves far
    with any new annotation, and every reading with it. The posterior's median camera moves as much
    as the posterior does; repeated over the warm-up's segments, the pilot approaches the camera that
    is the median of the posterior it defines (docs/inference.md, "The pilot")."""
    if not model.needs_pilot:
        return None
    return lambda cams: model.set_pilot(np.median(cams, axis=0))


def _interior(lower: np.ndarray, upper: np.ndarray, v: np.ndarray, margin: float = 1e-7) -> np.ndarray:
    """``v`` pulled inside its bounds by ``margin`` of their span: a MAP on a bound stays inside
    after the round trip through the sampled coordinates."""
    span = np.where(np.isfinite(upper - lower), upper - lower, 0.0)
    return np.clip(v, lower + margin * span, upper - margin * span)


def _laplace_start(model: Model, map_est: MapState, temperature: float):
    """The MAP in working coordinates (wc0 (5,), wo0 (m, 7)) and the Laplace approximation there by
    blocks (Sc, Ao, B, ok: :func:`~.laplace.laplace_blocks`)."""
    cams, objs = _interior(model.camera_lower, model.camera_upper, map_est.camera), \
        _interior(model.object_lower, model.object_upper, map_est.objects)
    wc0, wo0 = (a[0] for a in WorkingCoords(model).to_work(cams[None], objs[None]))
    return (wc0, wo0) + laplace_blocks(model, derivatives(model, wc0, wo0, temperature, with_jacobian=True))


def _columns(model: Model, map_est: MapState, cams: np.ndarray, objs: np.ndarray,
             hands: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """The quantities checked: every free parameter (yaw unwrapped around the MAP), each object's
    ground distance and, where both were sampled, its handedness (``hands`` (chain, draw, m)), as
    (chain, draw, k), with their names."""
    cols, names = [], []
    for j in np.flatnonzero(model.camera_free):
        cols.append(cams[..., j])
        names.append(f"camera.{CAMERA_NAMES[j]}")
    for i, o in enumerate(model.objects):
        for j in np.flatnonzero(model.object_free[i]):
            x = objs[..., i, j]
            if j == O_YAW:
                x = map_est.objects[i, O_YAW] + (x - map_est.objects[i, O_YAW] + np.pi) % (2 * np.pi) - np.pi
            cols.append(x)
            names.append(f"{o.id}.{OBJECT_NAMES[j]}")
        cols.append(np.hypot(objs[..., i, 0], objs[..., i, 1]))
        names.append(f"{o.id}.distance_m")
        if hands is not None and np.any(hands[..., i] != model.handedness[i]):
            cols.append(hands[..., i])
            names.append(f"{o.id}.handedness")
    return np.stack(cols, axis=-1), names


#: Quantities the diagnostics report but the stopping rule does not check (``<target id>.y``, the
#: bottom's y: the camera height less the ground offset, each checked).
REPORTED_ONLY = ("y",)


def _with_y(model: Model, draws: Draws, ess: dict, rhat: dict) -> tuple[dict, dict]:
    """The checked quantities' bulk ESS and R-hat with each object's ``y`` added: the camera
    height's where its ground offset is fixed, else its own from the draws."""
    ess, rhat = dict(ess), dict(rhat)
    h = f"camera.{CAMERA_NAMES[C_HEIGHT]}"
    for i, o in enumerate(model.objects):
        ess[f"{o.id}.y"], rhat[f"{o.id}.y"] = ess.get(h), rhat.get(h)
    free = np.flatnonzero(model.object_free[:, O_GROUND])
    if free.size:
        y = draws.cameras[..., C_HEIGHT, None] - draws.objects[..., free, O_GROUND]  # (chain, draw, k)
        eb, rh = ess_bulk_rhat(y)
        for i, e, r in zip(free, eb.tolist(), rh.tolist()):
            ess[f"{model.objects[i].id}.y"], rhat[f"{model.objects[i].id}.y"] = e, r
    return ess, rhat


