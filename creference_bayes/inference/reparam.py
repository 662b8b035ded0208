"""Sampler coordinates: a map from parameters to a space where the posterior is nearly round.

Pure NumPy; the ensemble kernel (:mod:`.ensemble`) learns the map from its warm-up. Affine-invariant
ensemble moves do not care how thin a ridge is, only how curved; the map straightens it:

1. w = A⁻¹ (p − m): a whitening of a sample, along its principal axes or triangular (Cholesky)
   in some order of the coordinates;
2. v with vⱼ = wⱼ − fⱼ(w₀ … wⱼ₋₁), fⱼ a quadratic form in the preceding coordinates plus a cubic
   term in w₀, fitted by least squares: a triangular shear, whose Jacobian determinant is 1 for
   *any* fⱼ, so it is always a bijection. fⱼ is evaluated on its arguments clipped to the fitted
   sample's range widened by one range on each side (a polynomial must not explode in the
   tails). The whitening, and which of its axes comes first, minimise the determinant of the
   sheared sample's covariance (the map preserves volume: the smaller, the straighter);
3. u = B (v − c): a final whitening.

The Jacobian is constant: the density needs no correction.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Coordinates"]

#: Minimum share of a coordinate's variance a shear term must explain to be kept.
_MIN_EXPLAINED = 0.02
#: At most this many sample points are used to fit the map.
_MAX_FIT_POINTS = 1500
#: The shear is extrapolated this many sample ranges beyond the fitted sample, then held constant.
_EXTRAPOLATE = 1.0


class Coordinates:
    """The map p ↔ u (module docstring).

    Parameters
    ----------
    m : (d,) centre;  A : (d, d) with p = m + A w
    shear : per j = 1 … d−1 a tuple (Q (j, j), κ) or None;  lo, hi : (d,) clip range of w
    c, B : v = c + B⁻¹ u
    """

    def __init__(self, m, A, shear=None, lo=None, hi=None, c=None, B=None):
        self.m, self.A = np.asarray(m, float), np.asarray(A, float)
        d = len(self.m)
        self.A_inv = np.linalg.inv(self.A)
        self.shear = shear
        self.lo = np.full(d, -np.inf) if lo is None else lo
        self.hi = np.full(d, np.inf) if hi is None else hi
        self.c = np.zeros(d) if c is None else c
        self.B = np.eye(d) if B is None else B
        self.B_inv = np.linalg.inv(self.B)

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def affine(cls, center: np.ndarray, cov: np.ndarray) -> "Coordinates":
        """Whitening by a Gaussian (centre, covariance)."""
        return cls(np.asarray(center, float), np.linalg.cholesky(np.asarray(cov, float)))

    @classmethod
    def fit(cls, samples: np.ndarray, shear: bool = True) -> "Coordinates":
        """Fit the map to samples (n, d) in parameter space.

        Raises
        ------
        numpy.linalg.LinAlgError : when the sample is degenerate (fewer distinct points than
            dimensions, or a coordinate that never moved)
        """
        q = np.asarray(samples, float)
        d = q.shape[1]
        if len(q) > _MAX_FIT_POINTS:  # evenly spaced: plenty for ≤ 15 coefficients, and fast
            q = q[np.linspace(0, len(q) - 1, _MAX_FIT_POINTS).astype(int)]
        m = q.mean(axis=0)
        cov = np.atleast_2d(np.cov(q.T))
        lam, V = np.linalg.eigh(cov)
        lam, V = lam[::-1], V[:, ::-1]
        if not (np.all(np.isfinite(lam)) and lam[-1] > 1e-14 * max(lam[0], 1e-300)):
            raise np.linalg.LinAlgError("degenerate sample")
        if not shear or d < 2:
            return cls(m, V * np.sqrt(lam))
        best = None
        for A in cls._candidate_whitenings(cov, V, lam):
            self = cls(m, A)
            w = (q - m) @ self.A_inv.T
            lo, hi = w.min(axis=0), w.max(axis=0)
            self.lo, self.hi = lo - _EXTRAPOLATE * (hi - lo), hi + _EXTRAPOLATE * (hi - lo)
            self.shear = [cls._fit_shear(w, j) for j in range(1, d)]
            v = self._shear(w, -1.0)
            cov_v = np.atleast_2d(np.cov(v.T))
            sign, logdet = np.linalg.slogdet(cov_v)
            if sign > 0 and (best is None or logdet < best[0]):
                best = (logdet, self, v, cov_v)
        if best is None:
            raise np.linalg.LinAlgError("degenerate sheared sample")
        _, self, v, cov_v = best
        L = np.linalg.cholesky(cov_v)
        self.c, self.B, self.B_inv = v.mean(axis=0), np.linalg.inv(L), L
        return self

    @staticmethod
    def _candidate_whitenings(cov: np.ndarray, V: np.ndarray, lam: np.ndarray):
        """Linear maps A (q − m = A w, cov(w) = I) whose first axis the shear bends the others
        along: each principal axis first, and each original coordinate first (a Cholesky
        whitening in that order, so the others are regressed on it, unrotated)."""
        d = len(lam)
        for first in range(d):
            order = [first] + [k for k in range(d) if k != first]
            yield V[:, order] * np.sqrt(lam[order])
            L = np.linalg.cholesky(cov[np.ix_(order, order)])
            A = np.zeros((d, d))
            A[order] = L
            yield A

    @staticmethod
    def _fit_shear(w: np.ndarray, j: int):
        cols = [w[:, a] * w[:, b] for a in range(j) for b in range(a, j)] + [w[:, 0] ** 3]
        X = np.column_stack(cols)
        X = X - X.mean(axis=0)
        y = w[:, j] - w[:, j].mean()
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        explained = 1.0 - np.var(y - X @ beta) / np.var(y)
        if not (explained > _MIN_EXPLAINED and np.all(np.isfinite(beta))):
            return None
        Q = np.zeros((j, j))
        Q[np.triu_indices(j)] = beta[:-1]
        return 0.5 * (Q + Q.T), float(beta[-1])

    # -- the map -----------------------------------------------------------------------------
    def _shear(self, a: np.ndarray, sign: float) -> np.ndarray:
        """v of w (``sign`` −1) or w of v (+1), column by column: wⱼ needs only w₀…wⱼ₋₁, already
        known (the inverse is the hot path of every log-probability call)."""
        out = a.copy()
        if not self.shear:
            return out
        w = a if sign < 0 else out
        x = np.empty_like(out)  # the clipped w
        x[:, 0] = np.minimum(np.maximum(w[:, 0], self.lo[0]), self.hi[0])
        cube = x[:, 0] ** 3
        for j, term in enumerate(self.shear, start=1):
            if term is not None:
                Q, kappa = term
                out[:, j] += sign * (((x[:, :j] @ Q) * x[:, :j]).sum(axis=1) + kappa * cube)
            x[:, j] = np.minimum(np.maximum(w[:, j], self.lo[j]), self.hi[j])
        return out

    def forward(self, p: np.ndarray) -> np.ndarray:
        """(..., d) parameters → (..., d) sampler coordinates."""
        shape = p.shape
        w = (p.reshape(-1, shape[-1]).astype(float) - self.m) @ self.A_inv.T
        return ((self._shear(w, -1.0) - self.c) @ self.B.T).reshape(shape)

    def inverse(self, u: np.ndarray) -> np.ndarray:
        """(..., d) sampler coordinates → (..., d) parameters."""
        shape = u.shape
        v = u.reshape(-1, shape[-1]) @ self.B_inv.T + self.c
        return (self._shear(v, 1.0) @ self.A.T + self.m).reshape(shape)
