"""Is the advice worth following? Experiments on simulated scenes (docs/studies/advice.md).

``predict``: predicted against realised. On each scene (``--objects`` targets: 1 for the paper's
scenes, more for frames) a random starting point (1, 2, 3 or 5 sets of dimension lines on every
target, 0–4 references) is estimated and advised on; then each kind of annotation is added as the
simulator makes it and the scene is estimated again. Kinds:

- ``target``: the simulator's next set of dimension lines on the first target;
- ``new-ref``: the simulator's next reference (a new object; the advice is given its segment and
  whether it is a value or a range, not the value);
- ``repeat-ref``: one more reference on the scene's first referenced object, drawn by a second
  simulated worker with the simulator's noise (the advice's own candidate for that object).

The predicted gain (the advice's: every target's 90 % HDI share of its distance now minus
expected after, summed over the targets, points) is compared with the realised one (the full
re-estimate's: before minus after). Each row also holds the update alone: the base draws
reweighted by the annotation actually added (the advice's update given the realised value).

``own``: the same on the model's own scenes: the truth drawn from the model's prior and every
annotation from its noise model, as simulation-based calibration draws them
(creference_bayes/bench/sbc.py, its box as the estimates' bounds; one target); the new reference
on a new line, the repeat a second reading of the first reference's line. There the advice's
expectation is the true one: a gap in ``own`` is the advice's, a gap only in ``predict`` is the
model's fit to the simulator's scenes.

``policy``: an adaptive policy against the paper's fixed designs (one target). From one set of
dimension lines, the policy collects the annotation with the highest expected gain per second
(the next set, a first reference on each of the scene's ten reference objects, or one more on one
already referenced) until the 90 % HDI is at most 10 % of the distance or the human time of the
5 + 5 design is spent; the fixed designs: sets only (1, 2, 5, 10) and 5 sets with k references.
Scenes: the paper-like tier (``high``), all settings, and outdoor alone. The gain is the advice's
``location`` objective (the expected drop of the location's posterior sd per second); ``--rank-by
hdi`` follows the narrowing of the distance's HDI instead.

``timing``: the advice's own time per scene with the default settings. ``report``: the tables
(Markdown, printed and written to ``OUT/advice_study.md``) and the policy figure; ``predict``'s
gains also by the simulated crowd's noise tier.

``predict --dataset auto`` runs the scenes through ``creference batch``'s data-set layer: the
``--n`` starting points are one data set (a first pass of MAPs into ``OUT/dataset/``), and every
estimate of a scene, before and after, takes the priors the other scenes hand it (the crowd's
reference and corner scales, its references' tail and segment floor, where the targets stand), as
the advice on a batch folder does.

``--option KEY=VALUE`` (``predict``, ``timing``, ``policy``) gives every estimate and advice a
metrology model option, as ``creference estimate --option`` does: ``ref_dof=30`` reads references
as nearly normal, for a crowd without the paper's heavy tails.

Records are appended to ``OUT/<experiment>.jsonl`` one scene at a time, so a run can be stopped
and resumed (scenes already recorded are skipped). Usage::

    python examples/advice_study.py predict --n 200 --out advice_study
    python examples/advice_study.py predict --n 40 --objects 4 --setting street --out advice_frames
    python examples/advice_study.py own --n 300 --out advice_study
    python examples/advice_study.py timing --n 20 --out advice_study
    python examples/advice_study.py policy --n 40 --out advice_study
    python examples/advice_study.py report --out advice_study

``--focal-prior MEDIAN,LOG_SD`` has every scene state a log-normal focal-length prior (1650,0.27
fits the simulator's cameras); ``--line-reading linear`` (or ``corrected``) has the estimates and
the advice read reference segments as drawn (or less the median lengthening their line noise
brings) instead of marginalising their end points. Each record says which. These
runs take tens of minutes (predict) to hours (policy) of CPU: on a shared machine run them under
the shared lock (``flock /work/bench.lock ...``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import (CAMERA_POPULATIONS, RANGE_PRECISION, measurement_factor, noise_tier,
                                             simulate_scene)
from creference_bayes.core.units import UNITS_TO_M
from creference_bayes.io.result import stored_draws
from creference_bayes.io.scene import Reference, SceneWarning, parse_scene
from creference_bayes.models.camera_terms import FocalPrior
from creference_bayes.models.metrology import LINE_READINGS
from creference_bayes.pipeline import estimate, map_state, reference_terms, result_draws
from creference_bayes.workflows.advice import AdviceSettings, advise
from creference_bayes.workflows.advice.candidates import Candidate, FormatMix, candidates, format_mix
from creference_bayes.workflows.advice.observe import DimsObservation, ReferenceObservation, at_hands
from creference_bayes.workflows.advice.update import MIN_ESS, MIN_ESS_FRACTION, normalise, shuffled_hdi, weighted_hdi

N_TARGET_POOL, N_REF_POOL = 13, 10
TARGET_S, REF_S = 183.5, 64.4
FIVE_PLUS_FIVE_S = 5 * TARGET_S + 5 * REF_S
#: The policy goal: 5 + 5's median location error within three quarters of its human time.
GOAL_S = 0.75 * FIVE_PLUS_FIVE_S
TARGET_SHARE = 0.10
FIXED = {"target x1": (1, 0), "target x2": (2, 0), "target x5": (5, 0), "target x10": (10, 0),
         "5 + 2 refs": (5, 2), "5 + 4 refs": (5, 4), "5 + 5 refs": (5, 5)}
KINDS = ("target", "new-ref", "repeat-ref")

#: The focal-length prior every simulated scene states (``--focal-prior``); None: the default.
_FOCAL_PRIOR: FocalPrior | None = None
#: Where the simulated scenes' cameras come from (``--cameras``; simulate_scene's ``cameras``).
_CAMERAS = "setting"
#: Metrology model settings of every estimate and advice (``--line-reading``).
_MODEL_OPTIONS: dict = {}
#: Further settings of every estimate (``own``: the box of the model's own scenes as the bounds).
_ESTIMATE_KW: dict = {}
#: What-if settings of ``predict`` (recorded with the options): ``distance_range`` (every estimate
#: told where the scenes' targets stand: "setting", the simulator's range for the scene's setting,
#: or [low, high] m) and ``reference_px`` (the simulated crowd's reference endpoint noise, px,
#: instead of its tier's).
_WHAT_IF: dict = {}
#: Every estimate's CPU seconds and convergence since the last record was written.
_COSTS: list[dict] = []
#: ``predict --dataset auto``: scene name → (the scene fields, the estimate keywords and the
#: ``dataset`` block the data-set layer hands it, learnt from the run's base scenes as one batch)
_DATASET: dict = {}
#: what the data-set layer hands back in the scene itself (the rest comes as estimate keywords)
_HANDED = ("focal_prior", "orientation_prior", "corner_scale", "camera_id")


# ------------------------------------------------------------------------------------------------
# scenes and annotations as the simulator makes them


def _parse(d):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = parse_scene(d)
    if _WHAT_IF.get("declare_setting"):  # what a data set's records say: where each photo was taken
        scene = dataclasses.replace(scene, setting=(d.get("ground_truth") or {}).get("setting"))
    # stated by the scene, the prior reaches the estimates and the advice alike
    return scene if _FOCAL_PRIOR is None else dataclasses.replace(scene, focal_prior=_FOCAL_PRIOR)


def _tier(name: str):
    """The simulator's noise tier or crowd ``name``, with the endpoint noise of ``--reference-px`` if given."""
    tier = noise_tier(name)
    return tier if "reference_px" not in _WHAT_IF else dataclasses.replace(tier, reference_px=_WHAT_IF["reference_px"])


def _scene(seed: int, k: int, tier: str, setting: str | None, n_objects: int = 1):
    return _parse(simulate_scene(np.random.default_rng([seed, k]), tier=_tier(tier), setting=setting, n_objects=n_objects,
                                 n_target_annotations=N_TARGET_POOL, n_references=N_REF_POOL, format_offset=k,
                                 cameras=_CAMERAS))


def _variant(pool, n_t: int, refs, extra=()):
    """``pool`` with every target's first ``n_t`` sets and the references ``refs`` (indices into the
    pool) followed by ``extra`` ((reference, owner) pairs), renumbered."""
    pairs = [(pool.references[j], pool.reference_targets[j]) for j in refs] + list(extra)
    return dataclasses.replace(
        pool, targets=tuple(dataclasses.replace(t, dimension_lines=t.dimension_lines[:n_t]) for t in pool.targets),
        references=tuple(dataclasses.replace(r, index=i) for i, (r, _) in enumerate(pairs)),
        reference_targets=tuple(o for _, o in pairs))


def _one_more_set(scene, pool):
    """``scene`` with the first target's next set of dimension lines from ``pool``."""
    t = scene.targets[0]
    nxt = pool.targets[0].dimension_lines[len(t.dimension_lines)]
    return dataclasses.replace(scene, targets=(dataclasses.replace(t, dimension_lines=t.dimension_lines + (nxt,)),)
                               + scene.targets[1:])


def _second_worker(pool, j: int, rng) -> tuple[Reference, object]:
    """One more reference on the object of the pool's reference ``j``, by a new simulated worker:
    the true segment with the tier's endpoint noise, the true length times the tier's measurement
    error, stated in reference j's format and unit (as bench/simulate.py does)."""
    gt = pool.ground_truth
    tier = _tier(gt["tier"])
    ref = pool.references[j]
    line = np.asarray(gt["reference_lines_px"][j], float) + rng.normal(0.0, tier.reference_px, (2, 2))
    line[:, 0] = np.clip(line[:, 0], 0, pool.image_width)
    line[:, 1] = np.clip(line[:, 1], 0, pool.image_height)
    stated = gt["reference_lengths_m"][j] * measurement_factor(rng, tier.measurement)
    owner = pool.reference_targets[j]
    size = pool.targets[owner if owner is not None else 0].dimensions
    scale = UNITS_TO_M[ref.unit] if ref.mode == "direct" else size[("length", "width").index(ref.measure)]
    value = stated / scale
    if ref.is_range:
        p = min(float(np.exp(rng.normal(math.log(RANGE_PRECISION["median"]), RANGE_PRECISION["log_sd"]))), 1.9)
        low, high = float(f"{value * (1 - p / 2):.4g}"), float(f"{value * (1 + p / 2):.4g}")
    else:
        low = high = float(f"{value:.4g}")
    factor = UNITS_TO_M[ref.unit] if ref.mode == "direct" else 1.0  # relative values stay ratios
    return Reference(index=0, measure=ref.measure, mode=ref.mode, low=low * factor, high=high * factor,
                     line=np.round(line, 2), is_range=ref.is_range, unit=ref.unit, object=ref.object,
                     worker=f"second-{j}", seconds=REF_S, stated=(low, high)), owner


def _costs() -> list[dict]:
    out = list(_COSTS)
    _COSTS.clear()
    return out


def _estimate(scene, seed, min_ess, priors=None):
    """The estimate and, per target, its HDI width, share and median of the distance, whether the
    truth is inside, the location errors (MAP, posterior mean) and the truth's quantile. ``priors``:
    estimate keywords the data set hands the scene (:func:`_handed`)."""
    t0 = time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            r = estimate(scene, seed=seed, sampling={"min_ess": min_ess}, keep_draws=2000,
                         **{**_MODEL_OPTIONS, **_ESTIMATE_KW, **_distance_range(scene), **(priors or {})})
        except RuntimeError as exc:  # no MAP found: the scene is left out, the failure recorded
            _COSTS.append({"cpu_s": time.process_time() - t0, "converged": False, "overflow_warnings": 0,
                           "failed": " ".join(str(exc).split())})
            return None
    _COSTS.append({"cpu_s": time.process_time() - t0, "converged": bool(r.converged),
                   "overflow_warnings": sum("overflow" in str(w.message) for w in caught)})
    d = r.to_dict()
    if "draws" not in d:
        return None
    cams, objs, _ = result_draws(d, r.model)
    kept = stored_draws(d)  # each draw's handedness where a target was sampled at both
    hands = None if kept is None or kept.handedness is None else kept.handedness.reshape(len(cams), -1)
    hdi = np.array([o["posterior"]["hdi"]["distance_m"] for o in d["objects"]], float)
    median = np.array([o["posterior"]["median"]["distance_m"] for o in d["objects"]], float)
    true_d = np.array([math.hypot(t.ground_truth["location_m"][0], t.ground_truth["location_m"][2])
                       for t in scene.targets])
    dist = np.hypot(objs[..., 0], objs[..., 1])
    width = hdi[:, 1] - hdi[:, 0]
    return {"result": r, "cams": cams, "objs": objs, "hands": hands, "width": width, "share": width / median,
            "covered": ((hdi[:, 0] <= true_d) & (true_d <= hdi[:, 1])).tolist(),
            "error": [o["evaluation"]["location_pct_error"] for o in d["objects"]],
            "post_error": [o["evaluation"]["posterior_location_pct_error"] for o in d["objects"]],
            "truth_quantile": np.mean(dist < true_d, axis=0).tolist(),
            "handedness_kept_true": [o["handedness"] == t.ground_truth.get("handedness")
                                     for o, t in zip(d["objects"], scene.targets)]}


def _advise(scene, est, seed, cands=None, mixes=None, settings=None):
    r = est["result"]
    camera, objects = map_state(r.to_dict())
    return advise(r.model, scene, est["cams"], est["objs"], camera_map=camera, objects_map=objects,
                  options=_options(r), seed=seed, candidates=cands, mixes=mixes, settings=settings,
                  hands=est.get("hands"))


def _options(result) -> dict:
    """The model options the estimate was made with (the study's and those the data set handed it),
    as the advice reads them from a result's provenance."""
    return {**_MODEL_OPTIONS, **{k: v for k, v in result.to_dict()["provenance"]["options"].items()
                                 if k.startswith("ref_scale")}}


def _learn_dataset(args, case_of) -> None:
    """``--dataset auto``: the run's ``--n`` base scenes as one data set, through ``creference
    batch``'s data-set layer (its first pass, a MAP each, into ``OUT/dataset/``, and what it hands
    each frame from the others: :func:`~creference_bayes.workflows.batch.learn_priors`). Every
    estimate of a scene, before and after the annotation added, then takes the priors its base
    scene was handed (the other frames' pools do not change with this frame's annotation)."""
    from creference_bayes.io.scene import scene_to_dict
    from creference_bayes.workflows.batch import BatchSettings, learn_priors

    folder = Path(args.out) / "dataset"
    (folder / "in").mkdir(parents=True, exist_ok=True)
    for k in range(args.n):
        path = folder / "in" / f"s{k:04d}.json"
        if not path.exists():
            path.write_text(json.dumps(scene_to_dict(case_of(args.seed, k)["base"])))
    handed = learn_priors([folder / "in"], folder / "first_pass",
                          BatchSettings(seed=args.seed, model="metrology", options=dict(_MODEL_OPTIONS)))
    _DATASET.update({key: ({f: getattr(scene, f) for f in _HANDED}, kwargs, block)
                     for key, (scene, kwargs, block) in handed.items()})


def _handed(name: str, scene):
    """``scene`` with what the data set hands it (``--dataset auto``) → (scene, estimate keywords)."""
    if name not in _DATASET:
        return scene, {}
    fields, kwargs, _ = _DATASET[name]
    return dataclasses.replace(scene, **fields), kwargs


def _reference_candidate(key, scene, j, seconds=REF_S):
    """Reference ``j`` of ``scene`` as a candidate (its segment and what it measures, not its value)."""
    term = reference_terms(scene)[j]
    r = scene.references[j]
    return Candidate(key, "reference", term.owner if term.kind != "ground" else None,
                     None if term.owner is None else scene.targets[term.owner].id, r.measure, r.object,
                     None if r.line is None else np.asarray(r.line, float), term, (), seconds)


def _reweighted(est, kind, scene_after, settings):
    """The update alone: the base draws reweighted by the annotation actually added (the advice's
    update, given the realised value, with its correction of the weighted HDI's small-sample
    narrowing), as the gain in points summed over the targets; None when the weights collapse
    (the advice would recompute that future by its tempered update)."""
    model = est["result"].model
    cams, objs = model.complete_camera(est["cams"]), est["objs"]
    keep = np.unique(np.linspace(0, len(cams) - 1, min(settings.n_draws, len(cams))).round().astype(int))
    cams, objs = cams[keep], objs[keep]
    hands = None if est.get("hands") is None else est["hands"][keep]
    if kind == "target":
        obs = DimsObservation(model, 0, _options(est["result"]))
        obs.corners = scene_after.targets[0].dimension_lines[-1].corners[None]
    else:
        term = reference_terms(scene_after)[-1]  # the reference as drawn and stated
        obs = ReferenceObservation(model, term, _options(est["result"]))
        if not obs.usable:
            return None
        if obs.needs_scale:
            cams = obs.scale_draws(cams, np.random.default_rng(0))
        obs.log_low, obs.log_high, obs.is_range = np.log([term.low]), np.log([term.high]), np.array([term.is_range])
    w, ess = normalise(obs.log_ratio(cams, objs, at_hands(model, hands).neg_log_posterior(cams, objs), hands=hands))
    if ess[0] < max(MIN_ESS, MIN_ESS_FRACTION * len(cams)):
        return None
    dist = np.hypot(objs[..., 0], objs[..., 1])
    now_w, now_m = weighted_hdi(dist, np.full((1, len(dist)), 1.0 / len(dist)), 0.9)
    width, median = weighted_hdi(dist, w, 0.9)
    _, shuffled = shuffled_hdi(dist, w, 0.9, np.random.default_rng(0))
    share = width / median * (now_w / now_m) / shuffled
    return float(100 * np.sum(now_w / now_m - share))


def _done(path: Path) -> set:
    """Scenes already recorded in ``path``; a folder of records made with another focal prior,
    line reading or camera population is refused (a resumed run must not mix them)."""
    if not path.is_file():
        return set()
    recs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    mine = (None if _FOCAL_PRIOR is None else _FOCAL_PRIOR.to_dict(), _MODEL_OPTIONS.get("line_reading", "marginal"),
            _CAMERAS, _other_options())
    for r in recs:
        theirs = (r.get("focal_prior"), r.get("line_reading", "linear"), r.get("cameras", "setting"),
                  r.get("options", {}))
        if theirs != mine:
            said = ["focal prior {}, line reading {!r}, cameras {!r} and options {}".format(*x) for x in (theirs, mine)]
            sys.exit(f"advice_study.py: {path} holds records made with {said[0]}, this run has {said[1]}: "
                     "use another --out")
    return {r["scene"] for r in recs}


def _other_options() -> dict:
    """The model options of ``--option`` (as a result records them: an infinite one as "inf") and
    the what-if settings (:data:`_WHAT_IF`)."""
    from creference_bayes.pipeline import option_record

    return {**{k: option_record(v) for k, v in sorted(_MODEL_OPTIONS.items()) if k != "line_reading"}, **_WHAT_IF}


def _distance_range(scene) -> dict:
    """The ``distance_range`` keyword of a scene's estimates (:data:`_WHAT_IF`), or none."""
    given = _WHAT_IF.get("distance_range")
    if given is None:
        return {}
    if given == "setting":
        from creference_bayes.bench.simulate import SETTINGS

        return {"distance_range": SETTINGS[scene.ground_truth["setting"]]["distance"]}
    return {"distance_range": tuple(given)}


def _append(path: Path, record: dict) -> None:
    options = _other_options()
    record = {**record, "focal_prior": None if _FOCAL_PRIOR is None else _FOCAL_PRIOR.to_dict(),
              "line_reading": _MODEL_OPTIONS.get("line_reading", "marginal"), "cameras": _CAMERAS,
              **({"options": options} if options else {})}
    with path.open("a") as f:
        f.write(json.dumps(record) + "\n")


def _bar(total, desc):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty())


# ------------------------------------------------------------------------------------------------
# predicted against realised


def _predict_case(seed: int, k: int, tiers: list[str], n_objects: int, setting: str | None):
    """Scene k of the predict experiment: its starting point and the annotations added."""
    tier = tiers[k % len(tiers)]
    pool = _scene(seed, k, tier, setting, n_objects)
    rng = np.random.default_rng([seed, k, 1])
    n_t, n_r = int(rng.choice([1, 2, 3, 5])), int(rng.integers(0, 5))
    base = _variant(pool, n_t, range(n_r))
    added = {"target": _one_more_set(base, pool), "new-ref": _variant(pool, n_t, range(n_r + 1))}
    return {"tier": tier, "setting": pool.ground_truth["setting"], "n_t": n_t, "n_r": n_r, "base": base,
            "added": added, "new_is_range": pool.references[n_r].is_range,
            "repeat": lambda j: _variant(pool, n_t, range(n_r),
                                         [_second_worker(pool, j, np.random.default_rng([seed, k, 4]))])}


OWN_SETS = (1, 2, 3, 5)


def _own_setting(sets) -> str:
    """The records' ``setting`` of an own-model run: "own", or which starting sets it drew from."""
    return "own" if tuple(sets) == OWN_SETS else "own, sets " + ",".join(map(str, sets))


def _own_case(seed: int, k: int, sets: tuple[int, ...] = OWN_SETS):
    """Scene k of the own-model check: the truth from the model's prior (within the box of
    simulation-based calibration), the annotations from its noise model (creference_bayes.bench.sbc),
    a starting point of one of ``sets`` sets and 0–4 references, and the annotations added: the
    next set, a reference on a new segment, a second worker's reading of the first one."""
    from creference_bayes.bench.sbc import draw_truth, sbc_reference, simulate_sbc_scene

    rng = np.random.default_rng([seed, k, 11])
    n_t, n_r = int(rng.choice(list(sets))), int(rng.integers(0, 5))
    d = repeat = None
    while d is None or (n_r and repeat is None):  # outside the image: a new scene (a selection on the data)
        truth = draw_truth(rng)
        d = simulate_sbc_scene(rng, truth, n_t + 1, n_r + 1)
        if d is not None:
            gt = d["ground_truth"]
            line, name = gt["reference_lines_true_px"][0], d["references"][0]["object"]
            tries = (sbc_reference(rng, truth, line, gt["crowd_scale"], "second-0", object=name) for _ in range(200))
            repeat = n_r and next((r for r in tries if r is not None), None)
    lines, refs = d["targets"][0]["dimension_lines"], d["references"]

    def scene_of(n_lines, references):
        return _parse({**d, "targets": [{**d["targets"][0], "dimension_lines": lines[:n_lines]}],
                       "references": references})

    return {"tier": "own", "setting": _own_setting(sets),
            "n_t": n_t, "n_r": n_r, "base": scene_of(n_t, refs[:n_r]), "new_is_range": False,
            "added": {"target": scene_of(n_t + 1, refs[:n_r]), "new-ref": scene_of(n_t, refs[:n_r + 1])},
            "repeat": lambda j: scene_of(n_t, refs[:n_r] + [repeat]) if j == 0 else None}




def run_predict(args, case_of=None, file: str = "predict.jsonl") -> None:
    """The predict experiment; ``case_of(seed, k)`` makes scene k (default: :func:`_predict_case`)."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / file
    done = _done(path)
    if case_of is None:
        def case_of(seed, k):
            return _predict_case(seed, k, args.tiers.split(","), args.objects, args.setting)
    settings = AdviceSettings(objective="hdi")  # this study measures the HDI advice
    if _WHAT_IF.get("dataset"):
        _learn_dataset(args, case_of)
    with _bar(args.n, file.split(".")[0]) as bar:
        for k in range(args.n):
            bar.update(1)
            name = f"s{k:04d}"
            if name in done:
                continue
            case = case_of(args.seed, k)
            base, priors = _handed(name, case["base"])
            _costs()
            before = _estimate(base, [args.seed, k, 2], args.min_ess, priors)
            if before is None:
                continue
            r = before["result"]
            every, _ = candidates(base, r.model, *map_state(r.to_dict()))
            cands = [dataclasses.replace(next(c for c in every if c.kind == "dims"), key="target")]
            cands.append(_reference_candidate("new-ref", case["added"]["new-ref"], case["n_r"]))
            mixes = {"new-ref": FormatMix(float(case["new_is_range"]), format_mix(base).range_precision, 0.0)}
            added = dict(case["added"])
            rep = next((c for c in every if c.based_on and not c.new_segment and c.line is not None), None)
            if rep is not None and case["repeat"](rep.based_on[0]) is not None:
                cands.append(dataclasses.replace(rep, key="repeat-ref"))
                added["repeat-ref"] = case["repeat"](rep.based_on[0])
            advice = _advise(base, before, [args.seed, k, 3], cands, mixes, settings)
            preds = {p.candidate.key: p for p in advice.predictions}
            rows = []
            for kind, scene in added.items():
                if kind not in preds:
                    continue
                after = _estimate(_handed(name, scene)[0], [args.seed, k, 5], args.min_ess, priors)
                if after is None:
                    continue
                p = preds[kind]
                rows.append({"kind": kind, "measure": p.candidate.measure,
                             "pred_now_share": advice.now.hdi_share.tolist(),
                             "pred_after_share": p.expected.hdi_share.tolist(),
                             "pred_gain_pct": p.gain_pct, "pred_gain_se_pct": p.gain_se_pct,
                             "real_before_share": before["share"].tolist(), "real_after_share": after["share"].tolist(),
                             "real_gain_pct": float(100 * np.sum(before["share"] - after["share"])),
                             "rew_gain_pct": _reweighted(before, kind, scene, settings),
                             "ess": p.ess_median, "fallbacks": p.fallbacks})
            _append(path, {"scene": name, "tier": case["tier"], "setting": case["setting"],
                           "n_objects": len(base.targets), "n_target": case["n_t"], "n_refs": case["n_r"],
                           "truth_quantile": before["truth_quantile"],
                           "handedness_kept_true": before["handedness_kept_true"],
                           "advice_only_s": advice.seconds, "n_candidates": len(every), "rows": rows,
                           **({"dataset": _DATASET[name][2]} if name in _DATASET else {}),
                           "estimates": _costs()})


def run_own(args) -> None:
    """Predicted against realised on the model's own scenes (module docstring)."""
    from creference_bayes.bench.sbc import SBC_BOX

    _ESTIMATE_KW.update(bounds=SBC_BOX.bounds(), focal_prior="default", location_prior="log-depth")
    sets, path = args.sets, Path(args.out) / "own.jsonl"
    other = {json.loads(x).get("setting") for x in path.read_text().splitlines() if x.strip()} \
        if path.is_file() else set()
    if other - {_own_setting(sets)}:
        sys.exit(f"advice_study.py: {path} holds records of {sorted(other)}, this run's --sets "
                 f"{','.join(map(str, sets))} makes {_own_setting(sets)!r}: use another --out")
    run_predict(args, case_of=lambda seed, k: _own_case(seed, k, sets), file="own.jsonl")


# ------------------------------------------------------------------------------------------------
# the adaptive policy and the fixed designs


def _policy_candidates(pool, scene, used_targets, used_objects):
    """The next set, a first reference on each unused pool object, one more on each used one."""
    cands = []
    t = scene.targets[0]
    if used_targets < N_TARGET_POOL:
        cands.append(Candidate("target", "dims", 0, t.id, None, t.id, None, None, (), TARGET_S))
    for j in range(len(pool.references)):
        c = _reference_candidate(f"first-{j}", pool, j)
        if j in used_objects:
            ref = pool.references[j]
            lines = [np.asarray(r.line) for r in scene.references if r.worker in (ref.worker, f"second-{j}")]
            line = np.median(np.stack(lines), axis=0)
            c = dataclasses.replace(c, key=f"more-{j}", line=line, term=dataclasses.replace(c.term, line=line))
        cands.append(dataclasses.replace(c, based_on=(j,)))
    return cands


def run_adaptive(pool, seed, k, min_ess, settings):
    scene = _variant(pool, 1, ())
    used_targets, used_objects, spent, steps = 1, set(), TARGET_S, []
    rng = np.random.default_rng([seed, k, 7])
    mix = FormatMix(0.5, RANGE_PRECISION["median"], 0.5)  # the simulator's ten formats, half ranges
    while True:
        est = _estimate(scene, [seed, k, 8, len(steps)], min_ess)
        if est is None:
            return None
        steps.append({"seconds": spent, "error": est["error"][0], "share": float(est["share"][0]),
                      "covered": est["covered"][0], "post_error": est["post_error"][0]})
        if est["share"][0] <= TARGET_SHARE or spent + REF_S > FIVE_PLUS_FIVE_S:
            break
        cands = [c for c in _policy_candidates(pool, scene, used_targets, used_objects)
                 if spent + c.seconds <= FIVE_PLUS_FIVE_S]
        ref_mix = format_mix(scene) if scene.references else mix
        advice = _advise(scene, est, [seed, k, 9, len(steps)], cands, {c.key: ref_mix for c in cands}, settings)
        if not advice.predictions:
            break
        steps[-1]["gains"] = {p.candidate.key: round(p.gain_per_minute, 4) for p in advice.predictions}
        best = advice.best.candidate  # ranked by the advice's objective (settings.objective)
        steps[-1]["chosen"] = best.key
        if best.kind == "dims":
            scene = _one_more_set(scene, pool)
            used_targets += 1
        else:
            j = best.based_on[0]
            new = (pool.references[j], pool.reference_targets[j]) if j not in used_objects else \
                _second_worker(pool, j, rng)
            used_objects.add(j)
            scene = dataclasses.replace(scene, references=scene.references + (dataclasses.replace(
                new[0], index=len(scene.references)),), reference_targets=scene.reference_targets + (new[1],))
        spent += best.seconds
    last = steps[-1]
    return {**{k: last[k] for k in ("seconds", "error", "post_error", "covered", "share")}, "steps": steps,
            "n_target": used_targets, "n_refs": len(scene.references)}


def run_policy(args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "policy.jsonl"
    done = _done(path)
    settings = AdviceSettings(min_gain=0.0, objective=args.rank_by)  # the policy follows the advice's ranking
    if path.is_file():
        other = {json.loads(x).get("rank_by", "hdi") for x in path.read_text().splitlines() if x.strip()}
        if other - {args.rank_by}:
            raise SystemExit(f"{path}: records ranked by {sorted(other)}; --rank-by {args.rank_by} needs its own --out")
    # conditions interleaved, so that a run stopped early has as many scenes of each
    jobs = [(f"{c}-{k:03d}", c, k) for k in range(args.n) for c in ("paper-like", "outdoor")]
    with _bar(len(jobs), "policy") as bar:
        for name, cond, k in jobs:
            bar.update(1)
            if name in done:
                continue
            pool = _scene(args.seed + (1000 if cond == "outdoor" else 0), k, "high",
                          "outdoor" if cond == "outdoor" else None)
            rec = {"scene": name, "condition": cond, "setting": pool.ground_truth["setting"], "fixed": {}}
            _costs()
            for label, (n_t, n_r) in FIXED.items():
                est = _estimate(_variant(pool, n_t, range(n_r)), [args.seed, k, 6, n_t, n_r], args.min_ess)
                if est is not None:
                    rec["fixed"][label] = {"seconds": n_t * TARGET_S + n_r * REF_S, "error": est["error"][0],
                                           "post_error": est["post_error"][0], "covered": est["covered"][0],
                                           "share": float(est["share"][0])}
            rec["adaptive"] = run_adaptive(pool, args.seed, k + (1000 if cond == "outdoor" else 0),
                                           args.min_ess, settings)
            _append(path, {**rec, "rank_by": args.rank_by, "estimates": _costs()})


# ------------------------------------------------------------------------------------------------
# time per scene


def run_timing(args) -> None:
    """The advice's own time per scene with the default settings and every candidate the scene
    allows, on scenes as the paper designs them (5 sets of dimension lines, 5 references), from
    the estimate's draws and from the 400 draws a result file keeps."""
    from creference_bayes.workflows.advice.inputs import advise_result

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "timing.jsonl"
    done = _done(path)
    with _bar(args.n, "timing") as bar:
        for k in range(args.n):
            bar.update(1)
            name = f"t{k:04d}"
            if name in done:
                continue
            pool = _scene(args.seed + 2000, k, "high" if k % 2 else "medium", args.setting, args.objects)
            scene = _variant(pool, 5, range(5))
            est = _estimate(scene, [args.seed, k, 10], args.min_ess)
            t0 = time.process_time()
            a = _advise(scene, est, [args.seed, k, 11])
            t_scene = time.process_time() - t0
            d = est["result"].to_dict()
            d["draws"] = {**d["draws"], **_thinned(d["draws"], 400)}
            t0 = time.process_time()
            advise_result(d, scene, seed=[args.seed, k, 12])
            _append(path, {"scene": name, "setting": pool.ground_truth["setting"], "n_objects": len(scene.targets),
                           "n_candidates": len(a.predictions), "scene_s": t_scene,
                           "result_s": time.process_time() - t0, "action": a.action})


def _thinned(draws: dict, n: int) -> dict:
    """A result's kept draws thinned to ``n`` (as a result file keeps them)."""
    idx = np.unique(np.linspace(0, draws["n"] - 1, n).round().astype(int))
    pick = lambda v: v if not isinstance(v, list) else [v[i] for i in idx]  # noqa: E731
    return {"n": len(idx), "camera": {k: pick(v) for k, v in draws["camera"].items()},
            "objects": [{k: pick(v) for k, v in o.items()} for o in draws["objects"]],
            **{k: pick(draws[k]) for k in ("chain", "lp") if k in draws}}


# ------------------------------------------------------------------------------------------------
# tables and figure


def _md(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join(lines + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def _boot_ratio(num, den, rng, n=2000):
    num, den = np.asarray(num), np.asarray(den)
    idx = rng.integers(len(num), size=(n, len(num)))
    return np.percentile(num[idx].mean(axis=1) / den[idx].mean(axis=1), [5, 95])


def _read(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def report_predict(out: Path, file: str = "predict.jsonl") -> str:
    recs = _read(out / file)
    rng = np.random.default_rng(0)

    def points(rows):  # n, predicted and realised points, their ratio [90 % bootstrap]
        ps, rs = np.array([x["pred_gain_pct"] for x in rows]), np.array([x["real_gain_pct"] for x in rows])
        lo, hi = _boot_ratio(rs, ps, rng)
        return len(rows), f"{ps.mean():.2f}", f"{rs.mean():.2f}", f"{rs.mean() / ps.mean():.2f} [{lo:.2f}, {hi:.2f}]"

    rows = [x for r in recs for x in r["rows"]]
    bands = []
    for lo_b, hi_b, label in ((0.0, 0.25, "< 25 %"), (0.25, 0.5, "25–50 %"), (0.5, 1.0, "50–100 %"),
                              (1.0, np.inf, ">= 100 %"), (0.0, np.inf, "all")):
        for kind in KINDS:
            sel = [x for x in rows if x["kind"] == kind and lo_b <= np.mean(x["real_before_share"]) < hi_b]
            if len(sel) >= 3:
                bands.append((label, kind, *points(sel)))
    bands.append(("all", "every kind (the total)", *points(rows)))
    by_sets = []
    for label, ok in (("one set", lambda n: n == 1), ("two", lambda n: n == 2), ("three or more", lambda n: n >= 3)):
        sel = [x for r in recs if ok(r["n_target"]) for x in r["rows"] if x["kind"] == "target"]
        if len(sel) >= 3:
            by_sets.append((label, *points(sel)))
    # by the crowd's noise tier: the model reads every reference with Student-t (ν = 2) errors, as
    # the paper's crowd has them; a crowd of lighter tails ("medium": log-normal, log-sd 0.4) is
    # more informative than the advice simulates
    tiers = sorted({r.get("tier") or "" for r in recs})
    by_tier = []
    for tier in tiers if len(tiers) > 1 else ():
        for kind in KINDS:
            sel = [x for r in recs if (r.get("tier") or "") == tier for x in r["rows"] if x["kind"] == kind]
            rew = [x["rew_gain_pct"] for x in sel if x.get("rew_gain_pct") is not None]
            if len(sel) >= 3:
                by_tier.append((tier, kind, *points(sel), f"{np.mean(rew):.2f}" if rew else ""))
    check = []
    for kind in KINDS:
        sel = [x for x in rows if x["kind"] == kind and x.get("rew_gain_pct") is not None]
        if sel:
            rew, real = np.array([x["rew_gain_pct"] for x in sel]), np.array([x["real_gain_pct"] for x in sel])
            check.append((kind, len(sel), f"{rew.mean():.2f}", f"{real.mean():.2f}",
                          f"{np.median(np.abs(rew - real)):.2f}", f"{np.percentile(np.abs(rew - real), 90):.2f}"))
    calib = []
    pairs = [(q, s, r.get("setting") or "") for r in recs if r["rows"]
             for q, s in zip(r["truth_quantile"], r["rows"][0]["real_before_share"])]
    # by setting too: a prior that is not the scenes' population is calibrated over all of them and
    # not within a band, where it decides most (docs/studies/advice.md, predicted against realised)
    settings = sorted({c for *_, c in pairs})
    for setting in ([""] + settings if len(settings) > 1 else [""]):
        for lo_b, hi_b, label in ((0.0, 0.5, "< 50 %"), (0.5, np.inf, ">= 50 %"), (0.0, np.inf, "all")):
            q = np.array([q for q, s, c in pairs if lo_b <= s < hi_b and setting in ("", c)])
            if len(q):
                calib.append((f"{label}, {setting}" if setting else label, len(q), f"{np.mean(q):.2f}",
                              f"{100 * np.mean(q < 0.5):.0f} %", f"{100 * np.mean((q > 0.05) & (q < 0.95)):.0f} %",
                              f"{100 * np.mean(q < 0.1):.0f} %"))
    kept = np.array([h for r in recs for h in r["handedness_kept_true"] if h is not None])
    secs = np.array([r["advice_only_s"] for r in recs])
    m = sorted({r.get("n_objects", 1) for r in recs})
    title = ("Predicted against realised" if file == "predict.jsonl" else
             "On the model's own scenes (prior and noise model of simulation-based calibration): predicted against "
             "realised")
    return (f"{title} gain ({len(recs)} scenes of {', '.join(map(str, m))} targets): every target's 90 % HDI of "
            "the distance as a share of its median, before minus after, summed over the targets, in points; "
            "predicted (the advice: now − expected after) against realised (the re-estimate), by the mean share "
            "before\n\n" + _md(("HDI share before", "kind", "n", "predicted pts", "realised pts",
                                "realised / predicted [90 % bootstrap]"), bands)
            + ("\n\nThe target set by the number of sets before it\n\n" + _md(
                ("target sets before", "n", "predicted pts", "realised pts", "realised / predicted [90 % bootstrap]"),
                by_sets) if by_sets else "")
            + ("\n\nBy the crowd's noise tier (the simulator's workers; the model reads references as Student-t "
               "with 2 degrees of freedom)\n\n" + _md(
                   ("tier", "kind", "n", "predicted pts", "realised pts", "realised / predicted [90 % bootstrap]",
                    "reweighted pts (the update alone, below)"), by_tier) if by_tier else "")
            + ("\n\nThe update alone: the base draws reweighted by the annotation actually added, against the "
               "re-estimate with it (gain in points; rows whose weights collapsed left out)\n\n" + _md(
                   ("kind", "n", "reweighted", "re-estimated", "median |difference|", "90th percentile"), check)
               if check else "")
            + ("\n\nWhere the true distance falls in the posterior before (its quantile, per target; calibrated: "
               "mean 0.5, half below the median, 90 % in the central 90 %, 10 % in the lowest decile)\n\n" + _md(
                   ("HDI share before", "targets", "mean quantile", "below the median", "in the central 90 %",
                    "in the lowest decile"), calib) if calib else "")
            + f"\n\nThe MAP kept the true handedness of {100 * kept.mean():.0f} % of the targets. Time per scene "
              f"(advice alone): median {np.median(secs):.2f} s, mean {secs.mean():.2f} s, 90th percentile "
              f"{np.percentile(secs, 90):.2f} s\n")


def report_timing(out: Path) -> str:
    recs = _read(out / "timing.jsonl")
    rows = []
    for key, label in (("scene_s", "from the estimate's draws (600 used)"),
                       ("result_s", "from a result file (400 draws; with rebuilding its model)")):
        t = np.array([r[key] for r in recs])
        rows.append((label, len(t), f"{np.median(t):.2f}", f"{t.mean():.2f}", f"{np.percentile(t, 90):.2f}",
                     f"{t.max():.2f}"))
    n = np.array([r["n_candidates"] for r in recs])
    return (f"Time per scene of the advice alone (CPU seconds; 5 sets + 5 references, every candidate the scene "
            f"allows: {n.mean():.1f} on average, {n.min()}–{n.max()})\n\n"
            + _md(("input", "scenes", "median", "mean", "90th percentile", "max"), rows) + "\n")


def _summary(entries):
    e = np.array([x["error"] for x in entries])
    return (len(e), f"{np.mean([x['seconds'] for x in entries]):.0f}", f"{np.median(e):.1f}", f"{e.mean():.1f}",
            f"{100 * np.mean([x['covered'] for x in entries]):.0f} %",
            f"{100 * np.mean([x['share'] <= TARGET_SHARE for x in entries]):.0f} %")


def _truncated(adaptive: dict, seconds: float) -> dict:
    """The adaptive run's state at its last estimate within ``seconds`` of human time (a
    conservative stand-in for a run with that budget)."""
    last = [s for s in adaptive["steps"] if s["seconds"] <= seconds][-1]
    return {k: last[k] for k in ("seconds", "error", "post_error", "covered", "share")}


def report_policy(out: Path) -> str:
    recs = _read(out / "policy.jsonl")
    text = []
    for cond in ("paper-like", "outdoor"):
        rs = [r for r in recs if r["condition"] == cond and r.get("adaptive")]
        if not rs:
            continue
        rows = [("adaptive",) + _summary([r["adaptive"] for r in rs]),
                (f"adaptive, stopped at {GOAL_S:.0f} s",) + _summary([_truncated(r["adaptive"], GOAL_S) for r in rs])]
        rows += [(label,) + _summary([r["fixed"][label] for r in rs if label in r["fixed"]]) for label in FIXED
                 if any(label in r["fixed"] for r in rs)]
        comp = np.array([[r["adaptive"]["n_target"], r["adaptive"]["n_refs"]] for r in rs])
        text.append(f"Policies, {cond} scenes (tier high)\n\n" + _md(
            ("policy", "scenes", "mean human s", "median error %", "mean error %", "90 % coverage", "HDI <= 10 %"),
            rows) + f"\n\nAdaptive: {comp[:, 0].mean():.1f} target sets and {comp[:, 1].mean():.1f} references "
                    "on average\n")
    return "\n".join(text)


def figure_policy(out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    recs = _read(out / "policy.jsonl")
    conds = [c for c in ("paper-like", "outdoor") if any(r["condition"] == c for r in recs)]
    fig, axes = plt.subplots(1, len(conds), figsize=(6 * len(conds), 5.2), squeeze=False)
    for ax, cond in zip(axes[0], conds):
        rs = [r for r in recs if r["condition"] == cond and r.get("adaptive")]
        for family, labels, style in (("target sets only", ("target x1", "target x2", "target x5", "target x10"), "o-"),
                                      ("5 sets + k references", ("target x5", "5 + 2 refs", "5 + 4 refs", "5 + 5 refs"),
                                       "s-")):
            ax.plot([np.mean([r["fixed"][lab]["seconds"] for r in rs if lab in r["fixed"]]) for lab in labels],
                    [np.median([r["fixed"][lab]["error"] for r in rs if lab in r["fixed"]]) for lab in labels],
                    style, label=family)
        grid = np.linspace(TARGET_S, FIVE_PLUS_FIVE_S, 60)
        curves = []
        for r in rs:
            t = np.array([s["seconds"] for s in r["adaptive"]["steps"]])
            e = np.array([s["error"] for s in r["adaptive"]["steps"]])
            curves.append(e[np.searchsorted(t, grid, side="right") - 1])
        ax.plot(grid, np.median(curves, axis=0), "-", color="k", label="adaptive policy (median along its runs)")
        ax.axvline(GOAL_S, color="grey", ls="--", lw=1, label="three quarters of the human time of 5 + 5")
        ax.set(xlabel="human seconds per target", ylabel="median location error, % (MAP)", yscale="log",
               title=f"{cond} scenes, tier high ({len(rs)} scenes)")
        ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.yaxis.set_minor_formatter(matplotlib.ticker.ScalarFormatter())
        ax.grid(alpha=0.3, which="both")
    fig.legend(*axes[0][0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path = out / "advice_policy.png"
    fig.savefig(path, dpi=120)
    return path


def report_estimates(out: Path) -> str | None:
    """CPU seconds per estimate in each study's records, with the share converged."""
    rows = []
    for study in ("predict", "own", "policy"):
        path = out / f"{study}.jsonl"
        costs = [c for r in _read(path) for c in r.get("estimates", [])] if path.is_file() else []
        if costs:
            t = np.array([c["cpu_s"] for c in costs])
            rows.append((study, len(t), f"{np.median(t):.2f}", f"{np.percentile(t, 99):.2f}", f"{t.max():.2f}",
                         int(np.sum(t > 5.0)), f"{100 * np.mean([c['converged'] for c in costs]):.1f} %",
                         sum(c.get("overflow_warnings", 0) for c in costs)))
    return ("Time per estimate (CPU seconds, MAP and posterior)\n\n" + _md(
        ("study", "estimates", "median", "99th percentile", "max", "over 5 s", "converged", "overflow warnings"),
        rows)) if rows else None


def run_report(args) -> None:
    out = Path(args.out)
    if not out.is_dir():
        raise SystemExit(f"{out}: no such folder (run predict, own, timing or policy first)")
    parts = []
    for name, make in (("predict", report_predict), ("own", lambda o: report_predict(o, "own.jsonl")),
                       ("timing", report_timing), ("policy", report_policy)):
        if (out / f"{name}.jsonl").is_file():
            parts.append(make(out))
    if (out / "policy.jsonl").is_file():
        parts.append(f"Figure: {figure_policy(out)}")
    parts += [t for t in (report_estimates(out),) if t]
    text = "\n\n".join(parts)
    (out / "advice_study.md").write_text(text + "\n")
    print(text)


def _sets_arg(text: str) -> tuple[int, ...]:
    try:
        sets = tuple(int(v) for v in text.split(","))
    except ValueError:
        sets = ()
    if not sets or min(sets) < 1:
        raise argparse.ArgumentTypeError(f"expected whole numbers ≥ 1 separated by commas, got {text!r}")
    return sets


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    for name, helptext in (("predict", "predicted against realised gain, by kind"),
                           ("own", "predicted against realised on the model's own scenes (its prior and noise)"),
                           ("timing", "the advice's time per scene with the default settings"),
                           ("policy", "the adaptive policy against the fixed designs"),
                           ("report", "tables and the figure from the records")):
        s = sub.add_parser(name, help=helptext)
        s.add_argument("--out", default="advice_study", help="folder of the records and outputs")
        if name == "report":
            continue
        s.add_argument("--n", type=int, default={"policy": 40, "timing": 20}.get(name, 200),
                       help="scenes (policy: per condition)")
        s.add_argument("--seed", type=int, default=0, help="base seed")
        s.add_argument("--min-ess", type=float, default=400.0,
                       help="bulk ESS each estimate runs to (default: %(default)s)")
        s.add_argument("--focal-prior", metavar="MEDIAN,LOG_SD",
                       help="every scene states a log-normal focal-length prior (median in pixels, log-sd), e.g. "
                            "1650,0.27 to match the simulator's cameras; default: the package's default prior")
        s.add_argument("--line-reading", choices=LINE_READINGS, default="marginal",
                       help="how the metrology model reads reference segments (default: %(default)s)")
        if name in ("predict", "timing", "policy"):
            s.add_argument("--cameras", choices=CAMERA_POPULATIONS, default="setting",
                           help="the simulator's cameras: each setting's ranges (setting) or real ones, phones to "
                                "street cameras (real; bench/simulate.py's REAL_CAMERAS)")
        if name in ("predict", "timing"):
            s.add_argument("--objects", type=int, default=1, help="targets per scene (default: %(default)s)")
            s.add_argument("--setting", choices=("indoor", "outdoor", "street"), default=None,
                           help="the simulator's setting (default: indoor and outdoor)")
        if name in ("predict", "timing", "policy"):
            s.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                           help="a metrology model option for every estimate and advice, as creference estimate "
                                "--option has it (repeatable), e.g. ref_dof=30 for a crowd without heavy tails")
        if name == "predict":
            s.add_argument("--tiers", default="medium,high",
                           help="noise tiers or crowds (bench/simulate.py's TIERS, CROWDS), cycled (default: %(default)s)")
            s.add_argument("--distance-range", default=None, metavar="setting|LOW,HIGH",
                           help="what if every estimate knew where the targets stand (creference estimate "
                                "--distance-range): the simulator's range of each scene's setting, or LOW,HIGH m")
            s.add_argument("--dataset", choices=("none", "auto"), default="none",
                           help="auto: the base scenes as one data set through creference batch's data-set layer "
                                "(what the frames share, learnt from a first pass and handed to each from the "
                                "others); every estimate of a scene takes its priors (default: %(default)s, each "
                                "scene alone)")
            s.add_argument("--declare-setting", action="store_true",
                           help="each scene names its setting (indoor, outdoor, street): with --dataset auto the "
                                "distance population is one per setting")
            s.add_argument("--reference-px", type=float, default=None, metavar="PX",
                           help="what if the simulated crowd drew reference segments with this endpoint noise "
                                "(px; 0: exact segments) instead of its tier's")
        if name == "own":
            s.add_argument("--sets", default="1,2,3,5", type=_sets_arg,
                           help="the starting point's numbers of sets, one drawn per scene (default: %(default)s)")
        if name == "policy":
            s.add_argument("--rank-by", choices=("location", "hdi"), default="location",
                           help="the advice's objective the policy follows: the annotation with the largest "
                                "expected drop of the location's sd (location) or narrowing of the distance's HDI "
                                "(hdi) per second (default: %(default)s)")
    args = p.parse_args(argv)
    global _FOCAL_PRIOR, _CAMERAS
    _CAMERAS = getattr(args, "cameras", "setting")
    _MODEL_OPTIONS.clear()
    _ESTIMATE_KW.clear()
    _WHAT_IF.clear()
    _DATASET.clear()
    if getattr(args, "distance_range", None):
        if args.distance_range == "setting":
            _WHAT_IF["distance_range"] = "setting"
        else:
            from creference_bayes.cli.estimate import distance_range_arg

            try:
                _WHAT_IF["distance_range"] = list(distance_range_arg(args.distance_range))
            except argparse.ArgumentTypeError as exc:
                p.error(f"--distance-range: setting, or {exc}")
    if getattr(args, "dataset", "none") != "none":
        if _WHAT_IF.get("distance_range"):
            p.error("--dataset auto: the data set learns where the targets stand; drop --distance-range")
        _WHAT_IF["dataset"] = args.dataset
    if getattr(args, "declare_setting", False):
        _WHAT_IF["declare_setting"] = True
    if getattr(args, "reference_px", None) is not None:
        if not args.reference_px >= 0:
            p.error(f"--reference-px: expected a number of pixels >= 0, got {args.reference_px!r}")
        _WHAT_IF["reference_px"] = args.reference_px
    if getattr(args, "line_reading", "marginal") != "marginal":
        _MODEL_OPTIONS["line_reading"] = args.line_reading
    if getattr(args, "option", None):
        from creference_bayes.pipeline import parse_model_options

        try:
            options = parse_model_options("metrology", args.option)
        except ValueError as exc:
            p.error(str(exc))
        if "line_reading" in options:
            p.error("--option line_reading: use --line-reading")
        _MODEL_OPTIONS.update(options)
    if getattr(args, "focal_prior", None):
        if args.command == "own":
            p.error("--focal-prior: the own-model check draws its cameras from the default prior, which its "
                    f"estimates use; got {args.focal_prior!r}")
        try:
            median, log_sd = (float(v) for v in args.focal_prior.split(","))
            _FOCAL_PRIOR = FocalPrior(median, log_sd, np.inf, source="scene")
        except ValueError as e:
            p.error(f"--focal-prior: expected MEDIAN,LOG_SD (two positive numbers), got {args.focal_prior!r} ({e})")
    {"predict": run_predict, "own": run_own, "timing": run_timing, "policy": run_policy,
     "report": run_report}[args.command](args)


if __name__ == "__main__":
    main()
