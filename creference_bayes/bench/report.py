"""The benchmark's tables: summaries of :func:`~.runner.run_bench` records, and Markdown.

Every table is computed from the records alone (``bench.json`` can be re-summarised later).
Errors are the paper's Eq. 3 location percentage error; "posterior mean" is the location of the
posterior mean; the CRB rows are the median ‖e‖ implied by the Cramér–Rao bound (:mod:`.crb`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["TASK_SECONDS", "summarise", "markdown_report", "stats", "estimator_rows"]

TIER_ORDER = ("none", "low", "medium", "high")
#: Tiers with noise: coverage on the noise-free tier says nothing (any region around the exact
#: MAP covers), so the pooled calibration numbers use these.
NOISY = ("low", "medium", "high")
#: The paper's mean task times (§7.2.2), seconds: one target annotation, one reference annotation.
TASK_SECONDS = {"target": 183.5, "reference": 64.4}
PARAMS = ("x", "y", "z", "yaw", "focal_length_px", "pitch", "roll", "distance_m")
#: The estimators whose posteriors are checked for calibration.
CALIBRATED = ("ours-paper", "ours-metrology", "ours-metrology-nohorizon", "ours-metrology-flatfocal")
N_RANK_BINS = 10
#: Distance bands (m) of the tables of scenes with several targets.
BANDS = ((0.0, 20.0), (20.0, 40.0), (40.0, np.inf))


def stats(values) -> dict:
    """n, median, mean and 90th percentile of a list of errors (NaN-free)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "median": float(np.median(v)), "mean": float(np.mean(v)),
            "p90": float(np.percentile(v, 90))}


def _sel(records, **want):
    return [r for r in records if all(r.get(k) == v for k, v in want.items())]


def estimator_rows(doc: dict) -> list[tuple[str, dict, str]]:
    """(label, selector, error key) of every row of the error-by-tier table."""
    cfg = doc["config"]
    nt, nref = cfg["n_target"], max(cfg["ref_counts"])
    restarts = cfg["paper_restarts"] or 200
    label = f"paper (preset `paper`, {restarts} restarts{', REDUCED: quick' if restarts != 200 else ''}), {nref} refs"
    rows = [(label, dict(estimator="paper", n_target=nt, n_refs=nref), "error"),
            ("p4pf (PoseLib, LS-refined), 0 refs", dict(estimator="p4pf"), "error")]
    for model in ("paper", "metrology"):
        for k in sorted({0, nref} & set(cfg["ref_counts"])):
            rows.append((f"ours-{model} MAP, {k} refs", dict(estimator=f"ours-{model}", n_target=nt, n_refs=k), "error"))
        for k in sorted({0, nref} & set(cfg["posterior_ref_counts"])):
            rows.append((f"ours-{model} posterior mean, {k} refs",
                         dict(estimator=f"ours-{model}", n_target=nt, n_refs=k), "post_error"))
    for est, what in (("ours-metrology-nohorizon", "no horizon"), ("ours-metrology-flatfocal", "flat focal prior")):
        for k in (0, nref):
            rows.append((f"{est} MAP, {k} refs", dict(estimator=est, n_target=nt, n_refs=k), "error"))
            if k in cfg["posterior_ref_counts"]:
                rows.append((f"{est} posterior mean, {k} refs", dict(estimator=est, n_target=nt, n_refs=k),
                             "post_error"))
    rows += [("Cramér–Rao bound, target only", dict(estimator="crb-target"), "error"),
             (f"Cramér–Rao bound, + {nref} refs (metrology)", dict(estimator="crb-refs"), "error"),
             ("Cramér–Rao bound, no horizon, target only", dict(estimator="crb-target-nohorizon"), "error"),
             (f"Cramér–Rao bound, no horizon, + {nref} refs", dict(estimator="crb-refs-nohorizon"), "error")]
    return [r for r in rows if _sel(doc["records"], **r[1])]


def _by_tier(doc) -> dict:
    recs = doc["records"]
    out = {}
    for label, sel, key in estimator_rows(doc):
        out[label] = {t: stats([r.get(key) for r in _sel(recs, tier=t, **sel)]) for t in TIER_ORDER}
        out[label]["all"] = stats([r.get(key) for r in _sel(recs, **sel)])
    return out


def _vs_refs(doc) -> dict:
    recs, nt = doc["records"], doc["config"]["n_target"]
    out = {}
    for setting in ("indoor", "outdoor", "all"):
        s = {} if setting == "all" else {"setting": setting}
        block = {}
        for model in ("paper", "metrology"):
            for key, kind in (("error", "MAP"), ("post_error", "posterior mean")):
                row = {k: stats([r.get(key) for r in _sel(recs, estimator=f"ours-{model}", n_target=nt, n_refs=k, **s)])
                       for k in range(6)}
                row = {k: v for k, v in row.items() if v["n"]}
                if row:
                    block[f"ours-{model} {kind}"] = row
        for name, sel in (("paper", dict(estimator="paper", n_target=nt)), ("p4pf", dict(estimator="p4pf"))):
            row = {}
            for r in _sel(recs, **sel, **s):
                row.setdefault(r["n_refs"], []).append(r["error"])
            if row:
                block[name] = {k: stats(v) for k, v in sorted(row.items())}
        out[setting] = block
    return out


def _same_time(doc) -> dict:
    recs, cfg = doc["records"], doc["config"]
    nt, nb = cfg["n_target"], cfg["n_target_baseline"]
    out = {"human_seconds": {"baseline": nb * TASK_SECONDS["target"],
                             "c-reference": nt * TASK_SECONDS["target"] + 5 * TASK_SECONDS["reference"]}}
    for name in ("ours-paper", "ours-metrology", "paper"):
        base_recs = _sel(recs, estimator=name, n_target=nb, n_refs=0)
        scenes = {r["scene"] for r in base_recs}  # compare on the same scenes
        base = stats([r["error"] for r in base_recs])
        cref = stats([r["error"] for r in _sel(recs, estimator=name, n_target=nt, n_refs=5) if r["scene"] in scenes])
        if base["n"] and cref["n"]:
            out[name] = {"baseline": base, "c-reference": cref,
                         "mean_reduction_pct": 100 * (1 - cref["mean"] / base["mean"]),
                         "median_reduction_pct": 100 * (1 - cref["median"] / base["median"])}
    return out


def _pairs(doc) -> dict:
    out = {}
    for model in ("paper", "metrology"):
        recs = _sel(doc["records"], estimator=f"pair-{model}")
        if recs:
            out[model] = {kind: {g: stats([r["error"] for r in recs
                                           if kind in ("all", r["pair"]) and r["skipped"] == flag])
                                 for g, flag in (("skipped", True), ("used", False))}
                          for kind in sorted({r["pair"] for r in recs}) + ["all"]}
    return out


def _coverage(recs) -> dict:
    out = {}
    for p in PARAMS:
        cov = [r["coverage"][p] for r in recs if p in r.get("coverage", {})]
        if cov:
            out[p] = {"n": len(cov), "50": float(np.mean([c["50"] for c in cov])),
                      "90": float(np.mean([c["90"] for c in cov]))}
    return out


def _ranks(recs) -> dict:
    out = {}
    for p in PARAMS:
        u = [r["ranks"][p] for r in recs if p in r.get("ranks", {})]
        if u:
            out[p] = np.histogram(u, bins=N_RANK_BINS, range=(0, 1))[0].tolist()
    return out


def _calibration(doc) -> dict:
    out = {}
    for est in CALIBRATED:
        recs = [r for r in _sel(doc["records"], estimator=est) if "coverage" in r]
        if not recs:
            continue
        noisy = [r for r in recs if r["tier"] in NOISY]
        out[est.removeprefix("ours-")] = {"temperature": recs[0]["temperature"], "all": _coverage(noisy), "ranks": _ranks(noisy),
                      "by_tier": {t: _coverage(_sel(recs, tier=t)) for t in TIER_ORDER},
                      "by_refs": {k: _coverage(_sel(noisy, n_refs=k)) for k in sorted({r["n_refs"] for r in recs})},
                      "converged": float(np.mean([r["converged"] for r in recs]))}
    return out


def _sweep(doc) -> dict:
    recs = _sel(doc["records"], estimator="sweep-paper")
    out = {}
    for sigma, T in sorted({(r["sigma"], r["temperature"]) for r in recs}, key=lambda k: (-k[0], k[1])):
        sub = _sel(recs, sigma=sigma, temperature=T)
        out[f"sigma={sigma:g}, T={T:g}"] = {
            "sigma": sigma, "temperature": T, "all": _coverage([r for r in sub if r["tier"] in NOISY]),
            "by_tier": {t: _coverage(_sel(sub, tier=t)) for t in TIER_ORDER},
            "map_error": stats([r["map_error"] for r in sub]), "post_error": stats([r["post_error"] for r in sub]),
            "post_seconds": float(np.median([r["post_seconds"] for r in sub]))}
    return out


def _timing(doc) -> dict:
    recs, nt = doc["records"], doc["config"]["n_target"]
    paper = {r["scene"]: r["seconds"] for r in _sel(recs, estimator="paper", n_target=nt)}
    out = {"paper": {"seconds": float(np.median(list(paper.values()))), "ratio": 1.0}}

    def add(name, rows, key):
        secs = [sum(r.get(k, 0.0) for k in key) for r in rows]
        ratios = [s / paper[r["scene"]] for s, r in zip(secs, rows) if r["scene"] in paper]
        if secs:
            out[name] = {"seconds": float(np.median(secs)), "ratio": float(np.median(ratios))}

    add("p4pf", _sel(recs, estimator="p4pf"), ("seconds",))
    for model in ("paper", "metrology"):
        rows = _sel(recs, estimator=f"ours-{model}", n_target=nt, n_refs=5)
        add(f"ours-{model} MAP", rows, ("seconds",))
        add(f"ours-{model} MAP + posterior", [r for r in rows if "post_seconds" in r], ("seconds", "post_seconds"))
    return out


def _crb_ratio(doc) -> dict:
    """Median over scenes of error / CRB (target-only bound for 0 refs, with refs otherwise)."""
    recs = doc["records"]
    crb = {(r["scene"], r["estimator"]): r["error"] for r in recs if r["estimator"].startswith("crb")}
    out = {}
    for label, sel, key in estimator_rows(doc):
        if label.startswith("Cramér"):
            continue
        block = {}
        for t in NOISY + ("noisy",):
            ratios = []
            for r in _sel(recs, **sel):
                if r["tier"] not in (NOISY if t == "noisy" else (t,)):
                    continue
                kind = "crb-refs" if r.get("n_refs") else "crb-target"
                suffix = "-nohorizon" if sel.get("estimator", "").endswith("-nohorizon") else ""
                bound = crb.get((r["scene"], kind + suffix))
                if r.get(key) is not None and bound and np.isfinite(bound):
                    ratios.append(r[key] / bound)
            if ratios:
                block[t] = float(np.median(ratios))
        out[label] = block
    return out


def _default_choice(by_tier: dict) -> dict:
    """Per tier, the model whose MAP with 5 references has the lower median error."""
    out = {}
    for t in TIER_ORDER:
        cand = {m: by_tier.get(f"ours-{m} MAP, 5 refs", {}).get(t, {}).get("median") for m in ("paper", "metrology")}
        cand = {m: v for m, v in cand.items() if v is not None}
        if cand:
            out[t] = min(cand, key=cand.get)
    return out


def _paired(doc, estimator: str, against: str = "ours-metrology") -> dict:
    """The same scenes with and without a change (``estimator`` against ``against``), per number of
    references: MAP error statistics and the distance's 50 / 90 % coverage, over the noisy tiers."""
    recs, nt = doc["records"], doc["config"]["n_target"]
    out = {}
    for k in sorted({r["n_refs"] for r in _sel(recs, estimator=estimator)}):
        block = {}
        for name in (against, estimator):
            rows = [r for r in _sel(recs, estimator=name, n_target=nt, n_refs=k) if r["tier"] in NOISY]
            block[name] = {"error": stats([r["error"] for r in rows]),
                           "post_error": stats([r.get("post_error") for r in rows]),
                           "coverage": _coverage(rows).get("distance_m", {"n": 0, "50": None, "90": None})}
        out[k] = block
    return out


def _exact(doc) -> dict:
    """Noise-free scenes with exact references: error with and without them, per scene."""
    recs = _sel(doc["records"], estimator="exact-metrology")
    scenes = sorted({r["scene"] for r in recs})
    rows = {}
    for sid in scenes:
        by_k = {r["n_refs"]: r["error"] for r in _sel(recs, scene=sid)}
        rows[sid] = {"without": by_k.get(0), "with": max(v for k, v in by_k.items() if k)}
    if not rows:
        return {}
    w, wo = [v["with"] for v in rows.values()], [v["without"] for v in rows.values()]
    return {"scenes": rows, "max_with": max(w), "max_without": max(wo),
            "worse": int(sum(a > b + 0.01 for a, b in zip(w, wo)))}


def _scene_interval(share: float, n_scenes: int, level: float = 0.95) -> tuple[float, float]:
    """A share's interval as if each of ``n_scenes`` scenes were one check (Clopper–Pearson at
    ``share × n_scenes`` successes): the objects of a scene share its camera, so they count for
    between one check and one each, and a handful of scenes is all a bench band holds (a bootstrap
    over so few clusters is too narrow, and says nothing when every object is covered)."""
    from scipy import stats

    k, n, tail = share * n_scenes, float(n_scenes), (1.0 - level) / 2
    low = float(stats.beta.ppf(tail, k, n - k + 1)) if k > 0 else 0.0
    high = float(stats.beta.ppf(1 - tail, k + 1, n - k)) if k < n else 1.0
    return low, high


def _frames(doc) -> dict:
    """Scenes of several targets: per tier and distance band the median errors of the joint MAP,
    the joint posterior mean and the MAP alone, the bound and the distance's 90 % coverage (with
    its 95 % interval counting scenes, whose objects share a camera, :func:`_scene_interval`); per
    tier and object count the MAP's and the posterior's seconds and the share converged."""
    recs = _sel(doc["records"], estimator="frame")
    bands, counts = [], []
    for tier in dict.fromkeys(r["tier"] for r in recs):
        for lo, hi in BANDS:
            sel = [r for r in recs if r["tier"] == tier and lo <= r["distance_m"] < hi]
            if sel:
                med = {k: stats([r[k] for r in sel]).get("median") for k in ("error", "post_error", "alone_error", "crb")}
                covered = [r["in_hdi90"] for r in sel]
                interval = _scene_interval(float(np.mean(covered)), len({r["scene"] for r in sel}))
                bands.append({"tier": tier, "band_m": [lo, hi if np.isfinite(hi) else None], "objects": len(sel), **med,
                              "ratio": med["error"] / med["crb"], "coverage_90": float(np.mean(covered)),
                              "coverage_90_interval": [float(v) for v in interval]})
        for n in sorted({r["n_objects"] for r in recs if r["tier"] == tier}):
            sel = list({r["scene"]: r for r in recs if r["tier"] == tier and r["n_objects"] == n}.values())
            post = [r["post_seconds"] for r in sel if r["post_seconds"] is not None]
            counts.append({"tier": tier, "n_objects": n, "scenes": len(sel), "map_s": stats([r["seconds"] for r in sel]),
                           "map_max_s": max(r["seconds"] for r in sel), "post_s": stats(post),
                           "post_max_s": max(post, default=None), "converged": float(np.mean([r["converged"] for r in sel]))})
    return {"bands": bands, "counts": counts}


def summarise(doc: dict) -> dict:
    out = {"frames": _frames(doc)} if _sel(doc["records"], estimator="frame") else {}
    if not [r for r in doc["records"] if r["estimator"] != "frame"]:
        return out
    by_tier = _by_tier(doc)
    return {"by_tier": by_tier, "vs_refs": _vs_refs(doc), "same_time": _same_time(doc), "pairs": _pairs(doc),
            "calibration": _calibration(doc), "sweep": _sweep(doc), "timing": _timing(doc),
            "crb_ratio": _crb_ratio(doc), "better_model": _default_choice(by_tier),
            "horizon": _paired(doc, "ours-metrology-nohorizon"),
            "focal_prior": _paired(doc, "ours-metrology-flatfocal"), "exact": _exact(doc), **out}


# ------------------------------------------------------------------------------------------------
# Markdown


def _f(x, nd=1) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "–"
    return f"{x:.{nd}f}"


def _mean_median(b: dict, n: bool = False) -> str:
    return f"{_f(b['mean'])} / {_f(b['median'])}" + (f" ({b['n']})" if n else "")


def _cov(b: dict) -> str:
    """A coverage block's 50 % / 90 % shares, in percent."""
    return f"{_f(100 * b['50'], 0)} / {_f(100 * b['90'], 0)}"


def _cov_row(block: dict, keys) -> list[str]:
    return [_cov(block[k]) if k in block else "–" for k in keys]


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _frame_tables(f: dict) -> list[str]:
    rows = [[b["tier"], f"{b['band_m'][0]:.0f}–{b['band_m'][1]:.0f} m" if b["band_m"][1] is not None
             else f"≥ {b['band_m'][0]:.0f} m", str(b["objects"]), _f(b["error"], 2), _f(b["post_error"], 2),
             _f(b["alone_error"], 2), _f(b["crb"], 2), _f(b["ratio"], 2),
             f"{100 * b['coverage_90']:.0f}% ({100 * b['coverage_90_interval'][0]:.0f}–{100 * b['coverage_90_interval'][1]:.0f})"]
            for b in f["bands"]]
    out = ["Several targets per scene: location error (%, median over the objects of a band), each object "
           "estimated jointly and alone, the scene's Cramér–Rao bound (data and priors), and coverage (in "
           "brackets its 95 % interval counting each scene as one check: the objects of a scene share its camera, "
           "so a few scenes cannot tell 97 % from 90 %).", "",
           _table(["tier", "distance", "objects", "joint MAP median %", "joint mean median %", "alone MAP median %",
                   "bound median %", "joint / bound", "90 % HDI coverage"], rows), ""]
    rows = [[c["tier"], str(c["n_objects"]), str(c["scenes"]), _f(c["map_s"].get("median"), 2), _f(c["map_max_s"], 2),
             _f(c["post_s"].get("median"), 2), _f(c["post_max_s"], 2), f"{100 * c['converged']:.0f}%"] for c in f["counts"]]
    return out + [_table(["tier", "objects per scene", "scenes", "MAP median s", "MAP max s", "posterior median s",
                          "posterior max s", "converged"], rows), ""]


def markdown_report(doc: dict) -> str:
    """All tables of a bench document as Markdown."""
    s = doc.get("summary") or summarise(doc)
    cfg = doc["config"]
    out = [f"## Benchmark `{cfg['name']}` — seed {doc['seed']}, creference_bayes {doc['version']}, "
           f"{len({r['scene'] for r in doc['records']})} scenes, {doc['seconds']:.0f} s "
           f"({doc.get('cpu_seconds', float('nan')):.0f} s CPU)"
           + (f", {cfg['cameras']} cameras" if cfg.get("cameras", "setting") != "setting" else ""), ""]
    if s.get("frames"):
        out += _frame_tables(s["frames"])
    if "by_tier" not in s:
        return "\n".join(out)
    out += ["Location error (paper Eq. 3, %) per noise tier: median / mean / p90 (n scenes).", ""]
    rows = [[label] + [f"{_f(b['median'])} / {_f(b['mean'])} / {_f(b['p90'])} ({b['n']})" if b["n"] else "–"
                       for b in (block[t] for t in TIER_ORDER)] for label, block in s["by_tier"].items()]
    out += [_table(["estimator"] + list(TIER_ORDER), rows), ""]

    out += ["Error / Cramér–Rao bound: median over scenes of the ratio of the estimator's error to the median "
            "error the bound implies (bound with references for estimators that use them). An efficient "
            "estimator scores about 1; each scene contributes one draw, so with few scenes the ratio is noisy.", ""]
    cols = NOISY + ("noisy",)
    out += [_table(["estimator"] + [c if c != "noisy" else "all noisy tiers" for c in cols],
                   [[k] + [_f(v.get(t), 2) for t in cols] for k, v in s["crb_ratio"].items()]), ""]

    out += ["Better model per tier (median MAP error with 5 references): "
            + ", ".join(f"{t}: **{m}**" for t, m in s["better_model"].items()), ""]

    for setting in ("indoor", "outdoor"):
        block = s["vs_refs"].get(setting, {})
        if not block:
            continue
        out += [f"Error against the number of references, {setting} (mean / median %, Fig. 10).", ""]
        rows = [[name] + [_mean_median(row[k]) if k in row else "" for k in range(6)]
                for name, row in block.items()]
        out += [_table(["estimator"] + [str(k) for k in range(6)], rows), ""]

    st = s["same_time"]
    hs = st["human_seconds"]
    out += [f"Same human time (Analysis 2): {cfg['n_target_baseline']} target annotations "
            f"({hs['baseline']:.1f} s) against {cfg['n_target']} target + 5 reference annotations "
            f"({hs['c-reference']:.1f} s; task times 183.5 s and 64.4 s).", ""]
    rows = [[name, _mean_median(v["baseline"], True), _mean_median(v["c-reference"], True),
             _f(v["mean_reduction_pct"]), _f(v["median_reduction_pct"])]
            for name, v in st.items() if name != "human_seconds"]
    out += [_table(["estimator", "10 target: mean / median % (n)", "5 + 5 refs: mean / median % (n)",
                    "mean reduction %", "median reduction %"], rows), ""]

    if s["pairs"]:
        out += ["Skipped against used reference pairs (Fig. 11; two references alone; "
                "\"skipped\" = the paper's pair solve has no valid solution). Mean / median % (n).", ""]
        rows = [[f"ours-{model}", kind] + [_mean_median(g[k], True) if g[k]["n"] else "–"
                                           for k in ("skipped", "used")]
                for model, block in s["pairs"].items() for kind, g in block.items()]
        out += [_table(["model", "pair", "skipped", "used"], rows), ""]

    for model, c in s["calibration"].items():
        out += [f"Calibration, ours-{model} (T = {c['temperature']:g}): share of scenes whose truth lies in "
                f"the 50 % / 90 % HDI (converged runs: {100 * c['converged']:.0f} %).", ""]
        rows = [["all noisy"] + _cov_row(c["all"], PARAMS)]
        rows += [[t] + _cov_row(c["by_tier"].get(t, {}), PARAMS) for t in TIER_ORDER]
        out += [_table(["tier"] + list(PARAMS), rows), ""]

    if s["sweep"]:
        out += ["Calibration sweep of the paper model's posterior (σ of Eq. 5 and temperature T; 5 refs): "
                "coverage 50 % / 90 % per parameter over the noisy tiers, and median MAP / posterior-mean "
                "error over all tiers.", ""]
        rows = [[key] + _cov_row(v["all"], PARAMS)
                + [f"{_f(v['map_error'].get('median'), 2)} / {_f(v['post_error'].get('median'), 2)}"]
                for key, v in s["sweep"].items()]
        out += [_table(["σ, T"] + list(PARAMS) + ["error MAP / mean %"], rows), ""]
        out += ["Distance coverage 50 % / 90 % by tier in the sweep:", ""]
        rows = [[key] + _cov_row({t: b["distance_m"] for t, b in v["by_tier"].items() if "distance_m" in b},
                                 TIER_ORDER) for key, v in s["sweep"].items()]
        out += [_table(["σ, T"] + list(TIER_ORDER), rows), ""]

    for key, title in (("horizon", "Without the horizon (pitch and roll estimated) against with it, same scenes, "
                                   "noisy tiers"),
                       ("focal_prior", "The default focal-length prior against a flat one, same scenes, noisy tiers")):
        block = s.get(key) or {}
        if not block:
            continue
        out += [f"{title}: MAP error median / mean / p90 %, posterior-mean error median / mean %, and the "
                f"share of scenes whose true distance lies in the 50 % / 90 % HDI.", ""]
        rows = []
        for k, pair in block.items():
            for name, v in pair.items():
                e, pe, c = v["error"], v["post_error"], v["coverage"]
                rows.append([name, str(k), f"{_f(e.get('median'), 2)} / {_f(e.get('mean'), 2)} / {_f(e.get('p90'), 2)}",
                             f"{_f(pe.get('median'), 2)} / {_f(pe.get('mean'), 2)}" if pe.get("n") else "–",
                             f"{_cov(c)} ({c['n']})" if c["n"] else "–"])
        out += [_table(["estimator", "refs", "MAP error", "posterior-mean error", "coverage 50 / 90"], rows), ""]

    ex = s.get("exact") or {}
    if ex:
        out += [f"Exact references (noise-free, 0.01 px, 20 exact single values, outdoor 25–45 m): MAP error %, "
                f"with the references at most {_f(ex['max_with'], 3)}, without at most {_f(ex['max_without'], 3)}; "
                f"worse with them (by over 0.01 points): {ex['worse']} of {len(ex['scenes'])} scenes.", ""]
        out += [_table(["scene", "without refs", "with 20 refs"],
                       [[sid, _f(v["without"], 4), _f(v["with"], 4)] for sid, v in ex["scenes"].items()]), ""]

    out += ["Time per target (median seconds; ratio to the `paper` preset on the same scene).", ""]
    out += [_table(["estimator", "seconds", "ratio to paper"],
                   [[k, _f(v["seconds"], 3), _f(v["ratio"], 4)] for k, v in s["timing"].items()]), ""]
    return "\n".join(out)
