"""A recording of CAN traffic made by the project's recorder, for the export and bus-replay tests.

40 cycles of the shipped DBC's frames as the controller's tap sees them: its RPDOs and SYNC
(sent), the drives' and the sensor's TPDOs (received), after one SDO exchange; times on a
known monotonic clock at odd microseconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import can
import cantools

from drivers.node_setup import EDS_DIR
from logs.recorder import SessionRecorder

DBC = EDS_DIR.parent / "dbc" / "cheope.dbc"
T0_S = 12_345.678901  # the controller's monotonic clock at the first frame
PERIOD_S = 0.0025
RecordedTraffic = list[tuple[float, bool, can.Message]]  # (monotonic time, sent by the controller, frame)


def _cycle_frames(db: cantools.database.Database, k: int) -> list[tuple[bool, can.Message]]:
    """(outgoing, frame) of one cycle as the controller's tap sees it."""

    def frame(name: str, values: dict[str, float]) -> can.Message:
        msg = db.get_message_by_name(name)
        return can.Message(arbitration_id=msg.frame_id, data=msg.encode(values), is_extended_id=False)

    out = [
        frame(
            f"Drive{j}_RPDO1",
            {s.name: s.minimum or 0 for s in db.get_message_by_name(f"Drive{j}_RPDO1").signals},
        )
        for j in (1, 2, 3)
    ]
    out.append(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))  # SYNC
    received = [
        frame(
            f"Drive{j}_TPDO1",
            {s.name: s.minimum or 0 for s in db.get_message_by_name(f"Drive{j}_TPDO1").signals},
        )
        for j in (1, 2, 3)
    ]
    received.append(
        can.Message(arbitration_id=0x190, data=bytes([k % 256, 1, 2, 3, 4, 5, 6, 7]), is_extended_id=False)
    )
    return [(True, f) for f in out] + [(False, f) for f in received]


def record_traffic(path: Path, extra: Sequence[tuple[bool, can.Message]] = ()) -> RecordedTraffic:
    """A recording of 40 cycles of traffic (and ``extra`` frames at the end); returns what went in."""
    db = cantools.database.load_file(DBC)
    now = [T0_S]
    frames: RecordedTraffic = []
    recorder = SessionRecorder(path, {"cheope.session": {"task": "path"}}, clock=lambda: now[0])
    with recorder:
        setup = [
            (
                True,
                can.Message(
                    arbitration_id=0x601, data=bytes([0x40, 0x18, 0x10, 1, 0, 0, 0, 0]), is_extended_id=False
                ),
            ),
            (
                False,
                can.Message(
                    arbitration_id=0x581,
                    data=bytes([0x43, 0x18, 0x10, 1, 0x9A, 0, 0, 0]),
                    is_extended_id=False,
                ),
            ),
        ]
        cycles = [f for k in range(40) for f in _cycle_frames(db, k)]
        for i, (outgoing, msg) in enumerate([*setup, *cycles, *extra]):
            t = T0_S + i * PERIOD_S / 9 + (i % 7) * 1.3e-6  # odd microseconds, not a grid
            recorder.on_frame(outgoing, t, msg)
            frames.append((t, outgoing, msg))
    return frames
