"""KITTI labels of the scenes of one image: one label file, one calib, one uncertainty sidecar.

Each target of each scene becomes one label line: its box is the MAP, ``type`` its class (else
its id), its score and the sidecar's quality P(IoU ≥ t), the share of the result's posterior draws
whose box overlaps the label's box by at least t (3D IoU, :mod:`~creference_bayes.evaluation.iou3d`).

The labels' frame. A scene made from a KITTI folder (``camera.kitti_p2``) gets its labels in
KITTI's own frame, the rectified camera frame of its P2: a point X of the model's gravity-aligned
frame is R(pitch, roll) X in the camera of P2, minus P2's offset K⁻¹ P2[:, 3]; a box's turn follows
its length axis through the same rotation; the calib file is P2 with the folder's other lines
(``camera.kitti_calib``). Any other scene gets labels in the gravity-aligned frame (x right, y down
along gravity, z forward) and a calib with P2 = K [R | 0] from the MAP camera, R = Rz(roll) Rx(pitch)
(:mod:`creference_bayes.io.kitti`). Several scenes of one image share its files; P2 is then the
camera of the scene whose focal length is best known, and ``calib_mismatch_px`` says how far each
box's corners move between its own scene's P2 and the image's.

The sidecar, ``creference-kitti-uncertainty/2`` (:data:`~creference_bayes.io.kitti.SIDECAR_FORMAT`),
holds the image, its scenes and files, the frame of the labels, the camera of P2 (MAP, posterior
summary and draws) and one entry per label line (its box, MAP and posterior, covariance in the
labels' frame, quality, evenly spaced draws, ``calib_mismatch_px`` and, with ground truth,
``true_iou``); every key is listed in docs/labels.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.geometry import box_points, box_vertices, rotation_from_pitch_roll
from ...io.kitti import (SIDECAR_FORMAT, KittiObject, kitti_object, project_with, projection_matrix,
                         write_calib_file, write_label_file, write_sidecar, wrap_pi)
from ...io.result import stored_draws
from ...io.scene import Scene
from ...models.contract import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, CAMERA_NAMES, O_GROUND, O_SIZE, O_X, O_YAW, O_Z
from ...pipeline import map_state
from .quality import LabelQuality, box_iou_3d, label_quality

__all__ = ["GRAVITY_FRAME", "KITTI_FRAME", "LabelInput", "ObjectLabel", "kitti_poses", "label_p2", "truth_boxes",
           "image_labels", "write_labels"]

#: How the sidecar describes the gravity-aligned frame of the labels.
GRAVITY_FRAME = {
    "name": "gravity-aligned camera frame (KITTI's rectified camera frame, R0_rect = I)",
    "axes": "x right, y down along gravity, z forward and horizontal; origin at the camera centre; metres",
    "rotation_y": "yaw about the y axis (gravity), radians; KITTI's box convention",
    "projection": "pixels = P2 @ [X; 1] with P2 = K [R | 0], R = Rz(roll) Rx(pitch) (the camera's rotation)",
}
#: How the sidecar describes the frame of the labels of a scene made from a KITTI folder.
KITTI_FRAME = {
    "name": "KITTI's rectified camera frame of the input calib's P2 (camera.kitti_p2 of the scene)",
    "axes": "x right, y down, z forward; origin at the rectified camera centre; metres (KITTI's own)",
    "rotation_y": "yaw about the y axis, radians; KITTI's box convention",
    "projection": "pixels = P2 @ [X; 1] with the scene's own P2 (the calib file repeats it)",
}
_BOX = ("x", "y", "z", "rotation_y", "length", "width", "height")


@dataclass(frozen=True)
class LabelInput:
    """One estimated scene: its KEY in the batch, its result (a ``creference-result/2`` dict), the
    scene, the name of its image's files and the image it is of (``group``)."""

    key: str
    result: dict
    scene: Scene
    name: str = ""
    group: str = ""


@dataclass(frozen=True)
class ObjectLabel:
    """One exported target: its KITTI line, quality (None without draws), true IoU (with ground
    truth) and sidecar entry."""

    key: str
    name: str
    target: str
    kitti: KittiObject
    quality: LabelQuality | None
    true_iou: float | None
    sidecar: dict = field(repr=False)


def kitti_poses(scene: Scene, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
    """Boxes of states in the labels' frame (module docstring).

    Parameters
    ----------
    scene : the scene (its ``kitti_p2`` decides the frame)
    cams : (n, 5) cameras, objs : (n, m, 7) objects, natural parameters (``models.contract``)

    Returns
    -------
    (n, m, 7) x, y, z (bottom centre, m), rotation_y (rad), length, width, height (m)
    """
    cams = np.atleast_2d(cams)
    objs = np.asarray(objs, float).reshape(len(cams), -1, 7)
    P = np.stack([objs[..., O_X], cams[:, C_HEIGHT, None] - objs[..., O_GROUND], objs[..., O_Z]], axis=-1)
    d = np.stack([np.cos(objs[..., O_YAW]), np.zeros(objs.shape[:2]), -np.sin(objs[..., O_YAW])], axis=-1)
    if scene.kitti_p2 is not None:
        P2 = np.asarray(scene.kitti_p2, float)
        R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])
        P = np.einsum("nij,nmj->nmi", R, P) - np.linalg.solve(P2[:, :3], P2[:, 3])
        d = np.einsum("nij,nmj->nmi", R, d)
    return np.concatenate([P, np.arctan2(-d[..., 2], d[..., 0])[..., None], objs[..., O_SIZE]], axis=-1)


def label_p2(scene: Scene, camera: np.ndarray) -> np.ndarray:
    """The calib's P2 (3, 4) of a scene with the MAP ``camera`` (5,): KITTI's own, else K [R | 0]."""
    if scene.kitti_p2 is not None:
        return np.asarray(scene.kitti_p2, float)
    R = rotation_from_pitch_roll(camera[C_PITCH], camera[C_ROLL])
    return projection_matrix(float(camera[C_FOCAL]), scene.principal_point, R)


def truth_boxes(scene: Scene) -> list[np.ndarray | None]:
    """Each target's true box (7,) in the labels' frame from its ground truth, or None.

    A scene with ``kitti_p2`` compares with KITTI's own label (``ground_truth.kitti``); another
    scene's labels and truth are both in the gravity-aligned frame (``location_m``, ``yaw_rad``,
    ``dimensions_m`` or the target's known dimensions)."""
    out = []
    for t in scene.targets:
        g = t.ground_truth or {}
        box = None
        if scene.kitti_p2 is not None:
            if g.get("kitti") is not None:
                h, w, l = g["kitti"]["dimensions_hwl"]
                box = np.array([*g["kitti"]["location"], g["kitti"]["rotation_y"], l, w, h], float)
        elif "location_m" in g and g.get("yaw_rad") is not None:
            d = g.get("dimensions_m")
            sizes = [d["length"], d["width"], d["height"]] if d else t.dimensions
            if sizes is not None:
                box = np.array([*g["location_m"], g["yaw_rad"], *sizes], float)
        out.append(box)
    return out


def _thin(n: int, k: int) -> np.ndarray:
    """``k`` evenly spaced indices of ``n``."""
    return np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(int))


def _covariance(boxes: np.ndarray, names: list[str]) -> list[list[float]]:
    """Sample covariance of draws' boxes (n, 7), rotation_y unwrapped around its circular mean."""
    cols = [boxes[:, _BOX.index(k)] for k in names]
    ry = cols[3]
    centre = np.arctan2(np.mean(np.sin(ry)), np.mean(np.cos(ry)))
    cols[3] = centre + wrap_pi(ry - centre)
    return np.atleast_2d(np.cov(np.column_stack(cols), rowvar=False)).round(10).tolist()


def _n_references(scene: Scene) -> list[int]:
    """Per target, the references that bear on it: those naming it and those of the whole scene."""
    out = [0] * len(scene.targets)
    for owner in scene.reference_targets:
        for k in (owner if isinstance(owner, tuple) else range(len(out)) if owner is None else (owner,)):
            out[k] += 1
    return out


def _scene_labels(inp: LabelInput, P2: np.ndarray, first_line: int, *, type_name, score_iou, n_draws):
    """The :class:`ObjectLabel` of each target of one scene, its lines numbered from ``first_line``."""
    scene, res = inp.scene, inp.result
    camera, objs = map_state(res)
    boxes = kitti_poses(scene, camera[None], objs[None])[0]
    kept = stored_draws(res)
    samples = None if kept is None else kitti_poses(scene, kept.cameras[0], kept.objects[0])
    own = label_p2(scene, camera)
    n_refs = _n_references(scene)
    diag = res.get("diagnostics") or {}
    out = []
    for i, (t, o, truth) in enumerate(zip(scene.targets, res["objects"], truth_boxes(scene))):
        quality = None if samples is None else label_quality(boxes[i], samples[:, i])
        score = 1.0 if quality is None else quality.p_iou[float(score_iou)]
        kobj = kitti_object(type_name or "_".join(str(t.cls or t.id).split()) or "Object", boxes[i, :4],
                            boxes[i, 4:7], P2, scene.image_size, score)
        corners = box_points(boxes[i, :4], box_vertices(*boxes[i, 4:7]))
        mismatch = float(np.max(np.linalg.norm(project_with(P2, corners)[0] - project_with(own, corners)[0], axis=1)))
        true_iou = None if truth is None else float(box_iou_3d(boxes[i], truth[None])[0])
        entry = {"line": first_line + i, "scene": inp.key, "target": t.id, "class": t.cls, "type": kobj.type,
                 "size": o.get("size"),
                 "label": {"location": [float(v) for v in boxes[i, :3]], "rotation_y": float(boxes[i, 3]),
                           "dimensions_hwl": [float(boxes[i, 6]), float(boxes[i, 5]), float(boxes[i, 4])]},
                 "point_label": "map", "map": o["map"], "posterior": o.get("posterior"),
                 "evidence": {"dimension_lines": len(t.dimension_lines), "references": n_refs[i],
                              "converged": diag.get("converged"), "warnings": res.get("warnings", [])},
                 "calib_mismatch_px": round(mismatch, 4)}
        if samples is not None:
            names = list(_BOX[:4] if o.get("size") == "known" else _BOX)
            pick = samples[_thin(len(samples), n_draws), i]
            entry["covariance"] = {"parameters": names, "units": ["m", "m", "m", "rad", "m", "m", "m"][:len(names)],
                                   "matrix": _covariance(samples[:, i], names), "n_draws": len(samples)}
            entry["quality"] = quality.to_dict()
            entry["draws"] = {"n": len(pick), "note": "evenly spaced over the result's draws (the same draws as the "
                              "camera's): boxes in the labels' frame; sizes only when estimated",
                              **{k: np.round(pick[:, _BOX.index(k)], 6).tolist() for k in names}}
        if true_iou is not None:
            entry["true_iou"] = true_iou
        out.append(ObjectLabel(inp.key, inp.name, t.id, kobj, quality, true_iou, entry))
    return out


def image_labels(members: list[LabelInput], name: str, *, type_name: str | None = None, score_iou: float = 0.7,
                 n_draws: int = 100):
    """The labels of the scenes of one image.

    Parameters
    ----------
    members : the image's scenes and their results (one or more; lines in this order)
    name : the image's label name (``label_2/NAME.txt``)
    type_name : the KITTI type of every object (default: each target's class, else its id)
    score_iou : t of the score P(IoU ≥ t)
    n_draws : box and camera draws per object in the sidecar (evenly spaced over the result's)

    Returns
    -------
    (P2 (3, 4), the calib's other lines (name → numbers) or None, one :class:`ObjectLabel` per
    target, the sidecar document or None when a result has no posterior draws (scores are then 1))
    """
    cams = [map_state(m.result)[0] for m in members]
    sds = [(m.result["camera"].get("posterior") or {}).get("sd", {}).get("focal_length_px") or 0.0 for m in members]
    ref = int(np.argmin(sds))  # the best known focal length (all equal when the scenes give it)
    P2 = label_p2(members[ref].scene, cams[ref])
    objects = []
    for m in members:
        objects += _scene_labels(m, P2, len(objects) + 1, type_name=type_name, score_iou=score_iou, n_draws=n_draws)
    calib = members[ref].scene.kitti_calib
    if any(o.quality is None for o in objects):
        return P2, calib, objects, None
    res, cam = members[ref].result, cams[ref]
    kept = stored_draws(res).cameras[0]
    pick = kept[_thin(len(kept), n_draws)]
    camera = {"scene": members[ref].key, "map": res["camera"]["map"], "free": res["camera"]["free"],
              **({"posterior": res["camera"]["posterior"]} if "posterior" in res["camera"] else {}),
              "principal_point": [float(v) for v in members[ref].scene.principal_point],
              "focal_length_px": float(cam[C_FOCAL]), "pitch_rad": float(cam[C_PITCH]), "roll_rad": float(cam[C_ROLL]),
              "draws": {"n": len(pick), **{k: np.round(pick[:, j], 6).tolist() for j, k in enumerate(CAMERA_NAMES)
                                           if k in res["camera"]["free"]}},
              **({"rig": res["rig"]} if res.get("rig") else {})}  # the camera's pool (creference batch)
    doc = {"format": SIDECAR_FORMAT, "image": name, "scenes": [m.key for m in members],
           "label_file": f"label_2/{name}.txt", "calib_file": f"calib/{name}.txt",
           "frame": KITTI_FRAME if members[ref].scene.kitti_p2 is not None else GRAVITY_FRAME, "camera": camera,
           "score": f"P(IoU >= {float(score_iou):g})", "objects": [o.sidecar for o in objects]}
    if res.get("dataset"):  # what the frame took from the data set and how sure that was (creference batch)
        doc["dataset"] = res["dataset"]
    return P2, calib, objects, doc


def write_labels(out: str | Path, name: str, members: list[LabelInput],
                 **options) -> tuple[list[ObjectLabel], dict | None]:
    """Write ``out/label_2/NAME.txt``, ``out/calib/NAME.txt`` and, when every result has posterior
    draws, ``out/uncertainty/NAME.json`` for the scenes of one image (``options``:
    :func:`image_labels`'s). Returns the objects and the sidecar (or None)."""
    out = Path(out)
    P2, calib, objects, doc = image_labels(members, name, **options)
    write_label_file(out / "label_2" / f"{name}.txt", [o.kitti for o in objects])
    write_calib_file(out / "calib" / f"{name}.txt", P2, calib)
    if doc is not None:
        write_sidecar(out / "uncertainty" / f"{name}.json", doc)
    return objects, doc
