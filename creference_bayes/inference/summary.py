"""The arviz adapter: the posterior of any result as an ``arviz.InferenceData``, and its summary
table. The only module that imports arviz.

The groups and their coordinates are documented in docs/result_format.md ("The netCDF file"): a
``chain`` is one independent unit of the sampler; ``log_likelihood.observations`` holds every
observation the model has and nothing else (:func:`observations`), so that ``arviz.loo`` counts
them right; every group's attributes hold the result's provenance (:func:`_provenance`).
``log_likelihood``, ``observed_data`` and ``constant_data`` need the model; without it the
attribute ``missing`` says why.
"""

from __future__ import annotations

import json
import warnings as _warnings

import numpy as np

from ..models.contract import CAMERA_NAMES, OBJECT_REPORT, object_report

with _warnings.catch_warnings():
    _warnings.simplefilter("ignore", FutureWarning)  # arviz 0.23 announces its refactor on import
    import arviz as az

__all__ = ["OBJECT_VARS", "CAMERA_VARS", "to_inference_data", "observations", "summary_table", "psis_weights", "az"]

#: The per-object quantities of the posterior group, in order (the results' own report).
OBJECT_VARS = OBJECT_REPORT
#: The camera's quantities of the posterior group, in the camera block's order (the camera's
#: height renamed: objects have a ``height_m`` of their own).
CAMERA_VARS = tuple("camera_height_m" if n == "height_m" else n for n in CAMERA_NAMES)


def observations(model, cams: np.ndarray, objs: np.ndarray, hands: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """The log-likelihood of each observation the model has at each draw, (n, k), and the
    coordinates of the ``observation`` dimension (module docstring): the model's pointwise terms
    without the padding (an object's missing sets of dimension lines, a horizon not measured,
    targets without references). ``hands`` (n, m): each draw's handedness (None: the model's)."""
    # each draw's terms at its own handedness: the model at one handedness per row
    ll = (model if hands is None else model.at_handedness(hands)).pointwise_log_likelihood(cams, objs)
    cols, coords = [], {"observation": [], "kind": [], "target": [], "index": []}

    def add(column, label, kind, target, index):
        cols.append(column)
        for k, v in zip(coords, (label, kind, target, index)):
            coords[k].append(v)

    ann = ll["annotations"]  # (n, m, K), padded where an object has fewer sets
    for i, o in enumerate(model.objects):
        for j in range(min(len(o.annotations), ann.shape[2])):
            add(ann[:, i, j], f"{o.id}/{j}", "annotation", o.id, j)
    refs = ll.get("references")
    if refs is not None and refs.size:
        if "reference_bounds" in model.capabilities:  # one penalty per target
            for i, (o, c) in enumerate(zip(model.objects, model.constraints)):
                if c is not None and c.n_pairs:
                    add(refs[:, i], f"{o.id}/references", "reference", o.id, i)
        elif "reference_likelihood" in model.capabilities:
            for k, r in enumerate(model.references):
                add(refs[:, k], f"reference {r.index}", "reference", "", int(r.index))
    hz = model.camera_terms.horizon
    if hz is not None and model.orientation == "free" and "horizon" in ll:
        add(ll["horizon"], "horizon", "horizon", "", 0)
    values = np.stack(cols, axis=-1) if cols else np.zeros((len(cams), 0))
    return values, coords


def _provenance(data: dict, note: str | None) -> dict:
    from .. import __version__

    out = {"format": str(data.get("format")), "model": str(data.get("model")), "preset": str(data.get("preset")),
           "scene": str(data.get("scene")), "scene_sha256": str((data.get("scene_id") or {}).get("sha256")),
           "provenance": json.dumps(data.get("provenance") or {}, sort_keys=True),
           "yaw": "radians, on the arc of ±pi around the MAP's", "creference_bayes_version": __version__,
           "inference_library": "emcee"}
    if note:
        out["missing"] = note
    return out


def to_inference_data(data: dict, draws, model=None, note: str | None = None) -> "az.InferenceData | None":
    """The posterior of a result as an InferenceData (module docstring for the layout), or None
    for a result without draws.

    Parameters
    ----------
    data : the result's dict (``creference-result/2``)
    draws : its draws: ``cameras`` (chain, draw, 5), ``objects`` (chain, draw, m, 7), ``log_prob``
        (chain, draw) or None
    model : the model estimated (or rebuilt); None: no ``log_likelihood``, ``observed_data`` and
        ``constant_data``
    note : why the model is missing (the attribute ``missing``)
    """
    if draws is None:
        return None
    cams, objs = np.asarray(draws.cameras, float), np.asarray(draws.objects, float)
    C, N, m = objs.shape[:3]
    ids = [o["id"] for o in data["objects"]]
    yaw_centre = np.array([o["map"]["yaw"] for o in data["objects"]])
    post = {name: cams[..., k] for k, name in enumerate(CAMERA_VARS)}
    table = object_report(cams, objs, yaw_centre)
    post.update({name: table[..., k] for k, name in enumerate(OBJECT_VARS)})
    attrs = _provenance(data, note)

    def dataset(values, dims, coords=None, sample=True):
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore", FutureWarning)
            return az.dict_to_dataset(values, coords=coords, dims=dims, attrs=attrs, index_origin=0,
                                      default_dims=None if sample else [])

    dims = {name: ["object"] for name in OBJECT_VARS}
    if getattr(draws, "handedness", None) is not None:  # a target sampled at both handednesses
        post["handedness"], dims["handedness"] = np.asarray(draws.handedness, float), ["object"]
    groups = {"posterior": dataset(post, dims, {"object": ids})}
    if draws.log_prob is not None:
        groups["sample_stats"] = dataset({"lp": np.asarray(draws.log_prob, float)}, {})
    if model is not None:
        hands = getattr(draws, "handedness", None)
        ll, where = observations(model, cams.reshape(-1, 5), objs.reshape(-1, m, 7),
                                 None if hands is None else np.asarray(hands, float).reshape(-1, m))
        ds = dataset({"observations": ll.reshape(C, N, -1)}, {"observations": ["observation"]},
                     {"observation": where["observation"]})
        groups["log_likelihood"] = ds.assign_coords({k: ("observation", where[k]) for k in ("kind", "target", "index")})
        labels = [(o.id, j) for o in model.objects for j in range(len(o.annotations))]
        observed = {"corners": np.concatenate([o.annotations for o in model.objects])}
        refs = model.all_references if "reference_likelihood" in model.capabilities else ()
        if refs:
            observed["reference_values"] = np.array([[r.low, r.high] for r in refs])
            observed["reference_lines"] = np.array([np.full((2, 2), np.nan) if r.line is None else r.line
                                                    for r in refs])
        ds = dataset(observed, {"corners": ["annotation", "corner", "pixel_axis"],
                                "reference_values": ["reference", "bound"],
                                "reference_lines": ["reference", "end", "pixel_axis"]},
                     {"annotation": [f"{t}/{j}" for t, j in labels], "reference": [int(r.index) for r in refs]},
                     sample=False)
        groups["observed_data"] = ds.assign_coords(annotation_target=("annotation", [t for t, _ in labels]),
                                                   annotation_index=("annotation", [j for _, j in labels]))
        constant = {"principal_point": np.asarray(model.principal_point, float),
                    "image_size": np.asarray(data.get("image_size") or model.image_size, float),
                    "handedness": np.asarray(model.handedness, float)}
        groups["constant_data"] = dataset(constant, {"principal_point": ["pixel_axis"], "image_size": ["pixel_axis"],
                                                     "handedness": ["object"]}, {"object": ids}, sample=False)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", FutureWarning)
        return az.InferenceData(**groups)


def summary_table(data: dict):
    """A result's summary as a pandas DataFrame, a row per quantity (the camera's by name, each
    object's as ``name[id]``, as ``arviz.summary`` names them): the MAP, the posterior's mean, sd,
    median and HDI (``hdi_5%``, ``hdi_95%`` for an HDI of 0.9), the sampler's bulk ESS and R-hat
    (NaN where the result has none: a fixed quantity, no posterior). The numbers are the result's
    own (its file's, from every draw), so a result read back from its file gives the same table."""
    import pandas as pd

    prob = data.get("hdi_prob") or 0.9
    lo, hi = f"hdi_{100 * (1 - prob) / 2:g}%", f"hdi_{100 * (1 + prob) / 2:g}%"
    diag = data.get("diagnostics") or {}
    ess, rhat = diag.get("ess_bulk") or {}, diag.get("r_hat") or {}
    rows, index = [], []

    def num(v):
        return np.nan if v is None else float(v)

    def row(label, name, block, key):
        post = block.get("posterior") or {}
        interval = (post.get("hdi") or {}).get(name) or (None, None)
        index.append(label)
        rows.append({"map": num(block["map"].get(name)), "mean": num((post.get("mean") or {}).get(name)),
                     "sd": num((post.get("sd") or {}).get(name)), "median": num((post.get("median") or {}).get(name)),
                     lo: num(interval[0]), hi: num(interval[1]), "ess_bulk": num(ess.get(key)),
                     "r_hat": num(rhat.get(key))})

    camera = data["camera"]
    for name, var in zip(CAMERA_NAMES, CAMERA_VARS):
        row(var, name, camera, f"camera.{name}")
    for o in data["objects"]:
        for name in OBJECT_VARS:
            row(f"{name}[{o['id']}]", name, o, f"{o['id']}.{name}")
    return pd.DataFrame(rows, index=index)


def psis_weights(log_ratios: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised Pareto-smoothed importance weights and their Pareto shapes.

    Parameters
    ----------
    log_ratios : (n_obs, n_draws) log importance ratios (for leave-one-out: minus each
        observation's log-likelihood term at each draw)

    Returns
    -------
    weights : (n_obs, n_draws), each row summing to 1
    k : (n_obs,) Pareto shape estimates
    """
    lr = np.atleast_2d(np.asarray(log_ratios, float))
    if not np.all(np.isfinite(lr)):
        raise ValueError("log_ratios: expected finite numbers")
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")  # arviz warns about k̂ itself; the caller decides
        lw, k = az.psislw(lr.copy(), reff=1.0)
    w = np.exp(lw - lw.max(axis=1, keepdims=True))
    return w / w.sum(axis=1, keepdims=True), np.atleast_1d(np.asarray(k, float))
