"""How much a scene's posterior hangs on its pilot, the MAP's camera at which every drawn segment's
reading is fixed (docs/studies/method.md, "The references' advice on real cameras, 100 and 60
scenes").

The scenes of ``advice_study.py predict --cameras real --tiers light --dataset auto`` (the same
seeds, each scene handed what the other ``--n`` scenes' data set says): for each scene asked for,
the starting point and the scene with a second worker's reading of its first repeatable reference
are estimated as the study does; then the scene with the second reading again, its pilot held at
the first estimate's, and the starting point with the second estimate's pilot. Per scene: the
focal length of both estimates' pilots (the camera their segments are read at), the 90 % HDI share of the distance (width over median) of the four
estimates, and the realised gain (points) with the pilot free and held, beside the advice study's
reweighted gain (the starting point's draws reweighted by the reading actually added).

    python examples/pilot_dependence.py --scenes 42 50 --n 100 --out pilot   # a first pass over 100 scenes

The first pass (a MAP per scene, as ``creference batch``'s data-set layer) goes to
``OUT/dataset/`` and is reused by a second run with the same ``--n``.
"""

from __future__ import annotations

import argparse
import sys
import types
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import advice_study as study  # noqa: E402  (the study's scenes and estimates, as it makes them)

from creference_bayes.models.metrology import MetrologyModel  # noqa: E402
from creference_bayes.pipeline import map_state  # noqa: E402
from creference_bayes.workflows.advice import AdviceSettings  # noqa: E402
from creference_bayes.workflows.advice.candidates import candidates  # noqa: E402


def _with_pilot(pilot, estimate, *args):
    """``estimate(*args)`` with every model's pilot held at ``pilot`` (5,)."""
    free = MetrologyModel.set_pilot
    MetrologyModel.set_pilot = lambda self, camera: free(self, np.asarray(pilot, float))
    try:
        return estimate(*args)
    finally:
        MetrologyModel.set_pilot = free


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, nargs="+", default=[0], help="scene numbers k of the study (s%%04d)")
    p.add_argument("--n", type=int, default=100, help="scenes of the data set (the study's --n)")
    p.add_argument("--min-ess", type=float, default=200.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="pilot_dependence", help="folder of the data set's first pass")
    args = p.parse_args(argv)
    if any(k < 0 or k >= args.n for k in args.scenes):
        p.error(f"--scenes: each between 0 and --n - 1 ({args.n - 1}), got {args.scenes}")
    study._CAMERAS = "real"
    study._WHAT_IF["dataset"] = "auto"

    def case_of(seed, k):
        return study._predict_case(seed, k, ["light"], 1, None)

    study._learn_dataset(types.SimpleNamespace(n=args.n, out=args.out, seed=args.seed), case_of)
    print("| scene | pilot focal px, before → after | HDI share before | after | after, pilot held | before, after's pilot "
          "| gain pts: free | held | reweighted |")
    print("|---|---|---|---|---|---|---|---|---|")
    for k in args.scenes:
        name, case = f"s{k:04d}", case_of(args.seed, k)
        base, priors = study._handed(name, case["base"])
        before = study._estimate(base, [args.seed, k, 2], args.min_ess, priors)
        if before is None:
            print(f"| {name} | no estimate | | | | | | | |")
            continue
        r = before["result"]
        every, _ = candidates(base, r.model, *map_state(r.to_dict()))
        rep = next((c for c in every if c.based_on and not c.new_segment and c.line is not None), None)
        after_scene = None if rep is None else case["repeat"](rep.based_on[0])
        if after_scene is None:
            print(f"| {name} | no reference to repeat | | | | | | | |")
            continue
        after_scene = study._handed(name, after_scene)[0]
        after = study._estimate(after_scene, [args.seed, k, 5], args.min_ess, priors)
        held = _with_pilot(r.model.pilot, study._estimate, after_scene, [args.seed, k, 5], args.min_ess, priors)
        moved = _with_pilot(after["result"].model.pilot, study._estimate, base, [args.seed, k, 2], args.min_ess, priors)
        rew = study._reweighted(before, "repeat-ref", after_scene, AdviceSettings(objective="hdi"))
        share = [float(np.sum(e["share"])) for e in (before, after, held, moved)]
        print(f"| {name} | {r.model.pilot[0]:.0f} → {after['result'].model.pilot[0]:.0f} | {share[0]:.3f} | "
              f"{share[1]:.3f} | {share[2]:.3f} | {share[3]:.3f} | {100 * (share[0] - share[1]):+.1f} | "
              f"{100 * (share[0] - share[2]):+.1f} | {'–' if rew is None else f'{rew:+.1f}'} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
