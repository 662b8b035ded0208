"""``creference evaluate kitti``: labels against KITTI's reference boxes, image by image
(docs/evaluation.md).

Reads a ground-truth label folder and a label folder (as ``creference labels`` writes it: its
``label_2/`` and, beside it, ``uncertainty/``), computes the overlaps (:mod:`.iou3d`), KITTI's AP
with the devkit's rules (:mod:`.kitti_ap`) and, from the sidecars, how well each label's
P(IoU ≥ t) matches the IoU it really has (:mod:`.reliability`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.validation import SceneError, read_json
from ..io.kitti import SIDECAR_FORMATS
from ..io.kitti_read import KittiLabels, LabelFileError, kitti_boxes, read_kitti_labels
from .iou3d import METRICS, overlaps
from .kitti_ap import CLASSES, DIFFICULTIES, MIN_OVERLAPS, FrameData, average_precision
from .reliability import brier_score, reliability_table

__all__ = ["RELIABILITY_THRESHOLDS", "KittiEvaluation", "label_folder", "read_sidecar_quality", "evaluate_kitti"]
#: The thresholds t of the sidecars' P(IoU ≥ t).
RELIABILITY_THRESHOLDS = (0.5, 0.7)


def label_folder(path: str | Path, role: str) -> Path:
    """The folder of ``.txt`` label files: ``path`` itself, or its ``label_2/`` when it has one."""
    path = Path(path)
    if not path.is_dir():
        raise LabelFileError(f"{role}: {path}: no such folder")
    return path / "label_2" if (path / "label_2").is_dir() else path


def read_sidecar_quality(path: Path) -> dict[int, dict[float, float]]:
    """Label line (1-based) → {t: P(IoU ≥ t)} from an uncertainty sidecar (docs/labels.md)."""
    try:
        doc = read_json(path)
    except SceneError as exc:
        raise LabelFileError(str(exc)) from None
    if not isinstance(doc, dict) or doc.get("format") not in SIDECAR_FORMATS:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise LabelFileError(f"{path}: format: expected one of {list(SIDECAR_FORMATS)}, got {got!r}")
    out = {}
    for k, obj in enumerate(doc.get("objects") or []):
        try:
            line = int(obj["line"])
            q = {t: float(obj["quality"][f"p_iou_ge_{t:g}"]) for t in RELIABILITY_THRESHOLDS}
        except (KeyError, TypeError, ValueError):
            raise LabelFileError(f"{path}: objects[{k}]: expected 'line' and quality "
                                 f"'p_iou_ge_0.5' and 'p_iou_ge_0.7'") from None
        for t, p in q.items():
            if not 0.0 <= p <= 1.0:
                raise LabelFileError(f"{path}: objects[{k}].quality.p_iou_ge_{t:g}: expected a "
                                     f"probability in [0, 1], got {p!r}")
        out[line] = q
    return out


@dataclass(frozen=True)
class KittiEvaluation:
    """What :func:`evaluate_kitti` found.

    Attributes
    ----------
    images : the evaluated images' names
    unlabelled : ground-truth files without a label file (skipped unless counted)
    ap : one dict per class, minimum overlap, metric and difficulty (AP R40, AP R11 in percent)
    not_evaluated : the classes without any detection (the devkit skips them)
    objects : one dict per label line: its IoU with the best-overlapping reference box, and its
        predicted P(IoU ≥ t) when a sidecar gives it
    reliability : t → ``count``, ``mean_predicted``, ``observed_share``, ``brier``, ``rows``
        (:func:`~.reliability.reliability_table`) over the labels with a sidecar
    """

    images: list[str]
    unlabelled: list[str]
    ap: list[dict]
    not_evaluated: list[str]
    objects: list[dict] = field(repr=False)
    reliability: dict[float, dict]

    def to_dict(self) -> dict:
        return {"format": "creference-kitti-evaluation/1", "images": self.images,
                "unlabelled_ground_truth": self.unlabelled, "ap": self.ap,
                "not_evaluated": self.not_evaluated,
                "reliability": {f"p_iou_ge_{t:g}": v for t, v in self.reliability.items()},
                "objects": self.objects}


def _frame(gt: KittiLabels, det: KittiLabels, metric: str) -> FrameData:
    dc = gt.dont_care
    det_boxes, gt_boxes = kitti_boxes(det), kitti_boxes(gt)
    return FrameData(gt_type=gt.type, gt_truncation=gt.truncated, gt_occlusion=gt.occluded,
                     gt_height_px=gt.height_px, det_type=det.type, det_height_px=det.height_px,
                     det_score=det.score, overlap=overlaps(det_boxes, gt_boxes, metric),
                     dontcare_overlap=overlaps(det_boxes, gt_boxes[dc], metric, normalise="first"))


def _empty_detections(path: Path) -> KittiLabels:
    z = np.zeros((0,))
    return KittiLabels(path=path, line=np.zeros(0, int), type=[], truncated=z, occluded=np.zeros(0, int),
                       alpha=z, bbox=np.zeros((0, 4)), dimensions=np.zeros((0, 3)), location=np.zeros((0, 3)),
                       rotation_y=z, score=z)


def evaluate_kitti(gt_dir: str | Path, label_dir: str | Path, *, count_unlabelled: bool = False,
                   n_bins: int = 10) -> KittiEvaluation:
    """Evaluate every label file of ``label_dir`` against the file of the same name in ``gt_dir``.

    Parameters
    ----------
    gt_dir : KITTI ground truth (a ``label_2`` folder, or a folder holding one)
    label_dir : labels with scores (the same), e.g. the output of ``creference labels``
    count_unlabelled : count ground-truth files without a label file as images without
        detections (default: skip them, as the devkit does)
    n_bins : bins of the reliability tables
    """
    gdir, ldir = label_folder(gt_dir, "GT_LABEL_DIR"), label_folder(label_dir, "LABEL_DIR")
    label_files = {p.stem: p for p in sorted(ldir.glob("*.txt"))}
    if not label_files:
        raise LabelFileError(f"LABEL_DIR: {ldir}: no label files (*.txt)")
    gt_files = {p.stem: p for p in sorted(gdir.glob("*.txt"))}
    for name, p in label_files.items():
        if name not in gt_files:
            raise LabelFileError(f"{gdir / p.name}: no such file (the ground truth of {p})")
    unlabelled = sorted(set(gt_files) - set(label_files))
    names = sorted(set(label_files) | (set(unlabelled) if count_unlabelled else set()))
    gts = [read_kitti_labels(gt_files[n], scores=False) for n in names]
    dets = [read_kitti_labels(label_files[n], scores=True) if n in label_files
            else _empty_detections(gdir / f"{n}.txt") for n in names]

    ap, not_evaluated = [], []
    detected = {t.lower() for d in dets for t in d.type}
    for metric in METRICS:
        frames = [_frame(g, d, metric) for g, d in zip(gts, dets)]
        for cls in CLASSES:
            if cls.lower() not in detected:
                if cls not in not_evaluated:
                    not_evaluated.append(cls)
                continue
            for thr in MIN_OVERLAPS[cls]:
                for k, diff in enumerate(DIFFICULTIES):
                    r = average_precision(frames, cls, k, thr)
                    ap.append({"class": cls, "min_overlap": thr, "metric": metric, "difficulty": diff,
                               "ap_r40": r.ap_r40, "ap_r11": r.ap_r11, "n_groundtruth": r.n_groundtruth,
                               "n_detections": r.n_detections, "precision": r.precision.round(6).tolist()})

    objects = _objects(names, gts, dets, ldir.parent / "uncertainty" if ldir.name == "label_2" else ldir / "uncertainty")
    reliability = {}
    for t in RELIABILITY_THRESHOLDS:
        known = [o for o in objects if o.get(f"p_iou_ge_{t:g}") is not None]
        if not known:
            continue
        p = np.array([o[f"p_iou_ge_{t:g}"] for o in known])
        hit = np.array([o["iou_3d"] >= t for o in known])
        reliability[t] = {"count": len(known), "mean_predicted": float(p.mean()),
                          "observed_share": float(hit.mean()), "brier": brier_score(p, hit),
                          "rows": reliability_table(p, hit, n_bins)}
    return KittiEvaluation(images=names, unlabelled=unlabelled, ap=ap, not_evaluated=not_evaluated,
                           objects=objects, reliability=reliability)


def _objects(names, gts, dets, sidecar_dir: Path) -> list[dict]:
    """Per label line: the best 3D and BEV IoU with a reference box (DontCare excluded) and the
    sidecar's P(IoU ≥ t)."""
    out = []
    for name, g, d in zip(names, gts, dets):
        if not len(d):
            continue
        side = sidecar_dir / f"{name}.json"
        quality = read_sidecar_quality(side) if side.is_file() else {}
        keep = ~g.dont_care
        boxes = kitti_boxes(g)[keep]
        iou3 = overlaps(kitti_boxes(d), boxes, "3d")
        iou_bev = overlaps(kitti_boxes(d), boxes, "bev")
        gt_lines, gt_types = g.line[keep], [t for t, k in zip(g.type, keep) if k]
        for j in range(len(d)):
            best = int(np.argmax(iou3[j])) if boxes.size else -1
            row = {"image": name, "line": int(d.line[j]), "type": d.type[j], "score": float(d.score[j]),
                   "iou_3d": float(iou3[j, best]) if best >= 0 else 0.0,
                   "iou_bev": float(iou_bev[j].max()) if best >= 0 else 0.0,
                   "reference_line": int(gt_lines[best]) if best >= 0 else None,
                   "reference_type": gt_types[best] if best >= 0 else None,
                   "distance_m": float(np.hypot(d.location[j, 0], d.location[j, 2]))}
            q = quality.get(int(d.line[j]))
            for t in RELIABILITY_THRESHOLDS:
                row[f"p_iou_ge_{t:g}"] = q[t] if q else None
            out.append(row)
    return out
