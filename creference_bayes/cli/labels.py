"""``creference labels BATCH_DIR --out DIR``: 3D labels with their uncertainty (docs/labels.md)."""

from __future__ import annotations

import sys

from .main import UsageError, require, usage_errors

__all__ = ["register", "FORMATS"]

#: Label formats.
FORMATS = ("kitti",)


def _run_labels(args) -> int:
    from ..workflows.labels import export_labels
    from ..workflows.labels.quality import IOU_THRESHOLDS
    from ..workflows.labels.report import write_report

    require(0.0 <= args.min_quality <= 1.0, "--min-quality", "a probability in [0, 1]", args.min_quality)
    require(args.score_iou in IOU_THRESHOLDS, "--score-iou", f"one of {list(IOU_THRESHOLDS)}", args.score_iou)
    with usage_errors():
        export = export_labels(args.batch_dir, args.out, type_name=args.type, score_iou=args.score_iou,
                               n_draws=args.draws)
    if not export.objects:
        raise UsageError(f"{args.batch_dir}: nothing labelled, nothing written: {_why_none(export)}")
    paths = write_report(export, args.out, min_quality=args.min_quality, score_iou=args.score_iou,
                         batch_dir=args.batch_dir, figure=not args.no_figure, advice_path=args.advice)
    key = f"p_iou_ge_{args.score_iou:g}"
    low = sum(o.quality.to_dict()[key] < args.min_quality for o in export.objects)
    if not args.quiet:
        print(f"wrote {len(export.objects)} labels for {len(export.images)} images to {args.out} "
              f"(label_2/, calib/, uncertainty/); {low} below the minimum quality "
              f"P(IoU ≥ {args.score_iou:g}) < {args.min_quality:g} (needs_annotation.csv); "
              f"not labelled: {len(export.failed_scenes)} failed, {len(export.skipped)} skipped; "
              f"report: {paths['report']}")
        if export.removed:
            print(f"removed {len(export.removed)} file(s) this command wrote for images no longer in the batch: "
                  f"{', '.join(export.removed)}")
    for rel in export.kept:
        print(f"warning: {rel}: of an image no longer in the batch, but changed since this command wrote it: "
              "kept", file=sys.stderr)
    return 0


def _why_none(export) -> str:
    """Why a batch gave no label, in one line: each reason with its count and a first key."""
    reasons: dict[str, list[str]] = {}
    for s in export.skipped:
        reasons.setdefault(s["reason"], []).append(s["key"])
    for f in export.failed_scenes:
        reasons.setdefault("the scene failed in the batch (errors/)", []).append(f["key"])
    if not reasons:
        return "results/ holds no result"
    return "; ".join(f"{reason}: {len(keys)} scene{'s' if len(keys) != 1 else ''} (e.g. {keys[0]})"
                     for reason, keys in reasons.items())


def register(subparsers) -> None:
    """Add ``labels`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "labels", help="KITTI 3D labels with their uncertainty from a batch folder",
        description="Write per image a KITTI label file (label_2/), its calib file (calib/, "
                    "P2 = K[R|0] in the gravity-aligned frame; a KITTI scene's own P2) and an uncertainty sidecar "
                    "(uncertainty/, JSON), plus a data-set report (report.md, quality.png, "
                    "labels.csv, needs_annotation.csv).")
    p.add_argument("batch_dir", metavar="BATCH_DIR", help="a folder written by creference batch")
    p.add_argument("--out", required=True, metavar="DIR", help="the label folder (created)")
    p.add_argument("--format", default="kitti", choices=FORMATS, help="label format (default: %(default)s)")
    p.add_argument("--type", default=None, metavar="NAME",
                   help="KITTI type of every object, e.g. Car (default: each target's class, else its id)")
    p.add_argument("--score-iou", type=float, default=0.7, metavar="T",
                   help="the score is P(IoU >= T), T = 0.5 or 0.7 (default: %(default)s)")
    p.add_argument("--min-quality", type=float, default=0.5, metavar="Q",
                   help="objects whose score is below Q are listed for more annotations (default: %(default)s)")
    p.add_argument("--draws", type=int, default=100, metavar="N",
                   help="posterior draws per object in the sidecar (default: %(default)s)")
    p.add_argument("--advice", default=None, metavar="PATH",
                   help="the advice whose verdicts needs_annotation.csv carries (default: "
                        "BATCH_DIR/advice/advice.json, as creference advise BATCH_DIR writes it)")
    p.add_argument("--no-figure", action="store_true", help="do not write quality.png")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run_labels)
