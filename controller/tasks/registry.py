"""The tasks the controller knows: one ``TaskEntry`` each.

An entry is the task's configuration section (``[task.<kind>]``, or none), the factory that
builds it for a robot, and what the simulator should place for it (``sim_environment``: the
contour task's workpiece). Which robot runs which task is the robot's entry's ``tasks``. The
built-in tasks are registered in ``controller/tasks/builtin.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from controller.config import Config
    from controller.robots.robot import Robot
    from controller.tasks.task import Task


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
class TaskEntry:
    kind: str  # task.kind in the configuration
    section: type | None  # its [task.<kind>] section (a frozen dataclass), or None
    build: Callable[[Config, Robot], BuiltTask]  # raises ConfigError / WorkspaceError / PlanningError
    check: Callable[[Any], None] | None = None  # cross-checks of its section: raise ConfigError
    sim_environment: str = (
        "free"  # what the simulator places with sim.environment = "auto": "free", "workpiece"
    )
    # Whether the task reads the force sensor's samples: then every cycle without one counts towards
    # safety.sensor_stale_cycles; if not, the sensor is supervised by its heartbeat (LawConfig).
    uses_force_sensor: bool = False


_TASKS: dict[str, TaskEntry] = {}


def register_task(entry: TaskEntry) -> None:
    """Add a task; registering a kind again replaces its entry."""
    _TASKS[entry.kind] = entry


def _entries() -> dict[str, TaskEntry]:
    if not _TASKS:
        import controller.tasks.builtin  # noqa: F401  (registers path, contour, planned)
    return _TASKS


def task_kinds() -> tuple[str, ...]:
    return tuple(_entries())


def task_sections() -> dict[str, type | None]:
    return {kind: e.section for kind, e in _entries().items()}


def task_entry(kind: str) -> TaskEntry:
    try:
        return _entries()[kind]
    except KeyError:
        raise KeyError(f"no task {kind!r} is registered (known: {', '.join(_entries())})") from None


def task_from_config(cfg: Config, robot: Robot) -> BuiltTask:
    return task_entry(cfg.task.kind).build(cfg, robot)
