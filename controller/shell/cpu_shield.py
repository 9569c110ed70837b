"""The loop's CPU kept clear of ordinary work while the loop runs (a CPU shield), and given back after.

The loop runs at ``SCHED_FIFO`` on one CPU (controller/realtime.py), so no normal task preempts
it inside the guest. On a virtual machine that is not enough: with two CPU hogs beside the demo
free to run on every CPU, both vCPUs were busy all the time and the host took them away more
(steal), cycles lasted up to 20 ms and drive frames went missing (42-162 a run); with the hogs
kept off the loop's CPU, 0-112, and the host's steal fell (median 10.5 against 23 ticks of 10 ms
a run; docs/measurements/index.md). Our reading: a vCPU that runs only the loop halts between
cycles and is woken at once, one that is always busy is the one the host preempts.

What real-time Linux set-ups do for it (``isolcpus``, ``cset shield``, systemd's ``AllowedCPUs=``,
tuned's cpu-partitioning profile) is machine configuration. ``cheope run`` and ``cheope demo`` do
the same for the time of a run, where they are permitted (CAP_SYS_NICE for other users' tasks):

- **the sweep**: every task (thread) of the machine under a normal policy (``SCHED_OTHER``,
  ``SCHED_BATCH``, ``SCHED_IDLE``) that may run on the loop's CPU loses it from its affinity,
  except the controller's own process and tasks that may run nowhere else. Real-time tasks are
  left as they are (the simulated drives, cyclictest, the kernel's threads: their placement is
  deliberate), and so are kernel threads. A task started later inherits its parent's affinity,
  so a hog started from a shell after the controller lands beside the others too.
- **the restore**: a swept task whose affinity is still the one the sweep gave it gets its own
  back; a task born under the shield whose affinity lacks the loop's CPU gets it back when its
  parent did (the inheritance replayed, in order of birth), or when its parent is gone. A task
  that set its own affinity in the meantime is left alone.
- **the guardian**: the sweep and the restore run in a small process of their own
  (``python -m controller.shell.cpu_shield``) that the controller starts before the loop and
  holds by a pipe. When the pipe closes (the controller ends, crashes or is killed with
  SIGKILL) it restores and exits; the machine never stays shielded after its controller.
  It holds a lock (``cpu-shield.lock`` in the state directory): one shield a machine, a second
  controller runs unshielded and says so. It writes what it moved to ``cpu-shield.json`` before
  it answers; a guardian killed itself leaves that file, and the next one to take the lock
  restores from it first.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import logging
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from controller.child_process import child_environment, python_module_command
from controller.realtime import RealtimeError, RealtimeOptions

log = logging.getLogger(__name__)

PF_KTHREAD = 0x00200000  # include/linux/sched.h: a kernel thread
NORMAL_POLICIES = frozenset({0, 3, 5})  # SCHED_OTHER, SCHED_BATCH, SCHED_IDLE
LOCK_NAME, STATE_NAME = "cpu-shield.lock", "cpu-shield.json"
START_TIMEOUT_S = 10.0  # the sweep of a few thousand tasks takes well under a second
STOP_TIMEOUT_S = 10.0


class CpuShieldError(RuntimeError):
    """The shield could not be raised; the message says why."""


@dataclass(frozen=True)
class Task:
    """One thread of the machine, as ``/proc/PID/task/TID/stat`` shows it."""

    pid: int  # its process (thread group)
    tid: int
    ppid: int
    start_ticks: int  # since boot, in clock ticks: with the tid, who it is (tids are reused)
    kernel: bool
    policy: int


@dataclass(frozen=True)
class MovedTask:
    pid: int
    tid: int
    start_ticks: int
    mask_before: tuple[int, ...]
    mask_set: tuple[int, ...]


@dataclass
class ShieldRecord:
    """What a sweep did: enough for the restore, also in another process after a crash."""

    cpus: tuple[int, ...]
    seen: list[tuple[int, int]] = field(default_factory=list)  # (tid, start ticks) of every task swept over
    moved: list[MovedTask] = field(default_factory=list)
    refused: int = 0  # tasks whose affinity could not be changed (permissions, gone meanwhile)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> ShieldRecord:
        raw = json.loads(text)
        moved = [
            MovedTask(m["pid"], m["tid"], m["start_ticks"], tuple(m["mask_before"]), tuple(m["mask_set"]))
            for m in raw["moved"]
        ]
        seen = [(int(tid), int(start)) for tid, start in raw["seen"]]
        return cls(tuple(raw["cpus"]), seen, moved, int(raw.get("refused", 0)))


def read_task(proc: Path, pid: int, tid: int) -> Task | None:
    """The task's stat line (proc(5)); None when it is gone."""
    try:
        text = (proc / str(pid) / "task" / str(tid) / "stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the name in parentheses may hold anything
    # fields[0] is stat's field 3 (state): ppid 4, flags 9, starttime 22, policy 41
    return Task(
        pid=pid,
        tid=tid,
        ppid=int(fields[1]),
        start_ticks=int(fields[19]),
        kernel=bool(int(fields[6]) & PF_KTHREAD),
        policy=int(fields[38]),
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


def _affinity(tid: int) -> frozenset[int] | None:
    try:
        return frozenset(os.sched_getaffinity(tid))
    except OSError:
        return None


def sweep(cpus: Iterable[int], exclude_pids: Iterable[int], proc: Path = Path("/proc")) -> ShieldRecord:
    """Take ``cpus`` out of the affinity of every normal task not of ``exclude_pids`` (module text)."""
    shield = frozenset(cpus)
    excluded = frozenset(exclude_pids)
    record = ShieldRecord(tuple(sorted(shield)))
    for task in all_tasks(proc):
        record.seen.append((task.tid, task.start_ticks))
        if task.pid in excluded or task.kernel or task.policy not in NORMAL_POLICIES:
            continue
        before = _affinity(task.tid)
        if before is None or not before & shield:
            continue
        after = before - shield
        if not after:
            continue  # it may run on the loop's CPU only: its placement is deliberate
        try:
            os.sched_setaffinity(task.tid, after)
        except OSError:
            record.refused += 1
            continue
        record.moved.append(
            MovedTask(task.pid, task.tid, task.start_ticks, tuple(sorted(before)), tuple(sorted(after)))
        )
    return record


def restore(record: ShieldRecord, proc: Path = Path("/proc")) -> int:
    """Give back what ``record``'s sweep took (module text); returns how many tasks got it back."""
    shield = frozenset(record.cpus)
    restored = 0
    given_back: set[int] = set()  # tids that have the shield's CPUs again
    for moved in record.moved:
        task = read_task(proc, moved.pid, moved.tid)
        if task is None or task.start_ticks != moved.start_ticks:
            continue  # gone, or its tid reused
        if _affinity(moved.tid) == frozenset(moved.mask_set) and _set(moved.tid, moved.mask_before):
            restored += 1
            given_back.add(moved.tid)
    alive = {t.tid: t for t in all_tasks(proc)}
    seen = set(record.seen)  # a clock tick is 10 ms: a task's start time alone does not say it came later
    born = sorted(
        (t for t in alive.values() if (t.tid, t.start_ticks) not in seen),
        key=lambda t: (t.start_ticks, t.tid),
    )
    for task in born:
        if task.kernel or task.policy not in NORMAL_POLICIES:
            continue
        mask = _affinity(task.tid)
        if mask is None or mask & shield:
            continue
        parent = task.pid if task.tid != task.pid else task.ppid  # a thread's: its process's main thread
        parent_has_it = (
            parent not in alive or parent in given_back or bool((_affinity(parent) or frozenset()) & shield)
        )
        if parent_has_it and _set(task.tid, sorted(mask | shield)):
            restored += 1
            given_back.add(task.tid)
    return restored


def _set(tid: int, mask: Iterable[int]) -> bool:
    try:
        os.sched_setaffinity(tid, set(mask))
    except OSError:
        return False
    return True


def default_state_dir() -> Path:
    """One per machine for root (/run/cheope), else one per user: a user can shield only their own tasks."""
    if os.geteuid() == 0 and os.access("/run", os.W_OK):
        return Path("/run/cheope")
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    return Path(runtime) / "cheope" if runtime else Path(tempfile.gettempdir()) / f"cheope-{os.geteuid()}"


# -- the guardian process ---------------------------------------------------------------------


def _answer(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def guard(
    cpus: tuple[int, ...], exclude: tuple[int, ...], state_dir: Path, proc: Path = Path("/proc")
) -> int:
    """The guardian's life: lock, recover a dead guardian's shield, sweep, wait for the pipe to close,
    restore. Answers one JSON line on stdout when shielded (or why not), one when restored."""
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # the finally below restores
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the controller decides when its run ends
    own = frozenset(os.sched_getaffinity(0)) - frozenset(cpus)
    if own:
        os.sched_setaffinity(0, own)
    state_dir.mkdir(parents=True, exist_ok=True)
    lock = open(state_dir / LOCK_NAME, "a+")  # noqa: SIM115  (held for the guardian's whole life)
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        _answer({"busy": lock.read().strip() or "another guardian"})
        return 3
    lock.seek(0)
    lock.truncate()
    lock.write(f"pid {os.getpid()}, CPUs {','.join(map(str, cpus))}\n")
    lock.flush()
    state = state_dir / STATE_NAME
    recovered = 0
    if state.exists():  # a guardian that died without restoring: give back what it took first
        with contextlib.suppress(
            OSError, ValueError, KeyError, TypeError
        ):  # unreadable: nothing to give back
            recovered = restore(ShieldRecord.from_json(state.read_text()), proc)
        state.unlink(missing_ok=True)
    record = sweep(cpus, (*exclude, os.getpid()), proc)
    try:
        tmp = state.with_suffix(".tmp")
        tmp.write_text(record.to_json())
        tmp.replace(state)
        _answer({"moved": len(record.moved), "refused": record.refused, "recovered": recovered})
        while sys.stdin.buffer.read(4096):  # until the controller's end closes the pipe
            pass
    finally:
        restored = restore(record, proc)
        state.unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # nobody reads any more
            _answer({"restored": restored})
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="keep CPUs clear of normal tasks until stdin closes")
    ap.add_argument("--cpus", required=True, help="the loop's CPUs, e.g. 1 or 2,3")
    ap.add_argument("--exclude", type=int, action="append", default=[], help="a process left alone")
    ap.add_argument("--state-dir", type=Path, default=None)
    args = ap.parse_args(argv)
    cpus = tuple(int(c) for c in args.cpus.split(","))
    return guard(cpus, tuple(args.exclude), args.state_dir or default_state_dir())


# -- the controller's side -----------------------------------------------------------------------


@contextmanager
def raise_shield(
    options: RealtimeOptions, summary: dict[str, Any], state_dir: Path | None = None
) -> Iterator[CpuShield | None]:
    """The shield for the run's loop when ``options`` ask for it, given back when the block ends.
    Refused: ``RealtimeError`` when required, else one line of warning and none. ``summary`` gets
    what it did (the run summary's ``cpu_shield``)."""
    if not options.shield or not options.cpus:
        yield None
        return
    try:
        shield = CpuShield.start(options.cpus, state_dir)
    except (CpuShieldError, OSError) as err:
        if options.required:
            raise RealtimeError(f"--cpu-shield: {err}") from err
        log.warning("CPU %s not kept clear of other work: %s", ",".join(map(str, options.cpus)), err)
        summary["off"] = str(err)
        yield None
        return
    if shield.raised["refused"]:
        log.warning(
            "CPU shield: %d task(s) of other users kept the loop's CPU (CAP_SYS_NICE moves them)",
            shield.raised["refused"],
        )
    try:
        yield shield
    finally:
        summary.update(shield.close())


class CpuShield:
    """A running guardian: ``start`` it before the loop, ``close`` it after (or just exit)."""

    def __init__(
        self, process: subprocess.Popen[bytes], cpus: tuple[int, ...], raised: dict[str, Any]
    ) -> None:
        self._process = process
        self.cpus = cpus
        self.raised = raised

    @classmethod
    def start(
        cls, cpus: tuple[int, ...], state_dir: Path | None = None, timeout_s: float = START_TIMEOUT_S
    ) -> CpuShield:
        """Start the guardian, shielding ``cpus`` from every process but this one; raises
        ``CpuShieldError`` when it cannot (another shield holds the machine, no answer)."""
        cmd = python_module_command(
            "controller.shell.cpu_shield", "--cpus", ",".join(map(str, cpus)), "--exclude", str(os.getpid())
        )
        if state_dir is not None:
            cmd += ["--state-dir", str(state_dir)]
        process = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=child_environment(),
            start_new_session=True,
            close_fds=True,
        )
        answer = _read_answer(process, timeout_s)
        if answer is None or "moved" not in answer:
            _end(process)
            if answer is not None and "busy" in answer:
                raise CpuShieldError(f"CPU shield already held ({answer['busy']})")
            raise CpuShieldError(f"the CPU shield's guardian did not answer ({answer})")
        return cls(process, cpus, answer)

    def close(self, timeout_s: float = STOP_TIMEOUT_S) -> dict[str, Any]:
        """Close the pipe: the guardian restores and exits. The run summary's ``cpu_shield``."""
        if self._process.stdin is not None and not self._process.stdin.closed:
            self._process.stdin.close()
        answer = _read_answer(self._process, timeout_s)
        _end(self._process, timeout_s)
        return {
            "cpus": list(self.cpus),
            "tasks_moved": self.raised["moved"],
            "tasks_refused": self.raised["refused"],
            "recovered_from_a_dead_guardian": self.raised["recovered"],
            "tasks_restored": (answer or {}).get("restored"),
        }

    @property
    def pid(self) -> int:
        return self._process.pid


def _read_answer(process: subprocess.Popen[bytes], timeout_s: float) -> dict[str, Any] | None:
    assert process.stdout is not None
    deadline = time.monotonic() + timeout_s
    line = b""
    while not line.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([process.stdout], [], [], left)[0]:
            return None
        chunk = os.read(process.stdout.fileno(), 1)
        if not chunk:
            return None
        line += chunk
    try:
        answer: dict[str, Any] = json.loads(line)
    except ValueError:
        return None
    return answer


def _end(process: subprocess.Popen[bytes], timeout_s: float = 2.0) -> None:
    if process.stdin is not None and not process.stdin.closed:
        process.stdin.close()
    try:
        process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
    if process.stdout is not None:
        process.stdout.close()


if __name__ == "__main__":
    sys.exit(main())
