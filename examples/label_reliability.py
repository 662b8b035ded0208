"""Is the label quality calibrated? Simulated scenes with ground truth go through the three steps
a labelling team runs (simulate → `creference batch` → `creference labels`); for every object the
labels give P(IoU ≥ 0.5) and P(IoU ≥ 0.7) of the exported (MAP) box from the posterior draws, and
the ground truth gives the exported box's true IoU. Prints the reliability tables (bins of predicted
probability: count, mean predicted, observed share) and writes the figure (quality.png: quality
histogram and reliability diagrams) with the data-set report.

    python examples/label_reliability.py --n 200 --workers 2 --out label_reliability_out

The batch is resumable: rerun the same command to finish an interrupted run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import write_scenes
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.engines import DaskEngine, LocalEngine
from creference_bayes.workflows.batch.summary import summary_line
from creference_bayes.workflows.labels import export_labels
from creference_bayes.workflows.labels.report import calibration, write_report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="simulated scenes (default: %(default)s)")
    ap.add_argument("--out", default="label_reliability_out", help="working folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tier", default="all", help="noise tier (default: all four, cycling)")
    ap.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    ap.add_argument("--scheduler", default=None, help="a Dask scheduler address instead")
    ap.add_argument("--bins", type=int, default=5, help="bins of predicted probability (default: %(default)s)")
    ap.add_argument("--min-ess", type=float, default=None,
                    help="bulk ESS of each estimate (default: the package's, 400; less for a quick check)")
    args = ap.parse_args()

    out = Path(args.out)
    scenes = out / "scenes"
    write_scenes(scenes, args.n, seed=args.seed, tier=args.tier, overwrite=True)
    engine = DaskEngine(args.scheduler) if args.scheduler else LocalEngine(args.workers)
    sampling = {} if args.min_ess is None else {"min_ess": args.min_ess}
    report = run_batch([scenes], out / "batch", engine, BatchSettings(seed=args.seed, sampling=sampling), progress=True)
    print(summary_line(report, out / "batch"))
    export = export_labels(out / "batch", out / "labels")
    paths = write_report(export, out / "labels", batch_dir=out / "batch")
    tables = calibration(export.objects, n_bins=args.bins)
    print(f"\n{len(export.objects)} labels; report {paths['report']}, figure {paths.get('figure')}\n")
    for t, rows in tables.items():
        pred = np.array([o.quality.p_iou[t] for o in export.objects if o.true_iou is not None])
        hit = np.array([o.true_iou >= t for o in export.objects if o.true_iou is not None])
        print(f"P(IoU >= {t:g}): mean predicted {pred.mean():.3f}, observed share {hit.mean():.3f}, "
              f"Brier score {np.mean((pred - hit) ** 2):.3f}")
        print("| predicted | objects | mean predicted | observed share | ±2 se |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['low']:.1f}–{r['high']:.1f} | {r['count']} | {r['mean_predicted']:.3f} | "
                  f"{r['observed_share']:.3f} | {2 * r['se']:.3f} |")
        print()


if __name__ == "__main__":
    main()
