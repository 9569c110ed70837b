"""What crosses the boundary of the pure control step: inputs, outputs and events.

All positions are in actuator units (metres for linear actuators, radians for rotary ones),
forces in newtons, torques in newton metres. Frozen, slotted dataclasses: cheap to build
once a cycle and safe to hand to the recorder and publisher threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum


@dataclass(frozen=True, slots=True)
class DriveFeedback:
    statusword: int
    position: float
    fresh: bool  # its TPDO arrived this cycle (else the values are the last ones received)


@dataclass(frozen=True, slots=True)
class SensorFeedback:
    force_n: tuple[float, float, float]
    torque_nm: tuple[float, float, float]
    status: int
    counter: int
    fresh: bool


@dataclass(frozen=True, slots=True)
class EmcyReport:
    node_id: int
    error_code: int
    error_register: int


class Command(StrEnum):
    """A remote command accepted for this cycle (controller/monitoring); a stop is ``stop_requested``."""

    NONE = ""
    PAUSE = "pause"
    RESUME = "resume"
    SET_FORCE = "set_force"  # command_value: the new force setpoint [N]
    RESET = "reset"  # leave FAULT


class Reaction(StrEnum):
    """What the law does about an abnormal input (config ``[safety]``, control_law ``_react``)."""

    FAULT = "fault"  # quick stop, stay in FAULT until a reset
    WARN = "warn"  # one warning event per episode, go on
    IGNORE = "ignore"


@dataclass(frozen=True, slots=True)
class BusFeedback:
    """What the bus delivered for one cycle: the exchange's result, before the loop adds its own inputs."""

    drives: tuple[DriveFeedback, ...]
    sensor: SensorFeedback | None = None
    emcy: tuple[EmcyReport, ...] = ()
    lost_heartbeats: tuple[int, ...] = ()  # node ids whose heartbeat is overdue
    error_frames: int = 0  # CAN error frames received this cycle
    bus_off: bool = False  # an error frame reported bus-off


@dataclass(frozen=True, slots=True)
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


@dataclass(frozen=True, slots=True)
class CycleOutputs:
    controlwords: tuple[int, ...]
    targets: tuple[float, ...]


class Severity(IntEnum):
    INFO = 0
    WARNING = 1
    FAULT = 2


@dataclass(frozen=True, slots=True)
class Event:
    kind: str  # a stable identifier: "mode", "drive_fault", "missing_tpdo", ...
    severity: Severity
    message: str


def cycle_inputs(feedback: BusFeedback, stop_requested: bool = False, command: Command = Command.NONE,
                 command_value: float = 0.0, late: bool = False) -> CycleInputs:
    """The step's inputs: the bus's feedback plus what the loop knows (stop, remote command, lateness)."""
    return CycleInputs(drives=feedback.drives, sensor=feedback.sensor, emcy=feedback.emcy,
                       stop_requested=stop_requested, command=command, command_value=command_value,
                       lost_heartbeats=feedback.lost_heartbeats, error_frames=feedback.error_frames,
                       bus_off=feedback.bus_off, late=late)
