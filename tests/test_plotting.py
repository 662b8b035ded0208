"""Plots (Agg): what they draw, and the ``creference plot`` command."""

import io
import json

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from creference_bayes.vision import plotting
from creference_bayes.cli.main import main
from creference_bayes.pipeline import estimate


@pytest.fixture(scope="module")
def noise_free(tmp_path_factory):
    """A noise-free scene written to disk, and its estimate (small posterior run)."""
    import warnings

    from creference_bayes.io.scene import load_scene
    from creference_bayes.bench.simulate import simulate_scene

    path = tmp_path_factory.mktemp("scene") / "scene.json"
    path.write_text(json.dumps(simulate_scene(np.random.default_rng(21), tier="none")))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(path)
    result = estimate(scene, seed=0, sampling={"min_ess": 200, "tau_multiple": 20})
    return path, scene, result


def test_map_box_passes_through_the_annotated_corners(noise_free):
    _, scene, result = noise_free
    d = result.to_dict()
    fig = plotting.plot_boxes(d, scene, plotting.draws_from_result(d), zoom=False)
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    red = [ln for ln in ax.lines if ln.get_color() == plotting._MAP_COLOR]
    assert len(red) == 12  # the box's edges
    ends = np.vstack([np.column_stack(ln.get_data()) for ln in red])
    for corner in scene.target.median_corners:
        assert np.min(np.linalg.norm(ends - corner, axis=1)) < 1.0
    blue = [ln for ln in ax.lines if ln.get_color() == plotting._POST_COLOR]
    assert len(blue) >= 12 * 10


def test_pair_and_rank_plots(noise_free):
    _, _, result = noise_free
    d = result.to_dict()
    draws = plotting.draws_from_result(d)
    assert draws["x"].shape[0] == result.diagnostics.n_ensembles
    fig = plotting.plot_pairs(draws, result=d, truth={"x": 1.0, "z": 5.0})
    visible = [a for a in fig.axes if a.get_visible()]
    assert len(visible) == 5 * 6 // 2  # lower triangle of the five parameters
    fig = plotting.plot_ranks(draws, result=d)
    assert len([a for a in fig.axes if a.get_visible()]) == 6
    # each ensemble's rank histogram sums to its number of draws
    ax = fig.axes[0]
    counts = [s.get_data().values.sum() for s in ax.patches]
    assert counts == [draws["x"].shape[1]] * draws["x"].shape[0]


def test_top_view_draws_reference_bounds_and_camera():
    result = {"map": {"x": 1.0, "y": 1.5, "z": 6.0, "yaw": 0.2, "focal_length_px": 1500.0},
              "references": {"on": "xz", "pairs": [
                  {"used": True, "x_bounds": [0.5, 1.5], "z_bounds": [5.0, 7.0]},
                  {"used": False, "reason": "parallel"},
                  {"used": True, "x_bounds": [0.8, 1.2], "z_bounds": [5.5, 6.5]}]}}
    rng = np.random.default_rng(0)
    draws = {"x": rng.normal(1.0, 0.1, (4, 200)), "z": rng.normal(6.0, 0.3, (4, 200))}
    fig = plotting.plot_top_view(result, draws, truth={"x": 1.1, "z": 6.2})
    ax = fig.axes[0]
    rects = [p for p in ax.patches if isinstance(p, Rectangle) and np.isfinite(p.get_x())]
    assert sorted((r.get_x(), r.get_y()) for r in rects) == [(0.5, 5.0), (0.8, 5.5)]
    lo, hi = ax.get_ylim()
    assert lo < 0 < hi  # the camera (origin) is in view
    fig.savefig(io.BytesIO(), format="png")


def test_plot_command_writes_figures(noise_free, tmp_path):
    scene_path, _, result = noise_free
    out = tmp_path / "r.json"
    result.to_json(out)
    figs = tmp_path / "figs"
    assert main(["plot", str(out), "--scene", str(scene_path), "--out", str(figs), "--quiet",
                 "--dpi", "30"]) == 0
    assert sorted(p.name for p in figs.iterdir()) == ["boxes.png", "pairs.png", "ranks.png", "top_view.png"]
    assert all(p.stat().st_size > 3_000 for p in figs.iterdir())
    # the scene is found next to the result when it is not given
    from creference_bayes.cli.plot import _find_scene

    (tmp_path / "scene.json").write_text(scene_path.read_text())
    found = _find_scene(json.loads(out.read_text()), out, None)
    assert found.source == tmp_path / "scene.json"


def test_plot_command_errors(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something-else"}))
    assert main(["plot", str(bad)]) == 2
    assert "format" in capsys.readouterr().err
    r = tmp_path / "r.json"
    r.write_text(json.dumps({"format": "creference-result/1", "scene": "nowhere.json",
                             "map": {"x": 0, "y": 1, "z": 5, "yaw": 0, "focal_length_px": 1000}}))
    assert main(["plot", str(r)]) == 2
    assert "nowhere.json" in capsys.readouterr().err


def test_boxes_without_a_horizon_are_drawn_with_each_draws_camera():
    """Without a horizon the box must be projected with the estimate's own pitch and roll (not a
    level camera): the MAP box lands on the annotated corners."""
    import warnings
    from dataclasses import replace

    import creference_bayes as cb
    from creference_bayes.bench.simulate import simulate_scene
    from creference_bayes.core.geometry import box_vertices, dimension_corners

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = cb.parse_scene(simulate_scene(3, tier="low", roll_deg=5.0))
    scene = replace(scene, horizon=None)
    d = cb.estimate(scene, seed=0, posterior=False).to_dict()
    box = plotting._project_boxes(scene, plotting._params(d["map"], scene))[0]
    t = scene.target
    c = dimension_corners(t.length, t.width, t.height, d["handedness"])
    verts = box_vertices(t.length, t.width, t.height)
    idx = [int(np.argmin(np.linalg.norm(verts - v, axis=1))) for v in c]  # the annotated corners' vertices
    assert np.median(np.linalg.norm(box[idx] - t.median_corners, axis=1)) < 5.0


def test_top_view_zooms_on_a_cloud_too_small_to_see():
    """A 5 cm cloud 20 m away is a dot at the plot's scale: an inset shows its credible region."""
    result = {"map": {"x": 3.0, "y": 1.5, "z": 20.0, "yaw": 0.2, "focal_length_px": 1500.0},
              "posterior": {"hdi": {"prob": 0.9}}}
    rng = np.random.default_rng(1)
    small = {"x": rng.normal(3.0, 0.02, (4, 300)), "z": rng.normal(20.0, 0.05, (4, 300))}
    fig = plotting.plot_top_view(result, small, truth={"x": 3.01, "z": 20.03})
    main_ax, = fig.axes
    insets = main_ax.child_axes
    assert len(insets) == 1
    (x0, x1), (z0, z1) = insets[0].get_xlim(), insets[0].get_ylim()
    assert x0 < 2.95 and x1 > 3.05 and z0 < 19.9 and z1 > 20.1  # the cloud's 99 % box
    assert x1 - x0 < 0.1 * np.ptp(main_ax.get_xlim())  # magnified at least ten times
    assert insets[0].collections  # the draws and the credible region's contour
    wide = {"x": rng.normal(3.0, 3.0, (4, 300)), "z": rng.normal(20.0, 6.0, (4, 300))}
    assert plotting.plot_top_view(result, wide).axes[0].child_axes == []  # visible as it is: no inset


@pytest.mark.parametrize("kind", ["evaluate", "labels"])
def test_reliability_bin_counts_overlap_no_tick_label(kind):
    """Issue 36: the bins' counts were written beside the points and ran into the tick labels when
    a point sat near an axis. They now stand above the panel, one per bin at the bin's centre."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from creference_bayes.evaluation.reliability import brier_score, reliability_table
    from creference_bayes.vision.label_figures import quality_figure, reliability_figure

    rng = np.random.default_rng(0)
    # predictions in every bin, with points on both axes' ends (share 0 at p ≈ 0.03, 1 at p ≈ 0.97)
    p = np.concatenate([np.full(111, 0.03), rng.uniform(0.1, 0.9, 300), np.full(7, 0.97)])
    y = np.concatenate([np.zeros(111, bool), rng.random(300) < 0.5, np.ones(7, bool)])
    rows = reliability_table(p, y)
    if kind == "evaluate":
        fig = reliability_figure({t: {"rows": rows, "brier": brier_score(p, y), "count": len(p)} for t in (0.5, 0.7)})
        panels = fig.axes[:2]
    else:
        fig = quality_figure(p, 0.5, reliability={0.7: rows})
        panels = fig.axes[1:2]
    FigureCanvasAgg(fig)
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    for ax in panels:
        (top,) = ax.child_axes
        counts = [t for t in top.xaxis.get_ticklabels() if t.get_visible() and t.get_text()]
        assert [t.get_text() for t in counts] == [str(r["count"]) for r in rows]
        others = [t for t in ax.xaxis.get_ticklabels() + ax.yaxis.get_ticklabels() if t.get_visible() and t.get_text()]
        others += [ax.title, ax.xaxis.label, ax.yaxis.label]
        frame = ax.get_window_extent(renderer)
        boxes = [t.get_window_extent(renderer) for t in counts]
        for b in boxes:
            assert b.y0 >= frame.y1  # above the panel: clear of the data
            for o in others:
                ob = o.get_window_extent(renderer)
                assert min(b.x1, ob.x1) <= max(b.x0, ob.x0) or min(b.y1, ob.y1) <= max(b.y0, ob.y0), o.get_text()
        for a, b in zip(boxes, boxes[1:]):
            assert a.x1 <= b.x0  # and clear of each other
