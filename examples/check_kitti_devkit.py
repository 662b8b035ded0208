"""Check ``creference evaluate kitti`` against KITTI's official C++ evaluator, not only against our
reading of it.

The devkit's ``evaluate_object_3d_offline.cpp`` (many public repositories carry it, e.g.
prclibo/kitti_eval) compiles with g++ and Boost (Debian: ``apt-get install g++ libboost-dev``)::

    g++ -O2 -w -o evaluate_object_3d_offline evaluate_object_3d_offline.cpp

Build it against Boost 1.81's headers (``apt-get download libboost1.81-dev``, ``dpkg -x`` it, then
``-I .../usr/include``): with Debian's default Boost 1.74 the devkit scores some nearly coincident
boxes as not overlapping (docs/evaluation.md). It judges Car at IoU 0.7; for Car at 0.5 build a second binary with the minimum overlaps set to
0.5 (``sed 's/{0.7, 0.5, 0.5}/{0.5, 0.5, 0.5}/g'`` on the ``MIN_OVERLAP`` line) and pass it as
``--devkit-car05``. Keep both outside the project: the devkit's source is not ours to commit.

From a ground-truth folder (``--kitti DIR``: a KITTI ``label_2`` folder or one holding it; or
``--synthetic N``: N images of random boxes written here) the script writes prediction folders:

- ``truth``: the ground truth itself (DontCare dropped), score 1;
- ``noisy``: every box moved (location, yaw, size, 2D box) with a random score;
- ``dropped_fp``: a third of the boxes dropped, false positives added (some near a true box, some
  small, some of another class), random scores;
- ``mixed``: noisy boxes, duplicates, relabelled classes, false positives, scores tied in steps.

Both evaluators run on the same files (names ``%06d.txt``, as the devkit wants); AP R40 and R11
of the devkit come from the 41-point precision curves it writes (``plot/*_detection_{3d,ground}.txt``),
R11 also checked against the figure it prints. Prints the comparison and the largest difference
per class, overlap, metric and difficulty; exit status 1 if any exceeds ``--tolerance`` (0.1 AP).

    python examples/check_kitti_devkit.py --devkit /work/devkit/evaluate_object_3d_offline \\
        --devkit-car05 /work/devkit/evaluate_object_3d_offline_car05 --kitti ../shared/kitti_dev
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CASES = ("truth", "noisy", "dropped_fp", "mixed")
DIFFS = ("easy", "moderate", "hard")
SIZES = {"Car": (1.5, 1.6, 3.9), "Van": (2.2, 1.9, 5.0), "Truck": (3.2, 2.5, 10.0),
         "Pedestrian": (1.75, 0.65, 0.85), "Person_sitting": (1.25, 0.6, 0.8),
         "Cyclist": (1.75, 0.6, 1.75), "Misc": (1.8, 1.4, 3.0)}


def _fmt(type_, trunc, occ, alpha, bbox, hwl, xyz, ry, score=None) -> str:
    vals = [f"{trunc:.2f}", f"{int(occ)}", f"{alpha:.2f}", *(f"{v:.2f}" for v in bbox),
            *(f"{v:.2f}" for v in hwl), *(f"{v:.2f}" for v in xyz), f"{ry:.2f}"]
    if score is not None:
        vals.append(f"{score:.4f}")
    return " ".join([type_, *vals])


def synthetic_ground_truth(out: Path, n_images: int, rng: np.random.Generator) -> Path:
    """N label files of random objects of every kind the rules look at (classes, neighbouring
    classes, truncation, occlusion, small boxes, DontCare regions)."""
    out.mkdir(parents=True, exist_ok=True)
    kinds = list(SIZES)
    p = np.array([0.45, 0.08, 0.04, 0.2, 0.05, 0.15, 0.03])
    for i in range(n_images):
        lines = []
        for _ in range(rng.integers(0, 14)):
            t = str(rng.choice(kinds, p=p))
            h, w, l = np.array(SIZES[t]) * rng.uniform(0.9, 1.1, 3)
            x, z = rng.uniform(-15, 15), rng.uniform(4, 60)
            y = rng.uniform(1.4, 1.9)
            ry = rng.uniform(-np.pi, np.pi)
            hp = 720 * h / z * rng.uniform(0.9, 1.1)  # about the 2D height at KITTI's focal length
            u = 620 + 720 * x / z
            bbox = (u - hp * l / h / 2, 180 - hp / 2, u + hp * l / h / 2, 180 + hp / 2)
            trunc = float(rng.choice([0.0, 0.0, 0.1, 0.2, 0.4, 0.6]))
            lines.append(_fmt(t, trunc, rng.integers(0, 4), ry - np.arctan2(x, z), bbox, (h, w, l), (x, y, z), ry))
            if rng.random() < 0.15:
                # a 2D box alone: the devkit's DontCare region
                u0, v0 = rng.uniform(0, 1100), rng.uniform(120, 220)
                lines.append(_fmt("DontCare", -1, -1, -10, (u0, v0, u0 + rng.uniform(10, 80), v0 + rng.uniform(8, 40)),
                                  (-1, -1, -1), (-1000, -1000, -1000), -10))
        (out / f"{i:06d}.txt").write_text("".join(s + "\n" for s in lines))
    return out


def _read(path: Path) -> list[list[str]]:
    return [ln.split() for ln in path.read_text().splitlines() if ln.split()]


def _box(f: list[str]):
    v = [float(x) for x in f[1:15]]
    return f[0], v[0], int(v[1]), v[2], v[3:7], v[7:10], v[10:13], v[13]


def _jitter(f, rng, scale):
    t, trunc, occ, alpha, bbox, hwl, xyz, ry = _box(f)
    scale = scale * rng.exponential(1.0)  # some boxes close, some far off: IoUs on both sides of 0.7
    xyz = np.array(xyz) + rng.normal(0, [0.1 * scale, 0.05 * scale, 0.3 * scale])
    hwl = np.array(hwl) * np.exp(rng.normal(0, 0.03 * scale, 3))
    ry = ry + rng.normal(0, 0.05 * scale)
    bbox = np.array(bbox) + rng.normal(0, 2.0 * scale, 4)
    return t, trunc, occ, alpha, bbox, hwl, xyz, ry


def _false_positive(rng, near=None):
    t = str(rng.choice(["Car", "Car", "Pedestrian", "Cyclist"]))
    h, w, l = SIZES[t]
    if near is not None:
        _, _, _, _, _, _, xyz, _ = _box(near)
        x, y, z = np.array(xyz) + rng.normal(0, [1.0, 0.1, 2.0])
    else:
        x, y, z = rng.uniform(-15, 15), rng.uniform(1.4, 1.9), rng.uniform(4, 60)
    hp = rng.choice([720 * h / z, rng.uniform(10, 30)])  # some below the minimum heights
    u = 620 + 720 * x / z
    return t, 0.0, 0, 0.0, (u - hp / 2, 180 - hp / 2, u + hp / 2, 180 + hp / 2), (h, w, l), (x, y, z), rng.uniform(-np.pi, np.pi)


def make_predictions(gt_dir: Path, out: Path, case: str, rng: np.random.Generator) -> Path:
    """One prediction folder (16 values a line) for every ground-truth file of ``gt_dir``."""
    out.mkdir(parents=True, exist_ok=True)
    for path in sorted(gt_dir.glob("*.txt")):
        objs = [f for f in _read(path) if f[0] != "DontCare"]
        lines = []
        for f in objs:
            if case == "truth":
                lines.append(_fmt(*_box(f), score=1.0))
                continue
            if case in ("dropped_fp", "mixed") and rng.random() < 1 / 3:
                continue
            box = _jitter(f, rng, 1.0 if case != "dropped_fp" else 0.5)
            score = rng.random()
            if case == "mixed":
                score = np.round(score * 8) / 8  # ties
                if rng.random() < 0.1:
                    box = (str(rng.choice(["Car", "Van", "Pedestrian", "Cyclist"])), *box[1:])
                if rng.random() < 0.2:  # a duplicate
                    lines.append(_fmt(*_jitter(f, rng, 0.5), score=float(rng.random())))
            lines.append(_fmt(*box, score=float(score)))
        if case in ("dropped_fp", "mixed"):
            for _ in range(rng.poisson(2)):
                near = objs[rng.integers(len(objs))] if objs and rng.random() < 0.5 else None
                lines.append(_fmt(*_false_positive(rng, near), score=float(rng.random())))
        rng.shuffle(lines)
        (out / path.name).write_text("".join(s + "\n" for s in lines))
    return out


def run_devkit(binary: Path, gt_dir: Path, pred_dir: Path, work: Path) -> dict:
    """(class, metric, difficulty) → (R40, R11) from the devkit's precision curves."""
    res = work / "result"
    shutil.rmtree(res, ignore_errors=True)
    shutil.copytree(pred_dir, res / "data")
    proc = subprocess.run([str(binary), str(gt_dir), str(res)], capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 or "An error occured" in proc.stdout:
        raise RuntimeError(f"the devkit failed on {pred_dir}: {proc.stdout[-500:]} {proc.stderr[-500:]}")
    printed = {}
    for ln in proc.stdout.splitlines():  # "car_detection_3d AP: e m h" (R11)
        if " AP: " in ln:
            name, vals = ln.split(" AP: ")
            printed[name.strip()] = [float(v) for v in vals.split()]
    out = {}
    for cls in ("car", "pedestrian", "cyclist"):
        for metric, suffix in (("3d", "3d"), ("bev", "ground")):
            curve = res / "plot" / f"{cls}_detection_{suffix}.txt"
            if not curve.is_file():
                continue
            prec = np.loadtxt(curve)[:, 1:4]  # (41, 3) easy, moderate, hard
            r40 = prec[1:].sum(axis=0) / 40 * 100
            r11 = prec[::4].sum(axis=0) / 11 * 100
            np.testing.assert_allclose(r11, printed[f"{cls}_detection_{suffix}"], atol=1e-3)
            for k, d in enumerate(DIFFS):
                out[(cls.capitalize(), metric, d)] = (float(r40[k]), float(r11[k]))
    return out


def compare(gt_dir: Path, work: Path, devkit: Path, devkit_car05: Path | None, seed: int) -> list[dict]:
    from creference_bayes.evaluation.kitti_eval import evaluate_kitti

    rows = []
    rng = np.random.default_rng(seed)
    for case in CASES:
        pred = make_predictions(gt_dir, work / "predictions" / case, case, rng)
        ours = {(r["class"], r["min_overlap"], r["metric"], r["difficulty"]): (r["ap_r40"], r["ap_r11"])
                for r in evaluate_kitti(gt_dir, pred).ap}
        theirs = {(c, 0.5 if c != "Car" else 0.7, m, d): v
                  for (c, m, d), v in run_devkit(devkit, gt_dir, pred, work).items()}
        if devkit_car05 is not None:
            theirs.update({(c, 0.5, m, d): v for (c, m, d), v in run_devkit(devkit_car05, gt_dir, pred, work).items()
                           if c == "Car"})
        for key in sorted(set(ours) | set(theirs), key=str):
            if key not in theirs or key not in ours:
                if key[:2] == ("Car", 0.5) and devkit_car05 is None:
                    continue
                raise RuntimeError(f"{case}: {key} evaluated by only one of the two")
            (a40, a11), (b40, b11) = ours[key], theirs[key]
            rows.append({"case": case, "class": key[0], "min_overlap": key[1], "metric": key[2],
                         "difficulty": key[3], "ours_r40": a40, "devkit_r40": b40, "ours_r11": a11,
                         "devkit_r11": b11, "diff_r40": abs(a40 - b40), "diff_r11": abs(a11 - b11)})
    return rows


def summary(rows: list[dict]) -> list[dict]:
    """The largest |ΔAP| over the cases per class, overlap, metric and difficulty."""
    out: dict = {}
    for r in rows:
        k = (r["class"], r["min_overlap"], r["metric"], r["difficulty"])
        s = out.setdefault(k, {"class": k[0], "min_overlap": k[1], "metric": k[2], "difficulty": k[3],
                               "max_diff_r40": 0.0, "max_diff_r11": 0.0, "ap_r40_range": [1e9, -1e9]})
        s["max_diff_r40"] = max(s["max_diff_r40"], r["diff_r40"])
        s["max_diff_r11"] = max(s["max_diff_r11"], r["diff_r11"])
        s["ap_r40_range"] = [min(s["ap_r40_range"][0], r["devkit_r40"]), max(s["ap_r40_range"][1], r["devkit_r40"])]
    return list(out.values())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devkit", required=True, type=Path, help="the compiled evaluate_object_3d_offline")
    ap.add_argument("--devkit-car05", type=Path, default=None,
                    help="the same built with Car's minimum overlap at 0.5 (Car at 0.5 is skipped without it)")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--kitti", type=Path, help="a KITTI label_2 folder (or a folder holding one) as ground truth")
    src.add_argument("--synthetic", type=int, metavar="N", help="N images of random ground truth instead")
    ap.add_argument("--workdir", type=Path, default=None, help="where the folders go (default: a temporary one)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tolerance", type=float, default=0.1, help="largest |ΔAP| allowed (default: %(default)s)")
    args = ap.parse_args(argv)
    for b in (args.devkit, args.devkit_car05):
        if b is not None and not b.is_file():
            print(f"error: {b}: no such file (the compiled devkit)", file=sys.stderr)
            return 2
    with tempfile.TemporaryDirectory() as tmp:
        work = args.workdir or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if args.synthetic is not None:
            gt = synthetic_ground_truth(work / "ground_truth", args.synthetic, np.random.default_rng(args.seed + 1))
        else:
            gt = args.kitti / "label_2" if (args.kitti / "label_2").is_dir() else args.kitti
            if not gt.is_dir():
                print(f"error: --kitti: {args.kitti}: no such folder", file=sys.stderr)
                return 2
        rows = compare(gt, work, args.devkit, args.devkit_car05, args.seed)
        table = summary(rows)
        print(f"{'case':<11} {'class':<11} {'IoU':>4} {'metric':<6} {'diff':<9} {'ours R40':>9} {'devkit':>9} "
              f"{'ours R11':>9} {'devkit':>9}")
        for r in rows:
            print(f"{r['case']:<11} {r['class']:<11} {r['min_overlap']:>4} {r['metric']:<6} {r['difficulty']:<9} "
                  f"{r['ours_r40']:9.3f} {r['devkit_r40']:9.3f} {r['ours_r11']:9.3f} {r['devkit_r11']:9.3f}")
        print("\nlargest |ΔAP| over the cases (devkit AP R40 range in brackets)")
        print(f"{'class':<11} {'IoU':>4} {'metric':<6} {'diff':<9} {'R40':>7} {'R11':>7}  devkit R40")
        for s in table:
            lo, hi = s["ap_r40_range"]
            print(f"{s['class']:<11} {s['min_overlap']:>4} {s['metric']:<6} {s['difficulty']:<9} "
                  f"{s['max_diff_r40']:7.4f} {s['max_diff_r11']:7.4f}  [{lo:.1f}, {hi:.1f}]")
        worst = max(max(s["max_diff_r40"], s["max_diff_r11"]) for s in table)
        if args.workdir:
            (work / "comparison.json").write_text(json.dumps({"rows": rows, "summary": table}, indent=1) + "\n")
        print(f"\nlargest difference {worst:.4f} AP (tolerance {args.tolerance}): "
              f"{'agree' if worst <= args.tolerance else 'DISAGREE'}")
        return 0 if worst <= args.tolerance else 1


if __name__ == "__main__":
    sys.exit(main())
