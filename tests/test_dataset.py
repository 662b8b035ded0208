"""The data-set layer (workflows/batch/dataset.py): what frames share, declared once, learnt by
default from a MAP first pass, handed back to each frame leaving it out; overrides win."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import truth_scene

from creference_bayes.io.scene import parse_scene
from creference_bayes.workflows.batch import BatchSettings, run_batch
from creference_bayes.workflows.batch.dataset import (SHARED, DataSet, Pool, Reading, hand_back, plan,
                                                      scale_depths)
from creference_bayes.workflows.batch.engines import LocalEngine

FAST = {"min_ess": 50, "max_steps": 300, "warmup": 100}


def _scene(seed, camera="cam-A", n_annotations=2, **kw):
    d, _ = truth_scene(seed, m=2, noise_px=1.0, n_annotations=n_annotations, sizes_known=False, focal_px=1400.0, **kw)
    if camera is not None:
        d["camera"]["id"] = camera
    return d


@pytest.fixture(scope="module")
def four_frames(tmp_path_factory):
    """Four frames of one camera, its focal length removed; MAP only (the layer reads a MAP's
    Laplace approximation, so no sampler is needed to test it)."""
    root = tmp_path_factory.mktemp("dataset")
    (root / "in").mkdir()
    for seed in range(4):
        (root / "in" / f"f{seed}.json").write_text(json.dumps(_scene(seed)))
    settings = BatchSettings(seed=1, posterior=False)
    report = run_batch([root / "in"], root / "out", LocalEngine(1), settings)
    return root, settings, report


def test_frames_of_one_camera_pool_it_by_default_and_each_result_says_so(four_frames):
    root, settings, report = four_frames
    assert report.ok and (root / "out" / "first_pass" / "results" / "f0.json").exists()
    assert report.dataset["focal_length_px"]["groups"]["cam-A"]["frames"] == 4
    assert report.dataset_notes == []  # everything planned was learnt
    assert json.loads((root / "out" / "batch.json").read_text())["dataset"] == report.dataset
    for k in range(4):
        res = json.loads((root / "out" / "results" / f"f{k}.json").read_text())
        took = res["dataset"]["focal_length_px"]
        assert took["from"] == "data set" and took["group"] == "cam-A" and took["held"]
        assert took["frames_offered"] == 4  # held: the camera's one value, each frame's evidence once in it
        assert took["shared_scale_log_sd"] == took["log_sd"] >= SHARED["log_focal"].floor  # how sure, floor in
        assert abs(math.log(took["median"] / 1400.0)) < 4 * took["log_sd"]
        assert res["camera"]["map"]["focal_length_px"] == took["median"] == report.dataset["focal_length_px"][
            "groups"]["cam-A"]["median"] and "focal_length_px" not in res["camera"]["free"]
        assert {"height_m", "pitch_deg", "roll_deg"} <= set(res["dataset"]) & set(res["rig"])  # the mounting too
    again = run_batch([root / "in"], root / "out", LocalEngine(1), settings)
    assert again.keys("skipped") == [f"f{k}" for k in range(4)]


def test_plot_draws_each_frames_reading_against_the_pool(four_frames, tmp_path, capsys):
    """``creference plot`` of a batch's folder draws the data set: a panel per quantity and group,
    with every frame's reading (the summary keeps them, in natural units, one sd each side) and
    the pool's value; a batch.json edited by hand is refused naming the key."""
    from creference_bayes.cli.main import main
    from creference_bayes.vision.dataset_figures import dataset_panels

    root, _, report = four_frames
    block = report.dataset["focal_length_px"]["groups"]["cam-A"]
    assert len(block["values"]) == 4 and {v["frame"] for v in block["values"]} == {f"f{k}" for k in range(4)}
    for v in block["values"]:
        assert v["low"] < v["value"] < v["high"] and abs(math.log(v["value"] / 1400.0)) < 1.0
    panels = dataset_panels(report.dataset)
    focal = next(p for p in panels if p["label"] == "focal_length_px")
    assert focal["group"] == "cam-A" and focal["log"] and focal["prior"] is None  # one value, held
    assert focal["center"] == block["median"] and focal["pool"][0] < block["median"] < focal["pool"][1]
    np.testing.assert_allclose(np.sort(focal["values"][:, 0]), sorted(v["value"] for v in block["values"]))
    height = next(p for p in panels if p["label"] == "height_m")
    assert height["prior"][0] < height["pool"][0] and height["prior"][1] > height["pool"][1]  # spread: wider
    assert main(["plot", str(root / "out"), "--out", str(tmp_path / "figs")]) == 0
    assert (tmp_path / "figs" / "dataset.png").stat().st_size > 10_000
    doc = json.loads((root / "out" / "batch.json").read_text())
    doc["dataset"]["focal_length_px"]["groups"]["cam-A"]["values"][2]["value"] = "big"
    (tmp_path / "batch.json").write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["plot", str(tmp_path / "batch.json"), "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "dataset.focal_length_px.groups.cam-A.values[2].value: expected a finite number, got 'big'" in err
    assert not (tmp_path / "bad" / "dataset.png").exists()
    del doc["dataset"]
    (tmp_path / "batch.json").write_text(json.dumps(doc))
    assert main(["plot", str(tmp_path), "--out", str(tmp_path / "bad")]) == 2
    assert "learnt nothing from its frames" in capsys.readouterr().err


def test_a_quantity_the_batch_could_not_learn_is_said_with_what_it_lacked():
    """A camera's frames whose focal-length readings are all too weak to pool (sd above the
    quantity's bar) learn nothing: the batch says so, with how many frames were informative and how
    many a pool needs; a camera of one frame, which has nothing to share, is not mentioned; a
    pooled group is not."""
    weak = [Reading(k, "cam-A", 7.2 + 0.1 * i, 1.0) for i, k in enumerate(("a", "b", "c"))]  # sd 1 in log
    lone = [Reading("d", "cam-B", 7.0, 400.0)]
    sharp = [Reading(k, "cam-C", 7.0, 400.0) for k in ("e", "f")]  # sd 0.05
    ds = DataSet({"log_focal": Pool(SHARED["log_focal"], weak + lone + sharp)}, ("log_focal",),
                 {k: c for k, c in zip("abcdef", ["cam-A"] * 3 + ["cam-B"] + ["cam-C"] * 2)})
    lines = ds.not_learnt()
    assert len(lines) == 1 and lines[0].startswith("focal_length_px of cam-A: not learnt: 0 of 3 frames read it within "
                                                   "an sd of 0.25 in log, 2 frames needed")
    assert "cam-C" in ds.summary()["focal_length_px"]["groups"]
    assert DataSet({}, ("log_ref_scale",), {}).not_learnt() == ["ref_scale: not learnt: no frame could read it"]


def test_the_table_says_how_many_of_a_cameras_frames_could_read_a_quantity():
    """Six frames of one camera, three of which read its pitch (the others' own prior decides it,
    a calibrated mounting say): the table's row counts 3 used of 3 offered of the camera's 6, and
    its legend says what offered means; a camera whose every frame read it is counted as before."""
    from creference_bayes.workflows.batch.dataset import dataset_lines

    readings = [Reading(k, "cam-A", math.radians(4.0 + 0.2 * i), math.radians(0.5) ** -2) for i, k in enumerate("abc")]
    readings += [Reading(k, "cam-B", math.radians(2.0 + 0.2 * i), math.radians(0.5) ** -2) for i, k in enumerate("gh")]
    ds = DataSet({"pitch": Pool(SHARED["pitch"], readings)}, ("pitch",),
                 {**{k: "cam-A" for k in "abcdef"}, "g": "cam-B", "h": "cam-B"})
    groups = ds.summary()["pitch_deg"]["groups"]
    assert groups["cam-A"]["group_frames"] == 6 and groups["cam-B"]["group_frames"] == 2
    lines = dataset_lines(ds.summary())
    row = next(line for line in lines if "cam-A" in line)
    assert " 3/3 of 6 " in row
    assert " 2/2 " in next(line for line in lines if "cam-B" in line)
    assert "of 2" not in next(line for line in lines if "cam-B" in line)
    assert any("offers none" in line for line in lines)


def test_dataset_none_estimates_every_frame_alone(four_frames, tmp_path):
    root, settings, _ = four_frames
    report = run_batch([root / "in" / "f0.json", root / "in" / "f1.json"], tmp_path / "o", LocalEngine(1),
                       replace(settings, dataset="none"))
    assert report.ok and not report.dataset and not (tmp_path / "o" / "first_pass").exists()
    res = json.loads((tmp_path / "o" / "results" / "f0.json").read_text())
    assert "dataset" not in res and res["camera"]["setup"]["focal_prior"]["source"] == "default"


def test_plan_learns_only_what_there_is_to_learn():
    two = [parse_scene(_scene(s)) for s in range(2)]
    assert plan(two, BatchSettings()) == ("log_focal", "log_height", "pitch", "roll")
    assert plan(two, BatchSettings(rig="focal")) == ("log_focal",)
    assert plan(two, BatchSettings(dataset="none")) == ()
    alone = [parse_scene(_scene(s, camera=None)) for s in range(2)]
    assert plan(alone, BatchSettings()) == ()  # no camera shared, no population from 2 frames
    many = [parse_scene(_scene(s, camera=None)) for s in range(6)]  # 12 targets in 6 frames: a population
    assert plan(many, BatchSettings()) == ("log_distance",)
    assert plan(many, BatchSettings(distance_range=(5.0, 60.0))) == ()  # a hand-set range wins
    refs = [parse_scene(_scene(s, camera=None, n_refs=2)) for s in range(3)]
    assert plan(refs, BatchSettings()) == ("log_ref_scale",)
    assert plan(refs, BatchSettings(options={"ref_scale_median": 0.4})) == ()


def test_the_corner_scale_is_learnt_from_the_residuals_only_where_no_object_is_annotated_twice():
    once = [parse_scene(_scene(s, camera=None, n_annotations=1)) for s in range(2)]
    assert plan(once, BatchSettings()) == ("corner_scale",)
    assert plan(once, BatchSettings(options={"target_sigma": 3.0})) == ()  # a hand-set scale wins
    assert plan(once, BatchSettings(pool_scale=False)) == ()  # --own-scale
    assert plan(once[:1], BatchSettings()) == ()  # no other frame to read it from
    twice = [parse_scene(_scene(s, camera=None)) for s in range(2)]
    assert plan(once + twice[:1], BatchSettings()) == ()  # read from the object annotated twice instead


@pytest.mark.parametrize("noise_px", [2.0, 6.0])
def test_a_crowd_whose_objects_are_each_annotated_once_has_its_corner_scale_read_from_the_residuals(tmp_path,
                                                                                                     noise_px):
    """Frames of three objects, one set of lines each drawn with ``noise_px`` per corner
    coordinate, the focal length given: no object annotated twice says how far the crowd's corners
    stray, the first pass's residuals do. Each frame is handed the other frames' reading (about
    the crowd's noise, where the default assumes 5 px), and says so."""
    for seed in range(4):
        d, _ = truth_scene(seed, m=3, noise_px=noise_px, n_annotations=1, sizes_known=False, focal_known=True,
                           focal_px=1400.0)
        (tmp_path / "in").mkdir(exist_ok=True)
        (tmp_path / "in" / f"f{seed}.json").write_text(json.dumps(d))
    report = run_batch([tmp_path / "in"], tmp_path / "out", LocalEngine(1), BatchSettings(seed=1, posterior=False))
    assert report.ok and report.dataset_notes == []
    pooled = report.dataset["corner_scale_px"]["groups"]["crowd"]
    assert 0.7 * noise_px < pooled["sd"] < 1.4 * noise_px and pooled["frames"] == 4
    for k in range(4):
        res = json.loads((tmp_path / "out" / "results" / f"f{k}.json").read_text())
        took = res["dataset"]["corner_scale_px"]
        assert took["from"] == "data set" and took["read"] == "the first pass's residuals"
        assert 0.6 * noise_px < took["sd"] < 1.5 * noise_px and took["dof"] > 5
        if noise_px == 2.0:  # read at 5 px first, then fitted again at about the crowd's scale
            assert 0.7 * noise_px < took["fitted_at_px"] < 1.4 * noise_px
            assert (tmp_path / "out" / "first_pass" / "at_crowd_scale" / "results" / f"f{k}.json").exists()
        scene = json.loads((tmp_path / "out" / "scenes" / f"f{k}.json").read_text())
        assert scene["corner_scale"]["sd_px"] == took["sd"]


def test_the_first_pass_is_fitted_again_only_where_its_residuals_read_a_scale_far_from_the_fits():
    """:meth:`DataSet.refit_at`: the pooled residual scale when it is a quarter or more from the
    default 5 px the first pass was fitted at (either way), once; never without residuals."""
    def at(sd, fitted=None):
        return DataSet({}, ("corner_scale",), residuals={"a": (sd**2 * 100, 100.0), "b": (sd**2 * 50, 50.0)},
                       fitted_at_px=fitted).refit_at()

    assert at(2.0) == 2.0 and at(8.0) == 8.0 and at(3.9) == 3.9 and at(6.5) == 6.5
    assert at(5.0) is None and at(4.2) is None and at(6.1) is None
    assert at(2.0, fitted=2.0) is None
    assert DataSet({}, ("corner_scale",)).refit_at() is None


def test_a_crowd_of_careful_and_careless_frames_hands_each_frame_its_own_scale():
    """Frames whose residuals read one crowd scale (4 px) are each handed the others' pool; frames
    drawn at 5 px and at 10 px (a careful and a careless half) read as a spread (Smyth's
    scaled inverse-χ² prior, d₀ finite), and each frame is handed the others' prior updated by its
    own residuals: on average nearer its own scale than the pool is."""
    from creference_bayes.workflows.batch.dataset import scale_spread

    rng = np.random.default_rng(3)
    dof = rng.uniform(2.0, 12.0, 200)
    one = {f"f{k}": (16.0 * rng.chisquare(d), d) for k, d in enumerate(dof)}
    assert scale_spread(np.array([r[0] for r in one.values()]), dof) is None
    ds = DataSet({}, ("corner_scale",), residuals=one)
    totals = (sum(r[0] for r in one.values()), sum(dof))
    for k in ("f0", "f1"):
        squares, d = totals[0] - one[k][0], totals[1] - one[k][1]
        assert ds.corner_scale_of(k) == (float(f"{math.sqrt(squares / d):.2g}"), float(f"{d:.1g}"))

    true_sd = np.where(np.arange(200) % 2 == 0, 5.0, 10.0)
    two = {f"f{k}": (true_sd[k] ** 2 * rng.chisquare(d), d) for k, d in enumerate(dof)}
    spread = scale_spread(np.array([r[0] for r in two.values()]), dof)
    assert spread is not None and 2.0 < spread[1] < 20.0 and 5.0 < math.sqrt(spread[0]) < 10.0
    ds = DataSet({}, ("corner_scale",), residuals=two)
    pooled = ds.corner_scale_of(None)[0]
    handed = np.array([ds.corner_scale_of(f"f{k}")[0] for k in range(200)])
    careful, careless = handed[true_sd == 5.0], handed[true_sd == 10.0]
    assert np.median(careful) < pooled < np.median(careless)
    assert np.mean(np.abs(np.log(handed / true_sd))) < np.mean(np.abs(np.log(pooled / true_sd)))
    assert all(ds.corner_scale_of(f"f{k}")[1] < 40 for k in range(5))  # d₀ + its own, not the pool's Σ dof
    assert "spread_dof" in ds.summary()["corner_scale_px"]["groups"]["crowd"]
    from creference_bayes.workflows.batch.dataset import dataset_lines
    assert any("frames spread: each its own" in line for line in dataset_lines(ds.summary()))
    # a frame's spread leaves its own reading out, as the readings without it give it
    others = {k: r for k, r in two.items() if k != "f3"}
    assert ds.scale_spread_of("f3") == pytest.approx(
        scale_spread(np.array([r[0] for r in others.values()]), np.array([r[1] for r in others.values()])))
    # a frame (or a service's task) without residuals of its own is handed the spread's prior itself
    s0, d0 = ds.scale_spread_of("task")
    assert ds.corner_scale_of("task") == (float(f"{math.sqrt(s0):.2g}"), float(f"{d0:.1g}"))


def test_one_outlying_frame_or_a_few_frames_are_no_spread_of_the_crowds_scale():
    """One frame whose corners sit almost exactly on their projection (squares 0.001 px²) among 100
    frames of one 4 px scale, or another 50 times noisier, does not make a spread (its fourth
    moment makes the spread's standard error large): every frame keeps the pool; nor do nine
    frames, however spread (too few to read a spread from)."""
    from creference_bayes.workflows.batch.dataset import scale_spread

    rng = np.random.default_rng(5)
    dof = np.full(101, 6.0)
    for factor in (1e-3 / (16.0 * 6.0), 50.0):
        squares = 16.0 * rng.chisquare(dof)
        squares[0] *= factor
        assert scale_spread(squares, dof) is None
        ds = DataSet({}, ("corner_scale",), residuals={f"f{k}": (q, d) for k, (q, d) in enumerate(zip(squares, dof))})
        assert ds.corner_scale_of("f1")[1] > 100  # the others' pool, its degrees of freedom summed
    nine = np.array([1.0, 100.0] * 4 + [1.0]) * 6.0
    assert scale_spread(nine, np.full(9, 6.0)) is None and scale_spread(np.append(nine, 600.0), np.full(10, 6.0))


def _population(seed=0, frames=12, per_frame=3, median=15.0, log_sd=0.5, noise=0.1):
    rng = np.random.default_rng(seed)
    truth = rng.normal(math.log(median), log_sd, (frames, per_frame))
    return [Reading(f"f{i}", "street", float(truth[i, j] + rng.normal(0, noise)), noise**-2)
            for i in range(frames) for j in range(per_frame)]


def test_a_distance_population_is_fitted_from_simulated_distances():
    est = Pool(SHARED["log_distance"], _population(frames=40)).estimate("street")
    assert math.exp(est.center) == pytest.approx(15.0, rel=0.15)
    assert est.tau == pytest.approx(0.5, rel=0.2) and est.readings == 120 and est.frames == 40
    # a frame is handed the next target's distribution: the spread and the mean's uncertainty
    assert est.prior_sd == pytest.approx(math.sqrt(est.var + est.tau**2))
    # too few frames: no population (MIN_POPULATION_FRAMES others)
    assert Pool(SHARED["log_distance"], _population(frames=5)).estimate("street", leave_out="f0") is None


def test_leave_one_out_leaves_every_reading_of_the_frame_out():
    readings = _population()
    moved = [replace(r, mean=r.mean + 3.0) if r.key == "f0" else r for r in readings]
    a = Pool(SHARED["log_distance"], readings).estimate("street", leave_out="f0")
    b = Pool(SHARED["log_distance"], moved).estimate("street", leave_out="f0")
    assert (a.center, a.var, a.tau) == (b.center, b.var, b.tau) and "f0" not in a.keys
    c = Pool(SHARED["log_distance"], moved).estimate("street", leave_out="f1")
    assert c.center > a.center  # another frame's pool does see f0's targets


@pytest.mark.parametrize("seeds", [range(2), pytest.param(range(2, 5), marks=pytest.mark.slow)])
def test_targets_of_two_settings_under_one_group_are_not_handed_one_population(seeds):
    """Indoor (4 m) and outdoor (25 m) frames without camera ids share one group: the readings look
    like two populations (a two-component mixture beats one by BIC), the pool says so and no frame
    is handed it (each keeps the default location prior, its block says why); one population of
    the same size and spread, readings of uneven precision, is handed back (seeds 0–4; 0–1 in the default run)."""
    from creference_bayes.workflows.batch.dataset import TWO_POPULATIONS, two_populations

    for seed in seeds:
        indoor = _population(seed, frames=20, median=4.0, log_sd=0.3, noise=0.2)
        outdoor = [replace(r, key=f"g{r.key}") for r in _population(seed + 10, frames=20, median=25.0, log_sd=0.3,
                                                                    noise=0.2)]
        pool = Pool(SHARED["log_distance"], indoor + outdoor)
        assert pool.mixed["street"] and TWO_POPULATIONS in pool.estimate("street", leave_out="f0").check.warnings
        # 30 indoor frames and 10 outdoor: against one centre the readings disagree (|D| > 2), which
        # the two populations already say; one warning for the one cause
        unequal = Pool(SHARED["log_distance"], _population(seed, frames=30, median=4.0, log_sd=0.3, noise=0.2)
                       + outdoor[:30]).estimate("street", leave_out="f0")
        assert abs(unequal.check.d) > 2 and unequal.check.warnings == (TWO_POPULATIONS,)
        one = _population(seed, frames=40, median=12.0, log_sd=0.6, noise=0.1)
        rng = np.random.default_rng(seed)
        uneven = [replace(r, precision=float(rng.uniform(0.15, 0.6)) ** -2) for r in one]
        assert not Pool(SHARED["log_distance"], uneven).mixed["street"]
        assert not two_populations(np.array([r.mean for r in uneven]), np.array([r.precision for r in uneven]))
        # a second population of fewer targets than a population needs (MIN_POPULATION_TARGETS) is none
        few = indoor + outdoor[:9]
        m, p = np.array([r.mean for r in few]), np.array([r.precision for r in few])
        assert two_populations(m, p, min_each=8) and not two_populations(m, p)
    keys = {r.key: "street" for r in indoor + outdoor}
    ds = DataSet({"log_distance": pool}, ("log_distance",), keys)
    _, kwargs, block, _ = hand_back(ds, "f0", parse_scene(_scene(0, camera=None)), BatchSettings())
    assert "location_prior" not in kwargs
    assert block["distance_m"] == {"from": "the frame", "group": "street", "why": TWO_POPULATIONS}


def test_a_setting_the_scenes_name_is_handed_its_population_even_with_two_modes():
    """The same two-mode readings (4 m and 25 m), but ``street`` is a setting the scenes name: the
    user says its frames are one setting, so the pool is handed back, as one population wide enough
    for both modes (its random-effects spread), and says it has two modes; a group nobody named
    keeps the guard."""
    from creference_bayes.models.location_prior import LocationPrior
    from creference_bayes.workflows.batch.dataset import TWO_MODES, TWO_POPULATIONS

    near = _population(0, frames=20, median=4.0, log_sd=0.3, noise=0.2)
    far = [replace(r, key=f"g{r.key}") for r in _population(10, frames=20, median=25.0, log_sd=0.3, noise=0.2)]
    named = Pool(SHARED["log_distance"], near + far, named=frozenset({"street"}))
    est = named.estimate("street", leave_out="f0")
    assert named.mixed["street"] and est.check.warnings == (TWO_MODES,)
    # wide enough for both: the modes are log(25 / 4) = 1.83 apart, each 0.3 wide
    assert est.prior_sd > 0.8 and math.log(4.0) < est.center < math.log(25.0)
    unnamed = Pool(SHARED["log_distance"], near + far, named=frozenset({"indoor"}))
    assert TWO_POPULATIONS in unnamed.estimate("street", leave_out="f0").check.warnings
    keys = {r.key: None for r in near + far}
    ds = DataSet({"log_distance": named}, ("log_distance",), keys, {k: "street" for k in keys})
    _, kwargs, block, _ = hand_back(ds, "f0", parse_scene(_scene(0, camera=None)), BatchSettings())
    prior = kwargs["location_prior"]
    assert isinstance(prior, LocationPrior) and prior.population[1] == pytest.approx(est.prior_sd, abs=1e-4)
    assert block["distance_m"]["from"] == "data set" and block["distance_m"]["group"] == "street"
    assert block["distance_m"]["warnings"] == [TWO_MODES]


def test_frames_that_name_their_setting_get_the_population_of_their_setting(tmp_path):
    """One data set, no camera ids, frames of two settings (targets 3–6 m and 25–50 m away): each
    scene that names its ``setting`` is pooled with its setting's frames only and handed that
    population (a camera may take photos of both, so the setting is not the camera's); the same
    frames naming none are one group."""
    for named in (True, False):
        folder = tmp_path / ("named" if named else "unnamed")
        (folder / "in").mkdir(parents=True)
        for k in range(12):
            near = k % 2 == 0
            d, _ = truth_scene(k, m=2, noise_px=1.0, sizes_known=False, focal_known=True, focal_px=1400.0,
                               ground_sd_m=0.05, depth=(3.0, 6.0) if near else (25.0, 50.0))
            if named:
                d["setting"] = "room" if near else "street"
            (folder / "in" / f"f{k:02d}.json").write_text(json.dumps(d))
        report = run_batch([folder / "in"], folder / "out", LocalEngine(1), BatchSettings(seed=1, posterior=False))
        assert report.ok
        groups = report.dataset["distance_m"]["groups"]
        if not named:
            assert set(groups) == {"data set"}
            continue
        assert set(groups) == {"room", "street"}
        assert 3.0 < groups["room"]["median"] < 6.0 and 25.0 < groups["street"]["median"] < 50.0
        assert groups["room"]["frames"] == groups["street"]["frames"] == 6 and not groups["room"]["warnings"]
        for k in range(12):
            res = json.loads((folder / "out" / "results" / f"f{k:02d}.json").read_text())
            took = res["dataset"]["distance_m"]
            assert took["from"] == "data set" and took["group"] == ("room" if k % 2 == 0 else "street")
            assert took["frames_offered"] == 10  # the readings of its setting's 5 other frames, 2 targets each
            prior = res["provenance"]["location_population"]
            assert (3.0 < prior[0] < 6.0) if k % 2 == 0 else (25.0 < prior[0] < 50.0)
            scene = json.loads((folder / "out" / "scenes" / f"f{k:02d}.json").read_text())
            assert scene["setting"] == took["group"]  # the batch's copy keeps it


def test_a_frame_keeps_its_setting_without_a_first_pass_and_a_setting_named_as_a_camera_is_said(tmp_path):
    """The batch gives every frame's setting (a frame whose first pass failed keeps its group);
    a setting named as the group of frames that name none (a camera id, or "data set") makes one
    group of both, and the batch says so."""
    (tmp_path / "first_pass").mkdir()
    frames = [("a", "cam-A"), ("b", "cam-A"), ("c", None)]
    ds = DataSet.from_first_pass(frames, tmp_path / "first_pass", ("log_distance",), settings={"a": "room"})
    assert [ds.group_of("log_distance", k) for k in "abc"] == ["room", "cam-A", "data set"]
    assert not any("also the group" in line for line in ds.not_learnt())
    for clash, says in (("cam-A", "camera 'cam-A'"), ("data set", "neither setting nor camera")):
        ds = DataSet.from_first_pass(frames, tmp_path / "first_pass", ("log_distance",), settings={"a": clash})
        (line,) = [line for line in ds.not_learnt() if "also the group" in line]
        assert line.startswith(f"distance_m of {clash}: the setting {clash!r} is also") and says in line


def test_a_task_of_the_service_takes_the_population_of_the_setting_it_names():
    """``creference serve`` in a batch folder (serve/priors.py): a task that names its ``setting``
    is handed that setting's population, one that names none its camera's group's."""
    from creference_bayes.io.scene import scene_fingerprint
    from creference_bayes.serve.predictions import Frame
    from creference_bayes.serve.priors import DataSetPriors

    room = [replace(r, group="room") for r in _population(0, median=4.0, log_sd=0.3)]
    street = [replace(r, key=f"g{r.key}", group="street") for r in _population(1, median=30.0, log_sd=0.3)]
    keys = {r.key: None for r in room + street}
    ds = DataSet({"log_distance": Pool(SHARED["log_distance"], room + street)}, ("log_distance",), keys,
                 setting_of={r.key: r.group for r in room + street})
    priors = DataSetPriors(Path("."), ds, (), BatchSettings())
    for setting, median in (("room", 4.0), ("street", 30.0)):
        d = _scene(0, camera=None)
        d["setting"] = setting
        scene = parse_scene(d)
        frame = priors.frame("task", Frame(scene, scene_fingerprint(scene)))
        assert frame.dataset["distance_m"]["group"] == setting
        assert frame.kwargs["location_prior"].population[0] == pytest.approx(median, rel=0.25)
    scene = parse_scene(_scene(0, camera=None))
    assert "distance_m" not in (priors.frame("task", Frame(scene, scene_fingerprint(scene))).dataset or {})


def test_overrides_win_and_are_recorded():
    pools = {"log_distance": Pool(SHARED["log_distance"], _population()),
             "log_ref_scale": Pool(SHARED["log_ref_scale"], [Reading(f"f{i}", "crowd", math.log(0.3), 400.0)
                                                             for i in range(12)]),
             "log_focal": Pool(SHARED["log_focal"], [Reading(f"f{i}", "street", 7.0, 400.0) for i in range(12)])}
    ds = DataSet(pools, tuple(pools), {f"f{i}": "street" for i in range(12)})
    d = _scene(0, camera="street")
    scene = parse_scene(d)
    _, kwargs, block, _ = hand_back(ds, "f0", scene, BatchSettings())
    assert kwargs["ref_scale_median"] == pytest.approx(0.3) and block["ref_scale"]["from"] == "data set"
    assert kwargs["location_prior"].population[0] == pytest.approx(15.0, rel=0.2)
    assert block["focal_length_px"]["from"] == "data set"
    d["camera"]["focal_length_px"] = 1400.0
    own = BatchSettings(distance_range=(5.0, 60.0), options={"ref_scale_median": 0.5})
    scene, kwargs, block, _ = hand_back(ds, "f0", parse_scene(d), own)
    assert kwargs == {} and scene.focal_prior is None
    assert block["distance_m"] == {"from": "override", "why": "--distance-range 5,60"}
    assert block["ref_scale"] == {"from": "override", "why": "--option ref_scale_median=0.5"}
    assert block["focal_length_px"] == {"from": "override", "why": "the scene's own focal length"}


def test_the_location_population_is_a_prior_a_result_records_and_rebuilds():
    from creference_bayes import estimate
    from creference_bayes.models.location_prior import LocationPrior
    from creference_bayes.pipeline import rebuild_model

    with pytest.raises(ValueError, match="population"):
        LocationPrior(population=(15.0, 0.0))
    near = LocationPrior(population=(10.0, 0.3))
    # a log-normal factor in the distance on the default's 1/z: relative to it every direction alike
    assert near.relative_log_prior(3.0, 4.0) == pytest.approx(near.relative_log_prior(0.0, 5.0))
    assert near.relative_log_prior(0.0, 10.0) > near.relative_log_prior(0.0, 30.0)
    # ... and a wide population is the default prior again (a flat factor), not another prior
    wide, default = LocationPrior(population=(10.0, 1e3)), LocationPrior()
    x, z = np.array([0.0, 5.0, -20.0]), np.array([3.0, 40.0, 90.0])
    assert np.ptp(wide.neg_log(x, z) - default.neg_log(x, z)) < 1e-4
    d = _scene(0)
    res = estimate(parse_scene(d), posterior=False, seed=0, location_prior=near).to_dict()
    assert res["provenance"]["location_population"] == [10.0, 0.3]
    assert rebuild_model(res, parse_scene(d)).location.population == (10.0, 0.3)


def test_cli_dataset_none_turns_the_layer_off(tmp_path, capsys):
    from creference_bayes.cli.main import main

    for seed in range(2):
        (tmp_path / f"s{seed}.json").write_text(json.dumps(_scene(seed)))
    assert main(["batch", str(tmp_path / "s0.json"), str(tmp_path / "s1.json"), "--out", str(tmp_path / "o"),
                 "--dataset", "none", "--no-posterior", "--workers", "1", "--quiet"]) == 0
    assert not (tmp_path / "o" / "first_pass").exists()


def test_a_batch_that_learns_names_its_first_pass_in_its_progress_lines(tmp_path, capsys):
    """Two passes over the same scenes log a line per scene each: the first pass's lines say so,
    the second's are the batch's."""
    from creference_bayes.cli.main import main

    for seed in range(2):
        (tmp_path / f"s{seed}.json").write_text(json.dumps(_scene(seed)))
    assert main(["batch", str(tmp_path / "s0.json"), str(tmp_path / "s1.json"), "--out", str(tmp_path / "o"),
                 "--no-posterior", "--workers", "1"]) == 0
    err = capsys.readouterr().err.splitlines()
    first = [line.split(":")[0] for line in err if line.startswith("first pass ")]
    second = [line.split(":")[0] for line in err if line.startswith("batch ")]
    assert first == ["first pass 1/2", "first pass 2/2"] and second == ["batch 1/2", "batch 2/2"], err
    assert err.index(next(line for line in err if line.startswith("batch "))) > err.index(
        next(line for line in err if line.startswith("first pass ")))


def test_a_frames_focal_length_is_read_given_its_cameras_pooled_pitch():
    """A weak frame's focal length leans with its pitch (the horizon pinned in pixels): under the
    wide default pitch prior the reading follows the frame's own pitch; given the camera's pooled
    pitch (the draws reweighted to it) it is the focal length at that pitch."""
    from creference_bayes.workflows.batch.rig import camera_likelihood

    rng = np.random.default_rng(3)
    pitch = rng.normal(math.radians(-3.0), math.radians(4.0), 20000)  # the frame alone: far off, wide
    log_focal = math.log(700.0) + 2.0 * (pitch - math.radians(1.0)) + rng.normal(0, 0.05, 20000)
    cams = np.column_stack([np.exp(log_focal), pitch, np.zeros(20000), np.full(20000, 1.6), np.full(20000, 0.5)])
    result = {"camera": {"free": ["focal_length_px", "pitch"], "setup": {
        "orientation_prior": {"pitch_mean": 0.0, "pitch_sd": 15.0, "roll_mean": 0.0, "roll_sd": 15.0,
                              "height_median_m": 1.6, "height_log_sd": 0.2}}}}
    alone = camera_likelihood(result, cams)["log_focal"]
    given = camera_likelihood(result, cams, {"pitch": (math.radians(1.0), math.radians(0.5))})["log_focal"]
    assert math.exp(alone[0]) < 0.9 * 700.0  # led by its own pitch, 4° low
    assert math.exp(given[0]) == pytest.approx(700.0, rel=0.01) and given[1] > alone[1]


def _copies(four_frames, folder, frames):
    """A batch folder whose first pass is ``frames`` frames of cam-A: the four frames' first-pass
    results and scenes, copied under the names 0, 1, ..."""
    import shutil

    root, _, _ = four_frames
    for sub in ("results", "scenes"):
        (folder / "first_pass" / sub).mkdir(parents=True)
        for i in range(frames):
            shutil.copy(root / "out" / "first_pass" / sub / f"f{i % 4}.json", folder / "first_pass" / sub / f"{i}.json")
    return folder


def _example(name, *args):
    """examples/NAME run with ``args`` → the finished process (it must succeed)."""
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / name
    proc = subprocess.run([sys.executable, str(example), *map(str, args)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc


def test_the_focal_length_alone_is_read_given_the_pooled_orientation_which_is_not_handed_back(four_frames):
    """``--rig focal`` learns the focal length only, but reads each frame's focal length as the
    default does, given the other frames' pool of its camera's pitch and roll: the same pool of
    focal lengths as when the orientation is learnt too, another than each frame's reading alone;
    the orientation's pools served the reading only, and a frame is handed no mounting."""
    root, settings, _ = four_frames
    frames = [(f"f{k}", "cam-A") for k in range(4)]
    first = root / "out" / "first_pass"
    focal = DataSet.from_first_pass(frames, first, ("log_focal",))
    mounting = DataSet.from_first_pass(frames, first, ("log_focal", "pitch", "roll"))
    alone = DataSet.from_first_pass(frames, first, ("log_focal",), focal_given_orientation=False)
    assert set(focal.pools) == {"log_focal"} and set(focal.summary()) == {"focal_length_px"}
    given, read_alone = focal.estimate("log_focal", "f0"), alone.estimate("log_focal", "f0")
    assert given.center == mounting.estimate("log_focal", "f0").center
    assert given.center != read_alone.center
    scene = parse_scene(json.loads((root / "in" / "f0.json").read_text()))
    _, _, block, rig = hand_back(focal, "f0", scene, settings)
    assert block["focal_length_px"]["from"] == "data set" and rig is None
    assert not {"pitch_deg", "roll_deg", "height_m"} & set(block)


def test_the_dataset_pool_example_prints_each_cameras_pool_both_ways(four_frames, tmp_path):
    """examples/dataset_pool.py (docs/studies/rig.md) on a batch's MAP first pass: a row per
    reading for a camera of ten frames; it writes nothing."""
    batch = _copies(four_frames, tmp_path / "b", 10)
    before = sorted(tmp_path.rglob("*"))
    proc = _example("dataset_pool.py", batch, "--groups", "0-4")
    rows = proc.stdout.splitlines()
    assert any(r.startswith("all    alone  cam-A") for r in rows) and any(r.startswith("all    given  cam-A") for r in rows)
    assert "z " in proc.stdout  # the scenes carry the truth
    assert sorted(tmp_path.rglob("*")) == before


def test_a_focal_length_k_times_larger_puts_the_targets_k_times_deeper_as_scale_depths_does():
    """The premise of a held focal length's shared scale: with the image fixed, µ → kµ moves each
    target's depth z to ≈ kz, x nearly unchanged (the MAPs of one frame at µ and 1.05µ); and
    scale_depths does exactly that to a result: the kept draws' depths and focal lengths, the MAP's
    when asked, the posterior summaries with them."""
    import copy

    from creference_bayes import estimate

    d = _scene(0)
    d["camera"]["focal_length_px"] = 1400.0
    fits = {}
    for k in (1.0, 1.05):
        d["camera"]["focal_length_px"] = 1400.0 * k
        fits[k] = estimate(parse_scene(d), seed=0, posterior=k == 1.0, sampling=FAST, keep_draws=100).to_dict()
    for a, b in zip(fits[1.0]["objects"], fits[1.05]["objects"]):
        assert b["map"]["z"] / a["map"]["z"] == pytest.approx(1.05, abs=0.02)  # 1.042–1.053 on seeds 0–2
        assert abs(b["map"]["x"] - a["map"]["x"]) < 0.2 * abs(b["map"]["z"] - a["map"]["z"])
    before = scale_depths(copy.deepcopy(fits[1.0]), 0.0)  # the summaries from the kept draws
    after = scale_depths(copy.deepcopy(fits[1.0]), math.log(1.05), math.log(1.05))
    assert after["camera"]["posterior"]["median"]["focal_length_px"] == pytest.approx(1470.0)
    for a, b, da, db in zip(before["objects"], after["objects"], before["draws"]["objects"], after["draws"]["objects"]):
        assert np.allclose(db["z"], 1.05 * np.asarray(da["z"]), atol=1e-5) and db["x"] == da["x"]
        assert b["posterior"]["median"]["z"] == pytest.approx(1.05 * a["posterior"]["median"]["z"], rel=1e-5)
        assert b["map"]["z"] == pytest.approx(1.05 * a["map"]["z"], rel=1e-5) and b["map"]["x"] == a["map"]["x"]
    with pytest.raises(ValueError, match="no posterior draws"):
        scale_depths({k: v for k, v in fits[1.05].items() if k != "draws"}, 0.1)


def test_a_held_focal_length_carries_its_pools_uncertainty_as_one_scale_the_cameras_frames_share(tmp_path):
    """Two frames of one camera, posterior sampled: each takes the pooled focal length as its
    own, and its draws carry the pool's whole log-sd as a factor exp(ε_d) on focal length and
    depths, the same ε_d in every frame of the camera (one value: one uncertainty, shared)."""
    (tmp_path / "in").mkdir()
    for seed in range(2):
        (tmp_path / "in" / f"f{seed}.json").write_text(json.dumps(_scene(seed)))
    report = run_batch([tmp_path / "in"], tmp_path / "out", LocalEngine(1), BatchSettings(seed=1, sampling=FAST))
    assert report.ok
    eps = []
    for k in range(2):
        res = json.loads((tmp_path / "out" / "results" / f"f{k}.json").read_text())
        took = res["dataset"]["focal_length_px"]
        assert took["held"] and res["camera"]["map"]["focal_length_px"] == took["median"]
        e = np.log(np.asarray(res["draws"]["camera"]["focal_length_px"]) / took["median"])
        assert np.std(e) == pytest.approx(took["shared_scale_log_sd"], rel=0.3)
        assert res["camera"]["posterior"]["sd"]["focal_length_px"] > 0.5 * took["log_sd"] * took["median"]
        eps.append(e)
    n = min(map(len, eps))
    assert np.allclose(eps[0][:n], eps[1][:n], atol=1e-5)


def test_the_focal_floor_example_measures_the_floor_on_frames_with_a_known_focal_length(four_frames, tmp_path):
    """examples/focal_floor.py (docs/studies/rig.md, "The floor, measured") on a batch's MAP first
    pass: a row per block size, the floor between the rms error and minus the rms stated sd."""
    batch = _copies(four_frames, tmp_path / "b", 8)
    proc = _example("focal_floor.py", batch, "--blocks", "2,4", "--partitions", "20", "--bootstrap", "10",
                    "--group", "0-5")
    assert "6 informative readings of 6" in proc.stdout.splitlines()[0]  # --group 0-5: six of the eight frames
    rows = [r.split() for r in proc.stdout.splitlines()[2:]]
    assert [r[0] for r in rows] == ["2", "4"]
    for _, floor, sd, rms, *_ in rows:
        assert -float(sd) - 1e-3 <= float(floor) <= float(rms) + 1e-3


def test_the_advice_weighs_a_held_focal_lengths_frame_given_the_held_value_and_states_its_labels_with_the_scale():
    """A result whose draws carry a held focal length's shared scale: the advice weighs its futures
    on the draws given the held value (the scale divided out: the model holds µ fixed, and no request
    on the frame moves the camera's pool), says so, and states the labels' quality now from the
    draws as they are, as ``creference labels`` does; a result without a scale is weighed as it is."""
    import copy

    from creference_bayes import estimate
    from creference_bayes.models.contract import C_FOCAL, O_Z
    from creference_bayes.pipeline import map_state, rebuild_model, result_draws
    from creference_bayes.workflows.advice import AdviceSettings, _label_quality
    from creference_bayes.workflows.advice.inputs import _given_held_focal, advise_result
    from creference_bayes.workflows.batch.dataset import share_scale

    d = _scene(0)
    d["camera"]["focal_length_px"] = 1400.0
    scene = parse_scene(d)
    plain = estimate(scene, seed=0, sampling=FAST, keep_draws=200).to_dict()
    held = share_scale(copy.deepcopy(plain), log_sd=0.08, seed=3)
    model = rebuild_model(held, scene)
    cams, objs, _ = result_draws(held, model)
    (wc, wo), notes = _given_held_focal(model, cams, objs)
    assert np.allclose(wc[:, C_FOCAL], 1400.0)
    p_cams, p_objs, _ = result_draws(plain, model)
    assert np.allclose(wo[..., O_Z], p_objs[..., O_Z], rtol=1e-5) and np.std(np.log(cams[:, C_FOCAL])) > 0.05
    assert len(notes) == 1 and "held at 1400.0 px" in notes[0]
    assert _given_held_focal(model, p_cams, p_objs) == ((p_cams, p_objs), [])
    settings = AdviceSettings(n_draws=100, n_futures=20, kinds=("dims",))
    advice = advise_result(held, scene, seed=0, settings=settings)
    assert notes[0] in advice.notes
    camera, objects = map_state(held)
    assert np.allclose(advice.now.p_iou, _label_quality(scene, camera, objects, cams, objs, settings.iou_threshold))


@pytest.fixture(scope="module")
def population_batch(tmp_path_factory):
    """Six frames of no named camera, two targets each: enough for the data set's distance
    population (plan()); MAP only (the advice then draws from the Laplace approximation)."""
    root = tmp_path_factory.mktemp("population")
    (root / "in").mkdir()
    for seed in range(6):
        (root / "in" / f"f{seed}.json").write_text(json.dumps(_scene(seed, camera=None)))
    settings = BatchSettings(seed=1, posterior=False)
    report = run_batch([root / "in"], root / "out", LocalEngine(1), settings)
    return root, settings, report


def test_the_advice_on_a_batch_predicts_under_the_priors_the_data_set_handed_each_frame(population_batch):
    """``advise`` on a batch folder rebuilds each frame's model as the frame was estimated: with the
    population the others handed it, so its present and its simulated outcomes draw from it."""
    from creference_bayes.pipeline import rebuild_model
    from creference_bayes.workflows.advice import AdviceSettings
    from creference_bayes.workflows.advice.inputs import advise_result, scene_for_result

    root, _, report = population_batch
    assert report.ok and "distance_m" in report.dataset
    path = root / "out" / "results" / "f0.json"
    res = json.loads(path.read_text())
    took = res["dataset"]["distance_m"]
    assert took["from"] == "data set" and took["frames_offered"] == 10  # the other 5 frames' targets
    scene = scene_for_result(path, res)  # the batch's copy, as advise_batch finds it
    median, log_sd = rebuild_model(res, scene).location.population
    assert median == pytest.approx(took["median"]) and log_sd == pytest.approx(
        math.hypot(took["log_sd"], took["spread_log_sd"]), abs=1e-3)
    settings = AdviceSettings(n_draws=200, n_futures=20)
    learned = advise_result(res, scene, seed=0, settings=settings)
    alone = {**res, "provenance": {k: v for k, v in res["provenance"].items() if k != "location_population"}}
    without = advise_result(alone, scene, seed=0, settings=settings)
    # the population is information the frame alone lacks: every target's present is surer with it
    assert np.all(learned.now.location_sd_m < without.now.location_sd_m)
    assert learned.now.hdi_width_m.sum() < without.now.hdi_width_m.sum()


def test_learn_priors_hands_each_frame_what_the_batch_estimated_it_with(population_batch):
    """``learn_priors`` (for studies that estimate the frames themselves) hands each frame the
    priors a batch gives it, from the same first pass (resumed, not estimated again)."""
    from creference_bayes.workflows.batch import learn_priors

    root, settings, _ = population_batch
    handed = learn_priors([root / "in"], root / "out" / "first_pass", settings)
    assert sorted(handed) == [f"f{k}" for k in range(6)]
    for key, (scene, kwargs, block) in handed.items():
        res = json.loads((root / "out" / "results" / f"{key}.json").read_text())
        assert kwargs["location_prior"].population == tuple(res["provenance"]["location_population"])
        assert block["distance_m"] == res["dataset"]["distance_m"]
        assert scene.corner_scale is None  # every target annotated twice: its own scale


def test_the_distance_population_example_checks_readings_and_priors_against_the_truth(population_batch, tmp_path):
    """examples/distance_population.py (docs/studies/rig.md) on a batch's first pass of simulated
    frames: a row of the 12 targets' readings against the truth and of the 6 frames' handed priors
    as forecasts; readings twice as wide have z half as spread; it writes nothing."""
    root, _, _ = population_batch
    before = sorted(tmp_path.rglob("*"))
    rows = {}
    for scale in ("1", "2"):
        out = _example("distance_population.py", root / "out", "--reading-sd-scale", scale).stdout
        assert out.startswith("group data set: 12 readings; pool of all frames: ")
        rows[scale] = next(r for r in out.splitlines() if r.startswith("| - |")).split(" | ")
        assert rows[scale][1] == "12" and rows[scale][5] == "12"  # readings; every frame's prior, its targets
    assert float(rows["2"][4]) == pytest.approx(float(rows["1"][4]) / 2, abs=0.011)
    assert sorted(tmp_path.rglob("*")) == before


def _tail_readings(tier, scenes=6, refs=10):
    """Each simulated scene's tail reading with its draws all at the truth (the leave-one-out
    weights then are flat: a reference is scored by its likelihood at the true state)."""
    from creference_bayes.bench.simulate import simulate_scene, true_state
    from creference_bayes.pipeline import build_model
    from creference_bayes.workflows.batch.dataset import read_tail

    out = {}
    for seed in range(scenes):
        scene = parse_scene(simulate_scene(seed, tier=tier, n_references=refs, n_target_annotations=2,
                                           single_values=True))
        model = build_model(scene)[0]
        cam, objs = true_state(scene)
        model.set_pilot(cam)
        out[f"s{seed}"] = read_tail(model, np.tile(cam, (3, 1)), np.tile(objs, (3, 1, 1)))
    return out


def test_the_crowds_tail_is_the_one_its_references_favour():
    """A crowd whose stated values err log-normally (10 %) is handed a light tail; one with the
    paper's heavy tails keeps a heavy one; each frame's choice leaves its own references out."""
    from creference_bayes.models.metrology import REF_DOF
    from creference_bayes.workflows.batch.dataset import MIN_TAIL_REFERENCES, TAIL_DOFS, TailPool

    light = TailPool(_tail_readings("low"), REF_DOF)
    est = light.estimate()
    assert est["dof"] == est["favoured"] >= 10 and est["gain"] > 2 * est["se"]
    assert est["references"] == sum(len(r) for r in _tail_readings("low").values()) and est["frames"] == 6
    heavy = TailPool(_tail_readings("high"), REF_DOF).estimate()
    assert heavy["dof"] <= 3 and heavy["favoured"] <= 4
    one = light.estimate("s0")  # leave one out: the others' references only
    assert one["references"] == est["references"] - len(light.keys[light.keys == "s0"]) and one["frames"] == 5
    few = TailPool({k: v for k, v in list(_tail_readings("low", scenes=2, refs=5).items())}, REF_DOF)
    assert len(few.keys) < MIN_TAIL_REFERENCES and few.estimate() is None
    assert REF_DOF in TAIL_DOFS  # the model's own tail is one of those scored


def test_a_tail_the_references_do_not_clearly_favour_leaves_the_models_own():
    """Scores that favour another tail by less than twice their difference's standard error hand
    back the model's own tail."""
    from creference_bayes.workflows.batch.dataset import TAIL_DOFS, TAIL_SCALES, TailPool

    rng = np.random.default_rng(0)
    scores = np.zeros((40, len(TAIL_SCALES), len(TAIL_DOFS)))
    noise = rng.normal(0.0, 1.0, (40, 1))
    scores[:, :, -1] = noise - noise.mean() + 0.1  # better by 4 nats in all, within its noise (se ≈ 6)
    pool = TailPool({"a": scores[:20], "b": scores[20:]}, 2.0)
    est = pool.estimate()
    assert est["dof"] == 2.0 and abs(est["gain"]) < 2 * est["se"]
    scores[:, :, -1] = 0.5  # clearly better on every reference
    est = TailPool({"a": scores[:20], "b": scores[20:]}, 2.0).estimate()
    assert est["dof"] == TAIL_DOFS[-1] and est["gain"] == pytest.approx(20.0, abs=0.1)


def test_a_batch_hands_each_frame_the_tail_of_the_other_frames_references(tmp_path):
    """Frames with references: the batch's first pass scores their tails, each frame is read with
    the tail of the others' references (recorded in its result, its settings and batch.json); a
    hand-set ``ref_dof`` wins and is recorded as an override."""
    from creference_bayes.workflows.batch.dataset import REF_TAIL

    (tmp_path / "in").mkdir()
    for seed in range(5):
        d, _ = truth_scene(seed, noise_px=1.0, n_annotations=2, n_refs=6, horizon="sd")
        (tmp_path / "in" / f"f{seed}.json").write_text(json.dumps(d))
    settings = BatchSettings(seed=1, posterior=False)
    report = run_batch([tmp_path / "in"], tmp_path / "out", LocalEngine(1), settings)
    assert report.ok and REF_TAIL.name in plan([parse_scene(json.loads(p.read_text()))
                                                  for p in sorted((tmp_path / "in").iterdir())], settings)
    pooled = report.dataset["ref_dof"]["groups"]["crowd"]
    assert pooled["references"] == 30 and pooled["frames"] == 5
    for k in range(5):
        res = json.loads((tmp_path / "out" / "results" / f"f{k}.json").read_text())
        took = res["dataset"]["ref_dof"]
        assert took["from"] == "data set" and took["references"] == 24 and took["frames"] == 4
        read_with = res["provenance"]["options"].get("ref_dof", 2.0)
        assert read_with == took["dof"]
    # the stated values here are exact: a light tail is favoured, and clearly (else the model's own)
    assert pooled["favoured"] >= 10 and (pooled["dof"] == pooled["favoured"]) == (pooled["gain"] > 2 * pooled["se"])
    ds = DataSet.from_first_pass([(f"f{k}", None) for k in range(5)], tmp_path / "out" / "first_pass",
                                 plan([parse_scene(json.loads((tmp_path / "in" / f"f{k}.json").read_text()))
                                       for k in range(5)], settings))
    took = json.loads((tmp_path / "out" / "results" / "f0.json").read_text())["dataset"]["ref_dof"]
    assert {"from": "data set", "shared_by": "crowd", **ds.tail_of("f0")} == took  # read again: the same
    # the other quantities are read under the chosen tail: without it, the crowd's scale reads otherwise
    alone = DataSet.from_first_pass([(f"f{k}", None) for k in range(5)], tmp_path / "out" / "first_pass",
                                    tuple(n for n in ds.learn if n != REF_TAIL.name))
    assert pooled["dof"] != 2.0 and ds.summary()["ref_scale"] == report.dataset["ref_scale"]
    assert alone.summary()["ref_scale"]["groups"]["crowd"]["median"] != report.dataset["ref_scale"]["groups"][
        "crowd"]["median"]
    scene = parse_scene(json.loads((tmp_path / "in" / "f0.json").read_text()))
    _, kwargs, block, _ = hand_back(ds, "f0", scene, replace(settings, options={"ref_dof": 5.0}))
    assert block["ref_dof"] == {"from": "override", "why": "--option ref_dof=5"} and "ref_dof" not in kwargs
    assert not plan([scene] * 5, replace(settings, options={"ref_dof": 5.0})).count(REF_TAIL.name)


def test_a_frame_is_read_under_the_crowds_tail_whose_scale_is_that_tails_own():
    """The first pass is estimated under the model's own tail (t₂); read under the crowd's
    (``tail_reweight``), the draws weigh each crowd scale by the chosen tail's likelihood, and a
    log-normal crowd's scale under a light tail is wider than t₂'s (t₂ fits the same errors with a
    narrower scale and long tails): the scale handed back is the tail's own."""
    from creference_bayes.bench.simulate import simulate_scene, true_state
    from creference_bayes.models.contract import C_SCALE
    from creference_bayes.pipeline import build_model
    from creference_bayes.workflows.batch.dataset import tail_reweight

    scene = parse_scene(simulate_scene(3, tier="low", n_references=40, n_target_annotations=2, single_values=True))
    model = build_model(scene)[0]
    cam, objs = true_state(scene)
    model.set_pilot(cam)
    scales = np.exp(np.linspace(np.log(0.01), np.log(1.0), 400))  # draws: the truth at a grid of crowd scales
    cams = np.tile(cam, (len(scales), 1))
    cams[:, C_SCALE] = scales
    objs = np.tile(objs, (len(scales), 1, 1))
    own, light = model.reference_log_densities(cams, objs, (2.0, 30.0))[0]
    log_w = tail_reweight(model, cams, objs, 30.0)
    assert np.allclose(log_w, np.nansum(light - own, axis=1))
    post = lambda lw: float(np.average(np.log(scales), weights=np.exp(lw - lw.max())))  # noqa: E731
    under_own = np.nansum(own, axis=1)
    assert post(under_own + log_w) == pytest.approx(post(np.nansum(light, axis=1)))
    assert math.exp(post(under_own + log_w)) > 1.2 * math.exp(post(under_own))
