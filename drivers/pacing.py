"""Pacing to deadlines on the monotonic clock: the loop shell's cycle, the cyclic exchange's answer
window and a replay onto a bus; and the monotonic clock on the wall clock.

``time.sleep`` alone wakes up to a scheduler tick late; the last ``spin_s`` before the
deadline is spent reading the clock instead, which costs CPU but lands within microseconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class DeadlineSleeper:
    """``time.sleep`` until ``spin_s`` before the deadline, then spin on the clock."""

    def __init__(self, spin_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.spin_s = spin_s
        self.clock = clock
        self.spun_s = 0.0  # time spent spinning so far: CPU use that is the price of the wake-up's precision

    def sleep_until(self, deadline_s: float) -> None:
        coarse = deadline_s - self.clock() - self.spin_s
        if coarse > 0.0:
            time.sleep(coarse)
        started = now = self.clock()
        while now < deadline_s:
            now = self.clock()
        self.spun_s += now - started


def wall_clock_offset_ns(clock: Callable[[], float] = time.monotonic) -> int:
    """Unix time minus ``clock`` [ns], read now: what turns the controller's monotonic readings into
    wall-clock (ROS) times: a recording's ``clock_offset_ns``, the monitoring Status's."""
    return time.time_ns() - round(clock() * 1e9)


MAX_FRAME_AGE_S = 1.0  # a receive timestamp older than this is on another clock: not believed


def arrival_s(timestamp_s: float, now_s: float, wall_now_s: float) -> float:
    """When a frame reached this machine, on a monotonic clock that reads ``now_s`` now.

    A receiver that reads its frames a while after they came (the simulator's process when it
    runs late, the cyclic exchange that sleeps through its answer window) takes the frame's
    receive timestamp (python-can's ``msg.timestamp``, on the wall clock: the kernel's on
    SocketCAN and udp_multicast, ``time.time()`` at the send on the virtual bus) moved to its
    clock by its age; ``now_s`` where the age is not plausible (no timestamp, another clock).
    """
    age_s = wall_now_s - timestamp_s
    return now_s - age_s if 0.0 <= age_s <= MAX_FRAME_AGE_S else now_s
