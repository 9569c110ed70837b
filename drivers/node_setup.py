"""Start-up configuration of the drives and the sensor with the canopen package (NMT, SDO).

This runs once, before the cyclic loop, with canopen's notifier thread reading the bus;
the notifier is stopped afterwards so the loop owns the bus alone.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import ODVariable

from controller.core.cia402 import MODE_CYCLIC_SYNC_POSITION
from controller.errors import DeviceError
from drivers.cob_ids import SYNC
from drivers.homing import HomingError, HomingPlan, home_drive
from drivers.pdo_codec import RATED_TORQUE, TORQUE_ACTUAL, DriveCodec, SensorFrameCodec
from drivers.pdo_mapping import (
    COB_ID_INVALID,
    DeviceDescriptionError,
    PdoConfig,
    PdoDirection,
    PdoMappingError,
    find_variable,
    layout,
    load_device_description,
    planned_pdo,
)
from drivers.sim_environment import (
    ABORT_DEVICE_STATE,
    ABORT_OBJECT_DOES_NOT_EXIST,
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


class NodeSetupError(DeviceError, RuntimeError):
    """A device did not answer, or answered with the wrong identity or configuration."""


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
    homing: tuple[HomingPlan, ...] | None = None  # each drive's CiA 402 homing, before the PDOs start
    following_error_window_counts: int = 0  # 0x6065 (0: not written; the EDS must have it)
    following_error_time_ms: int = 0  # 0x6066
    answer_timeout_s: float = 5.0  # how long a node may take to answer at all (it may still be booting)
    sdo_timeout_s: float = 1.0  # each SDO response; canopen's 0.3 s default is short for slow machines
    # announced to a simulated sensor (drivers/sim_environment.py): "free", "workpiece"; None: not announced
    sim_environment: str | None = None
    task_kind: str = ""  # named when the simulator refuses the environment


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


def _wait_until_answering(node: canopen.RemoteNode, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            node.sdo.upload(0x1000, 0)
            return
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as err:
            last = err
    raise NodeSetupError(f"node {node.id} did not answer SDO requests within {timeout_s} s ({last})")


def _variable(node: canopen.RemoteNode, node_id: int, index: int, subindex: int) -> ODVariable:
    var = find_variable(node.object_dictionary, index, subindex)
    if var is None:
        raise NodeSetupError(f"node {node_id}: 0x{index:04X}sub{subindex} is not in its device description")
    return var


def _write(node: canopen.RemoteNode, node_id: int, index: int, subindex: int, value: int) -> None:
    """One SDO download; an abort names the node, the object, the value and the abort."""
    var = _variable(node, node_id, index, subindex)
    try:
        node.sdo.download(index, subindex, var.encode_raw(value))
    except canopen.SdoAbortedError as err:
        raise NodeSetupError(
            f"node {node_id}: writing 0x{index:04X}sub{subindex} = 0x{value & 0xFFFFFFFF:X} refused: {err}"
        ) from err


def _read(node: canopen.RemoteNode, node_id: int, index: int, subindex: int) -> int:
    var = _variable(node, node_id, index, subindex)
    try:
        value = var.decode_raw(node.sdo.upload(index, subindex))
    except canopen.SdoAbortedError as err:
        raise NodeSetupError(f"node {node_id}: reading 0x{index:04X}sub{subindex} refused: {err}") from err
    if not isinstance(value, int):
        raise NodeSetupError(f"node {node_id}: 0x{index:04X}sub{subindex} is not an integer ({value!r})")
    return value


def _write_verified(node: canopen.RemoteNode, node_id: int, index: int, subindex: int, value: int) -> None:
    _write(node, node_id, index, subindex, value)
    _check_reads(node, node_id, index, subindex, value)


def _check_reads(node: canopen.RemoteNode, node_id: int, index: int, subindex: int, value: int) -> None:
    back = _read(node, node_id, index, subindex)
    if back != value:
        raise NodeSetupError(
            f"node {node_id}: 0x{index:04X}sub{subindex} reads back 0x{back & 0xFFFFFFFF:X}, "
            f"wrote 0x{value & 0xFFFFFFFF:X}"
        )


def _write_interpolation_period(node: canopen.RemoteNode, node_id: int, period_s: float) -> None:
    """0x60C2: the drive interpolates each target over this time (index first: no transient 2.5 s)."""
    value, index = interpolation_time_period(period_s)
    _write_verified(node, node_id, 0x60C2, 2, index)
    _write_verified(node, node_id, 0x60C2, 1, value)


def _write_sync_timing(node: canopen.RemoteNode, node_id: int, period_s: float) -> None:
    """0x1005 (the device consumes SYNC on 0x080) and 0x1006 (the cycle in µs), where the EDS has them."""
    od = node.object_dictionary
    if find_variable(od, 0x1005, 0) is not None:
        _write_verified(node, node_id, 0x1005, 0, SYNC)
    if find_variable(od, 0x1006, 0) is not None:
        _write_verified(node, node_id, 0x1006, 0, round(period_s * 1e6))


def _write_following_error(node: canopen.RemoteNode, node_id: int, plan: NodeSetupPlan) -> None:
    """0x6065/0x6066: the drive's own following-error monitor (CiA 402: beyond the window for longer
    than the time -> fault, EMCY 0x8611), where configured and the EDS has the objects."""
    if plan.following_error_window_counts <= 0:
        return
    od = node.object_dictionary
    if find_variable(od, 0x6065, 0) is None or find_variable(od, 0x6066, 0) is None:
        log.warning(
            "node %d: its EDS has no following-error objects 0x6065/0x6066; only the controller's "
            "window (safety.following_window_m) watches it",
            node_id,
        )
        return
    _write_verified(node, node_id, 0x6065, 0, plan.following_error_window_counts)
    _write_verified(node, node_id, 0x6066, 0, plan.following_error_time_ms)


ABORT_CONNECTION_QUICK_STOP = 3  # 0x6007 (CiA 402): what a drive does by itself when it loses its master


def _write_abort_connection(node: canopen.RemoteNode, node_id: int) -> None:
    """0x6007: a drive that loses the controller (its heartbeat, 0x1016, or NMT OPERATIONAL, where a
    foreign master can take it) quick-stops by itself; the controller's own stop may not reach it."""
    if find_variable(node.object_dictionary, 0x6007, 0) is None:
        log.warning(
            "node %d: its EDS has no abort connection option code 0x6007; on a lost master it "
            "reacts as its firmware does",
            node_id,
        )
        return
    _write_verified(node, node_id, 0x6007, 0, ABORT_CONNECTION_QUICK_STOP)


def configure_pdo(node: canopen.RemoteNode, node_id: int, config: PdoConfig) -> PdoConfig:
    """Write one PDO by CiA 301's remap procedure, then read every parameter back and compare.

    Invalid (COB-ID bit 31), transmission type, count 0, entries, count, valid again. Returns
    what the device reports, which is what the codecs are built from.
    """
    comm, mapping = config.communication_index, config.mapping_index
    _write(node, node_id, comm, 1, config.cob_id | COB_ID_INVALID)
    _write(node, node_id, comm, 2, config.transmission_type)
    _write(node, node_id, mapping, 0, 0)
    for k, obj in enumerate(config.objects, start=1):
        _write(node, node_id, mapping, k, obj.entry)
    _write(node, node_id, mapping, 0, len(config.objects))
    _write(node, node_id, comm, 1, config.cob_id)
    _check_reads(node, node_id, comm, 1, config.cob_id)
    _check_reads(node, node_id, comm, 2, config.transmission_type)
    _check_reads(node, node_id, mapping, 0, len(config.objects))
    for k, obj in enumerate(config.objects, start=1):
        _check_reads(node, node_id, mapping, k, obj.entry)
    return config


def _identity(
    node: canopen.RemoteNode, node_id: int, expected_vendor: int, expected_product: int
) -> NodeIdentity:
    """``node_id`` is the id ``node`` was made with (canopen types ``node.id`` as possibly None)."""

    def u32(sub: int) -> int:
        return int.from_bytes(node.sdo.upload(0x1018, sub), "little")

    ident = NodeIdentity(node_id, u32(1), u32(2), u32(3), u32(4))
    if (ident.vendor_id, ident.product_code) != (expected_vendor, expected_product):
        raise NodeSetupError(
            f"node {node_id}: identity 0x1018 reads vendor 0x{ident.vendor_id:08X} product "
            f"0x{ident.product_code:08X}, expected vendor 0x{expected_vendor:08X} product 0x{expected_product:08X}"
        )
    return ident


def _announce_environment(node: canopen.RemoteNode, node_id: int, environment: str, task_kind: str) -> None:
    """Tell a simulated sensor the workpiece the task needs; a real one has no such object."""
    try:
        node.sdo.download(
            SIM_ENVIRONMENT_INDEX, SIM_ENVIRONMENT_SUBINDEX, bytes([ENVIRONMENT_CODES[environment]])
        )
    except canopen.SdoAbortedError as err:
        if err.code == ABORT_OBJECT_DOES_NOT_EXIST:
            log.info("node %d has no simulator environment object: not a simulator", node_id)
            return
        if err.code != ABORT_DEVICE_STATE:
            raise
        code = node.sdo.upload(SIM_ENVIRONMENT_INDEX, SIM_ENVIRONMENT_SUBINDEX)[0]
        raise NodeSetupError(
            mismatch_message(ENVIRONMENT_NAMES.get(code, f"code {code}"), environment, task_kind)
        ) from err
    log.info(
        "node %d (simulated): environment %s announced for task.kind = %s", node_id, environment, task_kind
    )


def _remote_node(
    network: canopen.Network, node_id: int, eds: Path, plan: NodeSetupPlan
) -> canopen.RemoteNode:
    try:
        node = canopen.RemoteNode(node_id, load_device_description(eds, node_id))
    except PdoMappingError as err:
        raise NodeSetupError(f"node {node_id}: {err}") from err
    node.sdo.RESPONSE_TIMEOUT = plan.sdo_timeout_s
    network.add_node(node)
    _wait_until_answering(node, plan.answer_timeout_s)
    return node


def _home(node: canopen.RemoteNode, node_id: int, plan: HomingPlan) -> None:
    try:
        home_drive(
            node_id,
            plan,
            lambda index, sub, value: _write(node, node_id, index, sub, value),
            lambda index, sub: _read(node, node_id, index, sub),
        )
    except HomingError as err:
        raise NodeSetupError(str(err)) from err


def _configure_drive_pdos(node: canopen.RemoteNode, node_id: int, plan: NodeSetupPlan) -> DriveCodec:
    od = node.object_dictionary
    try:
        rpdo = planned_pdo(od, PdoDirection.RECEIVE, 1, node_id, plan.drive_rpdo_objects)
        tpdo = planned_pdo(od, PdoDirection.TRANSMIT, 1, node_id, plan.drive_tpdo_objects)
        rpdo, tpdo = configure_pdo(node, node_id, rpdo), configure_pdo(node, node_id, tpdo)
        where = f"node {node_id}"
        # The effort's scale is the drive's own rated torque (force, for a linear motor), read from it.
        maps_effort = any((o.index, o.subindex) == TORQUE_ACTUAL for o in tpdo.objects)
        rated = _read(node, node_id, *RATED_TORQUE) if maps_effort else 0
        return DriveCodec(
            layout(rpdo.objects, od, where),
            layout(tpdo.objects, od, where),
            where,
            rpdo.cob_id,
            tpdo.cob_id,
            effort_per_count(rated),
        )
    except PdoMappingError as err:
        raise NodeSetupError(str(err)) from err


def _configure_sensor_pdos(
    node: canopen.RemoteNode, node_id: int
) -> tuple[SensorFrameCodec, SensorFrameCodec]:
    od = node.object_dictionary
    codecs = []
    try:
        for number in (1, 2):
            tpdo = configure_pdo(node, node_id, planned_pdo(od, PdoDirection.TRANSMIT, number, node_id, ()))
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


def configure_nodes(bus: can.BusABC, plan: NodeSetupPlan) -> NodeSetupReport:
    """NMT pre-operational; per node: identity, mode, heartbeats (the drives consume the controller's),
    the drives' reaction to a lost master (0x6007), SYNC timing, PDOs; NMT start.

    Every value written is read back; the PDO codecs are built from what the devices report.
    """
    t0 = time.monotonic()
    network = canopen.Network(bus)
    # its receive thread waits on the bus this long at most: stopped below before the bus can be
    # closed (a thread still waiting when the bus was shut on an error path died with "Bad file
    # descriptor" and a traceback)
    network.NOTIFIER_CYCLE = 0.1
    network.connect()
    try:
        identities = []
        positions = []
        drive_codecs = []
        sensor_codecs = None
        network.nmt.state = "PRE-OPERATIONAL"  # broadcast
        hb_ms = round(plan.heartbeat_period_s * 1000)
        consumer = (plan.controller_id << 16) | round(plan.heartbeat_consumer_s * 1000)
        for j, node_id in enumerate(plan.drive_ids):
            node = _remote_node(network, node_id, plan.drive_eds, plan)
            identities.append(_identity(node, node_id, plan.vendor_id, plan.drive_product_code))
            if plan.homing is not None:
                _home(node, node_id, plan.homing[j])
            _write(node, node_id, 0x6060, 0, MODE_CYCLIC_SYNC_POSITION)
            mode = _read(node, node_id, 0x6061, 0)
            if mode != MODE_CYCLIC_SYNC_POSITION:
                raise NodeSetupError(
                    f"node {node_id}: mode of operation display 0x6061 reads {mode}, expected 8 (CSP)"
                )
            _write_verified(node, node_id, 0x1017, 0, hb_ms)
            _write_verified(node, node_id, 0x1016, 1, consumer)
            _write_abort_connection(node, node_id)
            if plan.cycle_period_s > 0:
                _write_sync_timing(node, node_id, plan.cycle_period_s)
                _write_interpolation_period(node, node_id, plan.cycle_period_s)
            _write_following_error(node, node_id, plan)
            drive_codecs.append(_configure_drive_pdos(node, node_id, plan))
            positions.append(_read(node, node_id, 0x6064, 0))
        if plan.sensor_id is not None:
            node = _remote_node(network, plan.sensor_id, plan.sensor_eds, plan)
            vendor = plan.vendor_id if plan.sensor_vendor_id is None else plan.sensor_vendor_id
            identities.append(_identity(node, plan.sensor_id, vendor, plan.sensor_product_code))
            _write_verified(node, plan.sensor_id, 0x1017, 0, hb_ms)
            if plan.cycle_period_s > 0:
                _write_sync_timing(node, plan.sensor_id, plan.cycle_period_s)
            sensor_codecs = _configure_sensor_pdos(node, plan.sensor_id)
            if plan.sim_environment is not None:
                _announce_environment(node, plan.sensor_id, plan.sim_environment, plan.task_kind)
        network.nmt.state = "OPERATIONAL"  # broadcast start
        return NodeSetupReport(
            tuple(identities), tuple(positions), time.monotonic() - t0, tuple(drive_codecs), sensor_codecs
        )
    except canopen.SdoAbortedError as err:
        raise NodeSetupError(f"SDO aborted during set-up: {err}") from err
    except canopen.SdoCommunicationError as err:
        raise NodeSetupError(f"SDO communication failed during set-up: {err}") from err
    finally:
        if network.notifier is not None:
            network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)  # returns once the thread has ended
        network.bus = None  # the bus stays open for the cyclic loop; canopen must not close it


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
