"""Process settings for low latency in CPython.

The loop thread shares the interpreter with the recorder's and the publisher's threads.
CPython hands the GIL over only every ``sys.getswitchinterval()`` seconds (5 ms by
default): a loop thread woken by an arriving frame can wait that long while a background
thread converts messages. Shortening the interval bounds that wait at a small cost in
throughput of the background threads.
"""

from __future__ import annotations

import sys


def set_gil_switch_interval(interval_s: float) -> float:
    """Set the interpreter's thread switch interval; returns the previous one."""
    if not 1e-6 <= interval_s <= 0.1:
        raise ValueError(f"GIL switch interval must be in [1e-6, 0.1] s, got {interval_s}")
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    return previous
