"""Simulation-based calibration of the metrology model's posterior (Talts et al. 2018;
docs/studies/benchmark.md, "Simulation-based calibration").

For each scene: draw the parameters from the model's own prior, simulate the annotations from the
model's own noise model, estimate, and record the rank of each true value among L thinned
posterior draws. A calibrated posterior gives ranks uniform on {0, …, L}; one too narrow piles
them at the ends, one too wide in the middle, a biased one on one side.

The prior is improper in places, so the parameters are drawn from it truncated to a box of
plausible scenes (:data:`SBC_BOX`) and the estimate gets the same box as its bounds. Within it:
x uniform, z log-uniform (the ``log-depth`` location prior), yaw uniform; µ from the default focal
prior; pitch ~ N(0°, 15°), roll ~ N(0°, 10°), log h ~ N(log 1.6 m, 0.6) (no horizon); the target's
size from the simulator's outdoor objects (given to the estimate).

Noise is the model's: every annotation corner off by a bivariate Student-t (ν = 4, scale
:data:`TARGET_SCALE_PX`); every reference a ground segment stated as ℓ·exp(s·ε), ε ~ t₂, s the
crowd scale drawn from its log-normal prior (:data:`~creference_bayes.models.contract.
REF_SCALE_MEDIAN`, ``REF_SCALE_LOG_SD``), its drawn end points off by N(0, (2σ)²) per coordinate.
The model reads a reference given its drawn line, with no prior on where people draw lines, so the
true line is drawn in the image independently of the parameters (:data:`REF_ROWS_PX`,
:data:`REF_PIXEL_LENGTH`) and ℓ is what the ground under it measures at the truth
(:func:`~creference_bayes.models.metrology.ground_lengths`); lines placed on the ground first
would tell the pitch something the model does not use. Scenes whose annotations leave the image
are drawn again (a selection on the data alone: the ranks stay uniform).
The check also measures what the model only approximates: the σ it plugs in from the spread of
several sets of lines, and the reading of each reference's segment fixed at a pilot estimate,
whose prior on the true segment (a ground segment of any direction, log-uniform in length) is not
how these lines are drawn (uniform in the image, 40–400 px long).

Designs: ``thin`` (one set of dimension lines, 0, 1 or 2 references in turn) and ``full``
(5 + 5). Quantities: the ground distance d, µ, pitch and roll. Per design and quantity: the rank
histogram, a χ² test of its uniformity (:data:`N_BINS` bins) and a Kolmogorov–Smirnov test of the
ranks jittered to (r + U)/(L + 1), each a p-value.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..core.geometry import box_points, dimension_corners, project, rotation_from_pitch_roll
from ..models.camera_terms import DEFAULT_ORIENTATION_PRIOR, default_focal_prior
from ..models.contract import (C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, C_SCALE, O_SIZE, O_X, O_YAW, O_Z,
                               REF_SCALE_LOG_SD, REF_SCALE_MEDIAN, Bounds)
from ..models.metrology import ground_lengths
from .simulate import OBJECTS

__all__ = ["SBC_BOX", "IMAGE_SIZE", "TARGET_SCALE_PX", "REF_ROWS_PX", "REF_PIXEL_LENGTH", "DESIGNS", "QUANTITIES",
           "N_RANK_DRAWS", "N_BINS", "SBCBox", "draw_truth", "simulate_sbc_scene", "sbc_reference", "rank_of_truth",
           "run_sbc", "sbc_summary", "sbc_markdown", "rank_uniformity"]

IMAGE_SIZE = (2880, 1800)
#: Scale of the t₄ corner noise, pixels (the model's scale for a single set of lines).
TARGET_SCALE_PX = 5.0
#: Rows of the image (pixels, from the top) a reference line's first end point is drawn in: the
#: lower part of the image, where the ground is for all but the box's most upward-looking cameras
#: (there a line above the horizon reads as the model reads it, a very long segment).
REF_ROWS_PX = (1200.0, 1790.0)
#: Lengths of the reference lines in the image, pixels.
REF_PIXEL_LENGTH = (40.0, 400.0)
#: name → (sets of dimension lines, references per scene in turn).
DESIGNS = {"thin": (1, (0, 1, 2)), "full": (5, (5,))}
#: The checked quantities and their draws' names.
QUANTITIES = ("distance_m", "focal_length_px", "pitch", "roll")
#: Thinned posterior draws the truth is ranked among (ranks 0 … L).
N_RANK_DRAWS = 39
#: Bins of the χ² test (the L + 1 = 40 ranks, 5 to a bin).
N_BINS = 8


@dataclass(frozen=True)
class SBCBox:
    """The box of plausible scenes: (low, high) of x, z (m), µ (px), pitch, roll (rad), h (m)."""

    x: tuple[float, float] = (-3.0, 3.0)
    z: tuple[float, float] = (5.0, 60.0)
    focal: tuple[float, float] = (1000.0, 5000.0)
    pitch: tuple[float, float] = (math.radians(-5.0), math.radians(25.0))
    roll: tuple[float, float] = (math.radians(-10.0), math.radians(10.0))
    height: tuple[float, float] = (0.8, 3.0)

    def bounds(self) -> Bounds:
        """The estimate's bounds: the box, the model's wide bounds elsewhere (yaw free)."""
        return Bounds.box(IMAGE_SIZE, x=self.x, z=self.z, focal_px=self.focal, pitch=self.pitch, roll=self.roll,
                          height=self.height)


SBC_BOX = SBCBox()


def _truncated(draw, lo: float, hi: float, tries: int = 10_000) -> float:
    """A draw of ``draw()`` within [lo, hi] (rejection: the prior truncated to the box)."""
    for _ in range(tries):
        v = float(draw())
        if lo <= v <= hi:
            return v
    raise RuntimeError(f"no prior draw within [{lo}, {hi}]")


def draw_truth(rng: np.random.Generator, box: SBCBox = SBC_BOX) -> tuple[np.ndarray, np.ndarray]:
    """A camera (5,) and a target (7,) (:mod:`~creference_bayes.models.contract` order) from the
    model's prior within ``box``; the target's size from the simulator's outdoor objects."""
    fp, op = default_focal_prior(IMAGE_SIZE), DEFAULT_ORIENTATION_PRIOR
    lo, hi = box.bounds().camera_lower[C_SCALE], box.bounds().camera_upper[C_SCALE]
    x = rng.uniform(*box.x)
    z = math.exp(rng.uniform(math.log(box.z[0]), math.log(box.z[1])))
    mu = _truncated(lambda: fp.median_px * math.exp(fp.log_sd * rng.standard_t(fp.dof)), *box.focal)
    pitch = _truncated(lambda: rng.normal(op.pitch_mean, op.pitch_sd), *box.pitch)
    roll = _truncated(lambda: rng.normal(op.roll_mean, op.roll_sd), *box.roll)
    h = _truncated(lambda: op.height_median_m * math.exp(op.height_log_sd * rng.normal()), *box.height)
    scale = _truncated(lambda: REF_SCALE_MEDIAN * math.exp(REF_SCALE_LOG_SD * rng.normal()), lo, hi)
    names = list(OBJECTS["outdoor"])
    size = [round(float(rng.uniform(*r)), 4) for r in OBJECTS["outdoor"][names[rng.integers(len(names))]]]
    return np.array([mu, pitch, roll, h, scale]), np.array([x, z, rng.uniform(-np.pi, np.pi), *size, 0.0])


def _reference_line(rng) -> np.ndarray:
    """(2, 2) a reference's true line in the image, pixels, drawn without regard to the parameters
    (module docstring)."""
    a = np.array([rng.uniform(0.0, IMAGE_SIZE[0]), rng.uniform(*REF_ROWS_PX)])
    ang, length = rng.uniform(-np.pi, np.pi), rng.uniform(*REF_PIXEL_LENGTH)
    return np.array([a, a + length * np.array([math.cos(ang), math.sin(ang)])])


def _inside(uv: np.ndarray) -> bool:
    w, h = IMAGE_SIZE
    return bool(np.all((uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)))


def simulate_sbc_scene(rng: np.random.Generator, truth, n_target: int, n_refs: int) -> dict | None:
    """A ``creference-scene/2`` scene (dict) of one target from ``truth`` (:func:`draw_truth`) with
    the model's own noise (module docstring): no horizon, focal length unknown, single-valued
    references in metres. None when the drawn annotations do not all lie in the image (the caller
    then draws a new scene)."""
    camera, obj = (np.asarray(a, float) for a in truth)
    pp = np.array(IMAGE_SIZE, float) / 2
    handed = int(rng.choice([1, -1]))
    pose = np.array([obj[O_X], camera[C_HEIGHT], obj[O_Z], obj[O_YAW]])
    corners, _ = project(box_points(pose, dimension_corners(*obj[O_SIZE], handed)),
                         rotation_from_pitch_roll(camera[C_PITCH], camera[C_ROLL]), camera[C_FOCAL], pp)

    def t4(shape):  # bivariate Student-t, ν = 4: normal / sqrt(χ²₄ / 4), one χ² per point
        return rng.normal(0.0, TARGET_SCALE_PX, shape) / np.sqrt(rng.chisquare(4.0, shape[:-1] + (1,)) / 4.0)

    noisy = [corners + t4(corners.shape) for _ in range(n_target)]
    if not all(_inside(c) for c in noisy):
        return None
    refs, true_lines = [], []
    for j in range(n_refs):
        for _ in range(200):  # a line that lies in the image, true and drawn
            line = _reference_line(rng)
            ref = sbc_reference(rng, truth, line, camera[C_SCALE], f"r{j + 1:02d}", object=f"segment-{j + 1}")
            if ref is not None:
                break
        else:
            return None
        refs.append(ref)
        true_lines.append(line.tolist())
    size = dict(zip(("length", "width", "height"), obj[O_SIZE].tolist()))
    return {"format": "creference-scene/2", "image": {"width": IMAGE_SIZE[0], "height": IMAGE_SIZE[1]},
            "camera": {"principal_point": pp.tolist(), "focal_length_px": None},
            "targets": [{"id": "target", "dimensions_m": size,
                         "dimension_lines": [{"worker": f"t{i + 1:02d}", "corners": c.tolist(), "seconds": 183.5}
                                             for i, c in enumerate(noisy)],
                         "ground_truth": {"location_m": pose[:3].tolist(), "yaw_rad": float(obj[O_YAW]),
                                          "handedness": handed, "dimensions_m": size}}],
            "references": refs,
            "ground_truth": {"focal_length_px": float(camera[C_FOCAL]), "camera_height_m": float(camera[C_HEIGHT]),
                             "pitch_rad": float(camera[C_PITCH]), "roll_rad": float(camera[C_ROLL]),
                             "crowd_scale": float(camera[C_SCALE]), "reference_lines_true_px": true_lines}}


def sbc_reference(rng: np.random.Generator, truth, true_line: np.ndarray, scale: float, worker: str,
                  object: str = "segment") -> dict | None:
    """One worker's reference on the ground segment under ``true_line`` ((2, 2) pixels) with the
    model's own noise (module docstring): the drawn line is the true one off by N(0, (2σ)²) px per
    coordinate, the stated length ℓ·exp(``scale`` · ε), ε ~ t₂, ℓ the segment's real length at the
    true camera (``truth``, :func:`draw_truth`). A second call on the same line is a second worker
    measuring the same thing. None when the true or the drawn line is not in the image."""
    true_line = np.asarray(true_line, float)
    uv = true_line + rng.normal(0.0, 2.0 * TARGET_SCALE_PX, true_line.shape)
    if not (_inside(true_line) and _inside(uv)):
        return None
    length = float(ground_lengths(true_line[None], np.array(IMAGE_SIZE, float) / 2, np.asarray(truth[0], float)[None])[0, 0])
    return {"worker": worker, "object": object, "measure": "length", "mode": "direct",
            "value": length * math.exp(scale * rng.standard_t(2.0)), "unit": "m", "line": uv.tolist(),
            "seconds": 64.4}


def rank_of_truth(draws: np.ndarray, truth: float, n: int = N_RANK_DRAWS) -> int:
    """The number of ``n`` evenly spaced (thinned) draws below ``truth``: 0 … n.

    ``draws`` is (chain, draw): the draws are taken step by step across the chains, so that the
    picks are spread over the whole run."""
    flat = np.asarray(draws, float).T.ravel()  # draw-major: consecutive entries are one step
    idx = np.linspace(0, len(flat) - 1, n).round().astype(int)
    return int(np.sum(flat[idx] < truth))


def run_sbc(n_scenes: int = 40, *, designs=tuple(DESIGNS), seed: int = 0, box: SBCBox = SBC_BOX,
            temperature: float | None = None, sampling: dict | None = None, progress=None) -> list[dict]:
    """Draw, simulate, estimate and rank: one record per scene and design.

    Parameters
    ----------
    n_scenes : scenes per design
    designs : names of :data:`DESIGNS`
    seed : the seed (scenes and estimates)
    temperature : the posterior's temperature (None: the model's own, 1; a miscalibrated one, e.g.
        0.3, is what the check must be able to catch)
    sampling : sampler settings (e.g. ``{"min_ess": 400}``)
    progress : callable taking a line of text per scene, or None

    Returns
    -------
    list of dict: design, scene, refs, ranks (quantity → 0 … L), converged, seconds, truth
    """
    import warnings

    from ..pipeline import estimate

    unknown = set(designs) - set(DESIGNS)
    if unknown:
        raise ValueError(f"designs: unknown design(s) {sorted(unknown)} (expected some of {list(DESIGNS)})")
    bounds = box.bounds()
    out = []
    for name in designs:
        n_target, ref_cycle = DESIGNS[name]
        for i in range(n_scenes):
            rng = np.random.default_rng([seed, list(DESIGNS).index(name), i])
            k = ref_cycle[i % len(ref_cycle)]
            d = None
            while d is None:  # annotations outside the image: a new scene
                camera, obj = draw_truth(rng, box)
                d = simulate_sbc_scene(rng, (camera, obj), n_target, k)
            t0 = time.process_time()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = estimate(d, seed=[seed, i], bounds=bounds, temperature=temperature, sampling=sampling,
                               location_prior="log-depth", focal_prior="default", keep_draws=0)
            seconds = time.process_time() - t0
            rec = {"design": name, "scene": i, "refs": k, "ranks": None, "converged": False, "seconds": seconds}
            if res.draws is not None:
                cams, objs = res.draws.cameras, res.draws.objects[..., 0, :]
                q = {"distance_m": np.hypot(objs[..., O_X], objs[..., O_Z]), "focal_length_px": cams[..., C_FOCAL],
                     "pitch": cams[..., C_PITCH], "roll": cams[..., C_ROLL]}
                true = {"distance_m": float(np.hypot(obj[O_X], obj[O_Z])), "focal_length_px": camera[C_FOCAL],
                        "pitch": camera[C_PITCH], "roll": camera[C_ROLL]}
                rec.update(ranks={n: rank_of_truth(q[n], true[n]) for n in QUANTITIES}, converged=bool(res.converged),
                           truth={n: float(v) for n, v in true.items()} | {"ref_scale": float(camera[C_SCALE])})
            out.append(rec)
            if progress is not None:
                progress(f"sbc {name} {i}: ranks {rec['ranks']}, {seconds:.1f} s")
    return out


def rank_uniformity(ranks, n_draws: int = N_RANK_DRAWS, n_bins: int = N_BINS, rng=0) -> dict:
    """Histogram and p-values of ranks 0 … ``n_draws`` against the discrete uniform.

    Returns ``{"counts": [n_bins ints], "chi2_p": float, "ks_p": float, "n": int}``: χ² over
    ``n_bins`` equal groups of ranks (``n_draws`` + 1 must be divisible by ``n_bins``), and a
    Kolmogorov–Smirnov test of the ranks jittered to (r + U)/(L + 1) (continuous uniform
    exactly when the ranks are uniform).
    """
    from scipy import stats

    r = np.asarray(ranks, int)
    if (n_draws + 1) % n_bins:
        raise ValueError(f"n_bins: {n_draws + 1} ranks do not split into {n_bins} equal bins")
    counts = np.bincount(r * n_bins // (n_draws + 1), minlength=n_bins)
    if len(r) == 0:
        return {"counts": counts.tolist(), "chi2_p": None, "ks_p": None, "n": 0}
    chi2_p = float(stats.chisquare(counts).pvalue)
    u = (r + np.random.default_rng(rng).uniform(size=len(r))) / (n_draws + 1)
    ks_p = float(stats.kstest(u, "uniform").pvalue)
    return {"counts": counts.tolist(), "chi2_p": chi2_p, "ks_p": ks_p, "n": int(len(r))}


def sbc_summary(records: list[dict]) -> dict:
    """design → quantity → :func:`rank_uniformity`, plus per design the scenes, the share
    converged and the estimates' CPU seconds (median, 99th percentile, max)."""
    out = {}
    for name in dict.fromkeys(r["design"] for r in records):
        recs = [r for r in records if r["design"] == name]
        ok = [r for r in recs if r["ranks"] is not None]
        sec = np.array([r["seconds"] for r in recs])
        out[name] = {"scenes": len(recs), "converged": float(np.mean([r["converged"] for r in recs])),
                     "seconds": {"median": float(np.median(sec)), "p99": float(np.percentile(sec, 99)),
                                 "max": float(sec.max())},
                     "quantities": {q: rank_uniformity([r["ranks"][q] for r in ok]) for q in QUANTITIES}}
    return out


def sbc_markdown(summary: dict) -> str:
    """The summary as a Markdown table: one row per design and quantity."""
    head = ("| design | quantity | scenes | rank histogram (8 bins, low → high) | χ² p | KS p |\n"
            "|---|---|---|---|---|---|")
    rows = []
    for d, s in summary.items():
        for q, u in s["quantities"].items():
            f = lambda v: "–" if v is None else f"{v:.3g}"
            rows.append(f"| {d} | {q} | {u['n']} | {' '.join(map(str, u['counts']))} | {f(u['chi2_p'])} | {f(u['ks_p'])} |")
    tail = [f"\n{d}: {s['scenes']} scenes, {100 * s['converged']:.0f} % converged, CPU seconds per estimate "
            f"median {s['seconds']['median']:.2f}, 99th percentile {s['seconds']['p99']:.2f}, max {s['seconds']['max']:.2f}"
            for d, s in summary.items()]
    return "\n".join([head, *rows]) + "\n" + "\n".join(tail)
