"""Bounded run statistics: percentiles to the stated resolution, the ring, the loop's folding."""

from __future__ import annotations

import numpy as np
import pytest

from controller.shell.loop import LoopStats, period_error_us
from controller.shell.streaming_stats import FloatRing, LogHistogram


def test_percentiles_are_within_the_stated_resolution_and_never_below():
    rng = np.random.default_rng(7)
    values = np.concatenate([rng.lognormal(3.0, 1.0, 50_000), [0.05, 0.0, 12345.0]])
    h = LogHistogram(0.1, 1e8, resolution=0.01)
    for block in np.array_split(values, 13):
        h.add(block)
    assert h.count == values.size and h.max == values.max() and h.min == values.min()
    for q in (1, 50, 90, 99, 99.9, 100):
        # the exact order statistic the histogram's rank points at
        exact = float(np.sort(values)[max(1, int(np.ceil(q / 100 * values.size))) - 1])
        got = h.percentile(q)
        assert exact <= got <= max(exact * 1.01, 0.1) + 1e-12, (q, exact, got)


def test_values_outside_the_range_are_counted_at_the_ends():
    h = LogHistogram(1.0, 100.0)
    h.add(np.array([-5.0, 0.5, 1e6]))
    assert h.counts[0] == 2 and h.counts[-1] == 1
    assert h.percentile(100) == 1e6 and h.min == -5.0


def test_an_empty_histogram_reports_zero():
    assert LogHistogram(1.0, 10.0).percentile(99) == 0.0


@pytest.mark.parametrize(
    ("lowest", "highest", "resolution"), [(0.0, 1.0, 0.01), (2.0, 1.0, 0.01), (1.0, 2.0, 1.5)]
)
def test_a_histogram_with_bad_bounds_is_refused(lowest, highest, resolution):
    with pytest.raises(ValueError, match="LogHistogram"):
        LogHistogram(lowest, highest, resolution)


def test_the_ring_keeps_the_last_values_in_order():
    r = FloatRing(4)
    for x in range(10):
        r.append(float(x))
    assert list(r.values()) == [6.0, 7.0, 8.0, 9.0] and len(r) == 4 and r.appended == 10
    with pytest.raises(ValueError, match="capacity"):
        FloatRing(0)


def test_loop_stats_fold_the_same_figures_as_the_whole_run_in_one_array():
    """A ring of 64 cycles folded 31 times gives the counts of the whole 2 000-cycle run."""
    period = 0.0025
    rng = np.random.default_rng(3)
    wake = rng.exponential(50e-6, 2000)
    wake[700] = 0.004  # one late cycle
    k = np.arange(2000)
    k[1500:] += 19  # 19 skipped deadlines
    small, whole = LoopStats(period, ring_cycles=64), LoopStats(period, ring_cycles=4096)
    for s in (small, whole):
        for i in range(2000):
            s.record(float(wake[i]), 1e-4, int(k[i]))
            s.record_observers(2e-5)
        s.fold()
    expected = period_error_us(k * period + wake, period)
    assert np.array_equal(small.period_error_hist_us.counts, whole.period_error_hist_us.counts)
    assert small.period_error_hist_us.count == expected.size
    assert small.period_error_hist_us.max == pytest.approx(expected.max())
    assert small.late_cycles() == whole.late_cycles() == np.count_nonzero(wake > 0.1 * period) > 0
    assert np.array_equal(small.last_cycles()["wake_error_s"], wake[-64:])
    assert small.observers_hist_us.count == 2000


def test_loop_stats_memory_does_not_grow_with_the_run():
    s = LoopStats(0.0025, ring_cycles=128)
    sizes = (s.wake_error_s.nbytes, s.period_error_hist_us.counts.nbytes)
    for i in range(100_000):
        s.record(1e-5, 1e-4, i)
    s.fold()
    assert (s.wake_error_s.nbytes, s.period_error_hist_us.counts.nbytes) == sizes
    assert s.cycles == 100_000 and s.wake_hist_us.count == 100_000


def test_loop_stats_fold_a_slice_of_the_ring_at_a_time():
    """The histograms take the cycles ``fold_cycles`` at a time, not a whole ring at once: a fold of
    4 096 cycles cost about 1 ms inside one cycle of the service (late cycles at 1 kHz)."""
    s = LoopStats(0.001, ring_cycles=4096, fold_cycles=256)
    for i in range(257):
        s.record(1e-5, 1e-4, i)
    assert s.wake_hist_us.count == 256  # the first slice, folded when the 257th cycle came
    for i in range(257, 5000):
        s.record(1e-5, 1e-4, i)
    assert s.cycles - s.wake_hist_us.count <= 256  # never more than a slice behind
    assert np.array_equal(s.last_cycles()["deadline_index"], np.arange(5000 - 4096, 5000))
    with pytest.raises(ValueError, match="fold_cycles"):
        LoopStats(0.001, fold_cycles=0)
