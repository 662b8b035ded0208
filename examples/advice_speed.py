"""How long the advice on a frame takes beside the frame's estimate, and how long a frame takes to
estimate again once a catalogue size is applied (docs/studies/advice.md, "Speed").

    python -m creference_bayes simulate --from-kitti KITTI_DIR --out SCENES
    python examples/advice_speed.py SCENES/000000.json SCENES/000011.json SCENES/000032.json [--seed 0]
    python examples/advice_speed.py SCENES/000011.json --no-advice    # the applied sizes only

Per scene: the estimate (``creference estimate``'s, the posterior) and the advice on its result
(``creference advise RESULT``'s defaults; ``--workers N`` processes weighing its requests), each
in CPU seconds (this process's and its worker processes': on a shared machine the wall time says
more about the neighbours than about the code) and wall seconds; then the scene again with every
vehicle's size from a catalogue (its true size times exp(N(0, CATALOGUE_LOG_SD)) per dimension,
as ``advise --apply`` puts it in) and its estimate's
CPU seconds and sampler steps beside the first's, and the camera pitch's posterior sd and bulk
effective draws per sampler step (how fast the sampler moves it) in both. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np


def timed(f, *args, **kwargs):
    """f's value, its CPU seconds (this process's and its ended child processes') and its wall seconds."""
    def cpu():
        own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime

    c, w = cpu(), time.perf_counter()
    out = f(*args, **kwargs)
    return out, cpu() - c, time.perf_counter() - w


def with_catalogue_sizes(scene, raw: dict, rng):
    """``scene`` with every vehicle's size from a catalogue, drawn around its ground truth."""
    from creference_bayes.workflows.advice.answers import CATALOGUE_LOG_SD, catalogue_lists, with_size

    n = 0
    for t, rt in zip(scene.targets, raw["targets"]):
        dims = (rt.get("ground_truth") or {}).get("dimensions_m")
        if dims and t.dimensions is None and catalogue_lists(t.cls):
            size = np.array([dims["length"], dims["width"], dims["height"]])
            scene = with_size(scene, t.id, size * np.exp(CATALOGUE_LOG_SD * rng.standard_normal(3)))
            n += 1
    return scene, n


def pitch_mixing(result) -> tuple[str, str]:
    """The camera pitch's posterior sd (radians) and its bulk ESS per sampler step, as text."""
    d = result.to_dict()
    pitch = np.asarray(((d.get("draws") or {}).get("camera") or {}).get("pitch", []), float)
    diag = d["diagnostics"]
    ess = (diag.get("ess_bulk") or {}).get("camera.pitch")
    sd = f"{pitch.std():.4f}" if pitch.size > 1 else "–"
    return sd, (f"{ess / diag['iterations']:.2f}" if ess else "–")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenes", nargs="+", type=Path, help="scene files with ground truth (simulate --from-kitti)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-advice", action="store_true", help="time the estimates only")
    p.add_argument("--workers", type=int, default=1,
                   help="processes that weigh a frame's requests at once (advise's --workers; default 1)")
    args = p.parse_args(argv)

    from creference_bayes.inference.threads import single_threaded_blas
    from creference_bayes.io.scene import load_scene
    from creference_bayes.pipeline import estimate
    from creference_bayes.workflows.advice.inputs import advise_result

    print("| frame | objects | estimate CPU s (wall) | advice CPU s (wall) | advice / estimate (CPU; wall) "
          "| sizes applied | estimate again CPU s | steps before → after | pitch sd (rad) before → after "
          "| pitch ESS per step before → after |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in args.scenes:
        scene = load_scene(path)
        with single_threaded_blas():
            result, e_cpu, e_wall = timed(estimate, scene, seed=args.seed)
            advice, a_cpu, a_wall = ((None, float("nan"), float("nan")) if args.no_advice else
                                     timed(advise_result, result, scene, seed=args.seed, workers=args.workers))
            answered, n = with_catalogue_sizes(scene, json.loads(path.read_text()), np.random.default_rng(args.seed))
            again, s_cpu, _ = (timed(estimate, answered, seed=args.seed) if n else (None, float("nan"), None))
        pitch = [pitch_mixing(r) if r is not None else ("–", "–") for r in (result, again)]
        steps = result.to_dict()["diagnostics"]["iterations"]
        after = again.to_dict()["diagnostics"]["iterations"] if again is not None else "–"
        print(f"| {path.stem} | {len(scene.targets)} | {e_cpu:.1f} ({e_wall:.1f}) | {a_cpu:.1f} ({a_wall:.1f}) | "
              f"{a_cpu / e_cpu:.1f}; {a_wall / e_wall:.1f} | {n} | {s_cpu:.1f} | {steps} → {after} | {pitch[0][0]} → {pitch[1][0]} | "
              f"{pitch[0][1]} → {pitch[1][1]} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
