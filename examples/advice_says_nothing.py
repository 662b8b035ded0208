"""What the advice states for a request that says nothing, on labels near the bar
(docs/studies/advice.md, "A label near the bar").

    python examples/advice_says_nothing.py
    python examples/advice_says_nothing.py --posteriors 1 2 3 --seeds 3 4 5 6

A street frame of three targets of class priors (two sets of lines each, 2 px, the focal length
known, 8–35 m away; simulated by ``creference_bayes.bench``), its posterior at each of
``--posteriors`` seeds (a short run, ``--min-ess``), and its advice with every set of dimension
lines replaced by an observation whose log-weights are noise of sd 0.5, nothing of the draws:
such a request can make no label good. Per posterior, each label's P(IoU ≥ t) against the bar
(``--bar``), and per request the good labels it is stated to make, averaged over the advice seeds,
beside three of that mean's standard errors (from the stated ones) plus 0.05: once on 100
simulated outcomes with the race (the defaults' share), once on 300 with every request weighed on
all. Prints a Markdown table.
"""

from __future__ import annotations

import argparse

import numpy as np


class SaysNothing:
    """A request whose log-weights are noise of sd ``SPREAD``, nothing of the draws."""

    usable, needs_scale = True, False
    SPREAD = 0.5

    def __init__(self, model, *args):
        self.model = model

    def simulate(self, rng, cams, objs, hands=None):
        self.m, self.rng = len(cams), rng

    def log_ratio(self, cams, objs, base, hands=None):
        return self.SPREAD * self.rng.standard_normal((self.m, len(cams)))


def frame(seed: int):
    """The frame (a parsed scene): three targets, class priors, focal length known."""
    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.scene import parse_scene

    d = simulate_scene([seed, 3], setting="street", tier="low", n_objects=3, n_references=0,
                       n_target_annotations=2, sizes="prior", horizon="none", focal_known=True,
                       distance_range=(8.0, 35.0))
    return parse_scene(d)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frame-seed", type=int, default=5)
    p.add_argument("--posteriors", type=int, nargs="+", default=[1, 2, 3], help="posterior seeds")
    p.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5, 6], help="advice seeds")
    p.add_argument("--bar", type=float, default=None,
                   help="the least P(IoU ≥ t) of a good label (default: 0.02 above the best label's, at the "
                        "first posterior)")
    p.add_argument("--min-ess", type=float, default=200.0)
    p.add_argument("--futures", type=int, nargs=2, default=[100, 300], metavar=("RACED", "ALL"))
    args = p.parse_args(argv)

    from creference_bayes.pipeline import estimate
    from creference_bayes.workflows import advice as advice_module
    from creference_bayes.workflows.advice import AdviceSettings
    from creference_bayes.workflows.advice.inputs import advise_result

    scene = frame(args.frame_seed)
    bar = args.bar
    print("| posterior | labels' P(IoU ≥ t) now (bar) | outcomes | request | stated good labels, mean "
          "| 3 se + 0.05 |")
    print("|---|---|---|---|---|---|")
    real = advice_module.DimsObservation
    try:
        for ps in args.posteriors:
            result = estimate(scene, seed=ps, sampling={"min_ess": args.min_ess})
            advice_module.DimsObservation = SaysNothing
            for futures, race in ((args.futures[0], 3), (args.futures[1], 1)):
                gains = {}
                for s in args.seeds:
                    if bar is None:  # set once, from the labels of the first posterior
                        now = advise_result(result, scene, seed=s, settings=AdviceSettings(n_futures=20,
                                                                                           kinds=("dims",))).now.p_iou
                        bar = round(float(np.max(now)) + 0.02, 2)
                    a = advise_result(result, scene, seed=s, settings=AdviceSettings(
                        n_draws=400, n_futures=futures, min_quality=bar, race_every=race, kinds=("dims",)))
                    for pr in a.predictions:
                        gains.setdefault(pr.candidate.key, []).append((pr.good_gain, pr.good_gain_se))
                now = ", ".join(f"{x:.3f}" for x in a.now.p_iou)
                for key, v in sorted(gains.items()):
                    v = np.array(v)
                    se = np.sqrt(np.mean(v[:, 1] ** 2) / len(v))
                    print(f"| {ps} | {now} ({bar:g}) | {futures}{' raced' if race > 1 else ''} | {key} | "
                          f"{v[:, 0].mean():.3f} | {3 * se + 0.05:.3f} |")
            advice_module.DimsObservation = real
    finally:
        advice_module.DimsObservation = real
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
