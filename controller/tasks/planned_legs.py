"""Streaming a planned non-holonomic motion of the 3-nSPU: the time-scaled leg lengths.

The planner (``controller/planning/nonholonomic.py``, seed 004) returns controls over a plan
time [0, T]; the legs follow l(t). This module plays l back on the actuators' clock:

- **Time scaling.** System (7) of seed 004 is driftless, so any monotone reparametrisation
  t = sigma(tau) of time traces exactly the same path of poses. We use
  sigma(tau) = T s(tau / D) with the quintic s(x) = 10x^3 - 15x^4 + 6x^5 (s' = s'' = 0 at both
  ends), so the legs start and stop with zero velocity and acceleration even though the
  Fourier controls of eq. (15) do not vanish at t = 0, T. The leg velocity, acceleration and
  jerk scale exactly as 1/D, 1/D^2, 1/D^3 with the duration D, so one evaluation at D = T
  gives the shortest D that keeps each within ``limit_fraction`` of the actuators' limits:
  D = T max(v/(f v_max), sqrt(a/(f a_max)), cbrt(j/(f j_max))), peaks taken at D = T.
- **Sampling.** The plan's controls are rolled out again with ``stream_steps`` steps; the
  legs l(t) and their exact rates (eq. (6)) give a cubic Hermite interpolant of l, evaluated
  at sigma(tau) on a uniform tau grid; the acceleration is the central difference of the
  velocity. At run time positions are cubic Hermite, velocity and acceleration linear
  between the samples.
- **Start.** The legs must be at the plan's start lengths when the task starts (the pose of a
  non-holonomic robot cannot be restored by moving the legs back): otherwise the task faults.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Protocol

import numpy as np

from controller.core.cycle_data import Event, Severity
from controller.planning.nonholonomic import PlanResult, controls, feedback_leg_rates, rollout
from controller.robots.nspu import leg_lengths_batch
from controller.tasks.task import JointReference, TaskContext, TaskStep

if TYPE_CHECKING:
    from controller.core.control_law import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs
    from controller.planning.nonholonomic import PlannerConfig
    from controller.robots.builtin import NspuSection
    from controller.robots.cheope import PoseStatus
    from controller.robots.nspu_robot import NspuRobot
    from controller.robots.registry import ActuatorUnits
    from controller.robots.robot import Robot
    from controller.shell.loop import CycleTiming

# A sample of the streamed plan: leg positions, velocities, accelerations, planned platform position.
LegsSample = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, float, float]]


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s(x) = 10x^3 - 15x^4 + 6x^5 and s'(x) (quintic, zero slope and curvature at 0 and 1)."""
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10.0 - 15.0 * x + 6.0 * x * x), 30.0 * x * x * (1.0 - x) ** 2


def _hermite(t: np.ndarray, y: np.ndarray, dy: np.ndarray, tq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite interpolant of samples (t, y, dy) [(N,), (N, 3), (N, 3)] and its derivative at tq."""
    k = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, t.size - 2)
    h = (t[k + 1] - t[k])[:, None]
    s = ((tq - t[k])[:, None]) / h
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    val = h00 * y[k] + h10 * h * dy[k] + h01 * y[k + 1] + h11 * h * dy[k + 1]
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    der = (d00 * y[k] + d01 * y[k + 1]) / h + d10 * dy[k] + d11 * dy[k + 1]
    return val, der


@dataclass(frozen=True, eq=False)
class StreamedPlan:
    """Time-scaled leg references on a uniform grid of task time [0, duration_s]."""

    t_s: np.ndarray  # (N,)
    legs_m: np.ndarray  # (N, 3)
    rates_m_s: np.ndarray  # (N, 3)
    accel_m_s2: np.ndarray  # (N, 3)
    platform_m: np.ndarray  # (N, 3) planned platform position (for the reference TCP)
    duration_s: float
    scale: float  # D / T
    peaks: tuple[float, float, float]  # max |velocity|, |acceleration|, |jerk| of the legs at duration_s

    def sample(self, tau: float) -> LegsSample:
        """Leg positions, velocities, accelerations and the planned platform position at task time tau."""
        t = self.t_s
        tau = min(max(tau, 0.0), self.duration_s)
        k = min(int(tau / self.duration_s * (t.size - 1)), t.size - 2)
        h = t[k + 1] - t[k]
        s = (tau - t[k]) / h
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        y, dy = self.legs_m, self.rates_m_s
        pos = h00 * y[k] + h10 * h * dy[k] + h01 * y[k + 1] + h11 * h * dy[k + 1]
        vel = (1 - s) * dy[k] + s * dy[k + 1]
        acc = (1 - s) * self.accel_m_s2[k] + s * self.accel_m_s2[k + 1]
        plat = (1 - s) * self.platform_m[k] + s * self.platform_m[k + 1]
        return tuple(pos.tolist()), tuple(vel.tolist()), tuple(acc.tolist()), tuple(plat.tolist())


def time_scale_plan(plan: PlanResult, max_velocity: float, max_acceleration: float, max_jerk: float,
                    limit_fraction: float = 0.5, stream_steps: int = 1000) -> StreamedPlan:
    """Resample a converged plan and time-scale it to ``limit_fraction`` of the actuators' limits (see module doc)."""
    plan.raise_for_status()
    if not 0.0 < limit_fraction <= 1.0:
        raise ValueError(f"limit_fraction must be in (0, 1], got {limit_fraction}")
    cfg = dataclasses.replace(plan.config, n_steps=stream_steps)
    horizon = cfg.horizon_s
    t, ps, rs = rollout(plan.geometry, plan.start, plan.lambdas, cfg)
    legs = leg_lengths_batch(plan.geometry, ps, rs)
    rates = feedback_leg_rates(plan.geometry, ps, rs, controls(plan.lambdas, t, horizon, cfg.harmonics))  # eq. (6)
    tau = np.linspace(0.0, 1.0, stream_steps + 1)  # task time at D = T, in units of T

    def profile(duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x = tau  # tau / D on the uniform grid
        s, ds = _smoothstep(x)
        sig = horizon * s
        pos, der = _hermite(t, legs, rates, sig)
        vel = der * (horizon * ds / duration)[:, None]
        tq = tau * duration
        acc = np.gradient(vel, tq, axis=0, edge_order=2)
        jerk = np.gradient(acc, tq, axis=0, edge_order=2)
        plat = np.stack([np.interp(sig, t, ps[:, i]) for i in range(3)], axis=1)
        return pos, vel, acc, jerk, plat

    _, v1, a1, j1, _ = profile(horizon)
    pv, pa, pj = float(np.abs(v1).max()), float(np.abs(a1).max()), float(np.abs(j1).max())
    f = limit_fraction
    scale = max(pv / (f * max_velocity), math.sqrt(pa / (f * max_acceleration)), (pj / (f * max_jerk)) ** (1 / 3))
    duration = horizon * scale
    pos, vel, acc, jerk, plat = profile(duration)
    acc[0] = acc[-1] = 0.0  # exact: s'' = 0 at both ends
    peaks = (float(np.abs(vel).max()), float(np.abs(acc).max()), float(np.abs(jerk).max()))
    return StreamedPlan(tau * duration, pos, vel, acc, plat, duration, scale, peaks)


class LegsPhase(IntEnum):
    CHECK_START = 0
    STREAMING = 1
    FINISHED = 2


@dataclass(frozen=True, slots=True)
class LegsTaskState:
    phase: LegsPhase = LegsPhase.CHECK_START
    start_s: float = 0.0


class ActuatorCheck(Protocol):
    """A robot that checks actuator positions (the leg stroke), as ``NspuRobot`` does."""

    def check_actuators(self, q_m: tuple[float, ...]) -> PoseStatus: ...


class PlannedLegsTask:
    """Streams a ``StreamedPlan``: checks the legs are at its start, then plays it back."""

    name = "planned_legs"

    def __init__(self, streamed: StreamedPlan, start_tolerance_m: float,
                 robot: ActuatorCheck | None = None) -> None:
        self.streamed = streamed
        self.start_tolerance_m = start_tolerance_m
        self.robot = robot  # with check_actuators: the reference is checked against the stroke
        first = streamed.sample(0.0)
        self._start = JointReference(first[0], (0.0,) * 3, (0.0,) * 3, first[3], False)

    def start(self) -> LegsTaskState:
        return LegsTaskState()

    def phase_name(self, state: LegsTaskState) -> str:
        return state.phase.name

    def step(self, state: LegsTaskState, ctx: TaskContext) -> TaskStep:
        if state.phase == LegsPhase.CHECK_START:
            off = max(abs(a - b) for a, b in zip(ctx.setpoint.position, self._start.position))
            if off > self.start_tolerance_m:
                why = (f"the legs {list(np.round(ctx.setpoint.position, 6))} m are not at the plan's start "
                       f"{list(np.round(self._start.position, 6))} m (off by {off:.2e} m > {self.start_tolerance_m} m): "
                       "a non-holonomic platform cannot be brought back to its start pose by moving the legs; "
                       "restart the simulator (or re-home the robot) at the planned start pose")
                return TaskStep(state, self._start, fault=why)
            state = LegsTaskState(LegsPhase.STREAMING, ctx.t_s)
            msg = (f"streaming the plan: {self.streamed.duration_s:.3f} s "
                   f"(time scale {self.streamed.scale:.3f})")
            ev: tuple[Event, ...] = (Event("task", Severity.INFO, msg),)
        else:
            ev = ()
        tau = ctx.t_s - state.start_s
        finished = tau >= self.streamed.duration_s
        if finished:
            state = LegsTaskState(LegsPhase.FINISHED, state.start_s)
        pos, vel, acc, plat = self.streamed.sample(tau)
        if self.robot is not None:
            status = self.robot.check_actuators(pos)
            if not status.ok:
                return TaskStep(state, self._start, fault=f"planned leg reference: {status.reason}")
        ref = JointReference(pos, vel, acc, plat, not finished)
        return TaskStep(state, ref, finished, events=ev)


EXPLANATION = (
    "The 3-nSPU is non-holonomic: its pose is the integral of the leg motion along the whole path, not a function "
    "of the final leg lengths, so every leg tracking error (drive lag, Ruckig smoothing, encoder quantisation) is "
    "integrated into a pose error that nothing corrects afterwards. The reached pose is integrated from the encoder "
    "readings of every cycle with the simulator's model (seed 000 eq. (11), RKMK4 per cycle); its distance from the "
    "goal is the plan's own end error (plan_end_*) plus what the streaming added: it measures how good the "
    "streaming is."
)


class PlanExecutionReport:
    """Loop observer: measured leg lengths per cycle, then the reached pose against the goal.

    The reached pose is integrated from the start pose through the measured leg lengths of
    every cycle (``nspu_robot.pose_odometry``): the same inputs and integrator as the
    simulator's mechanics, which integrate the drives' actual positions at every SYNC.
    """

    def __init__(self, robot: NspuRobot, plan: PlanResult, streamed: StreamedPlan,
                 planning_time_s: float) -> None:
        self.robot = robot
        self.plan = plan
        self.streamed = streamed
        self.planning_time_s = planning_time_s
        self._t: list[float] = []
        self._legs: list[tuple[float, ...]] = []
        self._refs: list[tuple[float, ...] | None] = [None, None]
        self.leg_errors_m: list[float] = []

    def on_cycle(self, cycle: int, t: float, inputs: CycleInputs, state: ControllerState,
                 outputs: CycleOutputs, events: tuple[Event, ...], timing: CycleTiming) -> None:
        ref = self._refs[-2]  # the setpoint the drives were to reach at this SYNC (sent two cycles ago)
        self._refs.append(state.setpoint.position if state.tcp_reference_m is not None else None)
        del self._refs[0]
        if not all(d.fresh for d in inputs.drives):  # a missing TPDO: no sample this cycle
            return
        legs = tuple(d.position for d in inputs.drives)
        self._t.append(t)
        self._legs.append(legs)
        if ref is not None:
            self.leg_errors_m.append(max(abs(a - b) for a, b in zip(legs, ref)))

    def summary(self) -> dict[str, object]:
        from controller.robots.nspu import so3_log
        from controller.robots.nspu_robot import pose_errors, pose_odometry

        plan, goal = self.plan, self.robot.goal
        plan_end = (float(np.linalg.norm(plan.p_m[-1] - goal.p_m)),
                    float(np.linalg.norm(so3_log(plan.R[-1] @ goal.R.T))))
        out: dict[str, object] = {
            "plan": {"status": plan.status.value, "iterations": plan.iterations, "final_error": plan.final_error,
                     "planning_time_s": round(self.planning_time_s, 3), "message": plan.message,
                     "streamed_duration_s": self.streamed.duration_s, "time_scale": self.streamed.scale,
                     "leg_peaks": {"velocity_m_s": self.streamed.peaks[0],
                                   "acceleration_m_s2": self.streamed.peaks[1], "jerk_m_s3": self.streamed.peaks[2]}},
            "plan_end_position_error_m": plan_end[0], "plan_end_angle_error_rad": plan_end[1],
            "goal_pose": {"position_m": goal.p_m.tolist(), "rotation_vector_rad": so3_log(goal.R).tolist()},
            "explanation": EXPLANATION,
        }
        err = np.asarray(self.leg_errors_m)
        out["leg_tracking_error_m"] = {"rms": float(np.sqrt(np.mean(err**2))) if err.size else None,
                                       "max": float(err.max()) if err.size else None, "samples": int(err.size)}
        if len(self._t) >= 2:
            reached = pose_odometry(self.robot.geometry, self.robot.start, np.array(self._t), np.array(self._legs))
            pe, ae = pose_errors(reached, goal)
            out.update({"reached_pose": {"position_m": reached.p_m.tolist(),
                                         "rotation_vector_rad": so3_log(reached.R).tolist()},
                        "position_error_m": pe, "angle_error_rad": ae})
        else:
            out.update({"reached_pose": None, "position_error_m": None, "angle_error_rad": None})
        return out


def build_planned_legs_task(section: NspuSection, limits: ActuatorUnits, settle_tolerance_m: float,
                            robot: Robot) -> tuple[PlannedLegsTask, PlanExecutionReport]:
    """Plan the configured motion (seed 004), time-scale it to ``section.limit_fraction`` of the
    actuators' limits and wrap it in a task with its report.

    Raises ``PlanningError`` (a RefusedError) naming the planner's status when the plan fails.
    """
    import time

    from controller.planning.nonholonomic import plan_motion
    from controller.robots.nspu_robot import NspuRobot

    if not isinstance(robot, NspuRobot):  # the registry pairs this task with the 3-nSPU only
        raise TypeError(f"the planned task needs the 3-nSPU robot model, got {type(robot).__name__}")
    t0 = time.perf_counter()
    plan = plan_motion(robot.geometry, robot.start, robot.goal, planner_config(section)).raise_for_status()
    planning_time = time.perf_counter() - t0
    streamed = time_scale_plan(plan, limits.max_velocity, limits.max_acceleration, limits.max_jerk,
                               section.limit_fraction, section.stream_steps)
    task = PlannedLegsTask(streamed, start_tolerance_m=max(settle_tolerance_m, 1e-5), robot=robot)
    return task, PlanExecutionReport(robot, plan, streamed, planning_time)


def planner_config(n: NspuSection, check_type2: bool | None = None) -> PlannerConfig:
    from controller.planning.nonholonomic import PlannerConfig

    return PlannerConfig(horizon_s=n.horizon_s, harmonics=n.harmonics, tolerance=n.tolerance,
                         max_iterations=n.max_iterations, n_steps=n.n_steps,
                         check_type2=n.check_type2 if check_type2 is None else check_type2, restarts=n.restarts)
