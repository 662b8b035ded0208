"""``creference batch INPUTS... --out DIR``: estimate every scene of a data set (docs/batch.md)."""

from __future__ import annotations

import math
import sys

from ..inference.map import PRESETS
from ..pipeline import DEFAULT_MODEL, MODELS
from .estimate import (add_camera_options, add_confidence_map_option, add_distance_range_option, add_model_option,
                       estimate_fields, load_classes)
from .main import UsageError, advanced_group, require, seed_value, usage_errors

__all__ = ["register", "EXIT_FAILED"]

#: Exit status when the batch ran but some scenes failed (2 is for invalid command lines).
EXIT_FAILED = 1


def _settings(args):
    from ..workflows.batch import BatchSettings

    fields = estimate_fields(args, load_classes(args.classes))
    with usage_errors():  # a sampler setting out of range
        return BatchSettings(**fields, seed=args.seed, dataset=args.dataset, rig=args.rig,
                             pool_scale=not (args.own_scale or args.dataset == "none"))


def _engine(args):
    from ..workflows.batch.engines import DaskEngine, LocalEngine

    if args.scheduler:
        if args.workers is not None:
            raise UsageError("--workers: with --scheduler the Dask workers decide (start them with "
                             "`dask worker ADDRESS --nworkers N --nthreads 1`)")
        with usage_errors("--scheduler: ", ConnectionError):
            return DaskEngine(args.scheduler)
    require(args.workers is None or args.workers >= 1, "--workers", "an integer >= 1", args.workers)
    return LocalEngine(args.workers)


def _run_batch(args) -> int:
    from ..inference.progress import progress_mode
    from ..workflows.batch import run_batch
    from ..workflows.batch.summary import summary_line

    settings = _settings(args)
    limit = args.time_limit
    require(limit is None or (math.isfinite(limit) and limit > 0), "--time-limit", "a number of seconds > 0",
            limit)
    engine = _engine(args)
    with usage_errors():  # no scene found, two scenes with one name (the engine is closed)
        report = run_batch(args.inputs, args.out, engine, settings, time_limit=args.time_limit,
                           progress=progress_mode(args.quiet))
    if not args.quiet:
        from ..workflows.batch.dataset import dataset_lines

        for line in dataset_lines(report.dataset):
            print(line, file=sys.stderr if line.startswith("warning:") else sys.stdout)
        for line in report.dataset_notes:
            print(f"note: data set: {line}", file=sys.stderr)
        for key, error in report.errors.items():
            print(f"failed: {key}: {error}", file=sys.stderr)
        print(summary_line(report, args.out))
    return 0 if report.ok else EXIT_FAILED


def register(subparsers) -> None:
    """Add ``batch`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "batch", help="estimate every scene of a data set, locally or on a Dask cluster",
        description="Estimate every scene file (folders: every *.json below them; creference-scene/1 "
                    "or /2, one target or many) into a batch "
                    "folder: results/, scenes/ (copies), errors/, summary.csv, batch.json. A rerun "
                    "skips scenes whose result is up to date. Exit status 0 when every scene "
                    "succeeded, 1 when some failed, 2 for an invalid command line.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="scene files and folders of scene files")
    p.add_argument("--out", required=True, metavar="DIR", help="the batch folder (created)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: the machine's cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask distributed scheduler, e.g. tcp://host:8786 (needs the dist extra)")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="base seed; each scene's seed derives from it and the scene's content "
                        "(default: %(default)s)")
    p.add_argument("--time-limit", type=float, default=None, metavar="SECONDS",
                   help="a scene still running after this long is recorded as failed (default: none)")
    p.add_argument("--classes", metavar="CLASSES.json", default=None,
                   help="size priors of your own classes (docs/overview.md, Class size priors); a scene's own win")
    add_distance_range_option(p)
    p.add_argument("--dataset", choices=("auto", "none"), default="auto",
                   help="what the frames share, learnt from all of them and handed back to each (the others' "
                        "evidence, leaving the frame out): a camera's focal length and mounting (frames with one "
                        "camera.id), the crowd's reference and corner scales, where the targets stand (a fitted "
                        "distance population). auto (the default): whatever there is something to learn of, from a "
                        "first pass (DIR/first_pass/, a MAP each); none: every frame alone. Hand-set values "
                        "(--distance-range, --option ref_scale_*, a scene's focal length) win (docs/batch.md)")
    p.add_argument("--no-posterior", action="store_true",
                   help="the MAP only, much faster (creference labels then has no uncertainty to export)")
    p.add_argument("--hdi-prob", type=float, default=0.9, metavar="P",
                   help="probability of the credible intervals (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar (on a terminal) or "
                                                             "line per finished scene (otherwise)")
    g = advanced_group(p)
    g.add_argument("--model", default=DEFAULT_MODEL, choices=MODELS,
                   help="how annotations are weighed: metrology, or the paper's cost to compare with it "
                        "(default: %(default)s; creference estimate --help)")
    g.add_argument("--preset", default="default", choices=PRESETS,
                   help="how the MAP is searched for: this package's optimiser (default) or the paper's "
                        "(paper, paper-controlled: slow; creference estimate --help)")
    g.add_argument("--no-references", action="store_true",
                   help="ignore the scenes' reference annotations (to see what they add)")
    add_confidence_map_option(p)
    add_model_option(p)
    add_camera_options(p)
    g.add_argument("--rig", choices=("auto", "none", "focal", "mounting"), default="auto",
                   help="which of its camera's quantities a frame takes from the others: auto or mounting (the focal length, height, pitch and roll; "
                        "the default), focal (the focal length only, read given the camera's pooled pitch and roll, which are "
                        "not handed back) or none (nothing of the camera)")
    g.add_argument("--own-scale", action="store_true",
                   help="each frame learns how far its crowd's corners stray (the corner scale) from its own "
                        "annotations only, and reads its reference segments with the default floor; by default an "
                        "object annotated once borrows the scale from the objects of the batch annotated more than "
                        "once, and the segments' floor is fitted to the other frames' drawn lengths (docs/batch.md)")
    g.add_argument("--temperature", type=float, default=None, metavar="T",
                   help="widen (T > 1) or narrow (T < 1) the posterior (default: the model's calibrated one)")
    g.add_argument("--min-ess", type=float, default=None, metavar="N",
                   help="the sampler runs until every checked quantity has this bulk effective sample size "
                        "(default: 400)")
    g.add_argument("--max-steps", type=int, default=None, metavar="N",
                   help="cap on the sampler's steps; a scene that has not converged by then says so in "
                        "its result (default: 20000)")
    p.set_defaults(func=_run_batch)
