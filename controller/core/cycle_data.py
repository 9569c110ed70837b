"""What crosses the boundary of the pure control step: inputs, outputs and events.

All positions are in actuator units (metres for linear actuators, radians for rotary ones),
forces in newtons, torques in newton metres. Frozen, slotted dataclasses: cheap to build
once a cycle and safe to hand to the recorder and publisher threads.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


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


@dataclass(frozen=True, slots=True)
class CycleInputs:
    drives: tuple[DriveFeedback, ...]
    sensor: SensorFeedback | None = None
    emcy: tuple[EmcyReport, ...] = ()
    stop_requested: bool = False
    command: str = ""  # a remote command accepted this cycle ("pause", "resume", "set_force", "reset"), else ""
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
