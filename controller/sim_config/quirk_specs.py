"""The drive quirks of ``sim.drive.quirks``: their names, scopes and grammar, checked against the
configuration when it is read. What each does is the simulator's (sim_backend/quirks.py)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import StrEnum

from controller.errors import InputError


class Quirk(StrEnum):
    BOOTS_IN_FAULT = "boots_in_fault"
    FAULT_RESET_HOLD = "fault_reset_hold"
    SLOW_POWER_STATES = "slow_power_states"
    LATE_BOOT = "late_boot"
    NEEDS_NMT_RESET = "needs_nmt_reset"
    SLOW_SDO = "slow_sdo"
    SDO_ABORTS = "sdo_aborts"
    FIXED_MAPPING = "fixed_mapping"
    HOMING_NOT_ATTAINED = "homing_not_attained"
    NO_HOMING = "no_homing"
    WARNING_EMCY_ON_ENABLE = "warning_emcy_on_enable"
    GUARDING_ONLY = "guarding_only"
    HEARTBEAT_ONLY = "heartbeat_only"
    BUS_OFF = "bus_off"
    UNCONFIGURED = "unconfigured"


class Scope(StrEnum):
    DRIVE = "drive"  # a drive's behaviour: every drive, or one drive's node id
    NODE = "node"  # a CANopen node's: any drive or the sensor
    BUS = "bus"  # the bus's: no node id


SCOPE = {
    Quirk.BOOTS_IN_FAULT: Scope.DRIVE,
    Quirk.FAULT_RESET_HOLD: Scope.DRIVE,
    Quirk.SLOW_POWER_STATES: Scope.DRIVE,
    Quirk.LATE_BOOT: Scope.NODE,
    Quirk.NEEDS_NMT_RESET: Scope.NODE,
    Quirk.SLOW_SDO: Scope.NODE,
    Quirk.SDO_ABORTS: Scope.NODE,
    Quirk.FIXED_MAPPING: Scope.DRIVE,
    Quirk.HOMING_NOT_ATTAINED: Scope.DRIVE,
    Quirk.NO_HOMING: Scope.DRIVE,
    Quirk.WARNING_EMCY_ON_ENABLE: Scope.DRIVE,
    Quirk.GUARDING_ONLY: Scope.DRIVE,
    Quirk.HEARTBEAT_ONLY: Scope.DRIVE,
    Quirk.BUS_OFF: Scope.BUS,
    Quirk.UNCONFIGURED: Scope.DRIVE,
}


_SPEC = re.compile(r"^(?P<name>[a-z_]+)(:(?P<node>\d+))?$")


class QuirkSpecError(InputError):
    """A quirk entry that does not parse or names a node the configuration does not have."""


@dataclass(frozen=True)
class QuirkSpec:
    quirk: Quirk
    node: int = 0  # 0: every node the quirk's scope covers


def parse_quirk(text: str) -> QuirkSpec:
    m = _SPEC.match(text.strip())
    if not m:
        raise QuirkSpecError(f"quirk {text!r}: expected NAME or NAME:NODE, e.g. slow_sdo:2")
    try:
        quirk = Quirk(m["name"])
    except ValueError:
        raise QuirkSpecError(
            f"quirk {text!r}: unknown name {m['name']!r}; known: {', '.join(q.value for q in Quirk)}"
        ) from None
    return QuirkSpec(quirk, int(m["node"]) if m["node"] else 0)


def check_quirk(text: str, drive_nodes: tuple[int, ...], sensor_node: int | None) -> QuirkSpec:
    """``parse_quirk`` plus what the configuration knows: the node exists and the scope fits."""
    spec = parse_quirk(text)
    scope = SCOPE[spec.quirk]
    if scope == Scope.BUS and spec.node:
        raise QuirkSpecError(f"quirk {text!r}: {spec.quirk} is the bus's, it takes no node id")
    if spec.node:
        allowed = (
            drive_nodes if scope == Scope.DRIVE else (*drive_nodes, *((sensor_node,) if sensor_node else ()))
        )
        if spec.node not in allowed:
            what = "drives" if scope == Scope.DRIVE else "nodes"
            raise QuirkSpecError(
                f"quirk {text!r}: node {spec.node} is not one of the {what} {', '.join(map(str, allowed))}"
            )
    return spec
