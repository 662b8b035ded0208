"""Draw the figures of the user documentation (docs/*.md) into this folder.

    python docs/figures/make_figures.py [--out DIR]

handedness.png: the two handednesses of a dimension-line annotation of one box, seen from above
(top row) and in a photo taken by a camera 1.5 m above the floor (bottom row). The corners and the
projection come from the package itself (core/geometry.py), so the figure shows what the code
means by +1 and −1.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from creference_bayes.core.geometry import (box_points, box_vertices, dimension_corners,  # noqa: E402
                                            project, rotation_from_pitch_roll, yaw_matrix)

HERE = Path(__file__).resolve().parent
#: The box (length, width, height, metres) and its pose (x, y, z metres, yaw radians).
BOX = (1.6, 0.8, 0.9)
POSE = np.array([0.3, 1.5, 4.0, 0.45])
#: Camera: focal length and principal point (pixels), pitch (radians, looking down), image size.
FOCAL, PRINCIPAL, PITCH, SIZE = 900.0, np.array([600.0, 400.0]), np.radians(12.0), (1200, 800)
COLORS = {1: "#1f77b4", -1: "#d62728"}
NAMES = ("t1", "t2 (length)", "t3 (width)", "t4 (height)")


def _lines(ax, pts, color):
    """The three dimension lines from t1: solid length, dashed width, dotted height."""
    for k, style in ((1, "-"), (2, "--"), (3, ":")):
        ax.plot(*pts[[0, k]].T, style, color=color, lw=2.4)
    ax.plot(*pts[0], "o", color=color, ms=6)


def annotation(handedness: int) -> np.ndarray:
    """Object-frame corners t1..t4 (4, 3) of an annotation of :data:`BOX` of this handedness,
    started at a near bottom corner (the −1 one is the package's −1 corners turned by 180°,
    which changes where the lines start, not their handedness)."""
    c = dimension_corners(*BOX, handedness)
    return c if handedness == 1 else c @ yaw_matrix(np.pi).T


def handedness_figure() -> Figure:
    fig = Figure(figsize=(8.4, 6.2), layout="constrained")
    axes = fig.subplots(2, 2, height_ratios=[1, 1.15])
    L, W, H = BOX
    verts = box_vertices(L, W, H)
    R = rotation_from_pitch_roll(PITCH, 0.0)
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    box_uv, _ = project(box_points(POSE, verts), R, FOCAL, PRINCIPAL)
    horizon_v = PRINCIPAL[1] - FOCAL * np.tan(PITCH)
    for col, h in enumerate((1, -1)):
        color, c = COLORS[h], annotation(h)
        side = "left" if h == 1 else "right"
        # top row: the footprint seen from above in the object's frame (x: length, z: width)
        top = axes[0, col]
        foot = verts[[0, 1, 2, 3, 0]]
        top.fill(foot[:, 0], foot[:, 2], color="#eeeeee", ec="#888888")
        _lines(top, c[:, [0, 2]], color)
        for k, (dx, dy) in zip(range(3), ((-6, -14), (-6, -14), (-6, 6))):
            top.annotate(NAMES[k], c[k, [0, 2]], xytext=(dx, dy), textcoords="offset points",
                         fontsize=8, color=color, ha="center")
        top.text(0, 0, "t4: straight up from t1", ha="center", va="center", fontsize=8, color="#666666")
        top.set_aspect("equal")
        top.set_xlim(-1.2, 1.2)
        top.set_ylim(-0.75, 0.75)
        top.set_xticks([])
        top.set_yticks([])
        top.set_title(f"handedness {h:+d}: seen from above, the width line\nturns {side} of the length "
                      f"line ({'counter-clockwise' if h == 1 else 'clockwise'})", fontsize=9, color=color)
        # bottom row: the same annotation in a photo taken 1.5 m above the floor
        photo = axes[1, col]
        for a, b in edges:
            photo.plot(*box_uv[[a, b]].T, color="#aaaaaa", lw=1)
        uv, _ = project(box_points(POSE, c), R, FOCAL, PRINCIPAL)
        _lines(photo, uv, color)
        for k, name in enumerate(NAMES):
            photo.annotate(name, uv[k], xytext=(4, 4), textcoords="offset points", fontsize=7, color=color)
        photo.axhline(horizon_v, color="#777777", ls="--", lw=0.8)
        photo.text(270, horizon_v - 10, "horizon", fontsize=7, color="#555555")
        photo.set_xlim(260, 940)
        photo.set_ylim(640, horizon_v - 40)
        photo.set_aspect("equal")
        photo.set_xlabel("u (px)")
        photo.set_ylabel("v (px)")
        photo.set_title("in the photo (solid: length, dashed: width,\ndotted: height)", fontsize=9)
    return fig


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(HERE), metavar="DIR",
                        help="folder for the PNG files (default: this script's folder)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    handedness_figure().savefig(out / "handedness.png", dpi=100)
    print(f"wrote {out / 'handedness.png'}")


if __name__ == "__main__":
    main()
