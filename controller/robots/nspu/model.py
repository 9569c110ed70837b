"""The under-actuated 3-nSPU (seeds 000, 004) as the controller and the simulator see it.

The actuator positions are the three leg lengths [m]. The platform has six DOFs and three
actuators with non-holonomic spherical pairs: the pose is **not** a function of the leg
lengths (it depends on how the legs moved), so ``direct_kinematics`` raises
``NoSolutionError`` and the control law reports no measured TCP. The pose is obtained by
integrating the leg motion from a known start pose (``controller/robots/nspu/kinematics.py``,
``advance_pose_to_leg_lengths``): the simulator does it from the drives' actual positions,
and the controller does it from the encoder readings it receives (``pose_odometry``).

``check_actuators`` checks the leg stroke every cycle, ``check_pose`` only that the
reference point is a finite position above the frame (the planned trajectory was checked
against the type-II and det S singularities and the stroke when it was planned; see
``controller/robots/nspu/planning/nonholonomic.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.core.ports import POSE_OK, PoseStatus
from controller.core.rotations import so3_log
from controller.errors import NoSolutionError, WorkspaceError
from controller.robots.nspu.kinematics import NspuGeometry, Pose, advance_pose_to_leg_lengths, leg_lengths


@dataclass(frozen=True, eq=False)
class NspuRobot:
    geometry: NspuGeometry
    start: Pose  # where the platform is when the drives are at leg_lengths(start)
    goal: Pose
    name: str = "nspu"
    n_actuators: int = 3
    actuator_unit: str = "m"

    def start_leg_lengths_m(self) -> np.ndarray:
        return leg_lengths(self.geometry, self.start)

    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        raise NoSolutionError(
            "the 3-nSPU has no inverse kinematics from a position alone: its pose has 6 DOFs "
            "and 3 actuators; stream a planned motion (controller/robots/nspu/planned_legs.py)"
        )

    def direct_kinematics(self, q_m: np.ndarray) -> np.ndarray:
        raise NoSolutionError(
            f"the 3-nSPU pose is not a function of the leg lengths {np.asarray(q_m).tolist()} m "
            "(non-holonomic joints): integrate it along the leg motion instead"
        )

    def check_actuators(self, q_m: tuple[float, ...]) -> PoseStatus:
        g = self.geometry
        for j, x in enumerate(q_m):
            if not g.leg_min_m <= x <= g.leg_max_m:  # also False for NaN
                return PoseStatus(
                    False,
                    f"leg {j + 1} at {x:.4f} m is outside its stroke [{g.leg_min_m}, {g.leg_max_m}] m",
                )
        return POSE_OK

    def check_pose(self, tcp_m: np.ndarray) -> PoseStatus:
        p = [float(x) for x in tcp_m]
        if not all(math.isfinite(x) for x in p):
            return PoseStatus(False, f"platform reference {p} m is not finite")
        if p[2] <= 0.0:
            return PoseStatus(False, f"platform reference {p} m is not above the frame plane z = 0")
        return POSE_OK

    def check_path(self, points_m: np.ndarray) -> None:
        for i, p in enumerate(np.asarray(points_m, float)):
            status = self.check_pose(p)
            if not status.ok:
                raise WorkspaceError(f"path sample {i}: {status.reason}")


# The pose is integrated over steps of at least this interval, not at every sample: one RKMK4
# step of the model costs 1.7 ms in numpy, most of a 2.5 ms cycle of the simulator that has to
# do it live. Over 10 ms of smooth (jerk-limited) leg motion one step from the leg lengths at
# its two ends is still accurate: it moves the default motion's reached pose by about 4 um
# (end error 15.0 um with a step per 2.5 ms cycle, 10.8 um with 10 ms steps; the simulated-time
# run of tests/test_nspu_integration.py).
ODOMETRY_INTERVAL_S = 0.01


def pose_odometry(
    geometry: NspuGeometry,
    start: Pose,
    t_s: np.ndarray,
    legs_m: np.ndarray,
    interval_s: float = ODOMETRY_INTERVAL_S,
) -> Pose:
    """The pose reached by moving the legs through the samples ``legs_m`` (N, 3) at ``t_s`` (N,).

    The same integration as the simulator's: one RKMK4 step from the leg lengths at the two
    ends of each interval of at least ``interval_s`` (``advance_pose_to_leg_lengths``).
    """
    pose = start
    t = np.asarray(t_s, float)
    legs = np.asarray(legs_m, float)
    if t.size == 0:
        return pose
    t_last = float(t[0])
    for k in range(1, t.size):
        dt = float(t[k]) - t_last
        if dt >= interval_s - 1e-9 or (k == t.size - 1 and dt > 0.0):
            pose = advance_pose_to_leg_lengths(geometry, pose, legs[k], dt)
            t_last = float(t[k])
    return pose


def pose_errors(reached: Pose, goal: Pose) -> tuple[float, float]:
    """(|p - p_goal| [m], |log(R R_goal^T)| [rad])."""
    return (
        float(np.linalg.norm(reached.p_m - goal.p_m)),
        float(np.linalg.norm(so3_log(reached.R @ goal.R.T))),
    )
