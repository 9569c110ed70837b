"""Faults the simulated hardware can be told to produce, on a schedule: the specs' grammar and
its kinds are in controller/sim_config/fault_specs.py; here the schedule and what each kind does to
the devices and the bus."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from controller.core.cycle_data import SENSOR_FORCE_SATURATED
from controller.core.periods import DEADLINE_ROUNDING_S
from controller.sim_config.fault_specs import Fault, fault_text, parse_fault
from drivers.pdo_codec import FORCE_N_PER_COUNT, decode_sensor_frame, encode_sensor_frame
from sim_backend.drive import EMCY_FORCED_FAULT

if TYPE_CHECKING:
    from sim_backend.drive import SimulatedDrive
    from sim_backend.force_sensor import SimulatedForceSensor


FLOOD_COB_ID = 0x001
FLOOD_FRAMES_PER_SYNC = 32  # more than a 1 Mbit/s bus carries in 2.5 ms besides the cycle's own frames
NMT_STOP, NMT_ENTER_PRE_OPERATIONAL, NMT_RESET_NODE = 0x02, 0x80, 0x81  # CiA 301 NMT command specifiers
ROGUE_EMCY_BYTES = 3  # an EMCY is 8 bytes (CiA 301)
ROGUE_TPDO_BYTES = 3  # shorter than any drive TPDO mapping with a statusword and a position
SPOOF_COUNTER_OFFSET = 128  # the spoofed sample's counter: as far from the true one as a u8 goes


class FaultSchedule:
    """Which faults are active at a time measured from the first SYNC."""

    def __init__(self, faults: tuple[Fault, ...]) -> None:
        self.faults = faults
        self.t0_s: float | None = None
        self.last_s: float | None = None  # the last SYNC's time (``start``)
        self._fired: set[int] = set()  # the one-shot faults that fired (``first_time``)
        self._acted: set[int] = set()  # the faults active at some SYNC (``missed``)

    @classmethod
    def from_strings(cls, texts: tuple[str, ...]) -> FaultSchedule:
        return cls(tuple(parse_fault(t) for t in texts))

    def start(self, now_s: float) -> None:
        """At every SYNC: the first is t = 0, the last how far the schedule got (``not_reached``)."""
        if self.t0_s is None:
            self.t0_s = now_s
        self.last_s = now_s

    def not_reached(self) -> tuple[str, ...]:
        """The specs (``fault_text``) of the faults whose start came after the last SYNC: they
        injected nothing (a fault at 100 s in a run of 70 passed silently before; the run's summary
        names them)."""
        return tuple(fault_text(self.faults[i]) for i in self._not_reached())

    def missed(self) -> tuple[str, ...]:
        """The specs of the faults the run reached (``not_reached`` names the others) that were
        active at no SYNC where a device or the bus asked for them: they injected nothing either.
        A window that no SYNC fell in (one period long, over a bus whose SYNCs came late around it;
        a ``drop`` while the loop was held up and sent none), or a device that never asked (a
        ``drop`` of a drive that sent no TPDO then)."""
        late = set(self._not_reached())
        return tuple(
            fault_text(f) for i, f in enumerate(self.faults) if i not in self._acted and i not in late
        )

    def _not_reached(self) -> list[int]:
        last = -math.inf if self.last_s is None else self.elapsed(self.last_s)
        return [i for i, f in enumerate(self.faults) if f.start_s > last]

    def elapsed(self, now_s: float) -> float:
        """The schedule's time of ``now_s``, moved on by ``DEADLINE_ROUNDING_S`` (a nanosecond); -inf
        before the first SYNC. A SYNC's time within rounding of a fault's start counts as reached,
        and one within rounding of its end as past it: a window of one period on the cycle grid
        holds one SYNC of it. Read as it was, `stall=0.02@0.005+0.0025` was active at no SYNC in
        simulated time (0.0075 - 0.0025 is 0.004999999999999999, before the window; the next SYNC
        read its end), while the same at 0.0025 and at 0.1 held the loop 8 deadlines (an outside
        tester)."""
        return -math.inf if self.t0_s is None else now_s - self.t0_s + DEADLINE_ROUNDING_S

    def active(self, kind: str, now_s: float, node: int = 0) -> Fault | None:
        """The first fault given of ``kind`` (on ``node``; 0: on any) active at ``now_s``, or None.
        Every one active then counts as acting (``missed``): an on-off fault (``drop``, ``block``,
        ``freeze`` ...) is in force while any of its kind is, and where a value is taken from one
        (``delay``, ``spoof_sensor``, ``rogue_tpdo``), the first given sets it."""
        if not self.faults:  # the common case, asked some twenty times a SYNC
            return None
        found = self.all_active(kind, now_s, node)
        return found[0] if found else None

    def all_active(self, kind: str, now_s: float, node: int = 0) -> list[Fault]:
        """Every fault of ``kind`` (on ``node``; 0: on any) active at ``now_s``, in the order given:
        the kinds whose faults add up (``force``, ``jump``) or each send a frame of their own
        (``nmt_stop``, ``rogue_emcy``, ``unknown_node`` ...)."""
        if not self.faults:
            return []
        t = self.elapsed(now_s)
        out: list[Fault] = []
        for i, f in enumerate(self.faults):
            if f.kind == kind and (node == 0 or f.node == node) and f.active(t):
                self._acted.add(i)
                out.append(f)
        return out

    def first_time(self, kind: str, now_s: float, node: int = 0) -> bool:
        """True when a fault of ``kind`` (on ``node``; 0: on any) is active at ``now_s`` for the first
        time (the one-shot faults: ``drive_fault``, ``reboot``). Every one due then fires with it: two
        given for one time are one event, where the second fired a SYNC later, or, over a window of
        one period, never and was listed as missed (an outside tester)."""
        fired = False
        t = self.elapsed(now_s)
        for i, f in enumerate(self.faults):
            if f.kind == kind and (node == 0 or f.node == node) and f.active(t) and i not in self._fired:
                self._fired.add(i)
                self._acted.add(i)
                fired = True
        return fired

    def with_drift_n(self, now_s: float, force_n: float) -> float:
        """``force_n`` plus what the ``drift`` faults add at ``now_s`` [N]: each its rate times the
        time since its start, up to its duration; after its end, the bias it reached."""
        t = self.elapsed(now_s)
        for i, f in enumerate(self.faults):
            if f.kind == "drift" and t >= f.start_s:
                force_n += f.value * min(t - f.start_s, f.duration_s)
                self._acted.add(i)
        return force_n


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
    schedule.start(now_s)
    for node, drive in zip(drive_ids, plant.drives):
        if schedule.first_time("drive_fault", now_s, node):
            drive.force_fault(EMCY_FORCED_FAULT)
        drive.reported_position_error = _sum_of(schedule.all_active("jump", now_s, node))
        drive.blocked = schedule.active("block", now_s, node) is not None
    sensor = plant.sensor
    if sensor is not None:
        sensor.freeze_counter = schedule.active("freeze", now_s) is not None
        sensor.hold_sample = schedule.active("stuck", now_s) is not None
        sat = schedule.active("saturate", now_s) is not None
        sensor.status_flags = (
            (sensor.status_flags | SENSOR_FORCE_SATURATED)
            if sat
            else (sensor.status_flags & ~SENSOR_FORCE_SATURATED)
        )
        extra_x = schedule.with_drift_n(now_s, _sum_of(schedule.all_active("force", now_s)))
        sensor.extra_force_n = (extra_x, 0.0, 0.0)


def _sum_of(faults: list[Fault]) -> float:
    """The values of ``faults`` added up: two offsets at once are their sum."""
    total = 0.0
    for f in faults:
        total += f.value
    return total


def tpdo_payload(schedule: FaultSchedule, node: int, payload: bytes, now_s: float) -> bytes | None:
    """The payload a drive sends this SYNC: None when dropped, cut short when malformed."""
    dropped = schedule.active("drop", now_s, node) is not None
    malformed = schedule.active("malformed", now_s, node) is not None  # in force inside a drop too
    if dropped:
        return None
    if malformed:
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
    # asked under bus_off too: in force with it, as an on-off fault inside another (not missed)
    error_frames = schedule.active("error_frames", now_s) is not None
    errors = bus_off or error_frames
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
        for nmt in schedule.all_active(kind, now_s):  # each its own command
            frames.append((0x000, bytes((command, nmt.node))))
    for emcy in schedule.all_active("rogue_emcy", now_s):
        frames.append((0x080 + emcy.node, bytes(ROGUE_EMCY_BYTES)))
    for stranger in schedule.all_active("unknown_node", now_s):
        frames += [(0x700 + stranger.node, b"\x05"), (0x180 + stranger.node, bytes(6))]
    if schedule.active("flood", now_s) is not None:
        frames += [(FLOOD_COB_ID, b"")] * FLOOD_FRAMES_PER_SYNC
    return tuple(frames)


def spoofed_sensor_frame(force_payload: bytes, force_x_n: float) -> bytes:
    """Someone else's sample on the sensor's force COB-ID: Fx replaced, its counter out of step.

    Written in the default layout (drivers/pdo_codec.py), which is what the spoofer knows.
    """
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
