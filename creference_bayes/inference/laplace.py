"""The Laplace approximation of a scene's posterior at its MAP, in working coordinates.

The posterior is close to a Gaussian in the working coordinates of :mod:`.coords`, so a Gaussian
fitted at the MAP there (the arrowhead Hessian, :func:`.map.derivatives`, with the Jacobian of the
coordinates as the sampler's density has it) gives cheap, curved draws in natural coordinates and
the delta-method variance of any per-object quantity (``creference plot`` and ``advise`` use them).

By blocks: the camera's marginal covariance ``Sc`` (5, 5), each object's covariance given the
camera ``Ao`` (m, 7, 7) and the shear ``B`` (m, 7, 5), E[oᵢ | c] = oᵢ* + Bᵢ (c − c*). Fixed
parameters have zero variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.contract import Model
from .coords import WorkingCoords
from .map import Arrowhead, derivatives

__all__ = ["Laplace", "laplace", "laplace_blocks", "conditional", "chol"]


@dataclass(frozen=True)
class Laplace:
    """A scene's Laplace approximation (module docstring): the MAP (``camera`` (5,), ``objects``
    (m, 7) natural; ``wc``, ``wo`` working), the arrowhead ``hessian`` there, its blocks ``Sc``,
    ``Ao``, ``B`` and ``ok`` (False: the Hessian was not positive definite and its blocks were
    repaired, :func:`laplace_blocks`)."""

    model: Model
    camera: np.ndarray
    objects: np.ndarray
    wc: np.ndarray
    wo: np.ndarray
    hessian: Arrowhead
    Sc: np.ndarray
    Ao: np.ndarray
    B: np.ndarray
    ok: bool

    def draws(self, n: int, rng=None) -> tuple[np.ndarray, np.ndarray]:
        """``n`` draws (fewer when some fall above the horizon): cameras (k, 5), objects (k, m, 7),
        natural coordinates."""
        rng = np.random.default_rng(rng)
        m = self.model.n_objects
        Lc = chol(self.Sc, self.model.camera_free)
        Lo = np.array([chol(self.Ao[i], self.model.object_free[i]) for i in range(m)])
        dc = rng.standard_normal((n, 5)) @ Lc.T
        do = np.einsum("mij,nmj->nmi", Lo, rng.standard_normal((n, m, 7))) + np.einsum("mic,nc->nmi", self.B, dc)
        cams, objs = WorkingCoords(self.model).from_work(self.wc[None] + dc, self.wo[None] + do)
        ok = np.all(np.isfinite(objs), axis=(1, 2)) & self.model.in_bounds(cams, objs)
        return cams[ok], objs[ok]


def laplace(model: Model, camera: np.ndarray, objects: np.ndarray, *,
                  temperature: float = 1.0) -> Laplace:
    """The Laplace approximation at the MAP ``camera`` (5,) and ``objects`` (m, 7) (natural
    coordinates; the model's handedness must be the MAP's)."""
    camera = model.complete_camera(np.asarray(camera, float)[None])[0]
    objects = np.asarray(objects, float)
    wc, wo = (a[0] for a in WorkingCoords(model).to_work(camera[None], objects[None]))
    H = derivatives(model, wc, wo, temperature, with_jacobian=True)
    Sc, Ao, B, ok = laplace_blocks(model, H)
    return Laplace(model, camera, objects, wc, wo, H, Sc, Ao, B, ok)


def laplace_blocks(model: Model, H: Arrowhead) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(``Sc``, ``Ao``, ``B``, ok) of an arrowhead Hessian ``H`` (module docstring), zero on fixed
    parameters. A block that is not positive definite (an object's, or the camera's Schur
    complement: a MAP in natural coordinates need not be a mode of the working-coordinate
    density) has its negative eigenvalues replaced by their absolute values (at least 1e-9 of its
    largest), and ok is False."""
    m = model.n_objects
    if len(H.pairs):
        return _dense_blocks(model, H)
    H_oo = H.H_oo.copy()
    ok = True
    for i in range(m):
        H_oo[i], good = _positive(H_oo[i], model.object_free[i])
        ok &= good
    Ao = np.linalg.inv(H_oo)
    B = -np.einsum("mij,mcj->mic", Ao, H.H_co)
    S = H.H_cc + np.einsum("mcj,mjd->cd", H.H_co, B)
    S, good = _positive(S, model.camera_free)
    ok &= good
    Sc = np.linalg.inv(S)
    Sc = Sc * np.outer(model.camera_free, model.camera_free)
    Ao = Ao * (model.object_free[:, :, None] & model.object_free[:, None, :])
    B = B * model.object_free[:, :, None] * model.camera_free[None, None, :]
    return Sc, Ao, B, bool(ok)


def _dense_blocks(model: Model, H: Arrowhead) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """:func:`laplace_blocks` when distance references couple objects: from the whole inverse,
    each object's covariance given the camera alone (the other objects integrated out), so that
    a quantity of one object has its marginal variance."""
    free = np.concatenate([model.camera_free, model.object_free.ravel()])
    A, ok = _positive(H.dense(), free)
    cov = np.linalg.inv(A)
    m = model.n_objects
    Scc = cov[:5, :5] * np.outer(model.camera_free, model.camera_free)
    Soo = np.array([cov[5 + 7 * i:12 + 7 * i, 5 + 7 * i:12 + 7 * i] for i in range(m)])
    return (Scc, *conditional(model, Scc, cov[5:, :5].reshape(m, 7, 5), Soo), bool(ok))


def conditional(model: Model, Scc: np.ndarray, Soc: np.ndarray, Soo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The objects given the camera, from a joint covariance's blocks (camera ``Scc`` (5, 5), each
    object with the camera ``Soc`` (m, 7, 5), each object ``Soo`` (m, 7, 7)): the conditional
    covariance ``Ao`` = Soo − B Socᵀ (m, 7, 7) and the regression ``B`` = Soc Scc⁺ (m, 7, 5), zero
    on fixed parameters."""
    cf, of = model.camera_free, model.object_free
    idx = np.flatnonzero(cf)
    inv = np.zeros((5, 5))
    if idx.size:
        inv[np.ix_(idx, idx)] = np.linalg.pinv(Scc[np.ix_(idx, idx)])
    B = np.einsum("mic,cd->mid", Soc, inv) * of[:, :, None] * cf[None, None, :]
    return (Soo - np.einsum("mic,mjc->mij", B, Soc)) * (of[:, :, None] & of[:, None, :]), B


def _positive(A: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, bool]:
    """``A`` with the eigenvalues of its free block made positive (module docstring of
    :func:`laplace_blocks`); True when they already were."""
    idx = np.flatnonzero(free)
    if not idx.size:
        return A, True
    sub = A[np.ix_(idx, idx)]
    sub = 0.5 * (sub + sub.T)
    finite = bool(np.all(np.isfinite(sub)))
    if not finite:  # the inverse diagonal where it is finite
        sub = np.diag(np.where(np.isfinite(np.diag(sub)), np.abs(np.diag(sub)), 1.0))
    w, V = np.linalg.eigh(sub)
    floor = 1e-9 * max(float(np.abs(w).max()), 1e-300)
    good = finite and bool(w.min() > floor)
    if good:
        return A, True
    out = A.copy()
    out[np.ix_(idx, idx)] = (V * np.maximum(np.abs(w), floor)) @ V.T
    return out, False


def chol(cov: np.ndarray, free: np.ndarray) -> np.ndarray:
    """A Cholesky factor of ``cov`` on its free rows and columns, zero elsewhere (jittered when
    not positive definite; the square roots of the diagonal as a last resort)."""
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
