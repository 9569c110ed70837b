"""Builds the configured robot model from a Config."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from controller.config import Config
from controller.robots.cheope import CheopeGeometry, CheopeLimits, CheopeRobot
from controller.robots.performance import MassModel

if TYPE_CHECKING:  # the URU and nSPU modules load on demand, when their robot is configured
    from controller.robots.nspu import NspuGeometry, Pose
    from controller.robots.nspu_robot import NspuRobot
    from controller.robots.uru_robot import UruRobot


def mass_model_from_config(cfg: Config) -> MassModel:
    """Cheope's lumped masses (``[robot.mass]``): the mass ellipsoid's and the simulated structure's."""
    m = cfg.robot.mass
    return MassModel(m.platform_kg, m.slider_kg, m.rod_pair_kg)


def cheope_from_config(cfg: Config) -> CheopeRobot:
    c = cfg.robot.cheope
    m = cfg.robot.margins
    geometry = CheopeGeometry(
        rod_length_m=c.rod_length_m,
        axis_tilt_rad=math.radians(c.axis_tilt_deg),
        axis_azimuths_rad=tuple(math.radians(a) for a in c.axis_azimuths_deg),  # type: ignore[arg-type]
        platform_radius_m=c.platform_radius_m,
        platform_azimuths_rad=tuple(math.radians(a) for a in c.platform_azimuths_deg),  # type: ignore[arg-type]
        joint_neutral_tcp_m=c.joint_neutral_tcp_m,
    )
    limits = CheopeLimits(
        stroke_min_m=c.stroke_min_m,
        stroke_max_m=c.stroke_max_m,
        joint_swing_limit_rad=math.radians(c.joint_swing_limit_deg),
        min_direct_measure=m.min_direct_measure,
        min_inverse_measure=m.min_inverse_measure,
        min_structural_measure=m.min_structural_measure,
        max_condition_number=m.max_condition_number,
    )
    return CheopeRobot(geometry=geometry, limits=limits)


def uru_from_config(cfg: Config) -> UruRobot:
    from controller.robots.uru import UruGeometry, UruPathMargins
    from controller.robots.uru_robot import UruLimits, UruRobot

    u = cfg.robot.uru
    geometry = UruGeometry(
        base_offset_m=u.base_offset_m, platform_offset_m=u.platform_offset_m,
        proximal_lengths_m=u.proximal_lengths_m, distal_lengths_m=u.distal_lengths_m, gear_ratios=u.gear_ratios,
        motor_offsets_rad=u.motor_offsets_rad, knee_sign=u.knee_sign, home_position_m=u.home_position_m,
    )
    margins = UruPathMargins(plane_distance_m=u.min_plane_distance_m, det_v=u.min_det_v, det_s=u.min_det_s,
                             det_a=u.min_det_a, sin_th3=u.min_sin_th3, workspace_m=u.min_workspace_margin_m)
    return UruRobot(geometry, UruLimits(u.motor_min_rad, u.motor_max_rad, margins))


def nspu_geometry_from_config(cfg: Config) -> NspuGeometry:
    from controller.robots.nspu import NspuGeometry

    n = cfg.robot.nspu
    g = NspuGeometry.paper_example(length_unit_m=n.length_unit_m, r3_variant=n.r3_variant)  # type: ignore[arg-type]
    return NspuGeometry(g.a_m, g.r, g.b_platform_m, g.w4_platform, leg_min_m=n.leg_min_m, leg_max_m=n.leg_max_m,
                        length_unit_m=n.length_unit_m, name=g.name)


def nspu_poses_from_config(cfg: Config) -> tuple[Pose, Pose]:
    """Start and goal of the configured motion; orientations as RPY = Rz(yaw) Ry(pitch) Rx(roll)."""
    from controller.robots.nspu import Pose, rpy

    n = cfg.robot.nspu
    return (Pose(np.array(n.start_position_m), rpy(*n.start_rpy_rad)),
            Pose(np.array(n.goal_position_m), rpy(*n.goal_rpy_rad)))


def nspu_from_config(cfg: Config) -> NspuRobot:
    from controller.robots.nspu_robot import NspuRobot

    start, goal = nspu_poses_from_config(cfg)
    return NspuRobot(nspu_geometry_from_config(cfg), start, goal)


def robot_from_config(cfg: Config):  # -> CheopeRobot | UruRobot | NspuRobot
    """The model of ``robot.kind``; ValueError (from the model) when the geometry is inconsistent."""
    return {"cheope": cheope_from_config, "uru": uru_from_config, "nspu": nspu_from_config}[cfg.robot.kind](cfg)


@dataclass(frozen=True)
class ActuatorUnits:
    """The actuators' position unit and the limits in that unit (m for linear, rad for rotary)."""

    unit: str
    counts_per_unit: float
    max_velocity: float  # [unit/s]   (Ruckig)
    max_acceleration: float  # [unit/s^2]
    max_jerk: float  # [unit/s^3]
    sim_max_velocity: float  # [unit/s]   (the simulated drive's saturation)
    sim_max_acceleration: float  # [unit/s^2]
    sim_quick_stop_deceleration: float  # [unit/s^2]
    stroke_min: float  # [unit]
    stroke_max: float


def actuator_units(cfg: Config) -> ActuatorUnits:
    """Units and limits of the configured robot's actuators: the ``_rad`` keys for the URU's motors."""
    a, d = cfg.actuators, cfg.sim.drive
    if cfg.robot.kind == "uru":
        u = cfg.robot.uru
        return ActuatorUnits("rad", a.counts_per_rad, a.max_velocity_rad_s, a.max_acceleration_rad_s2,
                             a.max_jerk_rad_s3, d.max_velocity_rad_s, d.max_acceleration_rad_s2,
                             d.quick_stop_deceleration_rad_s2, u.motor_min_rad, u.motor_max_rad)
    if cfg.robot.kind == "nspu":
        lo, hi = cfg.robot.nspu.leg_min_m, cfg.robot.nspu.leg_max_m
    else:
        lo, hi = cfg.robot.cheope.stroke_min_m, cfg.robot.cheope.stroke_max_m
    return ActuatorUnits("m", a.counts_per_m, a.max_velocity_m_s, a.max_acceleration_m_s2, a.max_jerk_m_s3,
                         d.max_velocity_m_s, d.max_acceleration_m_s2, d.quick_stop_deceleration_m_s2, lo, hi)
