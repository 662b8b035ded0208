"""The rig's pool of each camera, before and after the rule of issue 62, recomputed offline from a
batch folder's first pass (docs/studies/rig.md; creference_bayes/workflows/batch/rig.py).

    python examples/rig_pool.py BATCH [--groups 0-24,25-50] [--rig focal]

BATCH is a ``creference batch`` folder whose ``first_pass/`` is complete (the second pass is not
needed); its frames are read as the batch reads them (a MAP's Laplace approximation, or the
posterior draws a first pass of an earlier version kept). ``before`` needs kept draws. For every camera with two or more frames, and for all its frames and each group
of frames (frames named by an integer, e.g. KITTI's index: ``0-24`` takes frames 0 to 24; ``even``,
``odd``), the
pooled focal length under

- ``before``: the rule before issue 62 (the frame's prior divided out by a Laplace step at the
  posterior mean; every frame with at least a tenth of its posterior precision pooled; no floor);
- ``after``: the package's rule (:mod:`creference_bayes.workflows.batch.rig`: prior divided out
  exactly, informative frames only, the floor, the checks),

with, when the frames' scenes carry a ground-truth focal length (``simulate --from-kitti`` writes
the calibration's), the error and z = error / stated sd. Columns: pooled µ px, % vs truth, stated
log-sd, z, frames used/offered, n_eff, top-3 weight share, D, warnings; then the shared bias the
groups show, √mean(e² − V) over the groups (V without the floor: what the floor should cover).
"""

from __future__ import annotations

import argparse
import json
import math
import warnings
from pathlib import Path

import numpy as np

from creference_bayes.io.result import read_result, stored_draws
from creference_bayes.io.scene import SceneWarning, load_scene
from creference_bayes.workflows.batch import dataset as D
from creference_bayes.workflows.batch import rig as R


def laplace_likelihood(result: dict) -> tuple[float, float] | None:
    """The log-focal likelihood (mean, precision) by the rule before issue 62: a Laplace step at the
    posterior mean, frames with at least MIN_INFORMATION of their posterior precision."""
    draws = stored_draws(result)
    if draws is None or "focal_length_px" not in result["camera"].get("free", ()):  # a MAP first pass: none
        return None
    v = np.log(draws.cameras.reshape(-1, 5)[:, 0])
    m, var = float(v.mean()), float(v.var(ddof=1))
    post = 1.0 / var
    p = (result["camera"].get("setup") or {}).get("focal_prior")
    grad = curv = 0.0
    if p:
        s, r = float(p["log_sd"]), m - math.log(float(p["median_px"]))
        if p.get("dof") is None:
            grad, curv = -r / s**2, 1.0 / s**2
        else:
            nu = float(p["dof"])
            a = nu * s * s + r * r
            grad, curv = -(nu + 1.0) * r / a, (nu + 1.0) * (nu * s * s - r * r) / a**2
    lik = post - curv
    if not lik >= 0.1 * post:
        return None
    return m - grad / lik, lik


def load(folder: Path):
    """Per frame: key, camera, truth (px or None), before (m, p) or None, after (m, p) or None."""
    first = folder / "first_pass"
    rows = []
    for path in sorted((first / "results").glob("*.json")):
        key = path.stem
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            camera = R.camera_id_of(load_scene(first / "scenes" / path.name))
        raw = json.loads((first / "scenes" / path.name).read_text())
        truth = (raw.get("ground_truth") or {}).get("focal_length_px")
        result = read_result(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            after = D.read_readings(key, load_scene(first / "scenes" / path.name), result, camera or key)
        a = (after["log_focal"][0].mean, after["log_focal"][0].precision) if "log_focal" in after else None
        rows.append(dict(key=key, camera=camera, truth=truth, before=laplace_likelihood(result), after=a,
                         objects=len(raw.get("targets", ()))))
    return rows


def pool_before(m, p):
    """The rule before issue 62 on all frames offered: (M, V, check)."""
    c, v, _ = D.combine(m, p, "shared")
    return c, v, R.pool_check(m, p, c, v, len(m))


def pool_after(keys, m, p):
    """The package's rule, through RigPool: (M, V with floor, check) or None."""
    frames = [R.SharedLikelihood(k, "cam", {"log_focal": a}, {"log_focal": b}) for k, a, b in zip(keys, m, p)]
    est = R.RigPool(frames, "focal").estimate("cam")
    if est is None or "log_focal" not in est.center:
        return None
    return est.center["log_focal"], est.var["log_focal"], est.check["log_focal"]


def row(label, rule, res, truth):
    if res is None:
        return f"  {label:8s} {rule:6s}  (nothing pooled)"
    c, v, ch = res
    sd = math.sqrt(v)
    err = "" if truth is None else f"{100 * (math.exp(c) / truth - 1):+6.1f}%  z {(c - math.log(truth)) / sd:+5.2f}"
    return (f"  {label:8s} {rule:6s} µ {math.exp(c):7.1f} px {err}  sd {sd:.3f}  n {ch.used:2d}/{ch.offered:2d}  "
            f"n_eff {ch.n_eff:4.1f}  top-3 {ch.top3_share:.2f}  D {ch.d:+5.2f}  {'; '.join(ch.warnings)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("batch", type=Path)
    ap.add_argument("--groups", default="", help="comma-separated integer ranges of frame names (e.g. 0-24,25-50), "
                    "or even, odd")
    args = ap.parse_args(argv)
    rows = load(args.batch)
    groups = [("all", None)]
    for g in filter(None, args.groups.split(",")):
        groups.append((g, g if g in ("even", "odd") else tuple(int(x) for x in g.split("-"))))
    cameras = sorted({r["camera"] for r in rows if r["camera"] is not None})
    print(f"floor (SHARED_BIAS_SD) {R.SHARED_BIAS_SD['log_focal']}, informative: likelihood log-sd <= "
          f"{R.MAX_LIKELIHOOD_SD['log_focal']}")
    for cam in cameras:
        mine = [r for r in rows if r["camera"] == cam]
        if len(mine) < 2:
            continue
        truths = {r["truth"] for r in mine}
        truth = truths.pop() if len(truths) == 1 else None
        print(f"camera {cam}: {len(mine)} frames" + (f", truth {truth:g} px" if truth else ""))
        if truth is not None:  # each frame's likelihood against the truth, by objects per frame
            for lo, hi, lab in ((1, 1, "1 object"), (2, 2, "2 objects"), (3, 10**6, "3+ objects")):
                sel = [r for r in mine if lo <= r["objects"] <= hi]
                cells = []
                for rule in ("before", "after"):
                    e = [100 * (math.exp(r[rule][0]) / truth - 1) for r in sel if r[rule] is not None]
                    cells.append(f"{rule} median {np.median(e):+6.1f}% ({len(e)})" if e else f"{rule} -")
                print(f"  frames of {lab:10s}: {len(sel):2d}; likelihood's mean vs truth: " + ", ".join(cells))
        excess = {"before": [], "after": []}
        for label, rng in groups:
            sel = [r for r in mine if rng is None or (r["key"].isdigit() and (
                int(r["key"]) % 2 == (rng == "odd") if isinstance(rng, str) else rng[0] <= int(r["key"]) <= rng[1]))]
            b = [r for r in sel if r["before"] is not None]
            a = [r for r in sel if r["after"] is not None]
            res_b = pool_before(np.array([r["before"][0] for r in b]), np.array([r["before"][1] for r in b])) \
                if len(b) >= 2 else None
            res_a = pool_after([r["key"] for r in a], np.array([r["after"][0] for r in a]),
                               np.array([r["after"][1] for r in a])) if len(a) >= 2 else None
            print(row(label, "before", res_b, truth))
            print(row(label, "after", res_a, truth))
            if rng is not None and truth is not None:  # the groups' errors beyond their stated variance
                floor2 = R.SHARED_BIAS_SD["log_focal"] ** 2
                for rule, res, f2 in (("before", res_b, 0.0), ("after", res_a, floor2)):
                    if res is not None:
                        excess[rule].append((res[0] - math.log(truth)) ** 2 - (res[1] - f2))
        for rule, e in excess.items():
            if e:
                print(f"  shared bias sqrt(mean(e^2 - V)) over the {len(e)} groups ({rule}, V without floor): "
                      f"{math.sqrt(max(0.0, float(np.mean(e)))):.3f}")


if __name__ == "__main__":
    main()
