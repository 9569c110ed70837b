"""The loop's CPU kept clear of ordinary work while the loop runs (a CPU shield), and given back after.

The loop runs at ``SCHED_FIFO`` on one CPU (controller/realtime.py), so no normal task preempts
it inside the guest. On a virtual machine that is not enough: with two CPU hogs beside the demo
free to run on every CPU, both vCPUs were busy all the time and the host took them away more
(steal), cycles lasted up to 25 ms and drive frames went missing (81-294 a run); with the hogs
kept off the loop's CPU, 6-51, and the host's steal fell (3-7 against 21-46 ticks of 10 ms a
run; docs/measurements/index.md). Our first reading, that a vCPU busy all the time is the one
the host preempts, does not hold: vCPUs kept busy by idle pollers (controller/shell/idle_poll.py)
lost less time to the host, not more. What the hogs on the loop's CPU cost is measured; why is
open.

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
  back; a task born under the shield (or forked by a swept task while the sweep ran) gets the
  loop's CPU back when its affinity is the one it inherited from its parent under the shield
  (the inheritance replayed in order of birth; a parent gone: when it is every CPU but the
  loop's). A task that set its own affinity in the meantime is left alone; on a 2-CPU machine
  one that asked for exactly the other CPU cannot be told from one that inherited it.
- **the guardian**: the sweep and the restore run in a small process of their own
  (``python -m controller.shell.cpu_shield``) that the controller starts before the loop and
  holds by a pipe. When the pipe closes (the controller ends, crashes or is killed with
  SIGKILL) or SIGTERM, SIGHUP, SIGQUIT or SIGINT comes, it restores and exits; those signals
  stay blocked while it sweeps or restores, so one that comes meanwhile waits for the end of
  that work. It holds a lock (``cpu-shield.lock`` in its state directory, root's
  ``/run/cheope`` or a user's ``$XDG_RUNTIME_DIR/cheope``, refused unless the user's alone):
  one shield a machine, a second controller runs unshielded and says so. It writes the moves it
  is about to make to ``cpu-shield.json`` before the first, and what it made before it answers;
  a guardian killed itself (even in the middle of its sweep) leaves that file: the controller
  restores from it, at its end (``CpuShield.close``, the summary's ``guardian_failed``) or at once
  when the guardian never answered (``CpuShield.start``), or, when the controller died too, the
  next run: its guardian when it takes the lock, first, or a run without a shield
  (``give_back_abandoned``) (not from a file of an earlier boot; a damaged file is removed and
  logged).
- **its priority**: when the loop asks for ``SCHED_FIFO``, the controller moves the guardian off
  the loop's CPU and puts it at ``SCHED_FIFO`` ``GUARDIAN_PRIORITY`` (1) right after its exec,
  where it may (the summary's ``guardian_scheduling`` says what it got). Under the normal
  scheduler a machine busy with normal work starved it: beside 64 threads that each sleep 50 µs
  in a loop (an outside tester's neighbour) it did not answer within ``START_TIMEOUT_S``, the
  loop ran unshielded, and its killed process took minutes to exit before the loop started (docs:
  the real-time page). At priority 1 it waits for no normal task; it is strictly below the
  controller's other real-time tasks when the loop's priority is 32 or more (the writer runs 30
  below it; the default is 80). Its work: the sweep, the restore, and a look every ``SCAN_S``
  (about 45 µs per task of the machine). Once the loop has ended (``close``) it may use every
  CPU, and a guardian the controller has to end goes back to the normal scheduler first
  (``_end``): at priority 1 beside a busy real-time task of a higher priority on its CPU it would
  not run at all, not even to exit.
- **the real-time neighbours**: real-time tasks that may run on the loop's CPU are not moved,
  but the guardian names those that used CPU time there while the run lasted (the summary's
  ``realtime_neighbours``): a busy one spends the CPU's real-time budget for the loop too
  (controller/shell/realtime_neighbours.py).
- **the tracers**: a tracer attached to the controller's process (``strace -p``, a debugger,
  ``py-spy`` sampling in its default mode) holds the loop up at every system call or sample; the
  guardian names each one it saw (the summary's ``tracers``, controller/shell/tracer_watch.py).
- **not covered**: two shields under different locks (two users, or two state directories) on
  a machine with more than two CPUs can each take a CPU from the same task; the second restore
  then gives back only its own.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import logging
import math
import os
import select
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from controller.child_process import child_environment, exit_text, python_module_command
from controller.realtime import RealtimeError, RealtimeOptions
from controller.shell.machine_tasks import Task, affinity, all_tasks, read_task, ticks_now
from controller.shell.realtime_neighbours import SCAN_S, NeighbourWatch
from controller.shell.tracer_watch import TracerWatch

log = logging.getLogger(__name__)

NORMAL_POLICIES = frozenset({0, 3, 5})  # SCHED_OTHER, SCHED_BATCH, SCHED_IDLE
LOCK_NAME, STATE_NAME = "cpu-shield.lock", "cpu-shield.json"
START_TIMEOUT_S = 30.0  # the sweep of a few thousand tasks takes well under a second
STOP_TIMEOUT_S = 10.0
# The guardian's SCHED_FIFO priority (module text, "its priority"): above every normal task, below
# every real-time task of the controller's (with the defaults: the loop 80, the simulated drives 70,
# the loop process's other threads 60, the writer 50).
GUARDIAN_PRIORITY = 1


class CpuShieldError(RuntimeError):
    """The shield could not be raised; the message says why."""


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
    boot_id: str = ""  # a record of another boot of the machine names tasks that are gone
    start_ticks: int = 0  # the clock tick the sweep began in (since boot)
    seen: list[tuple[int, int]] = field(default_factory=list)  # (tid, start ticks) of every task swept over
    moved: list[MovedTask] = field(default_factory=list)
    refused: int = 0  # tasks whose affinity could not be changed (permissions, gone meanwhile)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> ShieldRecord:
        raw = json.loads(text)
        moved = [
            MovedTask(
                int(m["pid"]),
                int(m["tid"]),
                int(m["start_ticks"]),
                _cpu_set(m["mask_before"]),
                _cpu_set(m["mask_set"]),
            )
            for m in raw["moved"]
        ]
        seen = [(int(tid), int(start)) for tid, start in raw["seen"]]
        return cls(
            _cpu_set(raw["cpus"]),
            str(raw["boot_id"]),
            int(raw["start_ticks"]),
            seen,
            moved,
            int(raw["refused"]),
        )


def _cpu_set(values: Iterable[object]) -> tuple[int, ...]:
    cpus = tuple(sorted({int(v) for v in values}))  # type: ignore[call-overload]
    if any(not 0 <= c < 65536 for c in cpus):
        raise ValueError(f"not a CPU number in {cpus}")
    return cpus


def boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def plan_sweep(cpus: Iterable[int], exclude_pids: Iterable[int], proc: Path = Path("/proc")) -> ShieldRecord:
    """The moves a sweep of ``cpus`` would make (module text), made by none yet: ``moved`` lists
    every task to move, ``seen`` every task looked at."""
    shield = frozenset(cpus)
    excluded = frozenset(exclude_pids)
    record = ShieldRecord(tuple(sorted(shield)), boot_id(), ticks_now())
    for task in all_tasks(proc):
        record.seen.append((task.tid, task.start_ticks))
        if task.pid in excluded or task.kernel or task.policy not in NORMAL_POLICIES:
            continue
        before = affinity(task.tid)
        if before is None or not before & shield:
            continue
        after = before - shield
        if not after:
            continue  # it may run on the loop's CPU only: its placement is deliberate
        record.moved.append(
            MovedTask(task.pid, task.tid, task.start_ticks, tuple(sorted(before)), tuple(sorted(after)))
        )
    return record


def apply_sweep(plan: ShieldRecord) -> ShieldRecord:
    """Make ``plan``'s moves; the record of those made. A task whose affinity changed since the
    plan set its own and is left alone; one that cannot be moved (permissions, gone) is counted
    in ``refused``."""
    made = replace(plan, moved=[])
    for move in plan.moved:
        if affinity(move.tid) != frozenset(move.mask_before):
            continue
        if _set(move.tid, move.mask_set):
            made.moved.append(move)
        else:
            made.refused += 1
    return made


def sweep(cpus: Iterable[int], exclude_pids: Iterable[int], proc: Path = Path("/proc")) -> ShieldRecord:
    """Take ``cpus`` out of the affinity of every normal task not of ``exclude_pids`` (module text)."""
    return apply_sweep(plan_sweep(cpus, exclude_pids, proc))


def restore(record: ShieldRecord, proc: Path = Path("/proc")) -> int:
    """Give back what ``record``'s sweep took (module text); returns how many tasks got it back."""
    shield = frozenset(record.cpus)
    restored = 0
    shielded_mask: dict[int, frozenset[int]] = {}  # tid: its affinity under the shield, moved or born
    for moved in record.moved:
        task = read_task(proc, moved.pid, moved.tid)
        if task is None or task.start_ticks != moved.start_ticks:
            continue  # gone, or its tid reused
        shielded_mask[moved.tid] = frozenset(moved.mask_set)
        if affinity(moved.tid) == frozenset(moved.mask_set) and _set(moved.tid, moved.mask_before):
            restored += 1
    alive = {t.tid: t for t in all_tasks(proc)}
    everything = frozenset(os.sched_getaffinity(0)) | shield
    seen = set(record.seen)  # a clock tick is 10 ms: a task's start time alone does not say it came later
    moved_tids = {m.tid for m in record.moved}
    for task in sorted(alive.values(), key=lambda t: (t.start_ticks, t.tid)):  # parents before children
        if (task.tid, task.start_ticks) in seen and not _forked_during_sweep(task, record, moved_tids):
            continue  # there before the shield, and not moved: its affinity is its own
        if task.tid in moved_tids or task.kernel or task.policy not in NORMAL_POLICIES:
            continue
        mask = affinity(task.tid)
        if mask is None or mask & shield:
            continue
        shielded_mask[task.tid] = mask
        parent = task.pid if task.tid != task.pid else task.ppid  # a thread's: its process's main thread
        inherited = shielded_mask.get(parent) if parent in alive else everything - shield
        if mask == inherited and _set(task.tid, sorted(mask | shield)):
            restored += 1
    return restored


def _forked_during_sweep(task: Task, record: ShieldRecord, moved_tids: set[int]) -> bool:
    """Listed by the sweep, but forked by a task it had already moved: it inherited the shield."""
    parent = task.pid if task.tid != task.pid else task.ppid
    return task.start_ticks >= record.start_ticks and parent in moved_tids


def _set(tid: int, mask: Iterable[int]) -> bool:
    try:
        os.sched_setaffinity(tid, set(mask))
    except OSError:
        return False
    return True


def default_state_dir() -> Path | None:
    """One per machine for root (/run/cheope), else one in the user's runtime directory (a user can
    shield only their own tasks); None when the user has none (no shared /tmp: another user could
    have made the directory first)."""
    if os.geteuid() == 0:
        return Path("/run/cheope")
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    return Path(runtime) / "cheope" if runtime else None


def private_directory(path: Path) -> Path:
    """``path`` as a directory of this user's alone (made 0700 if missing); refuses one that is a
    symbolic link, another user's, or writable by others."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.geteuid() or info.st_mode & 0o022:
        raise CpuShieldError(f"{path}: not a directory of this user's alone (owner uid {info.st_uid})")
    return path


# -- the guardian process ---------------------------------------------------------------------


def _answer(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


ENDING_SIGNALS = {signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGINT}
_WAIT_POLL_S = 0.5  # how often the wait looks for an ending signal (blocked, so it is pending)


def guard(
    cpus: tuple[int, ...], exclude: tuple[int, ...], state_dir: Path, proc: Path = Path("/proc")
) -> int:
    """The guardian's life: lock, recover a dead guardian's shield, sweep, wait for the pipe to close
    or an ending signal, restore. Answers one JSON line on stdout when shielded (or why not), one
    when restored. The ending signals stay blocked throughout: one that comes in the middle of the
    sweep or the restore ends the guardian only after it (SIGKILL cannot wait; the state file,
    written before the answer, is for that)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, ENDING_SIGNALS)
    own = frozenset(os.sched_getaffinity(0)) - frozenset(cpus)
    if own:
        os.sched_setaffinity(0, own)
    try:
        lock = os.open(
            private_directory(state_dir) / LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o600
        )
    except (OSError, CpuShieldError) as err:
        _answer({"error": f"state directory {state_dir}: {err}"})
        return 2
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        _answer({"busy": os.pread(lock, 200, 0).decode(errors="replace").strip() or "another guardian"})
        return 3
    os.ftruncate(lock, 0)
    # read back by a controller it confines (shield_holder) and by a second guardian ("busy")
    os.pwrite(lock, f"pid {os.getpid()}, CPUs {','.join(map(str, cpus))}\n".encode(), 0)
    state = state_dir / STATE_NAME
    recovered = _recover(state, proc)
    ours = (*exclude, os.getpid())
    record = plan_sweep(cpus, ours, proc)
    neighbours = NeighbourWatch(cpus, ours, proc)
    tracers = TracerWatch(exclude, proc)  # the controller's processes, not the guardian
    try:
        # written before the first move: a guardian killed in the middle of its sweep (SIGKILL
        # cannot wait) leaves every task it moved in the file, for its controller or the next run
        # to give back; a planned move not made is skipped there (its affinity differs)
        _write_state(state, record)
        record = apply_sweep(record)
        _write_state(state, record)
        _answer({"moved": len(record.moved), "refused": record.refused, "recovered": recovered})
        _wait_for_the_end(neighbours, tracers)
    finally:
        restored = restore(record, proc)
        state.unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # nobody reads any more
            _answer(
                {
                    "restored": restored,
                    "realtime_neighbours": _last_look(neighbours),
                    "tracers": _last_look(tracers),
                }
            )
    return 0


def _write_state(state: Path, record: ShieldRecord) -> None:
    """``record`` in ``state``, whole or not at all (a new file renamed over the old)."""
    tmp = state.with_suffix(".tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(record.to_json())
    tmp.replace(state)


def _recover(state: Path, proc: Path) -> int:
    """What a guardian that died without restoring left in ``state``, given back (0: nothing)."""
    if not state.exists():
        return 0
    recovered = 0
    try:
        record = ShieldRecord.from_json(state.read_text())
        if record.boot_id == boot_id():  # of another boot: its tasks are gone, their tids others'
            recovered = restore(record, proc)
    except Exception as err:
        log.warning("%s unreadable, removed: %s", state, err)
    state.unlink(missing_ok=True)
    return recovered


def recover_now(state_dir: Path | None, proc: Path = Path("/proc")) -> int | str:
    """A dead guardian's shield given back by this process (``CpuShield.close``): the tasks
    restored, or why not (another guardian holds the lock: it recovered them when it took it)."""
    if state_dir is None:
        return "no state directory"
    try:
        lock = os.open(private_directory(state_dir) / LOCK_NAME, os.O_RDWR | os.O_NOFOLLOW)
    except (OSError, CpuShieldError) as err:
        return f"state directory {state_dir}: {err}"
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return _recover(state_dir / STATE_NAME, proc)
    except BlockingIOError:
        return "another guardian holds the shield (it gave them back when it started)"
    finally:
        os.close(lock)  # and the lock with it


def give_back_abandoned(state_dir: Path | None, proc: Path = Path("/proc")) -> int:
    """A dead guardian's shield, killed with its controller, given back by a run over a bus that
    raises none (``--no-cpu-shield``): until then only the next shield would. 0 when
    there is none, or when a live guardian holds the lock (it recovered the file when it began)."""
    if state_dir is None or not (state_dir / STATE_NAME).exists():
        return 0
    given_back = recover_now(state_dir, proc)
    return given_back if isinstance(given_back, int) else 0


def _last_look(watch: NeighbourWatch | TracerWatch) -> list[dict[str, Any]]:
    """A watch's report after a last scan (the real-time neighbours' time since the one before)."""
    try:
        watch.scan()
        return watch.report()
    except Exception:  # a courtesy: the restore's answer must go out whatever happens here
        log.exception("%s not reported", type(watch).__name__)
        return []


def _wait_for_the_end(neighbours: NeighbourWatch, tracers: TracerWatch) -> None:
    """Until the controller's end closes the pipe, or an ending signal is pending; meanwhile the
    real-time tasks beside the loop (realtime_neighbours) and the tracers of the controller
    (tracer_watch) are looked for every ``SCAN_S``."""
    stdin = sys.stdin.buffer
    next_scan_s = time.monotonic()
    while not ENDING_SIGNALS & signal.sigpending():
        if time.monotonic() >= next_scan_s:
            # from now, not from the look due: a guardian held up does not look twice as often after
            next_scan_s = time.monotonic() + SCAN_S
            try:
                neighbours.scan()
                tracers.scan()
            except Exception:  # naming them is a courtesy: the shield's restore must not depend on it
                log.exception("real-time neighbours and tracers not looked for any more")
                next_scan_s = math.inf
        if select.select([stdin], [], [], _WAIT_POLL_S)[0] and not os.read(stdin.fileno(), 4096):
            return


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="keep CPUs clear of normal tasks until stdin closes")
    ap.add_argument("--cpus", required=True, help="the loop's CPUs, e.g. 1 or 2,3")
    ap.add_argument("--exclude", type=int, action="append", default=[], help="a process left alone")
    ap.add_argument("--state-dir", type=Path, default=None)
    args = ap.parse_args(argv)
    cpus = tuple(int(c) for c in args.cpus.split(","))
    state_dir = args.state_dir or default_state_dir()
    if state_dir is None:
        _answer({"error": "no state directory: root's /run/cheope, or $XDG_RUNTIME_DIR/cheope for a user"})
        return 2
    return guard(cpus, tuple(args.exclude), state_dir)


# -- the controller's side -----------------------------------------------------------------------


@contextmanager
def raise_shield(
    options: RealtimeOptions, summary: dict[str, Any], state_dir: Path | None = None
) -> Iterator[CpuShield | None]:
    """The shield for the run's loop when ``options`` ask for it, given back when the block ends.
    Refused: ``RealtimeError`` when required, else one line of warning and none. ``summary`` gets
    what it did (the run summary's ``cpu_shield``)."""
    if not options.shield or not options.cpus:
        given_back = give_back_abandoned(state_dir or default_state_dir())
        if given_back:
            log.warning("CPU shield: %d task(s) a dead guardian had moved given back", given_back)
            summary["recovered_from_a_dead_guardian"] = given_back
        confined = confined_affinity(state_dir or default_state_dir())
        if confined:  # the loop has no CPU of its own to shield, and the summary says why
            log.warning("no CPU kept clear for the loop: %s", confined)
            summary["off"] = confined
        yield None
        return
    try:
        shield = CpuShield.start(options.cpus, state_dir, realtime=options.priority is not None)
    except (CpuShieldError, OSError) as err:
        if options.required:
            raise RealtimeError(f"--cpu-shield: {err}") from err
        log.warning("CPU %s not kept clear of other work: %s", ",".join(map(str, options.cpus)), err)
        summary["off"] = str(err)
        yield None
        return
    if shield.raised["refused"]:
        log.warning(
            "CPU shield: %d task(s) kept the loop's CPU: not permitted (CAP_SYS_NICE moves other users'), "
            "or held there by the kernel",
            shield.raised["refused"],
        )
    try:
        yield shield
    finally:
        summary.update(shield.close())


def confined_affinity(state_dir: Path | None = None) -> str:
    """Why this process may not use every CPU of the machine ("": it may): a shell under
    ``taskset``, or under a CPU shield that was not given back, starts a controller whose loop and
    simulator then share what is left (an outside tester's run on one CPU said nothing of it). So
    does a shell under another controller's shield, still up: that one is named (a second
    controller started beside a running one was told "taskset, or a CPU shield not given back")."""
    allowed = sorted(os.sched_getaffinity(0))
    total = os.cpu_count() or len(allowed)
    if len(allowed) >= total:
        return ""
    holder = shield_holder(state_dir)
    why = (
        f"another controller's CPU shield keeps CPU {holder[1]} clear for its loop (its guardian: pid {holder[0]})"
        if holder
        else "its affinity, inherited: taskset, or a CPU shield not given back"
    )
    return f"this process may run on CPU {','.join(map(str, allowed))} only, of the machine's {total} ({why})"


def shield_holder(state_dir: Path | None, proc: Path = Path("/proc")) -> tuple[int, str] | None:
    """The guardian holding the shield of ``state_dir`` now and its CPUs, from what it wrote in the
    lock file; None when there is none (no file, or its writer is gone: the file outlives it).
    Read without taking the lock: a guardian starting at that instant would find it taken."""
    if state_dir is None:
        return None
    try:
        text = (state_dir / LOCK_NAME).read_text(errors="replace")
        pid_text, cpus_text = text.strip().removeprefix("pid ").split(", CPUs ")
        pid = int(pid_text)
        cmdline = (proc / str(pid) / "cmdline").read_bytes()
    except (OSError, ValueError):
        return None
    # what the guardian writes is CPU numbers: nothing else of the file is printed
    if not cpus_text.replace(",", "").isdigit():
        return None
    return (pid, cpus_text) if b"controller.shell.cpu_shield" in cmdline else None


class CpuShield:
    """A running guardian: ``start`` it before the loop, ``close`` it after (or just exit)."""

    def __init__(
        self,
        process: subprocess.Popen[bytes],
        cpus: tuple[int, ...],
        raised: dict[str, Any],
        state_dir: Path | None = None,
    ) -> None:
        self._process = process
        self.cpus = cpus
        self.raised = raised
        self.state_dir = state_dir

    @classmethod
    def start(
        cls,
        cpus: tuple[int, ...],
        state_dir: Path | None = None,
        timeout_s: float = START_TIMEOUT_S,
        realtime: bool = True,
    ) -> CpuShield:
        """Start the guardian, shielding ``cpus`` from every process but this one; raises
        ``CpuShieldError`` when it cannot (another shield holds the machine, no answer).
        ``realtime``: the loop asks for ``SCHED_FIFO``, and the guardian is raised above normal
        work (module text, "its priority")."""
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
        scheduling = _raise_guardian(process.pid, cpus) if realtime else "normal scheduler (the loop's too)"
        answer = _read_answer(process, timeout_s)
        if answer is None or "moved" not in answer:
            _end(process)
            if answer is not None and "busy" in answer:
                raise CpuShieldError(f"CPU shield already held ({answer['busy']})")
            if answer is not None and "error" in answer:
                raise CpuShieldError(str(answer["error"]))
            # it may have died in the middle of its sweep: what it moved is in its state file
            given_back = recover_now(state_dir or default_state_dir())
            raise CpuShieldError(
                f"the CPU shield's guardian did not answer ({answer}, {exit_text(process.returncode)}; "
                f"{scheduling}); tasks it had moved given back: {given_back}"
            )
        return cls(process, cpus, {**answer, "guardian_scheduling": scheduling}, state_dir)

    def close(self, timeout_s: float = STOP_TIMEOUT_S) -> dict[str, Any]:
        """Close the pipe: the guardian restores and exits. The run summary's ``cpu_shield``.

        A guardian that restored nothing (killed under the run, or stopped and so ended here)
        leaves its sweep in its state file: it is given back here (``guardian_failed``), not left
        off the loop's CPU until the next shielded run (an outside tester's SIGSTOP left every task
        of the machine on one CPU)."""
        ended = self._process.poll()
        _unpin(self._process.pid)  # the loop has ended: its CPU may serve the restore
        if self._process.stdin is not None and not self._process.stdin.closed:
            with contextlib.suppress(BrokenPipeError):
                self._process.stdin.close()
        answer = _read_answer(self._process, timeout_s)
        _end(self._process, timeout_s)
        summary = {
            "cpus": list(self.cpus),
            "tasks_moved": self.raised["moved"],
            "tasks_refused": self.raised["refused"],
            "recovered_from_a_dead_guardian": self.raised["recovered"],
            "tasks_restored": (answer or {}).get("restored"),
            "guardian_scheduling": self.raised.get("guardian_scheduling"),
        }
        neighbours = (answer or {}).get("realtime_neighbours")
        if neighbours:  # real-time tasks that shared the loop's CPU, busy (realtime_neighbours)
            summary["realtime_neighbours"] = neighbours
        tracers = (answer or {}).get("tracers")
        if tracers:  # processes that traced the controller (tracer_watch)
            summary["tracers"] = tracers
        if answer is None or "restored" not in answer:
            summary["guardian_failed"] = (
                f"{exit_text(ended)} under the run"
                if ended is not None
                else f"no answer within {timeout_s:g} s (stopped?), then {exit_text(self._process.returncode)}"
            )
            summary["tasks_restored"] = recover_now(self.state_dir or default_state_dir())
        return summary

    @property
    def pid(self) -> int:
        return self._process.pid


def _raise_guardian(pid: int, loop_cpus: tuple[int, ...]) -> str:
    """The guardian off ``loop_cpus`` and at ``SCHED_FIFO`` ``GUARDIAN_PRIORITY`` (module text, "its
    priority"), right after its exec, normally before its interpreter reaches this module's code;
    what it got, for the summary. Its affinity first: at real-time priority it must not share the
    loop's CPU even while it starts (cyclictest runs there in a bench). Refused (no CAP_SYS_NICE
    and no ``RLIMIT_RTPRIO`` for it, a cgroup without real-time runtime, a user namespace's root),
    it stays under the normal scheduler, as it was before."""
    if not hasattr(os, "sched_setscheduler"):
        return "normal scheduler (no SCHED_FIFO on this system)"
    try:
        own = os.sched_getaffinity(pid) - set(loop_cpus)
        if own:
            os.sched_setaffinity(pid, own)
        os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(GUARDIAN_PRIORITY))
    except OSError as err:
        log.debug("the CPU shield's guardian left under the normal scheduler: %s", err)
        return f"normal scheduler (SCHED_FIFO {GUARDIAN_PRIORITY} refused: {err.strerror or err})"
    return f"SCHED_FIFO {GUARDIAN_PRIORITY}"


def _unpin(pid: int) -> None:
    """The guardian free to run on every CPU, once no loop runs on its own (module text, "its
    priority"): kept off the loop's CPU beside a busy real-time task of a higher priority, a
    guardian at priority 1 does not run."""
    with contextlib.suppress(OSError):  # ended already, or not ours to change
        os.sched_setaffinity(pid, range(os.cpu_count() or 1))


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


def _end(process: subprocess.Popen[bytes], timeout_s: float = STOP_TIMEOUT_S) -> None:
    """The guardian's end: the pipe closed, then SIGTERM (it restores first, whatever it was doing),
    SIGKILL only when that is not heeded either (the caller gives back from its state file).
    First it goes back to the normal scheduler on every CPU: at priority 1 beside a busy real-time
    task of a higher priority on its CPU it would not run at all, not even to exit, where under
    the normal scheduler the kernel's fair server gives it 50 ms a second."""
    _unpin(process.pid)
    if hasattr(os, "sched_setscheduler"):  # as _raise_guardian: no SCHED_FIFO here, nothing to undo
        with contextlib.suppress(OSError):  # ended already
            os.sched_setscheduler(process.pid, os.SCHED_OTHER, os.sched_param(0))
    if process.stdin is not None and not process.stdin.closed:
        process.stdin.close()
    for end in (process.terminate, process.kill):
        try:
            process.wait(timeout_s)
            break
        except subprocess.TimeoutExpired:
            end()
    process.wait()
    if process.stdout is not None:
        process.stdout.close()


if __name__ == "__main__":
    sys.exit(main())
