"""The papers' three robots, registered: Cheope (seed 001), the 3-URU (seed 003), the 3-nSPU (seeds 000, 004).

Each robot here is its configuration section (``[robot.<kind>]``, every key with its unit in
its name and its allowed range), the factory that turns the section into the model, and one
``RobotEntry``. The models themselves live in their own modules and know nothing of the
configuration.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Annotated, Literal

import msgspec

from controller.config_schema import ConfigError, Section, rng
from controller.configs import CONFIG_DIR
from controller.core.ports import ActuatorUnit
from controller.robots.registry import RobotEntry

if TYPE_CHECKING:  # the models load on demand, when a robot is built: the configuration loads without them
    from controller.robots.cheope import CheopeRobot
    from controller.robots.nspu import NspuGeometry, Pose
    from controller.robots.nspu_robot import NspuRobot
    from controller.robots.performance import MassModel
    from controller.robots.uru_robot import UruRobot


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
    actuator_stiffness_n_m: Annotated[float, rng(0.0, 1e12, lo_open=True)] = 2.0e5


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


def cheope_mass_model(m: MassSection) -> MassModel:
    """Cheope's lumped masses (``[robot.cheope.mass]``): the mass ellipsoid's and the simulated structure's."""
    from controller.robots.performance import MassModel

    return MassModel(m.platform_kg, m.slider_kg, m.rod_pair_kg)


def build_cheope(c: CheopeSection) -> CheopeRobot:
    from controller.robots.cheope import CheopeGeometry, CheopeLimits, CheopeRobot

    m = c.margins
    geometry = CheopeGeometry(
        rod_length_m=c.rod_length_m,
        axis_tilt_rad=math.radians(c.axis_tilt_deg),
        axis_azimuths_rad=_three(math.radians(a) for a in c.axis_azimuths_deg),
        platform_radius_m=c.platform_radius_m,
        platform_azimuths_rad=_three(math.radians(a) for a in c.platform_azimuths_deg),
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


def _three(values: Iterable[float]) -> tuple[float, float, float]:
    a, b, c = values
    return (a, b, c)


# -- 3-URU (seed 003) ---------------------------------------------------------------------------

_Link = Annotated[float, rng(0.0, 10.0, lo_open=True)]  # a link length [m]
_Gear = Annotated[float, rng(-1000.0, 1000.0)]
_Offset = Annotated[float, rng(-100.0, 100.0)]  # [rad]


class UruSection(Section, frozen=True):
    """LaMaViP 3-URU (seed 003); see controller/robots/uru.py and controller/robots/uru_robot.py."""

    base_offset_m: Annotated[float, rng(0.0, 10.0)] = 0.10
    platform_offset_m: Annotated[float, rng(0.0, 10.0)] = 0.10
    proximal_lengths_m: tuple[_Link, _Link, _Link] = (0.20, 0.20, 0.20)
    distal_lengths_m: tuple[_Link, _Link, _Link] = (0.20, 0.20, 0.20)
    gear_ratios: tuple[_Gear, _Gear, _Gear] = (1.0, 1.0, 1.0)
    motor_offsets_rad: tuple[_Offset, _Offset, _Offset] = (0.0, 0.0, 0.0)
    knee_sign: Literal[-1, 1] = 1
    home_position_m: tuple[float, float, float] = (0.12, 0.12, 0.12)  # the simulator starts here
    motor_min_rad: Annotated[float, rng(-1000.0, 1000.0)] = -3.2  # motor-shaft range
    motor_max_rad: Annotated[float, rng(-1000.0, 1000.0)] = 4.8
    min_plane_distance_m: Annotated[float, rng(0.0, 10.0)] = 0.02  # rotation loci eq. (17)
    min_det_v: Annotated[float, rng(0.0, 1.0)] = 0.05  # translation eq. (20)
    min_det_s: Annotated[float, rng(0.0, 1e6)] = 0.05  # actuation eq. (35)
    min_det_a: Annotated[float, rng(0.0, 1e6)] = 0.05  # combined eq. (36)
    min_sin_th3: Annotated[float, rng(0.0, 1.0)] = 0.10  # serial eq. (27)
    min_workspace_margin_m: Annotated[float, rng(0.0, 10.0)] = 0.02  # boundary eq. (29)


def _check_uru(u: UruSection) -> None:
    if any(k == 0 for k in u.gear_ratios):
        raise ConfigError(f"robot.uru.gear_ratios = {list(u.gear_ratios)}: must be non-zero")
    if u.motor_min_rad >= u.motor_max_rad:
        raise ConfigError(
            f"robot.uru.motor_min_rad = {u.motor_min_rad} must be < robot.uru.motor_max_rad = "
            f"{u.motor_max_rad}"
        )


def build_uru(u: UruSection) -> UruRobot:
    from controller.robots.uru import UruGeometry, UruPathMargins
    from controller.robots.uru_robot import UruLimits, UruRobot

    geometry = UruGeometry(
        base_offset_m=u.base_offset_m,
        platform_offset_m=u.platform_offset_m,
        proximal_lengths_m=u.proximal_lengths_m,
        distal_lengths_m=u.distal_lengths_m,
        gear_ratios=u.gear_ratios,
        motor_offsets_rad=u.motor_offsets_rad,
        knee_sign=u.knee_sign,
        home_position_m=u.home_position_m,
    )
    margins = UruPathMargins(
        plane_distance_m=u.min_plane_distance_m,
        det_v=u.min_det_v,
        det_s=u.min_det_s,
        det_a=u.min_det_a,
        sin_th3=u.min_sin_th3,
        workspace_m=u.min_workspace_margin_m,
    )
    return UruRobot(geometry, UruLimits(u.motor_min_rad, u.motor_max_rad, margins))


# -- 3-nSPU (seeds 000, 004) --------------------------------------------------------------------


class NspuSection(Section, frozen=True):
    """3-nSPU (seeds 000, 004): seed 000 §3.5 geometry, start and goal poses, planner, streaming."""

    length_unit_m: Annotated[float, rng(0.0, 10.0, lo_open=True)] = 0.01  # the papers' aul
    r3_variant: Literal["symmetric", "printed"] = "symmetric"
    leg_min_m: Annotated[float, rng(0.0, 10.0)] = 0.20
    leg_max_m: Annotated[float, rng(0.0, 10.0)] = 0.70
    start_position_m: tuple[float, float, float] = (0.0, 0.0, 0.25)
    start_rpy_rad: tuple[float, float, float] = (0.0, 0.0, -0.5236)
    goal_position_m: tuple[float, float, float] = (-0.0185, -0.0251, 0.2713)
    goal_rpy_rad: tuple[float, float, float] = (0.075, 0.31, -0.532)
    horizon_s: Annotated[float, rng(0.0, 1000.0, lo_open=True)] = 1.0  # plan time T
    harmonics: Annotated[int, rng(0, 10)] = 2
    tolerance: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 1e-3
    max_iterations: Annotated[int, rng(0, 10000)] = 50
    n_steps: Annotated[int, rng(4, 100000)] = 100
    check_type2: bool = True  # refuse plans that cross the type-II locus (seed 000 eq. (26))
    restarts: Annotated[int, rng(0, 100)] = 0
    stream_steps: Annotated[int, rng(10, 1000000)] = 1000  # resolution of the streamed plan
    limit_fraction: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.5  # of the limits
    # closed-loop execution with a pose tracker ([tracker] enabled; controller/tasks/planned_legs.py)
    correction_tolerance_m: Annotated[float, rng(0.0, 0.1, lo_open=True)] = (
        2.0e-4  # accepted distance to the goal
    )
    correction_tolerance_rad: Annotated[float, rng(0.0, 1.0, lo_open=True)] = (
        1.0e-3  # accepted angle to the goal
    )
    max_corrections: Annotated[int, rng(0, 100)] = 3  # correcting plans after the first
    tracker_samples: Annotated[int, rng(1, 10000)] = 10  # tracker samples averaged into one measurement
    settle_s: Annotated[float, rng(0.0, 10.0)] = 0.1  # after a motion, before measuring
    correction_planning: Literal["worker", "in_step"] = "worker"  # off the loop (a bus), or inside the step


def _check_nspu(n: NspuSection) -> None:
    if n.leg_min_m >= n.leg_max_m:
        raise ConfigError(
            f"robot.nspu.leg_min_m = {n.leg_min_m} must be < robot.nspu.leg_max_m = {n.leg_max_m}"
        )


def nspu_geometry(n: NspuSection) -> NspuGeometry:
    from controller.robots.nspu import NspuGeometry

    g = NspuGeometry.paper_example(length_unit_m=n.length_unit_m, r3_variant=n.r3_variant)
    return NspuGeometry(
        g.a_m,
        g.r,
        g.b_platform_m,
        g.w4_platform,
        leg_min_m=n.leg_min_m,
        leg_max_m=n.leg_max_m,
        length_unit_m=n.length_unit_m,
        name=g.name,
    )


def nspu_poses(n: NspuSection) -> tuple[Pose, Pose]:
    """Start and goal of the configured motion; orientations as RPY = Rz(yaw) Ry(pitch) Rx(roll)."""
    import numpy as np

    from controller.robots.nspu import Pose, rpy

    return (
        Pose(np.array(n.start_position_m), rpy(*n.start_rpy_rad)),
        Pose(np.array(n.goal_position_m), rpy(*n.goal_rpy_rad)),
    )


def build_nspu(n: NspuSection) -> NspuRobot:
    from controller.robots.nspu_robot import NspuRobot

    start, goal = nspu_poses(n)
    return NspuRobot(nspu_geometry(n), start, goal)


# -- the entries --------------------------------------------------------------------------------

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
URU = RobotEntry(
    kind="uru",
    section=UruSection,
    build=build_uru,
    unit=ActuatorUnit.RADIAN,
    stroke=lambda u: (u.motor_min_rad, u.motor_max_rad),
    tasks=("path",),
    config_file=CONFIG_DIR / "uru.toml",
    check=_check_uru,
)
NSPU = RobotEntry(
    kind="nspu",
    section=NspuSection,
    build=build_nspu,
    unit=ActuatorUnit.METRE,
    stroke=lambda n: (n.leg_min_m, n.leg_max_m),
    tasks=("planned",),
    config_file=CONFIG_DIR / "nspu.toml",
    check=_check_nspu,
)
