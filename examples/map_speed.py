"""Time the MAP on simulated scenes of several kinds, and compare two runs scene by scene.

    python examples/map_speed.py --out before.json                 # simulates the scenes itself
    python examples/map_speed.py --out after.json --compare before.json
    python examples/map_speed.py scenes/ other_scenes/ --out run.json   # scene files of your own

Without folders it simulates ``--n`` scenes of each kind (``creference simulate``, seed 0): the
light and heavy crowds, the four noise tiers, frames of five targets and outdoor scenes without a
horizon. Each MAP is timed on one BLAS thread as CPU seconds, the least of ``--repeat`` runs.
``--compare`` pairs the scenes with an earlier run's: whether each reached the same optimum (its
objective within 0.001 nats), and the ratio of the times per kind.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

KINDS = {"light": ["--tier", "light"], "tiers": ["--tier", "all"], "heavy": ["--tier", "heavy"],
         "five-targets": ["--tier", "all", "--objects", "5"],
         "no-horizon": ["--tier", "all", "--setting", "outdoor", "--horizon", "none"]}


def simulate(folder: Path, kinds: list[str], n: int) -> list[Path]:
    from creference_bayes.cli.main import main

    out = []
    for kind in kinds:
        if main(["simulate", str(folder / kind), "--n", str(n), "--seed", "0", *KINDS[kind], "--quiet"]) != 0:
            raise SystemExit(f"map_speed.py: simulating the {kind} scenes failed")
        out.append(folder / kind)
    return out


def time_maps(folders: list[Path], repeat: int) -> list[dict]:
    from creference_bayes.inference.map import optimize
    from creference_bayes.inference.threads import single_threaded_blas
    from creference_bayes.io.scene import SceneError, load_scene
    from creference_bayes.pipeline import build_model

    records = []
    with single_threaded_blas(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for folder in folders:
            for path in sorted(folder.glob("*.json")):
                try:
                    model = build_model(load_scene(path))[0]
                except SceneError as e:
                    print(f"{folder.name}/{path.name}: skipped ({e})", flush=True)
                    continue
                seconds = []
                for _ in range(repeat):
                    t = time.process_time()
                    state = optimize(model)
                    seconds.append(time.process_time() - t)
                records.append({"kind": folder.name, "scene": path.name, "cpu_s": min(seconds),
                                "objective": state.value, "iterations": state.info.get("iterations")})
                print(f"{folder.name}/{path.name}: {min(seconds):.3f} s, objective {state.value:.4f}", flush=True)
    return records


def table(records: list[dict], before: list[dict] | None) -> str:
    old = {(r["kind"], r["scene"]): r for r in before or []}
    lines = ["| kind | scenes | MAP CPU s, median |" + (" before | after / before, median | same optimum |"
                                                       if before else "")]
    lines.append("|---|---|---|" + ("---|---|---|" if before else ""))
    for kind in dict.fromkeys(r["kind"] for r in records):
        rs = [r for r in records if r["kind"] == kind]
        row = f"| {kind} | {len(rs)} | {np.median([r['cpu_s'] for r in rs]):.3f} |"
        if before:
            pairs = [(old[(kind, r["scene"])], r) for r in rs if (kind, r["scene"]) in old]
            if pairs:
                row += (f" {np.median([b['cpu_s'] for b, _ in pairs]):.3f} |"
                        f" {np.median([a['cpu_s'] / b['cpu_s'] for b, a in pairs]):.2f} |"
                        f" {sum(abs(a['objective'] - b['objective']) < 1e-3 for b, a in pairs)} of {len(pairs)} |")
        lines.append(row)
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], epilog=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folders", nargs="*", type=Path, help="folders of scene files (default: simulate them)")
    p.add_argument("--n", type=int, default=6, help="scenes of each kind simulated (default 6)")
    p.add_argument("--kinds", default=",".join(KINDS), help=f"kinds simulated (default: {','.join(KINDS)})")
    p.add_argument("--repeat", type=int, default=2, help="runs per MAP; the least time counts (default 2)")
    p.add_argument("--out", type=Path, help="write the records here (JSON)")
    p.add_argument("--compare", type=Path, help="an earlier run's records (JSON) to pair with")
    args = p.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        p.error(f"--kinds: unknown kind(s) {unknown} (expected some of {list(KINDS)})")
    if args.n < 1 or args.repeat < 1:
        p.error(f"--n and --repeat: expected integers >= 1, got {args.n} and {args.repeat}")
    from creference_bayes.core.jsonfile import read_json
    from creference_bayes.io.files import atomic_write_json

    def refuse(path, problem):
        return ValueError(f"{path}: {problem}")

    try:
        before = read_json(args.compare, refuse) if args.compare else None
    except (OSError, ValueError) as e:
        p.error(f"--compare: cannot read {args.compare}: {e}")
    if before is not None and not (isinstance(before, list) and all(
            isinstance(r, dict) and {"kind", "scene", "cpu_s", "objective"} <= set(r) for r in before)):
        p.error(f"--compare: {args.compare} is not a records file of this script")
    with tempfile.TemporaryDirectory() as tmp:
        folders = args.folders or simulate(Path(tmp), kinds, args.n)
        records = time_maps(folders, args.repeat)
    if args.out:
        atomic_write_json(args.out, records, indent=1)
    print(table(records, before))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
