"""Keep the controller's CPUs from halting while the loop runs: one poller per CPU at ``SCHED_IDLE``.

Why. On a virtual machine an idle vCPU halts and hands its physical CPU back to the host; what
wakes it (the loop's timer, the SYNC that wakes the simulated drives on the other CPU) waits
until the host runs that vCPU again, which on a busy host takes milliseconds no priority inside
the guest can shorten. The guest's own remedy (``idle=poll``, or a cpuidle driver such as
``haltpoll`` that polls before it halts) needs a kernel option or a driver; a guest without a
cpuidle driver (``/sys/devices/system/cpu/cpuidle/current_driver``: ``none``) halts at once, and
a PM QoS limit (``--cpu-latency-us``) changes nothing there. A process that spins at
``SCHED_IDLE`` on each CPU does the same from user space: the CPU never halts, and any other
task of its cgroup, real-time or normal, takes the CPU from it at once (``SCHED_IDLE`` weighs 3
where nice 0 weighs 1 024; with the cgroup v2 cpu controller that holds within its group only).
What it changes beside the demo: the real-time page of the docs.

The price: every CPU the controller may use is busy for as long as the loop runs (the pollers'
CPU time is in the run's summary, ``idle_poll.cpu_s``), and the host counts that time. The
default asks for it only where the guest halts at once and its kernel has no polling idle state
to keep it in by a latency limit of 0, which costs the loop less (``controller.realtime.idle_remedy``).

A poller is its own small interpreter, not a thread: a spinning thread of the loop's process
would hold the interpreter lock the loop needs. It is born under the normal scheduler whatever
its starter's policy (``posix_spawn``'s scheduler: it never runs at the loop's priority it would
otherwise inherit), in a process group of its own with none of the controller's files, takes
``SCHED_IDLE`` and its CPU, says so on a pipe, and ends by itself once the process that
started it is gone (its parent changes: within milliseconds of its CPU time), whatever ended
that one; ``stop`` ends it by its process id.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field

from controller.child_process import exit_text, process_cpu_s
from controller.realtime import RealtimeError, refused_realtime

log = logging.getLogger(__name__)

# The poller's whole program (argv: its CPU, the process id of the process that must outlive it).
# It says it is set up with one byte on fd 3; a poller that cannot set up exits without it. 200 000
# empty iterations take a few milliseconds of CPU time: the parent is checked that often. A parent
# stopped (Ctrl-Z, SIGSTOP, a debugger) has no loop to keep warm: the poller sleeps until it runs
# again, instead of spinning both CPUs for as long as the stop lasts (an outside tester: 993 of 1 000
# ticks in 5 s).
POLLER_SOURCE = """\
import os, sys, time
cpu, parent = int(sys.argv[1]), int(sys.argv[2])
try:
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    os.sched_setaffinity(0, {cpu})
except OSError:
    sys.exit(1)
os.write(3, b"1")
os.closerange(3, os.sysconf("SC_OPEN_MAX"))  # and whatever else the controller had inherited
def stopped():
    try:
        with open("/proc/%d/stat" % parent, "rb") as f:
            return f.read().rpartition(b")")[2].split()[0] in (b"T", b"t")
    except (OSError, IndexError):
        return False
while os.getppid() == parent:
    for _ in range(200_000):
        pass
    while stopped() and os.getppid() == parent:
        time.sleep(0.05)
"""


class IdlePollingError(OSError):
    """A poller that did not start, or did not take ``SCHED_IDLE`` and its CPU."""


@dataclass
class IdlePollers:
    """One ``SCHED_IDLE`` poller per CPU of ``cpus`` (module text); ``start``, then ``stop``."""

    cpus: tuple[int, ...]
    pids: dict[int, int] = field(default_factory=dict)  # CPU -> the poller's process id, once set up

    def start(self) -> list[str]:
        """Spawn the pollers and wait until each is set up; returns why a CPU has none (empty: every
        CPU has its poller)."""
        refused = []
        for cpu in self.cpus:
            try:
                self.pids[cpu] = self._spawn(cpu)
            except IdlePollingError as err:
                refused.append(f"CPU {cpu}: {err}")
        return refused

    def _spawn(self, cpu: int) -> int:
        """One poller on ``cpu``, set up (its byte read), or ``IdlePollingError``."""
        ready_r, ready_w = os.pipe()
        null = os.open(os.devnull, os.O_RDWR)
        try:
            try:
                pid = os.posix_spawn(
                    sys.executable,
                    [sys.executable, "-I", "-S", "-c", POLLER_SOURCE, str(cpu), str(os.getpid())],
                    os.environ,
                    # nothing of the controller's: not its terminal's or pipe's ends (a reader of
                    # the controller's output waits for their end), not its process group (a
                    # terminal's Ctrl-C is the controller's to handle)
                    file_actions=[
                        (os.POSIX_SPAWN_DUP2, null, 0),
                        (os.POSIX_SPAWN_DUP2, null, 1),
                        (os.POSIX_SPAWN_DUP2, null, 2),
                        (os.POSIX_SPAWN_DUP2, ready_w, 3),
                    ],
                    setpgroup=0,
                    # born under the normal scheduler whatever the caller's policy (glibc takes no
                    # SCHED_IDLE here): its first act is to take SCHED_IDLE
                    scheduler=(os.SCHED_OTHER, os.sched_param(0)),
                )
            except OSError as err:
                raise IdlePollingError(f"not started: {err}") from err
            os.close(ready_w)
            ready_w = -1
            if os.read(ready_r, 1) != b"1":  # its end: it exited without setting up
                os.waitpid(pid, 0)
                raise IdlePollingError("the kernel refused SCHED_IDLE or the CPU")
            return pid
        finally:
            os.close(ready_r)
            os.close(null)
            if ready_w >= 0:
                os.close(ready_w)

    def cpu_s(self) -> float:
        """The CPU time the pollers have taken so far [s] (one that ended counts until ``stop`` reaps
        it: a zombie's ``/proc`` entry keeps its times)."""
        return sum((t for t in map(process_cpu_s, self.pids.values()) if not math.isnan(t)), 0.0)

    def stop(self) -> PollersStopped:
        """End every poller by its process id; returns the CPU time they took and the CPUs whose
        poller had already ended (killed under the run: its CPU was not polled until the end)."""
        spent = self.cpu_s()
        ended_early: dict[int, str] = {}
        for cpu, pid in self.pids.items():
            with contextlib.suppress(ChildProcessError):
                reaped, status = os.waitpid(pid, os.WNOHANG)
                if reaped:
                    ended_early[cpu] = exit_text(os.waitstatus_to_exitcode(status))
                    continue
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
        self.pids.clear()
        return PollersStopped(spent, ended_early)


@dataclass(frozen=True)
class PollersStopped:
    """What ``IdlePollers.stop`` found: the pollers' CPU time [s], and the CPUs whose poller had
    ended before it (CPU -> how: ``exit_text``'s "killed by SIGKILL")."""

    cpu_s: float
    ended_early: dict[int, str]


@contextlib.contextmanager
def idle_polling(
    cpus: tuple[int, ...], summary: dict[str, object], required: bool = False
) -> Iterator[IdlePollers]:
    """Pollers on ``cpus`` (none: nothing) for the time of the block, which is given them;
    ``summary`` gets the CPUs polled, the pollers' CPU time and the CPUs whose poller ended before
    the block did. A CPU without its poller is a ``RealtimeError`` when ``required``, else one line
    of warning."""
    pollers = IdlePollers(cpus)
    if not cpus:
        yield pollers
        return
    try:
        refused = pollers.start()
        if refused:
            message = "--idle-poll: no poller on " + "; ".join(refused)
            if required:
                raise RealtimeError(message)
            log.warning("%s", refused_realtime([message]))
        yield pollers
    finally:
        summary["cpus"] = sorted(pollers.pids)
        stopped = pollers.stop()
        summary["cpu_s"] = round(stopped.cpu_s, 2)
        if stopped.ended_early:
            # polled at the start, not at the end: the run's timing had no poller there from then on
            summary["ended_early"] = sorted(stopped.ended_early)
            log.warning(
                "--idle-poll: the poller of %s ended before the run did; that CPU halted when idle from then on",
                "; ".join(f"CPU {cpu} ({how})" for cpu, how in sorted(stopped.ended_early.items())),
            )
