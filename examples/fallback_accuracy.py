"""How close an answer's fallback moves the draws to the answered re-estimate, and at what CPU
(docs/studies/advice.md, "The fallback's transport").

The frame of ``tests/test_advice_labels.py``'s fallback test (twelve targets of class priors, one
set of lines each, no horizon, the focal length known; 600 posterior draws): a catalogue size of
the second target simulated at a draw in the tail of its distance (its 5th percentile), and the
camera's mounting at a draw with the camera low (its height's 1st percentile). The advice's
fallback moves the draws, ``--futures`` copies at once as the advice moves a request's futures,
once per seed: as the advice does (the transported draws at their weights where at least
``--min-share`` of them count, else swept) and, a row per ``--sweeps`` count, every future swept
that many times from the transported draws (0: those draws unweighted). Against the posterior of
the scene estimated with the answer (``min_ess`` 1000), per target: the distance's weighted mean
difference over its sd (the worst target per seed: median and max over seeds) and the sd ratio;
and the CPU seconds of one call.

    python examples/fallback_accuracy.py --sweeps 0 4 6 --seeds 8
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sweeps", type=int, nargs="+", default=[0, 6],
                   help="block sweeps after the transport, each a row with every future moved so (0: none)")
    p.add_argument("--seeds", type=int, default=8, help="seeds of the move (default: %(default)s)")
    p.add_argument("--futures", type=int, default=10, help="futures moved at once (default: %(default)s)")
    p.add_argument("--min-ess", type=float, default=1000.0, help="bulk ESS of the two estimates (default: %(default)s)")
    p.add_argument("--targets", type=int, default=12, help="targets of the frame (default: %(default)s, the test's)")
    p.add_argument("--min-share", type=float, default=None,
                   help="effective draws, as a share of the draws, the transport must keep (default: the advice's)")
    args = p.parse_args(argv)

    from conftest import truth_scene  # the tests' scene maker

    import creference_bayes.workflows.advice as advice
    from creference_bayes.io.result import stored_draws
    from creference_bayes.io.scene import parse_scene
    from creference_bayes.pipeline import estimate, result_draws
    from creference_bayes.workflows.advice import fallback
    from creference_bayes.workflows.advice.answers import CATALOGUE_LOG_SD, MOUNTING_SD, with_mounting, with_size
    from creference_bayes.workflows.advice.observe import MountingObservation, SizeObservation

    d, _ = truth_scene(5, m=args.targets, noise_px=2.0, n_annotations=1, sizes_known=False, focal_known=True,
                       depth=(8.0, 35.0))
    scene = parse_scene(d)
    before = estimate(scene, seed=1, sampling={"min_ess": args.min_ess}, keep_draws=100_000)
    cams, objs, _ = result_draws(before.to_dict(), before.model)
    kept = stored_draws(before.to_dict())  # each draw's handedness, which the fallback keeps
    hands = None if kept.handedness is None else kept.handedness.reshape(len(cams), -1)
    keep = np.unique(np.linspace(0, len(cams) - 1, 600).round().astype(int))
    model = before.model
    cams, objs, hands = model.complete_camera(cams[keep]), objs[keep], None if hands is None else hands[keep]
    dist = np.hypot(objs[..., 0], objs[..., 1])
    print("| answer | move | worst target's \\|mean − re-estimate\\| / sd: median / max over seeds "
          "| sd ratio min / mean / max | CPU s a call |")
    print("|---|---|---|---|---|")
    default_sweeps = fallback.FALLBACK_SWEEPS
    for kind in ("size", "mounting"):
        j = int(np.argsort(dist[:, 1] if kind == "size" else cams[:, 3])[len(cams) // (20 if kind == "size" else 100)])
        obs = SizeObservation(model, 1, CATALOGUE_LOG_SD) if kind == "size" else MountingObservation(model, MOUNTING_SD)
        obs.simulate(np.random.default_rng(3), cams[[j]], objs[[j]])
        v = obs.values[0]
        answered = (with_size(scene, scene.targets[1].id, np.exp(v)) if kind == "size"
                    else with_mounting(scene, float(np.exp(v[0])), *map(float, v[1:])))
        after = estimate(answered, seed=2, sampling={"min_ess": args.min_ess}, keep_draws=100_000)
        _, on, _ = result_draws(after.to_dict(), after.model)
        dn = np.hypot(on[..., 0], on[..., 1])
        share = advice.TRANSPORT_ESS_SHARE if args.min_share is None else args.min_share
        for sweeps in [None] + args.sweeps:  # None: the advice's (weighted, else swept where weak)
            fallback.FALLBACK_SWEEPS = default_sweeps if sweeps is None else sweeps
            advice.TRANSPORT_ESS_SHARE = share if sweeps is None else np.inf
            worst, ratios, cpu, ess = [], [], 0.0, []
            for seed in range(args.seeds):
                t = time.process_time()
                _, moved, w = advice._moved(obs, np.zeros(args.futures, int), cams, objs, np.random.default_rng(seed),
                                            1.0, hands)
                cpu += time.process_time() - t
                dm, w = np.hypot(moved[0, ..., 0], moved[0, ..., 1]), w[0]
                mean = w @ dm
                worst.append(np.max(np.abs(mean - dn.mean(0)) / dn.std(0)))
                ratios.append(np.sqrt(w @ (dm - mean) ** 2) / dn.std(0))
                ess.append(1.0 / np.sum(w * w))
            r = np.array(ratios)
            how = (f"weighted (effective draws {np.median(ess):.0f} of {len(cams)})" if sweeps is None else
                   f"{sweeps} sweeps")
            print(f"| {kind} | {how} | {np.median(worst):.3f} / {np.max(worst):.3f} | {r.min():.3f} / {r.mean():.3f} / "
                  f"{r.max():.3f} | {cpu / args.seeds:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
