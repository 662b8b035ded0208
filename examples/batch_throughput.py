"""Throughput of `creference batch`: targets per minute with 1 and 2 local worker processes and a
2-worker Dask LocalCluster, on the same simulated scenes, with the scaling efficiency; and a
check that the three engines give identical numbers.

    python examples/batch_throughput.py --n 40 --out throughput_out

Each engine starts from an empty batch folder. Times cover what a user waits for: the worker
processes' start-up and first imports (arviz, emcee: about 2 s per process) and every estimate
(MAP and posterior at the default settings). The Dask cluster's own start is timed apart (a real
cluster is already running). Run it on an otherwise idle machine with at least 2 cores.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

from creference_bayes.bench.simulate import write_scenes
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.engines import DaskEngine, LocalEngine


def _numbers(folder: Path) -> dict:
    out = {}
    for p in sorted((folder / "results").glob("*.json")):
        d = json.loads(p.read_text())
        out[p.stem] = (d["camera"], d["objects"], d.get("draws"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="simulated scenes (default: %(default)s)")
    ap.add_argument("--out", default="throughput_out", help="working folder (emptied first)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tier", default="all", help="noise tier of the scenes (default: %(default)s)")
    ap.add_argument("--engines", default="local1,local2,dask2",
                    help="which engines to time, comma-separated (default: %(default)s)")
    ap.add_argument("--min-ess", type=float, default=None,
                    help="bulk ESS of each estimate (default: the package's, 400; less for a quick check)")
    args = ap.parse_args()
    engines = args.engines.split(",")
    if not engines or any(e not in ("local1", "local2", "dask2") for e in engines):
        ap.error(f"--engines: expected some of local1,local2,dask2, got {args.engines!r}")

    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    scenes = out / "scenes"
    write_scenes(scenes, args.n, seed=args.seed, tier=args.tier)
    settings = BatchSettings(seed=args.seed, sampling={} if args.min_ess is None else {"min_ess": args.min_ess})
    rows = []

    def run(label, engine, extra_s=0.0):
        folder = out / label.replace(" ", "_")
        t0 = time.perf_counter()
        report = run_batch([scenes], folder, engine, settings)
        seconds = time.perf_counter() - t0
        n = report.n_targets
        rows.append({"engine": label, "workers": 1 if label.startswith("local 1") else 2, "targets": n,
                     "failed": len(report.keys("failed")), "seconds": seconds,
                     "per_min": 60.0 * n / seconds, "startup_s": extra_s, "folder": folder})

    if "local1" in engines:
        run("local 1", LocalEngine(1))
    if "local2" in engines:
        run("local 2", LocalEngine(2))
    if "dask2" in engines:
        from distributed import LocalCluster

        t0 = time.perf_counter()
        with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
            cluster_s = time.perf_counter() - t0
            run("dask 2", DaskEngine(cluster.scheduler_address), cluster_s)

    base = rows[0]["per_min"] / rows[0]["workers"]  # targets/min per worker of the first engine
    reference = _numbers(rows[0]["folder"])
    print(f"{args.n} simulated scenes (tier {args.tier}, seed {args.seed}), "
          f"{'default estimate settings' if args.min_ess is None else f'bulk ESS {args.min_ess:g}'}\n")
    print("| engine | workers | targets | failed | seconds | targets/min | scaling efficiency | identical numbers |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        eff = r["per_min"] / (r["workers"] * base)
        same = _numbers(r["folder"]) == reference
        note = f" (+{r['startup_s']:.1f} s cluster start)" if r["startup_s"] else ""
        print(f"| {r['engine']} | {r['workers']} | {r['targets']} | {r['failed']} | {r['seconds']:.1f}{note} | "
              f"{r['per_min']:.1f} | {eff:.2f} | {'yes' if same else 'NO'} |")
    print(f"\nscaling efficiency = (targets/min) / (workers × targets/min per worker with {rows[0]['engine']})")


if __name__ == "__main__":
    main()
