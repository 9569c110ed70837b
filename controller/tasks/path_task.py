"""Streaming a Cartesian path to the actuators: move to its start, then follow it.

The joint reference is the inverse kinematics of the path; its velocity and acceleration
are central differences of the inverse kinematics in time (step ``fd_step_s``), which works
for any robot model with an ``inverse_kinematics`` and is accurate to O(h^2).
"""

from __future__ import annotations

from enum import IntEnum
from typing import Protocol

import numpy as np

from controller.core.ports import JointReference, TaskContext, TaskStep
from controller.core.records import record
from controller.core.setpoint_smoothing import Setpoint


class CartesianTrajectory(Protocol):
    @property
    def duration_s(self) -> float: ...

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def points(self, n: int) -> np.ndarray: ...  # n samples along the whole path, for the workspace check


class InverseKinematics(Protocol):
    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray: ...


class PathPhase(IntEnum):
    MOVE_TO_START = 0
    TRACKING = 1
    FINISHED = 2


@record
class PathTaskState:
    phase: PathPhase = PathPhase.MOVE_TO_START
    tracking_start_s: float = 0.0


class PathTask:
    name = "path"

    def __init__(
        self,
        robot: InverseKinematics,
        path: CartesianTrajectory,
        settle_tolerance: float,
        fd_step_s: float = 1e-3,
    ) -> None:
        self.robot = robot
        self.path = path
        self.settle_tolerance = settle_tolerance
        self.fd_step_s = fd_step_s
        p0, _, _ = path.sample(0.0)
        self._start = JointReference.at_rest(tuple(robot.inverse_kinematics(p0).tolist()), tuple(p0.tolist()))

    def start(self) -> PathTaskState:
        return PathTaskState()

    def _joint_reference(self, tau: float) -> JointReference:
        h = self.fd_step_s
        ik = self.robot.inverse_kinematics
        p, _, _ = self.path.sample(tau)
        q = ik(p).tolist()
        qp = ik(self.path.sample(tau + h)[0]).tolist()
        qm = ik(self.path.sample(tau - h)[0]).tolist()
        # the central differences in floats, element by element in numpy's order of operations
        # (the same doubles): a numpy operation on a 3-vector costs more than its arithmetic
        two_h, h2 = 2.0 * h, h * h
        qd = tuple((a - b) / two_h for a, b in zip(qp, qm, strict=True))
        qdd = tuple((a - 2.0 * x + b) / h2 for x, a, b in zip(q, qp, qm, strict=True))
        return JointReference(tuple(q), qd, qdd, tuple(p.tolist()), True)

    def phase_name(self, state: PathTaskState) -> str:
        return state.phase.name

    def step(self, state: PathTaskState, ctx: TaskContext) -> TaskStep:
        state, ref, finished = self.reference(state, ctx.t_s, ctx.setpoint)
        return TaskStep(state, ref, finished)

    def reference(
        self, state: PathTaskState, t_cmd_s: float, setpoint: Setpoint
    ) -> tuple[PathTaskState, JointReference, bool]:
        """Reference for the setpoint the drives reach at task time ``t_cmd_s``; True once finished."""
        if state.phase == PathPhase.MOVE_TO_START:
            start = self._start
            settled = all(
                abs(a - b) <= self.settle_tolerance
                for a, b in zip(setpoint.position, start.position, strict=True)
            ) and all(abs(v) <= self.settle_tolerance for v in setpoint.velocity)
            if not settled:
                return state, start, False
            state = PathTaskState(PathPhase.TRACKING, t_cmd_s)
        if state.phase == PathPhase.TRACKING:
            tau = t_cmd_s - state.tracking_start_s
            if tau < self.path.duration_s:
                return state, self._joint_reference(tau), False
            state = PathTaskState(PathPhase.FINISHED, state.tracking_start_s)
        return state, self._joint_reference(self.path.duration_s), True
