"""The 3-nSPU in the simulator (entry point cheope.sim_kinematics): its pose integrated from the legs' motion
(odometry), with the model mismatch of ``[sim.nspu]``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sim_backend.plant_kinematics import PlantKinematics

if TYPE_CHECKING:
    from controller.config import Config


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
        from controller.robots.nspu.kinematics import Pose, leg_lengths

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

    @property
    def pose_time_s(self) -> float | None:
        """The time of the drives' sample the pose is integrated to; None before the first."""
        return self._pose_time_s

    def initial_positions(self) -> tuple[float, ...]:
        if self._initial is not None:
            return self._initial
        return tuple(float(x) for x in self.robot.start_leg_lengths_m())

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        from controller.robots.nspu.kinematics import advance_pose_to_leg_lengths, leg_lengths
        from controller.robots.nspu.model import ODOMETRY_INTERVAL_S

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
    from controller.core.rotations import so3_exp

    out = np.array(axes, dtype=float)
    for i, a in enumerate(angles_rad):
        n = np.cross([0.0, 0.0, 1.0], out[i])
        n = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else np.array([1.0, 0.0, 0.0])
        out[i] = so3_exp(a * n) @ out[i]
    return out


def nspu_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    from controller.robots.nspu.kinematics import NspuGeometry

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
