"""The loop's process's other threads run real-time below the loop, late starters included, and
get their scheduler back after it (controller/shell/helper_threads.py).

The test's own thread stands for the loop, at SCHED_FIFO 10 for the test's duration (skipped
where the system refuses it); the helpers then get SCHED_FIFO 1 (10 - 20, at least 1).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest

from controller.shell.helper_threads import (
    HelperThreadWatch,
    helper_priority,
    raise_helper_threads,
)

LOOP_PRIORITY = 10


def _policy(tid: int) -> tuple[int, int]:
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority


class Parked:
    """A thread waiting on an event until closed; its kernel id once it runs."""

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.ready = threading.Event()
        self.tid = 0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.ready.wait(10.0)

    def _run(self) -> None:
        self.tid = threading.get_native_id()
        self.ready.set()
        self.stop.wait()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10.0)


@pytest.fixture
def fifo_loop_thread() -> Iterator[None]:
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no SCHED_FIFO on this system")
    before = _policy(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(LOOP_PRIORITY))
    except PermissionError:
        pytest.skip("SCHED_FIFO not permitted here")
    try:
        yield
    finally:
        os.sched_setscheduler(0, before[0], os.sched_param(before[1]))


@pytest.fixture
def normal_helper() -> Iterator[Parked]:
    """A thread started under the normal scheduler (before ``fifo_loop_thread`` where both are asked)."""
    helper = Parked()
    yield helper
    helper.close()


def test_threads_there_at_start_are_raised_below_the_loop_and_restored(normal_helper, fifo_loop_thread):
    helper = normal_helper
    assert _policy(helper.tid) == (os.SCHED_OTHER, 0)
    watch = HelperThreadWatch(every_cycles=1)
    assert watch.start() >= 1
    assert _policy(helper.tid) == (os.SCHED_FIFO, helper_priority(LOOP_PRIORITY)) == (os.SCHED_FIFO, 1)
    assert _policy(0) == (os.SCHED_FIFO, LOOP_PRIORITY)  # the loop's own is left alone
    watch.restore()
    assert _policy(helper.tid) == (os.SCHED_OTHER, 0)


def test_a_thread_started_during_the_run_is_raised_within_the_watch_s_period(fifo_loop_thread):
    watch = HelperThreadWatch(every_cycles=4)
    watch.start()
    late = Parked()  # started by the loop's thread: it inherits the loop's own priority
    try:
        assert _policy(late.tid) == (os.SCHED_FIFO, LOOP_PRIORITY)  # an equal of the loop, until the watch
        watch.on_cycle(3, 0.0, None, None, None, (), None)  # not a watch cycle
        assert _policy(late.tid) == (os.SCHED_FIFO, LOOP_PRIORITY)
        watch.on_cycle(4, 0.0, None, None, None, (), None)
        assert _policy(late.tid) == (os.SCHED_FIFO, 1)  # below the loop
        assert watch.raised == 1
        watch.restore()
        assert _policy(late.tid) == (os.SCHED_FIFO, LOOP_PRIORITY)  # as it was before the watch
    finally:
        late.close()


def test_nothing_changes_while_the_loop_runs_under_the_normal_scheduler():
    if not hasattr(os, "sched_getscheduler"):
        pytest.skip("no scheduler policies on this system")
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
    helper = Parked()
    try:
        assert raise_helper_threads() == {}
        watch = HelperThreadWatch(every_cycles=1)
        assert watch.start() == 0
        watch.on_cycle(0, 0.0, None, None, None, (), None)
        assert watch.raised == 0
        assert _policy(helper.tid) == (os.SCHED_OTHER, 0)
    finally:
        helper.close()


def test_a_loop_thread_with_reset_on_fork_is_still_seen_real_time(fifo_loop_thread):
    """``os.sched_getscheduler`` ORs SCHED_RESET_ON_FORK into the policy of a thread that set it
    (the 3-nSPU's plan worker replacer does, plan_worker.py): such a thread is SCHED_FIFO all the
    same, for the helpers' raise and for the run summary's ``realtime``."""
    from controller.realtime import fifo_priority, granted_realtime, scheduling_policy

    os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(LOOP_PRIORITY))
    assert os.sched_getscheduler(0) != os.SCHED_FIFO  # the flag in the policy read
    assert scheduling_policy() == os.SCHED_FIFO
    assert fifo_priority() == LOOP_PRIORITY
    assert granted_realtime().startswith(f"SCHED_FIFO {LOOP_PRIORITY}")
