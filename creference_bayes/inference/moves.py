"""The block kernel: what is particular to a scene's posterior, under one driver (:mod:`.sampler`).

**Block moves** (docs/inference.md, "Several object blocks"): a sweep updates every object given
the camera, each accepted on its own terms (objects coupled by a pair term coloured apart), then
the camera with every object riding along its regression on it; by random-walk steps or ``tries``
Student-t independence proposals per block, one taken by multiple-try Metropolis
(:meth:`BlockKernel.sweep`). In the sampler's sweeps the camera's random-walk step *carries* every
object whose ground offset is free at its image instead (:meth:`BlockTarget.carried`; elsewhere
only in a frame with an object of known size), and in such a frame a random-walk sweep ends with a
step along the **ridge** of the camera height and the ground offsets (:meth:`BlockKernel.ridge`).
An object whose handedness is sampled (:attr:`BlockTarget.flip`) crosses to its other handedness
by its independence proposal's mode there, or by a **jump** that a share of them propose in a
random-walk sweep instead of a step (:meth:`BlockKernel._jumped`). A walker's blobs hold each
block's log-density (camera, each object, each pair term).

This module does not import emcee: the driver wraps a sweep as an emcee move
(:mod:`.emcee_moves`), and a caller without the driver passes a :class:`SweepState`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.contract import C_FOCAL, C_HEIGHT, O_GROUND, O_SIZE, O_YAW, Model
from .coords import CAMERA_LOG, WorkingCoords

__all__ = ["IND_DOF", "IND_SCALE", "multiple_try_pick", "BlockTarget", "BlockKernel", "SweepState", "colours"]

#: Degrees of freedom and scale of the independence proposals (a Student-t a little wider than the
#: posterior's Gaussian approximation, so that its tails cover the posterior's).
IND_DOF = 5.0
IND_SCALE = 1.3


@dataclass
class SweepState:
    """What a sweep reads and writes (the fields of emcee's ``State`` it uses): ``coords`` (n, d)
    the walkers' working coordinates, ``log_prob`` (n,), ``blobs`` (n, k) each block's
    log-density (:meth:`BlockTarget.blocks`)."""

    coords: np.ndarray
    log_prob: np.ndarray
    blobs: np.ndarray


def multiple_try_pick(log_w_tries: np.ndarray, log_w_current: np.ndarray,
                      rng) -> tuple[np.ndarray, np.ndarray]:
    """One independent multiple-try Metropolis step (I-MTM; Martino 2018, "A review of multiple
    try MCMC algorithms for signal processing", Digital Signal Processing 75, section 4.1).

    Given k tries y₁…y_k drawn independently from a proposal q and the current state x, with
    importance weights w = π / q (``log_w_tries`` (…, k), ``log_w_current`` (…)), pick try j with
    probability w(y_j) / Σ w and accept it with probability
    min(1, Σⱼ w(yⱼ) / (Σⱼ w(yⱼ) − w(y_picked) + w(x))). The chain keeps π invariant; with k = 1
    this is the ordinary independence Metropolis–Hastings step. Tries of zero density (−inf or
    NaN) have zero weight. Returns (picked index (…), accepted (…) bool).
    """
    log_w_tries = np.asarray(log_w_tries, float)
    log_w_tries = np.where(np.isnan(log_w_tries), -np.inf, log_w_tries)
    top = np.max(log_w_tries, axis=-1)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(invalid="ignore", under="ignore", over="ignore"):
        w = np.exp(log_w_tries - top[..., None])
        w_cur = np.exp(np.asarray(log_w_current, float) - top)
    total = w.sum(axis=-1)
    u = rng.uniform(size=total.shape) * total
    j = np.minimum(np.sum(np.cumsum(w, axis=-1) <= u[..., None], axis=-1), w.shape[-1] - 1)
    picked = np.take_along_axis(w, j[..., None], axis=-1)[..., 0]
    with np.errstate(invalid="ignore", over="ignore"):
        ok = (total > 0) & (rng.uniform(size=total.shape) * (total - picked + w_cur) < total)
    return j, ok


#: The share of the objects whose handedness is sampled that, in a random-walk sweep, propose the
#: jump to the other handedness's mode instead of a step (:meth:`BlockKernel._jumped`).
JUMP_SHARE = 0.5
#: The widest log-size sd (every dimension) of a size that counts as known for the ridge step: a
#: catalogue's answer (0.03) is, a class's prior (0.11 or more in its widest dimension) is not.
KNOWN_SIZE_LOG_SD = 0.05
#: The narrowest log-sd of an object's size prior above which its size says little of its depth
#: (Misc's, 0.4 in every dimension; a car's height 0.09, a pedestrian's 0.07): in a frame with a known
#: size, the camera's step does not carry such an object (:attr:`BlockTarget.carry`).
VAGUE_SIZE_LOG_SD = 0.3
#: The ridge step's acceptance its scale adapts towards while the sampler tunes (long steps: the
#: ridge is long and flat; docs/studies/sampler.md, "The camera height's tail").
RIDGE_ACC = 0.25


def known_sizes(model: Model) -> np.ndarray:
    """(m,) which objects' sizes are known (given, or their prior within :data:`KNOWN_SIZE_LOG_SD`):
    such an object's depth is pinned by its image."""
    return np.array([o.sizes is not None or np.max(o.size_prior.log_sd) <= KNOWN_SIZE_LOG_SD for o in model.objects],
                    bool)


def sized(model: Model) -> bool:
    """Whether some object's size is known (:func:`known_sizes`): the camera height then trades
    against the ground offsets along the ridge, which the blocks' own moves cross slowly
    (docs/studies/sampler.md, "The camera height's tail")."""
    return bool(known_sizes(model).any())


class BlockTarget:
    """The log-posterior of ``model`` at temperature ``T``, by blocks, in the sampler's coordinates.

    The coordinates are the working coordinates (:mod:`.coords`) with each object measured from its
    conditional mean given the camera: õᵢ = oᵢ − Bᵢ δᵢ(c), ``B`` (m, 7, 5) the regression of the
    objects on the camera, δᵢ(c) the camera's displacement from a reference camera ``c0`` (5,) as
    object i measures it (:meth:`offset`; the shear has unit Jacobian; B = 0: the working
    coordinates themselves). A state is a flat vector ``u`` of the free coordinates:
    the camera's, then each object's; fixed entries come from ``c0`` and ``template`` (m, 7).
    """

    def __init__(self, model: Model, temperature: float, c0: np.ndarray, B: np.ndarray, template: np.ndarray,
                 yaw_window: np.ndarray | None = None, flip: np.ndarray | None = None, carry_all: bool = False):
        self.model, self.T = model, float(temperature)
        #: (m,) the objects whose handedness is sampled too: a state's last ``flip.sum()`` entries
        #: are ±1, −1 where that object takes the other handedness than the model's
        self.flip = np.zeros(model.n_objects, bool) if flip is None else np.asarray(flip, bool)
        #: (m,) the centre of each object's turn ψ (working yaw): states more than π from it have zero
        #: density (one turn; a periodic density on the whole line is improper), or None
        self.yaw_window = yaw_window
        self.coords = WorkingCoords(model)
        self.c0, self.B = np.asarray(c0, float), np.asarray(B, float)
        self.sheared = bool(np.any(self.B))
        self.template = np.asarray(template, float)  # (m, 7) sheared object coordinates of fixed entries
        free_ground = model.object_free[:, O_GROUND] & model.camera_free[C_HEIGHT]
        #: (m,) the objects the ridge step moves with the camera height: those whose ground offset
        #: is free, when the camera height is and some object's size is known (:func:`sized`)
        self.ridge = free_ground & sized(model)
        #: (m,) the objects whose shear measures the camera height in metres (:meth:`offset`): those
        #: of a known size. Such an object's image and size pin its depth t along its viewing ray d,
        #: so its ground offset h − t d_y moves with the height h in metres, where a line in log h
        #: misses it by more than its narrow spread given the camera (docs/studies/sampler.md, "The
        #: shear of an object of known size")
        self.metric = known_sizes(model)
        #: (m,) the objects a camera step carries (:meth:`carried`): with ``carry_all`` (the
        #: sampler's own sweeps) those whose ground offset is free, else the ridge's. In a frame
        #: with a known size, the sampler's step carries only the objects whose size tells their
        #: depth: the depth of one whose size says little (:data:`VAGUE_SIZE_LOG_SD`) rests on its
        #: ground contact, which a step at its depth moves along the ridge against its ground
        #: offset's prior, so it follows the shear (docs/studies/sampler.md, "An object whose size
        #: says little")
        self.carry = free_ground if carry_all else self.ridge
        if carry_all and self.ridge.any():
            tells = [o.sizes is not None or np.min(o.size_prior.log_sd) <= VAGUE_SIZE_LOG_SD for o in model.objects]
            self.carry = free_ground & np.array(tells)
        self.cf, self.of = model.camera_free, model.object_free
        self.kc = int(self.cf.sum())
        self.m = model.n_objects
        self.P = len(model.pairs)
        self.ko = self.kc + int(self.of.sum())  # where the handedness entries start
        self.ndim = self.ko + int(self.flip.sum())
        self.incidence = np.zeros((self.m, self.P))
        for p, (i, j) in enumerate(model.pairs):
            self.incidence[i, p] = self.incidence[j, p] = 1.0

    # -- coordinates -------------------------------------------------------------------------------
    def split(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, d) → camera working coordinates (n, 5) and sheared object coordinates (n, m, 7)."""
        u = np.atleast_2d(u)
        wc = np.repeat(self.c0[None], len(u), axis=0)
        wc[:, self.cf] = u[:, :self.kc]
        wt = np.repeat(self.template[None], len(u), axis=0)
        wt[:, self.of] = u[:, self.kc:self.ko]
        return wc, wt

    def join(self, wc: np.ndarray, wt: np.ndarray, flipped: np.ndarray | None = None) -> np.ndarray:
        """The states (n, d) of camera and sheared object coordinates and, where handednesses are
        sampled, which objects take the other one (``flipped`` (n, m) bool; None: none)."""
        wc = np.atleast_2d(wc)
        parts = [wc[:, self.cf], np.asarray(wt).reshape(len(wc), -1, 7)[:, self.of]]
        if self.flip.any():
            f = np.zeros((len(wc), self.m), bool) if flipped is None else np.asarray(flipped, bool)
            parts.append(np.where(f[:, self.flip], -1.0, 1.0))
        return np.concatenate(parts, axis=1)

    def flipped(self, u: np.ndarray) -> np.ndarray | None:
        """(n, m) which objects of states (n, d) take the other handedness, or None where none may."""
        if not self.flip.any():
            return None
        u = np.atleast_2d(u)
        f = np.zeros((len(u), self.m), bool)
        f[:, self.flip] = u[:, self.ko:] < 0
        return f

    def handedness(self, u: np.ndarray) -> np.ndarray | None:
        """(n, m) each object's handedness in states (n, d), or None where every state has the model's."""
        f = self.flipped(u)
        return None if f is None else np.where(f, -self.model.handedness, self.model.handedness)

    def at(self, flipped: np.ndarray | None) -> Model:
        """The model to evaluate rows with ``flipped`` (n, m) objects at their other handedness
        (:meth:`~..models.contract.Model.at_handedness`; None: the model)."""
        if flipped is None or not flipped.any():
            return self.model
        return self.model.at_handedness(np.where(flipped, -self.model.handedness, self.model.handedness))

    def offset(self, wc: np.ndarray) -> np.ndarray:
        """(…, m, 5) the displacement δᵢ of cameras ``wc`` (…, 5) from ``c0`` that each object's shear
        multiplies: in working coordinates, except that an object of :attr:`metric` measures the
        height relative to c₀'s, h / h₀ − 1 (the same to first order)."""
        d = np.asarray(wc, float)[..., None, :] - self.c0
        d = np.broadcast_to(d, d.shape[:-2] + (self.m, 5)).copy()
        if self.metric.any():
            d[..., self.metric, C_HEIGHT] = np.expm1(d[..., self.metric, C_HEIGHT])
        return d

    def shift(self, wc: np.ndarray) -> np.ndarray | float:
        """(n, m, 7) the shear Bᵢ δᵢ(c) of each object at cameras ``wc`` (n, 5) (0 where B = 0)."""
        return np.einsum("mik,nmk->nmi", self.B, self.offset(wc)) if self.sheared else 0.0

    def unshear(self, wc: np.ndarray, wt: np.ndarray) -> np.ndarray:
        """Working object coordinates (n, m, 7) of sheared ones."""
        return wt + self.shift(wc)

    def carried(self, wc: np.ndarray, wt: np.ndarray, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The objects (sheared, ``wt`` (n, m, 7)) as a camera move ``wc`` → ``pc`` (n, 5) carries
        them, and the move's log-Jacobian (n,). Each carried object (:attr:`carry`) keeps its
        image: its pixel and turn stay, its depth in the camera's frame scales with the focal
        length, its sizes in metres stay (a free size's log(size / z) moves by −log(z′/z), so its
        apparent size stays, as a known size's does; in a frame with a known size, whose ridge
        objects are carried, their free sizes keep log(size / z)), and its ground offset goes
        where that puts it, g → h′ − (µ′/µ) t d′_y, t = (h − g) / d_y its depth along the viewing
        ray d of its pixel (d′ the same pixel's ray from the new camera). This is the direction an
        image leaves open where its perspective is weak (a long focal length with every depth
        scaled with it), along which a frame of an unknown focal length has its long tail
        (docs/studies/sampler.md, "A camera step that keeps the image"). The other objects follow
        the shear. Jacobian ∂g′/∂g =
        (µ′/µ) d′_y / d_y (the sizes' shift is a translation); the move back (``pc`` → ``wc``)
        undoes it. Along the height alone (the ridge step) every ground offset moves with the
        height, h − g kept, and the Jacobian is 1."""
        if not self.carry.any():
            return wt, np.zeros(len(wc))
        cams, new = self.coords.camera_from_work(wc), self.coords.camera_from_work(pc)
        wo = self.unshear(wc, wt)
        po = np.where(self.carry[:, None], wo, self.unshear(pc, wt))
        ray, ray_n = self.coords.rays(cams, wo), self.coords.rays(new, po)
        d, dn = ray[..., 1], ray_n[..., 1]
        ratio = (new[:, C_FOCAL] / cams[:, C_FOCAL])[:, None]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            g = new[:, C_HEIGHT, None] - ratio * (cams[:, C_HEIGHT, None] - wo[..., O_GROUND]) / d * dn
            log_j = np.where(self.carry, np.log(ratio * dn / d), 0.0).sum(axis=1)
            # the ground's z (what a free size is measured against) moves by ratio · d′_z / d_z
            log_z = np.log(ratio * ray_n[..., 2] / ray[..., 2])
        po[..., O_GROUND] = np.where(self.carry, g, po[..., O_GROUND])
        sizes = (self.carry & ~self.ridge)[:, None] & self.of[:, O_SIZE]  # the ridge's keep their log(size / z)
        po[..., O_SIZE] = np.where(sizes, po[..., O_SIZE] - log_z[..., None], po[..., O_SIZE])
        return po - self.shift(pc), np.where(np.isfinite(log_j), log_j, -np.inf)

    def natural(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Natural parameters (cameras (n, 5), objects (n, m, 7)) of states (n, d)."""
        return self.coords.from_work(*self.working(u))

    def working(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Working coordinates (cameras (n, 5), objects (n, m, 7)) of states (n, d)."""
        wc, wt = self.split(u)
        return wc, self.unshear(wc, wt)

    # -- the blocks' log-densities -----------------------------------------------------------------
    def camera(self, wc: np.ndarray) -> np.ndarray:
        """(n,) log-density of the camera block alone (its terms and the Jacobian of its logs)."""
        cams = self.coords.camera_from_work(wc)
        with np.errstate(all="ignore"):
            return self._camera_lp(cams, wc, self.model.camera_term(cams, self.T))

    def objects(self, wc: np.ndarray, wt: np.ndarray, flipped: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(n, m) log-density of each object's block and (n, P) of each pair term; ``flipped``
        (n, m) which objects take the other handedness (None: none)."""
        m = self.at(flipped)
        cams, objs, jac = self.coords.from_work_jacobian(wc, self.unshear(wc, wt))
        with np.errstate(all="ignore"):
            lp = self._objects_lp(objs, wt, m.object_terms(cams, objs, self.T), jac)
            if not self.P:
                return lp, np.zeros((len(cams), 0))
            pp = -m.pair_terms(cams, objs, self.T)
        return lp, np.where(np.isfinite(pp), pp, -np.inf)

    def blocks(self, u: np.ndarray) -> np.ndarray:
        """(n, 1 + m + P): the camera's, each object's and each pair term's log-density (one
        evaluation of the model's terms, each object at its handedness)."""
        m = self.at(self.flipped(u))
        wc, wt = self.split(u)
        cams, objs, jac = self.coords.from_work_jacobian(wc, self.unshear(wc, wt))
        with np.errstate(all="ignore"):
            c, o, p = m.terms(cams, objs, self.T)
            lp_p = np.where(np.isfinite(p), -p, -np.inf)
            return np.column_stack([self._camera_lp(cams, wc, c), self._objects_lp(objs, wt, o, jac), lp_p])

    def _camera_lp(self, cams: np.ndarray, wc: np.ndarray, term: np.ndarray) -> np.ndarray:
        """(n,) the camera block's log-density from its term (−∞ outside the bounds)."""
        m = self.model
        lp = -term + np.sum(wc[:, CAMERA_LOG & m.camera_free], axis=1)
        ok = np.all((cams >= m.camera_lower) & (cams <= m.camera_upper), axis=1) & np.isfinite(lp)
        return np.where(ok, lp, -np.inf)

    def _objects_lp(self, objs: np.ndarray, wt: np.ndarray, terms: np.ndarray, jac: np.ndarray) -> np.ndarray:
        """(n, m) each object block's log-density from its terms and Jacobian (−∞ outside)."""
        lp = -terms + jac
        return np.where(self._inside(objs, wt) & np.isfinite(lp), lp, -np.inf)

    def _inside(self, objs: np.ndarray, wt: np.ndarray) -> np.ndarray:
        """(n, m) whether each object lies inside the bounds (and its turn inside the yaw window)."""
        m = self.model
        inside = (objs >= m.object_lower) & (objs <= m.object_upper)
        inside[..., O_YAW] = True if self.yaw_window is None else np.abs(wt[..., O_YAW] - self.yaw_window) < np.pi
        return np.all(inside, axis=-1)

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(n,) the log-posterior density in these coordinates."""
        with np.errstate(invalid="ignore"):
            return self.blocks(u).sum(axis=1)


def colours(m: int, pairs: np.ndarray) -> list:
    """Groups of objects no two of which are coupled (greedy graph colouring), as (m,) masks;
    ``[None]`` (every object at once) when nothing couples them."""
    if not len(pairs):
        return [None]
    colour = -np.ones(m, int)
    for i in range(m):
        taken = {colour[j] for a, b in pairs for j in ((b,) if a == i else (a,) if b == i else ())}
        colour[i] = next(c for c in range(m) if c not in taken)
    return [colour == c for c in range(colour.max() + 1)]


class BlockKernel:
    """What the sweeps share: the target, each block's proposal (Cholesky factors ``Lc`` (5, 5) and
    ``Lo`` (m, 7, 7), random-walk scales, independence centres ``mc`` (5,), ``mt`` (m, 7)), the
    colouring and the acceptance counts.

    ``adapt``: while True, each random-walk sweep moves its scales by exp(rate · (acceptance − 0.3)),
    rate = 3 / (t + 10)^0.6 at its t-th call (Robbins–Monro).

    ``modes``: other modes of the objects, (weights (m, 1 + E), centres (m, E, 7) at the camera
    ``target.c0``, Cholesky factors (m, E, 7, 7), how the centres move with the camera (m, E, 7, 5),
    whether each is at the object's other handedness (m, E) bool), or None: an object's
    independence proposal given the camera is then a mixture, its first component the one above
    (weight 0 pads an object with fewer modes). A proposal from a mode at the other handedness
    takes its object there (:attr:`BlockTarget.flip`): the proposal is a mixture over (object,
    handedness), so the multiple-try step keeps the joint posterior invariant.
    """

    def __init__(self, target: BlockTarget, Lc: np.ndarray, Lo: np.ndarray, mc: np.ndarray, mt: np.ndarray, *,
                 tries: int = 4, adapt: bool = False, modes=None):
        self.t = target
        self.Lc, self.Lo = Lc, Lo
        self.Lci, self.Loi = np.linalg.pinv(Lc), np.linalg.pinv(Lo)
        self.mc, self.mt = mc, mt
        self.modes = None
        if modes is not None:
            w, centres, L, shear, flips = modes
            with np.errstate(divide="ignore"):
                log_w = np.log(w)
            Ls = np.concatenate([Lo[:, None], L], axis=1)
            diag = np.diagonal(Ls, axis1=-2, axis2=-1)
            self.modes = (log_w, np.concatenate([mt[:, None], centres], axis=1), Ls, np.linalg.pinv(Ls),
                          np.sum(np.log(np.where(diag > 0, diag, 1.0)), axis=-1),
                          np.concatenate([np.zeros((len(mt), 1, 7, 5)), shear], axis=1),
                          np.concatenate([np.zeros((len(mt), 1), bool), flips], axis=1))
            #: (m,) each object's component at its other handedness (0: none)
            self.flip_k = np.where(flips.any(axis=1), 1 + np.argmax(flips, axis=1), 0)
        self.kc, self.ko = int(target.cf.sum()), target.of.sum(axis=1)
        self.sc = 2.38 / np.sqrt(max(self.kc, 1))
        self.so = 2.38 / np.sqrt(np.maximum(self.ko, 1))
        self.tries, self.adapt, self.calls = int(tries), adapt, 0
        self.colours = colours(target.m, target.model.pairs)
        self.accepted = {"camera": [], "objects": [], "all": []}
        #: the ridge step's scale in log height (None: no ridge), from the camera's proposal
        self.sr = 2.38 * float(np.linalg.norm(Lc[C_HEIGHT])) if target.ridge.any() else None

    # -- state <-> blocks ---------------------------------------------------------------------------
    def _unpack(self, state):
        wc, wt = self.t.split(state.coords)
        b = np.asarray(state.blobs, float).reshape(len(wc), -1)
        m = self.t.m
        f = self.t.flipped(state.coords)
        return wc, wt, b[:, 0].copy(), b[:, 1:1 + m].copy(), b[:, 1 + m:].copy(), f

    def _pack(self, state, wc, wt, lp_c, lp_o, lp_p, f):
        state.coords = self.t.join(wc, wt, f)
        state.blobs = np.column_stack([lp_c, lp_o, lp_p])
        with np.errstate(invalid="ignore"):
            state.log_prob = lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1)
        return state

    # -- proposals ------------------------------------------------------------------------------------
    @staticmethod
    def _t(rs, shape):
        return rs.standard_normal(shape) / np.sqrt(rs.chisquare(IND_DOF, shape[:-1] + (1,)) / IND_DOF)

    def _means(self, wc):  # (C, m, 1 + E, 7): each mode's centre given each walker's camera (C, 5)
        return self.modes[1] + np.einsum("meic,nmc->nmei", self.modes[5], self.t.offset(wc))

    def _log_q_obj(self, x, wc=None, f=None):  # (…, m): Student-t log-density (up to constants) of the object proposal
        if self.modes is not None:  # a mixture over the modes; x (C, [k,] m, 7), wc (C, 5), f as x[..., 0] (or None)
            log_w, _, _, Li, logdet = self.modes[:5]
            means = self._means(wc).reshape((len(wc),) + (1,) * (x.ndim - 3) + self.modes[1].shape)
            w = np.einsum("meij,...mej->...mei", Li, x[..., None, :] - means) / IND_SCALE
            lq = log_w - logdet - 0.5 * (IND_DOF + self.ko[:, None]) * np.log1p(np.sum(w * w, axis=-1) / IND_DOF)
            f = np.zeros(x.shape[:-1], bool) if f is None else f
            lq = np.where(self.modes[6] == f[..., None], lq, -np.inf)  # only the modes at its handedness
            top = np.max(lq, axis=-1)
            return top + np.log(np.sum(np.exp(lq - top[..., None]), axis=-1))
        w = np.einsum("mij,...mj->...mi", self.Loi, x - self.mt) / IND_SCALE
        return -0.5 * (IND_DOF + self.ko) * np.log1p(np.sum(w * w, axis=-1) / IND_DOF)

    def _draw_obj(self, rs, wc, k: int) -> tuple[np.ndarray, np.ndarray | None]:
        """(C, k, m, 7) independence proposals of every object given the cameras ``wc`` (C, 5) (a
        mixture over its modes) and (C, k, m) which take the other handedness (None: none may)."""
        C, m = len(wc), self.t.m
        z = self._t(rs, (C, k, m, 7))
        if self.modes is None:
            return self.mt + IND_SCALE * np.einsum("mij,ckmj->ckmi", self.Lo, z), None
        log_w, _, L = self.modes[:3]
        cum = np.cumsum(np.exp(log_w), axis=-1)
        comp = np.minimum(np.sum(rs.uniform(size=(C, k, m, 1)) * cum[:, -1:] >= cum, axis=-1), cum.shape[1] - 1)
        idx = np.arange(m)
        means = self._means(wc)[np.arange(C)[:, None, None], idx, comp]  # (C, k, m, 7)
        flips = self.modes[6][idx, comp] if self.t.flip.any() else None
        return means + IND_SCALE * np.einsum("ckmij,ckmj->ckmi", L[idx, comp], z), flips

    def _log_q_cam(self, x):
        w = (x - self.mc) @ self.Lci.T / IND_SCALE
        return -0.5 * (IND_DOF + self.kc) * np.log1p(np.sum(w * w, axis=-1) / IND_DOF)

    def sweep(self, state, rs, independent: bool):
        """One sweep (module docstring) of every walker; returns the state and which walkers moved."""
        wc, wt, lp_c, lp_o, lp_p, f = self._unpack(state)
        C, m = wt.shape[:2]
        inc = self.t.incidence
        a, hop = np.zeros((C, m), bool), np.zeros(C, bool)
        for colour in self.colours:
            if independent:
                k = self.tries
                props, pf = self._draw_obj(rs, wc, k)
                if colour is not None:
                    props = np.where(colour[None, None, :, None], props, wt[:, None])
                    pf = None if pf is None else np.where(colour[None, None, :], pf, f[:, None])
                own, pair = self.t.objects(np.repeat(wc, k, axis=0), props.reshape(C * k, m, 7),
                                           None if pf is None else pf.reshape(C * k, m))
                own, pair = own.reshape(C, k, m), pair.reshape(C, k, -1)
                new, cur = own, lp_o
                if lp_p.shape[1]:  # each object's own terms plus the pair terms it touches
                    with np.errstate(invalid="ignore"):
                        new, cur = own + pair @ inc.T, lp_o + lp_p @ inc.T
                j, ok = multiple_try_pick(np.moveaxis(new - self._log_q_obj(props, wc, pf), 1, -1),
                                          cur - self._log_q_obj(wt, wc, f), rs)
                if colour is not None:
                    ok &= colour[None, :]
                take = lambda x: np.take_along_axis(x, j.reshape((C, 1, m) + (1,) * (x.ndim - 3)), axis=1)[:, 0]
                wt = np.where(ok[..., None], take(props), wt)
                lp_o = np.where(ok, take(own), lp_o)
                if pf is not None:
                    f = np.where(ok, take(pf), f)
                for p_, (i_, k_) in enumerate(self.t.model.pairs):  # a pair term changes with either end
                    for end in (i_, k_):
                        val = np.take_along_axis(pair[:, :, p_], j[:, end][:, None], axis=1)[:, 0]
                        lp_p[:, p_] = np.where(ok[:, end], val, lp_p[:, p_])
            else:
                prop = wt + self.so[None, :, None] * np.einsum("mij,cmj->cmi", self.Lo, rs.standard_normal((C, m, 7)))
                pf, log_j, jumps = f, 0.0, np.zeros((C, m), bool)
                if f is not None:  # a share of the objects whose handedness is sampled jump to the other
                    jumps = self.t.flip & (rs.uniform(size=(C, m)) < JUMP_SHARE)
                    jp, log_j = self._jumped(wc, wt, f)
                    prop, pf, log_j = np.where(jumps[..., None], jp, prop), jumps ^ f, np.where(jumps, log_j, 0.0)
                if colour is not None:
                    prop = np.where(colour[None, :, None], prop, wt)
                    pf = None if pf is None else np.where(colour[None, :], pf, f)
                own, pair = self.t.objects(wc, prop, pf)
                delta = own - lp_o + log_j
                if lp_p.shape[1]:
                    with np.errstate(invalid="ignore"):
                        delta = delta + (pair - lp_p) @ inc.T
                with np.errstate(invalid="ignore"):
                    ok = np.log(rs.uniform(size=(C, m))) < delta
                if colour is not None:
                    ok &= colour[None, :]
                wt = np.where(ok[..., None], prop, wt)
                lp_o = np.where(ok, own, lp_o)
                f = None if f is None else np.where(ok, pf, f)
                if lp_p.shape[1]:
                    lp_p = np.where((ok.astype(float) @ inc) > 0, pair, lp_p)
                hop |= (ok & jumps).any(axis=1)
                ok = ok & ~jumps  # the scales adapt to the random-walk steps' acceptance
            a |= ok
        b = np.ones(C, bool)
        if self.kc:
            if independent:
                k = self.tries
                pcs = self.mc + IND_SCALE * self._t(rs, (C, k, 5)) @ self.Lc.T  # (C, k, 5)
                flat = pcs.reshape(C * k, 5)
                lpc = self.t.camera(flat)
                lpo, lpp = self.t.objects(flat, np.repeat(wt, k, axis=0), None if f is None else np.repeat(f, k, axis=0))
                with np.errstate(invalid="ignore"):
                    total = (lpc + lpo.sum(axis=1) + lpp.sum(axis=1)).reshape(C, k)
                    cur = lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1)
                j, b = multiple_try_pick(total - self._log_q_cam(flat).reshape(C, k), cur - self._log_q_cam(wc), rs)
                sel = np.arange(C) * k + j
                pc, lpc, lpo, lpp = pcs[np.arange(C), j], lpc[sel], lpo[sel], lpp[sel]
            else:
                pc = wc + self.sc * rs.standard_normal((C, 5)) @ self.Lc.T
                pt, log_j = self.t.carried(wc, wt, pc)
                lpc = self.t.camera(pc)
                lpo, lpp = self.t.objects(pc, pt, f)
                with np.errstate(invalid="ignore"):
                    b = np.log(rs.uniform(size=C)) < ((lpc + lpo.sum(axis=1) + lpp.sum(axis=1))
                                                      - (lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1)) + log_j)
                wt = np.where(b[:, None, None], pt, wt)
            wc = np.where(b[:, None], pc, wc)
            lp_c = np.where(b, lpc, lp_c)
            lp_o = np.where(b[:, None], lpo, lp_o)
            lp_p = np.where(b[:, None], lpp, lp_p)
        r = np.zeros(C, bool)
        if not independent:
            if self.sr is not None:
                wc, wt, lp_c, lp_o, lp_p, r = self.ridge(wc, wt, lp_c, lp_o, lp_p, rs, f)
            self.calls += 1
            if self.adapt:
                rate = 3.0 / (self.calls + 10) ** 0.6
                self.so = self.so * np.exp(rate * (a.mean(axis=0) - 0.3))
                self.sc = self.sc * np.exp(rate * (b.mean() - 0.3))
                if self.sr is not None:
                    self.sr *= np.exp(rate * (r.mean() - RIDGE_ACC))
        moved = a.any(axis=1) | b | r | hop
        self.accepted["objects"].append(a.mean(axis=0))
        self.accepted["camera"].append(float(b.mean()))
        self.accepted["all"].append(float(moved.mean()))
        return self._pack(state, wc, wt, lp_c, lp_o, lp_p, f), moved

    def _jumped(self, wc, wt, f):
        """Every object at the other handedness's mode (``f`` (C, m) which are flipped now):
        x → m₁ + L₁ L₀⁻¹ (x − m₀), m and L the two modes' centres given the walker's camera
        (:meth:`_means`) and Cholesky factors, and back; an involution. Returns the proposals
        (C, m, 7) and the log-Jacobians (C, m), log |L₁| / |L₀| towards the other."""
        means = self._means(wc)
        idx, e = np.arange(self.t.m), self.flip_k
        L, Li, logdet = self.modes[2], self.modes[3], self.modes[4]
        m0, m1 = means[:, idx, 0], means[:, idx, e]                           # (C, m, 7)
        prop = np.where(f[..., None], m0 + np.einsum("mij,cmj->cmi", L[idx, 0] @ Li[idx, e], wt - m1),
                        m1 + np.einsum("mij,cmj->cmi", L[idx, e] @ Li[idx, 0], wt - m0))
        log_j = logdet[idx, e] - logdet[idx, 0]
        return prop, np.where(f, -log_j, log_j)

    def ridge(self, wc, wt, lp_c, lp_o, lp_p, rs, f=None):
        """One random-walk step of every walker along the ridge: log h by ε ~ N(0, ``sr``²), ``sr``
        adapted towards an acceptance of :data:`RIDGE_ACC` while the sampler tunes, every ridge
        object carried (:meth:`BlockTarget.carried`: its ground offset moves with h), accepted by
        the whole posterior (the map has unit Jacobian and −ε undoes it). Returns the updated
        blocks and which walkers moved."""
        t, m = self.t, self.t.m
        pc = wc.copy()
        pc[:, C_HEIGHT] += self.sr * rs.standard_normal(len(wc))
        pt, _ = t.carried(wc, wt, pc)
        new = t.blocks(t.join(pc, pt, f))
        with np.errstate(invalid="ignore"):
            ok = np.log(rs.uniform(size=len(wc))) < new.sum(axis=1) - (lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1))
        return (np.where(ok[:, None], pc, wc), np.where(ok[:, None, None], pt, wt), np.where(ok, new[:, 0], lp_c),
                np.where(ok[:, None], new[:, 1:1 + m], lp_o), np.where(ok[:, None], new[:, 1 + m:], lp_p), ok)
