"""Simulated frames: several objects of known classes on one photo, with exact ground truth.

Two kinds of scene:

* ``street`` — a car-mounted camera as in KITTI (a wide image, µ 650–1100 px, height 1.4–1.9 m,
  pitch and roll within a few degrees, the principal point off-centre by up to 3 %), cars, vans,
  trucks, pedestrians and cyclists 4–60 m away, sizes drawn from the KITTI class priors.
* ``indoor`` — a hand-held photo of a room (2880 × 1800, µ 1000–2600 px, height 1.0–1.8 m,
  pitch 0–15° down), furniture 2–10 m away, sizes from the indoor classes below.

Every object's ground lies N(0, ``ground_sd_m``²) off the reference plane (uneven roads and
floors). Dimension lines: ``n_annotations`` per object, every corner moved by Gaussian noise of
``noise_px`` (or heavy-tailed noise with ``heavy_tails``: a Student-t with 3 degrees of freedom at
the same scale) and rounded to 0.01 px. Objects are kept when all four annotated corners are in
the image. The output is a ``creference-scene/2`` dict with ``ground_truth`` per target and for the
camera.
"""

from __future__ import annotations

import numpy as np

from ..models.frame import O_GROUND, O_SIZE, FrameModel, ObjectData
from ..models.size_priors import KITTI_SIZE_PRIORS, SizePrior

__all__ = ["INDOOR_CLASSES", "STREET_MIX", "simulate_frame", "KINDS"]

KINDS = ("street", "indoor")
#: Classes of the indoor scenes (medians in metres, log-sd), written into the scene's ``classes``.
INDOOR_CLASSES = {
    "chair": SizePrior((0.50, 0.50, 0.90), (0.15, 0.15, 0.10), "simulator"),
    "table": SizePrior((1.40, 0.80, 0.75), (0.25, 0.20, 0.08), "simulator"),
    "sofa": SizePrior((2.00, 0.90, 0.85), (0.20, 0.10, 0.10), "simulator"),
    "bookcase": SizePrior((0.90, 0.35, 1.80), (0.25, 0.20, 0.20), "simulator"),
    "bed": SizePrior((2.05, 1.50, 0.55), (0.05, 0.20, 0.20), "simulator"),
}
#: Share of each KITTI class among street objects.
STREET_MIX = {"Car": 0.6, "Van": 0.08, "Truck": 0.04, "Pedestrian": 0.18, "Cyclist": 0.1}


def _camera(kind: str, rng) -> tuple[dict, np.ndarray]:
    if kind == "street":
        w, h = 1242, 375
        mu = rng.uniform(650, 1100)
        cam = np.array([mu, np.radians(rng.uniform(-3, 3)), np.radians(rng.uniform(-2, 2)), rng.uniform(1.4, 1.9), 0.5])
    else:
        w, h = 2880, 1800
        mu = rng.uniform(1000, 2600)
        cam = np.array([mu, np.radians(rng.uniform(0, 15)), np.radians(rng.uniform(-3, 3)), rng.uniform(1.0, 1.8), 0.5])
    pp = np.array([w / 2, h / 2]) * (1 + rng.uniform(-0.03, 0.03, 2))
    return {"width": w, "height": h, "principal_point": pp}, cam


def _draw_object(kind: str, rng, classes: dict):
    if kind == "street":
        names, p = zip(*STREET_MIX.items())
        cls = str(rng.choice(names, p=np.array(p) / sum(p)))
        z = float(np.exp(rng.uniform(np.log(4.0), np.log(60.0))))
    else:
        cls = str(rng.choice(list(classes)))
        z = rng.uniform(2.0, 10.0)
    prior = classes[cls]
    sizes = np.exp(prior.log_median + rng.normal(0, 1, 3) * np.asarray(prior.log_sd))
    return cls, z, sizes


def simulate_frame(rng=None, *, kind: str = "street", n_objects: int = 5, n_annotations: int = 5,
                   noise_px: float = 2.0, heavy_tails: bool = False, ground_sd_m: float = 0.08,
                   focal_known: bool = False, horizon: str = "none", max_tries: int = 2000) -> dict:
    """One simulated frame as a ``creference-scene/2`` dict (module docstring).

    Parameters
    ----------
    rng : seed or Generator
    kind : ``street`` or ``indoor``
    n_objects : targets in the frame (fewer if the image cannot hold them)
    n_annotations, noise_px, heavy_tails : the dimension lines per target and their noise (px)
    ground_sd_m : spread of the objects' ground around the plane, metres
    focal_known : write the true focal length into the scene's camera
    horizon : ``none``, ``exact`` (the true horizon) or ``sd`` (the true horizon moved by
        N(0, 5 px) at each end, stated with ``horizon_sd_px`` 5)
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {list(KINDS)}, got {kind!r}")
    rng = np.random.default_rng(rng)
    classes = KITTI_SIZE_PRIORS if kind == "street" else INDOOR_CLASSES
    image, cam = _camera(kind, rng)
    w, h = image["width"], image["height"]
    objs, names = [], []
    probe = FrameModel(image["principal_point"], (w, h),
                       (ObjectData("probe", np.zeros((1, 4, 2)), 1, (1.0, 1.0, 1.0)),), orientation="free")
    occupied = []
    for _ in range(max_tries):
        if len(objs) >= n_objects:
            break
        cls, z, sizes = _draw_object(kind, rng, classes)
        half_fov = (w / 2) / cam[0]
        x = rng.uniform(-0.9, 0.9) * half_fov * z
        o = np.array([x, z, rng.uniform(-np.pi, np.pi), *sizes, rng.normal(0, ground_sd_m)])
        probe.handedness = np.array([1.0])
        uv, depth = probe.project(cam[None], o[None, None])
        if depth.min() < 1.0 or np.any(uv[0, 0] < 1) or np.any(uv[0, 0, :, 0] > w - 1) or np.any(uv[0, 0, :, 1] > h - 1):
            continue
        if any(np.hypot(x - a, z - b) < 0.6 * (sizes[0] + r) for a, b, r in occupied):
            continue  # boxes must not overlap on the ground
        occupied.append((x, z, sizes[0]))
        objs.append(o)
        names.append(cls)
    objs = np.array(objs)
    hands = rng.choice([1, -1], len(objs))
    model = FrameModel(image["principal_point"], (w, h),
                       tuple(ObjectData(f"t{i}", np.zeros((1, 4, 2)), int(hands[i]), None, classes[c], c)
                             for i, c in enumerate(names)), orientation="free")
    model.handedness = hands.astype(float)
    ann = model.simulate_annotations(cam, objs, n_annotations, 1.0, rng)
    clean, _ = model.project(cam[None], objs[None])
    noise = ann - clean[0][:, None]
    if heavy_tails:
        noise = rng.standard_t(3, noise.shape) * np.sqrt(1.0 / 3.0)
    ann = np.round(clean[0][:, None] + noise_px * noise, 2)
    scene = {
        "format": "creference-scene/2",
        "image": {"width": w, "height": h},
        "camera": {"principal_point": [round(float(v), 2) for v in image["principal_point"]]},
        "targets": [],
        "ground_truth": {"focal_length_px": float(cam[0]), "pitch_rad": float(cam[1]), "roll_rad": float(cam[2]),
                         "camera_height_m": float(cam[3])},
    }
    if kind == "indoor":
        scene["classes"] = {k: {"length_m": v.median_m[0], "width_m": v.median_m[1], "height_m": v.median_m[2],
                                "log_sd": list(v.log_sd)} for k, v in classes.items()}
    if focal_known:
        scene["camera"]["focal_length_px"] = float(cam[0])
    if horizon != "none":
        from ..core.geometry import horizon_from_rotation, rotation_from_pitch_roll

        pts = horizon_from_rotation(rotation_from_pitch_roll(cam[1], cam[2]), cam[0], image["principal_point"], w)
        if horizon == "sd":
            pts = pts + np.column_stack([np.zeros(2), rng.normal(0, 5.0, 2)])
            scene["horizon_sd_px"] = 5.0
        scene["horizon"] = np.round(pts, 2).tolist()
    for i, (o, c) in enumerate(zip(objs, names)):
        scene["targets"].append({
            "id": f"t{i}", "class": c,
            "dimension_lines": [{"corners": a.tolist()} for a in ann[i]],
            "ground_truth": {"location_m": [float(o[0]), float(cam[3] - o[O_GROUND]), float(o[1])],
                             "yaw_rad": float(o[2]), "handedness": int(hands[i]),
                             "dimensions_m": dict(zip(("length", "width", "height"), map(float, o[O_SIZE]))),
                             "ground_m": float(o[O_GROUND])},
        })
    return scene
