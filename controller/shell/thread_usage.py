"""Whether a long cycle of the loop thread was work, or waiting beside it.

A cycle blocks on nothing by design but its answer window's sleep: the send, the observers (in
the window), the frames' reading, the step's inputs, the step, the bookkeeping after it and a
collection are work, memory locked. When a cycle takes milliseconds more all the same, the
clock cannot say why; the thread's own usage over the cycle, from its wake-up to its end, can:
its CPU time, and its context switches, each kind a different culprit:

- voluntary, besides the window's sleep (one at 400 Hz): the thread blocked on a lock: the
  interpreter lock (taken back after the window's sleep, or handed to another thread of the
  process, which CPython asks the holder to do every ``sys.getswitchinterval()``) that the
  other thread did not give back in time, or a library's lock (a Zenoh ``put``'s);
- involuntary: a task of higher priority took the CPU from the loop (at ``SCHED_FIFO`` 80 only
  the kernel's own threads above it: ``migration``, ``watchdog``);
- neither, and CPU time close to the time awake (the span less the window's wait): the work
  itself was that long, or the host paused the vCPU without reporting it as steal (on this VM it
  reports few of its pauses: ``python -m controller.tools.bench.machine_pauses`` tells the two
  apart, from the kernel's events; docs/concepts/realtime.md);
- neither, and CPU time far below it: the kernel did not count the time to the thread
  although it did not switch away from it. On a VM guest whose kernel accounts steal time
  (``CONFIG_PARAVIRT_TIME_ACCOUNTING``, as this one's does) that is the host running something
  else on the vCPU; interrupts' time counts to the thread unless the kernel accounts it apart
  (``CONFIG_IRQ_TIME_ACCOUNTING``, not set on this guest).

The CPU time is ``CLOCK_THREAD_CPUTIME_ID`` (``time.thread_time``), which brings the scheduler's
count up to the instant it is read. Not ``getrusage``'s ``ru_utime + ru_stime``: for a thread
that is running they stand where the scheduler last updated them (a tick, a switch), and a
first version of this, which read them, showed 0 µs of CPU for 200-600 µs of work in four of
seven demos. The switches are ``getrusage(RUSAGE_THREAD)``'s counters.

The start is read at every wake-up (two system calls, 0.69 and 0.64 µs on this machine), the
end only for a cycle longer than the longest so far (``LoopStats.record_span``).
In simulated time there is nothing to read (``CycleLoop``'s ``thread_usage`` is None): the
clock is not the thread's.
"""

from __future__ import annotations

import functools
import resource
import time
from collections.abc import Callable
from typing import NamedTuple


class ThreadUsageReaders(NamedTuple):
    """What the loop thread calls to read its own usage: plain C callables, no Python frame."""

    cpu_s: Callable[[], float]  # the calling thread's CPU time [s], up to now
    switches: Callable[[], resource.struct_rusage]  # its usage, for the context switch counters


def thread_usage_readers() -> ThreadUsageReaders | None:
    """The calling thread's readers on Linux (``RUSAGE_THREAD``); elsewhere none."""
    who = getattr(resource, "RUSAGE_THREAD", None)
    return ThreadUsageReaders(time.thread_time, functools.partial(resource.getrusage, who)) if who else None


class UsageBetween(NamedTuple):
    """The loop thread's usage between a start read earlier and now."""

    on_cpu_s: float  # its CPU time
    waits: int  # voluntary context switches: it blocked (a lock)
    preemptions: int  # involuntary ones: the CPU was taken from it
    page_faults: int  # minor and major: memory it touched that the kernel had to map (again)

    @classmethod
    def since(
        cls, cpu_s: float, switches: resource.struct_rusage, readers: ThreadUsageReaders
    ) -> UsageBetween:
        now = readers.switches()
        return cls(
            on_cpu_s=readers.cpu_s() - cpu_s,
            waits=now.ru_nvcsw - switches.ru_nvcsw,
            preemptions=now.ru_nivcsw - switches.ru_nivcsw,
            page_faults=(now.ru_minflt + now.ru_majflt) - (switches.ru_minflt + switches.ru_majflt),
        )
