"""Scenes of several targets (the frame format, docs/scene_format.md): class size priors,
references that name a target or two, and what couples two objects in the posterior."""

import json

import numpy as np
import pytest

import creference_bayes as cb
from conftest import truth_scene
from creference_bayes.io.scene import SceneError, parse_scene, scene_to_dict
from creference_bayes.models.size_priors import KITTI_SIZE_PRIORS, size_priors_from_dict
from creference_bayes.pipeline import build_model


def _distance(d, a, b, value):
    d.setdefault("references", []).append({"worker": "wd", "measure": "distance", "mode": "direct", "value": value,
                                           "unit": "m", "targets": [a, b]})
    return d


def _true_distance(truth, i, j):
    o = truth["objects"]
    return float(np.hypot(o[i, 0] - o[j, 0], o[i, 1] - o[j, 1]))


def test_size_priors_from_a_dict_name_the_key():
    priors = size_priors_from_dict({"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4}})
    assert priors["Kayak"].median_m == (4.0, 0.7, 0.4)
    with pytest.raises(ValueError, match=r"classes.Kayak.width_m: expected a number > 0, got -1"):
        size_priors_from_dict({"Kayak": {"length_m": 4.0, "width_m": -1, "height_m": 0.4}})
    with pytest.raises(ValueError, match=r"classes.Kayak.log_sd"):
        size_priors_from_dict({"Kayak": {"length_m": 4.0, "width_m": 1, "height_m": 0.4, "log_sd": [0.1]}})
    assert set(KITTI_SIZE_PRIORS) >= {"Car", "Van", "Truck", "Pedestrian", "Cyclist", "Tram", "Misc"}


def test_a_scene_of_several_targets_round_trips_and_rejects_bad_input():
    d, _ = truth_scene(2, m=3, sizes_known=False)
    d["references"] = [{"measure": "length", "mode": "direct", "value": 4.1, "unit": "m", "target": "t0"},
                       {"measure": "length", "mode": "relative", "value": 1.5, "target": "t1",
                        "line": d["targets"][1]["dimension_lines"][0]["corners"][:2]}]
    scene = parse_scene(d)
    assert scene.reference_targets == (0, 1) and scene.references[0].line is None
    assert scene_to_dict(parse_scene(scene_to_dict(scene))) == scene_to_dict(scene)
    cases = [(lambda b: b["targets"][2].update(id="t0"), r"targets\[2\].id: duplicate id 't0'"),
             (lambda b: b["targets"][1].update({"class": "Spaceship"}), r"targets\[1\].class: no size prior for class 'Spaceship'"),
             (lambda b: b["targets"][1].update({"class": "Pedestrain"}),
              r"targets\[1\].class: no size prior for class 'Pedestrain' and no 'dimensions_m'; did you mean 'Pedestrian'\?$"),
             (lambda b: b["references"][1].pop("target"), r"references\[1\].target: a relative reference in a scene"),
             (lambda b: b["references"][0].update(target="nobody"), r"references\[0\].target: no target with id 'nobody'")]
    for change, message in cases:
        bad = json.loads(json.dumps(d))
        change(bad)
        with pytest.raises(SceneError, match=message):
            parse_scene(bad)


def test_a_version_1_scene_is_a_scene_of_one_target_of_known_size():
    from creference_bayes.cli.main import example_scene_path

    scene = cb.load_scene(example_scene_path())
    assert len(scene.targets) == 1 and scene.targets[0].dimensions is not None
    model, _ = build_model(scene)
    assert model.ground_sd_m == 0.0 and not model.object_free[0, 3:].any()


def test_a_distance_between_two_targets_round_trips_and_rejects_bad_input():
    d, _ = truth_scene(2, m=3)
    _distance(d, "t0", "t2", 12.5)
    scene = parse_scene(d)
    assert scene.reference_targets == ((0, 2),)
    assert scene.references[0].measure == "distance" and scene.references[0].low == 12.5
    assert scene_to_dict(parse_scene(scene_to_dict(scene))) == scene_to_dict(scene)
    model, _ = build_model(scene)
    assert model.pairs.tolist() == [[0, 2]]
    cases = [(lambda r: r.update(targets=["t0"]), r"references\[0\].targets: a distance is between two targets, got 1"),
             (lambda r: r.update(targets=["t0", "t9"]), r"references\[0\].targets\[1\]: no target with id 't9'"),
             (lambda r: r.update(targets=["t1", "t1"]), r"references\[0\].targets\[1\]: .*two different targets"),
             (lambda r: r.update(measure="height"), r"references\[0\].measure: .* measures their 'distance'"),
             (lambda r: r.update(line=[[1, 2], [3, 4]]), r"references\[0\].line: a distance between two targets has no"),
             (lambda r: r.update(value=-3), r"references\[0\]")]
    for change, message in cases:
        bad = json.loads(json.dumps(d))
        change(bad["references"][0])
        with pytest.raises(SceneError, match=message):
            parse_scene(bad)


def test_the_coupled_hessian_is_the_whole_posteriors():
    """The arrowhead with its pair blocks against brute-force second differences of the MAP's
    whole objective (working coordinates): the cross-object block is where the distance
    reference puts it."""
    from creference_bayes.inference.coords import FD_STEPS, WorkingCoords
    from creference_bayes.inference.map import derivatives, optimize

    d, truth = truth_scene(3, m=3, n_annotations=2, noise_px=1.0, sizes_known=False)
    _distance(d, "t0", "t1", round(_true_distance(truth, 0, 1), 1))
    model, _ = build_model(parse_scene(d))
    mp = optimize(model)
    model = mp.fitted(model)
    co = WorkingCoords(model)
    wc, wo = (x[0] for x in co.to_work(mp.camera[None], mp.objects[None]))
    dense = derivatives(model, wc, wo).dense()
    free = np.flatnonzero(np.concatenate([model.camera_free, model.object_free.ravel()]))
    x0 = np.concatenate([wc, wo.ravel()])
    h = np.concatenate([FD_STEPS[:5], np.tile(FD_STEPS[5:], model.n_objects)])

    def f(x):
        c, o = co.from_work(x[None, :5], x[None, 5:].reshape(1, -1, 7))
        return model.map_objective(c, o)[0]

    brute = np.zeros_like(dense)
    for i in free:
        for j in free[free >= i]:
            ei, ej = np.eye(len(x0))[i] * h[i], np.eye(len(x0))[j] * h[j]
            brute[i, j] = brute[j, i] = (f(x0 + ei + ej) - f(x0 + ei - ej) - f(x0 - ei + ej) + f(x0 - ei - ej)) / (4 * h[i] * h[j])
    sub = np.ix_(free, free)
    assert np.abs(brute[sub] - dense[sub]).max() < 1e-3 * np.abs(brute[sub]).max()  # two difference schemes
    cross = brute[5:12, 12:19]
    assert np.abs(cross - dense[5:12, 12:19]).max() < 1e-3 * np.abs(cross).max()
    assert np.abs(cross).max() > 1e3 * np.abs(brute[5:12, 19:26]).max()  # the pair couples t0 and t1, nothing else


@pytest.mark.slow  # two posteriors of three targets; the coupling test above keeps the pairs in the default run
def test_workers_distances_between_two_targets_narrow_the_posterior():
    """One set of dimension lines on t1, five on the others, sizes from class priors; three workers
    state the distance from t0 to t1 (within 4 % of the truth). The posterior's t0–t1 distance
    follows them, its 90 % spread falls, and t1's truth stays inside its interval."""
    d, truth = truth_scene(4, m=3, n_annotations=5, noise_px=2.0, sizes_known=False)
    d["targets"][1]["dimension_lines"] = d["targets"][1]["dimension_lines"][:1]
    plain = cb.estimate(json.loads(json.dumps(d)), seed=0, sampling={"min_ess": 150})
    true = _true_distance(truth, 0, 1)
    for factor in (0.96, 1.0, 1.03):
        _distance(d, "t0", "t1", round(true * factor, 1))
    coupled = cb.estimate(d, seed=0, sampling={"min_ess": 150})
    assert plain.converged and coupled.converged
    lo, hi = coupled.to_dict()["objects"][1]["posterior"]["hdi"]["distance_m"]
    assert lo <= np.hypot(*truth["objects"][1, :2]) <= hi
    between = lambda r: np.hypot(*(r.draws.objects[..., 0, :2] - r.draws.objects[..., 1, :2]).reshape(-1, 2).T)
    spread = lambda x: np.subtract(*np.percentile(x, [95, 5]))
    assert abs(np.median(between(coupled)) - true) < 0.05 * true
    assert spread(between(coupled)) < 0.8 * spread(between(plain))
