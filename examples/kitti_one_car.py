"""One car a scene on real KITTI photos: is the image horizon trusted only as much as it deserves?

    python examples/kitti_one_car.py KITTI_DIR [--cars-per-frame 2] [--annotations 13]
                                     [--focal unknown|known] [--level-sd PX] [--seed 0] [--limit N]
                                     [--json FILE]

KITTI_DIR is a folder in KITTI's object layout (``label_2/``, ``calib/``, ``image_2/``). For each
frame with an image, up to ``--cars-per-frame`` of its cars (chosen with the seed among the objects
``creference simulate --from-kitti`` keeps: 2D box ≥ 25 px, truncation ≤ 0.5, occlusion ≤ 2, the
annotated corners in the image) become scenes of one target (``creference-scene/2``):

- the target: the car with its true size (the single-target model's "object of known size") and
  ``--annotations`` sets of dimension lines, the projections of its real corners (P2) moved by
  ``--noise-px`` Gaussian pixel noise and rounded to 0.01 px;
- the references: every other object of the frame that is kept, as a worker's stated *range* for
  the length of its bottom edge (the line drawn from its nearest bottom corner along its length,
  with the same pixel noise): the true length times a heavy-tailed error (the bench's
  "paper-like" workers: log-factor 0.75·t₂, clipped at ×20) and a stated precision drawn as the
  bench draws it (median 25 %: over-confident for such errors);
- the camera: P2's principal point; the focal length unknown (the default prior) or, with
  ``--focal known``, P2's.

Every scene is estimated twice with the same seed: with the horizon found in the photo (no
``horizon`` key; the package estimates it from ``image.path``) and with the level horizon given
(the row c_y of P2 across the image, exact: KITTI's rectified camera is level to about a degree).
With ``--level-sd PX`` a third time, with the same level horizon given as a measurement known to
PX pixels (``horizon_sd_px``): a horizon as good as the level one but stated with an uncertainty
like the image's, which tells what the stated uncertainty costs apart from the image horizon's
error. The truth is KITTI's label moved into P2's camera frame. Prints per variant: the share of scenes
whose true distance lies in the 90 % HDI, the median and mean location error (MAP and posterior
mean, % of the true distance), the share converged, and the CPU time per estimate; then the
ratio of the image variant's median error to the level variant's, and the errors by how far the
image horizon is from the level row. The KITTI frames are not part of the
package (licence CC BY-NC-SA 3.0): this script only reads them from the folder given.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np


def one_car_scenes(folder: Path, *, cars_per_frame: int, n_annotations: int, noise_px: float,
                   focal: str, seed: int, limit: int | None = None):
    """Yield (scene id, scene dict with the image, the level horizon (2, 2) px) per chosen car."""
    from creference_bayes.bench.kitti import kitti_scene
    from creference_bayes.bench.simulate import RANGE_PRECISION, measurement_factor

    labels = sorted((folder / "label_2").glob("*.txt"))
    if limit is not None:
        labels = labels[:limit]
    for k, lp in enumerate(labels):
        image = folder / "image_2" / (lp.stem + ".png")
        if not image.exists():
            continue
        rng = np.random.default_rng([seed, k])
        frame, _ = kitti_scene(lp, folder / "calib" / lp.name, image.resolve(), rng=rng,
                               n_annotations=n_annotations, noise_px=noise_px, frame_id=lp.stem)
        objs = frame["targets"]
        cars = [i for i, o in enumerate(objs) if o["class"] == "Car"]
        if not cars:
            continue
        chosen = rng.permutation(cars)[:cars_per_frame]
        cam = frame["camera"]
        w, h = frame["image"]["width"], frame["image"]["height"]
        cy = cam["principal_point"][1]
        for i in sorted(int(c) for c in chosen):
            car = objs[i]
            refs = []
            for j, o in enumerate(objs):
                if j == i:
                    continue
                line = np.asarray(o["dimension_lines"][0]["corners"])[:2]  # c1 → along the length
                true_len = o["ground_truth"]["dimensions_m"]["length"]
                stated = true_len * measurement_factor(rng, "paper")
                precision = min(float(np.exp(rng.normal(math.log(RANGE_PRECISION["median"]),
                                                        RANGE_PRECISION["log_sd"]))), 1.9)
                refs.append({"worker": f"r{len(refs) + 1:02d}", "object": o["class"].lower(),
                             "measure": "length", "mode": "direct", "unit": "m",
                             "range": [round(stated * (1 - precision / 2), 4), round(stated * (1 + precision / 2), 4)],
                             "line": line.tolist()})
            scene = {
                "format": "creference-scene/2",
                "image": {"width": w, "height": h, "path": frame["image"]["path"]},
                "camera": {"principal_point": cam["principal_point"],
                           "focal_length_px": cam["focal_length_px"] if focal == "known" else None},
                "targets": [{**car, "id": f"{lp.stem}-{car['id']}", "dimensions_m": car["ground_truth"]["dimensions_m"]}],
                "references": refs,
                "ground_truth": {"focal_length_px": cam["focal_length_px"]},
            }
            yield f"{lp.stem}-{car['id']}", scene, np.array([[0.0, cy], [float(w), cy]])


def run(folder: Path, *, cars_per_frame: int = 2, n_annotations: int = 13, noise_px: float = 2.0,
        focal: str = "unknown", seed: int = 0, limit: int | None = None, sampling: dict | None = None,
        level_sd_px: float | None = None, say=print) -> list[dict]:
    """Estimate every one-car scene with the image horizon and with the level horizon (and, with
    ``level_sd_px``, the level horizon stated to that many pixels); one row each."""
    from creference_bayes.pipeline import estimate
    from creference_bayes.io.scene import parse_scene

    rows = []
    for sid, scene, level in one_car_scenes(folder, cars_per_frame=cars_per_frame, n_annotations=n_annotations,
                                            noise_px=noise_px, focal=focal, seed=seed, limit=limit):
        loc = np.asarray(scene["targets"][0]["ground_truth"]["location_m"])
        row = {"scene": sid, "distance_m": float(np.hypot(loc[0], loc[2])), "references": len(scene["references"])}
        for variant in ("image", "level") + (() if level_sd_px is None else ("level_sd",)):
            data = {"image": scene, "level": dict(scene, horizon=level.tolist()),
                    "level_sd": dict(scene, horizon=level.tolist(), horizon_sd_px=level_sd_px)}[variant]
            t0 = time.process_time()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                res = estimate(parse_scene(data), seed=seed, sampling=sampling, keep_draws=0)
            d = res.to_dict()
            o = d["objects"][0]
            ev = o["evaluation"]
            row[variant] = {"map_pct": ev["location_pct_error"], "mean_pct": ev["posterior_location_pct_error"],
                            "in90": bool(ev["distance_in_hdi"]), "converged": bool(res.converged),
                            "hdi_m": o["posterior"]["hdi"]["distance_m"] if "posterior" in o else None,
                            "seconds": time.process_time() - t0, "warnings": len(caught)}
            setup = d["camera"]["setup"]
            hz = setup.get("horizon") or {}
            row[variant]["orientation"] = setup.get("orientation")
            row[variant]["horizon_source"] = hz.get("source")
            if variant == "image":  # the larger of the two edges' |row − c_y|, pixels (None: no horizon found)
                row["horizon_error_px"] = (None if not hz.get("points") else
                                           float(np.max(np.abs(np.asarray(hz["points"])[:, 1] - level[0, 1]))))
        say(f"{sid}: {row['distance_m']:5.1f} m, {row['references']} refs  "
            f"image {row['image']['mean_pct']:6.1f} % {'in ' if row['image']['in90'] else 'OUT'}  "
            f"level {row['level']['mean_pct']:6.1f} % {'in ' if row['level']['in90'] else 'OUT'}  "
            f"({row['image']['seconds']:.1f} s, {row['level']['seconds']:.1f} s)")
        rows.append(row)
    return rows


def summary(rows: list[dict]) -> dict:
    """Per variant: coverage, median/mean MAP and posterior-mean errors, converged, time; the ratio."""
    out = {}
    for v in ("image", "level") + (("level_sd",) if "level_sd" in rows[0] else ()):
        r = [row[v] for row in rows]
        out[v] = {"scenes": len(r),
                  "coverage_90": float(np.mean([x["in90"] for x in r])),
                  "map_median_pct": float(np.median([x["map_pct"] for x in r])),
                  "map_mean_pct": float(np.mean([x["map_pct"] for x in r])),
                  "mean_median_pct": float(np.median([x["mean_pct"] for x in r])),
                  "mean_mean_pct": float(np.mean([x["mean_pct"] for x in r])),
                  "converged": float(np.mean([x["converged"] for x in r])),
                  "median_s": float(np.median([x["seconds"] for x in r])),
                  "max_s": float(np.max([x["seconds"] for x in r]))}
    out["median_ratio_map"] = out["image"]["map_median_pct"] / out["level"]["map_median_pct"]
    out["median_ratio_mean"] = out["image"]["mean_median_pct"] / out["level"]["mean_median_pct"]
    bands = []
    for lo, hi in HORIZON_BANDS:
        r = [row for row in rows if row["horizon_error_px"] is not None and lo <= row["horizon_error_px"] < hi]
        bands.append({"horizon_error_px": [lo, hi if math.isfinite(hi) else None], "scenes": len(r),
                      **{f"{v}_{k}": (float(np.median([x[v][k] for x in r])) if r else None)
                         for v in ("image", "level") for k in ("map_pct", "mean_pct")},
                      "image_coverage_90": float(np.mean([x["image"]["in90"] for x in r])) if r else None})
    out["by_horizon_error"] = bands
    out["no_image_horizon"] = sum(row["horizon_error_px"] is None for row in rows)
    return out


#: Bands of the image horizon's error (the larger of its two edges' |row − c_y|, pixels).
HORIZON_BANDS = ((0.0, 15.0), (15.0, 30.0), (30.0, 60.0), (60.0, math.inf))


def print_table(s: dict, say=print) -> None:
    say("| horizon | scenes | 90 % HDI holds the distance | median / mean error, MAP (%) | "
        "median / mean error, posterior mean (%) | converged | median / max s |")
    say("|---|---|---|---|---|---|---|")
    for v, name in (("image", "from the image"), ("level", "level, given"), ("level_sd", "level, given ± sd")):
        if v not in s:
            continue
        x = s[v]
        say(f"| {name} | {x['scenes']} | {100 * x['coverage_90']:.0f} % | {x['map_median_pct']:.1f} / "
            f"{x['map_mean_pct']:.1f} | {x['mean_median_pct']:.1f} / {x['mean_mean_pct']:.1f} | "
            f"{100 * x['converged']:.0f} % | {x['median_s']:.1f} / {x['max_s']:.1f} |")
    say(f"median error, image / level: {s['median_ratio_map']:.2f}× (MAP), {s['median_ratio_mean']:.2f}× (posterior mean)")
    if "level_sd" in s:
        x, y = s["level_sd"], s["level"]
        say(f"median error, level ± sd / level: {x['map_median_pct'] / y['map_median_pct']:.2f}× (MAP), "
            f"{x['mean_median_pct'] / y['mean_median_pct']:.2f}× (posterior mean)")
    say("")
    say("| image horizon's error (px) | scenes | median error, image horizon: MAP / mean (%) | "
        "level horizon: MAP / mean (%) | image: 90 % HDI holds the distance |")
    say("|---|---|---|---|---|")
    for b in s["by_horizon_error"]:
        lo, hi = b["horizon_error_px"]
        name = f"≥ {lo:.0f}" if hi is None else f"{lo:.0f}–{hi:.0f}"
        if not b["scenes"]:
            say(f"| {name} | 0 | | | |")
            continue
        say(f"| {name} | {b['scenes']} | {b['image_map_pct']:.1f} / {b['image_mean_pct']:.1f} | "
            f"{b['level_map_pct']:.1f} / {b['level_mean_pct']:.1f} | {100 * b['image_coverage_90']:.0f} % |")
    if s["no_image_horizon"]:
        n = s["no_image_horizon"]
        say(f"({n} scene{'' if n == 1 else 's'} without an image horizon)")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("kitti", type=Path, help="a KITTI folder (label_2/, calib/, image_2/)")
    p.add_argument("--cars-per-frame", type=int, default=2)
    p.add_argument("--annotations", type=int, default=13)
    p.add_argument("--noise-px", type=float, default=2.0)
    p.add_argument("--focal", choices=("unknown", "known"), default="unknown")
    p.add_argument("--level-sd", type=float, default=None, metavar="PX",
                   help="also estimate with the level horizon given as a measurement known to PX pixels")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--limit", type=int, default=None, help="the first N frames only")
    p.add_argument("--min-ess", type=int, default=None, help="the sampler's effective sample size target")
    p.add_argument("--json", type=Path, default=None, help="write the rows and the summary here")
    a = p.parse_args(argv)
    for sub in ("label_2", "calib", "image_2"):
        if not (a.kitti / sub).is_dir():
            p.error(f"{a.kitti}: expected the folder {sub}/ (KITTI's object layout)")
    if a.level_sd is not None and not (math.isfinite(a.level_sd) and a.level_sd > 0):
        p.error(f"--level-sd: expected a number of pixels > 0, got {a.level_sd}")
    rows = run(a.kitti, cars_per_frame=a.cars_per_frame, n_annotations=a.annotations, noise_px=a.noise_px,
               focal=a.focal, seed=a.seed, limit=a.limit, level_sd_px=a.level_sd,
               sampling=None if a.min_ess is None else {"min_ess": a.min_ess})
    if not rows:
        print(f"{a.kitti}: no frame with an image and a car", file=sys.stderr)
        return 1
    s = summary(rows)
    print_table(s)
    if a.json is not None:
        from creference_bayes.io.files import atomic_write_json

        atomic_write_json(a.json, {"rows": rows, "summary": s, "options": {k: str(v) for k, v in vars(a).items()}})
    return 0


if __name__ == "__main__":
    sys.exit(main())
