"""From a batch folder to KITTI labels with their uncertainty (docs/labels.md).

Per image (``NAME`` = the image's file name without extension, or the scene file's when the
scene has no image; the targets of one image share its files; a frame, ``creference-scene/2``,
is one image with its shared camera: :mod:`.frame_batch`)::

    OUT/label_2/NAME.txt        one KITTI line per target: the MAP box, score = P(IoU ≥ 0.7)
    OUT/calib/NAME.txt          P2 = K·[R | 0] in the gravity-aligned frame (io/kitti.py)
    OUT/uncertainty/NAME.json   per object: MAP, posterior mean, covariance, HDIs, quality, draws

The boxes are read from ``results/KEY.json`` and the targets' sizes and cameras from the scene
copies ``scenes/KEY.json`` that ``creference batch`` keeps; a copy whose fingerprint differs
from the one its result records is not used (the scene changed: rerun the batch).
"""

from __future__ import annotations

from ...io.files import read_text
import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePath

import numpy as np

from ...core.geometry import Camera, box_points, box_vertices, horizon_line, rotation_from_pitch_roll
from ...io.kitti import (KittiObject, kitti_object, project_with, projection_matrix, write_calib_file,
                        write_label_file, write_sidecar, wrap_pi)
from ...io.frame_result import FRAME_RESULT_FORMAT
from ...io.frame_scene import frame_fingerprint, load_frame
from ...io.result import RESULT_FORMAT
from ...io.scene import Scene, SceneError, SceneWarning, load_scene, scene_fingerprint
from .quality import IOU_THRESHOLDS, LabelQuality, box_iou_3d, label_quality

__all__ = ["SIDECAR_FORMAT", "FRAME", "LabelInput", "ObjectLabel", "LabelExport", "camera_angles",
           "load_batch", "label_image", "export_labels"]

SIDECAR_FORMAT = "creference-kitti-uncertainty/1"
#: How the sidecar describes the frame of the labels and draws.
FRAME = {
    "name": "gravity-aligned camera frame (KITTI's rectified camera frame, R0_rect = I)",
    "axes": "x right, y down along gravity, z forward and horizontal; origin at the camera centre; metres",
    "rotation_y": "yaw about the y axis (gravity), radians; KITTI's box convention",
    "projection": "pixels = P2 @ [X; 1] with P2 = K [R | 0], R = Rz(roll) Rx(pitch) (the camera's rotation)",
}
#: The names of the package's parameters in KITTI's terms.
KITTI_NAMES = {"x": "location[0]", "y": "location[1]", "z": "location[2]", "yaw": "rotation_y"}
_UNITS = {"x": "m", "y": "m", "z": "m", "yaw": "rad", "focal_length_px": "px", "pitch": "rad",
          "roll": "rad", "distance_m": "m"}


def camera_angles(values: dict, scene: Scene, result: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(pitch, roll) in radians of a MAP or of draws (scalars or arrays of the same shape).

    The result's own ``pitch`` and ``roll`` when it has them; otherwise they follow from the
    horizon the estimate used (the scene's, else the one estimated from the image and kept in the
    result's ``horizon_estimate``) and the focal length; a level camera without a horizon.
    """
    if "pitch" in values and "roll" in values:
        return np.asarray(values["pitch"], float), np.asarray(values["roll"], float)
    camera = Camera.from_scene(scene)
    points = ((result or {}).get("horizon_estimate") or {}).get("points")
    if camera.horizon is None and points is not None:
        camera = replace(camera, horizon=horizon_line(np.asarray(points, float)))
    return camera.pitch_roll(np.asarray(values["focal_length_px"], float))


@dataclass(frozen=True)
class LabelInput:
    """One estimated target with its scene: ``group`` identifies its image, ``name`` its files."""

    key: str
    result: dict
    scene: Scene
    name: str
    group: str


def _image_group(key: str, result: dict, copy: dict) -> tuple[str, str]:
    source = PurePath(result["batch"]["source"])
    image = (copy.get("image") or {}).get("path")
    if image is None:
        return f"scene:{key}", source.stem
    path = PurePath(image) if PurePath(image).is_absolute() else source.parent / image
    return f"image:{Path(path).resolve(strict=False)}", PurePath(image).stem


def load_batch(batch_dir: str | Path, frames: bool = False) -> tuple[list, list[dict]]:
    """The batch's results that can be labelled (a :class:`LabelInput` per one-target scene and,
    with ``frames``, a :class:`~.frame_batch.FrameLabelInput` per frame), and the others with the
    reason (``key``, ``reason``; without ``frames``, a frame's is that it is a frame)."""
    from .frame_batch import FrameLabelInput

    batch_dir = Path(batch_dir)
    if not (batch_dir / "results").is_dir():
        raise FileNotFoundError(2, "not a batch folder (no results/ inside)", str(batch_dir))
    inputs, skipped = [], []
    for path in sorted((batch_dir / "results").rglob("*.json")):
        key = path.relative_to(batch_dir / "results").with_suffix("").as_posix()
        if any(part.startswith(".") for part in key.split("/")):
            continue  # a temporary file left by a write that was killed (io/files.py)
        try:
            result = json.loads(read_text(path))
            if result.get("format") not in (RESULT_FORMAT, FRAME_RESULT_FORMAT) or "batch" not in result:
                raise ValueError("not a result of creference batch")
            is_frame = result["format"] == FRAME_RESULT_FORMAT
            if is_frame and not frames:
                skipped.append({"key": key, "reason": "a frame (creference-result/2): not taken here yet"})
                continue
            copy_path = batch_dir / result["batch"]["scene_copy"]
            copy = json.loads(read_text(copy_path))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SceneWarning)
                scene = load_frame(copy_path) if is_frame else load_scene(copy_path)
        except (OSError, ValueError, KeyError, TypeError, SceneError) as exc:
            skipped.append({"key": key, "reason": f"cannot be read: {' '.join(str(exc).split())}"})
            continue
        fingerprint = frame_fingerprint(scene) if is_frame else scene_fingerprint(scene)
        if fingerprint != result.get("scene_id", {}).get("sha256"):
            skipped.append({"key": key, "reason": "its scene copy is not the scene of the result "
                                                  "(rerun creference batch)"})
        elif not ((result.get("draws") if is_frame else (result.get("posterior") or {}).get("draws"))):
            skipped.append({"key": key, "reason": "no posterior draws (batch run with --no-posterior?)"})
        else:
            group, name = _image_group(key, result, copy)
            kind = FrameLabelInput if is_frame else LabelInput
            inputs.append(kind(key, result, scene, name=name, group=group))
    return inputs, skipped


@dataclass(frozen=True)
class ObjectLabel:
    """One exported object: its KITTI line, quality, true IoU (with ground truth) and sidecar entry."""

    key: str
    name: str
    target: str
    kitti: KittiObject
    quality: LabelQuality
    true_iou: float | None
    sidecar: dict = field(repr=False)


def _sizes(scene: Scene) -> np.ndarray:
    t = scene.target
    return np.array([t.length, t.width, t.height])


def _draw_boxes(draws: dict, sizes: np.ndarray) -> np.ndarray:
    pose = np.column_stack([np.asarray(draws[k], float) for k in ("x", "y", "z", "yaw")])
    return np.hstack([pose, np.broadcast_to(sizes, (len(pose), 3))])


def _camera(inp: LabelInput) -> dict:
    m = inp.result["map"]
    pitch, roll = camera_angles(m, inp.scene, inp.result)
    return {"focal_length_px": float(m["focal_length_px"]), "pitch_rad": float(pitch),
            "roll_rad": float(roll), "principal_point": [float(v) for v in inp.scene.principal_point]}


def _P(cam: dict) -> np.ndarray:
    return projection_matrix(cam["focal_length_px"], cam["principal_point"],
                             rotation_from_pitch_roll(cam["pitch_rad"], cam["roll_rad"]))


def _sampled_names(draws: dict) -> list[str]:
    return [k for k in draws if k not in ("chain", "distance_m")]


def _covariance(draws: dict, names: list[str]) -> np.ndarray:
    cols = []
    for k in names:
        v = np.asarray(draws[k], float)
        if k == "yaw":  # circular: unwrap around the circular mean first
            m = np.arctan2(np.mean(np.sin(v)), np.mean(np.cos(v)))
            v = m + wrap_pi(v - m)
        cols.append(v)
    return np.atleast_2d(np.cov(np.column_stack(cols), rowvar=False))


def _thin(draws: dict, names: list[str], n: int) -> dict:
    total = len(draws["x"])
    idx = np.unique(np.linspace(0, total - 1, min(n, total)).round().astype(int))
    return {k: [float(np.asarray(draws[k], float)[i]) for i in idx] for k in names}


def _sidecar_entry(inp: LabelInput, line: int, obj: KittiObject, quality: LabelQuality, cam: dict,
                   mismatch_px: float, true_iou: float | None, n_draws: int) -> dict:
    res, scene = inp.result, inp.scene
    post, draws = res["posterior"], res["posterior"]["draws"]
    names = _sampled_names(draws)
    kept = _thin(draws, names, n_draws)
    if "pitch" not in kept:
        pitch, roll = camera_angles(kept, scene, res)
        kept["pitch"], kept["roll"] = np.round(pitch, 7).tolist(), np.round(roll, 7).tolist()
    cov = _covariance(draws, names)
    refs = [r.measure for r in scene.references]
    diag = res.get("diagnostics") or {}
    entry = {
        "line": line, "scene": inp.key, "target": res["target"], "type": obj.type,
        "dimensions_m": {"h": scene.target.height, "w": scene.target.width, "l": scene.target.length},
        "dimensions_fixed": True,
        "point_label": "map",
        "map": {**res["map"], "pitch": cam["pitch_rad"], "roll": cam["roll_rad"]},
        "posterior_mean": dict(post["mean"]),
        "posterior_sd": dict(post["sd"]),
        "covariance": {"parameters": names, "units": [_UNITS.get(k, "") for k in names],
                       "kitti_names": {k: KITTI_NAMES[k] for k in names if k in KITTI_NAMES},
                       "matrix": cov.round(10).tolist(), "n_draws": len(draws["x"]),
                       "note": "from the draws kept in the result; yaw unwrapped around its circular mean"},
        "hdi": post["hdi"],
        "quality": quality.to_dict(),
        "draws": {"n": len(kept["x"]), "note": "evenly spaced over the result's draws; boxes of G "
                  "with the fixed dimensions; pitch and roll are each draw's camera", **kept},
        "evidence": {"dimension_lines": len(scene.target.dimension_lines), "references": len(refs),
                     "references_by_measure": {m: refs.count(m) for m in sorted(set(refs))},
                     "converged": diag.get("converged"), "warnings": res.get("warnings", [])},
        "calib_mismatch_px": mismatch_px,
    }
    if true_iou is not None:
        entry["true_iou"] = true_iou
    return entry


def label_image(inputs: list[LabelInput], *, type_name: str | None = None, score_iou: float = 0.7,
                n_draws: int = 100) -> tuple[np.ndarray, dict, list[ObjectLabel]]:
    """Labels of the targets of one image: (P2, the camera used for it, one :class:`ObjectLabel` each).

    P2 is built from the target whose focal length is best known (smallest posterior sd; all
    agree when the scene gives the focal length). ``calib_mismatch_px`` in each sidecar entry is
    the largest distance between its box's corners projected with P2 and with its own estimate's camera.
    """
    inputs = sorted(inputs, key=lambda i: i.key)
    cams = [_camera(i) for i in inputs]
    sds = [(i.result["posterior"]["sd"].get("focal_length_px") or 0.0) for i in inputs]
    cam = cams[int(np.argmin(sds))]
    P2 = _P(cam)
    objects = []
    for line, (inp, own) in enumerate(zip(inputs, cams), start=1):
        sizes = _sizes(inp.scene)
        pose = np.array([inp.result["map"][k] for k in ("x", "y", "z", "yaw")], float)
        exported = np.concatenate([pose, sizes])
        quality = label_quality(exported, _draw_boxes(inp.result["posterior"]["draws"], sizes))
        tname = type_name or "_".join(str(inp.result["target"]).split()) or "Misc"
        obj = kitti_object(tname, pose, sizes, P2, inp.scene.image_size, quality.p_iou[float(score_iou)])
        corners = box_points(pose, box_vertices(*sizes))
        mismatch = float(np.max(np.linalg.norm(project_with(P2, corners)[0] - project_with(_P(own), corners)[0], axis=1)))
        gt = inp.scene.ground_truth
        true_iou = None
        if gt is not None and gt.yaw_rad is not None:
            truth = np.concatenate([gt.location_m, [gt.yaw_rad], sizes])
            true_iou = float(box_iou_3d(exported, truth[None])[0])
        entry = _sidecar_entry(inp, line, obj, quality, own, round(mismatch, 4), true_iou, n_draws)
        objects.append(ObjectLabel(inp.key, inp.name, inp.result["target"], obj, quality, true_iou, entry))
    return P2, cam, objects


@dataclass(frozen=True)
class LabelExport:
    """What :func:`export_labels` wrote: the objects, the images' names, the skipped results."""

    objects: list[ObjectLabel]
    images: list[str]
    skipped: list[dict]
    failed_scenes: list[dict]


def export_labels(batch_dir: str | Path, out: str | Path, *, type_name: str | None = None,
                  score_iou: float = 0.7, n_draws: int = 100) -> LabelExport:
    """Write ``label_2/``, ``calib/`` and ``uncertainty/`` for every labelled image of a batch.

    Parameters
    ----------
    batch_dir : a ``creference batch`` folder
    out : the label folder (created)
    type_name : the KITTI type of every object (default: a frame's object its class; a one-target
        scene's target its id, whitespace → ``_``)
    score_iou : the IoU threshold t of the score P(IoU ≥ t), one of :data:`IOU_THRESHOLDS`
    n_draws : posterior draws per object in the sidecar
    """
    if float(score_iou) not in IOU_THRESHOLDS:
        raise ValueError(f"score_iou: expected one of {list(IOU_THRESHOLDS)}, got {score_iou!r}")
    if type_name is not None and (not type_name or any(c.isspace() for c in type_name)):
        raise ValueError(f"type: a KITTI class name has no whitespace, got {type_name!r}")
    if n_draws < 1:
        raise ValueError(f"draws: expected an integer >= 1, got {n_draws!r}")
    from .frame_batch import FrameLabelInput, label_frame

    inputs, skipped = load_batch(batch_dir, frames=True)
    groups: dict[str, list] = {}
    for inp in inputs:
        groups.setdefault(inp.group, []).append(inp)
    for group, members in groups.items():
        frames = [m.key for m in members if isinstance(m, FrameLabelInput)]
        if frames and len(members) > 1:
            others = [m.key for m in members if m.key != frames[0]]
            raise ValueError(f"the frame {frames[0]} and {', '.join(others)} are of one image ({group}): "
                             "a frame holds all the objects of its image (export them from separate batches)")
    names: dict[str, str] = {}
    for group, members in groups.items():
        name = members[0].name
        if name in names:
            raise ValueError(f"two images would share the label name {name!r}: {names[name]} and "
                             f"{group} (export them from separate batches)")
        names[name] = group
    out = Path(out)
    objects = []
    for name in sorted(names):
        members = groups[names[name]]
        if isinstance(members[0], FrameLabelInput):
            P2, doc, objs = label_frame(members[0], type_name=type_name, score_iou=score_iou, n_draws=n_draws,
                                        frame_description=FRAME)
        else:
            P2, cam, objs = label_image(members, type_name=type_name, score_iou=score_iou, n_draws=n_draws)
            doc = {"format": SIDECAR_FORMAT, "image": name, "label_file": f"label_2/{name}.txt",
                   "calib_file": f"calib/{name}.txt", "frame": FRAME, "camera": cam,
                   "score": f"P(IoU >= {float(score_iou):g})", "objects": [o.sidecar for o in objs]}
        write_calib_file(out / "calib" / f"{name}.txt", P2)
        write_label_file(out / "label_2" / f"{name}.txt", [o.kitti for o in objs])
        write_sidecar(out / "uncertainty" / f"{name}.json", doc)
        objects += objs
    failed = []
    for path in sorted((Path(batch_dir) / "errors").rglob("*.json")):
        if path.name.startswith("."):
            continue
        try:
            d = json.loads(read_text(path))
            failed.append({"key": d["key"], "error": d["error"]})
        except (OSError, ValueError, KeyError):
            continue
    return LabelExport(objects, sorted(names), skipped, failed)
