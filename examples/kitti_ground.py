"""A copy of a KITTI folder whose boxes stand on a simpler ground than the real road: what the
road's unevenness costs a frame estimated alone (docs/studies/kitti.md, "Where a frame alone goes wrong").

    python examples/kitti_ground.py KITTI_DIR OUT --ground level|plane

Only each labelled object's height is changed (the y of its bottom centre in the rectified camera
frame, metres, y down); everything else of a label line is KITTI's, so the scene maker's filters
(2D height, truncation, occlusion) keep the same objects:

- ``level``: every object's bottom at its frame's median bottom, one level plane (the rectified
  camera's horizontal) for the frame;
- ``plane``: every object's bottom on the plane fitted to its frame's bottoms by least squares
  (y = a·x + b·z + c), which keeps the frame's tilt and takes away each object's own offset from
  it; a frame of fewer than three objects keeps its heights.

``DontCare`` lines are kept as they are. ``OUT/calib`` and ``OUT/image_2`` are links to the
folder's own (nothing of KITTI's is copied); ``OUT/label_2`` holds the new label files. Then run
``examples/kitti_study.py OUT ...`` as on the folder itself: the study's truth is the moved boxes.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import numpy as np

GROUNDS = ("level", "plane")


def moved_heights(xyz: np.ndarray, ground: str) -> np.ndarray:
    """(n,) the new bottom heights y of a frame's n objects at ``xyz`` (n, 3), metres."""
    if ground == "level":
        return np.full(len(xyz), float(np.median(xyz[:, 1])))
    if len(xyz) < 3:
        return xyz[:, 1].copy()
    design = np.c_[xyz[:, 0], xyz[:, 2], np.ones(len(xyz))]
    coef, *_ = np.linalg.lstsq(design, xyz[:, 1], rcond=None)
    return design @ coef


def moved_label_text(text: str, ground: str) -> str:
    """A label file's text with its objects' heights moved (module docstring)."""
    rows = [line.split() for line in text.splitlines() if line.strip()]
    objects = [i for i, r in enumerate(rows) if r[0] != "DontCare"]
    if objects:
        xyz = np.array([[float(rows[i][k]) for k in (11, 12, 13)] for i in objects])
        for i, y in zip(objects, moved_heights(xyz, ground)):
            rows[i][12] = f"{y:.2f}"
    return "".join(" ".join(r) + "\n" for r in rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("kitti", type=Path, help="a KITTI folder (label_2/, calib/, image_2/)")
    p.add_argument("out", type=Path, help="the new folder (must not hold a label_2/ yet)")
    p.add_argument("--ground", choices=GROUNDS, required=True, help="level or plane (module docstring)")
    args = p.parse_args(argv)
    labels = sorted((args.kitti / "label_2").glob("*.txt"))
    if not labels or not (args.kitti / "calib").is_dir():
        p.error(f"{args.kitti}: not a KITTI folder (no label_2/*.txt or no calib/)")
    if (args.out / "label_2").exists():
        p.error(f"{args.out / 'label_2'} exists: choose another OUT")
    tmp = args.out / "label_2.partial"
    shutil.rmtree(tmp, ignore_errors=True)  # what an interrupted run left
    tmp.mkdir(parents=True)
    for path in labels:
        (tmp / path.name).write_text(moved_label_text(path.read_text(), args.ground))
    for sub in ("calib", "image_2"):
        if (args.kitti / sub).is_dir() and not (args.out / sub).exists():
            (args.out / sub).symlink_to((args.kitti / sub).resolve(), target_is_directory=True)
    tmp.rename(args.out / "label_2")
    print(f"wrote {len(labels)} label files to {args.out / 'label_2'} (ground {args.ground})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
