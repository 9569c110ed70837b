"""What a task is to the control law: a pure function from a context to a joint reference.

A task turns the robot's goal (follow a path, track a contour, play a plan) into the joint
reference Ruckig smooths. It sees the cycle's inputs and the measured TCP, keeps its own
frozen state, and may finish, raise events, or ask for a fault.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, TypeVar

from controller.core.cycle_data import CycleInputs, Event
from controller.core.setpoint_smoothing import Setpoint

S = TypeVar("S")  # a task's state


@dataclass(frozen=True, slots=True)
class JointReference:
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    tcp_m: tuple[float, float, float]
    on_path: bool  # False while moving to the task's start (not counted in tracking error)
    reactive: bool = False  # recomputed from measurements each cycle: smoothed by velocity (see
    #                         RuckigSmoother.track_velocity), else by position


@dataclass(frozen=True, slots=True)
class TaskContext:
    t_s: float  # task time the reference is for: advances only while the task runs
    period_s: float
    setpoint: Setpoint  # the last setpoint sent
    inputs: CycleInputs
    tcp_measured_m: tuple[float, float, float] | None


@dataclass(frozen=True, slots=True)
class TaskStep:
    state: object
    reference: JointReference
    finished: bool = False
    fault: str = ""  # non-empty: the law faults with this reason
    events: tuple[Event, ...] = ()


class Task(Protocol[S]):
    """A task, generic in its own frozen state ``S`` (the law keeps it in ``ControllerState.task_state``)."""

    name: str

    def start(self) -> S: ...

    def step(self, state: S, ctx: TaskContext) -> TaskStep: ...

    def phase_name(self, state: S) -> str: ...
