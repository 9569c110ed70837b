"""Process settings for low latency in CPython, and the Linux real-time options.

The loop thread shares the interpreter with the recorder's and the publisher's threads.
CPython hands the GIL over only every ``sys.getswitchinterval()`` seconds (5 ms by
default): a loop thread woken by an arriving frame can wait that long while a background
thread converts messages. Shortening the interval bounds that wait at a small cost in
throughput of the background threads.

Real-time options (Linux). By default (``RealtimeOptions.default``, as ros2_control's node
does) the controller asks for the first three and, where the system refuses, prints one line naming
what was refused and how to permit it, and runs on without it; ``--no-realtime`` asks for
nothing. Options given explicitly on the command line are required: a refusal ends the start
with that message.
- ``SCHED_FIFO`` priority (1..99): the calling *thread* preempts every normal (CFS) task on
  its CPU as soon as it is runnable. Threads created afterwards inherit the policy, so the
  controller applies it to the loop thread only, after its helper threads have started.
  The kernel's RT throttling (``/proc/sys/kernel/sched_rt_runtime_us``, 95 % by default)
  still leaves other tasks 5 % of each CPU, so a runaway loop cannot lock the machine.
- CPU affinity: keeps the loop on one CPU (its caches, no migrations); on a 2-core machine
  put the simulator on the other CPU.
- ``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page faults from swapped-out or lazily mapped
  pages on the hot path. Process-wide.
- A CPU wake-up latency limit (PM QoS, ``/dev/cpu_dma_latency``, held open while the process
  runs): 0 keeps every CPU out of idle states that take time to leave (on a VM guest the
  ``haltpoll`` driver's halt, which hands the vCPU back to the host): the cpuidle governor
  (``haltpoll``, ``menu``, ``teo``) then keeps an idle CPU in its ``POLL`` state, a loop in the
  kernel's idle task. Machine-wide while held; released when the file is closed. cyclictest
  would hold the same limit by default; the bench runs it with ``--laptop``, so that the floor it
  measures is the machine as the service leaves it. A guest without a cpuidle driver
  (``/sys/devices/system/cpu/cpuidle/current_driver``: none) always halts an idle CPU and the
  limit changes nothing there.
- Idle polling (``controller/shell/idle_poll.py``): a ``SCHED_IDLE`` poller process on every CPU
  keeps the vCPUs of a VM guest from halting where the kernel has no polling state to keep them
  in (no cpuidle driver), which it cannot be told to do without a boot option.

Where a VM guest halts idle CPUs at once (``halts_when_idle``: no cpuidle driver, or ``haltpoll``
told not to poll, ``guest_halt_poll_ns`` 0), the defaults keep them from halting
(``idle_remedy``): with the latency limit of 0 where the kernel has a polling state and the
device may be written, else with the pollers. The limit is the cheaper of the two where both
work: the idle task polls in the kernel, where a poller is a process of its own that the CPU
switches to and back from around every sleep of the loop. ``cheope bench --rates 400 --duration
30 --compare 0 --cyclictest 30 --schedulers realtime --task contour``, 2 runs each, alternating,
nothing else running (2026-12-05, the image of 2026-12-04): the loop's process, spin excluded,
14.3 and 14.7 % of a core with the limit against 16.8 and 16.5 % with the pollers, the step in
the service 118.6 and 117.7 µs against 134.1 and 136.9 µs at its median, the simulator 6.3 and
6.5 % against 7.8 and 8.1 % (docs/concepts/realtime.md).

All are taken after the start-up work, never before it (``check_realtime`` only probes):
several controllers and simulators share a host, and one's start-up at SCHED_FIFO took the
CPU from another's running loop.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import gc
import logging
import os
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from controller.errors import InputError

log = logging.getLogger(__name__)

MCL_CURRENT = 1
MCL_FUTURE = 2
DEFAULT_LOOP_PRIORITY = 80  # above the kernel's threaded IRQs (50) on PREEMPT_RT, below its watchdogs (99)
SIMULATOR_PRIORITY_STEP = 10  # the simulated hardware runs this far below the loop

_PRIORITY_HINT = (
    "run as root, give the interpreter CAP_SYS_NICE (sudo setcap cap_sys_nice+ep <python>), "
    "or allow it in /etc/security/limits.conf (@group - rtprio 90); inside a container "
    "start it with --cap-add SYS_NICE"
)
PM_QOS_DEVICE = "/dev/cpu_dma_latency"  # linux/Documentation/power/pm_qos_interface.rst
_LATENCY_HINT = (
    "run as root, or let the service's group write the device (a udev rule: "
    'KERNEL=="cpu_dma_latency", GROUP="realtime", MODE="0660")'
)
_LOCK_HINT = (
    "run as root, give the interpreter CAP_IPC_LOCK, or raise the limit (ulimit -l unlimited, "
    "or @group - memlock unlimited in /etc/security/limits.conf)"
)


class RealtimeError(InputError):
    """A real-time option was asked for and cannot be applied; the message says why and what to do."""


def set_gil_switch_interval(interval_s: float) -> float:
    """Set the interpreter's thread switch interval; returns the previous one."""
    if not 1e-6 <= interval_s <= 0.1:
        raise ValueError(f"GIL switch interval must be in [1e-6, 0.1] s, got {interval_s}")
    previous = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    return previous


@dataclass(frozen=True)
class RealtimeOptions:
    """What to ask of the kernel; the defaults ask for nothing."""

    priority: int | None = None  # SCHED_FIFO priority 1..99, None: stay SCHED_OTHER
    cpus: tuple[int, ...] = ()  # CPUs to run on, () : leave the affinity alone
    lock_memory: bool = False  # mlockall(MCL_CURRENT | MCL_FUTURE)
    cpu_latency_us: int | None = None  # PM QoS: the CPUs' wake-up latency limit while running, None: none
    shield: bool = (
        False  # keep normal tasks off ``cpus`` while the loop runs (controller/shell/cpu_shield.py)
    )
    idle_poll: bool = (
        False  # no CPU of the controller's halts while the loop runs (controller/shell/idle_poll.py)
    )
    required: bool = True  # False: where refused, warn in one line and run on without it
    default_cpus: bool = False  # ``cpus`` are the defaults' choice, not --cpu's (messages say which)

    @classmethod
    def default(cls, priority: int = DEFAULT_LOOP_PRIORITY) -> RealtimeOptions:
        """What the controller asks for unless told otherwise: SCHED_FIFO, the last CPU kept clear
        of normal tasks, locked memory, and on a VM guest that halts idle CPUs at once the CPUs
        kept from halting (``idle_remedy``: a latency limit of 0, or pollers).

        On a machine with more than one CPU the loop takes the last one and leaves the others
        to the rest of the system (and to the simulator, ``for_simulator``).
        """
        allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        cpus = (allowed[-1],) if len(allowed) > 1 else ()
        remedy = idle_remedy()
        return cls(
            priority=priority,
            cpus=cpus,
            lock_memory=True,
            cpu_latency_us=0 if remedy is IdleRemedy.LATENCY_LIMIT else None,
            shield=bool(cpus),
            idle_poll=remedy is IdleRemedy.POLLERS,
            required=False,
            default_cpus=bool(cpus),
        )

    def for_simulator(self) -> RealtimeOptions:
        """The simulated hardware's options beside a loop with these: one step below, on the other CPUs."""
        others = tuple(sorted(os.sched_getaffinity(0) - set(self.cpus))) if self.cpus else ()
        priority = None if self.priority is None else max(1, self.priority - SIMULATOR_PRIORITY_STEP)
        return RealtimeOptions(
            priority=priority,
            cpus=others,
            lock_memory=self.lock_memory,
            cpu_latency_us=self.cpu_latency_us,
            required=self.required,
            default_cpus=self.default_cpus and bool(others),
        )

    def __post_init__(self) -> None:
        if self.priority is not None and not 1 <= self.priority <= 99:
            raise RealtimeError(f"--rt-priority {self.priority}: SCHED_FIFO priorities are 1..99")
        for cpu in self.cpus:
            if cpu < 0:
                raise RealtimeError(f"--cpu {cpu}: CPU numbers start at 0")
        if self.cpu_latency_us is not None and not 0 <= self.cpu_latency_us <= 2_000_000_000:
            raise RealtimeError(f"--cpu-latency-us {self.cpu_latency_us}: must be 0 or more microseconds")
        if self.shield and not self.cpus:
            raise RealtimeError("--cpu-shield needs --cpu: the CPUs to keep clear are the loop's")

    @property
    def any(self) -> bool:
        return (
            self.priority is not None
            or bool(self.cpus)
            or self.lock_memory
            or self.cpu_latency_us is not None
            or self.idle_poll
        )

    def cli_args(self) -> list[str]:
        """The same request as options of ``cheope sim``/``run``: how a child process gets it."""
        args: list[str] = []
        if self.priority is not None:
            args += ["--rt-priority", str(self.priority)]
        if self.cpus:
            args += ["--cpu", ",".join(str(c) for c in self.cpus)]
        if self.lock_memory:
            args.append("--lock-memory")
        if self.cpu_latency_us is not None:
            args += ["--cpu-latency-us", str(self.cpu_latency_us)]
        if self.shield:
            args.append("--cpu-shield")
        if self.idle_poll:
            args.append("--idle-poll")
        if args and not self.required:
            args.append("--rt-best-effort")
        return args

    def describe(self) -> str:
        parts = []
        if self.priority is not None:
            parts.append(f"SCHED_FIFO {self.priority}")
        if self.cpus:
            parts.append("CPU " + ",".join(str(c) for c in self.cpus))
        if self.shield:
            parts.append("kept clear of normal tasks")
        if self.idle_poll:
            parts.append("CPUs kept from halting")
        if self.lock_memory:
            parts.append("memory locked")
        if self.cpu_latency_us is not None:
            parts.append(f"CPU wake-up latency <= {self.cpu_latency_us} us")
        return ", ".join(parts) or "none"


CPUIDLE_DRIVER = "/sys/devices/system/cpu/cpuidle/current_driver"
# the haltpoll governor's poll window: how long an idle vCPU polls before it halts (0: never polls)
HALTPOLL_WINDOW = "/sys/module/haltpoll/parameters/guest_halt_poll_ns"


def on_virtual_machine(cpuinfo_path: str = "/proc/cpuinfo") -> bool:
    """True when the CPUs say they run under a hypervisor (x86's ``hypervisor`` flag)."""
    try:
        with open(cpuinfo_path) as f:
            return any(line.startswith("flags") and " hypervisor" in line for line in f)
    except OSError:
        return False


def halts_when_idle(
    cpuinfo_path: str = "/proc/cpuinfo", driver_path: str = CPUIDLE_DRIVER, window_path: str = HALTPOLL_WINDOW
) -> bool:
    """A VM guest whose idle CPUs halt at once: no cpuidle driver (``none`` or no driver file), or
    the ``haltpoll`` driver with a poll window of 0 (booted with ``haltpoll.guest_halt_poll_ns=0``,
    as the development VM's image of 2026-12-04 is). There the host decides when a halted vCPU runs again, and
    the defaults keep the CPUs from halting (``idle_remedy``). A ``haltpoll`` guest that polls
    first, or one whose window cannot be read, is left alone."""
    if not on_virtual_machine(cpuinfo_path):
        return False
    try:
        with open(driver_path) as f:
            driver = f.read().strip()
    except OSError:
        return True
    if driver in ("", "none"):
        return True
    if driver != "haltpoll":
        return False
    try:
        with open(window_path) as f:
            return int(f.read().strip()) == 0
    except (OSError, ValueError):
        return False


class IdleRemedy(Enum):
    """How the defaults keep a VM guest's idle CPUs from halting while the loop runs (module text)."""

    NONE = "none"  # left as they are: not a guest, or a guest that polls before it halts
    LATENCY_LIMIT = "latency limit"  # PM QoS 0: the kernel's idle task polls (its POLL state)
    POLLERS = "pollers"  # a SCHED_IDLE poller process on each CPU (controller/shell/idle_poll.py)


# the first idle state of a CPU: "POLL" where the cpuidle driver has the kernel's polling state
FIRST_IDLE_STATE = "/sys/devices/system/cpu/cpu0/cpuidle/state0/name"


def idle_remedy(
    cpuinfo_path: str = "/proc/cpuinfo",
    driver_path: str = CPUIDLE_DRIVER,
    window_path: str = HALTPOLL_WINDOW,
    first_state_path: str = FIRST_IDLE_STATE,
    qos_path: str = PM_QOS_DEVICE,
) -> IdleRemedy:
    """What keeps this machine's idle CPUs from halting (module text): nothing where they do not
    halt at once (``halts_when_idle``); the latency limit where the cpuidle driver has a polling
    state and the PM QoS device may be written (a service without root gets the pollers, not a
    warning at every start); the pollers otherwise."""
    if not halts_when_idle(cpuinfo_path, driver_path, window_path):
        return IdleRemedy.NONE
    try:
        with open(first_state_path) as f:
            polls = f.read().strip() == "POLL"
    except OSError:
        polls = False
    return IdleRemedy.LATENCY_LIMIT if polls and os.access(qos_path, os.W_OK) else IdleRemedy.POLLERS


def set_fifo_priority(priority: int) -> None:
    """SCHED_FIFO at ``priority`` for the calling thread (Linux)."""
    if not hasattr(os, "sched_setscheduler"):
        raise RealtimeError(f"--rt-priority {priority}: SCHED_FIFO is not available on {sys.platform}")
    lo, hi = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
    if not lo <= priority <= hi:
        raise RealtimeError(f"--rt-priority {priority}: SCHED_FIFO priorities on this system are {lo}..{hi}")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError as err:
        raise RealtimeError(
            f"--rt-priority {priority}: SCHED_FIFO not permitted ({err.strerror}); {priority_hint()}"
        ) from err
    except OSError as err:
        raise RealtimeError(f"--rt-priority {priority}: SCHED_FIFO refused by the kernel: {err}") from err


def priority_hint(proc_cgroup: str = "/proc/self/cgroup", cgroup_root: str = "/sys/fs/cgroup") -> str:
    """How to be granted SCHED_FIFO where it was refused. To root, the usual advice (be root)
    says nothing: what refuses root is a cgroup without real-time runtime (cgroup v1 with the
    kernel's real-time group scheduling: a new group's ``cpu.rt_runtime_us`` is 0) or a
    container without CAP_SYS_NICE."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return _PRIORITY_HINT
    runtime = _group_rt_runtime(proc_cgroup, cgroup_root)
    if runtime is not None and runtime[1] == 0:
        return (
            f"root is refused too: this process's cpu cgroup has no real-time runtime ({runtime[0]} is 0); "
            f"give it some, within its parent's (echo 900000 > {runtime[0]}), or run the controller outside it"
        )
    return (
        "root is refused too: inside a container start it with CAP_SYS_NICE (--cap-add SYS_NICE); with the kernel's "
        "real-time group scheduling, this process's cpu cgroup needs cpu.rt_runtime_us above 0"
    )


def _group_rt_runtime(proc_cgroup: str, cgroup_root: str) -> tuple[str, int] | None:
    """``(path, value)`` of the calling process's cgroup-v1 ``cpu.rt_runtime_us``; None without one."""
    try:
        with open(proc_cgroup) as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    for line in lines:
        parts = line.split(":", 2)  # hierarchy id, controllers, path
        if len(parts) != 3 or "cpu" not in parts[1].split(","):
            continue
        controllers, group = parts[1], parts[2]
        for mount in (controllers, "cpu", "cpu,cpuacct"):
            path = os.path.join(cgroup_root, mount, group.lstrip("/"), "cpu.rt_runtime_us")
            try:
                with open(path) as f:
                    return path, int(f.read().strip())
            except (OSError, ValueError):
                continue
    return None


def scheduling_policy(thread_id: int = 0) -> int:
    """The scheduling policy of ``thread_id`` (0: the calling thread), without the
    ``SCHED_RESET_ON_FORK`` flag that ``os.sched_getscheduler`` ORs into it where it is set."""
    return int(os.sched_getscheduler(thread_id)) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)


def fifo_priority(thread_id: int = 0) -> int | None:
    """The SCHED_FIFO priority of ``thread_id`` (0: the calling thread), None when it has none."""
    if not hasattr(os, "sched_getscheduler") or scheduling_policy(thread_id) != os.SCHED_FIFO:
        return None
    return int(os.sched_getparam(thread_id).sched_priority)


def below_own_priority() -> None:
    """The calling thread one ``SCHED_FIFO`` priority below the one it runs at (at least 1); a
    thread under any other policy is left as it is."""
    priority = fifo_priority()
    if priority is not None:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, priority - 1)))


def reset_scheduler() -> None:
    """Back to SCHED_OTHER for the calling thread (used after a permission probe)."""
    if hasattr(os, "sched_setscheduler"):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def set_cpu_affinity(cpus: tuple[int, ...], default: bool = False) -> None:
    """Run the calling thread on ``cpus`` only (threads created later inherit it). ``default``:
    the CPUs are the defaults' choice, which the messages name instead of an option not given."""
    label = ",".join(str(c) for c in cpus)
    asked = f"the default CPU {label}" if default else f"--cpu {label}"
    if not hasattr(os, "sched_setaffinity"):
        raise RealtimeError(f"{asked}: CPU affinity is not available on {sys.platform}")
    allowed = os.sched_getaffinity(0)
    outside = sorted(set(cpus) - allowed)
    if outside:
        # the defaults chose among the CPUs allowed at the start: something took this one since
        why = (
            " any more (taken since the start: another controller's CPU shield, or taskset)"
            if default
            else ""
        )
        raise RealtimeError(
            f"{asked}: CPU {outside[0]} is not one this process may use{why} "
            f"(allowed: {','.join(str(c) for c in sorted(allowed))})"
        )
    try:
        os.sched_setaffinity(0, set(cpus))
    except OSError as err:
        raise RealtimeError(f"{asked}: the kernel refused the affinity: {err}") from err


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)


def lock_memory(libc: ctypes.CDLL | None = None) -> None:
    """mlockall(MCL_CURRENT | MCL_FUTURE) for the whole process."""
    if not sys.platform.startswith("linux"):
        raise RealtimeError(f"--lock-memory: mlockall is only supported on Linux, not {sys.platform}")
    libc = libc or _libc()
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        code = ctypes.get_errno()
        if code in (errno.EPERM, errno.ENOMEM):
            raise RealtimeError(f"--lock-memory: mlockall not permitted ({os.strerror(code)}); {_LOCK_HINT}")
        raise RealtimeError(f"--lock-memory: mlockall failed: {os.strerror(code)}")


def hold_cpu_latency(latency_us: int) -> int:
    """Ask the kernel to keep every CPU's wake-up latency at most ``latency_us`` (PM QoS) for as
    long as the returned file descriptor stays open; closing it withdraws the request."""
    path = PM_QOS_DEVICE
    try:
        fd = os.open(path, os.O_WRONLY)
    except FileNotFoundError as err:
        raise RealtimeError(
            f"--cpu-latency-us {latency_us}: this kernel has no PM QoS device ({path})"
        ) from err
    except PermissionError as err:
        raise RealtimeError(
            f"--cpu-latency-us {latency_us}: {path} not writable ({err.strerror}); {_LATENCY_HINT}"
        ) from err
    try:
        os.write(fd, struct.pack("i", latency_us))
    except OSError as err:
        os.close(fd)
        raise RealtimeError(f"--cpu-latency-us {latency_us}: the kernel refused the request: {err}") from err
    return fd


def check_realtime(options: RealtimeOptions, libc: ctypes.CDLL | None = None) -> None:
    """Refuse early, before anything is opened, when the kernel will not grant required ``options``.

    Each is tried and undone at once: the start-up work that follows (imports, sessions, the
    devices' set-up) runs under the normal scheduler with unlocked memory, so it cannot starve
    a loop or a simulator already running real-time on this host; ``apply_realtime`` applies
    them after it. Options that are not required are not checked here: ``apply_realtime``
    warns about them.
    """
    if not options.required:
        return
    if options.priority is not None:
        set_fifo_priority(options.priority)
        reset_scheduler()
    if options.cpus:
        before = os.sched_getaffinity(0)
        set_cpu_affinity(options.cpus, options.default_cpus)
        os.sched_setaffinity(0, before)
    if options.lock_memory:
        libc = libc or _libc()
        lock_memory(libc)
        libc.munlockall()
    if options.cpu_latency_us is not None:
        os.close(hold_cpu_latency(options.cpu_latency_us))


def apply_realtime(options: RealtimeOptions) -> Callable[[], None]:
    """Apply ``options`` to the calling thread (priority, affinity) and the process (memory lock,
    the CPUs' wake-up latency limit).

    Required options raise ``RealtimeError`` when refused; the others are applied where the
    system permits, and what it refused is logged in one line (``refused_realtime``).
    Returns a function that puts the thread's priority and affinity back and withdraws the
    latency limit (the lock stays).
    """
    before = os.sched_getaffinity(0) if options.cpus else None
    refused: list[str] = []

    def attempt(apply: Callable[[], None]) -> bool:
        try:
            apply()
        except RealtimeError as err:
            if options.required:
                raise
            refused.append(str(err))
            return False
        return True

    if options.lock_memory:
        attempt(lock_memory)
    latency_fd: list[int] = []
    if options.cpu_latency_us is not None:
        latency_us = options.cpu_latency_us
        attempt(lambda: latency_fd.append(hold_cpu_latency(latency_us)))
    if options.cpus:
        attempt(lambda: set_cpu_affinity(options.cpus, options.default_cpus))
    applied_priority = options.priority is not None and attempt(
        lambda: set_fifo_priority(options.priority or 0)
    )
    if refused:
        log.warning("%s", refused_realtime(refused))

    def restore() -> None:
        if applied_priority:
            reset_scheduler()
        if before is not None:
            os.sched_setaffinity(0, before)
        while latency_fd:
            os.close(latency_fd.pop())

    return restore


def granted_realtime() -> str:
    """What the calling thread runs with now, as ``describe`` words: the options as granted."""
    parts = []
    real_time = False  # the throttling below concerns real-time threads only
    if hasattr(os, "sched_getscheduler"):
        policy = scheduling_policy()
        real_time = policy in (os.SCHED_FIFO, getattr(os, "SCHED_RR", -1))
        if policy == os.SCHED_FIFO:
            parts.append(f"SCHED_FIFO {os.sched_getparam(0).sched_priority}")
        elif policy == getattr(os, "SCHED_RR", -1):
            parts.append(f"SCHED_RR {os.sched_getparam(0).sched_priority}")
        else:
            parts.append("normal scheduler")
    if hasattr(os, "sched_getaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        parts.append(("CPU " if len(cpus) == 1 else "CPUs ") + ",".join(str(c) for c in cpus))
    try:
        with open("/proc/self/status") as f:
            status = f.read()
        parts.append("memory locked" if memory_locked(status) else "memory not locked")
    except (OSError, ValueError):
        pass
    latency_us = cpu_latency_limit_us()
    if latency_us is not None:
        parts.append(f"CPU wake-up latency <= {latency_us} us (machine-wide)")
    if real_time:
        throttling = rt_throttling()
        if throttling is not None:
            parts.append(throttling)
    return ", ".join(parts)


def rt_throttling(proc_sys: str = "/proc/sys/kernel") -> str | None:
    """The kernel's real-time throttling, in ``granted_realtime``'s words; None where unreadable.

    Every real-time task of a CPU shares its budget: ``sched_rt_runtime_us`` of every
    ``sched_rt_period_us`` (950 000 of 1 000 000 by default). A busy real-time task on the loop's
    CPU, even at priority 1, spends it, and the loop then stands still with it for the rest of
    each period: 50 ms a second (an outside tester, docs/concepts/realtime.md). -1: no throttling.
    """
    try:
        with open(os.path.join(proc_sys, "sched_rt_runtime_us")) as f:
            runtime_us = int(f.read())
        with open(os.path.join(proc_sys, "sched_rt_period_us")) as f:
            period_us = int(f.read())
    except (OSError, ValueError):
        return None
    if runtime_us < 0:
        return "real-time throttling off (machine-wide)"
    return f"real-time tasks throttled to {runtime_us} of every {period_us} us per CPU (machine-wide)"


def memory_locked(status: str) -> bool:
    """Whether ``/proc/PID/status`` text says the process's memory is locked (``mlockall``): most of
    its resident memory locked (``VmLck`` at least half of ``VmRSS``). Not any locked page: a
    library locks a few of its own (12 kB of a 75-MB controller that never called ``mlockall``),
    and a run refused ``mlockall`` reported "memory locked" for them."""
    values = {}
    for line in status.splitlines():
        name, _, rest = line.partition(":")
        if name in ("VmLck", "VmRSS"):
            values[name] = int(rest.split()[0])
    return values.get("VmLck", 0) > 0 and 2 * values["VmLck"] >= values.get("VmRSS", 0)


PM_QOS_NO_LIMIT_US = 2_000_000_000  # the device's value when nobody asks for a limit (PM_QOS_DEFAULT_VALUE)


def cpu_latency_limit_us() -> int | None:
    """The machine's CPU wake-up latency limit now (the strictest request held), None when there
    is none or it cannot be read (the device is root's)."""
    try:
        with open(PM_QOS_DEVICE, "rb") as f:
            data = f.read(4)
    except OSError:
        return None
    if len(data) != 4:
        return None
    (value,) = struct.unpack("i", data)
    return None if value >= PM_QOS_NO_LIMIT_US else int(value)


def refused_realtime(reasons: list[str]) -> str:
    """The one line printed when default real-time options are refused."""
    return "real-time options refused, running without them (--no-realtime silences this): " + "; ".join(
        reasons
    )


def parse_cpus(text: str, option: str = "--cpu") -> tuple[int, ...]:
    """``"1"`` or ``"0,1"`` or ``"2-3"`` -> CPU numbers."""
    cpus: list[int] = []
    try:
        for part in text.split(","):
            lo, _, hi = part.strip().partition("-")
            cpus.extend(range(int(lo), int(hi or lo) + 1))
    except ValueError as err:
        raise RealtimeError(f"{option} {text!r}: expected CPU numbers like 1, 0,1 or 2-3") from err
    if not cpus:
        raise RealtimeError(f"{option} {text!r}: no CPU given")
    return tuple(cpus)


def freeze_garbage_collector() -> None:
    """Collect once, then move every object alive now out of the collector's view.

    The loop allocates small objects every cycle, so CPython's collector runs often; a full
    (generation 2) collection walks every object of the process, including everything the
    imports created (numpy, canopen, zenoh, protobuf), and took tens of milliseconds: a
    65.8 ms stall in a 1 kHz run (``cheope bench``). Frozen objects are never walked again.
    """
    gc.collect()
    gc.freeze()


def unfreeze_garbage_collector() -> None:
    """Give the frozen objects back to the collector once the loop is over.

    Frozen objects are never collected, not even at exit: cycles holding Ruckig's objects then
    outlive the interpreter, and nanobind (Ruckig's binding) prints a screen of "leaked
    instance" warnings after every run.
    """
    gc.unfreeze()
