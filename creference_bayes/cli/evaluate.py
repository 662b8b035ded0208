"""``creference evaluate kitti GT_LABEL_DIR LABEL_DIR``: KITTI's AP3D and AP BEV with the official
devkit's rules, and the reliability of the labels' P(IoU ≥ t) (docs/evaluation.md)."""

from __future__ import annotations

import sys
from pathlib import Path

from .main import UsageError, require, usage_errors

__all__ = ["register", "format_table"]


def format_table(ev) -> str:
    """The AP table and the reliability summary of a :class:`~creference_bayes.evaluation.kitti_eval.KittiEvaluation`."""
    out = [f"{len(ev.images)} images evaluated (AP in percent; the official devkit's rules)"]
    if ev.unlabelled:
        out.append(f"{len(ev.unlabelled)} ground-truth files without a label file were not evaluated "
                   f"(--count-unlabelled counts them)")
    out.append(f"{'':<26}{'AP R40':^24}  {'AP R11':^24}")
    out.append(f"{'class':<11}{'IoU':>4}  {'metric':<7}  " + "  ".join(["  easy    mod   hard"] * 2)
               + "  ground truth e/m/h  detections")
    groups: dict = {}
    for r in ev.ap:
        groups.setdefault((r["class"], r["min_overlap"], r["metric"]), {})[r["difficulty"]] = r
    for (cls, thr, metric), by in groups.items():
        d = [by[k] for k in ("easy", "moderate", "hard")]
        r40 = " ".join(f"{x['ap_r40']:6.2f}" for x in d)
        r11 = " ".join(f"{x['ap_r11']:6.2f}" for x in d)
        gt = "/".join(str(x["n_groundtruth"]) for x in d)
        out.append(f"{cls:<11}{thr:>4g}  {metric.upper():<7}  {r40}  {r11}  {gt:>18}  {d[0]['n_detections']:>10}")
    for cls in ev.not_evaluated:
        out.append(f"{cls:<11}  not evaluated: no label of this class (the devkit skips it too)")
    if ev.reliability:
        for t, r in ev.reliability.items():
            out.append(f"P(IoU ≥ {t:g}) of {r['count']} labels (sidecars): mean predicted {r['mean_predicted']:.3f}, "
                       f"observed share {r['observed_share']:.3f}, Brier score {r['brier']:.3f}")
    else:
        out.append("no uncertainty sidecars beside the labels: no reliability of P(IoU ≥ t)")
    return "\n".join(out)


def _run_kitti(args) -> int:
    from ..evaluation.kitti_eval import evaluate_kitti
    from ..io.files import atomic_path, atomic_write_json

    require(args.bins >= 1, "--bins", "an integer >= 1", args.bins)
    with usage_errors():
        ev = evaluate_kitti(args.gt_label_dir, args.label_dir, count_unlabelled=args.count_unlabelled,
                            n_bins=args.bins)
    if ev.ap and not any(r["n_groundtruth"] for r in ev.ap):
        print("warning: no ground-truth box counts at any difficulty (the devkit ignores boxes under 25 px high, "
              "occluded 3 or truncated over 0.5), so every AP is 0: is GT_LABEL_DIR KITTI's ground truth? "
              "(the labels creference labels writes say occluded 3)", file=sys.stderr)
    written = []
    if args.out is not None:
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise UsageError(f"--out: {out}: not a folder")
        if ev.reliability:
            from ..vision.label_figures import reliability_figure
            fig = reliability_figure(ev.reliability)
            with atomic_path(out / "reliability.png") as tmp:
                fig.savefig(tmp, dpi=110)
            written.append(out / "reliability.png")
        atomic_write_json(out / "evaluation.json", ev.to_dict())
        written.insert(0, out / "evaluation.json")
    if not args.quiet:
        print(format_table(ev))
        if written:
            print("wrote " + ", ".join(str(p) for p in written))
    return 0


def register(subparsers) -> None:
    """Add ``evaluate`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "evaluate", help="judge 3D labels against reference boxes (KITTI AP3D and AP BEV)",
        description="Judge 3D labels against reference boxes the way the field judges detectors.")
    sub = p.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK",
                           help="the benchmark (only kitti so far)")
    k = sub.add_parser(
        "kitti", help="AP3D and AP BEV (R40 and R11) with the official KITTI devkit's rules",
        description="AP3D and AP BEV with 40 recall points (R40) and the 11-point figure (R11) per "
                    "class (Car at IoU 0.7 and 0.5, Pedestrian and Cyclist at 0.5) and difficulty, "
                    "with the official devkit's rules; with the labels' uncertainty sidecars, the "
                    "reliability of their P(IoU >= t) against the IoU each label has. Every label "
                    "file of LABEL_DIR is compared with the file of the same name in GT_LABEL_DIR.")
    k.add_argument("gt_label_dir", metavar="GT_LABEL_DIR",
                   help="KITTI ground truth: a label_2 folder, or a folder holding one")
    k.add_argument("label_dir", metavar="LABEL_DIR",
                   help="labels with a score (16 values a line): the --out folder of creference "
                        "labels, or any label_2 folder")
    k.add_argument("--out", default=None, metavar="DIR",
                   help="write evaluation.json and reliability.png here (default: print only)")
    k.add_argument("--count-unlabelled", action="store_true",
                   help="count ground-truth files without a label file as images without labels "
                        "(default: skip them, as the devkit does)")
    k.add_argument("--bins", type=int, default=10, metavar="N",
                   help="bins of the reliability tables (default: %(default)s)")
    k.add_argument("--quiet", action="store_true", help="print nothing but errors")
    k.set_defaults(func=_run_kitti)
