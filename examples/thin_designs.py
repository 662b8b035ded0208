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


def _scene(k: int, cameras: str = "setting"):
    d = simulate_scene(np.random.default_rng([19, k]), setting="outdoor", tier=TIERS[k % 2],
                       distance_range=(15.0, 60.0), cameras=cameras)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


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
    records = []
    with open(out / "thin.jsonl", "w") as f:
        for k in range(args.n):
            scene = _scene(k, args.cameras)
            if equiv:  # a prior in 35 mm-equivalent terms (mm, log-sd, dof), on this scene's image
                focal = FocalPrior.from_35mm(equiv[0], scene.image_size, log_sd=equiv[1], dof=equiv[2], source="scene")
            x, _, z = scene.targets[0].ground_truth["location_m"]
            d_true = float(np.hypot(x, z))
            for n_refs in REFS:
                t0 = time.process_time()
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    r = estimate(variant(scene, 1, tuple(range(n_refs))), seed=k, focal_prior=focal,
                                 location_prior=args.location_prior, distance_range=distance_range,
                                 sampling={"min_ess": args.min_ess}, keep_draws=0)
                seconds = time.process_time() - t0
                o = r.to_dict()["objects"][0]
                dist = np.hypot(r.draws.objects[..., 0, 0], r.draws.objects[..., 0, 1]).ravel()
                lo, hi = o["posterior"]["hdi"]["distance_m"]
                rec = {"scene": k, "tier": TIERS[k % 2], "refs": n_refs, "distance": d_true,
                       "camera": scene.ground_truth.get("camera_kind", "outdoor"),
                       "quantile": float(np.mean(dist < d_true)),
                       "prior_quantile": _prior_quantile(scene, focal), "hdi": [lo, hi],
                       "covered": bool(lo <= d_true <= hi), "map_error": o["evaluation"]["location_pct_error"],
                       "post_error": o["evaluation"]["posterior_location_pct_error"],
                       "converged": bool(r.converged), "seconds": seconds,
                       "overflow_warnings": sum("overflow" in str(w.message) for w in caught)}
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
    groups = REFS if by == "refs" else sorted({r["camera"] for r in records})
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
    args = p.parse_args(argv)
    records = run(args)
    text = (table(records) + f"\n{scene_bootstrap(records)}\n"
            + ("" if args.cameras == "setting" else "\nBy camera:\n\n" + table(records, "camera")))
    (Path(args.out) / "thin.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
