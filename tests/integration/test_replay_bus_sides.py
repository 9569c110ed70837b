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
        r = _replay(path, port, *(("--only", only) if only else ()))
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
