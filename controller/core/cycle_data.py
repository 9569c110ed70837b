"""What crosses the boundary of the pure control step: inputs, outputs and events.

All positions are in actuator units (metres for linear actuators, radians for rotary ones),
forces in newtons, torques in newton metres. Frozen, slotted dataclasses: cheap to build
once a cycle and safe to hand to the recorder and publisher threads.
"""

from __future__ import annotations

import math
from enum import IntEnum, StrEnum

from controller.core.records import record


@record
class DriveFeedback:
    statusword: int
    position: float
    fresh: bool  # its TPDO arrived this cycle (else the values are the last ones received)
    # The drive's effort [N] (CiA 402 0x6077 torque actual value, a linear motor's force), positive
    # pushing its carriage towards +q; NaN where its TPDO does not map it. The contact force's
    # second witness (controller/core/contact_guard.py).
    effort_n: float = math.nan


# The force sensor's status bits (drivers/eds/force_sensor.eds, object 0x2002), as SensorFeedback.status carries them.
SENSOR_FORCE_SATURATED = 0x01
SENSOR_TORQUE_SATURATED = 0x02
SENSOR_ERROR = 0x04
# The pose tracker's status bits, as TrackerFeedback.status carries them (drivers/pdo_codec.py: both
# frames' bits of one sample). Any bit set: the task does not average the sample (planned_legs.py).
TRACKER_SATURATED = 0x01  # a coordinate beyond the i16 range (the frame carries the clipped value)


@record
class SensorFeedback:
    force_n: tuple[float, float, float]
    torque_nm: tuple[float, float, float]
    status: int
    counter: int
    fresh: bool


@record
class TrackerFeedback:
    """The platform's pose from a pose tracker (drivers/pdo_codec.py: its two TPDOs), in the base frame {0}."""

    position_m: tuple[float, float, float]
    rotation_vector_rad: tuple[float, float, float]  # R = exp([rotation_vector]x)
    status: int  # TRACKER_* bits of both frames of the sample (0: a good measurement)
    counter: int
    fresh: bool  # a new sample (both frames, one counter) arrived since the last cycle


@record
class EmcyReport:
    node_id: int
    error_code: int
    error_register: int


class Anomaly(StrEnum):
    """Something on the bus that no configured device or the controller itself should have sent."""

    UNKNOWN_FRAME = "unknown_frame"  # a COB-ID that no configured node and not the controller uses
    EXTENDED_FRAME = "extended_frame"  # a 29-bit identifier: no CANopen device's, whatever its value
    UNKNOWN_EMCY = "unknown_emcy"  # an EMCY from a node that is not configured
    UNKNOWN_HEARTBEAT = "unknown_heartbeat"  # a heartbeat or boot-up from a node that is not configured
    FOREIGN_SYNC = "foreign_sync"  # a SYNC the controller did not send: a second SYNC producer
    FOREIGN_NMT = "foreign_nmt"  # an NMT command the controller did not send, to all or to a configured node
    FOREIGN_COMMAND = "foreign_command"  # a frame on a COB-ID only the controller sends (RPDO, its heartbeat)
    FOREIGN_SDO = "foreign_sdo"  # a configured node's SDO answer to a request the controller did not send
    DUPLICATE_FRAME = "duplicate_frame"  # a node's TPDO twice in one cycle: its sample is unusable this cycle
    REJECTED_FRAME = "rejected_frame"  # a configured node's frame that does not decode (wrong length)
    IMPLAUSIBLE_FRAME = "implausible_frame"  # a candidate beyond the device's physics or counter
    FRAME_FLOOD = "frame_flood"  # more foreign frames in one cycle than safety.max_foreign_frames_per_cycle


@record
class BusAnomaly:
    """``count`` frames of one anomaly in one cycle; ``cob_id`` of the (first or most frequent) one.

    ``node_id``: the configured node the frames concern (the TPDO's or EMCY's owner, an NMT
    command's target; 0: none or all); ``command``: an NMT command's specifier (CiA 301).
    """

    kind: Anomaly
    cob_id: int
    count: int
    node_id: int = 0
    command: int = 0


@record
class NmtReport:
    """A configured node's heartbeat this cycle that did not say OPERATIONAL (CiA 301 states)."""

    node_id: int
    state: int  # 0 boot-up, 4 stopped, 5 operational, 127 pre-operational


class Command(StrEnum):
    """A remote command accepted for this cycle (controller/monitoring); a stop is ``stop_requested``."""

    NONE = ""
    PAUSE = "pause"
    RESUME = "resume"
    SET_FORCE = "set_force"  # command_value: the new force setpoint [N]
    RESET = "reset"  # leave FAULT
    QUICK_STOP = "quick_stop"  # from the loop shell only (a second signal, a stop that did not end in time)


class Reaction(StrEnum):
    """What the law does about an abnormal input (config ``[safety]``, control_law ``_react``)."""

    FAULT = "fault"  # quick stop, stay in FAULT until a reset
    WARN = "warn"  # one warning event per episode, go on
    IGNORE = "ignore"


class EmcyAction(StrEnum):
    """What the law does about a drive's EMCY error code (config ``actuators.emcy_reactions``)."""

    FAULT = "fault"  # quick stop, stay in FAULT until a reset (every code not configured)
    HOLD = "hold"  # a running task pauses (brakes and holds) until the operator resumes it
    WARN = "warn"  # one warning event per code and episode, go on


@record
class BusFeedback:
    """What the bus delivered for one cycle: the exchange's result, before the loop adds its own inputs."""

    drives: tuple[DriveFeedback, ...]
    sensor: SensorFeedback | None = None
    emcy: tuple[EmcyReport, ...] = ()
    lost_heartbeats: tuple[int, ...] = ()  # node ids whose heartbeat is overdue
    error_frames: int = 0  # CAN error frames received this cycle
    bus_off: bool = False  # an error frame reported bus-off
    anomalies: tuple[BusAnomaly, ...] = ()
    nmt_reports: tuple[NmtReport, ...] = ()
    tracker: TrackerFeedback | None = None


@record
class CycleInputs:
    drives: tuple[DriveFeedback, ...]
    sensor: SensorFeedback | None = None
    emcy: tuple[EmcyReport, ...] = ()
    stop_requested: bool = False
    command: Command = Command.NONE
    command_value: float = 0.0
    lost_heartbeats: tuple[int, ...] = ()  # node ids whose heartbeat is overdue
    error_frames: int = 0  # CAN error frames received this cycle
    bus_off: bool = False  # an error frame reported bus-off
    late: bool = False  # the loop woke more than the configured tolerance after its deadline
    anomalies: tuple[BusAnomaly, ...] = ()  # foreign, unknown, duplicate or flooding frames this cycle
    nmt_reports: tuple[NmtReport, ...] = ()  # configured nodes whose heartbeat was not OPERATIONAL
    tracker: TrackerFeedback | None = None  # the platform's measured pose, where a tracker is configured
    plans_ready: int = 0  # the last plan request the shell's off-loop planner has finished (plan_worker.py)
    # this cycle's SYNC went without the last step's targets: the loop skipped deadlines before it,
    # or it went too long after the SYNC before (drivers/cyclic_exchange.py targets_sync_gap_s)
    targets_withheld: bool = False


@record
class CycleOutputs:
    controlwords: tuple[int, ...]
    targets: tuple[float, ...]
    # (drive index, controlword) to be written by SDO 0x6040 as well this cycle: in FAULT, to drives
    # that may not process RPDOs (not OPERATIONAL, not heard). The loop shell writes it, off the step.
    sdo_controlwords: tuple[tuple[int, int], ...] = ()


class Severity(IntEnum):
    INFO = 0
    WARNING = 1
    FAULT = 2


@record
class Event:
    kind: str  # a stable identifier: "mode", "drive_fault", "missing_tpdo", ...
    severity: Severity
    message: str


def cycle_inputs(
    feedback: BusFeedback,
    stop_requested: bool = False,
    command: Command = Command.NONE,
    command_value: float = 0.0,
    late: bool = False,
    plans_ready: int = 0,
    targets_withheld: bool = False,
) -> CycleInputs:
    """The step's inputs: the bus's feedback plus what the loop knows (stop, remote command, lateness)."""
    return CycleInputs(
        drives=feedback.drives,
        sensor=feedback.sensor,
        emcy=feedback.emcy,
        stop_requested=stop_requested,
        command=command,
        command_value=command_value,
        lost_heartbeats=feedback.lost_heartbeats,
        error_frames=feedback.error_frames,
        bus_off=feedback.bus_off,
        late=late,
        anomalies=feedback.anomalies,
        nmt_reports=feedback.nmt_reports,
        tracker=feedback.tracker,
        plans_ready=plans_ready,
        targets_withheld=targets_withheld,
    )
