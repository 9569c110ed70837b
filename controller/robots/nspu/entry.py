"""The 3-nSPU (seeds 000, 004) registered: its section ``[robot.nspu]`` (the planner's settings too), the
factory of its model, its ``RobotEntry``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from controller.config_schema import ConfigError, Section, rng
from controller.core.ports import ActuatorUnit
from controller.robot_registry import RobotEntry

if TYPE_CHECKING:  # the models load on demand, when a robot is built: the configuration loads without them
    from controller.robots.nspu.kinematics import NspuGeometry, Pose
    from controller.robots.nspu.model import NspuRobot


# -- Cheope (seed 001) --------------------------------------------------------------------------


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
    # closed-loop execution with a pose tracker ([tracker] enabled; controller/robots/nspu/planned_legs.py)
    correction_tolerance_m: Annotated[float, rng(0.0, 0.1, lo_open=True)] = (
        2.0e-4  # accepted distance to the goal
    )
    correction_tolerance_rad: Annotated[float, rng(0.0, 1.0, lo_open=True)] = (
        1.0e-3  # accepted angle to the goal
    )
    max_corrections: Annotated[int, rng(0, 100)] = 3  # correcting plans after the first
    tracker_samples: Annotated[int, rng(1, 10000)] = 10  # tracker samples averaged into one measurement
    settle_s: Annotated[float, rng(0.0, 10.0)] = 0.1  # after a motion, before measuring
    # no usable tracker sample this long while measuring (after settle_s): the task faults, naming it
    tracker_timeout_s: Annotated[float, rng(0.0, 600.0, lo_open=True)] = 5.0
    correction_planning: Literal["worker", "in_step"] = "worker"  # off the loop (a bus), or inside the step
    # "worker": no plan this long after its request faults the task (a plan takes 0.5-1 s)
    correction_plan_timeout_s: Annotated[float, rng(0.0, 3600.0, lo_open=True)] = 30.0


def _check_nspu(n: NspuSection) -> None:
    if n.leg_min_m >= n.leg_max_m:
        raise ConfigError(
            f"robot.nspu.leg_min_m = {n.leg_min_m} must be < robot.nspu.leg_max_m = {n.leg_max_m}"
        )


def nspu_geometry(n: NspuSection) -> NspuGeometry:
    from controller.robots.nspu.kinematics import NspuGeometry

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

    from controller.core.rotations import rpy
    from controller.robots.nspu.kinematics import Pose

    return (
        Pose(np.array(n.start_position_m), rpy(*n.start_rpy_rad)),
        Pose(np.array(n.goal_position_m), rpy(*n.goal_rpy_rad)),
    )


def build_nspu(n: NspuSection) -> NspuRobot:
    from controller.robots.nspu.model import NspuRobot

    start, goal = nspu_poses(n)
    return NspuRobot(nspu_geometry(n), start, goal)


NSPU = RobotEntry(
    kind="nspu",
    section=NspuSection,
    build=build_nspu,
    unit=ActuatorUnit.METRE,
    stroke=lambda n: (n.leg_min_m, n.leg_max_m),
    tasks=("planned",),
    config_file=Path(__file__).with_name("nspu.toml"),  # beside it, in its home
    check=_check_nspu,
)
