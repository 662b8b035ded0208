"""``creference confidence fit|report``: how workers' stated confidence maps to a range
(docs/confidence.md)."""

from __future__ import annotations

import sys
from pathlib import Path

from .main import UsageError, require, seed_value, usage_errors

__all__ = ["register", "METHODS", "format_map"]

#: How ``fit`` finds the truth of each range.
METHODS = ("auto", "truth", "marginal")


def format_map(cmap) -> str:
    """A plain-text table of a fitted map's curves."""
    lines = []
    curves = [("pooled", cmap.pooled)] + sorted(cmap.groups.items())
    for name, c in curves:
        if c is None:
            continue
        lines.append(f"{name}:")
        lines.append(f"  {'stated':>6}  {'n':>5}  {'g':>6}  {cmap.interval_prob:.0%} interval")
        for i, lv in enumerate(c.levels):
            n = "" if c.n is None else str(c.n[i])
            band = "" if c.low is None else f"{c.low[i]:.3f}–{c.high[i]:.3f}"
            lines.append(f"  {lv:6.3g}  {n:>5}  {c.coverage[i]:6.3f}  {band}")
    shape = "normal" if cmap.dof is None else f"Student-t, {cmap.dof:g} degrees of freedom"
    lines.append(f"ranges are read through: {shape}")
    return "\n".join(lines)


def _check_fit_options(args) -> None:
    for name in ("draws", "min_per_level", "min_group", "workers"):
        value = getattr(args, name)
        require(value >= 1, f"--{name.replace('_', '-')}", "an integer >= 1", value)
    require(0.0 < args.interval_prob < 1.0, "--interval-prob", "a probability in (0, 1)", args.interval_prob)
    require(args.min_ess is None or args.min_ess >= 1, "--min-ess", "a number >= 1", args.min_ess)


def _run_fit(args) -> int:
    from ..io.files import atomic_write_json
    from ..workflows.confidence.data import load_scenes, stated_ranges
    from ..workflows.confidence.fit import fit_marginal, fit_with_truth, kept_levels

    _check_fit_options(args)
    with usage_errors():  # no scene files, two with one name
        scenes = load_scenes(args.inputs)
    ranges = stated_ranges(scenes)
    if not ranges:
        raise UsageError(f"no range with a stated confidence in {len(scenes)} scene(s): nothing to fit")
    method = args.method
    with_truth = [r for r in ranges if r.truth is not None]
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr))
    if method == "auto":
        method = "truth" if len(with_truth) == len(ranges) else "marginal"
        if method == "marginal" and with_truth:
            say(f"{len(ranges) - len(with_truth)} of {len(ranges)} ranges have no known truth, so the fit is without "
                f"ground truth (--method truth fits the {len(with_truth)} that have one)")
    with usage_errors():  # too few ranges per level: said before any estimate
        levels, _, _, keep = kept_levels([r.confidence for r in (with_truth if method == "truth" else ranges)],
                                         args.min_per_level)
    if method == "truth" and not with_truth:
        raise UsageError("--method truth: no range has a known truth (the scenes' ground truth needs "
                         "reference_lengths_m, the true camera (focal_length_px, pitch_rad, roll_rad, "
                         "camera_height_m), or the targets' truth for their sizes and distances)")
    options = dict(draws=args.draws, seed=args.seed, interval_prob=args.interval_prob,
                   min_per_level=args.min_per_level, min_group=args.min_group)
    with usage_errors():
        if method == "truth":
            say(f"fitting with ground truth: {len(with_truth)} ranges ({len(ranges) - len(with_truth)} "
                "without a truth left out)")
            cmap = fit_with_truth(ranges, **options)
        else:
            from ..inference.progress import progress_mode
            from ..workflows.confidence.loo import predict_data_set

            say(f"fitting without ground truth: {len(ranges)} ranges in {len(scenes)} scenes "
                "(one posterior per scene, leave-one-out per range)")
            preds, totals, errors = predict_data_set(
                scenes, seed=args.seed, workers=args.workers,
                sampling=None if args.min_ess is None else {"min_ess": args.min_ess},
                progress=progress_mode(args.quiet))
            for key, err in errors.items():
                print(f"failed: {key}: {err}", file=sys.stderr)
            cmap = fit_marginal(preds, **options)
            cmap.fit.update(scenes_failed=len(errors), ranges_above_horizon=totals["skipped"],
                            scenes_not_converged=totals["not_converged"])
    if not keep.all():
        print(f"warning: confidence level(s) {', '.join(f'{c:g}' for c in levels[~keep])} left out (fewer than "
              f"{args.min_per_level} ranges each): the map reads them between the levels kept, and is flat below "
              f"{levels[keep][0]:g} and above {levels[keep][-1]:g}", file=sys.stderr)
    atomic_write_json(args.out, cmap.to_dict())
    if not args.quiet:
        print(format_map(cmap))
        print(f"wrote {args.out}")
    return 0


def _run_report(args) -> int:
    from ..io.files import atomic_write_json, atomic_write_text
    from ..models.confidence_map import ConfidenceMap, ConfidenceMapError
    from ..workflows.confidence.data import load_scenes, range_counts, stated_ranges
    from ..workflows.confidence.report import confidence_report, markdown_report

    require(args.min_answers >= 1, "--min-answers", "an integer >= 1", args.min_answers)
    with usage_errors("--map: ", ConfidenceMapError):
        maps = {Path(path).stem: ConfidenceMap.load(path) for path in args.map or []}
    first = next(iter(maps.items()), (None, None))
    with usage_errors():
        scenes = load_scenes(args.inputs)
        rep = confidence_report(stated_ranges(scenes), range_counts(scenes), cmap=first[1],
                                min_answers=args.min_answers, map_label=first[0])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    figures = []
    if not args.no_figures:
        from ..io.files import atomic_path
        from ..vision.confidence_figures import reliability_figure, workers_figure

        figs = {"reliability.png": reliability_figure(rep.reliability, maps)}
        if rep.workers:
            figs["workers.png"] = workers_figure(rep.workers)
        for name, fig in figs.items():
            with atomic_path(out / name) as tmp:
                fig.savefig(tmp, dpi=130, format="png")
            figures.append(name)
    atomic_write_json(out / "report.json", rep.to_dict())
    atomic_write_text(out / "report.md", markdown_report(rep, figures))
    if not args.quiet:
        all_row = next(r for r in rep.scores if r.by == "all")
        print(f"{all_row.n} ranges: mean stated confidence {all_row.stated:.3f}, realised coverage "
              f"{all_row.coverage:.3f}, mean interval score {all_row.score_mean:.3f} (log-length); "
              f"{len(rep.workers)} workers with >= {args.min_answers} ranges")
        print(f"wrote {out / 'report.md'}, {out / 'report.json'}" + "".join(f", {out / f}" for f in figures))
    return 0


def register(subparsers) -> None:
    """Add ``confidence`` (``fit``, ``report``) to the ``creference`` command."""
    p = subparsers.add_parser(
        "confidence", help="fit and report how workers' stated confidence maps to a range",
        description="Research on stated confidence: fit a confidence map g (how often a range "
                    "stated at confidence c holds the truth) and report reliability and interval "
                    "scores. See docs/confidence.md.")
    sub = p.add_subparsers(dest="confidence_command", required=True, metavar="ACTION",
                           help="fit (write a map file) or report (reliability and scores)")
    f = sub.add_parser(
        "fit", help="fit a confidence map from scenes",
        description="Fit a monotone confidence map with an uncertainty per level and write it as a creference-confidence-map/1 file, for "
                    "`creference estimate --confidence-map MAP.json`. With ground truth the share "
                    "of ranges holding the truth is used; without, each range is scored against "
                    "the posterior of its length given the scene's other annotations (one estimate "
                    "per scene: minutes for a few hundred scenes).")
    f.add_argument("inputs", nargs="+", metavar="INPUT", help="scene files and folders of scene files")
    f.add_argument("--out", required=True, metavar="MAP.json", help="the map file to write")
    f.add_argument("--method", default="auto", choices=METHODS,
                   help="truth: ranges with a known truth; marginal: without ground truth; auto: "
                        "truth when every range has one (default: %(default)s)")
    f.add_argument("--draws", type=int, default=1000, metavar="B",
                   help="draws of each level's uncertainty: posterior draws with ground truth, "
                        "bootstrap samples over scenes without (default: %(default)s)")
    f.add_argument("--interval-prob", type=float, default=0.95, metavar="P",
                   help="probability of each level's interval (default: %(default)s)")
    f.add_argument("--min-per-level", type=int, default=10, metavar="N",
                   help="levels with fewer ranges are left out (default: %(default)s)")
    f.add_argument("--min-group", type=int, default=200, metavar="N",
                   help="a measure and mode with this many ranges gets a curve of its own "
                        "(default: %(default)s)")
    f.add_argument("--seed", type=seed_value, default=0, help="seed of the draws and the estimates (default: %(default)s)")
    f.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes for the estimates of the marginal method (default: %(default)s)")
    f.add_argument("--min-ess", type=float, default=None, metavar="N",
                   help="bulk effective sample size of each estimate (default: the sampler's)")
    f.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    f.set_defaults(func=_run_fit)
    r = sub.add_parser(
        "report", help="reliability diagram, interval scores and workers from scenes with ground truth",
        description="Write report.md, report.json, reliability.png (stated confidence against "
                    "realised coverage) and workers.png (workers who answered several times) into "
                    "DIR. Needs scenes whose ground truth gives each range's truth.")
    r.add_argument("inputs", nargs="+", metavar="INPUT", help="scene files and folders of scene files")
    r.add_argument("--out", required=True, metavar="DIR", help="the report folder (created)")
    r.add_argument("--map", action="append", metavar="MAP.json",
                   help="a fitted map to draw on the diagram (repeatable); the first also "
                        "recalibrates the ranges in the score tables")
    r.add_argument("--min-answers", type=int, default=5, metavar="N",
                   help="workers with fewer ranges are not shown on their own (default: %(default)s)")
    r.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    r.add_argument("--quiet", action="store_true", help="print nothing but errors")
    r.set_defaults(func=_run_report)
