"""Hybrid force/velocity tracking of an unknown contour (seed 001 §7, task frame after De Schutter).

The tool keeps contact with the rim of an object lying in a plane z = const and travels
along it. Every cycle, in the task frame {n, t, z}:

- n, the outward contour normal, follows the direction of the measured contact force in the
  XY plane (the contact pushes the tool out of the object). The force is low-pass filtered
  (``force_filter_hz``), and a second-order tracker of the normal's angle
  (``track_normal``, ``normal_tracker_hz``) smooths its direction: the direction's noise,
  times the tangential speed, would be a velocity into the contour. The normal is only
  updated while the in-plane force exceeds ``normal_min_force_n``: below it the direction of
  a small, noisy force means nothing.
- t = z x n is the tangent (counter-clockwise seen from +Z, or the opposite with
  ``direction = -1``): the tool moves along t at the lap's speed, with the speed changes
  limited to ``tangential_acceleration_m_s2``.
- along -n a PI loop on the normal-force error e = F_d - F_n sets an admittance velocity
  v_n = kp e + ki integral(e): the robot is position controlled, so force is controlled
  through the commanded motion (indirect force control);
- along z the commanded height is held.

The commanded TCP p_cmd integrates v = v_t t - v_n n each cycle; its inverse kinematics
and J v are the joint reference. It is marked reactive: recomputed from measurements every
cycle, it is smoothed through Ruckig's velocity interface (``RuckigSmoother.track_velocity``),
because streamed into the position interface a lagging setpoint chasing an accelerating
target makes the time-optimal profile change family from one cycle to the next, and the
setpoints stall and reverse (found in simulation at 35 mm/s).

Friction on the contact tilts the measured force away from the normal by atan(mu): with the
tool moving along t, F = F_n (n - mu t). With an estimate of the friction coefficient for
the material pair (``friction_estimate``), n is the direction of F + mu |F| / sqrt(1 + mu^2) t,
t taken from the previous cycle (its error enters only through the small friction term).
Removing the force component along t instead would leave a vector parallel to the previous
normal: the estimate could never turn.

Phases: MOVE_TO_START (to a point ``approach_clearance_m`` outside the expected contour),
TARE (average the sensor's offset with no contact), APPROACH (guarded move towards the
expected centre until the force passes ``contact_force_n``; fault after
``max_approach_distance_m``), TRACKING (laps counted by the angle swept around the centre
estimate, a least-squares circle fit of the contact points), RETRACT (along n), FINISHED.
Over ``max_force_n`` the tool retracts and the task faults. A contact lost for
``contact_lost_cycles`` cycles is counted and, as configured, re-approached along the last
normal or ends the task.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from enum import IntEnum
from typing import Protocol

import numpy as np

from controller.core.cycle_data import Command, Event, Severity
from controller.core.linalg3 import solve3
from controller.tasks.task import JointReference, TaskContext, TaskStep


class Kinematics(Protocol):
    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray: ...

    def joint_motion(self, tcp_m: tuple[float, float, float], velocity_m_s: tuple[float, float, float]
                     ) -> tuple[tuple[float, ...], tuple[float, ...]]: ...


class ContourPhase(IntEnum):
    MOVE_TO_START = 0
    TARE = 1
    APPROACH = 2
    TRACKING = 3
    RETRACT = 4
    FINISHED = 5


@dataclass(frozen=True)
class ContourParams:
    expected_centre_m: tuple[float, float]
    height_m: float
    expected_radius_m: float
    approach_direction_rad: float  # the side the tool comes from, seen from the expected centre
    approach_clearance_m: float
    approach_speed_m_s: float
    max_approach_distance_m: float  # beyond the expected contour
    contact_force_n: float
    force_setpoint_n: float
    lap_speeds_m_s: tuple[float, ...]
    tangential_acceleration_m_s2: float
    force_kp_m_s_per_n: float
    force_ki_m_s2_per_n: float
    max_normal_speed_m_s: float
    force_filter_hz: float
    normal_min_force_n: float
    max_force_n: float
    contact_lost_force_n: float
    contact_lost_cycles: int
    reapproach_on_contact_loss: bool
    retract_distance_m: float
    retract_speed_m_s: float
    tare_s: float
    settle_tolerance_m: float
    friction_estimate: float = 0.0
    direction: int = 1
    normal_tracker_hz: float = 1.5


@dataclass(frozen=True, slots=True)
class ContourState:
    phase: ContourPhase = ContourPhase.MOVE_TO_START
    p_cmd: tuple[float, float, float] = (0.0, 0.0, 0.0)
    speed_m_s: float = 0.0  # tangential speed command
    normal: tuple[float, float] = (1.0, 0.0)  # outward contour normal estimate (XY)
    normal_rate_rad_s: float = 0.0  # how fast the normal turns (the tracker's second state)
    force_f: tuple[float, float, float] = (0.0, 0.0, 0.0)  # filtered, offset removed [N]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor offset found by the tare [N]
    tare_sum: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # sum fx, fy, fz, count
    phase_start_s: float = 0.0
    travel_m: float = 0.0  # distance moved in the current approach or retract
    integral: float = 0.0  # of the normal-force error [N s]
    normal_force_n: float = 0.0
    force_error_n: float = 0.0
    swept_rad: float = 0.0
    last_angle: float | None = None
    lap: int = 0  # index of the lap in progress (0-based)
    fit: tuple[float, ...] = (0.0,) * 9  # sums for the circle fit
    centre: tuple[float, float] = (0.0, 0.0)
    low_force_cycles: int = 0
    contact_losses: tuple[int, ...] = ()
    fault: str = ""
    force_setpoint_n: float = 0.0
    qd_ref: tuple[float, ...] = ()  # joint velocity of the last reference, for its acceleration


def _unit2(x: float, y: float) -> tuple[float, float] | None:
    n = math.hypot(x, y)
    return (x / n, y / n) if n > 1e-12 else None


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def track_normal(angle_rad: float, rate_rad_s: float, measured_rad: float, dt: float, natural_hz: float
                 ) -> tuple[float, float]:
    """One step of a second-order (type-2) tracker of the normal's angle: (angle, turn rate).

    theta' = omega + 2 zeta w_n (theta_m - theta), omega' = w_n^2 (theta_m - theta), zeta = 1/sqrt(2):
    it follows a normal turning at a constant rate (a circle at constant speed, v / R) without lag,
    and passes the force direction's noise only up to about ``natural_hz``.
    """
    wn = 2.0 * math.pi * natural_hz
    predicted = angle_rad + rate_rad_s * dt
    innovation = _wrap(measured_rad - predicted)
    return _wrap(predicted + math.sqrt(2.0) * wn * dt * innovation), rate_rad_s + wn * wn * dt * innovation


def _fit_add(fit: tuple[float, ...], x: float, y: float) -> tuple[float, ...]:
    """Sums of the Kasa least-squares circle fit: x^2 + y^2 + D x + E y + F = 0."""
    r2 = x * x + y * y
    n, sx, sy, sxx, syy, sxy, sr2, sxr2, syr2 = fit
    return (n + 1, sx + x, sy + y, sxx + x * x, syy + y * y, sxy + x * y, sr2 + r2, sxr2 + x * r2, syr2 + y * r2)


def _fit_centre(fit: tuple[float, ...]) -> tuple[float, float] | None:
    n, sx, sy, sxx, syy, sxy, sr2, sxr2, syr2 = fit
    if n < 10:
        return None
    a = ((sxx, sxy, sx), (sxy, syy, sy), (sx, sy, n))
    if abs(sxx * (syy * n - sy * sy) - sxy * (sxy * n - sy * sx) + sx * (sxy * sy - syy * sx)) < 1e-18:
        return None
    d, e, _ = solve3(a, (-sxr2, -syr2, -sr2))
    return (-d / 2.0, -e / 2.0)


class ContourTrackingTask:
    name = "contour"

    def __init__(self, robot: Kinematics, params: ContourParams) -> None:
        self.robot = robot
        self.p = params
        u = (math.cos(params.approach_direction_rad), math.sin(params.approach_direction_rad))
        c = params.expected_centre_m
        r = params.expected_radius_m + params.approach_clearance_m
        self.start_m = (c[0] + r * u[0], c[1] + r * u[1], params.height_m)
        self._start_q = tuple(robot.inverse_kinematics(np.array(self.start_m)).tolist())

    @property
    def laps(self) -> int:
        return len(self.p.lap_speeds_m_s)

    def start(self) -> ContourState:
        u = (math.cos(self.p.approach_direction_rad), math.sin(self.p.approach_direction_rad))
        return ContourState(p_cmd=self.start_m, normal=u, centre=self.p.expected_centre_m,
                            contact_losses=(0,) * self.laps, force_setpoint_n=self.p.force_setpoint_n)

    def phase_name(self, state: ContourState) -> str:
        return state.phase.name

    # -- helpers ------------------------------------------------------------------------------

    def _reference(self, s: ContourState, v: tuple[float, float, float], on_path: bool, dt: float
                   ) -> tuple[ContourState, JointReference]:
        q, qd = self.robot.joint_motion(s.p_cmd, v)
        qdd = tuple((a - b) / dt for a, b in zip(qd, s.qd_ref)) if s.qd_ref else (0.0,) * len(qd)
        return replace(s, qd_ref=qd), JointReference(q, qd, qdd, s.p_cmd, on_path, reactive=True)

    def _filter_force(self, s: ContourState, ctx: TaskContext) -> ContourState:
        sensor = ctx.inputs.sensor
        if sensor is None or not sensor.fresh:
            return s
        a = 1.0 - math.exp(-2.0 * math.pi * self.p.force_filter_hz * ctx.period_s)
        f = tuple(fp + a * (fm - o - fp) for fp, fm, o in zip(s.force_f, sensor.force_n, s.offset))
        return replace(s, force_f=f)  # type: ignore[arg-type]

    def _move(self, s: ContourState, v: tuple[float, float, float], dt: float) -> tuple[float, float, float]:
        return (s.p_cmd[0] + v[0] * dt, s.p_cmd[1] + v[1] * dt, s.p_cmd[2] + v[2] * dt)

    # -- the step -------------------------------------------------------------------------------

    def step(self, state: ContourState, ctx: TaskContext) -> TaskStep:
        s = self._filter_force(state, ctx)
        if ctx.inputs.command == Command.SET_FORCE and ctx.inputs.command_value > 0:
            s = replace(s, force_setpoint_n=ctx.inputs.command_value)
        handler = {
            ContourPhase.MOVE_TO_START: self._move_to_start, ContourPhase.TARE: self._tare,
            ContourPhase.APPROACH: self._approach, ContourPhase.TRACKING: self._tracking,
            ContourPhase.RETRACT: self._retract, ContourPhase.FINISHED: self._finished,
        }[s.phase]
        return handler(s, ctx)

    def _move_to_start(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        tol = self.p.settle_tolerance_m
        sp = ctx.setpoint
        settled = all(abs(a - b) <= tol for a, b in zip(sp.position, self._start_q)) and \
            all(abs(v) <= tol for v in sp.velocity)
        ref = JointReference(self._start_q, (0.0,) * 3, (0.0,) * 3, self.start_m, False)
        if settled:
            s = replace(s, phase=ContourPhase.TARE, phase_start_s=ctx.t_s)
        return TaskStep(s, ref)

    def _tare(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        sensor = ctx.inputs.sensor
        if sensor is not None and sensor.fresh:
            fx, fy, fz, n = s.tare_sum
            s = replace(s, tare_sum=(fx + sensor.force_n[0], fy + sensor.force_n[1], fz + sensor.force_n[2], n + 1))
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        if ctx.t_s - s.phase_start_s < self.p.tare_s:
            return TaskStep(s, ref)
        fx, fy, fz, n = s.tare_sum
        if n == 0:
            return TaskStep(s, ref, fault="no force-sensor samples during the tare")
        offset = (fx / n, fy / n, fz / n)
        event = Event("contour", Severity.INFO, f"sensor offset {tuple(round(o, 3) for o in offset)} N; approaching")
        s = replace(s, phase=ContourPhase.APPROACH, offset=offset, force_f=(0.0, 0.0, 0.0), phase_start_s=ctx.t_s,
                    travel_m=0.0)
        return TaskStep(s, ref, events=(event,))

    def _approach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        p = self.p
        f_xy = math.hypot(s.force_f[0], s.force_f[1])
        if f_xy >= p.contact_force_n:
            n = _unit2(s.force_f[0], s.force_f[1]) or s.normal
            event = Event("contact", Severity.INFO, f"contact at {f_xy:.2f} N after {s.travel_m * 1000:.1f} mm")
            s = replace(s, phase=ContourPhase.TRACKING, normal=n, normal_rate_rad_s=0.0, integral=0.0,
                        low_force_cycles=0, phase_start_s=ctx.t_s)
            return self._tracking(s, ctx, (event,))
        limit = p.approach_clearance_m + p.max_approach_distance_m
        if s.travel_m > limit:
            why = f"no contact within {limit * 1000:.0f} mm of approach (force {f_xy:.2f} N < {p.contact_force_n} N)"
            s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
            return TaskStep(s, ref, fault=why)
        v = (-s.normal[0] * p.approach_speed_m_s, -s.normal[1] * p.approach_speed_m_s, 0.0)
        s = replace(s, p_cmd=self._move(s, v, ctx.period_s), travel_m=s.travel_m + p.approach_speed_m_s * ctx.period_s)
        s, ref = self._reference(s, v, False, ctx.period_s)
        return TaskStep(s, ref)

    def _tracking(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p = self.p
        dt = ctx.period_s
        fx, fy = s.force_f[0], s.force_f[1]
        f_xy = math.hypot(fx, fy)
        normal, rate = s.normal, s.normal_rate_rad_s
        if f_xy >= p.normal_min_force_n:
            angle = math.atan2(normal[1], normal[0])
            if fresh_sample(ctx):
                mu = p.friction_estimate if s.speed_m_s > 0.0 else 0.0
                t_prev = (-normal[1] * p.direction, normal[0] * p.direction)
                k = mu * f_xy / math.sqrt(1.0 + mu * mu)  # friction force magnitude mu F_n
                measured = math.atan2(fy + k * t_prev[1], fx + k * t_prev[0])
            else:  # a repeated sample is no new direction: the tracker only predicts
                measured = angle + rate * dt
            normal_angle, rate = track_normal(angle, rate, measured, dt, p.normal_tracker_hz)
            normal = (math.cos(normal_angle), math.sin(normal_angle))
        fn = fx * normal[0] + fy * normal[1]  # normal force pressing the tool out of the object
        if fn > p.max_force_n:
            why = f"contact force {fn:.1f} N above the limit of {p.max_force_n} N"
            ev = Event("over_force", Severity.FAULT, why + "; retracting")
            s = replace(s, phase=ContourPhase.RETRACT, fault=why, travel_m=0.0, normal=normal, normal_force_n=fn)
            return self._retract(s, ctx, events + (ev,))
        low = s.low_force_cycles + (1 if fresh_sample(ctx) else 0) if fn < p.contact_lost_force_n else 0
        if low >= p.contact_lost_cycles:
            losses = list(s.contact_losses)
            losses[min(s.lap, len(losses) - 1)] += 1
            s = replace(s, contact_losses=tuple(losses), low_force_cycles=0)
            if p.reapproach_on_contact_loss:
                ev = Event("contact_lost", Severity.WARNING, f"contact lost in lap {s.lap + 1}; re-approaching")
                s = replace(s, phase=ContourPhase.APPROACH, travel_m=p.approach_clearance_m, normal=normal,
                            speed_m_s=0.0)
                s, ref = self._reference(s, (0.0, 0.0, 0.0), False, dt)
                return TaskStep(s, ref, events=events + (ev,))
            ev = Event("contact_lost", Severity.WARNING, f"contact lost in lap {s.lap + 1}; stopping")
            s = replace(s, phase=ContourPhase.RETRACT, travel_m=0.0, normal=normal)
            return self._retract(s, ctx, events + (ev,))
        # PI admittance along the normal: positive error -> push further in (along -n). A cycle
        # without a new force sample (``sensor.fresh`` false: a late or lost frame) uses the last
        # filtered force but adds nothing to the integral: the same error integrated twice
        # would be a force spike made by the bus, not by the contact.
        err = s.force_setpoint_n - fn
        integral = s.integral + err * dt if fresh_sample(ctx) else s.integral
        vn = p.force_kp_m_s_per_n * err + p.force_ki_m_s2_per_n * integral
        if abs(vn) > p.max_normal_speed_m_s:  # clamp and stop integrating (anti-windup)
            vn = math.copysign(p.max_normal_speed_m_s, vn)
            integral = s.integral
        target_speed = p.lap_speeds_m_s[min(s.lap, len(p.lap_speeds_m_s) - 1)]
        dv = p.tangential_acceleration_m_s2 * dt
        speed = min(max(target_speed, s.speed_m_s - dv), s.speed_m_s + dv)
        t = (-normal[1] * p.direction, normal[0] * p.direction)
        v = (speed * t[0] - vn * normal[0], speed * t[1] - vn * normal[1], 0.0)  # z held at height_m
        # lap counting around the centre estimate from the measured contact points
        tcp = ctx.tcp_measured_m or s.p_cmd
        fit = _fit_add(s.fit, tcp[0], tcp[1])
        centre = s.centre
        if abs(s.swept_rad) > math.radians(60):
            centre = _fit_centre(fit) or centre
        angle = math.atan2(tcp[1] - centre[1], tcp[0] - centre[0])
        swept = s.swept_rad + (_wrap(angle - s.last_angle) if s.last_angle is not None else 0.0)
        lap = int(abs(swept) // (2.0 * math.pi))
        ev_list = list(events)
        if lap > s.lap:
            ev_list.append(Event("lap", Severity.INFO, f"lap {s.lap + 1} of {self.laps} done"))
        s = replace(s, p_cmd=self._move(s, v, dt), speed_m_s=speed, normal=normal, normal_rate_rad_s=rate,
                    integral=integral, normal_force_n=fn, force_error_n=err, swept_rad=swept, last_angle=angle,
                    lap=lap, fit=fit, centre=centre, low_force_cycles=low)
        if lap >= self.laps:
            ev_list.append(Event("contour", Severity.INFO, "all laps done; retracting"))
            s = replace(s, phase=ContourPhase.RETRACT, travel_m=0.0)
            return self._retract(s, ctx, tuple(ev_list))
        s, ref = self._reference(s, v, True, dt)
        return TaskStep(s, ref, events=tuple(ev_list))

    def _retract(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p = self.p
        if s.travel_m >= p.retract_distance_m:
            s = replace(s, phase=ContourPhase.FINISHED)
            return self._finished(s, ctx, events)
        v = (s.normal[0] * p.retract_speed_m_s, s.normal[1] * p.retract_speed_m_s, 0.0)
        s = replace(s, p_cmd=self._move(s, v, ctx.period_s), travel_m=s.travel_m + p.retract_speed_m_s * ctx.period_s,
                    speed_m_s=0.0)
        s, ref = self._reference(s, v, False, ctx.period_s)
        return TaskStep(s, ref, events=events)

    def _finished(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        return TaskStep(s, ref, finished=True, fault=s.fault, events=events)


def fresh_sample(ctx: TaskContext) -> bool:
    """Whether this cycle brought a new force sample (else the task runs on the last good one)."""
    return ctx.inputs.sensor is not None and ctx.inputs.sensor.fresh
