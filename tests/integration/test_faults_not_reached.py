"""Injected faults that inject nothing are said, not passed over (an outside tester's).

``--inject force=100@200`` in a 70-s demo, and ``stall=`` over the bus (the simulator process
cannot hold a loop that runs on its own clock), injected nothing and the run ended DONE, exit 0,
as if the fault had been met. Now the summary names the faults the run ended before
(``faults_not_reached``, and a note on stderr), and ``stall`` over a bus is refused at start. A
fault the run reached that was active at no SYNC injected nothing either (``faults_missed``).
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys

import pytest
from busy_machine import TOLERANT

pytestmark = pytest.mark.integration
NOT_REACHED_NOTE = (
    "note: the run ended before 1 injected fault(s) began, and they injected nothing: force=5@900"
)


def _cheope(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "controller", *args],
        capture_output=True,
        text=True,
        timeout=240.0,
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _path_demo(*args: str) -> subprocess.CompletedProcess[str]:
    return _cheope(
        "demo",
        "--task",
        "path",
        "--json",
        "--set",
        "task.path.laps=0.5",
        "--set",
        "monitoring.enabled=false",
        "--set",
        "recording.enabled=false",
        *args,
    )


def test_in_simulated_time_the_faults_after_the_end_are_named_and_the_others_not():
    r = _path_demo("--simulated-time", "--inject", "force=5@900", "--inject", "force=1@0.5+0.1")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["final_mode"] == "DONE" and s["faults_not_reached"] == ["force=5@900"]
    assert NOT_REACHED_NOTE in r.stderr
    reached = _path_demo("--simulated-time", "--inject", "force=1@0.5+0.1")
    assert "faults_not_reached" not in json.loads(reached.stdout) and "injected nothing" not in reached.stderr


def test_over_the_bus_the_simulator_names_the_faults_after_the_end():
    port = str(random.SystemRandom().randint(45000, 47999))
    r = _path_demo("--inject", "force=5@900", "--inject", "force=1@0.5+0.1", "--udp-port", port, *TOLERANT)
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["final_mode"] == "DONE" and s["faults_not_reached"] == ["force=5@900"]
    assert "faults_not_reached" not in s["simulator"]
    assert NOT_REACHED_NOTE in r.stderr


def test_in_simulated_time_stalls_on_the_cycle_grid_hold_the_loop_and_a_fault_no_sync_fell_in_is_named():
    # at 0 s the first deadline came before the schedule's first SYNC, and at 0.005 s its SYNC
    # read 0.004999999999999999: both stalls held nothing, and nothing said so (an outside tester)
    for stall in ("stall=0.02@0+0.0025", "stall=0.02@0.005+0.0025"):
        r = _path_demo("--simulated-time", "--inject", stall)
        assert r.returncode == 0, r.stderr
        s = json.loads(r.stdout)
        assert s["final_mode"] == "DONE" and s["overruns"] >= 7, stall  # 20 ms: 7 or 8 deadlines
        assert "faults_missed" not in s and "injected nothing" not in r.stderr
    # a drop inside a stall: no SYNC goes while the loop is held up, and the drop injects nothing
    r = _path_demo("--simulated-time", "--inject", "stall=0.02@0.5+0.0025", "--inject", "drop:1@0.505+0.0025")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["overruns"] >= 7 and s["faults_missed"] == ["drop:1@0.505+0.0025"]
    assert "faults_not_reached" not in s
    assert (
        "note: 1 injected fault(s) were active at no SYNC (no SYNC fell in their window, or no device "
        "asked for them then), and they injected nothing: drop:1@0.505+0.0025"
    ) in r.stderr


@pytest.mark.parametrize("command", [["demo"], ["sim", "--udp-port", "45999"]])
def test_a_stall_over_a_bus_is_refused_at_start(command: list[str]):
    r = _cheope(*command, "--inject", "stall=0.002@5", "--set", "monitoring.enabled=false", "--no-realtime")
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert (
        "fault 'stall=0.002@5': stall holds the in-process loop and is injected in simulated time only"
        in r.stderr
    )
    assert "cheope-sim ready" not in r.stdout  # no simulator started
