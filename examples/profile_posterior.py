"""Time the MAP and the whole posterior per target, and show where the time goes.

Run on one core, as the issue asks:

    taskset -c 0 python examples/profile_posterior.py                 # the shipped example
    taskset -c 0 python examples/profile_posterior.py scene.json --repeat 10
    taskset -c 0 python examples/profile_posterior.py --profile      # cProfile of one estimate

Imports (arviz alone takes about a second) are paid once per process and are excluded: the
script runs one untimed estimate first. "posterior" is the whole step after the MAP: the
Laplace start, the warm-up and main sampling to the requested ESS, the summaries, the
diagnostics and the InferenceData.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import time

import numpy as np

import creference_bayes as cb
from creference_bayes.cli.main import example_scene_path
from creference_bayes.core.geometry import Camera
from creference_bayes.core.metrology import aggregate_references
from creference_bayes.inference.optimize import optimize_map, preset_bounds
from creference_bayes.pipeline import build_models
from creference_bayes.inference.posterior import LogPosterior, laplace_scales
from creference_bayes.inference.sampling import sample
from creference_bayes.io.scene import load_scene
from creference_bayes.inference.summary import posterior_arrays, summarise, to_inference_data


class _Clock:
    """Wall and CPU seconds of consecutive stages."""

    def __init__(self):
        self.wall, self.cpu = {}, {}
        self._w, self._c = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        w, c = time.perf_counter(), time.process_time()
        self.wall[name], self.cpu[name] = w - self._w, c - self._c
        self._w, self._c = w, c


def stages(scene, seed: int) -> tuple[dict, dict, dict]:
    """Wall and CPU seconds per stage of one estimate (the steps of :func:`cb.estimate`)."""
    clock = _Clock()
    camera = Camera.from_scene(scene)
    bounds = preset_bounds("default", scene.image_width, scene.image_height)
    report = aggregate_references(scene, camera, focal_range_px=(bounds.lower[4], bounds.upper[4]))
    models = build_models(scene, camera=camera, constraints=report.constraints)
    rng = np.random.default_rng(seed)
    m = optimize_map(models, rng=rng)
    clock.lap("map")
    model = next(x for x in models if x.handedness == m.handedness)
    lp = LogPosterior(model)
    lap = laplace_scales(lp, m.params[model.free])
    clock.lap("laplace")
    chains = sample(lp, m.params[model.free], lap.cov, rng=rng, log_mask=model.bounds.lower[model.free] > 0)
    clock.lap("sampling")
    arrays = posterior_arrays(chains, model.bounds.lower, model.free)
    summarise(chains, model.bounds.lower, model.free, arrays=arrays)
    clock.lap("summaries")
    to_inference_data(chains, model.bounds.lower, model.free, scene=scene)
    clock.lap("inference_data")
    for t in (clock.wall, clock.cpu):
        t["posterior"] = sum(t[k] for k in ("laplace", "sampling", "summaries", "inference_data"))
        t["total"] = t["map"] + t["posterior"]
    info = {"steps": chains.warmup_steps + chains.n_steps, "calls": chains.info["log_prob_calls"]}
    return clock.wall, clock.cpu, info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(example_scene_path()),
                    help="a creference-scene/1 file (default: the shipped example scene)")
    ap.add_argument("--repeat", type=int, default=5, help="timed estimates (default: %(default)s)")
    ap.add_argument("--profile", action="store_true", help="cProfile one full estimate")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    cb.estimate(scene, seed=0)  # imports and first-call costs, untimed

    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        cb.estimate(scene, seed=1)
        prof.disable()
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        return

    rows = [stages(scene, seed) for seed in range(1, args.repeat + 1)]
    whole = []
    for seed in range(1, args.repeat + 1):
        w0, c0 = time.perf_counter(), time.process_time()
        r = cb.estimate(scene, seed=seed)
        whole.append((time.perf_counter() - w0, time.process_time() - c0, r.diagnostics.converged))
    keys = ["map", "laplace", "sampling", "summaries", "inference_data", "posterior", "total"]
    print(f"scene {args.scene}; {args.repeat} seeds; seconds per target\n")
    print("| stage | wall median | wall min | wall max | CPU median |")
    print("|---|---|---|---|---|")
    for k in keys:
        v, c = [r[0][k] for r in rows], [r[1][k] for r in rows]
        print(f"| {k} | {statistics.median(v):.3f} | {min(v):.3f} | {max(v):.3f} | {statistics.median(c):.3f} |")
    v, c = [w[0] for w in whole], [w[1] for w in whole]
    print(f"| `estimate()` end to end | {statistics.median(v):.3f} | {min(v):.3f} | {max(v):.3f} | "
          f"{statistics.median(c):.3f} |")
    print(f"\nsteps per walker (warm-up + main): median {statistics.median(r[2]['steps'] for r in rows):.0f}; "
          f"log-probability calls: median {statistics.median(r[2]['calls'] for r in rows):.0f}; "
          f"converged: {sum(w[2] for w in whole)}/{len(whole)}")


if __name__ == "__main__":
    main()
