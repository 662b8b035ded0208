"""The arviz adapter: InferenceData, posterior summaries, HDI and convergence diagnostics.

Chains come from :func:`.sampling.sample` as (step, ensemble, walker, parameter). In the
InferenceData, ``chain`` is the *ensemble* (the independent unit, so R-hat compares ensembles)
and ``draw`` runs over the kept (post-burn-in, thinned) steps of each walker in turn
("walker-major"): each walker's steps are contiguous, so autocorrelation-based ESS sees walker
chains, not a mix of walkers at one step.

Yaw is circular. Its draws are stored on the arc [m − π, m + π) around their circular mean m, so
they are continuous wherever the posterior is; its mean is the circular mean, its sd the circular
sd √(−2 ln R̄), and its HDI an arc [low, high] (high − low < 2π) whose ends may lie outside
[−π, π) when it straddles ±π. A true yaw is inside when some 2π-shift of it is.
"""

from __future__ import annotations

import warnings as _warnings

import numpy as np

from .autocorr import integrated_time
from ..models.params import PARAM_NAMES, wrap_angle
from ..io.result import Diagnostics, PosteriorSummary

with _warnings.catch_warnings():
    _warnings.simplefilter("ignore", FutureWarning)  # arviz 0.23 announces its refactor on import
    import arviz as az

__all__ = ["SUMMARY_NAMES", "DEFAULT_HDI_PROB", "to_inference_data", "summarise",
           "draws_from_inference_data", "summary_table", "in_hdi", "JSON_DRAWS", "convergence", "hdi_columns"]

#: Quantities summarised, in order: the parameters and the ground distance √(x² + z²).
SUMMARY_NAMES = PARAM_NAMES + ("distance_m",)
DEFAULT_HDI_PROB = 0.9
#: Draws per ensemble kept in the result JSON (for plots without the NetCDF file).
JSON_DRAWS = 100
_RHAT_MAX = 1.01


def _circular_mean(a: np.ndarray) -> float:
    return float(np.arctan2(np.mean(np.sin(a)), np.mean(np.cos(a))))


def _unwrap_around_mean(yaw: np.ndarray) -> np.ndarray:
    m = _circular_mean(yaw)
    return m + wrap_angle(yaw - m)


def _full(expand, free_draws: np.ndarray) -> np.ndarray:
    """(..., n_free) free parameters → (..., 7) full vectors through the model's ``expand``."""
    flat = free_draws.reshape(-1, free_draws.shape[-1])
    return expand(flat).reshape(free_draws.shape[:-1] + (len(PARAM_NAMES),))


def _varies(x: np.ndarray) -> bool:
    """Whether draws vary beyond rounding (a derived roll that is constant in exact arithmetic)."""
    return bool(np.ptp(x) > 1e-9 * max(1.0, float(np.max(np.abs(x)))))


def posterior_arrays(chains, expand) -> dict[str, np.ndarray]:
    """Named (n_ensembles, n_draws) arrays of every summarised quantity.

    Parameters
    ----------
    chains : :class:`~.sampling.Chains` over the free parameters
    expand : the model's map from free parameters (n, n_free) to full vectors (n, 7) (fixed
        values and derived pitch and roll filled in)
    """
    full = _full(expand, chains.draws())  # (n_ens, n_draws, 7)
    out = {name: full[..., i] for i, name in enumerate(PARAM_NAMES)}
    out["yaw"] = _unwrap_around_mean(out["yaw"])
    out["distance_m"] = np.hypot(out["x"], out["z"])
    return out


def to_inference_data(chains, expand, *, scene=None, attrs: dict | None = None,
                      arrays: dict | None = None) -> "az.InferenceData":
    """An InferenceData of a run (module docstring for the layout).

    Groups: ``posterior`` (x, y, z, yaw, focal_length_px, pitch, roll, distance_m), ``sample_stats`` (``lp``,
    the log-posterior −cost′/T up to a constant; ``accepted``, whether the step into this draw
    was an accepted move), and, given the scene, ``observed_data`` (the dimension-line corners,
    their per-corner median, the reference lines and their [low, high] values).
    """
    post = arrays if arrays is not None else posterior_arrays(chains, expand)
    lp = chains.draws(chains.log_prob)
    moved = np.ones(chains.chain.shape[:3], bool)
    moved[1:] = np.any(chains.chain[1:] != chains.chain[:-1], axis=-1)
    stats = {"lp": lp, "accepted": chains.draws(moved)}
    observed, dims = {}, {}
    if scene is not None:
        t = scene.target
        observed["corners"] = t.corners
        observed["median_corners"] = t.median_corners
        dims.update({"corners": ["annotation", "corner", "pixel_axis"],
                     "median_corners": ["corner", "pixel_axis"]})
        if scene.references:
            observed["reference_lines"] = np.stack([r.line for r in scene.references])
            observed["reference_values"] = np.array([[r.low, r.high] for r in scene.references])
            dims.update({"reference_lines": ["reference", "end", "pixel_axis"],
                         "reference_values": ["reference", "bound"]})
    meta = {"draw_order": "walker-major: draw = walker * n_kept + kept_step",
            "yaw": "radians, on the arc [m - pi, m + pi) around the circular mean m",
            "burn_in": chains.burn_in, "thin": chains.thin,
            "walkers_per_ensemble": chains.n_walkers, **(attrs or {})}
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", FutureWarning)
        idata = az.from_dict(posterior=post, sample_stats=stats, observed_data=observed or None,
                             dims=dims or None, attrs=meta)
    return idata


def draws_from_inference_data(idata) -> dict[str, np.ndarray]:
    """Named (chain, draw) arrays from an InferenceData's posterior group."""
    return {k: np.asarray(v) for k, v in idata.posterior.data_vars.items()}


def _hdi(x: np.ndarray, prob: float) -> tuple[float, float]:
    lo, hi = az.hdi(np.asarray(x).ravel(), hdi_prob=prob)
    return float(lo), float(hi)


def _yaw_hdi(yaw: np.ndarray, prob: float) -> tuple[float, float]:
    lo, hi = _hdi(yaw, prob)  # yaw is already unwrapped around its circular mean
    shift = 2 * np.pi * np.round((lo + hi) / 2 / (2 * np.pi))
    return lo - shift, hi - shift


def in_hdi(name: str, value: float, interval) -> bool:
    """Whether ``value`` lies in the HDI ``interval`` (yaw: on the circle)."""
    lo, hi = interval
    if name == "yaw":
        return bool(lo + (value - lo) % (2 * np.pi) <= hi)
    return bool(lo <= value <= hi)


def summarise(chains, expand, *, free=None, hdi_prob: float = DEFAULT_HDI_PROB, min_ess: float = 1000.0,
              tau_multiple: float = 50.0, handedness: int = 0, temperature: float = 1.0,
              arrays: dict | None = None) -> tuple[PosteriorSummary, Diagnostics]:
    """Posterior summary and diagnostics of a run.

    Parameters
    ----------
    chains : :class:`~.sampling.Chains` over the free parameters
    expand : the model's map from free parameters to full vectors (:func:`posterior_arrays`)
    free : (7,) bool, the sampled parameters: their autocorrelation times are the sampler's own
        (``chains.autocorr_time``); those of derived quantities are computed here. None: compute
        all here
    hdi_prob : probability of the highest-density intervals
    min_ess, tau_multiple : the convergence requirements (bulk ESS of every sampled quantity;
        chain length after burn-in in autocorrelation times)
    arrays : the output of :func:`posterior_arrays`, if already computed

    Returns
    -------
    PosteriorSummary, Diagnostics
    """
    if not 0.0 < hdi_prob < 1.0:
        raise ValueError(f"hdi_prob: expected a probability in (0, 1), got {hdi_prob!r}")
    post = arrays if arrays is not None else posterior_arrays(chains, expand)
    # sampled or derived from sampled ones (pitch and roll from µ and a horizon): not constant
    sampled = [n for n in SUMMARY_NAMES if _varies(post[n])]
    mean, median, sd, hdi = {}, {}, {}, {}
    for name in SUMMARY_NAMES:
        x = post[name]
        if name not in sampled:  # fixed (a known focal length): a point mass
            v = float(x.ravel()[0])
            mean[name], median[name], sd[name], hdi[name] = v, v, 0.0, (v, v)
        elif name == "yaw":
            mean[name] = float(wrap_angle(_circular_mean(x)))
            median[name] = float(wrap_angle(np.median(x)))
            r = np.hypot(np.mean(np.sin(x)), np.mean(np.cos(x)))
            sd[name] = float(np.sqrt(-2.0 * np.log(min(max(r, 1e-300), 1.0))))
            hdi[name] = _yaw_hdi(x, hdi_prob)
        else:
            mean[name], median[name], sd[name] = float(np.mean(x)), float(np.median(x)), float(np.std(x))
            hdi[name] = _hdi(x, hdi_prob)
    summary = PosteriorSummary(mean=mean, median=median, sd=sd, hdi=hdi, hdi_prob=hdi_prob,
                               handedness=int(handedness), temperature=float(temperature),
                               n_draws=int(post["x"].size),
                               draws=_json_draws(post, sampled))
    return summary, _diagnostics(chains, post, sampled, expand, free, min_ess, tau_multiple)


def _json_draws(post: dict, names: list[str]) -> dict:
    """A few evenly spaced draws per ensemble, rounded, for plots from the JSON alone."""
    n_ens, n_draws = post["x"].shape
    k = min(JSON_DRAWS, n_draws)
    idx = np.linspace(0, n_draws - 1, k).round().astype(int)
    out = {"chain": np.repeat(np.arange(n_ens), k).tolist()}
    for name in SUMMARY_NAMES:
        out[name] = [float(f"{v:.7g}") for v in post[name][:, idx].ravel()]
    return out


def _diagnostics(chains, post, sampled, expand, free, min_ess, tau_multiple) -> Diagnostics:
    kept = chains.chain[chains.burn_in:]
    full = _full(expand, kept).reshape(len(kept), -1, len(PARAM_NAMES))  # (step, walker, 7)
    tau = {n: float(t) for n, t in zip(PARAM_NAMES, integrated_time(full)) if n in sampled}
    if free is not None:  # the sampler's own estimate for what it sampled
        tau.update(zip([n for n, f in zip(PARAM_NAMES, free) if f], map(float, chains.autocorr_time)))
    tau["distance_m"] = float(integrated_time(np.hypot(full[..., 0], full[..., 2])))
    # the sampler's own, for what its stopping rule watched besides the parameters (a dict of
    # name → τ; :func:`creference_bayes.pipeline._reported`)
    derived = chains.info.get("derived_tau")
    if isinstance(derived, dict):
        tau.update({k: float(v) for k, v in derived.items() if k in tau})
    ess, ess_tail, rhat = {}, {}, {}
    for name in sampled:
        a = post[name]
        ess[name] = _finite(az.ess(a, method="bulk"))
        ess_tail[name] = _finite(az.ess(a, method="tail"))
        rhat[name] = _finite(az.rhat(a))
    reasons = []
    n_after = chains.n_steps - chains.burn_in
    tau_max = max(tau.values())
    if n_after < tau_multiple * tau_max:
        reasons.append(f"chain after burn-in is {n_after} steps, shorter than {tau_multiple:g} "
                       f"autocorrelation times ({tau_multiple * tau_max:.0f} steps)")
    high = {k: v for k, v in rhat.items() if v is None or v > _RHAT_MAX}
    if high:
        reasons.append("R-hat across ensembles above 1.01 for " + ", ".join(
            f"{k} ({'nan' if v is None else f'{v:.3f}'})" for k, v in high.items()))
    low = {k: v for k, v in ess.items() if v is None or v < min_ess}
    if low:
        reasons.append(f"bulk ESS under {min_ess:g} for " + ", ".join(
            f"{k} ({'nan' if v is None else f'{v:.0f}'})" for k, v in low.items()))
    if chains.info.get("stopped") == "max_steps":
        reasons.append(f"stopped at the step cap ({chains.n_steps} steps)")
    notes = []
    if chains.info.get("nonfinite"):
        notes.append(f"the log-posterior returned NaN or +inf {chains.info['nonfinite']} times "
                     "(treated as zero density)")
    return Diagnostics(
        n_walkers=chains.n_ensembles * chains.n_walkers, n_ensembles=chains.n_ensembles,
        n_steps=chains.n_steps, burn_in=chains.burn_in, thin=chains.thin,
        warmup_steps=chains.warmup_steps, autocorr_time=tau, ess_bulk=ess, ess_tail=ess_tail,
        r_hat=rhat, acceptance_fraction=float(np.mean(chains.acceptance_fraction)),
        converged=not reasons, warnings=tuple(reasons + notes), seconds=float(chains.seconds))


def _finite(v) -> float | None:
    v = float(np.asarray(v))
    return v if np.isfinite(v) else None


def summary_table(idata, hdi_prob: float = DEFAULT_HDI_PROB):
    """``az.summary`` of the posterior (a pandas DataFrame), yaw treated as circular."""
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        return az.summary(idata, hdi_prob=hdi_prob, circ_var_names=["yaw"])


def evaluate_posterior(summary: PosteriorSummary, truth, names) -> tuple[float, dict[str, bool]]:
    """Posterior-mean location error (Eq. 3, %) and whether each true value is in its HDI.

    Parameters
    ----------
    summary : the posterior summary
    truth : :class:`~creference_bayes.io.scene.GroundTruth`
    names : the sampled quantities to check (those with a true value are checked)
    """
    from ..core.metrics import location_percentage_error

    loc = np.array([summary.mean[k] for k in ("x", "y", "z")])
    true_loc = np.asarray(truth.location_m, float)
    values = {"x": true_loc[0], "y": true_loc[1], "z": true_loc[2], "yaw": truth.yaw_rad,
              "focal_length_px": truth.focal_length_px, "pitch": truth.extra.get("pitch_rad"),
              "roll": truth.extra.get("roll_rad"), "distance_m": float(np.hypot(true_loc[0], true_loc[2]))}
    inside = {k: in_hdi(k, float(values[k]), summary.hdi[k])
              for k in names if values.get(k) is not None}
    return float(location_percentage_error(loc, true_loc)), inside


def convergence(draws: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bulk ESS, tail ESS and rank-normalised split R-hat of every column of ``draws`` (chain,
    draw, k), each (k,); constant columns get NaN."""
    ds = az.convert_to_dataset({"p": np.asarray(draws, float)})
    ess_b = az.ess(ds, method="bulk")["p"].values
    ess_t = az.ess(ds, method="tail")["p"].values
    rhat = az.rhat(ds)["p"].values
    return np.asarray(ess_b, float), np.asarray(ess_t, float), np.asarray(rhat, float)


def hdi_columns(samples: np.ndarray, prob: float) -> np.ndarray:
    """Highest-density interval of every column of ``samples`` (N, k): (k, 2)."""
    s = np.asarray(samples, float)
    return np.array([az.hdi(s[:, j], hdi_prob=prob) for j in range(s.shape[1])]).reshape(-1, 2)
