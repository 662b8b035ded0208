"""The kernel of a model of one object block under the driver of :mod:`.sampler`: the whole free
vector by the ensemble kernel of :mod:`.ensemble` (docs/inference.md, "One object block")."""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from ..models.contract import O_YAW
from .chains import Draws, SamplerSettings
from .coords import HorizonDistance, WorkingCoords
from .ensemble import Ensemble
from .laplace import laplace_blocks
from .map import _newton, derivatives
from .modes import MIN_SHARE, MIX_MARGIN, Mode, _weighed, find_modes, mode_rows
from .moves import BlockTarget

__all__ = ["Whole"]


#: The sign of an auxiliary coordinate s ~ N(0, 1) appended to the state picks the handedness
#: (s ≥ 0: the MAP's); its two halves hold equal prior mass, so the chains weigh each handedness by
#: its posterior mass. A mode's s is centred at ±E|s| with the half-normal's variance.
SIDE_S, SIDE_VAR = 0.8, 0.36
#: Where both handednesses are sampled, each one's mode search explores with twice the walkers (for
#: as many steps, in one vectorised call a half-step each) and climbs from twice as many points
#: (docs/studies/method.md, "Several modes").
MIXED_SEARCH = {"n_steps": 150, "n_walkers": 64, "n_climbs": 16}


class _Side:
    """One handedness of the object block: its model, target and log-density in the sampled
    coordinates (pitch as log D where :class:`.coords.HorizonDistance` applies), and its optimum."""

    def __init__(self, model, temperature, wc, wo, hd):
        self.model, self.wc, self.wo = model, wc, wo
        target = self.target = BlockTarget(model, temperature, wc, np.zeros((model.n_objects, 7, 5)), wo,
                                           yaw_window=wo[:, O_YAW])
        self.log_prob = target if hd is None else (lambda q: target(hd.inverse(q)) + hd.log_jacobian(q))


class Whole:
    """The whole free vector by the ensemble kernel (module docstring), after a search for the
    joint posterior's modes; a mode denser than the MAP's becomes the centre. Where the other
    handedness comes within :data:`MIX_MARGIN` nats, both are sampled as one mixture
    (:data:`SIDE_S`; docs/inference.md, "Both handednesses")."""

    def __init__(self, model, start, s: SamplerSettings, rng, temperature, map_est):
        wc0, wo0, Sc, Ao, B, _ = start
        self.model = model
        cf, of = model.camera_free, model.object_free
        free = np.concatenate([cf, of.ravel()])
        flat = np.cumsum(free) - 1
        circular = [int(flat[5 + 7 * i + O_YAW]) for i in range(model.n_objects) if of[i, O_YAW]] or None
        hd = self.hd = HorizonDistance.of(model)  # pitch as the log of the first object's distance below the horizon
        self.to_u = (lambda q: q) if hd is None else hd.inverse
        sides = [_Side(model, temperature, wc0, wo0, hd)]
        other = _other_side(model, map_est, temperature)
        if other is not None and s.n_walkers >= 2 * (int(free.sum()) + 1):
            sides.append(_Side(other[0], temperature, other[1], other[2], hd))
        self.sides, self.target = sides, sides[0].target
        mixed = self.mixed = len(sides) > 1

        def in_q(u, cov_u):  # a point and its covariance, in the sampled coordinates
            if hd is None:
                return u, cov_u
            J = np.column_stack([(hd.forward(u + 1e-6 * e) - hd.forward(u - 1e-6 * e))[0] / 2e-6
                                 for e in np.eye(len(u))])
            return hd.forward(u[None])[0], J @ cov_u @ J.T

        side_rng = np.random.default_rng(np.random.SeedSequence(rng.bit_generator.seed_seq.entropy, spawn_key=tuple(
            rng.bit_generator.seed_seq.spawn_key) + (2**31 + 19,), pool_size=rng.bit_generator.seed_seq.pool_size))
        side_modes = []  # each side's modes, its optimum first
        search = MIXED_SEARCH if mixed else {}
        for k, side in enumerate(sides):
            t = side.target
            u0 = t.join(side.wc[None], side.wo[None])[0]
            cov_u = _joint_cov(Sc, Ao, B, free) if k == 0 else _whole_cov(side.model, t, u0, temperature, free)
            center, cov = in_q(u0, cov_u)
            modes = [Mode(center, cov, float(side.log_prob(center[None])[0]), 1.0)]
            if s.mode_search:
                laplace_q = lambda c, m=side.model, t=t: in_q(self.to_u(c[None])[0], _whole_cov(  # noqa: E731
                    m, t, self.to_u(c[None])[0], temperature, free))[1]
                hand = side.model.handedness
                others = [in_q(t.join(*WorkingCoords(model).to_work(c[None], o[None]))[0], cov)[0]
                          for c, o, h in map_est.others if np.array_equal(h, hand)]
                others += [m.center for ms in side_modes for m in ms]  # where the other side's modes are
                others += [in_q(o.target.join(o.wc[None], o.wo[None])[0], cov)[0] for o in sides[k + 1:]]
                if others and circular is not None:  # the same state one turn away: next to the centre
                    others = np.array(others)
                    others[:, circular] = center[circular] + (others[:, circular] - center[circular] + np.pi) % (
                        2 * np.pi) - np.pi
                modes = find_modes(side.log_prob, center, cov, laplace=laplace_q, rng=side_rng, circular=circular,
                                   extra_starts=np.array(others) if len(others) else None, **search)
            side_modes.append(modes)
        modes = side_modes[0]
        if mixed:  # every mode on the extended state, weighed together, the MAP's first
            modes = _weighed([(np.append(m.center, SIDE_S * (1 - 2 * k)), block_diag(m.cov, SIDE_VAR),
                               m.log_prob - 0.5 * SIDE_S**2, None) for k, ms in enumerate(side_modes) for m in ms],
                             np.ones(len(modes[0].center) + 1, bool), most=sum(map(len, side_modes)))
        log_prob = self._mixture if mixed else sides[0].log_prob
        center, cov = modes[0].center, modes[0].cov
        self.better = None
        if len(modes) > 1:  # a denser mode than the MAP's becomes the centre; modes with no mass go
            lp = log_prob(np.array([m.center for m in modes]))
            if lp.max() > lp[0] + 1.0:
                self.better = modes[int(np.argmax(lp))]
                modes = [self.better] + [m for m in modes if m is not self.better and m.share >= MIN_SHARE]
                center, cov = self.better.center, self.better.cov
        self.modes = modes if len(modes) > 1 else []
        self.kernel = Ensemble(log_prob, center, cov, settings=s, rng=rng,
                               modes=[(m.center, m.cov) for m in self.modes[1:]])
        self.n_chains, self.walkers = self.kernel.n_chains, self.kernel.walkers

    def _mixture(self, Q: np.ndarray) -> np.ndarray:
        """The log-density of extended states (n, d + 1): the side the last coordinate's sign picks,
        times that coordinate's N(0, 1)."""
        Q = np.atleast_2d(Q)
        first = Q[:, -1] >= 0
        out = np.empty(len(Q))
        with np.errstate(all="ignore"):  # NaN and ±∞: the ensemble's wrapper makes them −∞
            for side, rows in zip(self.sides, (first, ~first)):
                if rows.any():
                    out[rows] = side.log_prob(Q[rows, :-1])
        return out - 0.5 * Q[:, -1] ** 2

    def _q(self, Q: np.ndarray) -> np.ndarray:
        return Q[..., :-1] if self.mixed else Q

    def tune(self, bar, repilot=None) -> int:
        """The ensemble's warm-up; ``repilot`` (or None) is called with the cameras (n, 5) of each
        stage's second half (:meth:`.blocks.Blocks.tune`), and every side takes the pilot it sets."""
        if repilot is None:
            return self.kernel.tune(bar, None)

        def on_stage(Q):
            repilot(self.natural(Q[None])[0][0])
            for side in self.sides[1:]:
                side.model.set_pilot(self.model.pilot.copy())
        return self.kernel.tune(bar, on_stage)

    def run(self, steps: int):
        for Q, lp in self.kernel.run(steps):  # the log-density in working coordinates
            q = self._q(Q)
            if self.mixed:
                lp = lp + 0.5 * Q[:, -1] ** 2
            yield Q, lp if self.hd is None else lp - self.hd.log_jacobian(q)

    def natural(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = self._q(Q)
        cams, objs = self.target.natural(self.to_u(q.reshape(-1, q.shape[-1])))
        return cams.reshape(q.shape[:2] + (5,)), objs.reshape(q.shape[:2] + objs.shape[1:])

    def kept(self, Q: np.ndarray) -> tuple[np.ndarray, ...]:
        """What the driver keeps of states (n, S, d): cameras and objects (:meth:`natural`) and,
        where both handednesses are sampled, each state's (n, S, m)."""
        if not self.mixed:
            return self.natural(Q)
        hands = np.where((Q[..., -1] >= 0)[..., None], self.sides[0].model.handedness, self.sides[1].model.handedness)
        return self.natural(Q) + (hands,)

    def acceptance(self) -> tuple[float, float, float]:
        return (self.kernel.acceptance(),) * 3  # moves of the whole vector move every block at once

    def report(self, draws: Draws) -> dict:
        """The modes found (:func:`_mode_report`), every mode but the MAP's as a start for the MAP
        (with its handedness) and, where both handednesses were sampled, each one's share of the
        draws."""
        info = {}
        if self.modes or self.mixed:
            C, N = draws.cameras.shape[:2]
            wc, wo = WorkingCoords(self.model).to_work(draws.cameras.reshape(-1, 5),
                                                       draws.objects.reshape((C * N,) + draws.objects.shape[2:]))
            q = self.target.join(wc, wo)
            q = q if self.hd is None else self.hd.forward(q)
            if self.mixed:  # each draw's side: its handedness
                side = np.any(draws.handedness != self.sides[0].model.handedness, axis=-1).ravel()
                q = np.column_stack([q, np.where(side, -SIDE_S, SIDE_S)])
                info["handedness_share"] = [{"handedness": s_.model.handedness.astype(int).tolist(),
                                             "draw_share": float(np.mean(side == k))} for k, s_ in enumerate(self.sides)]
            if self.modes:
                near = self.kernel.nearest_mode(q).reshape(C, N)
                info["mode_report"] = _mode_report(self, near)
        starts = self.modes if self.better is not None else self.modes[1:]
        if starts:  # the pipeline refines the MAP from every other mode, and keeps the best
            c, o = self.natural(np.array([m.center for m in starts])[None])
            info["mode_starts"] = [(c[0, k], o[0, k], self.sides[self._side_of(m)].model.handedness)
                                   for k, m in enumerate(starts)]
        return info

    def _side_of(self, mode) -> int:
        return int(mode.center[-1] < 0) if self.mixed else 0


def _other_side(model, map_est, temperature: float):
    """The other handedness's optimum (its model, wc (5,), wo (m, 7)) refined by Newton steps, when
    the optimiser reached one within :data:`MIX_MARGIN` nats of the MAP; else None."""
    hand = np.asarray(map_est.handedness)
    for c, o, h in map_est.others:
        if np.array_equal(h, hand):
            continue
        other = model.variant(handedness=np.asarray(h, float))
        wc, wo = (a[0] for a in WorkingCoords(other).to_work(c[None], o[None]))
        wc, wo, f, _ = _newton(other, wc, wo, temperature)
        return (other, wc, wo) if np.isfinite(f) and f < map_est.value + MIX_MARGIN else None
    return None


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


def _mode_report(whole: Whole, near) -> list[dict]:
    """:func:`mode_rows` of the modes found before sampling, for the object whose distance
    differs most between them (each row with its handedness where both were sampled)."""
    centers = np.array([m.center for m in whole.modes])
    _, objs = whole.natural(centers[None])
    objs = objs[0]
    q = whole.to_u(whole._q(centers))
    lp = np.array([whole.sides[whole._side_of(m)].target(q[k:k + 1])[0] for k, m in enumerate(whole.modes)])
    i = int(np.argmax(np.ptp(np.log(np.hypot(objs[..., 0], objs[..., 1])), axis=0)))
    rows = mode_rows(whole.model.objects[i].id, objs[:, i], lp, whole.modes, near)
    if whole.mixed:
        for row, m in zip(rows, whole.modes):
            row["handedness"] = int(whole.sides[whole._side_of(m)].model.handedness[i])
    return rows


