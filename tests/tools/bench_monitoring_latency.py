"""Benchmarks of the Zenoh monitoring (not part of the default run: marker ``bench``).

    .venv/bin/pytest tests/tools/bench_monitoring_latency.py -m bench -s -q
    .venv/bin/python tests/tools/bench_monitoring_latency.py

1. What ``MonitorPublisher.on_cycle`` costs the loop's thread: per-call time over thousands
   of calls paced at 400 Hz like the loop (sleep, then spin), with the publisher thread running (so the GIL is contended as in
   a real run), for a decimated rate (50 Hz at 400 Hz) and for publishing every cycle.
2. End-to-end latency from the cycle that produced a sample (``cycle_monotonic_s``, taken in
   ``on_cycle``) to the monitor receiving it (in its Zenoh callback), with the controller in
   another process (controller.tools.sim_controller) on loopback. Both processes read
   CLOCK_MONOTONIC, which is system-wide on Linux.
"""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.core.cycle_data import CycleInputs, CycleOutputs, DriveFeedback, SensorFeedback
from controller.core.ports import CycleTiming
from controller.monitoring.monitor_view import MonitorClient, StateUpdate
from controller.monitoring.publisher import MonitorPublisher
from controller.monitoring.zenoh_session import MonitorKeys, free_loopback_port, monitor_settings
from controller.shell.service import publisher_settings
from drivers.pacing import DeadlineSleeper


def on_cycle_cost_us(publish_rate_hz: float, calls: int = 8000) -> tuple[np.ndarray, int]:
    ep = f"tcp/127.0.0.1:{free_loopback_port()}"
    cfg = load_config(
        overrides={
            "monitoring.publish_rate_hz": publish_rate_hz,
            "monitoring.listen": ep,
            "monitoring.on_listen_busy": "fail",
        }
    )
    law = build_law(cfg)
    state = law.initial_state()
    inputs = CycleInputs(
        drives=(DriveFeedback(0x1237, 0.55, True),) * 3,
        sensor=SensorFeedback((0.1, 0.2, 3.0), (0.0, 0.0, 0.0), 0, 1, True),
    )
    outputs = CycleOutputs((0x0F,) * 3, (0.55,) * 3)
    timing = CycleTiming(2e-6, 1.5e-4)
    cost = np.zeros(calls)
    with MonitorPublisher(
        publisher_settings(cfg), threading.Event(), law.task.name, law.task.phase_name
    ) as pub:
        # a subscriber so that samples really go out on the wire
        with MonitorClient(
            monitor_settings((ep,)), MonitorKeys.for_robot("cheope", "*", allow_wildcard=True)
        ):
            time.sleep(0.5)
            clock = time.perf_counter_ns
            sleeper = DeadlineSleeper(cfg.loop.spin_us * 1e-6)  # paced like the loop: 400 Hz
            first = time.monotonic()
            for k in range(calls):
                sleeper.sleep_until(first + k * cfg.period_s)
                t0 = clock()
                pub.on_cycle(k, k * cfg.period_s, inputs, state, outputs, (), timing)
                cost[k] = (clock() - t0) * 1e-3
            time.sleep(0.2)
        errors = pub.publish_errors
    return cost, errors


def end_to_end_latency_s(samples: int = 4000, publish_rate_hz: float = 400.0) -> dict[str, np.ndarray]:
    ep = f"tcp/127.0.0.1:{free_loopback_port()}"
    cmd = [
        sys.executable,
        "-m",
        "controller.tools.sim_controller",
        "--max-duration",
        "60",
        "--set",
        f'monitoring.listen="{ep}"',
        "--set",
        'monitoring.on_listen_busy="fail"',
        "--set",
        f"monitoring.publish_rate_hz={publish_rate_hz}",
        "--set",
        "task.path.laps=50",
    ]
    cycle, publish, received = [], [], []
    with MonitorClient(
        monitor_settings((ep,)), MonitorKeys.for_robot("cheope", "*", allow_wildcard=True)
    ) as client:
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        try:
            sel = selectors.DefaultSelector()
            sel.register(proc.stdout, selectors.EVENT_READ)
            assert sel.select(timeout=30) and proc.stdout.readline().startswith("READY")
            sel.close()
            deadline = time.monotonic() + 60
            skip = 50  # the first samples include the connection's set-up
            while len(cycle) < samples and time.monotonic() < deadline:
                u = client.next_update(0.5)
                if not isinstance(u, StateUpdate):
                    continue
                if skip:
                    skip -= 1
                    continue
                cycle.append(u.msg.cycle_monotonic_s)
                publish.append(u.msg.publish_monotonic_s)
                received.append(u.received_monotonic_s)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=30)
    c, p, r = np.array(cycle), np.array(publish), np.array(received)
    return {"cycle_to_receive": r - c, "cycle_to_publish": p - c, "publish_to_receive": r - p}


def _pct(a: np.ndarray, scale: float = 1.0) -> str:
    return (
        f"p50 {np.percentile(a, 50) * scale:.1f}, p99 {np.percentile(a, 99) * scale:.1f}, "
        f"max {a.max() * scale:.1f}"
    )


def report() -> str:
    lines = []
    for rate in (50.0, 400.0):
        cost, errors = on_cycle_cost_us(rate)
        published = cost[:: max(1, round(400.0 / rate))]  # the cycles that build and put a sample
        lines.append(
            f"on_cycle at 400 Hz loop, publish {rate:g} Hz, {cost.size} calls [us]: {_pct(cost)}; "
            f"publishing cycles: {_pct(published)}; publish errors {errors}"
        )
    lat = end_to_end_latency_s()
    n = lat["cycle_to_receive"].size
    lines.append(
        f"end-to-end latency, publish 400 Hz, {n} samples [us]: {_pct(lat['cycle_to_receive'], 1e6)}"
    )
    lines.append(
        f"  of which cycle -> put (protobuf, on the loop's thread) [us]: {_pct(lat['cycle_to_publish'], 1e6)}"
    )
    lines.append(f"  of which put -> monitor callback (Zenoh) [us]: {_pct(lat['publish_to_receive'], 1e6)}")
    return "\n".join(lines)


@pytest.mark.bench
def test_bench_monitoring():
    text = report()
    print("\n" + text)


if __name__ == "__main__":
    print(report())
