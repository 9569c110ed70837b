"""Real-time scheduling and memory locking come after the start-up work, never before it.

Several controllers and simulators share a host: one's start-up (imports, EDS files, plant,
set-up, a full garbage collection) at SCHED_FIFO took the CPU from another's running loop. These
tests record the order of the real start-up functions (the real-time calls themselves replaced
by recorders), so they need no timing and no permission.
"""

from __future__ import annotations

import ctypes
import logging
import os
import threading
import time

import can
import pytest

from controller import realtime
from controller.config import load_config
from controller.realtime import RealtimeOptions
from controller.shell import service
from drivers.bus import parse_bus_spec
from sim_backend import process
from sim_backend.server import Simulator

RT = RealtimeOptions(priority=70, cpus=(0,), lock_memory=True, required=False)


def test_the_simulator_is_real_time_only_from_after_its_set_up_to_before_its_shut_down(monkeypatch):
    calls: list[str] = []
    cfg = load_config()

    class RecordingSimulator(Simulator):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            calls.append("EDS files and plant loaded")

        def build_nodes(self):
            super().build_nodes()
            calls.append("canopen nodes built")

        def start(self):
            calls.append("device threads start")
            super().start()

        def stop(self):
            calls.append("device threads stop")
            super().stop()

    def open_bus(spec):
        calls.append("bus open")
        return real_open_bus(spec)

    def apply(options):
        assert options is RT
        running = {t.name for t in threading.enumerate()}
        assert "sim-cyclic" not in running and "sim-pose" not in running  # they must inherit it
        calls.append("real-time")
        return lambda: calls.append("normal scheduler")

    stop = threading.Event()
    real_open_bus = process.open_bus
    monkeypatch.setattr(process, "open_bus", open_bus)
    monkeypatch.setattr(process, "Simulator", RecordingSimulator)
    monkeypatch.setattr(process, "apply_realtime", apply)
    monkeypatch.setattr(process, "freeze_garbage_collector", lambda: calls.append("gc frozen"))
    monkeypatch.setattr(process, "unfreeze_garbage_collector", lambda: None)

    def announce(line):
        if line.startswith(process.READY_LINE):
            return (calls.append("READY"), stop.set())
        return calls.append(line.split(":")[0])  # the last words, on the normal scheduler

    process.serve(cfg, parse_bus_spec(f"virtual:rt-order-{time.monotonic_ns()}"), stop, announce, RT)
    assert calls == [
        "bus open",
        "EDS files and plant loaded",
        "canopen nodes built",
        "gc frozen",
        "real-time",
        "device threads start",
        "READY",
        "normal scheduler",
        "device threads stop",
        process.STOPPED_LINE,
    ]


def test_the_controller_goes_real_time_after_the_set_up_and_the_garbage_collection(monkeypatch):
    """A short run over a virtual bus against an in-process simulator; only the order is judged."""
    cfg = load_config(
        overrides={
            "recording.enabled": False,
            "monitoring.enabled": False,
            "sensor.enabled": False,
            "loop.freeze_gc": True,
        }
    )
    channel = f"rt-order-{time.monotonic_ns()}"
    calls: list[str] = []
    configure = service.configure_nodes

    def configure_nodes(bus, plan, stop=None):
        calls.append("devices configured")
        return configure(bus, plan, stop)

    def apply(options):
        calls.append("real-time")
        return lambda: calls.append("real-time restored")

    monkeypatch.setattr(service, "configure_nodes", configure_nodes)
    monkeypatch.setattr(service, "check_realtime", lambda options: calls.append("checked"))
    monkeypatch.setattr(service, "apply_realtime", apply)
    monkeypatch.setattr(service, "freeze_garbage_collector", lambda: calls.append("gc frozen"))
    monkeypatch.setattr(service, "notify", lambda state: calls.append(state))
    sim_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
    try:
        with Simulator(cfg, sim_bus):
            service.run_controller(
                cfg, parse_bus_spec(f"virtual:{channel}"), max_duration_s=0.05, realtime=RT
            )
    finally:
        sim_bus.shutdown()
    assert calls == [
        "checked",
        "devices configured",
        "gc frozen",
        "real-time",
        "READY=1",
        "STOPPING=1",
        "real-time restored",
    ]


class _RecordingLibc:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def mlockall(self, flags: int) -> int:
        self.calls.append("mlockall")
        return 0

    def munlockall(self) -> int:
        self.calls.append("munlockall")
        return 0


def test_checking_a_required_memory_lock_does_not_keep_it_for_the_start_up(monkeypatch):
    libc = _RecordingLibc()
    monkeypatch.setattr("sys.platform", "linux")
    realtime.check_realtime(RealtimeOptions(lock_memory=True), libc)  # type: ignore[arg-type]
    assert libc.calls == ["mlockall", "munlockall"]


def test_a_refused_memory_lock_is_still_refused_at_the_check(monkeypatch):
    class Refusing(_RecordingLibc):
        def mlockall(self, flags: int) -> int:
            ctypes.set_errno(1)  # EPERM
            return -1

    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(realtime.RealtimeError, match="mlockall not permitted"):
        realtime.check_realtime(RealtimeOptions(lock_memory=True), Refusing())  # type: ignore[arg-type]


class _MovesTheLoopThread:
    """An observer that moves the loop's thread to ``cpus`` at its first cycle, as an administrator's
    ``taskset`` or a CPU taken offline and back would (an outside tester's; no permission needed)."""

    def __init__(self, cpus: set[int]) -> None:
        self.cpus = cpus

    def on_cycle(self, cycle: int, *rest: object) -> None:
        if cycle == 0:
            os.sched_setaffinity(0, self.cpus)  # the calling thread: the loop's


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs to move the loop between")
def test_scheduling_changed_under_the_run_is_in_the_summary_beside_what_the_start_got(monkeypatch, caplog):
    """An outside tester's ``chrt -o`` of the loop's thread mid-run left the summary saying
    "SCHED_FIFO 80, CPU 1", and so did a CPU taken offline and back (the loop then on CPUs 0-1)."""
    cfg = load_config(
        overrides={"recording.enabled": False, "monitoring.enabled": False, "sensor.enabled": False}
    )
    channel = f"rt-at-end-{time.monotonic_ns()}"
    before = os.sched_getaffinity(0)
    monkeypatch.setattr(service, "apply_realtime", lambda options: lambda: None)  # the thread as it is
    sim_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
    try:
        with Simulator(cfg, sim_bus), caplog.at_level(logging.WARNING, logger="controller.shell.service"):
            summary = service.run_controller(
                cfg,
                parse_bus_spec(f"virtual:{channel}"),
                max_duration_s=0.05,
                realtime=RT,
                observers=(_MovesTheLoopThread({min(before)}),),
            )
    finally:
        os.sched_setaffinity(0, before)
        sim_bus.shutdown()
    start, end = str(summary["realtime"]), str(summary["realtime_at_end"])
    assert f"CPUs {','.join(map(str, sorted(before)))}" in start and f"CPU {min(before)}," in end
    assert f"changed during the run: {start} at the start, {end} at the end" in caplog.text
