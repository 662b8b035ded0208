"""The confidence-map study (docs/studies/confidence.md): simulated workers who state a confidence with each
range, with a known true map, and three checks of the research tools against it.

(a) fit with ground truth: does `creference confidence fit` recover the true map g within its
    stated uncertainty at every level? (over-confident, calibrated and under-confident workers)
(b) fit without ground truth: how close does the marginal-likelihood fit get, and how does it
    degrade with fewer scenes? (over-confident workers; the same scenes as (a), and noisier ones)
(c) in a reference-dominated setting (one set of target dimension lines, far targets): coverage
    of the 90 % region of the distance, its width, interval score and accuracy with the maps
    none, identity, the fits of (a) and (b) and the true map, for over-confident and for
    calibrated workers.

    python examples/confidence_study.py --out confidence_study_out --workers 2          # the full presets
    python examples/confidence_study.py --out confidence_study_out --workers 2 \
        --n-a 300 --replicates 200 --n-b 10,25,50,100,200 --n-b-medium 25,100 --n-c 150   # docs/studies/confidence.md
    python examples/confidence_study.py --out /tmp/cs --quick                           # a check, ~2 min

Every data set is written to OUT/data/NAME/ as scene files, so the package's own commands can be
run on them (the study prints them). Estimates of (b) and (c) are cached in OUT (rerun the same
command to finish an interrupted run).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.confidence_workers import ConfidentWorkers
from creference_bayes.bench.simulate import simulate_scene
from creference_bayes.core.metrics import interval_score
from creference_bayes.io.files import atomic_path, atomic_write_json, atomic_write_text
from creference_bayes.io.scene import parse_scene, scene_fingerprint
from creference_bayes.models.confidence_map import ConfidenceMap, CoverageCurve
from creference_bayes.models.contract import O_X, O_Z
from creference_bayes.workflows.confidence.data import StatedRange, stated_ranges
from creference_bayes.workflows.confidence.fit import fit_marginal, fit_with_truth
from creference_bayes.workflows.confidence.loo import RangePrediction, predict_data_set

#: The two kinds of scene: (a) and (b) use the standard one, (c) the reference-dominated one.
STANDARD = {"tier": "low", "n_references": 6}
#: With one annotation the model takes the target's corner noise to be 5 px and the lines' 10 px
#: (DEFAULT_TARGET_SIGMA_PX, REF_LINE_FACTOR): the medium tier's, so that (c) compares confidence
#: treatments, not a misjudged pixel noise.
REFERENCE_DOMINATED = {"tier": "medium", "n_references": 6, "n_target_annotations": 1, "setting": "outdoor",
                       "distance_range": (15.0, 30.0)}
POOL_SEEDS = {"over": 11, "calibrated": 12, "under": 13}
SIZES = {"full": {"a": 300, "b": (25, 50, 100, 200), "b_medium": (50, 200), "c": 150, "draws": 1000,
                  "replicates": 200},
         "quick": {"a": 40, "b": (4, 8), "b_medium": (4,), "c": 3, "draws": 200, "replicates": 10}}


def pool(kind: str, seed: int) -> ConfidentWorkers:
    return ConfidentWorkers.pool(kind, n_workers=40, seed=[seed, POOL_SEEDS[kind]])


def true_map(workers: ConfidentWorkers) -> ConfidenceMap:
    lv = np.array(workers.levels)
    return ConfidenceMap(kind="fitted", pooled=CoverageCurve(tuple(lv), tuple(workers.true_coverage(lv))),
                         fit={"method": "true map of the simulated workers"})


def data_set(out: Path, name: str, n: int, seed: int, workers: ConfidentWorkers, kind: dict,
             dicts: list | None = None) -> list:
    """(key, Scene) of ``n`` simulated scenes, also written to OUT/data/NAME/ (``dicts`` receives
    the scene dicts)."""
    folder = out / "data" / name
    folder.mkdir(parents=True, exist_ok=True)
    scenes = []
    tag = sum(map(ord, name))
    for i in range(n):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = simulate_scene(np.random.default_rng([seed, tag, i]), confidence=workers, **kind)
        atomic_write_text(folder / f"scene_{i:04d}.json", json.dumps(d, indent=1) + "\n")
        scenes.append((f"scene_{i:04d}", parse_scene(d)))
        if dicts is not None:
            dicts.append(d)
    return scenes


def compare(fitted: ConfidenceMap, workers: ConfidentWorkers) -> list[dict]:
    c = fitted.pooled
    g = workers.true_coverage(np.array(c.levels))
    return [{"level": lv, "true": float(t), "fit": f, "low": lo, "high": hi, "n": n, "inside": bool(lo <= t <= hi)}
            for lv, t, f, lo, hi, n in zip(c.levels, g, c.coverage, c.low, c.high, c.n)]


def print_table(title: str, head: list[str], rows: list[list], out_lines: list[str]) -> None:
    lines = ["", f"### {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    print("\n".join(lines), flush=True)
    out_lines += lines


# -- (a) ---------------------------------------------------------------------------------------------
def part_a(args, sizes, out, lines) -> dict:
    maps = {}
    for kind in ("over", "calibrated", "under"):
        workers = pool(kind, args.seed)
        scenes = data_set(out, f"a_{kind}", sizes["a"], args.seed, workers, STANDARD)
        # 5 ranges a level, as (b): a small run's levels hold fewer than the command's default 10
        fitted = fit_with_truth(stated_ranges(scenes), draws=sizes["draws"], seed=args.seed, min_per_level=5)
        atomic_write_json(out / f"map_a_{kind}.json", fitted.to_dict())
        maps[kind] = fitted
        rows = compare(fitted, workers)
        shape = "normal" if fitted.dof is None else f"t{fitted.dof:g}"
        print_table(f"(a) {kind} workers (κ = {workers.width_factor:g}): fit with ground truth, "
                    f"{fitted.fit['ranges']} ranges in {fitted.fit['scenes']} scenes; shape {shape}; "
                    f"{sum(r['inside'] for r in rows)} of {len(rows)} levels inside the 95 % interval",
                    ["stated c", "true g", "fitted g", "95 % interval", "n", "inside"],
                    [[f"{r['level']:g}", f"{r['true']:.3f}", f"{r['fit']:.3f}", f"{r['low']:.3f}–{r['high']:.3f}",
                      r["n"], "yes" if r["inside"] else "NO"] for r in rows], lines)
    return maps


def replicate_check(args, sizes, lines) -> None:
    """Are the stated 95 % intervals right? Many replicate data sets of the size of (a), the
    workers' statements drawn directly (the scenes do not matter to a fit with ground truth)."""
    rows = []
    for kind in ("over", "calibrated", "under"):
        workers = pool(kind, args.seed)
        g = workers.true_coverage(np.array(workers.levels))
        rng = np.random.default_rng([args.seed, 99, POOL_SEEDS[kind]])
        inside = []
        for rep in range(sizes["replicates"]):
            ranges = [_statement(workers, rng, f"s{s}", j) for s in range(sizes["a"]) for j in range(6)]
            try:
                c = fit_with_truth(ranges, draws=400, seed=rep, min_per_level=5).pooled
            except ValueError:  # too few ranges at every level but one: no fit of every level
                continue
            if len(c.levels) == len(g):
                inside.append([lo <= t <= hi for lo, hi, t in zip(c.low, c.high, g)])
        inside = np.array(inside, dtype=bool).reshape(-1, len(g))  # data sets whose fit has every level
        rows.append([kind, len(inside),
                     " ".join(f"{v:.2f}" for v in inside.mean(axis=0)) if len(inside) else "(no fit had every level)",
                     f"{inside.all(axis=1).mean():.2f}" if len(inside) else ""])
    print_table(f"(a) the stated uncertainty: share of {sizes['replicates']} replicate data sets of "
                f"{sizes['a']} scenes (× 6 ranges) whose 95 % interval holds the true g, per level "
                "(0.5 … 0.99) and at every level at once", ["workers", "replicates", "per level", "every level"],
                rows, lines)


def _statement(workers: ConfidentWorkers, rng, scene: str, j: int) -> StatedRange:
    """One statement about a length of 1 m."""
    w, lo, hi, c = workers.state(rng)
    return StatedRange(scene, j, w, "length", "direct", c, lo, hi, 1.0, "object")


# -- (b) ---------------------------------------------------------------------------------------------
def part_b(args, sizes, out, lines, tier: str = "low") -> ConfidenceMap:
    workers = pool("over", args.seed)
    counts = sizes["b"] if tier == "low" else sizes["b_medium"]
    n_max = max(counts)
    scenes = (data_set(out, "a_over", n_max, args.seed, workers, STANDARD) if tier == "low" else
              data_set(out, f"b_over_{tier}", n_max, args.seed, workers, {**STANDARD, "tier": tier}))
    cache = out / f"b_predictions_{tier}.json"
    preds = []
    if cache.exists():
        doc = json.loads(cache.read_text())
        if doc.get("n_scenes") == n_max and doc.get("seed") == args.seed:
            preds = [RangePrediction.from_dict(d) for d in doc["predictions"]]
    if not preds:
        t0 = time.perf_counter()
        preds, totals, errors = predict_data_set(scenes, seed=args.seed, workers=args.workers,
                                                 progress=sys.stderr.isatty())
        print(f"(b) leave-one-out posteriors of {n_max} scenes: {time.perf_counter() - t0:.0f} s; "
              f"{totals} errors {errors}", flush=True)
        atomic_write_json(cache, {"n_scenes": n_max, "seed": args.seed, "totals": totals,
                                  "predictions": [p.to_dict() for p in preds]}, indent=None)
    rows, per_level, final = [], {}, None
    order = {k: i for i, (k, _) in enumerate(scenes)}
    for n in counts:
        sub = [p for p in preds if order[p.range.scene] < n]
        marg = fit_marginal(sub, draws=sizes["draws"], seed=args.seed, min_per_level=5)
        truth = fit_with_truth(stated_ranges(scenes[:n]), draws=sizes["draws"], seed=args.seed,
                               min_per_level=5)
        cm, ct = compare(marg, workers), compare(truth, workers)
        err_m = np.array([r["fit"] - r["true"] for r in cm])
        err_t = np.array([r["fit"] - r["true"] for r in ct])
        rows.append([n, len(sub), "normal" if marg.dof is None else f"t{marg.dof:g}",
                     f"{np.mean(np.abs(err_m)):.3f}", f"{np.max(np.abs(err_m)):.3f}", f"{np.mean(err_m):+.3f}",
                     f"{sum(r['inside'] for r in cm)}/{len(cm)}",
                     f"{np.mean([r['high'] - r['low'] for r in cm]):.3f}",
                     f"{np.mean(np.abs(err_t)):.3f}", f"{np.mean([r['high'] - r['low'] for r in ct]):.3f}",
                     marg.fit["refits"]])
        per_level[n] = cm
        final = marg
        atomic_write_json(out / f"map_b_{tier}_{n}.json", marg.to_dict())
    print_table(f"(b) over-confident workers, {tier}-noise scenes: fit without ground truth (marginal "
                "likelihood) against the true map, by number of scenes; the fit with ground truth on the "
                "same scenes for comparison",
                ["scenes", "ranges", "shape", "mean abs error", "max abs error", "mean error",
                 "levels inside 95 %", "mean interval width", "truth fit: mean abs error",
                 "truth fit: mean width", "refits"], rows, lines)
    block_table(args, sizes, tier, workers, scenes, preds, order, lines)
    n = n_max
    print_table(f"(b) per level, {tier}-noise scenes, {n} scenes", ["stated c", "true g", "fitted g (no truth)", "95 % interval", "n"],
                [[f"{r['level']:g}", f"{r['true']:.3f}", f"{r['fit']:.3f}", f"{r['low']:.3f}–{r['high']:.3f}", r["n"]]
                 for r in per_level[n]], lines)
    return final


def block_table(args, sizes, tier, workers, scenes, preds, order, lines) -> None:
    """How the fit without truth degrades with fewer scenes, beyond the luck of one data set: the
    largest data set cut into disjoint blocks of n scenes, both fits on every block."""
    n_max = len(scenes)
    truths = stated_ranges(scenes)
    rows = []
    for n in [n for n in (sizes["b"] if tier == "low" else sizes["b_medium"]) if 2 * n <= n_max]:
        stats = {"marg": [], "truth": []}
        for b in range(n_max // n):
            block = range(b * n, (b + 1) * n)
            keys = {scenes[i][0] for i in block}
            fits = {"marg": fit_marginal([p for p in preds if order[p.range.scene] in block], draws=200,
                                         seed=args.seed, min_per_level=5),
                    "truth": fit_with_truth([r for r in truths if r.scene in keys], draws=200, seed=args.seed,
                                            min_per_level=5)}
            for name, fit in fits.items():
                cmp_ = compare(fit, workers)
                err = np.array([r["fit"] - r["true"] for r in cmp_])
                stats[name].append((err.mean(), np.abs(err).mean(), np.mean([r["inside"] for r in cmp_])))
        row = [n, n_max // n]
        for name in ("marg", "truth"):
            a = np.array(stats[name])
            row += [f"{a[:, 0].mean():+.3f} ± {a[:, 0].std(ddof=1) / np.sqrt(len(a)):.3f}", f"{a[:, 1].mean():.3f}",
                    f"{a[:, 2].mean():.2f}"]
        rows.append(row)
    if rows:
        print_table(f"(b) {tier}-noise scenes, the {n_max} scenes cut into disjoint blocks of n: mean over the "
                    "blocks of the mean error (± its standard error over blocks), the mean abs error and the "
                    "share of levels whose 95 % interval holds the true g",
                    ["n scenes", "blocks", "no truth: mean error", "no truth: mean abs error",
                     "no truth: levels inside", "truth: mean error", "truth: mean abs error", "truth: levels inside"],
                    rows, lines)


# -- (c) ---------------------------------------------------------------------------------------------
def estimate_job(job: dict) -> dict:
    """One estimate of (c): whether the target's true distance lies in its 90 % regions, their width,
    the interval score and the location error."""
    from creference_bayes.pipeline import estimate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = parse_scene(job["scene"])
        t0 = time.perf_counter()
        r = estimate(scene, seed=job["seed"], confidence_map=job["map"], keep_draws=0)
    x, _, z = scene.targets[0].ground_truth["location_m"]
    dist = float(np.hypot(x, z))
    target = r.to_dict()["objects"][0]
    d = np.hypot(r.draws.objects[..., 0, O_X], r.draws.objects[..., 0, O_Z]).ravel()
    lo, hi = np.quantile(d, [0.05, 0.95])
    hlo, hhi = target["posterior"]["hdi"]["distance_m"]
    return {"key": job["key"], "in_hdi": bool(hlo <= dist <= hhi), "hdi_width": (hhi - hlo) / dist,
            "in_central": bool(lo <= dist <= hi), "score": float(interval_score(lo, hi, dist, 0.1)) / dist,
            "error_pct": float(target["evaluation"]["posterior_location_pct_error"]),
            "map_error_pct": float(target["evaluation"]["location_pct_error"]),
            "converged": bool(r.converged), "seconds": time.perf_counter() - t0}


def run_jobs(jobs: list[dict], cache: Path, workers: int) -> dict:
    done = {}
    if cache.exists():
        for line in cache.read_text().splitlines():
            rec = json.loads(line)
            done[rec["key"]] = rec
    todo = [j for j in jobs if j["key"] not in done]
    if todo:
        from creference_bayes.workflows.batch.engines import LocalEngine
        import concurrent.futures as cf

        with open(cache, "a") as fh, LocalEngine(workers) as engine:
            futures = [engine.executor.submit(estimate_job, j) for j in todo]
            for k, fut in enumerate(cf.as_completed(futures), 1):
                rec = fut.result()
                done[rec["key"]] = rec
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                if k % 25 == 0 or k == len(todo):
                    print(f"  (c) {k}/{len(todo)} estimates", file=sys.stderr, flush=True)
    return done


def part_c(args, sizes, out, lines, fitted_a: dict, fitted_b: ConfidenceMap | None) -> None:
    rows = []
    for kind in ("over", "calibrated"):
        workers = pool(kind, args.seed)
        dicts = []
        scenes = data_set(out, f"c_{kind}", sizes["c"], args.seed, workers, REFERENCE_DOMINATED, dicts)
        maps = {"none": "none", "identity": "identity"}
        if kind in fitted_a:
            maps["fitted, with truth (a)"] = fitted_a[kind]
        if kind == "over" and fitted_b is not None:
            maps["fitted, no truth (b)"] = fitted_b
        maps["true map"] = true_map(workers)
        jobs = []
        for label, m in maps.items():
            tag = m if isinstance(m, str) else m.digest()[:12]
            jobs += [{"key": f"{kind}|{key}|{scene_fingerprint(sc)[:12]}|{tag}", "scene": dicts[i], "seed": i, "map": m}
                     for i, (key, sc) in enumerate(scenes)]
        done = run_jobs(jobs, out / "c_results.jsonl", args.workers)
        base = None
        for label, m in maps.items():
            tag = m if isinstance(m, str) else m.digest()[:12]
            recs = [done[f"{kind}|{key}|{scene_fingerprint(sc)[:12]}|{tag}"] for key, sc in scenes]
            hit = np.array([r["in_hdi"] for r in recs], float)
            err = np.array([r["error_pct"] for r in recs])
            if base is None:
                base = err
            rows.append([kind, label, len(recs), f"{hit.mean():.3f} ± {hit.std(ddof=1) / np.sqrt(len(hit)):.3f}"
                         if len(hit) > 1 else f"{hit.mean():.3f}",
                         f"{np.mean([r['in_central'] for r in recs]):.3f}",
                         f"{np.median([r['hdi_width'] for r in recs]):.3f}",
                         f"{np.mean([r['score'] for r in recs]):.3f}",
                         f"{np.median(err):.1f}", f"{np.mean(err):.1f}",
                         f"{np.median(err - base):+.2f}",
                         f"{np.mean([r['converged'] for r in recs]):.2f}",
                         f"{np.mean([r['seconds'] for r in recs]):.1f}"])
    print_table("(c) reference-dominated scenes (one set of target dimension lines, targets 15–30 m away, "
                "medium pixel noise, six ranges with a confidence): the distance's 90 % region",
                ["workers", "confidence map", "scenes", "coverage of the 90 % HDI ± se", "coverage, central 90 %",
                 "median HDI width / distance", "mean interval score / distance (central 90 %)",
                 "median error %", "mean error %", "median paired error change vs none (points)",
                 "converged", "seconds"], rows, lines)


def write_figure(out: Path, seed: int, sizes: dict, fitted_a: dict, fitted_b) -> Path | None:
    if "over" not in fitted_a:
        return None
    from creference_bayes.vision.confidence_figures import reliability_figure
    from creference_bayes.workflows.confidence.report import confidence_report

    workers = pool("over", seed)
    scenes = data_set(out, "a_over", sizes["a"], seed, workers, STANDARD)
    rep = confidence_report(stated_ranges(scenes), {})
    maps = {"fit with ground truth (a)": fitted_a["over"]}
    if fitted_b is not None:
        maps[f"fit without ground truth (b), {max(sizes['b'])} scenes"] = fitted_b
    fig = reliability_figure(rep.reliability, maps, true_map=workers.true_coverage)
    path = out / "reliability_over.png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, format="png")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="confidence_study_out", help="working folder (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="seed of workers, scenes and estimates (default: %(default)s)")
    ap.add_argument("--workers", type=int, default=1, help="local processes for the estimates (default: %(default)s)")
    ap.add_argument("--parts", default="abc", help="which parts to run, e.g. ab (default: %(default)s)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes: a check that everything runs")
    ap.add_argument("--quick-b", action="store_true",
                    help="(b) on low-noise scenes only (not also on medium-noise ones)")
    ap.add_argument("--n-a", type=int, help="scenes per data set of (a) (overrides the preset)")
    ap.add_argument("--n-b", help="numbers of scenes of (b), low noise, comma-separated (e.g. 10,25,50)")
    ap.add_argument("--n-b-medium", help="numbers of scenes of (b), medium noise, comma-separated")
    ap.add_argument("--n-c", type=int, help="scenes per kind of worker in (c)")
    ap.add_argument("--replicates", type=int, help="replicate data sets of the (a) coverage check")
    args = ap.parse_args()
    sizes = dict(SIZES["quick" if args.quick else "full"])
    for key, value in (("a", args.n_a), ("c", args.n_c), ("replicates", args.replicates)):
        if value is not None:
            sizes[key] = value
    for key, value in (("b", args.n_b), ("b_medium", args.n_b_medium)):
        if value:
            sizes[key] = tuple(sorted(int(v) for v in value.split(",")))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lines = [f"# Confidence-map study (seed {args.seed}, {'quick' if args.quick else 'full'} sizes; "
             f"a {sizes['a']}, b {sizes['b']}, b medium {sizes['b_medium']}, c {sizes['c']}, "
             f"replicates {sizes['replicates']})"]
    t0 = time.perf_counter()
    fitted_a = part_a(args, sizes, out, lines) if "a" in args.parts else {}
    if "a" in args.parts:
        replicate_check(args, sizes, lines)
    fitted_b = part_b(args, sizes, out, lines) if "b" in args.parts else None
    if "b" in args.parts and not args.quick_b:
        part_b(args, sizes, out, lines, tier="medium")
    if "c" in args.parts:
        part_c(args, sizes, out, lines, fitted_a, fitted_b)
    fig = write_figure(out, args.seed, sizes, fitted_a, fitted_b)
    lines += ["", f"Figure: {fig}" if fig else "", f"Total time: {time.perf_counter() - t0:.0f} s", "",
              "The same with the package's commands, on the data sets written above:", "", "```",
              f"creference confidence fit {out}/data/a_over --out {out}/map.json",
              f"creference confidence report {out}/data/a_over --out {out}/report --map {out}/map.json",
              f"creference confidence fit {out}/data/a_over --method marginal --workers 2 --out {out}/map_nogt.json",
              f"creference batch {out}/data/c_over --out {out}/batch_c --confidence-map {out}/map.json", "```"]
    atomic_write_text(out / "confidence_study.md", "\n".join(lines) + "\n")
    print("\n".join(lines[-9:]))
    print(f"wrote {out / 'confidence_study.md'}")


if __name__ == "__main__":
    main()
