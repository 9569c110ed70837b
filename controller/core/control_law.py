"""The pure control step: ``step(state, inputs, t) -> (state, outputs, events)``.

One call per cycle. ``t`` is the cycle's nominal time [s] (cycle index times period), never
a clock reading, so a recorded session replays bit for bit. The setpoint computed at ``t``
is sent at the next deadline, latched by the drives on that cycle's SYNC, and reached by
the drives' interpolators one period later: it is the setpoint for ``t + 2 * period``
(``PIPELINE_PERIODS``).

Supervisor modes (see ``Mode``)::

    CONFIGURING -> ENABLING -> HOLDING -> RUNNING <-> PAUSED
                                             |          |
                                             v          v
                                            STOPPING -> DONE          (any mode) -> FAULT

CONFIGURING waits for every drive's first TPDO (the loop shell has done NMT and SDO set-up
before the first cycle), ENABLING walks each drive's CiA 402 power state machine to
OPERATION ENABLED while commanding its measured position (no jump at enable), HOLDING keeps
the position for ``hold_before_task_s``, RUNNING streams the task through Ruckig, PAUSED
brakes and holds with the task clock stopped (remote ``pause``/``resume``), STOPPING brakes
within the limits and then shuts the drives down, FAULT quick-stops them.

The task runs on its own clock, ``task_time_s``, which advances one period per RUNNING
cycle: a pause does not make a path jump ahead when it resumes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Any, Protocol, runtime_checkable

import numpy as np

from controller.core.cycle_data import Command, CycleInputs, CycleOutputs, Event, Reaction, Severity
from controller.core.setpoint_smoothing import RuckigSmoother, Setpoint
from controller.robots.cheope import PoseStatus
from controller.robots.errors import NoSolutionError
from controller.robots.robot import Robot
from controller.tasks.task import Task, TaskContext
from drivers.cia402 import PowerState, controlword_towards, decode_statusword
from drivers.pdo_codec import SENSOR_FORCE_SATURATED

PIPELINE_PERIODS = 2
# A reactive reference's position error decays with a time constant of 1/0.25 = 4 periods.
REACTIVE_CORRECTION_PERIODS = 0.25


class Mode(IntEnum):
    CONFIGURING = 0
    ENABLING = 1
    HOLDING = 2
    RUNNING = 3
    PAUSED = 4
    STOPPING = 5
    DONE = 6
    FAULT = 7


@runtime_checkable
class ChecksActuators(Protocol):
    """A robot that knows its actuators' strokes (all three robots in controller/robots)."""

    def check_actuators(self, q: tuple[float, ...]) -> PoseStatus: ...


@dataclass(frozen=True)
class SafetyConfig:
    """Reactions to abnormal inputs ("fault", "warn" or "ignore"); see config.SafetySection."""

    max_contact_force_n: float = 60.0
    sensor_stale_cycles: int = 5
    on_sensor_stale: Reaction = Reaction.FAULT
    on_sensor_saturated: Reaction = Reaction.FAULT
    on_heartbeat_lost: Reaction = Reaction.FAULT
    on_error_frames: Reaction = Reaction.WARN
    max_consecutive_late_cycles: int = 50
    on_late_cycles: Reaction = Reaction.FAULT


@dataclass(frozen=True)
class LawConfig:
    period_s: float
    enable_timeout_s: float
    hold_before_task_s: float
    max_missing_cycles: int
    settle_tolerance: float  # [actuator unit] and [unit/s]: "at rest" for the stop
    safety: SafetyConfig = SafetyConfig()


@dataclass(frozen=True, slots=True)
class ControllerState:
    mode: Mode
    cycle: int
    mode_entered_s: float
    setpoint: Setpoint
    controlwords: tuple[int, ...]
    missing_streak: tuple[int, ...]
    task_state: object
    tcp_reference_m: tuple[float, float, float] | None  # path point for the next SYNC; None off the path
    tcp_measured_m: tuple[float, float, float] | None  # direct kinematics of the measured positions
    task_time_s: float = 0.0
    fault_reason: str = ""
    sensor_counter: int = -1  # last sensor counter seen, for staleness
    sensor_stale: int = 0  # cycles the counter has not advanced
    late_streak: int = 0  # consecutive late cycles
    warned: frozenset[str] = frozenset()  # warnings already raised in the current episode


# One handler per mode: (state, inputs, power states, measured positions, t, events) -> state.
ModeHandler = Callable[
    [ControllerState, CycleInputs, tuple[PowerState, ...], tuple[float, ...], float, list[Event]],
    ControllerState,
]


class ControlLaw:
    """Composes supervisor, CiA 402 power management, task and smoothing into ``step``."""

    def __init__(self, robot: Robot, task: Task[Any], smoother: RuckigSmoother, config: LawConfig) -> None:
        self.robot = robot
        self.task = task
        self.smoother = smoother
        self.config = config
        self.n = robot.n_actuators
        # Robots that know their actuators' strokes check the measured positions every cycle.
        self._check_actuators = robot.check_actuators if isinstance(robot, ChecksActuators) else None
        self._handlers: dict[Mode, ModeHandler] = {
            Mode.CONFIGURING: self._configuring, Mode.ENABLING: self._enabling, Mode.HOLDING: self._holding,
            Mode.RUNNING: self._running, Mode.PAUSED: self._paused, Mode.STOPPING: self._stopping,
            Mode.DONE: self._done, Mode.FAULT: self._fault,
        }

    def initial_state(self) -> ControllerState:
        zeros = (0.0,) * self.n
        return ControllerState(
            mode=Mode.CONFIGURING, cycle=0, mode_entered_s=0.0, setpoint=Setpoint.at_rest(zeros),
            controlwords=(0,) * self.n, missing_streak=(0,) * self.n, task_state=None,
            tcp_reference_m=None, tcp_measured_m=None,
        )

    # -- the step -------------------------------------------------------------------------

    def step(self, state: ControllerState, inputs: CycleInputs, t: float
             ) -> tuple[ControllerState, CycleOutputs, tuple[Event, ...]]:
        events: list[Event] = []
        measured = tuple(d.position for d in inputs.drives)
        powers = tuple(decode_statusword(d.statusword) for d in inputs.drives)
        streak = tuple(0 if d.fresh else s + 1 for d, s in zip(inputs.drives, state.missing_streak))
        state = replace(state, cycle=state.cycle + 1, missing_streak=streak,
                        tcp_measured_m=self._measured_tcp(state, inputs, measured))

        if state.mode not in (Mode.FAULT, Mode.CONFIGURING):
            state, reason = self._safety(state, inputs, events)
            reason = reason or self._fault_reason(state, inputs, powers)
            if reason:
                state = self._enter(state, Mode.FAULT, t, events, Severity.FAULT, reason)
                state = replace(state, fault_reason=reason, setpoint=Setpoint.at_rest(measured))
        elif state.mode == Mode.FAULT and inputs.command == Command.RESET:
            # Recovery without a jump: ENABLING resets the drives' faults and commands the
            # measured positions; HOLDING restarts Ruckig from rest there; the task starts again.
            state = replace(self._enter(state, Mode.ENABLING, t, events, why="reset"), fault_reason="",
                            setpoint=Setpoint.at_rest(measured), task_time_s=0.0, sensor_stale=0, late_streak=0,
                            warned=frozenset())
        if inputs.stop_requested and state.mode in (Mode.ENABLING, Mode.HOLDING, Mode.RUNNING, Mode.PAUSED):
            state = self._enter(state, Mode.STOPPING, t, events, Severity.INFO, "stop requested")
        elif inputs.command == Command.PAUSE and state.mode == Mode.RUNNING:
            state = self._enter(state, Mode.PAUSED, t, events, why="remote pause")
        elif inputs.command == Command.RESUME and state.mode == Mode.PAUSED:
            state = self._enter(state, Mode.RUNNING, t, events, why="remote resume")

        state = self._handlers[state.mode](state, inputs, powers, measured, t, events)
        outputs = CycleOutputs(controlwords=state.controlwords, targets=state.setpoint.position)
        return state, outputs, tuple(events)

    # -- checks ---------------------------------------------------------------------------

    def _measured_tcp(self, state: ControllerState, inputs: CycleInputs, measured: tuple[float, ...]
                      ) -> tuple[float, float, float] | None:
        if not all(d.fresh for d in inputs.drives):
            return state.tcp_measured_m
        try:
            return tuple(self.robot.direct_kinematics(np.asarray(measured)).tolist())
        except NoSolutionError:
            return None

    def _react(self, state: ControllerState, reaction: Reaction, key: str, why: str, events: list[Event]
               ) -> tuple[ControllerState, str]:
        """Apply a configured reaction to an abnormal condition ``key``."""
        if reaction == Reaction.FAULT:
            return state, why
        if reaction == Reaction.WARN and key not in state.warned:
            events.append(Event(key, Severity.WARNING, why))
            return replace(state, warned=state.warned | {key}), ""
        return state, ""

    def _safety(self, state: ControllerState, inputs: CycleInputs, events: list[Event]
                ) -> tuple[ControllerState, str]:
        """Configurable checks of the inputs; returns the updated state and a fault reason or ""."""
        sc = self.config.safety
        sensor = inputs.sensor
        stale = 0
        if sensor is not None and sensor.fresh:
            stale = state.sensor_stale + 1 if sensor.counter == state.sensor_counter else 0
            state = replace(state, sensor_counter=sensor.counter, sensor_stale=stale)
            f = sensor.force_n
            magnitude = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            if magnitude > sc.max_contact_force_n:
                return state, f"contact force {magnitude:.1f} N above the limit of {sc.max_contact_force_n} N"
            if sensor.status & SENSOR_FORCE_SATURATED:
                state, why = self._react(state, sc.on_sensor_saturated, "sensor_saturated",
                                         f"force sensor saturated (status 0x{sensor.status:02X})", events)
                if why:
                    return state, why
        if sensor is not None and stale >= sc.sensor_stale_cycles:  # stale > 0 only with a sensor
            state, why = self._react(state, sc.on_sensor_stale, "sensor_stale",
                                     f"force sensor stale: counter stuck at {sensor.counter} for {stale} cycles",
                                     events)
            if why:
                return state, why
        if inputs.lost_heartbeats:
            state, why = self._react(state, sc.on_heartbeat_lost, "heartbeat_lost",
                                     f"heartbeat lost from node(s) {list(inputs.lost_heartbeats)}", events)
            if why:
                return state, why
        if inputs.bus_off:
            return state, "CAN bus-off reported by an error frame"
        if inputs.error_frames:
            state, why = self._react(state, sc.on_error_frames, "error_frames",
                                     f"{inputs.error_frames} CAN error frame(s) received", events)
            if why:
                return state, why
        late = state.late_streak + 1 if inputs.late else 0
        if late != state.late_streak:
            state = replace(state, late_streak=late)
        if late >= sc.max_consecutive_late_cycles:
            state, why = self._react(state, sc.on_late_cycles, "late_cycles",
                                     f"the loop woke late {late} cycles in a row", events)
            if why:
                return state, why
        if self._check_actuators is not None:
            status = self._check_actuators(tuple(d.position for d in inputs.drives))
            if not status.ok:
                return state, status.reason
        return state, ""

    def _fault_reason(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...]) -> str:
        for j, (p, streak) in enumerate(zip(powers, state.missing_streak)):
            if p in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                return f"drive {j + 1} reports {p.name} (statusword 0x{inputs.drives[j].statusword:04X})"
            if streak >= self.config.max_missing_cycles:
                return f"drive {j + 1}: no TPDO for {streak} cycles"
        for e in inputs.emcy:
            if e.error_code != 0:
                return f"EMCY from node {e.node_id}: error code 0x{e.error_code:04X}, register 0x{e.error_register:02X}"
        if state.mode in (Mode.HOLDING, Mode.RUNNING, Mode.PAUSED) or (
                state.mode == Mode.STOPPING and not self._shutting_down(state)):
            for j, p in enumerate(powers):
                if p != PowerState.OPERATION_ENABLED:
                    return f"drive {j + 1} left OPERATION ENABLED (now {p.name})"
        for j, x in enumerate(inputs.drives):
            if not math.isfinite(x.position):
                return f"drive {j + 1} position is not a number"
        return ""

    def _shutting_down(self, state: ControllerState) -> bool:
        return any(cw != controlword_towards(PowerState.OPERATION_ENABLED, PowerState.OPERATION_ENABLED)
                   for cw in state.controlwords)

    # -- mode handlers ----------------------------------------------------------------------

    def _enter(self, state: ControllerState, mode: Mode, t: float, events: list[Event],
               severity: Severity = Severity.INFO, why: str = "") -> ControllerState:
        text = f"{state.mode.name} -> {mode.name}" + (f": {why}" if why else "")
        events.append(Event("mode", severity, text))
        return replace(state, mode=mode, mode_entered_s=t)

    def _configuring(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                     measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        if all(d.fresh for d in inputs.drives):
            state = replace(state, setpoint=Setpoint.at_rest(measured))
            return self._enter(state, Mode.ENABLING, t, events, why="all drives answer")
        return state

    def _enabling(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                  measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        # Command the measured position while the drives are not enabled: no jump at enable.
        cws = tuple(controlword_towards(p, PowerState.OPERATION_ENABLED, cw)
                    for p, cw in zip(powers, state.controlwords))
        state = replace(state, controlwords=cws, setpoint=Setpoint.at_rest(measured))
        if all(p == PowerState.OPERATION_ENABLED for p in powers):
            return self._enter(state, Mode.HOLDING, t, events, why="all drives in OPERATION ENABLED")
        if t - state.mode_entered_s > self.config.enable_timeout_s:
            states = ", ".join(f"{j + 1}: {p.name}" for j, p in enumerate(powers))
            why = f"drives not enabled within {self.config.enable_timeout_s} s ({states})"
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, why), fault_reason=why)
        return state

    def _holding(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                 measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        state = self._smooth_to_rest(state, t, events)
        if t - state.mode_entered_s >= self.config.hold_before_task_s and state.mode == Mode.HOLDING:
            state = replace(state, task_state=self.task.start())
            return self._enter(state, Mode.RUNNING, t, events, why=f"task {self.task.name} starts")
        return state

    def _running(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                 measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        period = self.config.period_s
        task_time = state.task_time_s + period
        ctx = TaskContext(t_s=task_time + PIPELINE_PERIODS * period, period_s=period, setpoint=state.setpoint,
                          inputs=inputs, tcp_measured_m=state.tcp_measured_m)
        out = self.task.step(state.task_state, ctx)
        events.extend(out.events)
        task_state, ref, finished = out.state, out.reference, out.finished
        if out.fault:
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, out.fault), fault_reason=out.fault,
                           task_state=task_state, setpoint=Setpoint.at_rest(measured))
        pose = self.robot.check_pose(np.asarray(ref.tcp_m))
        if not pose.ok:
            why = f"task reference leaves the safe workspace: {pose.reason}"
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, why), fault_reason=why,
                           setpoint=Setpoint.at_rest(measured))
        if ref.reactive:
            result = self.smoother.track_velocity(state.setpoint, ref.position, ref.velocity,
                                                  REACTIVE_CORRECTION_PERIODS / period)
        else:
            result = self.smoother.step(state.setpoint, ref.position, ref.velocity, ref.acceleration)
        if not result.ok:
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, result.message),
                           fault_reason=result.message, setpoint=Setpoint.at_rest(measured))
        state = replace(state, task_state=task_state, setpoint=result.setpoint, task_time_s=task_time,
                        tcp_reference_m=ref.tcp_m if ref.on_path else None)
        if finished:
            return self._enter(state, Mode.STOPPING, t, events, why=f"task {self.task.name} finished")
        return state

    def _paused(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        return replace(self._smooth_to_rest(state, t, events), tcp_reference_m=None)

    def _stopping(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
                  measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        state = replace(state, tcp_reference_m=None)
        if not self._shutting_down(state):
            state = self._smooth_to_rest(state, t, events)
            if state.mode != Mode.STOPPING:
                return state
            tol = self.config.settle_tolerance
            if all(abs(v) <= tol for v in state.setpoint.velocity):
                state = replace(state, setpoint=Setpoint.at_rest(state.setpoint.position))
            else:
                return state
        cws = tuple(controlword_towards(p, PowerState.READY_TO_SWITCH_ON, cw)
                    for p, cw in zip(powers, state.controlwords))
        state = replace(state, controlwords=cws)
        if all(p in (PowerState.READY_TO_SWITCH_ON, PowerState.SWITCH_ON_DISABLED) for p in powers):
            return self._enter(state, Mode.DONE, t, events, why="drives shut down")
        return state

    def _done(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
              measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        return state

    def _fault(self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...],
               measured: tuple[float, ...], t: float, events: list[Event]) -> ControllerState:
        cws = tuple(controlword_towards(p, PowerState.QUICK_STOP_ACTIVE, cw)
                    for p, cw in zip(powers, state.controlwords))
        return replace(state, controlwords=cws, setpoint=Setpoint.at_rest(measured))

    def _smooth_to_rest(self, state: ControllerState, t: float, events: list[Event]) -> ControllerState:
        result = self.smoother.brake(state.setpoint)
        if not result.ok:
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, result.message),
                           fault_reason=result.message)
        return replace(state, setpoint=result.setpoint)
