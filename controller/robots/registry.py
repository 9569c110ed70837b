"""Builds the configured robot model from a Config."""

from __future__ import annotations

import math

from controller.config import Config
from controller.robots.cheope import CheopeGeometry, CheopeLimits, CheopeRobot


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
