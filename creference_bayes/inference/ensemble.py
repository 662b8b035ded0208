"""The ensemble kernel: emcee's differential-evolution and stretch moves over a whole vector, in
coordinates learned during warm-up, with an independence proposal fitted to the walkers.

It moves any vectorised ``log_prob((n, ndim)) → (n,)`` from a point and a covariance (the MAP and
its Laplace approximation); :mod:`.sampler` runs it for a model of one object block. Groups,
start, warm-up stages and moves: docs/inference.md, "One object block". ``n_ensembles`` groups of
``n_walkers`` walkers share one vectorised log-probability call, but a walker's partners come from
its own group only (:mod:`.moves`), so each group is an independent chain of the driver. A
log-probability of NaN or ±∞ is taken as −∞ and counted in ``info["nonfinite"]``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.special import logsumexp

from .chains import SamplerSettings, SamplingError, run_chains
from .emcee_moves import EnsembleSampler, GroupedDEMove, GroupedStretchMove, IndependenceMove, State
from .reparam import Coordinates

__all__ = ["Ensemble", "Chains", "sample", "explore", "fit_mixture"]


#: Cap on warm-up steps.
MAX_WARMUP = 5000
#: Warm-up goes on while the independence proposal is accepted less often than this.
MIN_INDEPENDENCE_ACCEPTANCE = 0.15
#: Degrees of freedom and scale inflation of the independence proposal's t components.
PROPOSAL_DF, PROPOSAL_SCALE = 6.0, 1.2
#: Points of the warm-up sample the k-means and EM fit of that mixture use (evenly thinned).
MIXTURE_POINTS = 3000
#: Weight of the whole sample's t in a proposal mixture fitted to k-means centres
#: (:func:`_fit_proposal`).
DEFENSIVE_WEIGHT = 0.2


class _SafeLogProb:
    """Wraps a vectorised log-probability: NaN and ±∞ become −∞, and are counted."""

    def __init__(self, log_prob):
        self.log_prob = log_prob
        self.nonfinite = 0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.atleast_2d(p)
        with np.errstate(all="ignore"):
            lp = np.asarray(self.log_prob(p), float).reshape(len(p))
        bad = ~np.isfinite(lp)
        if bad.any():
            self.nonfinite += int(np.sum(bad & ~np.isneginf(lp)))
            lp = np.where(bad, -np.inf, lp)
        return lp


def _in_space(safe: _SafeLogProb, coords: Coordinates):
    """The log-probability in sampler coordinates (the map's Jacobian is constant)."""
    return lambda u: safe(coords.inverse(np.atleast_2d(u)))


def _initial_points(safe, starts, rngs, n_walkers, max_tries: int = 200,
                    max_halvings: int = 100) -> np.ndarray:
    """(n_ens · n_walkers, d) starting points with finite log-probability, one generator each;
    ensemble g is drawn from N(centre, cov) of ``starts[g % len(starts)]``.

    Points of log-probability −∞ are redrawn (the cloud halved every 20 tries); those still
    outside after ``max_tries`` are pulled towards the centre, halving their offset up to
    ``max_halvings`` times (a centre just inside two coupled bounds leaves a wedge too thin for
    redraws to hit)."""
    out = []
    for k, g in enumerate(rngs):
        center, cov = starts[k % len(starts)]
        L = np.linalg.cholesky(cov)
        pts = center + g.standard_normal((n_walkers, len(center))) @ L.T
        lp = safe(pts)
        shrink = 1.0
        for attempt in range(max_tries + max_halvings):
            bad = ~np.isfinite(lp)
            if not bad.any():
                break
            if attempt < max_tries:
                if attempt and attempt % 20 == 0:
                    shrink *= 0.5
                pts[bad] = center + shrink * g.standard_normal((bad.sum(), len(center))) @ L.T
            else:
                pts[bad] = center + 0.5 * (pts[bad] - center)
            lp[bad] = safe(pts[bad])
        else:
            raise SamplingError(f"could not draw {n_walkers} starting points with finite "
                                f"log-probability around the start in {max_tries} tries and "
                                f"{max_halvings} halvings towards it")
        out.append(pts)
    return np.vstack(out)


def _moves(settings: SamplerSettings, proposal: IndependenceMove | None):
    g = settings.n_ensembles
    local = [(GroupedDEMove(g), 0.8), (GroupedStretchMove(g), 0.2)]
    if proposal is None:
        return local
    w = 0.8 if settings.independence_weight is None else settings.independence_weight
    return [(proposal, w)] + [(m, (1.0 - w) * p) for m, p in local]


def _fit_proposal(u: np.ndarray, settings: SamplerSettings, centers=None,
                  rng=None) -> IndependenceMove | None:
    """The independence proposal fitted to a sample ``u`` (n, d) in sampler coordinates, or None.

    With several modes (``centers`` (k, d)) a mixture with a component per mode the sample still
    holds (:func:`fit_mixture`); otherwise up to ``proposal_components`` components from
    k-means centres (seeded by ``rng``) plus the whole sample's t at :data:`DEFENSIVE_WEIGHT` (a
    defensive mixture), or the single t. Fits use :data:`MIXTURE_POINTS` of the sample."""
    if settings.independence_weight == 0.0:
        return None
    defensive, fit_to = False, u
    if centers is None or len(centers) < 2:
        defensive, fit_to = True, _thinned(u)
        k = min(settings.proposal_components, len(u) // (4 * u.shape[1] + 4))
        centers = _kmeans_centres(fit_to, k, rng) if k >= 2 else None
    if centers is not None and len(centers) > 1:
        weights, means, covs = fit_mixture(fit_to, centers)
        if len(weights) > 1 and defensive:  # the whole sample's t as one more component
            weights = np.append((1.0 - DEFENSIVE_WEIGHT) * weights, DEFENSIVE_WEIGHT)
            means = np.vstack([means, u.mean(axis=0)])
            covs = np.concatenate([covs, np.atleast_2d(np.cov(u.T))[None]])
        if len(weights) > 1:
            try:
                chols = np.linalg.cholesky(covs * PROPOSAL_SCALE**2)
                return IndependenceMove(means, chols, PROPOSAL_DF, weights=weights,
                                        tries=settings.tries)
            except np.linalg.LinAlgError:
                pass
    cov = np.atleast_2d(np.cov(u.T)) * PROPOSAL_SCALE**2
    try:
        return IndependenceMove(u.mean(axis=0), np.linalg.cholesky(cov), PROPOSAL_DF,
                                tries=settings.tries)
    except np.linalg.LinAlgError:
        return None


def _thinned(u: np.ndarray, most: int = MIXTURE_POINTS) -> np.ndarray:
    """At most ``most`` rows of ``u``, evenly spaced (the walkers' successive steps are
    correlated: thinning them costs the fit little and saves most of its time)."""
    return u if len(u) <= most else u[np.linspace(0, len(u) - 1, most).astype(int)]


def _kmeans_centres(u: np.ndarray, k: int, rng) -> np.ndarray | None:
    """``k`` k-means centres of the sample ``u`` (n, d) (k-means++ start, seeded by ``rng``, by 0
    when it is None), or None when the sample is degenerate."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an empty cluster: fit_mixture drops it
        try:
            centres, _ = kmeans2(u, k, minit="++", seed=np.random.default_rng(0 if rng is None else rng))
        except (ValueError, np.linalg.LinAlgError):
            return None
    return centres if np.all(np.isfinite(centres)) else None


def _location_spread(u: np.ndarray, loose: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per-coordinate centre and spreads of a sample (n, d), as :func:`_stable` measures them:
    the median, and the interquartile and 5–95 % ranges over a normal's (1.349 and 3.290),
    (2, d); or with ``loose`` the mean and the standard deviation (1, d)."""
    if loose:
        return u.mean(axis=0), u.std(axis=0)[None]
    q5, q25, centre, q75, q95 = np.percentile(u, [5, 25, 50, 75, 95], axis=0)
    return centre, np.stack([(q75 - q25) / 1.349, (q95 - q5) / 3.290])


def _stable(u: np.ndarray, loose: bool = False, reference=None) -> bool:
    """Whether a stage's second half, in the coordinates fitted before it, still looks like the
    sample those coordinates were fitted to (``reference``: its :func:`_location_spread`; None: a
    normal's): each coordinate's centre within 0.3 whitened units and each spread within a factor
    1.33. Quantiles, not moments: a heavy-tailed posterior's standard deviation never settles.
    ``loose`` (several modes, whose shares fluctuate between stages): 0.5 and 2, on the mean and
    standard deviation (a mixture's median sits in its heaviest mode)."""
    centre, sd = _location_spread(u, loose)
    ref_centre, ref_sd = (0.0, 1.0) if reference is None else reference
    m_max, sd_max = (0.5, 2.0) if loose else (0.3, 1.33)
    ratio = sd / ref_sd
    return bool(np.all(np.abs(centre - ref_centre) < m_max)
                and np.all((ratio > 1 / sd_max) & (ratio < sd_max)))


class Ensemble:
    """The ensemble kernel (module docstring) on ``log_prob`` from ``center``: :meth:`tune` is its
    warm-up, :meth:`run` its steps; ``n_chains`` groups of ``walkers`` walkers, each a chain.

    ``log_prob``: (n, ndim) → (n,), NaN and ±∞ taken as −∞; ``center`` (ndim,): a point of finite
    density (the MAP); ``cov``: the starting cloud's covariance (default 0.01² · I); ``modes``:
    further (centre, covariance) pairs (:func:`.modes.find_modes`): group g starts in mode
    g mod (1 + len(modes)), the independence proposal has a component per mode and the map is
    affine. Raises :class:`SamplingError` when ``center`` or every starting point has density 0.
    """

    def __init__(self, log_prob, center, cov=None, *, settings: SamplerSettings | None = None, rng=None,
                 modes=None):
        s = self.s = settings or SamplerSettings()
        rng = np.random.default_rng(rng)
        center = np.atleast_1d(np.asarray(center, float))
        d = len(center)
        if s.n_walkers < 2 * d:
            raise ValueError(f"sampling.n_walkers: expected ≥ 2·ndim = {2 * d}, got {s.n_walkers}")
        cov = np.eye(d) * 1e-4 if cov is None else np.asarray(cov, float).reshape(d, d)
        self.safe = _SafeLogProb(log_prob)
        if not np.isfinite(self.safe(center[None])[0]):
            raise SamplingError("the starting point has log-probability −∞ (or NaN)")
        starts = [(center, cov)] + [(np.asarray(c, float).reshape(d), np.asarray(v, float).reshape(d, d))
                                    for c, v in (modes or [])]
        self.centers = np.array([c for c, _ in starts]) if len(starts) > 1 else None
        self.pos = _initial_points(self.safe, starts, rng.spawn(s.n_ensembles), s.n_walkers)
        self.rstate = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
        self.fit_rng = rng.spawn(1)[0]  # the proposal's k-means seeds (spawning leaves rng's draws alone)
        self.coords = Coordinates.affine(center, cov)
        self.n_chains, self.walkers = s.n_ensembles, s.n_walkers
        self.moved: list = []
        self.info: dict = {"warmup_stages": [], "reparametrised": False}

    def tune(self, bar, on_stage=None) -> int:
        """The warm-up: stages, the coordinates and the proposal refitted after each, until a stage
        run in the coordinates fitted before it looks like the sample they were fitted to and the
        proposal is accepted often enough (or :data:`MAX_WARMUP`); returns its steps. ``on_stage``
        (or None) is called with each stage's second half (n, ndim), before the next stage's
        log-densities are computed (the target may change in place)."""
        s, safe, coords, centers, info = self.s, self.safe, self.coords, self.centers, self.info
        pos, rstate, d = self.pos, self.rstate, self.pos.shape[1]
        proposal, n_warm, stage, stable, reference = None, 0, s.stage, False, None
        while not stable and n_warm < MAX_WARMUP:
            stage = min(stage, MAX_WARMUP - n_warm)
            sampler, state = _run(safe, coords, _moves(s, proposal), pos, rstate)
            done = 0
            while done < stage:  # in chunks: a stage already whitened ends early (below)
                state = sampler.run_mcmc(state, min(s.chunk, stage - done), skip_initial_state_check=True)
                done = sampler.iteration
                if done < min(stage, 2 * s.stage):
                    continue  # too short to be judged before its end
                tail_u = sampler.get_chain(discard=done // 2).reshape(-1, d)
                indep = proposal.acceptance if proposal is not None else float("nan")
                stable = info["reparametrised"] and _stable(tail_u, centers is not None, reference) and (
                    proposal is None or indep >= MIN_INDEPENDENCE_ACCEPTANCE)
                if stable:
                    break
            pos, rstate = coords.inverse(state.coords), state.random_state
            stage = done
            n_warm += stage
            info["warmup_stages"].append(stage)
            bar.update(stage)
            tail_p = coords.inverse(tail_u)
            if on_stage is not None:
                on_stage(tail_p)
            try:
                coords = Coordinates.fit(tail_p, shear=centers is None)
                fitted = coords.forward(tail_p)
                proposal = _fit_proposal(fitted, s, None if centers is None else coords.forward(centers), self.fit_rng)
                reference = _location_spread(fitted, centers is not None)
                info["reparametrised"] = True
            except np.linalg.LinAlgError:
                break  # nothing to learn from a degenerate sample: go on as we are
            if len(info["warmup_stages"]) >= 2:
                stage *= 2
        self.coords = coords
        self.sampler, self.state = _run(safe, coords, _moves(s, proposal), pos, rstate)
        return sum(info["warmup_stages"])

    def run(self, steps: int):
        """Yield the walkers' parameters (n_chains · walkers, ndim) and log-density there after each of
        ``steps`` steps."""
        for state in self.sampler.sample(self.state, iterations=steps, store=False, skip_initial_state_check=True):
            p = self.coords.inverse(state.coords)
            self.moved.append(float(np.mean(np.any(state.coords != self.state.coords, axis=1))))
            self.state = State(state, copy=True)
            yield p, state.log_prob

    def acceptance(self) -> float:
        """The share of a walker's steps that moved it."""
        return float(np.mean(self.moved)) if self.moved else float("nan")

    def nearest_mode(self, p: np.ndarray) -> np.ndarray:
        """Which mode each point p (..., ndim) is nearest to, in the kernel's coordinates."""
        u = self.coords.forward(p)
        return np.argmin(((u[..., None, :] - self.coords.forward(self.centers)) ** 2).sum(-1), axis=-1)


@dataclass(frozen=True)
class Chains:
    """What :func:`sample` returns: draws (chain, draw, ndim) (a chain per group, its walkers end to
    end), their log-density (chain, draw), steps of warm-up and of the main phase, the thinning,
    whether the stopping rule was met, its diagnostics and the kernel's ``info``."""

    draws: np.ndarray
    log_prob: np.ndarray
    warmup_steps: int
    n_steps: int
    thin: int
    converged: bool
    diagnostics: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def sample(log_prob, center, cov=None, *, settings: SamplerSettings | None = None, rng=None,
           modes=None) -> Chains:
    """Sample ``log_prob`` by the ensemble kernel (:class:`Ensemble`, the same parameters) under
    the driver's stopping rule (:func:`.sampler.run_chains`: bulk ESS and rank R-hat of every
    parameter over the groups)."""
    kernel = Ensemble(log_prob, center, cov, settings=settings, rng=rng, modes=modes)
    from .progress import progress_bar

    with progress_bar(False, 0) as bar:
        warm = kernel.tune(bar)
        (p,), lp, it, thin, diag = run_chains(kernel, lambda x: (x,), lambda x: (x, [
            f"x[{k}]" for k in range(x.shape[-1])]), kernel.s, bar)
    kernel.info["nonfinite"] = kernel.safe.nonfinite
    if kernel.centers is not None:  # the share of each chain's draws nearest each mode
        near = kernel.nearest_mode(p)
        kernel.info["mode_shares"] = [[float(np.mean(near[c] == k)) for k in range(len(kernel.centers))]
                                      for c in range(len(p))]
    return Chains(p, lp, warm, it, thin, diag["ok"], diag, kernel.info)


def explore(log_prob, coords: Coordinates, rng, *, temperature: float = 3.0, n_steps: int = 150,
            n_walkers: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A short ensemble run on the tempered density p^(1/T), for finding modes (:mod:`.modes`):
    ``n_walkers`` (even, ≥ 2·d) walkers start from N(0, I) in ``coords`` (sampler coordinates) and
    run ``n_steps`` steps. Returns the second half of the run in ``coords`` (n, d) and the
    untempered log-density there (n,)."""
    safe = _SafeLogProb(log_prob)
    in_space = _in_space(safe, coords)
    d = len(coords.m)
    n_walkers = max(n_walkers + n_walkers % 2, 2 * d)
    u0 = _initial_points(in_space, [(np.zeros(d), np.eye(d))], [rng], n_walkers)
    sampler = EnsembleSampler(n_walkers, d, lambda u: in_space(u) / temperature, vectorize=True,
                                    moves=[(GroupedDEMove(1), 0.8), (GroupedStretchMove(1), 0.2)])
    rstate = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
    sampler.run_mcmc(State(u0, random_state=rstate), n_steps, skip_initial_state_check=True)
    half = n_steps // 2
    return (sampler.get_chain(discard=half).reshape(-1, d),
            temperature * sampler.get_log_prob(discard=half).ravel())


def _run(safe, coords, moves, pos, rstate):
    """A fresh EnsembleSampler in ``coords`` and its state at parameters ``pos``."""
    nw, d = pos.shape
    sampler = EnsembleSampler(nw, d, _in_space(safe, coords), moves=moves, vectorize=True)
    return sampler, State(coords.forward(pos), random_state=rstate)


def fit_mixture(u: np.ndarray, centers: np.ndarray, *, n_iter: int = 10, min_weight: float = 0.05):
    """A Gaussian mixture fitted to a sample ``u`` (n, d) by ``n_iter`` EM iterations, a component
    per mode, started at ``centers`` (k, d) (the same coordinates). Returns weights (k',) (floored
    at ``min_weight`` over the components, so that the proposal keeps offering every mode), means
    (k', d) and covariances (k', d, d) of the components that keep at least 2·d + 2 points
    (k' ≤ k; k' may be 1)."""
    n, d = u.shape
    means = np.asarray(centers, float).copy()
    resp = np.zeros((n, len(means)))
    resp[np.arange(n), np.argmin(((u[:, None, :] - means[None]) ** 2).sum(-1), axis=1)] = 1.0
    covs = None
    for _ in range(n_iter):
        nk = resp.sum(axis=0)
        alive = nk >= 2 * d + 2
        if not alive.any():
            break
        resp, nk = resp[:, alive], nk[alive]
        means = (resp.T @ u) / nk[:, None]
        covs = np.stack([((resp[:, k, None] * (u - means[k])).T @ (u - means[k])) / nk[k]
                         + 1e-9 * np.eye(d) for k in range(len(nk))])
        weights = nk / n
        resp = np.exp(_log_resp(u, weights, means, covs))
    if covs is None:
        m = u.mean(axis=0)
        return np.ones(1), m[None], np.atleast_2d(np.cov(u.T))[None]
    weights = np.maximum(resp.sum(axis=0) / n, min_weight / len(means))
    return weights / weights.sum(), means, covs


def _log_resp(u, weights, means, covs) -> np.ndarray:
    """(n, k) log responsibilities of the components."""
    logs = []
    for w, m, c in zip(weights, means, covs):
        L = np.linalg.cholesky(c)
        z = np.linalg.solve(L, (u - m).T)
        logs.append(np.log(w) - np.sum(np.log(np.diag(L))) - 0.5 * np.sum(z * z, axis=0))
    logs = np.column_stack(logs)
    return logs - logsumexp(logs, axis=1, keepdims=True)
