"""The emcee adapter, the only module that imports emcee: its ``EnsembleSampler`` and ``State``
(the driver of both kernels), and the moves the kernels hand it.

:class:`RandomWalkSweep` and :class:`IndependenceSweep` run a sweep of the block kernel
(:class:`.moves.BlockKernel`). For the ensemble kernel (:mod:`.ensemble`), walkers
``g·K … (g+1)·K − 1`` form ensemble ``g``; :class:`GroupedDEMove` and :class:`GroupedStretchMove`
draw partners only from the other half of the walker's own ensemble and :class:`IndependenceMove`
uses none, so ensembles never exchange information.
"""

from __future__ import annotations

import emcee
import numpy as np
from emcee import EnsembleSampler, State

from .moves import BlockKernel, multiple_try_pick

__all__ = ["EnsembleSampler", "State", "RandomWalkSweep", "IndependenceSweep", "GroupedDEMove", "GroupedStretchMove", "IndependenceMove"]


class RandomWalkSweep(emcee.moves.Move):
    """A random-walk sweep of every block (module docstring)."""

    independent = False

    def __init__(self, kernel: BlockKernel):
        self.kernel = kernel

    def propose(self, model, state):
        return self.kernel.sweep(state, model.random, independent=self.independent)


class IndependenceSweep(RandomWalkSweep):
    """An independence sweep of every block, with multiple tries (module docstring)."""

    independent = True


def _log_prob(model, q: np.ndarray) -> np.ndarray:
    """Vectorised log-probability of proposals ``q``, shape (n,): the wrapped function
    (:func:`.ensemble._in_space`, which maps NaN and ±∞ to −∞) called directly, as emcee's
    ``compute_log_prob`` converts the result walker by walker in Python."""
    return np.asarray(model.log_prob_fn(q), float)


def _grouped_propose(move, model, state, n_groups: int):
    """Red-blue update in which each walker's complement comes from its own ensemble.

    Walkers ``g·K … (g+1)·K − 1`` form ensemble ``g``. Each ensemble is split at random into two
    halves; each half is updated in turn against the other half of the same ensemble. All
    ensembles' proposals go to the log-probability in one call.
    """
    nw, d = state.coords.shape
    k = nw // n_groups
    h = k // 2
    order = np.argsort(model.random.rand(n_groups, k), axis=1) + (np.arange(n_groups) * k)[:, None]
    accepted = np.zeros(nw, dtype=bool)
    for first, second in ((order[:, :h], order[:, h:]), (order[:, h:], order[:, :h])):
        q, factors = move.grouped_proposal(state.coords[first], state.coords[second], model.random)
        idx = first.ravel()
        q = q.reshape(-1, d)
        new_lp = _log_prob(model, q)
        acc = factors.ravel() + new_lp - state.log_prob[idx] > np.log(model.random.rand(len(idx)))
        state.coords[idx[acc]] = q[acc]
        state.log_prob[idx[acc]] = new_lp[acc]
        accepted[idx[acc]] = True
    return state, accepted


class _Grouped(emcee.moves.Move):
    def propose(self, model, state):
        return _grouped_propose(self, model, state, self.n_groups)


class GroupedDEMove(_Grouped):
    """Differential evolution (ter Braak 2006; emcee's ``DEMove``) within each ensemble.

    Proposal x' = x + γ (x_a − x_b), with a ≠ b two walkers of the complementary half of the
    walker's own ensemble and γ = γ₀ (1 + σ ε), γ₀ = 2.38 / √(2·ndim).
    """

    def __init__(self, n_groups: int, sigma: float = 1e-5, gamma0: float | None = None):
        self.n_groups, self.sigma, self.gamma0 = int(n_groups), sigma, gamma0

    def grouped_proposal(self, s, c, random):
        g, ns, d = s.shape
        nc = c.shape[1]
        i1 = random.randint(nc, size=(g, ns))
        i2 = (i1 + 1 + random.randint(nc - 1, size=(g, ns))) % nc
        gi = np.arange(g)[:, None]
        g0 = self.gamma0 if self.gamma0 is not None else 2.38 / np.sqrt(2.0 * d)
        gamma = g0 * (1.0 + self.sigma * random.randn(g, ns, 1))
        return s + gamma * (c[gi, i1] - c[gi, i2]), np.zeros((g, ns))


class GroupedStretchMove(_Grouped):
    """The Goodman & Weare stretch move (emcee's ``StretchMove``) within each ensemble."""

    def __init__(self, n_groups: int, a: float = 2.0):
        self.n_groups, self.a = int(n_groups), a

    def grouped_proposal(self, s, c, random):
        g, ns, d = s.shape
        zz = ((self.a - 1.0) * random.rand(g, ns) + 1.0) ** 2 / self.a
        j = random.randint(c.shape[1], size=(g, ns))
        cj = c[np.arange(g)[:, None], j]
        return cj - (cj - s) * zz[..., None], (d - 1.0) * np.log(zz)


class IndependenceMove(emcee.moves.Move):
    """Independence Metropolis–Hastings with a multivariate-t proposal, or a mixture of them.

    Every walker draws ``tries`` proposals x' ~ Σₖ wₖ t_ν(mₖ, Sₖ Sₖᵀ) regardless of where it is and
    takes one by independent multiple-try Metropolis (:func:`multiple_try_pick`; ``tries=1`` is the
    ordinary independence step, Hastings factor q(x) / q(x')); all tries of all walkers go to the
    log-probability in one call. It uses no other walker, so ensembles stay independent. A mixture
    (a component per mode, :mod:`.modes`) lets a walker jump between modes no local move connects.

    Parameters
    ----------
    mean : (ndim,) or (k, ndim);  chol : (ndim, ndim) or (k, ndim, ndim) lower-triangular Sₖ
    df : ν;  weights : (k,) mixture weights (default: one component);  tries : proposals per walker
    """

    def __init__(self, mean: np.ndarray, chol: np.ndarray, df: float, weights=None, tries: int = 1):
        self.means = np.atleast_2d(np.asarray(mean, float))
        self.chols = np.asarray(chol, float).reshape(len(self.means), self.means.shape[1], -1)
        k = len(self.means)
        self.weights = np.ones(k) / k if weights is None else np.asarray(weights, float) / np.sum(weights)
        self.df, self.tries = float(df), int(tries)
        if self.tries < 1:
            raise ValueError(f"tries: expected an integer ≥ 1, got {tries!r}")
        self._invs = np.linalg.inv(self.chols)
        self._shifts = np.einsum("kij,kj->ki", self._invs, self.means)
        self._log_norm = np.log(self.weights) - np.array([np.sum(np.log(np.abs(np.diag(c)))) for c in self.chols])
        self.proposed = self.accepted = 0

    @property
    def n_components(self) -> int:
        return len(self.means)

    @property
    def acceptance(self) -> float:
        """Share of this move's proposals accepted so far (NaN before any)."""
        return self.accepted / self.proposed if self.proposed else float("nan")

    def log_q(self, x: np.ndarray) -> np.ndarray:
        """(n,) log-density of the proposal at x, up to a constant."""
        k, d = self.means.shape
        # every component's whitened offset in one product: z_k = S_k⁻¹ x − S_k⁻¹ m_k
        z = (x @ self._invs.reshape(k * d, d).T).reshape(len(x), k, d) - self._shifts
        terms = self._log_norm - 0.5 * (self.df + d) * np.log1p(np.sum(z * z, axis=2) / self.df)
        top = terms.max(axis=1, keepdims=True)
        return (top + np.log(np.sum(np.exp(terms - top), axis=1, keepdims=True)))[:, 0]

    def propose(self, model, state):
        n, d = state.coords.shape
        k = self.tries
        y = self._draw(n * k, d, model.random)
        lp = _log_prob(model, y)
        log_w = (lp - self.log_q(y)).reshape(n, k)
        with np.errstate(invalid="ignore"):  # a current state of zero density has weight 0
            log_w_cur = state.log_prob - self.log_q(state.coords)
        j, accepted = multiple_try_pick(log_w, log_w_cur, model.random)
        pick = np.arange(n) * k + j
        state.coords[accepted] = y[pick[accepted]]
        state.log_prob[accepted] = lp[pick[accepted]]
        self.proposed += n
        self.accepted += int(accepted.sum())
        return state, accepted

    def _draw(self, n, d, random):
        """n draws from the proposal, (n, d)."""
        w = random.chisquare(self.df, n) / self.df
        z = random.randn(n, d) / np.sqrt(w)[:, None]
        if self.n_components == 1:
            return self.means[0] + z @ self.chols[0].T
        k = np.searchsorted(np.cumsum(self.weights), random.rand(n) * np.sum(self.weights))
        k = np.minimum(k, self.n_components - 1)
        y = np.empty((n, d))
        for j in range(self.n_components):  # one product per component, not per draw
            pick = k == j
            y[pick] = self.means[j] + z[pick] @ self.chols[j].T
        return y
