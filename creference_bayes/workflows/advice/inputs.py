"""Where the advice's posterior comes from (a scene estimated now, or a result file with its
scene: its kept draws, else the Laplace approximation at its MAP), and the advice as a table."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ...io.result import RESULT_DRAWS, RESULT_FORMAT, find_scene, result_from_v1
from . import Advice, AdviceSettings, advise

__all__ = ["ADVICE_MODEL", "advise_scene", "advise_result", "scene_for_result", "advice_table"]

#: The advice simulates observations under this model's noise model.
ADVICE_MODEL = "metrology"


def _recordable(seed):
    """The seed as the advice records it (None for a Generator)."""
    if isinstance(seed, (list, tuple)) and all(isinstance(v, int) for v in seed):
        return list(seed)
    return seed if isinstance(seed, (int, type(None))) else None


def advise_result(result, scene, *, seed=None, settings: AdviceSettings | None = None,
                  progress: bool = False, workers: int = 1) -> Advice:
    """Advise on an estimate of ``scene``: a :class:`~creference_bayes.io.result.Result` or a result
    file's dict (either format). Its kept posterior draws are weighed, else draws of the Laplace
    approximation at its MAP (:func:`~creference_bayes.pipeline.result_draws`); ``workers``
    processes weigh the requests at once (:func:`~creference_bayes.workflows.advice.advise`)."""
    from ...io.result import stored_draws
    from ...pipeline import map_state, rebuild_model, result_draws

    d = result if isinstance(result, dict) else result.to_dict()
    if d.get("format") == "creference-result/1":
        d = result_from_v1(d, scene)
    if d.get("format") != RESULT_FORMAT:
        raise ValueError(f"format: expected {RESULT_FORMAT!r}, got {d.get('format')!r}")
    if d.get("model") != ADVICE_MODEL:
        raise ValueError(f"model: the advice needs a result of the {ADVICE_MODEL} model, got {d.get('model')!r} "
                         f"(estimate with --model {ADVICE_MODEL})")
    settings = settings or AdviceSettings()
    model = getattr(result, "model", None) or rebuild_model(d, scene)
    rng = np.random.default_rng(seed)
    cams, objs, source = result_draws(d, model, n=settings.n_draws, seed=rng)
    kept = stored_draws(d) if source == "posterior" else None  # each kept draw's handedness, where it varies
    hands = None if kept is None or kept.handedness is None else kept.handedness.reshape(len(cams), -1)
    camera, objects = map_state(d)
    prov = d.get("provenance") or {}
    weighed, notes = _given_held_focal(model, cams, objs)
    advice = advise(model, scene, *weighed, camera_map=camera, objects_map=objects, options=prov.get("options"),
                    temperature=float(prov.get("temperature", 1.0)), seed=rng, settings=settings, source=source,
                    progress=progress, label_draws=(cams, objs), hands=hands, workers=workers)
    if notes:
        advice = dataclasses.replace(advice, notes=advice.notes + tuple(notes))
    return dataclasses.replace(advice, seed=_recordable(seed))


def _given_held_focal(model, cams: np.ndarray, objs: np.ndarray):
    """The draws the advice weighs, and a note. A frame whose camera's focal length a data set
    held (``creference batch``: one value for the camera's frames) keeps draws that carry the
    pool's uncertainty as one scale of focal length and depths the camera's frames share
    (:func:`~creference_bayes.workflows.batch.dataset.share_scale`). No annotation of this frame
    moves that scale, and the model holds the focal length fixed, so the futures are weighed on the
    draws given the held value (the scale divided out); the labels' quality now is stated from the
    draws as they are (:func:`~creference_bayes.workflows.advice.advise`'s ``label_draws``)."""
    from ...models.contract import C_FOCAL
    from ..batch.dataset import scale_draws

    held = model.focal_length_px
    if held is None or not len(cams):
        return (cams, objs), []
    with np.errstate(divide="ignore", invalid="ignore"):
        log_k = np.log(np.asarray(cams, float)[:, C_FOCAL] / float(held))
    if not np.all(np.isfinite(log_k)) or np.max(np.abs(log_k)) < 1e-9:
        return (cams, objs), []
    sd = 100.0 * float(np.std(log_k))
    return scale_draws(cams, objs, -log_k), [
        f"the focal length is held at {float(held):.1f} px (the data set's pool of this camera's frames); its "
        f"uncertainty (±{sd:.1f} %, shared by the camera's frames) is in the labels' quality now, and no request on "
        "this frame changes it"]


def advise_scene(scene, *, seed=None, settings: AdviceSettings | None = None, progress: bool = False,
                 workers: int = 1, **estimate_options):
    """Estimate ``scene`` (the metrology model, its posterior) and advise on it; returns
    (:class:`~creference_bayes.workflows.advice.Advice`, :class:`~creference_bayes.io.result.Result`)."""
    from ...pipeline import estimate

    if estimate_options.get("model", ADVICE_MODEL) != ADVICE_MODEL:
        raise ValueError(f"model: the advice needs the {ADVICE_MODEL} model, got {estimate_options['model']!r}")
    settings = settings or AdviceSettings()
    rng = np.random.default_rng(seed)
    result = estimate(scene, seed=rng, posterior=True, progress=progress,
                      keep_draws=max(settings.n_draws, RESULT_DRAWS), **estimate_options)
    advice = advise_result(result, scene, seed=rng, settings=settings, progress=progress, workers=workers)
    return dataclasses.replace(advice, seed=_recordable(seed)), result


def scene_for_result(result_path: str | Path, result: dict, scene_path: str | Path | None = None,
                     notes: list | None = None):
    """The scene a result was made from (:func:`~creference_bayes.io.result.find_scene`: ``scene_path``,
    else the batch folder's copy, else where ``estimate --out`` recorded it, else the file the result
    names; ``notes`` collects the candidates passed over), its image resolved for a batch copy."""
    return _with_batch_image(find_scene(result, result_path, scene_path, notes), result)


def _with_batch_image(scene, result: dict):
    """A batch copy keeps ``image.path`` as the original gave it: resolve it against the original."""
    source = (result.get("batch") or {}).get("source")
    if scene.image_path is None or scene.image_path.is_file() or not source:
        return scene
    rel = scene.image_path.relative_to(scene.source.parent) if scene.source else scene.image_path
    candidate = Path(source).parent / rel
    return dataclasses.replace(scene, image_path=candidate) if candidate.is_file() else scene


def advice_table(advice: Advice, estimate_hdi=None, rows: int = 20) -> str:
    """The advice as text: every target's present, the best ``rows`` observations (best first;
    ``good labels`` the expected labels lifted to the bar, ``falls`` the good ones expected to
    fall below it), the recommendation. ``estimate_hdi``: the estimate's own HDIs of the
    distances ((m, 2) metres, on all its draws), shown beside the advice's, which are computed on
    the draws it weighs (so the two differ by the sampling error of the thinned draws)."""
    now, s, ids = advice.now, advice.settings, advice.labels  # each target's class and id
    n = advice.n_weighed or s.n_draws  # the draws weighed (fewer than --draws when the result keeps fewer)
    lines = [f"advice for {', '.join(repr(t) for t in ids[:8])}{' …' if len(ids) > 8 else ''} "
             f"({'posterior draws' if advice.source == 'posterior' else 'draws of the Laplace approximation'})"]
    for i, tid in enumerate(ids):
        full = "" if estimate_hdi is None or estimate_hdi[i] is None else \
            (f" (on the {n} draws the advice weighs; the estimate's, on all its draws: "
             f"{estimate_hdi[i][1] - estimate_hdi[i][0]:.3g} m)")
        lines.append(f"now{'' if len(ids) == 1 else f' {tid}'}: {s.hdi_prob:.0%} HDI of the distance "
                     f"{now.hdi_width_m[i]:.3g} m = {100 * now.hdi_share[i]:.1f} % of {now.distance_m[i]:.3g} m{full}; "
                     f"location sd {now.location_sd_m[i]:.3g} m; P(IoU >= {s.iou_threshold:g}) {now.p_iou[i]:.2f}")
    head = ("rank", "annotation", "cost s", "good labels", "falls", "good/h", f"P(IoU>={s.iou_threshold:g})",
            "HDI after", "gain pts", "pts/min", "loc sd m", "ESS", "fallbacks", "outcomes")
    table = []
    for k, p in enumerate(advice.predictions[:rows], start=1):
        e, c = p.expected, p.candidate
        if c.target is not None:
            i = c.target
        elif s.objective == "labels" and len(p.p_good):
            i = int(np.argmax(np.where(advice.good, -np.inf, p.p_good)))
        elif s.objective == "location":
            i = int(np.argmax((now.location_sd_m - e.location_sd_m) / now.distance_m))
        else:
            i = int(np.argmax(now.hdi_share - e.hdi_share))
        on = "" if len(ids) == 1 else f"{ids[i]}: "
        table.append((str(k), c.description, f"{c.seconds:.0f}", f"{p.good_gain:+.2f} ±{p.good_gain_se:.2f}",
                      f"{p.good_loss:.2f}", f"{p.good_per_hour:+.2f}", f"{on}{now.p_iou[i]:.2f} → {e.p_iou[i]:.2f}",
                      f"{e.hdi_width_m[i]:.3g} m {100 * e.hdi_share[i]:.1f} %",
                      f"{p.gain_pct:+.2f} ±{p.gain_se_pct:.2f}", f"{p.gain_per_minute:+.3f}",
                      f"{e.location_sd_m[i]:.3g}", f"{100 * p.ess_median:.0f} %", str(p.fallbacks),
                      f"{p.futures}{' dropped' if p.dropped else ''}"))
    widths = [max(len(r[i]) for r in table + [head]) for i in range(len(head))]
    lines.append("")
    for r in [head] + table:
        lines.append("  ".join(c.ljust(w) if i == 1 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    if len(advice.predictions) > rows:
        lines.append(f"  … {len(advice.predictions) - rows} more (--out for all)")
    lines += ["good labels: labels below the bar expected to reach it (± its simulation error); falls: good labels "
              "expected to fall below it; good/h: good labels per human hour (the rows are ranked by it on the other "
              "half of the simulated outcomes)",
              f"HDI after: the expected {s.hdi_prob:.0%} HDI of the distance; gain pts: its narrowing in points of the "
              "distance (± its error); pts/min: that per minute of human time; loc sd m: the expected location sd",
              f"ESS: the median share of the {n} draws that still count once a simulated outcome reweights them (low: "
              f"a noisier row); fallbacks: the simulated outcomes recomputed on draws moved to their posterior "
              f"because too few counted; outcomes: those the row was weighed on (of {s.n_futures}; dropped: it left "
              "the race early, as it could change neither the plan nor a label's verdict)"]
    lines += ["", f"per target (a label is good when P(IoU >= {s.iou_threshold:g}) >= {s.min_quality:g}):"]
    lines += [f"  {name}: {v['text']}" for name, v in zip(ids, advice.verdicts())]
    said = advice.reason if advice.reason.startswith(advice.action) else f"{advice.action}: {advice.reason}"
    lines += ["", f"recommendation: {said}"]  # the action said once (a reason may begin with it)
    lines += [f"note: {n}" for n in advice.notes]
    dropped = sum(p.dropped for p in advice.predictions)
    lines.append(f"({len(advice.predictions)} annotations weighed on the {n} draws with {s.n_futures} simulated outcomes "
                 f"each{f', {dropped} of them dropped early' if dropped else ''}; {advice.seconds:.1f} s)")
    return "\n".join(lines)
