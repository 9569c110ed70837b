"""The 3-URU (seed 003) registered: its section ``[robot.uru]``, the factory of its model, its ``RobotEntry``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from controller.config_schema import ConfigError, Section, rng
from controller.core.ports import ActuatorUnit
from controller.robot_registry import RobotEntry

if TYPE_CHECKING:  # the models load on demand, when a robot is built: the configuration loads without them
    from controller.robots.uru.model import UruRobot


# -- Cheope (seed 001) --------------------------------------------------------------------------


_Link = Annotated[float, rng(0.0, 10.0, lo_open=True)]  # a link length [m]
_Gear = Annotated[float, rng(-1000.0, 1000.0)]
_Offset = Annotated[float, rng(-100.0, 100.0)]  # [rad]


class UruSection(Section, frozen=True):
    """LaMaViP 3-URU (seed 003); see controller/robots/uru/kinematics.py and controller/robots/uru/model.py."""

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
    from controller.robots.uru.kinematics import UruGeometry, UruPathMargins
    from controller.robots.uru.model import UruLimits, UruRobot

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


URU = RobotEntry(
    kind="uru",
    section=UruSection,
    build=build_uru,
    unit=ActuatorUnit.RADIAN,
    stroke=lambda u: (u.motor_min_rad, u.motor_max_rad),
    tasks=("path",),
    config_file=Path(__file__).with_name("uru.toml"),  # beside it, in its home
    check=_check_uru,
)
