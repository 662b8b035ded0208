"""The Result of an estimate for Python users (issue 63): accessors, a summary table, the
posterior as an arviz InferenceData whose log-likelihood holds every observation once, save and
load_result giving the same Result back (from estimate --out, Result.save and a batch), --netcdf
writing the same InferenceData, and an import that leaves the environment alone."""

import json
import os
import shutil
import subprocess
import sys
import warnings

import numpy as np
import pytest
from conftest import truth_scene

import creference_bayes as cb
from creference_bayes.cli.main import main

#: A tiny sampler budget: the tests are about the result's form, not the posterior's precision.
TINY = {"min_ess": 20, "max_steps": 100, "chunk": 50}
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _az():
    from creference_bayes.inference.summary import az

    return az


def _uneven_scene():
    """Three targets with 1, 2 and 5 sets of dimension lines, no references, no horizon."""
    d, _ = truth_scene(6, m=3, n_annotations=5, noise_px=1.0, sizes_known=False)
    for t, k in zip(d["targets"], (1, 2, 5)):
        t["dimension_lines"] = t["dimension_lines"][:k]
    return d


@pytest.fixture(scope="module")
def estimated(tmp_path_factory):
    """The uneven scene as a file, and its estimate (tiny budget)."""
    folder = tmp_path_factory.mktemp("uneven")
    path = folder / "scene.json"
    path.write_text(json.dumps(_uneven_scene()))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return path, cb.estimate(path, seed=0, sampling=TINY)


def test_loo_counts_each_set_of_dimension_lines_once(estimated):
    """A target with fewer sets adds no observations: LOO has exactly the scene's sets."""
    path, result = estimated
    scene = json.loads(path.read_text())
    expected = sum(len(t["dimension_lines"]) for t in scene["targets"])  # no references, no horizon
    assert expected == 8
    idata = result.to_inference_data()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pareto k of a tiny run
        loo = _az().loo(idata, pointwise=True)
        waic = _az().waic(idata, pointwise=True)
    assert loo.loo_i.size == expected and waic.waic_i.size == expected
    ll = idata.log_likelihood
    assert [(str(t), int(i)) for t, i in zip(ll["target"].values, ll["index"].values)] == \
        [("t0", 0), ("t1", 0), ("t1", 1), ("t2", 0), ("t2", 1), ("t2", 2), ("t2", 3), ("t2", 4)]
    assert idata.observed_data["corners"].shape == (expected, 4, 2)
    assert not np.isnan(idata.observed_data["corners"].values).any()
    assert set(idata.groups()) >= {"posterior", "sample_stats", "log_likelihood", "observed_data", "constant_data"}
    assert json.loads(idata.posterior.attrs["provenance"]) == result.to_dict()["provenance"]


def test_the_accessors_read_the_result_without_digging(estimated):
    _, result = estimated
    d = result.to_dict()
    assert [o.id for o in result.objects] == ["t0", "t1", "t2"]
    first = result.objects[0]
    assert first.location_m == tuple(d["objects"][0]["map"][k] for k in ("x", "y", "z"))
    assert first.distance_m == d["objects"][0]["map"]["distance_m"]
    assert first.hdi["distance_m"] == tuple(d["objects"][0]["posterior"]["hdi"]["distance_m"])
    assert first.n_annotations == 1 and first.hdi_prob == 0.9
    assert result.camera.focal_length_px == d["camera"]["map"]["focal_length_px"]
    assert result.converged == d["diagnostics"]["converged"]
    table = result.summary()
    assert {"map", "mean", "sd", "hdi_5%", "hdi_95%", "ess_bulk", "r_hat"} <= set(table.columns)
    assert table.loc["distance_m[t1]", "mean"] == d["objects"][1]["posterior"]["mean"]["distance_m"]
    assert table.loc["focal_length_px", "r_hat"] == d["diagnostics"]["r_hat"]["camera.focal_length_px"]


def test_a_saved_result_loads_back_the_same_and_rebuilds_its_inference_data(estimated, tmp_path):
    """Saved elsewhere than its scene, the result finds it again; without the scene, the
    InferenceData has the posterior and says what it lacks."""
    import pandas as pd

    scene_path, result = estimated
    out = result.save(tmp_path / "elsewhere" / "result.json")
    back = cb.load_result(out)
    assert isinstance(back, cb.Result)
    pd.testing.assert_frame_equal(back.summary(), result.summary())
    assert back.objects == result.objects and back.camera == result.camera and back.converged == result.converged
    idata = back.to_inference_data()
    assert set(idata.groups()) == set(result.to_inference_data().groups())
    assert idata.log_likelihood["observations"].shape[-1] == 8
    assert idata.sample_stats["lp"].shape == idata.posterior["x"].shape[:2]
    # the log-likelihood of the rebuilt model is the estimate's own at the same draws
    from creference_bayes.inference.summary import observations

    cams, objs = back.draws.cameras.reshape(-1, 5), back.draws.objects.reshape(-1, 3, 7)
    hands = None if back.draws.handedness is None else back.draws.handedness.reshape(-1, 3)
    np.testing.assert_allclose(observations(result.model, cams, objs, hands)[0],
                               idata.log_likelihood["observations"].values.reshape(len(cams), -1))
    # the scene gone: the posterior only, and a warning that says why
    moved = shutil.copy(out, tmp_path / "result.json")
    with pytest.warns(cb.ResultWarning, match="need the result's scene"):
        alone = cb.load_result(moved).to_inference_data()
    assert set(alone.groups()) == {"posterior", "sample_stats"}
    assert "scene" in alone.posterior.attrs["missing"]


def test_a_batch_result_loads_with_its_inference_data(tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "uneven.json").write_text(json.dumps(_uneven_scene()))
    out = tmp_path / "batch"
    assert main(["batch", str(scenes), "--out", str(out), "--workers", "1", "--quiet",
                 "--min-ess", "20", "--max-steps", "100"]) == 0
    back = cb.load_result(out / "results" / "uneven.json")
    assert isinstance(back, cb.Result) and [o.id for o in back.objects] == ["t0", "t1", "t2"]
    idata = back.to_inference_data()
    assert "log_likelihood" in idata.groups() and idata.log_likelihood["observations"].shape[-1] == 8
    import pandas as pd

    pd.testing.assert_frame_equal(cb.load_result(back.save(tmp_path / "again.json")).summary(), back.summary())


def test_netcdf_writes_what_to_inference_data_gives(tmp_path, capsys):
    d, _ = truth_scene(4, m=2, noise_px=1.0, n_annotations=2, n_refs=2)
    scene, out, nc = tmp_path / "scene.json", tmp_path / "result.json", tmp_path / "post.nc"
    scene.write_text(json.dumps(d))
    assert main(["estimate", str(scene), "--out", str(out), "--netcdf", str(nc), "--quiet", "--seed", "3",
                 "--min-ess", "20", "--max-steps", "100"]) == 0
    written = _az().from_netcdf(nc)
    made = cb.load_result(out).to_inference_data()
    assert set(written.groups()) == set(made.groups())
    for group in made.groups():
        a, b = getattr(written, group), getattr(made, group)
        assert set(a.data_vars) == set(b.data_vars), group
        assert {k: a[k].dims for k in a.data_vars} == {k: b[k].dims for k in b.data_vars}, group
        assert set(a.coords) == set(b.coords), group
    np.testing.assert_array_equal(written.log_likelihood["observation"].values, made.log_likelihood["observation"].values)
    assert written.posterior.attrs["provenance"] == made.posterior.attrs["provenance"]


def test_importing_the_package_leaves_the_environment_alone():
    code = ("import os\n"
            "before = dict(os.environ)\n"
            "import creference_bayes, creference_bayes.cli.main\n"
            "print(dict(os.environ) == before, [v for v in %r if v in os.environ])\n" % (THREAD_VARS,))
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(__import__("pathlib").Path(__file__).parents[1]),
                                                    env.get("PYTHONPATH")) if p)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["True", "[]"]


def test_one_settings_object_for_estimate_build_model_and_batch():
    """cb.EstimateSettings is what estimate, build_model and a batch read: a field by name, any other
    keyword a model option; bad values refused by name; a batch's settings extend it."""
    from creference_bayes.pipeline import build_model
    from creference_bayes.workflows.batch import BatchSettings

    s = cb.EstimateSettings(hdi_prob=0.5).replace(ground_sd_m=0.2, use_references=False)
    assert (s.hdi_prob, s.use_references, s.options) == (0.5, False, {"ground_sd_m": 0.2})
    with pytest.raises(ValueError, match="ground_sdm"):
        cb.EstimateSettings(options={"ground_sdm": 1.0})
    with pytest.raises(ValueError, match="temperature"):
        s.replace(temperature=0.0)
    with pytest.raises(ValueError, match="hdi_prob"):
        cb.EstimateSettings(hdi_prob=1.0)
    b = BatchSettings(seed=3, hdi_prob=0.5, use_references=False, options={"ground_sd_m": 0.2})
    assert b.estimate_settings() == s and type(b.estimate_settings()) is cb.EstimateSettings
    d, _ = truth_scene(0, m=2, sizes_known=False, n_refs=1)
    scene = cb.parse_scene(d)
    model, _ = build_model(scene, s)
    assert model.ground_sd_m == 0.2 and len(model.references) == 0
    res = cb.estimate(scene, s, seed=0, posterior=False)
    prov = res.to_dict()["provenance"]
    assert (prov["hdi_prob"], prov["use_references"], prov["options"]) == (0.5, False, {"ground_sd_m": 0.2})


def test_a_pitch_derived_from_an_exact_horizon_has_its_posterior_in_the_summary():
    """With an exact horizon the pitch follows from the focal length, so its draws spread with
    it: the result, the summary table and the InferenceData agree on that spread; the roll (from
    the horizon's slope alone) has none and is reported as fixed."""
    scene = cb.load_scene(os.path.join(os.path.dirname(cb.__file__), "data", "example_scene.json"))
    r = cb.estimate(scene, seed=0, sampling=TINY)
    assert r.camera.free == ("focal_length_px", "height_m", "ref_scale")  # pitch derived, not free
    pitch = r.to_inference_data().posterior["pitch"].values.ravel()
    assert pitch.std() > 0
    table = r.summary()
    assert table.loc["pitch", "mean"] == pytest.approx(pitch.mean(), abs=1e-6)
    assert table.loc["pitch", "hdi_5%"] < table.loc["pitch", "map"] < table.loc["pitch", "hdi_95%"]
    assert np.isnan(table.loc["roll", "mean"]) and "roll" not in r.camera.mean
    # the diagnostics say how many draws the summaries are of (a chain of walkers laid end to end)
    diag, post = r.to_dict()["diagnostics"], r.to_inference_data().posterior
    assert (diag["n_chains"], diag["draws_per_chain"]) == (post.sizes["chain"], post.sizes["draw"])
    assert diag["draws_per_chain"] > diag["iterations"]  # the one-target ensemble: several walkers a chain
