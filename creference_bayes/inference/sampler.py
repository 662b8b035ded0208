"""The posterior of any scene: one driver, its kernels composed by the model's blocks.

docs/inference.md, "Sampling and summaries", describes the kernels, the warm-up and the stopping
rule. One object block (:func:`.coords.explored_whole`): the whole free vector by the ensemble
kernel (:class:`_Whole`, :mod:`.ensemble`), pitch as log D (:class:`.coords.HorizonDistance`),
after a search for the joint modes; otherwise block sweeps (:class:`_Blocks`, :mod:`.moves`) in
sheared working coordinates, after a search for each object's modes. Either way a chain is one
independent unit, ``lp`` is the log-density in working coordinates, and :func:`run_chains`
stops every kernel by bulk ESS and rank R-hat. Everything random comes from ``rng``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields

import emcee
import numpy as np
from scipy.linalg import block_diag

from ..models.contract import C_HEIGHT, CAMERA_NAMES, O_GROUND, O_YAW, OBJECT_NAMES, Model
from .diagnostics import ess_bulk_rhat, rhat_split_raw
from .laplace import laplace_blocks
from .map import MapState, derivatives
from .coords import HorizonDistance, WorkingCoords, explored_whole
from .moves import BlockKernel, BlockTarget, IndependenceSweep, RandomWalkSweep

__all__ = ["SamplerSettings", "Draws", "Diagnostics", "SamplingError", "sample", "run_chains"]


#: Steps kept per walker (older ones thinned by two when twice as many are kept).
MAX_DRAWS = 2000
#: Steps of the main phase before the stopping rule may be met: a chain of an ensemble's walkers
#: laid end to end shows the ESS estimator only correlations within each walker's own run, so a
#: run shorter than the walkers' autocorrelation would over-state the ESS.
MIN_STEPS = 50
#: The least ESS the default R-hat bar is computed at (:meth:`SamplerSettings.rhat_bar`).
RHAT_ESS = 400.0


class SamplingError(RuntimeError):
    """The sampler cannot start (the MAP has zero posterior density)."""


@dataclass(frozen=True)
class SamplerSettings:
    """Settings of :func:`sample` (unknown keys of a user's dict are rejected: :meth:`from_options`).

    Every kernel
        min_ess : bulk effective sample size every free parameter (and every object's distance)
            must reach;  max_rhat : largest rank-normalised split R-hat over the chains accepted
            (None: :meth:`rhat_bar`, what well-mixed chains show at the ESS asked for);
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
    max_rhat: float | None = None
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

        checks = [("min_ess", self.min_ess >= 0, "a number ≥ 0"), ("max_rhat", self.max_rhat is None or self.max_rhat >= 1.0,
                                                                  "a number ≥ 1 or null"),
                  whole("chunk", 10), whole("max_steps", self.chunk, "chunk"), whole("tries", 1),
                  ("independence_weight", self.independence_weight is None or 0.0 <= self.independence_weight < 1.0,
                   "a number in [0, 1)"), ("mode_search", isinstance(self.mode_search, bool), "true or false"),
                  whole("n_chains", 2), whole("warmup", 50), whole("n_ensembles", 2),
                  ("n_walkers", whole("n_walkers", 8)[1] and self.n_walkers % 2 == 0, "an even integer ≥ 8"),
                  whole("stage", 10), whole("proposal_components", 1)]
        for name, ok, expected in checks:
            if not ok:
                raise ValueError(f"sampling.{name}: expected {expected}, got {getattr(self, name)!r}")

    def rhat_bar(self, chains: int) -> float:
        """The largest R-hat the stopping rule accepts over ``chains`` independent chains:
        ``max_rhat`` when set, else √(1 + 2·chains / E), E = max(``min_ess``, :data:`RHAT_ESS`).

        For chains that have mixed, the split R-hat's square is about 1 + 2·chains / ESS (Vats and
        Knudson 2021, "Revisiting the Gelman–Rubin diagnostic"), so a fixed bar asks for more
        effective draws the more chains there are: 1.01 is what 4 chains with 400 effective draws
        show on average (the usual advice), and 8 chains show it only at 800 (every quantity
        checked, so the worst of a frame's at about 1,400). The bar is therefore what the chains
        show at the ESS asked for (never laxer than at :data:`RHAT_ESS`): 1.010 for the ensemble's
        4 groups, 1.020 for 8 block-sweep chains (docs/studies/sampler.md, "The R-hat bar")."""
        if self.max_rhat is not None:
            return float(self.max_rhat)
        return float(np.sqrt(1.0 + 2.0 * chains / max(self.min_ess, RHAT_ESS)))

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


def _chol(cov: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Cholesky factor of ``cov`` on its free rows and columns, zero elsewhere."""
    out = np.zeros_like(cov)
    idx = np.flatnonzero(free)
    if idx.size == 0:
        return out
    sub = cov[np.ix_(idx, idx)]
    sub = 0.5 * (sub + sub.T)
    for jitter in (0.0, 1e-10, 1e-8, 1e-6, 1e-4):
        try:
            L = np.linalg.cholesky(sub + jitter * np.diag(np.maximum(np.diag(sub), 1e-12)))
            break
        except np.linalg.LinAlgError:
            continue
    else:
        L = np.diag(np.sqrt(np.maximum(np.abs(np.diag(sub)), 1e-12)))
    out[np.ix_(idx, idx)] = L
    return out


def _reestimate(model: Model, wc: np.ndarray, wo: np.ndarray, Sc0, Ao0, B0):
    """Covariances and shear from warm-up draws (pooled over chains; working coordinates),
    blended with the Laplace ones (80 % / 20 %); and the independence centres."""
    cf, of = model.camera_free, model.object_free
    C = wc.reshape(-1, 5)
    O = wo.reshape(-1, model.n_objects, 7)
    cm, om = C.mean(axis=0), O.mean(axis=0)
    dc, do = C - cm, O - om
    n = len(C)
    Scc = np.where(np.outer(cf, cf), dc.T @ dc / (n - 1), 0.0)
    Soo = np.einsum("nmi,nmj->mij", do, do) / (n - 1)
    Soc = np.einsum("nmi,nc->mic", do, dc) / (n - 1)
    idx = np.flatnonzero(cf)
    inv = np.zeros((5, 5))
    if idx.size:
        inv[np.ix_(idx, idx)] = np.linalg.pinv(Scc[np.ix_(idx, idx)])
    B = np.einsum("mic,cd->mid", Soc, inv) * of[:, :, None] * cf[None, None, :]
    cond = Soo - np.einsum("mic,mjc->mij", B, Soc)
    return 0.8 * Scc + 0.2 * Sc0, 0.8 * cond + 0.2 * Ao0, 0.8 * B + 0.2 * B0, cm


class _Run:
    """One segment of the run: a target in the current shear, its kernel and an EnsembleSampler."""

    def __init__(self, model, temperature, s: SamplerSettings, c0, Sc, Ao, B, mc, mt, adapt, modes=None):
        m = model.n_objects
        self.target = BlockTarget(model, temperature, c0, B, np.zeros((m, 7)))
        Lc = _chol(Sc, model.camera_free)
        Lo = np.array([_chol(Ao[i], model.object_free[i]) for i in range(m)])
        self.kernel = BlockKernel(self.target, Lc, Lo, mc, mt, tries=s.tries, adapt=adapt, modes=modes)
        w = 0.5 if s.independence_weight is None else s.independence_weight
        moves = [(RandomWalkSweep(self.kernel), 1.0 - w)]
        if w > 0:
            moves.append((IndependenceSweep(self.kernel), w))
        self.sampler = emcee.EnsembleSampler(s.n_chains, self.target.ndim, self.target, moves=moves, vectorize=True)

    def state(self, wc: np.ndarray, wo: np.ndarray, random_state) -> emcee.State:
        """The walkers at working coordinates (wc (C, 5), wo (C, m, 7)) in this segment's shear."""
        t = self.target
        wt = wo - np.einsum("mik,nk->nmi", t.B, wc - t.c0)
        u = t.join(wc, wt)
        blobs = t.blocks(u)
        with np.errstate(invalid="ignore"):
            return emcee.State(u, log_prob=blobs.sum(axis=1), blobs=blobs, random_state=random_state)

    def run(self, state: emcee.State, steps: int):
        """Yield the state after each of ``steps`` steps."""
        yield from self.sampler.sample(state, iterations=steps, store=False, skip_initial_state_check=True)


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
    kernel = (_Whole if explored_whole(model) else _Blocks)(model, start, s, rng, temperature, map_est)
    from .progress import progress_bar

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
    w, rb = kernel.walkers, s.rhat_bar(kernel.n_chains)
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
        need = it * (raw - 1.0) / (3.0 * (rb - 1.0)) if rb > 1.0 else it
        if raw <= 1.0 + 3.0 * (rb - 1.0) or it >= s.max_steps or diag is None:
            diag = _diagnose(arr, names, s, it, rb)
            if diag["ok"]:
                break
            need = max(need, s.min_ess * it / max(diag["min_ess"], 1.0))
            if diag["max_rhat"] > rb:
                need = max(need, it * (diag["max_rhat"] - 1.0) / (rb - 1.0) if rb > 1.0 else it)
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


class _Blocks:
    """Block sweeps (module docstring): ``n_chains`` walkers, each an independent chain, started
    from over-dispersed draws (1.2 ×) of the Laplace approximation (at the MAP where those have
    zero density), each object in its mode c mod k."""

    def __init__(self, model, start, s: SamplerSettings, rng, temperature, map_est):
        wc0, wo0, Sc, Ao, B, _ = self.start = start
        self.model, self.s, self.T = model, s, temperature
        m, C = model.n_objects, s.n_chains
        self.n_chains, self.walkers = C, 1
        of = model.object_free
        Lo = np.array([_chol(Ao[i], of[i]) for i in range(m)])
        dc = 1.2 * rng.standard_normal((C, 5)) @ _chol(Sc, model.camera_free).T
        wc = wc0 + dc
        wo = wo0 + 1.2 * np.einsum("mij,cmj->cmi", Lo, rng.standard_normal((C, m, 7))) + np.einsum("mik,ck->cmi", B, dc)
        random_state = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
        self.found = _object_modes(model, temperature, s, wc0, wo0, Sc, Ao, B)
        self.mix = _mixture(model, self.found, B)
        if self.mix is not None:  # chain c starts each object in its mode c (mod its modes)
            for i, modes in enumerate(self.found):
                for c in range(C):
                    k = c % len(modes)
                    if k:
                        wo[c, i] = modes[k].center + _chol(modes[k].cov, of[i]) @ rng.standard_normal(7) + B[i] @ dc[c]
        self.seg = _Run(model, temperature, s, wc0, Sc, Ao, B, wc0, wo0, adapt=True, modes=self.mix)
        state = self.seg.state(wc, wo, random_state)
        bad = ~np.isfinite(state.log_prob)
        wc[bad], wo[bad] = wc0, wo0
        self.state = self.seg.state(wc, wo, random_state)
        if not np.all(np.isfinite(self.state.log_prob)):
            raise SamplingError("the MAP has zero posterior density: cannot start the sampler")

    def tune(self, bar) -> int:
        """The warm-up (module docstring); returns its steps."""
        s, m = self.s, self.model.n_objects
        wc0, wo0, Sc0, Ao0, B0, _ = self.start
        seg, state, done, hist = self.seg, self.state, 0, []
        for mark in (int(0.4 * s.warmup), int(0.7 * s.warmup), s.warmup):  # warm-up segments
            for state in seg.run(state, mark - done):
                hist.append(seg.target.working(state.coords))
            bar.update(mark - done)
            done = mark
            if mark == s.warmup:
                break
            keep = hist[len(hist) // 2:]  # re-estimate from the second half of the segment
            wcs, wos = np.array([h[0] for h in keep]), np.array([h[1] for h in keep])
            Sc, Ao, B, mc = _reestimate(self.model, wcs, wos, Sc0, Ao0, B0)
            mt = (wos - np.einsum("mik,tck->tcmi", B, wcs - wc0)).reshape(-1, m, 7).mean(axis=0)
            if self.mix is not None:  # an object with several modes keeps its MAP mode's blocks (its
                several = np.array([len(modes) > 1 for modes in self.found])  # draws span every mode)
                Ao[several], B[several], mt[several] = Ao0[several], B0[several], wo0[several]
            wc, wo = seg.target.working(state.coords)
            seg = _Run(self.model, self.T, s, wc0, Sc, Ao, B, mc, mt, adapt=True, modes=self.mix)
            seg.kernel.calls = done // 2  # the scales' adaptation rate goes on falling
            state = seg.state(wc, wo, state.random_state)
            hist = []
        seg.kernel.adapt = False
        self.seg, self.state = seg, state
        return s.warmup

    def run(self, steps: int):
        for self.state in self.seg.run(self.state, steps):
            yield self.state.coords, self.state.log_prob

    def natural(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cameras (n, C, 5) and objects (n, C, m, 7) of states (n, C, d)."""
        cams, objs = self.seg.target.natural(u.reshape(-1, u.shape[-1]))
        return cams.reshape(u.shape[:2] + (5,)), objs.reshape(u.shape[:2] + objs.shape[1:])

    def acceptance(self) -> tuple[float, float, float]:
        return tuple(float(np.mean(self.seg.kernel.accepted[k])) for k in ("all", "camera", "objects"))

    def report(self, draws: Draws) -> dict:
        """The objects' modes (:func:`_object_mode_report`) and a mode denser than the MAP's."""
        if self.mix is None:
            return {}
        wc0, wo0 = self.start[:2]
        info = {"mode_report": _object_mode_report(self.model, self.found, draws, wc0, wo0)}
        denser = [(i, max(modes, key=lambda k: k.log_prob)) for i, modes in enumerate(self.found) if len(modes) > 1]
        denser = [(i, k) for i, k in denser if k.log_prob > self.found[i][0].log_prob + 1.0]
        if denser:  # an object's mode denser than the MAP's: the pipeline refines the MAP from there
            wo = wo0.copy()
            for i, k in denser:
                wo[i] = k.center
            c, o = WorkingCoords(self.model).from_work(wc0[None], wo[None])
            info["denser_mode"] = (c[0], o[0])
        return info


class _Whole:
    """The whole free vector by the ensemble kernel (module docstring), after a search for the
    joint posterior's modes; a mode denser than the MAP's becomes the centre."""

    def __init__(self, model, start, s: SamplerSettings, rng, temperature, map_est):
        from .ensemble import Ensemble
        from .modes import MIN_SHARE, find_modes

        wc0, wo0, Sc, Ao, B, _ = start
        self.model = model
        cf, of = model.camera_free, model.object_free
        target = self.target = BlockTarget(model, temperature, wc0, np.zeros_like(B), wo0, yaw_window=wo0[:, O_YAW])
        free = np.concatenate([cf, of.ravel()])
        flat = np.cumsum(free) - 1
        circular = [int(flat[5 + 7 * i + O_YAW]) for i in range(model.n_objects) if of[i, O_YAW]] or None
        hd = self.hd = HorizonDistance.of(model)  # pitch as the log of the first object's distance below the horizon
        self.to_u = (lambda q: q) if hd is None else hd.inverse
        log_prob = target if hd is None else (lambda q: target(hd.inverse(q)) + hd.log_jacobian(q))

        def in_q(u, cov_u):  # a point and its covariance, in the sampled coordinates
            if hd is None:
                return u, cov_u
            J = np.column_stack([(hd.forward(u + 1e-6 * e) - hd.forward(u - 1e-6 * e))[0] / 2e-6
                                 for e in np.eye(len(u))])
            return hd.forward(u[None])[0], J @ cov_u @ J.T

        center, cov = in_q(target.join(wc0[None], wo0[None])[0], _joint_cov(Sc, Ao, B, free))
        modes = []
        if s.mode_search:
            side = np.random.default_rng(np.random.SeedSequence(rng.bit_generator.seed_seq.entropy, spawn_key=tuple(
                rng.bit_generator.seed_seq.spawn_key) + (2**31 + 19,), pool_size=rng.bit_generator.seed_seq.pool_size))
            laplace_q = lambda c: in_q(self.to_u(c[None])[0], _whole_cov(model, target, self.to_u(c[None])[0],  # noqa: E731
                                                                         temperature, free))[1]
            others = [in_q(target.join(*WorkingCoords(model).to_work(c[None], o[None]))[0], cov)[0]
                      for c, o, h in map_est.others if np.array_equal(h, map_est.handedness)]
            others = [u for u in others if circular is None or np.all(np.abs(u[circular] - center[circular]) < np.pi)]
            modes = find_modes(log_prob, center, cov, laplace=laplace_q, rng=side, circular=circular,
                               extra_starts=np.array(others) if others else None)
        self.better = None
        if len(modes) > 1:  # a denser mode than the MAP's becomes the centre; modes with no mass go
            lp = log_prob(np.array([m.center for m in modes]))
            if lp.max() > lp[0] + 1.0:
                self.better = modes[int(np.argmax(lp))]
                modes = [self.better] + [m for m in modes if m is not self.better and m.share >= MIN_SHARE]
                center, cov = self.better.center, self.better.cov
        self.modes = modes
        self.kernel = Ensemble(log_prob, center, cov, settings=s, rng=rng,
                               modes=[(m.center, m.cov) for m in modes[1:]])
        self.n_chains, self.walkers = self.kernel.n_chains, self.kernel.walkers

    def tune(self, bar) -> int:
        return self.kernel.tune(bar)

    def run(self, steps: int):
        for q, lp in self.kernel.run(steps):  # the log-density in working coordinates
            yield q, lp if self.hd is None else lp - self.hd.log_jacobian(q)

    def natural(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cams, objs = self.target.natural(self.to_u(q.reshape(-1, q.shape[-1])))
        return cams.reshape(q.shape[:2] + (5,)), objs.reshape(q.shape[:2] + objs.shape[1:])

    def acceptance(self) -> tuple[float, float, float]:
        return (self.kernel.acceptance(),) * 3  # moves of the whole vector move every block at once

    def report(self, draws: Draws) -> dict:
        """The modes found (:func:`_mode_report`) and a mode denser than the MAP's."""
        info = {}
        if len(self.modes) > 1:
            C, N = draws.cameras.shape[:2]
            wc, wo = WorkingCoords(self.model).to_work(draws.cameras.reshape(-1, 5),
                                                       draws.objects.reshape((C * N,) + draws.objects.shape[2:]))
            q = self.target.join(wc, wo)
            near = self.kernel.nearest_mode(q if self.hd is None else self.hd.forward(q)).reshape(C, N)
            info["mode_report"] = _mode_report(self.modes, self.target, self.to_u, near)
        if self.better is not None:  # a mode denser than the MAP: the pipeline refines the MAP from there
            c, o = self.target.natural(self.to_u(self.better.center[None]))
            info["denser_mode"] = (c[0], o[0])
        return info


def _whole_cov(model, target: BlockTarget, u: np.ndarray, temperature: float, free: np.ndarray) -> np.ndarray:
    """The Laplace covariance of the free working coordinates at a state ``u`` (another mode)."""
    wc, wo = target.working(u[None])
    Sc, Ao, B, _ = laplace_blocks(model, derivatives(model, wc[0], wo[0], temperature, with_jacobian=True))
    return _joint_cov(Sc, Ao, B, free)


def _joint_cov(Sc, Ao, B, free: np.ndarray) -> np.ndarray:
    """The Laplace covariance of a scene's free coordinates, whole (the camera, then each object),
    from its blocks: the objects ride on the camera by their shear ``B``."""
    J = np.vstack([np.eye(5), B.reshape(-1, 5)])
    return (J @ Sc @ J.T + block_diag(np.zeros((5, 5)), *Ao))[np.ix_(free, free)]


def _mode_rows(target_id, objs: np.ndarray, lp, modes, near: np.ndarray) -> list[dict]:
    """A row per mode (``objs`` (k, 7) the object's natural parameters there, ``lp`` (k,) the
    log-density, ``near`` (chain, draw) each draw's nearest mode): the object's id, distance and
    yaw, how far below the MAP's the mode's log-density is, its Laplace share of the mass and the
    share of each chain's draws nearest to it (they should agree)."""
    return [{"target": target_id, "distance_m": float(np.hypot(objs[k, 0], objs[k, 1])), "yaw": float(objs[k, O_YAW]),
             "log_density_below_map": float(lp[0] - lp[k]), "laplace_share": float(mode.share),
             "draw_share_per_chain": [float(np.mean(g == k)) for g in near]} for k, mode in enumerate(modes)]


def _mode_report(modes, target: BlockTarget, to_u, near) -> list[dict]:
    """:func:`_mode_rows` of the modes found before sampling, for the object whose distance
    differs most between them."""
    centers = to_u(np.array([m.center for m in modes]))
    _, objs = target.natural(centers)
    i = int(np.argmax(np.ptp(np.log(np.hypot(objs[..., 0], objs[..., 1])), axis=0)))
    return _mode_rows(target.model.objects[i].id, objs[:, i], target(centers), modes, near)


def _object_modes(model, temperature, s: SamplerSettings, wc0, wo0, Sc, Ao, B):
    """Each object's modes given the MAP's camera (:func:`.modes.object_modes`), or each its
    MAP's alone without ``mode_search``."""
    from .modes import Mode, object_modes

    if not s.mode_search:
        return [[Mode(wo0[i], Ao[i], 0.0, 1.0)] for i in range(model.n_objects)]
    return object_modes(BlockTarget(model, temperature, wc0, B, np.zeros_like(wo0)), wc0, wo0, Ao, temperature)


#: Least weight of each mode's component in an object's independence proposal (so that the
#: proposal keeps offering every mode, whatever its Laplace share).
MIN_MODE_WEIGHT = 0.1


def _mixture(model, found, B):
    """The objects' other modes as :class:`~.moves.BlockKernel` takes them (weights (m, 1 + E),
    centres (m, E, 7), Cholesky factors (m, E, 7, 7), and how each centre moves with the camera in
    the sampler's coordinates (m, E, 7, 5), ``B`` (m, 7, 5) their shear), or None when no object
    has another."""
    E = max(len(modes) for modes in found) - 1
    if E == 0:
        return None
    m = model.n_objects
    w, centres, L, shear = np.zeros((m, 1 + E)), np.zeros((m, E, 7)), np.zeros((m, E, 7, 7)), np.zeros((m, E, 7, 5))
    for i, modes in enumerate(found):
        share = np.maximum([k.share for k in modes], MIN_MODE_WEIGHT)
        w[i, :len(modes)] = share / share.sum()
        for k, mode in enumerate(modes[1:]):
            centres[i, k], L[i, k] = mode.center, _chol(mode.cov, model.object_free[i])
            shear[i, k] = (mode.shear - B[i]) * model.object_free[i][:, None] * model.camera_free[None]
    return w, centres, L, shear


def _object_mode_report(model, found, draws: Draws, wc0, wo0) -> list[dict]:
    """:func:`_mode_rows` of each object with several modes (each draw's nearest in the mode's own
    Laplace metric; shares given the camera)."""
    coords = WorkingCoords(model)
    out = []
    for i, modes in enumerate(found):
        if len(modes) < 2:
            continue
        free = model.object_free[i]
        wo = np.repeat(wo0[None], len(modes), axis=0)
        wo[:, i] = [k.center for k in modes]
        _, objs = coords.from_work(np.repeat(wc0[None], len(modes), axis=0), wo)
        C, N = draws.objects.shape[:2]
        x = coords.to_work(draws.cameras.reshape(-1, 5), draws.objects.reshape(C * N, -1, 7))[1][:, i][:, free]
        dist = np.stack([np.einsum("ni,ij,nj->n", x - k.center[free], np.linalg.pinv(k.cov[np.ix_(free, free)]),
                                   x - k.center[free]) for k in modes], axis=1)
        out += _mode_rows(model.objects[i].id, objs[:, i], [k.log_prob for k in modes], modes,
                          np.argmin(dist, axis=1).reshape(C, N))
    return out


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


def _diagnose(arr: np.ndarray, names: list[str], s: SamplerSettings, steps: int, rhat_bar: float) -> dict:
    """Bulk ESS and rank-normalised R-hat of every column of ``arr``; whether the stopping rule
    is met (never before :data:`MIN_STEPS` steps; R-hat at most ``rhat_bar``)."""
    eb, rh = ess_bulk_rhat(arr)
    why = [] if steps >= MIN_STEPS else [f"{steps} steps < {MIN_STEPS}, too few to measure the ESS"]
    if np.nanmin(eb) < s.min_ess:
        k = int(np.nanargmin(eb))
        why.append(f"bulk ESS of {names[k]} {eb[k]:.0f} < {s.min_ess:g}")
    if np.nanmax(rh) > rhat_bar:
        k = int(np.nanargmax(rh))
        why.append(f"R-hat of {names[k]} {rh[k]:.3f} > {rhat_bar:.3f}")
    return {"ok": not why, "why": why, "min_ess": float(np.nanmin(eb)), "max_rhat": float(np.nanmax(rh)),
            "rhat_bar": rhat_bar,
            "ess_bulk": dict(zip(names, eb.tolist())), "r_hat": dict(zip(names, rh.tolist()))}
