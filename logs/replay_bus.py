"""``cheope replay FILE --bus INTERFACE:CHANNEL [--speed X]``: the recorded frames back on a bus.

Like can-utils' ``canplayer``: every frame goes out at its recorded time relative to the
first one, divided by ``speed`` (absolute deadlines, so the timing does not drift). The
recording holds every frame of the session once, in both directions: the controller's bus tap
(drivers/frame_tap.py) drops the bus's echoes of its own frames, so every recorded frame is
sent once, whatever its direction.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can

from drivers.bus import BusSpec, open_bus
from drivers.pacing import DeadlineSleeper
from logs.bus_traffic import recorded_frames
from logs.reader import ReadReport


@dataclass(frozen=True)
class BusReplayResult:
    frames_sent: int
    send_errors: int
    duration_s: float  # wall time of the replay
    report: ReadReport


def replay_to_bus(path: str | Path, spec: BusSpec, speed: float = 1.0, stop_event: threading.Event | None = None,
                  progress: Callable[[int], None] | None = None, bus: can.BusABC | None = None) -> BusReplayResult:
    """Send the recorded frames of ``path`` onto ``spec`` (or an open ``bus``) with their timing."""
    if not speed > 0:
        raise ValueError(f"--speed {speed}: must be > 0")
    path = Path(path)
    report = ReadReport(path)
    stop = stop_event or threading.Event()
    sleeper = DeadlineSleeper(spin_s=2e-4)
    sent = errors = 0
    owns_bus = bus is None
    bus = bus if bus is not None else open_bus(spec)
    t_start = time.monotonic()
    try:
        first: float | None = None
        for f in recorded_frames(path, report):
            if first is None:
                first, t_start = f.monotonic_s, time.monotonic()
            sleeper.sleep_until(t_start + (f.monotonic_s - first) / speed)
            if stop.is_set():
                break
            msg = can.Message(arbitration_id=f.arbitration_id, data=f.data, is_extended_id=f.arbitration_id > 0x7FF,
                              is_fd=f.is_fd, bitrate_switch=f.bitrate_switch, is_error_frame=f.is_error_frame)
            try:
                bus.send(msg, timeout=0.1)
                sent += 1
            except can.CanError:
                errors += 1
            if progress is not None and sent % 500 == 0:
                progress(report.end_offset)
    finally:
        if owns_bus:
            bus.shutdown()
    return BusReplayResult(sent, errors, time.monotonic() - t_start, report)
