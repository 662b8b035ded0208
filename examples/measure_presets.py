"""Measure the MAP presets on synthetic scenes: location error (Eq. 3) and time per estimate.

Every scene has pitch, roll and an off-centre principal point (up to 10 % of the image size) and
alternates indoor / outdoor; the estimate is the paper model's MAP, target-only (no references),
as in the paper's Fig. 9a. Prints a Markdown table. Examples::

    python examples/measure_presets.py                       # 50 noise-free scenes, default preset
    python examples/measure_presets.py --n 50 --n-paper 20 --presets default,paper
    python examples/measure_presets.py --tiers none,medium --n 20 --n-paper 5

Noisy tiers use 13 target annotations (per-corner median, paper §7.1.1). Times are per estimate
(both handednesses); on a shared machine run with ``OPENBLAS_NUM_THREADS=1``: the optimisers work
on tiny matrices and BLAS threads only contend for the cores.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

from creference_bayes.bench.simulate import TIERS, simulate_scene
from creference_bayes.inference.map import PRESETS, optimize
from creference_bayes.io.scene import parse_scene
from creference_bayes.pipeline import build_model


def make_scene(seed: int, tier: str):
    setting = "indoor" if seed % 2 == 0 else "outdoor"
    d = simulate_scene(seed, setting=setting, tier=tier, principal_offset=0.1,
                       n_target_annotations=1 if tier == "none" else 13)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def measure(preset: str, tier: str, seeds) -> dict:
    errors, wall, cpu = [], [], []
    for i, seed in enumerate(seeds):
        scene = make_scene(seed, tier)
        model, _ = build_model(scene, model="paper", preset=preset, use_references=False)
        c0 = time.process_time()
        est = optimize(model, preset=preset, temperature=model.default_temperature, rng=seed)
        cpu.append(time.process_time() - c0)
        wall.append(est.info["seconds"])
        truth = np.asarray(scene.targets[0].ground_truth["location_m"])
        found = np.array([est.objects[0, 0], est.camera[3], est.objects[0, 1]])
        errors.append(float(100 * np.linalg.norm(found - truth) / np.linalg.norm(truth)))
        print(f"  {preset:>16s} {tier:>6s} scene {i + 1}/{len(seeds)}: {errors[-1]:.3g} % in {wall[-1]:.2f} s",
              file=sys.stderr)
    e = np.array(errors)
    return {"preset": preset, "tier": tier, "n": len(e), "median": np.median(e), "mean": e.mean(),
            "max": e.max(), "under_0.1": int(np.sum(e < 0.1)), "under_10": int(np.sum(e < 10)),
            "wall": np.mean(wall), "cpu": np.mean(cpu)}


def table(rows) -> str:
    head = ("| preset | noise tier | scenes | median error % | mean error % | max error % "
            "| scenes < 0.1 % | scenes < 10 % | mean s / estimate (wall) | mean CPU s / estimate |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        out.append(f"| {r['preset']} | {r['tier']} | {r['n']} | {r['median']:.3g} | {r['mean']:.3g} | "
                   f"{r['max']:.3g} | {r['under_0.1']} | {r['under_10']} | {r['wall']:.2f} | {r['cpu']:.2f} |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=50, help="scenes for the default preset (default: %(default)s)")
    p.add_argument("--n-paper", type=int, default=20,
                   help="scenes for the paper presets, the first of the same seeds (default: %(default)s)")
    p.add_argument("--presets", default="default", help=f"comma-separated, from {list(PRESETS)}")
    p.add_argument("--tiers", default="none", help=f"comma-separated noise tiers, from {list(TIERS)}")
    p.add_argument("--seed0", type=int, default=0, help="first scene seed (default: %(default)s)")
    args = p.parse_args(argv)
    presets, tiers = args.presets.split(","), args.tiers.split(",")
    for name, allowed, given in (("preset", PRESETS, presets), ("tier", TIERS, tiers)):
        bad = [g for g in given if g not in allowed]
        if bad:
            p.error(f"unknown {name}(s) {bad} (expected some of {list(allowed)})")
    rows = []
    for tier in tiers:
        for preset in presets:
            n = args.n if preset == "default" else args.n_paper
            rows.append(measure(preset, tier, range(args.seed0, args.seed0 + n)))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
