"""creference evaluate kitti: 3D and BEV IoU, KITTI's AP with the devkit's rules, reliability.

Known answers are worked out by hand in the comments; the devkit itself is compared in
test_kitti_devkit.py (slow, needs the compiled devkit).
"""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from creference_bayes.cli.main import main
from creference_bayes.evaluation.iou3d import overlaps
from creference_bayes.evaluation.kitti_ap import FrameData, average_precision, get_thresholds
from creference_bayes.evaluation.reliability import brier_score, cluster_bootstrap
from creference_bayes.io.kitti_read import LabelFileError, read_kitti_labels

# x, y (bottom), z, rotation_y, length, width, height
CAR = np.array([0.0, 1.6, 10.0, 0.0, 4.0, 2.0, 1.5])


def _moved(box, dx=0.0, dy=0.0, dz=0.0, ry=None, **sizes):
    b = box.copy()
    b[:3] += [dx, dy, dz]
    if ry is not None:
        b[3] = ry
    for k, i in (("l", 4), ("w", 5), ("h", 6)):
        if k in sizes:
            b[i] = sizes[k]
    return b


def _iou(a, b, metric="3d", normalise="union"):
    return overlaps(a[None], b[None], metric, normalise)[0, 0]


# ------------------------------------------------------------------------------------------------
# 3D and bird's-eye IoU


@pytest.mark.parametrize("other, iou3d, bev", [
    (CAR, 1.0, 1.0),
    # 1 m along the length (x at rotation_y 0): footprints overlap 3 x 2 = 6 m², heights fully:
    # 3D 9 / (12 + 12 - 9) = 0.6, BEV 6 / (8 + 8 - 6) = 0.6
    (_moved(CAR, dx=1.0), 0.6, 0.6),
    # and 0.5 m across (z): 3 x 1.5 = 4.5 m²; BEV 4.5 / 11.5; 3D 6.75 / 17.25 (the same ratio)
    (_moved(CAR, dx=1.0, dz=0.5), 4.5 / 11.5, 4.5 / 11.5),
    # and 0.5 m down: height overlap 1.0 m: 3D 4.5 / (24 - 4.5)
    (_moved(CAR, dx=1.0, dz=0.5, dy=0.5), 4.5 / 19.5, 4.5 / 11.5),
    # stacked: the same footprint, heights [0.1, 1.6] and [−1.4, 0.1] touch only
    (_moved(CAR, dy=-1.5), 0.0, 1.0),
    # turned by 90°: x in [−1, 1], z in [8, 12] against x in [−2, 2], z in [9, 11]: 2 x 2 = 4 m²
    (_moved(CAR, ry=np.pi / 2), 4 / 12, 4 / 12),
    (_moved(CAR, ry=-np.pi / 2), 4 / 12, 4 / 12),
    (_moved(CAR, ry=np.pi), 1.0, 1.0),       # the same box
    (_moved(CAR, dx=4.01), 0.0, 0.0),        # disjoint
    (_moved(CAR, dz=2.5), 0.0, 0.0),
])
def test_iou_known_answers(other, iou3d, bev):
    assert _iou(CAR, other, "3d") == pytest.approx(iou3d, abs=1e-9)
    assert _iou(CAR, other, "bev") == pytest.approx(bev, abs=1e-9)


def test_rotation_y_turns_the_length_as_kittis_devkit_does():
    """KITTI's computeBox3D: the length axis (1, 0, 0) becomes (cos ry, 0, −sin ry). A thin box moved
    by 1 m along that direction keeps (4 − 1) / (4 + 1) of its overlap; moved along (cos, +sin),
    the wrong handedness, it would barely touch."""
    ry = np.pi / 4
    thin = _moved(CAR, ry=ry, w=0.2)
    along = _moved(thin, dx=np.cos(ry), dz=-np.sin(ry))
    assert _iou(thin, along) == pytest.approx(3 / 5, abs=1e-9)
    wrong = _moved(thin, dx=np.cos(ry), dz=np.sin(ry))
    assert _iou(thin, wrong) < 0.1


def test_overlap_over_the_first_box_is_one_inside_a_larger_box():
    small = _moved(CAR, l=1.0, w=1.0, h=1.0)
    assert _iou(small, CAR, normalise="first") == pytest.approx(1.0)
    assert _iou(CAR, small, normalise="first") == pytest.approx(1.0 / 12.0)
    assert _iou(small, CAR, "bev", normalise="first") == pytest.approx(1.0)


_box = st.tuples(st.floats(-5, 5), st.floats(0.5, 2.5), st.floats(2, 12), st.floats(-4, 4),
                 st.floats(0.3, 6), st.floats(0.3, 3), st.floats(0.3, 3)).map(np.array)


@settings(max_examples=60, deadline=None)
@given(a=_box, b=_box, shift=st.floats(-3, 3), turn=st.floats(-np.pi, np.pi))
def test_iou_is_symmetric_bounded_and_rigid(a, b, shift, turn):
    for metric in ("3d", "bev"):
        ab, ba = overlaps(a[None], b[None], metric)[0, 0], overlaps(b[None], a[None], metric)[0, 0]
        assert ab == pytest.approx(ba, abs=1e-9)
        assert 0.0 <= ab <= 1.0
        assert _iou(a, a, metric) == pytest.approx(1.0)
        # the same rigid motion of both boxes (a turn about the vertical axis, then a shift) keeps the IoU
        c, s = np.cos(turn), np.sin(turn)

        def move(box):
            x, z = box[0], box[2]
            return np.array([c * x + s * z + shift, box[1] + shift / 3, -s * x + c * z, box[3] + turn, *box[4:]])

        assert _iou(move(a), move(b), metric) == pytest.approx(ab, abs=1e-7)


# ------------------------------------------------------------------------------------------------
# AP with the devkit's rules, on frames built directly (overlaps given)


def _frame(gt, det, overlap, dontcare=None):
    """gt: (type, truncation, occlusion, height px); det: (type, height px, score)."""
    return FrameData(gt_type=[g[0] for g in gt], gt_truncation=np.array([g[1] for g in gt], float),
                     gt_occlusion=np.array([g[2] for g in gt], int), gt_height_px=np.array([g[3] for g in gt], float),
                     det_type=[d[0] for d in det], det_height_px=np.array([d[1] for d in det], float),
                     det_score=np.array([d[2] for d in det], float),
                     overlap=np.asarray(overlap, float).reshape(len(det), len(gt)),
                     dontcare_overlap=np.zeros((len(det), 0)) if dontcare is None else np.asarray(dontcare, float))


def _perfect(n):
    gt = [("Car", 0.0, 0, 100.0)] * n
    det = [("Car", 100.0, 1.0 - i / 1000) for i in range(n)]
    return _frame(gt, det, np.eye(n))


def test_every_box_found_gives_100_only_from_41_boxes_as_in_the_devkit():
    """The devkit samples one score per 1/40 of recall reached, so n true positives fill at most n
    of the 41 recall points: 41 boxes all found give 100; 40 leave the last point at 0, R40 =
    39/40, R11 = 10/11 (checked against the compiled devkit while writing this test)."""
    r = average_precision([_perfect(41)], "Car", 0, 0.7)
    assert (r.ap_r40, r.ap_r11) == pytest.approx((100.0, 100.0))
    r = average_precision([_perfect(40)], "Car", 0, 0.7)
    assert (r.ap_r40, r.ap_r11) == pytest.approx((97.5, 1000 / 11))
    r = average_precision([_perfect(20)] * 2, "Car", 1, 0.7)  # two images of 20: the same as one of 40
    assert (r.ap_r40, r.n_groundtruth) == pytest.approx((97.5, 40))


def test_difficulty_neighbouring_class_and_dontcare_rules():
    """One image: GT0 a visible car, GT1 a car with occlusion 1, GT2 a van; D0 finds GT0 (score 0.5),
    D1 finds GT1 (0.9), D2 finds the van (0.8), D3 finds nothing (0.95), D4 lies in a DontCare
    region (0.85).

    Easy: GT1 is ignored (occlusion above 0), the van too; 1 box counted, 1 true positive at score
    0.5, the only sampled score; there D3 is the one false positive (D1, D2 match ignored boxes, D4
    is in DontCare): precision 1/2 at recall point 0 → R11 = 0.5/11, R40 = 0.
    Moderate: GT1 counts; true positive scores 0.9, 0.5 → 2 samples: at 0.9 D1 and D3 (1/2), at
    0.5 2 of 3 (2/3); made non-increasing from the right: [2/3, 2/3] → R40 = (2/3)/40, R11 = (2/3)/11.
    """
    gt = [("Car", 0.0, 0, 60.0), ("Car", 0.0, 1, 60.0), ("Van", 0.0, 0, 60.0), ("DontCare", -1, -1, 30.0)]
    det = [("Car", 60.0, 0.5), ("Car", 60.0, 0.9), ("Car", 60.0, 0.8), ("Car", 60.0, 0.95), ("Car", 60.0, 0.85)]
    ov = np.zeros((5, 4))
    ov[0, 0], ov[1, 1], ov[2, 2] = 0.9, 0.8, 0.8
    dc = np.array([[0.0], [0.0], [0.0], [0.0], [0.6]])
    f = _frame(gt, det, ov, dc)
    easy = average_precision([f], "Car", 0, 0.5)
    assert (easy.n_groundtruth, easy.ap_r40, easy.ap_r11) == pytest.approx((1, 0.0, 50 / 11))
    mod = average_precision([f], "Car", 1, 0.5)
    assert (mod.n_groundtruth, mod.ap_r40, mod.ap_r11) == pytest.approx((2, 200 / 3 / 40, 200 / 3 / 11))
    # without the DontCare region D4 is one more false positive at 0.5: 2 / 4 there, so [1/2, 1/2]
    mod = average_precision([_frame(gt, det, ov)], "Car", 1, 0.5)
    assert mod.ap_r11 == pytest.approx(50 / 11)
    # were the van a car, D2 would be a true positive
    gt2 = [gt[0], gt[1], ("Car", 0.0, 0, 60.0), gt[3]]
    assert average_precision([_frame(gt2, det, ov, dc)], "Car", 1, 0.5).n_groundtruth == 3


def test_person_sitting_neither_counts_nor_penalises_a_pedestrian_detection():
    gt = [("Pedestrian", 0.0, 0, 80.0), ("Person_sitting", 0.0, 0, 80.0)]
    det = [("Pedestrian", 80.0, 0.3), ("Pedestrian", 80.0, 0.9)]
    ov = np.array([[0.8, 0.0], [0.0, 0.8]])
    r = average_precision([_frame(gt, det, ov)], "Pedestrian", 0, 0.5)
    assert (r.n_groundtruth, r.ap_r11) == pytest.approx((1, 100 / 11))  # precision 1 at the one sample
    gt_other = [gt[0], ("Cyclist", 0.0, 0, 80.0)]  # not a neighbour: the detection is a false positive
    r = average_precision([_frame(gt_other, det, ov)], "Pedestrian", 0, 0.5)
    assert r.ap_r11 == pytest.approx(50 / 11)


def test_min_height_and_minimum_overlap_are_the_devkits():
    """A detection 39.9 px tall is ignored in easy (40 px), whatever its class, so not a false
    positive; 40.0 px counts. Ground truth 39.9 px is not counted. An overlap equal to the minimum
    is not a match (strictly greater)."""
    gt = [("Car", 0.0, 0, 60.0)]
    tp = ("Car", 60.0, 0.5)
    for h, fp in ((39.9, False), (40.0, True)):
        f = _frame(gt, [tp, ("Car", h, 0.9)], [[0.9], [0.0]])
        assert average_precision([f], "Car", 0, 0.7).ap_r11 == pytest.approx(100 / 11 / (2 if fp else 1))
    f = _frame([("Car", 0.0, 0, 39.9)], [tp], [[0.9]])
    assert average_precision([f], "Car", 0, 0.7).n_groundtruth == 0
    # which difficulties count a box: easy ≤ 0.15 truncated, occlusion 0, ≥ 40 px; moderate 0.3,
    # 1, 25 px; hard 0.5, 2, 25 px
    for box, counted in [(("Car", 0.15, 0, 40.0), [1, 1, 1]), (("Car", 0.2, 0, 60.0), [0, 1, 1]),
                         (("Car", 0.4, 0, 60.0), [0, 0, 1]), (("Car", 0.6, 0, 60.0), [0, 0, 0]),
                         (("Car", 0.0, 2, 60.0), [0, 0, 1]), (("Car", 0.0, 3, 60.0), [0, 0, 0]),
                         (("Car", 0.0, 0, 24.9), [0, 0, 0]), (("Car", 0.0, 1, 30.0), [0, 1, 1])]:
        f = _frame([box], [tp], [[0.9]])
        assert [average_precision([f], "Car", k, 0.7).n_groundtruth for k in range(3)] == counted, box
    f = _frame(gt, [tp], [[0.7]])
    assert average_precision([f], "Car", 0, 0.7).ap_r11 == 0.0
    assert average_precision([f], "Car", 0, 0.69).ap_r11 == pytest.approx(100 / 11)


def test_thresholds_sample_recall_in_fortieths():
    assert get_thresholds([0.9, 0.8], 2) == [0.9, 0.8]
    # 80 boxes all found: one score per two true positives, 41 in all (recall 0, 1/40, …, 1)
    scores = list(np.linspace(1, 0.01, 80))
    t = get_thresholds(scores, 80)
    assert len(t) == 41 and t[0] == 1.0 and t[-1] == pytest.approx(0.01)


def test_brier_score_by_hand():
    assert brier_score([0.9, 0.8], [True, False]) == pytest.approx((0.01 + 0.64) / 2)
    with pytest.raises(ValueError, match="probabilities"):
        brier_score([1.5], [True])


def test_cluster_bootstrap_with_one_value_per_cluster_is_the_ordinary_interval_of_a_mean():
    x = np.random.default_rng(3).normal(2.0, 1.5, size=400)
    lo, hi = cluster_bootstrap(x, np.arange(400))
    # the normal-theory 95 % interval of a mean: ±1.96 sd / √n
    half = 1.96 * x.std(ddof=1) / np.sqrt(len(x))
    assert lo < x.mean() < hi
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.15)


def test_cluster_bootstrap_counts_a_cluster_once_however_many_rows_it_has():
    rng = np.random.default_rng(4)
    x = rng.normal(size=60)
    # every value repeated 10 times in its cluster: the same interval as one row each
    assert cluster_bootstrap(np.repeat(x, 10), np.repeat(np.arange(60), 10)) == pytest.approx(
        cluster_bootstrap(x, np.arange(60)))
    # the same 600 rows taken as independent: an interval about √10 times narrower, which is the
    # over-confidence the clustering removes
    lo_c, hi_c = cluster_bootstrap(np.repeat(x, 10), np.repeat(np.arange(60), 10))
    lo_i, hi_i = cluster_bootstrap(np.repeat(x, 10), np.arange(600))
    assert (hi_c - lo_c) / (hi_i - lo_i) == pytest.approx(np.sqrt(10), rel=0.25)


def test_cluster_bootstrap_takes_columns_and_bools_and_names_bad_input():
    covered = np.array([True, False, True, True])
    q = np.array([0.2, 0.97, 0.5, 0.6])
    lo, hi = cluster_bootstrap(np.c_[covered, q], ["a", "a", "b", "c"], n_boot=500)
    assert lo.shape == hi.shape == (2,)
    assert 0.0 <= lo[0] <= 0.75 <= hi[0] <= 1.0  # the share covered, 3 of 4
    assert lo[1] <= q.mean() <= hi[1]
    with pytest.raises(ValueError, match="clusters"):
        cluster_bootstrap([1.0, 2.0], ["a"])
    with pytest.raises(ValueError, match="finite"):
        cluster_bootstrap([1.0, np.nan], ["a", "b"])
    with pytest.raises(ValueError, match="level.*1.5"):
        cluster_bootstrap([1.0, 2.0], ["a", "b"], level=1.5)


# ------------------------------------------------------------------------------------------------
# Label files and the command


GT_LINES = [
    "Car 0.00 0 0.00 500.00 150.00 700.00 250.00 1.50 2.00 4.00 0.00 1.60 10.00 0.00",
    "Van 0.00 0 0.00 100.00 150.00 200.00 250.00 2.00 2.00 5.00 -8.00 1.60 12.00 0.00",
    "DontCare -1 -1 -10 800.00 150.00 900.00 200.00 -1 -1 -1 -1000 -1000 -1000 -10",
]


def _label_folder(root, lines_by_image, quality_by_image=None):
    (root / "label_2").mkdir(parents=True)
    for name, lines in lines_by_image.items():
        (root / "label_2" / f"{name}.txt").write_text("".join(s + "\n" for s in lines))
    if quality_by_image:
        (root / "uncertainty").mkdir()
        for name, qs in quality_by_image.items():
            objs = [{"line": i + 1, "quality": {"p_iou_ge_0.5": p5, "p_iou_ge_0.7": p7}} for i, (p5, p7) in enumerate(qs)]
            (root / "uncertainty" / f"{name}.json").write_text(json.dumps(
                {"format": "creference-kitti-uncertainty/1", "objects": objs}))
    return root


@pytest.fixture
def folders(tmp_path):
    gt = _label_folder(tmp_path / "gt", {"000000": GT_LINES, "000001": GT_LINES[:1]})
    labels = _label_folder(tmp_path / "labels", {
        # the car 1 m along its length (IoU 0.6), and exactly on the second image's car (IoU 1)
        "000000": ["Car 0.00 3 0.00 500.00 150.00 700.00 250.00 1.5000 2.0000 4.0000 1.0000 1.6000 10.0000 0.0000 0.8000"],
        "000001": ["Car 0.00 3 0.00 500.00 150.00 700.00 250.00 1.5000 2.0000 4.0000 0.0000 1.6000 10.0000 0.0000 0.9000"],
    }, {"000000": [(0.95, 0.8)], "000001": [(0.99, 0.9)]})
    return gt, labels


def test_evaluate_kitti_writes_the_table_json_and_figure(folders, tmp_path, capsys):
    gt, labels = folders
    out = tmp_path / "eval"
    assert main(["evaluate", "kitti", str(gt), str(labels), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Car" in text and "Pedestrian" in text and "not evaluated" in text
    doc = json.loads((out / "evaluation.json").read_text())
    assert (out / "reliability.png").stat().st_size > 1000
    ious = {(o["image"], o["line"]): o["iou_3d"] for o in doc["objects"]}
    assert ious == pytest.approx({("000000", 1): 0.6, ("000001", 1): 1.0}, abs=1e-6)
    rel = doc["reliability"]["p_iou_ge_0.7"]
    assert rel["count"] == 2 and rel["brier"] == pytest.approx(((0.8 - 0) ** 2 + (0.9 - 1) ** 2) / 2)
    assert doc["reliability"]["p_iou_ge_0.5"]["brier"] == pytest.approx((0.05 ** 2 + 0.01 ** 2) / 2)
    # Car easy at 0.7: 2 boxes, one true positive (score 0.9; the 0.8 label's IoU 0.6 is too low):
    # one sample, precision 1 → R11 100/11, R40 0; at 0.5 both found: samples 0.9, 0.8 at recall
    # points 0 and 1/40 → R40 100/40, R11 still 100/11 (its points are 0, 4/40, …)
    ap = {(r["min_overlap"], r["metric"], r["difficulty"]): (r["ap_r40"], r["ap_r11"]) for r in doc["ap"]
          if r["class"] == "Car"}
    assert ap[(0.7, "3d", "easy")] == pytest.approx((0.0, 100 / 11))
    assert ap[(0.5, "3d", "easy")] == pytest.approx((100 / 40, 100 / 11))
    assert doc["not_evaluated"] == ["Pedestrian", "Cyclist"]


def test_ground_truth_that_no_difficulty_counts_is_a_warning(folders, capsys):
    """creference's own labels (occluded 3) given as the ground truth: every AP 0, and it says why."""
    gt, labels = folders
    assert main(["evaluate", "kitti", str(gt), str(labels)]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["evaluate", "kitti", str(labels), str(labels), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: no ground-truth box counts at any difficulty"), err
    assert "is GT_LABEL_DIR KITTI's ground truth?" in err


def test_labels_given_as_their_label_2_folder_find_the_sidecars_too(folders, capsys):
    gt, labels = folders
    assert main(["evaluate", "kitti", str(gt / "label_2"), str(labels / "label_2")]) == 0
    assert "Brier score" in capsys.readouterr().out


def test_unlabelled_ground_truth_is_skipped_unless_counted(folders, capsys):
    gt, labels = folders
    (labels / "label_2" / "000001.txt").unlink()
    assert main(["evaluate", "kitti", str(gt), str(labels)]) == 0
    assert "1 ground-truth files without a label file" in capsys.readouterr().out
    assert main(["evaluate", "kitti", str(gt), str(labels), "--count-unlabelled"]) == 0
    assert "2 images evaluated" in capsys.readouterr().out


@pytest.mark.parametrize("line, expected", [
    ("Car 0.00 3 0.00 500 150 700 250 1.5 2.0 4.0 1.0 1.6 10.0 0.0", "000000.txt:2: expected 16 values"),
    ("Car 0.00 3 0.00 500 150 700 250 1.5 2.0 4.0 one 1.6 10.0 0.0 0.5", "000000.txt:2: x: expected a finite number, got 'one'"),
    ("Car 0.00 3 0.00 500 150 700 250 1.5 2.0 4.0 1.0 1.6 10.0 0.0 nan", "000000.txt:2: score: expected a finite number, got 'nan'"),
    ("Car 0.00 1.5 0.00 500 150 700 250 1.5 2.0 4.0 1.0 1.6 10.0 0.0 0.5", "000000.txt:2: occluded: expected an integer, got '1.5'"),
    ("Car 0.00 3 0.00 500 150 700 250 1.5 0.0 4.0 1.0 1.6 10.0 0.0 0.5", "000000.txt:2: w: expected a positive size"),
])
def test_a_malformed_label_line_is_one_line_naming_file_line_and_value(folders, tmp_path, capsys, line, expected):
    gt, labels = folders
    path = labels / "label_2" / "000000.txt"
    path.write_text(path.read_text() + line + "\n")
    out = tmp_path / "eval"
    assert main(["evaluate", "kitti", str(gt), str(labels), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert expected in err and str(path) in err and err.count("\n") == 1
    assert not out.exists()  # nothing written


def test_missing_folders_and_ground_truth_files_are_errors(folders, tmp_path, capsys):
    gt, labels = folders
    assert main(["evaluate", "kitti", str(tmp_path / "nope"), str(labels)]) == 2
    assert "GT_LABEL_DIR" in capsys.readouterr().err
    (labels / "label_2" / "000007.txt").write_text(GT_LINES[0] + " 0.5\n")
    assert main(["evaluate", "kitti", str(gt), str(labels)]) == 2
    err = capsys.readouterr().err
    assert "000007.txt: no such file" in err and err.count("\n") == 1
    with pytest.raises(LabelFileError, match="expected 15 values"):
        (tmp_path / "short.txt").write_text("Car 0 0 0\n")
        read_kitti_labels(tmp_path / "short.txt", scores=False)


def test_a_sidecar_with_a_bad_probability_is_an_error(folders, capsys):
    gt, labels = folders
    side = labels / "uncertainty" / "000000.json"
    doc = json.loads(side.read_text())
    doc["objects"][0]["quality"]["p_iou_ge_0.7"] = 1.7
    side.write_text(json.dumps(doc))
    assert main(["evaluate", "kitti", str(gt), str(labels)]) == 2
    assert "objects[0].quality.p_iou_ge_0.7" in capsys.readouterr().err
