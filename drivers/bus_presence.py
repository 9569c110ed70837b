"""Who else is on the bus, asked before taking it: one master per bus, one device per node id.

A second ``cheope run`` with the same ``--udp-port`` and robot id took over a running robot: its
NMT pre-operational faulted the running controller, then it re-enabled the drives out of quick
stop and started its own path within 0.23 s. A second simulator on the same port faulted a
running robot too. So before it sends anything:

- a controller listens ``listen_s`` (``bus.presence_listen_s``) for what only a master sends:
  SYNC, TIME, NMT commands, RPDOs, SDO requests, LSS, and the heartbeat of its own node id (a
  live controller of the same id). A running controller sends its SYNC every cycle and its
  heartbeat every ``loop.heartbeat_period_s``; one setting devices up sends SDO requests. Any
  of them refuses the start (``OtherMasterError``, exit code 2), naming what was heard;
- a simulator listens as long for frames of devices with its node ids (TPDOs, EMCY, SDO
  answers, heartbeats), and, when no master is active (which would see a request as foreign),
  asks each of its node ids for its device type (an SDO upload of 0x1000): an idle simulator
  answers. Either refuses the start (``NodeIdsTakenError``).

The frames heard are someone else's: nothing is sent before or during the listening (a bus
receives its own frames too: the probe's requests are not counted, only the answers).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Iterable

import can

from controller.errors import RefusedError
from drivers import cob_ids

TIME = 0x100
LSS_MASTER = 0x7E5
_RPDO_CODES = (4, 6, 8, 10)  # RPDO1..4 (cob_ids.function_name)
_TPDO_CODES = (3, 5, 7, 9)
_SDO_UPLOAD_DEVICE_TYPE = bytes((0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0))  # CiA 301: read 0x1000:00


class OtherMasterError(RefusedError):
    """Another master is active on the bus this controller was to take."""


class NodeIdsTakenError(RefusedError):
    """Devices with this simulator's node ids already answer on the bus."""


def _hear(bus: can.BusABC, listen_s: float, clock: Callable[[], float]) -> Iterable[can.Message]:
    deadline = clock() + listen_s
    while (left := deadline - clock()) > 0:
        msg = bus.recv(left)
        if msg is not None and not msg.is_error_frame and not msg.is_extended_id:
            yield msg


def master_frame(cob_id: int, controller_node_id: int) -> str | None:
    """The name of a frame only a master sends (None for the devices' frames)."""
    if cob_id in (cob_ids.NMT, cob_ids.SYNC, TIME, LSS_MASTER):
        return {cob_ids.NMT: "NMT command", cob_ids.SYNC: "SYNC", TIME: "TIME", LSS_MASTER: "LSS request"}[
            cob_id
        ]
    code, node = cob_id >> 7, cob_id & 0x7F
    if node and code in _RPDO_CODES:
        return f"{cob_ids.function_name(cob_id)} to node {node}"
    if node and code == 12:
        return f"SDO request to node {node}"
    if cob_id == cob_ids.heartbeat(controller_node_id):
        return f"heartbeat of node {controller_node_id}, this controller's node id (loop.controller_node_id)"
    return None


def device_frame(cob_id: int, node_ids: frozenset[int]) -> str | None:
    """The name of a frame a device with one of ``node_ids`` sends (None otherwise)."""
    code, node = cob_id >> 7, cob_id & 0x7F
    if node not in node_ids or cob_id == cob_ids.SYNC:
        return None
    if code in _TPDO_CODES or code in (1, 11, 14):  # TPDOs, EMCY, SDO response, heartbeat
        return f"{cob_ids.function_name(cob_id)} of node {node}"
    return None


def described(heard: Counter[tuple[str, int]], listen_s: float) -> str:
    """What ``masters_heard`` or ``devices_heard`` found, for a refusal."""
    parts = [f"{name} (0x{cob:03X}) x {n}" for (name, cob), n in heard.most_common(6)]
    more = len(heard) - 6
    return f"in {listen_s:g} s: " + ", ".join(parts) + (f" and {more} more kinds" if more > 0 else "")


def masters_heard(
    bus: can.BusABC, controller_node_id: int, listen_s: float, clock: Callable[[], float] = time.monotonic
) -> Counter[tuple[str, int]]:
    """The frames only a master sends heard on ``bus`` within ``listen_s``, by (name, COB-ID)."""
    heard: Counter[tuple[str, int]] = Counter()
    for msg in _hear(bus, listen_s, clock):
        name = master_frame(msg.arbitration_id, controller_node_id)
        if name is not None:
            heard[(name, msg.arbitration_id)] += 1
    return heard


def devices_heard(
    bus: can.BusABC,
    node_ids: Iterable[int],
    sdo_node_ids: Iterable[int],
    listen_s: float,
    clock: Callable[[], float] = time.monotonic,
) -> Counter[tuple[str, int]]:
    """The frames of devices with ``node_ids`` heard on ``bus`` within ``listen_s``; with none heard and
    no master active, the answers of ``sdo_node_ids`` to a read of their device type (module text)."""
    ids = frozenset(node_ids)
    heard: Counter[tuple[str, int]] = Counter()
    master_active = False
    for msg in _hear(bus, listen_s, clock):
        name = device_frame(msg.arbitration_id, ids)
        if name is not None:
            heard[(name, msg.arbitration_id)] += 1
        master_active = master_active or msg.arbitration_id == cob_ids.SYNC
    sdo_ids = sorted(set(sdo_node_ids))
    if not heard and not master_active and sdo_ids:
        for node in sdo_ids:
            bus.send(
                can.Message(
                    arbitration_id=cob_ids.sdo_request(node),
                    data=_SDO_UPLOAD_DEVICE_TYPE,
                    is_extended_id=False,
                )
            )
        answers = {cob_ids.sdo_response(n) for n in sdo_ids}
        for msg in _hear(bus, listen_s, clock):
            if msg.arbitration_id in answers:
                heard[(f"SDO answer of node {msg.arbitration_id & 0x7F}", msg.arbitration_id)] += 1
    return heard


def check_no_other_master(
    bus: can.BusABC,
    where: str,
    controller_node_id: int,
    listen_s: float,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Refuse (``OtherMasterError``) when a master's frame is heard on ``bus`` within ``listen_s``."""
    heard = masters_heard(bus, controller_node_id, listen_s, clock)
    if heard:
        raise OtherMasterError(
            f"another master is active on {where}, heard {described(heard, listen_s)}: stop it, or take "
            "another bus (--udp-port, --bus); nothing was sent"
        )


def check_node_ids_free(
    bus: can.BusABC,
    where: str,
    node_ids: Iterable[int],
    sdo_node_ids: Iterable[int],
    listen_s: float,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Refuse (``NodeIdsTakenError``) when devices with ``node_ids`` are heard on ``bus``, or, with no
    master active, answer an SDO request to one of ``sdo_node_ids`` (devices with an object dictionary)."""
    heard = devices_heard(bus, node_ids, sdo_node_ids, listen_s, clock)
    if heard:
        taken = sorted({cob & 0x7F for _, cob in heard})
        raise NodeIdsTakenError(
            f"node id(s) {', '.join(map(str, taken))} already answer on {where}, heard {described(heard, listen_s)}: "
            "another simulator or device has them; stop it, or take another bus (--udp-port, --bus)"
        )
