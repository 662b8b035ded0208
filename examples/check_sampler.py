"""Check the package's sampler against long plain-emcee runs on the same posteriors.

For simulated scenes, sample the paper model's posterior (MAP handedness) with
:func:`creference_bayes.inference.sampling.sample` and with two long runs of emcee's own ``DEMove``
(64 walkers, ``--steps`` steps, first quarter discarded), and print both means and sds and the
z-score of the difference of the means (Monte Carlo errors from each run's autocorrelation time).
Slow: about half a minute per scene and core. A check that it runs:
``python examples/check_sampler.py --seeds 1 --steps 400 --min-ess 200``.

    python examples/check_sampler.py --seeds 1 2 3 --tier medium            # with references
    python examples/check_sampler.py --seeds 1 2 3 --tier low --no-references

``--frame N``: the frame sampler instead (:func:`creference_bayes.inference.frame_sampler.sample_frame`,
blocked Metropolis-within-Gibbs with its default settings) on simulated street frames of N objects,
against a long plain random-walk Metropolis run on the whole joint posterior (8 chains, ``--steps``
steps each, the Laplace covariance at the MAP as its proposal shape, first quarter discarded): an
independent algorithm with none of the sampler's blocking, shear or independence steps. Compared:
each object's distance, x, z and yaw (wrapped) and the free camera parameters; Monte Carlo errors
from bulk ESS. A check that it runs: ``python examples/check_sampler.py --frame 3 --seeds 1 --steps 2000``.
``--distances K`` adds K workers' distances between pairs of targets (the terms that couple two
objects, sampled colour by colour).

    python examples/check_sampler.py --frame 10 --seeds 1 2 3 --steps 60000
    python examples/check_sampler.py --frame 5 --distances 3 --seeds 1 2 3 --steps 60000
"""

from __future__ import annotations

import argparse
import time
import warnings

import emcee
import numpy as np

from creference_bayes.camera_setup import setup_camera
from creference_bayes.core.metrology import aggregate_references
from creference_bayes.models.params import PARAM_NAMES
from creference_bayes.inference.optimize import optimize_map
from creference_bayes.pipeline import build_models
from creference_bayes.inference.posterior import LogPosterior, laplace_scales
from creference_bayes.inference.sampling import SamplerSettings, sample
from creference_bayes.io.scene import parse_scene
from creference_bayes.bench.simulate import simulate_scene


def posterior(seed: int, tier: str, references: bool):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = parse_scene(simulate_scene(np.random.default_rng(seed), tier=tier, principal_offset=0.05))
    setup = setup_camera(scene)
    constraints = aggregate_references(scene, setup.aggregation_camera).constraints if references else None
    models = build_models(scene, setup, model="paper", constraints=constraints)
    m = optimize_map(models, rng=0)
    model = next(x for x in models if x.handedness == m.handedness)
    return model, LogPosterior(model, model.default_temperature), m.params[model.free]


def reference_run(lp, start, steps, rng):
    """Two plain emcee DEMove runs; returns (n, d) draws and their τ (steps)."""
    runs, taus = [], []
    for _ in range(2):
        s = emcee.EnsembleSampler(64, start.shape[1], lp, vectorize=True, moves=emcee.moves.DEMove())
        s._random = np.random.RandomState(int(rng.integers(2**31)))
        s.run_mcmc(start[rng.integers(len(start), size=64)], steps)
        chain = s.get_chain(discard=steps // 4)
        runs.append(chain.reshape(-1, start.shape[1]))
        taus.append(emcee.autocorr.integrated_time(chain, quiet=True))
    return np.vstack(runs), np.max(taus, axis=0)


def frame_reference_run(model, map_est, steps: int, rng, n_chains: int = 8):
    """Plain random-walk Metropolis on the joint working coordinates; returns natural draws
    (cameras (n, 5), objects (n, m, 7)) and the seconds it took."""
    from creference_bayes.inference.frame_coords import FrameCoords
    from creference_bayes.inference.frame_sampler import _Target, _chol, _laplace

    t0 = time.perf_counter()
    target, coords = _Target(model, 1.0), FrameCoords(model)
    m = model.n_objects
    wc0, wo0 = (a[0] for a in coords.to_work(map_est.camera[None], map_est.objects[None]))
    Sc, Ao, B, _ = _laplace(model, wc0, wo0, 1.0)
    Lc = _chol(Sc, model.camera_free)
    Lo = np.array([_chol(Ao[i], model.object_free[i]) for i in range(m)])
    d = int(model.camera_free.sum() + model.object_free.sum())
    step = 2.38 / np.sqrt(d)

    def to_work(zc, zo):  # whitened → working: the Laplace approximation's square root
        wc = wc0 + zc @ Lc.T
        return wc, wo0 + np.einsum("mij,cmj->cmi", Lo, zo) + np.einsum("mik,ck->cmi", B, wc - wc0)

    def logp(zc, zo):
        wc, wo = to_work(zc, zo)
        return target.camera(wc) + target.objects(wc, wo).sum(axis=1) + target.pairs(wc, wo).sum(axis=1)

    zc, zo = np.zeros((n_chains, 5)), np.zeros((n_chains, m, 7))
    lp = logp(zc, zo)
    keep_c, keep_o = [], []
    for it in range(steps):
        pc = zc + step * rng.standard_normal(zc.shape)
        po = zo + step * rng.standard_normal(zo.shape)
        lq = logp(pc, po)
        ok = np.log(rng.random(n_chains)) < lq - lp
        zc[ok], zo[ok], lp[ok] = pc[ok], po[ok], lq[ok]
        if it >= steps // 4:
            keep_c.append(zc.copy())
            keep_o.append(zo.copy())
    zc, zo = np.stack(keep_c, axis=1), np.stack(keep_o, axis=1)  # (chains, n, …)
    wc, wo = to_work(zc.reshape(-1, 5), zo.reshape(-1, m, 7))
    cams, objs = coords.from_work(wc, wo)
    return cams.reshape(n_chains, -1, 5), objs.reshape(n_chains, -1, m, 7), time.perf_counter() - t0


def add_distances(scene: dict, k: int, rng) -> None:
    """Add ``k`` workers' distances between random pairs of the scene's targets: the true ground
    distance between their bottom centres, off by a log-normal factor (sd 0.1), to 0.5 m."""
    targets = scene["targets"]
    for _ in range(min(k, len(targets) * (len(targets) - 1) // 2)):
        i, j = rng.choice(len(targets), 2, replace=False)
        a, b = (np.array(targets[n]["ground_truth"]["location_m"]) for n in (i, j))
        d = float(np.hypot(a[0] - b[0], a[2] - b[2]) * np.exp(rng.normal(0.0, 0.1)))
        scene.setdefault("references", []).append({"targets": [targets[i]["id"], targets[j]["id"]],
                                                   "measure": "distance", "value": max(0.5, round(2 * d) / 2),
                                                   "unit": "m"})


def frame_check(args) -> None:
    """The frame sampler against :func:`frame_reference_run` (module docstring)."""
    from creference_bayes.bench.frame_simulate import simulate_frame
    from creference_bayes.frame_pipeline import build_frame_model
    from creference_bayes.inference.diagnostics import ess_bulk
    from creference_bayes.inference.frame_map import optimize_frame
    from creference_bayes.inference.frame_sampler import FrameSamplerSettings, sample_frame
    from creference_bayes.io.frame_scene import parse_frame
    from creference_bayes.models.frame import CAMERA_NAMES

    print("| seed | quantity | ours mean ± sd | reference mean ± sd | z | sd ratio |")
    print("|---|---|---|---|---|---|")
    worst = []
    for seed in args.seeds:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = simulate_frame(seed, n_objects=args.frame)
            add_distances(scene, args.distances, np.random.default_rng(200 + seed))
            frame = parse_frame(scene)
        model, _ = build_frame_model(frame)
        map_est = optimize_frame(model)
        settings = FrameSamplerSettings.from_options(None if args.min_ess is None else {"min_ess": int(args.min_ess)})
        draws, diag = sample_frame(model, map_est, settings=settings, rng=seed)
        rc, ro, ref_s = frame_reference_run(model, map_est, args.steps, np.random.default_rng(100 + seed))
        oc, oo = draws.cameras, draws.objects  # (chains, n, 5), (chains, n, m, 7)

        def quantities(cams, objs):
            out = {n: cams[..., k] for k, n in enumerate(CAMERA_NAMES) if model.camera_free[k]}
            yaw0 = map_est.objects[:, 2]
            for i in range(model.n_objects):
                out[f"object {i} distance"] = np.hypot(objs[..., i, 0], objs[..., i, 1])
                out[f"object {i} x"], out[f"object {i} z"] = objs[..., i, 0], objs[..., i, 1]
                out[f"object {i} yaw"] = (objs[..., i, 2] - yaw0[i] + np.pi) % (2 * np.pi) - np.pi
            return out

        ours, ref = quantities(oc, oo), quantities(rc, ro)
        for name in ours:
            a, b = ours[name], ref[name]
            ess_a, ess_b = float(ess_bulk(a[..., None])[0]), float(ess_bulk(b[..., None])[0])
            se2 = a.var() / ess_a + b.var() / ess_b
            z = (a.mean() - b.mean()) / np.sqrt(se2)
            worst.append((abs(z), a.std() / b.std(), ess_b))
            if name.startswith("object") and not name.endswith("distance"):
                continue  # the table shows the camera and the distances; the summary line has all
            print(f"| {seed} | {name} | {a.mean():.4g} ± {a.std():.3g} | {b.mean():.4g} ± {b.std():.3g} "
                  f"| {z:+.2f} | {a.std() / b.std():.3f} |", flush=True)
        print(f"| {seed} | (run) | {diag.seconds:.1f} s, {diag.iterations} iterations, converged {diag.converged} "
              f"| {ref_s:.1f} s, {args.steps} steps × 8 chains | | |", flush=True)
    z, ratio, ess = np.array(worst).T
    print(f"\n{len(z)} quantities: |z| median {np.median(z):.2f}, 95th percentile {np.percentile(z, 95):.2f}, "
          f"max {z.max():.2f} (a standard normal: 0.67, 1.96); sd ratio {ratio.min():.3f}–{ratio.max():.3f}; "
          f"reference bulk ESS min {ess.min():.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--tier", default="medium")
    ap.add_argument("--no-references", action="store_true")
    ap.add_argument("--steps", type=int, default=20000, help="steps of each plain emcee run (default: %(default)s)")
    ap.add_argument("--min-ess", type=float, default=None,
                    help="bulk ESS our sampler runs to (default: the package's, 1000)")
    ap.add_argument("--frame", type=int, default=None, metavar="N",
                    help="check the frame sampler on street frames of N objects instead")
    ap.add_argument("--distances", type=int, default=0, metavar="K",
                    help="with --frame: add K workers' distances between random pairs of targets")
    args = ap.parse_args()
    if args.frame is not None:
        frame_check(args)
        return
    settings = SamplerSettings.from_options(None if args.min_ess is None else {"min_ess": args.min_ess})
    print("| seed | parameter | ours mean ± sd | emcee mean ± sd | z | sd ratio | ours: s, steps, max τ |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        model, lp, center = posterior(seed, args.tier, not args.no_references)
        t0 = time.perf_counter()
        chains = sample(lp, center, laplace_scales(lp, center).cov, rng=seed, settings=settings,
                        log_mask=model.bounds.lower[model.free] > 0)
        seconds = time.perf_counter() - t0
        ours = chains.draws().reshape(-1, len(center))
        ess_ours = chains.chain.shape[1] * chains.chain.shape[2] * (chains.n_steps - chains.burn_in) / chains.autocorr_time
        ref, tau_ref = reference_run(lp, ours, args.steps, np.random.default_rng(100 + seed))
        ess_ref = 2 * 64 * (args.steps - args.steps // 4) / np.maximum(tau_ref, 1.0)
        names = [n for n, f in zip(PARAM_NAMES, model.free) if f]
        for i, name in enumerate(names):
            a, b = ours[:, i], ref[:, i]
            z = (a.mean() - b.mean()) / np.sqrt(a.var() / ess_ours[i] + b.var() / ess_ref[i])
            run = f"{seconds:.2f} s, {chains.warmup_steps}+{chains.n_steps}, {chains.autocorr_time.max():.1f}" if i == 0 else ""
            print(f"| {seed} | {name} | {a.mean():.4g} ± {a.std():.3g} | {b.mean():.4g} ± {b.std():.3g} "
                  f"| {z:+.2f} | {a.std() / b.std():.3f} | {run} |", flush=True)


if __name__ == "__main__":
    main()
