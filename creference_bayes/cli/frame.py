"""``creference estimate`` on a frame (``creference-scene/2``): a table per object and one for
the camera; and ``creference simulate --objects K``, frames with several objects."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from .main import UsageError
from ..io.files import read_text

__all__ = ["is_frame_file", "run_frame_estimate", "format_frame_tables", "run_frame_simulate",
           "run_kitti_simulate", "add_frame_simulate_options"]


def is_frame_file(path) -> bool:
    """Whether the scene file at ``path`` says ``creference-scene/2`` (other files go the
    single-target way; a file that cannot be read is left to the loader's error)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 20)
        return json.loads(head.decode("utf-8-sig")).get("format") == "creference-scene/2"
    except (OSError, ValueError, AttributeError):
        return False


def _load_classes(path):
    if path is None:
        return None
    from ..models.size_priors import size_priors_from_dict

    try:
        data = json.loads(read_text(path))
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno}") from None
    try:
        return size_priors_from_dict(data, f"{path}", "file")
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def frame_location_prior(option: str) -> str:
    """``--location-prior`` for a frame: ``auto`` is the frame default; ``inverse-square`` is a
    single-target comparison only (a usage error)."""
    from ..models.frame import FRAME_LOCATION_PRIORS

    if option == "auto":
        return FRAME_LOCATION_PRIORS[0]
    if option not in FRAME_LOCATION_PRIORS:
        raise UsageError(f"--location-prior: frames take {' or '.join(FRAME_LOCATION_PRIORS)}, got {option!r}")
    return option


def run_frame_estimate(args) -> int:
    from ..frame_pipeline import estimate_frame
    from ..io.files import atomic_write_json
    from ..io.frame_scene import load_frame

    classes = _load_classes(getattr(args, "classes", None))
    frame = load_frame(args.scene, classes=classes)
    for w in frame.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.model != "metrology" or args.preset != "default":
        raise UsageError("--model and --preset apply to single-target scenes; a creference-scene/2 frame "
                         "uses the frame model")
    if args.netcdf:
        raise UsageError("--netcdf: not yet available for frames (the result file holds the summaries)")
    sampling = {} if args.min_ess is None else {"min_ess": args.min_ess}
    location = frame_location_prior(args.location_prior)
    result = estimate_frame(frame, seed=args.seed, posterior=not args.no_posterior, hdi_prob=args.hdi_prob,
                            location_prior=location,
                            temperature=1.0 if args.temperature is None else args.temperature,
                            focal_prior=args.focal_prior, orientation=args.orientation,
                            classes=classes,
                            use_references=not args.no_references, sampling=sampling,
                            progress=not args.quiet and sys.stderr.isatty())
    if args.out:
        atomic_write_json(args.out, result.to_dict(), inline_numbers=True)
    if not args.quiet:
        print(format_frame_tables(result.to_dict()))
        for w in result.warnings:
            print(f"warning: {w}", file=sys.stderr)
        if args.out:
            print(f"wrote {args.out}")
    return 0


def _f(v, nd=2):
    return "-" if v is None else f"{v:.{nd}f}"


def format_frame_tables(d: dict) -> str:
    """The camera table and the per-object table of a ``creference-result/2`` dict."""
    cam = d["camera"]
    post = cam.get("posterior")
    prob = post["hdi"]["prob"] if post else None
    lines = ["camera" + (f" (MAP; posterior mean and {prob:.0%} HDI)" if post else " (MAP)")]
    show = {"focal_length_px": ("focal length px", 1, 1.0), "pitch": ("pitch deg", 2, 180 / np.pi),
            "roll": ("roll deg", 2, 180 / np.pi), "height_m": ("height m", 3, 1.0), "ref_scale": ("crowd scale", 3, 1.0)}
    for key, (label, nd, k) in show.items():
        m = cam["map"][key]
        row = f"  {label:<16}{_f(m * k, nd):>10}"
        if post and key in post["mean"]:
            lo, hi = post["hdi"][key]
            row += f"{_f(post['mean'][key] * k, nd):>10}  [{_f(lo * k, nd)}, {_f(hi * k, nd)}]"
        elif key not in cam["free"]:
            row += "  (fixed)" if key != "ref_scale" else "  (no references)"
        lines.append(row)
    lines.append("")
    head = f"  {'target':<10}{'class':<11}{'dist m':>8}{'x':>8}{'z':>8}{'yaw°':>7}{'l×w×h m':>16}"
    head += f"{'dist HDI':>18}" if post else ""
    truth = any("evaluation" in o for o in d["objects"])
    head += f"{'err %':>7}" if truth else ""
    lines.append("objects (MAP" + (f"; distance {prob:.0%} HDI)" if post else ")"))
    lines.append(head)
    for o in d["objects"]:
        m = o["map"]
        size = f"{m['length_m']:.2f}×{m['width_m']:.2f}×{m['height_m']:.2f}"
        row = (f"  {o['id'][:9]:<10}{str(o['class'] or '-')[:10]:<11}{_f(m['distance_m']):>8}{_f(m['x']):>8}"
               f"{_f(m['z']):>8}{_f(np.degrees(m['yaw']), 0):>7}{size:>16}")
        if post:
            lo, hi = o["posterior"]["hdi"]["distance_m"]
            row += f"{'[' + _f(lo) + ', ' + _f(hi) + ']':>18}"
        if truth:
            row += f"{_f(o.get('evaluation', {}).get('location_pct_error'), 1):>7}"
        lines.append(row)
    diag = d.get("diagnostics")
    if diag:
        lines.append("")
        lines.append(f"posterior: {'converged' if diag['converged'] else 'NOT converged'} after "
                     f"{diag['iterations']} iterations × {diag['n_chains']} chains (min bulk ESS "
                     f"{diag['min_ess_bulk']}, max R-hat {diag['max_r_hat']}), {d['seconds']:.1f} s")
    return "\n".join(lines)


def run_frame_simulate(args) -> int:
    """``creference simulate OUTDIR --n N --objects K``: N frames of K objects each."""
    from ..bench.frame_simulate import simulate_frame
    from ..io.files import atomic_write_json

    if args.seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {args.seed}")
    for name in ("objects", "n", "annotations"):
        if getattr(args, name) < 1:
            raise UsageError(f"--{name}: expected an integer ≥ 1, got {getattr(args, name)}")
    if not args.noise_px >= 0:
        raise UsageError(f"--noise-px: expected a number ≥ 0, got {args.noise_px}")
    out = Path(args.outdir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder")
    if not args.overwrite and out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out}: the folder is not empty; choose another or pass --overwrite")
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    for k in range(args.n):
        scene = simulate_frame(rng, kind=args.kind, n_objects=args.objects, n_annotations=args.annotations,
                               noise_px=args.noise_px, focal_known=args.focal_known, horizon=args.horizon)
        atomic_write_json(out / f"frame_{k:04d}.json", scene)
    if not args.quiet:
        print(f"wrote {args.n} frames to {out}")
    return 0


def run_kitti_simulate(args) -> int:
    """``creference simulate --from-kitti DIR --out SCENES``: frames on KITTI's real geometry."""
    from ..bench.kitti_frames import kitti_frames

    if args.seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {args.seed}")
    if args.annotations < 1:
        raise UsageError(f"--annotations: expected an integer ≥ 1, got {args.annotations}")
    if not args.noise_px >= 0:
        raise UsageError(f"--noise-px: expected a number ≥ 0, got {args.noise_px}")
    src = Path(args.from_kitti)
    if not (src / "label_2").is_dir() or not (src / "calib").is_dir():
        raise UsageError(f"--from-kitti {src}: not a KITTI folder (needs label_2/ and calib/)")
    out = Path(args.outdir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: not a folder")
    if not args.overwrite and out.is_dir() and any(out.iterdir()):
        raise UsageError(f"{out}: the folder is not empty; choose another or pass --overwrite")
    try:
        totals = kitti_frames(src, out, n_annotations=args.annotations, noise_px=args.noise_px, seed=args.seed,
                              sizes=args.sizes)
    except ValueError as exc:  # a malformed label or calib file: its message names file and line
        raise UsageError(str(exc)) from None
    if not args.quiet:
        skipped = ", ".join(f"{v} by {k}" for k, v in totals["skipped"].items() if v)
        print(f"wrote {totals['frames']} frames with {totals['kept']} objects to {out}"
              + (f" (left out: {skipped})" if skipped else ""))
    return 0


def add_frame_simulate_options(p) -> None:
    """The frame options of ``creference simulate``."""
    g = p.add_argument_group("frames (creference-scene/2, docs/frames.md)")
    g.add_argument("--from-kitti", metavar="DIR", default=None,
                   help="frames from a KITTI folder (label_2/, calib/, image_2/): simulated dimension lines "
                        "on the real boxes (docs/kitti.md)")
    g.add_argument("--sizes", choices=("prior", "known"), default="prior",
                   help="with --from-kitti: prior (the default) leaves the objects' sizes to their class "
                        "priors, as a crowd knows them; known writes each object's true size into the frame")
    g.add_argument("--objects", type=int, default=None, metavar="K",
                   help="write frames of K targets each instead of single-target scenes")
    g.add_argument("--kind", choices=("street", "indoor"), default="street", help="frames: the kind of scene")
    g.add_argument("--annotations", type=int, default=5, help="frames: dimension-line sets per target (default: %(default)s)")
    g.add_argument("--noise-px", type=float, default=2.0, help="frames: pixel noise per corner (default: %(default)s)")
    g.add_argument("--focal-known", action="store_true", help="frames: write the true focal length into the scene")
    g.add_argument("--horizon", choices=("none", "exact", "sd"), default="none",
                   help="frames: the horizon the scene gives (default: %(default)s)")
