"""Idle polling (controller/shell/idle_poll.py): a SCHED_IDLE poller per CPU while the loop runs,
ended by its process id, or by itself once the process that started it is gone."""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from waiting import wait_until

from controller.cli import _realtime, build_parser
from controller.realtime import (
    IdleRemedy,
    RealtimeError,
    RealtimeOptions,
    halts_when_idle,
    hold_cpu_latency,
    idle_remedy,
    on_virtual_machine,
)
from controller.shell.idle_poll import IdlePollers, idle_polling

ROOT = Path(__file__).resolve().parents[2]
linux_only = pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="SCHED_IDLE is Linux's")


@linux_only
def test_a_poller_spins_at_sched_idle_on_its_cpu_and_stop_ends_it_by_pid() -> None:
    cpu = max(os.sched_getaffinity(0))
    pollers = IdlePollers((cpu,))
    try:
        assert pollers.start() == []
        pid = pollers.pids[cpu]
        # start returns once the poller has said it is set up: no waiting here
        assert os.sched_getscheduler(pid) == os.SCHED_IDLE
        assert os.sched_getaffinity(pid) == {cpu}
        assert os.getpgid(pid) == pid  # a process group of its own: a terminal's Ctrl-C is not its
        # none of this process's files: its standard streams are /dev/null
        assert {os.readlink(f"/proc/{pid}/fd/{n}") for n in (0, 1, 2)} == {os.devnull}
        # and it closes the rest, what this process had inherited too, once it has said it is set up
        wait_until(lambda: sorted(os.listdir(f"/proc/{pid}/fd")) == ["0", "1", "2"], "only its 3 streams")
    finally:
        pollers.stop()
    assert not pollers.pids
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # ended and reaped


@linux_only
def test_a_cpu_the_kernel_refuses_has_no_poller_and_says_why(caplog: pytest.LogCaptureFixture) -> None:
    pollers = IdlePollers((4096,))
    assert pollers.start() == ["CPU 4096: the kernel refused SCHED_IDLE or the CPU"]
    assert not pollers.pids
    summary: dict[str, object] = {}
    with (
        pytest.raises(RealtimeError, match="--idle-poll: no poller on CPU 4096"),
        idle_polling((4096,), summary, required=True),
    ):
        pass
    assert summary["cpus"] == []
    with idle_polling((4096,), summary, required=False):
        assert "no poller on CPU 4096" in caplog.text  # one line of warning, and the run goes on
    assert summary["cpus"] == []


# A parent that starts a poller and dies without stopping it. The outer script is a child
# subreaper, so the orphaned poller becomes its child: it sees its parent change, and the outer
# script reaps it by its process id, or kills it and says so.
ORPHAN_SCENARIO = """
import ctypes, json, os, subprocess, sys, time
ctypes.CDLL(None, use_errno=True).prctl(36, 1)  # PR_SET_CHILD_SUBREAPER
child = subprocess.run(
    [sys.executable, "-c",
     "import os; from controller.shell.idle_poll import IdlePollers; p = IdlePollers((%d,)); "
     "p.start(); print(p.pids[%d], flush=True); os._exit(0)"],
    capture_output=True, text=True, check=True,
)
pid = int(child.stdout)
end = time.monotonic() + 60.0
ended = False
while time.monotonic() < end:
    done, _ = os.waitpid(pid, os.WNOHANG)
    if done:
        ended = True
        break
    time.sleep(0.01)
if not ended:
    os.kill(pid, 9)
    os.waitpid(pid, 0)
print(json.dumps({"ended_by_itself": ended}))
"""


@linux_only
def test_a_poller_whose_starter_died_without_stopping_it_ends_by_itself() -> None:
    cpu = max(os.sched_getaffinity(0))
    result = subprocess.run(
        [sys.executable, "-c", ORPHAN_SCENARIO % (cpu, cpu)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        cwd=ROOT,
    )
    assert json.loads(result.stdout) == {"ended_by_itself": True}


# A parent that starts a poller, prints its process id and waits to be stopped and killed.
STARTER = (
    "import os, time; from controller.shell.idle_poll import IdlePollers; p = IdlePollers((%d,)); "
    "p.start(); print(p.pids[%d], flush=True); time.sleep(120)"
)


def _state(pid: int) -> str:
    with open(f"/proc/{pid}/stat", "rb") as f:
        return f.read().rpartition(b")")[2].split()[0].decode()


@linux_only
def test_a_poller_sleeps_while_its_starter_is_stopped() -> None:
    """Ctrl-Z or SIGSTOP on the controller left its pollers spinning every CPU for as long as the
    stop lasted; now each sleeps (state S) until its starter runs again, then spins (R)."""

    cpu = max(os.sched_getaffinity(0))
    starter = subprocess.Popen(
        [sys.executable, "-c", STARTER % (cpu, cpu)], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    try:
        assert starter.stdout is not None
        poller = int(starter.stdout.readline())
        wait_until(lambda: _state(poller) == "R", "the poller spinning")
        os.kill(starter.pid, signal.SIGSTOP)
        wait_until(lambda: _state(poller) == "S", "the poller asleep while its starter is stopped")
        os.kill(starter.pid, signal.SIGCONT)
        wait_until(lambda: _state(poller) == "R", "the poller spinning again")
    finally:
        starter.kill()
        starter.wait()
    wait_until(lambda: not os.path.exists(f"/proc/{poller}") or _state(poller) == "Z", "the poller ending")


@linux_only
def test_the_block_polls_the_cpus_it_is_given_and_none_when_given_none() -> None:
    cpu = max(os.sched_getaffinity(0))
    summary: dict[str, object] = {}
    with idle_polling((cpu,), summary):
        pass
    assert summary["cpus"] == [cpu]
    nothing: dict[str, object] = {}
    with idle_polling((), nothing):
        pass
    assert nothing == {}


@linux_only
def test_a_poller_killed_under_the_run_is_named_in_the_summary_and_a_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # an outside tester killed a poller during a demo: the summary went on naming its CPU as
    # polled, with no word that it was not polled from then on
    cpu = max(os.sched_getaffinity(0))
    summary: dict[str, object] = {}
    with caplog.at_level(logging.WARNING), idle_polling((cpu,), summary) as pollers:
        poller = pollers.pids[cpu]
        os.kill(poller, signal.SIGKILL)
        wait_until(lambda: _state(poller) == "Z", "the killed poller ended")
    assert summary["cpus"] == [cpu] and summary["ended_early"] == [cpu]
    assert f"the poller of CPU {cpu} (killed by SIGKILL) ended before the run did" in caplog.text
    with pytest.raises(ProcessLookupError):
        os.kill(poller, 0)  # reaped: no zombie left behind


@linux_only
def test_pollers_that_lived_to_the_end_are_not_named_as_ended(caplog: pytest.LogCaptureFixture) -> None:
    cpu = max(os.sched_getaffinity(0))
    summary: dict[str, object] = {}
    with caplog.at_level(logging.WARNING), idle_polling((cpu,), summary):
        pass
    assert "ended_early" not in summary and "ended before" not in caplog.text
    assert isinstance(summary["cpu_s"], float) and summary["cpu_s"] >= 0.0


@dataclasses.dataclass(frozen=True)
class MachineFiles:
    """Stand-ins for /proc/cpuinfo and the cpuidle files, as the guests and machines below have them."""

    guest: Path  # cpuinfo with the hypervisor flag
    metal: Path  # cpuinfo without it
    none: Path  # current_driver: no cpuidle driver
    haltpoll: Path  # current_driver: haltpoll
    polls: Path  # haltpoll's poll window: 200 us
    never: Path  # haltpoll's poll window: 0, never polls


def _machine_files(tmp_path: Path) -> MachineFiles:
    contents = {
        "guest": "processor\t: 0\nflags\t\t: fpu vme de pse hypervisor lahf_lm\n",
        "metal": "processor\t: 0\nflags\t\t: fpu vme de pse lahf_lm\n",
        "none": "none\n",
        "haltpoll": "haltpoll\n",
        "polls": "200000\n",
        "never": "0\n",
    }
    for name, text in contents.items():
        (tmp_path / name).write_text(text)
    return MachineFiles(**{name: tmp_path / name for name in contents})


def test_a_guest_that_halts_at_once_is_known_by_its_cpus_and_its_cpuidle_driver(tmp_path: Path) -> None:
    m = _machine_files(tmp_path)
    assert on_virtual_machine(str(m.guest))
    assert not on_virtual_machine(str(m.metal))
    assert not on_virtual_machine(str(tmp_path / "missing"))
    assert halts_when_idle(str(m.guest), str(m.none))
    assert halts_when_idle(str(m.guest), str(tmp_path / "no cpuidle"))
    assert not halts_when_idle(str(m.guest), str(m.haltpoll), str(m.polls))  # it polls before it halts
    assert halts_when_idle(str(m.guest), str(m.haltpoll), str(m.never))  # told not to poll: halts at once
    # a window that cannot be read: unknown, left alone
    assert not halts_when_idle(str(m.guest), str(m.haltpoll), str(tmp_path / "no window"))
    assert not halts_when_idle(str(m.metal), str(m.none))  # a machine of its own: --cpu-latency-us


def test_a_guest_that_halts_is_kept_polling_by_the_latency_limit_where_its_kernel_has_a_polling_state(
    tmp_path: Path,
) -> None:
    m = _machine_files(tmp_path)
    poll_state, halt_state = tmp_path / "POLL", tmp_path / "haltpoll idle"
    poll_state.write_text("POLL\n")
    halt_state.write_text("haltpoll idle\n")
    writable = tmp_path / "cpu_dma_latency"
    writable.write_bytes(b"")
    read_only = tmp_path / "read-only"
    read_only.write_bytes(b"")

    def remedy(cpus: Path, driver: Path, window: Path, first_state: Path, qos: Path) -> IdleRemedy:
        return idle_remedy(str(cpus), str(driver), str(window), str(first_state), str(qos))

    # the development VM's image of 2026-12-04: haltpoll told not to poll, its POLL state first
    assert remedy(m.guest, m.haltpoll, m.never, poll_state, writable) is IdleRemedy.LATENCY_LIMIT
    # the device not writable (a service without root): the pollers, not a refusal at every start
    read_only.chmod(0o444)
    if not os.access(read_only, os.W_OK):  # root may write anything: the case is not made there
        assert remedy(m.guest, m.haltpoll, m.never, poll_state, read_only) is IdleRemedy.POLLERS
    assert remedy(m.guest, m.haltpoll, m.never, tmp_path / "no such state", writable) is IdleRemedy.POLLERS
    # no POLL state first
    assert remedy(m.guest, m.haltpoll, m.never, halt_state, writable) is IdleRemedy.POLLERS
    assert remedy(m.guest, m.haltpoll, m.never, poll_state, tmp_path / "no PM QoS") is IdleRemedy.POLLERS
    # no cpuidle driver: the limit changes nothing, the pollers
    assert remedy(m.guest, m.none, m.never, tmp_path / "no such state", writable) is IdleRemedy.POLLERS
    # a guest that polls before it halts, and a machine of its own: left alone
    assert remedy(m.guest, m.haltpoll, m.polls, poll_state, writable) is IdleRemedy.NONE
    assert remedy(m.metal, m.haltpoll, m.never, poll_state, writable) is IdleRemedy.NONE


def test_the_defaults_keep_a_halting_guest_polling_and_the_options_say_otherwise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import controller.realtime as realtime

    parse = build_parser().parse_args
    monkeypatch.setattr(realtime, "idle_remedy", lambda: IdleRemedy.POLLERS)
    default = _realtime(parse(["demo"]))
    assert default.idle_poll and default.cpu_latency_us is None and default.priority is not None
    assert not _realtime(parse(["demo"]), simulator=True).idle_poll  # the controller polls for both
    assert _realtime(parse(["demo", "--no-idle-poll"])) == dataclasses.replace(default, idle_poll=False)
    assert "--idle-poll" in RealtimeOptions(idle_poll=True).cli_args()
    monkeypatch.setattr(realtime, "idle_remedy", lambda: IdleRemedy.LATENCY_LIMIT)
    limited = _realtime(parse(["demo"]))
    assert limited.cpu_latency_us == 0 and not limited.idle_poll
    assert _realtime(parse(["demo"]), simulator=True).cpu_latency_us == 0  # the simulator holds it too
    # --no-idle-poll: the CPUs left to halt, either way; --idle-poll: the pollers in place of the limit
    assert _realtime(parse(["demo", "--no-idle-poll"])) == dataclasses.replace(limited, cpu_latency_us=None)
    assert _realtime(parse(["demo", "--idle-poll"])) == dataclasses.replace(
        limited, cpu_latency_us=None, idle_poll=True
    )
    monkeypatch.setattr(realtime, "idle_remedy", lambda: IdleRemedy.NONE)
    nothing = _realtime(parse(["demo"]))
    assert not nothing.idle_poll and nothing.cpu_latency_us is None
    # alone, --idle-poll changes the defaults; beside explicit options it is one of them
    assert _realtime(parse(["demo", "--idle-poll"])) == dataclasses.replace(nothing, idle_poll=True)
    assert _realtime(parse(["run", "--rt-priority", "80", "--idle-poll"])) == RealtimeOptions(
        priority=80, idle_poll=True
    )
    with pytest.raises(RealtimeError, match="contradict"):
        _realtime(parse(["demo", "--idle-poll", "--no-idle-poll"]))
    with pytest.raises(RealtimeError, match="--no-realtime cannot be combined"):
        _realtime(parse(["demo", "--no-realtime", "--idle-poll"]))
    with pytest.raises(RealtimeError, match="--idle-poll is the controller's"):
        _realtime(parse(["sim", "--idle-poll"]), simulator=True)
    with pytest.raises(RealtimeError, match="--no-idle-poll is the controller's"):  # accepted, unsaid
        _realtime(parse(["sim", "--no-idle-poll"]), simulator=True)


def test_real_time_options_are_refused_in_simulated_time_not_ignored(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Given explicitly, a real-time option is required; `demo --simulated-time` ignored them all."""
    from controller.cli import main

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    code = main(["demo", "--simulated-time", "--idle-poll", "--cpu-shield", "--rt-priority", "50"])
    err = capsys.readouterr().err
    assert code == 2
    assert (
        "--rt-priority, --cpu-shield, --idle-poll: --simulated-time runs the loop on a simulated clock" in err
    )
    assert main(["demo", "--simulated-time", "--cpu-latency-us", "0"]) == 2  # 0 is given, not absent
    assert "--cpu-latency-us: --simulated-time" in capsys.readouterr().err


def _halts_entered() -> int:
    """How often the machine's CPUs entered an idle state other than the kernel's polling one."""
    total = 0
    for state in Path("/sys/devices/system/cpu").glob("cpu[0-9]*/cpuidle/state[0-9]*"):
        if (state / "name").read_text().strip() != "POLL":
            total += int((state / "usage").read_text())
    return total


@pytest.mark.skipif(
    idle_remedy() is not IdleRemedy.LATENCY_LIMIT,
    reason="the default's latency limit is this guest's remedy only",
)
def test_under_the_default_latency_limit_no_cpu_halts() -> None:
    """The premise of the default (controller.realtime.idle_remedy): with the limit of 0 held, the
    governor keeps every idle CPU in its POLL state (without it, this guest's CPUs halted 31-70
    times in 2 s). A CPU deciding to halt as the limit came may enter once."""
    fd = hold_cpu_latency(0)
    try:
        before = _halts_entered()
        time.sleep(0.5)  # the window the halts are counted over, not a wait for something
        entered = _halts_entered() - before
    finally:
        os.close(fd)
    assert entered <= os.cpu_count(), f"{entered} halts under a latency limit of 0"


def test_options_only_a_run_over_the_bus_has_are_refused_in_simulated_time_not_ignored(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its bus, its recording's live views, its Zenoh session: `demo --simulated-time` took each and
    ignored it without a word (an outside tester, 2026-12-06)."""
    from controller.cli import main

    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    code = main(["demo", "--simulated-time", "--bus", "virtual:x", "--foxglove", "--udp-port", "-1"])
    err = capsys.readouterr().err
    assert code == 2
    assert "--bus, --udp-port, --foxglove: --simulated-time runs the devices in this process" in err
    for option in (["--zenoh-connect", "tcp/127.0.0.1:7447"], ["--robot-id", "r1"], ["--rerun"], ["--fd"]):
        assert main(["demo", "--simulated-time", *option]) == 2, option
        assert f"{option[0]}: --simulated-time runs the devices" in capsys.readouterr().err
