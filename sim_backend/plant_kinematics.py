"""How the simulated plant turns its drives' positions into the tool's position: one hook per robot.

A robot's hook is declared by kind under the entry-point group ``cheope.sim_kinematics``
(``controller/plugins.py``; the built-ins in ``pyproject.toml``); a robot without one is rigid: the TCP is its direct kinematics, and the drives start at
``sim.drive.initial_positions_m``. The hook also says where the simulated drives start (where
the robot stands at power-on) and whether its linear motors' cogging loads the compliant
structure (``sim_backend/plant.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from controller.plugins import SIM_KINEMATICS
from controller.robots.registry import check_axes

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

    Model mismatch (``[sim.nspu]``): the platform moves with ``geometry`` (default: the robot
    model's) and physical legs ``q + leg_offset_m``; its start pose keeps the model's start
    orientation and is moved in position until its physical legs are the encoders' start
    readings plus the offsets (the drives start at the plan's start readings, as the task checks).
    ``start_offset_m`` then moves that start position (the platform is not where the plan starts):
    the drives start at the encoder readings of the moved pose.
    """

    cogging = False

    def __init__(
        self,
        robot: Any,
        geometry: Any = None,
        leg_offset_m: np.ndarray | None = None,
        start_offset_m: np.ndarray | None = None,
    ) -> None:
        from controller.robots.nspu import Pose, leg_lengths

        self.robot = robot
        self._initial: tuple[float, ...] | None = None  # None: the plan's start readings
        self.geometry = robot.geometry if geometry is None else geometry
        self.leg_offset_m = np.zeros(3) if leg_offset_m is None else np.asarray(leg_offset_m, dtype=float)
        target = np.asarray(self.initial_positions()) + self.leg_offset_m
        p = np.array(robot.start.p_m, dtype=float)
        for _ in range(20):  # Newton on the position: l_true(p, R0) = encoder start + offset
            res = leg_lengths(self.geometry, Pose(p, robot.start.R)) - target
            if np.max(np.abs(res)) < 1e-13:
                break
            jac = np.empty((3, 3))
            for k in range(3):
                dp = np.zeros(3)
                dp[k] = 1e-7
                jac[:, k] = (leg_lengths(self.geometry, Pose(p + dp, robot.start.R)) - target - res) / 1e-7
            p = p - np.linalg.solve(jac, res)
        if start_offset_m is not None and np.any(start_offset_m):
            p = p + np.asarray(start_offset_m, dtype=float)
            self._initial = tuple(
                float(x) for x in leg_lengths(self.geometry, Pose(p, robot.start.R)) - self.leg_offset_m
            )
        self.pose = Pose(p, robot.start.R)
        self._pose_time_s: float | None = None

    def initial_positions(self) -> tuple[float, ...]:
        if self._initial is not None:
            return self._initial
        return tuple(float(x) for x in self.robot.start_leg_lengths_m())

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        from controller.robots.nspu import advance_pose_to_leg_lengths, leg_lengths
        from controller.robots.nspu_robot import ODOMETRY_INTERVAL_S

        legs = np.asarray(q, dtype=float) + self.leg_offset_m
        if self._pose_time_s is not None and t_s is not None and t_s > self._pose_time_s:
            if t_s - self._pose_time_s < ODOMETRY_INTERVAL_S - 1e-9:
                return previous_tcp_m  # not yet: the legs' motion over the next SYNCs goes into one step
            if np.any(np.abs(legs - leg_lengths(self.geometry, self.pose)) > 1e-12):
                self.pose = advance_pose_to_leg_lengths(
                    self.geometry, self.pose, legs, t_s - self._pose_time_s
                )
        self._pose_time_s = t_s
        return np.array(self.pose.p_m)


def _turned_axes(axes: np.ndarray, angles_rad: tuple[float, float, float]) -> np.ndarray:
    """Each unit row axes[i] turned by angles_rad[i] about z x axes[i] (x axis if that vanishes)."""
    from controller.robots.nspu import so3_exp

    out = np.array(axes, dtype=float)
    for i, a in enumerate(angles_rad):
        n = np.cross([0.0, 0.0, 1.0], out[i])
        n = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else np.array([1.0, 0.0, 0.0])
        out[i] = so3_exp(a * n) @ out[i]
    return out


def cheope_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    return RigidKinematics(robot, cfg.sim.drive.initial_positions_m, cogging=True)


def uru_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    home = np.asarray(cfg.robot.model("uru").home_position_m)
    return UruKinematics(robot, tuple(robot.inverse_kinematics(home).tolist()))


def nspu_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    from controller.robots.nspu import NspuGeometry

    mis = cfg.sim.nspu
    g = robot.geometry
    true_geometry = NspuGeometry(
        g.a_m,
        _turned_axes(g.r, mis.r_axis_error_rad),
        g.b_platform_m,
        _turned_axes(g.w4_platform, mis.w4_axis_error_rad),
        leg_min_m=g.leg_min_m,
        leg_max_m=g.leg_max_m,
        length_unit_m=g.length_unit_m,
        name=g.name + " (simulated)",
    )
    return NspuOdometry(robot, true_geometry, np.array(mis.leg_offset_m), np.array(mis.start_offset_m))


def plant_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    """The configured robot's hook, or rigid kinematics from ``sim.drive.initial_positions_m``."""
    factory = SIM_KINEMATICS.get(cfg.robot.kind)
    if factory is None:
        check_axes(
            cfg.robot.kind,
            robot.n_actuators,
            {"sim.drive.initial_positions_m": cfg.sim.drive.initial_positions_m},
        )
        return RigidKinematics(robot, cfg.sim.drive.initial_positions_m)
    kinematics: PlantKinematics = factory(cfg, robot)
    return kinematics
