"""Sampling a log-posterior with emcee: several independent ensembles, seeded, run to convergence.

The emcee adapter. It knows nothing of cameras or boxes: it samples any vectorised
``log_prob((n, ndim)) → (n,)`` from a starting point and a covariance (the MAP and its Laplace
approximation). :mod:`.sampler` uses it for a scene with one object block.

How it samples (docs/inference.md, "One object: the whole vector by ensemble moves")
--------------
* **Independent ensembles.** ``n_ensembles`` ensembles of ``n_walkers`` walkers share one
  :class:`emcee.EnsembleSampler` (one vectorised log-probability call), but their moves
  (:mod:`.moves`) draw partners only from the walker's own ensemble, so each ensemble is an
  independent Markov chain and R-hat across them is meaningful.
* **Start.** Each ensemble's walkers are drawn from N(centre, cov) with its own generator
  (spawned from ``rng``); points of log-probability −∞ are redrawn.
* **Warm-up.** In stages (``stage`` steps, later ones doubled) the sampler fits a map to the
  walkers (:class:`~.reparam.Coordinates`: logarithms, a whitening and a unit-Jacobian shear that
  straightens curved ridges) and an independence proposal (:func:`_fit_proposal`), until a stage
  run in the map fitted before it looks like the sample the map was fitted to (:func:`_stable`)
  and the proposal is accepted often enough. A stage is judged every ``chunk`` steps on the
  second half of what it has run, and ends once it passes after 2 · ``stage`` steps. Warm-up
  draws are discarded; the map and the proposal are then frozen. A first main chunk with a large
  τ becomes one more warm-up stage (at most ``max_retunes`` times).
* **Main phase.** The independence proposal (:class:`~.moves.IndependenceMove`, ``tries``
  proposals per walker by multiple-try Metropolis) on 80 % of steps, the grouped
  differential-evolution and stretch moves on the rest. It runs in chunks until the chain after
  burn-in is ``tau_multiple`` autocorrelation times long, τ has settled (within
  ``tau_tolerance``), the estimated bulk ESS reaches ``min_ess`` and the rank-normalised split
  R-hat across the ensembles is at most ``max_rhat``, or ``max_steps``. Burn-in is 2·max τ and
  thinning ½·min τ (emcee's advice).
* **Seeding.** Everything random comes from ``rng``: the same seed gives identical draws.
* **Robustness.** A log-probability of NaN or ±∞ is taken as −∞ (the state is rejected) and
  counted in ``Chains.info["nonfinite"]``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import emcee
import numpy as np
from scipy.cluster.vq import kmeans2

from .diagnostics import rhat_rank
from .modes import fit_mixture
from .moves import GroupedDEMove, GroupedStretchMove, IndependenceMove
from .reparam import Coordinates
from .sampler import SamplerSettings

__all__ = ["Chains", "SamplingError", "sample", "explore", "integrated_time"]


#: Points of the warm-up sample the k-means and EM fit of that mixture use (evenly thinned).
MIXTURE_POINTS = 3000
#: Weight of the whole sample's t in a proposal mixture fitted to k-means centres
#: (:func:`_fit_proposal`).
DEFENSIVE_WEIGHT = 0.2


class SamplingError(RuntimeError):
    """The sampler cannot start (for example, the starting point has zero density)."""


def integrated_time(x: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time τ of an ensemble chain.

    The estimator of :func:`emcee.autocorr.integrated_time`: each walker's normalised
    autocorrelation function, averaged over walkers, summed up to Sokal's window (the first lag M
    with M ≥ c·τ(M)). Computed for all walkers and parameters with one real FFT instead of one
    complex FFT per walker and parameter.

    Parameters
    ----------
    x : (n_steps, n_walkers, ndim) or (n_steps, n_walkers)
    c : window constant

    Returns
    -------
    (ndim,) array, or a float for 2-D input; steps. A walker that never moved contributes no
    correlation beyond lag 0.
    """
    x = np.asarray(x, float)
    scalar = x.ndim == 2
    if scalar:
        x = x[..., None]
    if x.ndim != 3 or x.shape[0] < 2:
        raise ValueError(f"integrated_time: expected (n_steps ≥ 2, n_walkers[, ndim]), got {x.shape}")
    n = x.shape[0]
    n_fft = 1 << int(np.ceil(np.log2(2 * n)))
    # a walker that never moved (or moved by rounding only: a derived roll that is constant in
    # exact arithmetic) is exactly zero after centring; its mean can differ from its value in the
    # last bit, and that constant residue would read as perfect correlation
    still = np.ptp(x, axis=0) <= 1e-9 * np.maximum(1.0, np.max(np.abs(x), axis=0))
    centred = np.where(still, 0.0, x - x.mean(axis=0))
    f = np.fft.rfft(centred, n=n_fft, axis=0)
    acf = np.fft.irfft(f.real**2 + f.imag**2, n=n_fft, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = acf / acf[0]
    acf = np.where(np.isfinite(acf), acf, 0.0)
    acf[0] = 1.0
    rho = acf.mean(axis=1)  # (n, ndim)
    taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
    inside = np.arange(n)[:, None] < c * taus
    window = np.where(inside.all(axis=0), n - 1, np.argmin(inside, axis=0))
    tau = taus[window, np.arange(taus.shape[1])]
    return float(tau[0]) if scalar else tau


@dataclass(frozen=True)
class Chains:
    """The main phase of a run.

    Attributes
    ----------
    chain : (n_steps, n_ensembles, n_walkers, ndim) positions, in the parameters of ``log_prob``
    log_prob : (n_steps, n_ensembles, n_walkers)
    burn_in, thin : steps discarded at the start, and the thinning of what is kept
    autocorr_time : (ndim,) integrated autocorrelation time, steps (after burn-in)
    acceptance_fraction : (n_ensembles, n_walkers) over the main phase
    warmup_steps : steps of the discarded warm-up
    converged : the length and ESS criteria were met before ``max_steps``
    seconds : wall time of the whole run
    info : what happened (plain dict): reasons it stopped, non-finite values seen, moves, …
    """

    chain: np.ndarray
    log_prob: np.ndarray
    burn_in: int
    thin: int
    autocorr_time: np.ndarray
    acceptance_fraction: np.ndarray
    warmup_steps: int
    converged: bool
    seconds: float
    info: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return self.chain.shape[0]

    @property
    def n_ensembles(self) -> int:
        return self.chain.shape[1]

    @property
    def n_walkers(self) -> int:
        """Walkers per ensemble."""
        return self.chain.shape[2]

    def draws(self, values: np.ndarray | None = None) -> np.ndarray:
        """Post-burn-in, thinned draws per ensemble, walker-major: (n_ensembles, n_walkers · n_kept,
        ...).

        Each walker's kept steps are contiguous, so the order along the draw axis is a
        concatenation of walker chains (what autocorrelation-based ESS estimates expect).
        """
        v = self.chain if values is None else values
        k = np.moveaxis(v[self.burn_in::self.thin], 0, 2)  # kept: (n_ens, n_walk, n_kept, ...)
        return k.reshape(k.shape[0], k.shape[1] * k.shape[2], *k.shape[3:])


class _SafeLogProb:
    """Wraps a vectorised log-probability: NaN and ±∞ become −∞, and are counted."""

    def __init__(self, log_prob):
        self.log_prob = log_prob
        self.nonfinite = self.calls = self.evaluations = 0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.atleast_2d(p)
        with np.errstate(all="ignore"):
            lp = np.asarray(self.log_prob(p), float).reshape(len(p))
        bad = ~np.isfinite(lp)
        if bad.any():
            self.nonfinite += int(np.sum(bad & ~np.isneginf(lp)))
            lp = np.where(bad, -np.inf, lp)
        self.calls += 1
        self.evaluations += len(p)
        return lp


class _InSpace:
    """log-probability in sampler coordinates: log p(p(u)) + log |∂p/∂u|."""

    def __init__(self, safe: _SafeLogProb, coords: Coordinates):
        self.safe, self.coords = safe, coords

    def __call__(self, u):
        q = self.coords.to_q(np.atleast_2d(u))
        return self.safe(self.coords.q_to_p(q)) + self.coords.log_jacobian(q)


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
    """The independence proposal fitted to a sample ``u`` (n, d) in sampler coordinates.

    With several modes (``centers`` (k, d), k ≥ 2) a mixture with a component per mode that the
    sample still holds (:func:`.modes.fit_mixture`). Otherwise a mixture of up to
    ``settings.proposal_components`` components started from k-means centres of the sample
    (``rng`` seeds them), or a single multivariate t when that is 1 or the mixture keeps one
    component. The k-means and EM fits use :data:`MIXTURE_POINTS` of the sample, evenly thinned.
    The mixture fitted to k-means centres keeps the single t as a component of weight
    :data:`DEFENSIVE_WEIGHT` (a defensive mixture: no tail is offered much less often than by the
    single t, where an independence step's weight p/q could strand a walker). The mixture gives a
    lump that the mode search merged with the MAP a component of its own (docs/inference.md)."""
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
                chols = np.linalg.cholesky(covs * settings.proposal_scale**2)
                return IndependenceMove(means, chols, settings.proposal_df, weights=weights,
                                        tries=settings.tries)
            except np.linalg.LinAlgError:
                pass
    cov = np.atleast_2d(np.cov(u.T)) * settings.proposal_scale**2
    try:
        return IndependenceMove(u.mean(axis=0), np.linalg.cholesky(cov), settings.proposal_df,
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
    sample those coordinates were fitted to.

    ``reference`` is that sample's (centre, spreads) in its own coordinates
    (:func:`_location_spread`); None stands for a normal's. The stage passes when each
    coordinate's centre is within 0.3 (0.5 with ``loose``) of the reference's, in whitened
    units, and each of its spreads within a factor 1.33 (2) of the reference's.

    Quantiles, not moments: a heavy-tailed posterior's standard deviation never settles however
    well the map fits the bulk. Compared with the fitted sample's own, not a normal's: a skewed
    posterior's quartiles stay unlike a normal's in the best of maps. The 5–95 % range catches
    walkers still spreading along a wide posterior.

    ``loose`` (several modes): the walkers' shares of the modes fluctuate between stages and the
    mixture proposal, not the map, does the work, so the tolerance is wider and the mean and
    standard deviation are used (a mixture's median sits in its heaviest mode)."""
    centre, sd = _location_spread(u, loose)
    ref_centre, ref_sd = (0.0, 1.0) if reference is None else reference
    m_max, sd_max = (0.5, 2.0) if loose else (0.3, 1.33)
    ratio = sd / ref_sd
    return bool(np.all(np.abs(centre - ref_centre) < m_max)
                and np.all((ratio > 1 / sd_max) & (ratio < sd_max)))


def _burn_and_tau(chain: np.ndarray, burn_prev: int | None) -> tuple[int, np.ndarray]:
    """Burn-in (2·max τ, at most half the chain) and τ after it; chain (n, walkers, d).

    τ is estimated after the previous check's burn-in (one FFT pass per check); on the first
    check, from the whole chain and then again after the burn-in it implies.
    """
    n = chain.shape[0]
    if n < 4:
        return 0, integrated_time(chain) if n >= 2 else np.ones(chain.shape[2])
    if burn_prev is None:
        burn_prev = int(np.ceil(2.0 * np.max(integrated_time(chain))))
    tau = integrated_time(chain[min(burn_prev, n // 2):])
    return min(int(np.ceil(2.0 * np.max(tau))), n // 2), tau


def sample(log_prob, center, cov=None, *, settings: SamplerSettings | None = None, rng=None,
           log_mask=None, progress: bool = False, modes=None, derived=None) -> Chains:
    """Sample ``log_prob`` with independent emcee ensembles until converged (module docstring).

    Parameters
    ----------
    log_prob : callable, (n, ndim) → (n,) unnormalised log-density; NaN and ±∞ are taken as −∞
    center : (ndim,) a point of high density (the MAP); must have a finite log-density
    cov : (ndim, ndim) covariance of the starting cloud (a Laplace approximation); default
        0.01² · I
    settings : :class:`SamplerSettings`
    rng : seed or ``numpy.random.Generator``
    log_mask : (ndim,) bool, parameters that are always positive and are better sampled as
        logarithms (:mod:`.reparam`); the density is corrected for it
    progress : show a progress bar (tqdm) on standard error
    modes : further modes of the posterior besides ``center`` (:func:`.modes.find_modes`), a
        sequence of (centre (ndim,), covariance (ndim, ndim)). Ensemble g then starts in mode
        g mod (1 + len(modes)), ``center`` being mode 0 (so R-hat across the ensembles tells
        whether they found the same posterior), the independence proposal has a component per
        mode, and the coordinates are affine (one polynomial cannot straighten two modes)
    derived : callable (n, ndim) → (n, k), quantities the result will report (the target's
        distance), or None; the stopping rule wants ``tau_multiple`` autocorrelation times of
        these too (they can mix more slowly than any parameter); their τ goes to
        ``Chains.info["derived_tau"]``

    Returns
    -------
    Chains

    Raises
    ------
    SamplingError : when ``center`` has log-density −∞ or no finite starting points are found
    """
    t0 = time.perf_counter()
    s = settings or SamplerSettings()
    rng = np.random.default_rng(rng)
    center = np.atleast_1d(np.asarray(center, float))
    d = len(center)
    if s.n_walkers < 2 * d:
        raise ValueError(f"sampling.n_walkers: expected ≥ 2·ndim = {2 * d}, got {s.n_walkers}")
    log_mask = np.zeros(d, bool) if log_mask is None else np.asarray(log_mask, bool).reshape(d)
    if np.any(center[log_mask] <= 0):
        raise ValueError("log_mask: a parameter sampled as a logarithm is not positive at the centre")
    cov = np.eye(d) * 1e-4 if cov is None else np.asarray(cov, float).reshape(d, d)
    safe = _SafeLogProb(log_prob)
    if not np.isfinite(safe(center[None])[0]):
        raise SamplingError("the starting point has log-probability −∞ (or NaN)")
    starts = [(center, cov)] + [(np.asarray(c, float).reshape(d), np.asarray(v, float).reshape(d, d))
                                for c, v in (modes or [])]
    centers = np.array([c for c, _ in starts]) if len(starts) > 1 else None
    pos = _initial_points(safe, starts, rng.spawn(s.n_ensembles), s.n_walkers)
    rstate = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
    fit_rng = rng.spawn(1)[0]  # the proposal's k-means seeds (spawning leaves rng's draws alone)
    info: dict = {"warmup_stages": [], "warmup_acceptance": [], "warmup_independence_acceptance": [],
                  "reparametrised": False, "modes": len(starts)}
    from .progress import progress_bar

    with progress_bar(progress, 3 * s.stage + 10 * s.chunk, desc="sampling", unit="step") as bar:
        coords = Coordinates.affine(center, cov, log_mask)
        coords, proposal, pos, rstate = _warmup(safe, coords, log_mask, pos, rstate, s, info, bar,
                                                centers, fit_rng)
        sampler, chain, burn, tau, coords = _main_phase(safe, coords, proposal, pos, rstate, s, info,
                                                        bar, log_mask, centers, derived, fit_rng)
    n, g, k = chain.shape[0], s.n_ensembles, s.n_walkers
    info.update({"nonfinite": safe.nonfinite, "log_prob_calls": safe.calls,
                 "log_prob_evaluations": safe.evaluations,
                 "moves": [type(m).__name__ for m in sampler._moves],
                 "proposal_components": next((m.n_components for m in sampler._moves
                                              if isinstance(m, IndependenceMove)), 0)})
    if centers is not None:  # which mode each kept draw is nearest to, per ensemble
        kept = coords.forward(chain[burn:]).reshape(-1, s.n_ensembles, s.n_walkers, d)
        near = np.argmin(((kept[..., None, :] - coords.forward(centers)) ** 2).sum(-1), axis=-1)
        info["mode_shares"] = [[float(np.mean(near[:, g] == k)) for k in range(len(centers))]
                               for g in range(s.n_ensembles)]
    with np.errstate(divide="ignore"):  # the sampler's log-density includes log |∂p/∂u|
        lp = sampler.get_log_prob() - np.sum(np.log(chain[..., log_mask]), axis=-1)
    return Chains(chain=chain.reshape(n, g, k, d), log_prob=lp.reshape(n, g, k), burn_in=burn,
                  thin=max(1, int(0.5 * np.min(tau))), autocorr_time=tau,
                  acceptance_fraction=sampler.acceptance_fraction.reshape(g, k),
                  warmup_steps=sum(info["warmup_stages"]), converged=info["stopped"] == "converged",
                  seconds=time.perf_counter() - t0, info=info)


def _warmup(safe, coords, log_mask, pos, rstate, s: SamplerSettings, info: dict, bar, centers=None,
            fit_rng=None):
    """Run stages, refitting the coordinates and the proposal after each, until a stage run in
    the coordinates fitted before it looks like the sample they were fitted to and the proposal
    is accepted often enough (or ``max_warmup``). Returns the coordinates, proposal, positions
    and random state."""
    d = pos.shape[1]
    proposal, n_warm, stage, stable, reference = None, 0, s.stage, False, None
    while not stable and n_warm < s.max_warmup:
        stage = min(stage, s.max_warmup - n_warm)
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
                proposal is None or indep >= s.min_independence_acceptance)
            if stable:
                break
        pos, rstate = coords.inverse(state.coords), state.random_state
        stage = done
        n_warm += stage
        info["warmup_stages"].append(stage)
        info["warmup_acceptance"].append(float(np.mean(sampler.acceptance_fraction)))
        info["warmup_independence_acceptance"].append(indep)
        bar.update(stage)
        if not s.adapt:
            break
        try:
            tail_p = coords.inverse(tail_u)
            coords = Coordinates.fit(tail_p, log_mask, shear=centers is None)
            fitted = coords.forward(tail_p)
            proposal = _fit_proposal(fitted, s, _forward(coords, centers), fit_rng)
            reference = _location_spread(fitted, centers is not None)
            info["reparametrised"] = True
        except np.linalg.LinAlgError:
            break  # nothing to learn from a degenerate sample: go on as we are
        if len(info["warmup_stages"]) >= 2:
            stage *= 2
    return coords, proposal, pos, rstate


def _main_phase(safe, coords, proposal, pos, rstate, s: SamplerSettings, info: dict, bar,
                log_mask=None, centers=None, derived=None, fit_rng=None):
    """Run in chunks until converged or ``max_steps``; returns the sampler, the chain in
    parameters (n, walkers, d), the burn-in, τ and the coordinates finally used.

    If the first chunk shows τ above ``retune_tau`` (the warm-up had not yet seen the whole
    posterior, so the map does not fit it), that chunk becomes one more warm-up stage: the map
    and the proposal are refitted to it and the main phase starts again (at most
    ``max_retunes`` times; the discarded chunks count as warm-up). Afterwards the chain grows
    towards the length the current τ asks for, at most doubling at a time.
    """
    nw, d = pos.shape
    sampler, state = _run(safe, coords, _moves(s, proposal), pos, rstate)
    chain, watched = np.zeros((0, nw, d)), None  # watched: the chain and its derived columns
    n, n_target, burn, tau, tau_prev = 0, s.chunk, None, np.full(d, np.nan), np.inf
    info["stopped"], info["retunes"] = "max_steps", 0
    while n < s.max_steps:
        # at most doubling: a high τ from a short chain must not commit the run to many steps
        step = int(min(max(s.chunk, min(n_target - n, n)), s.max_steps - n))
        state = sampler.run_mcmc(state, step, skip_initial_state_check=True)
        new = coords.inverse(sampler.get_chain(discard=n))
        chain = np.concatenate([chain, new])
        new = _with_derived(new, derived)  # derived columns of the new steps only
        watched = new if watched is None else np.concatenate([watched, new])
        n += step
        bar.update(step)
        burn, tau_all = _burn_and_tau(watched, burn)
        tau, info["derived_tau"] = tau_all[:d], [float(t) for t in tau_all[d:]]
        tau_max = float(np.max(tau_all))
        if n == step and tau_max > s.retune_tau and info["retunes"] < s.max_retunes and s.adapt:
            try:
                tail = chain[n // 2:].reshape(-1, d)
                coords = Coordinates.fit(tail, log_mask, shear=centers is None)
                proposal = _fit_proposal(coords.forward(tail), s, _forward(coords, centers), fit_rng)
            except np.linalg.LinAlgError:
                pass
            else:
                info["retunes"] += 1
                info["warmup_stages"].append(n)
                sampler, state = _run(safe, coords, _moves(s, proposal), chain[-1], state.random_state)
                chain, watched = np.zeros((0, nw, d)), None
                n, n_target, burn, tau_prev = 0, s.chunk, None, np.inf
                continue
        ess_est = nw * (n - burn) / tau_max
        steady = abs(tau_max - tau_prev) <= s.tau_tolerance * tau_max
        tau_prev = tau_max
        rhat_ok = True
        if n - burn >= s.tau_multiple * tau_max and ess_est >= s.min_ess and steady:
            info["max_r_hat"] = _max_rank_rhat(watched[burn:], s.n_ensembles)
            rhat_ok = info["max_r_hat"] <= s.max_rhat
            if rhat_ok:
                info["stopped"] = "converged"
                break
        # expected total: burn-in + max(50 τ, the steps the ESS needs), with a 10 % margin
        need = 2.0 * tau_max + max(s.tau_multiple * tau_max, s.min_ess * tau_max / nw)
        if not rhat_ok:  # R-hat − 1 falls about as 1 / length
            need = max(need, n * (info["max_r_hat"] - 1.0) / (s.max_rhat - 1.0) if s.max_rhat > 1.0 else 2 * n)
        n_target = int(np.ceil(1.1 * need))
        bar.total = sum(info["warmup_stages"]) + max(n_target, n + s.chunk)
        bar.refresh()
    return sampler, chain, burn, tau, coords


def _max_rank_rhat(chain: np.ndarray, n_ensembles: int) -> float:
    """The largest rank-normalised split R-hat across the ensembles of every column of a chain
    (n, walkers, k), each ensemble's draws walker-major (:mod:`.diagnostics`)."""
    n, w, k = chain.shape
    per = w // n_ensembles
    arr = np.moveaxis(chain.reshape(n, n_ensembles, per, k), 0, 2).reshape(n_ensembles, per * n, k)
    with np.errstate(all="ignore"):
        return float(np.nanmax(np.append(rhat_rank(arr), 1.0)))


def _with_derived(chain: np.ndarray, derived) -> np.ndarray:
    """(n, walkers, d) chain with the ``derived`` quantities appended as columns."""
    if derived is None or not len(chain):
        return chain
    n, w, d = chain.shape
    extra = np.asarray(derived(chain.reshape(-1, d)), float).reshape(n, w, -1)
    return np.concatenate([chain, extra], axis=2)


def _forward(coords, centers):
    return None if centers is None else coords.forward(centers)


def explore(log_prob, coords: Coordinates, rng, *, temperature: float = 3.0, n_steps: int = 150,
            n_walkers: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """A short ensemble run on the tempered density p^(1/T), for finding modes (:mod:`.modes`).

    Parameters
    ----------
    log_prob : callable, (n, d) → (n,) log-density in parameters
    coords : sampler coordinates (e.g. :meth:`.reparam.Coordinates.affine` at the MAP); the
        walkers start from N(0, I) in them
    rng : numpy Generator
    temperature, n_steps, n_walkers : T, steps and walkers (even, ≥ 2·d)

    Returns
    -------
    u : (n, d) the second half of the run, in ``coords``
    log_prob : (n,) the untempered log-density there (in ``coords``, with its Jacobian)
    """
    safe = _SafeLogProb(log_prob)
    in_space = _InSpace(safe, coords)
    d = len(coords.m)
    n_walkers = max(n_walkers + n_walkers % 2, 2 * d)
    u0 = _initial_points(in_space, [(np.zeros(d), np.eye(d))], [rng], n_walkers)
    sampler = emcee.EnsembleSampler(n_walkers, d, lambda u: in_space(u) / temperature, vectorize=True,
                                    moves=[(GroupedDEMove(1), 0.8), (GroupedStretchMove(1), 0.2)])
    rstate = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
    sampler.run_mcmc(emcee.State(u0, random_state=rstate), n_steps, skip_initial_state_check=True)
    half = n_steps // 2
    return (sampler.get_chain(discard=half).reshape(-1, d),
            temperature * sampler.get_log_prob(discard=half).ravel())


def _run(safe, coords, moves, pos, rstate):
    """A fresh EnsembleSampler in ``coords`` and its state at parameters ``pos``."""
    nw, d = pos.shape
    sampler = emcee.EnsembleSampler(nw, d, _InSpace(safe, coords), moves=moves, vectorize=True)
    return sampler, emcee.State(coords.forward(pos), random_state=rstate)
