"""Scenes from a KITTI folder: simulated crowd annotations on real street geometry (docs/kitti.md).

``creference simulate --from-kitti DIR --out SCENES`` reads a KITTI-layout folder (``label_2/``,
``calib/``, and ``image_2/`` when present) and writes one ``creference-scene/2`` scene per image.
Every object a person could annotate is a target: KITTI's classes other than DontCare whose 2D box
is at least 25 px high, truncated at most 0.5 and occluded at most 2 (the devkit's "hard" limits),
and whose four annotated corners lie in the image, at least 1 m in front of the camera. It gets K
sets of dimension lines, drawn as a worker draws them (from the box's bottom corner nearest the
camera: length, width, then height): the projections with the image's P2 of its real box's
corners, moved by Gaussian noise of ``noise_px`` per coordinate and rounded to 0.01 px.

The scene gives what a user with a calibrated camera knows: P2's focal length and principal point,
P2 itself (``camera.kitti_p2``, so that labels go back into KITTI's frame) and the calib file's
other lines (``camera.kitti_calib``, written back beside the labels for tools that need the real
``Tr_velo_to_cam``); not the camera's height, pitch and roll, the horizon (estimated from the photo
when there is one) or the sizes (the class priors apply), unless ``sizes="known"`` (each object's
true size: a target of known size, the method's original premise). Ground truth (for evaluation
only): each target's KITTI label (``kitti``) and its location in the camera frame of P2
(``location_m``, the rectified frame moved by P2's offset).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..io.kitti_read import read_kitti_labels
from ..models.size_priors import KITTI_SIZE_PRIORS

__all__ = ["ANNOTATABLE", "SIZES", "read_p2", "read_calib", "kitti_scene", "kitti_scenes", "MIN_HEIGHT_PX",
           "MAX_TRUNCATION", "MAX_OCCLUSION", "LEFT_OUT"]

ANNOTATABLE = tuple(KITTI_SIZE_PRIORS)
MIN_HEIGHT_PX = 25.0
MAX_TRUNCATION = 0.5
MAX_OCCLUSION = 2
#: Why :func:`kitti_scenes` left an object out, by its ``skipped`` key, as a person reads it.
LEFT_OUT = {"class": "of a class nobody annotates", "height": f"under {MIN_HEIGHT_PX:g} px tall in the image",
            "truncation": f"truncated by over {MAX_TRUNCATION:g} of their size",
            "occlusion": f"of occlusion level over {MAX_OCCLUSION:g}", "outside": "outside the image"}
#: What the scenes say of the objects' sizes: ``prior`` (nothing: the class priors apply) or
#: ``known`` (each object's true size, ``dimensions_m``).
SIZES = ("prior", "known")


def read_calib(path: str | Path) -> dict[str, list[float]]:
    """Every line of a KITTI calib file as name → numbers (``P0`` … ``Tr_imu_to_velo``);
    ``ValueError`` naming the file and line."""
    path = Path(path)
    out = {}
    for no, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        name, sep, rest = line.partition(":")
        if not sep or not name.strip() or any(c.isspace() for c in name.strip()):
            raise ValueError(f"{path}:{no}: expected 'NAME: numbers', got {line.strip()[:60]!r}")
        try:
            values = [float(v) for v in rest.split()]
        except ValueError:
            raise ValueError(f"{path}:{no}: {name.strip()}: expected numbers, got {rest.strip()[:60]!r}") from None
        if not values or not np.all(np.isfinite(values)):
            raise ValueError(f"{path}:{no}: {name.strip()}: expected finite numbers, got {rest.strip()[:60]!r}")
        out[name.strip()] = values
    return out


def read_p2(path: str | Path) -> np.ndarray:
    """The (3, 4) P2 matrix of a KITTI calib file; ``ValueError`` naming the file and line."""
    calib = read_calib(path)
    if "P2" not in calib:
        raise ValueError(f"{path}: no 'P2:' line")
    if len(calib["P2"]) != 12:
        raise ValueError(f"{path}: P2: expected 12 numbers, got {len(calib['P2'])}")
    return np.array(calib["P2"]).reshape(3, 4)


def _image_size(path: Path | None) -> tuple[int, int]:
    if path is None:
        return 1242, 375
    from ..vision.images import image_size

    return image_size(path)


def _corners(loc, ry, dims_hwl, hand_corner):
    """World (rectified) points of the dimension lines drawn from bottom corner (a, b)."""
    h, w, l = dims_hwl
    a, b = hand_corner
    p = np.array([[a * l / 2, 0, b * w / 2], [-a * l / 2, 0, b * w / 2], [a * l / 2, 0, -b * w / 2],
                  [a * l / 2, -h, b * w / 2]])
    c, s = np.cos(ry), np.sin(ry)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return loc + p @ R.T


def kitti_scene(label_path, calib_path, image_path=None, *, rng=None, n_annotations: int = 5,
                noise_px: float = 2.0, frame_id: str | None = None, sizes: str = "prior",
                focal_known: bool = True) -> tuple[dict, dict]:
    """One scene (a ``creference-scene/2`` dict) and a report of which objects were kept and why
    the others were not; ``sizes`` one of :data:`SIZES`; ``focal_known`` False leaves P2's focal
    length out of the camera block (a street camera nobody calibrated: it stays in the ground truth)."""
    if sizes not in SIZES:
        raise ValueError(f"sizes: expected one of {list(SIZES)}, got {sizes!r}")
    rng = np.random.default_rng(rng)
    labels = read_kitti_labels(label_path, scores=False)
    P2 = read_p2(calib_path)
    calib = {k: v for k, v in read_calib(calib_path).items() if k != "P2"}
    w, h = _image_size(None if image_path is None else Path(image_path))
    K = P2[:, :3]
    offset = np.linalg.solve(K, P2[:, 3])  # the rectified frame → P2's camera frame
    skipped = {"class": 0, "height": 0, "truncation": 0, "occlusion": 0, "outside": 0}
    targets = []
    for i in range(len(labels)):
        cls = labels.type[i]
        if cls not in ANNOTATABLE:
            skipped["class"] += cls != "DontCare"
            continue
        why = next((k for k, bad in (("height", labels.height_px[i] < MIN_HEIGHT_PX),
                                     ("truncation", labels.truncated[i] > MAX_TRUNCATION),
                                     ("occlusion", labels.occluded[i] > MAX_OCCLUSION)) if bad), None)
        if why is not None:
            skipped[why] += 1
            continue
        loc, ry = labels.location[i], float(labels.rotation_y[i])
        hwl = labels.dimensions[i]
        # the bottom corner nearest to the camera
        best = min(((a, b) for a in (-1, 1) for b in (-1, 1)),
                   key=lambda ab: np.linalg.norm(_corners(loc, ry, hwl, ab)[0] + offset))
        pts = _corners(loc, ry, hwl, best)
        X = pts @ K.T + P2[:, 3]
        uv = X[:, :2] / np.maximum(X[:, 2:], 1.0)  # the same where kept (depth ≥ 1 m)
        if np.any(X[:, 2] < 1.0) or np.any(uv < 0) or np.any(uv[:, 0] > w - 1) or np.any(uv[:, 1] > h - 1):
            skipped["outside"] += 1
            continue
        noisy = np.round(uv[None] + rng.normal(0.0, noise_px, (n_annotations, 4, 2)), 2)
        # the model's convention (models/contract.py): yaw and handedness of the drawn lines
        a, b = best
        yaw, hand = (ry, -b) if a == -1 else (ry + np.pi, b)
        yaw = float((yaw + np.pi) % (2 * np.pi) - np.pi)
        size = {"length": float(hwl[2]), "width": float(hwl[1]), "height": float(hwl[0])}
        targets.append({
            "id": f"{i}", "class": cls,
            **({"dimensions_m": dict(size)} if sizes == "known" else {}),
            "dimension_lines": [{"worker": f"w{k}", "corners": c.tolist()} for k, c in enumerate(noisy)],
            "ground_truth": {"location_m": (loc + offset).tolist(), "yaw_rad": yaw, "handedness": int(hand),
                             "dimensions_m": size,
                             "kitti": {"type": cls, "location": loc.tolist(), "rotation_y": ry,
                                       "dimensions_hwl": hwl.tolist(), "truncated": float(labels.truncated[i]),
                                       "occluded": int(labels.occluded[i]), "line": int(labels.line[i])}},
        })
    scene = {"format": "creference-scene/2", "image": {"width": int(w), "height": int(h)},
             "camera": {"id": kitti_camera_id(P2), "principal_point": [float(P2[0, 2]), float(P2[1, 2])],
                        **({"focal_length_px": float(P2[0, 0])} if focal_known else {}),
                        "kitti_p2": P2.tolist(), "kitti_calib": calib},
             "targets": targets, "ground_truth": {"frame": frame_id, "focal_length_px": float(P2[0, 0])}}
    if image_path is not None:
        scene["image"]["path"] = str(image_path)
    return scene, {"kept": len(targets), "skipped": skipped}


def kitti_camera_id(P2: np.ndarray) -> str:
    """The camera id of a KITTI calibration: ``kitti-`` and 10 hex digits of P2's SHA-256 (P2 as
    the calib file gives it, 12 significant digits), so that the same P2 gives the same id."""
    text = " ".join(f"{v:.12g}" for v in np.asarray(P2, float).ravel())
    return "kitti-" + hashlib.sha256(text.encode()).hexdigest()[:10]


def kitti_scenes(folder, out, *, n_annotations: int = 5, noise_px: float = 2.0, seed: int = 0,
                 progress=None, sizes: str = "prior", focal_known: bool = True) -> dict:
    """Write one scene per label file of ``folder`` into ``out`` (``<id>.json``); returns the totals
    of kept and skipped objects. Images without an annotatable object are not written."""
    from ..io.files import atomic_write_json

    folder, out = Path(folder), Path(out)
    labels = sorted((folder / "label_2").glob("*.txt"))
    if not labels:
        raise FileNotFoundError(2, "no label files (*.txt)", str(folder / "label_2"))
    out.mkdir(parents=True, exist_ok=True)
    totals = {"scenes": 0, "kept": 0, "skipped": {}}
    for k, lp in enumerate(labels):
        calib = folder / "calib" / lp.name
        image = folder / "image_2" / (lp.stem + ".png")
        scene, rep = kitti_scene(lp, calib, image.resolve() if image.exists() else None, rng=[seed, k],
                                 n_annotations=n_annotations, noise_px=noise_px, frame_id=lp.stem,
                                 sizes=sizes, focal_known=focal_known)
        for key, v in rep["skipped"].items():
            totals["skipped"][key] = totals["skipped"].get(key, 0) + v
        if rep["kept"]:
            atomic_write_json(out / f"{lp.stem}.json", scene)
            totals["scenes"] += 1
            totals["kept"] += rep["kept"]
        if progress:
            progress(f"{lp.stem}: {rep['kept']} objects")
    return totals
