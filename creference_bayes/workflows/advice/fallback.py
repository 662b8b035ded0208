"""Block sweeps that finish an answer's fallback (:func:`~creference_bayes.workflows.advice._moved`)
where its transport is weak: after the affine transport has carried the draws towards an answer
that enters as a normal prior (a size, a mounting) and its weights leave too few counting, the
sampler's own block kernel (:class:`~creference_bayes.inference.moves.BlockKernel`) corrects what
the linear map left, each object in its own few dimensions."""

from __future__ import annotations

import numpy as np

from ...inference.laplace import chol
from ...inference.moves import BlockKernel, BlockTarget, SweepState
from .observe import MountingObservation, SizeObservation, at_hands

__all__ = ["FALLBACK_SWEEPS", "block_sweeps", "AnsweredTarget"]

#: Random-walk sweeps after a weak transport (docs/studies/advice.md, "The fallback's transport").
FALLBACK_SWEEPS = 6


class AnsweredTarget(BlockTarget):
    """The sampler's block target with an answer's normal density added to the block it concerns
    (a size: its object's; a mounting: the camera's), row k of every state at answer ``values[k]``
    ((n, p), in the answer's quantities: :meth:`~.observe.SizeObservation.quantities`)."""

    def __init__(self, obs, values: np.ndarray, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.obs, self.values = obs, np.asarray(values, float)

    def _answer(self, q: np.ndarray) -> np.ndarray:
        z = (self.values - q) / self.obs.sd
        with np.errstate(invalid="ignore"):
            out = -0.5 * np.sum(z * z, axis=-1)
        return np.where(np.isfinite(out), out, -np.inf)

    def _camera_lp(self, cams, wc, term):
        lp = super()._camera_lp(cams, wc, term)
        return lp + self._answer(self.obs.quantities(cams, None)) if isinstance(self.obs, MountingObservation) else lp

    def _objects_lp(self, objs, wt, terms, jac):
        lp = super()._objects_lp(objs, wt, terms, jac)
        if isinstance(self.obs, SizeObservation):
            lp[:, self.obs.i] += self._answer(self.obs.quantities(None, objs))
        return lp


def block_sweeps(obs, values: np.ndarray, wc0: np.ndarray, wo0: np.ndarray, x: np.ndarray, rng, temperature: float,
                 sweeps: int | None = None, hands: np.ndarray | None = None) -> np.ndarray:
    """``sweeps`` (None: :data:`FALLBACK_SWEEPS`) random-walk sweeps of the block kernel (the
    camera, then every object block on its own) over F sets of draws ``x`` (F, N, d) in the
    working coordinates of ``obs.model``'s free
    parameters (fixed entries from ``wc0`` (5,), ``wo0`` (m, 7)), set f leaving the old posterior
    times the f-th answer (``values`` (F, p)) invariant. Each block's proposal is that block's
    covariance in the moved draws, pooled over the sets; its scale adapts to the acceptance. A sweep
    costs about two evaluations of the posterior and moves each object in its own few dimensions,
    where a random-walk step of the whole vector moves each by about a 1/√d share of its spread.
    ``hands`` (F · N, m): each draw's handedness, set after set (None: the model's)."""
    model = at_hands(obs.model, hands)  # every sweep evaluates the F · N rows in this order
    F, N, d = x.shape
    t = AnsweredTarget(obs, np.repeat(values, N, axis=0), model, temperature, wc0,
                       np.zeros((model.n_objects, 7, 5)), wo0)
    u = x.reshape(F * N, d)
    wc, wo = t.split(u)
    dc = (wc.reshape(F, N, 5) - wc.reshape(F, N, 5).mean(axis=1, keepdims=True)).reshape(F * N, 5)
    do = wo.reshape(F, N, -1, 7)
    do = (do - do.mean(axis=1, keepdims=True)).reshape(F * N, -1, 7)
    n = max(F * N - F, 1)
    Lc = chol(dc.T @ dc / n, model.camera_free)
    Lo = np.array([chol(do[:, i].T @ do[:, i] / n, model.object_free[i]) for i in range(model.n_objects)])
    kernel = BlockKernel(t, Lc, Lo, wc.mean(axis=0), wo.mean(axis=0), tries=1, adapt=True)
    blobs = t.blocks(u)
    with np.errstate(invalid="ignore"):
        state = SweepState(u.copy(), blobs.sum(axis=1), blobs)
    rs = np.random.RandomState(np.random.MT19937(rng.integers(2**63)))
    for _ in range(FALLBACK_SWEEPS if sweeps is None else sweeps):
        state, _ = kernel.sweep(state, rs, independent=False)
    return np.asarray(state.coords).reshape(F, N, d)
