"""Faults the simulated hardware can be told to produce, on a schedule.

A fault is written ``KIND[:NODE][=VALUE]@START[+DURATION]``: START seconds after the first
SYNC, for DURATION seconds (default: to the end). NODE is a CANopen node id where the kind
needs one. Kinds:

- ``drop:N``       node N sends no TPDO (a dead or unplugged drive)
- ``delay:N=S``    node N's TPDOs leave S seconds late (in-process: they miss their cycle)
- ``malformed:N``  node N's TPDO has the wrong length (counted and rejected by the controller)
- ``drive_fault:N``  drive N goes to FAULT and sends EMCY 0x5000
- ``heartbeat:N``  node N stops its heartbeat
- ``freeze``       the force sensor's counter stops advancing (stale data)
- ``saturate``     the force sensor reports saturation
- ``force=F``      the force sensor sees an extra F newtons along X (an unexpected contact)
- ``drift=R``      the force sensor's bias drifts by R newtons a second along X (temperature); after
                   DURATION the bias stays where it drifted to
- ``error_frames`` CAN error frames on the bus; ``bus_off`` an error frame reporting bus-off
- ``tx_full``      the controller's frames do not reach the devices (a full transmit queue)
- ``stall=S``      the controller's loop wakes S seconds late every cycle (in-process runs only)

Someone else on the bus (issue "a bus that cannot lie"):

- ``block:N``      drive N's carriage is mechanically stuck (a following error)
- ``jump:N=D``     drive N's encoder reports D (m or rad) more than the carriage is at
- ``reboot:N``     node N restarts: boot-up message, PRE-OPERATIONAL, power state machine from the start
- ``nmt_stop:N``   another master sends NMT "stop" to node N (it goes STOPPED and falls silent)
- ``foreign_sync`` a second SYNC producer: one more SYNC with every SYNC
- ``unknown_node:N``  an unconfigured node N sends heartbeats and TPDOs
- ``flood``        a babbling node floods the bus with frames of COB-ID 0x001
- ``spoof_sensor=F``  a second force frame with F newtons along X and a counter out of step,
  before the true one
- ``rogue_tpdo:N=D``  a second TPDO on drive N's COB-ID reporting D (m or rad) more than the
  drive, before the true answer (D = 0.05: a jump; D = 0.0025: a small offset that tracks it)
- ``rogue_short:N``  a TPDO of the wrong length on drive N's COB-ID, before the true answer
- ``rogue_emcy:N``   an EMCY of the wrong length (3 bytes) on node N's EMCY COB-ID
- ``nmt_preop:N``  another master sends NMT "enter PRE-OPERATIONAL" to node N (it stops
  processing RPDOs; a drive reacts by its 0x6007 abort connection option)
- ``nmt_reset:N``  another master sends NMT "reset node" to node N (it restarts)

Examples: ``drop:2@3.0+0.5``, ``force=100@2``, ``freeze@1.5``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from sim_backend.drive import SimulatedDrive
    from sim_backend.force_sensor import SimulatedForceSensor

from controller.errors import InputError

KINDS_WITH_NODE = (
    "drop",
    "delay",
    "malformed",
    "drive_fault",
    "heartbeat",
    "block",
    "jump",
    "reboot",
    "nmt_stop",
    "nmt_preop",
    "nmt_reset",
    "unknown_node",
    "rogue_tpdo",
    "rogue_short",
    "rogue_emcy",
)
KINDS = (
    *KINDS_WITH_NODE,
    "freeze",
    "saturate",
    "force",
    "drift",
    "error_frames",
    "bus_off",
    "tx_full",
    "stall",
    "foreign_sync",
    "flood",
    "spoof_sensor",
)
DRIVE_ONLY_KINDS = ("drive_fault", "block", "jump", "reboot", "rogue_tpdo", "rogue_short")
FLOOD_COB_ID = 0x001
FLOOD_FRAMES_PER_SYNC = 32  # more than a 1 Mbit/s bus carries in 2.5 ms besides the cycle's own frames
NMT_STOP, NMT_ENTER_PRE_OPERATIONAL, NMT_RESET_NODE = 0x02, 0x80, 0x81  # CiA 301 NMT command specifiers
ROGUE_EMCY_BYTES = 3  # an EMCY is 8 bytes (CiA 301)
ROGUE_TPDO_BYTES = 3  # shorter than any drive TPDO mapping with a statusword and a position
SPOOF_COUNTER_OFFSET = 128  # the spoofed sample's counter: as far from the true one as a u8 goes
_NUMBER = r"[0-9]+(?:\.[0-9]*)?(?:[eE][-+]?[0-9]+)?"
_PATTERN = re.compile(
    rf"^(?P<kind>[a-z_]+)(:(?P<node>\d+))?(=(?P<value>-?{_NUMBER}))?@(?P<start>{_NUMBER})"
    rf"(\+(?P<duration>{_NUMBER}))?$"
)


class FaultSpecError(InputError):
    """A fault description that does not parse; the message shows the expected form."""


@dataclass(frozen=True)
class Fault:
    kind: str
    start_s: float
    duration_s: float = math.inf
    node: int = 0
    value: float = 0.0

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s


def parse_fault(text: str) -> Fault:
    m = _PATTERN.match(text.strip())
    if not m:
        raise FaultSpecError(
            f"fault {text!r}: expected KIND[:NODE][=VALUE]@START[+DURATION], e.g. drop:2@3.0+0.5"
        )
    kind = m["kind"]
    if kind not in KINDS:
        raise FaultSpecError(f"fault {text!r}: unknown kind {kind!r}; known: {', '.join(KINDS)}")
    if kind in KINDS_WITH_NODE and m["node"] is None:
        raise FaultSpecError(f"fault {text!r}: {kind} needs a node id, e.g. {kind}:2@1.0")
    return Fault(
        kind=kind,
        start_s=float(m["start"]),
        duration_s=float(m["duration"]) if m["duration"] else math.inf,
        node=int(m["node"]) if m["node"] else 0,
        value=float(m["value"]) if m["value"] else 0.0,
    )


# A late frame or a late wake-up longer than this is no longer "late": it is a silent node
# (``drop:N``) or a dead controller, and a value like 1e9 s is a typo, not a scenario.
MAX_LATENESS_S = 1.0
MAX_EXTRA_FORCE_N = 10_000.0


def check_fault(
    text: str, drive_nodes: Sequence[int], sensor_node: int | None, period_s: float | None = None
) -> Fault:
    """``parse_fault`` plus what only the configuration knows: the node exists, values are sane,
    and (given the loop's ``period_s``) the fault can fire."""
    f = parse_fault(text)
    if not math.isfinite(f.start_s):
        raise FaultSpecError(f"fault {text!r}: START must be a finite number of seconds")
    # The simulator applies faults at the SYNCs, one a period, timed from the first (t = 0): a
    # window shorter than a period after that may lie between two SYNCs and never fire
    # (rogue_emcy:2@2+0.002 injected nothing at 400 Hz). One that opens at 0 holds the first SYNC.
    if period_s is not None and f.start_s > 0.0 and f.duration_s < period_s:
        raise FaultSpecError(
            f"fault {text!r}: lasts {f.duration_s:g} s, less than one cycle ({period_s:g} s at "
            f"loop.rate_hz = {1.0 / period_s:g}): the simulator applies faults at the SYNCs and "
            f"this one could fall between two of them and never fire; give +DURATION >= {period_s:g}"
        )
    devices = (*drive_nodes, *((sensor_node,) if sensor_node is not None else ()))
    if f.kind == "unknown_node" and (f.node in devices or not 1 <= f.node <= 127):
        raise FaultSpecError(
            f"fault {text!r}: unknown_node takes a node id in 1..127 that is not configured "
            f"(the bus has {', '.join(map(str, devices))})"
        )
    if f.kind in KINDS_WITH_NODE and f.kind != "unknown_node":
        allowed = tuple(drive_nodes) if f.kind in DRIVE_ONLY_KINDS else devices
        if f.node not in allowed:
            known = f"drives {', '.join(map(str, drive_nodes))}" + (
                f" and the sensor {sensor_node}"
                if sensor_node is not None and f.kind not in DRIVE_ONLY_KINDS
                else ""
            )
            what = "a drive" if f.node in devices else "on the bus"
            raise FaultSpecError(f"fault {text!r}: node {f.node} is not {what}; {f.kind} takes {known}")
    if f.kind in ("delay", "stall") and not 0.0 < f.value <= MAX_LATENESS_S:
        raise FaultSpecError(
            f"fault {text!r}: {f.kind} of {f.value:g} s must be in (0, {MAX_LATENESS_S:g}] s; "
            f"a longer silence is drop:N (a node) or a dead controller"
        )
    if f.kind in ("force", "drift") and not abs(f.value) <= MAX_EXTRA_FORCE_N:
        raise FaultSpecError(
            f"fault {text!r}: {f.kind}={f.value:g} is beyond +-{MAX_EXTRA_FORCE_N:g} N (N/s)"
        )
    return f


class FaultSchedule:
    """Which faults are active at a time measured from the first SYNC."""

    def __init__(self, faults: tuple[Fault, ...]) -> None:
        self.faults = faults
        self.t0_s: float | None = None
        self._fired: set[int] = set()

    @classmethod
    def from_strings(cls, texts: tuple[str, ...]) -> FaultSchedule:
        return cls(tuple(parse_fault(t) for t in texts))

    def start(self, now_s: float) -> None:
        if self.t0_s is None:
            self.t0_s = now_s

    def elapsed(self, now_s: float) -> float:
        return -math.inf if self.t0_s is None else now_s - self.t0_s

    def active(self, kind: str, now_s: float, node: int = 0) -> Fault | None:
        t = self.elapsed(now_s)
        for f in self.faults:
            if f.kind == kind and (node == 0 or f.node == node) and f.active(t):
                return f
        return None

    def first_time(self, kind: str, now_s: float, node: int = 0) -> bool:
        """True once, the first time ``kind`` is active (for one-shot faults such as drive_fault)."""
        for i, f in enumerate(self.faults):
            if (
                f.kind == kind
                and (node == 0 or f.node == node)
                and f.active(self.elapsed(now_s))
                and i not in self._fired
            ):
                self._fired.add(i)
                return True
        return False


class FaultableDevices(Protocol):
    """What ``apply_device_faults`` changes: the plant's simulated drives and force sensor."""

    @property
    def drives(self) -> Sequence[SimulatedDrive]: ...

    @property
    def sensor(self) -> SimulatedForceSensor | None: ...


def apply_device_faults(
    schedule: FaultSchedule, plant: FaultableDevices, drive_ids: tuple[int, ...], now_s: float
) -> None:
    """The faults that change the devices themselves, applied at a SYNC (simulator and loopback)."""
    from controller.core.cycle_data import SENSOR_FORCE_SATURATED
    from sim_backend.drive import EMCY_FORCED_FAULT

    schedule.start(now_s)
    for node, drive in zip(drive_ids, plant.drives, strict=True):
        if schedule.first_time("drive_fault", now_s, node):
            drive.force_fault(EMCY_FORCED_FAULT)
        jump = schedule.active("jump", now_s, node)
        drive.reported_position_error = jump.value if jump is not None else 0.0
        drive.blocked = schedule.active("block", now_s, node) is not None
    sensor = plant.sensor
    if sensor is not None:
        sensor.freeze_counter = schedule.active("freeze", now_s) is not None
        sat = schedule.active("saturate", now_s) is not None
        sensor.status_flags = (
            (sensor.status_flags | SENSOR_FORCE_SATURATED)
            if sat
            else (sensor.status_flags & ~SENSOR_FORCE_SATURATED)
        )
        force = schedule.active("force", now_s)
        extra_x = force.value if force is not None else 0.0
        t = schedule.elapsed(now_s)
        for f in schedule.faults:  # a drift keeps the bias it reached when it ends
            if f.kind == "drift" and t >= f.start_s:
                extra_x += f.value * min(t - f.start_s, f.duration_s)
        sensor.extra_force_n = (extra_x, 0.0, 0.0)


def tpdo_payload(schedule: FaultSchedule, node: int, payload: bytes, now_s: float) -> bytes | None:
    """The payload a drive sends this SYNC: None when dropped, cut short when malformed."""
    if schedule.active("drop", now_s, node) is not None:
        return None
    if schedule.active("malformed", now_s, node) is not None:
        return payload[:3]
    return payload


# SocketCAN error classes (linux/can/error.h) of the error frames the simulated bus reports
ERROR_CLASS_CONTROLLER = 0x004
ERROR_CLASS_BUS_OFF = 0x040  # drivers/cyclic_exchange.py CAN_ERR_BUSOFF (a test holds them equal)
ERROR_CLASS_RESTARTED = 0x100  # the controller restarted after a bus-off (CAN_ERR_RESTARTED)
ERROR_CONTROLLER_PASSIVE = 0x30  # data[1] of an ERROR_CLASS_CONTROLLER frame: RX and TX passive


@dataclass(frozen=True)
class BusFaults:
    """What the active faults do to the bus at one SYNC.

    The one decision both simulators render: the simulator process with real frames (no
    heartbeat, an error frame, a late timer), the in-process loopback as the feedback those
    frames would have produced (sim_backend/loopback.py).
    """

    controller_frames_lost: bool = False  # tx_full: the SYNC and RPDOs never reach the devices
    silent_heartbeats: tuple[int, ...] = ()  # nodes whose heartbeat producer stopped
    error_class: int = 0  # 0: none; else the class bits of one error frame sent this SYNC
    delays_s: tuple[tuple[int, float], ...] = ()  # (node, seconds) its TPDO leaves late
    foreign_frames: tuple[tuple[int, bytes], ...] = ()  # (COB-ID, data) someone else sends with this SYNC
    reboots: tuple[int, ...] = ()  # nodes that restart at this SYNC (once)
    spoofed_force_n: float | None = None  # a second force frame with this Fx, counter out of step, first
    rogue_offsets: tuple[tuple[int, float], ...] = ()  # (drive node, D): its TPDO + D, before the true one
    rogue_short: tuple[int, ...] = ()  # drive nodes: a short TPDO on their COB-ID before the true one


NO_BUS_FAULTS = BusFaults()


def bus_faults(schedule: FaultSchedule, now_s: float, node_ids: tuple[int, ...]) -> BusFaults:
    """``node_ids``: every device on the bus (the drives and the sensor), for ``heartbeat:N`` and ``delay:N``."""
    if not schedule.faults:
        return NO_BUS_FAULTS
    bus_off = schedule.active("bus_off", now_s) is not None
    errors = bus_off or schedule.active("error_frames", now_s) is not None
    delays = []
    for n in node_ids:
        d = schedule.active("delay", now_s, n)
        if d is not None:
            delays.append((n, d.value))
    spoof = schedule.active("spoof_sensor", now_s)
    return BusFaults(
        controller_frames_lost=schedule.active("tx_full", now_s) is not None,
        silent_heartbeats=tuple(n for n in node_ids if schedule.active("heartbeat", now_s, n) is not None),
        error_class=(ERROR_CLASS_BUS_OFF if bus_off else ERROR_CLASS_CONTROLLER) if errors else 0,
        delays_s=tuple(delays),
        foreign_frames=_foreign_frames(schedule, now_s),
        reboots=tuple(n for n in node_ids if schedule.first_time("reboot", now_s, n)),
        spoofed_force_n=spoof.value if spoof is not None else None,
        rogue_offsets=tuple(
            (n, f.value) for n in node_ids if (f := schedule.active("rogue_tpdo", now_s, n)) is not None
        ),
        rogue_short=tuple(n for n in node_ids if schedule.active("rogue_short", now_s, n) is not None),
    )


def _foreign_frames(schedule: FaultSchedule, now_s: float) -> tuple[tuple[int, bytes], ...]:
    frames: list[tuple[int, bytes]] = []
    if schedule.active("foreign_sync", now_s) is not None:
        frames.append((0x080, b""))
    for kind, command in (
        ("nmt_stop", NMT_STOP),
        ("nmt_preop", NMT_ENTER_PRE_OPERATIONAL),
        ("nmt_reset", NMT_RESET_NODE),
    ):
        nmt = schedule.active(kind, now_s)
        if nmt is not None:
            frames.append((0x000, bytes((command, nmt.node))))
    emcy = schedule.active("rogue_emcy", now_s)
    if emcy is not None:
        frames.append((0x080 + emcy.node, bytes(ROGUE_EMCY_BYTES)))
    stranger = schedule.active("unknown_node", now_s)
    if stranger is not None:
        frames += [(0x700 + stranger.node, b"\x05"), (0x180 + stranger.node, bytes(6))]
    if schedule.active("flood", now_s) is not None:
        frames += [(FLOOD_COB_ID, b"")] * FLOOD_FRAMES_PER_SYNC
    return tuple(frames)


def spoofed_sensor_frame(force_payload: bytes, force_x_n: float) -> bytes:
    """Someone else's sample on the sensor's force COB-ID: Fx replaced, its counter out of step.

    Written in the default layout (drivers/pdo_codec.py), which is what the spoofer knows.
    """
    from drivers.pdo_codec import FORCE_N_PER_COUNT, decode_sensor_frame, encode_sensor_frame

    _, y, z, status, counter = decode_sensor_frame(force_payload, FORCE_N_PER_COUNT)
    return encode_sensor_frame(
        (force_x_n, y, z), FORCE_N_PER_COUNT, status, (counter + SPOOF_COUNTER_OFFSET) % 256
    )


def nmt_commands(frames: tuple[tuple[int, bytes], ...]) -> list[tuple[int, int]]:
    """(command specifier, node: 0 = all) of the NMT commands among ``frames``."""
    return [(data[0], data[1]) for cob, data in frames if cob == 0x000 and len(data) == 2]


class RogueSource(Protocol):
    """What ``rogue_drive_frames`` reads: the simulated drives and their TPDOs as mapped (device_pdos.py)."""

    def rogue_drive_tpdo(self, j: int, offset: float) -> tuple[int, bytes] | None: ...


def rogue_drive_frames(
    pdos: RogueSource, drive_ids: tuple[int, ...], faults: BusFaults
) -> list[tuple[int, bytes]]:
    """Someone else's frames on the drives' TPDO COB-IDs, to be sent before the true answers:
    the drive's TPDO reporting D more (``rogue_tpdo``), or one of the wrong length (``rogue_short``)."""
    frames: list[tuple[int, bytes]] = []
    for node, offset in faults.rogue_offsets:
        tpdo = pdos.rogue_drive_tpdo(drive_ids.index(node), offset)
        if tpdo is not None:
            frames.append(tpdo)
    for node in faults.rogue_short:
        tpdo = pdos.rogue_drive_tpdo(drive_ids.index(node), 0.0)
        if tpdo is not None:
            frames.append((tpdo[0], tpdo[1][:ROGUE_TPDO_BYTES]))
    return frames
