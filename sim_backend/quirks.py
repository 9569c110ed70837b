"""Drives as they really are: vendor behaviours the simulated nodes can be given, one by one.

The simulated devices are ideal CiA 402 nodes unless ``sim.drive.quirks`` names some of the
behaviours below, each for every drive (``"NAME"``) or for one node (``"NAME:NODE"``); the
values they take (a delay, a hold time) are in ``[sim.quirk]``. Each models a behaviour that
users of the common CANopen masters have reported from real drives (the tracker threads named
in ``TRACKERS``); the controller handles each through configuration (docs/reference/canopen.md,
"Drives as they really are"). Where a behaviour lives:

- in the device (``sim_backend/drive.py``, ``DriveQuirks``), shared by the simulator process and
  the in-process loopback: ``boots_in_fault``, ``fault_reset_hold``, ``slow_power_states``,
  ``homing_not_attained``, ``no_homing``, ``warning_emcy_on_enable``;
- in the node's CANopen services (``sim_backend/server.py``): ``late_boot``, ``needs_nmt_reset``,
  ``slow_sdo``, ``sdo_aborts``, ``fixed_mapping``, ``guarding_only``, ``heartbeat_only``,
  ``unconfigured``;
- on the bus (both): ``bus_off``.

Pure data and parsing: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.sim_config.quirk_specs import (
    SCOPE,
    Quirk,
    Scope,
    parse_quirk,
)
from sim_backend.drive import EMCY_DC_LINK_UNDERVOLTAGE, DriveQuirks
from sim_backend.fault_injection import (
    ERROR_CLASS_BUS_OFF,
    ERROR_CLASS_CONTROLLER,
    ERROR_CLASS_RESTARTED,
    ERROR_CONTROLLER_PASSIVE,
)

# What each one does, in the words of the reference's table (docs/reference/canopen.md).
BEHAVIOUR = {
    Quirk.BOOTS_IN_FAULT: "boots in FAULT with 0x603F = 0x3220 (DC link under-voltage) and that EMCY until "
    "its power stage is ready (sim.quirk.power_stage_ready_s after boot); a fault reset before then "
    "is refused: the cause is still there",
    Quirk.FAULT_RESET_HOLD: "resets a fault only when controlword bit 7 has been held high for "
    "sim.quirk.fault_reset_hold_s; a one-cycle edge does nothing",
    Quirk.SLOW_POWER_STATES: "each transition towards OPERATION ENABLED (shutdown, switch on, enable "
    "operation: brake release) takes sim.quirk.transition_delay_s; the statusword shows the old "
    "state until then",
    Quirk.LATE_BOOT: "sends its boot-up and answers SDO only sim.quirk.boot_delay_s after power-on",
    Quirk.NEEDS_NMT_RESET: "stays silent after power-on (no boot-up, no SDO) until an NMT reset node or "
    "reset communication",
    Quirk.SLOW_SDO: "answers every SDO request sim.quirk.sdo_delay_min_s to sdo_delay_max_s late",
    Quirk.SDO_ABORTS: "aborts every sim.quirk.sdo_abort_every-th SDO request with 0x08000020 "
    "(data cannot be transferred): answered at the next try",
    Quirk.FIXED_MAPPING: "refuses any PDO remap (0x06010002, read only); its TPDO1 carries "
    "sim.quirk.fixed_tpdo_objects (statusword, position, mode display: no 0x6077)",
    Quirk.HOMING_NOT_ATTAINED: "homes, but never sets statusword bit 12 (homing attained): the end shows "
    "only as bit 10 and the home position",
    Quirk.NO_HOMING: "has no homing mode (0x6060 = 6 refused, 0x06090030): an absolute encoder that "
    "keeps its position across restarts",
    Quirk.WARNING_EMCY_ON_ENABLE: "sends a manufacturer-specific warning EMCY (sim.quirk.warning_emcy_code, "
    "error register bit 7) and sets statusword bit 7 each time it enables; it stays enabled",
    Quirk.GUARDING_ONLY: "has no heartbeat (0x1016, 0x1017 do not exist): it answers node guarding "
    "(0x100C, 0x100D) and reacts to a lost master by life guarding",
    Quirk.HEARTBEAT_ONLY: "has no node guarding (0x100C, 0x100D do not exist; remote frames unanswered)",
    Quirk.BUS_OFF: "the bus goes error passive sim.quirk.bus_off_after_s after the first SYNC, bus-off "
    "sim.quirk.error_passive_s later, and restarts sim.quirk.bus_off_restart_s after that",
    Quirk.UNCONFIGURED: "has no node id (LSS unconfigured, 0xFF): silent until an LSS master gives it one",
}

# The tracker threads each one is modelled on (the issue text of this work names them).
TRACKERS = {
    Quirk.BOOTS_IN_FAULT: "ros2_canopen #298, canopen #261",
    Quirk.FAULT_RESET_HOLD: "ros_canopen #138/#139, canopen #261",
    Quirk.SLOW_POWER_STATES: "ros2_canopen #298",
    Quirk.LATE_BOOT: "ros2_canopen #204, #364, #370",
    Quirk.NEEDS_NMT_RESET: "ros2_canopen #204, #364",
    Quirk.SLOW_SDO: "ros2_canopen #194/#220",
    Quirk.SDO_ABORTS: "ros2_canopen #194/#220",
    Quirk.FIXED_MAPPING: "(the controller reads the mapping back, DESIGN.md)",
    Quirk.HOMING_NOT_ATTAINED: "ros2_canopen #245",
    Quirk.NO_HOMING: "ros2_canopen #236, #200, canopen #248",
    Quirk.WARNING_EMCY_ON_ENABLE: "canopen #163",
    Quirk.GUARDING_ONLY: "canopen #543",
    Quirk.HEARTBEAT_ONLY: "canopen #543",
    Quirk.BUS_OFF: "ros_canopen #468",
    Quirk.UNCONFIGURED: "canopen #226, #290",
}


@dataclass(frozen=True)
class NodeQuirks:
    """The quirks one node has, resolved from the configuration."""

    quirks: frozenset[Quirk] = frozenset()

    def __contains__(self, quirk: Quirk) -> bool:
        return quirk in self.quirks


def quirks_of(specs: tuple[str, ...], node_id: int, is_drive: bool) -> NodeQuirks:
    """Which quirks ``specs`` (sim.drive.quirks, checked at load) give node ``node_id``."""
    found = set()
    for text in specs:
        spec = parse_quirk(text)
        scope = SCOPE[spec.quirk]
        if scope == Scope.BUS:
            continue
        if scope == Scope.DRIVE and not is_drive:
            continue
        if spec.node in (0, node_id):
            found.add(spec.quirk)
    return NodeQuirks(frozenset(found))


def bus_has(specs: tuple[str, ...], quirk: Quirk) -> bool:
    return any(parse_quirk(text).quirk == quirk for text in specs)


@dataclass(frozen=True)
class QuirkValues:
    """``[sim.quirk]`` as the devices use it (controller/sim_config/sections.py documents each value)."""

    power_stage_ready_s: float = 3.0
    fault_reset_hold_s: float = 0.05
    transition_delay_s: float = 0.3
    warning_emcy_code: int = 0xFF01


def drive_quirks(quirks: NodeQuirks, values: QuirkValues) -> DriveQuirks:
    """The device-side part of a drive's quirks (sim_backend/drive.py)."""
    return DriveQuirks(
        boot_fault_code=EMCY_DC_LINK_UNDERVOLTAGE if Quirk.BOOTS_IN_FAULT in quirks else 0,
        power_stage_ready_s=values.power_stage_ready_s,
        fault_reset_hold_s=values.fault_reset_hold_s if Quirk.FAULT_RESET_HOLD in quirks else 0.0,
        transition_delay_s=values.transition_delay_s if Quirk.SLOW_POWER_STATES in quirks else 0.0,
        homing_attained_bit=Quirk.HOMING_NOT_ATTAINED not in quirks,
        homing_mode=Quirk.NO_HOMING not in quirks,
        warning_emcy_code=values.warning_emcy_code if Quirk.WARNING_EMCY_ON_ENABLE in quirks else 0,
    )


@dataclass(frozen=True)
class BusOffSchedule:
    """The bus_off quirk on the time since the first SYNC: error passive at ``after_s``, bus-off
    ``passive_s`` later, the interface restarted ``restart_s`` after that (SocketCAN's restart-ms).

    While the bus is off nothing passes either way; the error frames are what a SocketCAN
    interface reports at each step (linux/can/error.h).
    """

    after_s: float
    passive_s: float
    restart_s: float

    def off(self, elapsed_s: float) -> bool:
        start = self.after_s + self.passive_s
        return start <= elapsed_s < start + self.restart_s

    def error_frames(self, before_s: float, now_s: float) -> tuple[tuple[int, bytes], ...]:
        """(class, data) of the error frames whose moment falls in (``before_s``, ``now_s``]."""
        off = self.after_s + self.passive_s
        steps = (
            (self.after_s, ERROR_CLASS_CONTROLLER, bytes((0, ERROR_CONTROLLER_PASSIVE, 0, 0, 0, 0, 0, 0))),
            (off, ERROR_CLASS_BUS_OFF, bytes(8)),
            (off + self.restart_s, ERROR_CLASS_RESTARTED, bytes(8)),
        )
        return tuple((cls, data) for at, cls, data in steps if before_s < at <= now_s)
