"""The control law's configuration: its timing, limits and the safety layer's reactions.

Resolved once from the configuration file by controller/assembly.py; frozen values, no behaviour
beyond looking a reaction up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.core.cia402 import FaultResetConfig
from controller.core.contact_guard import ContactGuardConfig
from controller.core.cycle_data import Anomaly, EmcyAction, Reaction


@dataclass(frozen=True)
class SafetyConfig:
    """Reactions to abnormal inputs ("fault", "warn" or "ignore"); see config.SafetySection."""

    max_contact_force_n: float = 60.0
    sensor_stale_cycles: int = 20
    on_sensor_stale: Reaction = Reaction.FAULT
    on_sensor_saturated: Reaction = Reaction.FAULT
    on_heartbeat_lost: Reaction = Reaction.FAULT
    on_error_frames: Reaction = Reaction.WARN
    max_consecutive_late_cycles: int = 50
    on_late_cycles: Reaction = Reaction.FAULT
    # Position plausibility [actuator unit]: a measured step beyond what the speed limit allows plus
    # this is a jump; a measured position this far from the commanded one is a following error.
    max_position_jump: float = math.inf
    following_window: float = math.inf
    on_unknown_node: Reaction = Reaction.WARN
    on_foreign_sync: Reaction = Reaction.FAULT
    on_foreign_nmt: Reaction = Reaction.FAULT
    on_foreign_command: Reaction = Reaction.FAULT
    on_duplicate_frames: Reaction = Reaction.FAULT
    on_rejected_frames: Reaction = Reaction.WARN
    on_frame_flood: Reaction = Reaction.FAULT
    sensor_breach_retract_s: float = 0.0  # see config.SafetySection; 0: fault at once
    contact: ContactGuardConfig = ContactGuardConfig()  # the contact guard ([safety.contact])

    def reaction_to(self, anomaly: Anomaly) -> Reaction:
        return {
            Anomaly.REJECTED_FRAME: self.on_rejected_frames,
            # beyond the device's physics, among several candidates: the law's jump check always faults too
            Anomaly.IMPLAUSIBLE_FRAME: Reaction.FAULT,
            Anomaly.UNKNOWN_FRAME: self.on_unknown_node,
            Anomaly.EXTENDED_FRAME: self.on_unknown_node,
            Anomaly.UNKNOWN_EMCY: self.on_unknown_node,
            Anomaly.UNKNOWN_HEARTBEAT: self.on_unknown_node,
            Anomaly.FOREIGN_SYNC: self.on_foreign_sync,
            Anomaly.FOREIGN_NMT: self.on_foreign_nmt,
            Anomaly.FOREIGN_COMMAND: self.on_foreign_command,
            Anomaly.FOREIGN_SDO: self.on_foreign_command,
            Anomaly.DUPLICATE_FRAME: self.on_duplicate_frames,
            Anomaly.FRAME_FLOOD: self.on_frame_flood,
        }[anomaly]


@dataclass(frozen=True)
class EmcyReaction:
    """EMCY error codes ``first``..``last`` of the drives get ``action`` (config ``actuators.emcy_reactions``)."""

    first: int
    last: int
    action: EmcyAction


@dataclass(frozen=True)
class LawConfig:
    period_s: float
    enable_timeout_s: float
    hold_before_task_s: float
    max_missing_cycles: int
    settle_tolerance: float  # [actuator unit] and [unit/s]: "at rest" for the stop
    # cycles of a device's silence that every device shared (loop.max_bus_silence_s); never fewer
    # than max_missing_cycles (SafetyMonitor.silent_too_long)
    max_bus_silence_cycles: int = 0
    safety: SafetyConfig = SafetyConfig()
    max_speed: float = math.inf  # [unit/s] the actuators' speed limit, for the plausibility check
    position_unit: str = "m"  # for messages
    rest_target: float = 0.0  # [unit] the target sent before a drive's first TPDO (mid-stroke)
    drive_node_ids: tuple[int, ...] = ()  # CANopen node ids of the drives, in order (empty: 1..n)
    # Does the task use the force sensor's samples? If it does, a sensor without a usable sample for
    # safety.sensor_stale_s faults; if not, a stall of its frames is no hazard and the sensor is
    # supervised by its heartbeat (loop.heartbeat_consumer_s), as any node the task does not read.
    # Its samples, when they come, are still judged against the contact-force limit. From the
    # task's entry (controller/tasks/registry.py ``uses_force_sensor``).
    sensor_in_task: bool = True
    sensor_node_id: int = 0  # the force sensor's CANopen node id (0: none), for a breach of its frames
    # The task retracts without force data when the sensor's frames are no longer trusted
    # (TaskEntry.retracts_on_sensor_breach); with safety.sensor_breach_retract_s > 0 the law lets it.
    task_retracts_on_sensor_breach: bool = False
    fault_resets: tuple[FaultResetConfig, ...] = ()  # per drive; empty: FaultResetConfig() for each
    emcy_reactions: tuple[EmcyReaction, ...] = ()  # the drives' EMCY codes that do not fault (first match)
    # A CSP drive interpolates from the target it holds to the one latched at a SYNC over one period
    # and, without a new target, runs on along that segment for this many periods more, then holds,
    # still (the drives' object 0x2010, written at set-up: sim_backend/drive.py). The step after a
    # hold-up knows from it where the drives went meanwhile (control_law ``_after_hold_up``).
    drive_extrapolation_periods: int = 1

    def fault_reset(self, j: int) -> FaultResetConfig:
        return self.fault_resets[j] if j < len(self.fault_resets) else FaultResetConfig()

    def emcy_action(self, node_id: int, code: int) -> EmcyAction:
        """A drive's EMCY ``code`` by the configured reactions; any other node's, or a code not listed: fault."""
        if node_id in self.drive_node_ids:
            for r in self.emcy_reactions:
                if r.first <= code <= r.last:
                    return r.action
        return EmcyAction.FAULT
