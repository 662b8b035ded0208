"""Time the estimate by object count: MAP and whole posterior, on simulated street scenes.

    python examples/speed_by_objects.py --counts 3 10 30 --scenes 5

Prints a table (per object count: median and maximum seconds of the MAP and of the posterior,
share converged, median of the smallest bulk ESS and of the largest R-hat). One core: the
estimate limits BLAS to one thread; run it alone on the machine for figures to quote.
"""

from __future__ import annotations

import argparse

import numpy as np

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.pipeline import estimate


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--counts", type=int, nargs="+", default=[3, 10, 30], help="objects per scene")
    p.add_argument("--scenes", type=int, default=5, help="scenes per count")
    p.add_argument("--annotations", type=int, default=5, help="dimension-line sets per object")
    p.add_argument("--setting", choices=("street", "indoor", "outdoor"), default="street")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-steps", type=int, default=20000, help="sampler cap (a tiny budget for tests)")
    args = p.parse_args(argv)
    print(f"{'objects':>8}{'scenes':>7}{'MAP med s':>10}{'MAP max s':>10}{'post med s':>11}{'post max s':>11}"
          f"{'converged':>10}{'min ESS':>9}{'max R-hat':>10}")
    for n in args.counts:
        t_map, t_post, conv, ess, rhat = [], [], [], [], []
        for k in range(args.scenes):
            scene = simulate_scene([args.seed, n, k], setting=args.setting, n_objects=n, sizes="prior", horizon="none",
                                   n_references=0, n_target_annotations=args.annotations, tier="low")
            d = estimate(scene, seed=k, sampling={"max_steps": args.max_steps}, keep_draws=0).to_dict()
            t_map.append(d["map_info"]["seconds"])
            t_post.append(d["diagnostics"]["seconds"])
            conv.append(d["diagnostics"]["converged"])
            ess.append(d["diagnostics"]["min_ess_bulk"])
            rhat.append(d["diagnostics"]["max_r_hat"])
        print(f"{n:>8}{args.scenes:>7}{np.median(t_map):>10.2f}{np.max(t_map):>10.2f}{np.median(t_post):>11.2f}"
              f"{np.max(t_post):>11.2f}{np.mean(conv):>10.0%}{np.median(ess):>9.0f}{np.median(rhat):>10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
