"""Whether a long stretch of the loop thread's work was work, or waiting beside it.

A cycle's work from the collect's return to its end (the step's inputs, the step, the
bookkeeping after it) blocks on nothing by design: no I/O, memory locked. When it takes
milliseconds all the same, the clock cannot say why. The thread's own usage can
(``getrusage(RUSAGE_THREAD)``): its CPU time over the stretch, and its context switches, each
kind a different culprit:

- voluntary: the thread blocked. In this work that is a lock: the interpreter lock, handed
  to another thread of the process (CPython asks the holder to drop it every
  ``sys.getswitchinterval()``) that then did not give it back in time, or a library's lock;
- involuntary: a task of higher priority took the CPU from the loop (at ``SCHED_FIFO`` 80 only
  the kernel's own threads at 99, or interrupts' time counted to it);
- neither, and CPU time close to the span: the work itself was that long;
- neither, and CPU time far below the span: the kernel did not count the time to the thread
  although it did not switch away from it. On a VM guest whose kernel accounts steal time
  (``CONFIG_PARAVIRT_TIME_ACCOUNTING``, as this one's does) that is the host running something
  else on the vCPU; interrupts' time counts to the thread unless the kernel accounts it apart
  (``CONFIG_IRQ_TIME_ACCOUNTING``, not set on this guest).

Two readings a cycle (0.64 µs each on this machine, a system call; ``ru_utime`` and
``ru_stime`` come from the scheduler's nanosecond count, rounded to the microsecond); what
they say is kept for the run's longest cycle only (``LoopStats.longest_cycle``). In simulated
time there is nothing to read (``no_usage``): the clock is not the thread's.
"""

from __future__ import annotations

import functools
import resource
from collections.abc import Callable
from typing import NamedTuple

ThreadUsageReader = Callable[[], "resource.struct_rusage | None"]


def no_usage() -> None:
    """Nothing read: simulated time, or a system without per-thread usage."""
    return None


def thread_usage_reader() -> ThreadUsageReader:
    """The calling thread's usage, read by whichever thread calls it (the loop's): Linux's
    ``RUSAGE_THREAD``; elsewhere nothing."""
    who = getattr(resource, "RUSAGE_THREAD", None)
    return functools.partial(resource.getrusage, who) if who is not None else no_usage


class UsageBetween(NamedTuple):
    """The loop thread's usage between two readings."""

    on_cpu_s: float  # its CPU time
    waits: int  # voluntary context switches: it blocked (a lock)
    preemptions: int  # involuntary ones: the CPU was taken from it

    @classmethod
    def of(cls, before: resource.struct_rusage, after: resource.struct_rusage) -> UsageBetween:
        return cls(
            on_cpu_s=(after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            waits=after.ru_nvcsw - before.ru_nvcsw,
            preemptions=after.ru_nivcsw - before.ru_nivcsw,
        )
