"""Synthetic scenes with exact ground truth (benchmark.md): one target or many, ``creference-scene/2``.

A scene is one camera and ``n_objects`` targets, boxes standing on the ground, each with noisy
dimension lines, plus reference objects measured by workers. Settings (:data:`SETTINGS`):
``indoor`` and ``outdoor`` (the paper's photos and Table 1 objects, :data:`OBJECTS`; the
benchmark's scenes) and ``street`` (a car-mounted camera as in KITTI; cars, vans, trucks,
pedestrians and cyclists uniform in log depth, sizes from the KITTI class priors). A setting's
camera comes from its own ranges, or (``cameras="real"``) from a population of real cameras
(:data:`REAL_CAMERAS`: phones, zoom, action and car-mounted cameras, each with its image size).

Noise tiers (:data:`TIERS`, and the crowds of :data:`CROWDS`) move the dimension lines' corners
(Gaussian, or Student-t with a tier's ``dof``), the reference lines' end points (each coordinate
off by N(0, ``reference_px``²) around the true segment's projection, so a drawn segment is always
noisy but in tier ``none``) and the workers' measurements (:func:`measurement_factor`, a share
``outliers`` of them off by a factor log-uniform within ±:data:`OUTLIER_FACTOR` instead).
References cycle through the paper's ten formats (:data:`FORMATS`). Targets' sizes are stated
(``sizes="known"``) or left to their class's prior (``"prior"``: KITTI's shipped classes, or
:func:`class_priors` written into the scene). With several targets, each one's ground may lie
N(0, ``ground_sd_m``²) off the plane. Everything is drawn from one ``numpy.random.Generator``: the
same seed gives the same scene.
"""

from __future__ import annotations

import errno
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.geometry import (box_points, box_vertices, dimension_corners, horizon_from_rotation,
                             project, rotation_from_pitch_roll)
from ..core.units import UNITS_TO_M
from ..models.camera_terms import FULL_FRAME_DIAGONAL_MM
from ..models.contract import REF_SCALE_MEDIAN
from ..models.size_priors import KITTI_SIZE_PRIORS, SizePrior
from .confidence_workers import ConfidentWorkers

__all__ = ["NoiseTier", "TIERS", "CROWDS", "OUTLIER_FACTOR", "noise_tier", "OBJECTS", "SETTINGS", "REAL_CAMERAS", "CAMERA_POPULATIONS", "FORMATS", "PAPER_NOISE", "RANGE_PRECISION", "STREET_MIX",
           "simulate_scene", "draw_camera", "measurement_factor", "class_priors", "true_state", "write_scenes"]


@dataclass(frozen=True)
class NoiseTier:
    """Annotation noise: target corner σ (px; with ``dof`` a Student-t of that standard deviation),
    reference endpoint σ (px), measurement model (:func:`measurement_factor`) and the share of
    measurements that are outliers (off by a factor log-uniform within ±:data:`OUTLIER_FACTOR`)."""

    name: str
    target_px: float
    reference_px: float
    measurement: str  # "none", "<x>%" (log-normal of log-sd x / 100) or "paper"
    dof: float | None = None
    outliers: float = 0.0


TIERS: dict[str, NoiseTier] = {
    "none": NoiseTier("none", 0.0, 0.0, "none"),
    "low": NoiseTier("low", 2.0, 5.0, "10%"),
    "medium": NoiseTier("medium", 5.0, 10.0, "40%"),
    "high": NoiseTier("high", 10.0, 30.0, "paper"),
}
#: Crowds whose drawn reference segments are noisy (issue 66): a light, careful crowd and a heavy one.
CROWDS: dict[str, NoiseTier] = {
    "light": NoiseTier("light", 2.0, 5.0, "10%"),
    "heavy": NoiseTier("heavy", 5.0, 10.0, "55%", outliers=0.12),
}
#: An outlier states the true length times a factor log-uniform in [1 / this, this] (a worker who
#: confuses units or measures another object).
OUTLIER_FACTOR = 10.0


def noise_tier(name: str | NoiseTier) -> NoiseTier:
    """The :class:`NoiseTier` of a name of :data:`TIERS` or :data:`CROWDS` (a tier is returned as is)."""
    if isinstance(name, NoiseTier):
        return name
    if name not in TIERS and name not in CROWDS:
        raise ValueError(f"tier: expected one of {[*TIERS, *CROWDS]}, got {name!r}")
    return TIERS.get(name) or CROWDS[name]

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
#: Share of each KITTI class among street objects (sizes from :data:`KITTI_SIZE_PRIORS`).
STREET_MIX = {"Car": 0.6, "Van": 0.08, "Truck": 0.04, "Pedestrian": 0.18, "Cyclist": 0.1}

#: Image, camera and distance ranges per setting (benchmark.md; street: KITTI-like).
SETTINGS = {
    "indoor": {"image": (2880, 1800), "focal": (1000.0, 2600.0), "height": (1.0, 1.8), "pitch_deg": (0.0, 15.0),
               "distance": (2.25, 10.0)},
    "outdoor": {"image": (2880, 1800), "focal": (1000.0, 2600.0), "height": (1.2, 2.5), "pitch_deg": (0.0, 10.0),
                "distance": (8.0, 45.0)},
    "street": {"image": (1242, 375), "focal": (650.0, 1100.0), "height": (1.4, 1.9), "pitch_deg": (-3.0, 3.0),
               "distance": (4.0, 60.0)},
}

#: Real cameras (``simulate_scene(cameras="real")``): per kind, the setting shares it is drawn with,
#: its image (width, height) px and its focal length, either a 35 mm-equivalent range (mm,
#: log-uniform; µ = mm / 43.27 × the image diagonal) or the calibrated µ of a named rig (px), and
#: for a vehicle's camera its mounting (height m, pitch °) instead of the setting's. Sources: the
#: makers' stated equivalents of current phones (main 23–28 mm, ultra-wide 13–16 mm, 2×–5×
#: telephoto 48–120 mm), the common 24–105 mm zoom range of interchangeable-lens cameras and
#: compacts, the linear mode of action cameras (16–24 mm); the calibration files of KITTI (P2,
#: 721.5 px on 1242 × 375), nuScenes' front camera (1266 px on 1600 × 900) and Cityscapes (2262 px
#: on 2048 × 1024). The shares are our assumption of who photographs what: phones most photos,
#: vehicle cameras a fifth of the outdoor ones and all the street ones.
REAL_CAMERAS = {
    "phone main": {"share": {"indoor": 0.6, "outdoor": 0.45}, "image": (4032, 3024), "equiv_mm": (23.0, 28.0)},
    "phone ultra-wide": {"share": {"indoor": 0.1, "outdoor": 0.08}, "image": (4032, 3024), "equiv_mm": (13.0, 16.0)},
    "phone telephoto": {"share": {"indoor": 0.05, "outdoor": 0.08}, "image": (4032, 3024), "equiv_mm": (48.0, 120.0)},
    "zoom camera": {"share": {"indoor": 0.2, "outdoor": 0.14}, "image": (6000, 4000), "equiv_mm": (24.0, 105.0)},
    "action camera": {"share": {"indoor": 0.05, "outdoor": 0.05}, "image": (1920, 1080), "equiv_mm": (16.0, 24.0)},
    "KITTI": {"share": {"outdoor": 0.08, "street": 0.4}, "image": (1242, 375), "focal_px": 721.5,
              "height": (1.6, 1.7), "pitch_deg": (-1.0, 1.0)},
    "nuScenes front": {"share": {"outdoor": 0.06, "street": 0.3}, "image": (1600, 900), "focal_px": 1266.0,
                       "height": (1.45, 1.6), "pitch_deg": (-1.0, 1.0)},
    "Cityscapes": {"share": {"outdoor": 0.06, "street": 0.3}, "image": (2048, 1024), "focal_px": 2262.0,
                   "height": (1.15, 1.3), "pitch_deg": (-1.0, 3.0)},
}
#: Where the bench's cameras come from: each setting's own ranges (:data:`SETTINGS`), or
#: :data:`REAL_CAMERAS`.
CAMERA_POPULATIONS = ("setting", "real")


def draw_camera(rng, setting: str, cameras: str = "setting") -> dict:
    """A camera for ``setting``: ``{"kind", "image": (w, h) px, "focal_px", "height_m", "pitch_deg"}``.
    ``cameras="setting"`` draws from the setting's ranges (:data:`SETTINGS`); ``"real"`` a kind of
    :data:`REAL_CAMERAS` by its share in the setting, then its focal length, and its mounting if it
    has one (else the setting's height and pitch)."""
    if cameras not in CAMERA_POPULATIONS:
        raise ValueError(f"cameras: expected one of {list(CAMERA_POPULATIONS)}, got {cameras!r}")
    cfg = SETTINGS[setting]
    if cameras == "setting":
        return {"kind": setting, "image": cfg["image"], "focal_px": float(rng.uniform(*cfg["focal"])),
                "height_m": float(rng.uniform(*cfg["height"])), "pitch_deg": float(rng.uniform(*cfg["pitch_deg"]))}
    kinds = [k for k, c in REAL_CAMERAS.items() if setting in c["share"]]
    share = np.array([REAL_CAMERAS[k]["share"][setting] for k in kinds])
    kind = kinds[int(rng.choice(len(kinds), p=share / share.sum()))]
    cam = REAL_CAMERAS[kind]
    if "focal_px" in cam:
        f = float(cam["focal_px"])
    else:
        f = math.exp(rng.uniform(*np.log(cam["equiv_mm"]))) / FULL_FRAME_DIAGONAL_MM * math.hypot(*cam["image"])
    return {"kind": kind, "image": cam["image"], "focal_px": f,
            "height_m": float(rng.uniform(*cam.get("height", cfg["height"]))),
            "pitch_deg": float(rng.uniform(*cam.get("pitch_deg", cfg["pitch_deg"])))}


#: The paper's ten measurement formats: (measure, mode, is_range).
FORMATS = tuple((m, mode, r) for m in ("length", "width", "distance") for mode in ("direct", "relative")
                for r in (False, True) if not (m == "distance" and mode == "relative"))

#: "Paper-like" worker measurements: the log of the error factor is ``scale · t_dof``, clipped to
#: ±log(clip) (the clip keeps the mean finite). Median absolute error 56 %, mean 160 %, like the
#: paper's Table 2 (tests/test_simulate.py checks these).
PAPER_NOISE = {"dof": 2.0, "scale": 0.75, "clip": 20.0}

#: Stated ranges: precision (Eq. 4) log-normal, median 25 %, log-sd 0.6 (mean ≈ 30 %, sd ≈ 20 %,
#: like the paper's Table 3), centred on the worker's (noisy) value.
RANGE_PRECISION = {"median": 0.25, "log_sd": 0.6}
_SIZES = ("length", "width", "height")


def measurement_factor(rng, model: str, size=None):
    """Multiplicative error factor(s) of a worker's measurement: stated = true × factor.

    Parameters
    ----------
    rng : numpy Generator
    model : ``"none"``, ``"<x>%"`` (log-normal of log-sd x / 100: ``"10%"`` 0.1, ``"40%"`` 0.4) or
        ``"paper"`` (heavy-tailed, :data:`PAPER_NOISE`)
    size : None for a float, else the shape of an array of factors
    """
    shape = () if size is None else size
    if model == "none":
        out = np.ones(shape)
    elif _percent(model) is not None:
        out = np.exp(rng.normal(0.0, _percent(model), shape))
    elif model == "paper":
        lim = math.log(PAPER_NOISE["clip"])
        out = np.exp(np.clip(PAPER_NOISE["scale"] * rng.standard_t(PAPER_NOISE["dof"], shape), -lim, lim))
    else:
        raise ValueError(f"measurement noise: unknown model {model!r} (expected none, a percentage such as 10% or paper)")
    return float(out) if size is None else out


def _percent(model: str) -> float | None:
    """x / 100 of a measurement model ``"<x>%"`` (x > 0), else None."""
    try:
        value = float(model[:-1]) / 100.0 if model.endswith("%") else None
    except ValueError:
        return None
    return value if value is not None and np.isfinite(value) and value > 0 else None


def class_priors(setting: str) -> dict[str, SizePrior]:
    """The size prior of each class of a setting: KITTI's for ``street``; for ``indoor`` and
    ``outdoor`` a log-normal over each :data:`OBJECTS` range (median its geometric centre, log-sd
    that of a uniform over the log-range, at least 0.02)."""
    if setting == "street":
        return {k: KITTI_SIZE_PRIORS[k] for k in STREET_MIX}
    return {name: SizePrior(tuple(math.sqrt(lo * hi) for lo, hi in r),
                            tuple(max(math.log(hi / lo) / math.sqrt(12.0), 0.02) for lo, hi in r), "simulator")
            for name, r in OBJECTS[setting].items()}


def _draw_object(rng, setting: str) -> tuple[str, tuple[float, float, float]]:
    """A class and its true size (m): uniform in the :data:`OBJECTS` ranges, or a KITTI prior draw."""
    if setting == "street":
        names, p = zip(*STREET_MIX.items())
        cls = str(rng.choice(names, p=np.array(p) / sum(p)))
        prior = KITTI_SIZE_PRIORS[cls]
        return cls, tuple(float(v) for v in np.exp(prior.log_median + rng.normal(0, 1, 3) * np.asarray(prior.log_sd)))
    names = list(OBJECTS[setting])
    cls = names[rng.integers(len(names))]
    return cls, tuple(float(rng.uniform(*r)) for r in OBJECTS[setting][cls])


def _place(rng, setting, R, f, pp, y, size, image, dist_range, need_inside, tries=400):
    """A ground position (bottom centre at height ``y`` below the camera) and yaw whose
    ``need_inside`` vertices lie in the image: (x, y, z, yaw, f), their pixels and points."""
    w_img, h_img = image
    for _ in range(tries):
        d = (math.exp(rng.uniform(math.log(dist_range[0]), math.log(dist_range[1]))) if setting == "street"
             else float(rng.uniform(*dist_range)))
        half_fov = math.atan2(0.45 * w_img, f)  # bearing within the horizontal field of view
        bearing = rng.uniform(-half_fov, half_fov)
        params = np.array([d * math.sin(bearing), y, d * math.cos(bearing), rng.uniform(-math.pi, math.pi), f])
        verts = box_points(params, box_vertices(*size))
        uv, depth = project(verts, R, f, pp)
        if np.any(depth <= 0.1):
            continue
        pts = uv[need_inside]
        if np.all((pts[:, 0] > 5) & (pts[:, 0] < w_img - 5) & (pts[:, 1] > 5) & (pts[:, 1] < h_img - 5)):
            return params, uv, verts
    raise RuntimeError("could not place an object inside the image")


def _nearest_first(params, size) -> tuple[int, np.ndarray]:
    """The handedness and yaw (among the box's symmetries) that put corner c1 of the dimension
    lines on the bottom corner nearest the camera, as a worker draws them."""
    best = None
    for s in (1, -1):
        for k in (0.0, math.pi):
            p = params.copy()
            p[3] = (p[3] + k + math.pi) % (2 * math.pi) - math.pi
            dist = float(np.linalg.norm(box_points(p, dimension_corners(*size, s))[0][[0, 2]]))
            if best is None or dist < best[0]:
                best = (dist, s, p)
    return best[1], best[2]


def simulate_scene(rng=None, *, setting: str | None = None, tier: str | NoiseTier = "none", n_objects: int = 1,
                   n_references: int = 5, n_target_annotations: int = 13, sizes: str = "known",
                   principal_offset: float = 0.0, roll_deg: float = 3.0, format_offset: int | None = None,
                   distance_range: tuple[float, float] | None = None, single_values: bool = False,
                   decimals: int | None = 2, confidence: ConfidentWorkers | None = None, ground_sd_m: float = 0.08,
                   horizon: str = "exact", focal_known: bool = False, cameras: str = "setting",
                   formats: tuple[int, ...] | None = None) -> dict:
    """Draw one synthetic scene.

    Parameters
    ----------
    rng : seed or Generator
    setting : a key of :data:`SETTINGS`, or None (two thirds indoor, one third outdoor)
    tier : a key of :data:`TIERS` or :data:`CROWDS`, or a :class:`NoiseTier`
    n_objects : targets (fewer when the image cannot hold them side by side; at least one)
    n_references : reference annotations (one object each), cycling through :data:`FORMATS`;
        relative ones are relative to the first target
    n_target_annotations : noisy copies of each target's dimension lines
    sizes : ``known`` (the targets' sizes are stated) or ``prior`` (left to their class's prior)
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
        range with a stated confidence, by a worker of the pool (the tier's measurement noise is
        not used); None leaves the scene exactly as without the option
    ground_sd_m : with several targets, the spread of their ground around the plane, metres
    horizon : ``exact`` (the true horizon), ``none``, or ``sd`` (moved by N(0, 5 px) at each end
        and stated with ``horizon_sd_px`` 5)
    focal_known : state the true focal length
    formats : indices of :data:`FORMATS` the references cycle through instead of all ten (e.g.
        the relative ones)
    cameras : ``setting`` (the setting's image, focal length and mounting ranges, :data:`SETTINGS`)
        or ``real`` (a camera of :data:`REAL_CAMERAS`, :func:`draw_camera`; its kind is in the
        ground truth's ``camera_kind``)

    Returns
    -------
    dict, a ``creference-scene/2`` scene. Its ``ground_truth`` holds the camera's (focal length,
    height, pitch, roll), the setting and tier and the references' true lengths and lines; each
    target's holds its location, yaw, handedness, size, ground offset and true corners.
    """
    rng = np.random.default_rng(rng)
    tier = noise_tier(tier)
    if n_target_annotations < 1 or n_references < 0 or n_objects < 1:
        raise ValueError(f"n_target_annotations and n_objects must be >= 1 and n_references >= 0, got "
                         f"{n_target_annotations!r}, {n_objects!r} and {n_references!r}")
    for name, value, allowed in (("sizes", sizes, ("known", "prior")), ("horizon", horizon, ("exact", "none", "sd"))):
        if value not in allowed:
            raise ValueError(f"{name}: expected one of {list(allowed)}, got {value!r}")
    if formats is not None and not (len(formats) and all(0 <= int(f) < len(FORMATS) for f in formats)):
        raise ValueError(f"formats: expected indices of FORMATS (0-{len(FORMATS) - 1}), got {formats!r}")
    if setting is None:
        setting = "indoor" if rng.uniform() < 2 / 3 else "outdoor"
    if setting not in SETTINGS:
        raise ValueError(f"setting: expected one of {list(SETTINGS)}, got {setting!r}")
    cfg = SETTINGS[setting]
    rnd = (lambda a: a) if decimals is None else (lambda a: np.round(a, decimals))
    # a real camera's photographer frames the subject: another camera when no target fits its view
    for _ in range(20 if cameras == "real" else 1):
        cam = draw_camera(rng, setting, cameras)
        image = w_img, h_img = cam["image"]
        f, h, pitch = cam["focal_px"], cam["height_m"], math.radians(cam["pitch_deg"])
        roll = math.radians(rng.uniform(-roll_deg, roll_deg))
        pp = np.array([w_img / 2, h_img / 2]) * (1 + rng.uniform(-principal_offset, principal_offset, 2))
        R = rotation_from_pitch_roll(pitch, roll)

        targets, placed = [], []
        for _ in range(20 * n_objects):
            if len(targets) == n_objects:
                break
            i = len(targets)
            ground = float(rng.normal(0.0, ground_sd_m)) if n_objects > 1 and ground_sd_m > 0 else 0.0
            cls, size = _draw_object(rng, setting)
            size = tuple(round(v, 4) for v in size)  # as stated in the scene file
            try:
                params, _, _ = _place(rng, setting, R, f, pp, h - ground, size, image,
                                      cfg["distance"] if distance_range is None else distance_range, np.arange(8))
            except RuntimeError:  # this object does not fit this camera's view (a telephoto, a near kiosk)
                continue
            if any(math.hypot(params[0] - p[0], params[2] - p[2]) < 0.6 * (max(size[:2]) + r) for p, r in placed):
                continue  # boxes must not overlap on the ground
            placed.append((params, max(size[:2])))
            handed, params = _nearest_first(params, size)
            corners, _ = project(box_points(params, dimension_corners(*size, handed)), R, f, pp)
            lines = []
            for k in range(n_target_annotations):
                if tier.dof is None:
                    noise = rng.normal(0.0, tier.target_px, corners.shape)
                else:  # a Student-t with the tier's standard deviation
                    noise = tier.target_px * math.sqrt((tier.dof - 2) / tier.dof) * rng.standard_t(tier.dof, corners.shape)
                lines.append({"worker": f"t{k + 1:02d}", "corners": rnd(corners + noise).tolist(), "seconds": 183.5})
            dims = dict(zip(_SIZES, size))
            targets.append({"id": "target" if n_objects == 1 else f"t{i}", "class": cls,
                            **({"dimensions_m": dims} if sizes == "known" else {}), "dimension_lines": lines,
                            "ground_truth": {"location_m": params[:3].tolist(), "yaw_rad": float(params[3]),
                                             "handedness": handed, "dimensions_m": dims, "ground_m": ground,
                                             "corners_px": corners.tolist()}})
        if targets:
            break
    if not targets:
        raise RuntimeError(f"could not place a target inside the {w_img}x{h_img} image (focal length {f:.0f} px)")

    refs, truths, true_lines = [], [], []
    first = targets[0]["ground_truth"]["dimensions_m"]
    dmin, dmax = cfg["distance"]
    pool = np.arange(len(FORMATS)) if formats is None else np.asarray(formats, int)
    order = pool[rng.permutation(len(pool))]
    if format_offset is not None:
        order = pool[(int(format_offset) + np.arange(len(pool))) % len(pool)]
    for j in range(n_references):
        measure, mode, is_range = FORMATS[order[j % len(pool)]]
        is_range = (is_range and not single_values) or confidence is not None
        for attempt in range(20):  # another object when one does not fit the view
            oname, osize = _draw_object(rng, setting)
            try:
                _, ouv, overts = _place(rng, setting, R, f, pp, h, osize, image,
                                        (max(1.0, 0.5 * dmin), 1.3 * dmax), np.arange(4))
                break
            except RuntimeError:
                if attempt == 19:
                    raise
        near = int(np.argmin(np.linalg.norm(overts[:4, [0, 2]], axis=1)))
        if measure in ("length", "width"):  # a bottom edge from the nearest corner
            other = ({0: 1, 1: 0, 2: 3, 3: 2} if measure == "length" else {0: 3, 3: 0, 1: 2, 2: 1})[near]
            seg_uv, seg_3d = ouv[[near, other]], overts[[near, other]]
        else:  # distance: ground line from the image's bottom edge up to the object's nearest corner
            q_uv = ouv[near]
            p_uv = np.array([max(float(q_uv[0]), 1.0), float(h_img - 1)])
            p_3d = _backproject(R, f, pp, h, p_uv)
            seg_uv, seg_3d = np.array([p_uv, q_uv]), np.array([p_3d, overts[near]])
        true_len = float(np.linalg.norm(seg_3d[1] - seg_3d[0]))
        if confidence is None:
            stated = true_len * measurement_factor(rng, tier.measurement)
            if tier.outliers and rng.uniform() < tier.outliers:
                stated = true_len * OUTLIER_FACTOR ** rng.uniform(-1.0, 1.0)
        else:
            worker, f_low, f_high, conf = confidence.state(rng)
            stated = true_len * math.sqrt(f_low * f_high)
        line = np.clip(seg_uv + rng.normal(0.0, tier.reference_px, (2, 2)), 0, [w_img, h_img])
        ref = {"worker": f"r{j + 1:02d}", "object": oname, "measure": measure, "mode": mode}
        if mode == "relative":
            value, unit = stated / first[measure], None
            ref["target"] = targets[0]["id"]
        else:
            unit = ["m", "ft", "in", "yd"][rng.integers(4)]
            value = stated / UNITS_TO_M[unit]
        if confidence is not None:
            per_metre = value / stated
            ref.update(worker=worker, confidence=conf,
                       range=[_sig(true_len * f_low * per_metre), _sig(true_len * f_high * per_metre)])
        elif is_range:
            precision = min(float(np.exp(rng.normal(math.log(RANGE_PRECISION["median"]), RANGE_PRECISION["log_sd"]))),
                            1.9)  # keep the low end positive
            ref["range"] = [_sig(value * (1 - precision / 2)), _sig(value * (1 + precision / 2))]
        else:
            ref["value"] = _sig(value)
        if unit is not None:
            ref["unit"] = unit
        refs.append({**ref, "line": rnd(line).tolist(), "seconds": 64.4})
        truths.append(true_len)
        true_lines.append(seg_uv.tolist())

    scene = {"format": "creference-scene/2", "image": {"width": int(w_img), "height": int(h_img)},
             "camera": {"principal_point": pp.tolist(), "focal_length_px": f if focal_known else None}}
    if horizon != "none":
        pts = horizon_from_rotation(R, f, pp, w_img)
        if horizon == "sd":
            pts = pts + np.column_stack([np.zeros(2), rng.normal(0, 5.0, 2)])
            scene["horizon_sd_px"] = 5.0
        scene["horizon"] = rnd(pts).tolist()
    if sizes == "prior" and setting != "street":
        scene["classes"] = {k: v.to_dict() for k, v in class_priors(setting).items()}
    scene.update(targets=targets, references=refs, ground_truth={
        "focal_length_px": f, "camera_height_m": h, "pitch_rad": pitch, "roll_rad": roll, "setting": setting,
        **({"camera_kind": cam["kind"]} if cameras == "real" else {}), "tier": tier.name, "reference_lengths_m": truths, "reference_lines_px": true_lines})
    return scene


def true_state(scene) -> tuple[np.ndarray, np.ndarray]:
    """The true camera (5,) and objects (m, 7) of a simulated scene (a parsed
    :class:`~creference_bayes.io.scene.Scene`), in the model's block order (the crowd scale at its
    prior median); ValueError when the scene has no simulated ground truth."""
    g = scene.ground_truth or {}
    if any(k not in g for k in ("focal_length_px", "camera_height_m", "pitch_rad", "roll_rad")):
        raise ValueError("scene: needs simulated ground truth (ground_truth.focal_length_px, camera_height_m, "
                         "pitch_rad and roll_rad)")
    camera = np.array([g["focal_length_px"], g["pitch_rad"], g["roll_rad"], g["camera_height_m"], REF_SCALE_MEDIAN])
    objects = []
    for t in scene.targets:
        x, y, z = t.ground_truth["location_m"]
        d = t.ground_truth["dimensions_m"]
        objects.append([x, z, t.ground_truth["yaw_rad"], d["length"], d["width"], d["height"], camera[3] - y])
    return camera, np.array(objects, float)


def write_scenes(outdir, n: int, seed: int = 0, tier: str = "all", setting: str | None = None,
                 *, overwrite: bool = False, noise_px: float | None = None, **options) -> list[Path]:
    """Write ``n`` simulated scenes ``scene_0000.json`` … to ``outdir`` (deterministic for ``seed``).

    ``tier`` is a name of :data:`TIERS` or :data:`CROWDS` or ``all`` (cycling none, low, medium,
    high); ``noise_px`` replaces
    its corner noise; reference formats cycle so that every ten references cover the ten formats
    once each. Each file is written whole or not at all. ``options`` go to :func:`simulate_scene`
    (``n_objects``, ``sizes``, ``confidence``, …).

    Raises
    ------
    FileExistsError
        When ``outdir`` exists and is not empty, unless ``overwrite`` (files of the same name are
        then replaced; other files are left alone).
    """
    from ..io.files import atomic_write_text

    outdir = Path(outdir)
    if not overwrite and outdir.is_dir() and any(outdir.iterdir()):
        raise FileExistsError(errno.EEXIST, "folder is not empty (overwrite=True replaces its scenes)", str(outdir))
    outdir.mkdir(parents=True, exist_ok=True)
    if tier != "all" and tier not in TIERS and tier not in CROWDS:
        raise ValueError(f"tier: expected one of {[*TIERS, *CROWDS, 'all']}, got {tier!r}")
    tiers = list(TIERS.values()) if tier == "all" else [noise_tier(tier)]
    if noise_px is not None:
        tiers = [replace(t, target_px=float(noise_px)) for t in tiers]
    paths = []
    for i in range(n):
        d = simulate_scene(np.random.default_rng([seed, i]), setting=setting, tier=tiers[i % len(tiers)],
                           format_offset=5 * i, **options)
        p = outdir / f"scene_{i:04d}.json"
        atomic_write_text(p, json.dumps(d, indent=1) + "\n")
        paths.append(p)
    return paths


def _sig(x: float, digits: int = 4) -> float:
    """``x`` rounded to ``digits`` significant digits (as a worker would state it)."""
    return float(f"{x:.{digits}g}")


def _backproject(R, f, pp, h, uv):
    """Ground point (Y = h) seen at pixel ``uv`` by a camera with rotation R."""
    d = np.array([(uv[0] - pp[0]) / f, (uv[1] - pp[1]) / f, 1.0]) @ R
    return d * (h / d[1])
