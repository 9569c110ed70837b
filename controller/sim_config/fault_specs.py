"""The fault specs of ``sim.faults`` and ``--inject``: their grammar and their checks against the configuration.

The simulator applies them (sim_backend/fault_injection.py); the configuration parses them here,
so that a bad spec is refused when the file is read, by any process.

A fault is written ``KIND[:NODE][=VALUE]@START[+DURATION]``: START seconds after the first
SYNC, for DURATION seconds (default: to the end). NODE is a CANopen node id where the kind
needs one. Kinds:

- ``drop:N``       node N sends no TPDO (a dead or unplugged drive)
- ``delay:N=S``    drive N's TPDOs leave S seconds late (in-process: they miss their cycle)
- ``malformed:N``  node N's TPDO has the wrong length (counted and rejected by the controller)
- ``drive_fault:N``  drive N goes to FAULT and sends EMCY 0x5000
- ``heartbeat:N``  node N stops its heartbeat
- ``freeze``       the force sensor's counter stops advancing (stale data)
- ``stuck``        the force sensor's sample stops changing while its counter advances (a dead
                   bridge or a hung converter: plausible, fresh and wrong)
- ``saturate``     the force sensor reports saturation
- ``force=F``      the force sensor sees an extra F newtons along X (an unexpected contact)
- ``drift=R``      the force sensor's bias drifts by R newtons a second along X (temperature); after
                   DURATION the bias stays where it drifted to
- ``error_frames`` CAN error frames on the bus; ``bus_off`` an error frame reporting bus-off
- ``tx_full``      the controller's frames do not reach the devices (a full transmit queue)
- ``stall=S``      the controller's loop wakes S seconds late at every deadline while active, and
                   skips the deadlines it missed (in-process runs in simulated time only)
- ``send_stall=S`` the controller's loop is held up S seconds inside its send at every SYNC while
                   active: after its RPDOs went and before their SYNC (in-process runs in simulated
                   time only; over a bus the machine does it: a 7.25-ms hold-up inside a send)

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
    "stuck",
    "saturate",
    "force",
    "drift",
    "error_frames",
    "bus_off",
    "tx_full",
    "stall",
    "send_stall",
    "foreign_sync",
    "flood",
    "spoof_sensor",
)


# The kinds that act on a drive alone. ``delay`` among them: the simulated devices delay a drive's
# TPDO only (sim_backend/server.py, loopback.py); delay:16 on the sensor was taken and injected
# nothing (an outside tester).
DRIVE_ONLY_KINDS = ("drive_fault", "block", "jump", "reboot", "rogue_tpdo", "rogue_short", "delay")


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
    if kind not in KINDS_WITH_NODE and m["node"] is not None:
        # it acts on the one force sensor or on the bus: a node here was ignored without a word
        raise FaultSpecError(f"fault {text!r}: {kind} takes no node id, e.g. {kind}@1.0")
    return Fault(
        kind=kind,
        start_s=float(m["start"]),
        duration_s=float(m["duration"]) if m["duration"] else math.inf,
        node=int(m["node"]) if m["node"] else 0,
        value=float(m["value"]) if m["value"] else 0.0,
    )


def fault_text(f: Fault) -> str:
    """``f`` written as a spec (``parse_fault`` reads it back as ``f``): how a summary names it."""
    node = f":{f.node}" if f.kind in KINDS_WITH_NODE else ""
    value = f"={f.value:g}" if f.value else ""
    duration = f"+{f.duration_s:g}" if math.isfinite(f.duration_s) else ""
    return f"{f.kind}{node}{value}@{f.start_s:g}{duration}"


# What only the in-process loop in simulated time can do: the simulator process cannot hold a
# controller's loop that runs on its own clock (over the bus a ``stall`` injected nothing, silently).
IN_PROCESS_ONLY_KINDS = ("stall", "send_stall")


def refuse_in_process_only(texts: Sequence[str], command: str) -> None:
    """A FaultSpecError naming the first fault of ``texts`` that ``command`` (over a bus) cannot inject."""
    for text in texts:
        f = parse_fault(text)
        if f.kind in IN_PROCESS_ONLY_KINDS:
            raise FaultSpecError(
                f"fault {text!r}: {f.kind} holds the in-process loop and is injected in simulated time "
                f"only (cheope demo --simulated-time); {command} runs over a bus, where the loop's "
                "lateness is the machine's own"
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
    if f.duration_s <= 0.0:  # drop:2@0+0 was taken, and injected nothing (an outside tester)
        raise FaultSpecError(
            f"fault {text!r}: lasts {f.duration_s:g} s: give +DURATION > 0, or none for ever"
        )
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
    if f.kind in ("delay", "stall", "send_stall") and not 0.0 < f.value <= MAX_LATENESS_S:
        raise FaultSpecError(
            f"fault {text!r}: {f.kind} of {f.value:g} s must be in (0, {MAX_LATENESS_S:g}] s; "
            f"a longer silence is drop:N (a node) or a dead controller"
        )
    if f.kind in ("force", "drift") and not abs(f.value) <= MAX_EXTRA_FORCE_N:
        raise FaultSpecError(
            f"fault {text!r}: {f.kind}={f.value:g} is beyond +-{MAX_EXTRA_FORCE_N:g} N (N/s)"
        )
    return f
