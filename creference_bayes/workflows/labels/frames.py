"""KITTI labels from a frame estimate: one label file and one calib per image, from the shared camera.

Each target becomes one label line (``type`` its class), its box the MAP, its score and the
sidecar's quality from the posterior: P(IoU ≥ t) is the share of posterior draws whose box
overlaps the label's box by at least t (3D IoU, :mod:`~creference_bayes.evaluation.iou3d`).

Frames: a frame made from a KITTI folder (``camera.kitti_p2``) gets its labels in KITTI's own
frame, the rectified camera frame of its P2: a state's point X of the model's gravity-aligned frame
is R(pitch, roll) X in the camera of P2, minus P2's offset K⁻¹ P2[:, 3]; the box's turn follows
its length axis through the same rotation. Other frames get labels in the gravity-aligned frame and
a calib with P2 = K [R | 0] from the MAP camera (docs/labels.md), as single-target labels do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.geometry import rotation_from_pitch_roll
from ...io.kitti import kitti_object, projection_matrix, write_calib_file, write_label_file, write_sidecar
from ...models.frame import C_FOCAL, C_HEIGHT, C_PITCH, C_ROLL, O_GROUND, O_SIZE, O_YAW

__all__ = ["kitti_poses", "frame_boxes", "truth_boxes", "frame_label_objects", "write_frame_labels",
           "SIDECAR_FORMAT"]

SIDECAR_FORMAT = "creference-kitti-uncertainty/1"


def kitti_poses(frame, cams: np.ndarray, objs: np.ndarray) -> np.ndarray:
    """Boxes of states in the labels' frame: (n, m, 7) x, y, z, rotation_y, length, width, height.

    ``cams`` (n, 5) and ``objs`` (n, m, 7) are natural parameters of the frame model."""
    cams = np.atleast_2d(cams)
    objs = np.asarray(objs, float).reshape(len(cams), -1, 7)
    P = np.stack([objs[..., 0], cams[:, C_HEIGHT, None] - objs[..., O_GROUND], objs[..., 1]], axis=-1)
    d = np.stack([np.cos(objs[..., O_YAW]), np.zeros(objs.shape[:2]), -np.sin(objs[..., O_YAW])], axis=-1)
    if frame.kitti_p2 is not None:
        P2 = np.asarray(frame.kitti_p2, float)
        offset = np.linalg.solve(P2[:, :3], P2[:, 3])
        R = rotation_from_pitch_roll(cams[:, C_PITCH], cams[:, C_ROLL])
        P = np.einsum("nij,nmj->nmi", R, P) - offset
        d = np.einsum("nij,nmj->nmi", R, d)
    ry = np.arctan2(-d[..., 2], d[..., 0])
    return np.concatenate([P, ry[..., None], objs[..., O_SIZE]], axis=-1)


def _p2(frame, cam: np.ndarray) -> np.ndarray:
    if frame.kitti_p2 is not None:
        return np.asarray(frame.kitti_p2, float)
    R = rotation_from_pitch_roll(cam[C_PITCH], cam[C_ROLL])
    return projection_matrix(float(cam[C_FOCAL]), frame.principal_point, R)


def _map_camera(result: dict) -> np.ndarray:
    from ...models.frame import CAMERA_NAMES

    return np.array([result["camera"]["map"][k] for k in CAMERA_NAMES], float)


def frame_boxes(frame, result: dict, draws=None, max_draws: int = 400):
    """The labels' boxes: the MAP's (m, 7) and, with ``draws``, at most ``max_draws`` evenly spaced
    draws' (n, m, 7) (else None), as :func:`kitti_poses`; with the draws' indices (n,)."""
    cam = _map_camera(result)
    objs = np.array([[o["map"][k] for k in ("x", "z", "yaw", "length_m", "width_m", "height_m", "ground_m")]
                     for o in result["objects"]], float)
    boxes = kitti_poses(frame, cam[None], objs[None])[0]
    if draws is None:
        return boxes, None, None
    c = draws.cameras.reshape(-1, 5)
    o = draws.objects.reshape(len(c), -1, 7)
    keep = np.linspace(0, len(c) - 1, min(max_draws, len(c))).astype(int)
    return boxes, kitti_poses(frame, c[keep], o[keep]), keep


def truth_boxes(frame) -> list[np.ndarray | None]:
    """Each target's true box in the labels' frame (7,) from the scene's ground truth, or None.

    A frame with ``kitti_p2`` compares with KITTI's own label (``ground_truth.kitti``); another
    frame's labels and truth are both in the gravity-aligned frame (``location_m``, ``yaw_rad``,
    ``dimensions_m`` or the target's known dimensions)."""
    out = []
    for t in frame.targets:
        g = t.ground_truth or {}
        box = None
        if frame.kitti_p2 is not None:
            k = g.get("kitti")
            if k is not None:
                h, w, l = k["dimensions_hwl"]
                box = np.array([*k["location"], k["rotation_y"], l, w, h], float)
        elif "location_m" in g and g.get("yaw_rad") is not None:
            d = g.get("dimensions_m")
            sizes = [d["length"], d["width"], d["height"]] if d else t.dimensions
            if sizes is not None:
                box = np.array([*g["location_m"], g["yaw_rad"], *sizes], float)
        out.append(box)
    return out


def frame_label_objects(frame, result: dict, draws=None, *, score_iou: float = 0.7, max_draws: int = 400,
                        type_name: str | None = None):
    """(P2 (3, 4), [(KittiObject, quality dict)]) for a frame and its ``creference-result/2`` dict.

    ``draws`` (a :class:`~creference_bayes.inference.frame_sampler.FrameDraws`, or the
    :class:`~creference_bayes.io.frame_result.StoredDraws` a result keeps) give each label's
    P(IoU ≥ 0.5) and P(IoU ≥ 0.7); the score is P(IoU ≥ ``score_iou``). Without draws the score is
    1 and the quality None. ``type`` is ``type_name``, else the target's class, else its id."""
    from ...evaluation.iou3d import overlaps

    cam = _map_camera(result)
    boxes, samples, _ = frame_boxes(frame, result, draws, max_draws)
    P2 = _p2(frame, cam)
    out = []
    for i, t in enumerate(frame.targets):
        quality = None
        score = 1.0
        if samples is not None:
            iou = overlaps(samples[:, i], boxes[i:i + 1])[:, 0]
            quality = {"p_iou_ge_0.5": float(np.mean(iou >= 0.5)), "p_iou_ge_0.7": float(np.mean(iou >= 0.7)),
                       "iou_mean": float(iou.mean()), "iou_median": float(np.median(iou)), "n_draws": int(len(iou))}
            score = quality[f"p_iou_ge_{score_iou:g}"]
        name = type_name or t.cls or "_".join(str(t.id).split()) or "Object"
        obj = kitti_object(name, boxes[i, :4], boxes[i, 4:7], P2, frame.image_size, score)
        out.append((obj, quality))
    return P2, out


def write_frame_labels(frame, result: dict, out: str | Path, name: str, draws=None, *,
                       score_iou: float = 0.7, scores: np.ndarray | None = None) -> dict:
    """Write ``out/label_2/name.txt``, ``out/calib/name.txt`` and, with posterior ``draws``,
    ``out/uncertainty/name.json``; ``scores`` (m,) overrides the labels' scores. Returns the
    sidecar (None without draws)."""
    import dataclasses

    out = Path(out)
    for sub in ("label_2", "calib") + (("uncertainty",) if draws is not None else ()):
        (out / sub).mkdir(parents=True, exist_ok=True)
    P2, items = frame_label_objects(frame, result, draws, score_iou=score_iou)
    objects = [o if scores is None else dataclasses.replace(o, score=float(scores[i])) for i, (o, _) in enumerate(items)]
    write_label_file(out / "label_2" / f"{name}.txt", objects)
    write_calib_file(out / "calib" / f"{name}.txt", P2, frame.kitti_calib)
    if draws is None:
        return None
    doc = {"format": SIDECAR_FORMAT, "frame": "kitti_p2" if frame.kitti_p2 is not None else "gravity-aligned",
           "camera": result["camera"],
           "objects": [{"line": k + 1, "id": t.id, "type": objects[k].type,
                        **({"quality": q} if q is not None else {}),
                        **({"posterior": result["objects"][k]["posterior"]} if "posterior" in result["objects"][k] else {})}
                       for k, (t, (_, q)) in enumerate(zip(frame.targets, items))]}
    write_sidecar(out / "uncertainty" / f"{name}.json", doc)
    return doc
