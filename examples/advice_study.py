"""Is the advice worth following? Two experiments on simulated scenes (docs/advice.md, "Checks").

``predict``: predicted against realised. On each scene a random starting point (1, 2, 3 or 5
sets of target dimension lines, 0–4 references) is estimated and advised on; then each kind of
annotation is added as the simulator makes it and the scene is estimated again. Kinds:

- ``target``: the simulator's next set of dimension lines;
- ``new-ref``: the simulator's next reference (a new object; the advice is given its segment and
  whether it is a value or a range, not the value);
- ``repeat-ref``: one more reference on the scene's first referenced object, drawn by a second
  simulated worker with the simulator's noise (the advice's own candidate for that object).

The predicted change of the 90 % HDI width of the distance (advice: now − expected after) is
compared with the realised change (full re-estimate: after − before, both from all draws).

``policy``: an adaptive policy against the paper's fixed designs. From one set of target
dimension lines, the policy repeatedly collects the annotation with the highest expected gain per
second (the advice; candidates: the next target set, a first reference on each of the scene's ten
reference objects, or one more on an object already referenced) until the 90 % HDI of the
distance is at most 10 % of it, nothing is expected to help, or the human time of the 5 + 5
design is spent. The fixed designs: target sets only (1, 2, 5, 10) and 5 sets with k references
(k = 0, 2, 4, 5). Scenes: the paper-like tier (``high``), all settings, and outdoor alone.
``--rank-by location`` makes the policy collect the annotation with the largest expected drop of
the location's posterior sd per second instead (the goal is stated in location error); it needs
its own ``--out`` folder.

``own``: predicted against realised on the model's own scenes: the truth drawn from the model's
prior and every annotation from its noise model, as simulation-based calibration draws them
(creference_bayes/bench/sbc.py, its box as the estimates' bounds); the same starting points and
kinds as ``predict`` (the new reference on a new line, the repeat a second reading of the first
reference's line). There the advice's expectation is the true one: a gap in ``own`` is the
advice's, a gap only in ``predict`` is the model's fit to the simulator's scenes.

``report``: the tables (Markdown, printed and written) and the figure (median location error
against human seconds, one line per policy) from the records.

Records are appended to ``OUT/predict.jsonl``, ``OUT/own.jsonl`` and ``OUT/policy.jsonl`` one scene at a time, so a
run can be stopped and resumed (scenes already recorded are skipped).

Usage::

    python examples/advice_study.py predict --n 200 --out advice_study
    python examples/advice_study.py own --n 300 --out advice_study
    python examples/advice_study.py timing --n 20 --out advice_study
    python examples/advice_study.py policy --n 40 --out advice_study
    python examples/advice_study.py report --out advice_study
    python examples/advice_study.py policy --n 40 --rank-by location --out advice_location
    python examples/advice_study.py predict --n 200 --focal-prior 1650,0.27 --out advice_matched
    python examples/advice_study.py predict --n 200 --line-reading corrected --out advice_corrected

``--focal-prior MEDIAN,LOG_SD`` has every scene state a log-normal focal-length prior (1650,0.27
fits the simulator's cameras, 1000–2600 px); without it the package's default prior is used, as
for a photo with nothing known about its camera. ``--line-reading corrected`` has the estimates
and the advice read reference segments less the lengthening their line noise brings (the
metrology model's option ``line_reading``; default ``linear``); ``--ref-scale S`` fixes the crowd's
error scale (the option ``ref_scale``; the paper-like tier's workers have 0.75) instead of
integrating it out. Each record says which.

These runs take tens of minutes (predict) to hours (policy) of CPU: run them under the shared lock (``flock /work/bench.lock ...``).
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

from creference_bayes.bench.runner import variant
from creference_bayes.bench.simulate import (RANGE_PRECISION, TIERS, measurement_factor,
                                             simulate_scene)
from creference_bayes.core.metrics import location_percentage_error
from creference_bayes.core.units import UNITS_TO_M
from creference_bayes.inference.summary import draws_from_inference_data
from creference_bayes.io.scene import Reference, SceneWarning, parse_scene
from creference_bayes.models.camera_terms import FocalPrior
from creference_bayes.models.params import PARAM_NAMES
from creference_bayes.pipeline import estimate
from creference_bayes.workflows.advice import AdviceSettings, advise_posterior
from creference_bayes.workflows.advice.candidates import Candidate, FormatMix, candidates, format_mix

N_TARGET_POOL, N_REF_POOL = 13, 10
TARGET_S, REF_S = 183.5, 64.4
FIVE_PLUS_FIVE_S = 5 * TARGET_S + 5 * REF_S
HALF_S = FIVE_PLUS_FIVE_S / 2
TARGET_SHARE = 0.10
FIXED = {"target x1": (1, 0), "target x2": (2, 0), "target x5": (5, 0), "target x10": (10, 0),
         "5 + 2 refs": (5, 2), "5 + 4 refs": (5, 4), "5 + 5 refs": (5, 5)}


# ------------------------------------------------------------------------------------------------
# scenes and annotations as the simulator makes them


#: The focal-length prior every simulated scene states (``--focal-prior``); None: the default.
_FOCAL_PRIOR: FocalPrior | None = None
#: Metrology model settings of every estimate and advice (``--line-reading``, ``--ref-scale``);
#: empty: the defaults.
_MODEL_OPTIONS: dict = {}
#: Further settings of every estimate (``own``: the box of the model's own scenes as the bounds).
_ESTIMATE_KW: dict = {}


def _scene(seed: int, k: int, tier: str, setting: str | None):
    d = simulate_scene(np.random.default_rng([seed, k]), tier=tier, setting=setting,
                       n_target_annotations=N_TARGET_POOL, n_references=N_REF_POOL, format_offset=k)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = parse_scene(d)
    # stated by the scene, the prior reaches the estimates and the advice alike
    return scene if _FOCAL_PRIOR is None else dataclasses.replace(scene, focal_prior=_FOCAL_PRIOR)


def _second_worker(pool, j: int, index: int, rng):
    """One more reference on the object of the pool's reference ``j``, by a new simulated worker:
    the true segment with the tier's endpoint noise, the true length times the tier's measurement
    error, stated in reference j's format and unit (as bench/simulate.py does)."""
    gt = pool.ground_truth.extra
    tier = TIERS[gt["tier"]]
    ref = pool.references[j]
    true_line = np.asarray(gt["reference_lines_px"][j], float)
    line = true_line + rng.normal(0.0, tier.reference_px, (2, 2))
    line[:, 0] = np.clip(line[:, 0], 0, pool.image_width)
    line[:, 1] = np.clip(line[:, 1], 0, pool.image_height)
    stated = gt["reference_lengths_m"][j] * measurement_factor(rng, tier.measurement)
    t = pool.target
    scale = UNITS_TO_M[ref.unit] if ref.mode == "direct" else (t.length if ref.measure == "length" else t.width)
    value = stated / scale
    if ref.is_range:
        p = min(float(np.exp(rng.normal(math.log(RANGE_PRECISION["median"]), RANGE_PRECISION["log_sd"]))), 1.9)
        low, high = float(f"{value * (1 - p / 2):.4g}"), float(f"{value * (1 + p / 2):.4g}")
    else:
        low = high = float(f"{value:.4g}")
    factor = UNITS_TO_M[ref.unit] if ref.mode == "direct" else 1.0  # relative values stay ratios
    return Reference(index=index, measure=ref.measure, mode=ref.mode, low=low * factor, high=high * factor,
                     line=np.round(line, 2), is_range=ref.is_range, unit=ref.unit, object=ref.object,
                     worker=f"second-{j}", seconds=REF_S, stated=(low, high))


#: Every estimate's CPU seconds, convergence and overflow warnings since the last record was
#: written (each record carries its own: the issue's bound of 5 s per estimate, checked in the report).
_COSTS: list[dict] = []


def _costs() -> list[dict]:
    out = list(_COSTS)
    _COSTS.clear()
    return out


def _with_refs(scene, refs):
    refs = tuple(dataclasses.replace(r, index=i) for i, r in enumerate(refs))
    return dataclasses.replace(scene, references=refs)


def _estimate(scene, seed, min_ess):
    t0 = time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = estimate(scene, seed=seed, sampling={"min_ess": min_ess}, **_MODEL_OPTIONS, **_ESTIMATE_KW)
    cost = {"cpu_s": time.process_time() - t0, "converged": bool(r.diagnostics.converged),
            "overflow_warnings": sum("overflow" in str(w.message) for w in caught)}
    _COSTS.append(cost)
    if r.inference_data is None:
        return None
    post = draws_from_inference_data(r.inference_data)
    draws = np.column_stack([np.asarray(post[k], float).ravel() for k in PARAM_NAMES])
    gt = scene.ground_truth
    true_d = float(np.hypot(gt.location_m[0], gt.location_m[2]))
    lo, hi = r.posterior.hdi["distance_m"]
    return {"result": r, "draws": draws, "width": hi - lo, "median": r.posterior.median["distance_m"],
            "share": (hi - lo) / r.posterior.median["distance_m"], "covered": bool(lo <= true_d <= hi),
            "error": float(location_percentage_error(r.map.params[:3], gt.location_m)),
            "post_error": r.evaluation.posterior_location_pct_error}


def _reweighted(base, est, scene, kind, n_draws=2000):
    """HDI width of the distance (m) of the base draws, evenly thinned, as they are and reweighted
    by the annotation that was actually added (the advice's update, given the realised value, with
    its correction of the weighted HDI's small-sample narrowing and its fallback): set against
    the re-estimate, it checks the update apart from the predictive distribution."""
    from creference_bayes.camera_setup import setup_camera
    from creference_bayes.workflows.advice.observe import ModelContext, ReferenceObservation, TargetObservation
    from creference_bayes.workflows.advice.update import (MIN_ESS, MIN_ESS_FRACTION, normalise, shuffled_hdi,
                                                          tempered_update, weighted_hdi)

    r = est["result"]
    ctx = ModelContext(base, setup_camera(base), r.map.handedness, r.map.params, options=_model_options())
    keep = np.unique(np.linspace(0, len(est["draws"]) - 1, n_draws).round().astype(int))
    draws = ctx.model.expand(est["draws"][keep][:, ctx.model.free])
    if kind == "target":
        obs = TargetObservation(ctx)
        obs.corners = scene.target.dimension_lines[-1].corners[None]
    else:
        ref = scene.references[-1]
        obs = ReferenceObservation(ctx, ref.line, measure=ref.measure, object=ref.object)
        low, high = ref.length_bounds_m(scene.target)
        obs.log_low, obs.log_high, obs.is_range = np.log([low]), np.log([high]), np.array([ref.is_range])
        if not obs.usable:
            return None, None
    w, ess = normalise(obs.log_ratio(draws))
    dist = np.hypot(draws[:, 0], draws[:, 2])
    now, _ = weighted_hdi(dist, np.full((1, len(dist)), 1.0 / len(dist)), 0.9)
    fallback = ess[0] < max(MIN_ESS, MIN_ESS_FRACTION * len(draws))  # the advice's threshold
    if fallback:  # as the advice does: the tempered update
        from creference_bayes.inference.posterior import LogPosterior

        new = ctx.model_of(scene)
        moved, _ = tempered_update(LogPosterior(ctx.model), LogPosterior(new), draws[:, ctx.model.free],
                                   np.random.default_rng(0))
        full = new.expand(moved)
        dist, w = np.hypot(full[:, 0], full[:, 2]), np.full((1, len(full)), 1.0 / len(full))
    after, _ = weighted_hdi(dist, w, 0.9)
    if not fallback:  # as the advice does: the small-sample narrowing out
        after = after * now / shuffled_hdi(dist, w, 0.9, np.random.default_rng(0))[0]
    return float(now[0]), float(after[0])


def _advise(scene, est, seed, cands, mixes=None, settings=None):
    r = est["result"]
    return advise_posterior(scene, est["draws"], handedness=r.map.handedness, map_params=r.map.params,
                            seed=seed, candidates=cands, mixes=mixes, settings=settings, model_options=_model_options())


def _model_options() -> dict:
    """The model settings the advice rebuilds its models with: the estimates' (and their bounds)."""
    return {**_MODEL_OPTIONS, **({"bounds": _ESTIMATE_KW["bounds"]} if "bounds" in _ESTIMATE_KW else {})}


def _done(path: Path) -> set:
    """Scenes already recorded in ``path``; a folder of records made with another focal prior,
    line reading or crowd scale is refused (a resumed run must not mix them)."""
    if not path.is_file():
        return set()
    recs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    mine = None if _FOCAL_PRIOR is None else _FOCAL_PRIOR.to_dict()
    reading = _MODEL_OPTIONS.get("line_reading", "linear")
    for r in recs:
        if r.get("focal_prior") != mine:
            sys.exit(f"advice_study.py: {path} holds records made with focal prior {r.get('focal_prior')}, "
                     f"this run has {mine}: use another --out")
        if r.get("line_reading", "linear") != reading:
            sys.exit(f"advice_study.py: {path} holds records made with line reading {r.get('line_reading', 'linear')!r}, "
                     f"this run has {reading!r}: use another --out")
        if r.get("ref_scale") != _MODEL_OPTIONS.get("ref_scale"):
            sys.exit(f"advice_study.py: {path} holds records made with crowd scale {r.get('ref_scale')!r}, "
                     f"this run has {_MODEL_OPTIONS.get('ref_scale')!r}: use another --out")
    return {r["scene"] for r in recs}


def _append(path: Path, record: dict) -> None:
    record = {**record, "focal_prior": None if _FOCAL_PRIOR is None else _FOCAL_PRIOR.to_dict(),
              "line_reading": _MODEL_OPTIONS.get("line_reading", "linear"),
              "ref_scale": _MODEL_OPTIONS.get("ref_scale")}
    with path.open("a") as f:
        f.write(json.dumps(record) + "\n")


def _bar(total, desc):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, disable=not sys.stderr.isatty())


# ------------------------------------------------------------------------------------------------
# predicted against realised


def _predict_case(seed: int, k: int, tiers: list[str]):
    """Scene k of the predict experiment: its pool, starting point and the annotations added."""
    tier = tiers[k % len(tiers)]
    pool = _scene(seed, k, tier, None)
    rng = np.random.default_rng([seed, k, 1])
    n_t, n_r = int(rng.choice([1, 2, 3, 5])), int(rng.integers(0, 5))
    base = variant(pool, n_t, range(n_r))
    nxt = pool.references[n_r]
    cands = [c for c in candidates(base) if c.kind == "target"]
    cands.append(Candidate("new-ref", "reference", nxt.measure, nxt.object, np.asarray(nxt.line), (), REF_S))
    mixes = {"new-ref": FormatMix(float(nxt.is_range), format_mix(base).range_precision, 0.0)}
    repeat = [c for c in candidates(base) if c.kind == "reference" and not c.new_segment][:1]
    cands += [dataclasses.replace(c, key="repeat-ref") for c in repeat]
    added = {"target": dataclasses.replace(base, target=dataclasses.replace(
                 base.target, dimension_lines=pool.target.dimension_lines[:n_t + 1])),
             "new-ref": _with_refs(base, base.references + (nxt,))}
    if repeat:
        j = repeat[0].based_on[0]
        added["repeat-ref"] = _with_refs(base, base.references + (
            _second_worker(pool, j, n_r, np.random.default_rng([seed, k, 4])),))
    return {"tier": tier, "setting": pool.ground_truth.extra["setting"], "pool": pool, "n_t": n_t, "n_r": n_r,
            "base": base, "cands": cands, "mixes": mixes, "added": added}


def run_predict(args, case_of=None, file: str = "predict.jsonl") -> None:
    """The predict experiment; ``case_of(seed, k)`` makes scene k (default: :func:`_predict_case`
    with ``--tiers``), its records go to ``OUT/file``."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / file
    done = _done(path)
    if case_of is None:
        tiers = args.tiers.split(",")

        def case_of(seed, k):
            return _predict_case(seed, k, tiers)
    with _bar(args.n, file.split(".")[0]) as bar:
        for k in range(args.n):
            bar.update(1)
            name = f"s{k:04d}"
            if name in done:
                continue
            case = case_of(args.seed, k)
            base = case["base"]
            _costs()
            t0 = time.perf_counter()
            before = _estimate(base, [args.seed, k, 2], args.min_ess)
            if before is None:
                continue
            advice = _advise(base, before, [args.seed, k, 3], case["cands"], case["mixes"])
            t_adv = time.perf_counter() - t0
            preds = {p.candidate.key: p for p in advice.predictions}
            rows = []
            for kind, scene in case["added"].items():
                if kind not in preds:
                    continue
                after = _estimate(scene, [args.seed, k, 5], args.min_ess)
                if after is None:
                    continue
                p = preds[kind]
                rew_now, rew_after = _reweighted(base, before, scene, kind)
                rows.append({"kind": kind, "measure": p.candidate.measure,
                             "rew_now_m": rew_now, "rew_after_m": rew_after,
                             "pred_now_m": advice.now.hdi_width_m, "pred_after_m": p.expected.hdi_width_m,
                             "pred_now_share": advice.now.hdi_share, "pred_after_share": p.expected.hdi_share,
                             "pred_gain_pct": p.gain_pct, "pred_gain_se_pct": p.gain_se_pct,
                             "real_before_m": before["width"], "real_after_m": after["width"],
                             "real_before_share": before["share"], "real_after_share": after["share"],
                             "ess": p.ess_median, "fallbacks": p.fallbacks})
            gt = base.ground_truth
            loc = gt.location_m
            dist = np.hypot(before["draws"][:, 0], before["draws"][:, 2])
            true_hand = gt.extra.get("handedness")
            kept = None if true_hand is None else bool(before["result"].map.handedness == true_hand)
            yaw_off = np.angle(np.exp(1j * (before["draws"][:, 3] - gt.yaw_rad)))  # draw − truth, on the circle
            _append(path, {"scene": name, "tier": case["tier"], "setting": case["setting"],
                           "truth_quantile": float(np.mean(dist < np.hypot(loc[0], loc[2]))),
                           "handedness_kept_true": kept, "yaw_quantile": float(np.mean(yaw_off < 0)),
                           "n_target": case["n_t"], "n_refs": case["n_r"], "estimate_and_advice_s": t_adv,
                           "advice_only_s": advice.seconds, "n_candidates": len(advice.predictions),
                           "rows": rows, "estimates": _costs()})


OWN_SETS = (1, 2, 3, 5)


def _own_setting(sets) -> str:
    """The records' ``setting`` of an own-model run: "own", or which starting sets it drew from."""
    return "own" if tuple(sets) == OWN_SETS else "own, sets " + ",".join(map(str, sets))


def _own_case(seed: int, k: int, sets: tuple[int, ...] = OWN_SETS):
    """Scene k of the own-model check: the truth drawn from the model's prior (within the box of
    simulation-based calibration), the annotations from its noise model (creference_bayes.bench.sbc),
    a starting point of ``sets`` sets (one of them, uniformly) and 0–4 references, and the
    annotations added: the next set, a reference on a new segment, a second worker's reference on the first one (the same true
    line, drawn again with the line noise, its length stated again with the crowd's error)."""
    from creference_bayes.bench.sbc import draw_truth, sbc_reference, simulate_sbc_scene

    rng = np.random.default_rng([seed, k, 11])
    n_t, n_r = int(rng.choice(list(sets))), int(rng.integers(0, 5))
    def second_reading(truth, d):  # another worker on the first reference's true line, or None
        gt = d["ground_truth"]
        for _ in range(200):
            ref = sbc_reference(rng, truth, gt["reference_lines_true_px"][0], gt["crowd_scale"], "second-0",
                                object=d["references"][0]["object"])
            if ref is not None:
                return ref
        return None

    d = repeat = None
    while d is None or (n_r and repeat is None):  # outside the image: a new scene (a selection on the data)
        truth = draw_truth(rng)
        d = simulate_sbc_scene(rng, truth, n_t + 1, n_r + 1)
        repeat = second_reading(truth, d) if d is not None and n_r else None
    lines, refs = d["target"]["dimension_lines"], d["references"]

    def scene_of(n_lines, references):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            return parse_scene({**d, "target": {**d["target"], "dimension_lines": lines[:n_lines]},
                                "references": references})

    base = scene_of(n_t, refs[:n_r])
    added = {"target": scene_of(n_t + 1, refs[:n_r]), "new-ref": scene_of(n_t, refs[:n_r + 1])}
    nxt = added["new-ref"].references[n_r]
    cands = [c for c in candidates(base) if c.kind == "target"]
    cands.append(Candidate("new-ref", "reference", nxt.measure, nxt.object, np.asarray(nxt.line), (), REF_S))
    mixes = {"new-ref": FormatMix(0.0, format_mix(base).range_precision, 0.0)}
    if repeat is not None:
        rep = [c for c in candidates(base) if c.kind == "reference" and not c.new_segment and 0 in c.based_on][:1]
        cands += [dataclasses.replace(c, key="repeat-ref") for c in rep]
        added["repeat-ref"] = scene_of(n_t, refs[:n_r] + [repeat])
    return {"tier": "own", "setting": _own_setting(sets), "n_t": n_t, "n_r": n_r, "base": base, "cands": cands,
            "mixes": mixes, "added": added}


def run_own(args) -> None:
    """Predicted against realised on the model's own scenes: where the scenes follow the model's
    prior and noise model, the mean realised narrowing equals the mean predicted one (the advice
    is an expectation under that posterior), in every band of the width before; a gap here is
    the advice's, a gap only in ``predict`` is the model's fit to the simulator's scenes."""
    from creference_bayes.bench.sbc import SBC_BOX

    _ESTIMATE_KW.update(bounds=SBC_BOX.bounds(), focal_prior="default", location_prior="log-depth")
    sets, path = args.sets, Path(args.out) / "own.jsonl"
    other = {json.loads(x).get("setting") for x in path.read_text().splitlines() if x.strip()} \
        if path.is_file() else set()
    if other - {_own_setting(sets)}:
        sys.exit(f"advice_study.py: {path} holds records of {sorted(other)}, this run's --sets "
                 f"{','.join(map(str, sets))} makes {_own_setting(sets)!r}: use another --out")
    run_predict(args, case_of=lambda seed, k: _own_case(seed, k, sets), file="own.jsonl")


def run_reweight(args) -> None:
    """For recorded predict scenes without them: the base draws reweighted by the annotation
    actually added (the base estimate is rerun with its seed, which gives the same draws)."""
    out = Path(args.out)
    recs = [json.loads(x) for x in (out / "predict.jsonl").read_text().splitlines() if x.strip()]
    path = out / "reweight.jsonl"
    done = _done(path)
    todo = [r for r in recs if r["scene"] not in done and r["rows"] and "rew_now_m" not in r["rows"][0]]
    tiers = args.tiers.split(",")
    with _bar(len(todo), "reweight") as bar:
        for r in todo[:args.n]:
            bar.update(1)
            k = int(r["scene"][1:])
            case = _predict_case(args.seed, k, tiers)
            before = _estimate(case["base"], [args.seed, k, 2], args.min_ess)
            if abs(before["width"] - r["rows"][0]["real_before_m"]) > 1e-9 * max(1.0, before["width"]):
                print(f"{r['scene']}: the rerun base estimate differs from the record; skipped", file=sys.stderr)
                continue
            rows = {}
            for kind, scene in case["added"].items():
                if any(x["kind"] == kind for x in r["rows"]):
                    rows[kind] = _reweighted(case["base"], before, scene, kind)
            loc = case["base"].ground_truth.location_m
            dist = np.hypot(before["draws"][:, 0], before["draws"][:, 2])
            # where the truth falls in the base posterior of the distance (calibration: uniform)
            _append(path, {"scene": r["scene"], "rows": rows,
                           "truth_quantile": float(np.mean(dist < np.hypot(loc[0], loc[2])))})


# ------------------------------------------------------------------------------------------------
# the adaptive policy and the fixed designs


def _policy_candidates(pool, scene, used_targets, used_objects):
    """The next target set, a first reference on each unused pool object, one more on each used one."""
    cands = []
    if used_targets < N_TARGET_POOL:
        cands.append(Candidate("target", "target", None, None, None, (), TARGET_S))
    for j, ref in enumerate(pool.references):
        if j in used_objects:
            lines = [np.asarray(r.line) for r in scene.references if r.worker in (ref.worker, f"second-{j}")]
            cands.append(Candidate(f"more-{j}", "reference", ref.measure, ref.object,
                                   np.median(np.stack(lines), axis=0), (j,), REF_S))
        else:
            cands.append(Candidate(f"first-{j}", "reference", ref.measure, ref.object, np.asarray(ref.line),
                                   (j,), REF_S))
    return cands


def _pick(advice, rank_by: str):
    """The annotation to collect: the advice's best (expected HDI narrowing per second), or with
    ``rank_by="location"`` the largest expected drop of the location's posterior sd per second."""
    if rank_by == "hdi":
        return advice.best.candidate
    now = advice.now.location_sd_m
    return max(advice.predictions, key=lambda p: (now - p.expected.location_sd_m) / p.candidate.seconds).candidate


def run_adaptive(pool, seed, k, min_ess, settings, rank_by="hdi"):
    scene = variant(pool, 1, ())
    used_targets, used_objects, spent, steps = 1, set(), TARGET_S, []
    rng = np.random.default_rng([seed, k, 7])
    mix = FormatMix(0.5, RANGE_PRECISION["median"], 0.5)  # the simulator's ten formats, half ranges
    while True:
        est = _estimate(scene, [seed, k, 8, len(steps)], min_ess)
        if est is None:
            return None
        steps.append({"seconds": spent, "error": est["error"], "share": est["share"],
                      "covered": est["covered"], "post_error": est["post_error"]})
        if est["share"] <= TARGET_SHARE or spent + REF_S > FIVE_PLUS_FIVE_S:
            break
        cands = [c for c in _policy_candidates(pool, scene, used_targets, used_objects)
                 if spent + c.seconds <= FIVE_PLUS_FIVE_S]
        ref_mix = format_mix(scene) if scene.references else mix
        advice = _advise(scene, est, [seed, k, 9, len(steps)], cands,
                         mixes={c.key: ref_mix for c in cands}, settings=settings)
        if not advice.predictions:
            break
        steps[-1]["gains"] = {p.candidate.key: round(p.gain_per_minute, 4) for p in advice.predictions}
        best = _pick(advice, rank_by)
        steps[-1]["chosen"] = best.key
        if best.kind == "target":
            scene = dataclasses.replace(scene, target=dataclasses.replace(
                scene.target, dimension_lines=pool.target.dimension_lines[:used_targets + 1]))
            used_targets += 1
        else:
            j = best.based_on[0]
            new = pool.references[j] if j not in used_objects else _second_worker(pool, j, 0, rng)
            used_objects.add(j)
            scene = _with_refs(scene, scene.references + (new,))
        spent += best.seconds
    last = steps[-1]
    return {"seconds": last["seconds"], "error": last["error"], "post_error": last["post_error"],
            "covered": last["covered"], "share": last["share"], "steps": steps,
            "n_target": used_targets, "n_refs": len(scene.references)}


def run_policy(args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "policy.jsonl"
    done = _done(path)
    settings = AdviceSettings(min_gain=0.0)
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
            rec = {"scene": name, "condition": cond, "setting": pool.ground_truth.extra["setting"], "fixed": {}}
            _costs()
            for label, (n_t, n_r) in FIXED.items():
                est = _estimate(variant(pool, n_t, range(n_r)), [args.seed, k, 6, n_t, n_r], args.min_ess)
                if est is not None:
                    rec["fixed"][label] = {"seconds": n_t * TARGET_S + n_r * REF_S, "error": est["error"],
                                           "post_error": est["post_error"], "covered": est["covered"],
                                           "share": est["share"]}
            rec["adaptive"] = run_adaptive(pool, args.seed, k + (1000 if cond == "outdoor" else 0),
                                           args.min_ess, settings, args.rank_by)
            rec["rank_by"] = args.rank_by
            rec["estimates"] = _costs()
            _append(path, rec)


# ------------------------------------------------------------------------------------------------
# time per object


def run_timing(args) -> None:
    """The advice's own time per object with the default settings and every candidate the scene
    allows, on scenes as the paper designs them (5 sets of dimension lines, 5 references), from
    the estimate's draws (a scene given to ``creference advise``) and from the 400 draws a result
    file keeps (a result or a batch folder)."""
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
            pool = _scene(args.seed + 2000, k, "high" if k % 2 else "medium", None)
            scene = variant(pool, 5, range(5))
            est = _estimate(scene, [args.seed, k, 10], args.min_ess)
            a = _advise(scene, est, [args.seed, k, 11], None)
            t0 = time.perf_counter()
            b = advise_result(est["result"].to_dict(), scene, seed=[args.seed, k, 12])
            t_result = time.perf_counter() - t0
            _append(path, {"scene": name, "setting": pool.ground_truth.extra["setting"],
                           "n_candidates": len(a.predictions), "scene_s": a.seconds, "result_s": t_result,
                           "result_advice_s": b.seconds, "action": a.action, "best": a.best.candidate.kind
                           if a.best else None})


def report_timing(out: Path) -> str:
    recs = [json.loads(x) for x in (out / "timing.jsonl").read_text().splitlines() if x.strip()]
    rows = []
    for key, label in (("scene_s", "from the estimate's draws (600 used)"),
                       ("result_s", "from a result file (400 draws; with rebuilding its models)")):
        t = np.array([r[key] for r in recs])
        rows.append((label, len(t), f"{np.median(t):.2f}", f"{t.mean():.2f}", f"{np.percentile(t, 90):.2f}",
                     f"{t.max():.2f}"))
    n = np.array([r["n_candidates"] for r in recs])
    return ("Time per object of the advice alone (seconds; 5 target sets + 5 references, every candidate "
            f"the scene allows: {n.mean():.1f} on average, {n.min()}–{n.max()})\n\n"
            + _md(("input", "objects", "median", "mean", "90th percentile", "max"), rows) + "\n")


# ------------------------------------------------------------------------------------------------
# tables and figure


def _md(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _boot_ratio(num, den, rng, n=2000):
    num, den = np.asarray(num), np.asarray(den)
    idx = rng.integers(len(num), size=(n, len(num)))
    r = num[idx].mean(axis=1) / den[idx].mean(axis=1)
    return np.percentile(r, [5, 95])


def report_predict(out: Path, file: str = "predict.jsonl") -> str:
    recs = [json.loads(x) for x in (out / file).read_text().splitlines() if x.strip()]
    if file == "predict.jsonl" and (out / "reweight.jsonl").is_file():
        extra = {}
        for x in (out / "reweight.jsonl").read_text().splitlines():
            if x.strip():
                d = json.loads(x)
                extra[d["scene"]] = d["rows"]
        for r in recs:
            for row in r["rows"]:
                if "rew_now_m" not in row and row["kind"] in extra.get(r["scene"], {}):
                    row["rew_now_m"], row["rew_after_m"] = extra[r["scene"]][row["kind"]]
    rows_by = {}
    for r in recs:
        for row in r["rows"]:
            rows_by.setdefault(row["kind"], []).append(row)
            if row["kind"] != "target":
                rows_by.setdefault(f"{row['kind']} ({row['measure']})", []).append(row)
    rng = np.random.default_rng(0)
    table = []
    for kind in sorted(rows_by, key=lambda s: (s.split(" ")[0] != "target", s)):
        rows = rows_by[kind]
        # the change as a share of the current width: each scene counts the same, near or far
        pred = np.array([(x["pred_now_m"] - x["pred_after_m"]) / x["pred_now_m"] for x in rows])
        real = np.array([(x["real_before_m"] - x["real_after_m"]) / x["real_before_m"] for x in rows])
        pm = np.array([x["pred_now_m"] - x["pred_after_m"] for x in rows])
        rm = np.array([x["real_before_m"] - x["real_after_m"] for x in rows])
        lo, hi = _boot_ratio(real, pred, rng)
        table.append((kind, len(rows), f"{100 * pred.mean():.2f} %", f"{100 * real.mean():.2f} %",
                      f"{real.mean() / pred.mean():.2f} [{lo:.2f}, {hi:.2f}]",
                      f"{pm.mean():.3f}", f"{rm.mean():.3f}", f"{np.median([x['ess'] for x in rows]):.2f}",
                      sum(x["fallbacks"] > 0 for x in rows)))
    def points(rows):  # n, predicted and realised points, their ratio [90 % bootstrap]
        ps = np.array([x["pred_now_share"] - x["pred_after_share"] for x in rows])
        rs = np.array([x["real_before_share"] - x["real_after_share"] for x in rows])
        lo, hi = _boot_ratio(rs, ps, rng)
        return (len(rows), f"{100 * ps.mean():.2f}", f"{100 * rs.mean():.2f}",
                f"{rs.mean() / ps.mean():.2f} [{lo:.2f}, {hi:.2f}]")

    bands = []
    for lo_b, hi_b, label in ((0.0, 0.25, "< 25 %"), (0.25, 0.5, "25–50 %"), (0.5, 1.0, "50–100 %"),
                              (1.0, np.inf, ">= 100 %"), (0.0, np.inf, "all")):
        for kind in ("target", "new-ref", "repeat-ref"):
            rows = [x for x in rows_by.get(kind, []) if lo_b <= x["real_before_share"] < hi_b]
            if len(rows) >= 3:
                bands.append((label, kind, *points(rows)))
    by_sets = []
    for label, sel in (("one set", lambda n: n == 1), ("two", lambda n: n == 2), ("three or more", lambda n: n >= 3)):
        rows = [x for r in recs if sel(r["n_target"]) for x in r["rows"] if x["kind"] == "target"]
        if len(rows) >= 3:
            by_sets.append((label, *points(rows)))
    quant = {r["scene"]: r.get("truth_quantile") for r in recs}
    if file == "predict.jsonl" and (out / "reweight.jsonl").is_file():
        for x in (out / "reweight.jsonl").read_text().splitlines():
            if x.strip():
                d = json.loads(x)
                quant[d["scene"]] = quant.get(d["scene"]) if quant.get(d["scene"]) is not None else d.get("truth_quantile")
    calib = []
    for lo_b, hi_b, label in ((0.0, 0.5, "< 50 %"), (0.5, np.inf, ">= 50 %"), (0.0, np.inf, "all")):
        q = np.array([quant[r["scene"]] for r in recs if r["rows"] and quant.get(r["scene"]) is not None
                      and lo_b <= r["rows"][0]["real_before_share"] < hi_b])
        if len(q):
            calib.append((label, len(q), f"{np.mean(q):.2f}", f"{100 * np.mean(q < 0.5):.0f} %",
                          f"{100 * np.mean((q > 0.05) & (q < 0.95)):.0f} %", f"{100 * np.mean(q < 0.1):.0f} %"))
    check = []
    for kind in ("target", "new-ref", "repeat-ref"):
        rows = [x for x in rows_by.get(kind, []) if x.get("rew_now_m")]
        if not rows:
            continue
        rew = np.array([x["rew_after_m"] / x["rew_now_m"] for x in rows])
        real = np.array([x["real_after_m"] / x["real_before_m"] for x in rows])
        check.append((kind, len(rows), f"{100 * (1 - rew.mean()):.2f} %", f"{100 * (1 - real.mean()):.2f} %",
                      f"{100 * np.median(np.abs(rew - real)):.1f} %", f"{100 * np.percentile(np.abs(rew - real), 90):.1f} %"))
    hand = []
    for label, sel in (("one set", lambda r: r["n_target"] == 1), ("two or more", lambda r: r["n_target"] > 1),
                       ("all", lambda r: True)):
        rs = [r for r in recs if sel(r) and r.get("handedness_kept_true") is not None and "yaw_quantile" in r]
        if not rs:
            continue
        kept = np.array([r["handedness_kept_true"] for r in rs])
        yq = np.array([r["yaw_quantile"] for r in rs])
        inner = (yq > 0.1) & (yq < 0.9)
        hand.append((label, len(rs), f"{100 * kept.mean():.0f} %",
                     f"{100 * inner[kept].mean():.0f} %" if kept.any() else "–",
                     f"{100 * inner[~kept].mean():.0f} %" if (~kept).any() else "–"))
    secs = np.array([r["advice_only_s"] for r in recs])
    ncand = np.array([r["n_candidates"] for r in recs])
    title = ("Predicted against realised" if file == "predict.jsonl" else
             "On the model's own scenes (prior and noise model of simulation-based calibration): predicted against realised")
    text = (f"{title} narrowing of the 90 % HDI of the distance ({len(recs)} scenes; "
            f"narrowing = (width before − width after) / width before, mean over scenes; in metres the "
            f"plain mean of before − after)\n\n"
            + _md(("kind", "n", "predicted", "realised", "realised / predicted [90 % bootstrap]",
                   "predicted m", "realised m", "median ESS share", "with fallbacks"), table)
            + "\n\nThe same as the gain the advice ranks by: points of the distance (HDI width over the "
              "posterior median), predicted (advice: now − expected after) against realised (before − "
              "after), by the width of the posterior before (HDI share)\n\n"
            + _md(("HDI share before", "kind", "n", "predicted pts", "realised pts",
                   "realised / predicted [90 % bootstrap]"), bands)
            + ("\n\nThe target set by the number of sets before it (points of the distance, as above)\n\n"
               + _md(("target sets before", "n", "predicted pts", "realised pts",
                      "realised / predicted [90 % bootstrap]"), by_sets) if by_sets else "")
            + ("\n\nThe update alone: the base draws reweighted by the annotation actually added, "
               "against the full re-estimate with it (narrowing as above; the difference of the "
               "after/before width ratios, per scene)\n\n" + _md(
                   ("kind", "n", "reweighted", "re-estimated", "median |difference|", "90th percentile"), check)
               if check else "")
            + ("\n\nWhere the true distance falls in the posterior before (its quantile; a calibrated "
               "posterior gives a uniform quantile: mean 0.5, half below the median, 90 % in the central "
               "90 %, 10 % in the lowest decile)\n\n" + _md(
                   ("HDI share before", "scenes", "mean quantile", "below the median", "in the central 90 %",
                    "in the lowest decile"), calib) if calib else "")
            + ("\n\nThe handedness the posterior is conditioned on (the MAP's) against the true one, and the "
               "yaw: the share of scenes whose true yaw lies in the central 80 % of the posterior (calibrated: "
               "80 %), with the true handedness kept and with the other\n\n" + _md(
                   ("target sets before", "scenes", "true handedness kept", "yaw in the central 80 %, kept",
                    "yaw in the central 80 %, the other"), hand) if hand else "")
            + f"\n\nTime per object (advice alone, without the estimate): median {np.median(secs):.2f} s, "
              f"mean {secs.mean():.2f} s, 90th percentile {np.percentile(secs, 90):.2f} s, "
              f"{ncand.mean():.1f} candidates on average\n")
    return text


def _summary(entries):
    e = np.array([x["error"] for x in entries])
    return (len(e), f"{np.mean([x['seconds'] for x in entries]):.0f}", f"{np.median(e):.1f}",
            f"{e.mean():.1f}", f"{100 * np.mean([x['covered'] for x in entries]):.0f} %",
            f"{100 * np.mean([x['share'] <= TARGET_SHARE for x in entries]):.0f} %")


def _truncated(adaptive: dict, seconds: float) -> dict:
    """The adaptive run's state at its last estimate within ``seconds`` of human time (a run with
    that budget could have added a cheaper annotation instead of the one that crossed it, so this
    is a conservative stand-in for it)."""
    last = [s for s in adaptive["steps"] if s["seconds"] <= seconds][-1]
    return {k: last[k] for k in ("seconds", "error", "post_error", "covered", "share")}


def report_policy(out: Path) -> str:
    recs = [json.loads(x) for x in (out / "policy.jsonl").read_text().splitlines() if x.strip()]
    text = []
    for cond in ("paper-like", "outdoor"):
        rs = [r for r in recs if r["condition"] == cond and r.get("adaptive")]
        if not rs:
            continue
        rows = []
        for label in ("target x10", "5 + 5 refs", "5 + 4 refs") + tuple(k for k in FIXED if k not in
                                                                       ("target x10", "5 + 5 refs", "5 + 4 refs")):
            got = [r["fixed"][label] for r in rs if label in r["fixed"]]
            if got:
                rows.append((label,) + _summary(got))
        rows.insert(0, ("adaptive",) + _summary([r["adaptive"] for r in rs]))
        rows.insert(1, (f"adaptive, stopped at {HALF_S:.0f} s",) + _summary([_truncated(r["adaptive"], HALF_S)
                                                                          for r in rs]))
        comp = np.array([[r["adaptive"]["n_target"], r["adaptive"]["n_refs"]] for r in rs])
        text.append(f"Policies, {cond} scenes (tier high)\n\n" + _md(
            ("policy", "scenes", "mean human s", "median error %", "mean error %", "90 % coverage",
             "HDI <= 10 %"), rows)
            + f"\n\nAdaptive: {comp[:, 0].mean():.1f} target sets and {comp[:, 1].mean():.1f} references "
              f"on average\n")
    return "\n".join(text)


def figure_policy(out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    recs = [json.loads(x) for x in (out / "policy.jsonl").read_text().splitlines() if x.strip()]
    conds = [c for c in ("paper-like", "outdoor") if any(r["condition"] == c for r in recs)]
    fig, axes = plt.subplots(1, len(conds), figsize=(6 * len(conds), 5.2), squeeze=False)
    for ax, cond in zip(axes[0], conds):
        rs = [r for r in recs if r["condition"] == cond and r.get("adaptive")]
        for family, labels, style in (("target sets only", ("target x1", "target x2", "target x5", "target x10"), "o-"),
                                      ("5 target sets + k references", ("target x5", "5 + 2 refs", "5 + 4 refs", "5 + 5 refs"), "s-")):
            xs = [np.mean([r["fixed"][lab]["seconds"] for r in rs if lab in r["fixed"]]) for lab in labels]
            ys = [np.median([r["fixed"][lab]["error"] for r in rs if lab in r["fixed"]]) for lab in labels]
            ax.plot(xs, ys, style, label=family)
        grid = np.linspace(TARGET_S, FIVE_PLUS_FIVE_S, 60)
        curves = []
        for r in rs:
            steps = r["adaptive"]["steps"]
            t = np.array([s["seconds"] for s in steps])
            e = np.array([s["error"] for s in steps])
            curves.append(e[np.searchsorted(t, grid, side="right") - 1])
        ax.plot(grid, np.median(curves, axis=0), "-", color="k", label="adaptive policy (median over "
                "scenes along its runs; a run that stopped keeps its last error)")
        a = [r["adaptive"] for r in rs]
        ax.plot(np.mean([x["seconds"] for x in a]), np.median([x["error"] for x in a]), "k*", ms=14,
                label="adaptive where it stopped (mean seconds)")
        ax.axvline(HALF_S, color="grey", ls="--", lw=1, label="half the human time of 5 + 5")
        five = [r["fixed"]["5 + 5 refs"]["error"] for r in rs if "5 + 5 refs" in r["fixed"]]
        ax.axhline(np.median(five), color="tab:orange", ls=":", lw=1, label="error of 5 + 5 (median)")
        ax.set_xlabel("human seconds per target")
        ax.set_ylabel("median location error, % (Eq. 3, MAP)")
        ax.set_title(f"{cond} scenes, tier high ({len(rs)} scenes)")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.yaxis.set_minor_formatter(matplotlib.ticker.ScalarFormatter())
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path = out / "advice_policy.png"
    fig.savefig(path, dpi=120)
    return path


def report_estimates(out: Path) -> str | None:
    """CPU seconds per estimate (MAP and posterior, one process) in each study's records, with the
    share converged and the overflow warnings: the issue's bound of 5 s per estimate."""
    rows = []
    for study in ("predict", "own", "policy"):
        path = out / f"{study}.jsonl"
        if not path.is_file():
            continue
        costs = [c for x in path.read_text().splitlines() if x.strip() for c in json.loads(x).get("estimates", [])]
        if not costs:
            continue
        t = np.array([c["cpu_s"] for c in costs])
        rows.append((study, len(t), f"{np.median(t):.2f}", f"{np.percentile(t, 99):.2f}", f"{t.max():.2f}",
                     int(np.sum(t > 5.0)), f"{100 * np.mean([c['converged'] for c in costs]):.1f} %",
                     sum(c["overflow_warnings"] for c in costs)))
    if not rows:
        return None
    return ("Time per estimate (CPU seconds, MAP and posterior, one process)\n\n"
            + _md(("study", "estimates", "median", "99th percentile", "max", "over 5 s", "converged",
                   "overflow warnings"), rows))


def run_report(args) -> None:
    out = Path(args.out)
    if not out.is_dir():
        raise SystemExit(f"{out}: no such folder (run predict, timing or policy first)")
    parts = []
    if (out / "predict.jsonl").is_file():
        parts.append(report_predict(out))
    if (out / "own.jsonl").is_file():
        parts.append(report_predict(out, "own.jsonl"))
    if (out / "timing.jsonl").is_file():
        parts.append(report_timing(out))
    if (out / "policy.jsonl").is_file():
        parts.append(report_policy(out))
        parts.append(f"Figure: {figure_policy(out)}")
    times = report_estimates(out)
    if times:
        parts.append(times)
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
    for name, helptext in (("predict", "predicted against realised change, by kind"),
                           ("own", "predicted against realised on the model's own scenes (its prior and noise)"),
                           ("reweight", "for recorded predict scenes: the update given the realised annotation"),
                           ("timing", "the advice's time per object with the default settings"),
                           ("policy", "the adaptive policy against the fixed designs"),
                           ("report", "tables and the figure from the records")):
        s = sub.add_parser(name, help=helptext)
        s.add_argument("--out", default="advice_study", help="folder of the records and outputs")
        if name != "report":
            s.add_argument("--n", type=int, default={"policy": 40, "timing": 20}.get(name, 200),
                           help="scenes (policy: per condition)")
            s.add_argument("--seed", type=int, default=0, help="base seed")
            s.add_argument("--min-ess", type=float, default=400.0,
                           help="bulk ESS each estimate runs to (default: %(default)s)")
            s.add_argument("--focal-prior", metavar="MEDIAN,LOG_SD",
                           help="every scene states a log-normal focal-length prior (median in pixels, "
                                "log-sd), e.g. 1650,0.27 to match the simulator's cameras; default: the "
                                "package's default prior")
            s.add_argument("--line-reading", choices=("linear", "corrected"), default="linear",
                           help="how the metrology model reads reference segments (its option line_reading; "
                                "default: %(default)s)")
            s.add_argument("--ref-scale", type=float, metavar="S",
                           help="a fixed crowd error scale in log-length for estimates and advice (the metrology "
                                "model's option ref_scale; 0.75 is the paper-like tier's); default: integrated out")
        if name == "own":
            s.add_argument("--sets", default="1,2,3,5", type=_sets_arg,
                           help="the starting point's numbers of target sets, one drawn per scene "
                                "(default: %(default)s)")
        if name in ("predict", "reweight"):
            s.add_argument("--tiers", default="medium,high", help="noise tiers, cycled (default: %(default)s)")
        if name == "policy":
            s.add_argument("--rank-by", choices=("hdi", "location"), default="hdi",
                           help="the adaptive policy collects the annotation with the largest expected narrowing "
                                "of the distance's HDI per second (hdi, the advice's ranking) or drop of the "
                                "location's posterior sd per second (location)")
    args = p.parse_args(argv)
    global _FOCAL_PRIOR
    _MODEL_OPTIONS.clear()
    _ESTIMATE_KW.clear()
    if getattr(args, "line_reading", "linear") != "linear":
        _MODEL_OPTIONS["line_reading"] = args.line_reading
    if getattr(args, "ref_scale", None) is not None:
        if not (math.isfinite(args.ref_scale) and args.ref_scale > 0):
            p.error(f"--ref-scale: expected a number > 0, got {args.ref_scale!r}")
        _MODEL_OPTIONS["ref_scale"] = args.ref_scale
    if getattr(args, "focal_prior", None) and args.command == "own":
        p.error("--focal-prior: the own-model check draws its cameras from the default prior, which its "
                f"estimates use; got {args.focal_prior!r}")
    if getattr(args, "focal_prior", None):
        try:
            median, log_sd = (float(v) for v in args.focal_prior.split(","))
            _FOCAL_PRIOR = FocalPrior(median, log_sd, np.inf, source="scene")
        except ValueError as e:
            p.error(f"--focal-prior: expected MEDIAN,LOG_SD (two positive numbers), got {args.focal_prior!r} ({e})")
    {"predict": run_predict, "own": run_own, "reweight": run_reweight, "timing": run_timing, "policy": run_policy,
     "report": run_report}[args.command](args)


if __name__ == "__main__":
    main()
