"""``cheope ros2``: a real rclpy subscriber in another process receives what the controller publishes over Zenoh.

Four processes on this machine: the controller (controller.tools.sim_controller, loopback Zenoh
endpoint), the bridge (``python -m controller ros2``), the subscriber (tests/ros2_probe.py) and
this test, which watches the same Zenoh state and compares. DDS discovery stays on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) in a ROS domain drawn per test, so that concurrent
runs do not see each other. Skipped where the ``ros2`` extra is not installed.
"""

from __future__ import annotations

import bisect
import itertools
import json
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from busy_machine import TOLERANT
from waiting import GENEROUS_S, ProcessLines, wait_for_exit

from controller.config import load_config
from controller.configured_robot import robot_from_config
from controller.monitoring.commands import RobotSelector, query_status
from controller.monitoring.monitor_view import MonitorClient, StateUpdate
from controller.monitoring.zenoh_session import (
    MonitorKeys,
    client_settings,
    free_loopback_port,
    monitor_settings,
)
from controller.ros2.bridge import CLOCK_TOPIC, GLOBAL_TOPICS, TOPICS, tf_message_class  # imports no ROS

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
        PYTHONFAULTHANDLER="1",  # a process that hangs prints its threads on SIGABRT (_process)
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
        try:
            wait_for_exit(proc.pid, what)
        except AssertionError:
            # still running after SIGTERM: its threads' stacks (PYTHONFAULTHANDLER, in ros_env)
            # say where it hangs; the process is ended either way, nothing left behind
            proc.send_signal(signal.SIGABRT)
            try:
                _, err = proc.communicate(timeout=GENEROUS_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                _, err = proc.communicate()
            raise AssertionError(
                f"{what} did not end within {GENEROUS_S} s of SIGTERM; its stderr:\n"
                + err.decode(errors="replace")[-6000:]
            ) from None
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
    out: dict[str, list[dict[str, Any]]] = {t: [] for t in (*TOPICS, *GLOBAL_TOPICS, CLOCK_TOPIC)}
    for line in lines:
        if "topic" in line:
            out[line["topic"]].append(line)
    return out


def _one(lines: list[dict[str, Any]], key: str) -> Any:
    (value,) = [line[key] for line in lines if key in line]
    return value


def _check_graph(lines: list[dict[str, Any]], namespace: str) -> None:
    graph = _one(lines, "graph")
    for topic, type_name in TOPICS.items():
        assert graph.get(f"{namespace}/{topic}") == [type_name], (topic, graph)
    for topic, type_name in GLOBAL_TOPICS.items():
        assert type_name in graph.get(topic, []), (topic, graph)


def _check_description(got: dict[str, list[dict[str, Any]]], joint_names: list[str]) -> Any:
    """robot_description, parsed by a URDF parser: the actuated joints real, the passive parts
    floating, the TCP a link; returns the model."""
    from urdf_parser_py.urdf import URDF

    (description,) = got["robot_description"]
    model = URDF.from_xml_string(description["urdf"])
    actuated = [j.name for j in model.joints if j.type in ("prismatic", "revolute")]
    assert actuated == joint_names
    assert {"base", "tcp"} <= {link.name for link in model.links}
    assert any(j.type == "floating" for j in model.joints) and any(j.type == "fixed" for j in model.joints)
    assert model.get_root() == "base"
    return model


def _matching(samples: dict[int, Any], stamp_ns: int) -> Any:
    assert stamp_ns in samples, f"no sample at {stamp_ns}"
    return samples[stamp_ns]


def _commanded(robot: Any, targets: Any) -> list[float]:
    return [float(x) for x in robot.direct_kinematics(np.asarray(targets, dtype=float))]


def _check_joint_states(
    got: dict[str, list[dict[str, Any]]], samples: dict[int, Any], positions_of: Any, efforts_of: Any
) -> None:
    """Each joint state names the joints and carries the positions and efforts of the sample of its
    stamp; its velocities are the positions' difference from an earlier sample's over the time
    between: the subscriber's previous message, or, where the subscriber missed the bridge's previous
    message (a subscriber may drop one on a busy machine), an earlier sample the bridge published."""
    names = ["slider_1", "slider_2", "slider_3"]
    stamps = sorted(samples)
    previous = None
    assert any(js["effort"] for js in got["joint_states"])  # the drives' 0x6077, mapped in their TPDO
    for js in got["joint_states"]:
        sample = _matching(samples, js["stamp"])
        assert js["name"] == names and js["effort"] == list(efforts_of(sample))
        assert js["position"] == list(positions_of(sample))
        if previous is not None and js["velocity"]:
            earlier = [previous["stamp"], *reversed(stamps[: bisect.bisect_left(stamps, js["stamp"])])]
            assert any(
                js["velocity"]
                == pytest.approx(_difference(js, t, positions_of(samples[t])), rel=1e-9, abs=1e-12)
                for t in earlier
            ), f"velocities {js['velocity']} at {js['stamp']} are no earlier sample's difference"
        previous = js


def _difference(js: dict[str, Any], earlier_stamp_ns: int, earlier_positions: Any) -> list[float]:
    dt_s = (js["stamp"] - earlier_stamp_ns) * 1e-9
    return [(p - p0) / dt_s for p, p0 in zip(js["position"], earlier_positions, strict=True)]


def test_a_ros2_subscriber_gets_the_zenoh_state_in_ros_time_and_the_commands_go_through_the_gate(ros_env):
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
        "actuators.sync_watchdog_s=0.5",
    ]
    robot = robot_from_config(load_config())
    with _process(controller, ros_env, "the controller") as ctl:
        ProcessLines(ctl).next_matching(lambda line: line.startswith("READY"), "the controller ready")
        keys = MonitorKeys.for_robot("cheope", ROBOT_ID)
        offset_ns = query_status(
            client_settings((endpoint,)), RobotSelector("cheope", ROBOT_ID), GENEROUS_S
        ).clock_offset_ns
        assert abs(offset_ns - (time.time_ns() - time.monotonic_ns())) < 1e9  # the same machine's clocks
        with (
            MonitorClient(monitor_settings((endpoint,)), keys) as watch,
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
            states: dict[int, Any] = {}
            while (u := watch.next_update(0.0)) is not None:
                if isinstance(u, StateUpdate):  # ROS time: the controller's clock on its wall clock
                    states[round(u.msg.cycle_monotonic_s * 1e9) + offset_ns] = u.msg
        final = json.loads(ctl.communicate(timeout=GENEROUS_S)[0].decode().splitlines()[-1])
    _check_graph(lines, namespace)
    got = _by_topic(lines)
    _check_description(got, ["slider_1", "slider_2", "slider_3"])
    _check_joint_states(got, states, lambda s: s.positions, lambda s: s.efforts_n)
    for w in got["wrench"]:
        assert w["force"] == list(_matching(states, w["stamp"]).force_n)
    for p in got["tcp/measured"]:
        assert p["position"] == list(_matching(states, p["stamp"]).tcp_m) and p["frame"] == "base"
    for p in got["tcp/reference"]:
        assert p["position"] == pytest.approx(
            _commanded(robot, _matching(states, p["stamp"]).targets), abs=1e-12
        )
    for d in got["/diagnostics"]:
        s = _matching(states, d["stamp"])
        assert (d["values"]["mode"], int(d["values"]["cycle"])) == (s.mode, s.cycle)
        assert d["hardware_id"] == ROBOT_ID and d["name"].endswith(f"controller {ROBOT_ID}")
    stamps = [d["stamp"] for d in got["/diagnostics"]]
    assert stamps and all(b - a >= 1_000_000_000 for a, b in itertools.pairwise(stamps))  # about 1 Hz
    for m in got["robot_markers"]:
        _matching(states, m["stamp"])
        assert m["first_action"] == MARKER_DELETEALL
        assert {"base", "guides", "sliders", "rods", "platform", "tool"} <= set(m["namespaces"])
    assert (
        _one(lines, "pause")["success"] is False
        and "--allow-remote-commands" in _one(lines, "pause")["message"]
    )
    assert _one(lines, "set_force")["successful"] is False
    stop = _one(lines, "stop")
    assert stop["success"] and "stop accepted" in stop["message"]
    assert final["final_mode"] == "DONE" and "INFO: RUNNING -> STOPPING: stop requested" in final["events"]
    events = [e for e in got["/rosout"] if e["name"].endswith("cheope_bridge")]
    assert events and all(
        e["msg"].split("] ", 1)[1] in {ev.split(": ", 1)[1] for ev in final["events"]} for e in events
    )


def test_a_replayed_recording_reaches_a_ros2_node_in_the_recordings_time_with_clock(ros_env, tmp_path):
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from logs import messages as m
    from logs.messages import recorded_efforts
    from logs.reader import iter_decoded
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
    cycles = {d.log_time_ns: d.message for d in iter_decoded(path, [m.TOPIC_CYCLE])}
    namespace = "/cheope_replay"
    with (
        _process(
            [
                sys.executable,
                PROBE,
                "--namespace",
                namespace,
                "--count",
                "5",
                "--sim-time",
                "--timeout",
                str(GENEROUS_S),
            ],
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
    _check_description(got, ["slider_1", "slider_2", "slider_3"])
    _check_joint_states(
        got,
        cycles,
        lambda c: [d.position for d in c.inputs.drives],
        lambda c: recorded_efforts(c.inputs.drives),
    )
    for w in got["wrench"]:
        sensor = _matching(cycles, w["stamp"]).inputs.sensor
        assert (w["force"], w["torque"]) == (list(sensor.force_n), list(sensor.torque_nm))
    for p in got["tcp/measured"]:
        assert p["position"] == list(_matching(cycles, p["stamp"]).state.tcp_measured_m)
    for d in got["/diagnostics"]:
        c = _matching(cycles, d["stamp"])
        assert (d["values"]["mode"], int(d["values"]["cycle"])) == (c.state.mode, c.cycle)
    # a node with use_sim_time follows /clock: its "now" is a recorded stamp, not this machine's time
    now = _one(lines, "now")
    assert (now in cycles and abs(now - time.time_ns()) > 0) or now == 0
    assert now in {js["stamp"] for js in got["joint_states"]} | set(cycles)
    tcp = [line["tf_tcp"] for line in lines if "tf_tcp" in line]
    if tf_message_class() is not None:  # a ROS 2 installation's tf2: the TCP from a tf2 buffer
        assert tcp and any(tcp[0] == list(c.state.tcp_measured_m) for c in cycles.values())
