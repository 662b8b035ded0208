"""Is the label quality calibrated? Simulated scenes with ground truth go through the three steps
a labelling team runs (simulate → `creference batch` → `creference labels`); for every object the
labels give P(IoU ≥ 0.5) and P(IoU ≥ 0.7) of the exported (MAP) box from the posterior draws, and
the ground truth gives the exported box's true IoU. Prints the reliability tables (bins of predicted
probability: count, mean predicted, observed share) and writes the figure (quality.png: quality
histogram and reliability diagrams) with the data-set report.

    python examples/label_reliability.py --n 200 --workers 2 --out label_reliability_out

With ``--kitti DIR`` the scenes are a KITTI folder's real boxes (``creference simulate
--from-kitti``) with ``--noise-px`` of corner error; with ``--twice-every N`` the objects of every
Nth scene are annotated twice and the others once (a team checking a sample), and the mean stated
and observed quality is printed for the objects annotated once and for the others. ``--own-scale``
runs the batch so (docs/batch.md, "The crowd's corner scale"):

    python examples/label_reliability.py --kitti KITTI/ --noise-px 8 --twice-every 4 --out lr_pooled
    python examples/label_reliability.py --kitti KITTI/ --noise-px 8 --twice-every 4 --own-scale --out lr_own

The batch is resumable: rerun the same command to finish an interrupted run.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from creference_bayes.bench.kitti import kitti_scenes
from creference_bayes.bench.simulate import write_scenes
from creference_bayes.io.files import atomic_write_json
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
    ap.add_argument("--kitti", metavar="DIR", help="scenes from a KITTI folder's boxes instead (--n ignored)")
    ap.add_argument("--noise-px", type=float, default=2.0, help="with --kitti: corner error, px (default: %(default)s)")
    ap.add_argument("--twice-every", type=int, default=None, metavar="N",
                    help="with --kitti: every Nth scene's objects annotated twice, the others once "
                         "(default: five sets everywhere; 0: every object annotated once)")
    ap.add_argument("--own-scale", action="store_true", help="each frame's corner scale from its own annotations only")
    args = ap.parse_args()

    out = Path(args.out)
    scenes = out / "scenes"
    if args.kitti:
        kitti_scenes(args.kitti, scenes, n_annotations=5 if args.twice_every is None else 2, noise_px=args.noise_px,
                     seed=args.seed)
        if args.twice_every is not None:
            for k, path in enumerate(sorted(scenes.glob("*.json"))):
                if args.twice_every == 0 or k % args.twice_every:  # the others keep their first set only
                    d = json.loads(path.read_text())
                    for t in d["targets"]:
                        t["dimension_lines"] = t["dimension_lines"][:1]
                    atomic_write_json(path, d)
    else:
        write_scenes(scenes, args.n, seed=args.seed, tier=args.tier, overwrite=True)
    engine = DaskEngine(args.scheduler) if args.scheduler else LocalEngine(args.workers)
    sampling = {} if args.min_ess is None else {"min_ess": args.min_ess}
    settings = BatchSettings(seed=args.seed, sampling=sampling, pool_scale=not args.own_scale)
    report = run_batch([scenes], out / "batch", engine, settings, progress=True)
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
        if args.twice_every is not None:
            sets = {(p.stem, t["id"]): len(t["dimension_lines"]) for p in scenes.glob("*.json")
                    for t in json.loads(p.read_text())["targets"]}
            for name, once in (("annotated once", True), ("annotated twice", False)):
                objs = [o for o in export.objects if o.true_iou is not None and (sets[o.key, o.target] == 1) == once]
                if not objs:
                    continue
                p = np.array([o.quality.p_iou[t] for o in objs])
                h = np.array([o.true_iou >= t for o in objs])
                se = np.sqrt(np.sum(p * (1 - p))) / len(p)
                print(f"  {name}: {len(objs)} objects, mean predicted {p.mean():.3f}, observed share {h.mean():.3f} "
                      f"({(h.mean() - p.mean()) / se:+.1f} se)")
        print("| predicted | objects | mean predicted | observed share | ±2 se |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['low']:.1f}–{r['high']:.1f} | {r['count']} | {r['mean_predicted']:.3f} | "
                  f"{r['observed_share']:.3f} | {2 * r['se']:.3f} |")
        print()


if __name__ == "__main__":
    main()
