"""Gaps in each CPU's kernel events beside a run's hold-ups (controller/tools/bench/machine_pauses.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from waiting import GENEROUS_S, wait_for_exit, wait_until

from controller.config import load_config
from controller.shell.simulated_rig import SimulatedRig
from controller.tools.bench import machine_pauses as mp
from logs.recorder import SessionRecorder, session_metadata

# three events of CPU 1 as tracefs prints them (trace_clock mono), and a line that is no event
TRACE = """\
# tracer: nop
          <idle>-0       [001] d.h2. 20695.364001: hrtimer_expire_entry: hrtimer=0000 function=tick_nohz_handler now=1
   python3-1234    [001] d.s1. 20695.364500: softirq_entry: vec=3 [action=NET_RX]
     cheope-77     [001] d..2. 20695.388800: sched_switch: prev_comm=cheope prev_pid=77 prev_prio=19 prev_state=S ==> next_comm=swapper/1 next_pid=0 next_prio=120
"""


def test_the_events_of_a_trace_are_read_in_the_kernels_clock_and_sorted():
    cpu = mp.read_cpu_trace(reversed(TRACE.splitlines()))
    assert cpu.times == [20695.364001, 20695.3645, 20695.3888]
    assert cpu.switches == [mp.Switch(20695.3888, "swapper/1-0", 0)]


def test_what_ran_on_a_cpu_in_a_span_is_each_tasks_time_there_the_idle_task_aside():
    switches = [
        mp.Switch(1.000, "cheope-77", 77),
        mp.Switch(1.002, "swapper/1-0", 0),
        mp.Switch(1.004, "ksoftirqd/1-24", 24),
        mp.Switch(1.0041, "cheope-77", 77),
        mp.Switch(1.010, "swapper/1-0", 0),
    ]
    ran = mp.ran_during(switches, 1.001, 1.012)
    assert ran.keys() == {"cheope-77", "ksoftirqd/1-24"}
    assert ran["cheope-77"] == pytest.approx(0.001 + 0.0059)
    assert ran["ksoftirqd/1-24"] == pytest.approx(0.0001)
    # a span inside one task's run, and one after the last switch, where the task runs on
    assert mp.ran_during(switches, 1.005, 1.006) == {"cheope-77": pytest.approx(0.001)}
    assert mp.ran_during(switches[:2], 1.0, 1.001) == {"cheope-77": pytest.approx(0.001)}
    assert mp.ran_during(switches, 1.011, 1.02) == {}


def test_a_gap_is_a_span_without_events_longer_than_the_least_and_within_the_run():
    times = [0.0, 0.004, 0.012, 0.014, 0.05, 0.051, 1.0]
    gaps = mp.gaps_of(1, times, 0.006, (0.001, 0.9))
    # 8 ms and 36 ms; the 949 ms that outlast the run (an idle CPU takes no tick) are left out
    assert [(g.start_s, round(g.length_s, 6)) for g in gaps] == [(0.004, 0.008), (0.014, 0.036)]
    assert mp.gaps_of(1, times, 0.04, (0.0, 2.0)) == [mp.Gap(1, 0.051, 0.949)]


def test_the_machine_stood_where_every_cpu_was_in_a_gap_at_once():
    gaps = {
        0: [mp.Gap(0, 1.000, 0.032), mp.Gap(0, 2.0, 0.01)],
        1: [mp.Gap(1, 1.008, 0.024), mp.Gap(1, 3.0, 0.01)],  # CPU 1's second gap alone: no pause of both
    }
    both = mp.all_at_once(gaps)
    assert [(g.cpu, g.start_s, round(g.length_s, 6)) for g in both] == [(-1, 1.008, 0.024)]
    assert mp.all_at_once({}) == []
    alone = mp.all_at_once({1: gaps[1]})  # one CPU: its own gaps
    assert [(g.start_s, round(g.length_s, 6)) for g in alone] == [(1.008, 0.024), (3.0, 0.01)]


def test_a_hold_up_meets_the_gaps_that_overlap_it_only():
    hold = mp.HoldUp(cycle=10, t_s=0.025, skipped=4, wake_error_s=0.0, start_s=1.0, end_s=1.015)
    gaps = [mp.Gap(0, 0.9, 0.05), mp.Gap(1, 1.002, 0.011), mp.Gap(0, 1.014, 0.01), mp.Gap(1, 1.015, 0.01)]
    assert mp.overlapping(hold, gaps) == [gaps[1], gaps[2]]


def _record_stalled_run(path: Path, stall: str) -> None:
    """The path task's start in simulated time, the loop held up where ``stall`` says."""
    rig = SimulatedRig(load_config(overrides={"sim.faults": [stall]}))
    with SessionRecorder(
        path, session_metadata(rig.cfg), clock=rig.clock.clock, phase_name=rig.law.task.phase_name
    ) as rec:
        rig.run((rec,), 1.0)


def test_a_recordings_hold_ups_come_on_the_loops_own_clock(tmp_path):
    """The loop held up 12 ms at 0.5 s (4 deadlines skipped at 400 Hz): one hold-up (the cycle of 0.51 s, the latest deadline passed), and the span it
    covers on the recording's monotonic clock holds the 12 ms, so a trace's gap there meets it."""
    path = tmp_path / "stalled.mcap"
    _record_stalled_run(path, "stall=0.012@0.5+0.0025")
    recorded = mp.recorded_run(str(path))
    holds = recorded.hold_ups
    assert [(h.skipped, round(h.t_s, 4)) for h in holds] == [(4, 0.51)]
    h = holds[0]
    assert h.end_s - h.start_s >= 0.012
    assert recorded.start_s < h.start_s < h.end_s < recorded.end_s
    stall_gap = mp.Gap(1, h.end_s - 0.013, 0.012)  # what a trace shows of the host taking 12 ms
    assert mp.overlapping(h, [stall_gap, mp.Gap(1, h.end_s + 1.0, 0.012)]) == [stall_gap]


def test_no_command_or_no_trace_is_a_clear_error(capsys, monkeypatch, tmp_path):
    with pytest.raises(SystemExit):
        mp.main(["--json"])
    assert "no command" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mp.main(["--hogs", "99", "--", "true"])
    assert "--hogs 99: must be 0 .. 16" in capsys.readouterr().err
    # a tracefs that cannot be written (not root, or not mounted): said, and the command not run
    monkeypatch.setattr(mp, "TRACEFS", tmp_path / "absent")
    marker = tmp_path / "ran"
    assert mp.main(["--", sys.executable, "-c", f"open({str(marker)!r}, 'w')"]) == 2
    assert "cannot set up the kernel's trace" in capsys.readouterr().err
    assert not marker.exists()


def _tracefs_here() -> bool:
    """Root, and tracefs mounted or mountable (the tool mounts it itself when it is not)."""
    return os.geteuid() == 0 and mp.tracefs_ready()


@pytest.mark.skipif(not _tracefs_here(), reason="needs root and a kernel with tracefs")
def test_a_command_runs_under_the_trace_and_the_trace_is_left_off(tmp_path):
    # 0.3 s of the command's own CPU time, however busy the machine (the suite's other workers): it
    # takes its scheduler tick throughout, 30 at the least a kernel has (100 Hz)
    report, out = mp.run(
        [
            sys.executable,
            "-c",
            "import os, time\nwhile time.process_time() < 0.3: pass\nprint(os.getpid())",
        ],
        0,
        0.05,
        0.002,
        keep=tmp_path / "trace",
    )
    assert report.returncode == 0
    command_pid = int(out.strip())
    assert sum(c.events for c in report.cpus) >= 30
    kept = {p.name for p in (tmp_path / "trace").iterdir()}
    assert kept == {f"cpu{c.cpu}.txt" for c in report.cpus}
    traces = [mp.read_cpu_trace((tmp_path / "trace" / k).read_text().splitlines()) for k in kept]
    assert sum(len(t.times) for t in traces) == sum(c.events for c in report.cpus)
    # the trace's switches credit the busy command with its CPU time (not "the busiest task": on a
    # busy machine another task may run longer on each CPU than this one did)
    ran_s = sum(
        s
        for t in traces
        for task, s in mp.ran_during(t.switches, *report.run_s).items()
        if task.endswith(f"-{command_pid}")
    )
    assert 0.25 <= ran_s <= report.run_s[1] - report.run_s[0]
    root = Path("/sys/kernel/tracing")
    assert (root / "tracing_on").read_text().strip() == "0"
    assert (root / "set_event").read_text().strip() == ""


@pytest.mark.skipif(not _tracefs_here(), reason="needs root and a kernel with tracefs")
def test_a_sigterm_leaves_the_trace_off_and_the_command_ended(tmp_path):
    pid_file = tmp_path / "command.pid"
    command = f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); time.sleep(60)"
    tool = subprocess.Popen(
        [sys.executable, "-m", "controller.tools.bench.machine_pauses", "--", sys.executable, "-c", command]
    )
    try:
        wait_until(lambda: pid_file.exists() and pid_file.read_text(), "the command started under the trace")
        assert (mp.TRACEFS / "tracing_on").read_text().strip() == "1"
        tool.terminate()
        assert tool.wait(timeout=GENEROUS_S) == 128 + signal.SIGTERM
    finally:
        tool.kill()
        tool.wait()
    assert (mp.TRACEFS / "tracing_on").read_text().strip() == "0"
    assert (mp.TRACEFS / "set_event").read_text().strip() == ""
    wait_for_exit(int(pid_file.read_text()), "the command, ended with the tool")
