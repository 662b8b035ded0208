"""The paper's error measures (§3.2, Eq. 1–4) on hand-computed values."""

import numpy as np
import pytest

from creference_bayes.core.metrics import (location_percentage_error, percentage_error,
                                           range_percentage_error, range_precision)


def test_eq1_percentage_error():
    assert percentage_error(3.0, 2.0) == pytest.approx(50.0)  # |3 − 2| / 2
    assert percentage_error(1.0, 4.0) == pytest.approx(75.0)  # |1 − 4| / 4
    assert percentage_error(-1.0, -2.0) == pytest.approx(50.0)  # |GT| in the denominator
    np.testing.assert_allclose(percentage_error([2.0, 6.0, 0.0], 4.0), [50.0, 50.0, 100.0])


def test_eq2_range_error_uses_the_centre():
    assert range_percentage_error(10.0, 15.0, 10.0) == pytest.approx(25.0)  # centre 12.5
    assert range_percentage_error(1.5, 2.5, 2.0) == pytest.approx(0.0)
    np.testing.assert_allclose(range_percentage_error([1.0, 3.0], [3.0, 5.0], [4.0, 4.0]), [50.0, 0.0])


def test_eq3_location_error():
    # ‖(3, 4, 12) − (0, 0, 12)‖ / ‖(0, 0, 12)‖ = 5 / 12
    assert location_percentage_error([3.0, 4.0, 12.0], [0.0, 0.0, 12.0]) == pytest.approx(500.0 / 12.0)
    # ‖(1, 2, 2)‖ = 3: an estimate at the origin is 100 % off, at 2·GT also 100 %
    assert location_percentage_error([0.0, 0.0, 0.0], [1.0, 2.0, 2.0]) == pytest.approx(100.0)
    assert location_percentage_error([2.0, 4.0, 4.0], [1.0, 2.0, 2.0]) == pytest.approx(100.0)
    batch = location_percentage_error([[1.0, 2.0, 2.0], [1.0, 2.0, 5.0]], [1.0, 2.0, 2.0])
    np.testing.assert_allclose(batch, [0.0, 100.0])


def test_eq4_range_precision():
    assert range_precision(10.0, 15.0) == pytest.approx(40.0)  # 5 / 12.5
    assert range_precision(2.0, 2.0) == 0.0
    np.testing.assert_allclose(range_precision([0.9, 1.0], [1.1, 3.0]), [20.0, 100.0])


def test_degenerate_inputs_are_rejected():
    with pytest.raises(ValueError):
        percentage_error(1.0, 0.0)
    with pytest.raises(ValueError):
        location_percentage_error([1.0, 1.0, 1.0], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        location_percentage_error([1.0, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError):
        range_precision(-1.0, 1.0)


def test_interval_score_known_answers():
    """Gneiting & Raftery (2007), Eq. 43, by hand: width, plus 2/α times the miss."""
    from creference_bayes.core.metrics import interval_score

    np.testing.assert_allclose(interval_score([1, 1, 1], [3, 3, 3], [2, 0, 4.5], 0.1), [2.0, 22.0, 32.0])
    assert interval_score(1.0, 3.0, 0.5, 0.5) == pytest.approx(2.0 + 4.0 * 0.5)
    with pytest.raises(ValueError, match="alpha"):
        interval_score(1, 2, 1.5, 1.0)
    with pytest.raises(ValueError, match="low > high"):
        interval_score(2, 1, 1.5, 0.1)
