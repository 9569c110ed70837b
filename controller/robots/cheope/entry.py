"""Cheope (seed 001) registered: its configuration section ``[robot.cheope]`` (every key with its unit and
range), the factory of its model from that section, and its ``RobotEntry`` (entry point cheope.robots)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Annotated

import msgspec

from controller.config_schema import ConfigError, Section, rng
from controller.configs import CONFIG_DIR
from controller.core.ports import ActuatorUnit
from controller.robot_masses import check_masses
from controller.robot_registry import RobotEntry

if TYPE_CHECKING:  # the models load on demand, when a robot is built: the configuration loads without them
    from controller.robots.cheope.model import CheopeRobot
    from controller.robots.performance import MassModel


# -- Cheope (seed 001) --------------------------------------------------------------------------


class MarginsSection(Section, frozen=True):
    """Minimum distances from the singularity classes of seed 001 §5.1 and a conditioning bound."""

    min_direct_measure: Annotated[float, rng(0.0, 1.0)] = 0.20
    min_inverse_measure: Annotated[float, rng(0.0, 1.0)] = 0.20
    min_structural_measure: Annotated[float, rng(0.0, 1.0)] = 0.20
    max_condition_number: Annotated[float, rng(1.0, 1e6)] = 10.0


class MassSection(Section, frozen=True):
    """Cheope's lumped masses and its actuators' servo stiffness (controller/robots/performance.py)."""

    platform_kg: Annotated[float, rng(0.0, 1000.0)] = 8.0
    slider_kg: Annotated[float, rng(0.0, 1000.0)] = 1.0
    rod_pair_kg: Annotated[float, rng(0.0, 1000.0)] = 0.4
    # 1 N/m and up, as safety.contact.cell_stiffness_n_m: softer, the robot's own weight (84 N at
    # the defaults) would sag it 84 m, no servo; and at 1e-300 N/m the stiffness ellipse's k^2
    # underflowed to 0, and `cheope analyze` failed on a NaN after writing its plots
    actuator_stiffness_n_m: Annotated[float, rng(1.0, 1e12)] = 2.0e5


class CheopeSection(Section, frozen=True):
    rod_length_m: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.50
    axis_tilt_deg: Annotated[float, rng(1.0, 89.0)] = 60.0
    axis_azimuths_deg: tuple[float, float, float] = (0.0, 90.0, 180.0)
    platform_radius_m: Annotated[float, rng(0.0, 1.0)] = 0.05
    platform_azimuths_deg: tuple[float, float, float] = (0.0, 90.0, 180.0)
    joint_neutral_tcp_m: tuple[float, float, float] = (0.0, 0.0, 0.50)
    joint_swing_limit_deg: Annotated[float, rng(0.0, 90.0, lo_open=True)] = 22.0
    stroke_min_m: Annotated[float, rng(-10.0, 10.0)] = 0.30
    stroke_max_m: Annotated[float, rng(-10.0, 10.0)] = 0.90
    margins: MarginsSection = msgspec.field(default_factory=MarginsSection)
    mass: MassSection = msgspec.field(default_factory=MassSection)


def _check_cheope(c: CheopeSection) -> None:
    if c.stroke_min_m >= c.stroke_max_m:
        raise ConfigError(
            f"robot.cheope.stroke_min_m = {c.stroke_min_m} must be < robot.cheope.stroke_max_m = {c.stroke_max_m}"
        )
    # every robot's check when its model is built (controller/configured_robot.py); Cheope's masses
    # are known from its section alone, so the configuration check names them before any start
    check_masses("cheope", c, cheope_mass_model(c.mass))


def cheope_mass_model(m: MassSection) -> MassModel:
    """Cheope's lumped masses (``[robot.cheope.mass]``): the mass ellipsoid's and the simulated structure's."""
    from controller.robots.performance import MassModel

    return MassModel(m.platform_kg, m.slider_kg, m.rod_pair_kg)


def build_cheope(c: CheopeSection) -> CheopeRobot:
    from controller.robots.cheope.model import CheopeGeometry, CheopeLimits, CheopeRobot

    m = c.margins
    geometry = CheopeGeometry(
        rod_length_m=c.rod_length_m,
        axis_tilt_rad=math.radians(c.axis_tilt_deg),
        axis_azimuths_rad=three_floats(math.radians(a) for a in c.axis_azimuths_deg),
        platform_radius_m=c.platform_radius_m,
        platform_azimuths_rad=three_floats(math.radians(a) for a in c.platform_azimuths_deg),
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
    return CheopeRobot(
        geometry=geometry,
        limits=limits,
        masses=cheope_mass_model(c.mass),
        actuator_stiffness_n_m=c.mass.actuator_stiffness_n_m,
    )


def three_floats(values: Iterable[float]) -> tuple[float, float, float]:
    a, b, c = values
    return (a, b, c)


CHEOPE = RobotEntry(
    kind="cheope",
    section=CheopeSection,
    build=build_cheope,
    unit=ActuatorUnit.METRE,
    stroke=lambda c: (c.stroke_min_m, c.stroke_max_m),
    tasks=("contour", "path"),
    config_file=CONFIG_DIR / "cheope.toml",
    check=_check_cheope,
)
