"""The machine's tasks (threads) as ``/proc/PID/task/TID/stat`` shows them (proc(5)): what the CPU
shield sweeps and restores (controller/shell/cpu_shield.py) and the real-time neighbours its
guardian names (controller/shell/realtime_neighbours.py) are read here."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

PF_KTHREAD = 0x00200000  # include/linux/sched.h: a kernel thread
CLOCK_TICKS_HZ = os.sysconf("SC_CLK_TCK")  # the unit of stat's times (utime, stime, starttime)


@dataclass(frozen=True)
class Task:
    """One thread of the machine, as ``/proc/PID/task/TID/stat`` shows it."""

    pid: int  # its process (thread group)
    tid: int
    ppid: int
    start_ticks: int  # since boot, in clock ticks: with the tid, who it is (tids are reused)
    kernel: bool
    policy: int
    name: str = ""  # its comm, as the kernel keeps it (15 characters at most)
    rt_priority: int = 0  # its real-time priority (0 under a normal policy)
    cpu_ticks: int = 0  # user and system time used so far, in clock ticks


def ticks_now() -> int:
    """Clock ticks since boot, as a task's start time counts them (proc(5))."""
    return int(time.clock_gettime(time.CLOCK_BOOTTIME) * CLOCK_TICKS_HZ)


def affinity(tid: int) -> frozenset[int] | None:
    """The CPUs task ``tid`` may run on; None when it is gone."""
    try:
        return frozenset(os.sched_getaffinity(tid))
    except OSError:
        return None


def read_task(proc: Path, pid: int, tid: int) -> Task | None:
    """The task's stat line (proc(5)); None when it is gone."""
    try:
        text = (proc / str(pid) / "task" / str(tid) / "stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the name in parentheses may hold anything
    # fields[0] is stat's field 3 (state): ppid 4, flags 9, utime 14, stime 15, starttime 22,
    # rt_priority 40, policy 41
    return Task(
        pid=pid,
        tid=tid,
        ppid=int(fields[1]),
        start_ticks=int(fields[19]),
        kernel=bool(int(fields[6]) & PF_KTHREAD),
        policy=int(fields[38]),
        name=text[text.index("(") + 1 : text.rindex(")")],
        rt_priority=int(fields[37]),
        cpu_ticks=int(fields[11]) + int(fields[12]),
    )


def all_tasks(proc: Path) -> Iterator[Task]:
    for entry in os.scandir(proc):
        if not entry.name.isdigit():
            continue
        pid = int(entry.name)
        try:
            tids = sorted(int(t) for t in os.listdir(proc / entry.name / "task"))
        except OSError:
            continue  # gone
        for tid in tids:
            task = read_task(proc, pid, tid)
            if task is not None:
                yield task
