"""``creference bench`` and ``creference simulate``: the benchmark and synthetic scenes."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from ..bench.runner import CONFIGS, plain, run_bench, write_scenes
from ..bench.simulate import SETTINGS, TIERS
from .main import UsageError

__all__ = ["register"]




def _run_bench_command(args) -> int:
    from ..bench.peers import INSTALL_HINT, poselib_available
    from ..bench.report import markdown_report

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
    doc = run_bench(config, seed=args.seed, temperature=args.temperature, progress=say)
    report = markdown_report(doc)
    if not poselib_available():
        report += f"\n\np4pf skipped: {INSTALL_HINT}\n"
    (out / "bench.json").write_text(json.dumps(plain(doc), indent=1, allow_nan=False) + "\n")
    (out / "bench.md").write_text(report + "\n")
    paths = []
    if not args.no_figures:
        from ..bench.figures import write_figures

        paths = write_figures(doc, out)
    if not args.quiet:
        print(report)
        print(f"\nwrote {out / 'bench.json'}, {out / 'bench.md'}" + "".join(f", {p}" for p in paths))
    return 0


def _run_simulate_command(args) -> int:
    if args.n < 1:
        raise UsageError(f"--n: expected an integer >= 1, got {args.n}")
    paths = write_scenes(args.outdir, args.n, seed=args.seed, tier=args.tier, setting=args.setting)
    if not args.quiet:
        print(f"wrote {len(paths)} scenes to {args.outdir}")
    return 0


def register(subparsers) -> None:
    """Add ``bench`` and ``simulate`` to the ``creference`` command."""
    p = subparsers.add_parser("bench", help="benchmark against the paper's method, P4Pf and the Cramér–Rao bound")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="CI-sized run (default; under two minutes)")
    size.add_argument("--full", action="store_true", help="the documented run (about 25 minutes)")
    p.add_argument("--out", default="bench_out", metavar="DIR", help="output directory (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of scenes and estimators (default: %(default)s)")
    p.add_argument("--paper-restarts", type=int, default=None, metavar="N",
                   help="override the paper preset's restarts (default: 200; 8 with --quick)")
    p.add_argument("--temperature", type=float, default=None,
                   help="posterior temperature of the paper model (default: the package's)")
    p.add_argument("--no-figures", action="store_true", help="write no PNG figures")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run_bench_command)

    p = subparsers.add_parser("simulate", help="write synthetic creference-scene/1 files with ground truth")
    p.add_argument("outdir", metavar="OUTDIR")
    p.add_argument("--n", type=int, required=True, help="number of scenes")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--tier", default="all", choices=[*TIERS, "all"],
                   help="noise tier, or all to cycle through them (default: %(default)s)")
    p.add_argument("--setting", default=None, choices=list(SETTINGS),
                   help="indoor or outdoor (default: two thirds indoor)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=_run_simulate_command)
