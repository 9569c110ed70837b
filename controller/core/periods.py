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


def cycles_in(seconds: float, period_s: float) -> int:
    """The whole cycles of ``period_s`` in ``seconds``, at least one: rounded, as 0.025 / 0.0025 is
    10.000000000000002 (at 400 Hz every shipped window is a whole number of cycles)."""
    return max(1, round(seconds / period_s))
