"""How the simulated plant turns its drives' positions into the tool's position: one hook per robot.

A robot's registry entry names its hook (``RobotEntry.sim_hook``, "module:factory"); a robot
without one is rigid: the TCP is its direct kinematics, and the drives start at
``sim.drive.initial_positions_m``. The hook also says where the simulated drives start (where
the robot stands at power-on) and whether its linear motors' cogging loads the compliant
structure (``sim_backend/plant.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from controller.robots.registry import load_reference, robot_entry

if TYPE_CHECKING:
    from controller.config import Config


class PlantKinematics(Protocol):
    cogging: bool  # the actuators are iron-core linear motors whose cogging the structure feels

    def initial_positions(self) -> tuple[float, ...]:
        """Where the simulated drives start [actuator unit]."""
        ...

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        """The TCP for drive positions ``q`` at ``t_s``; raises NoSolutionError where there is none."""
        ...


class RigidKinematics:
    """The TCP is the robot model's direct kinematics of the drives' positions."""

    def __init__(self, robot: Any, initial: tuple[float, ...], cogging: bool = False) -> None:
        self.robot = robot
        self._initial = tuple(float(x) for x in initial)
        self.cogging = cogging

    def initial_positions(self) -> tuple[float, ...]:
        return self._initial

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        return np.asarray(self.robot.direct_kinematics(q))


class UruKinematics(RigidKinematics):
    """Newton from the previous pose: the assembly the platform is in (several exist)."""

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        guess = previous_tcp_m if np.any(previous_tcp_m) else None
        return np.asarray(self.robot.direct_kinematics(q, guess))


class NspuOdometry:
    """3-nSPU: the pose (p, R) integrated from the drives' actual leg lengths (seed 000 eq. (11)).

    The pose of a non-holonomic robot depends on the whole leg motion, not on the lengths: one
    RKMK4 step (``nspu.advance_pose_to_leg_lengths``) per ``ODOMETRY_INTERVAL_S``. ``tcp_m``
    is the platform point P.
    """

    cogging = False

    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.pose = robot.start
        self._pose_time_s: float | None = None

    def initial_positions(self) -> tuple[float, ...]:
        return tuple(float(x) for x in self.robot.start_leg_lengths_m())

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        from controller.robots.nspu import advance_pose_to_leg_lengths, leg_lengths
        from controller.robots.nspu_robot import ODOMETRY_INTERVAL_S

        if self._pose_time_s is not None and t_s is not None and t_s > self._pose_time_s:
            if t_s - self._pose_time_s < ODOMETRY_INTERVAL_S - 1e-9:
                return previous_tcp_m  # not yet: the legs' motion over the next SYNCs goes into one step
            if np.any(np.abs(q - leg_lengths(self.robot.geometry, self.pose)) > 1e-12):
                self.pose = advance_pose_to_leg_lengths(self.robot.geometry, self.pose, q, t_s - self._pose_time_s)
        self._pose_time_s = t_s
        return np.array(self.pose.p_m)


def cheope_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    return RigidKinematics(robot, cfg.sim.drive.initial_positions_m, cogging=True)


def uru_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    home = np.asarray(cfg.robot.model("uru").home_position_m)
    return UruKinematics(robot, tuple(robot.inverse_kinematics(home).tolist()))


def nspu_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    return NspuOdometry(robot)


def plant_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    """The configured robot's hook, or rigid kinematics from ``sim.drive.initial_positions_m``."""
    hook = robot_entry(cfg.robot.kind).sim_hook
    if not hook:
        return RigidKinematics(robot, cfg.sim.drive.initial_positions_m)
    factory = load_reference(hook)
    kinematics: PlantKinematics = factory(cfg, robot)
    return kinematics
