"""``creference advise SCENE.json|RESULT.json|BATCH_DIR``: is one more annotation worth its human
time, and which (docs/advice.md)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from .main import UsageError, check_output_file, seed_value
from ..io.files import read_text

__all__ = ["register"]


def _settings(args):
    from ..workflows.advice import AdviceSettings

    if not (math.isfinite(args.target_hdi_width) and 0.0 <= args.target_hdi_width < 1.0):
        raise UsageError(f"--target-hdi-width: expected a share of the distance in [0, 1) "
                         f"(0.1 for 10 %), got {args.target_hdi_width!r}")
    if not (math.isfinite(args.min_gain) and args.min_gain >= 0.0):
        raise UsageError(f"--min-gain: expected a number >= 0 (points of the distance per minute), "
                         f"got {args.min_gain!r}")
    if args.draws < 50:
        raise UsageError(f"--draws: expected an integer >= 50, got {args.draws}")
    if args.futures < 10:
        raise UsageError(f"--futures: expected an integer >= 10, got {args.futures}")
    if args.workers < 1:
        raise UsageError(f"--workers: expected an integer >= 1, got {args.workers}")
    if args.budget is not None and not (math.isfinite(args.budget) and args.budget > 0):
        raise UsageError(f"--budget: expected a number of seconds > 0, got {args.budget!r}")
    return AdviceSettings(n_draws=args.draws, n_futures=args.futures, target_hdi_width=args.target_hdi_width,
                          min_gain=args.min_gain)


def _one(args, settings, progress: bool) -> int:
    import json

    from ..io.files import atomic_write_json
    from ..io.result import RESULT_FORMATS
    from ..io.scene import SceneError, load_scene
    from ..workflows.advice.inputs import advice_table, advise_result, advise_scene, scene_for_result

    check_output_file("--out", args.out)
    path = Path(args.input)
    if not path.is_file():
        raise FileNotFoundError(2, "no such file", str(path))
    try:
        d = json.loads(read_text(path))
    except (UnicodeDecodeError, ValueError):
        d = None  # not JSON: the scene reader says what is wrong
    try:
        if isinstance(d, dict) and d.get("format") in RESULT_FORMATS:
            scene = scene_for_result(path, d, args.scene)
            advice = advise_result(d, scene, seed=args.seed, settings=settings, progress=progress)
            objects = d.get("objects") or [{}]
        else:
            if args.scene is not None:
                raise UsageError("--scene: only for a result file (INPUT is a scene)")
            advice, estimated = advise_scene(load_scene(path), seed=args.seed, settings=settings, progress=progress)
            objects = estimated.to_dict()["objects"]
        hdi = [((o.get("posterior") or {}).get("hdi") or {}).get("distance_m") for o in objects]
    except SceneError:
        raise
    except (KeyError, TypeError) as exc:
        raise UsageError(f"{path}: the model cannot be rebuilt from it ({exc!r})") from None
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    if args.out is not None:
        atomic_write_json(args.out, advice.to_dict())
    if not args.quiet:
        print(advice_table(advice, hdi if len(hdi) == len(advice.targets) else None))
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0


def _batch(args, settings, progress: bool) -> int:
    from ..workflows.advice.batch import advise_batch, request_rows, write_batch_advice

    if args.scene is not None:
        raise UsageError("--scene: only for a result file (INPUT is a batch folder)")
    out = Path(args.out) if args.out is not None else Path(args.input) / "advice"
    try:
        batch = advise_batch(args.input, seed=args.seed, settings=settings, workers=args.workers,
                             progress=progress)
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    paths = write_batch_advice(batch, out, budget_s=args.budget, lines=args.lines)
    if not args.quiet:
        rows = request_rows(batch, args.budget)
        for r in rows[:10]:
            print(f"{r['rank']:>4}  {r['key']}  {r['target']}  {r['request']}  (+{float(r['gain_pts_per_minute']):.3f} "
                  f"points/min; HDI {r['hdi_now_pct']} % -> {r['hdi_expected_pct']} %)")
        if len(rows) > 10:
            print(f"      … {len(rows) - 10} more in {paths['requests']}")
        stop = len(batch.objects) - len(batch.requests)
        print(f"{len(batch.objects)} targets advised: {len(rows)} requests "
              f"({sum(float(r['seconds']) for r in rows) / 60:.1f} min of human time), {stop} need none; "
              f"{len(batch.skipped)} skipped; wrote {out} (advice.json, requests.csv, "
              f"label_studio_requests.json, cvat_requests.xml)")
        for s in batch.skipped:
            print(f"skipped: {s['key']}: {s['reason']}", file=sys.stderr)
    return 0


def _run(args) -> int:
    settings = _settings(args)
    progress = not args.quiet and sys.stderr.isatty()
    if Path(args.input).is_dir():
        return _batch(args, settings, progress)
    if args.budget is not None:
        raise UsageError("--budget: only for a batch folder")
    if args.workers != 1:
        raise UsageError("--workers: only for a batch folder")
    return _one(args, settings, progress)


def register(subparsers) -> None:
    """Add ``advise`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "advise", help="which annotation to collect next, or whether to stop",
        description="For the posterior of a scene (one target or many), the expected effect of each "
                    "annotation the scene allows (one more set of dimension lines on a target, one more "
                    "reference on a segment, a distance to a target, a target's length, the distance "
                    "between two targets) on every target's 90 % HDI of the distance, location sd and "
                    "label quality, per minute of human time (preposterior simulation over the posterior "
                    "draws under the model's noise model); a ranked table and a recommendation. On a "
                    "batch folder: every target ranked and the request list for the crowd (requests.csv, "
                    "Label Studio tasks, CVAT XML).")
    p.add_argument("input", metavar="INPUT",
                   help="a scene file (estimated first), a result file of the metrology model (its "
                        "posterior draws, else the Laplace approximation at its MAP), or a folder written "
                        "by creference batch")
    p.add_argument("--out", metavar="PATH", default=None,
                   help="a scene or result: write the advice as JSON to PATH; a batch folder: the "
                        "folder for the advice files (default: BATCH_DIR/advice)")
    p.add_argument("--scene", metavar="SCENE", default=None,
                   help="the scene of a result file (default: the batch copy, or the file the "
                        "result names next to it)")
    p.add_argument("--target-hdi-width", type=float, default=0.10, metavar="F",
                   help="stop when every target's 90 %% HDI of the distance is at most this share of "
                        "it (default: %(default)s, i.e. 10 %%)")
    p.add_argument("--min-gain", type=float, default=0.5, metavar="G",
                   help="stop when the best expected gain is below G points of the distance (HDI "
                        "width in percent of the distance) per minute of human time (default: %(default)s)")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="seed of the estimate and the simulation (default: %(default)s)")
    p.add_argument("--draws", type=int, default=600, metavar="N",
                   help="posterior draws used, thinned evenly (default: %(default)s)")
    p.add_argument("--futures", type=int, default=150, metavar="M",
                   help="simulated outcomes per annotation (default: %(default)s)")
    p.add_argument("--budget", type=float, default=None, metavar="SECONDS",
                   help="a batch folder: list requests, best first, until their human time reaches "
                        "this many seconds (default: every object that should get one)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="a batch folder: advise on N scenes at once in local processes (default: %(default)s)")
    p.add_argument("--lines", default="keypoints", choices=("keypoints", "vectors"),
                   help="how the Label Studio requests draw a segment, as the project's labelling "
                        "config does (default: %(default)s)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    p.set_defaults(func=_run)
