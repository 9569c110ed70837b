"""One master per bus, one device per node id (issue 38, item 4; drivers/bus_presence.py).

Before, a second ``cheope run`` on the same port faulted the running controller with its NMT
pre-operational and then drove the robot itself; a second simulator faulted a running robot too.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import can
import pytest
from busy_machine import TOLERANT, how_the_run_ended
from controller_on_the_bus import SYNC, another_master
from waiting import GENEROUS_S, wait_until

from controller.config import load_config
from controller.shell.demo import random_udp_port, simulator_process, stop_process
from drivers.bus import open_bus, parse_bus_spec
from drivers.bus_presence import (
    NodeIdsTakenError,
    OtherMasterError,
    check_no_other_master,
    check_node_ids_free,
)

pytestmark = pytest.mark.integration

QUIET = ["--set", "monitoring.enabled=false", "--set", "recording.enabled=false"]


def _cheope(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "controller", *args], capture_output=True, text=True, timeout=GENEROUS_S
    )


def test_a_running_controller_is_heard_and_its_devices_too_and_it_runs_on() -> None:
    """The checks themselves against a real run: they send nothing, so the run goes on to DONE."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    cfg = load_config()
    with simulator_process(spec, None, ["task.path.laps=3"]), open_bus(spec) as bus:
        ctrl = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "controller",
                "run",
                "--json",
                "--no-realtime",
                "--udp-port",
                str(spec.udp_port),
                "--set",
                "task.path.laps=3",
                *QUIET,
                *TOLERANT,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:

            def syncing() -> bool:
                assert ctrl.poll() is None, ctrl.communicate()
                msg = bus.recv(0.1)
                return msg is not None and msg.arbitration_id == 0x080

            wait_until(syncing, "the controller's SYNC", poll_s=0.0)
            with pytest.raises(OtherMasterError) as master:
                check_no_other_master(bus, spec.place, cfg.loop.controller_node_id, cfg.bus.presence_listen_s)
            assert f"another master is active on {spec.place}" in str(master.value)
            assert "SYNC (0x080)" in str(master.value) and "RPDO1 to node 1 (0x201)" in str(master.value)
            with pytest.raises(NodeIdsTakenError) as taken:
                check_node_ids_free(bus, spec.place, (1, 2, 3, 16), (1, 2, 3, 16), cfg.bus.presence_listen_s)
            assert "node id(s) 1, 2, 3, 16 already answer" in str(taken.value)
            assert "TPDO1 of node 1 (0x181)" in str(taken.value)
            ctrl.send_signal(signal.SIGTERM)
            out, err = ctrl.communicate(timeout=GENEROUS_S)
            assert ctrl.returncode == 0 and json.loads(out)["final_mode"] == "DONE", how_the_run_ended(
                out, err
            )
        finally:
            stop_process(ctrl)


def test_cheope_run_refuses_a_bus_with_another_master_and_sends_nothing() -> None:
    """A master heard by its SYNC and its heartbeat on node 100 (a live controller of the same node id)."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    sent_by_run: list[int] = []
    heartbeat_100 = can.Message(arbitration_id=0x764, data=b"\x05", is_extended_id=False)
    with open_bus(spec) as listener:
        with another_master(spec, (SYNC, heartbeat_100)):
            r = _cheope("run", "--no-realtime", "--udp-port", str(spec.udp_port), *QUIET)
        while (msg := listener.recv(0.0)) is not None:
            if msg.arbitration_id not in (0x080, 0x764):
                sent_by_run.append(msg.arbitration_id)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("cheope run: refused: another master is active on udp_multicast:")
    assert "SYNC (0x080)" in r.stderr and "heartbeat of node 100, this controller's node id" in r.stderr
    assert r.stderr.count("\n") == 1 and sent_by_run == []  # one line; not a frame of its own


def test_a_second_simulator_with_the_same_node_ids_is_refused_one_with_others_starts() -> None:
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    with simulator_process(spec, None, []):
        r = _cheope("sim", "--no-realtime", "--udp-port", str(spec.udp_port))
        assert r.returncode == 2, r.stdout + r.stderr
        assert "refused: node id(s) 1, 2, 3, 16 already answer on" in r.stderr
        assert "SDO answer of node 1 (0x581)" in r.stderr and r.stderr.count("\n") == 1
        others = ["actuators.node_ids=[4, 5, 6]", "sensor.node_id=17"]
        with simulator_process(spec, None, others) as proc:
            assert proc.poll() is None  # READY: devices of other ids may share the bus
            stop_process(proc)


def test_cheope_nodes_refuses_a_bus_with_a_running_master_and_sends_nothing() -> None:
    """An outside tester's ``cheope nodes`` beside a running demo faulted its controller mid-contour
    ("a second master", the scan's SDO requests) and printed a wrong table, exit 0."""
    spec = parse_bus_spec("udp_multicast", udp_port=random_udp_port())
    sent_by_nodes: list[int] = []
    with open_bus(spec) as listener:
        with another_master(spec, (SYNC,)):
            r = _cheope("nodes", "--udp-port", str(spec.udp_port))
        while (msg := listener.recv(0.0)) is not None:
            if msg.arbitration_id != 0x080:
                sent_by_nodes.append(msg.arbitration_id)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "refused: another master is active on udp_multicast:" in r.stderr and "SYNC (0x080)" in r.stderr
    assert r.stdout == "" and sent_by_nodes == []
