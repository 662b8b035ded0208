"""``creference bench`` and ``creference simulate``: the benchmark and synthetic scenes."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from ..bench.runner import CONFIGS, plain, run_bench, write_scenes
from ..bench.simulate import SETTINGS, TIERS
from ..io.files import atomic_write_text
from .main import UsageError, seed_value

__all__ = ["register", "BENCH_TIMES"]

#: How long each bench size takes (two cores, the adopted defaults; docs/benchmark_results.md:
#: quick 13 s, full 32 min). The README and docs/overview.md quote the same words (a test checks it).
BENCH_TIMES = {"quick": "under a minute", "full": "about 30 minutes"}


def _run_bench_command(args) -> int:
    from ..bench.peers import INSTALL_HINT, poselib_available
    from ..bench.report import markdown_report

    if args.frames:
        return _run_frame_bench(args)
    if args.sbc:
        return _run_sbc(args)
    config = CONFIGS["full" if args.full else "quick"]
    if args.paper_restarts is not None:
        if args.paper_restarts < 1:
            raise UsageError(f"--paper-restarts: expected an integer >= 1, got {args.paper_restarts}")
        config = replace(config, paper_restarts=args.paper_restarts)
    if args.temperature is not None and not args.temperature > 0:
        raise UsageError(f"--temperature: expected a number > 0, got {args.temperature}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    if not poselib_available():
        print(f"note: p4pf skipped ({INSTALL_HINT})", file=sys.stderr)
    doc = run_bench(config, seed=args.seed, temperature=args.temperature, progress=say,
                    progress_bar=not args.quiet and sys.stderr.isatty())
    report = markdown_report(doc)
    if not poselib_available():
        report += f"\n\np4pf skipped: {INSTALL_HINT}\n"
    atomic_write_text(out / "bench.json", json.dumps(plain(doc), indent=1, allow_nan=False) + "\n")
    atomic_write_text(out / "bench.md", report + "\n")
    paths = []
    if not args.no_figures:
        from ..bench.figures import write_figures

        paths = write_figures(doc, out)
    if not args.quiet:
        print(report)
        print(f"\nwrote {out / 'bench.json'}, {out / 'bench.md'}" + "".join(f", {p}" for p in paths))
    return 0


#: Defaults of ``simulate``'s options that --from-kitti does not take (given otherwise: an error).
_SIMULATE_DEFAULTS = {"kind": "street"}


def _run_simulate_command(args) -> int:
    if args.outdir is None and args.out_dir is None:
        raise UsageError("simulate: give the output folder (OUTDIR or --out)")
    if args.outdir is not None and args.out_dir is not None and args.outdir != args.out_dir:
        raise UsageError(f"simulate: two output folders, {args.outdir} and --out {args.out_dir}")
    args.outdir = args.outdir or args.out_dir
    if args.sizes != "prior" and args.from_kitti is None:
        raise UsageError(f"--sizes {args.sizes}: only with --from-kitti (simulated frames draw their own sizes)")
    if args.from_kitti is not None:
        from .frame import run_kitti_simulate

        given = [f"--{name.replace('_', '-')}" for name in ("n", "objects", "kind", "tier", "setting", "confidence")
                 if getattr(args, name) not in (None, "all", _SIMULATE_DEFAULTS.get(name))]
        given += [f"--{name.replace('_', '-')}" for name in ("focal_known",) if getattr(args, name)]
        given += ["--horizon"] if args.horizon != "none" else []
        if given:
            raise UsageError(f"{', '.join(given)}: not with --from-kitti (its frames are KITTI's own images, "
                             "objects and cameras; --annotations, --noise-px, --sizes and --seed apply)")

        return run_kitti_simulate(args)
    if args.n is None:
        raise UsageError("--n: the number of scenes is required (unless --from-kitti)")
    if args.objects is not None:
        from .frame import run_frame_simulate

        return run_frame_simulate(args)
    if args.n < 1:
        raise UsageError(f"--n: expected an integer >= 1, got {args.n}")
    out = Path(args.outdir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder")
    if not args.overwrite and out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out}: the folder is not empty; choose another or pass --overwrite "
                         "(replaces scene_NNNN.json files of the same name)")
    options = {}
    if args.confidence is not None:
        from ..bench.confidence_workers import TRUE_MAPS, ConfidentWorkers

        try:
            true_map = args.confidence if args.confidence in TRUE_MAPS else float(args.confidence)
        except ValueError:
            raise UsageError(f"--confidence: expected one of {list(TRUE_MAPS)} or a width factor > 0, "
                             f"got {args.confidence!r}") from None
        if args.confidence_workers < 1:
            raise UsageError(f"--confidence-workers: expected an integer >= 1, got {args.confidence_workers}")
        try:
            options["confidence"] = ConfidentWorkers.pool(true_map, n_workers=args.confidence_workers,
                                                          seed=[args.seed, 1])
        except ValueError as exc:
            raise UsageError(f"--confidence: {exc}") from None
    paths = write_scenes(out, args.n, seed=args.seed, tier=args.tier, setting=args.setting,
                         overwrite=True, **options)
    if not args.quiet:
        print(f"wrote {len(paths)} scenes to {args.outdir}")
    return 0


def _run_frame_bench(args) -> int:
    """``creference bench --frames``: the frame benchmark (docs/benchmark_results.md, "Frames")."""
    from ..bench.frame_bench import frame_tables, rows_to_json, run_frame_bench

    if args.full:
        kw = dict(counts=(3, 8, 15), frames=4, tiers=("low", "high"))
    else:
        kw = dict(counts=(3, 6), frames=1, tiers=("low",), sampling={"max_iterations": 2000})
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    rows = run_frame_bench(seed=args.seed, progress=say, **kw)
    table = frame_tables(rows)
    atomic_write_text(out / "frame_bench.json", json.dumps(rows_to_json(rows), indent=1, allow_nan=False) + "\n")
    atomic_write_text(out / "frame_bench.md", table + "\n")
    if not args.quiet:
        print(table)
        print(f"\nwrote {out / 'frame_bench.json'}, {out / 'frame_bench.md'}")
    return 0


def _run_sbc(args) -> int:
    """``creference bench --sbc``: simulation-based calibration (docs/benchmark_results.md, "SBC")."""
    from ..bench.sbc import run_sbc, sbc_markdown, sbc_summary

    n = args.sbc_scenes if args.sbc_scenes is not None else (60 if args.full else 4)
    if n < 1:
        raise UsageError(f"--sbc-scenes: expected an integer >= 1, got {n}")
    if args.temperature is not None and not args.temperature > 0:
        raise UsageError(f"--temperature: expected a number > 0, got {args.temperature}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    sampling = {"min_ess": 400} if args.full else {"min_ess": 200, "max_steps": 3000}
    records = run_sbc(n, seed=args.seed, temperature=args.temperature, sampling=sampling, progress=say)
    summary = sbc_summary(records)
    doc = {"n_scenes": n, "seed": args.seed, "temperature": args.temperature, "sampling": sampling,
           "summary": summary, "records": records}
    table = sbc_markdown(summary)
    atomic_write_text(out / "sbc.json", json.dumps(plain(doc), indent=1, allow_nan=False) + "\n")
    atomic_write_text(out / "sbc.md", table + "\n")
    paths = []
    if not args.no_figures:
        from ..vision.plotting import plot_sbc_ranks

        fig = plot_sbc_ranks(summary)
        tmp = out / ".sbc_ranks.tmp.png"
        fig.savefig(tmp, dpi=110)
        tmp.replace(out / "sbc_ranks.png")
        paths.append(out / "sbc_ranks.png")
    if not args.quiet:
        print(table)
        print(f"\nwrote {out / 'sbc.json'}, {out / 'sbc.md'}" + "".join(f", {p}" for p in paths))
    return 0


def _n_scenes(size: str) -> int:
    return sum(n for *_, n in CONFIGS[size].scenes)


def register(subparsers) -> None:
    """Add ``bench`` and ``simulate`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "bench", help="benchmark against the paper's method, P4Pf and the Cramér–Rao bound",
        description="Run the paper's method, PoseLib's P4Pf (extra 'peer'), both models of this "
                    "package and the Cramér–Rao bound on the same simulated scenes; write tables "
                    f"(bench.md, bench.json) and figures. --quick: {BENCH_TIMES['quick']}; --full: "
                    f"{BENCH_TIMES['full']} on two cores. See docs/benchmark_results.md.")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true",
                      help=f"CI-sized run, {_n_scenes('quick')} scenes (the default; {BENCH_TIMES['quick']})")
    size.add_argument("--full", action="store_true",
                      help=f"the documented run, {_n_scenes('full')} scenes ({BENCH_TIMES['full']})")
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output directory (default: %(default)s)")
    p.add_argument("--seed", type=seed_value, default=0, help="seed of scenes and estimators (default: %(default)s)")
    p.add_argument("--paper-restarts", type=int, default=None, metavar="N",
                   help="override the paper preset's restarts (default: 200; 8 with --quick)")
    p.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="posterior temperature of the paper model (default: the package's); with --sbc, "
                        "of the metrology model (a T below 1 makes it over-confident: the check must see it)")
    p.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    p.add_argument("--frames", action="store_true",
                   help="the frame benchmark instead: simulated frames of several objects, joint against one "
                        "at a time and the frame bound (--quick: 2 frames; --full: 24 frames of 3–15 objects)")
    p.add_argument("--sbc", action="store_true",
                   help="simulation-based calibration instead: parameters drawn from the model's prior "
                        "(within a box of plausible scenes), annotations from its noise model, ranks of "
                        "the truth among the posterior's draws (distance, focal length, pitch, roll) for "
                        "thin designs (1 set of lines, 0-2 references) and full ones (5 + 5); writes "
                        "sbc.md, sbc.json, sbc_ranks.png (--quick: 4 scenes a design; --full: 60)")
    p.add_argument("--sbc-scenes", type=int, default=None, metavar="N",
                   help="scenes per design of --sbc (overrides --quick/--full)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    p.set_defaults(func=_run_bench_command)

    p = subparsers.add_parser(
        "simulate", help="write synthetic scenes or frames with ground truth (creference-scene/1 or /2)",
        description="Write N simulated scenes (scene_0000.json, …) with exact ground truth, as the "
                    "benchmark draws them: a target box, 13 noisy dimension-line annotations, five "
                    "references in the paper's ten formats and the horizon (creference-scene/1). No photo. "
                    "With --objects K: frames of K targets each (creference-scene/2); with --from-kitti: "
                    "frames on the real boxes and cameras of a KITTI folder.")
    p.add_argument("outdir", metavar="OUTDIR", nargs="?", default=None,
                   help="folder to write into (created; must be empty unless --overwrite)")
    p.add_argument("--out", dest="out_dir", metavar="OUTDIR", default=None, help="the same as OUTDIR")
    p.add_argument("--n", type=int, default=None, help="number of scenes (not with --from-kitti)")
    p.add_argument("--seed", type=seed_value, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--tier", default="all", choices=[*TIERS, "all"],
                   help="noise tier, or all to cycle through them (default: %(default)s)")
    p.add_argument("--setting", default=None, choices=list(SETTINGS),
                   help="indoor or outdoor (default: two thirds indoor)")
    p.add_argument("--confidence", default=None, metavar="MAP",
                   help="every reference is a range stated with a confidence by a pool of workers "
                        "(each with an own error scale) whose true confidence map is calibrated, "
                        "over (over-confident: a stated 90%% holds about 60%%), under, or a width "
                        "factor (1 calibrated; docs/confidence.md); default: the paper's formats, "
                        "no confidence")
    p.add_argument("--confidence-workers", type=int, default=40, metavar="N",
                   help="workers in the pool of --confidence (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into a non-empty folder, replacing files of the same name")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    from .frame import add_frame_simulate_options

    add_frame_simulate_options(p)
    p.set_defaults(func=_run_simulate_command)
