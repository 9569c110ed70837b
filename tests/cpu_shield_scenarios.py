"""Scenarios of the CPU shield, run inside a PID namespace of their own (tests/unit/test_cpu_shield.py).

    unshare --pid --fork --mount-proc python tests/cpu_shield_scenarios.py SCENARIO STATE_DIR

In the namespace ``/proc`` lists only the scenario's processes: the shield's sweep meets them and
nothing else of the machine. Each scenario prints one JSON object of what it saw; the test asserts.
The process running the scenario stands for the controller (its own process is never swept).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from waiting import wait_for_exit

from controller.realtime import RealtimeError, RealtimeOptions
from controller.shell import cpu_shield
from controller.shell.cpu_shield import (
    STATE_NAME,
    CpuShield,
    CpuShieldError,
    raise_shield,
    restore,
    sweep,
)
from controller.shell.machine_tasks import read_task

SPAWNER = "import subprocess, sys\nfor _ in sys.stdin:\n    print(subprocess.Popen(['sleep', '600']).pid, flush=True)"


def mask(pid: int) -> list[int]:
    return sorted(os.sched_getaffinity(pid))


class Tasks:
    """A spawner (a normal task that starts children on request), a task pinned to the first CPU
    only, and one at SCHED_FIFO: what a sweep must move, and what it must leave alone."""

    def __init__(self) -> None:
        cpus = sorted(os.sched_getaffinity(0))
        self.loop_cpu = cpus[-1]
        self.spawner = subprocess.Popen(
            [sys.executable, "-c", SPAWNER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.pinned = subprocess.Popen(["sleep", "600"])
        os.sched_setaffinity(self.pinned.pid, {cpus[0]})
        self.fifo = subprocess.Popen(["sleep", "600"])
        os.sched_setscheduler(self.fifo.pid, os.SCHED_FIFO, os.sched_param(1))
        self.children: list[int] = []

    def spawn(self) -> int:
        """A child of the spawner, born now: it inherits the spawner's affinity."""
        assert self.spawner.stdin is not None and self.spawner.stdout is not None
        self.spawner.stdin.write("\n")
        self.spawner.stdin.flush()
        pid = int(self.spawner.stdout.readline())
        self.children.append(pid)
        return pid

    def masks(self) -> dict[str, Any]:
        return {
            "spawner": mask(self.spawner.pid),
            "pinned": mask(self.pinned.pid),
            "fifo": mask(self.fifo.pid),
            "children": [mask(pid) for pid in self.children],
        }

    def end(self) -> None:
        for pid in (*self.children, self.spawner.pid, self.pinned.pid, self.fifo.pid):
            os.kill(pid, signal.SIGKILL)


def restore_after_close(state_dir: Path) -> dict[str, Any]:
    tasks = Tasks()
    out: dict[str, Any] = {"loop_cpu": tasks.loop_cpu, "all": mask(0), "before": tasks.masks()}
    shield = CpuShield.start((tasks.loop_cpu,), state_dir)
    tasks.spawn()  # born under the shield
    out["during"] = tasks.masks()
    out["state_file_during"] = (state_dir / "cpu-shield.json").exists()
    out["summary"] = shield.close()
    out["after"] = tasks.masks()
    out["state_file_after"] = (state_dir / "cpu-shield.json").exists()
    tasks.end()
    return out


def guardian_priority(state_dir: Path) -> dict[str, Any]:
    """The guardian's scheduling while it holds the shield: its policy, priority and CPUs."""
    loop_cpu = sorted(os.sched_getaffinity(0))[-1]
    shield = CpuShield.start((loop_cpu,), state_dir)
    out: dict[str, Any] = {
        "loop_cpu": loop_cpu,
        "policy": os.sched_getscheduler(shield.pid),
        "priority": os.sched_getparam(shield.pid).sched_priority,
        "cpus": mask(shield.pid),
    }
    out["summary"] = shield.close()
    return out


def guardian_priority_refused(state_dir: Path) -> dict[str, Any]:
    """The same where the kernel refuses ``SCHED_FIFO`` for the guardian: the shield still rises."""

    def refuse(pid: int, policy: int, param: os.sched_param) -> None:
        raise PermissionError(1, "Operation not permitted")

    os.sched_setscheduler = refuse  # this process's os module only: the scenario's controller
    return guardian_priority(state_dir)


def guardian_beside_a_busy_realtime_task(state_dir: Path) -> dict[str, Any]:
    """A busy SCHED_FIFO task on the guardian's CPU, started before it: the guardian at priority 1
    does not run there and gives no answer; the start must still end, with the busy task still
    burning (it burns 20 s of CPU at most: a guardian that waited for it would end after it)."""
    cpus = sorted(os.sched_getaffinity(0))
    loop_cpu = cpus[-1]
    busy = _burner(cpus[0], 20.0, fifo=True)
    try:
        _start_burning(busy)
        try:
            CpuShield.start((loop_cpu,), state_dir, timeout_s=0.3)  # short: the busy task holds CPU 0
            started = "started"
        except CpuShieldError as err:
            started = str(err)
        assert busy.stdout is not None  # "burnt" not yet said: it burns (then it sleeps, alive)
        return {"start": started, "busy_still_burning": not select.select([busy.stdout], [], [], 0)[0]}
    finally:
        busy.kill()
        busy.wait()


CONTROLLER = """
import sys, time
from pathlib import Path
from controller.shell.cpu_shield import CpuShield
shield = CpuShield.start((int(sys.argv[1]),), Path(sys.argv[2]))
print(shield.pid, flush=True)
time.sleep(600)
"""


def controller_killed(state_dir: Path) -> dict[str, Any]:
    tasks = Tasks()
    everything = mask(0)  # before the controller's shield sweeps this process too
    controller = subprocess.Popen(
        [sys.executable, "-c", CONTROLLER, str(tasks.loop_cpu), str(state_dir)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    assert controller.stdout is not None
    guardian = int(controller.stdout.readline())
    out: dict[str, Any] = {"all": everything, "during": tasks.masks()}
    controller.kill()  # SIGKILL: no clean-up of its own
    controller.wait()
    wait_for_exit(guardian, "the guardian after its controller was killed")
    out["after"] = tasks.masks()
    out["state_file_after"] = (state_dir / "cpu-shield.json").exists()
    tasks.end()
    return out


def guardian_killed(state_dir: Path) -> dict[str, Any]:
    tasks = Tasks()
    first = CpuShield.start((tasks.loop_cpu,), state_dir)
    os.kill(first.pid, signal.SIGKILL)
    wait_for_exit(first.pid, "the killed guardian")
    out: dict[str, Any] = {"all": mask(0), "after_kill": tasks.masks()}
    out["state_file_after_kill"] = (state_dir / "cpu-shield.json").exists()
    out["close_summary"] = first.close(timeout_s=1.0)  # the controller's end gives them back
    out["after_close"] = tasks.masks()
    out["state_file_after_close"] = (state_dir / "cpu-shield.json").exists()
    # the controller gone with it (no close): the next guardian gives them back when it starts
    second = CpuShield.start((tasks.loop_cpu,), state_dir)
    os.kill(second.pid, signal.SIGKILL)
    wait_for_exit(second.pid, "the second killed guardian")
    out["after_second_kill"] = tasks.masks()
    third = CpuShield.start((tasks.loop_cpu,), state_dir)
    out["recovered"] = third.raised["recovered"]
    out["during_third"] = tasks.masks()
    third.close()
    out["after"] = tasks.masks()
    tasks.end()
    return out


# The guardian, killed (SIGKILL, no clean-up) in the middle of its sweep: after its first move,
# at its second
DYING_GUARDIAN = """
import os, signal, sys
import controller.shell.cpu_shield as shield
made, real_set = [], shield._set
def set_then_die(tid, mask):
    if made:
        os.kill(os.getpid(), signal.SIGKILL)
    made.append(tid)
    return real_set(tid, mask)
shield._set = set_then_die
sys.exit(shield.main(sys.argv[1:]))
"""


def _dying_guardian(module: str, *args: str) -> list[str]:
    return [sys.executable, "-c", DYING_GUARDIAN, *args]


def guardian_killed_mid_sweep(state_dir: Path) -> dict[str, Any]:
    """Killed between two moves of its sweep, before it answered: the moves made are in its state
    file, given back by the controller that started it (at once) or by the next run."""
    tasks = Tasks()
    tasks.spawn()
    tasks.spawn()  # three tasks to move: the spawner and its two children
    out: dict[str, Any] = {"all": mask(0)}
    cpu_shield.python_module_command = _dying_guardian  # what CpuShield.start runs
    try:
        CpuShield.start((tasks.loop_cpu,), state_dir)
        out["start"] = "answered"
    except CpuShieldError as err:
        out["start"] = str(err)
    out["after_start"] = tasks.masks()
    out["state_file_after_start"] = (state_dir / STATE_NAME).exists()
    # its controller gone with it: what it moved waits in its state file for the next run
    dying = subprocess.Popen(
        _dying_guardian(
            "", "--cpus", str(tasks.loop_cpu), "--exclude", str(os.getpid()), "--state-dir", str(state_dir)
        ),
        stdout=subprocess.PIPE,
        stdin=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    out["dying_answer"] = dying.communicate()[0].decode()
    out["dying_exit"] = dying.returncode
    out["after_kill"] = tasks.masks()
    out["state_file_after_kill"] = (state_dir / STATE_NAME).exists()
    # the next run gives them back, even one that raises no shield of its own
    summary: dict[str, Any] = {}
    with raise_shield(RealtimeOptions(cpus=(tasks.loop_cpu,), shield=False), summary, state_dir):
        out["after"] = tasks.masks()
    out["summary"] = summary
    out["state_file_after"] = (state_dir / STATE_NAME).exists()
    tasks.end()
    return out


def guardian_stopped(state_dir: Path) -> dict[str, Any]:
    tasks = Tasks()
    shield = CpuShield.start((tasks.loop_cpu,), state_dir)
    os.kill(shield.pid, signal.SIGSTOP)  # alive, but never answers: ended by SIGKILL at the close
    out: dict[str, Any] = {"all": mask(0), "during": tasks.masks()}
    out["close_summary"] = shield.close(timeout_s=1.0)
    out["after"] = tasks.masks()
    out["state_file_after"] = (state_dir / "cpu-shield.json").exists()
    tasks.end()
    return out


def one_a_machine(state_dir: Path) -> dict[str, Any]:
    cpu = sorted(os.sched_getaffinity(0))[-1]
    first = CpuShield.start((cpu,), state_dir)
    out: dict[str, Any] = {}
    try:
        CpuShield.start((cpu,), state_dir)
        out["second"] = "started"
    except CpuShieldError as err:
        out["second"] = str(err)
    summary: dict[str, Any] = {}
    best_effort = RealtimeOptions(cpus=(cpu,), shield=True, required=False)
    with raise_shield(best_effort, summary, state_dir) as shield:
        out["best_effort_shield"] = shield is not None
    out["best_effort_summary"] = summary
    try:
        with raise_shield(RealtimeOptions(cpus=(cpu,), shield=True), {}, state_dir):
            out["required"] = "started"
    except RealtimeError as err:
        out["required"] = str(err)
    first.close()
    return out


def forked_during_sweep(state_dir: Path) -> dict[str, Any]:
    """A child a swept task forks while the sweep is still reading /proc is listed by it with the
    shield already inherited: the restore must give it the CPU back like any child born after."""
    tasks = Tasks()
    record = sweep((tasks.loop_cpu,), (os.getpid(),))
    child = tasks.spawn()
    task = read_task(Path("/proc"), child, child)
    assert task is not None
    record.seen.append((task.tid, task.start_ticks))  # as if the sweep had listed it
    out: dict[str, Any] = {"all": mask(0), "during": tasks.masks()}
    out["restored"] = restore(record)
    out["after"] = tasks.masks()
    tasks.end()
    return out


def ending_signals(state_dir: Path) -> dict[str, Any]:
    """SIGTERM or SIGHUP to the guardian (systemd stopping a unit, a closed terminal): it restores first."""
    out: dict[str, Any] = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        tasks = Tasks()
        shield = CpuShield.start((tasks.loop_cpu,), state_dir)
        during = tasks.masks()["spawner"]
        os.kill(shield.pid, sig)
        wait_for_exit(shield.pid, f"the guardian after {sig.name}")
        out[sig.name] = {"all": mask(0), "during": during, "after": tasks.masks()["spawner"]}
        out[sig.name]["state_file_after"] = (state_dir / STATE_NAME).exists()
        shield.close(timeout_s=1.0)
        tasks.end()
    return out


def bad_state_files(state_dir: Path) -> dict[str, Any]:
    """A damaged, hostile or stale state file costs the shield nothing; a state directory that is
    not the user's alone is refused with its name."""
    out: dict[str, Any] = {}
    cpu = sorted(os.sched_getaffinity(0))[-1]
    stale = {"cpus": [cpu], "boot_id": "another boot", "start_ticks": 0, "seen": [], "refused": 0}
    stale["moved"] = [{"pid": 1, "tid": 1, "start_ticks": 0, "mask_before": [cpu], "mask_set": [cpu]}]
    for name, text in (
        ("garbage", "{not json"),
        ("nested", "[" * 100_000 + "]" * 100_000),
        ("huge cpu", json.dumps({**stale, "cpus": [10**30]})),
        ("stale", json.dumps(stale)),
    ):
        state_dir.mkdir(mode=0o700, exist_ok=True)
        (state_dir / STATE_NAME).write_text(text)
        shield = CpuShield.start((cpu,), state_dir)
        out[name] = {"recovered": shield.raised["recovered"], "summary": shield.close()}
        out[name]["state_file_after"] = (state_dir / STATE_NAME).exists()
    foreign = state_dir / "foreign"
    foreign.mkdir()
    os.chown(foreign, 65534, 65534)
    try:
        CpuShield.start((cpu,), foreign)
        out["foreign"] = "started"
    except CpuShieldError as err:
        out["foreign"] = str(err)
    return out


BURN = """
import sys, time
sys.stdin.readline()  # started: it burns when asked, under the shield
print("burning", flush=True)
start = time.process_time()
while time.process_time() - start < float(sys.argv[1]):
    pass
print("burnt", flush=True)
time.sleep(600)
"""


def _burner(cpu: int, seconds: float, fifo: bool) -> subprocess.Popen[str]:
    """A process that burns ``seconds`` of CPU on ``cpu`` when a line comes, at SCHED_FIFO 1 or not."""
    burner = subprocess.Popen(
        [sys.executable, "-c", BURN, str(seconds)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    os.sched_setaffinity(burner.pid, {cpu})
    if fifo:
        os.sched_setscheduler(burner.pid, os.SCHED_FIFO, os.sched_param(1))
    return burner


def _start_burning(burner: subprocess.Popen[str]) -> None:
    """Asks ``burner`` to burn; returns once it does."""
    assert burner.stdin is not None and burner.stdout is not None
    burner.stdin.write("\n")
    burner.stdin.flush()
    assert burner.stdout.readline().strip() == "burning"


def _burn(burner: subprocess.Popen[str]) -> None:
    """Asks ``burner`` to burn; returns once it has burnt its seconds."""
    _start_burning(burner)
    assert burner.stdout is not None
    assert burner.stdout.readline().strip() == "burnt"


NEIGHBOURS_CONTROLLER = """
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from cpu_shield_scenarios import _burn, _burner
from controller.shell.cpu_shield import CpuShield
cpu = int(sys.argv[1])
shield = CpuShield.start((cpu,), Path(sys.argv[2]))
own = _burner(cpu, 0.3, fifo=True)  # the controller's own real-time child (the simulated drives)
_burn(own)
print(own.pid, flush=True)
sys.stdin.readline()
summary = shield.close()
own.kill()
print(json.dumps(summary), flush=True)
"""


def realtime_neighbours(state_dir: Path) -> dict[str, Any]:
    """Real-time tasks that used CPU time on the loop's CPU during the run are named in the
    shield's summary; not one that only slept there, not a normal one, not the controller's own."""
    cpu = sorted(os.sched_getaffinity(0))[-1]
    controller = subprocess.Popen(
        [sys.executable, "-c", NEIGHBOURS_CONTROLLER, str(cpu), str(state_dir), str(Path(__file__).parent)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert controller.stdin is not None and controller.stdout is not None
    own = int(controller.stdout.readline())
    busy, normal = _burner(cpu, 0.5, fifo=True), _burner(cpu, 0.3, fifo=False)
    sleeper = subprocess.Popen(["sleep", "600"])
    os.sched_setaffinity(sleeper.pid, {cpu})
    os.sched_setscheduler(sleeper.pid, os.SCHED_FIFO, os.sched_param(1))
    _burn(busy)
    _burn(normal)
    controller.stdin.write("\n")
    controller.stdin.flush()
    summary = json.loads(controller.stdout.readline())
    for process in (busy, normal, sleeper, controller):
        process.kill()
    pids = {"own": own, "busy": busy.pid, "normal": normal.pid, "sleeper": sleeper.pid}
    return {"summary": summary, "pids": pids}


TRACED_CONTROLLER = """
import json, sys
from pathlib import Path
from controller.shell.cpu_shield import CpuShield
shield = CpuShield.start((int(sys.argv[1]),), Path(sys.argv[2]))
print("shielded", flush=True)
sys.stdin.readline()
print(json.dumps(shield.close()), flush=True)
"""
# A tracer as strace -p attaches (PTRACE_SEIZE, 0x4206: the tracee runs on), which passes each
# signal the tracee stops for back to it (PTRACE_CONT, 7), as strace does: a tracee that stops for
# a signal waits for its tracer.
TRACER = (
    "import ctypes, os, sys\n"
    "libc = ctypes.CDLL(None, use_errno=True)\n"
    "libc.ptrace.argtypes = (ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p)\n"
    "pid = int(sys.argv[1])\n"
    "print(libc.ptrace(0x4206, pid, None, None), ctypes.get_errno(), flush=True)\n"
    "while True:\n"
    "    _, status = os.waitpid(pid, 0x40000000)\n"  # __WALL
    "    if not os.WIFSTOPPED(status):\n"
    "        break\n"
    "    sig = os.WSTOPSIG(status)\n"
    "    libc.ptrace(7, pid, None, ctypes.c_void_p(0 if sig == 5 else sig))\n"
)


def traced(state_dir: Path) -> dict[str, Any]:
    """A process tracing the controller is named in the shield's summary (tracer_watch): the
    guardian's last look at the end, while the tracer is still attached, sees it."""
    cpu = sorted(os.sched_getaffinity(0))[-1]
    controller = subprocess.Popen(
        [sys.executable, "-c", TRACED_CONTROLLER, str(cpu), str(state_dir)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert controller.stdin is not None and controller.stdout is not None
    assert controller.stdout.readline().strip() == "shielded"
    tracer = subprocess.Popen(
        [sys.executable, "-c", TRACER, str(controller.pid)], stdout=subprocess.PIPE, text=True
    )
    assert tracer.stdout is not None
    seized = tracer.stdout.readline().split()  # ptrace's return and errno
    controller.stdin.write("\n")
    controller.stdin.flush()
    summary = json.loads(controller.stdout.readline())
    for process in (tracer, controller):
        process.kill()
        process.wait()
    return {"summary": summary, "tracer": tracer.pid, "seized": seized}


SCENARIOS = {
    f.__name__: f
    for f in (
        restore_after_close,
        guardian_priority,
        guardian_priority_refused,
        guardian_beside_a_busy_realtime_task,
        controller_killed,
        guardian_killed,
        guardian_killed_mid_sweep,
        guardian_stopped,
        one_a_machine,
        forked_during_sweep,
        ending_signals,
        bad_state_files,
        realtime_neighbours,
        traced,
    )
}

if __name__ == "__main__":
    name, state = sys.argv[1], Path(sys.argv[2])
    if os.getpid() != 1:  # on the host the sweep would move every task of the machine
        sys.exit("run it as the first process of a PID namespace: unshare --pid --fork --mount-proc ...")
    print(json.dumps(SCENARIOS[name](state)))
