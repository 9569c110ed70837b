"""Busy neighbours for a bench case: N processes that burn a CPU each at the normal priority.

What an ordinary busy machine does beside the controller (issue 37: two `while True: pass`),
started before the case and ended after it, by process id, whatever happened in between. The
loop and the simulator run real-time above them, so what reaches the loop through them is the
machine's own (a hypervisor's vCPU held, a kernel thread), which cyclictest beside the same case
shows as well.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

MAX_HOGS = 16


@contextmanager
def cpu_hogs(count: int) -> Iterator[list[int]]:
    """``count`` busy processes while the block runs; yields their process ids."""
    if not 0 <= count <= MAX_HOGS:
        raise ValueError(f"cpu hogs: {count}: must be 0 .. {MAX_HOGS}")
    procs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
        for _ in range(count)
    ]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()
