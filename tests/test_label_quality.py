"""3D IoU of ground boxes, label quality from draws and reliability tables."""

import numpy as np
import pytest

from creference_bayes.workflows.labels.quality import (box_iou_3d, footprints, label_quality,
                                                      reliability_table)

BOX = np.array([1.0, 1.5, 8.0, 0.3, 4.0, 1.8, 1.5])  # x, y, z, yaw, length, width, height


def _shifted(box, along_length=0.0, down=0.0, yaw=0.0):
    b = box.copy()
    b[0] += along_length * np.cos(box[3])
    b[2] -= along_length * np.sin(box[3])  # the object's x axis is (cos, −sin) in (x, z)
    b[1] += down
    b[3] += yaw
    return b


@pytest.mark.parametrize("other, expected", [
    (BOX, 1.0),
    (_shifted(BOX, along_length=2.0), 1 / 3),     # half the length: inter V/2, union 3V/2
    (_shifted(BOX, down=0.75), 1 / 3),            # half the height
    (_shifted(BOX, yaw=np.pi), 1.0),              # a box turned half way round is the same box
    (_shifted(BOX, along_length=4.5), 0.0),       # disjoint
])
def test_iou_known_answers(other, expected):
    assert box_iou_3d(BOX, other[None])[0] == pytest.approx(expected, abs=1e-9)


def test_iou_against_monte_carlo():
    """An independent estimate: the share of points drawn in box A that fall in box B."""
    rng = np.random.default_rng(0)
    b = np.array([1.7, 1.2, 8.4, 1.0, 3.0, 2.0, 1.2])
    u = rng.uniform(-0.5, 0.5, (400_000, 3))
    # points of A in its own axes → G
    local = u * [BOX[4], BOX[6], BOX[5]]  # along length, height, width
    c, s = np.cos(BOX[3]), np.sin(BOX[3])
    px = BOX[0] + local[:, 0] * c + local[:, 2] * s
    pz = BOX[2] - local[:, 0] * s + local[:, 2] * c
    py = BOX[1] - BOX[6] / 2 + local[:, 1]
    # in B? rotate into B's axes
    dx, dz = px - b[0], pz - b[2]
    cb, sb = np.cos(b[3]), np.sin(b[3])
    along, across = dx * cb - dz * sb, dx * sb + dz * cb
    inside = (np.abs(along) <= b[4] / 2) & (np.abs(across) <= b[5] / 2) & (py <= b[1]) & (py >= b[1] - b[6])
    va, vb = np.prod(BOX[4:]), np.prod(b[4:])
    inter = inside.mean() * va
    mc = inter / (va + vb - inter)
    se = np.sqrt(inside.mean() * (1 - inside.mean()) / inside.size) * va / (va + vb - inter) * 1.5
    assert box_iou_3d(BOX, b[None])[0] == pytest.approx(mc, abs=4 * se)
    assert 0.05 < mc < 0.9  # a real partial overlap


def test_footprint_has_the_box_sizes():
    fp = footprints(BOX[None])[0]
    sides = np.linalg.norm(np.roll(fp, -1, axis=0) - fp, axis=1)
    np.testing.assert_allclose(sides, [4.0, 1.8, 4.0, 1.8])


def test_quality_is_one_without_spread_and_falls_with_it():
    rng = np.random.default_rng(1)
    tight = np.tile(BOX, (50, 1))
    assert label_quality(BOX, tight).p_iou == {0.5: 1.0, 0.7: 1.0}
    probs = []
    for spread in (0.05, 0.3, 1.0):
        draws = np.tile(BOX, (400, 1))
        draws[:, [0, 2]] += rng.normal(0, spread, (400, 2))
        probs.append(label_quality(BOX, draws).p_iou[0.7])
    assert probs[0] > probs[1] > probs[2]


def test_quality_is_calibrated_when_the_truth_is_one_more_draw():
    """If the truth is distributed like the draws, P(IoU ≥ t) from the draws is calibrated: the
    reliability table's observed shares stay within a few standard errors of the predictions."""
    rng = np.random.default_rng(2)
    n_obj, n_draws = 400, 200
    pred, hit = [], []
    for _ in range(n_obj):
        sd = rng.uniform(0.02, 0.6)
        centre = BOX.copy()
        draws = np.tile(centre, (n_draws + 1, 1))
        draws[:, [0, 2]] += rng.normal(0, sd, (n_draws + 1, 2))
        draws[:, 3] += rng.normal(0, 0.1, n_draws + 1)
        truth, draws = draws[0], draws[1:]
        exported = centre  # the exported box is the posterior's centre, not a draw
        pred.append(label_quality(exported, draws).p_iou[0.7])
        hit.append(box_iou_3d(exported, truth[None])[0] >= 0.7)
    rows = reliability_table(pred, hit, n_bins=5)
    assert sum(r["count"] for r in rows) == n_obj
    for r in rows:
        mc = np.sqrt(r["se"] ** 2 + 0.25 / n_draws / r["count"])  # + the draws' own error
        assert abs(r["observed_share"] - r["mean_predicted"]) < 4 * mc + 0.02, r


def test_reliability_table_bins_and_rejects_bad_input():
    rows = reliability_table([0.0, 0.05, 0.55, 1.0, 1.0], [False, True, True, True, False], n_bins=10)
    assert [(r["low"], r["count"]) for r in rows] == [(0.0, 2), (0.5, 1), (0.9, 2)]
    assert rows[0]["observed_share"] == 0.5 and rows[2]["mean_predicted"] == 1.0
    with pytest.raises(ValueError, match="probabilities"):
        reliability_table([1.2], [True])
    with pytest.raises(ValueError, match="two"):
        reliability_table([0.2, 0.3], [True])
