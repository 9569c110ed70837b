"""Start-up configuration of the drives and the sensor with the canopen package (NMT, SDO).

This runs once, before the cyclic loop, with canopen's notifier thread reading the bus;
the notifier is stopped afterwards so the loop owns the bus alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import can
import canopen

from controller.errors import DeviceError
from drivers.cia402 import MODE_CYCLIC_SYNC_POSITION

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
    cycle_period_s: float = 0.0  # the SYNC period, written as the drives' interpolation time period (0: not written)
    answer_timeout_s: float = 5.0  # how long a node may take to answer at all (it may still be booting)
    sdo_timeout_s: float = 1.0  # each SDO response; canopen's 0.3 s default is short for slow machines


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


def interpolation_time_period(period_s: float) -> tuple[int, int]:
    """Object 0x60C2 for ``period_s``: (value, index) with value x 10^index s, value an UNSIGNED8.

    CiA 402 gives the interpolation time period as an UNSIGNED8 mantissa and an INTEGER8 power
    of ten; 2.5 ms is (25, -4), 1 ms (1, -3). The coarsest exact form is chosen; a period with
    no exact form (1/300 s) gets the finest one that fits in 8 bits (33 x 10^-4 s).
    """
    finest: tuple[int, int] | None = None
    for index in range(-1, -10, -1):
        value = period_s / 10.0 ** index
        if round(value) > 255:
            break
        if round(value) > 0:
            finest = (round(value), index)
            if abs(value - round(value)) < 1e-6 * value:
                return finest
    if finest is None:
        raise ValueError(f"interpolation time period {period_s} s cannot be written as an 8-bit value x 10^index s")
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


def _write_interpolation_period(node: canopen.RemoteNode, period_s: float) -> None:
    """0x60C2: the drive interpolates each target over this time (index first: no transient 2.5 s)."""
    value, index = interpolation_time_period(period_s)
    node.sdo[0x60C2][2].raw = index
    node.sdo[0x60C2][1].raw = value
    back = (node.sdo[0x60C2][1].raw, node.sdo[0x60C2][2].raw)
    if back != (value, index):
        raise NodeSetupError(f"node {node.id} interpolation time period 0x60C2 reads back {back}, "
                             f"wrote {(value, index)}")


def _identity(node: canopen.RemoteNode, node_id: int, expected_vendor: int, expected_product: int
              ) -> NodeIdentity:
    """``node_id`` is the id ``node`` was made with (canopen types ``node.id`` as possibly None)."""
    def u32(sub: int) -> int:
        return int.from_bytes(node.sdo.upload(0x1018, sub), "little")

    ident = NodeIdentity(node_id, u32(1), u32(2), u32(3), u32(4))
    if (ident.vendor_id, ident.product_code) != (expected_vendor, expected_product):
        raise NodeSetupError(
            f"node {node_id} identity vendor 0x{ident.vendor_id:08X} product 0x{ident.product_code:08X}, "
            f"expected vendor 0x{expected_vendor:08X} product 0x{expected_product:08X}"
        )
    return ident


def configure_nodes(bus: can.BusABC, plan: NodeSetupPlan) -> NodeSetupReport:
    """NMT pre-operational, SDO set-up and identity checks, NMT start of every node."""
    t0 = time.monotonic()
    network = canopen.Network(bus)
    network.connect()
    try:
        identities = []
        positions = []
        network.nmt.state = "PRE-OPERATIONAL"  # broadcast
        hb_ms = round(plan.heartbeat_period_s * 1000)
        consumer = (plan.controller_id << 16) | round(plan.heartbeat_consumer_s * 1000)
        for node_id in plan.drive_ids:
            node = canopen.RemoteNode(node_id, str(DRIVE_EDS))
            node.sdo.RESPONSE_TIMEOUT = plan.sdo_timeout_s
            network.add_node(node)
            _wait_until_answering(node, plan.answer_timeout_s)
            identities.append(_identity(node, node_id, plan.vendor_id, plan.drive_product_code))
            node.sdo[0x6060].raw = MODE_CYCLIC_SYNC_POSITION
            mode = node.sdo[0x6061].raw
            if mode != MODE_CYCLIC_SYNC_POSITION:
                raise NodeSetupError(f"node {node_id} reports mode of operation {mode}, expected 8 (CSP)")
            node.sdo[0x1017].raw = hb_ms
            node.sdo[0x1016][1].raw = consumer
            if plan.cycle_period_s > 0:
                _write_interpolation_period(node, plan.cycle_period_s)
            positions.append(node.sdo[0x6064].raw)
        if plan.sensor_id is not None:
            node = canopen.RemoteNode(plan.sensor_id, str(SENSOR_EDS))
            node.sdo.RESPONSE_TIMEOUT = plan.sdo_timeout_s
            network.add_node(node)
            _wait_until_answering(node, plan.answer_timeout_s)
            identities.append(_identity(node, plan.sensor_id, plan.vendor_id, plan.sensor_product_code))
            node.sdo[0x1017].raw = hb_ms
        network.nmt.state = "OPERATIONAL"  # broadcast start
        return NodeSetupReport(tuple(identities), tuple(positions), time.monotonic() - t0)
    except canopen.SdoAbortedError as err:
        raise NodeSetupError(f"SDO aborted during set-up: {err}") from err
    except canopen.SdoCommunicationError as err:
        raise NodeSetupError(f"SDO communication failed during set-up: {err}") from err
    finally:
        if network.notifier is not None:
            network.notifier.stop(1.0)
        network.bus = None  # the bus stays open for the cyclic loop; canopen must not close it
