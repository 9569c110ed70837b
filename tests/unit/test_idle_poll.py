"""Idle polling (controller/shell/idle_poll.py): a SCHED_IDLE poller per CPU while the loop runs,
ended by its process id, or by itself once the process that started it is gone."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from controller.cli import _realtime, build_parser
from controller.realtime import RealtimeError, RealtimeOptions, on_virtual_machine
from controller.shell.idle_poll import POLLER_SOURCE, IdlePollers, idle_polling

ROOT = Path(__file__).resolve().parents[2]
linux_only = pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="SCHED_IDLE is Linux's")


def _wait_for(condition, what: str, limit_s: float = 60.0) -> None:
    """Until ``condition()`` holds; the limit only ends a test that would hang, it times nothing."""
    end = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"not within {limit_s} s: {what}")
        time.sleep(0.01)


@linux_only
def test_a_poller_spins_at_sched_idle_on_its_cpu_and_stop_ends_it_by_pid() -> None:
    cpu = max(os.sched_getaffinity(0))
    pollers = IdlePollers((cpu,))
    pollers.start()
    try:
        pid = pollers.pids[cpu]
        _wait_for(lambda: os.sched_getaffinity(pid) == {cpu}, "the poller pinned to its CPU")
        assert os.sched_getscheduler(pid) == os.SCHED_IDLE  # taken before its CPU
        assert pollers.cpu_s() >= 0.0
    finally:
        pollers.stop()
    assert not pollers.pids
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # ended and reaped


@linux_only
def test_a_cpu_the_kernel_refuses_ends_its_poller_with_the_reason() -> None:
    result = subprocess.run(
        [sys.executable, "-I", "-S", "-c", POLLER_SOURCE, "4096", str(os.getpid())],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 1
    assert "idle poller: CPU 4096:" in result.stderr


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


@linux_only
def test_the_block_polls_the_cpus_it_is_given_and_none_when_given_none() -> None:
    cpu = max(os.sched_getaffinity(0))
    summary: dict[str, object] = {}
    with idle_polling((cpu,), summary):
        pass
    assert summary["cpus"] == [cpu] and isinstance(summary["cpu_s"], float)
    nothing: dict[str, object] = {}
    with idle_polling((), nothing):
        pass
    assert nothing == {}


def test_a_virtual_machine_is_known_by_its_cpus_hypervisor_flag(tmp_path: Path) -> None:
    guest = tmp_path / "guest"
    guest.write_text("processor\t: 0\nflags\t\t: fpu vme de pse hypervisor lahf_lm\n")
    metal = tmp_path / "metal"
    metal.write_text("processor\t: 0\nflags\t\t: fpu vme de pse lahf_lm\n")
    assert on_virtual_machine(str(guest))
    assert not on_virtual_machine(str(metal))
    assert not on_virtual_machine(str(tmp_path / "missing"))


def test_the_defaults_poll_on_a_virtual_machine_and_the_options_say_otherwise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import controller.realtime as realtime

    parse = build_parser().parse_args
    monkeypatch.setattr(realtime, "on_virtual_machine", lambda: True)
    assert _realtime(parse(["demo"])).idle_poll
    assert not _realtime(parse(["demo"]), simulator=True).idle_poll  # the controller polls for both
    assert not _realtime(parse(["demo", "--no-idle-poll"])).idle_poll
    assert _realtime(parse(["run", "--idle-poll"])) == RealtimeOptions(idle_poll=True)
    assert "--idle-poll" in RealtimeOptions(idle_poll=True).cli_args()
    monkeypatch.setattr(realtime, "on_virtual_machine", lambda: False)
    assert not _realtime(parse(["demo"])).idle_poll
    with pytest.raises(RealtimeError, match="contradict"):
        _realtime(parse(["demo", "--idle-poll", "--no-idle-poll"]))
    with pytest.raises(RealtimeError, match="--no-realtime cannot be combined"):
        _realtime(parse(["demo", "--no-realtime", "--idle-poll"]))
