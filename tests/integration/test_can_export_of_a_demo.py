"""A real session's frames in CAN tools: a path demo over udp_multicast, exported, read back, decoded.

Every frame of the recording comes back from each export with its id, data and direction, and
cantools decodes every frame the shipped DBC describes (the cyclic PDOs, SYNC, heartbeats; the
set-up's SDO and NMT frames are not in it).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import can
import cantools
import pytest
from busy_machine import TOLERANT
from can_traffic import DBC

from controller.shell.demo import random_udp_port
from logs.bus_traffic import recorded_frames
from logs.can_export import export_frames

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def demo_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("demo")
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
            str(random_udp_port()),
            "--set",
            "task.path.laps=0.25",
            "--set",
            f'recording.directory="{directory}"',
            *TOLERANT,
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    # DONE or, on a busy shared machine, FAULT (issue 30): either way a complete recording to export
    assert r.returncode in (0, 1) and r.stdout, r.stderr
    recording = json.loads(r.stdout)["recording"]
    assert not recording["error"] and recording["dropped"] == 0
    return Path(recording["path"])


@pytest.mark.parametrize("fmt", ["asc", "blf", "log", "trc"])
def test_every_frame_of_a_demo_comes_back_with_its_direction(demo_recording: Path, tmp_path: Path, fmt: str):
    recorded = [(f.arbitration_id, bytes(f.data), not f.outgoing) for f in recorded_frames(demo_recording)]
    result = export_frames(demo_recording, fmt, tmp_path / f"demo.{fmt}")
    assert result.frames_written == len(recorded) > 1000 and result.frames_not_written == {}
    read = [(m.arbitration_id, bytes(m.data), m.is_rx) for m in can.LogReader(result.output)]
    assert read == recorded


def test_cantools_decodes_every_frame_the_dbc_describes(demo_recording: Path, tmp_path: Path):
    db = cantools.database.load_file(DBC)
    described = {m.frame_id for m in db.messages}
    out = export_frames(demo_recording, "asc", tmp_path / "demo.asc").output
    decoded = 0
    names = set()
    for msg in can.LogReader(out):
        if msg.arbitration_id in described:
            db.decode_message(msg.arbitration_id, msg.data)  # raises on a frame that does not fit
            names.add(db.get_message_by_frame_id(msg.arbitration_id).name)
            decoded += 1
    assert decoded > 1000
    assert {
        "SYNC",
        "Drive1_RPDO1",
        "Drive1_TPDO1",
        "ForceSensor_TPDO1",
        "ForceSensor_TPDO2",
        "Controller_Heartbeat",
        "NMT",
    } <= names
