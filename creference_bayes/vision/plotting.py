"""Figures of an estimate of any scene (matplotlib): every object's box on the photo, the ground
seen from above with a zoom on each small object, pair plots of the posterior (the camera and the
chosen objects), rank plots of its chains, and the rank histograms of simulation-based calibration.

Every figure takes the scene (:class:`~creference_bayes.io.scene.Scene`), the MAP as model arrays
(camera (5,), objects (m, 7), :mod:`~creference_bayes.models.contract` order) and draws as model
arrays (cameras (n, 5), objects (n, m, 7)) or None; it draws on the ``ax``/``fig`` it is given or
on a new :class:`matplotlib.figure.Figure` (no pyplot state) and returns the figure.
:func:`scene_figures` makes every figure of a result at once (``creference plot``).

Each object has its own colour and line style (:func:`object_styles`) and a label (``id (class)``,
or the id alone with a key below the figure beyond :data:`FULL_LABELS_UP_TO` objects) placed near
it where it overlaps no other label, with a leader line when it had to move away.
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Polygon, Rectangle

from ..models.boxes import footprint as _footprint
from ..models.boxes import image_boxes
from ..models.contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, CAMERA_NAMES, O_YAW, OBJECT_NAMES

__all__ = ["scene_figures", "plot_boxes", "plot_top_view", "plot_zooms", "plot_pairs", "plot_ranks",
           "plot_sbc_ranks", "posterior_columns", "kept_chains", "zoom_indices", "object_labels", "object_styles",
           "short_labels", "Column", "OBJECT_COLORS", "OBJECT_LINESTYLES", "FULL_LABELS_UP_TO", "MAX_ZOOM_PANELS",
           "DRAWS_LABELS"]

_BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
#: The MAP (pair plots) and the posterior draws (histograms, clouds).
_MAP_COLOR, _POST_COLOR = "#d62728", "#1f77b4"
#: The truth is drawn in black (dashed footprints, stars), a colour no object has.
_TRUTH_COLOR = "k"
#: The MAP bottom centre in the zoom panels (black: an object may be red).
_CENTRE_COLOR = "k"
#: What the draws are, by where they came from (:func:`~creference_bayes.pipeline.result_draws`).
DRAWS_LABELS = {"posterior": "posterior draws", "laplace": "draws of the Laplace approximation"}

#: One strong colour per object: relative luminance at most 0.3 (3:1 contrast on white), any two
#: at least 24 apart (CIE76 ΔE); no grey or black (the legends' and the truth's).
OBJECT_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#d95f02", "#8c564b", "#c51b7d", "#00838f",
                 "#6b6b00", "#3f3f9f", "#b8860b")
#: The line style of an object's boxes and footprint: solid for the first round through the colours,
#: then dashed, dotted, …, so that colour and line style together tell 66 objects apart.
OBJECT_LINESTYLES = ("-", (0, (5, 2)), (0, (1, 1.2)), (0, (6, 2, 1, 2)), (0, (2.5, 2.5)), (0, (8, 2, 1, 2, 1, 2)))
#: Up to this many objects, each label reads ``id (class)``; beyond, the id alone (or its number when
#: an id is long) and a key below the figure gives each object's class.
FULL_LABELS_UP_TO = 12
#: The photo behind the figures is reduced to at most this many pixels a side (the figures are
#: at most 16 in wide; a full-size 50 MP photo would cost gigabytes to draw).
PHOTO_MAX_SIDE = 2400
#: At most this many zoom panels beside the top view; more go to :func:`plot_zooms`.
MAX_ZOOM_PANELS = 12
#: The longest side of a figure (inches) that grows with the number of objects.
MAX_FIGURE_IN = 18.0
#: An object gets a zoom panel when its footprint, cloud and truth together are smaller than this
#: share of the top view's span (at the plot's scale its credible region is then a smudge).
ZOOM_BELOW = 0.2
#: The photo gets an inset on its objects when the inset magnifies them at least this many times.
PHOTO_ZOOM_AT_LEAST = 2.5


def object_styles(m: int) -> list[dict]:
    """``{"color", "ls"}`` of each of ``m`` objects: the colours in turn, then again with the next
    line style; unique up to ``len(OBJECT_COLORS) * len(OBJECT_LINESTYLES)`` (66) objects."""
    k = len(OBJECT_COLORS)
    return [{"color": OBJECT_COLORS[i % k], "ls": OBJECT_LINESTYLES[(i // k) % len(OBJECT_LINESTYLES)]}
            for i in range(m)]


def object_labels(scene) -> list[str]:
    """``id (class)`` of every target."""
    return [t.id if t.cls is None else f"{t.id} ({t.cls})" for t in scene.targets]


def short_labels(scene) -> list[str]:
    """What marks each object in a crowded figure: its id when every id has at most 6 characters,
    else its number (1, 2, …; the key below the figure gives the id and class)."""
    ids = [str(t.id) for t in scene.targets]
    return ids if max((len(s) for s in ids), default=0) <= 6 else [str(i + 1) for i in range(len(ids))]


def _labelling(scene, m: int):
    """Styles, whether labels are full (``id (class)``), the labels and their font size."""
    full = m <= FULL_LABELS_UP_TO
    fs = 8.0 if full else 7.0 if m <= 30 else 6.0
    return object_styles(m), full, object_labels(scene) if full else short_labels(scene), fs


def _key(ax_or_fig, scene, styles, fontsize: float, width_in: float, *, outside: bool):
    """The key of a crowded figure: each object's line style, short label, id and class."""
    short, full = short_labels(scene), object_labels(scene)
    texts = [f if s == str(t.id) else f"{s}: {f}" for s, f, t in zip(short, full, scene.targets)]
    handles = [Line2D([], [], color=st["color"], ls=st["ls"], lw=1.8) for st in styles]
    entry_in = (max(len(s) for s in texts) * 0.55 * fontsize + 32) / 72
    ncols = int(np.clip(width_in // entry_in, 1, len(texts)))
    kw = dict(ncols=ncols, fontsize=fontsize, frameon=False, handlelength=2.6, columnspacing=1.2,
              title="objects", title_fontsize=fontsize + 1)
    if outside:
        return ax_or_fig.legend(handles, texts, loc="outside lower center", **kw)
    return ax_or_fig.legend(handles, texts, loc="upper center", bbox_to_anchor=(0.5, -0.12), **kw)


def _key_height_in(m: int, fontsize: float, width_in: float, scene) -> float:
    texts = object_labels(scene)
    entry_in = (max(len(s) for s in texts) * 0.55 * fontsize + 32) / 72
    rows = -(-m // max(1, int(width_in // entry_in)))
    return 0.45 + rows * fontsize * 1.75 / 72


def _truth_state(target) -> np.ndarray | None:
    """A target's true state (7,) in :data:`OBJECT_NAMES` order, or None when its truth lacks the
    yaw or the sizes (a known size counts)."""
    gt = target.ground_truth
    d = (gt or {}).get("dimensions_m")
    sizes = [d["length"], d["width"], d["height"]] if d else target.dimensions
    if gt is None or gt.get("yaw_rad") is None or sizes is None:
        return None
    x, _, z = gt["location_m"]
    return np.array([x, z, gt["yaw_rad"], *sizes, gt.get("ground_m") or 0.0], float)


def _load_image(scene):
    """The scene's photo as an (h, w, 3) array reduced to at most :data:`PHOTO_MAX_SIDE` pixels a
    side (drawn over the scene's own size, so a smaller copy lands in place), or None: no photo, or
    one that cannot be read (then an :class:`~.images.ImageWarning` names the file and why)."""
    import warnings

    from .images import ImageError, ImageWarning, read_image

    path = scene.image_path
    if path is None or not path.exists():
        return None
    try:
        return read_image(path, mode="RGB", max_side=PHOTO_MAX_SIDE)
    except ImageError as exc:
        warnings.warn(f"{exc}; the figures are drawn without the photo", ImageWarning, stacklevel=2)
        return None


def _hdr_levels(x, z, prob, bins=40):
    """Smoothed histogram of (x, z) and the density level enclosing ``prob`` of the draws.

    The grid spans the central 99 % of the draws (padded), so that a few far draws do not leave the
    cloud itself a handful of coarse cells; draws outside it count in the total.
    """
    from scipy.ndimage import gaussian_filter

    x, z = np.asarray(x, float), np.asarray(z, float)
    lo, hi = np.quantile(np.column_stack([x, z]), [0.005, 0.995], axis=0)
    pad = 0.3 * np.maximum(hi - lo, 1e-9)
    H, xe, ze = np.histogram2d(x, z, bins=bins, range=np.column_stack([lo - pad, hi + pad]))
    H = gaussian_filter(H, 1.5)
    flat = np.sort(H.ravel())[::-1]
    cum = np.cumsum(flat) / max(len(x), 1)
    level = flat[min(np.searchsorted(cum, prob), len(flat) - 1)]
    return H, xe, ze, level


def _central(cloud, q: float) -> np.ndarray:
    """(2, 2) the (x, z) quantiles ``q`` and 1 − ``q`` of a cloud of bottom centres."""
    return np.column_stack([np.quantile(cloud[0], [q, 1 - q]), np.quantile(cloud[1], [q, 1 - q])])


# ------------------------------------------------------------------------------------------------
# Labels that do not overlap


def _renderer(fig):
    """The figure's renderer (an Agg canvas is attached to a figure made without pyplot)."""
    if not hasattr(fig.canvas, "get_renderer"):
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    return fig.canvas.get_renderer()


def _rects(points_list, transform) -> np.ndarray:
    """(k, 4) display bounding rectangles x0, y0, x1, y1 of point sets in data coordinates."""
    out = []
    for p in points_list:
        p = np.asarray(p, float).reshape(-1, 2)
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p):
            d = transform(p)
            out.append([*d.min(axis=0), *d.max(axis=0)])
    return np.array(out, float).reshape(-1, 4)


def _overlap_area(cand: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """(K, k) intersection areas of K candidate rectangles with k rectangles."""
    if not len(rects):
        return np.zeros((len(cand), 0))
    w = np.minimum(cand[:, None, 2], rects[None, :, 2]) - np.maximum(cand[:, None, 0], rects[None, :, 0])
    h = np.minimum(cand[:, None, 3], rects[None, :, 3]) - np.maximum(cand[:, None, 1], rects[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


#: Directions tried around an anchor, best first: above, then the sides, then below.
_DIRECTIONS = np.deg2rad([90, 65, 115, 40, 140, 15, 165, 0, 180, -20, -160, -45, -135, -70, -110, -90])


def _place_labels(ax, anchors, texts, colors, *, fontsize: float, obstacles=(), avoid=(),
                  soft_weight: float = 4.0) -> list:
    """Write each text near its anchor (data coordinates), no two overlapping, all inside the axes:
    the free place nearest the anchor, preferring above it and places covering neither another
    anchor nor an obstacle (point sets in data coordinates; covering one costs ``soft_weight`` text
    heights of distance); no text covers an artist of ``avoid`` (a legend). A text moved away from
    its anchor gets a leader line. The figure is laid out first, then the texts placed in its pixels.

    Returns the :class:`~matplotlib.text.Annotation` of each text (None where the anchor is not finite).
    """
    fig = ax.figure.figure
    renderer = _renderer(fig)
    fig.draw_without_rendering()
    to_px = ax.transData.transform
    frame = ax.get_window_extent(renderer).extents
    A = np.asarray(anchors, float).reshape(-1, 2)
    ok = np.all(np.isfinite(A), axis=1)
    P = np.full_like(A, np.nan)
    if ok.any():
        P[ok] = to_px(A[ok])
    px_per_pt = fig.dpi / 72
    pad = 0.25 * fontsize * px_per_pt
    sizes = np.zeros((len(A), 2))
    for i, s in enumerate(texts):
        t = ax.text(0, 0, s, fontsize=fontsize)
        bb = t.get_window_extent(renderer)
        t.remove()
        sizes[i] = bb.width + 2 * pad, bb.height + 2 * pad
    h_ref = float(sizes[:, 1].max()) if len(sizes) else 10.0
    soft = _rects(obstacles, to_px)
    hard = np.array([a.get_window_extent(renderer).extents for a in avoid], float).reshape(-1, 4)
    dirs = np.column_stack([np.cos(_DIRECTIONS), np.sin(_DIRECTIONS)])
    rank = np.arange(len(dirs)) / len(dirs)  # a slight preference for the directions listed first
    radii = 0.15 * h_ref + 0.6 * h_ref * np.arange(40)
    # a coarse grid over the whole axes: the last resort of a label with no free place near it
    gx, gy = np.meshgrid(np.arange(frame[0], frame[2], h_ref), np.arange(frame[1], frame[3], h_ref / 2))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    # the most crowded anchors first: they take the places next to them
    crowd = np.array([np.sum(np.hypot(*(P[ok] - p).T) < 4 * h_ref) if ok[i] else -1 for i, p in enumerate(P)])
    placed = np.zeros((0, 4))
    centres = np.full_like(P, np.nan)
    for i in np.argsort(-crowd, kind="stable"):
        if not ok[i]:
            continue
        w, h = sizes[i]
        half = np.array([w / 2, h / 2])
        ring = P[i] + (dirs[None, :, :] * (half[None, None, :] + radii[:, None, None])).reshape(-1, 2)
        cand = np.vstack([ring, grid])
        dist = np.hypot(*(cand - P[i]).T) + np.concatenate([np.tile(rank, len(radii)), np.zeros(len(grid))]) * h_ref
        rect = np.column_stack([cand - half, cand + half])
        inside = (rect[:, 0] >= frame[0]) & (rect[:, 1] >= frame[1]) & (rect[:, 2] <= frame[2]) & (rect[:, 3] <= frame[3])
        clash = _overlap_area(rect, placed).sum(axis=1) + _overlap_area(rect, hard).sum(axis=1)
        others = P[ok & (np.arange(len(P)) != i)]
        covers = ((others[None, :, 0] > rect[:, None, 0]) & (others[None, :, 0] < rect[:, None, 2])
                  & (others[None, :, 1] > rect[:, None, 1]) & (others[None, :, 1] < rect[:, None, 3])).sum(axis=1)
        own = (rect[:, 0] < P[i, 0]) & (P[i, 0] < rect[:, 2]) & (rect[:, 1] < P[i, 1]) & (P[i, 1] < rect[:, 3])
        cost = dist + h_ref * (soft_weight * _overlap_area(rect, soft).sum(axis=1) / (w * h) + 4.0 * covers)
        inside &= ~own  # a label never hides its own object's anchor
        free = inside & (clash <= 0)
        if free.any():
            best = np.flatnonzero(free)[np.argmin(cost[free])]
        else:  # nowhere free: the least overlap inside the axes
            best = int(np.argmin(np.where(inside, clash, np.inf) + 1e-6 * cost))
        centres[i] = cand[best]
        placed = np.vstack([placed, rect[best]])
    out = []
    for i, s in enumerate(texts):
        if not ok[i]:
            out.append(None)
            continue
        off = centres[i] - P[i]
        w, h = sizes[i]
        gap = np.hypot(max(abs(off[0]) - w / 2, 0.0), max(abs(off[1]) - h / 2, 0.0))
        arrow = ({"arrowstyle": "-", "color": colors[i], "lw": 0.7, "shrinkA": 0, "shrinkB": 1.5, "alpha": 0.9}
                 if gap > 0.6 * h_ref else None)
        a = ax.annotate(s, A[i], xytext=tuple(off / px_per_pt), textcoords="offset points", ha="center",
                        va="center", fontsize=fontsize, color=colors[i], arrowprops=arrow, annotation_clip=False,
                        zorder=6, bbox={"boxstyle": "square,pad=0.15", "facecolor": "white", "alpha": 0.8, "lw": 0})
        a.set_in_layout(False)
        out.append(a)
    return out


# ------------------------------------------------------------------------------------------------
# Every box on the photo


def _box_segments(boxes: np.ndarray) -> list:
    """The finite edges of (n, 8, 2) projected boxes, as line segments."""
    segs = []
    for uv in np.asarray(boxes).reshape(-1, 8, 2):
        segs.extend(uv[[a, b]] for a, b in _BOX_EDGES if np.all(np.isfinite(uv[[a, b]])))
    return segs


def _median_box_pt(ax, boxes: list, width_px: int) -> float:
    """The median size (the larger side of its extent) of the projected ``boxes`` on the figure, in
    points: the axes' width in points per pixel of the image (``width_px`` wide) times each box's
    size in pixels."""
    pt_per_px = ax.get_position().width * ax.figure.figure.get_figwidth() * 72 / max(width_px, 1)
    sizes = [np.ptp(b[np.all(np.isfinite(b), axis=1)], axis=0).max() for b in boxes
             if np.all(np.isfinite(b), axis=1).sum() >= 2]
    return float(np.median(sizes)) * pt_per_px if sizes else 64.0


def _annotation_segments(corners: np.ndarray) -> list:
    """The three dimension lines (from the first corner) of (k, 4, 2) annotations, as segments."""
    return [c[[0, j]] for c in np.asarray(corners).reshape(-1, 4, 2) for j in (1, 2, 3)]


def plot_boxes(scene, camera: np.ndarray, objects: np.ndarray, draws=None, *, n_boxes: int = 25,
               draws_label: str = "posterior draws", zoom: bool = True, rng=0, ax=None) -> Figure:
    """The photo (or a blank canvas of its size) with the workers' annotations (thin black: each
    set of dimension lines; thick: their per-corner median), the horizon when the scene gives one,
    every object's labelled MAP box and ``n_boxes`` boxes per object from the draws, each projected
    with its draw's own camera. With ``zoom``, an inset magnifies the objects and their annotations
    when they are small in the photo (at least :data:`PHOTO_ZOOM_AT_LEAST` times)."""
    w, h = scene.image_width, scene.image_height
    m = len(objects)
    styles, full, labels, fs = _labelling(scene, m)
    own = ax is None
    if own:
        # inches per pixel: the image 12 in wide (16 in from 40 objects on), at most 10 in high
        scale = min((12.0 + 4.0 * np.clip((m - FULL_LABELS_UP_TO) / 28, 0, 1)) / w, 10.0 / h)
        width_in = max(w * scale + 0.9, 6.0)
        key_in = 0.0 if full else _key_height_in(m, fs, width_in, scene)
        fig = Figure(figsize=(width_in, h * scale + 1.0 + key_in), layout="constrained")
        ax = fig.add_subplot()
    else:
        fig = ax.figure.figure
    image = _load_image(scene)
    if image is not None:
        ax.imshow(image, extent=(0, w, h, 0))
    else:
        ax.add_patch(Rectangle((0, 0), w, h, facecolor="#f4f4f4", edgecolor="#999999"))
    if scene.horizon is not None:
        ax.plot(*np.asarray(scene.horizon).T, ls="--", color="#777777", lw=1, label="horizon")
    maps = [image_boxes(camera[None], objects[i][None], scene.principal_point)[0] for i in range(m)]
    # Line widths follow the objects' size on the figure (a KITTI frame's cars are a few dozen
    # points): the MAP box below, thin enough that the draws around it and the annotations drawn
    # over it (thin black) stay visible where they differ from it by a pixel or two.
    lw = float(np.clip(0.025 * _median_box_pt(ax, maps, w), 0.8, 1.6 if m <= 30 else 1.3))
    ax.add_collection(LineCollection([s for t in scene.targets for s in _annotation_segments(t.corners)],
                                     colors="k", linewidths=0.35 * lw, alpha=0.6, zorder=4, gid="annotations"),
                      autolim=False)
    ax.add_collection(LineCollection([s for t in scene.targets for s in _annotation_segments(t.median_corners)],
                                     colors="k", linewidths=0.6 * lw, zorder=4.5, gid="median annotations"),
                      autolim=False)
    if draws is not None:
        cams, objs = draws
        pick = np.random.default_rng(rng).choice(len(cams), size=min(n_boxes, len(cams)), replace=False)
        for i in range(m):
            segs = _box_segments(image_boxes(cams[pick], objs[pick, i], scene.principal_point))
            ax.add_collection(LineCollection(segs, colors=styles[i]["color"], linewidths=max(0.6 * lw, 0.8), alpha=0.45,
                                             zorder=3, gid="draw boxes"), autolim=False)
    anchors = np.full((m, 2), np.nan)
    for i, box in enumerate(maps):
        ax.add_collection(LineCollection(_box_segments(box), colors=styles[i]["color"], linestyles=[styles[i]["ls"]],
                                         linewidths=lw, zorder=2.5, gid="map box"), autolim=False)
        top = box[4:][np.all(np.isfinite(box[4:]), axis=1)]
        if len(top):
            anchors[i] = np.clip(top[:, 0].mean(), 0, w), np.clip(top[:, 1].min(), 0, h)
    # the legend's boxes in the first object's colour (the annotations are black)
    each = "" if m == 1 else ", each object in its colour"
    ax.plot([], [], color=styles[0]["color"], lw=lw, label=f"box at the MAP (the most probable{each})")
    if draws is not None:
        ax.plot([], [], color=styles[0]["color"], lw=max(0.6 * lw, 0.8), alpha=0.45,
                label=f"{min(n_boxes, len(draws[0]))} boxes per object: {draws_label}")
    ax.plot([], [], color="k", lw=max(0.6 * lw, 0.8), label="annotations (thin: each set; thick: their median)")
    ax.set(xlim=(0, w), ylim=(h, 0), aspect="equal", xlabel="u (px)", ylabel="v (px)")
    what = f"{m} objects" if m > 1 else labels[0]
    ax.set_title(f"{what}: boxes at the MAP" + (f" and {draws_label}" if draws is not None else ""))
    legend = ax.legend(loc="lower left", fontsize=8, framealpha=0.85)
    avoid = [legend]
    if zoom:
        pts = np.vstack([b.reshape(-1, 2) for b in maps] + [t.corners.reshape(-1, 2) for t in scene.targets])
        inset = _photo_inset(ax, pts, w, h)
        avoid += [inset] if inset is not None else []
    if not full:
        _key(fig if own else ax, scene, styles, fs, fig.get_figwidth(), outside=own)
    _place_labels(ax, anchors, labels, [s["color"] for s in styles], fontsize=fs,
                  obstacles=[np.clip(b, [0, 0], [w, h]) for b in maps], avoid=avoid, soft_weight=8.0)
    return fig


def _photo_inset(ax, pts: np.ndarray, w: int, h: int):
    """An inset magnifying the part of the photo that holds ``pts`` (pixels) at least
    :data:`PHOTO_ZOOM_AT_LEAST` times, in a corner of the axes clear of them (not the legend's, lower
    left); the inset axes, or None when they are too large for it or no corner is clear."""
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        return None
    lo, hi = np.maximum(pts.min(axis=0), 0), np.minimum(pts.max(axis=0), [w, h])
    size = max(hi[0] - lo[0], (hi[1] - lo[1]) * w / h) * 1.15 + 1.0
    if 0.42 * w / size < PHOTO_ZOOM_AT_LEAST:
        return None
    c = (lo + hi) / 2
    a, b = np.array([lo[0] / w, 1 - hi[1] / h]), np.array([hi[0] / w, 1 - lo[1] / h])  # axes fractions, y up
    clear = [k for k in ((0.56, 0.56), (0.02, 0.56), (0.56, 0.02))
             if np.any(b < np.array(k) - 0.01) or np.any(a > np.array(k) + 0.43)]
    if not clear:
        return None
    box = max(clear, key=lambda k: np.hypot(*(np.array(k) + 0.21 - (a + b) / 2)))
    inset = ax.inset_axes([*box, 0.42, 0.42])
    for im in ax.images:
        inset.imshow(im.get_array(), extent=im.get_extent())
    for p in ax.patches:
        if isinstance(p, Rectangle):
            inset.add_patch(Rectangle(p.get_xy(), p.get_width(), p.get_height(), facecolor=p.get_facecolor(),
                                      edgecolor="none"))
    for line in ax.lines:
        inset.plot(*line.get_data(), color=line.get_color(), lw=line.get_linewidth(), ls=line.get_linestyle(),
                   alpha=line.get_alpha())
    for col in ax.collections:
        inset.add_collection(LineCollection(col.get_segments(), colors=col.get_colors(), linewidths=col.get_linewidths(),
                                            linestyles=col.get_linestyles(), alpha=col.get_alpha(),
                                            zorder=col.get_zorder()), autolim=False)
    x0, y0 = c[0] - size / 2, c[1] - size * h / w / 2
    inset.set(xlim=(x0, x0 + size), ylim=(y0 + size * h / w, y0), xticks=[], yticks=[])
    inset.set_title(f"zoom ×{0.42 * w / size:.0f}", fontsize=8, pad=2)
    ax.indicate_inset_zoom(inset, edgecolor="0.3")
    return inset


# ------------------------------------------------------------------------------------------------
# The top view


def _cloud(ax, x, z, color, prob, max_points=800, rng=0, contour=True):
    sel = np.random.default_rng(rng).permutation(len(x))[:max_points]
    ax.scatter(x[sel], z[sel], s=2, alpha=0.25, color=color, lw=0)
    if contour and len(x) >= 50:
        H, xe, ze, level = _hdr_levels(x, z, prob)
        ax.contour((xe[:-1] + xe[1:]) / 2, (ze[:-1] + ze[1:]) / 2, H.T, levels=[level], colors=[color],
                   linewidths=1.2)


def _geometry(scene, objects, draws):
    """Truth states, clouds of bottom centres, the plotted points and their span (m)."""
    m = len(objects)
    truths = [_truth_state(t) for t in scene.targets]
    pts = [np.zeros((1, 2))] + [_footprint(o) for o in objects] + [_footprint(t) for t in truths if t is not None]
    clouds = []
    if draws is not None:
        objs = draws[1]
        for i in range(m):
            clouds.append((objs[:, i, 0], objs[:, i, 1]))
            pts.append(_central(clouds[-1], 0.01))
    pts = np.vstack(pts)
    span = max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 1.0)
    return truths, clouds, pts, span


def zoom_indices(scene, objects: np.ndarray, draws=None) -> list[int]:
    """The objects whose footprint, cloud and truth together are smaller than
    :data:`ZOOM_BELOW` of the top view's span: each gets a zoom panel at its own scale."""
    truths, clouds, _, span = _geometry(scene, objects, draws)
    return [i for i in range(len(objects))
            if _object_extent(objects[i], clouds[i] if clouds else None, truths[i]) < ZOOM_BELOW * span]


def _legend_entries(ax, *, clouds: bool, truth: bool, draws_label: str, prob: float, centre: str | None,
                    camera: bool) -> None:
    ax.plot([], [], color="0.3", lw=1.5, label="footprint at the MAP")
    if clouds:
        ax.scatter([], [], s=6, color="0.3", label=f"bottom centres, {draws_label}")
        ax.plot([], [], color="0.3", lw=1.2, label=f"{prob:.0%} credible region")
    if centre:
        ax.plot([], [], "x", color=_CENTRE_COLOR, ms=6, mew=1.5, label=centre)
    if truth:
        ax.plot([], [], color=_TRUTH_COLOR, ls="--", lw=1.0, label="truth")
    if camera:
        ax.plot([], [], color="#555555", lw=0.8, ls=":", label="field of view (at the MAP focal length)")
        ax.plot([], [], "^", color="k", ms=7, label="camera")


def plot_top_view(scene, camera: np.ndarray, objects: np.ndarray, draws=None, *, prob: float = 0.9,
                  draws_label: str = "posterior draws", rng=0, max_zoom: int | None = None, fig=None) -> Figure:
    """The ground seen from above: the camera and its field of view, every object's footprint at
    the MAP, its posterior cloud of bottom centres and their ``prob`` credible region, and the true
    footprint (dashed, black) when known. The objects of :func:`zoom_indices` get a zoom panel
    each (right, own scale) when there are at most ``max_zoom`` (default :data:`MAX_ZOOM_PANELS`);
    with more, the title says so and :func:`plot_zooms` draws them."""
    m = len(objects)
    styles, full, labels, fs = _labelling(scene, m)
    colors = [s["color"] for s in styles]
    truths, clouds, pts, span = _geometry(scene, objects, draws)
    zoom = zoom_indices(scene, objects, draws)
    beside = zoom if len(zoom) <= (MAX_ZOOM_PANELS if max_zoom is None else max_zoom) else []
    cols = -(-len(beside) // 4)  # at most 4 panels a column, as high as the top view
    rows = -(-len(beside) // cols) if cols else 0
    lo, hi = pts.min(axis=0) - 0.06 * span, pts.max(axis=0) + 0.06 * span
    lo[1] = min(lo[1], -0.05 * span)
    main_h = 7.5
    # at least 7.5 in wide with a key under it, so that the key's columns keep it short
    main_w = float(np.clip(main_h * (hi[0] - lo[0]) / (hi[1] - lo[1]), 5.0 if full else 7.5, 10.0))
    # widen the shorter side so that the data fill the panel at an equal aspect
    want = main_w / main_h
    if (hi[0] - lo[0]) / (hi[1] - lo[1]) < want:
        grow = want * (hi[1] - lo[1]) - (hi[0] - lo[0])
        lo[0], hi[0] = lo[0] - grow / 2, hi[0] + grow / 2
    else:
        grow = (hi[0] - lo[0]) / want - (hi[1] - lo[1])
        hi[1] += grow
    panel = 2.2
    key_in = 0.0 if full else _key_height_in(m, fs, main_w + 0.8, scene)
    if fig is None:
        fig = Figure(figsize=(main_w + 1.0 + panel * cols, max(main_h + 2.2 + key_in, panel * rows + 0.8)),
                     layout="constrained")
    if cols:
        left, right = fig.subfigures(1, 2, width_ratios=[main_w + 1.0, panel * cols])
    else:
        left, right = fig, None
    ax = left.add_subplot()
    for i in range(m):
        if clouds:
            _cloud(ax, *clouds[i], colors[i], prob, rng=rng, contour=i not in zoom)
        _draw_footprint(ax, objects[i], colors[i], ls=styles[i]["ls"])
        if truths[i] is not None:
            _draw_footprint(ax, truths[i], _TRUTH_COLOR, ls="--", lw=1.0, fill=False)
    _draw_camera(ax, scene, camera, 0.025 * span)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), aspect="equal", xlabel="x, right (m)",
           ylabel="z, forward (m)")
    ax.grid(alpha=0.3)
    _legend_entries(ax, clouds=bool(clouds), truth=any(t is not None for t in truths), draws_label=draws_label,
                    prob=prob, centre="bottom centre at the MAP (zoom panels)" if beside else None, camera=True)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.07), ncols=2, fontsize=7, frameon=False)
    title = "the ground seen from above" + (f" ({m} objects)" if m > 1 else "")
    if zoom and not beside:
        title += f"\nthe {len(zoom)} objects small at this scale: each at its own scale in the zoom figure"
    ax.set_title(title, fontsize=10)
    if not full:
        _key(left, scene, styles, fs, main_w + 0.8, outside=True)
    if cols:
        _zoom_panels(right, rows, cols, beside, scene, objects, clouds, truths, styles, prob, rng)
        right.suptitle("zoom on each small object\n(own scale)" if cols == 1 else "zoom on each small object (own scale)",
                       fontsize=9)
    _place_labels(ax, objects[:, :2], labels, colors, fontsize=fs, obstacles=[_footprint(o) for o in objects])
    return fig


def plot_zooms(scene, camera: np.ndarray, objects: np.ndarray, draws=None, *, indices=None,
               prob: float = 0.9, draws_label: str = "posterior draws", rng=0, fig=None) -> Figure:
    """One panel per object at its own scale (its footprint at the MAP, the cloud of its bottom
    centres and their ``prob`` credible region, the MAP bottom centre and the truth): the zoom
    panels of :func:`plot_top_view` on their own, for ``indices`` (default: the objects of
    :func:`zoom_indices`, or every object when none is small). At most 8 panels a row, and the
    figure at most :data:`MAX_FIGURE_IN` inches high."""
    m = len(objects)
    styles = object_styles(m)
    truths, clouds, _, _ = _geometry(scene, objects, draws)
    if indices is None:
        indices = zoom_indices(scene, objects, draws) or list(range(m))
    indices = list(indices)
    n = max(len(indices), 1)
    cols = int(min(8, max(1, np.ceil(np.sqrt(n)))))
    rows = -(-n // cols)
    panel = float(min(2.3, (MAX_FIGURE_IN - 1.2) / rows, MAX_FIGURE_IN / cols))
    if fig is None:
        fig = Figure(figsize=(max(panel * cols + 0.3, 4.6), panel * rows + 1.6), layout="constrained")
    _zoom_panels(fig, rows, cols, indices, scene, objects, clouds, truths, styles, prob, rng)
    proxy = fig.add_axes([0, 0, 0, 0])
    proxy.set_visible(False)
    _legend_entries(proxy, clouds=bool(clouds), truth=any(truths[i] is not None for i in indices),
                    draws_label=draws_label, prob=prob, centre="bottom centre at the MAP", camera=False)
    width_in = fig.get_figwidth()
    fig.legend(*proxy.get_legend_handles_labels(), loc="outside lower center", ncols=3 if width_in > 9 else 2,
               fontsize=8, frameon=False)
    proxy.remove()
    title = (f"each object at its own scale, seen from above ({len(indices)} of {m} objects; "
             f"x right, z forward, m)")
    fig.suptitle(textwrap.fill(title, int(width_in * 72 / 5.8)), fontsize=10)
    return fig


def _panel_points(obj, cloud, truth) -> np.ndarray:
    """The points an object's zoom panel shows: its footprint, its cloud's central 99 %, its truth."""
    pts = [_footprint(obj)] + ([] if cloud is None else [_central(cloud, 0.005)])
    return np.vstack(pts + ([] if truth is None else [_footprint(truth)]))


def _object_extent(obj, cloud, truth) -> float:
    p = _panel_points(obj, cloud, truth)
    return float(max(np.ptp(p[:, 0]), np.ptp(p[:, 1])))


def _zoom_panels(fig, rows, cols, indices, scene, objects, clouds, truths, styles, prob, rng) -> None:
    """A grid of ``rows`` × ``cols`` zoom panels on ``fig``, one per object of ``indices``."""
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    full = object_labels(scene)
    for a, i in zip(axes, indices):
        _zoom_panel(a, objects[i], clouds[i] if clouds else None, truths[i], styles[i], full[i], prob, rng)
    for a in axes[len(indices):]:
        a.set_visible(False)


def _zoom_panel(ax, obj, cloud, truth, style, label, prob, rng) -> None:
    color = style["color"]
    if cloud is not None:
        _cloud(ax, *cloud, color, prob, rng=rng)
    _draw_footprint(ax, obj, color, ls=style["ls"])
    ax.plot(obj[0], obj[1], "x", color=_CENTRE_COLOR, ms=6, mew=1.5, zorder=5)
    if truth is not None:
        _draw_footprint(ax, truth, _TRUTH_COLOR, ls="--", lw=1.0, fill=False)
    p = _panel_points(obj, cloud, truth)
    c = (p.min(axis=0) + p.max(axis=0)) / 2
    half = 0.55 * max(np.ptp(p[:, 0]), np.ptp(p[:, 1]), 0.5)
    ax.set(xlim=(c[0] - half, c[0] + half), ylim=(c[1] - half, c[1] + half), aspect="equal")
    ax.tick_params(labelsize=6)
    ax.grid(alpha=0.3)
    ax.set_title(f"{label}, {np.hypot(obj[0], obj[1]):.0f} m", fontsize=7, color=color)


def _draw_footprint(ax, obj, color, *, ls="-", lw=1.5, fill=True) -> None:
    if fill:
        ax.add_patch(Polygon(_footprint(obj), closed=True, facecolor=color, alpha=0.3, edgecolor="none"))
    ax.add_patch(Polygon(_footprint(obj), closed=True, facecolor="none", edgecolor=color, lw=lw, ls=ls))


def _draw_camera(ax, scene, camera, size: float) -> None:
    """The camera's foot point and its horizontal field of view at the MAP focal length."""
    cx = float(scene.principal_point[0])
    f = camera[C_FOCAL]
    far = 1e4
    ax.plot([0, -far * cx / f], [0, far], color="#555555", lw=0.8, ls=":")
    ax.plot([0, far * (scene.image_width - cx) / f], [0, far], color="#555555", lw=0.8, ls=":")
    tri = np.array([[0, 0], [-0.6, -1.0], [0.6, -1.0]]) * size
    ax.add_patch(Polygon(tri, closed=True, color="k"))


# ------------------------------------------------------------------------------------------------
# Pair and rank plots of the posterior


@dataclass(frozen=True)
class Column:
    """One quantity of a pair or rank plot, in the units it is shown in: ``name`` (``camera.pitch``,
    ``<id>.x``), its axis ``label``, the draws (n,), the MAP, the truth (or None) and the result's
    HDI (low, high) (or None)."""

    name: str
    label: str
    values: np.ndarray
    map: float
    truth: float | None = None
    hdi: tuple[float, float] | None = None


_DEG = 180 / np.pi
#: Camera quantities shown (the crowd's scale is a nuisance parameter): index, name, label, scale,
#: key of the scene's camera truth.
_CAMERA_SHOWN = ((C_FOCAL, "focal length (px)", 1.0, "focal_length_px"), (C_PITCH, "pitch (°)", _DEG, "pitch_rad"),
                 (C_ROLL, "roll (°)", _DEG, "roll_rad"), (C_HEIGHT, "camera height (m)", 1.0, "camera_height_m"))
_OBJECT_SHOWN = ((0, "x (m)", 1.0), (1, "z (m)", 1.0), (O_YAW, "yaw (°)", _DEG), (3, "length (m)", 1.0),
                 (4, "width (m)", 1.0), (5, "height (m)", 1.0), (6, "ground offset (m)", 1.0))


def _varies(v: np.ndarray) -> bool:
    """Whether draws vary beyond rounding (a pitch derived from a horizon wobbles by 1e-17)."""
    return bool(np.ptp(v) > 1e-9 * (1.0 + np.max(np.abs(v))))


def _hdi(block: dict | None, key: str, scale: float):
    iv = ((block or {}).get("posterior") or {}).get("hdi", {}).get(key)
    return None if iv is None or None in iv else (iv[0] * scale, iv[1] * scale)


def posterior_columns(scene, result: dict | None, camera: np.ndarray, objects: np.ndarray, draws,
                      chosen=(0,), *, distance: bool = False) -> list[Column]:
    """The quantities that vary in ``draws`` (cameras (n, 5), objects (n, m, 7)): the camera's
    focal length, pitch, roll and height, then each ``chosen`` object's x, z, yaw, sizes and ground
    offset (and, with ``distance``, its ground distance), with the MAP, the scene's truth and the
    result's HDI (a ``creference-result/2`` dict, or None). Angles in degrees, yaws on the arc of
    ±180° around the MAP's."""
    cams, objs = draws
    cam_truth = scene.ground_truth or {}
    cols = []
    for k, label, scale, key in _CAMERA_SHOWN:
        if _varies(cams[:, k]):
            t = cam_truth.get(key)
            cols.append(Column(f"camera.{CAMERA_NAMES[k]}", label, cams[:, k] * scale, camera[k] * scale,
                               None if t is None else t * scale,
                               _hdi((result or {}).get("camera"), CAMERA_NAMES[k], scale)))
    for i in chosen:
        target = scene.targets[i]
        prefix = f"{target.id}: " if len(chosen) > 1 else ""
        truth = _truth_state(target)
        entry = (result or {}).get("objects", [None] * len(objects))[i]
        o = objs[:, i].copy()
        o[:, O_YAW] = objects[i, O_YAW] + (o[:, O_YAW] - objects[i, O_YAW] + np.pi) % (2 * np.pi) - np.pi
        if truth is None and target.ground_truth and "location_m" in target.ground_truth:
            x, _, z = target.ground_truth["location_m"]
            truth = np.array([x, z] + [np.nan] * 5)
        for k, label, scale in _OBJECT_SHOWN:
            if _varies(o[:, k]):
                t = None if truth is None or not np.isfinite(truth[k]) else truth[k]
                if t is not None and k == O_YAW:
                    t = objects[i, O_YAW] + (t - objects[i, O_YAW] + np.pi) % (2 * np.pi) - np.pi
                cols.append(Column(f"{target.id}.{OBJECT_NAMES[k]}", prefix + label, o[:, k] * scale,
                                   objects[i, k] * scale, None if t is None else t * scale,
                                   _hdi(entry, OBJECT_NAMES[k], scale)))
        if distance:
            t = None if truth is None else float(np.hypot(truth[0], truth[1]))
            cols.append(Column(f"{target.id}.distance_m", prefix + "distance (m)", np.hypot(o[:, 0], o[:, 1]),
                               float(np.hypot(*objects[i, :2])), t, _hdi(entry, "distance_m", 1.0)))
    return cols


def plot_pairs(columns: list[Column], *, title: str = "", draws_label: str = "posterior draws",
               max_points: int = 3000, rng=0, fig=None) -> Figure:
    """Pair plot: each column's histogram on the diagonal (shaded: its HDI), the draws of each pair
    below it, with the MAP (red) and the truth (black) when known."""
    n = max(len(columns), 1)
    if fig is None:
        panel = float(np.clip(15.0 / n, 1.2, 1.9))
        fig = Figure(figsize=(panel * n + 0.6, panel * n + 0.8), layout="constrained")
    axes = fig.subplots(n, n, squeeze=False)
    k = len(columns[0].values) if columns else 0
    sel = np.random.default_rng(rng).permutation(k)[:max_points]
    for r, a in enumerate(columns):
        for c, b in enumerate(columns):
            ax = axes[r, c]
            if c > r:
                ax.set_visible(False)
                continue
            if r == c:
                ax.hist(a.values, bins=int(np.clip(np.sqrt(k), 10, 40)), color=_POST_COLOR, alpha=0.7)
                if a.hdi is not None:
                    ax.axvspan(*a.hdi, color=_POST_COLOR, alpha=0.12)
                ax.axvline(a.map, color=_MAP_COLOR, lw=1.5)
                if a.truth is not None:
                    ax.axvline(a.truth, color=_TRUTH_COLOR, lw=1.5)
                ax.set_yticks([])
            else:
                ax.scatter(b.values[sel], a.values[sel], s=2, alpha=0.25, color=_POST_COLOR, lw=0)
                ax.plot(b.map, a.map, "x", color=_MAP_COLOR, ms=7, mew=2)
                if a.truth is not None and b.truth is not None:
                    ax.plot(b.truth, a.truth, "*", color=_TRUTH_COLOR, ms=10)
            if r == n - 1:
                ax.set_xlabel(b.label, fontsize=8)
            else:
                ax.set_xticklabels([])
            if c == 0 and r > 0:
                ax.set_ylabel(a.label, fontsize=8)
            elif c > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=7)
    if not columns:
        axes[0, 0].text(0.5, 0.5, "nothing varies in the draws", ha="center", va="center")
        axes[0, 0].set_axis_off()
    handles = [Line2D([], [], ls="", marker="x", color=_MAP_COLOR, mew=2, label="MAP (the most probable)"),
               Line2D([], [], ls="", marker="o", ms=3, color=_POST_COLOR, label=draws_label)]
    if any(c.hdi is not None for c in columns):
        handles.append(Rectangle((0, 0), 1, 1, color=_POST_COLOR, alpha=0.25, label="HDI (diagonal)"))
    if any(c.truth is not None for c in columns):
        handles.append(Line2D([], [], ls="", marker="*", ms=9, color=_TRUTH_COLOR, label="truth"))
    if n >= 2:  # in the empty upper right triangle, below the title
        fig.legend(handles=handles, loc="upper right", bbox_to_anchor=(0.99, 0.92), fontsize=8)
    else:
        fig.legend(handles=handles, loc="outside right upper", fontsize=8)
    fig.suptitle(title or f"pair plot ({draws_label})", fontsize=10)
    return fig


def plot_ranks(columns: list[Column], chains: np.ndarray, *, bins: int | None = None, fig=None) -> Figure:
    """Rank plots: for each column, the histogram of each chain's ranks among all draws (``chains``
    (n,): the chain of each draw). Well-mixed independent chains give flat, overlapping histograms; a
    chain stuck apart shows up as a slope or a hump (Vehtari et al. 2021). ``bins`` defaults to
    about 20 draws per bin per chain, from 4 to 20 bins."""
    chains = np.asarray(chains)
    ids = np.unique(chains)
    n = max(len(columns), 1)
    cols = min(3, n)
    rows = -(-n // cols)
    if fig is None:
        fig = Figure(figsize=(4 * cols, min(2.4 * rows + 0.6, MAX_FIGURE_IN)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    per_chain = len(chains) / max(len(ids), 1)
    bins = bins or int(np.clip(per_chain // 20, 4, 20))
    edges = np.linspace(0, len(chains), bins + 1)
    for ax, col in zip(axes, columns):
        ranks = np.argsort(np.argsort(col.values, kind="stable"), kind="stable")
        for c in ids:
            counts, _ = np.histogram(ranks[chains == c], bins=edges)
            ax.stairs(counts, edges, baseline=None, label=f"chain {c}", lw=1.3)
        ax.axhline(per_chain / bins, color="k", ls=":", lw=1)
        ax.set_title(col.label, fontsize=9)
        ax.set(xticks=[], ylim=(0, 2 * per_chain / bins))
    for ax in axes[len(columns):]:
        ax.set_visible(False)
    if len(ids) <= 8:
        axes[0].legend(fontsize=7, loc="lower left", ncols=2)
    fig.suptitle(f"rank plots of {len(ids)} chains (dotted: uniform)", fontsize=10)
    return fig


def kept_chains(result: dict) -> np.ndarray | None:
    """The chain of each draw a ``creference-result/2`` keeps (``draws.chain``, else from
    ``diagnostics.n_chains``: the kept draws are evenly spaced over the chains laid end to end,
    :data:`~creference_bayes.io.result.RESULT_DRAWS`); None when the result does not say."""
    kept, diag = result.get("draws") or {}, result.get("diagnostics") or {}
    chain = kept.get("chain")
    if isinstance(chain, list) and len(chain) == kept.get("n"):
        ok = all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 10_000 for v in chain)
        return np.asarray(chain, int) if ok else None  # a result edited by hand: no chain said
    n, of, c = kept.get("n"), kept.get("of"), diag.get("n_chains")
    if not (isinstance(n, int) and isinstance(of, int) and isinstance(c, int)) or c < 2 or of % c:
        return None
    idx = np.unique(np.linspace(0, of - 1, min(n, of)).round().astype(int))
    return idx // (of // c) if len(idx) == n else None


def plot_sbc_ranks(summary: dict, *, fig=None) -> Figure:
    """Simulation-based calibration: the histogram of the truth's ranks per design (rows) and
    quantity (columns), with the uniform count and its 99 % band (binomial), and the χ² and KS
    p-values in each title.

    Parameters
    ----------
    summary : design → {"quantities": quantity → {"counts", "chi2_p", "ks_p", "n"}} (as
        :func:`creference_bayes.bench.sbc.sbc_summary` returns it)
    """
    from scipy import stats

    designs = list(summary)
    quants = list(next(iter(summary.values()))["quantities"]) if designs else []
    fig = fig or Figure(figsize=(3.2 * max(1, len(quants)), 2.4 * max(1, len(designs))), layout="constrained")
    axes = np.atleast_2d(fig.subplots(max(1, len(designs)), max(1, len(quants)), squeeze=False))
    for i, d in enumerate(designs):
        for j, q in enumerate(quants):
            ax, u = axes[i, j], summary[d]["quantities"][q]
            counts = np.asarray(u["counts"])
            k, n = len(counts), int(u["n"])
            ax.bar(np.arange(k), counts, width=0.9, color="C0")
            if n:
                lo, hi = stats.binom.ppf([0.005, 0.995], n, 1.0 / k)
                ax.axhspan(lo, hi, color="0.85", zorder=0)
                ax.axhline(n / k, color="k", ls=":", lw=1)
            p = lambda v: "–" if v is None else f"{v:.2g}"
            ax.set_title(f"{d}: {q}\nχ² p {p(u['chi2_p'])}, KS p {p(u['ks_p'])}", fontsize=8)
            ax.set_xticks([0, k - 1], ["low", "high"], fontsize=7)
    fig.suptitle("rank of the truth among posterior draws (grey: 99 % band of a uniform)", fontsize=9)
    return fig


# ------------------------------------------------------------------------------------------------
# Every figure of a result


def scene_figures(scene, result: dict, draws=None, *, source: str = "posterior", chains=None, chosen=(0,),
                  rng=0) -> dict[str, Figure]:
    """Every figure of an estimate, by name: ``boxes`` and ``top_view``; ``zooms`` when more objects
    need a zoom panel than fit beside the top view; with draws, ``pairs`` (the camera and the
    ``chosen`` objects' indices); with posterior draws and their chains, ``ranks``.

    Parameters
    ----------
    scene : the scene the result was estimated from
    result : its ``creference-result/2`` dict (the MAP, the HDIs)
    draws : cameras (n, 5) and objects (n, m, 7), or the sampler's
        :class:`~creference_bayes.inference.sampler.Draws` (chain, draw, …; its chains are then known)
    source : ``"posterior"`` or ``"laplace"``, where the draws came from (:data:`DRAWS_LABELS`)
    chains : (n,) the chain of each draw (:func:`kept_chains`), or None
    """
    camera = np.array([result["camera"]["map"][k] for k in CAMERA_NAMES], float)
    objects = np.array([[o["map"][k] for k in OBJECT_NAMES] for o in result["objects"]], float)
    if draws is not None and hasattr(draws, "cameras"):  # (chain, draw, …)
        C, N = draws.cameras.shape[:2]
        chains = np.repeat(np.arange(C), N)
        draws = (draws.cameras.reshape(C * N, 5), draws.objects.reshape(C * N, len(objects), 7))
    label = DRAWS_LABELS[source]
    prob = result.get("hdi_prob") or 0.9
    figs = {"boxes": plot_boxes(scene, camera, objects, draws, draws_label=label, rng=rng),
            "top_view": plot_top_view(scene, camera, objects, draws, prob=prob, draws_label=label, rng=rng)}
    zoom = zoom_indices(scene, objects, draws)
    if len(zoom) > MAX_ZOOM_PANELS:  # too many to sit beside the top view: a figure of their own
        figs["zooms"] = plot_zooms(scene, camera, objects, draws, indices=zoom, prob=prob, draws_label=label, rng=rng)
    if draws is not None:
        chosen = list(chosen)
        names = ", ".join(object_labels(scene)[i] for i in chosen)
        figs["pairs"] = plot_pairs(posterior_columns(scene, result, camera, objects, draws, chosen),
                                   title=f"the camera and {names} ({label})", draws_label=label, rng=rng)
        if source == "posterior" and chains is not None:
            cols = posterior_columns(scene, result, camera, objects, draws, chosen, distance=True)
            figs["ranks"] = plot_ranks(cols, chains)
    return figs
