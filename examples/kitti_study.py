"""The model on real street geometry: KITTI images in, KITTI labels out, AP3D against KITTI.

    python examples/kitti_study.py KITTI_DIR --out kitti_study/ [--annotations 5] [--noise-px 2]

For a KITTI-layout folder (label_2/, calib/, image_2/) it

1. simulates crowd annotations on the real boxes (``creference simulate --from-kitti``): one scene
   per image with every annotatable object;
2. estimates every scene jointly (MAP and posterior, one shared camera) and every object alone (a
   scene of that object only, with its own camera, its class's size prior: MAP);
3. draws boxes from the scene's Cramér–Rao covariance around the truth (the bound);
4. writes KITTI labels for each (``joint/``, ``alone/``, ``bound/``: label_2/, calib/, and
   uncertainty/ for the joint) in KITTI's frame of P2, and evaluates them with
   ``creference evaluate kitti``'s code against the folder's own label_2.

Scores: the joint labels carry P(IoU ≥ 0.7) from the posterior; ``--same-score`` gives every method
the same depth-based score instead (exp(−z / 40 m)), to compare geometry alone. Prints the AP table
(Car, Pedestrian, Cyclist; R40), the median 3D IoU by distance band, the label quality (mean
predicted against observed P(IoU ≥ 0.7), Brier score), each method's Car box errors against the
ground-truth boxes they were matched to (median absolute depth, height / width / length and yaw
error by distance band), with ``--focal unknown`` each frame's estimated focal length against P2's
by the number of objects in the frame, and the time per image. ``--option KEY=VALUE`` sets a
metrology model option for the joint and the alone estimates. ``--max-frames`` and ``--max-steps``
make a tiny run (the tests).

``--focal unknown --focal-sd S`` gives every frame P2's focal length as a log-normal prior of
log-sd S instead of a rig: what a camera pooled over many frames would give, to measure how well
the focal length must be known.

The bound under other assumptions (``--methods bound`` runs it alone, in seconds):
``--bound-option KEY=VALUE`` sets a model option for the bound's model only (for example
``ground_sd_m=0.005`` and ``ground_sd_per_m=0``: a flat road); ``--sizes known`` gives every
method each object's true size (no class prior). Each method's share of fully visible cars (KITTI occlusion 0) at 5–60 m
whose label reaches IoU 0.7 is printed by band.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np


def _model_options(pairs, parser) -> dict:
    """``KEY=VALUE`` strings → metrology model options (:func:`~creference_bayes.pipeline.parse_model_options`)
    and ``location_prior`` and ``distance_range=LOW,HIGH`` (metres, creference estimate --distance-range)."""
    from creference_bayes.pipeline import parse_model_options

    setup = ("location_prior=", "distance_range=")
    rest = [item for item in pairs if not item.startswith(setup)]
    out = {item.partition("=")[0]: item.partition("=")[2] for item in pairs if item.startswith(setup)}
    try:
        if "distance_range" in out:
            text = out["distance_range"]
            from creference_bayes.models.location_prior import LocationPrior

            try:
                out["distance_range"] = LocationPrior(distance_m=tuple(float(v) for v in text.split(","))).distance_m
            except ValueError:
                raise ValueError(f"--option distance_range: expected LOW,HIGH in metres (0 < LOW < HIGH), "
                                 f"got {text!r}") from None
        return {**parse_model_options("metrology", rest), **out}
    except ValueError as exc:
        parser.error(str(exc))


def _gt_row(gt: dict, gt_dir: Path, o: dict):
    """The ground-truth labels of ``o``'s image (read once into ``gt``) and the row the evaluation
    matched ``o`` to."""
    from creference_bayes.io.kitti_read import read_kitti_labels

    if o["image"] not in gt:
        gt[o["image"]] = read_kitti_labels(gt_dir / f"{o['image']}.txt", scores=False)
    g = gt[o["image"]]
    return g, int(np.flatnonzero(g.line == o["reference_line"])[0])


def _box_errors(gt: dict, gt_dir: Path, label_dir: Path, objects: list[dict]) -> dict:
    """Per distance band, the median absolute errors of the Car labels against the ground-truth box
    the evaluation matched each to: depth (% of the true z), log-sizes (%), yaw (°); and the count."""
    from creference_bayes.io.kitti_read import read_kitti_labels

    labels, rows = {}, []
    for o in objects:
        if o["type"] != "Car" or o.get("reference_line") is None:
            continue
        if o["image"] not in labels:
            labels[o["image"]] = read_kitti_labels(label_dir / f"{o['image']}.txt", scores=True)
        (g, i), d = _gt_row(gt, gt_dir, o), labels[o["image"]]
        j = int(np.flatnonzero(d.line == o["line"])[0])
        z = g.location[i, 2]
        yaw = (d.rotation_y[j] - g.rotation_y[i] + np.pi / 2) % np.pi - np.pi / 2
        rows.append([z, 100 * abs(d.location[j, 2] - z) / z, *(100 * np.abs(np.log(d.dimensions[j] / g.dimensions[i]))),
                     np.degrees(abs(yaw))])
    out = {}
    rows = np.array(rows).reshape(-1, 6)
    for lo, hi, name in ((0, 20, "0-20 m"), (20, 40, "20-40 m"), (40, np.inf, "40+ m")):
        sel = rows[(rows[:, 0] >= lo) & (rows[:, 0] < hi)]
        if len(sel):
            out[name] = [*np.median(sel[:, 1:], axis=0), len(sel)]
    return out


def _visible_car_shares(gt: dict, gt_dir: Path, objects: list[dict]) -> dict:
    """Among labels matched to a fully visible Car (occlusion 0) whose true distance is 5–60 m: per
    band (5–20, 20–40, 40–60 m and all), [share with 3D IoU ≥ 0.7, count]."""
    rows = []
    for o in objects:
        if o.get("reference_line") is None or o.get("reference_type") != "Car":
            continue
        g, i = _gt_row(gt, gt_dir, o)
        d = float(np.hypot(g.location[i, 0], g.location[i, 2]))
        if g.occluded[i] == 0 and 5.0 <= d < 60.0:
            rows.append((d, o["iou_3d"] >= 0.7))
    rows = np.array(rows, float).reshape(-1, 2)
    out = {}
    for lo, hi, name in ((5, 20, "5-20 m"), (20, 40, "20-40 m"), (40, 60, "40-60 m"), (5, 60, "5-60 m")):
        sel = rows[(rows[:, 0] >= lo) & (rows[:, 0] < hi), 1]
        out[name] = [float(sel.mean()) if len(sel) else float("nan"), int(len(sel))]
    return out


def _truth_state(frame):
    """The true camera (5,) (its height the objects' median bottom) and objects (m, 7)."""
    objs = []
    for t in frame.targets:
        g = t.ground_truth
        d = g["dimensions_m"]
        objs.append([g["location_m"][0], g["location_m"][2], g["yaw_rad"], d["length"], d["width"], d["height"], 0.0])
    h = float(np.median([t.ground_truth["location_m"][1] for t in frame.targets]))
    objs = np.array(objs)
    objs[:, 6] = h - np.array([t.ground_truth["location_m"][1] for t in frame.targets])
    return np.array([frame.focal_length_px, 0.0, 0.0, h, 0.5]), objs


def replace_targets(frame, targets):
    """The frame with only ``targets`` (its camera knowledge, priors included, kept; references
    that name a target other than these are left out)."""
    keep = [frame.targets.index(t) for t in targets]
    refs = [(r, None if o is None else keep.index(o)) for r, o in zip(frame.references, frame.reference_targets)
            if o is None or o in keep]
    return replace(frame, targets=tuple(targets), references=tuple(r for r, _ in refs),
                   reference_targets=tuple(o for _, o in refs))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("kitti", help="a KITTI folder (label_2/, calib/, image_2/)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--annotations", type=int, default=5)
    p.add_argument("--noise-px", type=float, default=2.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--max-steps", type=int, default=20000, help="the sampler's cap on steps per image")
    p.add_argument("--same-score", action="store_true", help="score every method by depth (module docstring)")
    p.add_argument("--camera", choices=("unknown", "known", "rig"), default="unknown",
                   help="unknown: only P2's focal length and principal point (the default); known: also the "
                        "camera's height (the objects' median bottom, ±2 %%) and a level pose (±0.5°), as a "
                        "rig with a measured mounting would give: shows how much of the gap to the goals is "
                        "the camera's scale; rig: the same, but one height for every frame of a camera (the "
                        "median over its frames of their objects' median bottom, as wide as those medians "
                        "spread, at least ±2 %%): the most a mounting shared by the frames can tell")
    p.add_argument("--focal", choices=("known", "unknown"), default="known",
                   help="known: P2's focal length is given (the default); unknown: left out of every scene (a "
                        "street camera nobody calibrated; creference simulate --from-kitti --focal-unknown)")
    p.add_argument("--focal-sd", type=float, default=None, metavar="LOG_SD",
                   help="with --focal unknown: give every frame P2's focal length as a log-normal prior of this "
                        "log-sd (0.02: ±2 %%), as a camera pooled over many frames would: how well the focal "
                        "length must be known (docs/studies/kitti.md); not with --rig")
    p.add_argument("--rig", choices=("none", "focal", "mounting"), default="none",
                   help="pool what frames of one camera share before the joint labels (creference batch --rig): "
                        "the focal length, or also the mounting (height, pitch, roll); default: each frame alone")
    p.add_argument("--split", choices=("all", "even", "odd"), default="all",
                   help="use every frame, or only those with an even or odd number (tune on one half, report on "
                        "the other; pooling uses only the frames in use)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="a metrology model option for the joint and the alone estimates (repeatable; "
                        "creference_bayes.pipeline.MODEL_OPTIONS, location_prior and distance_range=LOW,HIGH), e.g. "
                        "target_dof=30")
    p.add_argument("--methods", default="joint,alone,bound",
                   help="which of joint, alone, bound to run (comma-separated; default all three)")
    p.add_argument("--bound-option", action="append", default=[], metavar="KEY=VALUE",
                   help="a model option for the bound's model only (repeatable), e.g. ground_sd_m=0.005")
    p.add_argument("--sizes", choices=("prior", "known"), default="prior",
                   help="prior: sizes from the class priors (the default, what a crowd knows); known: every "
                        "method is given each object's true size (creference simulate --from-kitti --sizes known)")
    args = p.parse_args(argv)
    options = _model_options(args.option, p)
    bound_options = _model_options(args.bound_option, p)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods or set(methods) - {"joint", "alone", "bound"}:
        p.error(f"--methods {args.methods!r}: expected a comma-separated subset of joint, alone, bound")
    if args.rig != "none" and "joint" not in methods:
        p.error(f"--rig {args.rig}: pools the joint estimates' cameras; add joint to --methods")
    if args.focal_sd is not None:
        if not (np.isfinite(args.focal_sd) and args.focal_sd > 0):
            p.error(f"--focal-sd: expected a log-sd > 0, got {args.focal_sd}")
        if args.focal != "unknown" or args.rig != "none":
            p.error("--focal-sd: gives the focal length's prior in place of a rig; use it with --focal unknown "
                    "and without --rig")

    from creference_bayes.bench.kitti import kitti_scenes
    from creference_bayes.evaluation.kitti_eval import evaluate_kitti
    from creference_bayes.io.kitti import write_label_file
    from creference_bayes.pipeline import estimate
    from creference_bayes.workflows.labels.kitti import LabelInput, write_labels

    out = Path(args.out)
    scenes = out / "scenes"
    totals = kitti_scenes(args.kitti, scenes, n_annotations=args.annotations, noise_px=args.noise_px, seed=args.seed,
                          sizes=args.sizes, focal_known=args.focal == "known")
    paths = sorted(scenes.glob("*.json"))
    if args.split != "all":
        paths = [p for p in paths if int(p.stem) % 2 == (args.split == "odd")]
    paths = paths[:args.max_frames]
    print(f"{totals['scenes']} images, {totals['kept']} objects (left out: {totals['skipped']}); using {len(paths)}")
    rng = np.random.default_rng(args.seed)
    times = []
    rig_pool, rigs, first_pass = None, {}, {}
    mounts = _rig_mountings(paths) if args.camera == "rig" else None
    if mounts is not None:
        print(_mountings_text(paths, mounts))
    focal_rows = []  # each joint frame's focal length against P2's, when it was estimated
    if args.rig != "none" and "joint" in methods:  # pass one: every frame alone, for its camera's rig
        from creference_bayes.workflows.batch.rig import RigPool, shared_likelihood

        frames = []
        for path in paths:
            frame = _load_frame(path, args.camera, mounts=mounts)  # (no --focal-sd with a rig)
            t0 = time.perf_counter()
            res = estimate(frame, seed=args.seed, sampling={"max_steps": args.max_steps}, **options)
            first_pass[path.stem] = time.perf_counter() - t0
            frames.append(shared_likelihood(path.stem, frame.camera_id, res.to_dict()))
        rig_pool = RigPool(frames, args.rig)  # grouped by camera once
        print(f"rig pass one: {len(paths)} frames, median {np.median(list(first_pass.values())):.1f} s", flush=True)
    for path in paths:
        frame = _load_frame(path, args.camera, args.focal_sd, mounts)
        name = path.stem
        depth_score = lambda z: np.exp(-np.asarray(z) / 40.0)
        if "joint" in methods:
            if rig_pool is not None:
                from creference_bayes.workflows.batch.rig import apply_rig, rig_report

                frame, est = apply_rig(frame, rig_pool, args.rig, name)
                rigs[name] = rig_report(est)
            t0 = time.perf_counter()
            res = estimate(frame, seed=args.seed, sampling={"max_steps": args.max_steps}, **options)
            times.append(time.perf_counter() - t0 + first_pass.get(name, 0.0))
            d = res.to_dict()
            focal_rows.append(_focal_row(frame, res, d))
            labels, _ = write_labels(out / "joint", name, [LabelInput(name, d, frame)])
            if args.same_score:
                write_label_file(out / "joint" / "label_2" / f"{name}.txt",
                                 [replace(o.kitti, score=float(depth_score(o.kitti.location[2]))) for o in labels])
            print(f"{name}: {len(frame.targets)} objects, {times[-1]:.1f} s, converged "
                  f"{d['diagnostics']['converged']}", flush=True)
        if "alone" in methods:
            _alone(frame, name, options, out, depth_score)
        if "bound" in methods:
            _bound(frame, name, bound_options, args, out, rng, depth_score)
    gt = Path(args.kitti) / "label_2"
    gt_labels = {}  # each image's ground truth, read once for every table
    report = {}
    print()
    print(f"{'method':<8}{'class':<12}{'IoU':>5}{'easy':>8}{'moderate':>10}{'hard':>8}   (AP3D R40)")
    for method in methods:
        ev = evaluate_kitti(gt, out / method / "label_2")
        report[method] = ev.to_dict()
        for cls, thr in (("Car", 0.7), ("Car", 0.5), ("Pedestrian", 0.5), ("Cyclist", 0.5)):
            rows = {r["difficulty"]: r["ap_r40"] for r in ev.ap if r["class"] == cls and r["min_overlap"] == thr
                    and r["metric"] == "3d"}
            if rows:
                print(f"{method:<8}{cls:<12}{thr:>5.1f}{rows.get('easy', 0):>8.1f}{rows.get('moderate', 0):>10.1f}"
                      f"{rows.get('hard', 0):>8.1f}")
    print()
    print(f"{'method':<8}" + "".join(f"{b:>14}" for b in ("0-20 m", "20-40 m", "40+ m")) + "   (median 3D IoU, n)")
    for method in methods:
        objs = report[method]["objects"]
        cells = []
        for lo, hi in ((0, 20), (20, 40), (40, 1e9)):
            v = [o["iou_3d"] for o in objs if lo <= (o.get("distance_m") or 0) < hi]
            cells.append(f"{np.median(v):.2f} ({len(v)})" if v else "-")
        print(f"{method:<8}" + "".join(f"{c:>14}" for c in cells))
    print()
    print("fully visible cars (occlusion 0) at 5-60 m whose label reaches 3D IoU 0.7: share (n)")
    for method in methods:
        shares = _visible_car_shares(gt_labels, gt, report[method]["objects"])
        print(f"{method:<8}" + "".join(f"{band:>9} {v[0]:4.2f} ({v[1]})" for band, v in shares.items()))
    print()
    print("Car boxes against the ground-truth box each was matched to (median absolute error: depth %, "
          "height / width / length %, yaw °; n)")
    for method in methods:
        for band, row in _box_errors(gt_labels, gt, out / method / "label_2", report[method]["objects"]).items():
            print(f"{method:<8}{band:>8}  depth {row[0]:5.1f}  h/w/l {row[1]:4.1f} {row[2]:4.1f} {row[3]:4.1f}"
                  f"  yaw {row[4]:4.1f}  n {row[5]}")
    for thr in ("0.5", "0.7"):
        rel = report["joint"]["reliability"].get(f"p_iou_ge_{thr}") if "joint" in report else None
        if not rel:
            continue
        diff, se = _frame_se(report["joint"]["objects"], float(thr))
        print(f"\nlabel quality (joint): mean predicted P(IoU ≥ {thr}) {rel['mean_predicted']:.2f}, observed "
              f"{rel['observed_share']:.2f}, Brier {rel['brier']:.3f} over {rel['count']} labels; predicted − "
              f"observed {diff:+.3f}, se by frame {se:.3f} ({diff / se if se > 0 else float('nan'):+.1f} se)")
        print(f"predicted P(IoU ≥ {thr}) bin: labels, mean predicted, observed share ± 2 se, within 2 se")
        for r in rel["rows"]:
            if r["count"]:
                ok = abs(r["observed_share"] - r["mean_predicted"]) <= 2 * r["se"]
                print(f"  {r['low']:.1f}–{r['high']:.1f}: {r['count']:4d}, {r['mean_predicted']:.2f}, "
                      f"{r['observed_share']:.2f} ± {2 * r['se']:.2f}, {'yes' if ok else 'NO'}")
    focal_rows = [r for r in focal_rows if r is not None]
    if focal_rows:
        print("\n" + _focal_table(focal_rows))
    if times:
        print(f"time per frame: median {np.median(times):.1f} s, max {np.max(times):.1f} s"
              + (" (both passes)" if rig_pool is not None else ""))
    if rigs:
        _print_rigs(rigs, paths, out)
    (out / "study.json").write_text(json.dumps({"times": times, "rigs": rigs, **{k: {"ap": v["ap"], "reliability": v["reliability"]}
                                                                    for k, v in report.items()}}, indent=1))
    return 0


def _frame_se(objects: list[dict], t: float) -> tuple[float, float]:
    """The mean of (predicted P(IoU ≥ t) − whether the label reached t) over the labels that state
    it, and its standard error with the labels of one image as a cluster (they share its camera,
    so their errors are not independent): √(Σ_frames (Σ_labels (d − mean))²) / n."""
    rows = [o for o in objects if o.get(f"p_iou_ge_{t:g}") is not None]
    if not rows:
        return float("nan"), float("nan")
    d = np.array([o[f"p_iou_ge_{t:g}"] - float(o["iou_3d"] >= t) for o in rows])
    _, frame = np.unique([o["image"] for o in rows], return_inverse=True)
    mean = float(d.mean())
    sums = np.bincount(frame, d - mean)  # per frame
    return mean, float(np.sqrt(np.sum(sums**2)) / len(d))


def _focal_row(frame, res, d: dict) -> tuple[int, float, float, bool] | None:
    """A joint frame's estimated focal length against P2's (the scene's ground truth): (objects,
    posterior median ÷ P2, the quantile of P2 in the draws, P2 in the 90 % HDI); None when the
    focal length was given. ``d`` is ``res.to_dict()``."""
    truth = (frame.ground_truth or {}).get("focal_length_px")
    if frame.focal_length_px is not None or truth is None or res.draws is None:
        return None
    draws = res.draws.cameras[..., 0].ravel()
    lo, hi = d["camera"]["posterior"]["hdi"]["focal_length_px"]
    return len(frame.targets), float(np.median(draws) / truth), float(np.mean(draws < truth)), bool(lo <= truth <= hi)


def _focal_table(rows) -> str:
    """The frames' focal lengths against P2's, by objects per frame: where an unknown focal
    length goes wrong (a calibrated posterior puts P2 at a mean quantile of 0.5, inside 90 % of
    its 90 % HDIs)."""
    r = np.array(rows, float)
    lines = ["the frames' focal lengths against P2 (focal length estimated), by objects per frame: frames, "
             "median of (posterior median ÷ P2), mean quantile of P2 in the posterior, P2 in the 90 % HDI"]
    for name, lo, hi in (("1", 1, 1), ("2-3", 2, 3), ("4-7", 4, 7), ("8+", 8, np.inf), ("all", 1, np.inf)):
        s = r[(r[:, 0] >= lo) & (r[:, 0] <= hi)]
        if len(s):
            lines.append(f"  {name:>4} objects: {len(s):3d}, {np.median(s[:, 1]):.3f}, {s[:, 2].mean():.2f}, "
                         f"{int(s[:, 3].sum())} of {len(s)}")
    return "\n".join(lines)


def _true_heights(paths) -> dict:
    """Per camera id: its frames' true camera heights, each the median bottom of the frame's
    objects (m)."""
    heights: dict = {}
    for path in paths:
        scene = json.loads(path.read_text())
        h = float(np.median([t["ground_truth"]["location_m"][1] for t in scene["targets"]]))
        heights.setdefault((scene.get("camera") or {}).get("id"), []).append(h)
    return heights


def _rig_mountings(paths) -> dict:
    """Per camera id: (median, log-sd) of its frames' true camera heights (:func:`_true_heights`),
    the log-sd robust (1.4826 median absolute deviations: a frame of one object on a slope is far
    off) and at least 0.02 (``--camera rig``)."""
    out = {}
    for cam, h in _true_heights(paths).items():
        v = np.log(h)
        out[cam] = (float(np.exp(np.median(v))), max(0.02, 1.4826 * float(np.median(np.abs(v - np.median(v))))))
    return out


def _mountings_text(paths, mounts: dict) -> str:
    """``--camera rig``'s mounting per camera, with the range and quartiles of its frames' true
    heights."""
    heights = _true_heights(paths)
    lines = ["one mounting per camera (--camera rig): height (log-sd); its frames' true heights: min, quartiles, max"]
    for cam, (h, sd) in sorted(mounts.items(), key=lambda kv: -len(heights[kv[0]])):
        q = np.percentile(heights[cam], [0, 25, 75, 100])
        lines.append(f"  {cam}: {len(heights[cam])} frames, {h:.2f} m ({sd:.3f}); "
                     f"{q[0]:.2f}, {q[1]:.2f}–{q[2]:.2f}, {q[3]:.2f} m")
    return "\n".join(lines)


def _load_frame(path: Path, camera: str, focal_sd: float | None = None, mounts: dict | None = None):
    """A study scene; with ``--camera known`` the mounting a measured rig gives (the image's true
    camera height as a prior of ±2 %, a level pose ±0.5°), with ``--camera rig`` its camera's
    (``mounts``, :func:`_rig_mountings`); with ``focal_sd`` P2's focal length (the scene's ground
    truth) as a log-normal prior of that log-sd."""
    from creference_bayes.io.scene import load_scene
    from creference_bayes.models.camera_terms import FocalPrior, OrientationPrior

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frame = load_scene(path)
    if camera in ("known", "rig"):
        h, sd = float(np.median([t.ground_truth["location_m"][1] for t in frame.targets])), 0.02
        if camera == "rig":
            h, sd = mounts[frame.camera_id]
        frame = replace(frame, orientation_prior=OrientationPrior(
            pitch_sd=float(np.radians(0.5)), roll_sd=float(np.radians(0.5)), height_median_m=h, height_log_sd=sd))
    if focal_sd is not None:
        frame = replace(frame, focal_prior=FocalPrior(float(frame.ground_truth["focal_length_px"]), focal_sd, np.inf,
                                                      source="study"))
    return frame


def _print_rigs(rigs: dict, paths, out: Path) -> None:
    """Each camera's pooled focal length, height and pitch (the median over its frames' leave-one-out
    rigs) against KITTI's P2 and the objects' median bottom (the height's truth, roughly)."""
    print("\nrig by camera (median of the frames' leave-one-out rigs; truth: P2's focal length, the objects' median "
          "bottom y)")
    by_cam: dict = {}
    for path in paths:
        r = rigs.get(path.stem)
        if r is None:
            continue
        scene = json.loads(path.read_text())
        truth_f = scene["ground_truth"].get("focal_length_px")
        truth_h = float(np.median([t["ground_truth"]["location_m"][1] for t in scene["targets"]]))
        by_cam.setdefault(r["camera_id"], []).append((r, truth_f, truth_h))
    for cam, rows in sorted(by_cam.items()):
        f = [r["focal_length_px"]["median"] for r, *_ in rows if "focal_length_px" in r]
        fsd = [r["focal_length_px"]["log_sd"] for r, *_ in rows if "focal_length_px" in r]
        line = f"  {cam}: {len(rows)} frames"
        if f:
            line += f", focal {np.median(f):.1f} px (log-sd {np.median(fsd):.3f}; P2 {rows[0][1]:.1f})"
        h = [r["height_m"]["median"] for r, *_ in rows if "height_m" in r]
        if h:
            hs = [r["height_m"]["spread_log_sd"] for r, *_ in rows if "height_m" in r]
            line += (f", height {np.median(h):.2f} m (spread log-sd {np.median(hs):.3f}; objects' median "
                     f"{np.median([t for *_, t in rows]):.2f} m)")
        p = [r["pitch_deg"]["mean"] for r, *_ in rows if "pitch_deg" in r]
        if p:
            ps = [r["pitch_deg"]["spread_sd"] for r, *_ in rows if "pitch_deg" in r]
            line += f", pitch {np.median(p):+.2f}° (spread {np.median(ps):.2f}°)"
        print(line)


def _alone(frame, name, options, out, depth_score):
    """Each object of ``frame`` as a scene of its own (its own camera), the MAP, as KITTI labels."""
    from creference_bayes.inference.map import optimize
    from creference_bayes.pipeline import build_model
    from creference_bayes.workflows.labels.kitti import kitti_poses

    boxes = []
    for t in frame.targets:
        m = optimize(build_model(replace_targets(frame, [t]), **options)[0])
        boxes.append(kitti_poses(frame, m.camera[None], m.objects[None])[0, 0])
    # each object with its own camera: still one label file per image
    _write_labels(out / "alone", name, frame, boxes, [depth_score(b[2]) for b in boxes])


def _write_labels(folder: Path, name: str, frame, boxes, scores) -> None:
    """One image's KITTI label file (``boxes``: per target x, y, z, rotation_y, l, w, h in P2's
    frame) and its calib under ``folder``."""
    from creference_bayes.io.kitti import kitti_object, write_calib_file, write_label_file

    write_label_file(folder / "label_2" / f"{name}.txt",
                     [kitti_object(t.cls, b[:4], b[4:7], frame.kitti_p2, frame.image_size, float(sc))
                      for t, b, sc in zip(frame.targets, boxes, scores)])
    write_calib_file(folder / "calib" / f"{name}.txt", frame.kitti_p2, frame.kitti_calib)


def _bound(frame, name, bound_options, args, out, rng, depth_score):
    """Boxes drawn from the model's Cramér–Rao covariance around the truth, as KITTI labels
    (``bound_options`` change the bound's model only)."""
    from creference_bayes.bench.crb import cramer_rao
    from creference_bayes.models.contract import CAMERA_NAMES, OBJECT_NAMES
    from creference_bayes.pipeline import build_model
    from creference_bayes.workflows.labels.kitti import kitti_poses

    model, _ = build_model(frame, **bound_options)
    model.handedness = np.array([t.ground_truth["handedness"] for t in frame.targets], float)
    cam_b, objs_b = _truth_state(frame)
    bound = cramer_rao(model, cam_b, objs_b, args.noise_px)
    if not bound.singular:
        delta = rng.multivariate_normal(np.zeros(len(bound.cov)), bound.cov, method="eigh")
        for par, d in zip(bound.names, delta):  # "camera.<name>" or "<object index>.<name>"
            owner, _, key = par.partition(".")
            if owner == "camera":
                cam_b[CAMERA_NAMES.index(key)] += d
            else:
                objs_b[int(owner), OBJECT_NAMES.index(key)] += d
        cam_b = model.complete_camera(cam_b[None])[0]
    boxes = kitti_poses(frame, cam_b[None], objs_b[None])[0]
    _write_labels(out / "bound", name, frame, boxes, [depth_score(b[2]) for b in boxes])


if __name__ == "__main__":
    raise SystemExit(main())
