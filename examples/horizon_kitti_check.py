"""The image horizon against KITTI's level camera: is its stated uncertainty honest on real photos?

KITTI_DIR is a folder in KITTI's object layout: ``calib/NNNNNN.txt`` (with the P2 matrix) and
``image_2/NNNNNN.png``. KITTI's rectified colour camera is level to about a degree, so the true
horizon is (about) the image row v = c_y of P2 across the whole image (roll 0). For each frame the
package's :func:`~creference_bayes.vision.horizon.estimate_horizon` runs on the image alone (with
P2's principal point, as a user who knows it would give), and its rows at the left and right
edges are compared with c_y: the signed error (pixels, positive = estimate below the truth), the
z-score error / ``sd_px``, and whether both edges lie within the stated 90 % interval (±1.645
``sd_px`` for a normal error, ±6.31 ``sd_px`` for the Cauchy the package states, the
estimate's ``dof``). The summary gives the median and 90th percentile of the larger |error| of
the two edges, the coverage of the stated 90 % interval, and the systematic fraction of the
image's larger side, with the estimator's degrees of freedom, that maximises the likelihood of
the errors (a bivariate Student-t per frame) with the coverage it gives, and the smallest one
giving a 90 % coverage.

    python examples/horizon_kitti_check.py ../shared/kitti_dev [--limit N] [--json FILE]

The KITTI frames are not part of the package (licence: CC BY-NC-SA 3.0); this script only reads
them from the folder given.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from scipy import stats

from creference_bayes.vision.horizon import HORIZON_DOF, SYSTEMATIC_FRACTION, estimate_horizon, read_gray


def z90(dof) -> float:
    """Half-width of the central 90 % interval of the stated error distribution, in scales:
    1.645 for a normal (dof None), the Student-t quantile otherwise (6.31 for a Cauchy)."""
    return float(stats.norm.ppf(0.95) if dof is None else stats.t.ppf(0.95, dof))


def read_p2(path: Path) -> np.ndarray:
    """The (3, 4) P2 matrix of a KITTI calib file."""
    for line in path.read_text().splitlines():
        if line.startswith("P2:"):
            values = [float(v) for v in line.split()[1:]]
            if len(values) != 12:
                raise ValueError(f"{path}: P2 has {len(values)} numbers, expected 12")
            return np.array(values).reshape(3, 4)
    raise ValueError(f"{path}: no P2 line")


def frames(folder: Path, limit: int | None):
    """(frame id, image path, calib path) of the frames that have both files, in order."""
    calib = folder / "calib"
    images = folder / "image_2"
    if not calib.is_dir() or not images.is_dir():
        raise FileNotFoundError(f"{folder}: expected the folders calib/ and image_2/ (KITTI's layout)")
    out = []
    for c in sorted(calib.glob("*.txt")):
        img = next((p for p in (images / f"{c.stem}{ext}" for ext in (".png", ".jpg")) if p.is_file()), None)
        if img is not None:
            out.append((c.stem, img, c))
    return out[:limit] if limit else out


def measure(image: Path, calib: Path) -> dict:
    """One frame's row: the estimate's errors at the two edges, its sd and z-scores."""
    P2 = read_p2(calib)
    cx, cy = P2[0, 2], P2[1, 2]
    h, w = read_gray(image).shape
    est = estimate_horizon(image, principal_point=(cx, cy))
    row = {"frame": image.stem, "width": w, "height": h, "c_y": cy, "found": bool(est)}
    if not est:
        row["reason"] = est.reason
        return row
    err = est.points[:, 1] - cy  # rows at u = 0 and u = width, minus the level horizon's row
    dof = getattr(est, "dof", None)
    row.update({"error_left_px": float(err[0]), "error_right_px": float(err[1]),
                "sd_px": float(est.sd_px), "dof": dof, "statistical_px": float(np.max(est.sigma_rows_px)),
                "assumed_level": bool(est.assumed_level),
                "z_left": float(err[0] / est.sd_px), "z_right": float(err[1] / est.sd_px)})
    row["inside_90"] = bool(max(abs(row["z_left"]), abs(row["z_right"])) <= z90(dof))
    return row


def _scales(found, f):
    return np.array([math.hypot(r["statistical_px"], f * max(r["width"], r["height"])
                                * (2.0 if r["assumed_level"] else 1.0)) for r in found])


def fitted_fraction(rows: list[dict], dof: float = HORIZON_DOF) -> tuple[float, float]:
    """The systematic fraction of the larger side (as the estimator uses it, doubled when the
    horizon was assumed level) that maximises the likelihood of the two edges' errors under a
    bivariate Student-t with ``dof``, and the coverage of the 90 % interval (both edges) at it."""
    from scipy.optimize import minimize_scalar
    from scipy.special import gammaln

    found = [r for r in rows if r["found"]]
    if not found:
        return float("nan"), float("nan")
    e2 = np.array([r["error_left_px"] ** 2 + r["error_right_px"] ** 2 for r in found])
    worst = np.array([max(abs(r["error_left_px"]), abs(r["error_right_px"])) for r in found])

    def nll(log_f):
        s = _scales(found, math.exp(log_f))
        return -np.sum(gammaln((dof + 2) / 2) - gammaln(dof / 2) - np.log(dof * np.pi) - 2 * np.log(s)
                       - (dof + 2) / 2 * np.log1p(e2 / (dof * s**2)))

    f = math.exp(minimize_scalar(nll, bounds=(-10.0, 0.0), method="bounded").x)
    return f, float(np.mean(worst <= z90(dof) * _scales(found, f)))


def coverage_fraction(rows: list[dict], dof: float = HORIZON_DOF, coverage: float = 0.9) -> float:
    """The smallest systematic fraction of the larger side at which ``coverage`` of the frames
    have both edges inside the stated 90 % interval (Student-t with ``dof``)."""
    found = [r for r in rows if r["found"]]
    if not found:
        return float("nan")
    worst = np.array([max(abs(r["error_left_px"]), abs(r["error_right_px"])) for r in found])
    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if np.mean(worst <= z90(dof) * _scales(found, mid)) >= coverage else (mid, hi)
    return hi


def summary(rows: list[dict]) -> dict:
    found = [r for r in rows if r["found"]]
    worst = np.array([max(abs(r["error_left_px"]), abs(r["error_right_px"])) for r in found])
    height = np.array([r["height"] for r in found], float)
    z = np.array([[r["z_left"], r["z_right"]] for r in found]).ravel()
    out = {"frames": len(rows), "found": len(found), "systematic_fraction": SYSTEMATIC_FRACTION}
    if found:
        out.update({
            "median_abs_error_px": float(np.median(worst)),
            "p90_abs_error_px": float(np.quantile(worst, 0.9)),
            "median_abs_error_pct_height": float(np.median(100 * worst / height)),
            "p90_abs_error_pct_height": float(np.quantile(100 * worst / height, 0.9)),
            "mean_signed_error_px": float(np.mean([0.5 * (r["error_left_px"] + r["error_right_px"]) for r in found])),
            "median_sd_px": float(np.median([r["sd_px"] for r in found])),
            "median_abs_z": float(np.median(np.abs(z))),
            "coverage_90": float(np.mean([r["inside_90"] for r in found])),
            "edge_coverage_90": float(np.mean(np.abs(z) <= z90(found[0]["dof"]))),
            "fitted_systematic_fraction": (fit := fitted_fraction(rows))[0],
            "fitted_coverage_90": fit[1],
            "coverage_systematic_fraction": coverage_fraction(rows)})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("kitti_dir", type=Path, help="folder with calib/ and image_2/")
    ap.add_argument("--limit", type=int, default=None, help="only the first N frames")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows and summary here")
    args = ap.parse_args(argv)
    try:
        todo = frames(args.kitti_dir, args.limit)
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not todo:
        print(f"error: {args.kitti_dir}: no frame with both calib/*.txt and image_2/*.png", file=sys.stderr)
        return 2
    rows = []
    print(f"{'frame':>8} {'left px':>8} {'right px':>8} {'sd px':>6} {'z left':>7} {'z right':>7} in90 level")
    for stem, img, calib in todo:
        r = measure(img, calib)
        rows.append(r)
        if r["found"]:
            print(f"{stem:>8} {r['error_left_px']:8.1f} {r['error_right_px']:8.1f} {r['sd_px']:6.1f} "
                  f"{r['z_left']:7.2f} {r['z_right']:7.2f} {'yes' if r['inside_90'] else 'NO':>4} "
                  f"{'yes' if r['assumed_level'] else ''}")
        else:
            print(f"{stem:>8} no horizon: {r['reason']}")
    s = summary(rows)
    print(f"\n{s['found']} of {s['frames']} frames with a horizon (systematic part "
          f"{100 * s['systematic_fraction']:.2f} % of the larger side, t with {HORIZON_DOF:g} dof)")
    if s["found"]:
        print(f"larger |error| of the two edges: median {s['median_abs_error_px']:.1f} px "
              f"({s['median_abs_error_pct_height']:.1f} % of the height), 90th percentile "
              f"{s['p90_abs_error_px']:.1f} px ({s['p90_abs_error_pct_height']:.1f} %); "
              f"mean signed error {s['mean_signed_error_px']:+.1f} px")
        print(f"stated scale: median {s['median_sd_px']:.1f} px; median |z| {s['median_abs_z']:.2f}; "
              f"coverage of the stated 90 % interval: {100 * s['coverage_90']:.0f} % of frames (both "
              f"edges), {100 * s['edge_coverage_90']:.0f} % of edges")
        print(f"maximum-likelihood systematic fraction here: {100 * s['fitted_systematic_fraction']:.2f} % "
              f"of the larger side (coverage {100 * s['fitted_coverage_90']:.0f} % of frames); the smallest "
              f"giving a 90 % coverage: {100 * s['coverage_systematic_fraction']:.2f} %")
    if args.json is not None:
        tmp = args.json.with_suffix(args.json.suffix + ".tmp")
        tmp.write_text(json.dumps({"rows": rows, "summary": s}, indent=1))
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
