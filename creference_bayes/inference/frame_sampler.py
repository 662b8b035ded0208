"""Sampling a frame's posterior: blocked Metropolis within Gibbs, in sheared coordinates.

A frame of m objects has 5 + 7m parameters (40–70 for ten objects), but given the camera its
objects are independent. The sampler uses that:

* **Coordinates.** Working coordinates (:mod:`.frame_coords`), then a *shear*: each object's
  block is measured from its conditional mean given the camera, õᵢ = oᵢ − Bᵢ (c − c*), with Bᵢ
  the regression of object i on the camera (from the Laplace approximation at the MAP, then
  re-estimated from the warm-up draws). The shear has unit Jacobian. In (c, õ) the blocks are
  close to independent, so updating them in turn mixes as if they were.
* **Object step.** Every object of every chain proposes a random-walk move õᵢ' = õᵢ + sᵢ Lᵢ z
  (Lᵢ the Cholesky factor of its conditional covariance) and accepts or rejects it on its own
  term alone; this is valid because, given the camera, the posterior factorises over objects.
  All objects and chains are one vectorised evaluation. Two objects coupled by a worker's
  distance between them are never moved in the same pass: the objects are coloured so that no
  coupled pair shares a colour, one pass per colour, each accepting on its own terms plus the
  pair terms it touches.
* **Camera step.** The camera proposes c' = c + s_c L_c z (its marginal covariance); every
  object moves with it along its regression (õ fixed), and the whole posterior accepts or rejects.
* **Independence steps.** Every other iteration, each block instead draws ``tries`` (default 4)
  proposals from a Student-t (5 degrees of freedom, 1.3 × the block's covariance) around its
  centre and takes one by independent multiple-try Metropolis (:func:`multiple_try_pick`): one
  picked with probability ∝ posterior / proposal, accepted with the multiple-try ratio. Where the
  posterior is close to Gaussian in these coordinates (most blocks) such a step jumps across the
  whole posterior; the extra tries rescue the chains that sit where the proposal is thin (a
  curved yaw–length ridge, a skewed camera marginal), which a single try leaves for long stretches.
  All tries of all chains are one vectorised evaluation, so four tries cost about twice one.
  Where the proposal does not fit at all, the random-walk steps still mix.
* **Warm-up.** The step scales are adapted towards an acceptance of about 0.3 and the
  covariances and shear re-estimated twice from the draws; then everything is frozen and the
  main phase is an ordinary Markov chain. Warm-up draws are discarded.
* **Stopping.** Chains run in chunks (each long enough for the slowest quantity to reach the
  target at its current rate) until every free parameter's bulk ESS reaches ``min_ess``
  and its rank-normalised split R-hat across the chains is at most ``max_rhat``, or
  ``max_iterations``; ``converged`` says which. The ranked check sorts every column of every
  draw, so it runs only when the raw split R-hat (means and variances) is within 3× of the
  threshold; the rule that decides is always the ranked one.

Everything random comes from ``rng``: the same seed gives the same draws.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..models.frame import CAMERA_NAMES, O_YAW, OBJECT_NAMES, FrameModel
from .frame_coords import CAMERA_LOG as _CAMERA_LOG, FrameCoords
from .diagnostics import ess_bulk_rhat, rhat_split_raw
from .frame_map import FrameMAP, derivatives
from .options import settings_from_options
from .multiple_try import multiple_try_pick

__all__ = ["FrameSamplerSettings", "FrameDraws", "FrameDiagnostics", "sample_frame"]

#: Degrees of freedom and scale of the independence proposals (a Student-t a little wider than the
#: posterior's Gaussian approximation, so that its tails cover the posterior's).
_IND_DOF = 5.0
_IND_SCALE = 1.3


@dataclass(frozen=True)
class FrameSamplerSettings:
    """Settings of :func:`sample_frame`.

    Attributes
    ----------
    n_chains : independent chains (for R-hat), ≥ 2
    min_ess : bulk effective sample size every free parameter must reach
    max_rhat : largest split R-hat accepted
    warmup : warm-up iterations (one object step and one camera step each)
    chunk : iterations between convergence checks
    max_iterations : cap on main-phase iterations (the result then says it has not converged)
    max_draws : draws kept per chain (older draws are thinned when exceeded)
    tries : tries per independence step (multiple-try Metropolis; 1: a plain independence step)
    """

    n_chains: int = 8
    min_ess: float = 400.0
    max_rhat: float = 1.01
    warmup: int = 600
    chunk: int = 400
    max_iterations: int = 20000
    max_draws: int = 2000
    tries: int = 4

    def __post_init__(self):
        checks = [("n_chains", self.n_chains >= 2, "an integer ≥ 2"), ("min_ess", self.min_ess >= 0, "a number ≥ 0"),
                  ("max_rhat", self.max_rhat >= 1.0, "a number ≥ 1"), ("warmup", self.warmup >= 50, "an integer ≥ 50"),
                  ("chunk", self.chunk >= 20, "an integer ≥ 20"),
                  ("max_iterations", self.max_iterations >= self.chunk, "an integer ≥ chunk"),
                  ("max_draws", self.max_draws >= 100, "an integer ≥ 100"),
                  ("tries", self.tries >= 1, "an integer ≥ 1")]
        for name, ok, expected in checks:
            if not ok:
                raise ValueError(f"sampling.{name}: expected {expected}, got {getattr(self, name)!r}")

    @classmethod
    def from_options(cls, options: dict | None) -> "FrameSamplerSettings":
        return settings_from_options(cls, options)


@dataclass(frozen=True)
class FrameDraws:
    """Posterior draws in natural parameters: cameras (chain, draw, 5), objects (chain, draw, m, 7)."""

    cameras: np.ndarray
    objects: np.ndarray


@dataclass(frozen=True)
class FrameDiagnostics:
    """How the sampler did: per free parameter bulk ESS and R-hat (dicts keyed by
    ``camera.<name>`` and ``<target id>.<name>``), iterations, acceptance rates, ``converged`` and
    the reasons when it is not, seconds."""

    n_chains: int
    warmup: int
    iterations: int
    thin: int
    ess_bulk: dict
    r_hat: dict
    acceptance: dict
    converged: bool
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0
    info: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        r = lambda d: {k: (None if v is None or not np.isfinite(v) else round(float(v), 4)) for k, v in d.items()}
        return {"n_chains": self.n_chains, "warmup": self.warmup, "iterations": self.iterations, "thin": self.thin,
                "min_ess_bulk": _min(self.ess_bulk), "max_r_hat": _max(self.r_hat),
                "ess_bulk": r(self.ess_bulk), "r_hat": r(self.r_hat),
                "acceptance": {k: round(float(v), 3) for k, v in self.acceptance.items()},
                "converged": self.converged, "warnings": list(self.warnings), "seconds": round(self.seconds, 3)}


def _min(d):
    v = [x for x in d.values() if x is not None and np.isfinite(x)]
    return round(float(min(v)), 1) if v else None


def _max(d):
    v = [x for x in d.values() if x is not None and np.isfinite(x)]
    return round(float(max(v)), 4) if v else None


class _Target:
    """The log-density in working coordinates, split into the camera's and each object's part."""

    def __init__(self, model: FrameModel, temperature: float):
        self.m, self.T = model, temperature
        self.coords = FrameCoords(model)

    def objects(self, wc, wo, with_pairs: bool = False):
        """(C, m) log-density of each object's block; with ``with_pairs`` also :meth:`pairs`'s
        (C, P), from the same transform."""
        cams, objs, jac = self.coords.from_work_jacobian(wc, wo)
        with np.errstate(all="ignore"):
            lp = -self.m.object_terms(cams, objs, self.T) + jac
            inside = (objs >= self.m.object_lower) & (objs <= self.m.object_upper)
        inside[..., O_YAW] = True
        ok = np.all(inside, axis=-1) & np.isfinite(lp)
        lp = np.where(ok, lp, -np.inf)
        return (lp, self._pairs(cams, objs)) if with_pairs else lp

    def pairs(self, wc, wo):
        """(C, P) log-density of each distance reference's pair term."""
        if not len(self.m.pairs):
            return np.zeros((len(wc), 0))
        return self._pairs(*self.coords.from_work(wc, wo))

    def _pairs(self, cams, objs):
        if not len(self.m.pairs):
            return np.zeros((len(cams), 0))
        with np.errstate(all="ignore"):
            lp = -self.m.pair_terms(cams, objs, self.T)
        return np.where(np.isfinite(lp), lp, -np.inf)

    def camera(self, wc):
        cams = self.coords.camera_from_work(wc)
        with np.errstate(all="ignore"):
            lp = -self.m.camera_term(cams, self.T) + np.sum(wc[:, _CAMERA_LOG & self.m.camera_free], axis=1)
        ok = np.all((cams >= self.m.camera_lower) & (cams <= self.m.camera_upper), axis=1) & np.isfinite(lp)
        return np.where(ok, lp, -np.inf)


def _chol(cov: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Cholesky factor of ``cov`` on its free rows and columns, zero elsewhere; (…, k, k)."""
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


def _laplace(model: FrameModel, wc0, wo0, temperature):
    D = derivatives(model, wc0, wo0, temperature, with_jacobian=True)
    m = model.n_objects
    try:
        Sc, Ao, B = D.covariance_blocks()
        ok = np.all(np.isfinite(Sc)) and np.all(np.isfinite(Ao)) and np.all(np.linalg.eigvalsh(Sc[np.ix_(model.camera_free, model.camera_free)]) > 0)
    except np.linalg.LinAlgError:
        ok = False
    if not ok:  # a diagonal fallback: conditional variances along the axes
        Sc = np.diag(1.0 / np.maximum(np.abs(np.diag(D.H_cc)), 1e-6))
        Ao = np.array([np.diag(1.0 / np.maximum(np.abs(np.diag(D.H_oo[i])), 1e-6)) for i in range(m)])
        B = np.zeros((m, 7, 5))
    B = B * model.object_free[:, :, None] * model.camera_free[None, None, :]
    return Sc, Ao, B, ok


def _reestimate(model, wc_hist, wo_hist, Sc0, Ao0, B0):
    """Covariances and shear from warm-up draws (pooled over chains), blended with the Laplace
    ones (80 % / 20 %) so that a short warm-up cannot make them singular."""
    cf, of = model.camera_free, model.object_free
    C = wc_hist.reshape(-1, 5)
    O = wo_hist.reshape(-1, model.n_objects, 7)
    cm, om = C.mean(axis=0), O.mean(axis=0)
    dc, do = C - cm, O - om
    n = len(C)
    Scc = dc.T @ dc / (n - 1)
    Scc = np.where(np.outer(cf, cf), Scc, 0.0)
    Soo = np.einsum("nmi,nmj->mij", do, do) / (n - 1)
    Soc = np.einsum("nmi,nc->mic", do, dc) / (n - 1)
    idx = np.flatnonzero(cf)
    inv = np.zeros((5, 5))
    if idx.size:
        inv[np.ix_(idx, idx)] = np.linalg.pinv(Scc[np.ix_(idx, idx)])
    B = np.einsum("mic,cd->mid", Soc, inv) * of[:, :, None] * cf[None, None, :]
    cond = Soo - np.einsum("mic,mjc->mij", B, Soc)
    Sc = 0.8 * Scc + 0.2 * Sc0
    Ao = 0.8 * cond + 0.2 * Ao0
    Bn = 0.8 * B + 0.2 * B0
    return Sc, Ao, Bn


def sample_frame(model: FrameModel, map_est: FrameMAP, *, settings: FrameSamplerSettings | None = None,
                 rng=None, temperature: float = 1.0, progress: bool = False) -> tuple[FrameDraws, FrameDiagnostics]:
    """Sample the posterior of ``model`` from its MAP (module docstring).

    Returns the draws (natural parameters) and the diagnostics.
    """
    s = settings or FrameSamplerSettings()
    rng = np.random.default_rng(rng)
    t0 = time.perf_counter()
    m, C = model.n_objects, s.n_chains
    cf, of = model.camera_free, model.object_free
    target = _Target(model, temperature)
    coords = FrameCoords(model)
    wc0, wo0 = (a[0] for a in coords.to_work(map_est.camera[None], map_est.objects[None]))
    Sc, Ao, B, laplace_ok = _laplace(model, wc0, wo0, temperature)
    Sc0, Ao0, B0 = Sc, Ao, B
    kc = int(cf.sum())
    ko = of.sum(axis=1)
    sc = 2.38 / np.sqrt(max(kc, 1))
    so = 2.38 / np.sqrt(np.maximum(ko, 1))
    Lc = _chol(Sc, cf)
    Lo = np.array([_chol(Ao[i], of[i]) for i in range(m)])
    # start: over-dispersed draws from the Laplace approximation
    wc = wc0 + 1.2 * rng.standard_normal((C, 5)) @ Lc.T
    wt = wo0 + 1.2 * np.einsum("mij,cmj->cmi", Lo, rng.standard_normal((C, m, 7)))
    shear = lambda wc_: np.einsum("mik,ck->cmi", B, wc_ - wc0)
    wo = wt + shear(wc)
    lp_c, (lp_o, lp_p) = target.camera(wc), target.objects(wc, wo, with_pairs=True)
    bad = ~(np.isfinite(lp_c) & np.all(np.isfinite(lp_o), axis=1) & np.all(np.isfinite(lp_p), axis=1))
    wc[bad], wt[bad] = wc0, wo0
    wo = wt + shear(wc)
    lp_c, (lp_o, lp_p) = target.camera(wc), target.objects(wc, wo, with_pairs=True)
    if not (np.all(np.isfinite(lp_c)) and np.all(np.isfinite(lp_o)) and np.all(np.isfinite(lp_p))):
        raise RuntimeError("the MAP has zero posterior density: cannot start the sampler")
    # objects coupled by a distance reference never move in the same object step: the objects are
    # updated colour by colour (one colour, all of them, when nothing couples them)
    colours = _colour(m, model.pairs)
    incidence = np.zeros((m, len(model.pairs)))
    for p_, (i_, j_) in enumerate(model.pairs):
        incidence[i_, p_] = incidence[j_, p_] = 1.0
    acc_c, acc_o = [], []

    mc, mt = wc0.copy(), wo0.copy()  # centres of the independence proposals (camera; sheared objects)
    Lci, Loi = np.linalg.pinv(Lc), np.linalg.pinv(Lo)

    def log_q_obj(x):  # (C, m): Student-t log-density (up to constants) of the object proposal
        w = np.einsum("mij,cmj->cmi", Loi, x - mt) / _IND_SCALE
        return -0.5 * (_IND_DOF + ko) * np.log1p(np.sum(w * w, axis=-1) / _IND_DOF)

    def log_q_cam(x):
        w = (x - mc) @ Lci.T / _IND_SCALE
        return -0.5 * (_IND_DOF + kc) * np.log1p(np.sum(w * w, axis=-1) / _IND_DOF)

    def t_draws(shape):
        return rng.standard_normal(shape) / np.sqrt(rng.chisquare(_IND_DOF, shape[:-1] + (1,)) / _IND_DOF)

    tries = s.tries

    def step(adapt_rate: float | None, independent: bool):
        nonlocal wc, wt, wo, lp_c, lp_o, lp_p, sc, so
        # objects, given the camera (and, colour by colour, given the objects they are coupled to)
        a = np.zeros((C, m), bool)
        for colour in colours:
            if independent and tries > 1:
                ac = _object_tries(colour)
                a |= ac
                continue
            if independent:
                prop = mt + _IND_SCALE * np.einsum("mij,cmj->cmi", Lo, t_draws((C, m, 7)))
                corr = log_q_obj(wt) - log_q_obj(prop)
            else:
                prop = wt + so[None, :, None] * np.einsum("mij,cmj->cmi", Lo, rng.standard_normal((C, m, 7)))
                corr = 0.0
            if colour is not None:
                prop = np.where(colour[None, :, None], prop, wt)
            new = prop + (wo - wt)
            lp_new, lp_p_new = target.objects(wc, new, with_pairs=True)
            delta = lp_new - lp_o + corr
            if lp_p.shape[1]:
                with np.errstate(invalid="ignore"):
                    delta = delta + (lp_p_new - lp_p) @ incidence.T
            with np.errstate(invalid="ignore"):
                ac = np.log(rng.uniform(size=(C, m))) < delta
            if colour is not None:
                ac &= colour[None, :]
            wt = np.where(ac[..., None], prop, wt)
            wo = np.where(ac[..., None], new, wo)
            lp_o = np.where(ac, lp_new, lp_o)
            if lp_p.shape[1]:
                moved = (ac.astype(float) @ incidence) > 0  # (C, P): one end at most moved
                lp_p = np.where(moved, lp_p_new, lp_p)
            a |= ac
        # the camera, objects moving along their regression
        if kc:
            if independent and tries > 1:
                b = _camera_tries()
            else:
                if independent:
                    pc = mc + _IND_SCALE * t_draws((C, 5)) @ Lc.T
                    corr = log_q_cam(wc) - log_q_cam(pc)
                else:
                    pc = wc + sc * rng.standard_normal((C, 5)) @ Lc.T
                    corr = 0.0
                new = wt + shear(pc)
                lpc_new, (lpo_new, lpp_new) = target.camera(pc), target.objects(pc, new, with_pairs=True)
                with np.errstate(invalid="ignore"):
                    b = np.log(rng.uniform(size=C)) < ((lpc_new + lpo_new.sum(axis=1) + lpp_new.sum(axis=1))
                                                       - (lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1)) + corr)
                _accept_camera(b, pc, new, lpc_new, lpo_new, lpp_new)
        else:
            b = np.ones(C, bool)
        if adapt_rate is not None and not independent:
            so = so * np.exp(adapt_rate * (a.mean(axis=0) - 0.3))
            sc = sc * np.exp(adapt_rate * (b.mean() - 0.3))
        return a, b

    def _accept_camera(b, pc, new, lpc_new, lpo_new, lpp_new):
        nonlocal wc, wo, lp_c, lp_o, lp_p
        wc = np.where(b[:, None], pc, wc)
        wo = np.where(b[:, None, None], new, wo)
        lp_c = np.where(b, lpc_new, lp_c)
        lp_o = np.where(b[:, None], lpo_new, lp_o)
        lp_p = np.where(b[:, None], lpp_new, lp_p)

    def _object_tries(colour):
        """The objects' independence step with ``tries`` tries each (one vectorised evaluation)."""
        nonlocal wt, wo, lp_o, lp_p
        props = mt + _IND_SCALE * np.einsum("mij,ckmj->ckmi", Lo, t_draws((C, tries, m, 7)))  # (C, k, m, 7)
        if colour is not None:  # the other objects stay where they are
            props = np.where(colour[None, None, :, None], props, wt[:, None])
        news = props + (wo - wt)[:, None]
        own, pair = target.objects(np.repeat(wc, tries, axis=0), news.reshape(C * tries, m, 7), with_pairs=True)
        own = own.reshape(C, tries, m)
        lp_new, lp_cur = own, lp_o
        if lp_p.shape[1]:  # each object's own terms plus the pair terms it touches (its partners fixed)
            pair = pair.reshape(C, tries, -1)
            with np.errstate(invalid="ignore"):
                lp_new = own + pair @ incidence.T
                lp_cur = lp_o + lp_p @ incidence.T
        log_q = log_q_obj(props.reshape(C * tries, m, 7)).reshape(C, tries, m)
        j, ok = multiple_try_pick(np.moveaxis(lp_new - log_q, 1, -1), lp_cur - log_q_obj(wt), rng)  # (C, m)
        if colour is not None:
            ok &= colour[None, :]
        take = lambda x: np.take_along_axis(x, j.reshape((C, 1, m) + (1,) * (x.ndim - 3)), axis=1)[:, 0]
        wt = np.where(ok[..., None], take(props), wt)
        wo = np.where(ok[..., None], take(news), wo)
        lp_o = np.where(ok, take(own), lp_o)
        if lp_p.shape[1]:
            # a pair term changes when one of its ends moved (never both: they differ in colour)
            for p_, (i_, k_) in enumerate(model.pairs):
                for end in (i_, k_):
                    moved = ok[:, end]
                    val = np.take_along_axis(pair[:, :, p_], j[:, end][:, None], axis=1)[:, 0]
                    lp_p[:, p_] = np.where(moved, val, lp_p[:, p_])
        return ok

    def _camera_tries():
        """The camera's independence step with ``tries`` tries (objects along their regression)."""
        pcs = mc + _IND_SCALE * t_draws((C, tries, 5)) @ Lc.T  # (C, k, 5)
        flat = pcs.reshape(C * tries, 5)
        news = (np.repeat(wt, tries, axis=0) + shear(flat)).reshape(C, tries, m, 7)
        lpc, (lpo, lpp) = target.camera(flat), target.objects(flat, news.reshape(C * tries, m, 7), with_pairs=True)
        with np.errstate(invalid="ignore"):
            total = (lpc + lpo.sum(axis=1) + lpp.sum(axis=1)).reshape(C, tries)
            cur = lp_c + lp_o.sum(axis=1) + lp_p.sum(axis=1)
        j, ok = multiple_try_pick(total - log_q_cam(flat).reshape(C, tries), cur - log_q_cam(wc), rng)
        sel = np.arange(C) * tries + j
        _accept_camera(ok, pcs[np.arange(C), j], news[np.arange(C), j], lpc[sel], lpo[sel], lpp[sel])
        return ok

    from .progress import progress_bar

    with progress_bar(progress, s.warmup + s.max_iterations, desc="sampling", unit="it") as bar:
        hist_c, hist_o = [], []
        marks = {int(0.4 * s.warmup), int(0.7 * s.warmup)}
        for t in range(s.warmup):
            step(1.0 / (t + 10) ** 0.6 * 3.0, independent=t % 2 == 1)
            hist_c.append(wc.copy())
            hist_o.append(wo.copy())
            if t in marks:
                keep = slice(len(hist_c) // 2, None)
                Sc, Ao, B = _reestimate(model, np.array(hist_c[keep]), np.array(hist_o[keep]), Sc0, Ao0, B0)
                Lc = _chol(Sc, cf)
                Lo = np.array([_chol(Ao[i], of[i]) for i in range(m)])
                Lci, Loi = np.linalg.pinv(Lc), np.linalg.pinv(Lo)
                sc = 2.38 / np.sqrt(max(kc, 1))
                so = 2.38 / np.sqrt(np.maximum(ko, 1))
                wt = wo - shear(wc)
                hc = np.array(hist_c[keep]).reshape(-1, 5)
                mc = hc.mean(axis=0)
                mt = (np.array(hist_o[keep]) - np.einsum("mik,tck->tcmi", B, np.array(hist_c[keep]) - wc0)).reshape(-1, m, 7).mean(axis=0)
                hist_c, hist_o = [], []
            bar.update(1)
        # main phase
        cams_d, objs_d = [], []
        thin, it, ok = 1, 0, False
        diag = None
        chunk = s.chunk
        while it < s.max_iterations:
            chunk = min(chunk, s.max_iterations - it)
            for _ in range(chunk):
                a, b = step(None, independent=it % 2 == 1)
                acc_o.append(a.mean(axis=0))
                acc_c.append(b.mean())
                it += 1
                if it % thin == 0:
                    cams, objs = coords.from_work(wc, wo)
                    cams_d.append(cams)
                    objs_d.append(objs)
                if len(cams_d) >= 2 * s.max_draws:
                    cams_d, objs_d, thin = cams_d[1::2], objs_d[1::2], thin * 2
            bar.update(chunk)
            arr, names = _columns(model, np.array(cams_d), np.array(objs_d), map_est)
            # a cheap look first: while the raw split R-hat fails by far (it runs above the ranked
            # one on heavy tails, hence the margin), the full check cannot pass, so skip it and
            # sample on (R-hat − 1 falls about as 1 / iterations)
            with np.errstate(all="ignore"):
                raw = float(np.nanmax(np.append(rhat_split_raw(arr), 1.0)))
            need = it * (raw - 1.0) / (3.0 * (s.max_rhat - 1.0)) if s.max_rhat > 1.0 else it
            if raw <= 1.0 + 3.0 * (s.max_rhat - 1.0) or it >= s.max_iterations or diag is None:
                diag = _diagnose(arr, names, s)
                if diag["ok"]:
                    ok = True
                    break
                rate = max(diag["min_ess"], 1.0) / it
                need = max(need, s.min_ess / rate)
                if diag["max_rhat"] > s.max_rhat:
                    need = max(need, it * (diag["max_rhat"] - 1.0) / (s.max_rhat - 1.0) if s.max_rhat > 1.0 else it)
            # the next check where the slowest quantity should pass (checks are costly)
            chunk = int(np.clip(1.2 * need - it, s.chunk, 2 * it))
    cams = np.transpose(np.array(cams_d), (1, 0, 2))
    objs = np.transpose(np.array(objs_d), (1, 0, 2, 3))
    acceptance = {"camera": float(np.mean(acc_c)), "objects": float(np.mean(acc_o))}
    warn = []
    if not ok:
        warn.append(f"not converged after {it} iterations: " + "; ".join(diag["why"]))
    if not laplace_ok:
        warn.append("the Laplace approximation at the MAP was not positive definite (diagonal proposals used)")
    return FrameDraws(cams, objs), FrameDiagnostics(
        C, s.warmup, it, thin, diag["ess_bulk"], diag["r_hat"], acceptance, ok, tuple(warn),
        time.perf_counter() - t0, {"laplace_positive_definite": bool(laplace_ok)})


def _colour(m: int, pairs: np.ndarray) -> list:
    """Groups of objects no two of which are coupled (greedy graph colouring), as (m,) masks;
    ``[None]`` (every object at once) when nothing couples them."""
    if not len(pairs):
        return [None]
    colour = -np.ones(m, int)
    for i in range(m):
        taken = {colour[j] for a, b in pairs for j in ((b,) if a == i else (a,) if b == i else ())}
        colour[i] = next(c for c in range(m) if c not in taken)
    return [colour == c for c in range(colour.max() + 1)]


def _columns(model: FrameModel, cams: np.ndarray, objs: np.ndarray, map_est: FrameMAP) -> tuple[np.ndarray, list[str]]:
    """The quantities checked: every free parameter (yaw unwrapped around the MAP) and each
    object's ground distance, as (chain, draw, k), with their names."""
    cols, names = [], []
    cams = np.transpose(cams, (1, 0, 2))  # (chain, draw, 5)
    objs = np.transpose(objs, (1, 0, 2, 3))
    for j in np.flatnonzero(model.camera_free):
        cols.append(cams[..., j])
        names.append(f"camera.{CAMERA_NAMES[j]}")
    for i, o in enumerate(model.objects):
        for j in np.flatnonzero(model.object_free[i]):
            x = objs[..., i, j]
            if j == O_YAW:
                x = map_est.objects[i, O_YAW] + (x - map_est.objects[i, O_YAW] + np.pi) % (2 * np.pi) - np.pi
            cols.append(x)
            names.append(f"{o.id}.{OBJECT_NAMES[j]}")
        cols.append(np.hypot(objs[..., i, 0], objs[..., i, 1]))
        names.append(f"{o.id}.distance_m")
    return np.stack(cols, axis=-1), names


def _diagnose(arr: np.ndarray, names: list[str], s: FrameSamplerSettings) -> dict:
    """Bulk ESS and rank-normalised R-hat of every column of ``arr``; whether the stopping rule
    is met."""
    eb, rh = ess_bulk_rhat(arr)
    why = []
    if np.nanmin(eb) < s.min_ess:
        k = int(np.nanargmin(eb))
        why.append(f"bulk ESS of {names[k]} {eb[k]:.0f} < {s.min_ess:g}")
    if np.nanmax(rh) > s.max_rhat:
        k = int(np.nanargmax(rh))
        why.append(f"R-hat of {names[k]} {rh[k]:.3f} > {s.max_rhat:g}")
    return {"ok": not why, "why": why, "min_ess": float(np.nanmin(eb)), "max_rhat": float(np.nanmax(rh)),
            "ess_bulk": dict(zip(names, eb.tolist())), "r_hat": dict(zip(names, rh.tolist()))}
