"""Keep the machine's CPUs from halting while the loop runs: one poller per CPU at ``SCHED_IDLE``.

Why. On a virtual machine an idle vCPU halts and hands its physical CPU back to the host; what
wakes it (the loop's timer, the SYNC that wakes the simulated drives on the other CPU) waits
until the host runs that vCPU again, which on a busy host takes milliseconds no priority inside
the guest can shorten. The guest's own remedy (``idle=poll``, the ``haltpoll`` cpuidle driver
with a PM QoS limit, ``--cpu-latency-us``) needs a kernel option or a cpuidle driver; this
guest has neither (``/sys/devices/system/cpu/cpuidle/current_driver``: ``none``). A process
that spins at ``SCHED_IDLE`` on each CPU does the same from user space: the CPU never halts,
and any other task, real-time or normal, takes it from the poller at once (``SCHED_IDLE`` is
below every nice level). What it changes beside the demo: the real-time page of the docs.

The price: every CPU of the machine is busy for as long as the loop runs (the pollers' CPU time
is in the run's summary, ``idle_poll.cpu_s``); on a machine of its own that is power and heat
for nothing a PM QoS limit does not do better, so the default asks for it on a VM guest only
(``controller.realtime.on_virtual_machine``).

A poller is its own small interpreter, not a thread: a spinning thread of the loop's process
would hold the interpreter lock the loop needs. It is born under the normal scheduler whatever
its starter's policy (``posix_spawn``'s scheduler: it never runs at the loop's priority it would
otherwise inherit), takes ``SCHED_IDLE`` and its CPU first, and ends by itself within
milliseconds once the process that started it is gone (its parent changes), whatever ended that
one; ``stop`` ends it by its process id.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

# The poller's whole program (argv: its CPU, the process id of the process that must outlive it).
# 200 000 empty iterations take a few milliseconds: the parent is checked that often.
POLLER_SOURCE = """\
import os, sys
cpu, parent = int(sys.argv[1]), int(sys.argv[2])
try:
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    os.sched_setaffinity(0, {cpu})
except OSError as err:
    sys.exit(f"idle poller: CPU {cpu}: {err}")
while os.getppid() == parent:
    for _ in range(200_000):
        pass
"""


@dataclass
class IdlePollers:
    """One ``SCHED_IDLE`` poller per CPU of ``cpus`` (module text); ``start``, then ``stop``."""

    cpus: tuple[int, ...]
    pids: dict[int, int] = field(default_factory=dict)  # CPU -> the poller's process id

    def start(self) -> None:
        """Spawn the pollers. A CPU the kernel refuses is skipped with one line of warning."""
        parent = str(os.getpid())
        for cpu in self.cpus:
            try:
                pid = os.posix_spawn(
                    sys.executable,
                    [sys.executable, "-I", "-S", "-c", POLLER_SOURCE, str(cpu), parent],
                    os.environ,
                    # born under the normal scheduler whatever the caller's policy (glibc takes no
                    # SCHED_IDLE here): its first act is to take SCHED_IDLE
                    scheduler=(os.SCHED_OTHER, os.sched_param(0)),
                )
            except OSError as err:
                log.warning("idle polling: no poller on CPU %d: %s", cpu, err)
                continue
            self.pids[cpu] = pid

    def cpu_s(self) -> float:
        """The CPU time the running pollers have taken so far [s] (``/proc/<pid>/stat``)."""
        ticks = os.sysconf("SC_CLK_TCK")
        total = 0.0
        for pid in self.pids.values():
            with contextlib.suppress(OSError, IndexError, ValueError):
                with open(f"/proc/{pid}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / ticks  # utime, stime
        return total

    def stop(self) -> float:
        """End every poller by its process id; returns the CPU time they took [s]."""
        spent = self.cpu_s()
        for pid in self.pids.values():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, 9)
        for pid in self.pids.values():
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, 0)
        self.pids.clear()
        return spent


@contextlib.contextmanager
def idle_polling(cpus: tuple[int, ...], summary: dict[str, object]) -> Iterator[None]:
    """Pollers on ``cpus`` (none: nothing) for the time of the block; ``summary`` gets the CPUs
    polled and the pollers' CPU time."""
    if not cpus:
        yield
        return
    pollers = IdlePollers(cpus)
    pollers.start()
    try:
        yield
    finally:
        summary["cpus"] = sorted(pollers.pids)
        summary["cpu_s"] = round(pollers.stop(), 2)
