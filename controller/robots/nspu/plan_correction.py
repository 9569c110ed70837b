"""The 3-nSPU's correcting plans: from a measured pose to the goal, deterministic and memoised.

The planned task (``planned_legs.py``) asks for a correcting plan with a *request*: the measured
pose as six floats (P [m], rotation vector [rad]) and a request number. The plan is a pure
function of the request (``plan_motion`` is deterministic: fixed initial controls, a seeded
restart generator), so it may be computed anywhere and the step stays pure:

- off the loop by the shell's ``PlanWorker`` (controller/robots/nspu/plan_worker.py), which fills
  this memo and tells the step through the recorded input ``CycleInputs.plans_ready``; the
  step then reads the memo;
- inside the step (``in_step``: simulated time, and replay, where the memo is empty): the same
  call computes it. A replay therefore reproduces the recorded outputs bit for bit.

Planning takes 0.2-1 s: inside the step of a 400 Hz loop that stalls SYNC for hundreds of
periods and the drives' SYNC watchdog (50 ms) quick-stops them, so on a bus the worker is used.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from controller.robots.nspu.kinematics import NspuGeometry, Pose
    from controller.robots.nspu.planning.nonholonomic import PlannerConfig
    from controller.robots.nspu.streamed_plan import StreamedPlan

PoseRequest = tuple[float, float, float, float, float, float]  # P [m], rotation vector [rad]


@dataclass(frozen=True)
class CorrectionPlan:
    """The streamed plan of a request, or why there is none."""

    streamed: StreamedPlan | None
    failure: str = ""
    iterations: int = 0


def pose_from_request(request: PoseRequest) -> Pose:
    from controller.core.rotations import so3_exp
    from controller.robots.nspu.kinematics import Pose

    return Pose(np.array(request[:3]), so3_exp(np.array(request[3:])))


@dataclass(frozen=True)
class CorrectionProblem:
    """Everything a correcting plan depends on besides its request: picklable, for a worker process."""

    geometry: NspuGeometry
    goal: Pose
    config: PlannerConfig
    limits: tuple[float, float, float]  # the actuators' velocity, acceleration, jerk limits
    limit_fraction: float
    stream_steps: int


def correction_plan(problem: CorrectionProblem, request: PoseRequest) -> CorrectionPlan:
    """The plan from the request's pose to the goal, time-scaled: a pure function of its arguments."""
    from controller.robots.nspu.kinematics import NspuModelError
    from controller.robots.nspu.planning.nonholonomic import plan_motion
    from controller.robots.nspu.streamed_plan import time_scale_plan

    try:
        start = pose_from_request(request)
        plan = plan_motion(problem.geometry, start, problem.goal, problem.config)
    except NspuModelError as err:
        return CorrectionPlan(None, f"the measured pose has no plan: {err}")
    if not plan.ok:
        return CorrectionPlan(None, f"planner {plan.status.value}: {plan.message}", plan.iterations)
    streamed = time_scale_plan(plan, *problem.limits, problem.limit_fraction, problem.stream_steps)
    return CorrectionPlan(streamed, "", plan.iterations)


class CorrectionPlanner:
    """plan(request) -> CorrectionPlan, memoised by the request's exact floats (thread-safe)."""

    def __init__(self, problem: CorrectionProblem) -> None:
        self.problem = problem
        self._memo: dict[PoseRequest, CorrectionPlan] = {}
        self._lock = threading.Lock()

    def store(self, request: PoseRequest, result: CorrectionPlan) -> None:
        """A plan computed elsewhere (the shell's worker) for ``request``."""
        with self._lock:
            self._memo[request] = result

    def plan(self, request: PoseRequest) -> CorrectionPlan:
        with self._lock:
            done = self._memo.get(request)
        if done is not None:
            return done
        result = correction_plan(self.problem, request)
        self.store(request, result)
        return result
