"""Figures of an estimate (Agg) and the ``creference plot`` command, for one object and for several:
what the figures draw, where their draws come from, and the command's files and messages."""

import copy
import json

import math

import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

import creference_bayes as cb
from creference_bayes.cli.main import main
from creference_bayes.pipeline import map_state, rebuild_model, result_draws
from creference_bayes.vision import plotting
from conftest import truth_scene


def _write(path, data):
    path.write_text(json.dumps(data))
    return path


@pytest.fixture(scope="module")
def one(tmp_path_factory):
    """A one-target scene (its truth known) on disk and its estimate with a small posterior run."""
    folder = tmp_path_factory.mktemp("one")
    scene_dict, truth = truth_scene(5, m=1, noise_px=1.0, n_annotations=4, n_refs=2, horizon="sd")
    path = _write(folder / "scene.json", scene_dict)
    scene = cb.load_scene(path)
    result = cb.estimate(scene, seed=0, sampling={"min_ess": 50})
    _write(folder / "result.json", result.to_dict())
    return folder, scene, result, truth


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """A scene of three objects of class-prior sizes, on disk, and its MAP-only result beside it."""
    folder = tmp_path_factory.mktemp("three")
    scene_dict, truth = truth_scene(1, m=3, sizes_known=False, noise_px=1.0, n_annotations=3)
    path = _write(folder / "scene.json", scene_dict)
    scene = cb.load_scene(path)
    result = cb.estimate(scene, seed=0, posterior=False)
    _write(folder / "result.json", result.to_dict())
    return folder, scene, result.to_dict(), truth


def _map_boxes(ax):
    return [c for c in ax.collections if isinstance(c, LineCollection) and c.get_gid() == "map box"]


@pytest.mark.parametrize("which", ["one", "three"])
def test_map_box_bottom_holds_the_models_projected_corners(which, request):
    """The figures' boxes (models/boxes) and the likelihood's projection (Model.project) are written
    separately: each MAP box drawn must hold the three ground corners of the model's projection."""
    folder, scene, result, _ = request.getfixturevalue(which)
    d = result if isinstance(result, dict) else result.to_dict()
    model = rebuild_model(d, scene)
    cam, objs = map_state(d)
    uv, _ = model.project(model.complete_camera(cam[None]), objs[None])
    fig = plotting.plot_boxes(scene, cam, objs, None, zoom=False)
    boxes = _map_boxes(fig.axes[0])
    assert len(boxes) == len(objs)
    for i, col in enumerate(boxes):
        ends = np.vstack(col.get_segments())
        for corner in uv[0, i, :3]:
            assert np.min(np.hypot(*(ends - corner).T)) < 1e-6


def test_boxes_show_the_annotations_and_each_objects_draws(three):
    folder, scene, d, _ = three
    cam, objs = map_state(d)
    cams, draws, source = result_draws(d, rebuild_model(d, scene), n=200)
    assert source == "laplace"
    ax = plotting.plot_boxes(scene, cam, objs, (cams, draws), zoom=False).axes[0]
    by_gid = {}
    for c in ax.collections:
        by_gid.setdefault(c.get_gid(), []).append(c)
    annotations = sum(len(t.dimension_lines) for t in scene.targets)
    assert len(by_gid["annotations"][0].get_segments()) == 3 * annotations  # three lines a set
    assert len(by_gid["median annotations"][0].get_segments()) == 3 * len(scene.targets)
    assert len(by_gid["draw boxes"]) == len(scene.targets)
    assert all(c.get_alpha() >= 0.25 and c.get_linewidth()[0] >= 0.8 for c in by_gid["draw boxes"])


def test_a_small_object_gets_a_zoom_inset_on_the_photo():
    far, state = truth_scene(0, m=1, depth=(28.0, 30.0), n_annotations=3, noise_px=2.0)
    scene = cb.parse_scene(far)
    ax = plotting.plot_boxes(scene, state["camera"], state["objects"]).axes[0]
    (inset,) = ax.child_axes
    (x0, x1), (y1, y0) = inset.get_xlim(), inset.get_ylim()
    pts = scene.targets[0].corners.reshape(-1, 2)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    assert x0 <= lo[0] and hi[0] <= x1 and y0 <= lo[1] and hi[1] <= y1  # every annotation inside
    assert (x1 - x0) * plotting.PHOTO_ZOOM_AT_LEAST <= 0.42 * scene.image_width + 1e-6  # magnified enough
    near, state = truth_scene(0, m=1, depth=(4.0, 4.5))
    assert plotting.plot_boxes(cb.parse_scene(near), state["camera"], state["objects"]).axes[0].child_axes == []


def test_pairs_show_what_varies_with_the_map_truth_and_hdi(one):
    folder, scene, result, truth = one
    d = result.to_dict()
    cams, objs = result.draws.cameras.reshape(-1, 5), result.draws.objects.reshape(-1, 1, 7)
    cam, mp = map_state(d)
    cols = plotting.posterior_columns(scene, d, cam, mp, (cams, objs))
    names = [c.name for c in cols]
    free = [f"camera.{k}" for k in d["camera"]["free"] if k != "ref_scale"]
    assert names[:len(free)] == free  # the camera's free quantities first (a horizon with an sd: pitch, roll free)
    assert names[len(free):] == [f"{scene.targets[0].id}.{k}" for k in ("x", "z", "yaw")]  # known sizes
    x = next(c for c in cols if c.name.endswith(".x"))
    assert x.truth == pytest.approx(truth["objects"][0, 0])
    assert x.hdi == tuple(d["objects"][0]["posterior"]["hdi"]["x"])
    fig = plotting.plot_pairs(cols)
    assert len([a for a in fig.axes if a.get_visible()]) == len(cols) * (len(cols) + 1) // 2


def test_kept_draws_know_their_chains_and_ranks_count_every_draw(one):
    folder, scene, result, _ = one
    d = result.to_dict()
    chains = plotting.kept_chains(d)
    C, N = result.draws.cameras.shape[:2]
    kept = np.asarray(d["draws"]["camera"]["focal_length_px"])
    # each kept draw is a draw of the chain it is said to come from
    for k in range(0, len(kept), 37):
        row = result.draws.cameras[chains[k], :, 0]
        assert np.min(np.abs(row - kept[k])) < 1e-4
    assert set(chains) == set(range(C))
    cams, objs, _ = result_draws(d, result.model)
    cols = plotting.posterior_columns(scene, d, *map_state(d), (cams, objs), distance=True)
    fig = plotting.plot_ranks(cols, chains)
    counts = [s.get_data().values.sum() for s in fig.axes[0].patches]
    assert counts == [np.sum(chains == c) for c in range(C)]


def test_stored_draws_are_used_before_the_laplace_approximation(three):
    folder, scene, d, _ = three
    model = rebuild_model(d, scene)
    _, _, source = result_draws(d, model, n=50)
    assert source == "laplace"
    cams = np.tile([700.0, 0.01, 0.0, 1.6, 0.5], (7, 1))
    objs = np.tile(map_state(d)[1], (7, 1, 1))
    columns = lambda a: {k: a[:, j].tolist() for j, k in enumerate(("focal_length_px", "pitch", "roll", "height_m",
                                                                   "ref_scale"))}
    kept = {"n": 7, "of": 7, "camera": columns(cams),
            "objects": [{k: objs[:, i, j].tolist() for j, k in enumerate(("x", "z", "yaw", "length_m", "width_m",
                                                                          "height_m", "ground_m"))} for i in range(3)]}
    c, o, source = result_draws(dict(d, draws=kept), model)
    assert source == "posterior" and c.shape == (7, 5) and o.shape == (7, 3, 7)
    assert np.allclose(c[:, 0], 700.0) and np.allclose(o, objs)


def test_top_view_zooms_on_each_object_too_small_to_see(three):
    folder, scene, d, _ = three
    cam, objs = map_state(d)
    cams, draws, _ = result_draws(d, rebuild_model(d, scene), n=500)
    fig = plotting.plot_top_view(scene, cam, objs, (cams, draws))
    zoom = plotting.zoom_indices(scene, objs, (cams, draws))
    panels = [a for a in fig.get_axes() if a.get_visible() and a.get_xlabel() != "x, right (m)"]
    assert len(panels) == len(zoom)
    main_ax = next(a for a in fig.get_axes() if a.get_xlabel() == "x, right (m)")
    lo, hi = main_ax.get_ylim()
    assert lo < 0 < hi  # the camera (origin) is in view
    labels = {t.get_text() for t in main_ax.texts}
    assert labels == set(plotting.object_labels(scene))


# ------------------------------------------------------------------------------------------------
# creference plot


def test_plot_a_result_with_posterior_draws_writes_every_figure(one, tmp_path):
    folder, _, _, _ = one
    out = tmp_path / "figs"
    assert main(["plot", str(folder / "result.json"), "--out", str(out), "--quiet", "--dpi", "30"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["boxes.png", "pairs.png", "ranks.png", "top_view.png"]
    assert all(p.stat().st_size > 2_000 for p in out.iterdir())


def test_plot_a_map_only_result_shows_the_laplace_approximation(three, tmp_path, capsys):
    folder, scene, d, _ = three
    assert main(["plot", str(folder / "result.json"), "--out", str(tmp_path), "--object", "t2", "--dpi", "40"]) == 0
    out = capsys.readouterr().out
    assert "Laplace approximation" in out and "no rank plot" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["boxes.png", "pairs.png", "top_view.png"]
    assert main(["plot", str(folder / "result.json"), "--out", str(tmp_path), "--object", "car"]) == 2
    assert "--object car: no such object" in capsys.readouterr().err


def test_plot_writes_the_zoom_panels_apart_when_too_many_for_the_top_view(three, tmp_path, monkeypatch):
    folder, scene, d, _ = three
    monkeypatch.setattr(plotting, "MAX_ZOOM_PANELS", 0)  # as a crowded scene's: more than fit beside it
    zoom = plotting.zoom_indices(scene, map_state(d)[1], result_draws(d, rebuild_model(d, scene), n=2000)[:2])
    assert main(["plot", str(folder / "result.json"), "--out", str(tmp_path), "--quiet", "--dpi", "30"]) == 0
    assert (tmp_path / "zooms.png").exists() == bool(zoom)


def test_plot_refuses_a_scene_that_is_not_the_results(three, one, tmp_path, capsys):
    folder, scene, d, _ = three
    code = main(["plot", str(folder / "result.json"), "--scene", str(one[0] / "scene.json"), "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err
    assert err == (f"error: --scene {one[0] / 'scene.json'}: not the scene this result was estimated from "
                   "(target 't0', the result's are ['t0', 't1', 't2'])\n")
    edited = json.loads((folder / "scene.json").read_text())
    edited["targets"][1]["dimension_lines"][0]["corners"][0][0] += 1.0
    assert main(["plot", str(folder / "result.json"), "--scene", str(_write(tmp_path / "e.json", edited)),
                 "--out", str(tmp_path)]) == 2
    assert "same targets and image size but different content" in capsys.readouterr().err
    assert not any(tmp_path.glob("*.png"))


def test_a_result_missing_a_key_is_a_one_line_error(three, tmp_path, capsys):
    folder, scene, d, _ = three
    broken = copy.deepcopy(d)
    del broken["objects"][1]["map"]["yaw"]
    path = _write(tmp_path / "result.json", broken)
    assert main(["plot", str(path), "--scene", str(folder / "scene.json"), "--out", str(tmp_path / "figs")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {path}: objects[1].map.yaw: expected a finite number, got None: not a result as this "
                   "package writes it (edited by hand?)")
    assert not (tmp_path / "figs").exists()


def test_plot_command_errors(tmp_path, capsys):
    bad = _write(tmp_path / "bad.json", {"format": "something-else"})
    assert main(["plot", str(bad)]) == 2
    assert "format: expected one of ['creference-result/1', 'creference-result/2']" in capsys.readouterr().err
    r = _write(tmp_path / "r.json", {"format": "creference-result/1", "scene": "nowhere.json", "target": "t",
                                     "map": {"x": 0, "y": 1, "z": 5, "yaw": 0, "focal_length_px": 1000}})
    assert main(["plot", str(r)]) == 2
    assert "nowhere.json" in capsys.readouterr().err


def _as_v1(d: dict, scene) -> dict:
    """A result of a one-target scene as ``creference-result/1`` wrote it (docs/result_format.md of
    version 0.1): the target's MAP with the camera's focal length, pitch and roll, kept draws with
    their chains, the scene named and recorded by target and image size."""
    o, cam, cpost = d["objects"][0], d["camera"]["map"], d["camera"]["posterior"]
    names = ("x", "y", "z", "yaw", "distance_m")
    summary = {k: {**{n: o["posterior"][k][n] for n in names}, "focal_length_px": cpost[k]["focal_length_px"]}
               for k in ("mean", "median", "sd", "hdi")}
    summary["hdi"]["prob"] = cpost["hdi"]["prob"]
    kept = d["draws"]
    draws = {k: kept["objects"][0][k] for k in ("x", "z", "yaw")}
    draws.update(y=kept["camera"]["height_m"], focal_length_px=kept["camera"]["focal_length_px"],
                 chain=plotting.kept_chains(d).tolist())
    return {"format": "creference-result/1", "scene": d["scene"], "target": o["id"],
            "scene_id": {"target": o["id"], "image_size": d["image_size"], "sha256": "0" * 64},
            "model": "metrology", "preset": "default",
            "map": {**{k: o["map"][k] for k in names[:4]}, "focal_length_px": cam["focal_length_px"],
                    "pitch": cam["pitch"], "roll": cam["roll"]},
            "posterior": {"handedness": o["handedness"], "temperature": 1.0, **summary, "draws": draws}}


def test_a_version_1_result_is_plotted_with_its_scene(one, tmp_path, capsys):
    folder, scene, result, _ = one
    v1 = _write(folder / "old.json", _as_v1(result.to_dict(), scene))  # beside its scene, which it names
    assert main(["plot", str(v1), "--out", str(tmp_path), "--dpi", "30"]) == 0
    captured = capsys.readouterr()
    assert captured.err.startswith("warning: a creference-result/1")
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["boxes.png", "pairs.png", "ranks.png", "top_view.png"]
    other = _write(tmp_path / "other.json", truth_scene(9, m=2)[0])
    assert main(["plot", str(v1), "--scene", str(other), "--out", str(tmp_path / "x")]) == 2
    assert "(targets ['t0', 't1'], the result's is 't0')" in capsys.readouterr().err


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
    assert isinstance(fig, Figure)
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


def _shown(fig, gid: str) -> float:
    """The share of the pixels the collections ``gid`` paint on their own that still show (differ
    from the figure without them) when everything is drawn."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    arts = [c for c in fig.axes[0].collections if c.get_gid() in ("annotations", "median annotations",
                                                                   "draw boxes", "map box")]

    def render(keep):
        for c in arts:
            c.set_visible(keep(c))
        fig.canvas.draw()
        return np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)

    full, without = render(lambda c: True), render(lambda c: c.get_gid() != gid)
    alone, blank = render(lambda c: c.get_gid() == gid), render(lambda c: False)
    painted = np.abs(alone - blank).sum(axis=-1) > 40
    return float((np.abs(full - without).sum(axis=-1) > 40)[painted].mean())


def test_boxes_on_a_wide_street_frame_show_the_annotations_and_the_draws_the_legend_promises():
    """Issue 64: on a KITTI-sized frame (1242×375) the MAP boxes covered the annotations and the
    posterior draws, which differ from them by a pixel or two."""
    scene_d, truth = truth_scene(5, m=4, noise_px=1.5, n_annotations=4, image=(1242, 375), focal_px=720.0,
                                 depth=(8.0, 30.0))
    scene = cb.parse_scene(scene_d)
    cam, objs = truth["camera"], truth["objects"]
    rng = np.random.default_rng(0)
    cams = np.repeat(cam[None], 200, axis=0)
    draws = objs[None] + rng.normal(0, 1, (200, *objs.shape)) * np.array([0.15, 0.4, 0.03, 0, 0, 0, 0])
    fig = plotting.plot_boxes(scene, cam, objs, (cams, draws), zoom=False)
    assert _shown(fig, "annotations") > 0.6
    assert _shown(fig, "median annotations") > 0.6
    assert _shown(fig, "draw boxes") > 0.4


def test_a_reading_off_the_data_set_panels_scale_is_marked_at_its_edge_with_its_value():
    """The panel's scale follows the pooled readings; a weak reading far off it (257 px beside a pool
    near 700) stands at the panel's edge as an arrowhead with its value, not outside the picture."""
    from matplotlib.figure import Figure

    from creference_bayes.vision.dataset_figures import _panel

    values = np.array([[690.0, 650.0, 730.0], [710.0, 670.0, 750.0], [257.0, 170.0, 389.0]])
    p = {"values": values, "used": np.array([True, True, False]), "frames": ["a", "b", "c"], "prior": None,
         "pool": (680.0, 720.0), "center": 700.0, "log": True, "label": "focal_length_px", "title": "camera c",
         "warned": False, "group": "c"}
    ax = Figure().subplots()
    _panel(ax, p)
    bottom, _ = ax.get_ylim()
    assert bottom > 257.0
    marks = [line for line in ax.lines if line.get_marker() == "v"]
    assert len(marks) == 1 and marks[0].get_ydata()[0] == bottom and marks[0].get_xdata()[0] == 0  # sorted first
    assert [t.get_text() for t in ax.texts] == ["257"]


def test_the_label_quality_histogram_counts_in_whole_objects():
    from matplotlib.figure import Figure

    from creference_bayes.vision.label_figures import quality_figure

    fig = quality_figure(np.array([0.1, 0.35, 0.8]), 0.5, fig=Figure())
    ticks = fig.axes[0].get_yticks()
    assert len(ticks) >= 2 and np.allclose(ticks, np.round(ticks))


def test_a_data_set_pool_with_an_absurd_log_sd_is_refused_by_its_key():
    """A batch.json edited to a log-sd of 710 (found by the long fuzz): the panel's band would be
    e^710; the figure names the key instead of overflowing."""
    from creference_bayes.vision.dataset_figures import dataset_panels

    block = {"focal_length_px": {"shared_by": "camera", "groups": {"rig/front": {
        "median": 700.0, "log_sd": 710, "frames": 3,
        "values": [{"frame": "a", "value": 690.0, "low": 650.0, "high": 730.0, "used": True}]}}}}
    with pytest.raises(ValueError, match=r"dataset\.focal_length_px\.groups\.rig/front\.log_sd: expected a number in "
                                         r"\[0, 10\] \(a log-sd\), got 710"):
        dataset_panels(block)
    block["focal_length_px"]["groups"]["rig/front"]["log_sd"] = 0.05
    assert dataset_panels(block)[0]["pool"] == pytest.approx((700.0 * math.exp(-0.05), 700.0 * math.exp(0.05)))


def test_the_corner_scale_read_from_the_residuals_is_drawn_frame_by_frame_with_its_spread():
    """A crowd of careful (5 px) and careless (10 px) frames: the data set's figure has a panel of
    the corner scale, each frame's residual reading against the pool, and a frame's prior (the
    lighter band) is the frames' spread around its typical scale, not around the pool; a batch.json
    whose block keeps no readings (an older batch) has no such panel."""
    from creference_bayes.vision.dataset_figures import dataset_panels
    from creference_bayes.workflows.batch.dataset import DataSet

    rng = np.random.default_rng(0)
    dof = rng.uniform(2.0, 6.0, 80)
    true = np.where(np.arange(80) % 2, 5.0, 10.0)
    ds = DataSet({}, ("corner_scale",), residuals={f"k{k}": (float(true[k] ** 2 * rng.chisquare(dof[k])), float(dof[k]))
                                                   for k in range(80)})
    block = json.loads(json.dumps(ds.summary()))
    (panel,) = dataset_panels(block)
    crowd = block["corner_scale_px"]["groups"]["crowd"]
    assert panel["label"] == "corner_scale_px" and len(panel["values"]) == 80 and panel["center"] == crowd["sd"]
    low, high = panel["prior"]
    assert low < crowd["spread_sd"] < high and math.sqrt(low * high) == pytest.approx(crowd["spread_sd"])
    assert crowd["spread_sd"] < crowd["sd"]  # the typical scale sits below the pooled variance's
    crowd["values"] = []  # every frame's corners on their projection (annotations without noise)
    assert dataset_panels(block) == []
    del crowd["values"]
    assert dataset_panels(block) == []
