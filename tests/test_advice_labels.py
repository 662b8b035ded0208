"""Advice that serves the labels: answers put into a scene (a size from a catalogue, a camera's
mounting), their simulated observations against the models the answers make, the good-labels
objective, the verdicts, the batch plan (a mounting once per camera) and the labels' report
carrying the verdicts."""

import csv
import dataclasses
import json
import math
import re

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.cli.main import main
from creference_bayes.io.scene import parse_scene, scene_to_dict
from creference_bayes.pipeline import build_model
from creference_bayes.workflows.advice import AdviceSettings, combined_chance, good_chance
from creference_bayes.workflows.advice.answers import (CATALOGUE_LOG_SD, MOUNTING_SD, with_dimension_lines,
                                                       with_mounting, with_size)
from creference_bayes.workflows.advice.observe import MountingObservation, SizeObservation


@pytest.fixture(scope="module")
def frame():
    """Three targets of class priors, no horizon, the focal length known."""
    d, truth = truth_scene(5, m=3, noise_px=2.0, n_annotations=2, sizes_known=False, focal_known=True,
                           depth=(8.0, 35.0))
    return parse_scene(d), truth


def test_a_catalogue_size_multiplies_the_class_prior(frame):
    scene, _ = frame
    t = scene.targets[1]
    prior = scene.size_prior(t.cls)
    answered = with_size(scene, t.id, (4.0, 1.8, 1.5), log_sd=0.03)
    got = answered.targets[1].size_prior
    for k, size in enumerate((4.0, 1.8, 1.5)):
        w0, w1 = prior.log_sd[k] ** -2, 0.03 ** -2
        assert got.log_sd[k] == pytest.approx((w0 + w1) ** -0.5)
        assert math.log(got.median_m[k]) == pytest.approx((w0 * math.log(prior.median_m[k]) + w1 * math.log(size))
                                                          / (w0 + w1))
    assert answered.targets[0] == scene.targets[0] and got.source == "catalogue"
    # the scene file keeps it, and the estimate uses it in place of the class's
    again = parse_scene(json.loads(json.dumps(scene_to_dict(answered))))
    assert again.targets[1].size_prior.median_m == pytest.approx(got.median_m)
    model, _ = build_model(again)
    assert model.objects[1].size_prior.log_sd == pytest.approx(got.log_sd)


@pytest.mark.parametrize("bad, message", [
    ({"size_prior": {"length_m": 4, "width_m": 1.8, "height_m": -1, "log_sd": 0.03}}, "size_prior.height_m"),
    ({"size_prior": {"length_m": 4, "width_m": 1.8, "height_m": 1.5, "log_sd": 0.03},
      "dimensions_m": {"length": 4, "width": 1.8, "height": 1.5}}, "takes no size prior"),
])
def test_a_bad_size_prior_is_named(frame, bad, message):
    d = scene_to_dict(frame[0])
    d["targets"][0].update(bad)
    with pytest.raises(ValueError, match=message):
        parse_scene(d)


def test_answers_name_what_is_wrong(frame):
    scene, _ = frame
    with pytest.raises(ValueError, match="no target 'nope'"):
        with_size(scene, "nope", (4, 2, 1.5))
    with pytest.raises(ValueError, match="size_m"):
        with_size(scene, scene.targets[0].id, (4, 0, 1.5))
    with pytest.raises(ValueError, match="height_m"):
        with_mounting(scene, -1.0, 0.0)
    with pytest.raises(ValueError, match="corners"):
        with_dimension_lines(scene, scene.targets[0].id, np.zeros((3, 2)))
    more = with_dimension_lines(scene, scene.targets[2].id, scene.targets[2].corners[0] + 1.0)
    assert len(more.targets[2].dimension_lines) == len(scene.targets[2].dimension_lines) + 1


def test_an_answer_replaces_an_earlier_one_of_its_kind_and_a_wrong_unit_is_refused(frame):
    """The same catalogue size or calibration applied twice is one fact: the prior is that of one
    answer (not narrowed again); a second, other answer replaces the first. A size in millimetres,
    a height in centimetres or a pitch in radians given as degrees is refused, naming the unit."""
    scene, _ = frame
    tid = scene.targets[1].id
    once = with_size(scene, tid, (4.0, 1.8, 1.5))
    assert with_size(once, tid, (4.0, 1.8, 1.5)) == once
    assert with_size(once, tid, (4.4, 1.8, 1.5)) == with_size(scene, tid, (4.4, 1.8, 1.5))
    mounted = with_mounting(scene, 1.65, math.radians(1.0))
    assert mounted.orientation_prior.source == "calibration"
    assert with_mounting(mounted, 1.65, math.radians(1.0)) == mounted
    assert with_mounting(mounted, 1.5, 0.0) == with_mounting(scene, 1.5, 0.0)
    again = parse_scene(json.loads(json.dumps(scene_to_dict(mounted))))  # the scene file keeps where it came from
    assert again.orientation_prior == mounted.orientation_prior
    with pytest.raises(ValueError, match=r"size \[4355.0, 1736.0, 1745.0\] m is \d+ standard deviations from its "
                                         r"prior .*: metres expected"):
        with_size(scene, tid, (4355.0, 1736.0, 1745.0))
    with pytest.raises(ValueError, match="height 170 m: expected metres, between 0.1 and 30"):
        with_mounting(scene, 170.0, 0.0)
    with pytest.raises(ValueError, match="pitch 90°: expected degrees, at most 60 either way"):
        with_mounting(scene, 1.6, math.radians(90.0))


def test_a_size_or_mounting_already_answered_is_not_asked_again(frame):
    from creference_bayes.workflows.advice.candidates import candidates

    scene, truth = frame

    def keys(s):
        model, _ = build_model(s)
        return {c.key for c in candidates(s, model, truth["camera"], truth["objects"])[0]}

    tid = scene.targets[1].id
    before = keys(scene)
    assert {f"{tid}:size", "camera:mounting"} <= before
    after = keys(with_mounting(with_size(scene, tid, (4.0, 1.8, 1.5)), 1.6, 0.0))
    assert before - after == {f"{tid}:size", "camera:mounting"} and after <= before


def _draws(model, truth, n, rng):
    """States scattered around the truth (not a posterior: the identities hold at any state)."""
    cams = np.repeat(truth["camera"][None], n, axis=0) * np.exp(0.03 * rng.standard_normal((n, 5)))
    cams[:, 1:3] = truth["camera"][1:3] + np.radians(1.0) * rng.standard_normal((n, 2))
    objs = np.repeat(truth["objects"][None], n, axis=0)
    objs[..., 3:6] *= np.exp(0.05 * rng.standard_normal(objs[..., 3:6].shape))
    objs[..., :2] += 0.3 * rng.standard_normal(objs[..., :2].shape)
    return model.complete_camera(cams), objs


def test_the_simulated_answers_are_what_the_answered_scenes_estimate_with(frame):
    """The advice's ratio of a size or a mounting is, at every state, the answered scene's
    log-posterior less the present's, up to a constant: what the advice predicts is what the
    estimate does with the answer."""
    scene, truth = frame
    rng = np.random.default_rng(0)
    model, _ = build_model(scene)
    model.handedness = np.asarray(truth["handedness"], float)
    cams, objs = _draws(model, truth, 50, rng)
    base = model.neg_log_posterior(cams, objs)
    size = SizeObservation(model, 1, CATALOGUE_LOG_SD)
    size.simulate(rng, cams[:3], objs[:3])
    mount = MountingObservation(model, MOUNTING_SD)
    assert [n for _, n in mount.parts] == ["log_height", "pitch", "roll"]
    mount.simulate(rng, cams[:3], objs[:3])
    for k in range(3):
        answered = [with_size(scene, scene.targets[1].id, np.exp(size.values[k])),
                    with_mounting(scene, float(np.exp(mount.values[k, 0])), *map(float, mount.values[k, 1:]))]
        for obs, new_scene in zip((size, mount), answered):
            new, _ = build_model(new_scene)
            new.handedness = model.handedness
            diff = base - new.neg_log_posterior(cams, objs)
            ratio = obs.log_ratio(cams, objs)[k]
            assert np.ptp(diff - ratio) < 1e-6 * max(1.0, np.ptp(ratio))


def test_a_labels_chance_is_its_futures_spread_at_the_bar_without_the_estimators_noise():
    """Futures whose true P(IoU ≥ 0.7) is p, each read from 16 resampled draws (a binomial share).
    The chance the label is good is the share of futures at or above the bar once the reading's
    noise is taken out: near 1 when every future is at 0.67 (counting the noisy reads against the
    bar and taking off the present's level, as the advice did, gave about 0.6 there and on KITTI
    frames stated 5.2 of the 9 labels at 0.4-0.5 that a size all lifted), near 0 when every future
    is at 0.4, and the true share when the futures differ."""
    rng = np.random.default_rng(0)
    n = np.full(75, 16.0)

    def chances(p):  # 200 targets whose futures are all at p, or drawn from p(size) when callable
        true = p(rng, (75, 200)) if callable(p) else np.full((75, 200), p)
        return good_chance(rng.binomial(16, true) / 16, n, np.full(200, 0.5))

    assert np.median(chances(0.67)) > 0.99 and np.mean(chances(0.67)) > 0.97
    assert np.median(chances(0.4)) < 0.01 and np.mean(chances(0.4)) < 0.05
    assert 0.4 < np.mean(chances(0.52)) < 0.9 and 0.1 < np.mean(chances(0.48)) < 0.6
    spread = chances(lambda r, shape: r.beta(6.0, 4.0, shape))    # P(beta(6, 4) ≥ 0.5) = 0.746
    assert abs(np.mean(spread) - 0.746) < 0.05
    mixed = chances(lambda r, shape: np.where(r.uniform(size=shape) < 0.5, 0.3, 0.8))
    assert abs(np.mean(mixed) - 0.5) < 0.12   # two clusters, approximated by one beta
    # the bar is per label; a bar at or below 0 is always met, one above 1 never
    two = good_chance(rng.binomial(16, 0.6, size=(75, 2)) / 16, n, np.array([0.0, 1.01]))
    np.testing.assert_allclose(two, [1.0, 0.0], atol=1e-9)


@pytest.fixture(scope="module")
def crowded():
    """Twelve targets of class priors with one set of lines each (no horizon, the focal length
    known), and 600 draws of their posterior with each draw's handedness (some target's other
    handedness holds part of the mass)."""
    from creference_bayes.io.result import stored_draws
    from creference_bayes.pipeline import estimate, result_draws

    d, _ = truth_scene(5, m=12, noise_px=2.0, n_annotations=1, sizes_known=False, focal_known=True,
                       depth=(8.0, 35.0))
    scene = parse_scene(d)
    before = estimate(scene, seed=1, sampling={"min_ess": 1000}, keep_draws=100_000)
    cams, objs, _ = result_draws(before.to_dict(), before.model)
    hands = stored_draws(before.to_dict()).handedness.reshape(len(cams), -1)
    keep = np.unique(np.linspace(0, len(cams) - 1, 600).round().astype(int))
    return scene, before.model, before.model.complete_camera(cams[keep]), objs[keep], hands[keep]


@pytest.mark.parametrize("kind", ["size", "mounting"])
def test_an_answers_fallback_moves_the_draws_to_the_answered_estimate(crowded, kind):
    """A size of the second target (or the camera's mounting), simulated at a draw in the tail of
    the present: the draws the advice moves to the answer (its fallback for collapsed weights)
    against the posterior of the scene estimated with that answer, every target's distance. The
    tempered update this replaced left every target's spread too narrow here, by 4–21 % for the
    size (mean 13 %) and 4–13 % for the mounting (mean 8 %): its random walk does not cross a
    frame's many dimensions."""
    from creference_bayes.pipeline import estimate, result_draws
    from creference_bayes.workflows.advice import _moved
    from creference_bayes.workflows.advice.update import normalise

    scene, model, cams, objs, hands = crowded
    assert np.any(hands != model.handedness)  # the premise: draws at the other handedness too
    dist = np.hypot(objs[..., 0], objs[..., 1])          # (x, z): the bottom centre on the ground
    # the second target near (its 5th percentile), or the camera low (its height's 1st percentile)
    j = int(np.argsort(dist[:, 1] if kind == "size" else cams[:, 3])[len(cams) // (20 if kind == "size" else 100)])
    obs = SizeObservation(model, 1, CATALOGUE_LOG_SD) if kind == "size" else MountingObservation(model, MOUNTING_SD)
    obs.simulate(np.random.default_rng(3), cams[[j]], objs[[j]])
    assert normalise(obs.log_ratio(cams, objs))[1][0] < 0.15 * len(cams)   # reweighting leaves few draws
    _, moved, w = _moved(obs, 0, cams, objs, np.random.default_rng(4), 1.0, hands)
    v = obs.values[0]
    answered = (with_size(scene, scene.targets[1].id, np.exp(v)) if kind == "size"
                else with_mounting(scene, float(np.exp(v[0])), *map(float, v[1:])))
    after = estimate(answered, seed=2, sampling={"min_ess": 1000}, keep_draws=100_000)
    _, objs_new, _ = result_draws(after.to_dict(), after.model)
    dist_moved, dist_new = (np.hypot(o[..., 0], o[..., 1]) for o in (moved, objs_new))
    assert np.max(np.abs(dist_new.mean(0) - dist.mean(0)) / dist.std(0)) > 0.5   # the answer moved the posterior …
    # … and the moved draws, at their weights, followed (600 of them, at least a tenth counting: an sd
    # within about 3 to 10 %)
    assert w.shape == (len(cams),) and abs(w.sum() - 1.0) < 1e-9 and 1.0 / np.sum(w * w) >= 0.1 * len(cams)
    mean = w @ dist_moved
    assert np.all(np.abs(mean - dist_new.mean(0)) < 0.3 * dist_new.std(0))
    ratio = np.sqrt(w @ (dist_moved - mean) ** 2) / dist_new.std(0)
    assert np.all(np.abs(ratio - 1.0) < 0.12) and abs(np.mean(ratio) - 1.0) < 0.05


def test_the_collapsed_futures_of_a_size_are_moved_together_each_to_its_own_answer(crowded):
    """The fallback moves every collapsed future of a request in one pass: two answers for the
    second target's size, one from a draw in each tail of its length, each move its own set of
    draws to a length near its answer (the answer is 3 % sure, the class prior 20 % or more)."""
    from creference_bayes.models.contract import O_SIZE
    from creference_bayes.workflows.advice import _moved

    scene, model, cams, objs, hands = crowded
    length = objs[:, 1, O_SIZE.start]
    tails = np.argsort(length)[[len(cams) // 20, -len(cams) // 20]]
    obs = SizeObservation(model, 1, CATALOGUE_LOG_SD)
    obs.simulate(np.random.default_rng(3), cams[tails], objs[tails])
    moved_cams, moved, w = _moved(obs, np.array([0, 1]), cams[:250], objs[:250], np.random.default_rng(4), 1.0,
                                  hands[:250])
    assert moved_cams.shape == (2, 250, 5) and moved.shape == (2, 250, *objs.shape[1:]) and w.shape == (2, 250)
    for f in range(2):
        log_length = np.log(moved[f, :, 1, O_SIZE.start])
        assert w[f] @ log_length == pytest.approx(obs.values[f, 0], abs=0.05)
    assert obs.values[1, 0] - obs.values[0, 0] > 0.2   # two answers apart
    assert np.all(np.isfinite(moved))


@pytest.mark.slow
def test_the_fallbacks_on_fewer_draws_predict_what_they_did_on_all(monkeypatch):
    """The advice recomputes a collapsed future on FALLBACK_DRAWS of the draws (docs/studies/advice.md,
    "Speed of the advice on a frame"): every request's predictions as they were on all the draws,
    within their Monte Carlo noise."""
    import creference_bayes.workflows.advice as advice_module
    from creference_bayes.pipeline import estimate
    from creference_bayes.workflows.advice.inputs import advise_result

    d, _ = truth_scene(5, m=3, noise_px=2.0, n_annotations=2, sizes_known=False, focal_known=True, depth=(8.0, 35.0))
    scene = parse_scene(d)
    result = estimate(scene, seed=1, sampling={"min_ess": 400}, keep_draws=400)
    settings = AdviceSettings(n_draws=400, n_futures=60)
    runs = []
    for draws in (250, 400):
        monkeypatch.setattr(advice_module, "FALLBACK_DRAWS", draws)
        runs.append({p.candidate.key: p for p in advise_result(result, scene, seed=3, settings=settings).predictions})
    fast, full = runs
    assert sum(p.fallbacks for p in fast.values()) >= 10   # the fallbacks were used
    assert fast.keys() == full.keys()
    for key, p in fast.items():
        q = full[key]
        np.testing.assert_allclose(p.expected.p_iou, q.expected.p_iou, atol=0.03, err_msg=key)
        # measured over seeds 3 and 4: the fallbacks on 250 draws moved a target's expected HDI share by
        # 0.0040 at most, where the same prediction moves by up to 0.0087 from one seed to the next
        np.testing.assert_allclose(p.expected.hdi_share, q.expected.hdi_share, atol=0.006, err_msg=key)
        assert abs(p.good_gain - q.good_gain) <= 0.05 + 3 * np.hypot(p.good_gain_se, q.good_gain_se), key


@pytest.fixture(scope="module")
def advised(frame):
    from creference_bayes.workflows.advice.inputs import advise_scene

    advice, result = advise_scene(frame[0], seed=1, settings=AdviceSettings(n_draws=200, n_futures=40),
                                  sampling={"min_ess": 200})
    return advice, result


def test_the_labels_objective_ranks_and_says_what_would_lift_each_label(advised):
    advice, result = advised
    kinds = {p.candidate.kind for p in advice.predictions}
    assert {"dims", "size", "mounting"} <= kinds
    for p in advice.predictions:
        assert p.good_per_hour == pytest.approx(p.good_gain * 3600.0 / p.candidate.seconds)
        assert len(p.p_good) == 3 and np.all((p.p_good >= 0) & (p.p_good <= 1))
    # a label good now counts in no gain; its chance to fall below the bar is stated as the loss
    for p in advice.predictions:
        assert p.good_gain == pytest.approx(float(np.sum(p.p_good[~advice.good])))
        assert p.good_loss == pytest.approx(float(np.sum(1.0 - p.p_good[advice.good])))
        assert p.to_dict()["good_loss"] == p.good_loss
    verdicts = advice.verdicts()
    assert [v["target"] for v in verdicts] == list(advice.targets)
    for v, good in zip(verdicts, advice.good):
        assert (v["verdict"] == "good") == bool(good)
        if v["verdict"] == "lift":
            assert v["chance"] >= 0.5 and v["best"] in {p.candidate.key for p in advice.predictions}
        if v["verdict"] == "none":
            assert "no single request lifts it" in v["text"]
    assert advice.to_dict()["verdicts"] == verdicts


def test_the_present_quality_is_the_labels(frame, advised):
    from creference_bayes.io.result import stored_draws
    from creference_bayes.pipeline import map_state
    from creference_bayes.workflows.labels.kitti import kitti_poses
    from creference_bayes.workflows.labels.quality import label_quality

    advice, result = advised
    d = result.to_dict()
    camera, objs = map_state(d)
    kept = stored_draws(d)
    box = kitti_poses(frame[0], camera[None], objs[None])[0]
    samples = kitti_poses(frame[0], kept.cameras[0], kept.objects[0])
    assert len(samples) > advice.n_weighed  # all the result's draws, not only those the advice weighs
    for i in range(3):
        assert advice.now.p_iou[i] == label_quality(box[i], samples[:, i]).p_iou[0.7]


def test_the_advice_weighs_boxes_in_the_labels_frame(frame):
    """On a KITTI frame the labels' boxes are in the camera's frame. Draws that differ only in the
    camera's pitch, with every object's place turned with it (the image sees the same boxes), give
    the same labels; the advice must say so (in the ground's frame the boxes would scatter by
    tenths of a metre and seem uncertain)."""
    from creference_bayes.core.geometry import rotation_from_pitch_roll
    from creference_bayes.models.contract import C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_X, O_Z
    from creference_bayes.workflows.advice import _Draws
    from creference_bayes.workflows.labels.kitti import kitti_poses

    scene, truth = frame
    p2 = np.hstack([np.diag([1500.0, 1500.0, 1.0]), np.array([[40.0], [0.2], [0.003]])])
    scene = dataclasses.replace(scene, kitti_p2=p2)
    cam0, objs0 = truth["camera"], truth["objects"]
    rng = np.random.default_rng(4)
    n = 200
    cams = np.repeat(cam0[None], n, axis=0)
    cams[:, C_PITCH] += np.radians(rng.normal(0.0, 1.0, n))  # 1 degree of pitch, all else seen alike
    objs = np.repeat(objs0[None], n, axis=0)
    world0 = np.stack([objs0[:, O_X], cam0[C_HEIGHT] - objs0[:, O_GROUND], objs0[:, O_Z]], axis=-1)
    in_camera = world0 @ rotation_from_pitch_roll(cam0[C_PITCH], cam0[C_ROLL]).T
    for k in range(n):
        world = in_camera @ rotation_from_pitch_roll(cams[k, C_PITCH], cams[k, C_ROLL])  # R_k^T applied per row
        objs[k, :, O_X], objs[k, :, O_Z] = world[:, 0], world[:, 2]
        objs[k, :, O_GROUND] = cams[k, C_HEIGHT] - world[:, 1]
    boxes = kitti_poses(scene, cams, objs)
    assert np.ptp(boxes[..., :3], axis=0).max() < 1e-6  # the labels' boxes do not move
    assert np.ptp(objs[..., O_GROUND], axis=0).max() > 0.3  # the ground's frame does
    p = _Draws(cams, objs, scene).outlooks(np.full((1, n), 1.0 / n), AdviceSettings(), rng, n)["p_iou"][0]
    np.testing.assert_allclose(p, 1.0)


def test_when_no_request_lifts_a_label_its_verdict_names_the_one_that_moves_it_most(advised):
    """Chances of a few millionths are nothing: the verdict then names the request whose expected
    quality is highest, not the one whose simulated outcomes happened to leave a crumb of chance."""
    advice, _ = advised
    i = 0
    mine = [p for p in advice.predictions if p.candidate.target in (i, None)]
    top = max(mine, key=lambda p: float(p.expected.p_iou[i]))
    crumb = min(mine, key=lambda p: float(p.expected.p_iou[i]))
    assert top is not crumb

    def with_chance(p, c):
        q = np.zeros(len(advice.targets))
        q[i] = c
        return dataclasses.replace(p, p_good=q, rank_p_good=q, good_gain=c, rank_good_gain=c)

    preds = tuple(with_chance(p, 5e-6 if p is crumb else 0.0) for p in advice.predictions)
    low = np.minimum(advice.now.p_iou, 0.1)  # every label below the bar
    hopeless = dataclasses.replace(advice, predictions=preds, now=dataclasses.replace(advice.now, p_iou=low))
    row = hopeless.verdicts()[i]
    assert row["verdict"] == "none" and row["best"] == top.candidate.key


def test_good_labels_per_hour_rank_to_three_decimals_and_hdi_points_as_they_are():
    """rank_key: crumbs of chance (good labels per hour a millionth apart) do not order requests,
    the HDI gain does; HDI points per minute order requests however small they are."""
    from types import SimpleNamespace

    from creference_bayes.workflows.advice import rank_key

    def pred(key, labels_per_hour, hdi_per_minute):
        return SimpleNamespace(candidate=SimpleNamespace(key=key), dropped=False,
                               score=lambda objective: labels_per_hour if objective == "labels" else hdi_per_minute)

    crumb, wider = pred("a", 2e-5, 0.01), pred("b", 1e-5, 0.5)
    assert sorted([crumb, wider], key=rank_key("labels")) == [wider, crumb]
    assert sorted([pred("a", 0.30, 0.5), pred("b", 0.31, 0.1)], key=rank_key("labels"))[0].candidate.key == "b"
    small, smaller = pred("a", 0.9, 0.0027), pred("b", 0.0, 0.0031)
    assert sorted([small, smaller], key=rank_key("hdi")) == [smaller, small]
    assert sorted([pred("b", 0.0, 0.003), pred("a", 0.0, 0.003)], key=rank_key("hdi"))[0].candidate.key == "a"


def test_the_location_objective_ranks_by_the_drop_of_the_locations_sd_per_minute():
    """A reference that narrows the HDI more per minute, and a set of lines that brings the
    location's sd down more per minute (0.9 of 2.0 m in 183.5 s against 0.2 m in 64.4 s): the hdi
    objective puts the reference first, the location objective the lines; each is worth its time
    by its own points per minute (``min_gain``)."""
    from creference_bayes.workflows.advice import Outlook, Prediction, rank_key
    from creference_bayes.workflows.advice.candidates import Candidate

    def pred(key, seconds, hdi_pts, sd_m):
        cand = Candidate(key, "dims" if key == "lines" else "reference", 0, "t", None, None, None, None, (), seconds)
        out = Outlook(*(np.array([v]) for v in (4.0, 0.2, 20.0, sd_m, 0.3)))
        return Prediction(cand, out, gain_pct=hdi_pts, gain_se_pct=0.1, gain_per_minute=hdi_pts * 60.0 / seconds,
                          ess_median=0.5, fallbacks=0, location_gain_pct=100.0 * (2.0 - sd_m) / 20.0)

    ref, lines = pred("ref", 64.4, 3.0, 1.8), pred("lines", 183.5, 2.0, 1.1)
    assert sorted([lines, ref], key=rank_key("hdi"))[0] is ref
    assert sorted([ref, lines], key=rank_key("location"))[0] is lines
    assert lines.score("location") == pytest.approx(4.5 * 60.0 / 183.5)  # 0.9 m of 20 m: 4.5 points
    assert ref.score("location") == pytest.approx(1.0 * 60.0 / 64.4)
    assert lines.value("location") == pytest.approx(4.5) and lines.value("hdi") == 2.0
    at = AdviceSettings(objective="location", min_gain=1.0)
    assert at.worth(lines.value("location"), 183.5) and not at.worth(ref.value("location"), 64.4)
    with pytest.raises(ValueError, match="objective"):
        AdviceSettings(objective="sd")


def _says_nothing(spread: float):
    """An observation whose log-weights are noise of sd ``spread``, nothing of the draws."""
    class Nothing:
        usable, needs_scale = True, False

        def __init__(self, model, *args):
            self.model = model

        def simulate(self, rng, cams, objs, hands=None):
            self.m, self.rng = len(cams), rng

        def log_ratio(self, cams, objs, base, hands=None):
            return spread * self.rng.standard_normal((self.m, len(cams)))

    return Nothing


def test_the_targets_a_request_says_nothing_of_keep_their_hdi_and_every_label_its_numbers(crowded, monkeypatch):
    """The screen (:func:`~creference_bayes.workflows.advice.update.informative`) against reading
    every target's distance from every future, on twelve targets (their vehicles' sizes, the mounting):
    each label's numbers are the same to the bit (the screen reads the HDIs only); a target left out
    keeps the present's HDI; each request's HDI gain moves by less than three of its standard
    errors."""
    from creference_bayes.workflows.advice import advise
    from creference_bayes.workflows.advice import update

    scene, model, cams, objs, hands = crowded
    settings = AdviceSettings(n_draws=200, n_futures=40, kinds=("size", "mounting"))

    def run():
        return advise(model, scene, cams, objs, camera_map=cams[0], objects_map=objs[0], seed=2, settings=settings,
                      hands=hands)

    screened = run()
    monkeypatch.setattr(update, "SCREEN_SD", -np.inf)
    every = run()
    other = {p.candidate.key: p for p in every.predictions}
    assert len(other) == len(screened.predictions) > 5
    left_out = 0
    for a in screened.predictions:
        b = other[a.candidate.key]
        for k in ("p_good", "good_gain", "good_gain_se", "good_loss", "rank_good_gain"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
        kept = a.expected.hdi_width_m == screened.now.hdi_width_m
        left_out += int(kept.sum())
        assert abs(a.gain_pct - b.gain_pct) < 3.0 * b.gain_se_pct + 0.05
    assert left_out > 0   # the premise: some request says nothing of some target


def test_an_observation_that_says_nothing_makes_no_label_good(frame, advised, monkeypatch):
    """Weights that scatter the draws but say nothing: no label becomes good. Counting the
    futures' noisy P(IoU ≥ t) against the bar without the present's level (the estimator's own
    smoothing) gave every target near the bar a gain.

    Every request on 300 futures (no race): a label a few points below the bar still takes a
    chance of reaching it from the futures' noise where they are few (docs/studies/advice.md,
    "A label near the bar"), which would make this test hang on where the posterior's draws put
    the labels."""
    from creference_bayes.workflows import advice as advice_module
    from creference_bayes.workflows.advice.inputs import advise_result

    monkeypatch.setattr(advice_module, "DimsObservation", _says_nothing(0.5))
    _, result = advised
    scene = frame[0]
    a = advise_result(result, scene, seed=3, settings=AdviceSettings(n_draws=400, n_futures=300, min_quality=0.3,
                                                                       race_every=1, kinds=("dims",)))
    dims = [p for p in a.predictions if p.candidate.kind == "dims"]
    assert len(dims) == 3
    for p in dims:
        assert abs(p.good_gain) < 3 * p.good_gain_se + 0.05


def test_a_collapsed_future_that_says_nothing_makes_no_label_good(frame, advised, monkeypatch):
    """Weights that collapse (every future goes to the fallback) and a fallback that returns the
    present's draws: no label becomes good. The fallback's equally weighted draws are set against
    the present's level; against the collapsed weights' shuffled level (a handful of draws, whose
    labels look far better than those of all of them) every label would lose."""
    from creference_bayes.workflows import advice as advice_module
    from creference_bayes.workflows.advice.inputs import advise_result

    def present(obs, idx, cams, objs, rng, temperature, hands=None):  # the fallback: the present's draws, shuffled
        orders = [rng.permutation(len(cams)) for _ in np.atleast_1d(idx)]   # one set per collapsed future
        return (np.stack([cams[o] for o in orders]), np.stack([objs[o] for o in orders]),
                np.full((len(orders), len(cams)), 1.0 / len(cams)))

    monkeypatch.setattr(advice_module, "DimsObservation", _says_nothing(20.0))
    monkeypatch.setattr(advice_module, "_moved", present)
    _, result = advised
    a = advise_result(result, frame[0], seed=3, settings=AdviceSettings(n_draws=400, n_futures=60, min_quality=0.3,
                                                                       race_every=1))  # every future weighed
    dims = [p for p in a.predictions if p.candidate.kind == "dims"]
    assert len(dims) == 3 and all(p.fallbacks == 60 for p in dims)
    for p in dims:
        assert abs(p.good_gain) < 3 * p.good_gain_se + 0.05


def test_requests_are_ranked_on_futures_apart_from_those_their_gain_is_stated_from(advised):
    """The ranking's figure and the stated gain come from different halves of the futures: both
    estimate the same gain, and neither is the other."""
    advice, _ = advised
    labels = [p for p in advice.predictions if p.rank_good_gain is not None]
    assert len(labels) == len(advice.predictions)
    assert any(p.rank_good_gain != p.good_gain for p in labels)
    scores = [round(p.score("labels"), 3) for p in advice.predictions]  # ranked to three decimals
    assert scores == sorted(scores, reverse=True)
    diff = np.array([p.rank_good_gain - p.good_gain for p in labels])
    se = np.array([p.good_gain_se for p in labels])
    assert np.all(np.abs(diff) < 6 * se + 0.05)


@pytest.fixture(scope="module")
def advised_batch(tmp_path_factory):
    """Three frames: two of one named camera, one of none; a short posterior each."""
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    root = tmp_path_factory.mktemp("advised")
    (root / "in").mkdir()
    for seed in range(3):
        scene, _ = truth_scene(seed + 10, m=2, noise_px=2.0, n_annotations=2, sizes_known=False, focal_known=True,
                               depth=(8.0, 35.0))
        if seed < 2:
            scene["camera"]["id"] = "rig-B"
        (root / "in" / f"f{seed}.json").write_text(json.dumps(scene))
    run_batch([root / "in"], root / "out", LocalEngine(1),
              BatchSettings(seed=0, sampling={"min_ess": 100, "max_steps": 400, "warmup": 200}))
    assert main(["advise", str(root / "out"), "--draws", "100", "--futures", "20", "--min-good-per-hour", "0",
                 "--quiet"]) == 0
    return root


def test_the_plan_asks_a_mounting_once_per_camera(advised_batch):
    from creference_bayes.workflows.advice.batch import advise_batch, request_rows

    out = advised_batch / "out"
    rows = list(csv.DictReader((out / "advice" / "requests.csv").open()))
    mountings = [r for r in rows if r["kind"] == "mounting"]
    assert len([r for r in mountings if r["camera"] == "rig-B"]) == 1
    assert all(r["frames"] == "2" for r in mountings if r["camera"] == "rig-B")
    assert all(r["frames"] == "1" and r["key"] == "f2" for r in mountings if not r["camera"])
    # requests.csv is the plan (the same seed and settings), its gains stated from the other futures
    batch = advise_batch(out, settings=AdviceSettings(n_draws=100, n_futures=20, min_good_per_hour=0.0))
    plan = batch.plan()
    assert [r["kind"] for r in rows] == [r.prediction.candidate.kind for r in plan]
    assert [float(r["good_gain"]) for r in rows] == pytest.approx([r.gain for r in plan], abs=1e-3)
    assert [float(r["good_loss"]) for r in rows] == pytest.approx([r.loss for r in plan], abs=1e-3)
    # the first request is the best alone per human second (a mounting: summed over its frames)
    frames = {o.key: o.advice for o in batch.objects}
    alone = [(sum(q.value("labels") for q in ps) / ps[0].candidate.seconds)
             for ps in ([p for p in a.predictions if p.candidate.kind != "mounting"] for a in frames.values())
             for ps in ([p] for p in ps)]
    for cam in {o.scene.camera_id or o.key for o in batch.objects}:
        ms = [p for o in batch.objects if o.target == 0 and (o.scene.camera_id or o.key) == cam
              for p in o.advice.predictions if p.candidate.kind == "mounting"]
        alone.append(sum(p.value("labels") for p in ms) / ms[0].candidate.seconds)
    assert plan[0].rate == pytest.approx(max(alone))
    # a frame's requests are answered together: the plan's gains and losses add up to each label's
    # chance to be good after all of its frame's requests (combined_chance), less now
    chosen = {}
    for r in plan:
        for o, p in zip(r.objects, r.predictions):
            chosen.setdefault(o.key, []).append(p.moments)
    after = {k: combined_chance(*frames[k].futures_scale(), ms) for k, ms in chosen.items()}
    assert sum(r.gain for r in plan) == pytest.approx(sum(float(a[~frames[k].good].sum()) for k, a in after.items()))
    assert sum(r.loss for r in plan) == pytest.approx(sum(float((1 - a[frames[k].good]).sum()) for k, a in after.items()))
    assert len(plan) > len(frames)
    # a team that asks only for lines gets only lines
    only = advise_batch(out, settings=AdviceSettings(n_draws=100, n_futures=20, min_good_per_hour=0.0,
                                                     kinds=("dims",)))
    assert {p.candidate.kind for o in only.objects for p in o.advice.predictions} == {"dims"}
    # a budget keeps the plan within it, best value per second first
    budget = min(r.seconds for r in plan) + 1.0
    cut = request_rows(batch, budget)
    assert sum(float(r["seconds"]) for r in cut) <= budget and len(cut) >= 1


def _planned(frames: dict, min_good_per_hour: float = 1.0, se: float = 0.0, spread: float = 1e-9):
    """A BatchAdvice of frames given as {key: (camera, P(IoU ≥ 0.7) of its labels now, [(kind, target,
    seconds, the request's change of each label's P(IoU ≥ 0.7))])}, each change known to ``se``, the
    futures' variance ``spread`` (by default as sure as can be: a label is lifted when its change
    takes it past the bar of 0.5). A request's chances alone are those of combined_chance, on both
    halves of the futures; a kind ending in "-dropped" left its frame's race (Prediction.dropped)."""
    from types import SimpleNamespace

    from creference_bayes.workflows.advice import Advice, Moments, Outlook, Prediction
    from creference_bayes.workflows.advice.batch import BatchAdvice, ObjectAdvice
    from creference_bayes.workflows.advice.candidates import Candidate

    settings = AdviceSettings(min_good_per_hour=min_good_per_hour)
    objects = []
    for key, (camera, p_now, requests) in frames.items():
        one, p_now = np.ones(len(p_now)), np.asarray(p_now, float)
        now = Outlook(hdi_width_m=one, hdi_share=one * 0.2, distance_m=one * 20, location_sd_m=one, p_iou=p_now)
        below = p_now < 0.5
        predictions = []
        for kind, target, seconds, change in requests:
            m = Moments(np.asarray(change, float), one * se, one * spread)
            q = combined_chance(p_now, one * 0.5, [m])
            kind, dropped = kind.removesuffix("-dropped"), kind.endswith("-dropped")
            predictions.append(Prediction(
                Candidate(f"{kind}:{target}", kind, target, None, None, None, None, None, (), seconds), now,
                0.0, 0.0, 0.0, 1.0, 0, p_good=q, good_gain=float(q[below].sum()), rank_p_good=q,
                rank_good_gain=float(q[below].sum()), good_loss=float((1 - q[~below]).sum()), moments=m,
                rank_moments=m, dropped=dropped))
        advice = Advice(tuple(f"t{i}" for i in range(len(p_now))), now, tuple(predictions), "collect", "",
                        settings=settings)
        objects += [ObjectAdvice(key, f"{key}.png", SimpleNamespace(camera_id=camera), advice, i, None)
                    for i in range(len(p_now))]
    return BatchAdvice(tuple(objects))


def test_requests_answered_together_add_their_changes():
    """A label at 0.3 (bar 0.45): two requests that each move it by +0.1 lift it only together; a
    change within its noise counts for little; the futures' spreads add."""
    base, bar = np.array([0.3]), np.array([0.45])

    def m(change, se=0.0, spread=1e-9):
        from creference_bayes.workflows.advice import Moments

        return Moments(np.array([change]), np.array([se]), np.array([spread]))

    assert combined_chance(base, bar, [m(0.1)]) == pytest.approx([0.0], abs=1e-6)
    assert combined_chance(base, bar, [m(0.1), m(0.1)]) == pytest.approx([1.0], abs=1e-6)
    # +0.2 known to 0.2 counts as +0.1: the label stays below
    assert combined_chance(base, bar, [m(0.2)]) == pytest.approx([1.0], abs=1e-6)
    assert combined_chance(base, bar, [m(0.2, se=0.2)]) == pytest.approx([0.0], abs=1e-6)
    # no request: the label keeps its verdict (its frame is not estimated again)
    assert combined_chance(np.array([0.3, 0.6]), np.array([0.5, 0.5]), []) == pytest.approx([0.0, 1.0])
    # a symmetric future at the bar is good with chance one half; wider futures reach further
    half = combined_chance(np.array([0.5]), np.array([0.5]), [m(0.0, spread=0.01)])
    assert half == pytest.approx([0.5], abs=1e-6)
    one, two = (combined_chance(base, bar, [m(0.0, spread=0.01)] * k)[0] for k in (1, 2))
    assert 0.0 < one < two < 0.5


def test_the_plan_chooses_by_each_requests_chances_and_states_them_answered_together():
    """Frames of one camera, a car each below the bar of 0.5: a at 0.2, b at 0.3. Every change is
    +0.3 with a spread of 0.01 (sd 0.1), so a request on a's car lifts it alone with chance 1/2 (a
    future symmetric about the bar), one on b's with more. The plan chooses by the chances alone (a
    label lifted once any request lifts it): after a's size (1/2 per 64.4 s), a's lines are worth
    1/2 × 1/2 per 183.5 s. It states each request's gain with the frame's requests answered
    together: a's lines take a's car to 0.8, so they add more than their own chance; a request
    stated to add less than its time is worth is passed over."""
    from creference_bayes.workflows.advice import Moments

    frames = {"a": ("cam", [0.2], [("size", 0, 64.4, [0.3]), ("dims", 0, 183.5, [0.3]),
                                   ("mounting", None, 900.0, [0.3])]),
              "b": ("cam", [0.3], [("size", 0, 64.4, [0.3]), ("mounting", None, 900.0, [0.3])])}
    batch = _planned(frames, spread=0.01)
    p = {(o.key, q.candidate.kind): float(q.p_good[0]) for o in batch.objects for q in o.advice.predictions}
    assert p[("a", "size")] == pytest.approx(0.5, abs=1e-6) and p[("b", "size")] > 0.8
    # the mounting, chosen at 1.04 labels per hour, is stated to add 0.70 per hour answered together
    # with the frames' other requests: below the minimum of 1, passed over; at a minimum of 0.5, asked
    assert [(r.objects[0].key, r.prediction.candidate.kind) for r in batch.plan()] == [
        ("b", "size"), ("a", "size"), ("a", "dims")]
    plan = _planned(frames, min_good_per_hour=0.5, spread=0.01).plan()
    assert [(r.objects[0].key, r.prediction.candidate.kind) for r in plan] == [
        ("b", "size"), ("a", "size"), ("a", "dims"), ("a", "mounting")]
    assert [r.value for r in plan] == pytest.approx([p[("b", "size")], 0.5, 0.25,
                                                     0.25 * 0.5 + (1 - p[("b", "size")]) * p[("b", "mounting")]])
    mounting = plan[-1]
    assert mounting.camera == "cam" and [o.key for o in mounting.objects] == ["a", "b"]
    assert mounting.value * 3600 / 900 > 1.0 > mounting.gain * 3600 / 900 > 0.5
    # stated answered together: a's car after its size and lines is a future of mean 0.8, var 0.02
    one = np.ones(1)
    m = Moments(one * 0.3, one * 0.0, one * 0.01)
    after = [combined_chance(np.array([x]), one * 0.5, [m] * k)[0] for x, k in ((0.2, 1), (0.2, 2), (0.2, 3))]
    assert plan[2].gain == pytest.approx(after[1] - after[0]) and plan[2].gain > plan[2].value
    assert plan[3].gain == pytest.approx(after[2] - after[1] + combined_chance(np.array([0.3]), one * 0.5, [m] * 2)[0]
                                         - p[("b", "size")])
    # a request no longer worth its time is left out; a budget cuts the rest
    assert [r.prediction.candidate.kind for r in _planned(frames, min_good_per_hour=4.0, spread=0.01).plan()] == [
        "size", "size", "dims"]
    # one that left its frame's race is not asked, whatever its first round's futures said
    raced = {**frames, "b": ("cam", [0.3], frames["b"][2] + [("reference-dropped", 0, 10.0, [0.3])])}
    assert [(r.objects[0].key, r.prediction.candidate.kind) for r in _planned(raced, spread=0.01).plan()] == [
        ("b", "size"), ("a", "size"), ("a", "dims")]
    assert [r.objects[0].key for r in _planned(frames, spread=0.01).plan(budget_s=2 * 64.4)] == ["b", "a"]


def test_the_plan_states_the_good_labels_it_may_drop_without_choosing_by_them():
    """Frame a: cars at 0.2, 0.6 and 0.45 (bar 0.5), every future as sure as can be. A size on the
    first lifts it (+0.4) and drops the second (−0.15); lines on the third lift it (+0.1) and bring
    the second back (+0.1). The plan takes both by their lifts; the size's loss is 1, the lines'
    −1. Frame b's good car would fall under its size, which lifts nothing: b gets no request and
    loses nothing."""
    frames = {"a": ("cam", [0.2, 0.6, 0.45], [("size", 0, 64.4, [0.4, -0.15, 0.0]),
                                               ("dims", 2, 183.5, [0.0, 0.1, 0.1])]),
              "b": ("cam", [0.6], [("size", 0, 64.4, [-0.3])])}
    plan = _planned(frames).plan()
    assert [(r.objects[0].key, r.prediction.candidate.kind) for r in plan] == [("a", "size"), ("a", "dims")]
    assert [r.gain for r in plan] == pytest.approx([1.0, 1.0], abs=1e-6)
    assert [r.loss for r in plan] == pytest.approx([1.0, -1.0], abs=1e-6)
    # changes known to 0.1: the lines' +0.1 counts as +0.05, and the third car reaches the bar
    # exactly (good with chance one half)
    shaky = _planned(frames, se=0.1).plan()
    assert [r.gain for r in shaky] == pytest.approx([1.0, 0.5], abs=1e-3)


def test_a_request_the_two_halves_of_its_futures_disagree_on_is_passed_over():
    """Frame a: cars at 0.2 and 0.3 (bar 0.5). Its size lifts the first on the futures it is ranked
    by, but on the others it is stated from it changes nothing: a plan that asked it would state
    0.00 good labels for it. It is passed over, and the lines on the second car, worth their time
    on both, are still asked."""
    from creference_bayes.workflows.advice import Moments

    frames = {"a": ("cam", [0.2, 0.3], [("size", 0, 64.4, [0.4, 0.0]), ("dims", 1, 183.5, [0.0, 0.3])])}
    both = _planned(frames)
    assert [r.prediction.candidate.kind for r in both.plan()] == ["size", "dims"]
    advice = both.objects[0].advice
    size = advice.predictions[0]
    flat = Moments(np.zeros(2), np.zeros(2), np.full(2, 1e-9))
    told_nothing = dataclasses.replace(size, moments=flat, p_good=np.zeros(2), good_gain=0.0)
    advice = dataclasses.replace(advice, predictions=(told_nothing,) + advice.predictions[1:])
    split = dataclasses.replace(both, objects=tuple(dataclasses.replace(o, advice=advice) for o in both.objects))
    plan = split.plan()
    assert [r.prediction.candidate.kind for r in plan] == ["dims"]
    assert plan[0].gain == pytest.approx(1.0, abs=1e-6)


def test_a_stop_quotes_the_figure_it_stopped_by():
    """The advice stops on the futures the requests are ranked by: it states the table's figure (the
    stated half's) and then the ranking half's it stopped by, below the minimum."""
    from creference_bayes.workflows.advice import _recommend_labels

    batch = _planned({"a": (None, [0.2], [("size", 0, 64.4, [0.1])])})
    advice = batch.objects[0].advice
    best = dataclasses.replace(advice.predictions[0], good_gain=0.05, rank_p_good=np.array([0.01]),
                               rank_good_gain=0.01)
    action, reason = _recommend_labels(advice.now, [best], advice.settings, advice.targets)
    assert action == "stop" and "make 0.05 ± 0.00 of them good" in reason
    assert "those that rank the requests, it makes 0.01, 0.56 per human hour, below the minimum 1" in reason


def test_needs_annotation_carries_the_advices_verdicts(advised_batch, tmp_path):
    out = advised_batch / "out"
    assert main(["labels", str(out), "--out", str(tmp_path / "labels"), "--min-quality", "1.0", "--quiet",
                 "--no-figure"]) == 0
    rows = list(csv.DictReader((tmp_path / "labels" / "needs_annotation.csv").open()))
    advice = json.loads((out / "advice" / "advice.json").read_text())
    # the advice was made for P(IoU >= 0.7) >= 0.5, the labels ask for >= 1.0: no verdicts, and why
    assert rows and not any(r["verdict"] for r in rows)
    assert "is for P(IoU ≥ 0.7) ≥ 0.5" in (tmp_path / "labels" / "report.md").read_text()
    assert main(["labels", str(out), "--out", str(tmp_path / "same"), "--quiet", "--no-figure"]) == 0
    rows = list(csv.DictReader((tmp_path / "same" / "needs_annotation.csv").open()))
    verdicts = {(s["key"], v["target"]): v for s in advice["scenes"] for v in s["verdicts"]}
    for r in rows:
        v = verdicts[(r["scene"], r["target"])]
        assert r["verdict"] == v["verdict"] and r["advice"] == v["text"]
        # the two commands agree on which labels are below the bar
        assert v["verdict"] != "good"
    below = {k for k, v in verdicts.items() if v["verdict"] != "good"}
    assert below == {(r["scene"], r["target"]) for r in rows}


def test_the_label_studio_requests_load_their_images_by_the_prefix_and_hide_the_truth(advised_batch, capsys):
    out = advised_batch / "out"
    failed = out / "errors" / "f9.json"  # a frame the batch could not estimate (and no earlier result)
    failed.parent.mkdir(exist_ok=True)
    failed.write_text(json.dumps({"format": "creference-batch-error/1", "key": "f9", "error": "SceneError: …"}))
    try:
        assert main(["advise", str(out), "--draws", "100", "--futures", "20", "--min-good-per-hour", "0",
                     "--out", str(advised_batch / "urls"), "--image-url-prefix", "/data/local-files/?d=frames/"]) == 0
    finally:
        failed.unlink()
    printed = capsys.readouterr().out
    assert f"0 skipped, 1 frame not advised (failed in the batch: {out / 'errors'}); wrote" in printed
    assert re.search(r"\([+-]\d+\.\d\d good labels, [+-]\d+\.\d\d/h\)", printed) and "+-" not in printed, printed
    assert printed.startswith("rank  where  request  (what it adds to the requests above it, stated on other")
    tasks = json.loads((advised_batch / "urls" / "label_studio_requests.json").read_text())
    assert tasks and all(t["data"]["image"] == f"/data/local-files/?d=frames/{t['data']['request_key']}.jpg"
                         for t in tasks)  # the scenes name no image: KEY.jpg, as requests.csv's image column
    plain = json.loads((out / "advice" / "label_studio_requests.json").read_text())
    assert [t["data"]["request_candidate"] for t in plain] == [t["data"]["request_candidate"] for t in tasks]
    assert all(t["data"]["image"] == "" for t in plain)
    assert "ground_truth" in json.loads((advised_batch / "in" / "f0.json").read_text())
    assert "ground_truth" not in json.dumps(tasks)  # workers could read it in the tool


def test_answers_go_into_the_scene_files_and_only_those_frames_are_estimated_again(advised_batch, capsys):
    """Last in this file: it changes the batch the tests above read."""
    from creference_bayes.io.scene import load_scene
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    out = advised_batch / "out"
    path = out / "advice" / "requests.csv"
    rows = list(csv.DictReader(path.open()))
    fields = list(rows[0])
    size = {"rank": "1", "key": "f2", "target": "t0", "kind": "size", "camera": "", "answer": "4.0, 1.8, 1.5"}
    mount = {"rank": "2", "key": "", "target": "", "kind": "mounting", "camera": "rig-B", "answer": "1.6,6,1"}
    bad = dict(size, rank="3", answer="4.0,1.8")
    def apply(answers):
        with (advised_batch / "answers.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows({k: r.get(k, "") for k in fields} for r in answers)
        return main(["advise", str(out), "--apply", str(advised_batch / "answers.csv"), "--quiet"])

    before = {k: (advised_batch / "in" / f"f{k}.json").read_text() for k in range(3)}
    assert apply([dict(size, answer=" ")]) == 2  # the requests as advised, nobody's answer in them yet
    assert "no request is answered yet: fill in the 'answer' column" in capsys.readouterr().err
    # an answer of a kind that comes back as an annotation is said, and nothing is written
    assert apply([dict(size, rank="4", kind="dims", answer="drawn")]) == 0
    assert ("warning: requests row 4 (dims): answered, but only sizes, mountings and measurements without a "
            "segment are put in from requests.csv; drawn lines and segments come back as annotations"
            in capsys.readouterr().err)
    assert before == {k: (advised_batch / "in" / f"f{k}.json").read_text() for k in range(3)}
    assert apply([bad]) == 2  # a usage error, and nothing written
    assert "requests row 3 (size): expected 3 numbers" in capsys.readouterr().err
    assert before == {k: (advised_batch / "in" / f"f{k}.json").read_text() for k in range(3)}
    # a target's length and the distance between two targets: no segment, answered in the csv
    length = {"rank": "5", "key": "f2", "target": "t0", "kind": "reference", "measure": "length", "object": "t0",
              "line_px": "", "answer": "4.1"}
    pair = dict(length, rank="6", measure="distance", object="t1", answer="7.5")
    assert apply([size, length, pair]) == 0
    f2 = load_scene(advised_batch / "in" / "f2.json")
    assert f2.targets[0].size_prior.source == "catalogue" and f2.targets[1].size_prior is None
    added = [(r.measure, r.low, r.line) for r in f2.references[-2:]]
    assert added == [("length", 4.1, None), ("distance", 7.5, None)]
    assert f2.reference_targets[-1] == (0, 1)  # the pair term: between t0 and t1
    text = (advised_batch / "in" / "f2.json").read_text()
    assert apply([size, length, pair]) == 0  # the same answers again: nothing changes
    assert (advised_batch / "in" / "f2.json").read_text() == text
    # batch re-estimates the one frame whose scene changed
    again = run_batch([advised_batch / "in"], out, LocalEngine(1),
                      BatchSettings(seed=0, sampling={"min_ess": 100, "max_steps": 400, "warmup": 200}))
    assert again.keys("done") == ["f2"] and sorted(again.keys("skipped")) == ["f0", "f1"]
    # a camera's mounting goes to every frame of it
    assert apply([mount]) == 0
    for k in (0, 1):
        p = load_scene(advised_batch / "in" / f"f{k}.json").orientation_prior
        assert p.height_median_m == pytest.approx(1.6, rel=0.03) and math.degrees(p.pitch_sd) < 0.55
        assert math.degrees(p.pitch_mean) == pytest.approx(6.0, abs=0.1)
    assert load_scene(advised_batch / "in" / "f2.json").orientation_prior is None

    # the drawn answers, as creference import writes them: the frame's scene without what the
    # tools do not carry (its truth, its priors), with one more set of lines and one more reference
    source = advised_batch / "in" / "f2.json"
    before = load_scene(source)
    imported = scene_to_dict(before)
    for key in ("ground_truth",):
        imported.pop(key, None)
    for t in imported["targets"]:
        t.pop("size_prior", None)
        t.pop("ground_truth", None)
    line = {"worker": "w-new", "corners": (np.asarray(imported["targets"][1]["dimension_lines"][0]["corners"])
                                           + 1.5).tolist()}
    imported["targets"][1]["dimension_lines"].append(line)
    imported["references"].append({**imported["references"][0], "worker": "w-new", "value": 2.5})
    imported["references"][-1].pop("range", None)
    folder = advised_batch / "imported"
    folder.mkdir()
    (folder / "f2.json").write_text(json.dumps(imported))
    (folder / "ghost.json").write_text(json.dumps(imported))
    assert main(["advise", str(out), "--merge", str(folder), "--quiet"]) == 0
    assert f"warning: {folder / 'ghost.json'}: no frame of {out} has this name or image; skipped" in (
        capsys.readouterr().err)
    after = load_scene(source)
    assert len(after.targets[1].dimension_lines) == len(before.targets[1].dimension_lines) + 1
    assert len(after.references) == len(before.references) + 1 and after.references[-1].low == 2.5
    assert after.ground_truth == before.ground_truth and after.targets[0].size_prior == before.targets[0].size_prior
    text = source.read_text()
    assert main(["advise", str(out), "--merge", str(folder), "--quiet"]) == 0  # merged already: nothing new
    assert source.read_text() == text


def test_bad_advice_settings_are_named(capsys):
    with pytest.raises(ValueError, match="kinds: expected some of"):
        AdviceSettings(kinds=("dims", "catalogue"))
    with pytest.raises(ValueError, match="min_quality"):
        AdviceSettings(min_quality=0.0)
    with pytest.raises(ValueError, match="objective"):
        AdviceSettings(objective="boxes")
    for every in (2, 0, -1):  # the race's rounds: an odd count, each holding futures of both halves
        with pytest.raises(ValueError, match=f"race_every: expected an odd integer >= 1, got {every}"):
            AdviceSettings(race_every=every)
    for args, message in ((["--requests", "dims,foo"], "--requests: expected some of"),
                          (["--min-quality", "1.5"], "--min-quality"), (["--score-iou", "1"], "--score-iou")):
        assert main(["advise", "nothing.json", *args]) == 2
        assert message in capsys.readouterr().err


@pytest.mark.slow  # another advice of the batch; test_batch.py checks the line per scene of the same engine
def test_advise_batch_prints_a_line_per_scene_when_stderr_is_not_a_terminal(advised_batch, capsys):
    """An advice of a batch run into a log file said nothing until its end (issue 64): a line per
    frame advised, naming it."""
    import re

    assert main(["advise", str(advised_batch / "out"), "--draws", "100", "--futures", "20", "--min-good-per-hour",
                 "0", "--out", str(advised_batch / "logged")]) == 0  # capsys: standard error is not a terminal
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("advice ")]
    assert sorted(re.fullmatch(r"advice [123]/3: (f[012]) advised \(\d+ s\)", line).group(1) for line in lines) == [
        "f0", "f1", "f2"], lines


def _advice_files(folder) -> tuple[str, list]:
    """requests.csv (the plan) and advice.json's scenes and ranking, without the time each took."""
    data = json.loads((folder / "advice.json").read_text())
    for s in data["scenes"]:
        s.pop("seconds", None)
    return (folder / "requests.csv").read_text(), [data["scenes"], data["ranking"], data["skipped"]]


def _advise_into(batch, out, *engine) -> tuple[str, list]:
    assert main(["advise", str(batch / "out"), "--draws", "100", "--futures", "20", "--min-good-per-hour", "0",
                 "--quiet", "--out", str(batch / out), *engine]) == 0
    return _advice_files(batch / out)


@pytest.mark.slow  # three advices of the batch; test_advice.py checks the worker count on a smaller one
def test_advise_batch_gives_the_same_plan_on_one_worker_or_two(advised_batch):
    """issue 64: the frames run on batch's engine; a frame's seed is fixed by its key, so the plan
    and the advice do not depend on the number of workers."""
    one = _advise_into(advised_batch, "one_worker", "--workers", "1")
    assert one[0].count("\n") > 1  # a plan with requests
    assert _advise_into(advised_batch, "two_workers", "--workers", "2") == one
    assert _advise_into(advised_batch, "default_workers") == one  # the default: the machine's cores


@pytest.mark.slow  # a cluster and an advice; test_batch.py runs the same engine on a LocalCluster
def test_advise_batch_runs_on_a_dask_scheduler_with_the_same_numbers(advised_batch):
    """issue 64: --scheduler as creference batch has it; the numbers are those of local processes."""
    distributed = pytest.importorskip("distributed")

    local = _advise_into(advised_batch, "local", "--workers", "1")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        dask = _advise_into(advised_batch, "dask", "--scheduler", cluster.scheduler_address)
    assert dask == local


def test_advise_batch_takes_batch_s_engine_options(advised_batch, monkeypatch, capsys):
    """issue 64: --workers defaults to the machine's cores as for creference batch (the frames run
    on its LocalEngine, no more workers than frames); --workers with --scheduler is refused as there."""
    from creference_bayes.workflows.batch import engines

    made = []

    class Spy(engines.LocalEngine):
        def __init__(self, workers=None):
            made.append(workers)
            super().__init__(workers)

    monkeypatch.setattr(engines, "LocalEngine", Spy)
    assert main(["advise", str(advised_batch / "out"), "--draws", "100", "--futures", "20", "--requests", "size",
                 "--quiet", "--out", str(advised_batch / "spied")]) == 0
    cores = engines.default_workers()  # one process a core, no more than the three frames; one: this process
    assert made == ([min(cores, 3)] if cores > 1 else [])
    assert main(["advise", str(advised_batch / "out"), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "with --scheduler the Dask workers decide" in capsys.readouterr().err
