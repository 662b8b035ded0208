"""Time the MAP and the whole posterior per scene, and show where the time goes.

Run on one core, as the speed goal is stated:

    taskset -c 0 python examples/profile_posterior.py                    # the shipped example
    taskset -c 0 python examples/profile_posterior.py --study            # 13 annotations, 20 refs
    taskset -c 0 python examples/profile_posterior.py --study --no-horizon   # pitch and roll free
    taskset -c 0 python examples/profile_posterior.py scene.json --repeat 10
    taskset -c 0 python examples/profile_posterior.py --study --profile  # cProfile of one estimate

``--study`` simulates scenes the size of the paper's study (13 target annotations, 20 references,
mild noise: 2 px corners, 5 px lines, 10 % measurements; pitch, roll up to 5°, an off-centre
principal point), one per seed. Imports (arviz alone takes about a second) are paid once per
process and are excluded: the script runs one untimed estimate first. "posterior" is the whole
step after the MAP: the Laplace start, the warm-up and main sampling to the requested ESS, the
summaries, the diagnostics and the InferenceData.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import statistics
import time
import warnings

import numpy as np

import creference_bayes as cb
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.cli.main import example_scene_path
from creference_bayes.io.scene import load_scene, parse_scene


def study_scene(seed: int, horizon: bool = True):
    """A scene of the paper's study size (module docstring)."""
    d = simulate_scene(np.random.default_rng([9, seed]), tier="low", n_references=20,
                       n_target_annotations=13, principal_offset=0.05, roll_deg=5.0)
    if not horizon:
        del d["horizon"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("scene", nargs="?", default=None, help="a scene file (default: the shipped example)")
    ap.add_argument("--study", action="store_true", help="simulated scenes of the study's size instead")
    ap.add_argument("--no-horizon", action="store_true", help="with --study: drop the horizon")
    ap.add_argument("--repeat", type=int, default=5, help="seeds (scenes with --study) timed (default 5)")
    ap.add_argument("--profile", action="store_true", help="cProfile one full estimate")
    ap.add_argument("--sampling", default=None, metavar="JSON",
                    help='sampler settings to try, e.g. \'{"n_walkers": 24}\' (default: the package\'s)')
    args = ap.parse_args(argv)
    sampling = None if args.sampling is None else json.loads(args.sampling)

    def scene_for(seed):
        if args.study:
            return study_scene(seed, horizon=not args.no_horizon)
        return load_scene(args.scene or example_scene_path())

    cb.estimate(scene_for(0), seed=0)  # imports and first-call costs, untimed
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        cb.estimate(scene_for(1), seed=1)
        prof.disable()
        pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        pstats.Stats(prof).sort_stats("tottime").print_stats(20)
        return

    rows = []
    for seed in range(1, args.repeat + 1):
        scene = scene_for(seed)
        w0, c0 = time.perf_counter(), time.process_time()
        r = cb.estimate(scene, seed=seed, sampling=sampling)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        d = r.to_dict()
        g = d["diagnostics"]
        errors = [o["evaluation"]["location_pct_error"] for o in d["objects"] if "evaluation" in o]
        rows.append({"map": d["map_info"]["seconds"], "posterior": g["seconds"], "total": wall, "cpu": cpu,
                     "steps": g["warmup"] + g["iterations"], "ess": g["min_ess_bulk"], "converged": g["converged"],
                     "error": statistics.median(errors) if errors else None})
    what = ("study scenes, " + ("no horizon" if args.no_horizon else "horizon given")) if args.study \
        else (args.scene or "the shipped example")
    print(f"{what}; {args.repeat} seeds; seconds per scene (wall, one process)\n")
    print("| stage | median | min | max |")
    print("|---|---|---|---|")
    for k in ("map", "posterior", "total", "cpu"):
        v = [r[k] for r in rows]
        print(f"| {k if k != 'total' else '`estimate()` end to end'} | {statistics.median(v):.3f} | "
              f"{min(v):.3f} | {max(v):.3f} |")
    print(f"\nsteps per chain (warm-up + main): median {statistics.median(r['steps'] for r in rows):.0f}; "
          f"smallest bulk ESS: median {statistics.median(r['ess'] for r in rows):.0f}; "
          f"converged: {sum(r['converged'] for r in rows)}/{len(rows)}")
    errs = [r["error"] for r in rows if r["error"] is not None]
    if errs:
        print(f"MAP location error (median over the objects): median {statistics.median(errs):.2f} %, "
              f"max {max(errs):.2f} %")


if __name__ == "__main__":
    main()
