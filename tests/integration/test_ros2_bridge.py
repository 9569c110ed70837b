"""``cheope ros2``: a real rclpy subscriber in another process receives what the controller publishes over Zenoh.

Four processes on this machine: the controller (controller.tools.sim_controller, loopback Zenoh
endpoint), the bridge (``python -m controller ros2``), the subscriber (tests/ros2_probe.py) and
this test, which watches the same Zenoh state and compares. DDS discovery stays on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in a ROS domain drawn per test, so that concurrent
runs do not see each other. Skipped where the ``ros2`` extra is not installed.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from busy_machine import TOLERANT
from waiting import GENEROUS_S, ProcessLines, wait_for_exit

from controller.config import load_config
from controller.monitoring.monitor_view import MonitorClient, StateUpdate
from controller.monitoring.zenoh_session import MonitorKeys, free_loopback_port, monitor_settings
from controller.robots.registry import robot_from_config
from controller.ros2.bridge import TOPICS  # imports no ROS

pytest.importorskip(
    "rclpy",
    reason="the ros2 extra is not installed (pip install '.[ros2]': ROS 2 wheels, "
    "CPython 3.11 on Linux x86_64)",
)
pytestmark = pytest.mark.ros2
ROBOT_ID = "ros2-bridge-test"
PROBE = str(Path(__file__).resolve().parent.parent / "ros2_probe.py")
MARKER_DELETEALL = 3


@pytest.fixture
def ros_env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "ROS_LOCALHOST_ONLY"}
    env.update(
        ROS_DOMAIN_ID=str(random.randint(1, 200)),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        PYTHONUNBUFFERED="1",
    )
    return env


@contextmanager
def _process(cmd: list[str], env: dict[str, str], what: str) -> Iterator[subprocess.Popen[bytes]]:
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
        wait_for_exit(proc.pid, what)
        proc.communicate()


def _probe_lines(proc: subprocess.Popen[bytes], bridge: subprocess.Popen[bytes]) -> list[dict[str, Any]]:
    out, err = proc.communicate(timeout=GENEROUS_S * 2)
    if proc.returncode != 0:
        bridge.terminate()
        raise AssertionError(
            f"the subscriber: {out[-2000:]!r} {err[-2000:]!r}; the bridge: {bridge.communicate()!r}"
        )
    return [json.loads(line) for line in out.decode().splitlines() if line.startswith("{")]


def _by_topic(lines: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {t: [] for t in TOPICS}
    for line in lines:
        if "topic" in line:
            out[line["topic"]].append(line)
    return out


def _matching(samples: dict[float, Any], stamp_s: float) -> Any:
    """The sample stamped ``stamp_s`` (the header's nanoseconds round the float seconds)."""
    (key,) = [k for k in samples if abs(k - stamp_s) < 2e-9 * max(1.0, abs(k))] or [None]
    assert key is not None, f"no sample at {stamp_s!r}"
    return samples[key]


def _check_graph(lines: list[dict[str, Any]], namespace: str) -> None:
    (graph,) = [line["graph"] for line in lines if "graph" in line]
    for topic, type_name in TOPICS.items():
        assert graph.get(f"{namespace}/{topic}") == [type_name], (topic, graph)


def _commanded(robot: Any, targets: Any) -> list[float]:
    return [float(x) for x in robot.direct_kinematics(np.asarray(targets, dtype=float))]


def test_a_ros2_subscriber_gets_the_zenoh_state_and_its_stop_request_stops_the_controller(ros_env):
    endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
    namespace = "/cheope_test"
    controller = [
        sys.executable,
        "-m",
        "controller.tools.sim_controller",
        "--max-duration",
        "120",
        "--set",
        f'monitoring.listen="{endpoint}"',
        "--set",
        f'monitoring.robot_id="{ROBOT_ID}"',
        "--set",
        "task.path.laps=50",
        *TOLERANT,
        "--set",
        "sim.drive.sync_timeout_s=0.5",
    ]
    robot = robot_from_config(load_config())
    with _process(controller, ros_env, "the controller") as ctl:
        ProcessLines(ctl).next_matching(lambda line: line.startswith("READY"), "the controller ready")
        with (
            MonitorClient(monitor_settings((endpoint,)), MonitorKeys.for_robot("cheope", ROBOT_ID)) as watch,
            _process(
                [
                    sys.executable,
                    "-m",
                    "controller",
                    "ros2",
                    "--robot-id",
                    ROBOT_ID,
                    "--zenoh-connect",
                    endpoint,
                    "--namespace",
                    namespace,
                ],
                ros_env,
                "the bridge",
            ) as bridge,
            _process(
                [
                    sys.executable,
                    PROBE,
                    "--namespace",
                    namespace,
                    "--count",
                    "5",
                    "--call-stop",
                    "--timeout",
                    str(GENEROUS_S),
                ],
                ros_env,
                "the subscriber",
            ) as probe,
        ):
            lines = _probe_lines(probe, bridge)
            states: dict[float, Any] = {}
            while (u := watch.next_update(0.0)) is not None:
                if isinstance(u, StateUpdate):
                    states[u.msg.cycle_monotonic_s] = u.msg
        final = json.loads(ctl.communicate(timeout=GENEROUS_S)[0].decode().splitlines()[-1])
    _check_graph(lines, namespace)
    got = _by_topic(lines)
    for js in got["joint_states"]:
        assert js["name"] == ["actuator_1", "actuator_2", "actuator_3"] and js["frame"] == "base"
        assert js["position"] == list(_matching(states, js["stamp"]).positions)
    for w in got["wrench"]:
        assert w["force"] == list(_matching(states, w["stamp"]).force_n)
    for p in got["tcp/measured"]:
        assert p["position"] == list(_matching(states, p["stamp"]).tcp_m)
    for p in got["tcp/reference"]:
        assert p["position"] == pytest.approx(
            _commanded(robot, _matching(states, p["stamp"]).targets), abs=1e-12
        )
    for d in got["diagnostics"]:
        s = _matching(states, d["stamp"])
        assert (d["values"]["mode"], int(d["values"]["cycle"])) == (s.mode, s.cycle)
    for m in got["robot_markers"]:
        _matching(states, m["stamp"])
        assert m["first_action"] == MARKER_DELETEALL
        assert {"base", "guides", "sliders", "rods", "platform", "tool"} <= set(m["namespaces"])
    assert all(len(got[t]) >= 5 for t in TOPICS if t != "events"), {t: len(v) for t, v in got.items()}
    (stop,) = [line["stop"] for line in lines if "stop" in line]
    assert stop["success"] and "stop accepted" in stop["message"]
    assert final["final_mode"] == "DONE" and "INFO: RUNNING -> STOPPING: stop requested" in final["events"]
    assert got["events"] and all(
        e["msg"].split("] ", 1)[1] in {ev.split(": ", 1)[1] for ev in final["events"]} for e in got["events"]
    )


def test_a_replayed_recording_reaches_a_ros2_subscriber_as_recorded(ros_env, tmp_path):
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from logs import messages as m
    from logs.reader import iter_decoded, read_info
    from logs.recorder import SessionRecorder, session_metadata
    from sim_backend.loopback import LoopbackExchange

    cfg = load_config()
    path = tmp_path / "session.mcap"
    clock = SimulatedTime()
    law = build_law(cfg)
    with SessionRecorder(
        path, session_metadata(cfg), clock=clock.clock, phase_name=law.task.phase_name, lossless=True
    ) as rec:
        loop = CycleLoop(
            law,
            LoopbackExchange(cfg, clock.clock),
            cfg.period_s,
            cfg.loop.collect_fraction,
            clock,
            clock.clock,
            observers=(rec,),
        )
        loop.run(law.initial_state(), 3.0)
    offset_s = int(read_info(path).metadata[m.META_SESSION]["clock_offset_ns"]) * 1e-9
    cycles = {d.log_time_ns * 1e-9 - offset_s: d.message for d in iter_decoded(path, [m.TOPIC_CYCLE])}
    namespace = "/cheope_replay"
    with (
        _process(
            [sys.executable, PROBE, "--namespace", namespace, "--count", "5", "--timeout", str(GENEROUS_S)],
            ros_env,
            "the subscriber",
        ) as probe,
        _process(
            [
                sys.executable,
                "-m",
                "controller",
                "ros2",
                "--replay",
                str(path),
                "--namespace",
                namespace,
                "--wait-subscriber",
                str(GENEROUS_S),
            ],
            ros_env,
            "the bridge",
        ) as bridge,
    ):
        lines = _probe_lines(probe, bridge)
    _check_graph(lines, namespace)
    got = _by_topic(lines)
    for js in got["joint_states"]:
        assert js["position"] == [d.position for d in _matching(cycles, js["stamp"]).inputs.drives]
    for w in got["wrench"]:
        sensor = _matching(cycles, w["stamp"]).inputs.sensor
        assert (w["force"], w["torque"]) == (list(sensor.force_n), list(sensor.torque_nm))
    for p in got["tcp/measured"]:
        assert p["position"] == list(_matching(cycles, p["stamp"]).state.tcp_measured_m)
    for d in got["diagnostics"]:
        c = _matching(cycles, d["stamp"])
        assert (d["values"]["mode"], int(d["values"]["cycle"])) == (c.state.mode, c.cycle)
    assert all(len(got[t]) >= 5 for t in TOPICS if t != "events"), {t: len(v) for t, v in got.items()}
