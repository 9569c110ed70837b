"""The CPU shield (controller/shell/cpu_shield.py): normal tasks kept off the loop's CPU while a
run lasts, and given back after it, however it ends.

Each scenario runs in a PID namespace the test creates (tests/cpu_shield_scenarios.py): the sweep
there meets the scenario's own processes and nothing else of the machine. Needs root (a PID
namespace) and two CPUs.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from controller.cli import _realtime, build_parser
from controller.realtime import RealtimeError, RealtimeOptions
from controller.shell.cpu_shield import GUARDIAN_PRIORITY

SCENARIOS = Path(__file__).resolve().parents[1] / "cpu_shield_scenarios.py"


def _unavailable() -> str:
    if os.geteuid() != 0:
        return "a PID namespace needs root"
    if shutil.which("unshare") is None:
        return "no unshare command (util-linux)"
    if len(os.sched_getaffinity(0)) < 2:
        return "a CPU shield needs two CPUs"
    return ""


needs_namespace = pytest.mark.skipif(bool(_unavailable()), reason=_unavailable() or "available")


def run_scenario(name: str, tmp_path: Path) -> dict[str, Any]:
    done = subprocess.run(
        ["unshare", "--pid", "--fork", "--mount-proc", sys.executable, str(SCENARIOS), name, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, Any] = json.loads(done.stdout.splitlines()[-1])
    return result


@needs_namespace
def test_normal_tasks_leave_the_loops_cpu_and_get_it_back(tmp_path: Path) -> None:
    out = run_scenario("restore_after_close", tmp_path)
    everything, loop = out["all"], out["loop_cpu"]
    others = [c for c in everything if c != loop]
    assert out["before"]["spawner"] == everything
    assert out["during"]["spawner"] == others  # swept
    assert out["during"]["children"] == [others]  # born under the shield: inherited it
    assert out["during"]["pinned"] == [everything[0]]  # it never ran on the loop's CPU
    assert out["during"]["fifo"] == everything  # real-time: its placement is deliberate
    assert out["state_file_during"]
    assert out["after"] == {
        "spawner": everything,
        "pinned": [everything[0]],
        "fifo": everything,
        "children": [everything],
    }
    assert not out["state_file_after"]
    assert out["summary"]["tasks_moved"] >= 1 and out["summary"]["tasks_restored"] >= 2


@needs_namespace
def test_the_guardian_runs_above_every_normal_task_and_off_the_loops_cpu(tmp_path: Path) -> None:
    # under the normal scheduler, a machine busy with normal work starved it past its start timeout
    # (64 threads sleeping 50 µs each: the loop ran unshielded, the killed guardian took minutes to end)
    out = run_scenario("guardian_priority", tmp_path)
    assert out["policy"] == os.SCHED_FIFO
    assert out["priority"] == GUARDIAN_PRIORITY
    assert out["loop_cpu"] not in out["cpus"]
    assert out["summary"]["guardian_scheduling"] == f"SCHED_FIFO {GUARDIAN_PRIORITY}"
    assert out["summary"]["tasks_restored"] is not None  # it answered its restore


@needs_namespace
def test_a_guardian_refused_its_priority_still_shields_and_says_so(tmp_path: Path) -> None:
    out = run_scenario("guardian_priority_refused", tmp_path)
    assert out["policy"] == os.SCHED_OTHER
    assert out["loop_cpu"] not in out["cpus"]  # it moves itself off the loop's CPU as before
    assert out["summary"]["guardian_scheduling"].startswith("normal scheduler (SCHED_FIFO 1 refused")
    assert out["summary"]["tasks_restored"] is not None


@needs_namespace
def test_a_guardian_starved_by_a_real_time_task_is_ended_without_waiting_for_that_task(
    tmp_path: Path,
) -> None:
    # at priority 1, pinned beside a busy SCHED_FIFO task, it never runs: ended under the normal
    # scheduler on every CPU, it exits while the busy task still burns
    out = run_scenario("guardian_beside_a_busy_realtime_task", tmp_path)
    assert "did not answer" in out["start"] and "SCHED_FIFO 1" in out["start"]
    assert out["busy_still_burning"]


@needs_namespace
def test_a_killed_controller_leaves_no_shield_behind(tmp_path: Path) -> None:
    out = run_scenario("controller_killed", tmp_path)
    assert out["during"]["spawner"] != out["all"]
    assert out["after"]["spawner"] == out["all"]
    assert not out["state_file_after"]


@needs_namespace
def test_a_killed_guardians_tasks_are_given_back_at_the_end_or_by_the_next(tmp_path: Path) -> None:
    out = run_scenario("guardian_killed", tmp_path)
    assert out["after_kill"]["spawner"] != out["all"]  # nobody restored it
    assert out["state_file_after_kill"]
    # the controller's close names the guardian's end and gives back what it took
    summary = out["close_summary"]
    assert summary["guardian_failed"] == "killed by SIGKILL under the run"
    assert summary["tasks_restored"] >= 1
    assert out["after_close"]["spawner"] == out["all"] and not out["state_file_after_close"]
    # a guardian killed with its controller: the next one gives them back when it starts
    assert out["after_second_kill"]["spawner"] != out["all"]
    assert out["recovered"] >= 1
    assert out["during_third"]["spawner"] != out["all"]  # and the third shield holds
    assert out["after"]["spawner"] == out["all"]


@needs_namespace
def test_a_guardian_killed_in_the_middle_of_its_sweep_leaves_no_task_behind(tmp_path: Path) -> None:
    """Its state file used to be written after the sweep: killed in between, the tasks it had moved
    stayed off the loop's CPU with nothing to say so (a machine found with its first process on
    one CPU of two after an outside tester's runs)."""
    out = run_scenario("guardian_killed_mid_sweep", tmp_path)
    everything, moved = out["all"], [c for c in out["all"] if c != max(out["all"])]
    # the controller that started it is told, and gives back the one task it had moved at once
    assert "did not answer" in out["start"] and "killed by SIGKILL" in out["start"], out["start"]
    assert out["start"].endswith("tasks it had moved given back: 1"), out["start"]
    assert out["after_start"]["spawner"] == everything
    assert out["after_start"]["children"] == [everything, everything]
    assert not out["state_file_after_start"]
    # killed with its controller: one task moved, the others not, and the file says which
    assert out["dying_exit"] == -9 and out["dying_answer"] == ""
    masks = [out["after_kill"]["spawner"], *out["after_kill"]["children"]]
    assert sorted(masks) == sorted([moved, everything, everything]), masks
    assert out["state_file_after_kill"]
    # the next run, one without a shield of its own too, gives it back
    assert out["summary"]["recovered_from_a_dead_guardian"] == 1, out["summary"]
    assert out["after"]["spawner"] == everything and out["after"]["children"] == [everything, everything]
    assert not out["state_file_after"]


@needs_namespace
def test_a_stopped_guardians_tasks_are_given_back_at_the_end(tmp_path: Path) -> None:
    """An outside tester's SIGSTOP to the guardian left every task of the machine on one CPU."""
    out = run_scenario("guardian_stopped", tmp_path)
    assert out["during"]["spawner"] != out["all"]
    summary = out["close_summary"]
    assert summary["guardian_failed"] == "no answer within 1 s (stopped?), then killed by SIGKILL"
    assert summary["tasks_restored"] >= 1
    assert out["after"]["spawner"] == out["all"] and not out["state_file_after"]


@needs_namespace
def test_one_shield_a_machine(tmp_path: Path) -> None:
    out = run_scenario("one_a_machine", tmp_path)
    assert "already held" in out["second"] and "pid " in out["second"]
    assert out["best_effort_shield"] is False
    assert "already held" in out["best_effort_summary"]["off"]
    assert out["required"].startswith("--cpu-shield: ")


@needs_namespace
def test_a_busy_real_time_task_on_the_loops_cpu_is_named(tmp_path: Path) -> None:
    """A real-time task the shield may not move, busy on the loop's CPU, spends the CPU's real-time
    budget for the loop too (controller/shell/realtime_neighbours.py): the summary names it."""
    out = run_scenario("realtime_neighbours", tmp_path)
    named = out["summary"]["realtime_neighbours"]
    assert [n["pid"] for n in named] == [out["pids"]["busy"]]  # not the sleeper, the normal, the own
    (busy,) = named
    assert busy["policy"] == "SCHED_FIFO" and busy["priority"] == 1 and busy["name"].startswith("python")
    assert busy["cpu_s"] >= 0.45  # 0.5 s burnt, in clock ticks


@needs_namespace
def test_a_process_tracing_the_controller_is_named(tmp_path: Path) -> None:
    """A tracer holds the loop up at every system call (controller/shell/tracer_watch.py): the summary
    names it."""
    out = run_scenario("traced", tmp_path)
    assert out["seized"] == ["0", "0"]  # ptrace attached
    (tracer,) = out["summary"]["tracers"]
    assert tracer["pid"] == out["tracer"] and tracer["name"].startswith("python") and tracer["looks"] >= 1


@needs_namespace
def test_a_child_forked_while_the_sweep_runs_gets_the_cpu_back(tmp_path: Path) -> None:
    out = run_scenario("forked_during_sweep", tmp_path)
    assert out["during"]["spawner"] != out["all"]  # swept
    assert out["during"]["children"] == [out["during"]["spawner"]]  # inherited it
    assert out["after"]["children"] == [out["all"]] and out["after"]["spawner"] == out["all"]


@needs_namespace
def test_the_guardian_restores_before_it_ends_on_a_signal(tmp_path: Path) -> None:
    out = run_scenario("ending_signals", tmp_path)
    for name in ("SIGTERM", "SIGHUP"):
        assert out[name]["during"] != out[name]["all"], name
        assert out[name]["after"] == out[name]["all"], name
        assert not out[name]["state_file_after"], name


@needs_namespace
def test_bad_state_files_cost_the_shield_nothing(tmp_path: Path) -> None:
    out = run_scenario("bad_state_files", tmp_path)
    for name in ("garbage", "nested", "huge cpu", "stale"):
        assert out[name]["recovered"] == 0, name  # the stale record names pid 1 of another boot: untouched
        assert out[name]["summary"]["tasks_restored"] is not None, name
        assert not out[name]["state_file_after"], name
    assert "not a directory of this user's alone" in out["foreign"]


def test_the_default_options_shield_the_loops_cpu(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    parse = build_parser().parse_args
    default = _realtime(parse(["demo"]))
    assert default.shield and default.cpus == (1,)
    assert not _realtime(parse(["demo"]), simulator=True).shield  # the simulator never shields
    assert not _realtime(parse(["demo", "--no-cpu-shield"])).shield
    assert _realtime(parse(["demo", "--cpu", "1", "--cpu-shield"])) == RealtimeOptions(cpus=(1,), shield=True)
    with pytest.raises(RealtimeError, match="--cpu-shield needs --cpu"):
        _realtime(parse(["demo", "--cpu-shield"]))
    with pytest.raises(RealtimeError, match="contradict"):
        _realtime(parse(["demo", "--cpu-shield", "--no-cpu-shield", "--cpu", "1"]))
    with pytest.raises(RealtimeError, match="--no-realtime cannot be combined"):
        _realtime(parse(["demo", "--no-realtime", "--cpu-shield"]))


def test_a_confined_process_says_why_it_has_no_shield(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Started from a shell left on one CPU (a stopped guardian's), a demo ran its loop and its
    simulator on that CPU with ``cpu_shield`` empty."""
    from controller.shell import cpu_shield

    monkeypatch.setattr(cpu_shield.os, "sched_getaffinity", lambda _pid: {0})
    monkeypatch.setattr(cpu_shield.os, "cpu_count", lambda: 2)
    summary: dict[str, Any] = {}
    with cpu_shield.raise_shield(RealtimeOptions(cpus=(), shield=False), summary, tmp_path) as shield:
        assert shield is None
    assert summary["off"].startswith("this process may run on CPU 0 only, of the machine's 2")
    monkeypatch.setattr(cpu_shield.os, "sched_getaffinity", lambda _pid: {0, 1})
    summary = {}
    with cpu_shield.raise_shield(RealtimeOptions(cpus=(), shield=False), summary, tmp_path):
        pass
    assert summary == {}  # --no-cpu-shield on a free process: nothing to say


def test_a_process_confined_by_another_controllers_shield_names_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A second controller started beside a running one finds its shell kept off the first's loop
    CPU: it named "taskset, or a CPU shield not given back". It now names the shield that holds the
    CPU, from the lock file its guardian wrote, while that guardian lives; not after."""
    from controller.shell import cpu_shield

    monkeypatch.setattr(cpu_shield.os, "sched_getaffinity", lambda _pid: {0})
    monkeypatch.setattr(cpu_shield.os, "cpu_count", lambda: 2)
    # a stand-in guardian: a live process whose command line is the guardian's module, read once it
    # runs (between its fork and its exec, its command line was still pytest's: a CI run failed so)
    guardian = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import time; print(flush=True); time.sleep(60)",
            "controller.shell.cpu_shield",
        ],
        stdout=subprocess.PIPE,
    )
    try:
        assert guardian.stdout is not None and guardian.stdout.readline() == b"\n"
        (tmp_path / cpu_shield.LOCK_NAME).write_text(f"pid {guardian.pid}, CPUs 1\n")
        off = cpu_shield.confined_affinity(tmp_path)
        assert off == (
            "this process may run on CPU 0 only, of the machine's 2 (another controller's CPU shield "
            f"keeps CPU 1 clear for its loop (its guardian: pid {guardian.pid}))"
        )
        # a live guardian's pid beside what no guardian writes: nothing of it printed
        (tmp_path / cpu_shield.LOCK_NAME).write_text(f"pid {guardian.pid}, CPUs 1\x1b[2J")
        assert "another controller" not in cpu_shield.confined_affinity(tmp_path)
    finally:
        guardian.kill()
        guardian.communicate()
    for stale in (f"pid {guardian.pid}, CPUs 1\n", "pid ?, CPUs 1", "", f"pid {os.getpid()}, CPUs 1"):
        (tmp_path / cpu_shield.LOCK_NAME).write_text(stale)  # gone, unreadable, or not a guardian
        assert cpu_shield.confined_affinity(tmp_path).endswith(
            "(its affinity, inherited: taskset, or a CPU shield not given back)"
        )
