"""Are a frame's posteriors calibrated? Simulated street frames, every object at once.

The frames are the bench's scenes of several targets (docs/studies/benchmark.md, "Scenes of
several targets"): street cameras, 5 sets of dimension lines per object, no focal length and no
horizon given, sizes left to the class priors (``--sizes known``: given), the `low` (2 px) and
`high` (5 px, Student-t) tiers. Each frame is estimated once with the package's defaults (MAP, then the posterior). Per
quantity (the camera's focal length, height, pitch and roll; each object's ground distance,
length, width, height and ground offset): the share of true values inside the posterior's central
90 % interval (calibrated: 90 %) and the mean quantile of the truth in the posterior (calibrated:
0.5), each with a 95 % interval from a bootstrap over frames: the objects of a frame share its
camera, so a frame of 15 objects is not 15 independent checks.

    python examples/frame_calibration.py --frames 20 --out frame_cal     # 120 frames, 640 objects; 5 minutes
    python examples/frame_calibration.py --frames 10 --sizes known --out frame_cal_sized

Records go to ``OUT/frames.jsonl`` (one line per object), the table to ``OUT/frames.md``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from creference_bayes.bench.runner import FRAME_TIERS, street_scene
from creference_bayes.evaluation.reliability import cluster_bootstrap
from creference_bayes.io.files import atomic_write_text
from creference_bayes.models.contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, O_X, O_Z
from creference_bayes.pipeline import estimate

#: The quantities checked: camera ones (one per frame) and object ones (one per object).
CAMERA_QUANTITIES = ("focal_length_px", "camera_height_m", "pitch_rad", "roll_rad")
OBJECT_QUANTITIES = ("distance_m", "length_m", "width_m", "height_m", "ground_m")


def _quantile(draws, truth) -> float | None:
    """The share of draws below the true value; None for a quantity the model holds fixed (every
    draw the same, as the ground offset of a frame's only object), which has nothing to check."""
    draws = np.asarray(draws, float)
    return None if np.ptp(draws) == 0 else float(np.mean(draws < truth))


def frame_records(scene, result, frame: str) -> list[dict]:
    """One record per object: the quantile of each true value in the posterior draws (the share of
    draws below it; None when the quantity is fixed), the camera's repeated on each of its objects."""
    cams = result.draws.cameras.reshape(-1, result.draws.cameras.shape[-1])
    objs = result.draws.objects.reshape(-1, *result.draws.objects.shape[-2:])
    g = scene.ground_truth
    cam = {name: _quantile(cams[:, c], g[name])
           for name, c in zip(CAMERA_QUANTITIES, (C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL))}
    out = []
    for i, t in enumerate(scene.targets):
        tg = t.ground_truth
        x, _, z = tg["location_m"]
        sizes = objs[:, i, O_SIZE]
        truth = {"distance_m": (np.hypot(objs[:, i, O_X], objs[:, i, O_Z]), float(np.hypot(x, z))),
                 "length_m": (sizes[:, 0], tg["dimensions_m"]["length"]),
                 "width_m": (sizes[:, 1], tg["dimensions_m"]["width"]),
                 "height_m": (sizes[:, 2], tg["dimensions_m"]["height"]),
                 "ground_m": (objs[:, i, O_GROUND], tg["ground_m"])}
        out.append({"frame": frame, "object": t.id, "cls": t.cls, "distance": float(np.hypot(x, z)),
                    **cam, **{name: _quantile(draws, v) for name, (draws, v) in truth.items()}})
    return out


def run(args) -> list[dict]:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    records = []
    sampling = {"min_ess": args.min_ess} if args.min_ess else None
    with open(out / "frames.jsonl", "w") as f:
        for tier in args.tiers:
            for n in args.counts:
                for k in range(args.frames):
                    scene = street_scene(tier, n, k, args.seed, sizes=args.sizes)
                    result = estimate(scene, seed=k, sampling=sampling, keep_draws=0)
                    recs = frame_records(scene, result, f"{tier}-{n}-{k}")
                    for r in recs:
                        r.update(tier=tier, n_objects=n, converged=bool(result.converged))
                        f.write(json.dumps(r) + "\n")
                    f.flush()
                    records += recs
                    print(f"{tier}, {n} objects, frame {k}: converged {result.converged}", flush=True)
    return records


def table(records: list[dict]) -> str:
    """The Markdown table: per quantity, frames or objects, the central 90 % interval's coverage
    and the mean quantile, each with its bootstrap interval over frames."""
    head = ("| quantity | checks | 90 % interval covers | 95 % interval | mean quantile | 95 % interval |\n"
            "|---|---|---|---|---|---|")
    rows = []
    first = {}
    for r in records:  # the camera's quantities: once per frame
        first.setdefault(r["frame"], r)
    for name in (*CAMERA_QUANTITIES, *OBJECT_QUANTITIES):
        s = [r for r in (first.values() if name in CAMERA_QUANTITIES else records) if r[name] is not None]
        if not s:
            rows.append(f"| {name} | 0 (held fixed) | | | | |")
            continue
        q = np.array([r[name] for r in s])
        covered = (q > 0.05) & (q < 0.95)
        lo, hi = cluster_bootstrap(np.c_[covered, q], [r["frame"] for r in s])
        rows.append(f"| {name} | {len(s)} | {100 * covered.mean():.1f} % | {100 * lo[0]:.1f}–{100 * hi[0]:.1f} % | "
                    f"{q.mean():.3f} | {lo[1]:.3f}–{hi[1]:.3f} |")
    conv = np.mean([r["converged"] for r in first.values()])
    return "\n".join([head, *rows]) + f"\n\n{len(first)} frames, {len(records)} objects, {100 * conv:.0f} % converged\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=20, help="frames per tier and object count (default: %(default)s)")
    p.add_argument("--counts", default="3,5,8", help="objects per frame, comma-separated (default: %(default)s)")
    p.add_argument("--tiers", default="low,high", help="noise tiers, comma-separated (default: %(default)s)")
    p.add_argument("--sizes", choices=("prior", "known"), default="prior",
                   help="the objects' sizes: their class's prior, or known (a catalogue's) (default: %(default)s)")
    p.add_argument("--seed", type=int, default=1, help="the frames' seed (the bench's frames use 0; default: %(default)s)")
    p.add_argument("--min-ess", type=int, default=None, help="bulk ESS of each posterior (default: the package's)")
    p.add_argument("--out", default="frame_calibration", help="output folder (default: %(default)s)")
    args = p.parse_args(argv)
    args.tiers = [t.strip() for t in args.tiers.split(",")]
    if not args.tiers or set(args.tiers) - set(FRAME_TIERS):
        p.error(f"--tiers: expected names of {list(FRAME_TIERS)}, comma-separated; got {','.join(args.tiers)!r}")
    raw = args.counts
    try:
        args.counts = [int(v) for v in raw.split(",")]
    except ValueError:
        args.counts = []
    if not args.counts or min(args.counts) < 1 or args.frames < 1:
        p.error(f"--counts and --frames: expected whole numbers ≥ 1, got --counts {raw!r} --frames {args.frames}")
    records = run(args)
    text = table(records)
    atomic_write_text(Path(args.out) / "frames.md", text)
    print(text)


if __name__ == "__main__":
    main()
