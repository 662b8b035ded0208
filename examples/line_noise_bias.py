"""How far off is the length a model reads from a noisy reference line? (docs/method.md, "The
metrology model": line noise.)

The metrology model reads a reference's ground length from the segment as drawn (its option
``line_reading="linear"``, the default) or less the lengthening the drawn segment's pixel noise
brings (``"corrected"``: its shift, :func:`~creference_bayes.models.metrology.segment_reading`).
On the bench's simulator this script measures, at the *true* camera and location of each scene,
the reading of every reference's true segment moved by the tier's endpoint noise (``--draws``
noise draws per segment): the median shift of the raw log ℓ from the true log-length (the bias a
worker's exact value meets when the segment is read as drawn), its 10th and 90th percentiles over
the segments, the same for the corrected reading log ℓ − shift (on the first ``--corrected`` draws
of each segment, each drawn segment corrected by its own shift), and the ratio of the raw
reading's spread (half the 16–84 % range) to the linearised sd at the true segment. Rows by noise
tier and by what the segment measures.

``--estimates N`` also estimates N paper-like (high tier) scenes four times: with the references'
lines as simulated and drawn exactly, each read as drawn and corrected (the same scenes, seeds
and everything else), for one set of dimension lines with 2 references and for 5 with 5: how do
the lengthening and its correction move the MAP? (median and mean of log(MAP distance / true
distance), the MAP's location error, and the mean paired difference of that error, corrected
minus linear.) ``--focal-prior MEDIAN,LOG_SD`` has every scene state a focal-length prior
(1650,0.27 fits the simulator's cameras).

Usage::

    python examples/line_noise_bias.py --n 80             # 80 scenes a tier, 10 segments each
    python examples/line_noise_bias.py --n 80 --estimates 60
    python examples/line_noise_bias.py --n 80 --estimates 60 --focal-prior 1650,0.27

A shift of 0 and a spread ratio of 1 would mean the raw reading is right. The tables are in
docs/method.md ("Line noise"). About a minute for 80 scenes a tier, and a minute for
``--estimates 60``.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from creference_bayes.bench.simulate import TIERS, simulate_scene, true_state
from creference_bayes.camera_setup import setup_camera
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.metrology import ground_lengths, linear_line_variances, segment_reading


def _read(lines, pp, truth) -> np.ndarray:
    """log ℓ of (k, 2, 2) segments at the (1, 5) true camera ``truth``, (k,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log(ground_lengths(lines.reshape(-1, 2, 2), pp, truth))[0]


def measure(n: int, tiers: list[str], draws: int, seed: int, corrected: int = 40) -> list[dict]:
    """One record per reference segment: tier, measure, the median shift of the noisy reading's
    log-length, of the corrected reading's (its first ``corrected`` draws), and the raw reading's
    spread against the linearised one."""
    rng = np.random.default_rng(seed)
    out = []
    for tier in tiers:
        sigma = TIERS[tier].reference_px
        for k in range(n):
            d = simulate_scene(np.random.default_rng([seed, k]), tier=tier, n_references=10)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                scene = parse_scene(d)
            truth = true_state(scene)[0][None]
            pp = setup_camera(scene).camera.principal_point
            gt = scene.ground_truth
            for ref, line, length in zip(scene.references, gt["reference_lines_px"], gt["reference_lengths_m"]):
                line = np.asarray(line, float)
                lin_sd = float(np.sqrt(linear_line_variances(line[None], pp, truth[0], sigma)[0]))  # as the model's
                drawn = line[None] + rng.normal(0.0, sigma, (draws, 2, 2))
                noisy = _read(drawn, pp, truth)
                ok = np.isfinite(noisy)
                if ok.mean() < 0.5:
                    continue
                lo, med, hi = np.quantile(noisy[ok], [0.16, 0.5, 0.84])
                k = min(corrected, draws)
                fixed = noisy[:k] - segment_reading(drawn[:k], pp, truth[0], sigma)[0] if k else np.full(1, np.nan)
                out.append({"tier": tier, "measure": ref.measure, "shift": float(med - np.log(length)),
                            "corrected_shift": float(np.nanmedian(np.where(np.isfinite(fixed), fixed, np.nan))
                                                     - np.log(length)) if k else float("nan"),
                            "spread_ratio": float(0.5 * (hi - lo) / lin_sd) if lin_sd > 0 else float("nan")})
    return out


def table(records: list[dict]) -> str:
    head = ("| tier (endpoint σ) | measure | segments | median shift of log ℓ | 10th / 90th percentile | "
            "corrected: median shift | 10th / 90th percentile | spread / linearised sd, median |\n"
            "|---|---|---|---|---|---|---|---|")
    rows = []
    for tier in dict.fromkeys(r["tier"] for r in records):
        for measure in ("length", "width", "distance", "all"):
            s = [r for r in records if r["tier"] == tier and (measure == "all" or r["measure"] == measure)]
            if not s:
                continue
            shift = np.array([r["shift"] for r in s])
            fixed = np.array([r["corrected_shift"] for r in s])
            ratio = np.array([r["spread_ratio"] for r in s])
            p10, p50, p90 = np.percentile(shift, [10, 50, 90])
            c10, c50, c90 = np.nanpercentile(fixed, [10, 50, 90]) if np.isfinite(fixed).any() else [np.nan] * 3
            rows.append(f"| {tier} ({TIERS[tier].reference_px:g} px) | {measure} | {len(s)} | {p50:+.3f} | "
                        f"{p10:+.3f} / {p90:+.3f} | {c50:+.3f} | {c10:+.3f} / {c90:+.3f} | "
                        f"{np.nanmedian(ratio) if np.isfinite(ratio).any() else np.nan:.2f} |")
    return "\n".join([head, *rows])


def estimates(n: int, seed: int, focal_prior=None) -> str:
    """The MAP's distance on paper-like scenes, for one set + 2 references and 5 + 5, with the
    references' lines as simulated and drawn exactly, each read as drawn (``linear``) and less
    the lengthening their noise brings (``corrected``); ``focal_prior`` (median px, log-sd) is
    stated by every scene when given (a Markdown table)."""
    import dataclasses

    from creference_bayes.bench.simulate import NoiseTier
    from creference_bayes.models.camera_terms import FocalPrior
    from creference_bayes.pipeline import estimate

    high = TIERS["high"]
    exact = NoiseTier("high, exact reference lines", high.target_px, 0.0, high.measurement)
    prior = None if focal_prior is None else FocalPrior(focal_prior[0], focal_prior[1], np.inf, source="scene")
    rows = ["| design | reference lines | line reading | scenes | log(MAP distance / true), median / mean | "
            "MAP location error %, median / mean | corrected − linear, mean [90 % bootstrap] |",
            "|---|---|---|---|---|---|---|"]
    for n_t, n_r in ((1, 2), (5, 5)):
        for label, tier in (("as simulated (30 px)", high), ("exact", exact)):
            errors = {}
            for reading in ("linear", "corrected"):
                logs, errors[reading] = [], []
                for k in range(n):
                    d = simulate_scene(np.random.default_rng([seed, 1000 + k]), tier=tier,
                                       n_target_annotations=n_t, n_references=n_r)
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        scene = parse_scene(d)
                        if prior is not None:
                            scene = dataclasses.replace(scene, focal_prior=prior)
                        o = estimate(scene, seed=k, posterior=False, line_reading=reading).to_dict()["objects"][0]
                    g, m = scene.targets[0].ground_truth["location_m"], o["map"]
                    logs.append(np.log(m["distance_m"] / np.hypot(g[0], g[2])))
                    errors[reading].append(o["evaluation"]["location_pct_error"])
                diff = ""
                if reading == "corrected":
                    dd = np.subtract(errors["corrected"], errors["linear"])
                    boot = np.random.default_rng(0).choice(dd, (2000, len(dd))).mean(axis=1)
                    diff = f"{dd.mean():+.2f} [{np.percentile(boot, 5):+.2f}, {np.percentile(boot, 95):+.2f}]"
                rows.append(f"| {n_t} + {n_r} | {label} | {reading} | {n} | {np.median(logs):+.3f} / "
                            f"{np.mean(logs):+.3f} | {np.median(errors[reading]):.1f} / {np.mean(errors[reading]):.1f} | "
                            f"{diff} |")
    return "\n".join(rows)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=80, help="scenes per tier (default: %(default)s)")
    p.add_argument("--tiers", default="medium,high", help="noise tiers (default: %(default)s)")
    p.add_argument("--draws", type=int, default=2000, help="noise draws per segment (default: %(default)s)")
    p.add_argument("--corrected", type=int, default=40,
                   help="of them, draws read with the model's correction (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--estimates", type=int, default=0, metavar="N",
                   help="also estimate N paper-like scenes with the reference lines as simulated and exact, "
                        "read as drawn and corrected")
    p.add_argument("--focal-prior", metavar="MEDIAN,LOG_SD",
                   help="with --estimates: every scene states a log-normal focal-length prior (e.g. 1650,0.27, "
                        "the simulator's cameras); default: the package's default prior")
    args = p.parse_args(argv)
    tiers = args.tiers.split(",")
    for t in tiers:
        if t not in TIERS:
            p.error(f"--tiers: unknown tier {t!r} (expected some of {list(TIERS)})")
    print(table(measure(args.n, tiers, args.draws, args.seed, args.corrected)))
    prior = None
    if args.focal_prior:
        try:
            prior = tuple(float(v) for v in args.focal_prior.split(","))
            if len(prior) != 2 or min(prior) <= 0:
                raise ValueError("two positive numbers")
        except ValueError as e:
            p.error(f"--focal-prior: expected MEDIAN,LOG_SD (two positive numbers), got {args.focal_prior!r} ({e})")
    if args.estimates:
        print()
        print(estimates(args.estimates, args.seed, prior))


if __name__ == "__main__":
    main()
