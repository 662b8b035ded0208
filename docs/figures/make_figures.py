"""Draw the figures of the user documentation (docs/*.md) into this folder.

    python docs/figures/make_figures.py [--out DIR] [--all | --only NAME ...]

Without options it draws the quick figures (handedness, one_path); --all also draws the scene_*.png
figures, which simulate and estimate a 20-object scene first (a minute or so).

handedness.png: the two handednesses of a dimension-line annotation of one box, seen from above
(top row) and in a photo taken by a camera 1.5 m above the floor (bottom row). The corners and the
projection come from the package itself (core/geometry.py), so the figure shows what the code
means by +1 and −1.

one_path.png: the one path every scene takes, from its inputs to what is done with its result
(docs/overview.md): boxes and arrows, the module of each stage.

scene_boxes.png, scene_top_view.png, scene_zooms.png, scene_pairs.png, scene_ranks.png: the figures
`creference plot` draws for a simulated street scene of 20 objects (docs/user_guide.md), made by
running the command line itself:

    creference simulate DIR --n 1 --objects 20 --setting street --seed 2 --tier low --annotations 5
    creference estimate DIR/scene_0000.json --out DIR/result.json --seed 0
    creference plot DIR/result.json --out DIR --dpi 80
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


# ------------------------------------------------------------------------------------------------
# one_path.png: the path of every scene


def _box(ax, x, y, w, h, title, body="", *, face="#ffffff", edge="#555555", title_size=11.0, body_size=9.5,
         ls="-"):
    """A rounded box with lower-left corner (x, y), inches; a bold title line and plain body lines."""
    from matplotlib.patches import FancyBboxPatch

    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0,rounding_size=0.12", fc=face, ec=edge,
                                lw=1.2, ls=ls))
    if body:
        ax.text(x + w / 2, y + h - 0.12, title, ha="center", va="top", fontsize=title_size, weight="bold")
        ax.text(x + w / 2, y + h - 0.45, body, ha="center", va="top", fontsize=body_size, linespacing=1.35)
    else:
        ax.text(x + w / 2, y + h / 2, title, ha="center", va="center", fontsize=title_size, weight="bold")


def _arrow(ax, start, end, *, color="#333333", rad=0.0):
    """An arrow from ``start`` to ``end`` (inches), bent by ``rad``."""
    from matplotlib.patches import FancyArrowPatch

    ax.add_patch(FancyArrowPatch(start, end, arrowstyle="-|>", mutation_scale=16, lw=1.4, color=color,
                                 connectionstyle=f"arc3,rad={rad}", shrinkA=1, shrinkB=1))


def one_path_figure() -> Figure:
    """The one path: inputs → Scene → build_model → MAP → posterior → Result → what uses it."""
    W, H = 11.0, 12.9
    fig = Figure(figsize=(W, H))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, W)
    ax.set_ylim(0, H)
    ax.axis("off")
    inp, core, sub, out = "#dbe8f5", "#fdf3d0", "#ffffff", "#dcefd9"

    # inputs
    top = 11.4
    _box(ax, 0.3, top, 3.3, 1.35, "scene files",
         "creference-scene/2 (written, read)\ncreference-scene/1 (read, forever:\na scene of one target)", face=inp)
    _box(ax, 3.85, top, 3.3, 1.35, "annotation tools",
         "creference import label-studio\ncreference import cvat\n(one scene file per image)", face=inp)
    _box(ax, 7.4, top, 3.3, 1.35, "simulator",
         "creference simulate\ninvented rooms and streets,\nor the real boxes of a KITTI folder", face=inp)

    # the dashed box: what one estimate does
    from matplotlib.patches import FancyBboxPatch

    ax.add_patch(FancyBboxPatch((0.15, 1.9), W - 0.3, 9.15, boxstyle="round,pad=0,rounding_size=0.15",
                                fc="none", ec="#888888", lw=1.2, ls="--"))
    ax.text(W / 2, 0.12, "dashed box: creference estimate, one scene; creference batch runs it for every scene of "
            "a data set, on local processes or a Dask cluster", ha="center", va="bottom", fontsize=9.5,
            style="italic", color="#444444")
    x0, w0 = 0.6, 9.0
    # Scene
    _box(ax, x0, 9.25, w0, 1.15, "Scene   (io/scene.py: load_scene, parse_scene)",
         "one photo: its size, the camera (principal point; focal length or a prior on it), the horizon;\n"
         "targets 1 … m (dimension lines; a known size or a class's size prior); the workers' references",
         face=core)
    for xa in (1.95, 5.5, 9.05):
        _arrow(ax, (xa, top), (min(max(xa, x0 + 0.4), x0 + w0 - 0.4), 9.25 + 1.15))
    # build_model
    yb = 6.75
    _box(ax, x0, yb, w0, 2.1, "build_model   (pipeline.py) → a Model of the contract (models/contract.py)",
         "metrology (the default: every annotation a measurement)   or   paper (the paper's cost)", face=core)
    sg = 0.3
    sw = (w0 - 0.3 - 2 * sg) / 3
    for k, (title, body) in enumerate((("camera: one block of 5", "focal length, pitch, roll,\ncamera height, crowd scale"),
                                       ("one block of 7 per object", "x, z, yaw, length, width,\nheight, ground offset"),
                                       ("pair terms", "a worker's distance\nbetween two targets"))):
        _box(ax, x0 + 0.15 + k * (sw + sg), yb + 0.15, sw, 1.15, title, body, face=sub, title_size=10, body_size=9.5)
    _arrow(ax, (x0 + w0 / 2, 9.25), (x0 + w0 / 2, yb + 2.1))
    # MAP
    ym = 5.35
    _box(ax, x0, ym, w0, 1.05, "MAP   (inference/map.py: optimize)",
         "closed-form starts, then joint Newton steps on the arrowhead Hessian (camera block, object blocks);\n"
         "presets paper and paper-controlled: the paper's basin hopping with random restarts", face=core,
         body_size=9.2)
    _arrow(ax, (x0 + w0 / 2, yb), (x0 + w0 / 2, ym + 1.05))
    # posterior
    yp = 3.2
    _box(ax, x0, yp, w0, 1.65, "posterior   (inference/sampler.py: sample, with emcee)",
         "moves chosen by the model's block structure, never by the kind of scene", face=core)
    hw = (w0 - 0.45) / 2
    _box(ax, x0 + 0.15, yp + 0.12, hw, 0.9, "one object",
         "ensemble moves on the whole vector:\n4 independent ensembles × 24 walkers", face=sub, title_size=10,
         body_size=9.2)
    _box(ax, x0 + 0.3 + hw, yp + 0.12, hw, 0.9, "several objects",
         "block sweeps (camera, then every object):\nrandom walk and multiple-try independence, 8 chains",
         face=sub, title_size=10, body_size=9.2)
    _arrow(ax, (x0 + w0 / 2, ym), (x0 + w0 / 2, yp + 1.65))
    # Result
    yr = 2.15
    _box(ax, x0, yr, w0, 0.5, "Result   (io/result.py)  →  creference-result/2 JSON (--out),  NetCDF via arviz (--netcdf)",
         face=core, title_size=10.5)
    _arrow(ax, (x0 + w0 / 2, yp), (x0 + w0 / 2, yr + 0.5))
    # the MAP only
    _arrow(ax, (x0 + w0, ym + 0.5), (x0 + w0, yr + 0.25), rad=-0.35)
    ax.text(x0 + w0 + 0.78, (ym + yr) / 2 + 0.55, "--no-posterior:\nthe MAP only", ha="center", va="center",
            fontsize=8.5, rotation=90, color="#333333")
    # what uses a result
    yo, ow, og = 0.5, 2.4, 0.27
    outs = (("creference plot", "boxes, top view, zooms,\npairs, ranks"),
            ("creference advise", "which annotation next,\nor stop"),
            ("creference labels", "KITTI labels with\ntheir uncertainty"),
            ("creference evaluate kitti", "AP3D, AP BEV, and the\nlabels' reliability"))
    xs = [0.35 + k * (ow + og) for k in range(4)]
    for x, (title, body) in zip(xs, outs):
        _box(ax, x, yo, ow, 1.15, title, body, face=out, title_size=10, body_size=9.2)
    for x in xs[:3]:
        _arrow(ax, (min(max(x + ow / 2, x0 + 0.4), x0 + w0 - 0.4), yr), (x + ow / 2, yo + 1.15))
    _arrow(ax, (xs[2] + ow, yo + 0.575), (xs[3], yo + 0.575))
    return fig


def scene_figures(out: Path) -> list[Path]:
    """The figures of ``creference plot`` for a simulated 20-object street scene (module docstring),
    copied to ``out`` as scene_*.png."""
    import shutil
    import tempfile

    from creference_bayes.cli.main import main as creference

    written = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for argv in (["simulate", str(work), "--n", "1", "--objects", "20", "--setting", "street", "--seed", "2",
                      "--tier", "low", "--annotations", "5", "--quiet"],
                     ["estimate", str(work / "scene_0000.json"), "--out", str(work / "result.json"), "--seed", "0",
                      "--quiet"],
                     ["plot", str(work / "result.json"), "--out", str(work), "--dpi", "80", "--quiet"]):
            status = creference(argv)
            if status != 0:
                raise SystemExit(f"creference {' '.join(argv)}: exit status {status}")
        for png in sorted(work.glob("*.png")):
            target = out / f"scene_{png.name}"
            shutil.copyfile(png, target)
            written.append(target)
    return written


FIGURES = ("handedness", "one_path", "scene")
#: What the script draws without options (the figures that take a second).
QUICK = ("handedness", "one_path")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(HERE), metavar="DIR",
                        help="folder for the PNG files (default: this script's folder)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--all", action="store_true",
                       help="every figure, also the scene_*.png ones (they simulate and estimate a 20-object scene "
                            "first: a minute or so)")
    which.add_argument("--only", nargs="+", choices=FIGURES, default=list(QUICK), metavar="NAME",
                       help=f"draw only these, of {', '.join(FIGURES)} (default: {' '.join(QUICK)})")
    args = parser.parse_args(argv)
    if args.all:
        args.only = list(FIGURES)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, make in (("handedness", handedness_figure), ("one_path", one_path_figure)):
        if name in args.only:
            make().savefig(out / f"{name}.png", dpi=100)
            print(f"wrote {out / f'{name}.png'}")
    if "scene" in args.only:
        for path in scene_figures(out):
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
