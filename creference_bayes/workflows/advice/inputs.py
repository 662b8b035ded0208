"""Where the advice's posterior comes from (a scene estimated now, or a result file with its
scene), and the advice as a table for the terminal."""

from __future__ import annotations

from ...io.files import read_text
import json
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from ...io.result import RESULT_FORMAT
from ...io.result import scene_candidates
from ...io.scene import SceneWarning, load_scene, scene_fingerprint
from ...models.params import PARAM_NAMES
from . import Advice, AdviceSettings, advise_posterior

__all__ = ["ADVICE_MODEL", "advise_scene", "advise_result", "draws_from_result", "scene_for_result",
           "advice_table"]

#: The advice simulates annotations under this model's noise model.
ADVICE_MODEL = "metrology"


def advise_scene(scene, *, seed=None, settings: AdviceSettings | None = None, progress: bool = False,
                 **estimate_options):
    """Estimate ``scene`` (the default metrology model, its posterior) and advise on it.

    Returns
    -------
    (Advice, Result)
    """
    from ...pipeline import estimate

    if estimate_options.get("model", ADVICE_MODEL) != ADVICE_MODEL:
        raise ValueError(f"model: the advice needs the {ADVICE_MODEL} model, got {estimate_options['model']!r}")
    rng = np.random.default_rng(seed)
    result = estimate(scene, seed=rng, posterior=True, progress=progress, **estimate_options)
    if result.inference_data is None:
        raise ValueError("the posterior could not be sampled: " + "; ".join(result.warnings))
    from ...inference.summary import draws_from_inference_data

    post = draws_from_inference_data(result.inference_data)
    draws = np.column_stack([np.asarray(post[k], float).ravel() for k in PARAM_NAMES])
    advice = advise_posterior(scene, draws, handedness=result.map.handedness, map_params=result.map.params,
                              seed=rng, settings=settings, progress=progress)
    return _with_seed(advice, seed), result


def _with_seed(advice: Advice, seed) -> Advice:
    import dataclasses

    if isinstance(seed, (list, tuple)) and all(isinstance(v, int) for v in seed):
        seed = list(seed)
    elif not isinstance(seed, (int, type(None))):
        seed = None  # a Generator: not recordable
    return dataclasses.replace(advice, seed=seed)


def _vector(values: dict, what: str, required) -> np.ndarray:
    """(…, 7) from named values; the names in ``required`` must be there (others may be filled in
    by the model's ``expand``)."""
    missing = [k for k in required if k not in values]
    if missing:
        raise ValueError(f"{what}: no values of {missing} (was the result made by an older version? "
                         "estimate the scene again)")
    n = len(np.atleast_1d(values[required[0]])) if required else 1
    return np.column_stack([np.asarray(values.get(k, np.zeros(n)), float).reshape(-1) for k in PARAM_NAMES])


def draws_from_result(result: dict, model) -> np.ndarray:
    """(n, 7) posterior draws kept in a ``creference-result/1`` document (``posterior.draws``)."""
    post = result.get("posterior") or {}
    draws = post.get("draws") or {}
    free = [k for k, f in zip(PARAM_NAMES, model.free) if f]
    full = _vector(draws, "posterior.draws", free)
    return model.expand(full[:, model.free])


def scene_for_result(result_path: str | Path, result: dict, scene_path: str | Path | None = None):
    """The scene a result was made from: ``scene_path``, else the batch folder's copy
    (``batch.scene_copy``), else the file named by ``scene`` next to the result, in the current
    folder or among the package's shipped scenes; its
    fingerprint must be the one the result records."""
    result_path = Path(result_path)
    tried = [Path(scene_path)] if scene_path is not None else scene_candidates(result, result_path)
    for path in tried:
        if path.is_file():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = load_scene(path)
            want = (result.get("scene_id") or {}).get("sha256")
            if want is not None and scene_fingerprint(scene) != want:
                raise ValueError(f"{path}: not the scene of the result (its fingerprint differs: the "
                                 "scene changed since the estimate; estimate it again)")
            return _with_batch_image(scene, result)
    if scene_path is not None:
        raise FileNotFoundError(2, "no such file", str(scene_path))
    where = (f"the result's scene {result['scene']!r} is not beside it, in the current folder or "
             "among the shipped scenes" if result.get("scene") else "the result names no scene")
    raise FileNotFoundError(2, f"{where}: give it with --scene", str(result_path))


def _with_batch_image(scene, result: dict):
    """A batch copy keeps ``image.path`` as the original gave it: resolve it against the original."""
    import dataclasses

    source = (result.get("batch") or {}).get("source")
    if scene.image_path is None or scene.image_path.is_file() or not source:
        return scene
    rel = scene.image_path.relative_to(scene.source.parent) if scene.source else scene.image_path
    candidate = Path(source).parent / rel
    return dataclasses.replace(scene, image_path=candidate) if candidate.is_file() else scene


def _camera_setup(result: dict, scene):
    """The camera set-up the result's estimate used: its batch settings' ``orientation`` and
    ``focal_prior`` when it has them, else read back from its ``camera`` block; checked against
    that block (a posterior of another set-up would be reweighted with the wrong model)."""
    from ...camera_setup import setup_camera

    cam = result.get("camera") or {}
    batch = (result.get("batch") or {}).get("settings") or {}
    mode = cam.get("orientation")
    orientation = batch.get("orientation") or ("level" if mode == "level" else "free" if mode == "free" else "auto")
    prior = cam.get("focal_prior") or {}
    focal_prior = batch.get("focal_prior") or (
        "none" if "focal_prior" in cam and cam["focal_prior"] is None and scene.focal_length_px is None
        else "default" if prior.get("source") == "default" else "auto")
    setup = setup_camera(scene, orientation=orientation, focal_prior=focal_prior)
    if cam:
        mine = setup.to_dict()
        theirs_fp, mine_fp = cam.get("focal_prior"), mine.get("focal_prior")
        same_fp = (theirs_fp is None) == (mine_fp is None) and (
            theirs_fp is None or np.isclose(theirs_fp["median_px"], mine_fp["median_px"], rtol=1e-6))
        if mine["orientation"] != mode or not same_fp:
            raise ValueError("the camera set-up cannot be rebuilt as the estimate had it (orientation "
                             f"{mode!r}, focal prior {theirs_fp!r}); estimate the scene again with "
                             "creference advise SCENE")
    return setup


def advise_result(result: dict, scene, *, seed=None, settings: AdviceSettings | None = None,
                  progress: bool = False) -> Advice:
    """Advise on a stored result (its ``posterior.draws``) of ``scene``."""
    from ...pipeline import build_models

    if result.get("format") != RESULT_FORMAT:
        raise ValueError(f"format: expected {RESULT_FORMAT!r}, got {result.get('format')!r}")
    if result.get("model") != ADVICE_MODEL:
        raise ValueError(f"model: the advice needs a result of the {ADVICE_MODEL} model, got "
                         f"{result.get('model')!r} (estimate with --model {ADVICE_MODEL})")
    handedness = int(result.get("handedness") or (result.get("posterior") or {}).get("handedness") or 0)
    if handedness not in (1, -1):
        raise ValueError(f"handedness: expected 1 or -1, got {result.get('handedness')!r}")
    setup = _camera_setup(result, scene)
    model = next(m for m in build_models(scene, setup) if m.handedness == handedness)
    free = [k for k, f in zip(PARAM_NAMES, model.free) if f]
    pilot = model.expand(_vector(result.get("map") or {}, "map", free)[:, model.free])[0]
    draws = draws_from_result(result, model)
    advice = advise_posterior(scene, draws, handedness=handedness, map_params=pilot, setup=setup,
                              seed=seed, settings=settings, progress=progress)
    return _with_seed(advice, seed)


def load_result(path: str | Path) -> dict:
    """A result file's document (JSON object with the result format), or None if it is not one."""
    try:
        d = json.loads(read_text(path))
    except (ValueError, UnicodeDecodeError):
        return None
    return d if isinstance(d, dict) and d.get("format") == RESULT_FORMAT else None


def recommendation_line(action: str, reason: str) -> str:
    """``recommendation: …`` with the action said once (a reason may begin with it)."""
    return f"recommendation: {reason if reason.startswith(action) else f'{action}: {reason}'}"


def advice_table(advice: Advice, estimate_hdi: tuple[float, float] | None = None) -> str:
    """The advice as text: the present, one row per annotation (best first), the recommendation.

    ``estimate_hdi``: the estimate's own HDI of the distance (metres, on all its draws), shown
    beside the advice's, which is computed on the ``settings.n_draws`` draws it weighs (so the
    two differ by the sampling error of the thinned draws).
    """
    now, s = advice.now, advice.settings
    full = ""
    if estimate_hdi is not None:
        full = (f" (on the {s.n_draws} draws the advice weighs; the estimate's, on all its draws: "
                f"{estimate_hdi[1] - estimate_hdi[0]:.3g} m)")
    lines = [f"advice for target {advice.target!r}",
             f"now: {s.hdi_prob:.0%} HDI of the distance {now.hdi_width_m:.3g} m = "
             f"{100 * now.hdi_share:.1f} % of {now.distance_m:.3g} m{full}; location sd "
             f"{now.location_sd_m:.3g} m; P(IoU >= {s.iou_threshold:g}) {now.p_iou:.2f}", ""]
    head = ("rank", "annotation", "cost s", "HDI after", "gain pts", "pts/min", "loc sd m",
            f"P(IoU>={s.iou_threshold:g})", "ESS", "fallbacks")
    rows = []
    for k, p in enumerate(advice.predictions, start=1):
        e = p.expected
        rows.append((str(k), p.candidate.description, f"{p.candidate.seconds:.0f}",
                     f"{e.hdi_width_m:.3g} m {100 * e.hdi_share:.1f} %",
                     f"{p.gain_pct:+.2f} ±{p.gain_se_pct:.2f}",
                     f"{p.gain_per_minute:+.3f}", f"{e.location_sd_m:.3g}", f"{e.p_iou:.2f}",
                     f"{100 * p.ess_median:.0f} %", str(p.fallbacks)))
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(len(head))]
    for r in [head] + rows:
        lines.append("  ".join(c.ljust(w) if i == 1 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    lines += ["", recommendation_line(advice.action, advice.reason)]
    lines += [f"note: {n}" for n in advice.notes]
    lines.append(f"({len(advice.predictions)} annotations weighed with {s.n_futures} simulated outcomes "
                 f"each on {s.n_draws} posterior draws at most; {advice.seconds:.1f} s)")
    return "\n".join(lines)
