"""The tasks the controller knows: one ``TaskEntry`` each.

An entry is the task's configuration section (``[task.<kind>]``, or none), the factory that
builds it for a robot, and what the simulator should place for it (``sim_environment``: the
contour task's workpiece). Which robot runs which task is the robot's entry's ``tasks``. Tasks
are found through the ``cheope.tasks`` entry points (controller/plugins.py): the built-in ones
are declared in this project's ``pyproject.toml``, their entries in ``controller/tasks/builtin.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from controller.plugins import TASKS_GROUP, Registry

if TYPE_CHECKING:
    from controller.core.ports import Robot, Task
    from controller.robot_registry import ActuatorUnits


class RunReport(Protocol):
    """A task's own account of a run (the 3-nSPU's reached pose against its goal): an observer
    of every cycle (controller/shell/loop.py ``CycleObserver``) whose summary joins the run's."""

    def on_cycle(
        self, cycle: int, t: float, inputs: Any, state: Any, outputs: Any, events: Any, timing: Any
    ) -> None: ...

    def summary(self) -> dict[str, object]: ...


@dataclass(frozen=True)
class BuiltTask:
    task: Task[Any]
    reports: tuple[RunReport, ...] = field(default=())


@dataclass(frozen=True)
class TaskSettings:
    """What a task's factory may need beside its own section, resolved once by the assembly
    (``controller/assembly.py``): a task does not read the whole configuration."""

    robot_section: Any  # [robot.<kind>]: a task made for one robot reads that robot's settings here
    units: ActuatorUnits  # the actuators' unit and limits
    settle_tolerance_m: float  # loop.settle_tolerance_m: "at rest" at the end of a motion
    max_contact_force_n: float  # safety.max_contact_force_n: the safety layer's limit
    tracker_enabled: bool  # [tracker]: a pose tracker measures the platform
    witness_tolerance_n: float = 6.0  # safety.contact.tolerance_n: the drives' effort witness's own error
    guarded_move_force_n: float = 25.0  # safety.contact.guarded_move_force_n: a guarded move stops above
    max_contact_speed_m_s: float = 0.1  # safety.contact.max_contact_speed_m_s: moves expecting contact
    cell_stiffness_n_m: float = 2.4e5  # safety.contact.cell_stiffness_n_m: the stiffest contact of the cell
    period_s: float = 0.0025  # 1 / loop.rate_hz


@dataclass(frozen=True)
class TaskEntry:
    kind: str  # task.kind in the configuration
    section: type | None  # its [task.<kind>] section (a frozen dataclass), or None
    # (its section or None, the robot, the shared settings) -> the task; raises ConfigError /
    # WorkspaceError / PlanningError
    build: Callable[[Any, Robot, TaskSettings], BuiltTask]
    check: Callable[[Any], None] | None = None  # cross-checks of its section: raise ConfigError
    sim_environment: str = (
        "free"  # what the simulator places with sim.environment = "auto": "free", "workpiece"
    )
    # Whether the task reads the force sensor's samples: then every cycle without one counts towards
    # safety.sensor_stale_s; if not, the sensor is supervised by its heartbeat (LawConfig).
    uses_force_sensor: bool = False
    # Whether the task, told that the force sensor is no longer trusted (``TaskContext.sensor_breach``),
    # retracts without force data and ends with a fault: then a second sender on the sensor's COB-ID
    # during the task is a controlled retract, not a quick stop in contact (docs/concepts/supervision.md).
    retracts_on_sensor_breach: bool = False
    # Laps the task runs, from its section (the live status line's "lap 2/5"); None: it counts none.
    laps: Callable[[Any], int] | None = None
    # The outline the task expects to meet, from its section, in {0} [m] (drawn faint in the 3D
    # scene beside what the simulator really has); None: nothing expected.
    expected_outline: Callable[[Any], tuple[tuple[float, float, float], ...]] | None = None
    # Overrides (dotted keys) that make the task last at least this long [s], from its section: a
    # bench run of a fixed length (``cheope bench``); None: the task lasts as configured.
    lasting: Callable[[Any, float], dict[str, object]] | None = None
    # Robot kinds this task runs on besides the robots whose entry lists it (``RobotEntry.tasks``):
    # a task of a plug-in names the robots it was made for without changing their entries.
    robots: tuple[str, ...] = ()
    # The robot's optional capabilities the task calls (controller/core/ports.py: ``JointMotion``, ...):
    # a robot without one is refused at start, naming what it lacks (controller/assembly.py).
    needs: tuple[type, ...] = ()


TASKS: Registry[TaskEntry] = Registry(TASKS_GROUP, TaskEntry, "task")
register_task = TASKS.register
unregister_task = TASKS.unregister


def _entries() -> dict[str, TaskEntry]:
    return TASKS.entries()


def task_kinds() -> tuple[str, ...]:
    return tuple(_entries())


def task_sections() -> dict[str, type | None]:
    return {kind: e.section for kind, e in _entries().items()}


def task_entry(kind: str) -> TaskEntry:
    return TASKS.entry(kind)
