"""Streaming a Cartesian path to the actuators: move to its start, then follow it.

The joint reference is the inverse kinematics of the path; its velocity and acceleration
are central differences of the inverse kinematics in time (step ``fd_step_s``), which works
for any robot model with an ``inverse_kinematics`` and is accurate to O(h^2).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from enum import IntEnum
from typing import Protocol

import numpy as np

from controller.core.ports import ContactExpectation, JointReference, TaskContext, TaskStep
from controller.core.records import record, replace
from controller.core.setpoint_smoothing import Setpoint


class CartesianTrajectory(Protocol):
    @property
    def duration_s(self) -> float: ...

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def points(self, n: int) -> np.ndarray: ...  # n samples along the whole path, for the workspace check


def position_of(path: CartesianTrajectory) -> Callable[[float], tuple[float, float, float]]:
    """The path's position at a time in floats, the path task's call every cycle: the path's own
    ``position(tau)`` where it has one (``CirclePath``: numpy's per-call cost is most of a sample's),
    else its ``sample``'s first array. Both give the same doubles."""
    position = getattr(path, "position", None)
    if callable(position):
        return position  # type: ignore[no-any-return]  # a path's optional float twin of sample

    def from_sample(tau: float) -> tuple[float, float, float]:
        p = path.sample(tau)[0]
        return (float(p[0]), float(p[1]), float(p[2]))

    return from_sample


class InverseKinematics(Protocol):
    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray: ...


BOUNDED_MOVE_ACCELERATION_M_S2 = 0.2  # a bounded move to the start speeds up and brakes at this


class PathPhase(IntEnum):
    MOVE_TO_START = 0
    TRACKING = 1
    FINISHED = 2


@record
class PathTaskState:
    phase: PathPhase = PathPhase.MOVE_TO_START
    tracking_start_s: float = 0.0
    p_cmd: tuple[float, float, float] | None = None  # a bounded move to the start: where it is [m]
    speed_m_s: float = 0.0  # ... and how fast it goes


class PathTask:
    name = "path"

    def __init__(
        self,
        robot: InverseKinematics,
        path: CartesianTrajectory,
        settle_tolerance: float,
        fd_step_s: float = 1e-3,
        contact: ContactExpectation = ContactExpectation.NONE,
        move_speed_m_s: float = 0.0,
    ) -> None:
        self.robot = robot
        self.path = path
        self.settle_tolerance = settle_tolerance
        self.fd_step_s = fd_step_s
        # A path meant to touch (the contour demo's position-control comparison) says so to the contact
        # guard, and goes to its start as a guarded move at ``move_speed_m_s`` (0: Ruckig's own speed).
        self.contact = contact
        self.move_speed_m_s = move_speed_m_s
        p0, _, _ = path.sample(0.0)
        self._start = JointReference.at_rest(tuple(robot.inverse_kinematics(p0).tolist()), tuple(p0.tolist()))
        self._position = position_of(path)

    def start(self) -> PathTaskState:
        return PathTaskState()

    def _joint_reference(self, tau: float) -> JointReference:
        h = self.fd_step_s
        ik = self.robot.inverse_kinematics
        position = self._position
        p = position(tau)
        q = ik(np.asarray(p)).tolist()
        qp = ik(np.asarray(position(tau + h))).tolist()
        qm = ik(np.asarray(position(tau - h))).tolist()
        # the central differences in floats, element by element in numpy's order of operations
        # (the same doubles): a numpy operation on a 3-vector costs more than its arithmetic
        two_h, h2 = 2.0 * h, h * h
        qd = tuple((a - b) / two_h for a, b in zip(qp, qm))
        qdd = tuple((a - 2.0 * x + b) / h2 for x, a, b in zip(q, qp, qm))
        return JointReference(tuple(q), qd, qdd, p, True, contact=self.contact)

    def phase_name(self, state: PathTaskState) -> str:
        return state.phase.name

    def step(self, state: PathTaskState, ctx: TaskContext) -> TaskStep:
        if state.phase == PathPhase.MOVE_TO_START and self.move_speed_m_s > 0.0:
            moved = self._bounded_move(state, ctx)
            if moved is not None:
                return moved
            # Arrived: the move stays there while Ruckig settles the start. Restarted from the
            # measured position, a few micrometres off, it moved again every other cycle and the
            # setpoint never settled (at 25 Hz the path never started).
            state = replace(state, p_cmd=self._start.tcp_m, speed_m_s=0.0)
        state, ref, finished = self.reference(state, ctx.t_s, ctx.setpoint)
        return TaskStep(state, ref, finished)

    def _bounded_move(self, state: PathTaskState, ctx: TaskContext) -> TaskStep | None:
        """A straight line to the start at ``move_speed_m_s``, guarded; None once there (Ruckig settles it)."""
        here = state.p_cmd or ctx.tcp_measured_m
        if here is None:
            return TaskStep(state, JointReference.at_rest(ctx.setpoint.position, self._start.tcp_m))
        goal = self._start.tcp_m
        d = (goal[0] - here[0], goal[1] - here[1], goal[2] - here[2])
        left = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        dt = ctx.period_s
        if left <= 1e-6:
            return None
        a = BOUNDED_MOVE_ACCELERATION_M_S2
        speed = min(self.move_speed_m_s, state.speed_m_s + a * dt, math.sqrt(2.0 * a * left), left / dt)
        p = (
            here[0] + d[0] / left * speed * dt,
            here[1] + d[1] / left * speed * dt,
            here[2] + d[2] / left * speed * dt,
        )
        q = self.robot.inverse_kinematics(np.asarray(p)).tolist()
        ahead = self.robot.inverse_kinematics(np.asarray(p) + np.asarray(d) / left * speed * dt).tolist()
        qd = tuple((b - c) / dt for b, c in zip(ahead, q))
        ref = JointReference(
            tuple(q), qd, (0.0,) * len(q), p, False, reactive=True, contact=ContactExpectation.GUARDED
        )
        return TaskStep(replace(state, p_cmd=p, speed_m_s=speed), ref)

    def reference(
        self, state: PathTaskState, t_cmd_s: float, setpoint: Setpoint
    ) -> tuple[PathTaskState, JointReference, bool]:
        """Reference for the setpoint the drives reach at task time ``t_cmd_s``; True once finished."""
        if state.phase == PathPhase.MOVE_TO_START:
            start = self._start
            settled = all(
                abs(a - b) <= self.settle_tolerance for a, b in zip(setpoint.position, start.position)
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
