"""Thin designs on far outdoor targets: is the posterior centred on the truth? (docs/method.md,
"The location prior").

Outdoor scenes of the bench's simulator with the target 15–60 m away, the medium and the
paper-like (high) noise tiers in turn, each estimated from one set of dimension lines and 0, 1 and
2 references. Per design: the mean quantile of the true distance in the posterior (a calibrated
posterior gives 0.5; in brackets, the mean quantile of the true focal length in the focal prior
used, which is where the truth would fall if the annotations said nothing along the
depth–focal-length ridge) and the share of scenes in each decile of it (10 % each), the 90 % HDI's
coverage of the distance, the median HDI width over the distance, the MAP's and the posterior
mean's location errors, the share converged and the CPU seconds per estimate (99th percentile
and maximum). Under the table, over all designs: 95 % intervals of the mean quantile and of the
coverage from a bootstrap over scenes (a scene's three designs share its camera and target).

Usage::

    python examples/thin_designs.py --n 40 --out thin            # the default priors
    python examples/thin_designs.py --n 40 --out thin_flat --location-prior flat
    python examples/thin_designs.py --n 40 --out thin_m --focal-prior 1650,0.27   # a focal prior
                                                                 # matched to the simulator's µ
    python examples/thin_designs.py --n 120 --out thin_real --cameras real  # real cameras (phones,
                                                                 # zoom, action and street cameras)
    python examples/thin_designs.py --n 80 --cameras real --dataset auto --refs 0,2 --out thin_ds
                                         # each design's scenes as one batch, the data-set layer on
                                         # (--dataset none: the same batch, every frame alone;
                                         # --mixed: every second scene indoor;
                                         # --declare-setting: each scene names its setting)

Records go to ``OUT/thin.jsonl`` (one line per estimate), the table to ``OUT/thin.md``. Tens of
estimates a minute on one core; run it under the shared lock (``flock /tmp/bench.lock …``).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.runner import variant
from creference_bayes.bench.simulate import CAMERA_POPULATIONS, simulate_scene
from creference_bayes.evaluation.reliability import cluster_bootstrap
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.camera_terms import FocalPrior
from creference_bayes.pipeline import estimate

TIERS = ("medium", "high")
REFS = (0, 1, 2)


def _scene_dict(k: int, cameras: str = "setting", mixed: bool = False) -> dict:
    """Scene k as the simulator writes it: outdoor, 15–60 m; with ``mixed`` every second scene
    indoor (the simulator's indoor range, 2.25–10 m)."""
    indoor = mixed and k % 2 == 1
    return simulate_scene(np.random.default_rng([19, k]), setting="indoor" if indoor else "outdoor",
                          tier=TIERS[(k // 2 if mixed else k) % 2], distance_range=None if indoor else (15.0, 60.0),
                          cameras=cameras)


def _scene(k: int, cameras: str = "setting", mixed: bool = False):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(_scene_dict(k, cameras, mixed))


def _design(d: dict, n_refs: int) -> dict:
    """The scene file of a design: one set of lines on each target, the first ``n_refs`` references."""
    return {**d, "targets": [{**t, "dimension_lines": t["dimension_lines"][:1]} for t in d["targets"]],
            "references": d["references"][:n_refs]}


def _record(k: int, scene, n_refs: int, dist: np.ndarray, o: dict, converged: bool, seconds: float,
            focal="auto", overflow: int = 0) -> dict:
    """One estimate's record: ``dist`` the posterior draws of the target's ground distance, ``o``
    the result's object."""
    x, _, z = scene.targets[0].ground_truth["location_m"]
    d_true = float(np.hypot(x, z))
    lo, hi = o["posterior"]["hdi"]["distance_m"]
    return {"scene": k, "tier": scene.ground_truth["tier"], "refs": n_refs, "distance": d_true,
            "setting": scene.ground_truth["setting"], "camera": scene.ground_truth.get("camera_kind", "outdoor"),
            "quantile": float(np.mean(dist < d_true)), "prior_quantile": _prior_quantile(scene, focal),
            "hdi": [lo, hi], "covered": bool(lo <= d_true <= hi), "map_error": o["evaluation"]["location_pct_error"],
            "post_error": o["evaluation"]["posterior_location_pct_error"], "converged": converged,
            "seconds": seconds, "overflow_warnings": overflow}


def _prior_quantile(scene, focal) -> float:
    """The true focal length's quantile in the focal prior the estimate used: where the truth
    would fall in the posterior of the distance if the annotations said nothing along the
    depth–focal-length ridge (there the distance scales with µ, and the log-depth prior adds no
    lean of its own; docs/method.md, "The location prior")."""
    from scipy import stats

    from creference_bayes.camera_setup import setup_camera

    prior = setup_camera(scene, focal_prior=focal).terms.focal
    z = float(prior.z(scene.ground_truth["focal_length_px"]))
    return float(stats.norm.cdf(z) if np.isinf(prior.dof) else stats.t.cdf(z, prior.dof))


def run(args) -> list[dict]:
    focal = "auto"
    if args.focal_prior:
        median, log_sd = (float(v) for v in args.focal_prior.split(","))
        focal = FocalPrior(median, log_sd, np.inf, source="scene")
    equiv = tuple(float(v) for v in args.focal_35mm.split(",")) if args.focal_35mm else None
    distance_range = args.distance_range
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.dataset is not None:
        return run_batches(args, out)
    records = []
    with open(out / "thin.jsonl", "w") as f:
        for k in range(args.n):
            scene = _scene(k, args.cameras, args.mixed)
            if equiv:  # a prior in 35 mm-equivalent terms (mm, log-sd, dof), on this scene's image
                focal = FocalPrior.from_35mm(equiv[0], scene.image_size, log_sd=equiv[1], dof=equiv[2], source="scene")
            for n_refs in args.refs:
                t0 = time.process_time()
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    r = estimate(variant(scene, 1, tuple(range(n_refs))), seed=k, focal_prior=focal,
                                 location_prior=args.location_prior, distance_range=distance_range,
                                 sampling={"min_ess": args.min_ess}, keep_draws=0)
                dist = np.hypot(r.draws.objects[..., 0, 0], r.draws.objects[..., 0, 1]).ravel()
                rec = _record(k, scene, n_refs, dist, r.to_dict()["objects"][0], bool(r.converged),
                              time.process_time() - t0, focal, sum("overflow" in str(w.message) for w in caught))
                f.write(json.dumps(rec) + "\n")
                f.flush()
                records.append(rec)
    return records


def run_batches(args, out: Path) -> list[dict]:
    """``--dataset``: each design's scenes as one data set, estimated by ``creference batch`` with
    its defaults (``auto``: the data-set layer learns what the frames share, the distance
    population among it; ``none``: every frame alone) into ``OUT/refsR/``; the records read from
    its results (their kept draws; seconds: each estimate's own, the first pass not counted)."""
    from creference_bayes.io.result import stored_draws
    from creference_bayes.workflows.batch import BatchSettings, run_batch
    from creference_bayes.workflows.batch.engines import LocalEngine

    settings = BatchSettings(sampling={"min_ess": args.min_ess}, location_prior=args.location_prior,
                             distance_range=args.distance_range, dataset=args.dataset)
    dicts = [_scene_dict(k, args.cameras, args.mixed) for k in range(args.n)]
    if args.declare_setting:  # what a data set's own records say: where each photo was taken
        dicts = [{**d, "setting": d["ground_truth"]["setting"]} for d in dicts]
    records = []
    with open(out / "thin.jsonl", "w") as f:
        for n_refs in args.refs:
            folder = out / f"refs{n_refs}"
            (folder / "in").mkdir(parents=True, exist_ok=True)
            for k, d in enumerate(dicts):
                (folder / "in" / f"k{k:04d}.json").write_text(json.dumps(_design(d, n_refs)))
            t0 = time.perf_counter()
            run_batch([folder / "in"], folder / "batch", LocalEngine(args.workers), settings)
            print(f"{n_refs} references: batch of {args.n} in {time.perf_counter() - t0:.0f} s", flush=True)
            for k in range(args.n):
                path = folder / "batch" / "results" / f"k{k:04d}.json"
                if not path.exists():
                    continue
                res = json.loads(path.read_text())
                objs = stored_draws(res).objects
                dist = np.hypot(objs[..., 0, 0], objs[..., 0, 1]).ravel()
                rec = _record(k, _scene(k, args.cameras, args.mixed), n_refs, dist, res["objects"][0],
                              bool((res.get("diagnostics") or {}).get("converged")), float(res["seconds"]))
                rec["population"] = (res.get("dataset") or {}).get("distance_m")
                f.write(json.dumps(rec) + "\n")
                f.flush()
                records.append(rec)
    return records


def table(records: list[dict], by: str = "refs") -> str:
    """The Markdown table of the records, one row per design (``by="refs"``) or camera kind
    (``by="camera"``), and one for all."""
    head = (f"| {by} | estimates | mean quantile (focal prior alone) | deciles of the quantile, % (0–0.1 … 0.9–1) | 90 % HDI covers | "
            "median HDI / distance | MAP error % median / mean | posterior-mean error % median / mean | "
            "converged | CPU s p99 / max |\n|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    groups = sorted({r[by] for r in records})
    for refs in [*groups, "all"]:
        s = [r for r in records if refs == "all" or r[by] == refs]
        if not s:
            continue
        q = np.array([r["quantile"] for r in s])
        dec = np.bincount(np.minimum((q * 10).astype(int), 9), minlength=10) / len(q) * 100
        w = np.median([(r["hdi"][1] - r["hdi"][0]) / r["distance"] for r in s])
        me, pe = np.array([r["map_error"] for r in s]), np.array([r["post_error"] for r in s])
        sec = np.array([r["seconds"] for r in s])
        alone = np.mean([r["prior_quantile"] for r in s]) if all("prior_quantile" in r for r in s) else np.nan
        rows.append(f"| {refs} | {len(s)} | {q.mean():.2f} ({alone:.2f}) | {' '.join(f'{v:.0f}' for v in dec)} | "
                    f"{100 * np.mean([r['covered'] for r in s]):.0f} % | {w:.2f} | {np.median(me):.1f} / {me.mean():.1f} | "
                    f"{np.median(pe):.1f} / {pe.mean():.1f} | {100 * np.mean([r['converged'] for r in s]):.0f} % | "
                    f"{np.percentile(sec, 99):.1f} / {sec.max():.1f} |")
    warn = sum(r["overflow_warnings"] for r in records)
    return "\n".join([head, *rows]) + f"\n\noverflow warnings: {warn}\n"


def scene_bootstrap(records: list[dict]) -> str:
    """The 95 % bootstrap intervals of the mean quantile and of the 90 % HDI's coverage over all
    estimates, resampling whole scenes (the designs of one scene share its camera and target, so
    they are not independent draws)."""
    lo, hi = cluster_bootstrap([[r["quantile"], r["covered"]] for r in records], [r["scene"] for r in records])
    return (f"all designs, 95 % bootstrap over the {len({r['scene'] for r in records})} scenes: mean quantile "
            f"{lo[0]:.2f}–{hi[0]:.2f}, 90 % HDI coverage {100 * lo[1]:.0f}–{100 * hi[1]:.0f} %")


def main(argv=None) -> None:
    from creference_bayes.cli.estimate import distance_range_arg

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=40, help="scenes (each estimated with 0, 1 and 2 references)")
    p.add_argument("--out", default="thin_designs", help="output folder (default: %(default)s)")
    p.add_argument("--min-ess", type=int, default=400, help="bulk ESS of each posterior (default: %(default)s)")
    p.add_argument("--location-prior", default="auto", choices=("auto", "log-depth", "flat", "inverse-square"))
    p.add_argument("--distance-range", default=None, metavar="LOW,HIGH", type=distance_range_arg,
                   help="the data set's distances in metres (creference estimate --distance-range), for example "
                        "10,80 around these scenes' 15-60 m targets (default: none)")
    p.add_argument("--focal-prior", default=None, metavar="MEDIAN_PX,LOG_SD",
                   help="a log-normal focal-length prior instead of the default")
    p.add_argument("--focal-35mm", default=None, metavar="MM,LOG_SD,DOF",
                   help="a Student-t focal-length prior in 35 mm-equivalent terms (DOF inf: log-normal) instead "
                        "of the default, e.g. 30,0.5,3 (the default's own numbers)")
    p.add_argument("--cameras", default="setting", choices=CAMERA_POPULATIONS,
                   help="the simulator's outdoor cameras (setting) or real ones, street cameras included (real)")
    p.add_argument("--mixed", action="store_true",
                   help="every second scene indoor (the simulator's indoor range, 2.25-10 m): one data set of both")
    p.add_argument("--declare-setting", action="store_true",
                   help="each scene file names its setting (indoor, outdoor): the data set's distance population "
                        "is then one per setting (--dataset)")
    p.add_argument("--dataset", default=None, choices=("auto", "none"),
                   help="each design's scenes as one batch (creference batch --dataset auto: the data-set layer, "
                        "its default; none: every frame alone); default: each scene estimated on its own")
    p.add_argument("--workers", type=int, default=1, help="the batch's worker processes (--dataset)")
    p.add_argument("--refs", default=",".join(map(str, REFS)), type=lambda v: tuple(int(x) for x in v.split(",")),
                   help="the designs: references with the one set of lines (default: %(default)s)")
    args = p.parse_args(argv)
    if args.dataset is not None and (args.focal_prior or args.focal_35mm):
        p.error("--dataset: the batch estimates with the default focal-length prior; drop --focal-prior / --focal-35mm")
    records = run(args)
    text = (table(records) + f"\n{scene_bootstrap(records)}\n"
            + ("" if args.cameras == "setting" else "\nBy camera:\n\n" + table(records, "camera"))
            + ("" if not args.mixed else "\nBy setting:\n\n" + table(records, "setting") + "\n"
               + "\n".join(f"{s}: {scene_bootstrap([r for r in records if r['setting'] == s])}"
                           for s in ("indoor", "outdoor"))))
    (Path(args.out) / "thin.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
