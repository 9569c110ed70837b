"""What a commissioning tool shows of a CANopen bus: every node that answers, with its identity,
NMT state, CiA 402 power state, error code and PDO mapping (``cheope nodes``); and the LSS
services (CiA 305, canopen's LSS master) that find nodes without a node id and give them one.

Read-only for configured nodes (SDO uploads, a node guarding request to a node without
heartbeat): it changes nothing on them. It is a master's traffic, though: a running controller
takes it for a second master (safety.on_foreign_command). LSS changes what it assigns.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import can
import canopen
from canopen.lss import LssError

from controller.core.cia402 import decode_statusword
from controller.errors import DeviceError
from drivers.pdo_mapping import MappedObject, find_variable, load_device_description

NMT_NAMES = {0: "BOOT-UP", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}
CIA402 = 402  # 0x1000 device type, low 16 bits: the device profile
HEARTBEAT_LISTEN_S = 1.2  # how long heartbeats are heard (the default producer time is 0.1 s, a slow one 1 s)
LSS_RESPONSE_TIMEOUT_S = (
    0.05  # each LSS request; a fast scan asks ~130 and each unanswered one waits this long
)
PDOS = (("RPDO", 0x1400, 4), ("TPDO", 0x1800, 4))  # the first four of each


class NodeScanError(DeviceError):
    """The scan or an LSS service could not be carried out; the message says which and why."""


@dataclass(frozen=True)
class ScannedNode:
    node_id: int
    device_type: int
    vendor_id: int | None
    product_code: int | None
    revision: int | None
    serial: int | None
    nmt_state: str  # from its heartbeat, else its answer to node guarding; "?" when neither came
    supervision: str  # "heartbeat", "guarding" or "" (none heard)
    statusword: int | None = None  # CiA 402 devices only
    power_state: str = ""
    error_code: int | None = None  # 0x603F
    mode_display: int | None = None  # 0x6061
    mapping: dict[str, list[str]] = field(default_factory=dict)  # "TPDO1" -> ["0x6041sub0 Statusword", ...]


def _u(node: canopen.RemoteNode, index: int, subindex: int, size: int, signed: bool = False) -> int | None:
    try:
        data = node.sdo.upload(index, subindex)
    except (canopen.SdoAbortedError, canopen.SdoCommunicationError):
        return None
    return int.from_bytes(data[:size].ljust(size, b"\0"), "little", signed=signed)


class _Names:
    """Object names from device descriptions (the shipped EDS files unless given): for the mapping."""

    def __init__(self, eds_files: tuple[Path, ...]) -> None:
        self.ods = []
        for eds in eds_files:
            with contextlib.suppress(Exception):
                self.ods.append(load_device_description(eds, 1))

    def __call__(self, obj: MappedObject) -> str:
        for od in self.ods:
            var = find_variable(od, obj.index, obj.subindex)
            if var is not None:
                return f"0x{obj.index:04X}sub{obj.subindex} {var.name}"
        return f"0x{obj.index:04X}sub{obj.subindex}"


def _mapping(node: canopen.RemoteNode, names: _Names) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for kind, base, count in PDOS:
        for k in range(count):
            cob = _u(node, base + k, 1, 4)
            if cob is None:
                break  # the device has no more of them
            if cob & 0x80000000:
                continue  # not valid: not in use
            n = _u(node, base + k + 0x200, 0, 1) or 0
            entries = [_u(node, base + k + 0x200, s, 4) for s in range(1, n + 1)]
            out[f"{kind}{k + 1}"] = [names(MappedObject.from_entry(e)) for e in entries if e is not None]
    return out


@contextlib.contextmanager
def _network(bus: can.BusABC) -> Iterator[canopen.Network]:
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        yield network
    finally:
        if network.notifier is not None:
            network.notifier.stop(1.0)
        network.bus = None  # the caller's bus: canopen must not close it


def scan_nodes(
    bus: can.BusABC,
    eds_files: tuple[Path, ...] = (),
    sdo_timeout_s: float = 0.3,
    listen_s: float = HEARTBEAT_LISTEN_S,
) -> list[ScannedNode]:
    """Every node that answers an SDO request for 0x1000 (node ids 1..127), each described."""
    names = _Names(eds_files)
    heard: dict[int, int] = {}

    def on_frame(msg: can.Message) -> None:
        if 0x701 <= msg.arbitration_id <= 0x77F and len(msg.data) == 1 and not msg.is_remote_frame:
            heard[msg.arbitration_id - 0x700] = msg.data[0] & 0x7F

    with _network(bus) as network:
        if network.notifier is not None:
            network.notifier.add_listener(on_frame)
        network.scanner.search()  # SDO upload 0x1000 to every node id
        time.sleep(max(listen_s, sdo_timeout_s))
        found = sorted(set(network.scanner.nodes))
        nodes = []
        for node_id in found:
            node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
            node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            network.add_node(node)
            supervision = "heartbeat" if node_id in heard else ""
            state = heard.get(node_id)
            if state is None:  # no heartbeat: ask by node guarding
                before = dict(heard)
                bus.send(
                    can.Message(
                        arbitration_id=0x700 + node_id, is_remote_frame=True, dlc=1, is_extended_id=False
                    )
                )
                time.sleep(sdo_timeout_s)
                if node_id in heard and node_id not in before:
                    state, supervision = heard[node_id], "guarding"
            device_type = _u(node, 0x1000, 0, 4) or 0
            is_drive = device_type & 0xFFFF == CIA402
            sw = _u(node, 0x6041, 0, 2) if is_drive else None
            nodes.append(
                ScannedNode(
                    node_id=node_id,
                    device_type=device_type,
                    vendor_id=_u(node, 0x1018, 1, 4),
                    product_code=_u(node, 0x1018, 2, 4),
                    revision=_u(node, 0x1018, 3, 4),
                    serial=_u(node, 0x1018, 4, 4),
                    nmt_state=NMT_NAMES.get(state, f"state {state}") if state is not None else "?",
                    supervision=supervision,
                    statusword=sw,
                    power_state=decode_statusword(sw).name if sw is not None else "",
                    error_code=_u(node, 0x603F, 0, 2) if is_drive else None,
                    mode_display=_u(node, 0x6061, 0, 1, signed=True) if is_drive else None,
                    mapping=_mapping(node, names),
                )
            )
    return nodes


def nodes_as_json(nodes: list[ScannedNode]) -> list[dict[str, object]]:
    return [asdict(n) for n in nodes]


def _hex(value: int | None, digits: int) -> str:
    return "-" if value is None else f"0x{value:0{digits}X}"


def nodes_table(nodes: list[ScannedNode]) -> str:
    """One block per node, as a commissioning tool shows it."""
    if not nodes:
        return "no node answered (bus, bit rate, termination, power; an unconfigured one: --lss-scan)"
    lines = []
    for n in nodes:
        lines.append(
            f"node {n.node_id}: vendor {_hex(n.vendor_id, 8)} product {_hex(n.product_code, 8)} "
            f"revision {_hex(n.revision, 8)} serial {_hex(n.serial, 8)}, device type {_hex(n.device_type, 8)}"
        )
        lines.append(
            f"  NMT {n.nmt_state}"
            + (f" ({n.supervision})" if n.supervision else " (neither heartbeat nor guarding answered)")
        )
        if n.statusword is not None:
            lines.append(
                f"  power {n.power_state} (statusword {_hex(n.statusword, 4)}), error code 0x603F {_hex(n.error_code, 4)}, "
                f"mode display {n.mode_display}"
            )
        for name, objects in n.mapping.items():
            lines.append(f"  {name}: " + (", ".join(objects) if objects else "(nothing mapped)"))
    return "\n".join(lines)


# -- LSS (CiA 305) --------------------------------------------------------------------------


@dataclass(frozen=True)
class LssNode:
    """A node without a node id found by the fast scan: its LSS address (0x1018 sub 1..4)."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int
    assigned: int | None = None  # the node id it was given (None: only found)


def lss_fast_scan(bus: can.BusABC, assign: tuple[int, ...] = (), max_nodes: int = 16) -> list[LssNode]:
    """Find the nodes without a node id (LSS fast scan), one at a time; give the first ``assign[0]``,
    the next ``assign[1]``, ... (configure node id, store, back to waiting: it starts with it).

    Without ids to give, each found node is left in waiting again, and is found again: the scan
    stops after the first (the fast scan finds the unconfigured node with the lowest address)."""
    found: list[LssNode] = []
    with _network(bus) as network:
        lss = network.lss
        lss.RESPONSE_TIMEOUT = LSS_RESPONSE_TIMEOUT_S
        lss.send_switch_state_global(lss.WAITING_STATE)
        while len(found) < max_nodes:
            ok, address = lss.fast_scan()
            if not ok or address is None:
                break
            node = LssNode(address[0], address[1], address[2], address[3])
            k = len(found)
            if k >= len(assign):
                found.append(node)
                lss.send_switch_state_global(lss.WAITING_STATE)
                break
            try:
                lss.configure_node_id(assign[k])
                lss.store_configuration()
            except LssError as err:
                lss.send_switch_state_global(lss.WAITING_STATE)
                raise NodeScanError(
                    f"LSS: the node with serial 0x{node.serial:08X} refused node id {assign[k]}: {err}"
                ) from err
            lss.send_switch_state_global(lss.WAITING_STATE)  # it starts with its new id
            vendor, product, revision, serial = address
            found.append(LssNode(vendor, product, revision, serial, assigned=assign[k]))
            time.sleep(0.1)  # its boot-up
    return found


def log_quietly() -> None:
    """canopen logs an INFO line per LSS message and an ERROR per SDO timeout of a scan's absent nodes."""
    for name in ("canopen.lss", "canopen.sdo.client"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
