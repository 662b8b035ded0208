"""KITTI's average precision, following the official devkit's ``evaluate_object`` step by step
(NumPy only: the overlaps come in precomputed; docs/evaluation.md, "The devkit's rules").

Per class and difficulty: ground truth of the class counts when its 2D box is tall enough and it
is occluded and truncated little enough; the rest of the class and the neighbouring class (Van for
Car, Person_sitting for Pedestrian) are *ignored* (a detection matched to them is neither a true
nor a false positive), as are detections lower than the minimum height. Every counted box takes
its best-scoring overlapping detection; the true positives' sorted scores, sampled at 41 recall
levels (:func:`get_thresholds`), are the thresholds. At each, every box takes the detection that
overlaps it most (a counted one first); unmatched counted boxes are misses, unmatched counted
detections false positives unless they overlap a DontCare region (over their own size). Precision
is made non-increasing from the right; AP R40 is the mean of the 40 samples at recall 1/40 … 1,
AP R11 of the 11 at 0, 0.1, … 1, in percent. A class is evaluated only when some detection has
its name; names compare case-insensitively.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CLASSES", "DIFFICULTIES", "MIN_HEIGHT", "MAX_OCCLUSION", "MAX_TRUNCATION",
           "MIN_OVERLAPS", "N_SAMPLE_PTS", "FrameData", "ClassAP", "ground_truth_flags",
           "detection_flags", "frame_statistics", "get_thresholds", "average_precision"]

CLASSES = ("Car", "Pedestrian", "Cyclist")
DIFFICULTIES = ("easy", "moderate", "hard")
#: Per difficulty (easy, moderate, hard): the minimum 2D box height (px) of counted ground truth
#: and detections, the maximum occlusion code and truncation of counted ground truth.
MIN_HEIGHT = (40, 25, 25)
MAX_OCCLUSION = (0, 1, 2)
MAX_TRUNCATION = (0.15, 0.3, 0.5)
#: The minimum overlaps per class: the devkit's (Car 0.7, Pedestrian and Cyclist 0.5) and the
#: looser 0.5 for Car that papers also report.
MIN_OVERLAPS = {"Car": (0.7, 0.5), "Pedestrian": (0.5,), "Cyclist": (0.5,)}
#: The neighbouring class of a class: neither counted nor penalised.
NEIGHBOURS = {"car": "van", "pedestrian": "person_sitting"}
N_SAMPLE_PTS = 41
_NO_DETECTION = -10000000.0


@dataclass(frozen=True)
class FrameData:
    """What the evaluation needs of one image (n ground truth boxes incl. DontCare, m detections).

    Attributes
    ----------
    gt_type : n class names; gt_truncation (n,), gt_occlusion (n,) int, gt_height_px (n,)
    det_type : m class names; det_height_px (m,) the 2D box's height; det_score (m,)
    overlap : (m, n) IoU of each detection with each ground truth box (for one metric)
    dontcare_overlap : (m, k) intersection over the detection's own size with each of the k
        DontCare boxes (for the same metric)
    """

    gt_type: list[str]
    gt_truncation: np.ndarray
    gt_occlusion: np.ndarray
    gt_height_px: np.ndarray
    det_type: list[str]
    det_height_px: np.ndarray
    det_score: np.ndarray
    overlap: np.ndarray
    dontcare_overlap: np.ndarray


def ground_truth_flags(frame: FrameData, cls: str, difficulty: int) -> np.ndarray:
    """(n,) 0 counted, 1 ignored (neighbouring class, or too small, occluded or truncated), −1
    another class (incl. DontCare)."""
    cls = cls.lower()
    types = np.array([t.lower() for t in frame.gt_type], str)
    hard = ((np.asarray(frame.gt_occlusion) > MAX_OCCLUSION[difficulty])
            | (np.asarray(frame.gt_truncation) > MAX_TRUNCATION[difficulty])
            | (np.asarray(frame.gt_height_px) < MIN_HEIGHT[difficulty]))
    return np.where(types == cls, hard.astype(int), np.where(types == NEIGHBOURS.get(cls, ""), 1, -1))


def detection_flags(frame: FrameData, cls: str, difficulty: int) -> np.ndarray:
    """(m,) 0 counted, 1 ignored (lower than the minimum height, whatever the class), −1 another class."""
    cls = cls.lower()
    height = np.abs(frame.det_height_px)
    same = np.array([t.lower() == cls for t in frame.det_type], bool)
    return np.where(height < MIN_HEIGHT[difficulty], 1, np.where(same, 0, -1))


def frame_statistics(frame: FrameData, ignored_gt: np.ndarray, ignored_det: np.ndarray,
                     min_overlap: float, threshold: float | None = None) -> tuple[int, int, int, list[float]]:
    """True positives, false positives, misses and the true positives' scores of one image.

    ``threshold`` None: the first pass (each ground truth box takes the highest-scoring
    candidate; no false positives counted). Otherwise detections scoring below it are dropped,
    each box takes the candidate of greatest overlap, and false positives are counted.
    """
    m = len(frame.det_type)
    scores = frame.det_score
    assigned = np.zeros(m, bool)
    usable = ignored_det != -1
    if threshold is not None:
        usable &= scores >= threshold
    else:
        usable &= scores > _NO_DETECTION
    tp = fn = 0
    tp_scores: list[float] = []
    for i in range(len(ignored_gt)):
        if ignored_gt[i] == -1:
            continue
        cand = np.flatnonzero(usable & ~assigned & (frame.overlap[:, i] > min_overlap))
        det = -1
        if cand.size:
            if threshold is None:
                det = int(cand[np.argmax(scores[cand])])  # the first of the highest score
            else:
                counted = cand[ignored_det[cand] == 0]
                det = int(counted[np.argmax(frame.overlap[counted, i])]) if counted.size else int(cand[0])
        if det < 0:
            fn += int(ignored_gt[i] == 0)
        elif ignored_gt[i] == 1 or ignored_det[det] == 1:
            assigned[det] = True
        else:
            tp += 1
            tp_scores.append(float(scores[det]))
            assigned[det] = True
    fp = 0
    if threshold is not None:
        false = ~assigned & (ignored_det == 0) & usable
        fp = int(false.sum())
        dc = frame.dontcare_overlap
        if dc.size:
            fp -= int(np.sum(false & np.any(dc > min_overlap, axis=1)))
    return tp, fp, fn, tp_scores


def get_thresholds(scores, n_groundtruth: int) -> list[float]:
    """The scores at which the precision is sampled: the true positives' scores, sorted
    descending, at recall levels 0, 1/40, … (the devkit's ``getThresholds``, float for float)."""
    v = sorted((float(s) for s in scores), reverse=True)
    t: list[float] = []
    current = 0.0
    for i, s in enumerate(v):
        left = (i + 1) / n_groundtruth
        right = (i + 2) / n_groundtruth if i < len(v) - 1 else left
        if (right - current) < (current - left) and i < len(v) - 1:
            continue
        t.append(s)
        current += 1.0 / (N_SAMPLE_PTS - 1.0)
    return t


@dataclass(frozen=True)
class ClassAP:
    """AP of one class, difficulty, metric and minimum overlap.

    Attributes
    ----------
    ap_r40, ap_r11 : percent
    precision : (41,) the non-increasing precision at recall 0, 1/40, … 1 (the devkit's curve)
    n_groundtruth : counted ground truth boxes (the recall's denominator)
    n_detections : detections of the class
    """

    ap_r40: float
    ap_r11: float
    precision: np.ndarray
    n_groundtruth: int
    n_detections: int


def _relevant(frame: FrameData, g: np.ndarray, d: np.ndarray) -> tuple[FrameData, np.ndarray, np.ndarray] | None:
    """The frame without the boxes of other classes (never matched, never counted): the same
    statistics, less work; None when nothing is left."""
    gk, dk = np.flatnonzero(g != -1), np.flatnonzero(d != -1)
    if not gk.size and not dk.size:
        return None
    f = FrameData(gt_type=[frame.gt_type[i] for i in gk], gt_truncation=frame.gt_truncation[gk],
                  gt_occlusion=frame.gt_occlusion[gk], gt_height_px=frame.gt_height_px[gk],
                  det_type=[frame.det_type[j] for j in dk], det_height_px=frame.det_height_px[dk],
                  det_score=frame.det_score[dk], overlap=frame.overlap[np.ix_(dk, gk)],
                  dontcare_overlap=frame.dontcare_overlap[dk])
    return f, g[gk], d[dk]


def average_precision(frames: list[FrameData], cls: str, difficulty: int, min_overlap: float) -> ClassAP:
    """AP R40 and R11 of one class at one difficulty (0 easy, 1 moderate, 2 hard) over images."""
    flags = [(ground_truth_flags(f, cls, difficulty), detection_flags(f, cls, difficulty)) for f in frames]
    n_gt = int(sum(np.sum(g == 0) for g, _ in flags))
    n_det = int(sum(np.sum([t.lower() == cls.lower() for t in f.det_type]) for f in frames))
    work = [r for r in (_relevant(f, g, d) for f, (g, d) in zip(frames, flags)) if r is not None]
    scores: list[float] = []
    for f, g, d in work:
        scores += frame_statistics(f, g, d, min_overlap)[3]
    thresholds = get_thresholds(scores, n_gt)[:N_SAMPLE_PTS]
    precision = np.zeros(N_SAMPLE_PTS)
    cache: list[dict] = [{} for _ in work]  # a frame's statistics depend only on which scores pass
    for k, thr in enumerate(thresholds):
        tp = fp = 0
        for (f, g, d), seen in zip(work, cache):
            key = int(np.count_nonzero(f.det_score >= thr))
            if key not in seen:
                seen[key] = frame_statistics(f, g, d, min_overlap, thr)[:2]
            a, b = seen[key]
            tp, fp = tp + a, fp + b
        # the devkit divides without a check; no detection above a sampled score is left only
        # in degenerate cases, where we take the precision as 0
        precision[k] = tp / (tp + fp) if tp + fp else 0.0
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    return ClassAP(ap_r40=float(precision[1:].sum() / 40 * 100), ap_r11=float(precision[::4].sum() / 11 * 100),
                   precision=precision, n_groundtruth=n_gt, n_detections=n_det)
