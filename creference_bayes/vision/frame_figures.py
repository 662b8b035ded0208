"""Figures of a frame's estimate (matplotlib): every object's box on the photo, a top view of the
whole frame with a zoom per object, and the shared camera's posterior (docs/frames.md).

Every function takes the frame (:class:`~creference_bayes.io.frame_scene.FrameScene`), the MAP as
model arrays (camera (5,), objects (m, 7), :mod:`~creference_bayes.models.frame` order) and
posterior draws as model arrays (cameras (n, 5), objects (n, m, 7)) or None, draws on a new
:class:`matplotlib.figure.Figure` (no pyplot state) and returns it.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle

from ..models.frame import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL
from ..models.frame_boxes import footprint as _footprint
from ..models.frame_boxes import frame_boxes_2d
from .plotting import ZOOM_BELOW, _BOX_EDGES, _MAP_COLOR, _POST_COLOR, _hdr_levels, _load_image

#: The truth is drawn in black (dashed): the objects' own colours include the single-target green.
_TRUTH_COLOR = "k"

__all__ = ["plot_frame_boxes", "plot_frame_top_view", "plot_frame_camera", "object_labels"]

def _colors(m: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["tab10" if m <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(m)]


def object_labels(frame) -> list[str]:
    """``id (class)`` of every target."""
    return [t.id if t.cls is None else f"{t.id} ({t.cls})" for t in frame.targets]


def _truth_state(target) -> np.ndarray | None:
    gt = target.ground_truth
    if gt is None or gt.get("yaw_rad") is None or gt.get("dimensions_m") is None:
        return None
    x, _, z = gt["location_m"]
    d = gt["dimensions_m"]
    return np.array([x, z, gt["yaw_rad"], d["length"], d["width"], d["height"], 0.0])


def _pick(n_draws: int, k: int, rng) -> np.ndarray:
    return np.random.default_rng(rng).choice(n_draws, size=min(k, n_draws), replace=False)


def plot_frame_boxes(frame, camera: np.ndarray, objects: np.ndarray, draws=None, *, n_boxes: int = 25,
                     draws_label: str = "posterior draws", rng=0) -> Figure:
    """The photo (or a blank canvas of its size) with every object's MAP box (its colour, labelled
    with its id and class) and a light spread of ``n_boxes`` boxes per object from the draws, each
    projected with its draw's own camera."""
    w, h = frame.image_width, frame.image_height
    fig = Figure(figsize=(12, 12 * h / w + 1.0), layout="constrained")
    ax = fig.add_subplot()
    image = _load_image(frame)
    if image is not None:
        ax.imshow(image, extent=(0, w, h, 0))
    else:
        ax.add_patch(Rectangle((0, 0), w, h, facecolor="#f4f4f4", edgecolor="#999999"))
    m = len(objects)
    colors = _colors(m)
    labels = object_labels(frame)
    if draws is not None:
        cams, objs = draws
        pick = _pick(len(cams), n_boxes, rng)
        for i in range(m):
            for box in frame_boxes_2d(cams[pick], objs[pick, i], frame.principal_point):
                _draw_box(ax, box, color=colors[i], alpha=0.12, lw=0.7)
    maps = [frame_boxes_2d(camera[None], objects[i][None], frame.principal_point)[0] for i in range(m)]
    for i, box in enumerate(maps):
        _draw_box(ax, box, color=colors[i], lw=1.6)
        top = box[4:][np.all(np.isfinite(box[4:]), axis=1)]
        if len(top):
            u, v = top[:, 0].mean(), top[:, 1].min()
            ax.text(np.clip(u, 0, w), np.clip(v - 4, 8, h), labels[i], color=colors[i], fontsize=7, ha="center",
                    va="bottom", bbox={"facecolor": "white", "alpha": 0.6, "lw": 0, "pad": 0.5})
    ax.plot([], [], color="0.2", lw=1.6, label="MAP box")
    if draws is not None:
        ax.plot([], [], color="0.2", lw=0.7, alpha=0.35, label=f"{min(n_boxes, len(draws[0]))} boxes per object: {draws_label}")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"{m} objects: MAP and posterior boxes")
    ax.legend(loc="lower left", fontsize=8, framealpha=0.8)
    return fig


def _draw_box(ax, uv: np.ndarray, **style) -> None:
    for a, b in _BOX_EDGES:
        if np.all(np.isfinite(uv[[a, b]])):
            ax.plot(*uv[[a, b]].T, **style)


def _cloud(ax, x, z, color, prob, max_points=800, rng=0, contour=True):
    sel = np.random.default_rng(rng).permutation(len(x))[:max_points]
    ax.scatter(x[sel], z[sel], s=2, alpha=0.2, color=color, lw=0)
    if contour and len(x) >= 50:
        H, xe, ze, level = _hdr_levels(x, z, prob)
        ax.contour((xe[:-1] + xe[1:]) / 2, (ze[:-1] + ze[1:]) / 2, H.T, levels=[level], colors=[color],
                   linewidths=1.2)


def plot_frame_top_view(frame, camera: np.ndarray, objects: np.ndarray, draws=None, *, prob: float = 0.9,
                        draws_label: str = "posterior draws", rng=0) -> Figure:
    """The ground seen from above: the camera and its field of view, every object's footprint at
    the MAP (its colour), its posterior cloud of bottom centres and their ``prob`` credible region,
    and the true footprint (dashed, green) when the scene has one. Objects whose cloud is smaller
    than :data:`~.plotting.ZOOM_BELOW` of the plotted span get a zoom panel of their own (right),
    each at its own scale."""
    m = len(objects)
    colors = _colors(m)
    labels = object_labels(frame)
    truths = [_truth_state(t) for t in frame.targets]
    pts = [np.zeros((1, 2))] + [_footprint(o) for o in objects] + [_footprint(t) for t in truths if t is not None]
    clouds = []
    if draws is not None:
        objs = draws[1]
        for i in range(m):
            clouds.append((objs[:, i, 0], objs[:, i, 1]))
            pts.append(np.column_stack([np.quantile(objs[:, i, 0], [0.01, 0.99]), np.quantile(objs[:, i, 1], [0.01, 0.99])]))
    pts = np.vstack(pts)
    span = max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 1.0)
    zoom = [i for i in range(m) if _object_extent(objects[i], clouds[i] if clouds else None, truths[i]) < ZOOM_BELOW * span]
    cols = 0 if not zoom else min(len(zoom), 2 if len(zoom) <= 4 else 3 if len(zoom) <= 12 else 4 if len(zoom) <= 20 else 5)
    rows = -(-len(zoom) // cols) if cols else 0
    lo, hi = pts.min(axis=0) - 0.06 * span, pts.max(axis=0) + 0.06 * span
    lo[1] = min(lo[1], -0.05 * span)
    main_h = 7.5
    main_w = float(np.clip(main_h * (hi[0] - lo[0]) / (hi[1] - lo[1]), 4.5, 10.0))
    # widen the shorter side so that the data fill the panel at an equal aspect
    want = main_w / main_h
    if (hi[0] - lo[0]) / (hi[1] - lo[1]) < want:
        grow = want * (hi[1] - lo[1]) - (hi[0] - lo[0])
        lo[0], hi[0] = lo[0] - grow / 2, hi[0] + grow / 2
    else:
        grow = (hi[0] - lo[0]) / want - (hi[1] - lo[1])
        hi[1] += grow
    fig = Figure(figsize=(main_w + 0.8 + 2.3 * cols, max(main_h + 1.6, 2.3 * rows + 0.6)), layout="constrained")
    if cols:
        left, right = fig.subfigures(1, 2, width_ratios=[main_w + 0.8, 2.3 * cols])
    else:
        left, right = fig, None
    ax = left.add_subplot()
    for i in range(m):
        if clouds:
            _cloud(ax, *clouds[i], colors[i], prob, rng=rng, contour=i not in zoom)
        _draw_footprint(ax, objects[i], colors[i])
        if truths[i] is not None:
            _draw_footprint(ax, truths[i], _TRUTH_COLOR, ls="--", lw=1.0, fill=False)
        fx, fz = _footprint(objects[i]).mean(axis=0)
        ax.annotate(labels[i], (fx, fz), xytext=(4, 3), textcoords="offset points", fontsize=7, color=colors[i])
    _draw_camera(ax, frame, camera, 0.025 * span)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x, right (m)")
    ax.set_ylabel("z, forward (m)")
    ax.grid(alpha=0.3)
    ax.plot([], [], color="0.3", lw=1.5, label="footprint at the MAP")
    if clouds:
        ax.scatter([], [], s=6, color="0.3", label=f"bottom centres, {draws_label}")
        ax.plot([], [], color="0.3", lw=1.2, label=f"{prob:.0%} credible region")
    if any(t is not None for t in truths):
        ax.plot([], [], color=_TRUTH_COLOR, ls="--", lw=1.0, label="truth")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncols=2, fontsize=7, frameon=False)
    ax.set_title(f"top view of the frame ({m} objects)", fontsize=10)
    if cols:
        axes = np.atleast_1d(right.subplots(rows, cols, squeeze=False)).ravel()
        for a, i in zip(axes, zoom):
            _zoom_panel(a, objects[i], clouds[i] if clouds else None, truths[i], colors[i], labels[i], prob, rng)
        for a in axes[len(zoom):]:
            a.set_visible(False)
        right.suptitle("zoom on each object (own scale)", fontsize=9)
    return fig


def _object_extent(obj, cloud, truth) -> float:
    pts = [_footprint(obj)]
    if cloud is not None:
        pts.append(np.column_stack([np.quantile(cloud[0], [0.005, 0.995]), np.quantile(cloud[1], [0.005, 0.995])]))
    if truth is not None:
        pts.append(_footprint(truth))
    p = np.vstack(pts)
    return float(max(np.ptp(p[:, 0]), np.ptp(p[:, 1])))


def _zoom_panel(ax, obj, cloud, truth, color, label, prob, rng) -> None:
    pts = [_footprint(obj)]
    if cloud is not None:
        _cloud(ax, *cloud, color, prob, rng=rng)
        pts.append(np.column_stack([np.quantile(cloud[0], [0.005, 0.995]), np.quantile(cloud[1], [0.005, 0.995])]))
    _draw_footprint(ax, obj, color)
    ax.plot(obj[0], obj[1], "x", color=_MAP_COLOR, ms=5, mew=1.5)
    if truth is not None:
        _draw_footprint(ax, truth, _TRUTH_COLOR, ls="--", lw=1.0, fill=False)
        pts.append(_footprint(truth))
    p = np.vstack(pts)
    c = (p.min(axis=0) + p.max(axis=0)) / 2
    half = 0.55 * max(np.ptp(p[:, 0]), np.ptp(p[:, 1]), 0.5)
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)
    ax.grid(alpha=0.3)
    ax.set_title(f"{label}, {np.hypot(obj[0], obj[1]):.0f} m", fontsize=7, color=color)


def _draw_footprint(ax, obj, color, *, ls="-", lw=1.5, fill=True) -> None:
    ax.add_patch(Polygon(_footprint(obj), closed=True, facecolor=color if fill else "none", alpha=0.35 if fill else 1.0,
                         edgecolor=color, lw=lw, ls=ls))
    if fill:
        ax.add_patch(Polygon(_footprint(obj), closed=True, facecolor="none", edgecolor=color, lw=lw, ls=ls))


def _draw_camera(ax, frame, camera, size: float) -> None:
    """The camera's foot point and its horizontal field of view at the MAP focal length."""
    cx = float(frame.principal_point[0])
    f = camera[C_FOCAL]
    far = 1e4
    ax.plot([0, -far * cx / f], [0, far], color="#555555", lw=0.8, ls=":")
    ax.plot([0, far * (frame.image_width - cx) / f], [0, far], color="#555555", lw=0.8, ls=":",
            label="field of view (MAP µ)")
    tri = np.array([[0, 0], [-0.6, -1.0], [0.6, -1.0]]) * size
    ax.add_patch(Polygon(tri, closed=True, color="k", label="camera"))


_CAMERA_SHOWN = ((C_FOCAL, "focal_length_px", "focal length (px)", 1.0), (C_PITCH, "pitch", "pitch (°)", 180 / np.pi),
                 (C_ROLL, "roll", "roll (°)", 180 / np.pi), (C_HEIGHT, "height_m", "camera height (m)", 1.0))
_TRUTH_KEYS = {"focal_length_px": "focal_length_px", "pitch": "pitch_rad", "roll": "roll_rad", "height_m": "camera_height_m"}


def plot_frame_camera(cams: np.ndarray, camera: np.ndarray, free, *, truth: dict | None = None,
                      draws_label: str = "posterior draws", max_points: int = 3000, rng=0) -> Figure:
    """The shared camera's posterior: marginal histograms (diagonal) and pairs (below) of the free
    ones of focal length, pitch, roll and camera height, with the MAP and the truth when known.

    ``free`` is the (5,) mask of free camera parameters (:attr:`FrameModel.camera_free`);
    ``truth`` the frame's camera ground truth (``focal_length_px``, ``pitch_rad``, ``roll_rad``,
    ``camera_height_m``) or None.
    """
    shown = [s for s in _CAMERA_SHOWN if free[s[0]] and np.ptp(cams[:, s[0]]) > 0]
    n = max(len(shown), 1)
    fig = Figure(figsize=(1.8 * n + 0.6, 1.8 * n + 0.6), layout="constrained")
    axes = fig.subplots(n, n, squeeze=False)
    sel = np.random.default_rng(rng).permutation(len(cams))[:max_points]
    tv = {name: (truth or {}).get(key) for name, key in _TRUTH_KEYS.items()}
    for r, (ia, na, la, ka) in enumerate(shown):
        for c, (ib, nb, lb, kb) in enumerate(shown):
            ax = axes[r, c]
            if c > r:
                ax.set_visible(False)
                continue
            if r == c:
                ax.hist(cams[:, ia] * ka, bins=int(np.clip(np.sqrt(len(cams)), 10, 40)), color=_POST_COLOR, alpha=0.7)
                ax.axvline(camera[ia] * ka, color=_MAP_COLOR, lw=1.5)
                if tv[na] is not None:
                    ax.axvline(tv[na] * ka, color=_TRUTH_COLOR, lw=1.5)
                ax.set_yticks([])
            else:
                ax.scatter(cams[sel, ib] * kb, cams[sel, ia] * ka, s=2, alpha=0.25, color=_POST_COLOR, lw=0)
                ax.plot(camera[ib] * kb, camera[ia] * ka, "x", color=_MAP_COLOR, ms=7, mew=2)
                if tv[na] is not None and tv[nb] is not None:
                    ax.plot(tv[nb] * kb, tv[na] * ka, "*", color=_TRUTH_COLOR, ms=10)
            if r == n - 1:
                ax.set_xlabel(lb, fontsize=8)
            else:
                ax.set_xticklabels([])
            if c == 0 and r > 0:
                ax.set_ylabel(la, fontsize=8)
            elif c > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=7)
    if not shown:
        axes[0, 0].text(0.5, 0.5, "every camera parameter is fixed", ha="center", va="center")
        axes[0, 0].set_axis_off()
    handles = [axes[0, 0].plot([], [], "x", color=_MAP_COLOR, label="MAP")[0]]
    if any(v is not None for v in tv.values()):
        handles.append(axes[0, 0].plot([], [], "*", color=_TRUTH_COLOR, label="truth")[0])
    fig.legend(handles=handles, loc="upper right", fontsize=8)
    fig.suptitle(f"the shared camera ({draws_label})", fontsize=10)
    return fig
