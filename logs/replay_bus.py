"""``cheope replay FILE --bus INTERFACE:CHANNEL [--speed X] [--only sent|received]``: the recorded frames back on a bus.

Like can-utils' ``canplayer``: every frame goes out at its recorded time relative to the
first one, divided by ``speed`` (absolute deadlines, so the timing does not drift). The
recording holds every frame of the session once, in both directions: the controller's bus tap
(drivers/frame_tap.py) drops the bus's echoes of its own frames, so every recorded frame is
sent once, whatever its direction.

The direction does not survive a bus, by the nature of CAN: a frame carries no sender, and
Rx/Tx is the view of the node that logs it. A listener marks what it did not send itself as
received: on ``udp_multicast`` every replayed frame is Rx; python-can on SocketCAN marks frames
created on its own host as Tx (``MSG_DONTROUTE``), so there a listener beside the replay sees
them all as Tx. What the replay can keep is the side: ``only="sent"`` plays the controller's
frames alone (to drive devices as it did), ``only="received"`` the devices' alone (to play
them to a controller under test). For the frames with their recorded direction use
``cheope logs export`` (logs/can_export.py).

Every frame is handed to the bus (``send_errors`` counts the refusals). ``udp_multicast`` has
no flow control: a listener held off the CPU for longer than its socket's receive buffer lasts
(the default 208 KiB holds about 270 frames, 75 ms of a 400 Hz session) loses frames there, and
python-can's ``can_logger`` writes through a buffered file, so a logger killed rather than
stopped (SIGINT) loses its last lines.
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
from logs.bus_traffic import as_message, recorded_frames
from logs.reader import ReadReport

# a pause between frames waits on the stop up to this long before the frame, then on the clock
STOP_WAIT_MARGIN_S = 2e-3


@dataclass(frozen=True)
class BusReplayResult:
    frames_sent: int
    send_errors: int
    duration_s: float  # wall time of the replay
    report: ReadReport


REPLAY_SIDES = ("sent", "received")  # --only: the controller's frames, or its devices'


def replay_to_bus(
    path: str | Path,
    spec: BusSpec,
    speed: float = 1.0,
    stop_event: threading.Event | None = None,
    progress: Callable[[int], None] | None = None,
    bus: can.BusABC | None = None,
    only: str | None = None,
) -> BusReplayResult:
    """Send the recorded frames of ``path`` onto ``spec`` (or an open ``bus``) with their timing;
    ``only``: "sent" or "received" (by the controller) plays that side alone, its timing kept."""
    if not speed > 0:
        raise ValueError(f"--speed {speed}: must be > 0")
    if only is not None and only not in REPLAY_SIDES:
        raise ValueError(f"--only {only}: must be one of {', '.join(REPLAY_SIDES)}")
    wanted_outgoing = None if only is None else only == "sent"
    path = Path(path)
    report = ReadReport(path)
    stop = stop_event or threading.Event()
    sleeper = DeadlineSleeper(spin_s=2e-4)
    sent = errors = 0
    owns_bus = bus is None
    bus = bus if bus is not None else open_bus(spec)
    t_start = time.monotonic()
    try:
        first_ns: int | None = None
        for f in recorded_frames(path, report):
            if wanted_outgoing is not None and f.outgoing != wanted_outgoing:
                continue
            if first_ns is None:
                first_ns, t_start = f.unix_time_ns, time.monotonic()
            due_s = t_start + (f.unix_time_ns - first_ns) * 1e-9 / speed
            # a stop ends a long pause between two frames at once (--speed 1e-9 waited for ages)
            wait_s = due_s - time.monotonic() - STOP_WAIT_MARGIN_S
            if stop.wait(wait_s) if wait_s > 0 else stop.is_set():
                break
            sleeper.sleep_until(due_s)
            if stop.is_set():
                break
            try:
                bus.send(as_message(f, direction=False), timeout=0.1)
                sent += 1
            except can.CanError:
                errors += 1
            if progress is not None and sent % 500 == 0:
                progress(report.end_offset)
    finally:
        if owns_bus:
            bus.shutdown()
    return BusReplayResult(sent, errors, time.monotonic() - t_start, report)
