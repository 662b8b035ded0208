"""Simulation-based calibration of the metrology model's posterior (Talts et al. 2018).

For each scene: draw the parameters from the model's own prior, simulate the annotations from the
model's own noise model, estimate, and record the rank of each true value among L thinned
posterior draws. If the posterior is the Bayesian posterior of the model that made the data, each
rank is uniform on {0, …, L}, whatever the scenes; a posterior too narrow piles the ranks at the
ends, one too wide in the middle, one biased on one side.

The prior, and the box. The model's prior is improper in places (flat in x; uniform in log depth
over the wide default bounds; pitch, roll, µ and the camera height proper but heavy-tailed, and
extending to cameras that see no ground), so the parameters are drawn from it truncated to a box
of plausible scenes (:data:`SBC_BOX`), and the estimate is given the same box as its bounds: the
same truncated prior on both sides. Within the box:

- x uniform, z log-uniform (the ``log-depth`` location prior, p(x, z) ∝ 1/z), yaw uniform;
- µ from the default focal-length prior (log µ ~ Student-t₃(log m, 0.5), m a 30 mm-equivalent
  lens); pitch ~ N(0°, 15°), roll ~ N(0°, 10°), log h ~ N(log 1.6 m, 0.6): the default pose
  prior (no horizon: pitch and roll are parameters);
- the target's size from the simulator's outdoor objects (it is given to the estimate, not
  estimated).

The noise model is the model's: every corner of every set of dimension lines is off by a bivariate
Student-t (ν = 4, scale :data:`TARGET_SCALE_PX`); every reference is a segment on the ground
whose stated value is ℓ·exp(s·ε), ε ~ Student-t₂, with the crowd's scale s drawn from the model's
grid with its prior weights, and whose drawn end points are off by N(0, (2σ)²) per coordinate
(the model's line noise, σ_line = 2σ).

Where the references are. The model reads a reference *given its drawn line*: it has no prior on
where in the image, or where on the ground, people draw references, so the line's position must
say nothing about the camera. The true line is therefore drawn in the image, independently of
the parameters (an end point uniform in the lower part of the image, :data:`REF_ROWS_PX`, a
direction uniform and a length uniform in :data:`REF_PIXEL_LENGTH`), and its real length ℓ is
what the ground under it measures at the true parameters (the model's own reading,
:func:`~creference_bayes.models.metrology.ground_lengths`). Segments placed on the ground first
(a prior over where objects stand) make where their lines fall in the image evidence about the
pitch that the model does not use: with them the ranks of the pitch piled at the low end (one
set of lines and four references, 100 scenes: χ² and KS p 0.001), while they are uniform with
the lines placed in the image (KS p 0.61; docs/benchmark_results.md).

Scenes whose annotations do not all lie in the image are drawn again: a selection on the data
alone, which leaves the posterior given the data, and so the uniformity of the ranks, unchanged. What the model only
approximates: with several sets of dimension lines it plugs in the spread of the annotations for
σ (their pooled standard deviation, √2 times the t₄ scale); the line noise enters through
derivatives at a pilot estimate. The check measures those approximations too.

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
from ..io.scene import SCENE_FORMAT
from ..models.camera_terms import DEFAULT_ORIENTATION_PRIOR, default_focal_prior
from ..models.metrology import REF_SCALE_GRID, REF_SCALE_LOG_SD, REF_SCALE_MEDIAN, ground_lengths
from ..models.params import MAX_PITCH, MAX_ROLL, Bounds
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
        """The estimate's bounds: the box, yaw free."""
        assert -MAX_PITCH <= self.pitch[0] and self.pitch[1] <= MAX_PITCH and abs(self.roll[0]) <= MAX_ROLL
        return Bounds(np.array([self.x[0], self.height[0], self.z[0], -np.pi, self.focal[0], self.pitch[0], self.roll[0]]),
                      np.array([self.x[1], self.height[1], self.z[1], np.pi, self.focal[1], self.pitch[1], self.roll[1]]))


SBC_BOX = SBCBox()


def _truncated(draw, lo: float, hi: float, tries: int = 10_000) -> float:
    """A draw of ``draw()`` within [lo, hi] (rejection: the prior truncated to the box)."""
    for _ in range(tries):
        v = float(draw())
        if lo <= v <= hi:
            return v
    raise RuntimeError(f"no prior draw within [{lo}, {hi}]")


def draw_truth(rng: np.random.Generator, box: SBCBox = SBC_BOX) -> np.ndarray:
    """(7,) parameters (x, y, z, yaw, µ, pitch, roll) from the model's prior within ``box``."""
    fp = default_focal_prior(IMAGE_SIZE)
    op = DEFAULT_ORIENTATION_PRIOR
    x = rng.uniform(*box.x)
    z = math.exp(rng.uniform(math.log(box.z[0]), math.log(box.z[1])))
    mu = _truncated(lambda: fp.median_px * math.exp(fp.log_sd * rng.standard_t(fp.dof)), *box.focal)
    pitch = _truncated(lambda: rng.normal(op.pitch_mean, op.pitch_sd), *box.pitch)
    roll = _truncated(lambda: rng.normal(op.roll_mean, op.roll_sd), *box.roll)
    h = _truncated(lambda: op.height_median_m * math.exp(op.height_log_sd * rng.normal()), *box.height)
    return np.array([x, h, z, rng.uniform(-np.pi, np.pi), mu, pitch, roll])


def _reference_line(rng) -> np.ndarray:
    """(2, 2) a reference's true line in the image, pixels, drawn without regard to the parameters
    (module docstring)."""
    w, _ = IMAGE_SIZE
    a = np.array([rng.uniform(0.0, w), rng.uniform(*REF_ROWS_PX)])
    ang, length = rng.uniform(-np.pi, np.pi), rng.uniform(*REF_PIXEL_LENGTH)
    return np.array([a, a + length * np.array([math.cos(ang), math.sin(ang)])])


_TRIES = 200


def _inside(uv: np.ndarray) -> bool:
    w, h = IMAGE_SIZE
    return bool(np.all((uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)))


def simulate_sbc_scene(rng: np.random.Generator, truth: np.ndarray, n_target: int, n_refs: int) -> dict | None:
    """A ``creference-scene/1`` scene (dict) from ``truth`` with the model's own noise (module
    docstring): no horizon, focal length unknown, single-valued references in metres. None when
    the drawn annotations do not all lie in the image (the caller then draws a new scene: a
    selection on the data alone, which leaves the posterior given the data, and so the ranks'
    uniformity, unchanged)."""
    w, h_img = IMAGE_SIZE
    pp = np.array([w / 2, h_img / 2])
    R = rotation_from_pitch_roll(truth[5], truth[6])
    names = list(OBJECTS["outdoor"])
    size = tuple(round(float(rng.uniform(*r)), 4) for r in OBJECTS["outdoor"][names[rng.integers(len(names))]])
    handed = int(rng.choice([1, -1]))
    corners, _ = project(box_points(truth[:5], dimension_corners(*size, handed)), R, truth[4], pp)

    def t4(shape):  # bivariate Student-t, ν = 4: normal / sqrt(χ²₄ / 4), one χ² per point
        return rng.normal(0.0, TARGET_SCALE_PX, shape) / np.sqrt(rng.chisquare(4.0, shape[:-1] + (1,)) / 4.0)

    noisy = [corners + t4(corners.shape) for _ in range(n_target)]
    if not all(_inside(c) for c in noisy):
        return None
    lines = [{"worker": f"t{i + 1:02d}", "corners": c.tolist(), "seconds": 183.5} for i, c in enumerate(noisy)]
    w_k = np.exp(-0.5 * ((np.log(REF_SCALE_GRID) - math.log(REF_SCALE_MEDIAN)) / REF_SCALE_LOG_SD) ** 2)
    s = float(rng.choice(REF_SCALE_GRID, p=w_k / w_k.sum()))
    refs, true_lines = [], []
    for j in range(n_refs):
        for _ in range(_TRIES):  # a line that lies in the image, true and drawn
            line = _reference_line(rng)
            ref = sbc_reference(rng, truth, line, s, f"r{j + 1:02d}", object=f"segment-{j + 1}")
            if ref is not None:
                break
        else:
            return None
        refs.append(ref)
        true_lines.append(line.tolist())
    return {"format": SCENE_FORMAT, "image": {"width": w, "height": h_img},
            "camera": {"principal_point": pp.tolist(), "focal_length_px": None},
            "target": {"id": "target", "dimensions_m": dict(zip(("length", "width", "height"), size)),
                       "dimension_lines": lines},
            "references": refs,
            "ground_truth": {"location_m": truth[:3].tolist(), "yaw_rad": float(truth[3]),
                             "focal_length_px": float(truth[4]), "camera_height_m": float(truth[1]),
                             "pitch_rad": float(truth[5]), "roll_rad": float(truth[6]), "handedness": handed,
                             "crowd_scale": s, "reference_lines_true_px": true_lines}}


def sbc_reference(rng: np.random.Generator, truth: np.ndarray, true_line: np.ndarray, scale: float, worker: str,
                  object: str = "segment") -> dict | None:
    """One worker's reference on the ground segment under ``true_line`` ((2, 2) pixels) under the
    model's own noise model (module docstring): its drawn line, the true one off by N(0, (2σ)²) px
    per coordinate, and its stated length, the segment's real length ℓ at ``truth`` times
    exp(``scale`` · ε), ε ~ Student-t₂. A second call on the same line is a second worker
    measuring the same thing. None when the true or the drawn line is not in the image."""
    w, h_img = IMAGE_SIZE
    true_line = np.asarray(true_line, float)
    uv = true_line + rng.normal(0.0, 2.0 * TARGET_SCALE_PX, true_line.shape)
    if not (_inside(true_line) and _inside(uv)):
        return None
    length = float(ground_lengths(true_line[None], np.array([w / 2, h_img / 2]), np.asarray(truth, float)[None])[0, 0])
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

    from ..inference.summary import draws_from_inference_data
    from ..io.scene import parse_scene
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
            while d is None:  # annotations outside the image: a new scene (a selection on the data)
                truth = draw_truth(rng, box)
                d = simulate_sbc_scene(rng, truth, n_target, k)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                scene = parse_scene(d)
            t0 = time.process_time()
            res = estimate(scene, seed=[seed, i], bounds=bounds, temperature=temperature, sampling=sampling,
                           location_prior="log-depth", focal_prior="default")
            seconds = time.process_time() - t0
            if res.inference_data is None:
                out.append({"design": name, "scene": i, "refs": k, "ranks": None, "converged": False,
                            "seconds": seconds})
                continue
            d = draws_from_inference_data(res.inference_data)
            d["distance_m"] = np.hypot(d["x"], d["z"])
            true = {"distance_m": float(np.hypot(truth[0], truth[2])), "focal_length_px": truth[4],
                    "pitch": truth[5], "roll": truth[6]}
            ranks = {q: rank_of_truth(d[q], true[q]) for q in QUANTITIES}
            out.append({"design": name, "scene": i, "refs": k, "ranks": ranks,
                        "converged": bool(res.diagnostics.converged), "seconds": seconds,
                        "truth": {q: float(v) for q, v in true.items()}})
            if progress is not None:
                progress(f"sbc {name} {i}: ranks {ranks}, {seconds:.1f} s")
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
