"""The arviz adapter: layout, circular yaw, HDI, diagnostics, result JSON and NetCDF."""

import json

import numpy as np
import pytest
from scipy import stats

from creference_bayes.cli.main import main
from creference_bayes.inference.sampling import Chains
from creference_bayes.inference.summary import (az, in_hdi, posterior_arrays, summarise,
                                                summary_table, to_inference_data)


FREE = np.array([True] * 5 + [False] * 2)


def EXPAND(p):
    """A model's expand: the five sampled parameters plus a level camera's pitch and roll."""
    p = np.atleast_2d(p)
    return np.column_stack([p, np.zeros((len(p), 2))])



def _chains(values, burn_in=0, thin=1, tau=1.0):
    """Chains from (n_steps, n_ens, n_walk, 5) values, as the sampler would return them."""
    n, g, k, d = values.shape
    return Chains(chain=values, log_prob=-0.5 * np.sum(values**2, axis=-1), burn_in=burn_in, thin=thin,
                  autocorr_time=np.full(d, tau), acceptance_fraction=np.full((g, k), 0.4),
                  warmup_steps=0, converged=True, seconds=0.1, info={"stopped": "converged"})


def _iid(rng, n=400, g=4, k=16, loc=(1.0, 1.5, 5.0, 0.3, 1000.0), scale=(0.1, 0.1, 0.5, 0.05, 50.0)):
    return rng.normal(loc, scale, size=(n, g, k, 5))


def test_inference_data_layout_and_netcdf_round_trip(tmp_path, make_scene):
    rng = np.random.default_rng(0)
    values = _iid(rng)
    chains = _chains(values, burn_in=100, thin=2)
    scene = make_scene(3, tier="low")
    idata = to_inference_data(chains, EXPAND, scene=scene)
    post = idata.posterior
    assert set(post.data_vars) == {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll", "distance_m"}
    assert post.sizes["chain"] == 4 and post.sizes["draw"] == 16 * 150
    # walker-major: the first 150 draws of ensemble 0 are walker 0's kept steps in order
    np.testing.assert_array_equal(post["z"].values[0, :150], values[100::2, 0, 0, 2])
    np.testing.assert_allclose(post["distance_m"], np.hypot(post["x"], post["z"]))
    assert set(idata.sample_stats.data_vars) == {"lp", "accepted"}
    assert idata.observed_data["corners"].shape == scene.target.corners.shape
    assert idata.observed_data["reference_lines"].shape == (len(scene.references), 2, 2)
    path = tmp_path / "post.nc"
    idata.to_netcdf(path)
    back = az.from_netcdf(path)
    np.testing.assert_array_equal(back.posterior["yaw"].values, post["yaw"].values)


def test_gaussian_moments_and_hdi():
    rng = np.random.default_rng(1)
    values = _iid(rng, n=2000)
    summary, diag = summarise(_chains(values), EXPAND, hdi_prob=0.9)
    for name, mu, sd in (("x", 1.0, 0.1), ("z", 5.0, 0.5), ("focal_length_px", 1000.0, 50.0)):
        n = values.shape[0] * values.shape[1] * values.shape[2]
        assert summary.mean[name] == pytest.approx(mu, abs=4 * sd / np.sqrt(n))
        assert summary.sd[name] == pytest.approx(sd, rel=4 / np.sqrt(2 * n))
        lo, hi = summary.hdi[name]
        z = stats.norm.ppf(0.95)
        # Monte Carlo error of a sample 5 % quantile: √(p(1 − p)/n) / density, in units of sd
        se = np.sqrt(0.05 * 0.95 / n) / stats.norm.pdf(z) * sd
        assert lo == pytest.approx(mu - z * sd, abs=5 * se)
        assert hi == pytest.approx(mu + z * sd, abs=5 * se)
    assert diag.converged and diag.warnings == ()
    assert all(v < 1.01 for v in diag.r_hat.values())


def test_yaw_is_circular_across_pi():
    """Yaw near ±π: the circular mean and sd match scipy's, the HDI is an arc through π."""
    rng = np.random.default_rng(2)
    values = _iid(rng)
    yaw = stats.vonmises.rvs(kappa=50, loc=3.1, size=values.shape[:3], random_state=3)
    values[..., 3] = (yaw + np.pi) % (2 * np.pi) - np.pi  # wrapped, as a sampler might return
    summary, _ = summarise(_chains(values), EXPAND)
    flat = values[..., 3].ravel()
    assert summary.mean["yaw"] == pytest.approx(stats.circmean(flat, high=np.pi, low=-np.pi), abs=1e-9)
    assert summary.sd["yaw"] == pytest.approx(stats.circstd(flat, high=np.pi, low=-np.pi), rel=1e-6)
    lo, hi = summary.hdi["yaw"]
    assert lo < np.pi < hi and hi - lo < 1.0
    assert in_hdi("yaw", -np.pi + 0.01, (lo, hi))  # just across the seam
    assert in_hdi("yaw", np.pi - 0.01 + 4 * np.pi, (lo, hi))
    assert not in_hdi("yaw", 0.0, (lo, hi))
    arrays = posterior_arrays(_chains(values), EXPAND)
    assert np.ptp(arrays["yaw"]) < 2.0  # unwrapped around the mean: no jump of 2π


def test_diagnostics_say_why_not_converged():
    rng = np.random.default_rng(4)
    values = _iid(rng, n=60)
    values[:, 0, :, 2] += 1.0  # ensemble 0 stuck elsewhere in z
    _, diag = summarise(_chains(values, tau=5.0), EXPAND, free=FREE, min_ess=1e6)
    assert not diag.converged
    text = " | ".join(diag.warnings)
    assert "R-hat across ensembles above 1.01 for z" in text
    assert "shorter than 50 autocorrelation times" in text
    assert "bulk ESS under 1e+06" in text
    assert "x (" not in text.split("R-hat")[1].split("|")[0]  # only z is flagged for R-hat


def test_result_json_follows_the_contract(tmp_path):
    out = tmp_path / "r.json"
    nc = tmp_path / "r.nc"
    assert main(["demo", "--quiet", "--out", str(out), "--netcdf", str(nc), "--hdi-prob", "0.8"]) == 0
    d = json.loads(out.read_text())
    keys = {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll", "distance_m"}
    for part in ("mean", "median", "sd"):
        assert set(d["posterior"][part]) == keys
    assert d["posterior"]["hdi"]["prob"] == 0.8
    assert all(len(d["posterior"]["hdi"][k]) == 2 for k in keys)
    diag = d["diagnostics"]
    for key in ("n_walkers", "n_steps", "burn_in", "thin", "autocorr_time", "ess_bulk", "r_hat",
                "acceptance_fraction", "converged", "warnings"):
        assert key in diag
    assert diag["n_walkers"] >= 32
    assert set(d["evaluation"]["in_hdi"]) <= keys
    assert d["netcdf"] == str(nc)
    idata = az.from_netcdf(nc)
    # the summary's mean is the mean of the draws written to NetCDF
    assert d["posterior"]["mean"]["z"] == pytest.approx(float(idata.posterior["z"].mean()), rel=1e-9)
    table = summary_table(idata)
    assert {"mean", "sd", "ess_bulk", "r_hat"} <= set(table.columns)


def test_cli_posterior_options(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["demo", "--quiet", "--no-posterior", "--out", str(out)]) == 0
    assert "posterior" not in json.loads(out.read_text())
    assert main(["demo", "--no-posterior", "--netcdf", str(tmp_path / "x.nc")]) == 2
    assert main(["demo", "--hdi-prob", "1.5"]) == 2
    assert main(["demo", "--temperature", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--hdi-prob: expected a probability in (0, 1), got 1.5" in err
    assert "--temperature: expected a number > 0, got -1.0" in err
