"""Calibration of data-rich one-target scenes whose reference segments are drawn with noise, read
two ways (docs/studies/method.md, "A drawn reference's end points").

Scenes of the simulator's crowds (``creference_bayes.bench.simulate.CROWDS``): ``light`` (2 px
corners, 5 px reference end points, log-sd 0.1) and ``heavy`` (5 px corners, 10 px end points,
log-sd 0.55, 12 % outliers); each scene has 13 sets of dimension lines, 20 references cycling
through the paper's ten formats (direct and relative, values and ranges, lengths, widths and
distances), the exact horizon, the focal length unknown; indoor and outdoor alternate. Every scene
is estimated once per ``--readings`` (the metrology model's ``line_reading``), with the same
seed. Per crowd and reading: the 90 % HDI's coverage of the target's distance and of the focal
length, the mean quantile of each truth in its posterior, the share of truths above the posterior
median, the median HDI width over the distance, the MAP's and posterior mean's location errors,
and CPU seconds; under the table, 95 % bootstrap intervals over scenes.

Usage::

    python examples/reference_reading_study.py --n 100 --crowds light --out rr_light
    python examples/reference_reading_study.py --n 100 --crowds heavy --out rr_heavy
    python examples/reference_reading_study.py --report --out rr_light

Records go to ``OUT/records.jsonl`` (one line per estimate; a run continues where a previous one
into the same folder stopped), the table to ``OUT/table.md``. About 3–4 s of CPU per estimate.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.bench.simulate import CROWDS, simulate_scene
from creference_bayes.evaluation.reliability import cluster_bootstrap
from creference_bayes.io.scene import parse_scene
from creference_bayes.models.metrology import LINE_READINGS
from creference_bayes.pipeline import estimate

SETTINGS = ("indoor", "outdoor")


def scene(crowd: str, k: int):
    """The k-th scene of a crowd (module docstring); indoor for even k, outdoor for odd."""
    d = simulate_scene(np.random.default_rng([66, list(CROWDS).index(crowd), k]), setting=SETTINGS[k % 2],
                       tier=crowd, n_target_annotations=13, n_references=20, format_offset=5 * k)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene(d)


def record(sc, result, crowd: str, k: int, reading: str, seconds: float) -> dict:
    """What one estimate says about its truth (module docstring)."""
    cams, objs = result.draws.cameras, result.draws.objects[..., 0, :]
    d = result.to_dict()
    x, _, z = sc.targets[0].ground_truth["location_m"]
    truth = {"distance_m": float(np.hypot(x, z)), "focal_length_px": float(sc.ground_truth["focal_length_px"])}
    draws = {"distance_m": np.hypot(objs[..., 0], objs[..., 1]).ravel(), "focal_length_px": cams[..., 0].ravel()}
    hdis = {"distance_m": d["objects"][0]["posterior"]["hdi"]["distance_m"],
            "focal_length_px": d["camera"]["posterior"]["hdi"]["focal_length_px"]}
    o = d["objects"][0]
    return {"crowd": crowd, "scene": k, "setting": SETTINGS[k % 2], "reading": reading,
            **{f"quantile_{q}": float(np.mean(draws[q] < truth[q])) for q in truth},
            **{f"covered_{q}": bool(hdis[q][0] <= truth[q] <= hdis[q][1]) for q in truth},
            "hdi_over_distance": (hdis["distance_m"][1] - hdis["distance_m"][0]) / truth["distance_m"],
            "map_error": o["evaluation"]["location_pct_error"], "post_error": o["evaluation"]["posterior_location_pct_error"],
            "converged": bool(result.converged), "seconds": seconds}


def run(args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "records.jsonl"
    done = {(r["crowd"], r["scene"], r["reading"]) for r in _load(path)}
    with open(path, "a") as f:
        for k in range(args.n):
            for crowd in args.crowds:
                sc = None
                for reading in args.readings:
                    if (crowd, k, reading) in done:
                        continue
                    sc = sc or scene(crowd, k)
                    t0 = time.process_time()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        r = estimate(sc, seed=k, line_reading=reading, sampling={"min_ess": args.min_ess}, keep_draws=0)
                    rec = record(sc, r, crowd, k, reading, time.process_time() - t0)
                    f.write(json.dumps(rec) + "\n")
                    f.flush()
                    if not args.quiet:
                        print(f"{crowd} {k} {reading}: distance q {rec['quantile_distance_m']:.2f} "
                              f"covered {rec['covered_distance_m']}, focal q {rec['quantile_focal_length_px']:.2f} "
                              f"covered {rec['covered_focal_length_px']}, {rec['seconds']:.1f} s", flush=True)


def _load(path: Path) -> list[dict]:
    return [json.loads(line) for line in open(path)] if path.exists() else []


def table(records: list[dict]) -> str:
    """One row per crowd, setting (and both) and reading; bootstrap intervals under it."""
    head = ("| crowd | setting | reading | estimates | distance: 90 % HDI covers | mean quantile | truth above the median "
            "| focal length: 90 % HDI covers | mean quantile | median HDI / distance | MAP error % median / mean "
            "| posterior-mean error % median / mean | converged | CPU s median / max |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows, intervals = [], []
    keys = sorted({(r["crowd"], r["reading"]) for r in records}, key=lambda c: (list(CROWDS).index(c[0]), c[1]))
    for crowd, reading in keys:
        for setting in (*SETTINGS, "both"):
            s = [r for r in records if r["crowd"] == crowd and r["reading"] == reading
                 and setting in ("both", r["setting"])]
            if not s:
                continue
            col = lambda key: np.array([r[key] for r in s], float)  # noqa: E731
            me, pe, sec = col("map_error"), col("post_error"), col("seconds")
            rows.append(f"| {crowd} | {setting} | {reading} | {len(s)} | {100 * col('covered_distance_m').mean():.0f} % | "
                        f"{col('quantile_distance_m').mean():.2f} | {100 * np.mean(col('quantile_distance_m') > 0.5):.0f} % | "
                        f"{100 * col('covered_focal_length_px').mean():.0f} % | {col('quantile_focal_length_px').mean():.2f} | "
                        f"{np.median(col('hdi_over_distance')):.3f} | {np.median(me):.1f} / {me.mean():.1f} | "
                        f"{np.median(pe):.1f} / {pe.mean():.1f} | {100 * col('converged').mean():.0f} % | "
                        f"{np.median(sec):.1f} / {sec.max():.1f} |")
        s = [r for r in records if r["crowd"] == crowd and r["reading"] == reading]
        lo, hi = cluster_bootstrap([[r["covered_distance_m"], r["quantile_distance_m"], r["covered_focal_length_px"],
                                     r["quantile_focal_length_px"]] for r in s], [r["scene"] for r in s])
        intervals.append(f"- {crowd}, {reading}: distance coverage {100 * lo[0]:.0f}–{100 * hi[0]:.0f} %, mean quantile "
                         f"{lo[1]:.2f}–{hi[1]:.2f}; focal length coverage {100 * lo[2]:.0f}–{100 * hi[2]:.0f} %, mean "
                         f"quantile {lo[3]:.2f}–{hi[3]:.2f}")
    return "\n".join([head, *rows]) + "\n\n95 % bootstrap intervals over scenes:\n\n" + "\n".join(intervals) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=100, help="scenes per crowd (default: %(default)s)")
    p.add_argument("--crowds", default="light,heavy", type=lambda v: v.split(","),
                   help=f"comma-separated, of {list(CROWDS)} (default: %(default)s)")
    p.add_argument("--readings", default="linear,marginal", type=lambda v: v.split(","),
                   help=f"comma-separated, of {list(LINE_READINGS)} (default: %(default)s)")
    p.add_argument("--min-ess", type=int, default=400, help="bulk ESS of each posterior (default: %(default)s)")
    p.add_argument("--out", default="reference_reading", help="output folder (default: %(default)s)")
    p.add_argument("--report", action="store_true", help="only write the table of the records in --out")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    for name, values, allowed in (("--crowds", args.crowds, CROWDS), ("--readings", args.readings, LINE_READINGS)):
        bad = [v for v in values if v not in allowed]
        if bad:
            p.error(f"{name}: unknown {bad} (expected some of {list(allowed)})")
    if not args.report:
        run(args)
    text = table(_load(Path(args.out) / "records.jsonl"))
    (Path(args.out) / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
