"""Real-time tasks beside the loop on its CPU, named by the CPU shield's guardian.

The shield moves normal tasks off the loop's CPU (controller/shell/cpu_shield.py); a real-time
task that may run there stays, since its placement is deliberate (cyclictest's floor is one). A
busy one, even at ``SCHED_FIFO`` 1, far below the loop, still stops the loop: the kernel throttles
a CPU's real-time tasks together once they have used ``sched_rt_runtime_us`` of each
``sched_rt_period_us``, and the loop stands still with the rest (50 ms of every second at the
defaults: 679-745 late cycles a demo, docs/concepts/realtime.md). Nothing in the controller may
move such a task; what it can do is name it, so that a run with a stall once a second says why.

The guardian, a process of its own on another CPU, looks every ``SCAN_S`` for the real-time
tasks (``SCHED_FIFO``, ``SCHED_RR``, ``SCHED_DEADLINE``) that may run on the loop's CPU: not
kernel threads, not the controller's process nor its children (the simulated drives run
real-time on purpose). At the end it reports those that used at least ``MIN_CPU_S`` of CPU time
while it saw them (the summary's ``cpu_shield.realtime_neighbours``), and once more as it ends.
Of a task born before the watch began, the time before the guardian first saw it is not counted
(up to ``SCAN_S``); of one born after, all of it is.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller.shell.machine_tasks import CLOCK_TICKS_HZ, Task, affinity, all_tasks, ticks_now

SCAN_S = 1.0  # how often the guardian looks
MIN_CPU_S = 0.1  # a neighbour that used less is no throttling's cause worth a line
REALTIME_POLICIES = {1: "SCHED_FIFO", 2: "SCHED_RR", 6: "SCHED_DEADLINE"}


@dataclass
class Neighbour:
    """One real-time thread seen on the loop's CPU: who it is and the CPU time it used meanwhile."""

    task: Task
    first_seen_s: float  # since the watch began
    last_seen_s: float
    cpu_ticks_first: int
    cpu_ticks_last: int

    def report(self) -> dict[str, Any]:
        t = self.task
        return {
            "pid": t.pid,
            "tid": t.tid,
            "name": t.name,
            "policy": REALTIME_POLICIES.get(t.policy, str(t.policy)),
            "priority": t.rt_priority,
            "cpu_s": round((self.cpu_ticks_last - self.cpu_ticks_first) / CLOCK_TICKS_HZ, 2),
            "seen_s": [round(self.first_seen_s, 1), round(self.last_seen_s, 1)],  # after the shield rose
        }


class NeighbourWatch:
    """The real-time tasks that may run on ``cpus``, but the processes ``exclude_pids`` and their
    descendants; ``scan`` looks once, ``report`` lists those that used ``MIN_CPU_S`` or more."""

    def __init__(
        self,
        cpus: Iterable[int],
        exclude_pids: Iterable[int],
        proc: Path = Path("/proc"),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cpus, self.exclude = frozenset(cpus), frozenset(exclude_pids)
        self.proc, self.clock, self.start_s = proc, clock, clock()
        self.start_ticks = ticks_now()  # a task born after it used all its CPU time under the watch
        self.seen: dict[tuple[int, int], Neighbour] = {}  # (tid, start ticks): tids are reused

    def scan(self) -> None:
        now = self.clock() - self.start_s
        tasks = list(all_tasks(self.proc))
        parent = {t.pid: t.ppid for t in tasks}
        for t in tasks:
            if t.kernel or t.policy not in REALTIME_POLICIES or self._ours(t.pid, parent):
                continue
            allowed = affinity(t.tid)
            if allowed is None or not self.cpus & allowed:
                continue  # gone, or kept off the loop's CPU
            known = self.seen.get((t.tid, t.start_ticks))
            if known is None:
                before = 0 if t.start_ticks >= self.start_ticks else t.cpu_ticks
                self.seen[(t.tid, t.start_ticks)] = Neighbour(t, now, now, before, t.cpu_ticks)
            else:
                known.task, known.last_seen_s, known.cpu_ticks_last = t, now, t.cpu_ticks

    def _ours(self, pid: int, parent: dict[int, int]) -> bool:
        hops = 0
        while pid > 0 and hops < 64:  # a chain of parents, never a cycle (64: more than any tree here)
            if pid in self.exclude:
                return True
            pid, hops = parent.get(pid, 0), hops + 1
        return False

    def report(self) -> list[dict[str, Any]]:
        busy = [
            n
            for n in self.seen.values()
            if n.cpu_ticks_last - n.cpu_ticks_first >= MIN_CPU_S * CLOCK_TICKS_HZ
        ]
        return [n.report() for n in sorted(busy, key=lambda n: n.first_seen_s)]
