"""A whole data set from annotation-tool exports to KITTI labels, with the package's commands.

Simulates N scenes (mixed noise tiers, with ground truth), writes them as a Label Studio JSON
export (as if the crowd had annotated them there) and as a CVAT for images 1.1 file, and then runs
the three commands a labelling team would run:

    creference import label-studio export.json --out scenes/        (and: import cvat …)
    creference batch scenes/ --out batch/ --workers W
    creference labels batch/ --out labels/

It prints each command with its exit status and time, checks that the Label Studio and CVAT imports
give the same scenes, and that every exported KITTI box, projected with its calib file's P2 the way
KITTI's tooling does it (P2 · [X; 1]), lands on the scene's annotated corners.

    python examples/dataset_pipeline.py --n 40 --out dataset_run [--workers 2] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _run(cmd: list[str]) -> tuple[int, float]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "creference_bayes", *cmd], capture_output=True, text=True)
    secs = time.perf_counter() - t0
    print(f"$ creference {' '.join(cmd)}\n  exit {proc.returncode}, {secs:.1f} s")
    tail = (proc.stdout.strip().splitlines() or [""])[-1]
    if tail:
        print(f"  {tail}")
    if proc.returncode not in (0,):
        print(proc.stderr[-2000:])
    return proc.returncode, secs


def _kitti_corners(line: str, P2: np.ndarray) -> np.ndarray:
    """The 8 image corners of a KITTI label line, as KITTI's devkit computes them."""
    v = line.split()
    h, w, l, x, y, z, ry = map(float, v[8:15])
    xs = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    ys = [0, 0, 0, 0, -h, -h, -h, -h]
    zs = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    R = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    X = R @ np.array([xs, ys, zs]) + np.array([[x], [y], [z]])
    uvw = P2 @ np.vstack([X, np.ones(8)])
    return (uvw[:2] / uvw[2]).T


def _targets(folder: Path) -> dict:
    """Every target of the scene files of ``folder`` by (its scene file's name without extension, its id)."""
    from creference_bayes.io.scene import load_scene

    return {(p.stem, t.id): t for p in sorted(folder.glob("*.json")) for t in load_scene(p).targets}


def _reprojection(labels: Path, scenes: Path) -> list[float]:
    """Per label, the mean distance (px) from each annotated corner t1..t4 (median over
    annotations) to the nearest projected box corner: how well the label sits on the photo."""
    import csv

    targets = _targets(scenes)
    out = []
    with open(labels / "labels.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        calib = {k.strip(): np.array(v.split(), float) for k, v in
                 (ln.split(":", 1) for ln in (labels / "calib" / f"{row['image']}.txt").read_text().splitlines()
                  if ":" in ln)}
        P2 = calib["P2"].reshape(3, 4)
        line = (labels / "label_2" / f"{row['image']}.txt").read_text().splitlines()[int(row["line"]) - 1]
        corners = targets[row["scene"], row["target"]].median_corners
        d = np.linalg.norm(corners[:, None] - _kitti_corners(line, P2)[None], axis=2)  # (4 annotated, 8 box)
        out.append(float(np.mean(d.min(axis=1))))
    return out


def _same_scenes(a: Path, b: Path) -> tuple[int, float]:
    """Targets found in both imports, and the largest corner difference between them (px)."""
    ta, tb = _targets(a), _targets(b)
    common = sorted(set(ta) & set(tb))
    diff = max((float(np.max(np.abs(ta[t].corners - tb[t].corners))) for t in common), default=float("nan"))
    return len(common), diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--n", type=int, default=40, help="scenes to simulate (default %(default)s)")
    ap.add_argument("--out", default="dataset_run", help="work folder (default %(default)s; must not exist)")
    ap.add_argument("--workers", type=int, default=2, help="local batch workers (default %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="simulation and batch seed (default %(default)s)")
    ap.add_argument("--min-ess", type=float, default=None,
                    help="the batch's bulk ESS (default: the package's, 400; less for a quick check)")
    args = ap.parse_args(argv)

    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.io.cvat import cvat_xml
    from creference_bayes.io.labelstudio_export import label_studio_tasks

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=False)
    tiers = ("none", "low", "medium", "high")
    scenes = []
    for i in range(args.n):
        d = simulate_scene(np.random.default_rng([args.seed, i]), tier=tiers[i % 4], format_offset=5 * i)
        d["image"]["path"] = f"photo_{i:03d}.png"  # the annotated photo's name (not needed to estimate)
        scenes.append(d)
    (out / "label_studio_export.json").write_text(json.dumps(label_studio_tasks(scenes)))
    (out / "cvat_annotations.xml").write_text(cvat_xml(scenes))
    print(f"{args.n} simulated scenes written as a Label Studio export and a CVAT file in {out}\n")

    status = []
    status.append(_run(["import", "label-studio", str(out / "label_studio_export.json"), "--out", str(out / "scenes")]))
    status.append(_run(["import", "cvat", str(out / "cvat_annotations.xml"), "--out", str(out / "scenes_cvat")]))
    n, diff = _same_scenes(out / "scenes", out / "scenes_cvat")
    print(f"  the same {n} targets from both tools; largest corner difference {diff:.3f} px")
    status.append(_run(["batch", str(out / "scenes"), "--out", str(out / "batch"), "--workers",
                        str(args.workers), "--seed", str(args.seed), "--quiet",
                        *(["--min-ess", f"{args.min_ess:g}"] if args.min_ess else [])]))
    status.append(_run(["labels", str(out / "batch"), "--out", str(out / "labels")]))
    errors = _reprojection(out / "labels", out / "scenes")
    print(f"\nreprojection of the exported KITTI boxes with their calib P2, against the annotated corners: "
          f"{len(errors)} labels, median {np.median(errors):.2f} px, max {np.max(errors):.2f} px")
    return 0 if all(code == 0 for code, _ in status) else 1


if __name__ == "__main__":
    sys.exit(main())
