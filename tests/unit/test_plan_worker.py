"""The 3-nSPU's planning worker: what a replacement process starts with (controller/robots/nspu/plan_worker.py).

Its replacement of a dead worker and the task's timeout are tested with the task
(tests/unit/test_nspu_integration.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest

from controller.realtime import RealtimeError, set_fifo_priority
from controller.robots.nspu.plan_worker import _children_start_normal

CHILD_POLICY = [sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"]


def _child_policy_from_a_fifo_thread(prepare: bool) -> int:
    """The scheduling policy of a process started by a SCHED_FIFO thread (a helper of the loop),
    after ``_children_start_normal`` on that thread when ``prepare``."""
    seen: list[int | BaseException] = []

    def run() -> None:
        try:
            set_fifo_priority(10)
            if prepare:
                _children_start_normal()
            out = subprocess.run(CHILD_POLICY, capture_output=True, text=True, check=True, timeout=60)
            seen.append(int(out.stdout))
        except (RealtimeError, subprocess.SubprocessError, ValueError) as err:
            seen.append(err)

    thread = threading.Thread(target=run)  # a thread of its own: the policy is per thread
    thread.start()
    thread.join()
    (result,) = seen
    if isinstance(result, RealtimeError):
        pytest.skip(f"SCHED_FIFO not permitted here: {result}")
    assert not isinstance(result, BaseException), result
    return result


def test_a_replacement_worker_starts_under_the_normal_scheduler():
    """A process started by a SCHED_FIFO thread inherits SCHED_FIFO; after
    ``_children_start_normal`` (SCHED_RESET_ON_FORK) it starts under SCHED_OTHER: a worker spawned
    by a real-time thread imported its modules at real-time priority and stalled the loop 0.37-0.42 s."""
    assert _child_policy_from_a_fifo_thread(prepare=False) == os.SCHED_FIFO
    assert _child_policy_from_a_fifo_thread(prepare=True) == os.SCHED_OTHER
