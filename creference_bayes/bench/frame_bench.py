"""The frame benchmark: simulated frames of 3–15 objects, joint against one at a time, against
the frame's Cramér–Rao bound (docs/benchmark_results.md, "Frames").

For each frame (:mod:`.frame_simulate`, street-like by default) every object is estimated

* **jointly**: the frame model, MAP and posterior (its posterior mean and the 90 % HDI of the
  distance);
* **alone**: the same object with the same annotations as a one-object frame (its own camera,
  its class's size prior), MAP only;

and set beside the bound (:mod:`.frame_crb`). Tiers: ``low`` (2 px Gaussian corner noise) and
``high`` (5 px, heavy-tailed: Student-t with 3 degrees of freedom), 5 annotations per object.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .frame_crb import frame_crb
from .frame_simulate import simulate_frame

__all__ = ["FRAME_TIERS", "BANDS", "FrameRow", "run_frame_bench", "frame_tables", "rows_to_json"]

FRAME_TIERS = {"low": (2.0, False), "high": (5.0, True)}
BANDS = ((0.0, 20.0), (20.0, 40.0), (40.0, np.inf))


@dataclass(frozen=True)
class FrameRow:
    """One object of one frame."""

    tier: str
    n_objects: int
    frame: int
    target: str
    cls: str
    distance_m: float
    joint_map_pct: float
    joint_mean_pct: float
    alone_map_pct: float
    bound_pct: float
    in_hdi90: bool
    converged: bool
    map_s: float
    posterior_s: float


def _truth(scene):
    gt = scene["ground_truth"]
    cam = np.array([gt["focal_length_px"], gt["pitch_rad"], gt["roll_rad"], gt["camera_height_m"], 0.5])
    objs = np.array([[t["ground_truth"]["location_m"][0], t["ground_truth"]["location_m"][2],
                      t["ground_truth"]["yaw_rad"], *t["ground_truth"]["dimensions_m"].values(),
                      t["ground_truth"]["ground_m"]] for t in scene["targets"]])
    hands = np.array([t["ground_truth"]["handedness"] for t in scene["targets"]], float)
    return cam, objs, hands


def _err(est, loc):
    return float(100 * np.linalg.norm(np.asarray(est) - loc) / np.linalg.norm(loc))


def run_frame_bench(*, counts=(3, 8, 15), frames: int = 4, tiers=("low", "high"), kind: str = "street",
                    seed: int = 0, sampling: dict | None = None, progress=None) -> list[FrameRow]:
    """Run the benchmark; ``progress`` is called with a line of text after each frame."""
    from ..frame_pipeline import build_frame_model, estimate_frame
    from ..inference.frame_map import optimize_frame
    from ..io.frame_scene import parse_frame

    rows = []
    for tier in tiers:
        noise, heavy = FRAME_TIERS[tier]
        for n in counts:
            for k in range(frames):
                scene = simulate_frame([seed, n, k, len(tier)], kind=kind, n_objects=n, noise_px=noise,
                                       heavy_tails=heavy)
                frame = parse_frame(scene)
                res = estimate_frame(frame, seed=k, sampling=sampling)
                d = res.to_dict()
                cam, objs, hands = _truth(scene)
                model, _ = build_frame_model(frame)
                model.handedness = hands
                bound = frame_crb(model, cam, objs, noise)
                for i, t in enumerate(scene["targets"]):
                    loc = np.asarray(t["ground_truth"]["location_m"])
                    single = dict(scene, targets=[t])
                    alone = optimize_frame(build_frame_model(parse_frame(single))[0])
                    a = [alone.objects[0, 0], alone.camera[3] - alone.objects[0, 6], alone.objects[0, 1]]
                    o = d["objects"][i]
                    mean = o["posterior"]["mean"]
                    lo, hi = o["posterior"]["hdi"]["distance_m"]
                    dist = float(np.hypot(loc[0], loc[2]))
                    rows.append(FrameRow(tier, len(scene["targets"]), k, t["id"], t["class"], dist,
                                         o["evaluation"]["location_pct_error"],
                                         _err([mean["x"], mean["y"], mean["z"]], loc), _err(a, loc),
                                         float(bound.median_pct[i]), bool(lo <= dist <= hi),
                                         bool(d["diagnostics"]["converged"]), d["map_info"]["seconds"],
                                         d["diagnostics"]["seconds"]))
                if progress:
                    progress(f"{tier} n={n} frame {k}: {d['seconds']:.1f} s, converged {d['diagnostics']['converged']}")
    return rows


def frame_tables(rows: list[FrameRow]) -> str:
    """Markdown tables: error by distance band (joint, alone, bound, coverage), time by count."""
    out = ["| tier | distance | objects | joint MAP median % | joint mean median % | alone MAP median % | "
           "bound median % | joint / bound | 90 % HDI coverage |", "|---|---|---|---|---|---|---|---|---|"]
    for tier in dict.fromkeys(r.tier for r in rows):
        for lo, hi in BANDS:
            sel = [r for r in rows if r.tier == tier and lo <= r.distance_m < hi]
            if not sel:
                continue
            j = np.median([r.joint_map_pct for r in sel])
            b = np.median([r.bound_pct for r in sel])
            band = f"{lo:.0f}–{hi:.0f} m" if np.isfinite(hi) else f"≥ {lo:.0f} m"
            out.append(f"| {tier} | {band} | {len(sel)} | {j:.2f} | {np.median([r.joint_mean_pct for r in sel]):.2f} | "
                       f"{np.median([r.alone_map_pct for r in sel]):.2f} | {b:.2f} | {j / b:.2f} | "
                       f"{np.mean([r.in_hdi90 for r in sel]):.0%} |")
    out += ["", "| tier | objects per frame | frames | MAP median s | MAP max s | posterior median s | "
            "posterior max s | converged |", "|---|---|---|---|---|---|---|---|"]
    for tier in dict.fromkeys(r.tier for r in rows):
        for n in sorted({r.n_objects for r in rows if r.tier == tier}):
            sel = {(r.frame): r for r in rows if r.tier == tier and r.n_objects == n}.values()
            sel = list(sel)
            out.append(f"| {tier} | {n} | {len(sel)} | {np.median([r.map_s for r in sel]):.2f} | "
                       f"{np.max([r.map_s for r in sel]):.2f} | {np.median([r.posterior_s for r in sel]):.2f} | "
                       f"{np.max([r.posterior_s for r in sel]):.2f} | {np.mean([r.converged for r in sel]):.0%} |")
    return "\n".join(out)


def rows_to_json(rows: list[FrameRow]) -> list[dict]:
    return [asdict(r) for r in rows]
