"""The sampler's settings, and the main phase of every kernel to one stopping rule
(:func:`run_chains`; docs/inference.md, "Stopping")."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .diagnostics import ess_bulk_rhat, rhat_split_raw

__all__ = ["SamplingError", "SamplerSettings", "Draws", "run_chains"]


#: Steps kept per walker (older ones thinned by two when twice as many are kept).
MAX_DRAWS = 2000
#: Steps of the main phase before the stopping rule may be met: a chain of an ensemble's walkers
#: laid end to end shows the ESS estimator only correlations within each walker's own run, so a
#: run shorter than the walkers' autocorrelation would over-state the ESS.
MIN_STEPS = 50
#: A later chunk is at least the run so far over this (and ``chunk``): it aims at the length the last
#: check asks for (docs/inference.md, "Stopping"), not at the first chunk's length again.
LATER_SHARE = 4
#: The least ESS the default R-hat bar is computed at (:meth:`SamplerSettings.rhat_bar`).
RHAT_ESS = 400.0


class SamplingError(RuntimeError):
    """The sampler cannot start (the MAP has zero posterior density)."""


@dataclass(frozen=True)
class SamplerSettings:
    """Settings of :func:`.sampler.sample` (unknown keys of a user's dict are rejected: :meth:`from_options`).

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
    """Posterior draws in natural parameters: cameras (chain, draw, 5), objects (chain, draw, m, 7),
    the log-density of each (chain, draw) in the sampler's coordinates and, where it varies, each
    draw's handedness."""

    cameras: np.ndarray
    objects: np.ndarray
    log_prob: np.ndarray | None = None
    #: each draw's handedness of every object (chain, draw, m) where both of a target's were
    #: sampled (:mod:`.whole`), else None (the MAP's throughout)
    handedness: np.ndarray | None = None


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
        chunk = int(np.clip(1.2 * need - it, max(s.chunk, it // LATER_SHARE), 2 * it))
    return tuple(_by_chain(a, w) for a in arrays), _by_chain(lps, w), it, thin, diag


def _by_chain(a: np.ndarray, walkers: int) -> np.ndarray:
    """Kept steps of the walkers (n, S, …) as chains (S / walkers, walkers · n, …): each chain's
    walkers' draws laid end to end, walker after walker."""
    n, S = a.shape[:2]
    return np.swapaxes(a, 0, 1).reshape((S // walkers, walkers * n) + a.shape[2:])


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
