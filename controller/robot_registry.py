"""The robots the controller knows: one ``RobotEntry`` each.

An entry is everything the rest of the code needs to know about a robot: its configuration
section (``[robot.<kind>]``), the factory of its model, its actuators' unit and stroke, its
default task, its shipped configuration file, and, named by module path so that the runtime
does not import them, its simulator hook (``sim_backend``) and its analysis plots (tools).
The registry finds its robots through the ``cheope.robots`` entry points (controller/plugins.py):
the three robots of the papers are declared in this project's ``pyproject.toml`` (their entries
in ``controller/robots/<kind>/entry.py``), a plug-in robot in its own distribution's; a robot of a
test or a script can also be added with ``register_robot`` (docs/tutorial/own-robot.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.core.ports import ActuatorUnit
from controller.plugins import ROBOTS_GROUP, Registry

if TYPE_CHECKING:
    from controller.core.ports import Robot


@dataclass(frozen=True)
class RobotEntry:
    kind: str  # robot.kind in the configuration
    section: type  # its [robot.<kind>] section: a frozen dataclass (controller/config.py validates it)
    build: Callable[[Any], Robot]  # its model from its section; ValueError when the geometry is inconsistent
    unit: ActuatorUnit
    stroke: Callable[[Any], tuple[float, float]]  # the actuators' range [unit] from its section
    tasks: tuple[str, ...] = ("path",)  # the task kinds it can run; the first is its demo's
    config_file: Path | None = None  # its shipped configuration (``cheope ... --robot KIND``)
    check: Callable[[Any], None] | None = None  # cross-checks of its section: raise ConfigError
    # Its simulator kinematics and its analysis plots are hooks of their own, by robot kind
    # (entry-point groups cheope.sim_kinematics and cheope.analyses: controller/plugins.py).


ROBOTS: Registry[RobotEntry] = Registry(ROBOTS_GROUP, RobotEntry, "robot")
register_robot = ROBOTS.register
unregister_robot = ROBOTS.unregister


def _entries() -> dict[str, RobotEntry]:
    return ROBOTS.entries()


def robot_kinds() -> tuple[str, ...]:
    return tuple(_entries())


def robot_sections() -> dict[str, type]:
    """``kind -> section type`` of every registered robot, for the configuration loader."""
    return {kind: e.section for kind, e in _entries().items()}


def robot_entry(kind: str) -> RobotEntry:
    return ROBOTS.entry(kind)


def check_axes(kind: str, n: int, lists: dict[str, tuple[Any, ...]]) -> None:
    """Every per-actuator list of the configuration holds one value per actuator of the robot: a
    robot of 4 or 6 axes is configured with lists of 4 or 6 (any length is a valid list)."""
    from controller.config_schema import ConfigError

    for key, values in lists.items():
        if len(values) != n:
            raise ConfigError(
                f"{key} = {list(values)}: {len(values)} value(s) for the {n} actuators of robot.kind = {kind!r}"
            )


@dataclass(frozen=True)
class ActuatorUnits:
    """The actuators' position unit and the limits in that unit (m for linear, rad for rotary)."""

    unit: ActuatorUnit
    counts_per_unit: float
    max_velocity: float  # [unit/s]   (Ruckig)
    max_acceleration: float  # [unit/s^2]
    max_jerk: float  # [unit/s^3]
    stroke_min: float  # [unit]
    stroke_max: float
