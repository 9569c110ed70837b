"""A recording holds every frame of the session once, with its direction, set-up traffic included.

A path demo runs over udp_multicast as a user runs it (simulator and controller in their own
processes); a third listener on the same group, as candump would, is the independent witness of
what went over the bus. Only the controller produces NMT commands, SYNC, RPDOs, SDO requests and
its own heartbeat, so the witness can tell the controller's frames by their COB-ID.
"""

from __future__ import annotations

import json
import os
import random
import socket
import subprocess
import sys
import threading
from collections import Counter
from pathlib import Path
from typing import Self

import pytest
from busy_machine import TOLERANT

from controller.config import load_config
from drivers import cob_ids
from drivers.bus import open_bus, parse_bus_spec
from logs import messages as m
from logs.bus_traffic import recorded_traffic
from logs.reader import iter_decoded

pytestmark = pytest.mark.integration
Frame = tuple[int, bytes]


WITNESS_BUFFER_BYTES = 16 * 2**20
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # linux/socket.h


def _enlarge_receive_buffer(fd: int, size: int) -> None:
    """A witness that falls behind must not lose frames: the default buffer (208 KiB) holds about
    270 datagrams, 80 ms of this bus, and a witness thread on a busy 2-core machine can be held off
    longer (CI lost 16 SYNCs once). Past ``rmem_max`` as root (SO_RCVBUFFORCE), else up to it."""
    with socket.socket(fileno=os.dup(fd)) as sock:
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
        except PermissionError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


class Witness:
    """Every frame on the bus while it runs, received on a socket of its own (a thread)."""

    def __init__(self, port: int) -> None:
        self.bus = open_bus(parse_bus_spec("udp_multicast", udp_port=port))
        _enlarge_receive_buffer(self.bus.fileno(), WITNESS_BUFFER_BYTES)
        self.frames: list[Frame] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bus witness")

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.1)
            if msg is not None:
                self.frames.append((msg.arbitration_id, bytes(msg.data)))

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        while (msg := self.bus.recv(timeout=0.0)) is not None:  # what was already in the socket
            self.frames.append((msg.arbitration_id, bytes(msg.data)))
        self.bus.shutdown()


def test_a_path_demo_records_each_frame_once_with_the_sdo_and_nmt_set_up(tmp_path: Path):
    cfg = load_config()
    drives, sensor, me = tuple(cfg.actuators.node_ids), cfg.sensor.node_id, cfg.loop.controller_node_id
    nodes = (*drives, sensor)
    controller_ids = {
        cob_ids.NMT,
        cob_ids.SYNC,
        cob_ids.heartbeat(me),
        *(cob_ids.rpdo1(i) for i in drives),
        *(cob_ids.sdo_request(i) for i in nodes),
    }
    sdo_responses = {cob_ids.sdo_response(i) for i in nodes}
    port = random.SystemRandom().randint(45000, 47999)
    with Witness(port) as witness:
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "controller",
                "demo",
                "--task",
                "path",
                "--json",
                "--no-realtime",
                "--udp-port",
                str(port),
                "--set",
                "task.path.laps=0.25",
                "--set",
                f'recording.directory="{tmp_path}"',
                *TOLERANT,
            ],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    assert r.returncode == 0, r.stderr + r.stdout
    summary = json.loads(r.stdout)
    assert summary["recording"]["dropped"] == 0 and not summary["recording"]["error"]
    path = summary["recording"]["path"]
    recorded = [d.message for d in iter_decoded(path, [m.TOPIC_CAN])]
    sent = Counter((f.arbitration_id, bytes(f.data)) for f in recorded if f.outgoing)
    received = Counter((f.arbitration_id, bytes(f.data)) for f in recorded if not f.outgoing)
    # the controller's session starts with its NMT pre-operational: before it the simulator started
    # (its boot-ups, and its SDO probe whether its node ids are taken: drivers/bus_presence.py)
    first_nmt = next(i for i, (cob, _) in enumerate(witness.frames) if cob == cob_ids.NMT)
    on_bus = Counter(witness.frames[first_nmt:])

    # each frame the controller sent: recorded once as sent, never again as received
    assert {cid for cid, _ in sent} <= controller_ids
    assert not [f for f in received if f[0] in controller_ids]
    assert sent == Counter({f: k for f, k in on_bus.items() if f[0] in controller_ids})
    assert sum(sent.values()) == summary["frames"]["sent"]
    # the bus hands none back (drivers/local_multicast.py)
    assert summary["frames"]["own_echoes_dropped"] == 0
    # the set-up: NMT pre-operational and start, every SDO request answered, all of it recorded
    nmt = [f for f in recorded if f.arbitration_id == cob_ids.NMT]
    assert [(f.outgoing, bytes(f.data)) for f in nmt] == [(True, b"\x80\x00"), (True, b"\x01\x00")]
    requests = sum(k for f, k in sent.items() if f[0] in {cob_ids.sdo_request(i) for i in nodes})
    responses = Counter({f: k for f, k in received.items() if f[0] in sdo_responses})
    assert requests > 4 * len(nodes) and sum(responses.values()) == requests
    assert responses == Counter({f: k for f, k in on_bus.items() if f[0] in sdo_responses})
    # one SYNC per executed cycle
    assert sent[(cob_ids.SYNC, b"")] == summary["cycles"]

    # the recorded bus load is the computed one, at the SYNC rate the loop achieved (without real-time
    # scheduling on a busy machine it skips deadlines); SYNC and RPDOs counted twice would add 40 %
    traffic = recorded_traffic(path)
    assert traffic.planned_load_percent == pytest.approx(summary["bus_load_percent"], abs=0.05)
    # (or less: the first SYNC after skipped deadlines goes out without its RPDOs, shell/loop.py; under
    # the tests' load 7 % less in one run)
    planned = traffic.planned_at_sync_rate_percent
    assert planned is not None and 0.75 * planned <= traffic.load_percent <= 1.05 * planned
    assert traffic.frames_out == sum(sent.values()) and traffic.frames_in == sum(received.values())
