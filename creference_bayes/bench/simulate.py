"""Synthetic ``creference-scene/1`` scenes with exact ground truth (benchmark.md).

Cameras have pitch, roll and (optionally) an off-centre principal point; the target and five
reference objects are boxes standing on the ground. Noise tiers perturb the target's dimension
lines, the reference lines and the workers' measurements. Everything is drawn from one
``numpy.random.Generator``: the same seed gives the same scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.geometry import (box_points, box_vertices, dimension_corners, horizon_from_rotation,
                             project, rotation_from_pitch_roll)
from ..io.scene import SCENE_FORMAT
from ..core.units import UNITS_TO_M
from .confidence_workers import ConfidentWorkers

__all__ = ["NoiseTier", "TIERS", "OBJECTS", "SETTINGS", "FORMATS", "PAPER_NOISE", "RANGE_PRECISION",
           "simulate_scene", "measurement_factor", "true_params"]


@dataclass(frozen=True)
class NoiseTier:
    """Annotation noise: target corner σ (px), reference endpoint σ (px), measurement model."""

    name: str
    target_px: float
    reference_px: float
    measurement: str  # "none", "10%", "40%" or "paper"


TIERS: dict[str, NoiseTier] = {
    "none": NoiseTier("none", 0.0, 0.0, "none"),
    "low": NoiseTier("low", 2.0, 5.0, "10%"),
    "medium": NoiseTier("medium", 5.0, 10.0, "40%"),
    "high": NoiseTier("high", 10.0, 30.0, "paper"),
}

#: (length, width, height) ranges in metres per object type (within the paper's Table 1).
OBJECTS: dict[str, dict[str, tuple[tuple[float, float], ...]]] = {
    "indoor": {
        "chair": ((0.45, 0.6), (0.42, 0.55), (0.8, 1.05)),
        "dining table": ((1.2, 2.2), (0.75, 1.1), (0.72, 0.78)),
        "coffee table": ((0.8, 1.3), (0.45, 0.7), (0.35, 0.5)),
        "bookcase": ((0.6, 1.2), (0.25, 0.4), (1.2, 2.2)),
        "couch": ((1.6, 2.6), (0.8, 1.0), (0.7, 0.95)),
        "fridge": ((0.6, 0.9), (0.6, 0.75), (1.6, 1.9)),
        "bed": ((1.9, 2.2), (0.9, 1.9), (0.4, 0.65)),
        "cupboard": ((0.8, 1.5), (0.4, 0.6), (1.6, 2.2)),
        "desk": ((1.0, 1.8), (0.55, 0.8), (0.72, 0.78)),
        "tv stand": ((1.0, 2.0), (0.35, 0.5), (0.4, 0.6)),
    },
    "outdoor": {
        "car": ((3.8, 4.63), (1.7, 1.95), (1.4, 1.6)),
        "bench": ((1.2, 2.0), (0.45, 0.7), (0.75, 0.95)),
        "hydrant": ((0.3, 0.45), (0.3, 0.45), (0.6, 0.9)),
        "bush": ((0.8, 2.5), (0.8, 2.0), (0.6, 1.8)),
        "sign": ((0.06, 0.3), (0.06, 0.3), (2.0, 3.0)),
        "van": ((4.4, 4.63), (1.9, 2.1), (1.9, 2.4)),
        "trash bin": ((0.5, 0.75), (0.5, 0.75), (0.9, 1.2)),
        "kiosk": ((2.0, 3.5), (1.5, 3.0), (2.4, 3.2)),
    },
}

#: Camera and distance ranges per setting (benchmark.md).
SETTINGS = {
    "indoor": {"height": (1.0, 1.8), "pitch_deg": (0.0, 15.0), "distance": (2.25, 10.0)},
    "outdoor": {"height": (1.2, 2.5), "pitch_deg": (0.0, 10.0), "distance": (8.0, 45.0)},
}

#: The paper's ten measurement formats: (measure, mode, is_range).
FORMATS = tuple((m, mode, r) for m in ("length", "width", "distance") for mode in ("direct", "relative")
                for r in (False, True) if not (m == "distance" and mode == "relative"))


def _u(rng, lohi):
    return float(rng.uniform(*lohi))


#: "Paper-like" worker measurements: the log of the error factor is ``scale · t_dof``, clipped to
#: ±log(clip) (no worker is off by more than a factor ``clip``; the clip also keeps the mean
#: finite: exp of an unclipped t has no mean). Measured on 10⁶ draws: median absolute error
#: 56 %, mean 160 % (paper Table 2: medians 50–68 %, means 55–291 %; benchmark.md asks for a
#: median of 50–65 % and a mean of 100–250 %). tests/test_simulate.py checks these.
PAPER_NOISE = {"dof": 2.0, "scale": 0.75, "clip": 20.0}

#: Stated ranges: precision (Eq. 4) log-normal with median 25 % and log-sd 0.6, i.e. mean ≈ 30 %,
#: sd ≈ 20 % (paper Table 3: medians 18–29 %, means 26–37 %, sds 17–29 %), centred on the
#: worker's (noisy) value.
RANGE_PRECISION = {"median": 0.25, "log_sd": 0.6}


def measurement_factor(rng, model: str, size=None):
    """Multiplicative error factor(s) of a worker's measurement: stated = true × factor.

    Parameters
    ----------
    rng : numpy Generator
    model : ``"none"``, ``"10%"`` / ``"40%"`` (log-normal, log-sd 0.1 / 0.4) or ``"paper"``
        (heavy-tailed, :data:`PAPER_NOISE`)
    size : None for a float, else the shape of an array of factors
    """
    shape = () if size is None else size
    if model == "none":
        out = np.ones(shape)
    elif model in ("10%", "40%"):
        out = np.exp(rng.normal(0.0, 0.1 if model == "10%" else 0.4, shape))
    elif model == "paper":
        lim = math.log(PAPER_NOISE["clip"])
        out = np.exp(np.clip(PAPER_NOISE["scale"] * rng.standard_t(PAPER_NOISE["dof"], shape), -lim, lim))
    else:
        raise ValueError(f"measurement noise: unknown model {model!r} (expected none, 10%, 40% or paper)")
    return float(out) if size is None else out


def _measure_noise(rng, model: str) -> float:
    return measurement_factor(rng, model)


def _place(rng, setting, R, f, pp, h, size, w_img, h_img, dist_range, need_inside, tries=400):
    """Draw a ground position and yaw so that ``need_inside`` corner set lies in the image."""
    for _ in range(tries):
        d = _u(rng, dist_range)
        # bearing within the horizontal field of view
        half_fov = math.atan2(0.45 * w_img, f)
        bearing = rng.uniform(-half_fov, half_fov)
        loc = np.array([d * math.sin(bearing), h, d * math.cos(bearing)])
        yaw = rng.uniform(-math.pi, math.pi)
        params = np.array([*loc, yaw, f])
        verts = box_points(params, box_vertices(*size))
        uv, depth = project(verts, R, f, pp)
        if np.any(depth <= 0.1):
            continue
        pts = uv[need_inside]
        if np.all((pts[:, 0] > 5) & (pts[:, 0] < w_img - 5) & (pts[:, 1] > 5) & (pts[:, 1] < h_img - 5)):
            return params, uv, verts
    raise RuntimeError("could not place an object inside the image")


def true_params(scene) -> np.ndarray:
    """The true parameter vector of a simulated scene, shape (7,), in ``PARAM_NAMES`` order:
    x, y, z (m), yaw (rad), focal length (px), pitch, roll (rad).

    Raises ValueError when the scene has no simulated ground truth (pitch and roll in its extras).
    """
    gt = scene.ground_truth
    if gt is None or "pitch_rad" not in gt.extra or "roll_rad" not in gt.extra:
        raise ValueError("scene: needs simulated ground truth (ground_truth.pitch_rad and roll_rad)")
    return np.array([*gt.location_m, gt.yaw_rad, gt.focal_length_px, gt.extra["pitch_rad"],
                     gt.extra["roll_rad"]], dtype=float)


def simulate_scene(rng=None, *, setting: str | None = None, tier: str | NoiseTier = "none",
                   n_references: int = 5, n_target_annotations: int = 13,
                   image_size: tuple[int, int] = (2880, 1800), principal_offset: float = 0.0,
                   roll_deg: float = 3.0, target_id: str = "target",
                   format_offset: int | None = None, distance_range: tuple[float, float] | None = None,
                   single_values: bool = False, decimals: int | None = 2,
                   confidence: ConfidentWorkers | None = None) -> dict:
    """Draw one synthetic scene.

    Parameters
    ----------
    rng : seed or Generator
    setting : "indoor", "outdoor" or None (two thirds indoor)
    tier : a key of :data:`TIERS` or a :class:`NoiseTier`
    n_references : reference annotations (one object each), cycling through :data:`FORMATS`
    n_target_annotations : noisy copies of the target's dimension lines
    image_size : (width, height) pixels
    principal_offset : the principal point is moved from the centre by up to this fraction of
        the image size in each axis
    roll_deg : roll is drawn within ±roll_deg degrees
    format_offset : None to give the references distinct formats in a random order; an integer k
        to use ``FORMATS[(k + j) % 10]`` for reference j, so that scenes simulated with offsets
        0, 5, 10, … cover all ten formats in exactly equal shares (``creference simulate`` does)
    distance_range : (low, high) target distance, metres, instead of the setting's
    single_values : every reference states a single value (no ranges)
    decimals : image coordinates (corners, lines, horizon) are rounded to this many decimals, as
        annotation tools store them (2: 0.01 px); None keeps them exact
    confidence : a :class:`~.confidence_workers.ConfidentWorkers` pool: every reference is then a
        range with a stated confidence, by a worker of the pool, with the pool's true confidence
        map (the tier's measurement noise is not used; measure and mode follow the formats as
        usual). None (default) leaves the scene exactly as without the option

    Returns
    -------
    dict, a ``creference-scene/1`` scene whose ``ground_truth`` carries camera height, pitch,
    roll, handedness and the true reference lengths as extra keys.
    """
    rng = np.random.default_rng(rng)
    if isinstance(tier, str):
        if tier not in TIERS:
            raise ValueError(f"tier: expected one of {list(TIERS)}, got {tier!r}")
        tier = TIERS[tier]
    if n_target_annotations < 1 or n_references < 0:
        raise ValueError(f"n_target_annotations must be >= 1 and n_references >= 0, got "
                         f"{n_target_annotations!r} and {n_references!r}")
    if setting is None:
        setting = "indoor" if rng.uniform() < 2 / 3 else "outdoor"
    if setting not in SETTINGS:
        raise ValueError(f"setting: expected one of {list(SETTINGS)}, got {setting!r}")
    cfg = SETTINGS[setting]
    w_img, h_img = image_size
    f = _u(rng, (1000.0, 2600.0))
    h = _u(rng, cfg["height"])
    pitch = math.radians(_u(rng, cfg["pitch_deg"]))
    roll = math.radians(rng.uniform(-roll_deg, roll_deg))
    pp = np.array([w_img / 2, h_img / 2]) * (1 + rng.uniform(-principal_offset, principal_offset, 2))
    R = rotation_from_pitch_roll(pitch, roll)

    # target: the annotated corner c1 is the bottom corner nearest the camera
    catalogue = OBJECTS[setting]
    names = list(catalogue)
    tname = names[rng.integers(len(names))]
    size = tuple(round(_u(rng, r), 4) for r in catalogue[tname])  # as stated in the scene file
    L, W, H = size
    params, _, _ = _place(rng, setting, R, f, pp, h, size, w_img, h_img,
                          cfg["distance"] if distance_range is None else distance_range,
                          need_inside=np.arange(8))
    best = None
    for s in (1, -1):
        for k in (0.0, math.pi):
            p = params.copy()
            p[3] = (p[3] + k + math.pi) % (2 * math.pi) - math.pi
            c1 = box_points(p, dimension_corners(L, W, H, s))[0]
            dist = float(np.linalg.norm(c1[[0, 2]]))
            if best is None or dist < best[0]:
                best = (dist, s, p)
    _, handed, params = best
    corners_true, _ = project(box_points(params, dimension_corners(L, W, H, handed)), R, f, pp)
    lines = []
    for i in range(n_target_annotations):
        noisy = _round(corners_true + rng.normal(0.0, tier.target_px, corners_true.shape), decimals)
        lines.append({"worker": f"t{i + 1:02d}", "corners": noisy.tolist(),
                      "seconds": 183.5})

    # references
    refs, truths, true_lines = [], [], []
    dmin, dmax = cfg["distance"]
    order = rng.permutation(len(FORMATS))
    if format_offset is not None:
        order = (int(format_offset) + np.arange(len(FORMATS))) % len(FORMATS)
    for j in range(n_references):
        measure, mode, is_range = FORMATS[order[j % len(FORMATS)]]
        is_range = (is_range and not single_values) or confidence is not None
        oname = names[rng.integers(len(names))]
        osize = tuple(_u(rng, r) for r in catalogue[oname])
        oparams, ouv, overts = _place(rng, setting, R, f, pp, h, osize, w_img, h_img,
                                      (max(1.0, 0.5 * dmin), 1.3 * dmax), need_inside=np.arange(4))
        near = int(np.argmin(np.linalg.norm(overts[:4, [0, 2]], axis=1)))
        if measure == "length":  # bottom edge along the length from the nearest corner
            a, b = near, {0: 1, 1: 0, 2: 3, 3: 2}[near]
            seg_uv, seg_3d = ouv[[a, b]], overts[[a, b]]
        elif measure == "width":
            a, b = near, {0: 3, 3: 0, 1: 2, 2: 1}[near]
            seg_uv, seg_3d = ouv[[a, b]], overts[[a, b]]
        else:  # distance: ground line from the image's bottom edge up to the object's nearest corner
            q_uv = ouv[near]
            # the pixel on the bottom edge below it (it sees the ground, since pitch >= 0)
            p_uv = np.array([max(float(q_uv[0]), 1.0), float(h_img - 1)])
            p_3d = _backproject(R, f, pp, h, p_uv)
            seg_uv, seg_3d = np.array([p_uv, q_uv]), np.array([p_3d, overts[near]])
        true_len = float(np.linalg.norm(seg_3d[1] - seg_3d[0]))
        if confidence is None:
            stated = true_len * _measure_noise(rng, tier.measurement)
        else:
            worker, f_low, f_high, conf = confidence.state(rng)
            stated = true_len * math.sqrt(f_low * f_high)
        line = seg_uv + rng.normal(0.0, tier.reference_px, (2, 2))
        line[:, 0] = np.clip(line[:, 0], 0, w_img)
        line[:, 1] = np.clip(line[:, 1], 0, h_img)
        line = _round(line, decimals)
        ref = {"worker": f"r{j + 1:02d}", "object": oname, "measure": measure, "mode": mode}
        if mode == "relative":
            base = L if measure == "length" else W
            value, unit = stated / base, None
        else:
            unit = ["m", "ft", "in", "yd"][rng.integers(4)]
            value = stated / UNITS_TO_M[unit]
        if confidence is not None:
            per_metre = value / stated
            ref.update(worker=worker, confidence=conf,
                       range=[_sig(true_len * f_low * per_metre), _sig(true_len * f_high * per_metre)])
        elif is_range:
            precision = float(np.exp(rng.normal(math.log(RANGE_PRECISION["median"]),
                                                RANGE_PRECISION["log_sd"])))
            precision = min(precision, 1.9)  # keep the low end positive
            ref["range"] = [_sig(value * (1 - precision / 2)), _sig(value * (1 + precision / 2))]
        else:
            ref["value"] = _sig(value)
        if unit is not None:
            ref["unit"] = unit
        ref["line"] = line.tolist()
        ref["seconds"] = 64.4
        refs.append(ref)
        truths.append(true_len)
        true_lines.append(seg_uv.tolist())

    horizon = _round(horizon_from_rotation(R, f, pp, w_img), decimals)
    return {
        "format": SCENE_FORMAT,
        "image": {"width": int(w_img), "height": int(h_img)},
        "camera": {"principal_point": pp.tolist(), "focal_length_px": None},
        "horizon": horizon.tolist(),
        "target": {"id": target_id,
                   "dimensions_m": {"length": L, "width": W, "height": H},
                   "dimension_lines": lines},
        "references": refs,
        "ground_truth": {
            "location_m": params[:3].tolist(), "yaw_rad": float(params[3]), "focal_length_px": f,
            "camera_height_m": h, "pitch_rad": pitch, "roll_rad": roll, "handedness": handed,
            "setting": setting, "tier": tier.name, "target_object": tname, "reference_lengths_m": truths,
            "reference_lines_px": true_lines, "target_corners_px": corners_true.tolist(),
        },
    }


def _round(a: np.ndarray, decimals: int | None) -> np.ndarray:
    return a if decimals is None else np.round(a, decimals)


def _sig(x: float, digits: int = 4) -> float:
    """``x`` rounded to ``digits`` significant digits (as a worker would state it)."""
    return float(f"{x:.{digits}g}")


def _backproject(R, f, pp, h, uv):
    """Ground point (Y = h) seen at pixel ``uv`` by a camera with rotation R (a bare R, no horizon
    line, so :meth:`~creference_bayes.core.geometry.Camera.backproject_to_ground` does not apply)."""
    d = np.array([(uv[0] - pp[0]) / f, (uv[1] - pp[1]) / f, 1.0]) @ R
    return d * (h / d[1])

