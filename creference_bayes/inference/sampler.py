"""The posterior of any scene: one driver, its kernels composed by the model's blocks.

docs/inference.md, "Sampling and summaries", describes the kernels, the warm-up and the stopping
rule. One object block (:func:`.coords.explored_whole`): the whole free vector by the ensemble
kernel (:mod:`.whole`, :mod:`.ensemble`), pitch as log D (:class:`.coords.HorizonDistance`),
after a search for the joint modes; otherwise block sweeps (:mod:`.blocks`, :mod:`.moves`) in
sheared working coordinates, after a search for each object's modes. Either way a chain is one
independent unit, ``lp`` is the log-density in working coordinates, and :func:`run_chains`
stops every kernel by bulk ESS and rank R-hat. Everything random comes from ``rng``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields

import numpy as np

from ..models.contract import C_HEIGHT, CAMERA_NAMES, O_GROUND, O_YAW, OBJECT_NAMES, Model
from .coords import WorkingCoords, explored_whole
from .diagnostics import ess_bulk_rhat, rhat_split_raw
from .laplace import laplace_blocks
from .map import MapState, derivatives

__all__ = ["SamplerSettings", "Draws", "Diagnostics", "SamplingError", "sample", "run_chains"]


#: Steps kept per walker (older ones thinned by two when twice as many are kept).
MAX_DRAWS = 2000
#: Steps of the main phase before the stopping rule may be met: a chain of an ensemble's walkers
#: laid end to end shows the ESS estimator only correlations within each walker's own run, so a
#: run shorter than the walkers' autocorrelation would over-state the ESS.
MIN_STEPS = 50


class SamplingError(RuntimeError):
    """The sampler cannot start (the MAP has zero posterior density)."""


@dataclass(frozen=True)
class SamplerSettings:
    """Settings of :func:`sample` (unknown keys of a user's dict are rejected: :meth:`from_options`).

    Every kernel
        min_ess : bulk effective sample size every free parameter (and every object's distance)
            must reach;  max_rhat : largest rank-normalised split R-hat over the chains accepted;
            max_steps : cap on main-phase steps (the result then says it has not converged);
            chunk : steps between convergence checks (at least);  tries : tries per independence
            proposal (multiple-try Metropolis; 1: plain);  independence_weight : the share of steps
            that are independence moves (None: 0.5 for block sweeps, 0.8 for the ensemble kernel);
            mode_search : look for other modes before sampling (:mod:`.modes`)
    Block sweeps
        n_chains : walkers, each an independent chain;  warmup : warm-up steps
    Ensemble kernel (one object block; :mod:`.ensemble`)
        n_ensembles, n_walkers : groups (each a chain) and the walkers of each;  stage :
        the first warm-up stage's length (later ones double);  proposal_components : the
        independence proposal's mixture components
    """

    min_ess: float = 400.0
    max_rhat: float = 1.01
    max_steps: int = 20000
    chunk: int = 50
    tries: int = 4
    independence_weight: float | None = None
    mode_search: bool = True
    n_chains: int = 8
    warmup: int = 600
    n_ensembles: int = 4
    n_walkers: int = 24
    stage: int = 50
    proposal_components: int = 3

    def __post_init__(self):
        def whole(k, lo, what=None):
            v = getattr(self, k)
            ok = isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= lo
            return k, ok, f"an integer ≥ {what or lo}"

        checks = [("min_ess", self.min_ess >= 0, "a number ≥ 0"), ("max_rhat", self.max_rhat >= 1.0, "a number ≥ 1"),
                  whole("chunk", 10), whole("max_steps", self.chunk, "chunk"), whole("tries", 1),
                  ("independence_weight", self.independence_weight is None or 0.0 <= self.independence_weight < 1.0,
                   "a number in [0, 1)"), ("mode_search", isinstance(self.mode_search, bool), "true or false"),
                  whole("n_chains", 2), whole("warmup", 50), whole("n_ensembles", 2),
                  ("n_walkers", whole("n_walkers", 8)[1] and self.n_walkers % 2 == 0, "an even integer ≥ 8"),
                  whole("stage", 10), whole("proposal_components", 1)]
        for name, ok, expected in checks:
            if not ok:
                raise ValueError(f"sampling.{name}: expected {expected}, got {getattr(self, name)!r}")

    @classmethod
    def from_options(cls, options: dict | None) -> "SamplerSettings":
        """``cls(**options)``; unknown keys are rejected with a :class:`ValueError` naming them
        (and the fields' own checks name a bad value)."""
        options = dict(options or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"sampling: unknown option(s) {unknown} (expected some of {sorted(known)})")
        return cls(**options)



@dataclass(frozen=True)
class Draws:
    """Posterior draws in natural parameters: cameras (chain, draw, 5), objects (chain, draw, m, 7)
    and the log-density of each (chain, draw) in the sampler's coordinates."""

    cameras: np.ndarray
    objects: np.ndarray
    log_prob: np.ndarray | None = None


@dataclass(frozen=True)
class Diagnostics:
    """How the sampler did, in one shape whatever its moves: per checked quantity bulk ESS and R-hat
    (dicts keyed by ``camera.<name>`` and ``<target id>.<name>``), steps, acceptance rates (``all``:
    the share of a walker's steps that moved it; ``camera``, ``objects``: of those blocks' proposals
    accepted; moves of the whole vector give ``all`` for each), ``converged`` and the reasons when
    it is not, seconds, the modes found before sampling (None: one)."""

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

    def to_dict(self) -> dict:
        r = lambda d: {k: (None if v is None or not np.isfinite(v) else round(float(v), 4)) for k, v in d.items()}
        return {"sampler": "emcee", "n_chains": self.n_chains, "warmup": self.warmup, "iterations": self.iterations,
                "thin": self.thin, "min_ess_bulk": _extreme(_checked(self.ess_bulk), min, 1),
                "max_r_hat": _extreme(_checked(self.r_hat), max, 4), "ess_bulk": r(self.ess_bulk), "r_hat": r(self.r_hat),
                "acceptance": {k: round(float(v), 3) for k, v in self.acceptance.items()},
                "converged": self.converged, "warnings": list(self.warnings), "seconds": round(self.seconds, 3),
                "modes": self.info.get("mode_report") or None}


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
    when the MAP has zero posterior density. The model is sampled at the MAP's handedness and pilot
    (:meth:`MapState.fitted`); ``model`` itself is not changed.
    """
    t0 = time.perf_counter()
    s = settings or SamplerSettings()
    rng = np.random.default_rng(rng)
    model = map_est.fitted(model)
    start = _laplace_start(model, map_est, temperature)
    from .blocks import Blocks
    from .progress import progress_bar
    from .whole import Whole

    kernel = (Whole if explored_whole(model) else Blocks)(model, start, s, rng, temperature, map_est)

    with progress_bar(progress, s.warmup + s.max_steps, desc="sampling", unit="step") as bar:
        warm = kernel.tune(bar)
        (cams, objs), lp, it, thin, diag = run_chains(kernel, kernel.natural,
                                                      lambda c, o: _columns(model, c, o, map_est), s, bar)
    draws = Draws(cams, objs, lp)
    warn = [] if diag["ok"] else [f"not converged after {it} steps: " + "; ".join(diag["why"])]
    if not start[-1]:
        warn.append("the Laplace approximation at the MAP was not positive definite (its blocks were repaired)")
    acceptance = dict(zip(("all", "camera", "objects"), kernel.acceptance()))
    return draws, Diagnostics(kernel.n_chains, warm, it, thin, *_with_y(model, draws, diag["ess_bulk"], diag["r_hat"]),
                              acceptance, diag["ok"], tuple(warn), time.perf_counter() - t0, kernel.report(draws))


def run_chains(kernel, convert, columns, s: SamplerSettings, bar):
    """The main phase of every kernel, to the one stopping rule (docs/inference.md, "Stopping").

    ``kernel.run(steps)`` yields each step's states (S, …) of its walkers (``kernel.n_chains``
    chains of ``kernel.walkers`` consecutive walkers) and their log-densities (S,); every
    ``thin``-th step is kept (``thin`` doubles whenever 2 · :data:`MAX_DRAWS` steps are kept).
    ``convert`` turns kept states (n, S, …) into a tuple of arrays; ``columns`` turns those, each
    chain's walkers end to end (:func:`_by_chain`), into the checked quantities (C, N, k) and their
    names. Returns the kept arrays (C, N, …), log-densities (C, N), steps run, thinning and the
    last check (:func:`_diagnose`).
    """
    arrays, lps, thin, it, diag = None, None, 1, 0, None
    w = kernel.walkers
    first = max(s.chunk, -(-64 * s.chunk // (kernel.n_chains * w)))
    chunk = first
    while it < s.max_steps:
        chunk = min(chunk, s.max_steps - it)
        xs, ls = [], []
        for x, lp in kernel.run(chunk):
            it += 1
            if it % thin == 0:
                xs.append(np.array(x))
                ls.append(np.array(lp))
        bar.update(chunk)
        if xs:
            new = convert(np.array(xs))
            arrays = new if arrays is None else tuple(np.concatenate(p) for p in zip(arrays, new))
            lps = np.array(ls) if lps is None else np.concatenate([lps, ls])
        while len(lps) >= 2 * MAX_DRAWS:
            arrays, lps, thin = tuple(a[1::2] for a in arrays), lps[1::2], 2 * thin
        arr, names = columns(*(_by_chain(a, w) for a in arrays))
        with np.errstate(all="ignore"):  # a cheap look first (module docstring)
            raw = float(np.nanmax(np.append(rhat_split_raw(arr), 1.0)))
        need = it * (raw - 1.0) / (3.0 * (s.max_rhat - 1.0)) if s.max_rhat > 1.0 else it
        if raw <= 1.0 + 3.0 * (s.max_rhat - 1.0) or it >= s.max_steps or diag is None:
            diag = _diagnose(arr, names, s, it)
            if diag["ok"]:
                break
            need = max(need, s.min_ess * it / max(diag["min_ess"], 1.0))
            if diag["max_rhat"] > s.max_rhat:
                need = max(need, it * (diag["max_rhat"] - 1.0) / (s.max_rhat - 1.0) if s.max_rhat > 1.0 else it)
        chunk = int(np.clip(1.2 * need - it, first, 2 * it))
    return tuple(_by_chain(a, w) for a in arrays), _by_chain(lps, w), it, thin, diag


def _by_chain(a: np.ndarray, walkers: int) -> np.ndarray:
    """Kept steps of the walkers (n, S, …) as chains (S / walkers, walkers · n, …): each chain's
    walkers' draws laid end to end, walker after walker."""
    n, S = a.shape[:2]
    return np.swapaxes(a, 0, 1).reshape((S // walkers, walkers * n) + a.shape[2:])


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


def _columns(model: Model, cams: np.ndarray, objs: np.ndarray, map_est: MapState) -> tuple[np.ndarray, list[str]]:
    """The quantities checked: every free parameter (yaw unwrapped around the MAP) and each
    object's ground distance, as (chain, draw, k), with their names."""
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


def _diagnose(arr: np.ndarray, names: list[str], s: SamplerSettings, steps: int) -> dict:
    """Bulk ESS and rank-normalised R-hat of every column of ``arr``; whether the stopping rule
    is met (never before :data:`MIN_STEPS` steps)."""
    eb, rh = ess_bulk_rhat(arr)
    why = [] if steps >= MIN_STEPS else [f"{steps} steps < {MIN_STEPS}, too few to measure the ESS"]
    if np.nanmin(eb) < s.min_ess:
        k = int(np.nanargmin(eb))
        why.append(f"bulk ESS of {names[k]} {eb[k]:.0f} < {s.min_ess:g}")
    if np.nanmax(rh) > s.max_rhat:
        k = int(np.nanargmax(rh))
        why.append(f"R-hat of {names[k]} {rh[k]:.3f} > {s.max_rhat:g}")
    return {"ok": not why, "why": why, "min_ess": float(np.nanmin(eb)), "max_rhat": float(np.nanmax(rh)),
            "ess_bulk": dict(zip(names, eb.tolist())), "r_hat": dict(zip(names, rh.tolist()))}
