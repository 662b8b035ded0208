"""The one-target frame is the special case: the bench's own scenes through both paths.

    python examples/one_target_frames.py [--per-tier 6] [--tiers ...] [--min-ess 400] [--seed 0]

Every scene of the benchmark's grid (every tier, indoor and outdoor, 5 sets of dimension
lines and the scene's 5 references, the horizon as the bench gives it) is estimated twice with the
same seed: by today's single-target estimate (``creference_bayes.estimate``, the metrology model,
MAP and posterior) and as a one-target frame (``creference_bayes.estimate_frame`` on the scene read
as ``creference-scene/1``). Prints, per tier and overall, the median and mean location error of the
MAP and of the posterior mean, the share of scenes whose true distance lies in the 90 % HDI, and
the paired differences (frame − single) with their standard errors, so "the same numbers within
Monte Carlo error" can be read off.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def _run(per_tier: int, tiers, min_ess: int, seed: int, say=print) -> list[dict]:
    from creference_bayes import estimate, estimate_frame
    from creference_bayes.bench.runner import BenchConfig, _grid, bench_scenes, variant
    from creference_bayes.bench.simulate import TIERS
    from creference_bayes.io.frame_scene import frame_from_scene

    n_out = per_tier // 2
    config = BenchConfig(name="one-target", scenes=_grid({t: (per_tier - n_out, n_out) for t in tiers or TIERS}))
    rows = []
    for sid, scene in bench_scenes(config, seed=seed):
        scene = variant(scene, 5, tuple(range(len(scene.references))))
        loc = np.asarray(scene.ground_truth.location_m)
        dist = float(np.hypot(loc[0], loc[2]))
        t0 = time.perf_counter()
        single = estimate(scene, seed=seed, posterior=True, sampling={"min_ess": min_ess})
        t1 = time.perf_counter()
        frame = estimate_frame(frame_from_scene(scene), seed=seed, sampling={"min_ess": min_ess})
        t2 = time.perf_counter()
        ev = single.evaluation
        o = frame.to_dict()["objects"][0]
        row = {"scene": sid, "tier": sid.split("-")[0], "distance_m": dist,
               "single_map": ev.location_pct_error, "single_mean": ev.posterior_location_pct_error,
               "single_in90": _single_in_hdi(single, dist), "single_s": t1 - t0,
               "frame_map": o["evaluation"]["location_pct_error"],
               "frame_mean": o["evaluation"]["posterior_location_pct_error"],
               "frame_in90": o["evaluation"]["distance_in_hdi"], "frame_s": t2 - t1,
               "frame_converged": bool(frame.converged), "single_converged": bool(single.diagnostics.converged)}
        rows.append(row)
        say(f"{sid}: {dist:5.1f} m  single {row['single_map']:6.2f} % / {row['single_mean']:6.2f} %  "
            f"frame {row['frame_map']:6.2f} % / {row['frame_mean']:6.2f} %  ({row['single_s']:.1f} s, {row['frame_s']:.1f} s)")
    return rows


def _single_in_hdi(result, dist: float) -> bool:
    return bool(result.to_dict()["evaluation"]["in_hdi"]["distance_m"])


def _table(rows: list[dict]) -> str:
    out = ["| tier | scenes | MAP median % (single / frame) | MAP mean % | posterior-mean median % | "
           "90 % HDI holds the distance | paired MAP difference, mean ± se (pp) | time median s |",
           "|---|---|---|---|---|---|---|---|"]
    tiers = sorted({r["tier"] for r in rows}, key=[r["tier"] for r in rows].index) + ["all"]
    for tier in tiers:
        sel = [r for r in rows if tier in ("all", r["tier"])]
        s, f = np.array([r["single_map"] for r in sel]), np.array([r["frame_map"] for r in sel])
        sm, fm = np.array([r["single_mean"] for r in sel]), np.array([r["frame_mean"] for r in sel])
        d = f - s
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
        out.append(f"| {tier} | {len(sel)} | {np.median(s):.2f} / {np.median(f):.2f} | {s.mean():.2f} / {f.mean():.2f} | "
                   f"{np.median(sm):.2f} / {np.median(fm):.2f} | "
                   f"{np.mean([r['single_in90'] for r in sel]):.0%} / {np.mean([r['frame_in90'] for r in sel]):.0%} | "
                   f"{d.mean():+.2f} ± {se:.2f} | "
                   f"{np.median([r['single_s'] for r in sel]):.1f} / {np.median([r['frame_s'] for r in sel]):.1f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--per-tier", type=int, default=6, help="scenes per tier (half indoor, half outdoor)")
    p.add_argument("--tiers", nargs="+", default=None, help="noise tiers (default: all)")
    p.add_argument("--min-ess", type=int, default=400, help="bulk ESS both samplers aim for")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = _run(args.per_tier, args.tiers, args.min_ess, args.seed)
    print()
    print(_table(rows))
    conv = np.mean([r["frame_converged"] for r in rows]), np.mean([r["single_converged"] for r in rows])
    print(f"\nconverged: frame {conv[0]:.0%}, single {conv[1]:.0%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
