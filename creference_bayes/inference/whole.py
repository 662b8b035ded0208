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
from .map import derivatives
from .modes import MIN_SHARE, find_modes, mode_rows
from .moves import BlockTarget

__all__ = ["Whole"]


class Whole:
    """The whole free vector by the ensemble kernel (module docstring), after a search for the
    joint posterior's modes; a mode denser than the MAP's becomes the centre."""

    def __init__(self, model, start, s: SamplerSettings, rng, temperature, map_est):
        wc0, wo0, Sc, Ao, B, _ = start
        self.model = model
        cf, of = model.camera_free, model.object_free
        target = self.target = BlockTarget(model, temperature, wc0, np.zeros_like(B), wo0, yaw_window=wo0[:, O_YAW])
        free = np.concatenate([cf, of.ravel()])
        flat = np.cumsum(free) - 1
        circular = [int(flat[5 + 7 * i + O_YAW]) for i in range(model.n_objects) if of[i, O_YAW]] or None
        hd = self.hd = HorizonDistance.of(model)  # pitch as the log of the first object's distance below the horizon
        self.to_u = (lambda q: q) if hd is None else hd.inverse
        log_prob = target if hd is None else (lambda q: target(hd.inverse(q)) + hd.log_jacobian(q))

        def in_q(u, cov_u):  # a point and its covariance, in the sampled coordinates
            if hd is None:
                return u, cov_u
            J = np.column_stack([(hd.forward(u + 1e-6 * e) - hd.forward(u - 1e-6 * e))[0] / 2e-6
                                 for e in np.eye(len(u))])
            return hd.forward(u[None])[0], J @ cov_u @ J.T

        center, cov = in_q(target.join(wc0[None], wo0[None])[0], _joint_cov(Sc, Ao, B, free))
        modes = []
        if s.mode_search:
            side = np.random.default_rng(np.random.SeedSequence(rng.bit_generator.seed_seq.entropy, spawn_key=tuple(
                rng.bit_generator.seed_seq.spawn_key) + (2**31 + 19,), pool_size=rng.bit_generator.seed_seq.pool_size))
            laplace_q = lambda c: in_q(self.to_u(c[None])[0], _whole_cov(model, target, self.to_u(c[None])[0],  # noqa: E731
                                                                         temperature, free))[1]
            others = [in_q(target.join(*WorkingCoords(model).to_work(c[None], o[None]))[0], cov)[0]
                      for c, o, h in map_est.others if np.array_equal(h, map_est.handedness)]
            others = [u for u in others if circular is None or np.all(np.abs(u[circular] - center[circular]) < np.pi)]
            modes = find_modes(log_prob, center, cov, laplace=laplace_q, rng=side, circular=circular,
                               extra_starts=np.array(others) if others else None)
        self.better = None
        if len(modes) > 1:  # a denser mode than the MAP's becomes the centre; modes with no mass go
            lp = log_prob(np.array([m.center for m in modes]))
            if lp.max() > lp[0] + 1.0:
                self.better = modes[int(np.argmax(lp))]
                modes = [self.better] + [m for m in modes if m is not self.better and m.share >= MIN_SHARE]
                center, cov = self.better.center, self.better.cov
        self.modes = modes
        self.kernel = Ensemble(log_prob, center, cov, settings=s, rng=rng,
                               modes=[(m.center, m.cov) for m in modes[1:]])
        self.n_chains, self.walkers = self.kernel.n_chains, self.kernel.walkers

    def tune(self, bar, repilot=None) -> int:
        """The ensemble's warm-up; ``repilot`` (or None) is called with the cameras (n, 5) of each
        stage's second half (:meth:`.blocks.Blocks.tune`)."""
        return self.kernel.tune(bar, None if repilot is None else lambda q: repilot(self.natural(q[None])[0][0]))

    def run(self, steps: int):
        for q, lp in self.kernel.run(steps):  # the log-density in working coordinates
            yield q, lp if self.hd is None else lp - self.hd.log_jacobian(q)

    def natural(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cams, objs = self.target.natural(self.to_u(q.reshape(-1, q.shape[-1])))
        return cams.reshape(q.shape[:2] + (5,)), objs.reshape(q.shape[:2] + objs.shape[1:])

    def acceptance(self) -> tuple[float, float, float]:
        return (self.kernel.acceptance(),) * 3  # moves of the whole vector move every block at once

    def report(self, draws: Draws) -> dict:
        """The modes found (:func:`_mode_report`) and a mode denser than the MAP's."""
        info = {}
        if len(self.modes) > 1:
            C, N = draws.cameras.shape[:2]
            wc, wo = WorkingCoords(self.model).to_work(draws.cameras.reshape(-1, 5),
                                                       draws.objects.reshape((C * N,) + draws.objects.shape[2:]))
            q = self.target.join(wc, wo)
            near = self.kernel.nearest_mode(q if self.hd is None else self.hd.forward(q)).reshape(C, N)
            info["mode_report"] = _mode_report(self.modes, self.target, self.to_u, near)
        if self.better is not None:  # a mode denser than the MAP: the pipeline refines the MAP from there
            c, o = self.target.natural(self.to_u(self.better.center[None]))
            info["denser_mode"] = (c[0], o[0])
        return info


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


def _mode_report(modes, target: BlockTarget, to_u, near) -> list[dict]:
    """:func:`mode_rows` of the modes found before sampling, for the object whose distance
    differs most between them."""
    centers = to_u(np.array([m.center for m in modes]))
    _, objs = target.natural(centers)
    i = int(np.argmax(np.ptp(np.log(np.hypot(objs[..., 0], objs[..., 1])), axis=0)))
    return mode_rows(target.model.objects[i].id, objs[:, i], target(centers), modes, near)


