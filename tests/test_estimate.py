"""The one path (pipeline.py): any scene, in either file format, from the scene to its result."""

import json
from pathlib import Path

import numpy as np
import pytest

import creference_bayes as cb
from conftest import truth_scene
from creference_bayes.io.result import RESULT_FORMAT, read_result, stored_draws
from creference_bayes.pipeline import map_state, rebuild_model, result_draws

FAST = {"min_ess": 100}


def _timeless(d):
    """A result dict without its timings (every ``seconds``)."""
    if isinstance(d, dict):
        return {k: _timeless(v) for k, v in d.items() if k != "seconds"}
    return [_timeless(v) for v in d] if isinstance(d, list) else d


def _as_version_1(d: dict) -> dict:
    """The same one-target scene written as ``creference-scene/1``."""
    t = d["targets"][0]
    truth = dict(t["ground_truth"])
    truth.pop("dimensions_m"), truth.pop("ground_m")
    truth.update(d["ground_truth"])
    return {"format": "creference-scene/1", "image": d["image"], "camera": d["camera"],
            "target": {"id": t["id"], "dimensions_m": t["dimensions_m"], "dimension_lines": t["dimension_lines"]},
            "references": d.get("references", []), "ground_truth": truth}


def test_a_one_object_frame_and_the_same_scene_as_version_1_give_the_same_posterior():
    d, _ = truth_scene(3, n_annotations=3, noise_px=2.0, n_refs=2)
    a = cb.estimate(d, seed=5, sampling=FAST)
    b = cb.estimate(_as_version_1(d), seed=5, sampling=FAST)
    assert b.to_dict()["scene_format"] == "creference-scene/1"
    np.testing.assert_array_equal(a.draws.objects, b.draws.objects)
    np.testing.assert_array_equal(a.draws.cameras, b.draws.cameras)
    for key in ("map", "posterior", "evaluation"):
        assert a.to_dict()["objects"][0][key] == b.to_dict()["objects"][0][key]
    assert a.to_dict()["camera"] == b.to_dict()["camera"]


@pytest.mark.parametrize("m", [1, pytest.param(3, marks=pytest.mark.slow)])
def test_the_same_seed_gives_the_same_result_and_it_rebuilds_its_model(m, tmp_path):
    d, _ = truth_scene(4, m=m, n_annotations=2, noise_px=2.0, n_refs=2, sizes_known=m == 1)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    a, b = (cb.estimate(path, seed=11, sampling=FAST) for _ in range(2))
    assert _timeless(a.to_dict()) == _timeless(b.to_dict())
    doc = json.loads(json.dumps(a.to_dict(), allow_nan=False))
    assert doc["format"] == RESULT_FORMAT and load_result_path(tmp_path, doc)["format"] == RESULT_FORMAT
    model = rebuild_model(doc, path)
    cam, objs = map_state(doc)
    assert np.array_equal(model.handedness, np.array([o["handedness"] for o in doc["objects"]], float))
    T = doc["provenance"]["temperature"]
    assert model.map_objective(cam[None], objs[None], T)[0] == pytest.approx(a.model.map_objective(cam[None], objs[None], T)[0])
    cams, objects, source = result_draws(doc, model)
    assert source == "posterior" and objects.shape == (doc["draws"]["n"], m, 7)
    if m > 1:  # the ground's prior is recorded; a result from before it was (none recorded) had the normal of 8 cm
        assert doc["provenance"]["ground"] == {"sd_m": 0.056, "sd_per_m": 0.0017, "dof": 2.0,
                                               "tilt_sd_rad": pytest.approx(np.radians(1.0))}
        assert (model.ground_sd_m, model.ground_sd_per_m, model.ground_dof) == (0.056, 0.0017, 2.0)
        older = {**doc, "provenance": {k: v for k, v in doc["provenance"].items() if k != "ground"}}
        old = rebuild_model(older, path)
        assert (old.ground_sd_m, old.ground_sd_per_m, old.ground_dof) == (0.08, 0.0, np.inf)
        assert rebuild_model({**older, "provenance": {**older["provenance"], "options": {"ground_sd_m": 0.2}}},
                             path).ground_sd_m == 0.2  # an option given wins


def test_an_infinite_model_option_is_written_as_a_word_and_read_back_as_infinity(tmp_path):
    """JSON has no infinity: ``ground_dof=inf`` (a normal) is recorded as "inf", and the model is
    rebuilt with it (a result written with ``allow_nan=False``, as the CLI writes it)."""
    d, _ = truth_scene(4, m=2, n_annotations=2, noise_px=2.0)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    res = cb.estimate(path, seed=3, posterior=False, ground_dof=np.inf, ground_sd_m=0.08)
    doc = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert doc["provenance"]["options"] == {"ground_dof": "inf", "ground_sd_m": 0.08}
    assert doc["provenance"]["ground"]["dof"] is None
    model = rebuild_model(doc, path)
    assert (model.ground_dof, model.ground_sd_m) == (np.inf, 0.08)
    cam, objs = map_state(doc)
    assert model.map_objective(cam[None], objs[None])[0] == pytest.approx(res.model.map_objective(cam[None], objs[None])[0])


def load_result_path(tmp_path, doc):
    p = tmp_path / "result.json"
    p.write_text(json.dumps(doc))
    return read_result(p)


def test_the_posterior_of_a_noise_free_scene_holds_the_truth_and_is_narrow():
    d, truth = truth_scene(5, m=2, n_annotations=2, n_refs=2)
    # the camera height's ridge with the ground offsets mixes slowly on a noise-free frame; the
    # distances, which this test is about, are sampled well within 2,000 steps
    r = cb.estimate(d, seed=0, sampling={**FAST, "max_steps": 2000})
    for o, t in zip(r.to_dict()["objects"], truth["objects"]):
        lo, hi = o["posterior"]["hdi"]["distance_m"]
        assert lo <= np.hypot(t[0], t[1]) <= hi and (hi - lo) / (hi + lo) < 0.01
        assert o["evaluation"]["distance_in_hdi"]


def test_every_result_has_its_inference_data(tmp_path):
    """log_likelihood per observation, observed data, one posterior variable per quantity; the
    NetCDF file reads back."""
    d, _ = truth_scene(6, m=2, n_annotations=2, noise_px=1.0, n_refs=3, sizes_known=False)
    r = cb.estimate(d, seed=0, sampling=FAST)
    idata = r.to_inference_data()
    assert set(idata.groups()) >= {"posterior", "log_likelihood", "sample_stats", "observed_data", "constant_data"}
    post = idata.posterior
    assert post["distance_m"].dims == ("chain", "draw", "object") and list(post["object"].values) == ["t0", "t1"]
    kinds = list(idata.log_likelihood["kind"].values)
    assert kinds.count("annotation") == 4 and kinds.count("reference") == 3
    path = tmp_path / "post.nc"
    idata.to_netcdf(path)
    import arviz as az

    back = az.from_netcdf(path)
    np.testing.assert_allclose(back.posterior["x"].values, post["x"].values)
    assert cb.estimate(d, posterior=False).to_inference_data() is None


def test_the_result_keeps_draws_that_read_back():
    d, _ = truth_scene(7, m=3, n_annotations=2, noise_px=2.0, sizes_known=False)
    r = cb.estimate(d, seed=0, sampling=FAST, keep_draws=50)
    kept = stored_draws(r.to_dict())
    assert kept.objects.shape == (1, 50, 3, 7)
    assert stored_draws(cb.estimate(d, seed=0, posterior=False).to_dict()) is None


@pytest.mark.slow  # three estimates; test_map.py checks the presets, test_models.py the paper model
def test_both_models_and_every_preset_take_any_scene():
    d, _ = truth_scene(8, m=2, n_annotations=2, noise_px=2.0, n_refs=3)
    docs = []
    for kw in ({"model": "paper"}, {"model": "paper", "preset": "paper", "restarts": 2},
               {"model": "metrology", "preset": "paper-controlled", "restarts": 2}):
        docs.append(doc := cb.estimate(d, seed=0, posterior=False, **kw).to_dict())
        assert doc["model"] == kw["model"] and doc["preset"] == kw.get("preset", "default")
        assert all(np.isfinite(o["map"]["distance_m"]) for o in doc["objects"])
    assert docs[0]["references"]["used_as"] == "pairwise bounds"


def test_bad_options_are_refused_by_name():
    d, _ = truth_scene(9)
    with pytest.raises(ValueError, match="unknown model"):
        cb.estimate(d, model="magic")
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['sigmaa'\]"):
        cb.estimate(d, model="paper", sigmaa=2.0)
    with pytest.raises(ValueError, match="temperature"):
        cb.estimate(d, temperature=0.0)
    with pytest.raises(ValueError, match=r"sampling: unknown option\(s\) \['min_es'\]"):
        cb.estimate(d, sampling={"min_es": 3})
    with pytest.raises(ValueError, match="paper model does not read stated confidences"):
        cb.estimate(d, model="paper", confidence_map="identity")


def test_a_version_1_result_converts_with_its_diagnostics_batch_block_and_camera():
    """A creference-result/1 file (as batches wrote them) reads as this format: its sampler's
    verdict and its batch block carried over; pitch and roll, which older files left out with a
    horizon, follow from the horizon and the focal length."""

    from creference_bayes.core.geometry import horizon_from_rotation, rotation_from_pitch_roll
    from creference_bayes.io.result import result_from_v1

    root = Path(__file__).parent / "data" / "batch_v1"
    d = json.loads((root / "results" / "s0.json").read_text())
    scene = cb.load_scene(root / "scenes" / "s0.json")
    r = result_from_v1(d, scene)
    assert r["diagnostics"]["converged"] is d["diagnostics"]["converged"]
    assert r["diagnostics"]["r_hat"] == d["diagnostics"]["r_hat"]
    assert r["batch"] == d["batch"]
    assert r["objects"][0]["handedness"] == d["handedness"]
    pitch, roll, f = np.radians(4.0), np.radians(-2.0), d["map"]["focal_length_px"]
    horizon = horizon_from_rotation(rotation_from_pitch_roll(pitch, roll), f, scene.principal_point, scene.image_width)
    scene = cb.parse_scene({**json.loads((root / "scenes" / "s0.json").read_text()), "horizon": horizon.tolist()})
    del d["map"]["pitch"], d["map"]["roll"]
    cam = result_from_v1(d, scene)["camera"]["map"]
    assert (cam["pitch"], cam["roll"]) == pytest.approx((pitch, roll), abs=1e-9)


def test_a_crowd_measured_elsewhere_replaces_the_crowd_scales_prior(tmp_path):
    """``ref_scale_median`` / ``ref_scale_log_sd``: the crowd scale's posterior follows the given
    prior where the scene's references say little of it (two exact references here: the default
    prior, median 0.5 and log-sd 1, lets them pull the scale far below 0.5); the result records the
    options and the rebuilt model has them; the advice draws a scene's first crowd scale from it."""
    from creference_bayes.models.contract import C_SCALE
    from creference_bayes.pipeline import build_model, reference_terms
    from creference_bayes.workflows.advice.observe import ReferenceObservation

    d, _ = truth_scene(11, n_annotations=2, noise_px=1.0, n_refs=2)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))

    def scale_median(res):
        return float(np.median(res.draws.cameras[..., C_SCALE]))

    default = cb.estimate(path, seed=0, sampling=FAST)
    told = cb.estimate(path, seed=0, sampling=FAST, ref_scale_median=2.0, ref_scale_log_sd=0.05)
    assert scale_median(default) < 1.0 and 1.7 < scale_median(told) < 2.3
    doc = json.loads(json.dumps(told.to_dict()))
    assert doc["provenance"]["options"] == {"ref_scale_log_sd": 0.05, "ref_scale_median": 2.0}
    model = rebuild_model(doc, path)
    assert (model.ref_scale_median, model.ref_scale_log_sd) == (2.0, 0.05)

    bare = {**d, "references": []}
    scene = cb.io.scene.parse_scene(bare)
    m, _ = build_model(scene, ref_scale_median=2.0, ref_scale_log_sd=0.05)
    obs = ReferenceObservation(m, reference_terms(cb.io.scene.parse_scene(d))[0], {"ref_scale_median": 2.0,
                                                                                 "ref_scale_log_sd": 0.05})
    assert obs.needs_scale
    s = obs.scale_draws(np.tile(m.complete_camera(np.ones((1, 5))), (400, 1)), np.random.default_rng(0))[:, C_SCALE]
    assert abs(np.log(np.median(s)) - np.log(2.0)) < 0.02 and np.std(np.log(s)) < 0.08
    for key, value in (("ref_scale_median", 0.0), ("ref_scale_log_sd", -1.0), ("ref_scale_median", np.inf),
                       ("ref_scale_median", 5.0)):  # beyond the crowd scale's bounds (0.005 to 3)
        with pytest.raises(ValueError, match=key):
            cb.estimate(path, posterior=False, **{key: value})
