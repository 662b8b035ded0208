"""What the sampler costs on scene files: per scene and seed, its objects, the estimate's CPU
seconds (``process_time``, one process), the sampler's main-phase steps, whether it converged and
the least bulk ESS of the quantities it checks; then the sums, for scenes of one object and of
several, with the least ESS per CPU second (at a fixed length: how fast the sampler mixes)
(docs/studies/sampler.md, "Frames of an unknown focal length").

    python -m creference_bayes simulate --from-kitti KITTI_DIR --focal-unknown --out scenes/
    python examples/frame_steps.py scenes/*.json --seeds 0 1 --out steps.jsonl
    python examples/frame_steps.py scenes/*.json --sampling '{"independence_weight": 0.8}'
    python examples/frame_steps.py scenes/*.json --sampling '{"min_ess": 1e9, "max_steps": 6000}'  # a fixed length

``--sampling`` passes sampler settings (JSON, as ``creference estimate --sampling``) to every
estimate. Two versions of the code are compared by running this once with each on ``PYTHONPATH``.
Prints a Markdown table; ``--out`` also writes one JSON line per estimate.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings
from pathlib import Path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("scenes", nargs="+", type=Path, help="scene files")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="estimate seeds (default: 0)")
    p.add_argument("--sampling", default=None, metavar="JSON", help="sampler settings for every estimate")
    p.add_argument("--out", type=Path, default=None, help="also write one JSON line per estimate here")
    args = p.parse_args(argv)
    from creference_bayes.inference.chains import SamplerSettings

    try:
        sampling = None if args.sampling is None else json.loads(args.sampling)
        if sampling is not None and not isinstance(sampling, dict):
            raise ValueError(f"expected a JSON object of settings, got {args.sampling!r}")
        SamplerSettings.from_options(sampling)  # an unknown key or a bad value, said once and up front
    except json.JSONDecodeError as exc:
        p.error(f"--sampling: expected JSON, got {args.sampling!r} ({exc.msg})")
    except (TypeError, ValueError) as exc:
        p.error(f"--sampling: {exc}")

    import creference_bayes as cb

    rows = []
    print("| scene | objects | seed | CPU s | steps | converged | least bulk ESS |")
    print("|---|---|---|---|---|---|---|")
    for path in args.scenes:
        try:
            scene = cb.load_scene(path)
        except (OSError, ValueError) as exc:
            print(f"| {path.name} | – | – | – | – | not a scene: {exc} | – |", flush=True)
            continue
        for seed in args.seeds:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = time.process_time()
                result = cb.estimate(scene, seed=seed, sampling=sampling)
                cpu = time.process_time() - t
            diag = result.to_dict()["diagnostics"]
            row = {"scene": path.name, "objects": len(scene.targets), "seed": seed, "cpu": round(cpu, 2),
                   "steps": diag["iterations"], "converged": bool(diag["converged"]),
                   "min_ess": diag["min_ess_bulk"]}
            rows.append(row)
            print(f"| {row['scene']} | {row['objects']} | {seed} | {cpu:.1f} | {row['steps']} | "
                  f"{'yes' if row['converged'] else 'no'} | {row['min_ess']:.0f} |", flush=True)
    print()
    print("| scenes | estimates | CPU s | steps | not converged | least bulk ESS per CPU s, geometric mean "
          "| least ESS under 100 |")
    print("|---|---|---|---|---|---|---|")
    for name, keep in (("one object", lambda r: r["objects"] == 1), ("several", lambda r: r["objects"] > 1)):
        part = [r for r in rows if keep(r)]
        rate = [r["min_ess"] / r["cpu"] for r in part if r["min_ess"] and r["cpu"] > 0]
        mean = f"{math.exp(sum(map(math.log, rate)) / len(rate)):.1f}" if rate else "–"
        print(f"| {name} | {len(part)} | {sum(r['cpu'] for r in part):.1f} | {sum(r['steps'] for r in part)} | "
              f"{sum(not r['converged'] for r in part)} | {mean} | {sum(r['min_ess'] < 100 for r in part)} |")
    if args.out is not None:
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
