"""The arviz adapter: the posterior of any scene as an ``arviz.InferenceData``, its diagnostics.

Layout of :func:`to_inference_data`. ``chain`` is what the sampler ran independently: one of its
ensembles for a scene of one object (each ensemble's walkers' draws, laid end to end), one walker
for a scene of several (block sweeps):

* ``posterior``: the camera's ``focal_length_px``, ``pitch``, ``roll``, ``camera_height_m``,
  ``ref_scale`` (chain, draw) and each object's ``x``, ``y``, ``z``, ``yaw``, ``length_m``,
  ``width_m``, ``height_m``, ``ground_m`` and ``distance_m`` (chain, draw, object), metres and radians
  (``y`` is the camera height less the object's ground offset; yaw on the arc of ±π around the
  MAP's);
* ``sample_stats``: ``lp``, the log-posterior density in the sampler's coordinates;
* ``log_likelihood``: the log-likelihood of every observation at every draw (the model's
  :meth:`~creference_bayes.models.contract.Model.pointwise_log_likelihood`): ``annotations``
  (chain, draw, object, annotation; 0 where an object has fewer), ``references`` and ``horizon``;
* ``observed_data``: the dimension-line corners (object, annotation, corner, pixel_axis; NaN where
  an object has fewer annotations), the reference lines (NaN for a reference without one) and their
  stated [low, high] (metres, or ratios for relative ones).
"""

from __future__ import annotations

import warnings as _warnings

import numpy as np

from ..models.contract import CAMERA_NAMES, OBJECT_REPORT, object_report

with _warnings.catch_warnings():
    _warnings.simplefilter("ignore", FutureWarning)  # arviz 0.23 announces its refactor on import
    import arviz as az

__all__ = ["OBJECT_VARS", "CAMERA_VARS", "to_inference_data", "summary_table", "az"]

#: The per-object quantities of the posterior group, in order (the results' own report).
OBJECT_VARS = OBJECT_REPORT
#: The camera's quantities of the posterior group, in the camera block's order (the camera's
#: height renamed: objects have a ``height_m`` of their own).
CAMERA_VARS = tuple("camera_height_m" if n == "height_m" else n for n in CAMERA_NAMES)


def to_inference_data(result, attrs: dict | None = None) -> "az.InferenceData | None":
    """The whole posterior of an estimate as an InferenceData (module docstring for the layout),
    or None for an estimate without draws.

    Parameters
    ----------
    result : :class:`~creference_bayes.io.result.Result` returned by :func:`creference_bayes.estimate`
        (a result read back from its file holds a thinned set of draws only: use
        ``result["draws"]`` there)
    attrs : extra metadata for the InferenceData
    """
    draws, model = result.draws, result.model
    if draws is None or model is None:
        return None
    cams, objs = draws.cameras, draws.objects  # (C, N, 5), (C, N, m, 7)
    C, N, m = objs.shape[:3]
    yaw_centre = np.array([o["map"]["yaw"] for o in result.data["objects"]])
    post = {name: cams[..., k] for k, name in enumerate(CAMERA_VARS)}
    table = object_report(cams, objs, yaw_centre)
    post.update({name: table[..., k] for k, name in enumerate(OBJECT_VARS)})
    ll = model.pointwise_log_likelihood(cams.reshape(-1, 5), objs.reshape(-1, m, 7))
    log_lik = {k: v.reshape((C, N) + v.shape[1:]) for k, v in ll.items() if v.size}
    K = max(len(o.annotations) for o in model.objects)
    corners = np.full((m, K, 4, 2), np.nan)
    for i, o in enumerate(model.objects):
        corners[i, :len(o.annotations)] = o.annotations
    observed = {"corners": corners}
    refs = getattr(model, "all_references", ())
    if refs:
        observed["reference_values"] = np.array([[r.low, r.high] for r in refs])
        observed["reference_lines"] = np.array([np.full((2, 2), np.nan) if r.line is None else r.line for r in refs])
    dims = {name: ["object"] for name in OBJECT_VARS}
    dims.update({"corners": ["object", "annotation", "corner", "pixel_axis"], "reference_values": ["reference", "bound"],
                 "reference_lines": ["reference", "end", "pixel_axis"], "annotations": ["object", "annotation"],
                 "references": ["reference_used" if model.name == "metrology" else "object"]})
    meta = {"model": model.name, "handedness": [int(h) for h in model.handedness],
            "yaw": "radians, on the arc of ±pi around the MAP's", "scene": str(result.data.get("scene")),
            **(attrs or {})}
    stats = {"lp": draws.log_prob} if draws.log_prob is not None else None
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore", FutureWarning)
        return az.from_dict(posterior=post, sample_stats=stats, log_likelihood=log_lik, observed_data=observed,
                            coords={"object": [o.id for o in model.objects]}, dims=dims, attrs=meta)


def summary_table(idata, hdi_prob: float = 0.9):
    """``az.summary`` of the posterior (a pandas DataFrame), yaw treated as circular."""
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        return az.summary(idata, hdi_prob=hdi_prob, circ_var_names=["yaw"])
