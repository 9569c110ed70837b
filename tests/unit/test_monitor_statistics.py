"""The monitor's loop statistics (controller/monitoring/publisher.py): its percentiles are numpy's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from controller.monitoring.publisher import linear_percentiles

QS = (0.0, 1.0, 50.0, 99.0, 99.9, 100.0)


@given(arrays(np.float64, st.integers(1, 1100), elements=st.floats(0.0, 1e7, allow_subnormal=False)))
def test_linear_percentiles_are_numpys_default_percentiles(values: np.ndarray) -> None:
    expected = np.percentile(values, QS)
    assert linear_percentiles(values, QS) == pytest.approx(tuple(expected), rel=1e-12, abs=1e-12)


def test_the_values_are_left_as_they_were() -> None:
    values = np.array([5.0, 1.0, 4.0, 2.0, 3.0])
    assert linear_percentiles(values, (50.0, 100.0)) == (3.0, 5.0)
    assert values.tolist() == [5.0, 1.0, 4.0, 2.0, 3.0]
