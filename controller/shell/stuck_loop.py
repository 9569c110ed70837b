"""The end of a process whose loop no longer cycles: a stop must end it in bounded time.

A stop (a signal, ``cheope stop``, a lost recording) is acted on by the loop, and so is
the quick stop of a second signal or of ``loop.stop_timeout_s``: a loop that no longer completes
cycles acts on neither. An outside tester's plug-in task blocked inside its step: ``cheope stop``
answered "accepted", SIGTERM, SIGINT and a second SIGTERM were ignored for 23 s, only SIGKILL
ended it. The drives were safe (their SYNC and heartbeat watchdogs quick-stop them, configured at
set-up: 0x6007 = 3), but the service manager's stop and the operator's were not.

``StuckLoopGuard`` watches from its own thread, once a stop was asked: when no cycle has completed
for ``loop.stop_timeout_s`` after the stop (1 s after a quick stop), it names what it saw on
stderr and ends the process (``os._exit(1)``): the drives stop on their watchdogs, the recording's
writer finishes the file on the end of its input, a demo's simulator ends with its parent.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable

QUICK_STOP_GRACE_S = 1.0  # after a second signal: this long without a cycle is a stuck loop
POLL_S = 0.1  # after a stop: how often the cycles are counted
IDLE_POLL_S = 0.5  # before one: how often the thread looks whether the loop returned (2 wake-ups a second)


class StuckLoopGuard:
    """Ends the process when a stop was asked and the loop completes no cycle (module doc)."""

    def __init__(
        self,
        cycles_done: Callable[[], int],
        stop: threading.Event,
        quick_stop: threading.Event,
        stop_timeout_s: float,
        period_s: float,
        end_process: Callable[[int], object] = os._exit,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cycles_done, self.stop, self.quick_stop = cycles_done, stop, quick_stop
        self.stop_timeout_s = stop_timeout_s
        # a healthy loop completes a cycle every period: at 1 Hz a second without one is no hold-up
        self.least_s = 3.0 * period_s + POLL_S
        self.end_process, self.clock = end_process, clock
        self._finished = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="cheope-stuck-loop-guard", daemon=True)

    def __enter__(self) -> StuckLoopGuard:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._finished.set()  # the loop returned: nothing to guard
        self._thread.join(timeout=1.0)

    def _watch(self) -> None:
        while not self.stop.wait(IDLE_POLL_S):
            if self._finished.is_set():
                return
        seen, since = self.cycles_done(), self.clock()
        while not self._finished.wait(POLL_S):
            now, cycles = self.clock(), self.cycles_done()
            if cycles != seen:
                seen, since = cycles, now
                continue
            allowed = max(
                QUICK_STOP_GRACE_S if self.quick_stop.is_set() else self.stop_timeout_s, self.least_s
            )
            if now - since >= allowed:
                print(
                    f"cheope: the loop has completed no cycle for {now - since:.1f} s after a stop was asked "
                    "(held up inside a cycle, by a task's step?): the process ends; the drives stop on "
                    "their watchdogs",
                    file=sys.stderr,
                    flush=True,
                )
                self.end_process(1)
                return
