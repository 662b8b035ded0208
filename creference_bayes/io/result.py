"""The estimate of a scene, and its file ``creference-result/2`` (docs/result_format.md).

One format for every scene: the shared camera and every target, each with its MAP, its posterior
summary (mean, median, sd, highest-density intervals) and, given the scene's ground truth, an
evaluation. The result records how it was made (``provenance``: the model, the preset, its options,
the camera's treatment, the seed, the sampler settings, the classes given by the user, the bounds;
``pilot_camera`` and each target's ``handedness``), so
:func:`creference_bayes.pipeline.rebuild_model` makes the same model again from the result and
its scene. ``creference-result/1`` files (one target, written before) are still read
(:func:`result_from_v1`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..models.contract import C_FOCAL, CAMERA_NAMES, O_YAW, OBJECT_NAMES, OBJECT_REPORT, object_report
from ..models.metrology import MIN_TARGET_SIGMA_PX
from .validation import _short

__all__ = ["RESULT_FORMAT", "RESULT_FORMATS", "RESULT_DRAWS", "OBJECT_REPORT", "ObjectEstimate", "CameraEstimate",
           "StoredDraws", "hdi", "result_data", "stored_draws", "chained_draws", "read_result", "result_from_v1", "scene_candidates", "scene_path_from", "scene_mismatch",
           "find_scene", "canonical_sha256", "map_checks"]

RESULT_FORMAT = "creference-result/2"
#: The result formats this package reads.
RESULT_FORMATS = ("creference-result/1", RESULT_FORMAT)
#: Posterior draws a result keeps (``draws``: evenly spaced over every chain's draws), enough for
#: the labels' P(IoU ≥ t) to about ±0.025 and small enough for a batch of thousands of scenes.
RESULT_DRAWS = 400
#: Decimals of the kept draws (10 µm, 10 µrad, 10⁻⁵ px).
DRAW_DECIMALS = 5
#: How far the MAP's box may miss its annotations (RMS of its corners from their median, over
#: this many times the annotations' own spread) before the result says so.
REPROJECTION_WARN_FACTOR = 3.0
REPROJECTION_MIN_SPREAD_PX = 1.0


def hdi(samples: np.ndarray, prob: float) -> np.ndarray:
    """Highest-density interval of each column of (N, k) samples: the narrowest window holding
    ``prob`` of the sorted draws, (k, 2)."""
    x = np.sort(np.asarray(samples, float), axis=0)
    n = len(x)
    w = max(1, min(n - 1, int(np.floor(prob * n))))
    widths = x[w:] - x[:n - w]
    i = np.argmin(widths, axis=0)
    cols = np.arange(x.shape[1])
    return np.column_stack([x[i, cols], x[i + w, cols]])


def _summary(x: np.ndarray, prob: float) -> dict:
    return {"mean": x.mean(axis=0), "median": np.median(x, axis=0), "sd": x.std(axis=0, ddof=1), "hdi": hdi(x, prob)}


@dataclass(frozen=True)
class StoredDraws:
    """Draws read back from a result's ``draws``: cameras (chain, n, 5), objects (chain, n, m, 7),
    natural parameters in the order of ``CAMERA_NAMES`` and ``OBJECT_NAMES``, and the log-density
    of each (chain, n) in the sampler's coordinates (None when the file has none)."""

    cameras: np.ndarray
    objects: np.ndarray
    log_prob: np.ndarray | None = None
    #: each draw's handedness of every object (chain, n, m) where the file gives it (a target
    #: sampled at both handednesses), else None
    handedness: np.ndarray | None = None


def _column(v: np.ndarray):
    """A kept column: one number when every draw has it (a fixed parameter), else the list."""
    v = np.round(np.asarray(v, float), DRAW_DECIMALS)
    return float(v[0]) if np.all(v == v[0]) else v.tolist()


def _keep_draws(cams: np.ndarray, objs: np.ndarray, n_keep: int, n_chains: int, lp: np.ndarray | None = None,
                hands: np.ndarray | None = None) -> dict:
    """Evenly spaced draws of the chains' draws laid end to end, each with its chain (and its
    log-density, ``lp``, and each object's handedness, ``hands`` (n, m), where it varies)."""
    n = len(cams)
    idx = np.unique(np.linspace(0, n - 1, min(n_keep, n)).round().astype(int))
    out = {"n": int(len(idx)), "of": int(n), "chain": (idx // (n // n_chains)).tolist(),
           "camera": {k: _column(cams[idx, j]) for j, k in enumerate(CAMERA_NAMES)},
           "objects": [{k: _column(objs[idx, i, j]) for j, k in enumerate(OBJECT_NAMES)}
                       for i in range(objs.shape[1])]}
    if lp is not None:
        out["lp"] = _column(np.asarray(lp, float).reshape(-1)[idx])
    if hands is not None:
        for i, o in enumerate(out["objects"]):
            o["handedness"] = [int(v) for v in hands[idx, i]]
    return out


def stored_draws(d: dict) -> StoredDraws | None:
    """The draws a result dict keeps (its ``draws``), or None when it has none; ``ValueError``
    (naming the key) when ``draws`` is malformed."""
    kept = d.get("draws")
    if not kept:
        return None
    try:
        n = int(kept["n"])
        col = lambda v: np.broadcast_to(np.asarray(v, float), (n,))
        cams = np.column_stack([col(kept["camera"][k]) for k in CAMERA_NAMES])
        objs = np.stack([np.column_stack([col(o[k]) for k in OBJECT_NAMES]) for o in kept["objects"]], axis=1)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f"draws: not the draws of a {RESULT_FORMAT} ({' '.join(str(exc).split())})") from None
    if not (np.all(np.isfinite(cams)) and np.all(np.isfinite(objs))):
        raise ValueError("draws: expected finite numbers")
    if objs.shape[1] != len(d.get("objects", ())):
        raise ValueError(f"draws.objects: {objs.shape[1]} objects, the result has {len(d.get('objects', ()))}")
    lp = None
    if kept.get("lp") is not None:
        try:
            lp = np.broadcast_to(np.asarray(kept["lp"], float), (n,)).copy()
        except (TypeError, ValueError):
            raise ValueError(f"draws.lp: expected {n} numbers") from None
    hands = None
    if any("handedness" in o for o in kept["objects"]):
        try:
            hands = np.column_stack([np.broadcast_to(np.asarray(o["handedness"] if "handedness" in o else
                                                                d["objects"][i]["handedness"], float), (n,))
                                     for i, o in enumerate(kept["objects"])])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"draws.objects[].handedness: expected {n} values of 1 or -1") from None
        if not np.all(np.isin(hands, (-1.0, 1.0))):
            raise ValueError(f"draws.objects[].handedness: expected 1 or -1, got {sorted(set(hands.ravel()) - {-1.0, 1.0})[:3]}")
    return StoredDraws(cams[None], objs[None], None if lp is None else lp[None], None if hands is None else hands[None])


def chained_draws(d: dict) -> StoredDraws | None:
    """The kept draws of a result dict arranged by the chain each came from (``draws.chain``):
    cameras (chain, k, 5), objects (chain, k, m, 7), each chain cut to the shortest one's k
    draws (the even spacing leaves them a draw apart at most); one chain when the file does not
    say. None when the result keeps no draws."""
    kept = stored_draws(d)
    if kept is None:
        return None
    chain = d["draws"].get("chain")
    if not isinstance(chain, list) or len(chain) != kept.cameras.shape[1]:
        return kept
    chain = np.asarray(chain, int)
    rows = [np.flatnonzero(chain == c) for c in np.unique(chain)]
    k = min(len(r) for r in rows)
    pick = np.stack([r[:k] for r in rows])  # (C, k) indices into the kept draws
    lp = None if kept.log_prob is None else kept.log_prob[0][pick]
    hands = None if kept.handedness is None else kept.handedness[0][pick]
    return StoredDraws(kept.cameras[0][pick], kept.objects[0][pick], lp, hands)


def _r(v, nd=6):
    return None if v is None or not np.isfinite(v) else round(float(v), nd)


def _named(names, values, keep=None) -> dict:
    """``names`` → rounded ``values`` (``keep``: which of them; None: all)."""
    return {n: _r(v) if np.ndim(v) == 0 else [_r(x) for x in v]
            for n, v, k in zip(names, values, [True] * len(names) if keep is None else keep) if k}


def _posterior_block(names, s: dict, prob: float, keep=None) -> dict:
    out = {k: _named(names, s[k], keep) for k in ("mean", "median", "sd", "hdi")}
    out["hdi"]["prob"] = prob
    return out


def camera_posterior(cams: np.ndarray, prob: float, free) -> dict:
    """A result's ``camera.posterior`` from draws ``cams`` (n, 5): the parameters ``free`` (5,)
    and those whose draws spread with them (an exact horizon's pitch follows the focal length)."""
    spread = np.asarray(free, bool) | (np.ptp(cams, axis=0) > 1e-9 * (1.0 + np.abs(cams).max(axis=0)))
    return _posterior_block(CAMERA_NAMES, _summary(cams, prob), prob, spread)


def _pairs(block: dict | None, names) -> dict:
    """``{name: (low, high)}`` of an HDI block (its ``prob`` left out); empty for None."""
    return {} if not block else {n: tuple(block[n]) for n in names if n in block and block[n] is not None}


def _values(block: dict | None, names) -> dict:
    return {} if not block else {n: block[n] for n in names if n in block}


@dataclass(frozen=True)
class ObjectEstimate:
    """One target's estimate (a result's ``objects`` entry, read for Python).

    Attributes
    ----------
    id, cls : the target's id and class
    location_m : the MAP's (x, y, z), metres, camera frame (x right, y down to the ground, z ahead)
    size_m : the MAP's (length, width, height), metres
    yaw_rad, distance_m : the MAP's yaw (radians) and ground distance from the camera (metres)
    map : every reported quantity's MAP (``OBJECT_REPORT`` names)
    mean, sd, median : the posterior's (empty without a posterior)
    hdi : quantity → (low, high), the highest-density interval of probability ``hdi_prob``
    hdi_prob : the HDIs' probability, or None without a posterior
    n_annotations : the target's sets of dimension lines
    evaluation : errors against the scene's ground truth, or None
    """

    id: str
    cls: str | None
    location_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    yaw_rad: float
    distance_m: float
    map: dict
    mean: dict
    sd: dict
    median: dict
    hdi: dict
    hdi_prob: float | None
    n_annotations: int
    evaluation: dict | None = None

    @classmethod
    def from_dict(cls, o: dict) -> "ObjectEstimate":
        m = o["map"]
        return cls(id=o["id"], cls=o.get("class"), location_m=(m["x"], m["y"], m["z"]),
                   size_m=(m["length_m"], m["width_m"], m["height_m"]), yaw_rad=m["yaw"],
                   distance_m=m["distance_m"], map=dict(m), **_posterior_fields(o.get("posterior"), OBJECT_REPORT),
                   n_annotations=int(o.get("n_annotations", 0)), evaluation=o.get("evaluation"))


@dataclass(frozen=True)
class CameraEstimate:
    """The shared camera's estimate (a result's ``camera``, read for Python): the MAP's focal
    length (px), pitch and roll (radians) and height (metres); ``free`` the quantities estimated
    (the others fixed); ``map``, ``mean``, ``sd``, ``median``, ``hdi`` as for
    :class:`ObjectEstimate` (``CAMERA_NAMES``), the posterior's of the quantities with a spread in
    its draws (the free ones and those derived from them, as an exact horizon's pitch from µ)."""

    focal_length_px: float
    pitch_rad: float
    roll_rad: float
    height_m: float
    free: tuple[str, ...]
    map: dict
    mean: dict
    sd: dict
    median: dict
    hdi: dict
    hdi_prob: float | None

    @classmethod
    def from_dict(cls, c: dict) -> "CameraEstimate":
        m = c["map"]
        return cls(focal_length_px=m["focal_length_px"], pitch_rad=m["pitch"], roll_rad=m["roll"],
                   height_m=m["height_m"], free=tuple(c.get("free", ())), map=dict(m),
                   **_posterior_fields(c.get("posterior"), CAMERA_NAMES))


def _posterior_fields(post: dict | None, names) -> dict:
    """An estimate's ``mean``, ``sd``, ``median``, ``hdi`` (of ``names``) and ``hdi_prob`` from a
    result's ``posterior`` block (empty without one)."""
    post = post or {}
    return {"mean": _values(post.get("mean"), names), "sd": _values(post.get("sd"), names),
            "median": _values(post.get("median"), names), "hdi": _pairs(post.get("hdi"), names),
            "hdi_prob": (post.get("hdi") or {}).get("prob")}


def result_data(scene, model, setup, map_est, draws, diag, *, hdi_prob: float, provenance: dict,
                seconds: float, notes=(), keep_draws: int = RESULT_DRAWS) -> dict:
    """The file's content (``creference-result/2``) of an estimate: the MAP, the posterior's
    summary of every draw and ``keep_draws`` of them, the diagnostics, the warnings (``warnings``:
    the scene's, the set-up's, ``notes`` and the MAP's checks) and ``provenance``."""
    from .scene import scene_fingerprint

    warnings = list(scene.warnings) + list(setup.notes) + list(notes)
    cf = model.camera_free
    camera = {"map": _named(CAMERA_NAMES, map_est.camera), "free": [n for n, f in zip(CAMERA_NAMES, cf) if f],
              "setup": setup.to_dict()}
    if setup.horizon_estimate is not None:
        camera["setup"]["horizon_estimate"] = setup.horizon_estimate.to_dict()
    objs_map = object_report(map_est.camera, map_est.objects)
    post_obj = kept = None
    if draws is not None:
        cams = draws.cameras.reshape(-1, 5)
        objs = draws.objects.reshape(-1, model.n_objects, 7).copy()
        yaw0 = map_est.objects[:, O_YAW]
        objs[..., O_YAW] = yaw0 + (objs[..., O_YAW] - yaw0 + np.pi) % (2 * np.pi) - np.pi
        table = object_report(cams, objs)  # (N, m, 9)
        if keep_draws > 0:
            hands = getattr(draws, "handedness", None)
            kept = _keep_draws(cams, objs, keep_draws, draws.cameras.shape[0], draws.log_prob,
                               None if hands is None else hands.reshape(-1, model.n_objects))
        post_obj = [_summary(table[:, i], hdi_prob) for i in range(model.n_objects)]
        camera["posterior"] = camera_posterior(cams, hdi_prob, cf)
        if not diag.converged:
            warnings += [f"posterior not converged: {w}" for w in diag.warnings]
    if scene.ground_truth:
        camera["evaluation"] = _camera_evaluation(scene.ground_truth, camera.get("posterior"))
    warnings += map_checks(scene, model, setup, map_est)
    objects = []
    for i, (t, o) in enumerate(zip(scene.targets, model.objects)):
        entry = {"id": t.id, "class": t.cls, "handedness": int(map_est.handedness[i]),
                 "size": "known" if o.sizes is not None else "class prior",
                 "n_annotations": len(o.annotations),
                 "map": {n: _r(v) for n, v in zip(OBJECT_REPORT, objs_map[i])}}
        if "object_sigma" in model.capabilities:
            entry["sigma_px"] = _r(model.sigma[i], 3)
        if post_obj is not None:
            entry["posterior"] = _posterior_block(OBJECT_REPORT, post_obj[i], hdi_prob)
        if t.ground_truth is not None and "location_m" in t.ground_truth:
            entry["evaluation"] = _evaluate(t.ground_truth, objs_map[i], None if post_obj is None else post_obj[i])
        objects.append(entry)
    data = {"format": RESULT_FORMAT, "scene": scene.source.name if scene.source else None,
            "scene_format": scene.format, "scene_id": {"sha256": scene_fingerprint(scene)},
            "image_size": [scene.image_width, scene.image_height], "model": model.name,
            "preset": provenance.get("preset", "default"), "hdi_prob": hdi_prob,
            "camera": camera, "objects": objects, "references": _references(model),
            "map_info": {k: _r(v, 4) if isinstance(v, float) else v for k, v in map_est.info.items()},
            "diagnostics": None if diag is None else diag.to_dict(),
            "pilot_camera": None if model.pilot is None else [float(v) for v in model.pilot],
            "provenance": provenance, "seconds": round(seconds, 3), "warnings": warnings}
    if kept is not None:
        data["draws"] = kept
    return data


def _references(model) -> dict:
    """What the references contributed: how many entered the likelihood (and which were left out,
    why) for the metrology model; for the paper model, each object's pairs used and skipped."""
    if "reference_bounds" in model.capabilities:
        return {"used_as": "pairwise bounds",
                "objects": [{"pairs_used": r.pairs_used, "pairs_skipped": r.pairs_skipped,
                             "skipped_reasons": r.skipped_reasons} for r in model.reference_reports]}
    likelihood = "reference_likelihood" in model.capabilities
    status = model.reference_status if likelihood else {}
    out = {"used_as": "likelihood", "n_references": len(status),
           "in_likelihood": sum(v == "used" for v in status.values())}
    left = {str(k): v for k, v in status.items() if v != "used"}
    if left:
        out["left_out"] = left
    if likelihood and model.n_stated_ranges:
        out["read_with_confidence_map"] = model.n_stated_ranges
    return out


def map_checks(scene, model, setup, map_est) -> list[str]:
    """Warnings about the MAP: a box that misses its annotations, targets whose sets of dimension
    lines are identical (a noise-free simulated scene: a posterior too narrow to sample), and a
    focal length that the annotations and an informative prior disagree on (a cropped photo?)."""
    out, identical = [], []
    uv, _ = model.project(map_est.camera[None], map_est.objects[None])
    for i, t in enumerate(scene.targets):
        med = np.median(t.corners, axis=0)
        err = float(np.sqrt(np.mean(np.sum((uv[0, i] - med) ** 2, axis=-1))))
        c = t.corners
        spread = np.sqrt(np.sum((c - c.mean(axis=0)) ** 2) / (8 * (len(c) - 1))) if len(c) > 1 else 5.0
        if len(c) > 1 and spread < MIN_TARGET_SIGMA_PX:
            identical.append(t.id)
        spread = max(np.sqrt(2.0) * spread, REPROJECTION_MIN_SPREAD_PX)
        if not np.isfinite(err) or err > REPROJECTION_WARN_FACTOR * spread:
            out.append(f"target {t.id!r}: the MAP's box misses its annotations: its corners are {err:.1f} px (RMS) "
                       f"from the annotations' median, over {REPROJECTION_WARN_FACTOR:g} times their own spread "
                       f"({spread:.1f} px); check the dimension lines and the target's size")
    if identical:
        say = ", ".join(map(repr, identical[:5])) + (f" and {len(identical) - 5} more" if len(identical) > 5 else "")
        out.append(f"target{'s' if len(identical) > 1 else ''} {say}: the sets of dimension lines agree to "
                   f"within {MIN_TARGET_SIGMA_PX:g} px (a noise-free simulated scene?), so the corner scale is at "
                   "that floor and a posterior so narrow may not converge; real annotations scatter by pixels")
    prior = setup.terms.focal
    if prior is not None and prior.source != "default" and model.camera_free[C_FOCAL]:
        lo, hi = prior.interval(0.99)
        mu = float(map_est.camera[C_FOCAL])
        if not lo <= mu <= hi:
            out.append(f"the annotations disagree with the {prior.source} focal length prior: MAP {mu:.0f} px, "
                       f"prior median {prior.median_px:.0f} px (99 % interval {lo:.0f}–{hi:.0f}); was the image "
                       "cropped or resized?")
    return out


def _evaluate(truth: dict, map_row: np.ndarray, post: dict | None) -> dict:
    """Errors against a target's ground truth: Eq. 3 for the MAP and the posterior mean, and
    whether each true value lies in its HDI."""
    loc = np.asarray(truth["location_m"], float)
    out = {"location_pct_error": _r(100 * np.linalg.norm(map_row[:3] - loc) / np.linalg.norm(loc), 4)}
    if post is not None:
        out["posterior_location_pct_error"] = _r(100 * np.linalg.norm(post["mean"][:3] - loc) / np.linalg.norm(loc), 4)
        d = float(np.hypot(loc[0], loc[2]))
        values = {"x": loc[0], "y": loc[1], "z": loc[2], "distance_m": d}
        if truth.get("yaw_rad") is not None:
            values["yaw"] = truth["yaw_rad"]
        inside = {}
        for k, v in values.items():
            a, b = post["hdi"][OBJECT_REPORT.index(k)]
            if k == "yaw":  # circular: some turn of the true yaw inside
                v = a + (v - a) % (2 * np.pi)
            inside[k] = bool(a <= v <= b)
        out["distance_in_hdi"] = inside["distance_m"]
        out["in_hdi"] = inside
    return out


def _camera_evaluation(truth: dict, post: dict | None) -> dict:
    """Whether the camera's true focal length, pitch, roll and height lie in their HDIs."""
    keys = {"focal_length_px": "focal_length_px", "pitch_rad": "pitch", "roll_rad": "roll", "camera_height_m": "height_m"}
    out = {"truth": {v: truth[k] for k, v in keys.items() if truth.get(k) is not None}}
    if post is not None:
        hdi_ = post["hdi"]
        out["in_hdi"] = {k: bool(None not in hdi_[k] and hdi_[k][0] <= v <= hdi_[k][1])
                         for k, v in out["truth"].items() if k in hdi_}
    return out


def read_result(path: str | Path) -> dict:
    """A result file's content as a dict (either format; check with :data:`RESULT_FORMATS`);
    ``ValueError`` naming the file when it is not one. :func:`creference_bayes.load_result` reads
    it as a :class:`~creference_bayes.pipeline.Result`."""
    from .validation import SceneError, read_json

    try:
        data = read_json(path)
    except SceneError as exc:
        raise ValueError(f"{path}: not a result file ({exc.problem})") from None
    if not isinstance(data, dict) or data.get("format") not in RESULT_FORMATS:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ValueError(f"{path}: format: expected one of {list(RESULT_FORMATS)}, got {got!r}")
    if data["format"] == RESULT_FORMAT:
        why = result_problem(data)
        if why:
            raise ValueError(f"{path}: {why}: not a result as this package writes it (edited by hand?)")
    return data


def _numbers(block, names, where: str) -> str | None:
    """What is wrong with ``block`` as an object of finite numbers under ``names``, or None."""
    if not isinstance(block, dict):
        return f"{where}: expected an object, got {_short(block)}"
    for k in names:
        v = block.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            return f"{where}.{k}: expected a finite number, got {_short(v)}"
    return None


def _posterior_problem(post, where: str) -> str | None:
    """What is wrong with a posterior block (None, or an object whose ``sd`` is an object)."""
    if post is not None and not (isinstance(post, dict) and isinstance(post.get("sd", {}), dict)):
        return f"{where}: expected an object with an object sd, got {_short(post)}"
    return None


def result_problem(d: dict) -> str | None:
    """What in a ``creference-result/2`` dict is not as the package writes it, where the commands
    that read results (``plot``, ``advise``, ``labels``, a batch's rig) index into it: the camera's
    and every object's MAP (finite numbers), which camera parameters were free, the objects' ids,
    the posterior's standard deviations and the kept draws (:func:`stored_draws`); None when all is
    well."""
    camera, objects = d.get("camera"), d.get("objects")
    for key in ("scene_id", "draws", "diagnostics"):
        if d.get(key) is not None and not isinstance(d[key], dict):
            return f"{key}: expected an object, got {_short(d[key])}"
    if not isinstance(camera, dict):
        return f"camera: expected an object, got {_short(camera)}"
    why = _numbers(camera.get("map"), CAMERA_NAMES, "camera.map")
    if why:
        return why
    why = _posterior_problem(camera.get("posterior"), "camera.posterior")
    if why:
        return why
    free = camera.get("free", [])
    if not (isinstance(free, list) and all(isinstance(k, str) and k in CAMERA_NAMES for k in free)):
        return f"camera.free: expected a list of some of {list(CAMERA_NAMES)}, got {_short(free)}"
    if not isinstance(objects, list) or not objects:
        return f"objects: expected a list of objects, got {_short(objects)}"
    for i, o in enumerate(objects):
        if not isinstance(o, dict) or not isinstance(o.get("id"), str):
            return f"objects[{i}]: expected an object with an id, got {_short(o)}"
        why = _numbers(o.get("map"), OBJECT_NAMES, f"objects[{i}].map") or \
            _posterior_problem(o.get("posterior"), f"objects[{i}].posterior")
        if why:
            return why
    prov = d.get("provenance")
    if prov is not None:
        if not isinstance(prov, dict):
            return f"provenance: expected an object, got {_short(prov)}"
        for key, kind in (("options", dict), ("classes", dict), ("confidence_map", dict), ("ground", dict),
                          ("bounds", dict), ("orientation", str), ("focal_prior", (str, dict)),
                          ("model", str), ("preset", str), ("location_prior", str)):
            if prov.get(key) is not None and not isinstance(prov[key], kind):
                return f"provenance.{key}: got {_short(prov[key])}"
    try:
        stored_draws(d)
    except ValueError as exc:
        return str(exc)
    return None


def result_from_v1(d: dict, scene) -> dict:
    """A ``creference-result/1`` dict (one target, as written before) in this format, given its
    scene: the MAP, the posterior summary, the kept draws and the provenance that
    :func:`~creference_bayes.pipeline.rebuild_model` needs."""
    t = scene.targets[0]
    size = t.dimensions
    m = d["map"]
    pitch, roll = m.get("pitch"), m.get("roll")
    if (pitch is None or roll is None) and scene.horizon is not None:  # older files: from the horizon
        from ..core.geometry import horizon_line, pitch_roll_from_horizon

        pitch, roll = (float(v) for v in pitch_roll_from_horizon(horizon_line(scene.horizon), m["focal_length_px"],
                                                                 scene.principal_point))
    pitch, roll = pitch or 0.0, roll or 0.0
    camera = {"map": {"focal_length_px": m["focal_length_px"], "pitch": pitch, "roll": roll, "height_m": m["y"],
                      "ref_scale": 0.5}, "free": [], "setup": (d.get("extra") or {}).get("camera") or {}}
    hand = d.get("handedness", (d.get("posterior") or {}).get("handedness", 1))
    obj = {"id": t.id, "class": t.cls, "handedness": int(hand),
           "size": "known", "n_annotations": len(t.dimension_lines),
           "map": {"x": m["x"], "y": m["y"], "z": m["z"], "yaw": m["yaw"], "length_m": size[0], "width_m": size[1],
                   "height_m": size[2], "ground_m": 0.0, "distance_m": float(np.hypot(m["x"], m["z"]))}}
    out = {"format": RESULT_FORMAT, "scene": d.get("scene"), "scene_format": "creference-scene/1",
           "scene_id": d.get("scene_id") or {}, "image_size": [scene.image_width, scene.image_height],
           "model": d.get("model"), "preset": d.get("preset"), "camera": camera, "objects": [obj],
           "warnings": list(d.get("warnings", [])), "pilot_camera": None,
           "provenance": {"model": d.get("model"), "preset": d.get("preset"), "options": {},
                          "orientation": "auto", "focal_prior": "auto", "use_references": True,
                          "temperature": float((d.get("posterior") or {}).get("temperature", 1.0)),
                          "location_prior": "log-depth" if d.get("preset") == "default" else "flat"},
           "converted_from": "creference-result/1"}
    post = d.get("posterior")
    if post:
        prob = post["hdi"]["prob"]
        out["hdi_prob"] = prob
        stats = ("mean", "median", "sd", "hdi")
        names = ("x", "y", "z", "yaw", "distance_m")
        obj["posterior"] = {k: {n: post[k].get(n) for n in names} for k in stats}
        cam_names = {"focal_length_px": "focal_length_px", "pitch": "pitch", "roll": "roll", "y": "height_m"}
        camera["posterior"] = {k: {v: post[k][n] for n, v in cam_names.items() if n in post[k]}
                               for k in stats}
        obj["posterior"]["hdi"]["prob"] = camera["posterior"]["hdi"]["prob"] = prob
        camera["free"] = [v for n, v in cam_names.items() if n in post["sd"] and (post["sd"][n] or 0) > 0]
        draws = post.get("draws")
        if draws and "x" in draws:
            n = len(draws["x"])
            col = lambda k, default: draws.get(k, [default] * n)
            out["draws"] = {"n": n, "of": n,
                            "camera": {"focal_length_px": col("focal_length_px", m["focal_length_px"]),
                                       "pitch": col("pitch", pitch), "roll": col("roll", roll), "height_m": draws["y"],
                                       "ref_scale": 0.5},
                            "objects": [{"x": draws["x"], "z": draws["z"], "yaw": draws["yaw"], "length_m": size[0],
                                         "width_m": size[1], "height_m": size[2], "ground_m": 0.0}]}
    if d.get("evaluation"):
        obj["evaluation"] = dict(d["evaluation"])
    diag = d.get("diagnostics")
    if isinstance(diag, dict):
        out["diagnostics"] = {"sampler": "emcee", "n_chains": diag.get("n_ensembles"), "warmup": diag.get("warmup_steps"),
                              "iterations": diag.get("n_steps"), "thin": diag.get("thin"),
                              "ess_bulk": diag.get("ess_bulk"), "r_hat": diag.get("r_hat"),
                              "converged": diag.get("converged"), "warnings": list(diag.get("warnings") or [])}
    if isinstance(d.get("batch"), dict):
        out["batch"] = dict(d["batch"])
    return out


def batch_fields(result: dict, result_path: str | Path) -> dict:
    """The ``batch`` block of a result from ``creference batch`` (``{}`` when it has none), its
    ``key``, ``scene_copy`` and ``source`` checked: text, a ``scene_copy`` inside the batch folder
    (relative, no ``..``) and a ``key`` of no more folders than the result file lies below
    (``results/KEY.json`` in the batch folder); else ``ValueError`` naming the file and the field."""
    batch = result.get("batch")
    if batch is None:
        return {}
    if not isinstance(batch, dict):
        raise ValueError(f"{result_path}: batch: expected an object, got {type(batch).__name__}")
    for name in ("key", "scene_copy", "source"):
        value = batch.get(name)
        if value is not None and (not isinstance(value, str) or not value or "\0" in value):
            raise ValueError(f"{result_path}: batch.{name}: expected a file name, got {_short(value)}")
    copy = batch.get("scene_copy")
    if copy is not None and (Path(copy).is_absolute() or ".." in Path(copy).parts):
        raise ValueError(f"{result_path}: batch.scene_copy: {_short(copy)} is outside the batch folder; refused")
    key = batch.get("key")
    if key is not None:
        parts = Path(key).parts
        if Path(key).is_absolute() or ".." in parts or len(parts) >= len(Path(result_path).absolute().parents):
            raise ValueError(f"{result_path}: batch.key: {_short(key)} is not where the result lies "
                             "(expected the file's path below the batch folder's results/)")
    return batch


def scene_candidates(result: dict, result_path: str | Path) -> list[Path]:
    """Where the scene of a result (either format) may be, in the order to look: the batch
    folder's copy when the result came from ``creference batch`` (``batch.scene_copy``), the path
    ``creference estimate --out`` recorded (``scene_path``, relative to the result's folder), then
    the file the result names (``scene``) beside the result, in the current folder and among the
    package's shipped scenes. The result file itself is never a candidate (a batch result is
    named like its scene), nor is a path twice."""
    from importlib import resources

    result_path = Path(result_path)
    out = []
    batch = batch_fields(result, result_path)
    if batch.get("scene_copy") and batch.get("key"):
        up = len(Path(batch["key"]).parts)  # results/KEY.json: the batch folder is that many folders up
        parents = result_path.parents if up < len(result_path.parents) else result_path.absolute().parents
        out.append(parents[up] / batch["scene_copy"])
    recorded = result.get("scene_path")
    if isinstance(recorded, str) and recorded:
        out.append(result_path.parent / recorded)
    name = result.get("scene")
    if isinstance(name, str) and name:
        out += [result_path.parent / name, Path.cwd() / name,
                Path(str(resources.files("creference_bayes") / "data" / name))]
    seen = {result_path.resolve()}
    unique = []
    for p in out:
        if p.resolve() not in seen:
            seen.add(p.resolve())
            unique.append(p)
    return unique


def scene_path_from(result_path: str | Path, scene_path: str | Path) -> str:
    """The scene file's path as a result written to ``result_path`` records it (``scene_path``):
    relative to the result's folder, with forward slashes (absolute when there is no relative
    path, as between two drives)."""
    import os

    scene_path = Path(scene_path).resolve()
    try:
        return Path(os.path.relpath(scene_path, Path(result_path).resolve().parent)).as_posix()
    except ValueError:
        return scene_path.as_posix()


def canonical_sha256(data) -> str:
    """SHA-256 (hex) of decoded JSON in its canonical form (sorted keys, no spaces): a batch
    folder's scene copy is written so, and its result records this, whichever version wrote them."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def scene_mismatch(result: dict, scene, file_sha256: str | None = None) -> str | None:
    """What differs between the scene a result (either format) records and ``scene``, or None: the
    target ids, the image size, and the content's hash (``scene_id.sha256``: the scene's
    fingerprint, or ``file_sha256``, the canonical hash of the scene file as read, which a batch
    copy of either version matches). A ``creference-result/1`` not from a batch hashed its scene
    another way: its hash is not compared."""
    from .scene import scene_fingerprint

    v1 = result.get("format") == "creference-result/1"
    recorded = result.get("scene_id") if isinstance(result.get("scene_id"), dict) else {}
    objects = result.get("objects") if isinstance(result.get("objects"), list) else []
    ids = [result.get("target")] if v1 else [o.get("id") if isinstance(o, dict) else None for o in objects]
    mine = [t.id for t in scene.targets]
    size = result.get("image_size") or recorded.get("image_size")
    if size is not None and not (isinstance(size, list) and len(size) == 2):  # a result edited by hand
        size = [size, "?"]
    diffs = []
    if ids != mine:
        say = lambda v: (repr(v[0]) if len(v) == 1 else f"{v[:5]}{'…' if len(v) > 5 else ''}")
        diffs.append(f"target{'s' if len(mine) > 1 else ''} {say(mine)}, the result's "
                     f"{'are' if len(ids) > 1 else 'is'} {say(ids)}")
    if size is not None and list(size) != [scene.image_width, scene.image_height]:
        diffs.append(f"image {scene.image_width}x{scene.image_height} px, the result's is {size[0]}x{size[1]}")
    want = recorded.get("sha256")
    if not diffs and want is not None and want not in (scene_fingerprint(scene), file_sha256) \
            and not (v1 and "batch" not in result):
        diffs.append(f"same targets and image size but different content (its fingerprint differs): sha256 {scene_fingerprint(scene)[:12]}…, "
                     f"the result's is {str(want)[:12]}…; edited since the estimate?")
    return "; ".join(diffs) or None


def find_scene(result: dict, result_path: str | Path, explicit: str | Path | None = None,
               notes: list | None = None):
    """The scene a result (either format) was estimated from: ``explicit``, else the first of
    :func:`scene_candidates` that exists and is the result's (:func:`scene_mismatch`: another
    scene of the same name beside the result does not hide the right one in the current folder).
    Each candidate passed over because it is not the result's is said in ``notes`` (a list to
    append to). Raises ``FileNotFoundError`` when no candidate exists (the message says where it
    looked) and ``ValueError`` when none of those found is the result's (the message says what
    differs in the first)."""
    import warnings

    from ..models.size_priors import size_priors_from_dict
    from .scene import SceneWarning, parse_scene, read_scene_json

    result_path = Path(result_path)
    recorded = (result.get("provenance") or {}).get("classes")  # a classes file's priors it was made with
    classes = size_priors_from_dict(recorded, "provenance.classes", "file") if recorded else None
    if explicit is not None:
        paths, how = [Path(explicit)], f"--scene {explicit}"
        if not paths[0].is_file():
            raise FileNotFoundError(2, "no such file", str(explicit))
    else:
        paths, how = scene_candidates(result, result_path), None
    passed = []  # (path, why) of the candidates that are not the result's scene
    for path in paths:
        if path.is_file():
            data = read_scene_json(path)  # read once: the scene and the file's fingerprint
            file_sha = canonical_sha256(data)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = parse_scene(data, source=path, classes=classes)
            why = scene_mismatch(result, scene, file_sha)
            if not why:
                if notes is not None:
                    notes += [f"{other}: not the scene this result was estimated from ({reason}); used {path}"
                              for other, reason in passed]
                return scene
            passed.append((path, why))
    if passed:
        path, why = passed[0]
        where = how or f"scene {str(path)!r} (found by the result's scene name; pass --scene)"
        raise ValueError(f"{where}: not the scene this result was estimated from ({why})")
    if not result.get("scene") and not result.get("batch"):
        raise FileNotFoundError(2, "the result names no scene: give it with --scene", str(result_path))
    raise FileNotFoundError(2, f"the result's scene {result.get('scene')!r} is not beside it, in the current folder or among "
                               "the shipped scenes: give it with --scene", str(result_path))
