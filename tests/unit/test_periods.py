"""Deadlines skipped between two cycles: the one count the law, the hold-up tools and the trace
reader share (controller/core/periods.py)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from controller.core.periods import cycles_in, deadlines_skipped

PERIOD_S = 0.0025


def test_cycles_a_period_apart_skip_none() -> None:
    # 0.0075 - 0.005 is 0.0024999999999999996: one period in value, not in the last bit
    assert deadlines_skipped(0.0075 - 0.005, PERIOD_S) == 0
    assert deadlines_skipped(PERIOD_S, PERIOD_S) == 0


def test_a_hold_up_counts_the_deadlines_between() -> None:
    assert deadlines_skipped(2 * PERIOD_S, PERIOD_S) == 1
    # a 15.5-ms hold-up at 400 Hz (the lap over its bound beside two hogs): 6 deadlines
    assert deadlines_skipped(0.0175, PERIOD_S) == 6


def test_cycles_closer_than_a_period_or_without_one_skip_none() -> None:
    # two cycles at the same instant, or a recording without a period: never a negative count
    assert deadlines_skipped(0.0, PERIOD_S) == 0
    assert deadlines_skipped(0.001, PERIOD_S) == 0
    assert deadlines_skipped(0.01, 0.0) == 0


@given(k=st.integers(min_value=1, max_value=100_000), jitter=st.floats(min_value=-0.4, max_value=0.4))
def test_deadlines_k_periods_apart_skip_k_minus_one(k: int, jitter: float) -> None:
    # a cycle at a deadline, give or take less than half a period of wake-up error
    assert deadlines_skipped((k + jitter) * PERIOD_S, PERIOD_S) == k - 1


def test_cycles_in_counts_at_least_one() -> None:
    assert cycles_in(0.025, PERIOD_S) == 10
    assert cycles_in(0.0001, PERIOD_S) == 1
