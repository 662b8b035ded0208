"""Block sweeps (:mod:`.moves`), the kernel of a model of several object blocks under the driver
of :mod:`.sampler`: its start, warm-up and mode report (docs/inference.md, "Several object blocks")."""

from __future__ import annotations

import numpy as np

from .chains import Draws, SamplerSettings, SamplingError
from .coords import WorkingCoords
from .laplace import chol, conditional
from .modes import Mode, mode_rows, object_modes
from .emcee_moves import EnsembleSampler, IndependenceSweep, RandomWalkSweep, State
from .moves import BlockKernel, BlockTarget

__all__ = ["Blocks"]


def _reestimate(target: BlockTarget, wc: np.ndarray, wo: np.ndarray, Sc0, Ao0, B0):
    """Covariances and shear from warm-up draws (pooled over chains; working coordinates, each
    object's shear on the camera as it measures it, :meth:`~.moves.BlockTarget.offset`), blended
    with the Laplace ones (80 % / 20 %); and the independence centres."""
    model = target.model
    cf = model.camera_free
    C, O = wc.reshape(-1, 5), wo.reshape(-1, model.n_objects, 7)
    cm, om = C.mean(axis=0), O.mean(axis=0)
    dc, do = C - cm, O - om
    n = len(C)
    Scc = np.where(np.outer(cf, cf), dc.T @ dc / (n - 1), 0.0)
    Soo = np.einsum("nmi,nmj->mij", do, do) / (n - 1)
    cond, B = conditional(model, Scc, np.einsum("nmi,nc->mic", do, dc) / (n - 1), Soo)
    if target.metric.any():  # the same regression on the height in metres, for the objects that measure it so
        dm = target.offset(C)[:, int(np.argmax(target.metric))]
        dm = dm - dm.mean(axis=0)
        Smm = np.where(np.outer(cf, cf), dm.T @ dm / (n - 1), 0.0)
        cond_m, B_m = conditional(model, Smm, np.einsum("nmi,nc->mic", do, dm) / (n - 1), Soo)
        cond = np.where(target.metric[:, None, None], cond_m, cond)
        B = np.where(target.metric[:, None, None], B_m, B)
    return 0.8 * Scc + 0.2 * Sc0, 0.8 * cond + 0.2 * Ao0, 0.8 * B + 0.2 * B0, cm


class _Run:
    """One segment of the run: a target in the current shear, its kernel and an EnsembleSampler."""

    def __init__(self, model, temperature, s: SamplerSettings, c0, Sc, Ao, B, mc, mt, adapt, modes=None):
        m = model.n_objects
        flip = None if modes is None else modes[4].any(axis=1)  # objects with a mode at the other handedness
        self.target = BlockTarget(model, temperature, c0, B, np.zeros((m, 7)), flip=flip, carry_all=True)
        Lc = chol(Sc, model.camera_free)
        Lo = np.array([chol(Ao[i], model.object_free[i]) for i in range(m)])
        self.kernel = BlockKernel(self.target, Lc, Lo, mc, mt, tries=s.tries, adapt=adapt, modes=modes)
        w = 0.5 if s.independence_weight is None else s.independence_weight
        moves = [(RandomWalkSweep(self.kernel), 1.0 - w)]
        if w > 0:
            moves.append((IndependenceSweep(self.kernel), w))
        self.sampler = EnsembleSampler(s.n_chains, self.target.ndim, self.target, moves=moves, vectorize=True)

    def state(self, wc: np.ndarray, wo: np.ndarray, random_state, flipped=None) -> State:
        """The walkers at working coordinates (wc (C, 5), wo (C, m, 7)) in this segment's shear,
        ``flipped`` (C, m) the objects at their other handedness (None: none)."""
        t = self.target
        wt = wo - t.shift(wc)
        u = t.join(wc, wt, flipped)
        blobs = t.blocks(u)
        with np.errstate(invalid="ignore"):
            return State(u, log_prob=blobs.sum(axis=1), blobs=blobs, random_state=random_state)

    def run(self, state: State, steps: int):
        """Yield the state after each of ``steps`` steps."""
        yield from self.sampler.sample(state, iterations=steps, store=False, skip_initial_state_check=True)


class Blocks:
    """Block sweeps (module docstring): ``n_chains`` walkers, each an independent chain, started
    from over-dispersed draws (1.2 ×) of the Laplace approximation (at the MAP where those have
    zero density), each object in its mode c mod k."""

    def __init__(self, model, start, s: SamplerSettings, rng, temperature, map_est):
        wc0, wo0, Sc, Ao, B, _ = self.start = start
        self.model, self.s, self.T = model, s, temperature
        m, C = model.n_objects, s.n_chains
        self.n_chains, self.walkers = C, 1
        of = model.object_free
        Lo = np.array([chol(Ao[i], of[i]) for i in range(m)])
        dc = 1.2 * rng.standard_normal((C, 5)) @ chol(Sc, model.camera_free).T
        wc = wc0 + dc
        wo = wo0 + 1.2 * np.einsum("mij,cmj->cmi", Lo, rng.standard_normal((C, m, 7))) + np.einsum("mik,ck->cmi", B, dc)
        random_state = np.random.RandomState(np.random.MT19937(rng.integers(2**63))).get_state()
        self.found = _object_modes(model, temperature, s, wc0, wo0, Sc, Ao, B)
        self.mix = _mixture(model, self.found, B)
        flipped = np.zeros((C, m), bool)
        if self.mix is not None:  # chain c starts each object in its mode c (mod its modes)
            for i, modes in enumerate(self.found):
                for c in range(C):
                    k = c % len(modes)
                    if k:
                        wo[c, i] = modes[k].center + chol(modes[k].cov, of[i]) @ rng.standard_normal(7) + B[i] @ dc[c]
                        flipped[c, i] = modes[k].flipped
        self.seg = _Run(model, temperature, s, wc0, Sc, Ao, B, wc0, wo0, adapt=True, modes=self.mix)
        state = self.seg.state(wc, wo, random_state, flipped)
        bad = ~np.isfinite(state.log_prob)
        wc[bad], wo[bad], flipped[bad] = wc0, wo0, False
        self.state = self.seg.state(wc, wo, random_state, flipped)
        if not np.all(np.isfinite(self.state.log_prob)):
            raise SamplingError("the MAP has zero posterior density: cannot start the sampler")

    def tune(self, bar, repilot=None) -> int:
        """The warm-up (module docstring); returns its steps. ``repilot`` (or None) is called with
        the cameras (n, 5) of each segment's second half, the model possibly changed in place: the
        next segment, and the main phase, start from log-densities computed anew."""
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
            self._repilot(repilot, wcs, wos)  # the next segment's states are scored anew
            Sc, Ao, B, mc = _reestimate(seg.target, wcs, wos, Sc0, Ao0, B0)
            mt = (wos - np.einsum("mik,tcmk->tcmi", B, seg.target.offset(wcs))).reshape(-1, m, 7).mean(axis=0)
            if self.mix is not None:  # an object with several modes keeps its MAP mode's blocks (its
                several = np.array([len(modes) > 1 for modes in self.found])  # draws span every mode)
                Ao[several], B[several], mt[several] = Ao0[several], B0[several], wo0[several]
            wc, wo = seg.target.working(state.coords)
            flipped = seg.target.flipped(state.coords)
            seg = _Run(self.model, self.T, s, wc0, Sc, Ao, B, mc, mt, adapt=True, modes=self.mix)
            seg.kernel.calls = done // 2  # the scales' adaptation rate goes on falling
            state = seg.state(wc, wo, state.random_state, flipped)
            hist = []
        seg.kernel.adapt = False
        if repilot is not None:
            keep = hist[len(hist) // 2:]
            self._repilot(repilot, np.array([h[0] for h in keep]), np.array([h[1] for h in keep]))
            state = seg.state(*seg.target.working(state.coords), state.random_state,
                              seg.target.flipped(state.coords))  # scored anew
        self.seg, self.state = seg, state
        return s.warmup

    def _repilot(self, repilot, wcs: np.ndarray, wos: np.ndarray) -> None:
        """``repilot`` (if any) with the cameras of warm-up states (working coordinates wcs (T, C, 5),
        wos (T, C, m, 7))."""
        if repilot is not None:
            repilot(WorkingCoords(self.model).from_work(wcs.reshape(-1, 5), wos.reshape((-1,) + wos.shape[2:]))[0])

    def run(self, steps: int):
        for self.state in self.seg.run(self.state, steps):
            yield self.state.coords, self.state.log_prob

    def natural(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cameras (n, C, 5) and objects (n, C, m, 7) of states (n, C, d)."""
        cams, objs = self.seg.target.natural(u.reshape(-1, u.shape[-1]))
        return cams.reshape(u.shape[:2] + (5,)), objs.reshape(u.shape[:2] + objs.shape[1:])

    def kept(self, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """What the driver keeps of states (n, C, d): cameras and objects (:meth:`natural`) and,
        where some object's handedness is sampled, each state's (n, C, m)."""
        hands = self.seg.target.handedness(u.reshape(-1, u.shape[-1]))
        return self.natural(u) + (() if hands is None else (hands.reshape(u.shape[:2] + hands.shape[1:]),))

    def acceptance(self) -> tuple[float, float, float]:
        return tuple(float(np.mean(self.seg.kernel.accepted[k])) for k in ("all", "camera", "objects"))

    def report(self, draws: Draws) -> dict:
        """The objects' modes (:func:`_object_mode_report`) and a mode denser than the MAP's."""
        if self.mix is None:
            return {}
        wc0, wo0 = self.start[:2]
        info = {"mode_report": _object_mode_report(self.model, self.found, draws, wc0, wo0)}
        denser = [(i, max((k for k in modes if not k.flipped), key=lambda k: k.log_prob))
                  for i, modes in enumerate(self.found) if len(modes) > 1]
        denser = [(i, k) for i, k in denser if k.log_prob > self.found[i][0].log_prob + 1.0]
        if denser:  # an object's mode denser than the MAP's: the pipeline refines the MAP from there
            wo = wo0.copy()
            for i, k in denser:
                wo[i] = k.center
            c, o = WorkingCoords(self.model).from_work(wc0[None], wo[None])
            info["mode_starts"] = [(c[0], o[0], None)]
        return info


def _object_modes(model, temperature, s: SamplerSettings, wc0, wo0, Sc, Ao, B):
    """Each object's modes given the MAP's camera (:func:`.modes.object_modes`), or each its
    MAP's alone without ``mode_search``."""
    if not s.mode_search:
        return [[Mode(wo0[i], Ao[i], 0.0, 1.0)] for i in range(model.n_objects)]
    return object_modes(BlockTarget(model, temperature, wc0, B, np.zeros_like(wo0)), wc0, wo0, Ao, temperature)


#: Least weight of each mode's component in an object's independence proposal (so that the
#: proposal keeps offering every mode, whatever its Laplace share).
MIN_MODE_WEIGHT = 0.1


def _mixture(model, found, B):
    """The objects' other modes as :class:`~.moves.BlockKernel` takes them (weights (m, 1 + E),
    centres (m, E, 7), Cholesky factors (m, E, 7, 7), how each centre moves with the camera in
    the sampler's coordinates (m, E, 7, 5), ``B`` (m, 7, 5) their shear, and whether each is at its
    object's other handedness (m, E)), or None when no object has another."""
    E = max(len(modes) for modes in found) - 1
    if E == 0:
        return None
    m = model.n_objects
    w, centres, L, shear = np.zeros((m, 1 + E)), np.zeros((m, E, 7)), np.zeros((m, E, 7, 7)), np.zeros((m, E, 7, 5))
    flips = np.zeros((m, E), bool)
    for i, modes in enumerate(found):
        share = np.maximum([k.share for k in modes], MIN_MODE_WEIGHT)
        w[i, :len(modes)] = share / share.sum()
        for k, mode in enumerate(modes[1:]):
            centres[i, k], L[i, k] = mode.center, chol(mode.cov, model.object_free[i])
            shear[i, k] = (mode.shear - B[i]) * model.object_free[i][:, None] * model.camera_free[None]
            flips[i, k] = mode.flipped
    return w, centres, L, shear, flips


def _object_mode_report(model, found, draws: Draws, wc0, wo0) -> list[dict]:
    """:func:`mode_rows` of each object with several modes (each draw's nearest in the mode's own
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
        rows = mode_rows(model.objects[i].id, objs[:, i], [k.log_prob for k in modes], modes,
                         np.argmin(dist, axis=1).reshape(C, N))
        if any(k.flipped for k in modes):  # each mode's handedness where both are sampled
            for row, k in zip(rows, modes):
                row["handedness"] = int(-model.handedness[i] if k.flipped else model.handedness[i])
        out += rows
    return out


