"""Times as counts of the loop's cycles.

The law counts in cycles (a streak of missing frames, of late wake-ups, of disagreeing samples);
what a user configures, and what such a window means, is a time: 100 ms of a silent drive is as
long at 1 kHz as at 400 Hz, and the drives' own SYNC watchdog is a time too. Every window of the
configuration is given in seconds (``loop.max_missing_s``, ``safety.sensor_stale_s``, ...) and
counted in cycles of the loop's period by ``cycles_in``, once at assembly or every cycle where the
step has the period at hand. Until issue 37 they were counts of cycles, tuned at 400 Hz: at 1 kHz
each was 2.5 times shorter, and the 1-kHz contour demo over CAN FD faulted on 40 ms of silence and
on 50 ms of late wake-ups (controller/config.py reads an older file's counts as the same times).
"""

from __future__ import annotations

# A deadline is the first one plus k periods, and a time "at" one, in simulated time, is that sum
# again: equal in value, unequal in the last bit (0.0075 - 0.0025 is 0.004999999999999999). Held up
# exactly a period (simulated time's `stall=0.0025`), the loop read itself not past its next
# deadline, ran that cycle late, then the next at the same instant: two SYNCs at once (an outside
# tester). Times this close to a deadline count as at it: a nanosecond, far below any clock's tick
# and far above the rounding of the sums (about 1e-11 s after 10^5 s).
DEADLINE_ROUNDING_S = 1e-9


def cycles_in(seconds: float, period_s: float) -> int:
    """The whole cycles of ``period_s`` in ``seconds``, at least one: rounded, as 0.025 / 0.0025 is
    10.000000000000002 (at 400 Hz every shipped window is a whole number of cycles)."""
    return max(1, round(seconds / period_s))


def deadlines_skipped(interval_s: float, period_s: float) -> int:
    """The deadlines a loop skipped between two cycles ``interval_s`` apart (a hold-up): the whole
    periods between them, rounded as the deadlines are a period apart, less the one it ran at; 0
    for cycles a period apart or less, or without a period."""
    if period_s <= 0.0:
        return 0
    return max(0, round(interval_s / period_s) - 1)
