"""Check the package's sampler against long plain-emcee runs on the same posteriors.

For simulated scenes, sample the paper model's posterior (MAP handedness) with
:func:`creference_bayes.inference.sampling.sample` and with two long runs of emcee's own ``DEMove``
(64 walkers, ``--steps`` steps, first quarter discarded), and print both means and sds and the
z-score of the difference of the means (Monte Carlo errors from each run's autocorrelation time).
Slow: about half a minute per scene and core. A check that it runs:
``python examples/check_sampler.py --seeds 1 --steps 400 --min-ess 200``.

    python examples/check_sampler.py --seeds 1 2 3 --tier medium            # with references
    python examples/check_sampler.py --seeds 1 2 3 --tier low --no-references
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--tier", default="medium")
    ap.add_argument("--no-references", action="store_true")
    ap.add_argument("--steps", type=int, default=20000, help="steps of each plain emcee run (default: %(default)s)")
    ap.add_argument("--min-ess", type=float, default=None,
                    help="bulk ESS our sampler runs to (default: the package's, 1000)")
    args = ap.parse_args()
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
