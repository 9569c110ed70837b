"""What the ROS 2 bridge publishes, taken from a controller's Zenoh state or from a recorded cycle (no ROS here).

One ``BridgeSample`` per state sample, from either source, so that ``cheope ros2`` and
``cheope ros2 --replay`` publish the same topics with the same meaning:

- ``stamp_ns``: ROS time, the wall clock [ns]: the controller's monotonic clock when the loop
  handed the cycle over (``MonitorState.cycle_monotonic_s``) plus the controller's offset of the
  wall clock from it (``Status.clock_offset_ns``); in a recording the message's log time, which
  is the same reading with the recording's ``clock_offset_ns``;
- ``tcp_reference_m``: the TCP the actuator targets command, the robot's direct kinematics of
  ``targets`` (the Zenoh state carries the targets, not the task's path point); None where the
  model has no solution there;
- ``torque_nm`` only from a recording (the Zenoh state carries the forces only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.core.controller_state import Mode
from logs.messages import recorded_efforts

if TYPE_CHECKING:
    from controller.core.ports import Robot

Vec3 = tuple[float, float, float]
_GRID_TOLERANCE_S = 1e-6  # the sum of the sampling intervals drifts from the cycles' times by rounding


@dataclass(frozen=True)
class BridgeSample:
    robot_id: str
    cycle: int
    t_s: float  # the cycle's nominal time since the start [s]
    stamp_ns: int  # ROS time at this cycle: the controller's monotonic clock on the wall clock [ns]
    mode: str
    task: str
    task_phase: str
    positions: tuple[float, ...]  # measured actuator positions [m] or [rad]
    efforts: tuple[float, ...]  # the drives' efforts (0x6077) [N] or [N m]; empty where not mapped
    targets: tuple[float, ...]
    tcp_measured_m: Vec3 | None
    tcp_reference_m: Vec3 | None
    force_n: Vec3 | None
    torque_nm: Vec3 | None
    alarms: tuple[str, ...] = ()
    counters: dict[str, float] = field(default_factory=dict)  # loop statistics, by name


def _vec3(values: Any) -> Vec3 | None:
    v = tuple(float(x) for x in values)
    return (v[0], v[1], v[2]) if len(v) == 3 else None


def commanded_tcp(robot: Robot | None, targets: tuple[float, ...]) -> Vec3 | None:
    """The robot's direct kinematics of ``targets``; None without a model, a solution or a finite result."""
    if robot is None or len(targets) != robot.n_actuators:
        return None
    from controller.errors import NoSolutionError

    try:
        p = robot.direct_kinematics(np.asarray(targets, dtype=float))
    except (NoSolutionError, ValueError, ArithmeticError):
        return None
    v = _vec3(np.ravel(p)[:3])
    return v if v is not None and all(math.isfinite(x) for x in v) else None


def sample_from_state(state: Any, robot: Robot | None, clock_offset_ns: int) -> BridgeSample:
    """A ``cheope.v1.MonitorState`` as a sample, stamped with the controller's ``clock_offset_ns``."""
    loop = state.loop
    targets = tuple(state.targets)
    return BridgeSample(
        robot_id=state.robot_id,
        cycle=state.cycle,
        t_s=state.t_s,
        stamp_ns=round(state.cycle_monotonic_s * 1e9) + clock_offset_ns,
        mode=state.mode,
        task=state.task,
        task_phase=state.task_phase,
        positions=tuple(state.positions),
        efforts=tuple(state.efforts_n),
        targets=targets,
        tcp_measured_m=_vec3(state.tcp_m),
        tcp_reference_m=commanded_tcp(robot, targets),
        force_n=_vec3(state.force_n),
        torque_nm=None,
        alarms=tuple(state.alarms),
        counters={
            "achieved_rate_hz": loop.achieved_rate_hz,
            "period_error_p50_us": loop.period_error_p50_us,
            "period_error_p99_us": loop.period_error_p99_us,
            "late_cycles": loop.late_cycles,
            "missing_drive_frames": loop.missing_drive_frames,
            "missing_sensor_frames": loop.missing_sensor_frames,
            "rejected_frames": loop.rejected_frames,
        },
    )


@dataclass
class CycleSampler:
    """Recorded ``cheope.v1.Cycle`` messages as samples, at most one per ``1 / rate_hz`` of cycle time."""

    robot_id: str
    task: str
    robot: Robot | None
    rate_hz: float
    late_cycles: int = 0
    _next_t: float = -math.inf

    def sample(self, c: Any, stamp_ns: int) -> BridgeSample | None:
        self.late_cycles += bool(c.inputs.late)
        if c.t_s < self._next_t - _GRID_TOLERANCE_S:
            return None
        interval_s = 1.0 / self.rate_hz
        self._next_t = (c.t_s if self._next_t == -math.inf else self._next_t) + interval_s
        if self._next_t <= c.t_s:  # a gap in the recording: restart the grid here
            self._next_t = c.t_s + interval_s
        sensor = c.inputs.sensor if c.inputs.HasField("sensor") else None
        targets = tuple(c.outputs.targets)
        st = c.state
        return BridgeSample(
            robot_id=self.robot_id,
            cycle=c.cycle,
            t_s=c.t_s,
            stamp_ns=stamp_ns,
            mode=st.mode,
            task=self.task,
            task_phase=st.task_phase,
            positions=tuple(d.position for d in c.inputs.drives),
            efforts=recorded_efforts(c.inputs.drives),
            targets=targets,
            tcp_measured_m=_vec3(st.tcp_measured_m),
            tcp_reference_m=commanded_tcp(self.robot, targets),
            force_n=_vec3(sensor.force_n) if sensor is not None else None,
            torque_nm=_vec3(sensor.torque_nm) if sensor is not None else None,
            alarms=(f"FAULT: {st.fault_reason}",) if st.fault_reason else (),
            counters={"late_cycles": self.late_cycles},
        )


def diagnostic_level(sample: BridgeSample) -> int:
    """0 OK, 1 WARN (alarms), 2 ERROR (the controller is in FAULT): diagnostic_msgs/DiagnosticStatus levels."""
    if sample.mode == Mode.FAULT.name:
        return 2
    return 1 if sample.alarms else 0


@dataclass
class EveryInterval:
    """True at most once per ``interval_ns`` of sample time (``/diagnostics`` at about 1 Hz)."""

    interval_ns: int
    _next_ns: int | None = None

    def due(self, stamp_ns: int) -> bool:
        if self._next_ns is not None and stamp_ns < self._next_ns:
            return False
        self._next_ns = stamp_ns + self.interval_ns
        return True
