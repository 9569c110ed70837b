"""Streaming a planned non-holonomic motion of the 3-nSPU: the time-scaled leg lengths.

The planner (``controller/robots/nspu/planning/nonholonomic.py``, seed 004) returns controls over a plan
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
- **Start.** Open loop, the legs must be at the plan's start lengths when the task starts (the
  pose of a non-holonomic robot cannot be restored by moving the legs back): otherwise the task
  faults.
- **Closed loop** (a pose tracker, ``[tracker]``): the task measures the platform before and after
  each motion and replans from the measured pose (``PlannedLegsTask``; the plans from
  ``plan_correction.py``, off the loop in ``controller/robots/nspu/plan_worker.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Protocol

import numpy as np

from controller.core.cycle_data import TRACKER_SATURATED, Event, Severity
from controller.core.ports import JointReference, OffLoopWorker, TaskContext, TaskStep
from controller.core.records import record, replace
from controller.robots.nspu.streamed_plan import StreamedPlan, time_scale_plan

if TYPE_CHECKING:
    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs
    from controller.core.ports import CycleTiming, PoseStatus, Robot
    from controller.robot_registry import ActuatorUnits
    from controller.robots.nspu.entry import NspuSection
    from controller.robots.nspu.kinematics import Pose
    from controller.robots.nspu.model import NspuRobot
    from controller.robots.nspu.plan_correction import CorrectionPlanner
    from controller.robots.nspu.planning.nonholonomic import PlannerConfig, PlanResult


class LegsPhase(IntEnum):
    CHECK_START = 0
    STREAMING = 1
    FINISHED = 2
    MEASURING = 3  # holding the legs, averaging the tracker's samples
    PLANNING = 4  # holding the legs until the correcting plan is ready


@dataclass(frozen=True)
class CorrectionSettings:
    """Closed-loop execution (``[robot.nspu]`` correction_*): see ``PlannedLegsTask``."""

    tolerance_m: float  # the measured pose is accepted within this distance of the goal ...
    tolerance_rad: float  # ... and this angle
    max_corrections: int  # correcting plans after the first one; 0: measure and report only
    tracker_samples: int  # fresh tracker samples averaged into one measurement
    settle_s: float  # wait after a stream ends before measuring (the drives' lag)
    tracker_timeout_s: float  # no usable sample this long while measuring: the task faults, naming it
    plan_timeout_s: float  # no plan from the off-loop worker this long after the request: the task faults
    in_step: bool  # plan inside the step (simulated time); else wait for the off-loop worker's plans_ready


@record
class LegsTaskState:
    phase: LegsPhase = LegsPhase.CHECK_START
    start_s: float = 0.0
    # legs the streamed plan's increments are added to (None: the plan's own absolute lengths)
    leg_origin_m: tuple[float, ...] | None = None
    streamed: StreamedPlan | None = None  # the plan being streamed (None: the task's first plan)
    corrections: int = 0  # correcting plans streamed so far
    moved: bool = False  # a plan has been streamed
    samples: int = 0  # tracker samples in the running sums
    last_sample_s: float = -math.inf  # task time of the last usable tracker sample
    last_status: int = 0  # the status of the last flagged sample since the last usable one (0: none)
    sum_pose: tuple[float, ...] = (0.0,) * 6  # P [m] and rotation vector [rad], summed
    request_id: int = 0  # the last correcting plan asked for (PlanWorker: CycleInputs.plans_ready)
    request: tuple[float, ...] = ()  # its start: the measured pose (P, rotation vector)
    measured_position_error_m: float = math.nan  # last measurement against the goal
    measured_angle_error_rad: float = math.nan


class ActuatorCheck(Protocol):
    """A robot that checks actuator positions (the leg stroke), as ``NspuRobot`` does."""

    def check_actuators(self, q_m: tuple[float, ...]) -> PoseStatus: ...


class PlannedLegsTask:
    """Streams a ``StreamedPlan``; with a pose tracker, measures and corrects (closed loop).

    Without a tracker (``correction`` None): checks the legs are at the plan's start, plays it
    back, finishes (open loop: the odometry integrates the same model the plan used, so it
    cannot see a model mismatch; it is reported by ``PlanExecutionReport``).

    With a tracker the execution is corrected by *replanning from the measured pose*, between
    motions, not during them:
      1. hold the legs, average ``tracker_samples`` fresh samples (the start pose); a sample whose
         status is not 0 (the tracker's own flag of a bad measurement: a coordinate saturated) is
         not averaged, and no usable sample for ``tracker_timeout_s`` faults, naming it: a dead
         or blind tracker otherwise held the legs, silently, until the run's duration ended;
      2. if it is within the tolerance of the plan's start, stream the first plan, else plan
         from the measured pose to the goal and stream that;
      3. at the end of a stream, wait ``settle_s``, measure again; within the tolerance of the
         goal: finished; else plan from the measured pose to the goal and stream it, up to
         ``max_corrections`` times.
    A plan is streamed as leg *increments* from where the legs stand (l_ref = l_now + l(t) - l(0)):
    system (7) of seed 004 moves the platform with the leg rates, and with a model mismatch the
    plan's absolute start lengths are not those of the measured pose on the real robot.
    Why replanning and not tracking with feedback along the motion: the 3-nSPU has 3 inputs for
    6 coordinates; a correction of a pose error is itself a non-holonomic motion (Lie brackets of
    the leg fields), which the planner computes and a linear feedback on the plan cannot; the
    model errors act along the whole motion, so a full replan from the measured pose at the end
    of each motion removes what they accumulated, and each correction is a small motion whose
    own error is small (the error shrinks geometrically with the corrections).
    """

    name = "planned_legs"

    def __init__(
        self,
        streamed: StreamedPlan,
        start_tolerance_m: float,
        robot: ActuatorCheck | None = None,
        correction: CorrectionSettings | None = None,
        planner: CorrectionPlanner | None = None,
        goal: Pose | None = None,
    ) -> None:
        self.streamed = streamed
        self.start_tolerance_m = start_tolerance_m
        self.robot = robot  # with check_actuators: the reference is checked against the stroke
        if correction is not None and (planner is None or goal is None):
            raise ValueError("a corrected execution needs the correction planner and the goal")
        self.correction = correction
        self.correction_planner = planner  # the PlanWorker (off_loop_worker) fills its memo off the loop
        self.goal = goal
        first = streamed.sample(0.0)
        self._start = JointReference.at_rest(first[0], first[3])

    def off_loop_worker(self) -> OffLoopWorker | None:
        """The worker process that computes the correcting plans off the loop (``PlansOffLoop``), or
        None when the plans are computed in the step (``correction.in_step``) or not at all."""
        if self.correction_planner is None or self.correction is None or self.correction.in_step:
            return None
        from controller.robots.nspu.plan_worker import PlanWorker

        return PlanWorker(self.correction_planner)

    def start(self) -> LegsTaskState:
        return LegsTaskState()

    def phase_name(self, state: LegsTaskState) -> str:
        return state.phase.name

    def _hold(self, ctx: TaskContext, plan: StreamedPlan) -> JointReference:
        return JointReference.at_rest(ctx.setpoint.position, plan.sample(plan.duration_s)[3])

    def step(self, state: LegsTaskState, ctx: TaskContext) -> TaskStep:
        if state.phase == LegsPhase.CHECK_START:
            if self.correction is not None:  # measure where the platform is before moving
                return TaskStep(
                    replace(state, phase=LegsPhase.MEASURING, start_s=ctx.t_s), self._hold(ctx, self.streamed)
                )
            off = max(abs(a - b) for a, b in zip(ctx.setpoint.position, self._start.position, strict=True))
            if off > self.start_tolerance_m:
                why = (
                    f"the legs {_lengths_text(ctx.setpoint.position)} m are not at the plan's start "
                    f"{_lengths_text(self._start.position)} m (off by {off:.2e} m > {self.start_tolerance_m} m): "
                    "a non-holonomic platform cannot be brought back to its start pose by moving the legs; "
                    "restart the simulator (or re-home the robot) at the planned start pose"
                )
                return TaskStep(state, self._start, fault=why)
            return self._begin_stream(state, ctx, self.streamed, None, "streaming the plan")
        if state.phase == LegsPhase.MEASURING:
            return self._measure(state, ctx)
        if state.phase == LegsPhase.PLANNING:
            return self._await_plan(state, ctx)
        plan = state.streamed or self.streamed
        tau = ctx.t_s - state.start_s
        ended = tau >= plan.duration_s
        pos, vel, acc, plat = plan.sample(tau)
        if state.leg_origin_m is not None:  # increments from where the legs stood
            l0 = plan.legs_m[0]
            pos = tuple(o + p - float(z) for o, p, z in zip(state.leg_origin_m, pos, l0, strict=True))
        if self.robot is not None:
            status = self.robot.check_actuators(pos)
            if not status.ok:
                return TaskStep(state, self._start, fault=f"planned leg reference: {status.reason}")
        if ended and state.phase == LegsPhase.STREAMING:
            if self.correction is None:
                state = replace(state, phase=LegsPhase.FINISHED)
            else:  # settle, then measure against the goal
                state = replace(
                    state,
                    phase=LegsPhase.MEASURING,
                    start_s=ctx.t_s,
                    samples=0,
                    sum_pose=(0.0,) * 6,
                    last_status=0,
                )
                return TaskStep(state, JointReference.at_rest(pos, plat))
        finished = state.phase == LegsPhase.FINISHED
        return TaskStep(state, JointReference(pos, vel, acc, plat, not finished), finished)

    def _begin_stream(
        self,
        state: LegsTaskState,
        ctx: TaskContext,
        plan: StreamedPlan,
        origin: tuple[float, ...] | None,
        what: str,
    ) -> TaskStep:
        state = replace(
            state, phase=LegsPhase.STREAMING, start_s=ctx.t_s, streamed=plan, leg_origin_m=origin, moved=True
        )
        msg = f"{what}: {plan.duration_s:.3f} s (time scale {plan.scale:.3f})"
        pos, vel, acc, plat = plan.sample(0.0)
        if origin is not None:
            pos = origin
        return TaskStep(
            state, JointReference(pos, vel, acc, plat, True), events=(Event("task", Severity.INFO, msg),)
        )

    def _measure(self, state: LegsTaskState, ctx: TaskContext) -> TaskStep:
        """Hold the legs; after settle_s, average the fresh tracker samples; then decide."""
        c = self.correction
        assert c is not None and self.goal is not None
        hold = self._hold(ctx, state.streamed or self.streamed)
        k = ctx.inputs.tracker
        if ctx.t_s - state.start_s < c.settle_s:
            return TaskStep(state, hold)
        if k is None or not k.fresh or k.status != 0:
            if k is not None and k.fresh:
                state = replace(state, last_status=k.status)
            return self._await_sample(state, ctx, hold)
        sums = tuple(
            a + b for a, b in zip(state.sum_pose, (*k.position_m, *k.rotation_vector_rad), strict=True)
        )
        n = state.samples + 1
        if n < c.tracker_samples:
            return TaskStep(
                replace(state, samples=n, sum_pose=sums, last_sample_s=ctx.t_s, last_status=0), hold
            )
        from controller.robots.nspu.model import pose_errors
        from controller.robots.nspu.plan_correction import pose_from_request

        request = tuple(v / n for v in sums)
        measured = pose_from_request(request)  # type: ignore[arg-type]
        if not state.moved:  # before any motion: against the plan's start
            from controller.robots.nspu.model import NspuRobot

            start = self.robot.start if isinstance(self.robot, NspuRobot) else self.goal
            pe, ae = pose_errors(measured, start)
            if pe <= c.tolerance_m and ae <= c.tolerance_rad:
                return self._begin_stream(
                    replace(state, samples=0, sum_pose=(0.0,) * 6),
                    ctx,
                    self.streamed,
                    ctx.setpoint.position,
                    f"at the plan's start ({pe * 1e3:.3f} mm, {ae * 1e3:.2f} mrad off): streaming the plan",
                )
            what = f"the platform is {pe * 1e3:.3f} mm, {ae * 1e3:.2f} mrad from the plan's start"
        else:
            pe, ae = pose_errors(measured, self.goal)
            state = replace(state, measured_position_error_m=pe, measured_angle_error_rad=ae)
            if pe <= c.tolerance_m and ae <= c.tolerance_rad:
                msg = f"measured {pe * 1e3:.3f} mm, {ae * 1e3:.2f} mrad from the goal: within the tolerance"
                return TaskStep(
                    replace(state, phase=LegsPhase.FINISHED),
                    hold,
                    True,
                    events=(Event("task", Severity.INFO, msg),),
                )
            if state.corrections >= c.max_corrections:
                msg = (
                    f"measured {pe * 1e3:.3f} mm, {ae * 1e3:.2f} mrad from the goal after {state.corrections} "
                    f"corrections (tolerance {c.tolerance_m * 1e3:.3f} mm, {c.tolerance_rad * 1e3:.2f} mrad)"
                )
                return TaskStep(
                    replace(state, phase=LegsPhase.FINISHED),
                    hold,
                    True,
                    events=(Event("task", Severity.WARNING, msg),),
                )
            what = f"measured {pe * 1e3:.3f} mm, {ae * 1e3:.2f} mrad from the goal"
        state = replace(
            state,
            phase=LegsPhase.PLANNING,
            start_s=ctx.t_s,
            samples=0,
            sum_pose=(0.0,) * 6,
            request_id=state.request_id + 1,
            request=request,
        )
        ev = Event(
            "task",
            Severity.INFO,
            f"{what}: replanning from the measured pose (plan request {state.request_id})",
        )
        step = self._await_plan(state, ctx)
        return replace(step, events=(ev, *step.events))

    def _await_sample(self, state: LegsTaskState, ctx: TaskContext, hold: JointReference) -> TaskStep:
        """Hold on while the tracker's silence is shorter than ``tracker_timeout_s`` (from the end of
        the settling or the last usable sample); past it, fault with what was (not) received."""
        c = self.correction
        assert c is not None
        since_s = max(state.start_s + c.settle_s, state.last_sample_s)
        if ctx.t_s - since_s <= c.tracker_timeout_s:
            return TaskStep(state, hold)
        if state.last_status == 0:  # a tracker that fell silent, even after usable samples
            what = "no sample"
        else:
            saturated = " (a coordinate saturated)" if state.last_status & TRACKER_SATURATED else ""
            what = f"only samples flagged bad, status 0x{state.last_status:02X}{saturated},"
        why = (
            f"the pose tracker sent {what} for {ctx.t_s - since_s:.2f} s while the platform was measured "
            f"({state.samples} of {c.tracker_samples} samples averaged; robot.nspu.tracker_timeout_s = "
            f"{c.tracker_timeout_s:g}): the closed loop cannot measure the platform; check the tracker "
            "([tracker] node_id) and its view of the platform"
        )
        return TaskStep(state, hold, fault=why)

    def _await_plan(self, state: LegsTaskState, ctx: TaskContext) -> TaskStep:
        c, planner = self.correction, self.correction_planner
        assert c is not None and planner is not None
        hold = self._hold(ctx, state.streamed or self.streamed)
        if not c.in_step and ctx.inputs.plans_ready < state.request_id:
            # the off-loop worker has not finished it yet; one that never does (died for good, its
            # plan raised) is named here: planning inside the step instead stalled the loop 0.5 s
            # and the drives' SYNC watchdog quick-stopped them (EMCY 0x8240), naming no worker
            waited_s = ctx.t_s - state.start_s
            if waited_s <= c.plan_timeout_s:
                return TaskStep(state, hold)
            why = (
                f"correction {state.request_id}: no plan from the planning worker {waited_s:.2f} s after the "
                f"request (robot.nspu.correction_plan_timeout_s = {c.plan_timeout_s:g}): the worker process "
                "failed or is starved; the service's log says why"
            )
            return TaskStep(state, hold, fault=why)
        result = planner.plan(state.request)  # type: ignore[arg-type]  # memo hit, or computed here (replay)
        if result.streamed is None:
            return TaskStep(state, hold, fault=f"correction {state.request_id}: {result.failure}")
        corrections = state.corrections + (1 if state.moved else 0)
        return self._begin_stream(
            replace(state, corrections=corrections),
            ctx,
            result.streamed,
            ctx.setpoint.position,
            f"streaming the plan from the measured pose (request {state.request_id}, "
            f"{result.iterations} iterations)",
        )


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

    A cycle whose TPDO from a drive is missing takes that drive's setpoint for the SYNC instead
    (the position it was sent to reach there; the leg tracking error says how close the drives
    follow): the pose of a non-holonomic platform depends on the legs' path, and a gap of m
    cycles integrated as one step would replace the path between its two ends by a straight line
    of the leg lengths (0.03 mm off the goal for a gap of 4 cycles of the default motion, 0.25 mm for
    8, 2.8 mm for 20, where the correction tolerance is 0.2 mm). A simulator or a bus that is late
    under load drops such runs of samples; ``odometry_setpoint_samples`` counts the cycles that
    took a setpoint.
    """

    def __init__(
        self, robot: NspuRobot, plan: PlanResult, streamed: StreamedPlan, planning_time_s: float
    ) -> None:
        self.robot = robot
        self.plan = plan
        self.streamed = streamed
        self.planning_time_s = planning_time_s
        self._t: list[float] = []
        self._legs: list[tuple[float, ...]] = []
        self._refs: list[tuple[float, ...] | None] = [None, None]
        self.leg_errors_m: list[float] = []
        self.setpoint_samples = 0  # cycles whose legs took a drive's setpoint for its missing TPDO
        self._task_state: object = None  # the last one: the closed loop's measurements and corrections

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        self._task_state = state.task_state
        ref = self._refs[-2]  # the setpoint the drives were to reach at this SYNC (sent two cycles ago)
        self._refs.append(state.setpoint.position if state.tcp_reference_m is not None else None)
        del self._refs[0]
        fresh = all(d.fresh for d in inputs.drives)
        if fresh:
            legs = tuple(d.position for d in inputs.drives)
        elif ref is not None:  # the setpoint for a drive whose TPDO is missing (class text)
            legs = tuple(d.position if d.fresh else r for d, r in zip(inputs.drives, ref, strict=True))
            self.setpoint_samples += 1
        else:  # a missing TPDO outside the stream: no sample this cycle
            return
        self._t.append(t)
        self._legs.append(legs)
        if ref is not None and fresh:
            self.leg_errors_m.append(max(abs(a - b) for a, b in zip(legs, ref, strict=True)))

    def summary(self) -> dict[str, object]:
        from controller.core.rotations import so3_log
        from controller.robots.nspu.model import pose_errors, pose_odometry

        plan, goal = self.plan, self.robot.goal
        plan_end = (
            float(np.linalg.norm(plan.p_m[-1] - goal.p_m)),
            float(np.linalg.norm(so3_log(plan.R[-1] @ goal.R.T))),
        )
        out: dict[str, object] = {
            "plan": {
                "status": plan.status.value,
                "iterations": plan.iterations,
                "final_error": plan.final_error,
                "planning_time_s": round(self.planning_time_s, 3),
                "message": plan.message,
                "streamed_duration_s": self.streamed.duration_s,
                "time_scale": self.streamed.scale,
                "leg_peaks": {
                    "velocity_m_s": self.streamed.peaks[0],
                    "acceleration_m_s2": self.streamed.peaks[1],
                    "jerk_m_s3": self.streamed.peaks[2],
                },
            },
            "plan_end_position_error_m": plan_end[0],
            "plan_end_angle_error_rad": plan_end[1],
            "goal_pose": {"position_m": goal.p_m.tolist(), "rotation_vector_rad": so3_log(goal.R).tolist()},
            "explanation": EXPLANATION,
        }
        ts = self._task_state
        if isinstance(ts, LegsTaskState) and (
            ts.request_id > 0 or not math.isnan(ts.measured_position_error_m)
        ):
            # the tracker's view (averaged samples) at the last measurement against the goal
            out["closed_loop"] = {
                "plans_from_measured_pose": ts.request_id,
                "corrections": ts.corrections,
                "measured_position_error_m": ts.measured_position_error_m,
                "measured_angle_error_rad": ts.measured_angle_error_rad,
                "note": "position_error_m and angle_error_rad are the odometry's, integrated with "
                "the model from the plan's start pose: they cannot see a model mismatch "
                "or an off start; these are the tracker's",
            }
        err = np.asarray(self.leg_errors_m)
        out["leg_tracking_error_m"] = {
            "rms": float(np.sqrt(np.mean(err**2))) if err.size else None,
            "max": float(err.max()) if err.size else None,
            "samples": int(err.size),
        }
        out["odometry_setpoint_samples"] = self.setpoint_samples
        if len(self._t) >= 2:
            reached = pose_odometry(
                self.robot.geometry, self.robot.start, np.array(self._t), np.array(self._legs)
            )
            pe, ae = pose_errors(reached, goal)
            out.update(
                {
                    "reached_pose": {
                        "position_m": reached.p_m.tolist(),
                        "rotation_vector_rad": so3_log(reached.R).tolist(),
                    },
                    "position_error_m": pe,
                    "angle_error_rad": ae,
                }
            )
        else:
            out.update({"reached_pose": None, "position_error_m": None, "angle_error_rad": None})
        return out


def build_planned_legs_task(
    section: NspuSection,
    limits: ActuatorUnits,
    settle_tolerance_m: float,
    robot: Robot,
    tracker: bool = False,
) -> tuple[PlannedLegsTask, PlanExecutionReport]:
    """Plan the configured motion (seed 004), time-scale it to ``section.limit_fraction`` of the
    actuators' limits and wrap it in a task with its report.

    Raises ``PlanningError`` (a RefusedError) naming the planner's status when the plan fails.
    """
    import time

    from controller.robots.nspu.model import NspuRobot
    from controller.robots.nspu.planning.nonholonomic import plan_motion

    if not isinstance(robot, NspuRobot):  # the registry pairs this task with the 3-nSPU only
        raise TypeError(f"the planned task needs the 3-nSPU robot model, got {type(robot).__name__}")
    t0 = time.perf_counter()
    plan = plan_motion(robot.geometry, robot.start, robot.goal, planner_config(section)).raise_for_status()
    planning_time = time.perf_counter() - t0
    streamed = time_scale_plan(
        plan,
        limits.max_velocity,
        limits.max_acceleration,
        limits.max_jerk,
        section.limit_fraction,
        section.stream_steps,
    )
    correction, planner = None, None
    if tracker:  # closed loop: measure with the tracker, replan from the measured pose (PlannedLegsTask)
        from controller.robots.nspu.plan_correction import CorrectionPlanner, CorrectionProblem

        correction = CorrectionSettings(
            section.correction_tolerance_m,
            section.correction_tolerance_rad,
            section.max_corrections,
            section.tracker_samples,
            section.settle_s,
            section.tracker_timeout_s,
            section.correction_plan_timeout_s,
            in_step=section.correction_planning == "in_step",
        )
        planner = CorrectionPlanner(
            CorrectionProblem(
                robot.geometry,
                robot.goal,
                planner_config(section),
                (limits.max_velocity, limits.max_acceleration, limits.max_jerk),
                section.limit_fraction,
                section.stream_steps,
            )
        )
    task = PlannedLegsTask(
        streamed,
        start_tolerance_m=max(settle_tolerance_m, 1e-5),
        robot=robot,
        correction=correction,
        planner=planner,
        goal=robot.goal,
    )
    return task, PlanExecutionReport(robot, plan, streamed, planning_time)


def planner_config(n: NspuSection, check_type2: bool | None = None) -> PlannerConfig:
    from controller.robots.nspu.planning.nonholonomic import PlannerConfig

    return PlannerConfig(
        horizon_s=n.horizon_s,
        harmonics=n.harmonics,
        tolerance=n.tolerance,
        max_iterations=n.max_iterations,
        n_steps=n.n_steps,
        plan_steps=min(PlannerConfig.plan_steps, n.n_steps),  # the iteration's steps: at most n_steps
        check_type2=n.check_type2 if check_type2 is None else check_type2,
        restarts=n.restarts,
    )


def _lengths_text(lengths_m: Sequence[float]) -> str:
    """Leg lengths for a message, to the micrometre: [0.388734, 0.390042, 0.395033] (a list of numpy
    floats prints as [np.float64(0.388734), ...] with numpy 2)."""
    return "[" + ", ".join(f"{float(x):.6f}" for x in lengths_m) + "]"
