"""The data set's distance population, checked offline against the truth from a batch folder's
first pass (docs/studies/rig.md, "Mixed settings and thin coverage"; workflows/batch/dataset.py).

    python examples/distance_population.py BATCH [--reading-sd-scale 1.0]

BATCH is a ``creference batch`` folder of simulated scenes (``ground_truth`` on every target, as
``examples/thin_designs.py`` writes them) whose ``first_pass/`` is complete. Per setting (the
scenes' ``ground_truth.setting``) and camera kind: each target's reading of log distance against
the truth (mean error and the sd of z = error × √precision: 1 for honest readings), and the prior
each frame is handed (leave-one-out; none when the group looks like two populations) as a
forecast of its targets' true log distance: the truth's mean quantile in it and the share inside
its central 90 %.
``--reading-sd-scale``: every reading's sd multiplied by this before pooling (what if the
readings were that much less sure).
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

import numpy as np
from scipy import stats

from creference_bayes.io.scene import SceneWarning, load_scene
from creference_bayes.workflows.batch import dataset as D


def truths(first: Path) -> dict:
    """KEY → (setting, camera kind or None, [true log ground distance of each target])."""
    out = {}
    for path in sorted((first / "results").glob("*.json")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            scene = load_scene(first / "scenes" / path.name)
        gt = scene.ground_truth or {}
        logs = [0.5 * math.log(t.ground_truth["location_m"][0] ** 2 + t.ground_truth["location_m"][2] ** 2)
                for t in scene.targets]
        out[path.stem] = (gt.get("setting", "-"), gt.get("camera_kind"), logs)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch", type=Path)
    ap.add_argument("--reading-sd-scale", type=float, default=1.0)
    args = ap.parse_args(argv)
    first = args.batch / "first_pass"
    truth = truths(first)
    ds = D.DataSet.from_first_pass([(k, None) for k in truth], first, ("log_distance",))
    pool = ds.pools["log_distance"]
    if args.reading_sd_scale != 1.0:
        readings = [D.Reading(k, g, m, p / args.reading_sd_scale**2) for g, (ks, ms, ps) in pool.groups.items()
                    for k, m, p in zip(ks, ms, ps)]
        ds.pools["log_distance"] = pool = D.Pool(pool.quantity, readings)
    rows = []
    for g, (keys, m, p) in pool.groups.items():
        seen: dict = {}
        for k, mi, pi in zip(keys, m, p):
            j = seen[k] = seen.get(k, -1) + 1
            setting, kind, logs = truth[k]
            rows.append({"setting": setting, "kind": kind, "z": (mi - logs[j]) * math.sqrt(pi), "err": mi - logs[j]})
        full = pool.estimate(g)
        print(f"group {g}: {len(m)} readings; pool of all frames: {math.exp(full.center):.1f} m (prior sd "
              f"{full.prior_sd:.3f}); {', '.join(full.check.warnings) or 'no warning'}")
    forecasts = []
    for k, (setting, kind, logs) in truth.items():
        est = ds.estimate("log_distance", k)
        if est is None or D.TWO_POPULATIONS in est.check.warnings:  # handed none
            continue
        for y in logs:
            q = float(stats.norm.cdf((y - est.center) / est.prior_sd))
            forecasts.append({"setting": setting, "kind": kind, "q": q, "in90": 0.05 <= q <= 0.95})
    print("\n| by | readings | mean error (log d) | z mean | z sd | prior forecasts | truth's mean quantile | "
          "inside its 90 % |\n|---|---|---|---|---|---|---|---|")
    for by in ("setting", "kind"):
        for v in sorted({r[by] for r in rows} - {None}):  # scenes without a camera kind: no such rows
            r = [x for x in rows if x[by] == v]
            f = [x for x in forecasts if x[by] == v]
            z = np.array([x["z"] for x in r])
            fq = (f"{np.mean([x['q'] for x in f]):.2f} | {100 * np.mean([x['in90'] for x in f]):.0f} %" if f
                  else "– | –")
            print(f"| {v} | {len(r)} | {np.mean([x['err'] for x in r]):+.3f} | {z.mean():+.2f} | {z.std():.2f} | "
                  f"{len(f)} | {fq} |")


if __name__ == "__main__":
    main()
