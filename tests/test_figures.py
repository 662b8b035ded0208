"""The figures of a scene of 1 to 60 objects (issue 36): labels that do not overlap, strong and
distinct object styles, titles inside the figure, capped sizes, a legend that names every mark.

The figures are drawn at the simulated truth with synthetic draws around it (no optimiser, no
sampler): what is checked is the drawing, not where an estimate happens to stop.
"""

import itertools

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.text import Text

from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.io.scene import parse_scene
from creference_bayes.vision import plotting as ff


def simulate_frame(seed, n_objects):
    """A simulated street scene of ``n_objects`` objects whose sizes come from their classes' priors."""
    return simulate_scene(seed, setting="street", n_objects=n_objects, sizes="prior")


def _truth_state(scene):
    g = scene["ground_truth"]
    cam = np.array([g["focal_length_px"], g["pitch_rad"], g["roll_rad"], g["camera_height_m"], 1.0])
    objs = np.array([[t["ground_truth"]["location_m"][0], t["ground_truth"]["location_m"][2], t["ground_truth"]["yaw_rad"],
                      *(t["ground_truth"]["dimensions_m"][k] for k in ("length", "width", "height")),
                      t["ground_truth"].get("ground_m", 0.0)] for t in scene["targets"]])
    return cam, objs


def _draws(cam, objs, n=400, seed=0):
    """Draws around the state: depth spread growing with the distance, as a frame's posterior does."""
    rng = np.random.default_rng(seed)
    cams = cam + rng.normal(0, 1, (n, 5)) * [15.0, 0.004, 0.004, 0.03, 0.0]
    o = np.repeat(objs[None], n, axis=0)
    dist = np.hypot(objs[:, 0], objs[:, 1])
    scale = rng.normal(0, 1, (n, len(objs))) * 0.04 * dist / 10
    o[:, :, 0] *= 1 + scale
    o[:, :, 1] *= 1 + scale
    o[:, :, 2] += rng.normal(0, 0.05, (n, len(objs)))
    return cams, o


@pytest.fixture(scope="module", params=[1, 3, 10, 60])
def drawn(request):
    """A simulated street scene of 1, 3, 10 or 60 objects and its figures."""
    m = request.param
    scene = simulate_frame(7, n_objects=m)
    frame = parse_scene(scene)
    assert len(frame.targets) == m
    cam, objs = _truth_state(scene)
    draws = _draws(cam, objs)
    figs = {"boxes": ff.plot_boxes(frame, cam, objs, draws),
            "top": ff.plot_top_view(frame, cam, objs, draws),
            "zooms": ff.plot_zooms(frame, cam, objs, draws),
            "pairs": ff.plot_pairs(ff.posterior_columns(frame, None, cam, objs, draws)),
            "ranks": ff.plot_ranks(ff.posterior_columns(frame, None, cam, objs, draws, distance=True),
                                   np.arange(len(draws[0])) % 4)}
    for fig in figs.values():
        if not isinstance(fig.canvas, FigureCanvasAgg):
            FigureCanvasAgg(fig)
        fig.draw_without_rendering()
    return {"m": m, "frame": frame, "cam": cam, "objs": objs, "draws": draws, "figs": figs}


def _main_axes(fig, xlabel):
    return next(a for a in fig.get_axes() if a.get_xlabel() == xlabel)


def _labels(ax):
    return [t for t in ax.texts if t.get_visible()]


def _overlap(a, b) -> float:
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return max(w, 0.0) * max(h, 0.0)


def _luminance(color) -> float:
    """WCAG relative luminance (0 black, 1 white)."""
    c = np.asarray(to_rgb(color))
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return float(lin @ [0.2126, 0.7152, 0.0722])


def _lab(color) -> np.ndarray:
    c = np.asarray(to_rgb(color))
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ lin
    f = np.cbrt(xyz / [0.95047, 1.0, 1.08883])
    f = np.where(xyz / [0.95047, 1.0, 1.08883] > (6 / 29) ** 3, f, xyz / [0.95047, 1.0, 1.08883] / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


@pytest.mark.parametrize("which, xlabel", [("boxes", "u (px)"), ("top", "x, right (m)")])
def test_no_two_labels_overlap_and_each_lies_inside_its_panel(drawn, which, xlabel):
    fig = drawn["figs"][which]
    ax = _main_axes(fig, xlabel)
    renderer = fig.canvas.get_renderer()
    labels = _labels(ax)
    assert len(labels) == drawn["m"]
    boxes = [Text.get_window_extent(t, renderer) for t in labels]  # the text, not its leader line
    frame = ax.get_window_extent(renderer)
    for a, b in itertools.combinations(range(len(boxes)), 2):
        assert _overlap(boxes[a], boxes[b]) < 1.0, (labels[a].get_text(), labels[b].get_text())
    for t, b in zip(labels, boxes):
        assert frame.x0 - 1 <= b.x0 and b.x1 <= frame.x1 + 1 and frame.y0 - 1 <= b.y0 and b.y1 <= frame.y1 + 1, t.get_text()


def test_labels_name_every_object_with_its_class_or_a_key_does(drawn):
    m, frame = drawn["m"], drawn["frame"]
    ax = _main_axes(drawn["figs"]["boxes"], "u (px)")
    texts = [t.get_text() for t in _labels(ax)]
    keys = [lg for lg in drawn["figs"]["boxes"].legends if lg.get_title().get_text() == "objects"]
    if m <= ff.FULL_LABELS_UP_TO:
        assert texts == ff.object_labels(frame) and not keys
    else:  # the ids on the image, the classes in the key below it
        assert texts == ff.short_labels(frame)
        assert [t.get_text() for t in keys[0].get_texts()] == ff.object_labels(frame)


def test_object_colours_are_strong_and_distinct_and_styles_unique():
    styles = ff.object_styles(66)
    assert len({(s["color"], str(s["ls"])) for s in styles}) == 66
    first = [s["color"] for s in styles[:len(ff.OBJECT_COLORS)]]
    assert len(set(first)) == len(first) == len(ff.OBJECT_COLORS) >= 10
    for c in ff.OBJECT_COLORS:
        assert _luminance(c) <= 0.3, c  # contrast ≥ 3:1 against white: no pale orange or yellow
        assert _luminance(c) >= 0.04, c  # and not black (the truth's)
    for a, b in itertools.combinations(ff.OBJECT_COLORS, 2):
        assert np.linalg.norm(_lab(a) - _lab(b)) >= 20, (a, b)
    # a pale colour fails the check (the test's own sanity)
    assert _luminance("#ffbb78") > 0.3 and _luminance("#bcbd22") > 0.3


def test_every_object_is_drawn_in_its_own_style(drawn):
    m = drawn["m"]
    ax = _main_axes(drawn["figs"]["boxes"], "u (px)")
    styles = ff.object_styles(m)
    maps = [c for c in ax.collections if isinstance(c, LineCollection) and c.get_gid() == "map box"]
    assert len(maps) == m
    used = {(tuple(np.round(c.get_color()[0][:3], 3)), str(c.get_linestyle()[0])) for c in maps}
    assert len(used) == m  # no two objects look alike
    for t, s in zip(_labels(ax), styles):
        assert t.get_color() == s["color"] and _luminance(t.get_color()) <= 0.3


def test_posterior_boxes_are_visible(drawn):
    ax = _main_axes(drawn["figs"]["boxes"], "u (px)")
    spread = [c for c in ax.collections if isinstance(c, LineCollection) and c.get_gid() == "draw boxes"]
    assert len(spread) == drawn["m"]
    for c in spread:
        assert c.get_alpha() >= 0.25 and c.get_linewidth()[0] >= 0.8


def test_titles_and_legends_lie_inside_the_figure(drawn):
    for name, fig in drawn["figs"].items():
        renderer = fig.canvas.get_renderer()
        whole = fig.bbox
        items = [a.title for a in fig.get_axes() if a.get_visible() and a.get_title()]
        items += [f._suptitle for f in [fig, *fig.subfigs] if f._suptitle is not None]
        items += list(fig.legends) + [a.get_legend() for a in fig.get_axes() if a.get_legend() is not None]
        assert items, name
        for it in items:
            b = it.get_window_extent(renderer)
            assert whole.x0 - 1 <= b.x0 and b.x1 <= whole.x1 + 1 and whole.y0 - 1 <= b.y0 and b.y1 <= whole.y1 + 1, \
                (name, getattr(it, "get_text", lambda: "legend")())


def test_figure_sizes_are_capped(drawn):
    for name, fig in drawn["figs"].items():
        w, h = fig.get_size_inches()
        assert w <= ff.MAX_FIGURE_IN + 1 and h <= ff.MAX_FIGURE_IN + 1, (name, w, h)
    top = drawn["figs"]["top"]
    w, h = top.get_size_inches()
    assert w <= 18 and h <= 12  # the top view at most about 2000 × 1300 px at the default 110 dpi
    zoom = ff.zoom_indices(drawn["frame"], drawn["objs"], drawn["draws"])
    panels = [a for a in top.get_axes() if a.get_visible() and a.get_xlabel() != "x, right (m)"]
    assert len(panels) == (len(zoom) if len(zoom) <= ff.MAX_ZOOM_PANELS else 0)
    zooms = [a for a in drawn["figs"]["zooms"].get_axes() if a.get_visible()]
    assert len(zooms) == (len(zoom) or drawn["m"])


def test_the_legend_names_the_zoom_marker_and_the_field_of_view_in_plain_words(drawn):
    top = drawn["figs"]["top"]
    ax = _main_axes(top, "x, right (m)")
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "field of view (at the MAP focal length)" in texts
    assert not any("µ" in t for fig in drawn["figs"].values() for lg in _all_legends(fig) for t in
                   (x.get_text() for x in lg.get_texts()))
    panels = [a for a in top.get_axes() if a.get_visible() and a is not ax]
    if panels:
        assert "bottom centre at the MAP (zoom panels)" in texts
        handle = ax.get_legend().legend_handles[texts.index("bottom centre at the MAP (zoom panels)")]
        marked = [ln for ln in panels[0].lines if ln.get_marker() == "x"]
        assert marked and handle.get_marker() == "x" and handle.get_color() == marked[0].get_color()
    zl = [t.get_text() for lg in drawn["figs"]["zooms"].legends for t in lg.get_texts()]
    assert "bottom centre at the MAP" in zl


def _all_legends(fig):
    return list(fig.legends) + [lg for sf in fig.subfigs for lg in sf.legends] + \
        [a.get_legend() for a in fig.get_axes() if a.get_legend() is not None]


def test_a_figure_can_be_drawn_on_given_axes():
    from matplotlib.figure import Figure

    scene = simulate_frame(3, n_objects=4)
    frame = parse_scene(scene)
    cam, objs = _truth_state(scene)
    fig = Figure(figsize=(8, 4))
    ax = fig.add_subplot()
    assert ff.plot_boxes(frame, cam, objs, None, ax=ax) is fig
    assert [t.get_text() for t in _labels(ax)] == ff.object_labels(frame)
    other = Figure()
    assert ff.plot_top_view(frame, cam, objs, _draws(cam, objs), fig=other) is other
    given = Figure()
    assert ff.plot_pairs(ff.posterior_columns(frame, None, cam, objs, _draws(cam, objs)), fig=given) is given
