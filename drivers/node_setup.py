"""Start-up configuration of the drives and the sensor with the canopen package (NMT, SDO).

This runs once, before the cyclic loop, with canopen's notifier thread reading the bus;
the notifier is stopped afterwards so the loop owns the bus alone.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import can
import canopen
from canopen.objectdictionary import ODVariable

from controller.core.cia402 import (
    MODE_CYCLIC_SYNC_POSITION,
    FaultResetConfig,
)
from controller.errors import DeviceError
from drivers.cob_ids import SYNC
from drivers.fault_reset import FaultResetError, reset_fault
from drivers.homing import HomingError, HomingPlan, home_drive
from drivers.pdo_codec import RATED_TORQUE, TORQUE_ACTUAL, DriveCodec, SensorFrameCodec
from drivers.pdo_mapping import (
    COB_ID_INVALID,
    COB_ID_MASK,
    TRANSMISSION_SYNCHRONOUS,
    DeviceDescriptionError,
    MappedObject,
    PdoConfig,
    PdoDirection,
    PdoMappingError,
    find_variable,
    layout,
    load_device_description,
    planned_pdo,
    remap_writes,
)
from drivers.sim_environment import (
    ABORT_DEVICE_STATE,
    ABORT_OBJECT_DOES_NOT_EXIST,
    ABORT_VALUE_RANGE_CODE,
    ENVIRONMENT_CODES,
    ENVIRONMENT_NAMES,
    SIM_ENVIRONMENT_INDEX,
    SIM_ENVIRONMENT_SUBINDEX,
    mismatch_message,
)

log = logging.getLogger(__name__)

EDS_DIR = Path(__file__).resolve().parent / "eds"
DRIVE_EDS = EDS_DIR / "cheope_drive.eds"
SENSOR_EDS = EDS_DIR / "force_sensor.eds"


R = TypeVar("R")


class NodeSetupError(DeviceError, RuntimeError):
    """A device did not answer, or answered with the wrong identity or configuration."""


class SetupStoppedError(NodeSetupError):
    """A stop was requested (a signal, ``cheope stop``) while the nodes were being set up."""


@dataclass(frozen=True)
class NodeOptions:
    """One node's own set-up values (controller/node_plan.py resolves them from the configuration)."""

    boot_timeout_s: float = 5.0  # how long it may take to answer SDO at all (it may still be booting)
    boot_retries: int = 0  # then an NMT reset node and as long again, this many times
    sdo_timeout_s: float = 1.0  # each SDO response; canopen's 0.3 s default is short for slow machines
    sdo_retries: int = 0  # an SDO that timed out or was aborted as transient (TRANSIENT_ABORTS), again
    revision: int | None = None  # 0x1018 sub 3 (None: not checked)
    serial: int | None = None  # 0x1018 sub 4
    supervision: str = "heartbeat"  # a drive's: "heartbeat" (0x1016/0x1017) or "guarding" (0x100C/0x100D)
    guard_time_s: float = 0.1
    life_time_factor: int = 3
    pdo_mapping: str = "write"  # a drive's: "write" the mapping, or "read" it as the drive has it
    fault_reset: FaultResetConfig = field(default_factory=FaultResetConfig)
    fault_reset_timeout_s: float = 2.0  # loop.enable_timeout_s: the fault reset's time at set-up


@dataclass(frozen=True)
class NodeSetupPlan:
    drive_ids: tuple[int, ...]
    sensor_id: int | None
    vendor_id: int
    drive_product_code: int
    sensor_product_code: int
    controller_id: int
    heartbeat_period_s: float
    heartbeat_consumer_s: float
    cycle_period_s: float = (
        0.0  # the SYNC period: 0x1006 and the drives' interpolation time period (0: not written)
    )
    drive_eds: Path = DRIVE_EDS
    sensor_eds: Path = SENSOR_EDS
    sensor_vendor_id: int | None = None  # None: vendor_id
    drive_rpdo_objects: tuple[str, ...] = ()  # "0x607A", "0x2000:1"; empty: the EDS's default mapping
    drive_tpdo_objects: tuple[str, ...] = ()
    # each drive's CiA 402 homing (None: that drive does not home), before the PDOs start
    homing: tuple[HomingPlan | None, ...] | None = None
    following_error_window_counts: int = 0  # 0x6065 (0: not written; the EDS must have it)
    following_error_time_ms: int = 0  # 0x6066
    # 0x2010: periods a drive runs on past its last target without a new one (None: not written)
    extrapolation_periods: int | None = None
    # 0x2011: the drives' SYNC watchdog in ms (None: not written, each keeps its own)
    sync_watchdog_ms: int | None = None
    # announced to a simulated sensor (drivers/sim_environment.py): "free", "workpiece"; None: not announced
    sim_environment: str | None = None
    task_kind: str = ""  # named when the simulator refuses the environment
    nodes: Mapping[int, NodeOptions] = field(default_factory=dict)  # by node id; missing: NodeOptions()

    def options(self, node_id: int) -> NodeOptions:
        return self.nodes.get(node_id, NodeOptions())

    def guarded(self) -> dict[int, tuple[float, int]]:
        """The drives supervised by node guarding: node -> (guard time [s], life time factor)."""
        return {
            n: (o.guard_time_s, o.life_time_factor)
            for n in self.drive_ids
            if (o := self.options(n)).supervision == "guarding"
        }


@dataclass(frozen=True)
class NodeIdentity:
    node_id: int
    vendor_id: int
    product_code: int
    revision: int
    serial: int


@dataclass(frozen=True)
class NodeSetupReport:
    identities: tuple[NodeIdentity, ...]
    initial_positions_counts: tuple[int, ...]
    duration_s: float
    drive_codecs: tuple[DriveCodec, ...] = ()  # from each drive's mapping as read back
    sensor_codecs: tuple[SensorFrameCodec, SensorFrameCodec] | None = None
    # what the set-up met and handled beyond the plain sequence: a late boot, an NMT reset, SDO
    # retries, a fault reset, homing skipped (one line each, also logged)
    notes: tuple[str, ...] = ()


def interpolation_time_period(period_s: float) -> tuple[int, int]:
    """Object 0x60C2 for ``period_s``: (value, index) with value x 10^index s, value an UNSIGNED8.

    CiA 402 gives the interpolation time period as an UNSIGNED8 mantissa and an INTEGER8 power
    of ten; 2.5 ms is (25, -4), 1 ms (1, -3). The coarsest exact form is chosen; a period with
    no exact form (1/300 s) gets the finest one that fits in 8 bits (33 x 10^-4 s).
    """
    finest: tuple[int, int] | None = None
    for index in range(-1, -10, -1):
        value = period_s / 10.0**index
        if round(value) > 255:
            break
        if round(value) > 0:
            finest = (round(value), index)
            if abs(value - round(value)) < 1e-6 * value:
                return finest
    if finest is None:
        raise ValueError(
            f"interpolation time period {period_s} s cannot be written as an 8-bit value x 10^index s"
        )
    return finest


# SDO aborts that say "not now", not "never" (CiA 301): retried under sdo_retries, as a timeout is.
ABORT_TRANSFER = 0x08000020  # data cannot be transferred or stored to the application
ABORT_LOCAL_CONTROL = 0x08000021  # ... because of local control
ABORT_SDO_TIMEOUT = 0x05040000  # SDO protocol timed out
TRANSIENT_ABORTS = frozenset((ABORT_TRANSFER, ABORT_LOCAL_CONTROL, ABORT_SDO_TIMEOUT))
ABORT_READ_ONLY = 0x06010002  # attempt to write a read only object (a fixed PDO mapping)
NMT_RESET_NODE = 0x81
NMT_ENTER_PRE_OPERATIONAL = 0x80

# What a refusal of these objects most likely means, and the configuration that handles it.
_HINTS: dict[tuple[int, int], str] = {
    (
        0x2010,
        ABORT_VALUE_RANGE_CODE,
    ): "more periods of extrapolation than the drive allows: lower actuators.extrapolation_s",
    (
        0x2011,
        ABORT_VALUE_RANGE_CODE,
    ): "a SYNC watchdog time the drive does not take: change actuators.sync_watchdog_s",
    (0x1017, ABORT_OBJECT_DOES_NOT_EXIST): 'a drive without heartbeat: actuators.supervision = "guarding"',
    (0x1016, ABORT_OBJECT_DOES_NOT_EXIST): 'a drive without heartbeat: actuators.supervision = "guarding"',
    (
        0x100C,
        ABORT_OBJECT_DOES_NOT_EXIST,
    ): 'a drive without node guarding: actuators.supervision = "heartbeat"',
    (
        0x100D,
        ABORT_OBJECT_DOES_NOT_EXIST,
    ): 'a drive without node guarding: actuators.supervision = "heartbeat"',
    (
        0x6060,
        ABORT_VALUE_RANGE_CODE,
    ): "a drive without this mode of operation (homing: actuators.homing_method = 0 for it, [[node]])",
}


def refusal_hint(index: int, code: int) -> str:
    """ " (what it likely means: the configuration that handles it)" for an abort of a write, or ""."""
    mapping = 0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF
    if mapping and code in (ABORT_READ_ONLY, ABORT_DEVICE_STATE):
        return ' (a fixed PDO mapping: actuators.pdo_mapping = "read")'
    if code in TRANSIENT_ABORTS:
        return " (refused for now, not for good: loop.sdo_retries)"
    hint = _HINTS.get((index, code))
    return f" ({hint})" if hint else ""


class _Device:
    """One node during the set-up: checked SDO reads and writes with the node's retries, named in
    every error, and the notes of what was handled."""

    def __init__(
        self,
        node: canopen.RemoteNode,
        node_id: int,
        opts: NodeOptions,
        notes: list[str],
        stop: threading.Event | None = None,
    ) -> None:
        self.node = node
        self.node_id = node_id
        self.opts = opts
        self.notes = notes
        self.retried = 0
        self.stop = stop  # set: the set-up ends at its next wait (boot, homing), SetupStoppedError

    def check_stop(self, during: str) -> None:
        if self.stop is not None and self.stop.is_set():
            raise SetupStoppedError(
                f"node {self.node_id}: stopped on request during {during}; no drive left enabled"
            )

    def sleep(self, seconds: float) -> None:
        """A wait of the set-up that a stop request ends at once (homing's polls)."""
        if self.stop is not None:
            self.stop.wait(seconds)
        else:
            time.sleep(seconds)
        self.check_stop("homing")

    def note(self, text: str, level: int = logging.INFO) -> None:
        log.log(level, "%s", text)
        self.notes.append(text)

    def _sdo(self, call: Callable[[], R], what: str) -> R:
        """``call`` (one SDO transfer) with the node's retries for timeouts and transient aborts."""
        tries = self.opts.sdo_retries + 1
        for k in range(tries):
            try:
                return call()
            except canopen.SdoCommunicationError as err:
                last: Exception = err
            except canopen.SdoAbortedError as err:
                if err.code not in TRANSIENT_ABORTS:
                    raise
                last = err
            if k + 1 < tries:
                self.retried += 1
                log.info("node %d: %s: %s; again (%d of %d)", self.node_id, what, last, k + 1, tries - 1)
        assert last is not None
        if isinstance(last, canopen.SdoCommunicationError):
            raise NodeSetupError(
                f"node {self.node_id}: {what}: no answer within {self.opts.sdo_timeout_s} s"
                + (f", {tries} tries" if tries > 1 else "")
                + f" ({last}; loop.sdo_timeout_s, loop.sdo_retries)"
            ) from last
        raise last

    def upload(self, index: int, subindex: int) -> bytes:
        data: bytes = self._sdo(
            lambda: self.node.sdo.upload(index, subindex), f"reading 0x{index:04X}sub{subindex}"
        )
        return data

    def download(self, index: int, subindex: int, data: bytes) -> None:
        self._sdo(
            lambda: self.node.sdo.download(index, subindex, data), f"writing 0x{index:04X}sub{subindex}"
        )

    def variable(self, index: int, subindex: int) -> ODVariable:
        var = find_variable(self.node.object_dictionary, index, subindex)
        if var is None:
            raise NodeSetupError(
                f"node {self.node_id}: 0x{index:04X}sub{subindex} is not in its device description"
            )
        return var

    def has(self, index: int, subindex: int = 0) -> bool:
        return find_variable(self.node.object_dictionary, index, subindex) is not None

    def write(self, index: int, subindex: int, value: int) -> None:
        """One SDO download; an abort names the node, the object, the value, the abort and, where
        it points at a known habit of drives, the configuration that handles it."""
        var = self.variable(index, subindex)
        try:
            self.download(index, subindex, var.encode_raw(value))
        except canopen.SdoAbortedError as err:
            raise NodeSetupError(
                f"node {self.node_id}: writing 0x{index:04X}sub{subindex} = 0x{value & 0xFFFFFFFF:X} "
                f"refused: {err}{refusal_hint(index, err.code)}"
            ) from err

    def read(self, index: int, subindex: int) -> int:
        var = self.variable(index, subindex)
        try:
            value = var.decode_raw(self.upload(index, subindex))
        except canopen.SdoAbortedError as err:
            raise NodeSetupError(
                f"node {self.node_id}: reading 0x{index:04X}sub{subindex} refused: {err}"
                f"{refusal_hint(index, err.code)}"
            ) from err
        if not isinstance(value, int):
            raise NodeSetupError(
                f"node {self.node_id}: 0x{index:04X}sub{subindex} is not an integer ({value!r})"
            )
        return value

    def write_verified(self, index: int, subindex: int, value: int) -> None:
        self.write(index, subindex, value)
        self.check_reads(index, subindex, value)

    def check_reads(self, index: int, subindex: int, value: int) -> None:
        back = self.read(index, subindex)
        if back != value:
            raise NodeSetupError(
                f"node {self.node_id}: 0x{index:04X}sub{subindex} reads back 0x{back & 0xFFFFFFFF:X}, "
                f"wrote 0x{value & 0xFFFFFFFF:X}"
            )


def _answers(device: _Device, timeout_s: float) -> Exception | None:
    """None once the node answers an SDO request within ``timeout_s``, else the last error."""
    deadline = time.monotonic() + timeout_s
    last: Exception | None = TimeoutError(f"no answer within {timeout_s} s")
    while time.monotonic() < deadline:
        device.check_stop("its boot")  # a node that never answers is waited for boot_timeout_s x retries
        try:
            device.node.sdo.upload(0x1000, 0)
            return None
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            last = err
    return last


def _wait_until_answering(device: _Device, network: canopen.Network) -> None:
    """Until the node answers SDO, for its boot timeout; then, as often as its boot retries allow, an
    NMT reset node (a node that boots only when told to) and the boot timeout again."""
    opts, node_id = device.opts, device.node_id
    t0 = time.monotonic()
    for attempt in range(opts.boot_retries + 1):
        if attempt:
            network.send_message(0x000, bytes((NMT_RESET_NODE, node_id)))  # NMT reset node
            device.note(
                f"node {node_id}: no SDO answer within {opts.boot_timeout_s} s: NMT reset node sent "
                f"({attempt} of {opts.boot_retries}, loop.boot_retries)"
            )
        last = _answers(device, opts.boot_timeout_s)
        if last is None:
            waited = time.monotonic() - t0
            if attempt:
                device.note(
                    f"node {node_id}: answers after the NMT reset ({waited:.1f} s after the first request)"
                )
            elif waited > 0.5:
                device.note(f"node {node_id}: booted late: first SDO answer after {waited:.1f} s")
            if attempt:
                # a node reset by us has restarted its NMT state machine: back to PRE-OPERATIONAL
                network.send_message(0x000, bytes((NMT_ENTER_PRE_OPERATIONAL, node_id)))
            return
    raise NodeSetupError(
        f"node {node_id} did not answer SDO requests within {opts.boot_timeout_s} s"
        + (f" after each of {opts.boot_retries} NMT reset(s)" if opts.boot_retries else "")
        + f" ({last}): not booted, or not on the bus (a node slow to boot: loop.boot_timeout_s; one that "
        "boots only after an NMT reset: loop.boot_retries)"
    )


def _write_interpolation_period(device: _Device, period_s: float) -> None:
    """0x60C2: the drive interpolates each target over this time (index first: no transient 2.5 s)."""
    value, index = interpolation_time_period(period_s)
    device.write_verified(0x60C2, 2, index)
    device.write_verified(0x60C2, 1, value)


def _write_sync_timing(device: _Device, period_s: float) -> None:
    """0x1005 (the device consumes SYNC on 0x080) and 0x1006 (the cycle in µs), where the EDS has them."""
    if device.has(0x1005):
        device.write_verified(0x1005, 0, SYNC)
    if device.has(0x1006):
        device.write_verified(0x1006, 0, round(period_s * 1e6))


def _write_following_error(device: _Device, plan: NodeSetupPlan) -> None:
    """0x6065/0x6066: the drive's own following-error monitor (CiA 402: beyond the window for longer
    than the time -> fault, EMCY 0x8611), where configured and the EDS has the objects."""
    if plan.following_error_window_counts <= 0:
        return
    if not device.has(0x6065) or not device.has(0x6066):
        log.warning(
            "node %d: its EDS has no following-error objects 0x6065/0x6066; only the controller's "
            "window (safety.following_window_m) watches it",
            device.node_id,
        )
        return
    device.write_verified(0x6065, 0, plan.following_error_window_counts)
    device.write_verified(0x6066, 0, plan.following_error_time_ms)


EXTRAPOLATION_PERIODS = 0x2010  # manufacturer-specific (drivers/eds/cheope_drive.eds)
DRIVE_DEFAULT_EXTRAPOLATION_PERIODS = 1  # what a drive without the object is taken to do


def check_extrapolation_object(node_id: int, periods: int, has_object: bool) -> None:
    """A drive whose EDS has no 0x2010 is taken to run on one period, the common choice; configured
    otherwise (``actuators.extrapolation_s``), set-up refuses it: the control law would count on
    periods the drive does not run."""
    if not has_object and periods != DRIVE_DEFAULT_EXTRAPOLATION_PERIODS:
        raise NodeSetupError(
            f"node {node_id}: its EDS has no extrapolation periods object 0x2010, so it cannot be told "
            f"to run on {periods} periods without a new target; set actuators.extrapolation_s to one "
            f"period, what such a drive is taken to do"
        )


def _write_extrapolation(device: _Device, periods: int | None) -> None:
    """0x2010: how far the drive runs on blind when no new target comes (the control law counts on it
    after a hold-up, ``LawConfig.drive_extrapolation_periods``)."""
    if periods is None:
        return
    has_object = device.has(EXTRAPOLATION_PERIODS)
    check_extrapolation_object(device.node_id, periods, has_object)
    if has_object:
        device.write_verified(EXTRAPOLATION_PERIODS, 0, periods)


SYNC_WATCHDOG = 0x2011  # manufacturer-specific (drivers/eds/cheope_drive.eds): ms


def _write_sync_watchdog(device: _Device, ms: int | None) -> None:
    """0x2011: how long the drive waits for the next SYNC before it quick-stops (EMCY 0x8240). A drive
    without the object keeps its own time, named in a warning: the controller cannot know it."""
    if ms is None:
        return
    if not device.has(SYNC_WATCHDOG):
        device.note(  # a warning, and in the run's summary (node_setup_notes)
            f"node {device.node_id}: its EDS has no SYNC watchdog object 0x2011; it stops on a silent "
            "SYNC after its own time, not actuators.sync_watchdog_s",
            logging.WARNING,
        )
        return
    device.write_verified(SYNC_WATCHDOG, 0, ms)


ABORT_CONNECTION_QUICK_STOP = 3  # 0x6007 (CiA 402): what a drive does by itself when it loses its master


def _write_abort_connection(device: _Device) -> None:
    """0x6007: a drive that loses the controller (its heartbeat or guarding, or NMT OPERATIONAL, where a
    foreign master can take it) quick-stops by itself; the controller's own stop may not reach it."""
    if not device.has(0x6007):
        log.warning(
            "node %d: its EDS has no abort connection option code 0x6007; on a lost master it "
            "reacts as its firmware does",
            device.node_id,
        )
        return
    device.write_verified(0x6007, 0, ABORT_CONNECTION_QUICK_STOP)


def _write_supervision(device: _Device, plan: NodeSetupPlan) -> None:
    """How the drive and the controller watch each other: heartbeat (the drive produces one, 0x1017,
    and consumes the controller's, 0x1016) or node guarding (the controller polls every guard time,
    0x100C; the drive's life guarding expects a poll within guard time x life time factor, 0x100D)."""
    opts = device.opts
    if opts.supervision == "guarding":
        device.write_verified(0x100C, 0, round(opts.guard_time_s * 1000))
        device.write_verified(0x100D, 0, opts.life_time_factor)
        return
    device.write_verified(0x1017, 0, round(plan.heartbeat_period_s * 1000))
    device.write_verified(0x1016, 1, (plan.controller_id << 16) | round(plan.heartbeat_consumer_s * 1000))


def configure_pdo(device: _Device, config: PdoConfig) -> PdoConfig:
    """Write one PDO by CiA 301's remap procedure, then read every parameter back and compare.

    Invalid (COB-ID bit 31), transmission type, count 0, entries, count, valid again. Returns
    what the device reports, which is what the codecs are built from.
    """
    comm, mapping = config.communication_index, config.mapping_index
    for index, subindex, value in remap_writes(config):
        device.write(index, subindex, value)
    device.check_reads(comm, 1, config.cob_id)
    device.check_reads(comm, 2, config.transmission_type)
    device.check_reads(mapping, 0, len(config.objects))
    for k, obj in enumerate(config.objects, start=1):
        device.check_reads(mapping, k, obj.entry)
    return config


def read_pdo(device: _Device, direction: PdoDirection, number: int) -> PdoConfig:
    """A PDO as the device has it (a fixed mapping): its COB-ID and entries read, nothing remapped;
    a synchronous transmission type (1: every SYNC) written where it is not."""
    base = 0x1400 if direction == PdoDirection.RECEIVE else 0x1800
    comm, mapping = base + number - 1, base + number - 1 + 0x200
    cob_field = device.read(comm, 1)
    count = device.read(mapping, 0)
    if cob_field & COB_ID_INVALID:
        # left invalid by an earlier master (a remap the drive refused half-way): valid again, as it is
        if count == 0:
            raise NodeSetupError(
                f"node {device.node_id}: its {direction.value}{number} is not valid (0x{comm:04X}sub1 = "
                f"0x{cob_field:08X}) and maps nothing, and its mapping is read, not written "
                '(actuators.pdo_mapping = "read")'
            )
        device.write_verified(comm, 1, cob_field & ~COB_ID_INVALID)
        device.note(f"node {device.node_id}: its {direction.value}{number} was not valid: made valid again")
        cob_field &= ~COB_ID_INVALID
    if device.read(comm, 2) != TRANSMISSION_SYNCHRONOUS:
        device.write_verified(comm, 2, TRANSMISSION_SYNCHRONOUS)
    objects = tuple(MappedObject.from_entry(device.read(mapping, k)) for k in range(1, count + 1))
    config = PdoConfig(direction, number, cob_field & COB_ID_MASK, TRANSMISSION_SYNCHRONOUS, objects)
    device.note(
        f"node {device.node_id}: {config.name} read from the drive: "
        + ", ".join(str(o) for o in objects)
        + ' (actuators.pdo_mapping = "read")'
    )
    return config


def _identity(device: _Device, expected_vendor: int, expected_product: int) -> NodeIdentity:
    def u32(sub: int) -> int:
        return int.from_bytes(device.upload(0x1018, sub), "little")

    node_id = device.node_id
    ident = NodeIdentity(node_id, u32(1), u32(2), u32(3), u32(4))
    if (ident.vendor_id, ident.product_code) != (expected_vendor, expected_product):
        raise NodeSetupError(
            f"node {node_id}: identity 0x1018 reads vendor 0x{ident.vendor_id:08X} product "
            f"0x{ident.product_code:08X}, expected vendor 0x{expected_vendor:08X} product 0x{expected_product:08X}"
        )
    for sub, name, got, want, key in (
        (3, "revision number", ident.revision, device.opts.revision, "actuators.revision_number or [[node]]"),
        (4, "serial number", ident.serial, device.opts.serial, "[[node]] serial_number"),
    ):
        if want is not None and got != want:
            raise NodeSetupError(
                f"node {node_id}: identity 0x1018 sub {sub} {name} reads 0x{got:08X}, expected 0x{want:08X} "
                f"({key}): another device than the one configured"
            )
    return ident


def _reset_fault(device: _Device) -> None:
    """A drive in FAULT at start: reset over SDO and verified (drivers/fault_reset.py)."""
    try:
        note = reset_fault(
            device.node_id,
            device.opts.fault_reset,
            device.opts.fault_reset_timeout_s,
            device.write,
            device.read,
            has_error_code=device.has(0x603F),
        )
    except FaultResetError as err:
        raise NodeSetupError(str(err)) from err
    if note:
        device.note(note)


def _announce_environment(device: _Device, environment: str, task_kind: str) -> None:
    """Tell a simulated sensor the workpiece the task needs; a real one has no such object."""
    node_id = device.node_id
    try:
        device.download(
            SIM_ENVIRONMENT_INDEX, SIM_ENVIRONMENT_SUBINDEX, bytes([ENVIRONMENT_CODES[environment]])
        )
    except canopen.SdoAbortedError as err:
        if err.code == ABORT_OBJECT_DOES_NOT_EXIST:
            log.info("node %d has no simulator environment object: not a simulator", node_id)
            return
        if err.code != ABORT_DEVICE_STATE:
            raise
        code = device.upload(SIM_ENVIRONMENT_INDEX, SIM_ENVIRONMENT_SUBINDEX)[0]
        raise NodeSetupError(
            mismatch_message(ENVIRONMENT_NAMES.get(code, f"code {code}"), environment, task_kind)
        ) from err
    log.info(
        "node %d (simulated): environment %s announced for task.kind = %s", node_id, environment, task_kind
    )


def _device(
    network: canopen.Network,
    node_id: int,
    eds: Path,
    plan: NodeSetupPlan,
    notes: list[str],
    stop: threading.Event | None = None,
) -> _Device:
    try:
        node = canopen.RemoteNode(node_id, load_device_description(eds, node_id))
    except PdoMappingError as err:
        raise NodeSetupError(f"node {node_id}: {err}") from err
    opts = plan.options(node_id)
    node.sdo.RESPONSE_TIMEOUT = opts.sdo_timeout_s
    network.add_node(node)
    device = _Device(node, node_id, opts, notes, stop)
    device.check_stop("the set-up")
    _wait_until_answering(device, network)
    return device


def _home(device: _Device, plan: HomingPlan) -> None:
    try:
        homed = home_drive(device.node_id, plan, device.write, device.read, sleep=device.sleep)
    except HomingError as err:
        raise NodeSetupError(str(err)) from err
    if not homed:
        device.note(
            f"node {device.node_id}: reports itself homed (mode 6, statusword bit 12): homing skipped "
            "(actuators.homing_skip_if_homed)"
        )


def _configure_drive_pdos(device: _Device, plan: NodeSetupPlan) -> DriveCodec:
    od = device.node.object_dictionary
    node_id = device.node_id
    where = f"node {node_id}"
    try:
        if device.opts.pdo_mapping == "read":
            rpdo = read_pdo(device, PdoDirection.RECEIVE, 1)
            tpdo = read_pdo(device, PdoDirection.TRANSMIT, 1)
            where = f'node {node_id} (its mapping as read: actuators.pdo_mapping = "read")'
        else:
            rpdo = planned_pdo(od, PdoDirection.RECEIVE, 1, node_id, plan.drive_rpdo_objects)
            tpdo = planned_pdo(od, PdoDirection.TRANSMIT, 1, node_id, plan.drive_tpdo_objects)
            rpdo, tpdo = configure_pdo(device, rpdo), configure_pdo(device, tpdo)
        # The effort's scale is the drive's own rated torque (force, for a linear motor), read from it.
        maps_effort = any((o.index, o.subindex) == TORQUE_ACTUAL for o in tpdo.objects)
        rated = device.read(*RATED_TORQUE) if maps_effort else 0
        return DriveCodec(
            layout(rpdo.objects, od, where),
            layout(tpdo.objects, od, where),
            where,
            rpdo.cob_id,
            tpdo.cob_id,
            effort_per_count(rated),
        )
    except PdoMappingError as err:
        raise NodeSetupError(f"{err}: the controller cannot run this drive with it") from err


def _configure_sensor_pdos(device: _Device) -> tuple[SensorFrameCodec, SensorFrameCodec]:
    od = device.node.object_dictionary
    node_id = device.node_id
    codecs = []
    try:
        for number in (1, 2):
            tpdo = configure_pdo(device, planned_pdo(od, PdoDirection.TRANSMIT, number, node_id, ()))
            where = f"node {node_id} {tpdo.name}"
            codecs.append(SensorFrameCodec(layout(tpdo.objects, od, where), where, tpdo.cob_id))
        return force_then_torque(codecs[0], codecs[1], node_id)
    except PdoMappingError as err:
        raise NodeSetupError(str(err)) from err


def force_then_torque(
    force: SensorFrameCodec, torque: SensorFrameCodec, node_id: int
) -> tuple[SensorFrameCodec, SensorFrameCodec]:
    """The sensor's two TPDOs in the order the exchange reads them, or a ``PdoMappingError``."""
    if not force.is_force or torque.is_force:
        raise PdoMappingError(
            f"node {node_id}: TPDO1 must carry the force 0x2000 and TPDO2 the torque 0x2001"
        )
    return force, torque


def _configure_drive(device: _Device, j: int, plan: NodeSetupPlan) -> tuple[NodeIdentity, DriveCodec, int]:
    ident = _identity(device, plan.vendor_id, plan.drive_product_code)
    _reset_fault(device)
    homing = plan.homing[j] if plan.homing is not None else None
    if homing is not None:
        _home(device, homing)
    device.write(0x6060, 0, MODE_CYCLIC_SYNC_POSITION)
    mode = device.read(0x6061, 0)
    if mode != MODE_CYCLIC_SYNC_POSITION:
        raise NodeSetupError(
            f"node {device.node_id}: mode of operation display 0x6061 reads {mode}, expected 8 (CSP)"
        )
    _write_supervision(device, plan)
    _write_abort_connection(device)
    if plan.cycle_period_s > 0:
        _write_sync_timing(device, plan.cycle_period_s)
        _write_interpolation_period(device, plan.cycle_period_s)
    _write_following_error(device, plan)
    _write_extrapolation(device, plan.extrapolation_periods)
    _write_sync_watchdog(device, plan.sync_watchdog_ms)
    codec = _configure_drive_pdos(device, plan)
    return ident, codec, device.read(0x6064, 0)


def configure_nodes(
    bus: can.BusABC, plan: NodeSetupPlan, stop: threading.Event | None = None
) -> NodeSetupReport:
    """NMT pre-operational; per node: boot (timeout, NMT reset retries), identity, a fault at start
    reset, homing, mode, supervision (heartbeat or guarding), the drives' reaction to a lost master
    (0x6007), SYNC timing, PDOs (written, or read where fixed); NMT start.

    Every value written is read back; the PDO codecs are built from what the devices report.
    ``stop`` set (a signal, ``cheope stop``) ends the set-up at its next wait with ``SetupStoppedError``:
    the boot of a silent node (``boot_timeout_s`` times its retries) and homing (up to
    ``homing_timeout_s``, the drive disabled) were waited out before, past a service manager's
    stop timeout.
    """
    t0 = time.monotonic()
    network = canopen.Network(bus)
    # its receive thread waits on the bus this long at most: stopped below before the bus can be
    # closed (a thread still waiting when the bus was shut on an error path died with "Bad file
    # descriptor" and a traceback)
    network.NOTIFIER_CYCLE = 0.1
    network.connect()
    notes: list[str] = []
    client_log = logging.getLogger("canopen.sdo.client")
    client_log.addFilter(_quiet_client)
    try:
        identities = []
        positions = []
        drive_codecs = []
        sensor_codecs = None
        network.nmt.state = "PRE-OPERATIONAL"  # broadcast
        devices = []
        for j, node_id in enumerate(plan.drive_ids):
            device = _device(network, node_id, plan.drive_eds, plan, notes, stop)
            devices.append(device)
            ident, codec, position = _configure_drive(device, j, plan)
            identities.append(ident)
            drive_codecs.append(codec)
            positions.append(position)
        if plan.sensor_id is not None:
            device = _device(network, plan.sensor_id, plan.sensor_eds, plan, notes, stop)
            devices.append(device)
            vendor = plan.vendor_id if plan.sensor_vendor_id is None else plan.sensor_vendor_id
            identities.append(_identity(device, vendor, plan.sensor_product_code))
            device.write_verified(0x1017, 0, round(plan.heartbeat_period_s * 1000))
            if plan.cycle_period_s > 0:
                _write_sync_timing(device, plan.cycle_period_s)
            sensor_codecs = _configure_sensor_pdos(device)
            if plan.sim_environment is not None:
                _announce_environment(device, plan.sim_environment, plan.task_kind)
        for device in devices:
            if device.retried:
                device.note(
                    f"node {device.node_id}: {device.retried} SDO transfer(s) repeated (loop.sdo_retries)"
                )
        network.nmt.state = "OPERATIONAL"  # broadcast start
        return NodeSetupReport(
            tuple(identities),
            tuple(positions),
            time.monotonic() - t0,
            tuple(drive_codecs),
            sensor_codecs,
            tuple(notes),
        )
    except canopen.SdoAbortedError as err:
        raise NodeSetupError(f"SDO aborted during set-up: {err}") from err
    except canopen.SdoCommunicationError as err:
        raise NodeSetupError(f"SDO communication failed during set-up: {err}") from err
    finally:
        client_log.removeFilter(_quiet_client)
        if network.notifier is not None:
            network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)  # returns once the thread has ended
        network.bus = None  # the bus stays open for the cyclic loop; canopen must not close it


def _quiet_client(record: logging.LogRecord) -> bool:
    """canopen's SDO client logs an ERROR line for each timed-out transfer; set-up waits for booting
    nodes by timing out, retries, and names a real failure in its own error: not a library's line."""
    return not record.getMessage().startswith("Transfer aborted by client")


def description_drive_codec(
    node_id: int,
    eds: Path = DRIVE_EDS,
    rpdo_objects: tuple[str, ...] = (),
    tpdo_objects: tuple[str, ...] = (),
) -> DriveCodec:
    """The codec of a drive mapped as ``eds`` and the configuration say, without asking the drive
    (what ``configure_nodes`` writes; for exchanges built without a set-up: tests, bench)."""
    od = load_device_description(eds, node_id)
    rpdo = planned_pdo(od, PdoDirection.RECEIVE, 1, node_id, rpdo_objects)
    tpdo = planned_pdo(od, PdoDirection.TRANSMIT, 1, node_id, tpdo_objects)
    where = f"node {node_id}"
    rated = od.get_variable(*RATED_TORQUE) if RATED_TORQUE[0] in od else None
    return DriveCodec(
        layout(rpdo.objects, od, where),
        layout(tpdo.objects, od, where),
        where,
        rpdo.cob_id,
        tpdo.cob_id,
        effort_per_count(int(rated.default) if rated is not None and rated.default else 0),
    )


def effort_per_count(rated_torque: int) -> float:
    """[N] per count of the torque actual value 0x6077: a thousandth of the rated torque 0x6076 [mN m],
    for a linear motor its rated force [mN] (CiA 402); 0 where the drive states none (no effort)."""
    return rated_torque / 1.0e6


def description_sensor_codecs(
    node_id: int, eds: Path = SENSOR_EDS
) -> tuple[SensorFrameCodec, SensorFrameCodec]:
    od = load_device_description(eds, node_id)
    codecs = []
    for number in (1, 2):
        tpdo = planned_pdo(od, PdoDirection.TRANSMIT, number, node_id, ())
        codecs.append(
            SensorFrameCodec(
                layout(tpdo.objects, od, f"node {node_id} {tpdo.name}"),
                f"node {node_id} {tpdo.name}",
                tpdo.cob_id,
            )
        )
    return force_then_torque(codecs[0], codecs[1], node_id)


def check_device_descriptions(plan: NodeSetupPlan) -> None:
    """Build from the EDS files alone what the set-up builds from them, before any bus is opened.

    A damaged file, or a mapping its file cannot carry, refuses the start with one line naming
    the file (``DeviceDescriptionError``) instead of failing in the middle of the set-up.
    """
    for node_id in plan.drive_ids:
        with naming_the_file(plan.drive_eds):
            description_drive_codec(node_id, plan.drive_eds, plan.drive_rpdo_objects, plan.drive_tpdo_objects)
    if plan.sensor_id is not None:
        with naming_the_file(plan.sensor_eds):
            description_sensor_codecs(plan.sensor_id, plan.sensor_eds)


@contextlib.contextmanager
def naming_the_file(eds: Path) -> Iterator[None]:
    """A mapping error inside the block names ``eds`` (a file error already does); the simulator's too."""
    try:
        yield
    except DeviceDescriptionError:
        raise
    except PdoMappingError as err:
        raise DeviceDescriptionError(f"device description {eds}: {err}") from None


def device_description_path(configured: str, default: Path) -> Path:
    """A configured EDS path ("" is the shipped one); relative paths are taken from the working directory."""
    return Path(configured).resolve() if configured else default
