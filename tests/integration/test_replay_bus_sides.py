"""``cheope replay FILE --bus``: every recorded frame reaches a listener, in order; ``--only`` plays one side.

The replay runs as its own process, as a user runs it; the listener is a socket of this test on
the same udp_multicast group, with a receive buffer large enough that a busy machine cannot
make it lose frames (logs/replay_bus.py says why a small one can). What the listener cannot get
is the direction: a bus carries none, and every replayed frame arrives as received.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import can
import pytest
from can_traffic import record_traffic
from controller_on_the_bus import SYNC, another_master
from waiting import wait_until

from controller.shell.demo import random_udp_port
from drivers.bus import open_bus, parse_bus_spec

pytestmark = pytest.mark.integration
LISTENER_BUFFER_BYTES = 8 * 2**20


class Listener:
    """Every frame on the group while it runs, on a socket of its own (a thread)."""

    def __init__(self, port: int) -> None:
        self.bus = open_bus(parse_bus_spec("udp_multicast", udp_port=port))
        with socket.socket(fileno=os.dup(self.bus.fileno())) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, LISTENER_BUFFER_BYTES)
        self.frames: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay listener")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.1)
            if msg is not None:
                self.frames.append(msg)
                self.on_frame(msg)

    def on_frame(self, msg: can.Message) -> None:
        """What a listener that answers does with each frame (nothing here)."""

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.bus.shutdown()


def _replay(path: Path, port: int, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "controller",
            "replay",
            str(path),
            "--bus",
            "udp_multicast",
            "--udp-port",
            str(port),
            "--speed",
            "4",
            *extra,
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )


@pytest.mark.parametrize("only", [None, "sent", "received"])
def test_every_frame_of_the_side_replayed_arrives_once_in_order(tmp_path: Path, only: str | None):
    path = tmp_path / "traffic.mcap"
    recorded = record_traffic(path)
    want = [
        (m.arbitration_id, bytes(m.data))
        for _, outgoing, m in recorded
        if only is None or outgoing == (only == "sent")
    ]
    port = random_udp_port()
    listener = Listener(port)
    try:
        # no device on this port; without --live-devices the replay's own read of the recorded devices'
        # type (test_the_controllers_frames_are_not_replayed_onto_live_devices) would reach the listener too
        r = _replay(path, port, "--live-devices", *(("--only", only) if only else ()))
        assert (
            r.returncode == 0
            and r.stdout.startswith(f"sent {len(want)} frames")
            and "0 send errors" in r.stdout
        ), r.stdout + r.stderr
        wait_until(lambda: len(listener.frames) >= len(want), f"{len(want)} replayed frames at the listener")
    finally:
        listener.close()
    assert [(m.arbitration_id, bytes(m.data)) for m in listener.frames] == want
    assert all(m.is_rx for m in listener.frames)  # a bus carries no direction: logs export keeps it


class AnsweringDevice(Listener):
    """An idle CANopen device on the group: answers a read of its device type (0x1000) as node 1."""

    def on_frame(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x601 and bytes(msg.data[:4]) == bytes((0x40, 0x00, 0x10, 0x00)):
            answer = bytes((0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00))  # CiA 402 drive
            self.bus.send(can.Message(arbitration_id=0x581, data=answer, is_extended_id=False))


def test_the_controllers_frames_are_not_replayed_onto_live_devices(tmp_path: Path):
    """An outside tester replayed a contour session onto a live simulator: it enabled the drives and
    ran the contour again, open loop, 62.3 N true at --speed 4 (the limit 60). The replay of the
    controller's side is refused where the recording's devices answer, and so is the devices' side,
    which would answer in their name beside them; with --live-devices both are replayed."""
    path = tmp_path / "traffic.mcap"
    recorded = record_traffic(path)  # node 1 answers an SDO in it: the recording's device
    port = random_udp_port()
    device = AnsweringDevice(port)
    try:
        for only in ((), ("--only", "sent")):
            r = _replay(path, port, *only)
            assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
            assert "the recording's devices answer (node ids 1)" in r.stderr, r.stderr
            assert "SDO answer of node 1 (0x581)" in r.stderr and "--live-devices" in r.stderr
        # the refused runs put nothing recorded on the bus: only their reads of the devices' type
        probes = list(device.frames)
        assert probes and all(
            m.arbitration_id & ~0x7F == 0x600 and bytes(m.data[:4]) == bytes((0x40, 0, 0x10, 0))
            for m in probes
        ), probes
        # the devices' side would answer in node 1's name beside it (an outside tester's fault of a demo)
        r = _replay(path, port, "--only", "received")
        assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
        assert "would answer in their name beside them" in r.stderr and "(node ids 1)" in r.stderr, r.stderr
        r = _replay(path, port, "--live-devices", "--only", "received")
        assert r.returncode == 0 and r.stdout.startswith("sent "), r.stdout + r.stderr
        r = _replay(path, port, "--live-devices", "--only", "sent")
        sent = sum(1 for _, outgoing, _ in recorded if outgoing)
        assert r.returncode == 0 and r.stdout.startswith(f"sent {sent} frames"), r.stdout + r.stderr
    finally:
        device.close()


def test_a_replay_onto_a_bus_with_a_running_master_is_refused(tmp_path: Path):
    path = tmp_path / "traffic.mcap"
    record_traffic(path)
    port = random_udp_port()
    with another_master(parse_bus_spec("udp_multicast", udp_port=port), (SYNC,)):
        r = _replay(path, port)
    assert r.returncode == 2 and "another master is active" in r.stderr and "SYNC (0x080)" in r.stderr, (
        r.stderr
    )


def test_the_devices_side_is_not_replayed_beside_live_devices_and_their_master(tmp_path: Path):
    """An outside tester replayed the devices' side (--only received) onto a running demo's bus: the
    controller took the recorded SDO answers for its drives' and faulted (a second SDO client), a
    quick stop at 17.2 N of true contact force. With a master active the replay only listens (no
    read of its own to reach the master): node 1's heartbeat is enough to refuse it."""
    path = tmp_path / "traffic.mcap"
    record_traffic(path)  # node 1 answers an SDO in it: the recording's device
    port = random_udp_port()
    heartbeat = can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)  # node 1, operational
    listener = Listener(port)
    try:
        with another_master(parse_bus_spec("udp_multicast", udp_port=port), (SYNC, heartbeat)):
            r = _replay(path, port, "--only", "received")
    finally:
        listener.close()
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert "the recording's devices answer (node ids 1)" in r.stderr and "heartbeat" in r.stderr.lower(), (
        r.stderr
    )
    # nothing of the replay's reached the bus: the listener heard only the master's and node 1's frames
    assert {m.arbitration_id for m in listener.frames} <= {0x080, 0x701}, listener.frames
