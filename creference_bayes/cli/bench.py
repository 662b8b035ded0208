"""``creference bench`` and ``creference simulate``: the benchmark and synthetic scenes."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from ..bench.runner import CONFIGS, plain, run_bench
from ..bench.simulate import CAMERA_POPULATIONS, CROWDS, SETTINGS, TIERS
from ..io.files import atomic_write_text
from .main import UsageError, advanced_group, require, seed_value, usage_errors

__all__ = ["register", "BENCH_TIMES"]

#: How long each bench size takes (two cores, the adopted defaults; docs/studies/benchmark.md:
#: quick 13 s, full 32 min). The README and docs/overview.md quote the same words (a test checks it).
BENCH_TIMES = {"quick": "under a minute", "full": "about 30 minutes"}


def _say(args):
    return (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))


def _out(args) -> Path:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def _check_temperature(args) -> None:
    t = args.temperature
    require(t is None or t > 0, "--temperature", "a number > 0", t)


def _run_bench_command(args) -> int:
    from ..bench.peers import INSTALL_HINT, poselib_available
    from ..bench.report import markdown_report

    _check_temperature(args)
    if args.sbc:
        if args.cameras != "setting":
            raise UsageError(f"--cameras {args.cameras}: not with --sbc (it draws its cameras from the model's prior)")
        return _run_sbc(args)
    config = CONFIGS[("frames" if args.frames else "full" if args.full else "quick")
                     + ("-full" if args.frames and args.full else "")]
    if args.paper_restarts is not None:
        require(args.paper_restarts >= 1, "--paper-restarts", "an integer >= 1", args.paper_restarts)
        config = replace(config, paper_restarts=args.paper_restarts)
    config = replace(config, cameras=args.cameras)
    out = _out(args)
    note = "" if poselib_available() or not config.scenes else f"p4pf skipped: {INSTALL_HINT}"
    if note and not args.quiet:
        print(f"note: {note}", file=sys.stderr)
    doc = run_bench(config, seed=args.seed, temperature=args.temperature, progress=_say(args),
                    progress_bar=not args.quiet and sys.stderr.isatty())
    report = markdown_report(doc) + (f"\n\n{note}\n" if note else "")
    atomic_write_text(out / "bench.json", json.dumps(plain(doc), indent=1, allow_nan=False) + "\n")
    atomic_write_text(out / "bench.md", report + "\n")
    paths = []
    if not args.no_figures and config.scenes:
        from ..bench.figures import write_figures

        paths = write_figures(doc, out)
    if not args.quiet:
        print(report)
        print(f"\nwrote {out / 'bench.json'}, {out / 'bench.md'}" + "".join(f", {p}" for p in paths))
    return 0


def _run_sbc(args) -> int:
    """``creference bench --sbc``: simulation-based calibration (docs/studies/benchmark.md, "SBC")."""
    from ..bench.sbc import run_sbc, sbc_markdown, sbc_summary

    n = args.sbc_scenes if args.sbc_scenes is not None else (60 if args.full else 4)
    require(n >= 1, "--sbc-scenes", "an integer >= 1", n)
    out = _out(args)
    sampling = {"min_ess": 400} if args.full else {"min_ess": 200, "max_steps": 3000}
    records = run_sbc(n, seed=args.seed, temperature=args.temperature, sampling=sampling, progress=_say(args))
    summary = sbc_summary(records)
    doc = {"n_scenes": n, "seed": args.seed, "temperature": args.temperature, "sampling": sampling,
           "summary": summary, "records": records}
    table = sbc_markdown(summary)
    atomic_write_text(out / "sbc.json", json.dumps(plain(doc), indent=1, allow_nan=False) + "\n")
    atomic_write_text(out / "sbc.md", table + "\n")
    paths = []
    if not args.no_figures:
        from ..vision.plotting import plot_sbc_ranks

        tmp = out / ".sbc_ranks.tmp.png"
        plot_sbc_ranks(summary).savefig(tmp, dpi=110)
        tmp.replace(out / "sbc_ranks.png")
        paths.append(out / "sbc_ranks.png")
    if not args.quiet:
        print(table)
        print(f"\nwrote {out / 'sbc.json'}, {out / 'sbc.md'}" + "".join(f", {p}" for p in paths))
    return 0


#: Options of ``simulate`` that --from-kitti does not take, with their defaults (given otherwise: an error).
_NOT_FROM_KITTI = {"n": None, "objects": 1, "tier": "all", "setting": None, "confidence": None, "references": 5,
                   "horizon": "exact", "focal_known": False, "cameras": "setting"}


def _run_simulate_command(args) -> int:
    if args.outdir is None and args.out_dir is None:
        raise UsageError("simulate: give the output folder (OUTDIR or --out)")
    if args.outdir is not None and args.out_dir is not None and args.outdir != args.out_dir:
        raise UsageError(f"simulate: two output folders, {args.outdir} and --out {args.out_dir}")
    out = Path(args.outdir or args.out_dir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder")
    if not args.overwrite and out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out}: the folder is not empty; choose another or pass --overwrite "
                         "(replaces files of the same name)")
    for name in ("annotations", "objects", "confidence_workers"):
        value = getattr(args, name)
        require(value is None or value >= 1, f"--{name.replace('_', '-')}", "an integer >= 1", value)
    require(args.references >= 0, "--references", "an integer >= 0", args.references)
    require(args.noise_px is None or args.noise_px >= 0, "--noise-px", "a number >= 0", args.noise_px)
    if args.focal_unknown and args.from_kitti is None:
        raise UsageError("--focal-unknown: only with --from-kitti (a simulated scene leaves the focal length out "
                         "unless --focal-known)")
    if args.from_kitti is not None:
        return _run_kitti(args, out)
    if args.n is None:
        raise UsageError("--n: the number of scenes is required (unless --from-kitti)")
    require(args.n >= 1, "--n", "an integer >= 1", args.n)
    from ..bench.simulate import write_scenes

    options = {"n_objects": args.objects, "n_references": args.references, "sizes": args.sizes or "known",
               "n_target_annotations": 13 if args.annotations is None else args.annotations,
               "horizon": args.horizon, "focal_known": args.focal_known, "noise_px": args.noise_px,
               "cameras": args.cameras}
    if args.confidence is not None:
        from ..bench.confidence_workers import TRUE_MAPS, ConfidentWorkers

        try:
            true_map = args.confidence if args.confidence in TRUE_MAPS else float(args.confidence)
            options["confidence"] = ConfidentWorkers.pool(true_map, n_workers=args.confidence_workers,
                                                          seed=[args.seed, 1])
        except ValueError as exc:
            raise UsageError(f"--confidence: expected one of {list(TRUE_MAPS)} or a width factor > 0 "
                             f"({exc})") from None
    paths = write_scenes(out, args.n, seed=args.seed, tier=args.tier, setting=args.setting, overwrite=True, **options)
    if not args.quiet:
        tiers = (" (noise tiers none, low, medium and high in turn, so scene_0000 is noise-free; --tier picks one)"
                 if args.tier == "all" and args.noise_px is None else "")
        print(f"wrote {len(paths)} scene{'s' if len(paths) != 1 else ''} to {out}{tiers}")
    return 0


def _run_kitti(args, out: Path) -> int:
    """``creference simulate --from-kitti DIR --out SCENES``: scenes on KITTI's real geometry."""
    from ..bench.kitti import kitti_scenes

    given = [f"--{k.replace('_', '-')}" for k, v in _NOT_FROM_KITTI.items() if getattr(args, k) != v]
    if given:
        raise UsageError(f"{', '.join(given)}: not with --from-kitti (its scenes are KITTI's own images, objects "
                         "and cameras; --annotations, --noise-px, --sizes and --seed apply)")
    src = Path(args.from_kitti)
    if not src.is_dir():
        raise UsageError(f"--from-kitti {src}: no such folder")
    if not (src / "label_2").is_dir() or not (src / "calib").is_dir():
        raise UsageError(f"--from-kitti {src}: not a KITTI folder (needs label_2/ and calib/)")
    with usage_errors():  # a malformed label or calib file: its message names file and line
        totals = kitti_scenes(src, out, n_annotations=5 if args.annotations is None else args.annotations,
                              noise_px=2.0 if args.noise_px is None else args.noise_px, seed=args.seed,
                              sizes=args.sizes or "prior", focal_known=not args.focal_unknown)
    from ..bench.kitti import LEFT_OUT

    skipped = ", ".join(f"{v} {LEFT_OUT.get(k, k)}" for k, v in totals["skipped"].items() if v)
    if not totals["scenes"]:
        raise UsageError(f"--from-kitti {src}: no scene written: no image has an object a person could annotate"
                         + (f" (left out: {skipped})" if skipped else " (no labelled object)"))
    if not args.quiet:
        print(f"wrote {totals['scenes']} scene{'s' if totals['scenes'] != 1 else ''} with {totals['kept']} objects "
              f"to {out}" + (f" (left out: {skipped})" if skipped else ""))
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
                    f"{BENCH_TIMES['full']} on two cores. See docs/studies/benchmark.md.")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true",
                      help=f"CI-sized run, {_n_scenes('quick')} scenes (the default; {BENCH_TIMES['quick']})")
    size.add_argument("--full", action="store_true",
                      help=f"the documented run, {_n_scenes('full')} scenes ({BENCH_TIMES['full']})")
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output directory (default: %(default)s)")
    p.add_argument("--seed", type=seed_value, default=0, help="seed of scenes and estimators (default: %(default)s)")
    p.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--frames", action="store_true",
                      help="scenes of several targets instead: simulated street scenes, every object estimated "
                           "jointly and alone, beside the scene's bound (--quick: 2 scenes; --full: 24 scenes of "
                           "3–15 objects)")
    kind.add_argument("--sbc", action="store_true",
                      help="simulation-based calibration instead: parameters drawn from the model's prior "
                           "(within a box of plausible scenes), annotations from its noise model, ranks of "
                           "the truth among the posterior's draws (distance, focal length, pitch, roll) for "
                           "thin designs (1 set of lines, 0-2 references) and full ones (5 + 5); writes "
                           "sbc.md, sbc.json, sbc_ranks.png (--quick: 4 scenes a design; --full: 60)")
    p.add_argument("--cameras", choices=CAMERA_POPULATIONS, default="setting",
                   help="the scenes' cameras: each setting's ranges (setting, the documented runs) or real ones: "
                        "phones, zoom, action and vehicle cameras (real; not with --sbc, which draws its "
                        "cameras from the prior)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    g = advanced_group(p)
    g.add_argument("--paper-restarts", type=int, default=None, metavar="N",
                   help="random restarts of the paper's optimiser (default: 200; 8 with --quick)")
    g.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="posterior temperature of the paper model (default: the package's); with --sbc, "
                        "of the metrology model (a T below 1 makes it over-confident: the check must see it)")
    g.add_argument("--sbc-scenes", type=int, default=None, metavar="N",
                   help="scenes per design of --sbc (overrides --quick/--full)")
    p.set_defaults(func=_run_bench_command)

    p = subparsers.add_parser(
        "simulate", help="write synthetic scenes with ground truth (creference-scene/2)",
        description="Write N simulated scenes (scene_0000.json, …) with exact ground truth, as the "
                    "benchmark draws them: one target box (or --objects K), 13 noisy dimension-line "
                    "annotations each, five references in the paper's ten formats and the horizon. No photo. "
                    "With --from-kitti: scenes on the real boxes and cameras of a KITTI folder.")
    p.add_argument("outdir", metavar="OUTDIR", nargs="?", default=None,
                   help="folder to write into (created; must be empty unless --overwrite)")
    p.add_argument("--out", dest="out_dir", metavar="OUTDIR", default=None, help="the same as OUTDIR")
    p.add_argument("--n", type=int, default=None, help="number of scenes (not with --from-kitti)")
    p.add_argument("--seed", type=seed_value, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--tier", default="all", choices=[*TIERS, *CROWDS, "all"],
                   help="how noisy the simulated crowd is: none, low, medium or high (the paper's), or all "
                        "to cycle through them; or the crowds light (2 px corners, 5 px reference end points, "
                        "log-sd 0.1) and heavy (5 px, 10 px, log-sd 0.55, 12%% outliers) (default: %(default)s)")
    p.add_argument("--setting", default=None, choices=list(SETTINGS),
                   help="indoor, outdoor or street (a KITTI-like car camera; default: two thirds indoor, "
                        "one third outdoor)")
    p.add_argument("--objects", type=int, default=1, metavar="K", help="targets per scene (default: %(default)s)")
    p.add_argument("--annotations", type=int, default=None,
                   help="dimension-line sets per target (default: 13; 5 with --from-kitti)")
    p.add_argument("--references", type=int, default=5, help="references per scene (default: %(default)s)")
    p.add_argument("--from-kitti", metavar="DIR", default=None,
                   help="scenes from a KITTI folder (label_2/, calib/, image_2/): simulated dimension lines "
                        "on the real boxes (docs/kitti.md)")
    p.add_argument("--overwrite", action="store_true",
                   help="write into a non-empty folder, replacing files of the same name")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    g = advanced_group(p)
    g.add_argument("--noise-px", type=float, default=None,
                   help="pixel noise per corner instead of the tier's (default: the tier's; 2 with --from-kitti)")
    g.add_argument("--sizes", choices=("known", "prior"), default=None,
                   help="known: each target's size is stated; prior: left to its class's size prior "
                        "(default: known; prior with --from-kitti, as a crowd knows them)")
    g.add_argument("--horizon", choices=("exact", "none", "sd"), default="exact",
                   help="the horizon the scene gives: exact, none, or sd (off by 5 px and stated so; "
                        "default: %(default)s)")
    g.add_argument("--focal-known", action="store_true", help="write the true focal length into the scene")
    g.add_argument("--cameras", choices=CAMERA_POPULATIONS, default="setting",
                   help="each setting's camera ranges (setting, the default) or real cameras: phones, zoom, action "
                        "and vehicle cameras, each with its own image size (real)")
    g.add_argument("--focal-unknown", action="store_true",
                   help="with --from-kitti: give the estimate no focal length (a street camera nobody calibrated; "
                        "every scene still names its camera, camera.id, and keeps P2 as camera.kitti_p2 for the "
                        "labels' KITTI frame only)")
    g.add_argument("--confidence", default=None, metavar="MAP",
                   help="every reference is a range stated with a confidence by a pool of workers "
                        "(each with an own error scale) whose true confidence map is calibrated, "
                        "over (over-confident: a stated 90%% holds about 60%%), under, or a width "
                        "factor (1 calibrated; docs/confidence.md); default: the paper's formats, "
                        "no confidence")
    g.add_argument("--confidence-workers", type=int, default=40, metavar="N",
                   help="workers in the pool of --confidence (default: %(default)s)")
    p.set_defaults(func=_run_simulate_command)
