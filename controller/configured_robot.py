"""The configured robot: its model and its actuators' units and limits, from a whole configuration.

Beside the registry (controller/robot_registry.py), which knows the robots but not the
configuration that chooses one: the registry is what ``controller/config.py`` reads its sections
from, and these read the configuration.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from controller.core.ports import ActuatorUnit, CompliantStructure
from controller.robot_masses import check_masses
from controller.robot_registry import ActuatorUnits, check_axes, robot_entry

if TYPE_CHECKING:
    from controller.config import Config
    from controller.core.ports import Robot


def robot_from_config(cfg: Config) -> Robot:
    """The model of ``robot.kind``; ValueError (from the model) when the geometry is inconsistent,
    ConfigError when a per-actuator list has not one value per actuator or its structure's masses
    cannot move (every robot's, a plug-in's too: its masses come from keys only its model reads)."""
    section = cfg.robot.model()
    robot = robot_entry(cfg.robot.kind).build(section)
    if isinstance(robot, CompliantStructure):  # the capability that declares masses
        check_masses(cfg.robot.kind, section, robot.masses)
    check_axes(
        cfg.robot.kind,
        robot.n_actuators,
        {
            "actuators.node_ids": cfg.actuators.node_ids,
            "actuators.home_offsets_m": cfg.actuators.home_offsets_m,
        },
    )
    return robot


def actuator_units(cfg: Config) -> ActuatorUnits:
    """Units and limits of the configured robot's actuators: the ``_rad`` keys for rotary ones."""
    entry = robot_entry(cfg.robot.kind)
    a = cfg.actuators
    lo, hi = entry.stroke(cfg.robot.model())
    if entry.unit == ActuatorUnit.RADIAN:
        return ActuatorUnits(
            entry.unit,
            a.counts_per_rad,
            a.max_velocity_rad_s,
            a.max_acceleration_rad_s2,
            a.max_jerk_rad_s3,
            lo,
            hi,
        )
    return ActuatorUnits(
        entry.unit, a.counts_per_m, a.max_velocity_m_s, a.max_acceleration_m_s2, a.max_jerk_m_s3, lo, hi
    )
