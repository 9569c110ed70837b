"""Fast tests of the benchmark's pieces and the real-time options (the bench itself: -m bench)."""

from __future__ import annotations

import ctypes
import errno
import math
import os
import re
import shutil
import struct
import subprocess
import sys

import numpy as np
import pytest

from controller import realtime
from controller.realtime import IdleRemedy, RealtimeError, RealtimeOptions, idle_remedy, parse_cpus
from controller.shell.loop import period_error_us
from controller.tools.bench import (
    compare_pdo_paths,
    compare_sleepers,
    cpu_use_percent,
    late_per_10k,
    naive_loop,
    percentiles_us,
    schedule_stats,
)
from drivers.bus_load import classical_frame_bits, fd_frame_time_s, measured_bus_load


def test_percentiles_of_known_values():
    v = np.arange(1, 1001, dtype=float)  # 1..1000 us
    p = percentiles_us(v)
    assert p["p50"] == pytest.approx(500.5, abs=0.1)
    assert p["p99"] == pytest.approx(990.01, abs=0.1)
    assert p["p99_9"] == pytest.approx(999.0, abs=0.1)
    assert p["max"] == 1000.0
    assert percentiles_us(np.zeros(0)) == {"p50": 0.0, "p99": 0.0, "p99_9": 0.0, "max": 0.0}


def test_period_error_from_wake_times_and_from_wake_errors_agree():
    period = 1e-3
    errors = np.array([0.0, 20e-6, -10e-6, 5e-6])
    wake = np.arange(4) * period + errors
    assert np.allclose(period_error_us(wake, period), [20.0, 30.0, 15.0])
    assert np.allclose(period_error_us(errors, 0.0), [20.0, 30.0, 15.0])


def test_late_cycles_count_threshold_and_overruns():
    period = 1e-3
    wake_error = np.array([0.0, 50e-6, 101e-6, 2e-3] + [0.0] * 96)
    assert late_per_10k(wake_error, period, 0.1) == pytest.approx(1e4 * 2 / 100)
    assert late_per_10k(wake_error, period, 0.1, overruns=4) == pytest.approx(1e4 * 6 / 104)


def test_schedule_stats_sees_drift_of_a_slow_loop():
    period = 1e-3
    wake = np.arange(1001) * 1.05e-3  # every period 50 us too long
    s = schedule_stats(wake, period)
    assert s["achieved_rate_hz"] == pytest.approx(1000 / 1.05, rel=1e-6)
    assert s["drift_ms"] == pytest.approx(50.0, rel=1e-6)
    assert s["period_error_us"]["p50"] == pytest.approx(50.0, abs=0.1)
    # cycle k is k * 50 us late: late (> 100 us) from cycle 3 on
    assert s["late_per_10k"] == pytest.approx(1e4 * 998 / 1000)
    with pytest.raises(ValueError, match="at least 2"):
        schedule_stats(np.zeros(1), period)


def test_naive_loop_drifts_behind_its_schedule():
    period, work = 2e-3, 0.5e-3
    wake = naive_loop(period, 60, work)
    s = schedule_stats(wake, period)
    # work + sleep(period) + oversleep: each period at least ``work`` too long
    assert s["achieved_rate_hz"] < 1.0 / (period + work) * 1.01
    assert s["drift_ms"] > 59 * work * 1e3 * 0.9


@pytest.mark.bench  # wall-clock rates: a figure for the bench, not an assertion for a busy machine
def test_deadline_loop_keeps_the_rate_where_the_naive_one_drifts():
    r = compare_sleepers(2e-3, 0.6, 0.3e-3, 0.3e-3, blocks=2)
    assert abs(r["deadline"]["drift_ms_per_s"]) < abs(r["naive"]["drift_ms_per_s"])
    assert r["naive"]["achieved_rate_hz"] < 0.9 * 500
    assert r["deadline"]["achieved_rate_hz"] == pytest.approx(500, rel=0.02)


def test_cpu_use_from_samples():
    nan = float("nan")
    # (monotonic, loop thread, controller, simulator, writer) [s]; the writer is found after the first sample
    samples = [(10.0, 1.0, 2.0, 3.0, nan), (11.0, 1.2, 2.5, 3.2, 0.5), (12.0, 1.5, 3.0, nan, 0.6)]
    assert cpu_use_percent(samples) == {
        "loop_thread": 25.0,
        "controller_process": 50.0,
        "simulator_process": None,
        "writer_process": 10.0,
    }
    assert cpu_use_percent(samples[:1])["loop_thread"] is None


def test_measured_bus_load_uses_each_frames_own_flags():
    # 1000 classical 6-byte frames and 1000 FD 6-byte frames with BRS in one second
    frames = {0x181: 1000, 0x182: 1000}
    shapes = {0x181: (6, False, False), 0x182: (6, True, True)}
    m = measured_bus_load(frames, shapes, 1.0, 1e6, 5e6)
    expected = 1000 * classical_frame_bits(6) / 1e6 + 1000 * fd_frame_time_s(6, 1e6, 5e6)
    assert m["percent"] == pytest.approx(100 * expected, abs=0.05)
    assert m["classical_frames_per_second"] == 1000.0


def test_project_pdo_path_is_cheaper_than_canopens_pdo_objects():
    r = compare_pdo_paths(300)
    assert r["project_cpu_us"] > 0 and r["canopen_cpu_us"] > 0
    assert r["canopen_over_project"] > 1.0


# -- real-time options ------------------------------------------------------------------------


def test_options_validate_their_values():
    with pytest.raises(RealtimeError, match=re.escape("--rt-priority 0: SCHED_FIFO priorities are 1..99")):
        RealtimeOptions(priority=0)
    with pytest.raises(RealtimeError, match="--cpu -1"):
        RealtimeOptions(cpus=(-1,))
    assert RealtimeOptions().describe() == "none" and not RealtimeOptions().any
    assert (
        RealtimeOptions(priority=80, cpus=(1,), lock_memory=True).describe()
        == "SCHED_FIFO 80, CPU 1, memory locked"
    )


def test_parse_cpus():
    assert parse_cpus("1") == (1,)
    assert parse_cpus("0,2-3") == (0, 2, 3)
    with pytest.raises(RealtimeError, match="expected CPU numbers"):
        parse_cpus("one")
    with pytest.raises(RealtimeError, match=r"--sim-cpu '': expected CPU numbers"):
        parse_cpus("", "--sim-cpu")


def test_an_empty_cpu_list_is_refused_not_taken_for_the_default():
    """``demo --cpu ''`` started a demo with the default affinity."""
    from controller.cli import _realtime, build_parser

    with pytest.raises(RealtimeError, match=r"--cpu '': expected CPU numbers"):
        _realtime(build_parser().parse_args(["demo", "--cpu", ""]))


def test_priority_not_permitted_says_how_to_get_it(monkeypatch):
    def refuse(pid, policy, param):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "geteuid", lambda: 1000)  # root's refusal has its own hint (below)
    with pytest.raises(
        RealtimeError, match=r"--rt-priority 50: SCHED_FIFO not permitted .*CAP_SYS_NICE.*rtprio"
    ):
        realtime.set_fifo_priority(50)


def test_priority_refused_to_root_names_the_cgroup_without_real_time_runtime(monkeypatch, tmp_path):
    """Root refused SCHED_FIFO in a cgroup-v1 group whose cpu.rt_runtime_us is 0 (a new group's
    under the kernel's real-time group scheduling) was told to run as root."""
    group = tmp_path / "cpu" / "cheope"
    group.mkdir(parents=True)
    (group / "cpu.rt_runtime_us").write_text("0\n")
    cgroups = tmp_path / "cgroup"
    cgroups.write_text("4:memory:/\n1:cpu:/cheope\n0::/\n")
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    hint = realtime.priority_hint(str(cgroups), str(tmp_path))
    assert "no real-time runtime" in hint and str(group / "cpu.rt_runtime_us") in hint
    assert "run as root" not in hint
    (group / "cpu.rt_runtime_us").write_text("900000\n")  # runtime there: the container's capability
    assert "SYS_NICE" in realtime.priority_hint(str(cgroups), str(tmp_path))
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    assert realtime.priority_hint(str(cgroups), str(tmp_path)).startswith("run as root")


def test_cpu_outside_the_allowed_set_is_named(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    with pytest.raises(
        RealtimeError, match=r"--cpu 7: CPU 7 is not one this process may use \(allowed: 0,1\)"
    ):
        realtime.set_cpu_affinity((7,))


def test_a_default_cpu_taken_since_the_start_is_not_named_as_an_option(monkeypatch):
    # an outside tester: a demo whose default CPU another demo's shield took between the defaults'
    # choice and the affinity was told "--cpu 1", an option never typed
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    options = realtime.RealtimeOptions.default()
    assert options.cpus == (1,) and options.default_cpus
    assert options.for_simulator().default_cpus
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})  # swept off CPU 1 since
    with pytest.raises(
        RealtimeError, match=r"^the default CPU 1: CPU 1 is not one this process may use any more"
    ):
        realtime.set_cpu_affinity(options.cpus, options.default_cpus)
    assert not realtime.RealtimeOptions(cpus=(1,)).default_cpus


def test_mlockall_not_permitted_says_how_to_get_it(monkeypatch):
    class FakeLibc:
        def mlockall(self, flags):
            assert flags == realtime.MCL_CURRENT | realtime.MCL_FUTURE
            ctypes.set_errno(errno.EPERM)
            return -1

    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(RealtimeError, match=r"--lock-memory: mlockall not permitted .*CAP_IPC_LOCK.*memlock"):
        realtime.lock_memory(FakeLibc())


def test_affinity_applies_to_this_thread_and_restores():
    before = os.sched_getaffinity(0)
    cpu = min(before)
    restore = realtime.apply_realtime(RealtimeOptions(cpus=(cpu,)))
    try:
        assert os.sched_getaffinity(0) == {cpu}
    finally:
        restore()
    assert os.sched_getaffinity(0) == before


def test_cli_refuses_a_bad_rt_option_with_one_line():
    r = subprocess.run(
        [sys.executable, "-m", "controller", "run", "--rt-priority", "120", "--duration", "1"],
        check=False,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].endswith("--rt-priority 120: SCHED_FIFO priorities are 1..99")


def test_bus_frame_cost_measures_both_sides_of_the_udp_bus():
    from controller.tools.bench import bus_frame_cost

    r = bus_frame_cost("udp_multicast", fd=False, frames=200)
    assert r["frames"] == 200 and r["bus"].startswith("udp_multicast")
    for side in ("send_us", "recv_us"):
        assert 0.0 < r[side]["p50"] <= r[side]["p99"] < 100_000.0
    assert 0 <= r["own_frames_received_back"] <= 200


def test_loop_probe_times_the_devices_answer_from_sync_to_the_last_tpdo():
    import can

    from controller.core.ports import CycleTiming
    from controller.tools.bench import LoopProbe
    from drivers import cob_ids

    probe = LoopProbe(4, frozenset({0x181, 0x182}), 0x201, None, sample_every=1000)
    for k, (first, last) in enumerate(((3e-4, 4e-4), (2e-4, 6e-4))):
        t0 = k * 1e-3
        probe.sink(True, t0, can.Message(arbitration_id=cob_ids.SYNC, data=b"", is_extended_id=False))
        probe.sink(False, t0 + first, can.Message(arbitration_id=0x181, data=bytes(6), is_extended_id=False))
        probe.sink(False, t0 + last, can.Message(arbitration_id=0x182, data=bytes(6), is_extended_id=False))
        probe.on_cycle(k, t0, None, None, None, (), CycleTiming(0.0, 1e-4))
    assert probe.answer_s[:2] == pytest.approx([4e-4, 6e-4])


def test_loop_probe_pairs_a_cycle_observed_after_the_next_sync_with_its_own_frames():
    """Over a bus the loop hands cycle k to its observers after cycle k+1's RPDOs and SYNC went
    out (controller/shell/loop.py, step 5): the answer, the step and the next RPDO are still cycle k's."""
    import can

    from controller.core.ports import CycleTiming
    from controller.tools.bench import LoopProbe
    from drivers import cob_ids

    def frame(cob_id: int) -> can.Message:
        return can.Message(arbitration_id=cob_id, data=bytes(6), is_extended_id=False)

    probe = LoopProbe(4, frozenset({0x181, 0x182}), 0x201, None, sample_every=1000)
    period = 1e-3
    last_tpdo = (4e-4, 6e-4, 5e-4)
    for k, last in enumerate(last_tpdo):
        t0 = k * period
        if k > 0:  # cycle k-1's targets, sent before this cycle's SYNC
            probe.sink(True, t0 - 1e-6, frame(0x201))
        probe.sink(True, t0, frame(cob_ids.SYNC))
        if k > 0:  # the cycle before, observed in this one's answer window
            stepped = (k - 1) * period + last_tpdo[k - 1] + 2e-4
            probe.on_cycle(k - 1, (k - 1) * period, None, None, None, (), CycleTiming(0.0, 1e-4, stepped))
        probe.sink(False, t0 + 1e-4, frame(0x181))
        probe.sink(False, t0 + last, frame(0x182))
    probe.on_cycle(2, 2 * period, None, None, None, (), CycleTiming(0.0, 1e-4, 2 * period + 7e-4))
    assert probe.answer_s[:3] == pytest.approx(last_tpdo)
    assert probe.ready_after_tpdo_s[:3] == pytest.approx([2e-4, 2e-4, 2e-4])
    # cycle k's last TPDO to cycle k+1's first RPDO; none yet after the last cycle
    assert probe.rpdo_after_tpdo_s[:2] == pytest.approx([period - 1e-6 - 4e-4, period - 1e-6 - 6e-4])
    assert math.isnan(probe.rpdo_after_tpdo_s[2])


def test_demo_gives_the_simulator_the_other_cpus_one_priority_step_below():
    import os

    from controller.shell.demo import simulator_realtime_args

    assert simulator_realtime_args(None) == []
    assert simulator_realtime_args(RealtimeOptions(priority=80, lock_memory=True)) == [
        "--rt-priority",
        "70",
        "--lock-memory",
    ]
    allowed = sorted(os.sched_getaffinity(0))
    args = simulator_realtime_args(RealtimeOptions(priority=5, cpus=(allowed[-1],)))
    assert args[:2] == ["--rt-priority", "1"]
    others = [c for c in allowed if c != allowed[-1]]
    assert (args[2:] == ["--cpu", ",".join(map(str, others))]) if others else args[2:] == []


def test_realtime_options_as_a_child_process_options():
    assert RealtimeOptions().cli_args() == []
    assert RealtimeOptions(priority=70, cpus=(0, 1), lock_memory=True).cli_args() == [
        "--rt-priority",
        "70",
        "--cpu",
        "0,1",
        "--lock-memory",
    ]


# -- real-time scheduling by default, where permitted ------------------------------------------


def test_default_realtime_asks_for_fifo_the_last_cpu_and_locked_memory():
    rt = RealtimeOptions.default()
    allowed = sorted(os.sched_getaffinity(0))
    assert rt.priority == 80 and rt.lock_memory and not rt.required
    assert rt.cpus == ((allowed[-1],) if len(allowed) > 1 else ())
    sim = rt.for_simulator()
    assert sim.priority == 70 and not sim.required and set(sim.cpus).isdisjoint(rt.cpus)
    assert rt.cli_args()[-1] == "--rt-best-effort"  # the child warns and runs on as the parent does
    # a limit of 0 only where it keeps a halting guest's CPUs polling (docs/concepts/realtime.md)
    remedy = idle_remedy()
    assert rt.cpu_latency_us == (0 if remedy is IdleRemedy.LATENCY_LIMIT else None)
    assert rt.idle_poll == (remedy is IdleRemedy.POLLERS)
    assert RealtimeOptions(cpu_latency_us=0).for_simulator().cpu_latency_us == 0
    assert RealtimeOptions(priority=80, cpu_latency_us=0, required=False).cli_args() == [
        "--rt-priority",
        "80",
        "--cpu-latency-us",
        "0",
        "--rt-best-effort",
    ]


def test_the_cpu_latency_limit_is_held_while_running_and_withdrawn_after(monkeypatch, tmp_path, caplog):
    """PM QoS: the request is written once and lasts while the file stays open (a stand-in file
    here: the real device is machine-wide)."""
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    monkeypatch.setattr(realtime, "PM_QOS_DEVICE", str(device))

    def open_files() -> set[str]:
        return {os.path.realpath(f"/proc/self/fd/{fd}") for fd in os.listdir("/proc/self/fd")}

    restore = realtime.apply_realtime(RealtimeOptions(cpu_latency_us=0))
    assert device.read_bytes() == struct.pack("i", 0) and str(device) in open_files()
    assert (
        realtime.cpu_latency_limit_us() == 0 and "CPU wake-up latency <= 0 us" in realtime.granted_realtime()
    )
    restore()
    assert str(device) not in open_files()
    # refused: required, the start ends naming the option; by default, one line and run on
    monkeypatch.setattr(realtime, "PM_QOS_DEVICE", str(tmp_path / "missing"))
    with pytest.raises(RealtimeError, match="--cpu-latency-us 0: this kernel has no PM QoS device"):
        realtime.apply_realtime(RealtimeOptions(cpu_latency_us=0))
    with caplog.at_level("WARNING", logger="controller.realtime"):
        realtime.apply_realtime(RealtimeOptions(cpu_latency_us=0, required=False))()
    (record,) = caplog.records
    assert "no PM QoS device" in record.getMessage()
    with pytest.raises(RealtimeError, match="must be 0 or more"):
        RealtimeOptions(cpu_latency_us=-1)


def test_refused_default_realtime_warns_in_one_line_and_runs_on(monkeypatch, caplog):
    def refuse(pid, policy, param):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    class NoLock:
        def mlockall(self, flags):
            ctypes.set_errno(errno.ENOMEM)
            return -1

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(realtime, "_libc", lambda: NoLock())
    monkeypatch.setattr(sys, "platform", "linux")
    before = os.sched_getaffinity(0)
    with caplog.at_level("WARNING", logger="controller.realtime"):
        restore = realtime.apply_realtime(RealtimeOptions(priority=80, lock_memory=True, required=False))
    restore()
    assert os.sched_getaffinity(0) == before
    (record,) = caplog.records
    line = record.getMessage()
    assert "\n" not in line and line.startswith("real-time options refused, running without them")
    assert "SCHED_FIFO not permitted" in line and "CAP_SYS_NICE" in line and "mlockall not permitted" in line
    # the same refusal of an option given explicitly ends the start
    with pytest.raises(RealtimeError, match="SCHED_FIFO not permitted"):
        realtime.apply_realtime(RealtimeOptions(priority=80))


def test_cli_realtime_defaults_and_opt_out():
    from controller.cli import _realtime, build_parser

    def parse(*argv):
        return build_parser().parse_args(["run", *argv])

    assert _realtime(parse()) == RealtimeOptions.default()
    assert _realtime(parse(), simulator=True) == RealtimeOptions.default().for_simulator()
    assert _realtime(parse("--no-realtime")) == RealtimeOptions()
    explicit = _realtime(parse("--rt-priority", "50"))
    assert explicit.priority == 50 and explicit.required and not explicit.lock_memory
    assert not _realtime(parse("--rt-priority", "50", "--rt-best-effort")).required
    with pytest.raises(RealtimeError, match="--no-realtime cannot be combined"):
        _realtime(parse("--no-realtime", "--cpu", "0"))
    latency = _realtime(parse("--cpu-latency-us", "20"))
    assert latency.cpu_latency_us == 20 and latency.required and latency.priority is None
    with pytest.raises(RealtimeError, match="--no-realtime cannot be combined"):
        _realtime(parse("--no-realtime", "--cpu-latency-us", "0"))


# -- the machine's floor: cyclictest -----------------------------------------------------------

HISTOGRAM = """# /dev/cpu_dma_latency set to 0us
# Histogram
000000 000000
000001 000010
000002 000080
000003 000005
000004 000003
# Total: 000000100
# Min Latencies: 00001
# Avg Latencies: 00002
# Max Latencies: 00950
# Histogram Overflows: 00002
# Histogram Overflow at cycle number:
# Thread 0: 00017 00051
"""


def test_cyclictest_histogram_percentiles_and_rate_above_a_threshold():
    from controller.tools.bench.cyclictest import parse_histogram

    h = parse_histogram(HISTOGRAM)
    assert h.samples == 100 and h.overflows == 2 and h.max_us == 950.0
    assert h.percentile_us(0.5) == 2.0
    assert h.percentile_us(0.95) == 3.0
    assert h.percentile_us(0.99) == 950.0  # among the overflows: the maximum
    assert h.per_10k_above(2.0) == pytest.approx(1e4 * (5 + 3 + 2) / 100)
    assert h.per_10k_above(3.0) == pytest.approx(1e4 * (3 + 2) / 100)


def test_the_floor_counts_the_deadlines_a_late_wake_up_passed_as_the_loop_counts_its_own():
    """cyclictest samples wake-ups and moves past the deadlines a late one passed; the loop counts
    those as late cycles (its overruns): the floor counts them too (controller/tools/bench/cyclictest.py)."""
    from controller.tools.bench.cyclictest import Histogram

    counts = np.zeros(20_000, dtype=np.int64)
    counts[10] = 9_990  # on time
    counts[300] = 4  # late, passed no deadline after its own (period 2 500 us)
    counts[2_500] = 1  # late by exactly a period: the next deadline is now, not passed
    counts[2_501] = 2  # ... 1 us more: it passed the next
    counts[10_000] = 3  # passed 3
    h = Histogram(counts, overflows=0, max_us=10_000.0)
    assert h.per_10k_above(250.0) == pytest.approx(1e4 * 10 / 10_000)  # wake-ups only
    late = 4 + 1 + 2 * 2 + 3 * 4  # each late one and the deadlines it passed
    assert h.late_deadlines_per_10k(250.0, 2_500.0) == pytest.approx(1e4 * late / (10_000 + 2 + 9))
    # beyond the histogram: each overflow at its end (20 000 us: 7 passed), the largest at its maximum
    over = Histogram(counts, overflows=2, max_us=50_000.0)
    late_over = late + 2 + 7 + 19
    assert over.late_deadlines_per_10k(250.0, 2_500.0) == pytest.approx(
        1e4 * late_over / (10_002 + 2 + 9 + 7 + 19)
    )
    # a threshold above every latency: none late, whatever passed
    assert h.late_deadlines_per_10k(20_000.0, 2_500.0) == 0.0


def test_cyclictest_command_per_scheduling_class():
    from pathlib import Path

    from controller.tools.bench.cyclictest import cyclictest_command

    rt = cyclictest_command("cyclictest", 2500, 400, 10000, Path("/tmp/h"), 80, 1, True)
    assert rt[:4] == ["cyclictest", "-t1", "-q", "-i2500"] and "-p80" in rt and "-a1" in rt and "-m" in rt
    # never its own PM QoS limit: the loop beside it would run on other idle states than in service
    assert "--laptop" in rt
    normal = cyclictest_command("cyclictest", 1000, 10, 10000, Path("/tmp/h"), None, None, False)
    assert "--policy=other" in normal and not any(a.startswith(("-p", "-a")) for a in normal)


@pytest.mark.skipif(shutil.which("cyclictest") is None, reason="cyclictest (rt-tests) not installed")
def test_cyclictest_runs_under_the_normal_scheduler():
    from controller.tools.bench.cyclictest import run_cyclictest

    r = run_cyclictest(1000.0, 0.2, None, None, False, (100.0,))
    assert r["samples"] == 200
    assert 0.0 <= r["latency_us"]["p50"] <= r["latency_us"]["max"]
    assert 0.0 <= r["per_10k_above_us"]["100"] <= 1e4


def test_the_summary_says_what_was_granted_not_what_was_asked():
    cpu = min(os.sched_getaffinity(0))
    restore = realtime.apply_realtime(RealtimeOptions(cpus=(cpu,)))
    try:
        granted = realtime.granted_realtime()
    finally:
        restore()
    assert f"CPU {cpu}" in granted
    if os.sched_getscheduler(0) == os.SCHED_OTHER:
        assert granted.startswith("normal scheduler")


def test_the_kernel_s_real_time_throttling_is_named(tmp_path):
    (tmp_path / "sched_rt_period_us").write_text("1000000\n")
    (tmp_path / "sched_rt_runtime_us").write_text("950000\n")
    assert realtime.rt_throttling(str(tmp_path)) == (
        "real-time tasks throttled to 950000 of every 1000000 us per CPU (machine-wide)"
    )
    (tmp_path / "sched_rt_runtime_us").write_text("-1\n")
    assert realtime.rt_throttling(str(tmp_path)) == "real-time throttling off (machine-wide)"
    (tmp_path / "sched_rt_runtime_us").write_text("lots\n")
    assert realtime.rt_throttling(str(tmp_path)) is None
    assert realtime.rt_throttling(str(tmp_path / "nowhere")) is None


def test_a_real_time_summary_names_the_throttling_a_normal_one_does_not(monkeypatch):
    monkeypatch.setattr(realtime, "rt_throttling", lambda: "real-time throttling off (machine-wide)")
    monkeypatch.setattr(realtime, "scheduling_policy", lambda tid=0: os.SCHED_FIFO)
    monkeypatch.setattr(os, "sched_getparam", lambda tid: os.sched_param(80))
    assert realtime.granted_realtime().startswith("SCHED_FIFO 80")
    assert realtime.granted_realtime().endswith(", real-time throttling off (machine-wide)")
    monkeypatch.setattr(realtime, "scheduling_policy", lambda tid=0: os.SCHED_OTHER)
    assert "throttling" not in realtime.granted_realtime()


def test_memory_is_locked_when_most_of_it_is_not_when_a_library_locked_a_few_pages():
    status = "Name:\tpython3\nVmSize:\t  808132 kB\nVmLck:\t      {lck} kB\nVmRSS:\t   75452 kB\n"
    assert not realtime.memory_locked(status.format(lck=12))  # a library's pages, no mlockall
    assert not realtime.memory_locked(status.format(lck=0))
    assert realtime.memory_locked(status.format(lck=75452))  # mlockall: all of it
    assert not realtime.memory_locked("Name:\tkthread\n")  # no memory of its own


def test_a_bench_run_asks_the_task_for_enough_of_itself():
    """The path task lasts as long as the run (its entry's ``lasting``); the contour its laps."""
    import math

    from controller.config import load_config
    from controller.tasks.registry import task_entry

    p = load_config().task.model("path")
    (key, laps), *_ = task_entry("path").lasting(p, 60.0).items()
    assert key == "task.path.laps" and laps * 2 * math.pi * p.radius_m >= 60.0 * p.speed_m_s
    assert (laps - 2) * 2 * math.pi * p.radius_m < 60.0 * p.speed_m_s  # one lap more, not many
    assert task_entry("contour").lasting is None


def _children_names() -> list[str]:
    """The names of this process's children, by the parent id in each process's stat (the
    /proc/self/task/*/children lists missed a running cyclictest on CI's machine)."""
    from pathlib import Path

    names = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # gone meanwhile
            continue
        comm, rest = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :].split()
        if int(rest[1]) == os.getpid():
            names.append(comm)
    return names


@pytest.mark.skipif(shutil.which("cyclictest") is None, reason="cyclictest (rt-tests) not installed")
def test_the_floor_is_measured_beside_the_run_not_after_it():
    """cyclictest runs while the block runs (the case's run), and its figures are there after it."""

    from controller.realtime import RealtimeOptions
    from controller.tools.bench import machine_floor, machine_floor_beside

    with machine_floor_beside(400.0, 1.0, RealtimeOptions()) as floor:
        assert floor == {}  # filled when the block ends
        assert "cyclictest" in _children_names()  # running now, beside the block's run
    assert floor["samples"] >= 300
    case = {"late_per_10k": 0.0, "wake_latency_us": {"p99": 10.0}}
    assert machine_floor(floor, 250.0, case)["late_us"] == 250.0


def test_cpu_hogs_run_while_the_block_runs_and_are_gone_after_it():
    from controller.tools.bench.cpu_hogs import cpu_hogs

    with cpu_hogs(2) as pids:
        assert len(pids) == 2
        for pid in pids:  # running, at the normal scheduler
            assert os.path.exists(f"/proc/{pid}") and os.sched_getscheduler(pid) == os.SCHED_OTHER
    for pid in pids:  # killed and reaped by the block: no such process any more
        assert not os.path.exists(f"/proc/{pid}")
    with pytest.raises(ValueError, match="cpu hogs: 17"), cpu_hogs(17):
        pass


def test_cli_refuses_too_many_hogs_naming_the_option():
    proc = subprocess.run(
        [sys.executable, "-m", "controller", "bench", "--hogs", "17", "--duration", "1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != 0
    assert "--hogs 17: must be 0 .. 16" in proc.stderr


def test_the_loops_floor_is_python_cans_frames_plus_the_step_in_process():
    from controller.tools.bench.report import loop_floor_percent, python_can_floor_percent

    cost = {"send_us": {"p50": 10.0}, "recv_us": {"p50": 20.0}, "own_frames_received_back": 0, "frames": 2000}
    case = {"rate_hz": 400.0, "frames_per_cycle": {"in": 5, "out": 4}}
    report = {"bus_frame_cost": cost, "step_breakdown": [{"rate_hz": 400.0, "step_us": {"p50": 100.0}}]}
    # 400 a second x (4 sends of 10 us + 5 receives of 20 us) = 5.6 %; the step 400 x 100 us = 4 %
    assert python_can_floor_percent(case, cost) == (5.6, 5.2)
    assert loop_floor_percent(case, report) == 9.6
    assert loop_floor_percent({**case, "rate_hz": 1000.0}, report) is None  # no step measured at 1 kHz


def test_the_record_cost_bench_times_equal_records_compiled_and_interpreted():
    from controller.tools.bench.record_cost import record_cost

    out = record_cost("path", passes=1)  # refuses (SystemExit) when the two records differ
    assert out["cycles"] == 20 and out["passes"] == 1
    for part in ("loop_us", "loop_interpreted_us", "writer_us"):
        assert out[part]["median"] > 0, part  # type: ignore[index]
