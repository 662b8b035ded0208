"""Labels of the frames of a batch: one label file, one calib and one sidecar per frame's image.

A frame (``creference-scene/2``) is estimated with one shared camera, so its image gets one P2
from that camera (KITTI's own P2 when the scene has ``camera.kitti_p2``, and its labels in that
frame: :mod:`.frames`), one line per object with ``type`` its class, and a sidecar with the
camera's posterior and each object's posterior, P(IoU ≥ t) and evenly spaced box draws. The boxes,
scores and qualities come from :func:`.frames.frame_label_objects`, the draws from the result
(``draws``, :func:`~creference_bayes.io.frame_result.stored_draws`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...evaluation.iou3d import overlaps
from ...io.frame_result import stored_draws
from ...io.frame_scene import FrameScene
from ...models.frame import CAMERA_NAMES
from .frames import SIDECAR_FORMAT, _map_camera, frame_boxes, frame_label_objects, truth_boxes
from .quality import IOU_THRESHOLDS, LabelQuality

__all__ = ["FrameLabelInput", "KITTI_FRAME", "label_frame"]

#: How the sidecar describes the frame of the labels of a frame made from a KITTI folder.
KITTI_FRAME = {
    "name": "KITTI's rectified camera frame of the input calib's P2 (camera.kitti_p2 of the scene)",
    "axes": "x right, y down, z forward; origin at the rectified camera centre; metres (KITTI's own)",
    "rotation_y": "yaw about the y axis, radians; KITTI's box convention",
    "projection": "pixels = P2 @ [X; 1] with the scene's own P2 (the calib file repeats it)",
}


@dataclass(frozen=True)
class FrameLabelInput:
    """One estimated frame of a batch: its result (``creference-result/2``), its scene, the name
    of its files and the image it is (``group``)."""

    key: str
    result: dict
    frame: FrameScene
    name: str
    group: str


def _thin(values: np.ndarray, n: int) -> list[int]:
    return np.unique(np.linspace(0, len(values) - 1, min(n, len(values))).round().astype(int)).tolist()


def label_frame(inp: FrameLabelInput, *, type_name: str | None = None, score_iou: float = 0.7,
                n_draws: int = 100, frame_description: dict | None = None):
    """Labels of one frame: (P2 (3, 4), the sidecar document, one ``ObjectLabel`` per target).

    Parameters
    ----------
    inp : the frame and its result
    type_name : the KITTI type of every object (default: each target's class, else its id)
    score_iou : t of the score P(IoU ≥ t)
    n_draws : box and camera draws per object in the sidecar (evenly spaced over the result's)
    frame_description : how the sidecar describes a gravity-aligned frame (``FRAME``)
    """
    from . import ObjectLabel

    frame, res = inp.frame, inp.result
    draws = stored_draws(res)
    P2, items = frame_label_objects(frame, res, draws, score_iou=score_iou, type_name=type_name)
    boxes, samples, idx = frame_boxes(frame, res, draws)
    truths = truth_boxes(frame)
    keep = _thin(samples, n_draws)
    cams = draws.cameras.reshape(-1, 5)[idx][keep]
    cam = _map_camera(res)
    diag = res.get("diagnostics") or {}

    camera = {"map": res["camera"]["map"], "free": res["camera"]["free"],
              **({"posterior": res["camera"]["posterior"]} if "posterior" in res["camera"] else {}),
              "principal_point": [float(v) for v in frame.principal_point],
              "focal_length_px": float(cam[0]), "pitch_rad": float(cam[1]), "roll_rad": float(cam[2]),
              "draws": {"n": len(keep), **{k: np.round(cams[:, j], 6).tolist()
                                           for j, k in enumerate(CAMERA_NAMES) if k in res["camera"]["free"]}}}
    objects, entries = [], []
    n_refs = [0] * len(frame.targets)
    for owner in frame.reference_targets:
        for k in (owner if isinstance(owner, tuple) else () if owner is None else (owner,)):
            n_refs[k] += 1
    for i, (t, o, (kobj, q)) in enumerate(zip(frame.targets, res["objects"], items)):
        quality = LabelQuality(p_iou={float(th): q[f"p_iou_ge_{th:g}"] for th in IOU_THRESHOLDS},
                               iou_mean=q["iou_mean"], iou_median=q["iou_median"], n_draws=q["n_draws"])
        true_iou = None
        if truths[i] is not None:
            true_iou = float(overlaps(boxes[i:i + 1], truths[i][None])[0, 0])
        s = samples[keep, i]
        box_draws = {"x": s[:, 0], "y": s[:, 1], "z": s[:, 2], "rotation_y": s[:, 3]}
        if o["size"] != "known":
            box_draws.update(length=s[:, 4], width=s[:, 5], height=s[:, 6])
        entry = {
            "line": i + 1, "scene": inp.key, "target": t.id, "class": t.cls, "type": kobj.type,
            "size": o["size"],
            "label": {"location": [float(v) for v in boxes[i, :3]], "rotation_y": float(boxes[i, 3]),
                      "dimensions_hwl": [float(boxes[i, 6]), float(boxes[i, 5]), float(boxes[i, 4])]},
            "point_label": "map",
            "map": o["map"],
            "posterior": o.get("posterior"),
            "posterior_sd": (o.get("posterior") or {}).get("sd", {}),
            "quality": quality.to_dict(),
            "draws": {"n": len(keep), "note": "evenly spaced over the result's draws (the same draws as "
                      "the camera's): boxes in the labels' frame; sizes only when estimated",
                      **{k: np.round(v, 6).tolist() for k, v in box_draws.items()}},
            "evidence": {"dimension_lines": o["n_annotations"], "references": n_refs[i],
                         "converged": diag.get("converged"), "warnings": res.get("warnings", [])},
            "calib_mismatch_px": 0.0,
        }
        if true_iou is not None:
            entry["true_iou"] = true_iou
        entries.append(entry)
        objects.append(ObjectLabel(inp.key, inp.name, t.id, kobj, quality, true_iou, entry))
    doc = {"format": SIDECAR_FORMAT, "image": inp.name, "scene": inp.key,
           "label_file": f"label_2/{inp.name}.txt", "calib_file": f"calib/{inp.name}.txt",
           "frame": KITTI_FRAME if frame.kitti_p2 is not None else frame_description,
           "camera": camera, "score": f"P(IoU >= {float(score_iou):g})", "objects": entries}
    return P2, doc, objects
