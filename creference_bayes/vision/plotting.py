"""Plots of an estimate (matplotlib): projected boxes, pair plot, rank plots, top view.

Every function takes the result as a ``creference-result/1`` dict (:meth:`Result.to_dict` or a
loaded file) and posterior draws as named (chain, draw) arrays (:func:`draws_from_result`), draws
on the ``ax``/``fig`` it is given or on a new :class:`matplotlib.figure.Figure` (no pyplot state),
and returns the figure.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon, Rectangle, Wedge

from ..core.cost import project_params
from ..core.geometry import Camera, box_vertices
from ..models.params import PARAM_NAMES, PARAM_UNITS

__all__ = ["draws_from_result", "plot_boxes", "plot_pairs", "plot_ranks", "plot_sbc_ranks", "plot_top_view"]

_NAMES = PARAM_NAMES + ("distance_m",)
_UNITS = dict(zip(_NAMES, PARAM_UNITS + ("m",)))
_BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
              (0, 4), (1, 5), (2, 6), (3, 7)]
_MAP_COLOR, _POST_COLOR, _TRUTH_COLOR, _REF_COLOR = "#d62728", "#1f77b4", "#2ca02c", "#ff7f0e"


def draws_from_result(result: dict, idata=None) -> dict[str, np.ndarray] | None:
    """Named (chain, draw) arrays: from an InferenceData when given, else from the draws kept in
    the result's ``posterior.draws``; None when the result has no posterior."""
    if idata is not None:
        return {k: np.asarray(v) for k, v in idata.posterior.data_vars.items()}
    draws = (result.get("posterior") or {}).get("draws")
    if not draws:
        return None
    chain = np.asarray(draws["chain"])
    n_chain = int(chain.max()) + 1
    return {k: np.asarray(v, float).reshape(n_chain, -1) for k, v in draws.items() if k != "chain"}


def _new_axes(ax, figsize):
    if ax is not None:
        return ax.figure, ax
    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.add_subplot()


def _truth(scene) -> dict | None:
    gt = getattr(scene, "ground_truth", None)
    if gt is None:
        return None
    x, y, z = gt.location_m
    return {"x": x, "y": y, "z": z, "yaw": gt.yaw_rad, "focal_length_px": gt.focal_length_px,
            "distance_m": float(np.hypot(x, z))}


def _params(source: dict, scene) -> np.ndarray:
    """(n, 7) parameter vectors from a MAP dict or from draws (arrays under each name). Results
    written before pitch and roll were parameters lack them: they then follow from the scene's
    horizon (a level camera without one)."""
    cols = {k: np.atleast_1d(np.asarray(source[k], float)).ravel() for k in PARAM_NAMES[:5]}
    if "pitch" in source and "roll" in source:
        pitch, roll = (np.atleast_1d(np.asarray(source[k], float)).ravel() for k in ("pitch", "roll"))
    else:
        pitch, roll = Camera.from_scene(scene).pitch_roll(cols["focal_length_px"])
    return np.column_stack([*cols.values(), pitch, roll])


def _project_boxes(scene, params: np.ndarray) -> np.ndarray:
    """(n, 8, 2) pixels of the boxes at (n, 7) parameters, each with its own camera (focal length,
    pitch, roll); NaN where behind the camera."""
    t = scene.target
    uv, depth = project_params(params, box_vertices(t.length, t.width, t.height), scene.principal_point)
    uv[depth <= 0] = np.nan
    return uv


def plot_boxes(result: dict, scene, draws: dict | None = None, *, n_boxes: int = 60,
               zoom: bool = True, ax=None, rng=0) -> Figure:
    """The photo (or a blank canvas of its size) with the annotations, the MAP box and a spread
    of boxes drawn from the posterior, projected with each draw's own focal length.

    Parameters
    ----------
    result : ``creference-result/1`` dict
    scene : the :class:`~creference_bayes.scene.Scene` (camera, target size, annotations)
    draws : named (chain, draw) arrays, or None to draw the MAP only
    n_boxes : posterior boxes to draw (chosen at random with ``rng``)
    zoom : add an inset that zooms on the target (in the corner of the image farthest from it)
    """
    w, h = scene.image_width, scene.image_height
    fig, ax = _new_axes(ax, (9, 9 * h / w + 0.6))
    image = _load_image(scene)
    if image is not None:
        ax.imshow(image, extent=(0, w, h, 0))
    else:
        ax.add_patch(Rectangle((0, 0), w, h, facecolor="#f4f4f4", edgecolor="#999999"))
    if scene.horizon is not None:
        ax.plot(*np.asarray(scene.horizon).T, ls="--", color="#777777", lw=1, label="horizon")
    boxes = np.zeros((0, 8, 2))
    if draws is not None:
        flat = _params(draws, scene)
        pick = np.random.default_rng(rng).choice(len(flat), size=min(n_boxes, len(flat)), replace=False)
        boxes = _project_boxes(scene, flat[pick])
        for box in boxes:
            _draw_box(ax, box, color=_POST_COLOR, alpha=0.15, lw=0.8)
        ax.plot([], [], color=_POST_COLOR, alpha=0.5, label=f"{len(pick)} posterior draws")
    _draw_box(ax, _project_boxes(scene, _params(result["map"], scene))[0], color=_MAP_COLOR, lw=1.8,
              label="MAP")
    for i, c in enumerate(scene.target.corners):
        ax.plot(*c[[1, 0, 2]].T, color="k", lw=0.6, alpha=0.5, label="annotations" if i == 0 else None)
        ax.plot(*c[[0, 3]].T, color="k", lw=0.6, alpha=0.5)
    m = scene.target.median_corners
    ax.plot(*m[[1, 0, 2]].T, "k-", lw=1.5, label="median annotation")
    ax.plot(*m[[0, 3]].T, "k-", lw=1.5)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    if zoom:
        _zoom_inset(ax, scene, result, boxes)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"{result.get('target', '')}: MAP and posterior boxes")
    ax.legend(loc="lower left", fontsize=8, framealpha=0.8)
    return fig


def _zoom_inset(ax, scene, result, boxes) -> None:
    w, h = scene.image_width, scene.image_height
    pts = np.vstack([scene.target.corners.reshape(-1, 2),
                     _project_boxes(scene, _params(result["map"], scene))[0], boxes.reshape(-1, 2)])
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    lo, hi = np.maximum(pts.min(axis=0), 0), np.minimum(pts.max(axis=0), [w, h])
    size = max(hi[0] - lo[0], (hi[1] - lo[1]) * w / h) * 1.15 + 1.0
    c = (lo + hi) / 2
    if size > 0.5 * w:
        return
    x0, y0 = c[0] - size / 2, c[1] - size * h / w / 2
    # put the inset in the image corner farthest from the target
    right, bottom = c[0] < w / 2, c[1] < h / 2
    box = [0.56 if right else 0.02, 0.02 if bottom else 0.56, 0.42, 0.42]
    inset = ax.inset_axes(box)
    for artist in list(ax.lines):
        inset.plot(*artist.get_data(), color=artist.get_color(), lw=artist.get_linewidth(),
                   ls=artist.get_linestyle(), alpha=artist.get_alpha())
    for image in ax.images:
        inset.imshow(image.get_array(), extent=image.get_extent())
    inset.set_xlim(x0, x0 + size)
    inset.set_ylim(y0 + size * h / w, y0)
    inset.set_xticks([])
    inset.set_yticks([])
    inset.set_facecolor("#f4f4f4")
    ax.indicate_inset_zoom(inset, edgecolor="#444444")


def _load_image(scene):
    path = getattr(scene, "image_path", None)
    if path is None or not path.exists():
        return None
    import matplotlib.image as mpimg

    try:
        return mpimg.imread(path)
    except (OSError, ValueError, SyntaxError):
        return None


def _draw_box(ax, uv: np.ndarray, label=None, **style) -> None:
    first = True
    for a, b in _BOX_EDGES:
        if np.all(np.isfinite(uv[[a, b]])):
            ax.plot(*uv[[a, b]].T, label=label if first else None, **style)
            first = False


def plot_pairs(draws: dict, *, names=None, result: dict | None = None, truth: dict | None = None,
               fig=None, max_points: int = 4000, rng=0) -> Figure:
    """Pair plot: marginal histograms on the diagonal, draws below it, with the MAP and the truth.

    Parameters
    ----------
    draws : named (chain, draw) arrays
    names : quantities to show (default: the parameters that were sampled: those that vary, but
        not pitch and roll when the result says they followed from a horizon)
    result : the result dict (for the MAP and the HDI); truth : true values, or None
    """
    if names is None:
        names = _sampled_names(draws, result)
    n = len(names)
    fig = fig or Figure(figsize=(2.1 * n + 0.5, 2.1 * n + 0.5), layout="constrained")
    axes = fig.subplots(n, n, squeeze=False)
    flat = {k: np.asarray(draws[k]).ravel() for k in names}
    sel = np.random.default_rng(rng).permutation(len(flat[names[0]]))[:max_points]
    mp = (result or {}).get("map", {})
    hdi = ((result or {}).get("posterior") or {}).get("hdi", {})
    for i, a in enumerate(names):
        for j, b in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(flat[a], bins=int(np.clip(np.sqrt(len(flat[a])), 10, 40)), color=_POST_COLOR,
                        alpha=0.7)
                if a in hdi:
                    ax.axvspan(*hdi[a], color=_POST_COLOR, alpha=0.12)
                _vline(ax, mp.get(a), _MAP_COLOR)
                _vline(ax, (truth or {}).get(a), _TRUTH_COLOR)
                ax.set_yticks([])
            else:
                ax.scatter(flat[b][sel], flat[a][sel], s=2, alpha=0.25, color=_POST_COLOR, lw=0)
                if a in mp and b in mp:
                    ax.plot(mp[b], mp[a], "x", color=_MAP_COLOR, ms=7, mew=2)
                if truth and truth.get(a) is not None and truth.get(b) is not None:
                    ax.plot(truth[b], truth[a], "*", color=_TRUTH_COLOR, ms=10)
            if i == n - 1:
                ax.set_xlabel(f"{b} ({_UNITS[b]})", fontsize=8)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(f"{a} ({_UNITS[a]})", fontsize=8)
            elif j > 0:
                ax.set_yticklabels([])
            ax.tick_params(labelsize=7)
    handles = [axes[0, 0].plot([], [], "x", color=_MAP_COLOR, label="MAP")[0]]
    if truth:
        handles.append(axes[0, 0].plot([], [], "*", color=_TRUTH_COLOR, label="truth")[0])
    fig.legend(handles=handles, loc="upper right", fontsize=9)
    fig.suptitle("posterior pair plot (shaded: HDI)")
    return fig


def _vline(ax, value, color) -> None:
    if value is not None:
        ax.axvline(value, color=color, lw=1.5)


def _sampled_names(draws: dict, result: dict | None) -> list[str]:
    """Parameters that vary in ``draws``; pitch and roll only when they were free parameters."""
    derived = ((result or {}).get("camera") or {}).get("orientation") not in (None, "free")
    return [k for k in PARAM_NAMES if k in draws and np.ptp(np.asarray(draws[k])) > 0
            and not (derived and k in ("pitch", "roll"))]


def plot_ranks(draws: dict, *, names=None, fig=None, bins: int | None = None,
               result: dict | None = None) -> Figure:
    """Rank plots: for each quantity, the histogram of each chain's (ensemble's) ranks among all
    draws. Well-mixed independent chains give flat, overlapping histograms; a chain stuck apart
    shows up as a slope or a hump (Vehtari et al. 2021). ``bins`` defaults to about 20 draws
    per bin per chain, at most 20 bins."""
    if names is None:
        names = _sampled_names(draws, result) + (["distance_m"] if "distance_m" in draws else [])
    n = len(names)
    cols = min(3, n)
    rows = -(-n // cols)
    fig = fig or Figure(figsize=(4 * cols, 2.6 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, name in zip(axes, names):
        x = np.asarray(draws[name])
        n_chain, n_draw = x.shape
        bins = bins or int(np.clip(n_draw // 20, 4, 20))
        ranks = np.argsort(np.argsort(x.ravel(), kind="stable"), kind="stable").reshape(x.shape)
        edges = np.linspace(0, x.size, bins + 1)
        for c in range(n_chain):
            counts, _ = np.histogram(ranks[c], bins=edges)
            ax.stairs(counts, edges, baseline=None, label=f"ensemble {c}", lw=1.3)
        expected = n_draw / bins
        ax.axhline(expected, color="k", ls=":", lw=1)
        ax.set_title(name, fontsize=10)
        ax.set_xticks([])
        ax.set_ylim(0, 2 * expected)
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7, loc="lower left", ncols=2)
    fig.suptitle("rank plots per ensemble (dotted: uniform)")
    return fig


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


def _hdr_levels(x, z, prob, bins=40):
    """Smoothed histogram of (x, z) and the density level enclosing ``prob`` of the draws.

    The grid spans the central 99 % of the draws (padded), so that a few far draws do not leave the
    cloud itself a handful of coarse cells; draws outside it count in the total.
    """
    from scipy.ndimage import gaussian_filter

    x, z = np.asarray(x, float), np.asarray(z, float)
    rng = []
    for v in (x, z):
        lo, hi = np.quantile(v, [0.005, 0.995])
        pad = 0.3 * max(hi - lo, 1e-9)
        rng.append([lo - pad, hi + pad])
    H, xe, ze = np.histogram2d(x, z, bins=bins, range=rng)
    H = gaussian_filter(H, 1.5)
    flat = np.sort(H.ravel())[::-1]
    cum = np.cumsum(flat) / max(len(x), 1)
    level = flat[min(np.searchsorted(cum, prob), len(flat) - 1)]
    return H, xe, ze, level


def plot_top_view(result: dict, draws: dict | None = None, *, scene=None, truth: dict | None = None,
                  ax=None, max_points: int = 4000, rng=0) -> Figure:
    """The ground plane seen from above (X right, Z forward from the camera's foot point): the
    posterior cloud and its credible region (at the result's HDI probability), the MAP, the
    truth, the camera and its field of view, and the bounds the reference pairs imply.

    Reference bounds come from the result's ``references.pairs`` (x_bounds/z_bounds rectangles,
    or distance_bounds rings when the constraints are on the ground distance); without them the
    plot simply has none.
    """
    fig, ax = _new_axes(ax, (7.5, 7.5))
    mp = result["map"]
    prob = ((result.get("posterior") or {}).get("hdi") or {}).get("prob", 0.9)
    pts = [np.array([[0.0, 0.0], [mp["x"], mp["z"]]])]
    for pair in (result.get("references") or {}).get("pairs", []) or []:
        if not pair.get("used", True):
            continue
        if "x_bounds" in pair and "z_bounds" in pair and (result["references"].get("on", "xz") == "xz"):
            (x0, x1), (z0, z1) = pair["x_bounds"], pair["z_bounds"]
            ax.add_patch(Rectangle((x0, z0), x1 - x0, z1 - z0, facecolor=_REF_COLOR, alpha=0.08,
                                   edgecolor=_REF_COLOR, lw=0.8))
            pts.append(np.array([[x0, z0], [x1, z1]]))
        elif "distance_bounds" in pair:
            d0, d1 = pair["distance_bounds"]
            ax.add_patch(Wedge((0, 0), d1, 0, 180, width=d1 - d0, facecolor=_REF_COLOR, alpha=0.08,
                               edgecolor=_REF_COLOR, lw=0.8))
            pts.append(np.array([[-d1, 0.0], [d1, d1]]))
    if len(pts) > 1:
        ax.add_patch(Rectangle((np.nan, np.nan), 0, 0, facecolor=_REF_COLOR, alpha=0.3,
                               label=f"bounds from {len(pts) - 1} reference pairs"))
    if draws is not None:
        x, z = np.asarray(draws["x"]).ravel(), np.asarray(draws["z"]).ravel()
        sel = np.random.default_rng(rng).permutation(len(x))[:max_points]
        ax.scatter(x[sel], z[sel], s=3, alpha=0.25, color=_POST_COLOR, lw=0, label="posterior draws")
        H, xe, ze, level = _hdr_levels(x, z, prob)
        ax.contour((xe[:-1] + xe[1:]) / 2, (ze[:-1] + ze[1:]) / 2, H.T, levels=[level],
                   colors=[_POST_COLOR], linewidths=1.5)
        ax.plot([], [], color=_POST_COLOR, lw=1.5, label=f"{prob:.0%} credible region")
        pts.append(np.column_stack([np.quantile(x, [0.005, 0.995]), np.quantile(z, [0.005, 0.995])]))
    ax.plot(mp["x"], mp["z"], "x", color=_MAP_COLOR, ms=10, mew=2.5, label="MAP")
    truth = truth if truth is not None else _truth(scene)
    if truth is not None:
        ax.plot(truth["x"], truth["z"], "*", color=_TRUTH_COLOR, ms=14, label="truth")
        pts.append(np.array([[truth["x"], truth["z"]]]))
    pts = np.vstack(pts)
    span = max(np.ptp(pts[:, 0]), np.ptp(pts[:, 1]), 1e-3)
    lo, hi = pts.min(axis=0) - 0.08 * span, pts.max(axis=0) + 0.08 * span
    _draw_camera(ax, mp, scene, 0.08 * span)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(min(lo[1], -0.05 * span), hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x, right (m)")
    ax.set_ylabel("z, forward (m)")
    ax.set_title("top view of the ground plane")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8, framealpha=0.85)
    if draws is not None:
        _zoom_on_cloud(ax, x, z, (xe, ze, H, level), mp, truth, span)
    return fig


#: The top view gets an inset on the posterior cloud when the cloud's 99 % box is smaller than
#: this share of the plotted span (at the plot's scale its credible region is then a smudge).
ZOOM_BELOW = 0.2


def _zoom_on_cloud(ax, x, z, region, mp: dict, truth: dict | None, span: float) -> None:
    """An inset magnifying the posterior cloud, its credible region, the MAP and the truth, in the
    corner of the plot farthest from the cloud (not the legend's)."""
    xe, ze, H, level = region
    lo = np.array([np.quantile(x, 0.005), np.quantile(z, 0.005)])
    hi = np.array([np.quantile(x, 0.995), np.quantile(z, 0.995)])
    if truth is not None and np.all(np.abs(np.array([truth["x"], truth["z"]]) - (lo + hi) / 2) < span * ZOOM_BELOW):
        lo = np.minimum(lo, [truth["x"], truth["z"]])
        hi = np.maximum(hi, [truth["x"], truth["z"]])
    size = max(float(np.max(hi - lo)), 1e-6)
    if size >= ZOOM_BELOW * span:
        return
    centre = (lo + hi) / 2
    half = 0.6 * size
    # where the cloud sits in the axes (fractions), and the free corner farthest from it
    to_axes = ax.transAxes.inverted().transform
    cx, cy = to_axes(ax.transData.transform(centre))
    # lower right, upper right, lower left (upper left holds the legend): the first the cloud is not in
    free = [c for c in ((0.53, 0.04), (0.53, 0.53), (0.04, 0.04))
            if not (c[0] - 0.05 < cx < c[0] + 0.48 and c[1] - 0.05 < cy < c[1] + 0.48)]
    ox, oy = free[0] if free else (0.53, 0.04)
    inset = ax.inset_axes([ox, oy, 0.43, 0.43])
    sel = np.abs(x - centre[0]) < 2 * half
    sel &= np.abs(z - centre[1]) < 2 * half
    inset.scatter(x[sel][:4000], z[sel][:4000], s=3, alpha=0.25, color=_POST_COLOR, lw=0)
    inset.contour((xe[:-1] + xe[1:]) / 2, (ze[:-1] + ze[1:]) / 2, H.T, levels=[level],
                  colors=[_POST_COLOR], linewidths=1.5)
    inset.plot(mp["x"], mp["z"], "x", color=_MAP_COLOR, ms=9, mew=2.2)
    if truth is not None:
        inset.plot(truth["x"], truth["z"], "*", color=_TRUTH_COLOR, ms=12)
    inset.set_xlim(centre[0] - half, centre[0] + half)
    inset.set_ylim(centre[1] - half, centre[1] + half)
    inset.set_aspect("equal")
    inset.tick_params(labelsize=7)
    inset.grid(alpha=0.3)
    inset.set_title(f"zoom ×{span / (2 * half):.0f}", fontsize=8)
    ax.indicate_inset_zoom(inset, edgecolor="0.4")


def _draw_camera(ax, mp: dict, scene, size: float) -> None:
    """The camera's foot point and its horizontal field of view at the MAP focal length."""
    if scene is not None:
        cx = float(scene.principal_point[0])
        left, right = -cx, scene.image_width - cx
        f = mp["focal_length_px"]
        far = 1e4
        ax.plot([0, far * left / f], [0, far], color="#555555", lw=0.8, ls=":")
        ax.plot([0, far * right / f], [0, far], color="#555555", lw=0.8, ls=":",
                label="field of view (MAP µ, level)")
    tri = np.array([[0, 0], [-0.6, -1.0], [0.6, -1.0]]) * size
    ax.add_patch(Polygon(tri, closed=True, color="k", label="camera"))
