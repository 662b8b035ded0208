"""How often a target of a frame reads as well at its other handedness, and the share of the
posterior each handedness gets (docs/studies/sampler.md, "Each target's handedness in a frame").

    creference simulate --from-kitti KITTI_DIR --annotations 1 --out k1
    python examples/handedness_frames.py k1 --max-frames 20
    python examples/handedness_frames.py k1 --max-frames 8 --sample

For each scene of the folder with at least two targets: its MAP (the package's optimiser), then
each target's optimum at its other handedness given the MAP's camera (placed from its lines, the
MAP's sizes, Newton steps with the camera held: what the sampler starts from), and the gap, how
many nats below the MAP's the target's log-density given the camera is there. Prints the share of
targets whose gap is under 2, 5 and 12 nats (12: the sampler then samples both). With
``--sample`` each frame is estimated too (``--min-ess``), and each target whose both handednesses
were sampled is listed with the share of the draws at each, per chain, beside its Laplace share.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np


def gaps(scene) -> np.ndarray:
    """(m,) each target's gap (nats) at its other handedness given the MAP's camera."""
    from creference_bayes.inference.map import optimize
    from creference_bayes.inference.modes import _other_hands
    from creference_bayes.inference.moves import BlockTarget
    from creference_bayes.inference.sampler import _laplace_start
    from creference_bayes.pipeline import build_model

    model, _ = build_model(scene)
    T = model.default_temperature
    est = optimize(model, temperature=T)
    fit = est.fitted(model)
    wc0, wo0, *_ = _laplace_start(fit, est, T)
    target = BlockTarget(fit, T, wc0, np.zeros((fit.n_objects, 7, 5)), np.zeros_like(wo0))
    _, wo_f, lp_f, _ = _other_hands(target, wc0, wo0, T)
    with np.errstate(all="ignore"):
        lp0 = target.objects(wc0[None], wo0[None])[0][0]
    return np.where(np.isfinite(lp_f), lp0 - lp_f, np.inf)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", help="a folder of scene files (creference simulate --from-kitti)")
    ap.add_argument("--max-frames", type=int, default=20, help="scenes of two or more targets read (default 20)")
    ap.add_argument("--sample", action="store_true", help="estimate each frame too and show the draws' shares")
    ap.add_argument("--min-ess", type=float, default=200, help="with --sample: the sampler's bulk ESS (default 200)")
    args = ap.parse_args(argv)
    if args.max_frames < 1 or args.min_ess <= 0:
        ap.error("--max-frames and --min-ess must be positive")
    import creference_bayes as cb

    paths = sorted(Path(args.folder).glob("*.json"))
    if not paths:
        ap.error(f"{args.folder}: no scene files (*.json)")
    all_gaps, done = [], 0
    for path in paths:
        if done >= args.max_frames:
            break
        try:
            scene = cb.load_scene(path)
        except (ValueError, OSError) as exc:
            print(f"{path.name}: skipped ({exc})", file=sys.stderr)
            continue
        if len(scene.targets) < 2:
            continue
        done += 1
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            g = gaps(scene)
        all_gaps += list(g)
        print(f"{path.name}: {len(g)} targets, gaps (nats) {', '.join(f'{v:.1f}' for v in np.sort(g))}", flush=True)
        if args.sample:
            t0 = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = cb.estimate(scene, seed=0, sampling={"min_ess": args.min_ess})
            d = r.to_dict()["diagnostics"]
            for row in d.get("modes") or []:
                if "handedness" in row and row["log_density_below_map"] > 0:
                    chains = ", ".join(f"{v:.2f}" for v in row["draw_share_per_chain"])
                    print(f"  {row['target']}: other handedness {row['log_density_below_map']:.1f} nats below, "
                          f"Laplace share {row['laplace_share']:.2f}, draws per chain {chains}")
            print(f"  sampled in {time.process_time() - t0:.1f} CPU s, {d['warmup'] + d['iterations']} steps, "
                  f"{'converged' if d['converged'] else 'not converged'}", flush=True)
    g = np.array(all_gaps)
    if not len(g):
        print("no scene with two or more targets")
        return
    print(f"\n{done} frames, {len(g)} targets: other handedness within 2 nats {np.mean(g < 2):.0%}, "
          f"5 nats {np.mean(g < 5):.0%}, 12 nats {np.mean(g < 12):.0%}")


if __name__ == "__main__":
    main()
