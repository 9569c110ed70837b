"""The ports: the interfaces every part of the controller speaks, in one place.

A robot model, a task, and whatever watches the loop (recorder, publisher, statistics, a tool's
own observer) meet the pure law here and nowhere else. Everything in this module is vocabulary:
protocols and frozen values, no behaviour. ``controller/core`` imports nothing above itself, so
a robot or a task of your own depends on the core and the core on neither.

- ``Robot`` (with ``PoseStatus``, ``POSE_OK`` and ``ActuatorUnit``): what a robot model is to the
  law and the service. Registered with ``controller.robot_registry``.
- ``Task`` (with ``TaskContext``, ``TaskStep``, ``JointReference``): what a task is to the law, a
  pure function from a context to a joint reference. Registered with ``controller.tasks.registry``.
  ``ForceSetpointTask``: a task whose force setpoint a remote ``set_force`` may change, and below what.
- ``JointMotion``, ``CompliantStructure``, ``ForceWitnessModel``: a robot's optional capabilities,
  what a task (``TaskEntry.needs``) or the simulator asks beyond ``Robot``; a robot that lacks one
  is refused at start naming the members it lacks (``missing_capability``).
- ``CycleObserver`` and ``CycleTiming``: what the loop shell hands every observer each cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol, Self, TypeVar, runtime_checkable

from controller.core.contact_guard import (
    ContactExpectation as ContactExpectation,  # re-exported: a task's word
)
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
from controller.core.records import record
from controller.core.setpoint_smoothing import Setpoint

if TYPE_CHECKING:  # annotations only: the registries and the configuration load without numpy
    import numpy as np

    from controller.core.controller_state import ControllerState


# -- robots -----------------------------------------------------------------------------------


class ActuatorUnit(StrEnum):
    """The position unit of a robot's actuators; it selects the ``_m`` or ``_rad`` limit keys."""

    METRE = "m"
    RADIAN = "rad"


@dataclass(frozen=True)
class PoseStatus:
    """Result of a per-cycle pose check: ``ok`` or the reason it is not."""

    ok: bool
    reason: str = ""


POSE_OK = PoseStatus(True)


class Robot(Protocol):
    """A parallel robot's model: kinematics and the checks the law and the service make.

    Positions ``q`` are in actuator units (m for linear, rad for rotary actuators, see
    ``ActuatorUnit``); poses and points in metres in the base frame.
    """

    @property
    def n_actuators(self) -> int: ...  # read-only: the models are frozen dataclasses

    def inverse_kinematics(self, tcp_m: np.ndarray, /) -> np.ndarray:
        """Actuator positions for a TCP position; raises NoSolutionError outside the workspace."""
        ...

    def direct_kinematics(self, q: np.ndarray, /) -> np.ndarray:
        """The TCP position for actuator positions; raises NoSolutionError where there is none."""
        ...

    def check_pose(self, tcp_m: np.ndarray, /) -> PoseStatus:
        """Every cycle, on the task's reference: inside the safe workspace and margins?"""
        ...

    def check_path(self, points_m: np.ndarray, /) -> None:
        """Before a run, on a whole path: raises WorkspaceError naming the first bad sample."""
        ...


@runtime_checkable
class ChecksActuators(Protocol):
    """A robot that knows its actuators' strokes (all three robots in controller/robots): the safety
    monitor checks the measured positions and each task reference's with it, every cycle, and
    prefixes whose they are ("measured: ", "task path commands "), so its reason names only the
    actuator, its position and its range. Declared here, not in the safety monitor that asks for
    it: a runtime-checkable protocol cannot live in a module compiled by mypyc
    (controller/compiled_law.py)."""

    def check_actuators(self, q: tuple[float, ...], /) -> PoseStatus: ...


@runtime_checkable
class JointMotion(Protocol):
    """A robot that gives a reactive task its actuators' motion for a TCP motion, every cycle, in plain
    floats (numpy's per-call cost is too high there): the contour task's need (``TaskEntry.needs``)."""

    def joint_motion(
        self, tcp_m: tuple[float, float, float], velocity_m_s: tuple[float, float, float], /
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(q, q_dot = J v) at ``tcp_m`` for the TCP velocity ``velocity_m_s``."""
        ...


class LumpedMasses(Protocol):
    """A translational robot's lumped masses: M = m0 I + mq J^T J (controller/robots/performance.py)."""

    @property
    def translating_kg(self) -> float: ...  # m0: what translates with the TCP

    @property
    def per_actuator_kg(self) -> float: ...  # mq: what moves with each carriage


@runtime_checkable
class CompliantStructure(Protocol):
    """A robot whose structure the simulator models: three actuators of stiffness k along J, the
    Cartesian stiffness k J^T J (seed 001 §6) and the masses above it. The simulated workpiece presses
    on this structure, and its drives report the effort (0x6077) it takes; a robot without the
    capability runs in free space only (sim_backend/plant.py refuses a workpiece at start)."""

    @property
    def masses(self) -> LumpedMasses: ...

    @property
    def actuator_stiffness_n_m(self) -> float: ...

    def jacobian(self, tcp_m: np.ndarray, /) -> np.ndarray:
        """J with q_dot = J v at ``tcp_m`` (3 x 3); raises NoSolutionError where there is none."""
        ...


@runtime_checkable
class ForceWitnessModel(Protocol):
    """A robot that tells the contact force from its drives' efforts: the force sensor's second witness.

    An optional capability (controller/core/contact_guard.py): the law cross-checks the sensor with
    it every cycle and its limits act on the larger of the two. Cheope's (controller/robots/cheope/model.py)
    maps the efforts through its Jacobian and adds back its own inertial load.
    """

    def contact_force_from_efforts(
        self,
        tcp_m: tuple[float, float, float],
        q: tuple[float, ...],
        efforts_n: tuple[float, ...],
        qdd: tuple[float, ...],
    ) -> tuple[tuple[float, float, float], float] | None:
        """(the contact force on the tool [N], |M a| [N]: the model's own inertial load), or None at a
        pose where the efforts tell nothing (a singularity)."""
        ...


# The optional capabilities of a robot: each one's members, named in a refusal at start.
CAPABILITIES: dict[type, str] = {
    JointMotion: "joint_motion()",
    CompliantStructure: "jacobian(), masses, actuator_stiffness_n_m",
    ForceWitnessModel: "contact_force_from_efforts()",
}


def missing_capability(robot: object, capability: type) -> str:
    """What ``robot`` lacks of ``capability`` (its missing members, named), or "" when it has it all."""
    members = CAPABILITIES[capability].split(", ")
    return ", ".join(m for m in members if getattr(robot, m.removesuffix("()"), None) is None)


# -- tasks ------------------------------------------------------------------------------------


S = TypeVar("S")  # a task's state


@record
class JointReference:
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    tcp_m: tuple[float, float, float]
    on_path: bool  # False while moving to the task's start (not counted in tracking error)
    reactive: bool = False  # recomputed from measurements each cycle: smoothed by velocity (see
    #                         RuckigSmoother.track_velocity), else by position
    contact: ContactExpectation = ContactExpectation.NONE  # what the law's contact guard expects

    @classmethod
    def at_rest(cls, position: tuple[float, ...], tcp_m: tuple[float, float, float]) -> JointReference:
        """Go to ``position`` and stop there (off the path): no velocity or acceleration, on any number of axes."""
        zeros = (0.0,) * len(position)
        return cls(position, zeros, zeros, tcp_m, False)


@record
class TaskContext:
    t_s: float  # task time the reference is for: advances only while the task runs
    period_s: float
    setpoint: Setpoint  # the last setpoint sent
    inputs: CycleInputs
    tcp_measured_m: tuple[float, float, float] | None
    # Non-empty: the force sensor's frames are no longer trusted (a second sender on its COB-ID, named
    # here); ``inputs.sensor`` is None from then on. A task whose entry says ``retracts_on_sensor_breach``
    # moves away from the contact without force data and ends with a fault naming it, within
    # safety.sensor_breach_retract_s; else the law faults at once.
    sensor_breach: str = ""
    # The contact force the drives' efforts imply (the sensor's second witness, contact_guard.py), this
    # cycle or the last; None without one (a robot without the capability, drives that do not map it).
    force_witness_n: tuple[float, float, float] | None = None
    # Non-empty: the sensor disagrees with that witness beyond its tolerance (why); the task must
    # resolve it (re-tare in free space) within safety.contact.sensor_suspect_s, or the law backs off.
    sensor_suspect: str = ""
    # The loop was held up so long before this cycle that the drives stand at the last setpoint
    # (``LawConfig.drive_extrapolation_periods``): a reactive reference's smoothing restarts from
    # rest there, and a task that keeps a speed of its own restarts it from zero too.
    drives_held: bool = False
    # This period is one the drives ran on blind through a hold-up of the loop: it is past, and they
    # went on at their last step. It is no period of missing samples: a task that brakes on those (the
    # contour's ``stale_hold_s``) would brake where the drives did not, and the next target would
    # pull them back. The cycle after, with its measurements, decides.
    drives_ran_on: bool = False


@record
class TaskStep:
    state: object
    reference: JointReference
    finished: bool = False
    fault: str = ""  # non-empty: the law faults with this reason
    events: tuple[Event, ...] = ()


class Task(Protocol[S]):
    """A task, generic in its own frozen state ``S`` (the law keeps it in ``ControllerState.task_state``).

    A task turns the robot's goal (follow a path, track a contour, play a plan) into the joint
    reference Ruckig smooths. It sees the cycle's inputs and the measured TCP, keeps its own
    frozen state, and may finish, raise events, or ask for a fault.

    ``step`` is called once a period of the task's time: once a cycle, and after a hold-up of the
    loop once more for each period the drives ran on meanwhile, first with inputs that measured
    nothing (``fresh`` False, ``late`` True, no command; control_law ``_after_hold_up``).
    """

    name: str

    def start(self) -> S: ...

    def step(self, state: S, ctx: TaskContext) -> TaskStep: ...

    def phase_name(self, state: S) -> str: ...


@dataclass(frozen=True)
class ForceSetpointLimit:
    """What a force setpoint must stay between, and where the bounds come from (for a refusal).

    ``accepts`` is the one rule for a setpoint: the configured one (controller/tasks/builtin.py),
    a remote ``set_force`` at the gate (controller/monitoring/command_gate.py) and in the task's step.
    """

    below_n: float  # a setpoint must be below this [N]
    why: str  # the configuration keys that set it, in words
    # and above this [N]: a setpoint the task would read as contact lost (its force below it for
    # contact_lost_s) is one it cannot hold; 0: any positive force
    above_n: float = 0.0
    above_why: str = "a force that presses"

    def accepts(self, value_n: float) -> bool:
        return math.isfinite(value_n) and max(self.above_n, 0.0) < value_n < self.below_n

    def refusal(self, value_n: float) -> str:
        """Why ``value_n`` is refused, naming both bounds and their keys."""
        return (
            f"{value_n:g} N refused: must be above {self.above_n:g} N, {self.above_why}, and below "
            f"{self.below_n:g} N, {self.why}"
        )


@runtime_checkable
class ForceSetpointTask(Protocol):
    """A task that presses with a force setpoint a remote ``set_force`` may change (the contour).

    The limit is the task's own: the force it can track and not fault at, not the safety layer's
    contact-force limit (a setpoint between the two was accepted, then faulted the task 2 s later).
    """

    def force_setpoint_limit(self) -> ForceSetpointLimit: ...


@runtime_checkable
class PlansOffLoop(Protocol):
    """A task that hands work off the loop to a process of its own (the 3-nSPU's correcting plans):
    the run starts its worker and passes the worker's progress to each step as ``CycleInputs.plans_ready``."""

    def off_loop_worker(self) -> OffLoopWorker | None: ...


# -- the loop's observers ---------------------------------------------------------------------


@record
class CycleTiming:
    wake_error_s: float  # actual wake-up minus the deadline
    step_s: float  # compute time of law.step
    # the loop's clock when the step returned; the observers may see the cycle later (in the next
    # cycle's answer window: controller/shell/loop.py)
    stepped_s: float = math.nan


class CycleObserver(Protocol):
    """Receives every cycle. Runs on the loop's thread: it must hand off and return in microseconds."""

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None: ...


class OffLoopWorker(CycleObserver, Protocol):
    """A task's worker off the loop: watches each cycle's state for a request (an observer), runs it in
    a process of its own; a context manager around the run; ``ready()`` is the number of the last
    request done, a recorded input of the step (a replay computes the same in the step)."""

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc: object) -> None: ...

    def ready(self) -> int: ...
