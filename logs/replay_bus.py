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

The controller's frames drive devices: played onto a bus where the recorded drives answer, they
enable them and stream the recorded targets, open loop, with no controller watching (an outside
tester re-ran a contour on a live simulator so, 62.3 N of true contact force at ``--speed 4``
where the limit is 60). So before sending the controller's frames (``only`` None or "sent") the
replay listens ``listen_s`` for another master (``bus_presence.masters_heard``) and for devices
with the node ids the recording's devices had (``devices_heard``: their frames, or an answer to a
read of their device type), and refuses either (``LiveDevicesError``, exit 2)
unless ``live_devices``: ``--live-devices`` says the devices are meant to move.

The devices' frames (``only`` "received") impersonate the recording's devices: played beside
those devices live, two nodes answer with one id, and a master there takes the recorded SDO
answers and TPDOs for its devices' (an outside tester's replay of the devices' side onto a
running demo's bus faulted it: "SDO answer to a request the controller did not send", a quick
stop at 17.2 N of true contact force). So that side is refused where the recording's devices
are heard (``refuse_impersonation``: their frames, or with no master active their answer to a
read of their device type) unless ``live_devices``; a master alone is what it is meant for.

Every frame is handed to the bus (``send_errors`` counts the refusals). ``udp_multicast`` has
no flow control: a listener held off the CPU for longer than its socket's receive buffer lasts
(the default 208 KiB holds about 270 frames, 75 ms of a 400 Hz session) loses frames there, and
python-can's ``can_logger`` writes through a buffered file, so a logger killed rather than
stopped (SIGINT) loses its last lines.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can

from controller.errors import RefusedError
from drivers.bus import BusSpec, open_bus
from drivers.bus_presence import described, device_frame, devices_heard, masters_heard
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
DEVICE_IDS_FROM_FRAMES = 20_000  # the recording's devices: from its first frames (set-up, heartbeats)
ANY_NODE = frozenset(range(1, 128))  # CANopen's node ids


class LiveDevicesError(RefusedError):
    """The controller's recorded frames would drive devices that answer on the bus (module text)."""


def recorded_device_ids(path: Path, frames: int = DEVICE_IDS_FROM_FRAMES) -> frozenset[int]:
    """The node ids of the devices in the first ``frames`` frames of ``path``: those that sent a TPDO,
    an EMCY, an SDO answer or a heartbeat."""
    ids: set[int] = set()
    for k, frame in enumerate(recorded_frames(path, ReadReport(path))):
        if k >= frames:
            break
        if not frame.outgoing and not frame.is_extended_id and device_frame(frame.arbitration_id, ANY_NODE):
            ids.add(frame.arbitration_id & 0x7F)
    return frozenset(ids)


def refuse_live_devices(bus: can.BusABC, where: str, device_ids: frozenset[int], listen_s: float) -> None:
    """``LiveDevicesError`` when a master, or a device with one of ``device_ids``, is on ``bus``."""
    heard = masters_heard(bus, controller_node_id=0, listen_s=listen_s)  # node 0 has no heartbeat
    who = "another master is active"
    if not heard:
        heard, who = _recording_devices_heard(bus, device_ids, listen_s)
    if heard:
        raise LiveDevicesError(
            f"{who} on {where}, heard {described(heard, listen_s)}: the controller's recorded frames "
            "would drive them open loop, with no controller watching; no recorded frame was sent. Replay onto a bus "
            "without them, only the devices' side (--only received) where the recording's devices do not "
            "answer, or pass --live-devices to drive them"
        )


def refuse_impersonation(bus: can.BusABC, where: str, device_ids: frozenset[int], listen_s: float) -> None:
    """``LiveDevicesError`` when a device with one of ``device_ids`` is on ``bus``: the devices' recorded
    frames would answer in its name beside it (module text)."""
    heard, who = _recording_devices_heard(bus, device_ids, listen_s)
    if heard:
        raise LiveDevicesError(
            f"{who} on {where}, heard {described(heard, listen_s)}: their recorded frames would answer in "
            "their name beside them, two nodes of one id, and a master there would take the recorded ones for "
            "its devices'; no recorded frame was sent. Replay the devices' side onto a bus where they do not "
            "answer, or pass --live-devices to send it beside them"
        )


def _recording_devices_heard(
    bus: can.BusABC, device_ids: frozenset[int], listen_s: float
) -> tuple[Counter[tuple[str, int]], str]:
    """The frames of the recording's devices heard on ``bus`` (``devices_heard``), and who answered
    in the refusals' words."""
    heard = devices_heard(bus, device_ids, device_ids, listen_s) if device_ids else Counter()
    answering = sorted({cob_id & 0x7F for _, cob_id in heard})
    return heard, f"the recording's devices answer (node ids {', '.join(map(str, answering))})"


def replay_to_bus(
    path: str | Path,
    spec: BusSpec,
    speed: float = 1.0,
    stop_event: threading.Event | None = None,
    progress: Callable[[int], None] | None = None,
    bus: can.BusABC | None = None,
    only: str | None = None,
    live_devices: bool = False,
    listen_s: float = 0.3,
) -> BusReplayResult:
    """Send the recorded frames of ``path`` onto ``spec`` (or an open ``bus``) with their timing;
    ``only``: "sent" or "received" (by the controller) plays that side alone, its timing kept.
    The controller's frames go onto a bus with a master or the recording's devices on it only with
    ``live_devices`` (module text); ``listen_s``: how long to listen for them."""
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
        if not live_devices:
            refuse = refuse_impersonation if wanted_outgoing is False else refuse_live_devices
            refuse(bus, spec.place, recorded_device_ids(path), listen_s)
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
