"""The loop's process's other threads, real-time below the loop, so that no normal task can hold it up.

The loop thread runs at ``SCHED_FIFO`` (controller/realtime.py), but it shares the process
with other threads: Zenoh's runtime (Rust: ``app``, ``net``, ``acc`` and what it starts later),
the query servers (Python, controller/monitoring/query_server.py), and whatever a library starts.
Each can hold something the loop needs in the middle of a cycle: the interpreter lock (every
Python thread, and a Rust thread calling into Python), a lock inside Zenoh that the loop's
``put`` takes, the logging module's lock. Under the normal scheduler such a thread is preempted
by any busy process; the loop then waits, at its real-time priority, for a thread that does not
run: a priority inversion. Two CPU hogs beside the demo held a cycle for 407 ms that way while
the loop's wake-up latency stayed at 2 ms (issue 37).

So every other thread of the process runs at ``SCHED_FIFO`` too, ``HELPER_PRIORITY_STEP`` below
the loop: above every normal task (a thread holding what the loop needs finishes its work and
lets go whatever else runs on the machine), below the simulated hardware (one step below the
loop, on the other CPUs: it stands in for devices with their own hardware), and below the loop
itself (the loop preempts a helper whenever it is runnable). ``raise_helper_threads`` does it once
before the loop starts; ``HelperThreadWatch``, an observer of the loop, looks once a second for
threads started since (a monitor joining, a library's lazy pool) and gives them the same. A
thread started by the loop thread would inherit the loop's own priority and compete with it
as an equal: it is put down to the helpers' priority the same way.

Only where the loop itself runs at ``SCHED_FIFO``: raising helpers above a loop under the normal
scheduler would make the inversion worse, not better.

The recording's writer process (logs/session_writer.py) is no helper: the loop never waits for it
(it hands each cycle over a non-blocking pipe). But a writer starved for ``WRITER_STALL_S`` (5 s)
while its backlog is full stops the run under ``recording.on_failure = "stop"``, and under the
normal scheduler any busy enough work starves it: two CPU hogs at ``nice -n -20`` beside the demo
stopped it after lap 2, 2 of 2 runs, while the loop kept its beat (an outside tester, 2ec478d). So
its main thread runs at ``SCHED_FIFO`` too, ``WRITER_PRIORITY_STEP`` below the loop: above every
normal task, below the helpers and the simulated hardware (``writer_priority``; the recorder's
``raise_writer`` does it once the loop has its priority). Its main thread only: the live views'
servers in that process (Foxglove's, Rerun's) do work that grows with their clients, and at
real-time priority it would take the CPU's real-time budget that the simulated drives share.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from dataclasses import dataclass, field

from controller.core.controller_state import ControllerState
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
from controller.core.ports import CycleTiming
from controller.realtime import fifo_priority, scheduling_policy

log = logging.getLogger(__name__)

HELPER_PRIORITY_STEP = 20  # the helpers run this far below the loop (the simulator: 10 below)
WRITER_PRIORITY_STEP = 30  # the recording's writer runs this far below the loop (module text)
WATCH_EVERY_S = 1.0  # how often the watch looks for new threads


def helper_priority(loop_priority: int) -> int:
    return max(1, loop_priority - HELPER_PRIORITY_STEP)


def writer_priority(loop_priority: int) -> int:
    return max(1, loop_priority - WRITER_PRIORITY_STEP)


def process_thread_ids() -> set[int]:
    """The kernel's ids of every thread of this process (Linux); empty where /proc is missing."""
    try:
        return {int(name) for name in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def _needs_raising(tid: int, loop_priority: int) -> bool:
    """A thread under the normal scheduler, or real-time at the loop's priority or above it."""
    policy = scheduling_policy(tid)  # a helper that set SCHED_RESET_ON_FORK (plan_worker.py) is one
    if policy not in (os.SCHED_FIFO, os.SCHED_RR):
        return True
    return int(os.sched_getparam(tid).sched_priority) >= loop_priority


def raise_threads(thread_ids: set[int], loop_priority: int) -> dict[int, tuple[int, int]]:
    """SCHED_FIFO at the helpers' priority for those of ``thread_ids`` that need it; each changed
    thread's previous policy and priority, by id (what ``restore_threads`` puts back).

    A thread that ended in between is skipped; a refusal (the loop got its priority, so it is rare:
    a thread of another user's library) is logged and the thread left as it is.
    """
    changed: dict[int, tuple[int, int]] = {}
    param = os.sched_param(helper_priority(loop_priority))
    for tid in sorted(thread_ids):
        try:
            before = (os.sched_getscheduler(tid), int(os.sched_getparam(tid).sched_priority))
            if _needs_raising(tid, loop_priority):
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
                changed[tid] = before
        except ProcessLookupError:
            continue  # ended since it was listed
        except OSError as err:
            log.warning("thread %d of the loop's process left under its scheduler: %s", tid, err)
    return changed


def restore_threads(changed: dict[int, tuple[int, int]]) -> None:
    """Each thread of ``changed`` still running back to its policy and priority of before."""
    for tid, (policy, priority) in changed.items():
        with contextlib.suppress(OSError):  # ended, or no longer ours to change
            os.sched_setscheduler(tid, policy, os.sched_param(priority))


def raise_helper_threads(loop_thread_id: int | None = None) -> dict[int, tuple[int, int]]:
    """Every thread of this process but the loop's (the calling thread: None) at the helpers'
    priority, when the loop runs at SCHED_FIFO; what changed (nothing when it does not)."""
    loop_tid = threading.get_native_id() if loop_thread_id is None else loop_thread_id
    priority = fifo_priority(loop_tid)
    if priority is None:
        return {}
    return raise_threads(process_thread_ids() - {loop_tid}, priority)


@dataclass
class HelperThreadWatch:
    """The loop's observer that gives threads started during the run the helpers' priority.

    Once every ``every_cycles`` it lists the process's threads (one directory read, no allocation
    beyond the ids); only a thread it has not seen is looked at. Nothing happens while the loop
    runs under the normal scheduler.
    """

    every_cycles: int
    loop_thread_id: int = field(default_factory=threading.get_native_id)
    known: set[int] = field(default_factory=set)
    raised: int = 0  # threads given the helpers' priority during the run
    changed: dict[int, tuple[int, int]] = field(default_factory=dict)  # for ``restore``

    @classmethod
    def for_period(cls, period_s: float) -> HelperThreadWatch:
        return cls(every_cycles=max(1, round(WATCH_EVERY_S / period_s)))

    def start(self) -> int:
        """``raise_helper_threads`` for the threads there now, from the loop's thread before it
        starts; how many it changed."""
        self.loop_thread_id = threading.get_native_id()
        self.changed = raise_helper_threads(self.loop_thread_id)
        self.known = process_thread_ids()
        return len(self.changed)

    def restore(self) -> None:
        """The threads raised back as they were, after the loop: a process that goes on (a test
        session, a tool running several loops) keeps no thread real-time it did not ask for."""
        restore_threads(self.changed)
        self.changed = {}

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        if cycle % self.every_cycles:
            return
        now = process_thread_ids()
        new = now - self.known
        self.known = now
        if not new:
            return
        priority = fifo_priority(self.loop_thread_id)
        if priority is not None:
            changed = raise_threads(new - {self.loop_thread_id}, priority)
            self.changed.update(changed)
            self.raised += len(changed)
