"""``creference advise SCENE.json|RESULT.json|BATCH_DIR``: is one more annotation worth its human
time, and which (docs/advice.md)."""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

from .estimate import distance_range_arg, model_options
from .main import UsageError, advanced_group, check_output_file, require, seed_value, usage_errors
from ..io.files import read_csv_rows, read_text
from ..io.validation import read_json

__all__ = ["register"]


def _settings(args):
    from ..workflows.advice import KINDS, AdviceSettings

    # (a NaN fails every comparison; the unbounded ones also refuse infinity)
    require(0.0 <= args.target_hdi_width < 1.0, "--target-hdi-width",
            "a share of the distance in [0, 1) (0.1 for 10 %)", args.target_hdi_width)
    require(math.isfinite(args.min_gain) and args.min_gain >= 0.0, "--min-gain",
            "a number >= 0 (points of the distance per minute)", args.min_gain)
    require(args.draws >= 50, "--draws", "an integer >= 50", args.draws)
    require(args.futures >= 10, "--futures", "an integer >= 10", args.futures)
    require(args.budget is None or (math.isfinite(args.budget) and args.budget > 0), "--budget",
            "a number of seconds > 0", args.budget)
    require(0.0 < args.score_iou < 1.0, "--score-iou", "an IoU threshold in (0, 1)", args.score_iou)
    require(0.0 < args.min_quality <= 1.0, "--min-quality", "a probability in (0, 1]", args.min_quality)
    require(math.isfinite(args.min_good_per_hour) and args.min_good_per_hour >= 0.0, "--min-good-per-hour",
            "a number >= 0", args.min_good_per_hour)
    kinds = tuple(k.strip() for k in args.requests.split(",") if k.strip())
    if not kinds or any(k not in KINDS for k in kinds):
        raise UsageError(f"--requests: expected some of {', '.join(KINDS)} separated by commas, got {args.requests!r}")
    return AdviceSettings(kinds=kinds, n_draws=args.draws, n_futures=args.futures, target_hdi_width=args.target_hdi_width,
                          min_gain=args.min_gain, iou_threshold=args.score_iou, min_quality=args.min_quality,
                          objective=args.rank, min_good_per_hour=args.min_good_per_hour)


def _one(args, settings, progress: bool) -> int:
    from ..io.files import atomic_write_json
    from ..io.result import RESULT_FORMATS, read_result
    from ..io.scene import SceneError, load_scene
    from ..workflows.advice.inputs import advice_table, advise_result, advise_scene, scene_for_result

    check_output_file("--out", args.out)
    path = Path(args.input)
    if not path.is_file():
        raise FileNotFoundError(2, "no such file", str(path))
    try:
        d = read_json(path)
    except ValueError as exc:
        if args.scene is not None:  # meant as a result: say what is wrong with it
            raise UsageError(" ".join(str(exc).split())) from None
        d = None  # not JSON: the scene reader says what is wrong
    try:
        made_with = None  # a scene's estimate: its options and range, recorded with the advice
        if isinstance(d, dict) and d.get("format") in RESULT_FORMATS:
            d = read_result(path)  # its content checked: a result edited by hand is refused by name
            _only_for_a_scene(args, "a result is advised with the settings it was made with")
            notes: list[str] = []
            scene = scene_for_result(path, d, args.scene, notes)
            for note in notes:  # a scene of the result's name that is another photo's, passed over
                print(f"warning: {note}", file=sys.stderr)
            advice = advise_result(d, scene, seed=args.seed, settings=settings, progress=progress,
                                   workers=_frame_workers(args))
            objects = d.get("objects") or [{}]
        else:
            if args.scene is not None:
                raise UsageError("--scene: only for a result file (INPUT is a scene)")
            scene = load_scene(path)
            args.model, args.preset = "metrology", "default"  # what the advice estimates with
            options = model_options(args, scene)
            if args.distance_range is not None:
                options["distance_range"] = args.distance_range
            advice, estimated = advise_scene(scene, seed=args.seed, settings=settings, progress=progress,
                                             workers=_frame_workers(args), **options)
            done = estimated.to_dict()
            prov = done["provenance"]
            made_with = {"options": prov["options"], **{k: prov[k] for k in ("distance_range_m",) if k in prov}}
            objects = done["objects"]
        hdi = [_distance_hdi(o) for o in objects]
    except SceneError:
        raise
    except (KeyError, TypeError) as exc:
        raise UsageError(f"{path}: the model cannot be rebuilt from it ({exc!r})") from None
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    if args.out is not None:
        atomic_write_json(args.out, {**advice.to_dict(), **({"estimate": made_with} if made_with else {})})
    if not args.quiet:
        print(advice_table(advice, hdi if len(hdi) == len(advice.targets) else None))
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0


def _frame_workers(args) -> int:
    """The processes that weigh one frame's requests at once: ``--workers``, else the cores."""
    from ..workflows.batch.engines import default_workers

    require(args.workers is None or args.workers >= 1, "--workers", "an integer >= 1", args.workers)
    return default_workers() if args.workers is None else args.workers


def _distance_hdi(obj) -> tuple[float, float] | None:
    """The estimate's HDI of an object's distance (m) as a result stores it, for the table beside
    the advice; None where the result has none or something else there (it is only shown)."""
    try:
        lo, hi = map(float, obj["posterior"]["hdi"]["distance_m"])
    except (KeyError, TypeError, ValueError):
        return None
    return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) else None


def _only_for_a_scene(args, why: str) -> None:
    """``--distance-range`` and ``--option`` set a scene's estimate; ``why`` they do nothing here."""
    for flag, given in (("--distance-range", args.distance_range is not None), ("--option", bool(args.option))):
        if given:
            raise UsageError(f"{flag}: only for a scene file ({why})")


def _batch(args, settings, progress: bool | str) -> int:
    from ..workflows.advice.batch import advise_batch, request_rows, write_batch_advice
    from .batch import _engine

    if args.scene is not None:
        raise UsageError("--scene: only for a result file (INPUT is a batch folder)")
    _only_for_a_scene(args, "a batch is advised with the settings it was made with")
    out = Path(args.out) if args.out is not None else Path(args.input) / "advice"
    # as creference batch runs: local processes (no more than the frames) or a Dask scheduler
    engine = _engine(args) if args.scheduler else None
    require(args.workers is None or args.workers >= 1, "--workers", "an integer >= 1", args.workers)
    _keep_answers(args.input, out / "requests.csv")
    with usage_errors(one_line=True):
        batch = advise_batch(args.input, seed=args.seed, settings=settings, engine=engine, workers=args.workers,
                             progress=progress)
    paths = write_batch_advice(batch, out, budget_s=args.budget, lines=args.lines,
                               image_url_prefix=args.image_url_prefix)
    if not args.quiet:
        rows = request_rows(batch, args.budget)
        if rows:  # the order is the plan's; a gain is stated on outcomes other than those it was chosen by
            print("rank  where  request  (" + ("what it adds to the requests above it, stated on other "
                                                      "simulated outcomes than those it was chosen by"
                                                      if settings.objective == "labels" else "its gain alone") + ")")
        for r in rows[:10]:
            where = f"{r['key']}  {r['target']}" if r["kind"] != "mounting" else \
                f"camera {r['camera'] or r['key']} ({r['frames']} frame{'s' if r['frames'] != 1 else ''})"
            minutes = max(float(r["seconds"]), 1e-9) / 60.0
            gain = (f"{float(r['good_gain']):+.2f} good labels, {float(r['good_per_hour']):+.2f}/h"
                    if settings.objective == "labels" else f"{float(r['gain_pts_per_minute']):+.3f} points/min"
                    if settings.objective == "hdi" else
                    f"{float(r['location_gain_pts']) / minutes:+.3f} location-sd points/min")
            print(f"{r['rank']:>4}  {where}  {r['request']}  ({gain})")
        if len(rows) > 10:
            print(f"      … {len(rows) - 10} more in {paths['requests']}")
        errors = Path(args.input) / "errors"
        results = Path(args.input) / "results"  # a frame that failed and has no earlier result: not advised
        failed = [p for p in sorted(errors.rglob("*.json")) if not p.name.startswith(".")
                  and not (results / p.relative_to(errors)).exists()] if errors.is_dir() else []
        good = sum(bool(o.advice.good[o.target]) for o in batch.objects)
        stuck = sum(o.advice.verdicts()[o.target]["verdict"] == "none" for o in batch.objects)
        print(f"{len(batch.objects)} targets advised: {good} label{'s' * (good != 1)} good (P(IoU ≥ {settings.iou_threshold:g}) ≥ "
              f"{settings.min_quality:g}), {stuck} that no single request lifts; {len(rows)} request{'s' * (len(rows) != 1)} "
              f"({sum(float(r['seconds']) for r in rows) / 60:.1f} min of human time, "
              f"{sum(float(r['good_gain']) for r in rows):.1f} labels expected to become good, "
              f"{sum(float(r['good_loss']) for r in rows):.1f} good ones to fall below the bar); "
              f"{len(batch.skipped)} skipped"
              + (f", {len(failed)} frame{'s' * (len(failed) != 1)} not advised (failed in the batch: {errors})"
                 if failed else "")
              + f"; wrote {out} (advice.json, requests.csv, label_studio_requests.json, cvat_requests.xml)")
        for s in batch.skipped:
            print(f"skipped: {s['key']}: {s['reason']}", file=sys.stderr)
    return 0


def _into_scenes(args, put, noun: str, verb: str, nothing: str, cost=None) -> int:
    """Run ``put(notes)`` (--apply or --merge: it writes the user's scene files and returns (file,
    what, whether it changed the file, which answer) per answer and file), its notes as warnings,
    then what changed and what to run next, an answer counted once however many files it went
    into (a camera's mounting goes to each of its frames); when nothing changed (no file written),
    ``nothing``: why. ``cost(what)``: what an answer that changed a file costs the next estimate,
    if anything (said once)."""
    notes: list[str] = []
    with usage_errors(one_line=True):
        done = put(notes)
    for note in notes:
        print(f"warning: {note}", file=sys.stderr)
    if not args.quiet:
        for source, what, changed, _ in done:
            print(f"{source}: {what}" + ("" if changed else " (in the file already)"))
        new = [source for source, _, changed, _ in done if changed]
        if not new:
            print(f"nothing changed: {nothing}; no scene file written, nothing to estimate again")
        else:
            n = len({answer for *_, changed, answer in done if changed})
            same = len({answer for *_, answer in done}) - n
            print(f"{n} {noun}{'s' if n != 1 else ''} {verb} {len(set(new))} scene file(s)"
                  + (f" ({same} in them already)" if same else "")
                  + "; run creference batch on them again, with the same settings: it re-estimates the frames "
                    "that changed")
            said = {cost(what) for _, what, changed, _ in done if changed and cost is not None} - {None}
            for text in sorted(said):
                print(f"note: {text}")
    return 0


def _apply(args) -> int:
    from ..workflows.advice.answers import apply_answers

    if not Path(args.input).is_dir():
        raise UsageError("--apply: INPUT must be the batch folder the requests are of")
    path = Path(args.apply)
    if not path.is_file():
        raise FileNotFoundError(2, "no such file", str(path))
    rows = _request_rows(path, f"--apply {path}")
    if not any((row.get("answer") or "").strip() for row in rows):
        raise UsageError(f"--apply {path}: no request is answered yet: fill in the 'answer' column of the rows "
                         "the crowd answered (docs/requests.md)")
    return _into_scenes(args, lambda notes: apply_answers(args.input, rows, notes), "answer", "put into",
                        "every answer is in the scene files already", _answer_cost)


def _request_rows(path: Path, where: str) -> list[dict]:
    """The rows of a ``requests.csv`` (dicts); UsageError naming ``where`` when it is not one."""
    try:
        rows = read_csv_rows(read_text(path))
    except UnicodeDecodeError as exc:
        raise UsageError(f"{where}: not UTF-8 text (byte {exc.start}): save requests.csv as UTF-8") from None
    except csv.Error as exc:
        raise UsageError(f"{where}: not a CSV file ({exc})") from None
    if rows and "answer" not in rows[0]:
        raise UsageError(f"{where}: no 'answer' column (a requests.csv of creference advise)")
    return rows


def _keep_answers(batch_dir: str, path: Path) -> None:
    """Refuse to advise where the new plan would replace a ``requests.csv`` that holds answers not
    yet in the scene files (typed in, not applied): UsageError naming them and what to do. Checked
    before any advice is computed; answers already put in (a rerun after ``--apply``) let it
    be replaced."""
    from ..workflows.advice.answers import apply_answers

    if not path.is_file():
        return
    where = f"{path} (the plan a new advice would replace)"
    rows = _request_rows(path, where)
    if not any((row.get("answer") or "").strip() for row in rows):
        return
    keep = (f"put them in first (creference advise {batch_dir} --apply {path}), or move the file away or give "
            "another --out; nothing was advised")
    try:
        pending = list({answer: what for _, what, changed, answer in apply_answers(batch_dir, rows, write=False)
                        if changed}.values())  # an answer once, not once per frame it goes to
    except (ValueError, OSError) as exc:
        raise UsageError(f"{where} holds answers that cannot be checked against the scene files ({exc}): {keep}") from None
    if pending:
        raise UsageError(f"{where} holds {len(pending)} answer{'s' * (len(pending) != 1)} not yet in the scene "
                         f"files ({'; '.join(pending[:3])}{'; …' if len(pending) > 3 else ''}): {keep}")


def _answer_cost(what: str) -> str | None:
    """What an answer (``apply_answers``' text of it) costs the frame's next estimate."""
    if ": size " in what:
        return ("a catalogue size ties the camera to that object's distance: on some frames the sampler then moves "
                "the camera's pitch and height more slowly, and the frame's estimate takes up to a few times longer "
                "(the same posterior; docs/studies/advice.md, 'Speed')")
    return None


def _merge(args) -> int:
    from ..workflows.advice.answers import merge_annotations

    if not Path(args.input).is_dir():
        raise UsageError("--merge: INPUT must be the batch folder the requests are of")
    folder = Path(args.merge)
    if not folder.is_dir():
        raise FileNotFoundError(2, "no such folder", str(folder))
    files = sorted(p for p in folder.glob("*.json") if not p.name.startswith("."))  # not a killed write's
    if not files:
        raise UsageError(f"--merge {folder}: no scene files (*.json): the folder creference import wrote")
    return _into_scenes(args, lambda notes: merge_annotations(args.input, files, notes), "annotation", "added to",
                        "the scene files hold every annotation of the imported scenes already")


def _run(args) -> int:
    if args.apply is not None and args.merge is not None:
        raise UsageError("--apply and --merge: one at a time (--merge first: the answers drawn, then those written)")
    if args.merge is not None or args.apply is not None:
        _only_for_a_scene(args, "--apply and --merge write answers into scene files and estimate nothing")
    if args.merge is not None:
        return _merge(args)
    if args.apply is not None:
        return _apply(args)
    settings = _settings(args)
    progress = not args.quiet and sys.stderr.isatty()
    if Path(args.input).is_dir():  # a line per scene advised when standard error is not a terminal
        from ..inference.progress import progress_mode

        return _batch(args, settings, progress_mode(args.quiet))
    if args.budget is not None:
        raise UsageError("--budget: only for a batch folder")
    if args.scheduler is not None:
        raise UsageError("--scheduler: only for a batch folder")
    return _one(args, settings, progress)


def register(subparsers) -> None:
    """Add ``advise`` to the ``creference`` command."""
    p = subparsers.add_parser(
        "advise", help="which annotation to collect next, or whether to stop",
        description="For the posterior of a scene (one target or many), the expected effect of each "
                    "request the scene allows (one more set of dimension lines on a target, one more "
                    "reference on a segment, a distance to a target, a target's length, the distance "
                    "between two targets, a target's size from a catalogue, the camera's mounting) on "
                    "every target's label quality P(IoU >= T), 90 % HDI of the distance and location sd "
                    "(preposterior simulation over the posterior draws under the model's noise model); "
                    "ranked by the labels expected to become good per human hour, with a verdict per "
                    "target and a recommendation. On a batch folder: every target's verdict and a plan "
                    "within --budget (requests.csv, Label Studio tasks, CVAT XML).")
    p.add_argument("input", metavar="INPUT",
                   help="a scene file (estimated first), a result file of the metrology model (its "
                        "posterior draws, else the Laplace approximation at its MAP), or a folder written "
                        "by creference batch")
    p.add_argument("--out", metavar="PATH", default=None,
                   help="a scene or result: write the advice as JSON to PATH; a batch folder: the "
                        "folder for the advice files (default: BATCH_DIR/advice)")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="seed of the estimate and the simulation (default: %(default)s)")
    p.add_argument("--requests", default="dims,reference,size,mounting", metavar="KINDS",
                   help="the kinds of request to weigh, of dims, reference, size, mounting, separated by "
                        "commas (default: all)")
    p.add_argument("--budget", type=float, default=None, metavar="SECONDS",
                   help="a batch folder: plan requests, most value added per human second first, "
                        "within this many seconds of human time (default: every request worth "
                        "its time)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local processes: on a batch folder, N scenes advised at once, as creference batch; on "
                        "a scene or a result, its requests weighed N at once (default: the machine's cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a batch folder: run on a Dask distributed scheduler, e.g. tcp://host:8786, as "
                        "creference batch (needs the dist extra)")
    p.add_argument("--draws", type=int, default=600, metavar="N",
                   help="posterior draws the advice weighs, thinned evenly: fewer is faster and rougher "
                        "(default: %(default)s)")
    p.add_argument("--distance-range", type=distance_range_arg, default=None, metavar="LOW,HIGH",
                   help="a scene: estimate it with this distance range in metres, as creference estimate "
                        "--distance-range (a result or a batch is advised with what it was made with)")
    p.add_argument("--merge", metavar="IMPORTED_DIR", default=None,
                   help="a batch folder: add the dimension lines and references of the scenes creference "
                        "import wrote from the answered requests (a Label Studio or CVAT export) that the "
                        "scene files the batch was made from lack, and advise nothing (do this before --apply)")
    p.add_argument("--apply", metavar="REQUESTS_CSV", default=None,
                   help="a batch folder: put the answered sizes, mountings and measurements without a "
                        "segment of REQUESTS_CSV "
                        "(its answer column) into the scene files the batch was made from, and advise "
                        "nothing")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors; no progress bar")
    g = advanced_group(p)
    g.add_argument("--image-url-prefix", metavar="PREFIX", default=None,
                   help="a batch folder: the Label Studio request tasks load each image from PREFIX "
                        "followed by its file name (e.g. /data/local-files/?d=frames/ for Label Studio's "
                        "local files; default: the scene's image path)")
    g.add_argument("--rank", choices=("labels", "hdi", "location"), default="labels",
                   help="what a request is worth: labels (the labels it is expected to make good per human "
                        "hour), hdi (how much it narrows the distances' 90 %% HDIs per minute) or location "
                        "(how much it lowers the locations' sd per minute) (default: %(default)s)")
    g.add_argument("--min-good-per-hour", type=float, default=1.0, metavar="N",
                   help="--rank labels: stop when the best request makes fewer than N labels good per "
                        "human hour (default: %(default)s)")
    g.add_argument("--target-hdi-width", type=float, default=0.10, metavar="F",
                   help="--rank hdi, location: stop when every target's 90 %% HDI of the distance is at most this "
                        "share of it (default: %(default)s, i.e. 10 %%)")
    g.add_argument("--min-gain", type=float, default=0.5, metavar="G",
                   help="--rank hdi, location: stop when the best expected gain is below G points of the "
                        "distance (HDI width or location sd in percent of the distance) per minute of human "
                        "time (default: %(default)s)")
    g.add_argument("--score-iou", type=float, default=0.7, metavar="T",
                   help="a label's quality is P(IoU >= T) (default: %(default)s)")
    g.add_argument("--min-quality", type=float, default=0.5, metavar="Q",
                   help="a label is good when its P(IoU >= T) >= Q, as creference labels --min-quality "
                        "(default: %(default)s)")
    g.add_argument("--futures", type=int, default=150, metavar="M",
                   help="how many possible answers to each request are simulated to weigh it: more is "
                        "slower and steadier (default: %(default)s)")
    g.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="a scene: change one setting of the metrology model for its estimate, as creference "
                        "estimate --option (repeatable; docs/user_guide.md, Model options)")
    g.add_argument("--lines", default="keypoints", choices=("keypoints", "vectors"),
                   help="how the Label Studio requests draw a segment, as the project's labelling "
                        "config does (default: %(default)s)")
    g.add_argument("--scene", metavar="SCENE", default=None,
                   help="the scene of a result file (default: the batch copy, or the file the "
                        "result names next to it)")
    p.set_defaults(func=_run)
