"""Hybrid force/velocity tracking of an unknown contour (seed 001 §7, task frame after De Schutter).

The tool keeps contact with the rim of an object lying in a plane z = const and travels
along it. The object is any closed planar contour: the task knows only where it roughly is
(``expected_centre_m``, ``expected_radius_m`` along the approach direction). Every cycle, in
the task frame {n, t, z}:

- n, the outward contour normal, follows the direction of the measured contact force in the
  XY plane (the contact pushes the tool out of the object). The force is low-pass filtered
  (``force_filter_hz``), and a third-order tracker of the normal's angle
  (``track_normal``, ``normal_tracker_hz``) smooths its direction: the direction's noise,
  times the tangential speed, would be a velocity into the contour. The normal is only
  updated while the in-plane force exceeds ``normal_min_force_n``: below it the direction of
  a small, noisy force means nothing. A direction further than ``normal_gate_deg`` from the
  tracker's prediction is no measurement of the contour (a disturbance is pulling on the
  tool): the tracker only predicts.
- t = z x n is the tangent (counter-clockwise seen from +Z, or the opposite with
  ``direction = -1``): the tool moves along t at the lap's speed, with speed increases
  limited to ``tangential_acceleration_m_s2`` and decreases to ``stop_deceleration_m_s2``.
  Where the normal turns faster than ``max_normal_turn_rate_rad_s`` (a corner: the
  curvature is the turn rate over the speed) the speed is derated so that it does not.
- along -n a PI loop on the normal-force error e = F_d - F_n sets an admittance velocity
  v_n = kp e + ki integral(e): the robot is position controlled, so force is controlled
  through the commanded motion (indirect force control). The integral follows the tangential
  speed (``_integral_at_speed``): what it holds while sliding is a velocity into the contour
  proportional to the speed;
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

Off the happy path (DESIGN.md, "Off the happy path"), by design rather than by exception:

- **Never push past the limit.** Above ``saturation_force_n`` (a fraction of the safety
  layer's contact-force limit) in the filtered or the latest raw sample, the normal command
  only moves away from the contact, faster the nearer the limit (admittance saturation), and
  the integral is emptied. Over ``max_force_n`` the tool retracts and the task faults; the
  safety layer's limit stays the last line.
- **Implausible force.** A step between two samples larger than ``max_force_step_n`` (the
  sensor and the structure do not produce it while tracking: 1.8 N is the largest step measured
  on the disk, 7-8 N in the rounded star's concave valleys at 40 mm/s) makes the signal suspect:
  the sample is kept out of the filter, the normal and the integral, the tool does not move into
  the contact and the tangential motion brakes. The signal is trusted again when it steps back
  (a spike), or after ``implausible_hold_s`` at its new level (a real change: the filter
  restarts from it). Cycles without a fresh sample (late, lost or stale frames) are
  treated the same way after ``stale_hold_cycles``.
- **Contact loss** (normal force under ``contact_lost_force_n`` for ``contact_lost_cycles``
  fresh samples): CONTACT_LOST brakes the tangential motion; REAPPROACH moves along the last
  normal measured in good contact, at the approach speed, guarded by the contact force, at
  most ``reapproach_distance_m``; BACK_OFF returns to where that attempt started. After
  ``max_reacquire_attempts`` failed attempts the tool retracts and the task ends with a fault
  naming the cause. A re-acquired contact resumes tracking and lap counting where they stopped.

Laps are counted without knowing the shape: by the angle the tool sweeps about a point inside
the contour (the winding number of a closed curve about any inside point is one), the expected
centre during the first lap and the centroid of the traced first lap after it. Every phase
change is an event.

Phases: MOVE_TO_START (to a point ``approach_clearance_m`` outside the expected contour),
TARE (average the sensor's offset with no contact), APPROACH (guarded move towards the
expected centre until the force passes ``contact_force_n``; fault after
``max_approach_distance_m``), TRACKING, CONTACT_LOST, REAPPROACH, BACK_OFF, RETRACT (along n),
FINISHED.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Protocol

import numpy as np

from controller.core.cycle_data import Command, Event, Severity
from controller.core.ports import ForceSetpointLimit, JointReference, TaskContext, TaskStep
from controller.core.records import record, replace


class Kinematics(Protocol):
    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray: ...

    def joint_motion(
        self, tcp_m: tuple[float, float, float], velocity_m_s: tuple[float, float, float]
    ) -> tuple[tuple[float, ...], tuple[float, ...]]: ...


SETTLED_CONTACT_S = 0.25  # a contact this long near the setpoint and trusted gives the re-approach's normal
STIFFNESS_PROBE_N = 1.0  # a rise of the normal force this large shows a contact answering the motion
MOTION_WITNESS_SPEED_M_S = 0.02  # sliding faster than this, the measured motion witnesses the tangent
# A force direction is taken at most this far from the motion's normal: 15 let a force spike tilt the
# type-3 tracker into the task's retract, 5 ended a drifting bias in the safety fault (the contour scan).
MOTION_GATE_DEG = 10.0
CONSISTENCY_MAX_DEG = 8.0  # the measured motion's angle to the tangent for a contact normal to be trusted
CONSISTENCY_MIN_SPEED_M_S = 0.005  # slower motion says nothing about the tangent
RETARE_MAX_FRACTION = 0.5  # of the setpoint: a re-approach re-tares the sensor when it reads less than this
FORCE_BAND_FRACTION = 0.3  # of the force setpoint: a larger error derates the tangential speed ...
FORCE_STOP_FRACTION = 0.6  # ... down to zero at this one (the disk's laps stay within 0.17 at 60 mm/s)
UNSEEN_TURN_DECAY_S = 0.1  # without a direction measurement the normal's turn rate (and its change) fade with this time constant


class ContourPhase(IntEnum):
    MOVE_TO_START = 0
    TARE = 1
    APPROACH = 2
    TRACKING = 3
    RETRACT = 4
    FINISHED = 5
    CONTACT_LOST = 6
    REAPPROACH = 7
    BACK_OFF = 8


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
    saturation_force_n: float  # above: the normal command only moves away from the contact [N]
    friction_estimate: float = 0.0
    direction: int = 1
    normal_tracker_hz: float = 1.5
    normal_gate_deg: float = 60.0  # a force direction further from the prediction is no normal [deg]
    max_force_step_n: float = 10.0  # a larger step between two samples is implausible [N]
    implausible_hold_s: float = 0.5  # the longest a suspect signal is held off before its level is taken [s]
    stale_hold_cycles: int = 4  # cycles without a fresh sample before the law holds as for a suspect one
    stop_deceleration_m_s2: float = (
        2.0  # tangential braking (contact loss, suspect signal, corners, force band)
    )
    reapproach_distance_m: float = 0.008  # guarded travel along the last normal per attempt
    max_reacquire_attempts: int = 3
    max_normal_turn_rate_rad_s: float = 2.0  # corners: the speed is derated to keep the normal's turn rate
    min_tangential_speed_m_s: float = 0.005  # the derating's floor; slower, the integral acts in proportion
    max_push_without_force_m: float = 0.003  # into the contact without the force rising: no contact there
    creep_speed_m_s: float = (
        0.01  # after a re-acquisition, for creep_distance_m: the contour is irregular there
    )
    creep_distance_m: float = 0.025


@record
class ContourState:
    phase: ContourPhase = ContourPhase.MOVE_TO_START
    p_cmd: tuple[float, float, float] = (0.0, 0.0, 0.0)
    speed_m_s: float = 0.0  # tangential speed command
    normal: tuple[float, float] = (1.0, 0.0)  # outward contour normal estimate (XY)
    normal_rate_rad_s: float = 0.0  # how fast the normal turns (the tracker's second state)
    normal_accel_rad_s2: float = 0.0  # how fast that rate changes (its third: the curvature changes)
    contact_normal: tuple[float, float] = (1.0, 0.0)  # the normal when the contact was last good
    contact_point: tuple[float, float] | None = None  # the measured TCP then: a re-approach aims behind it
    force_f: tuple[float, float, float] = (0.0, 0.0, 0.0)  # filtered, offset removed [N]
    raw_force: tuple[float, float, float] | None = None  # the last sample, offset removed [N]
    held_force: tuple[float, float, float] | None = None  # the last sample before an implausible step [N]
    held_step: tuple[float, float] = (0.0, 0.0)  # that step in XY [N]: the same step back ends the suspicion
    suspect_cycles: int = 0  # cycles since that step
    settled_cycles: int = 0  # cycles of trusted force in a row: the contact normal is taken only when settled
    stale_cycles: int = 0  # cycles in a row without a fresh sample
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor offset found by the tare [N]
    tare_sum: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # sum fx, fy, fz, count
    phase_start_s: float = 0.0
    travel_m: float = 0.0  # distance moved in the current approach, re-approach, back-off or retract
    integral: float = 0.0  # of the normal-force error [N s]
    normal_force_n: float = 0.0
    force_error_n: float = 0.0
    swept_rad: float = 0.0
    last_angle: float | None = None
    lap: int = 0  # index of the lap in progress (0-based)
    centre: tuple[float, float] = (0.0, 0.0)  # the point laps are counted about (inside the contour)
    path_sums: tuple[float, float, float] = (0.0, 0.0, 0.0)  # first lap: sum x ds, sum y ds, sum ds
    last_xy: tuple[float, float] | None = None  # measured TCP at the last tracking cycle
    arc_m: float = 0.0  # tracked arc length
    low_force_cycles: int = 0
    pushed_m: float = 0.0  # motion commanded into the contact since the force last rose
    push_ref_n: float = 0.0  # the lowest normal force since then
    creep_m: float = 0.0  # distance still to go at creep speed after a re-acquisition
    contact_losses: tuple[int, ...] = ()
    attempts: int = 0  # failed re-acquisitions of the current loss
    reapproach_direction: tuple[float, float] = (0.0, 0.0)  # unit, of the current re-approach
    reapproach_m: float = 0.0  # its length: to the aim behind the last contact point
    fault: str = ""
    force_setpoint_n: float = 0.0
    qd_ref: tuple[float, ...] = ()  # joint velocity of the last reference, for its acceleration


def _unit2(x: float, y: float) -> tuple[float, float] | None:
    n = math.hypot(x, y)
    return (x / n, y / n) if n > 1e-12 else None


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def predict_normal(angle_rad: float, rate_rad_s: float, accel_rad_s2: float, dt: float) -> float:
    """The tracker's angle one cycle on, before this cycle's measurement."""
    return angle_rad + rate_rad_s * dt + 0.5 * accel_rad_s2 * dt * dt


def track_normal(
    angle_rad: float,
    rate_rad_s: float,
    accel_rad_s2: float,
    measured_rad: float,
    dt: float,
    natural_hz: float,
) -> tuple[float, float, float]:
    """One step of a third-order (type-3) tracker of the normal's angle: (angle, turn rate, turn acceleration).

    With e = theta_m - theta: theta' = omega + 2 w e, omega' = alpha + 2 w^2 e, alpha' = w^3 e, whose
    error polynomial s^3 + 2 w s^2 + 2 w^2 s + w^3 = (s + w)(s^2 + w s + w^2) is a Butterworth's.
    The normal turns at rate = curvature x speed. On a circle the rate is constant; where the
    curvature changes (a rounded star's lobe into its valley: from +1/23 to -1/38 mm^-1 within a few
    cm) the rate ramps, and a type-2 tracker (angle, rate) lags a ramp by alpha / w^2: 3.6 degrees
    at 1.5 Hz and 40 mm/s on the star, enough for 1.03 N of force error RMS (2.5 Hz met the star but
    followed a force spike into the workpiece). The third state follows the ramp without lag at the
    same bandwidth; the force direction's noise passes up to about ``natural_hz``.
    """
    wn = 2.0 * math.pi * natural_hz
    predicted = predict_normal(angle_rad, rate_rad_s, accel_rad_s2, dt)
    innovation = _wrap(measured_rad - predicted)
    return (
        _wrap(predicted + 2.0 * wn * dt * innovation),
        rate_rad_s + accel_rad_s2 * dt + 2.0 * wn * wn * dt * innovation,
        accel_rad_s2 + wn * wn * wn * dt * innovation,
    )


def fresh_sample(ctx: TaskContext) -> bool:
    """Whether this cycle brought a new force sample (else the task runs on the last good one)."""
    return ctx.inputs.sensor is not None and ctx.inputs.sensor.fresh


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
        return ContourState(
            p_cmd=self.start_m,
            normal=u,
            contact_normal=u,
            centre=self.p.expected_centre_m,
            contact_losses=(0,) * self.laps,
            force_setpoint_n=self.p.force_setpoint_n,
        )

    def force_setpoint_limit(self) -> ForceSetpointLimit:
        """Below the admittance saturation (above it the law only moves away from the contact: the
        force cannot be held there) and below the task's own limit (``max_force_n``: it faults there)."""
        p = self.p
        if p.saturation_force_n < p.max_force_n:
            return ForceSetpointLimit(
                p.saturation_force_n,
                f"the task's admittance saturation ({p.saturation_force_n:g} N = "
                "task.contour.admittance_saturation_fraction x safety.max_contact_force_n; its limit "
                f"task.contour.max_force_n = {p.max_force_n:g} N)",
            )
        return ForceSetpointLimit(
            p.max_force_n, f"the task's limit task.contour.max_force_n = {p.max_force_n:g} N"
        )

    def phase_name(self, state: ContourState) -> str:
        return state.phase.name

    # -- helpers ------------------------------------------------------------------------------

    def _reference(
        self, s: ContourState, v: tuple[float, float, float], on_path: bool, dt: float
    ) -> tuple[ContourState, JointReference]:
        q, qd = self.robot.joint_motion(s.p_cmd, v)
        qdd = tuple((a - b) / dt for a, b in zip(qd, s.qd_ref, strict=True)) if s.qd_ref else (0.0,) * len(qd)
        return replace(s, qd_ref=qd), JointReference(q, qd, qdd, s.p_cmd, on_path, reactive=True)

    def _moving(
        self,
        s: ContourState,
        v: tuple[float, float, float],
        dt: float,
        on_path: bool = False,
        events: tuple[Event, ...] = (),
        travel_m: float = 0.0,
    ) -> TaskStep:
        """Move the commanded TCP by v dt (travel adds to the phase's distance) and make the reference."""
        s = replace(
            s,
            p_cmd=(s.p_cmd[0] + v[0] * dt, s.p_cmd[1] + v[1] * dt, s.p_cmd[2] + v[2] * dt),
            travel_m=s.travel_m + travel_m,
        )
        s, ref = self._reference(s, v, on_path, dt)
        return TaskStep(s, ref, events=events)

    def _enter(self, s: ContourState, phase: ContourPhase, t_s: float, **fields: object) -> ContourState:
        return replace(s, phase=phase, phase_start_s=t_s, travel_m=0.0, **fields)

    def _filter_force(self, s: ContourState, ctx: TaskContext) -> tuple[ContourState, tuple[Event, ...]]:
        """The sample into the filter, unless it is a step the sensor and structure cannot make.

        After such a step the signal is suspect: samples stay out of the filter until it returns to
        within ``max_force_step_n`` of the level before the step (a spike), or until it has held
        the new level for ``implausible_hold_s`` (a real change: the filter restarts from it).
        Before the tare there is no offset yet, and the tare averages raw samples itself.
        """
        sensor = ctx.inputs.sensor
        if sensor is None or not sensor.fresh:
            return replace(s, stale_cycles=s.stale_cycles + 1), ()
        raw = (
            sensor.force_n[0] - s.offset[0],
            sensor.force_n[1] - s.offset[1],
            sensor.force_n[2] - s.offset[2],
        )
        last, s = s.raw_force, replace(s, stale_cycles=0, raw_force=raw)
        if s.phase in (ContourPhase.MOVE_TO_START, ContourPhase.TARE) or last is None:
            return s, ()
        p = self.p
        if s.held_force is not None:  # suspect: has the signal come back, or held its new level long enough?
            held, jump = s.held_force, s.held_step
            elapsed_s = (s.suspect_cycles + 1) * ctx.period_s
            tolerance = (
                0.5 * p.max_force_step_n
            )  # tighter than the step: a swing of the structure is no return
            back = math.hypot(raw[0] - last[0] + jump[0], raw[1] - last[1] + jump[1]) <= tolerance
            if back or math.hypot(raw[0] - held[0], raw[1] - held[1]) <= tolerance:
                return self._filtered(replace(s, held_force=None, suspect_cycles=0), raw, ctx), (
                    Event(
                        "force_plausible",
                        Severity.INFO,
                        f"force back at its level after {elapsed_s * 1000:.0f} ms; tracking on",
                    ),
                )
            if elapsed_s >= p.implausible_hold_s:
                return replace(s, held_force=None, suspect_cycles=0, force_f=raw), (
                    Event(
                        "force_plausible",
                        Severity.WARNING,
                        f"force held a new level for {elapsed_s * 1000:.0f} ms: taken as real",
                    ),
                )
            return replace(s, suspect_cycles=s.suspect_cycles + 1), ()
        step = math.hypot(raw[0] - last[0], raw[1] - last[1])
        if step > p.max_force_step_n:
            return replace(
                s, held_force=last, held_step=(raw[0] - last[0], raw[1] - last[1]), suspect_cycles=0
            ), (
                Event(
                    "force_implausible",
                    Severity.WARNING,
                    f"force step of {step:.1f} N in one sample (> {p.max_force_step_n} N): held off, "
                    f"no motion into the contact, tangential motion braking",
                ),
            )
        return self._filtered(s, raw, ctx), ()

    def _filtered(self, s: ContourState, raw: tuple[float, float, float], ctx: TaskContext) -> ContourState:
        a = 1.0 - math.exp(-2.0 * math.pi * self.p.force_filter_hz * ctx.period_s)
        f = s.force_f
        return replace(
            s, force_f=(f[0] + a * (raw[0] - f[0]), f[1] + a * (raw[1] - f[1]), f[2] + a * (raw[2] - f[2]))
        )

    def _trusted(self, s: ContourState) -> bool:
        """Whether this cycle's force may steer the law: no implausible step held, no run of stale cycles."""
        return s.held_force is None and s.stale_cycles < self.p.stale_hold_cycles

    def _pressing_n(self, s: ContourState, normal: tuple[float, float]) -> float:
        """The contact force along the normal that saturation judges: the larger of filtered and raw."""
        filtered = s.force_f[0] * normal[0] + s.force_f[1] * normal[1]
        raw = s.raw_force[0] * normal[0] + s.raw_force[1] * normal[1] if s.raw_force is not None else filtered
        return max(filtered, raw)

    def _saturated_retreat(self, pressing_n: float) -> float | None:
        """Admittance saturation: the speed away from the contact [m/s] above ``saturation_force_n``, else None."""
        p = self.p
        if pressing_n <= p.saturation_force_n:
            return None
        span = max(p.max_force_n - p.saturation_force_n, 1e-9)
        return p.max_normal_speed_m_s * min(1.0, 0.25 + (pressing_n - p.saturation_force_n) / span)

    @staticmethod
    def _moves_along_tangent(
        s: ContourState, normal: tuple[float, float], tcp: tuple[float, float, float], dt: float
    ) -> bool:
        """The measured TCP moved (faster than CONSISTENCY_MIN_SPEED) within CONSISTENCY_MAX_DEG of the tangent."""
        if s.last_xy is None:
            return False
        dx, dy = tcp[0] - s.last_xy[0], tcp[1] - s.last_xy[1]
        step = math.hypot(dx, dy)
        if step < CONSISTENCY_MIN_SPEED_M_S * dt:
            return False
        return abs(dx * normal[0] + dy * normal[1]) <= step * math.sin(math.radians(CONSISTENCY_MAX_DEG))

    @staticmethod
    def _in_band(s: ContourState, force_error_n: float) -> float:
        """1 with the force error within its band, falling linearly to 0 at the stop fraction."""
        band, stop = FORCE_BAND_FRACTION * s.force_setpoint_n, FORCE_STOP_FRACTION * s.force_setpoint_n
        return min(1.0, max(0.0, (stop - abs(force_error_n)) / (stop - band)))

    def _integral_at_speed(self, s: ContourState, speed_m_s: float) -> tuple[ContourState, float]:
        """The integral scaled with the tangential speed, and the share of it that acts at this speed.

        What the integral holds while sliding is a velocity into the contour proportional to the
        speed: the normal estimate is tilted by the friction the estimate gets wrong (0.15 in the
        simulator against an estimate of 0.1) and the tangent leaves the contour by that angle.
        Measured over the bus: ki x integral 1.1, 2.4, 3.9 mm/s at 20, 40, 60 mm/s. Kept while the
        tool brakes (2 m/s^2: 60 mm/s to rest in 30 ms, faster than the integral unwinds), it
        drove a stopped tool into the disk: 10 -> 24 N within 20 cycles; scaled down only, the
        tool pressed 2 N too little for the 0.4 s it took to speed up again. So it follows the
        speed both ways down to ``min_tangential_speed_m_s``; slower, it is kept for when the tool
        slides again and acts only in proportion (a tool at rest has no tilt to make up for).
        """
        floor = self.p.min_tangential_speed_m_s
        ratio = max(speed_m_s, floor) / max(s.speed_m_s, floor)
        return replace(s, integral=s.integral * ratio), min(1.0, speed_m_s / floor)

    def _braked(self, speed: float, dt: float) -> float:
        return max(0.0, speed - self.p.stop_deceleration_m_s2 * dt)

    # -- the step -------------------------------------------------------------------------------

    def step(self, state: ContourState, ctx: TaskContext) -> TaskStep:
        s, signal_events = self._filter_force(state, ctx)
        if ctx.sensor_breach and s.phase not in (ContourPhase.RETRACT, ContourPhase.FINISHED):
            return self._sensor_breach(s, ctx)
        if (
            ctx.inputs.command == Command.SET_FORCE
            and 0.0 < ctx.inputs.command_value < self.force_setpoint_limit().below_n
        ):  # the command gate refuses the others already; the step takes no setpoint it cannot track
            s = replace(s, force_setpoint_n=ctx.inputs.command_value)
        handler = {
            ContourPhase.MOVE_TO_START: self._move_to_start,
            ContourPhase.TARE: self._tare,
            ContourPhase.APPROACH: self._approach,
            ContourPhase.TRACKING: self._tracking,
            ContourPhase.CONTACT_LOST: self._contact_lost,
            ContourPhase.REAPPROACH: self._reapproach,
            ContourPhase.BACK_OFF: self._back_off,
            ContourPhase.RETRACT: self._retract,
            ContourPhase.FINISHED: self._finished,
        }[s.phase]
        out = handler(s, ctx)
        return replace(out, events=signal_events + out.events) if signal_events else out

    def _move_to_start(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        tol = self.p.settle_tolerance_m
        sp = ctx.setpoint
        settled = all(abs(a - b) <= tol for a, b in zip(sp.position, self._start_q, strict=True)) and all(
            abs(v) <= tol for v in sp.velocity
        )
        ref = JointReference.at_rest(self._start_q, self.start_m)
        if settled:
            s = self._enter(s, ContourPhase.TARE, ctx.t_s)
        return TaskStep(s, ref)

    def _tare(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        sensor = ctx.inputs.sensor
        if sensor is not None and sensor.fresh:
            fx, fy, fz, n = s.tare_sum
            s = replace(
                s, tare_sum=(fx + sensor.force_n[0], fy + sensor.force_n[1], fz + sensor.force_n[2], n + 1)
            )
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        if ctx.t_s - s.phase_start_s < self.p.tare_s:
            return TaskStep(s, ref)
        fx, fy, fz, n = s.tare_sum
        if n == 0:
            return TaskStep(s, ref, fault="no force-sensor samples during the tare")
        offset = (fx / n, fy / n, fz / n)
        event = Event(
            "contour", Severity.INFO, f"sensor offset {tuple(round(o, 3) for o in offset)} N; approaching"
        )
        s = self._enter(
            s, ContourPhase.APPROACH, ctx.t_s, offset=offset, force_f=(0.0, 0.0, 0.0), raw_force=None
        )
        return TaskStep(s, ref, events=(event,))

    def _in_contact(self, s: ContourState, along: tuple[float, float]) -> float | None:
        """The contact force [N] when a guarded move towards -``along`` has met the contour, else None."""
        if not self._trusted(s):
            return None
        f_xy = math.hypot(s.force_f[0], s.force_f[1])
        return f_xy if f_xy >= self.p.contact_force_n else None

    def _approach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        p = self.p
        f_contact = self._in_contact(s, s.normal)
        if f_contact is not None:
            n = _unit2(s.force_f[0], s.force_f[1]) or s.normal
            event = Event(
                "contact", Severity.INFO, f"contact at {f_contact:.2f} N after {s.travel_m * 1000:.1f} mm"
            )
            s = self._enter(
                s,
                ContourPhase.TRACKING,
                ctx.t_s,
                normal=n,
                contact_normal=n,
                normal_rate_rad_s=0.0,
                normal_accel_rad_s2=0.0,
                integral=0.0,
                low_force_cycles=0,
            )
            return self._tracking(s, ctx, (event,))
        limit = p.approach_clearance_m + p.max_approach_distance_m
        if s.travel_m > limit:
            f_xy = math.hypot(s.force_f[0], s.force_f[1])
            why = f"no contact within {limit * 1000:.0f} mm of approach (force {f_xy:.2f} N < {p.contact_force_n} N)"
            s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
            return TaskStep(s, ref, fault=why)
        speed = p.approach_speed_m_s if self._trusted(s) else 0.0
        v = (-s.normal[0] * speed, -s.normal[1] * speed, 0.0)
        return self._moving(s, v, ctx.period_s, travel_m=speed * ctx.period_s)

    def _normal_update(
        self, s: ContourState, ctx: TaskContext, f_xy: float
    ) -> tuple[tuple[float, float], float, float]:
        """The normal estimate, its turn rate and the rate's change after this cycle's force (gated, see
        the module's text)."""
        p, dt = self.p, ctx.period_s
        normal, rate, accel = s.normal, s.normal_rate_rad_s, s.normal_accel_rad_s2
        angle = math.atan2(normal[1], normal[0])
        predicted = predict_normal(angle, rate, accel, dt)
        measured = predicted  # a repeated or suspect sample is no new direction: the tracker only predicts
        if not self._trusted(s):
            # The normal turns because the tool moves along a curved contour (rate = curvature x speed,
            # its change curvature' x speed^2): while the tool brakes on an untrusted force, it turns only
            # as far as the tool goes.
            speed = self._braked(s.speed_m_s, dt)
            ratio = speed / s.speed_m_s if s.speed_m_s > 0.0 else 0.0
            rate, accel = rate * ratio, accel * ratio * ratio
            angle = angle + rate * dt
            return (math.cos(angle), math.sin(angle)), rate, accel
        if fresh_sample(ctx):
            fx, fy = s.force_f[0], s.force_f[1]
            mu = p.friction_estimate if s.speed_m_s > 0.0 else 0.0
            t_prev = (-normal[1] * p.direction, normal[0] * p.direction)
            k = mu * f_xy / math.sqrt(1.0 + mu * mu)  # friction force magnitude mu F_n
            direction = math.atan2(fy + k * t_prev[1], fx + k * t_prev[0])
            witness = self._motion_normal(s, ctx)
            if witness is not None:  # at most MOTION_GATE_DEG from the normal the motion implies
                gate = math.radians(MOTION_GATE_DEG)
                direction = witness + min(max(_wrap(direction - witness), -gate), gate)
            if abs(_wrap(direction - predicted)) <= math.radians(p.normal_gate_deg):
                measured = direction
        if measured == predicted:  # no direction this cycle: the turn fades instead of running on unseen
            fade = math.exp(-dt / UNSEEN_TURN_DECAY_S)
            return (math.cos(predicted), math.sin(predicted)), rate * fade, accel * fade
        angle, rate, accel = track_normal(angle, rate, accel, measured, dt, p.normal_tracker_hz)
        return (math.cos(angle), math.sin(angle)), rate, accel

    def _motion_normal(self, s: ContourState, ctx: TaskContext) -> float | None:
        """The normal's angle the measured motion implies, sliding faster than MOTION_WITNESS_SPEED_M_S; else None.

        In contact the contour guides the tool: its measured motion runs along the true tangent
        (the law's own normal correction is a few mm/s against tens along the tangent). A force
        direction far from that normal is a disturbance pulling on the tool, not the contour.
        """
        tcp = ctx.tcp_measured_m
        if tcp is None or s.last_xy is None or s.speed_m_s < MOTION_WITNESS_SPEED_M_S:
            return None
        dx, dy = tcp[0] - s.last_xy[0], tcp[1] - s.last_xy[1]
        if math.hypot(dx, dy) < 0.5 * MOTION_WITNESS_SPEED_M_S * ctx.period_s:
            return None
        # t = z x n turned back: n = t x z, with the travel direction's sign
        return math.atan2(-dx * self.p.direction, dy * self.p.direction)

    def _tangential_speed(self, s: ContourState, rate_rad_s: float, force_error_n: float, dt: float) -> float:
        """The lap's speed, derated where the normal turns fast or the force leaves its band, braked
        while the force is not trusted.

        A force error beyond ``FORCE_BAND_FRACTION`` of the setpoint means the contour is not where
        the tool is going: the edge of a notch (the force fades) or the ramp of a bump (it climbs).
        The speed falls linearly to zero at ``FORCE_STOP_FRACTION``: the tool then goes down into the
        notch or backs off the ramp along the normal before it goes on, instead of meeting the
        notch's far wall or the bump's face at full speed.
        """
        p = self.p
        if not self._trusted(s):
            return self._braked(s.speed_m_s, dt)
        target = p.lap_speeds_m_s[min(s.lap, len(p.lap_speeds_m_s) - 1)]
        if s.creep_m > 0.0:
            target = min(target, p.creep_speed_m_s)
        raw_error_n = (
            force_error_n
            if s.raw_force is None
            else s.force_setpoint_n - (s.raw_force[0] * s.normal[0] + s.raw_force[1] * s.normal[1])
        )
        # the raw sample too: a contact surprise shows there about 15 ms before it does through the filter
        target *= min(self._in_band(s, force_error_n), self._in_band(s, raw_error_n))
        up, down = p.tangential_acceleration_m_s2 * dt, p.stop_deceleration_m_s2 * dt
        if (
            abs(rate_rad_s) > p.max_normal_turn_rate_rad_s and s.speed_m_s > 0.0
        ):  # a corner: keep the turn rate
            corner = max(
                p.min_tangential_speed_m_s, s.speed_m_s * p.max_normal_turn_rate_rad_s / abs(rate_rad_s)
            )
            if corner < target:
                # gently: the turn rate is measured through the normal's tracker, which lags the speed;
                # a hard brake on it would make the two chase each other
                target, down = corner, up
        return min(max(target, s.speed_m_s - down), s.speed_m_s + up)

    def _normal_speed(
        self, s: ContourState, ctx: TaskContext, fn: float, pressing_n: float, share: float
    ) -> tuple[float, float, float]:
        """(v_n into the contact [m/s], the new integral, the force error): PI admittance, saturated;
        ``share`` of the integral acts (``_integral_at_speed``)."""
        p = self.p
        err = s.force_setpoint_n - fn
        if not self._trusted(s):  # no new evidence: do not move into the contact, keep the integral
            vn = min(0.0, p.force_kp_m_s_per_n * err + p.force_ki_m_s2_per_n * share * s.integral)
            integral = s.integral
        else:
            # A cycle without a new force sample uses the last filtered force but adds nothing to the
            # integral: the same error integrated twice would be a force spike made by the bus. Nor
            # does a tool too slow for its integral to act fully: it would wind up unseen.
            learning = fresh_sample(ctx) and share == 1.0
            integral = s.integral + err * ctx.period_s if learning else s.integral
            vn = p.force_kp_m_s_per_n * err + p.force_ki_m_s2_per_n * share * integral
            # Out of the force band the contact is not where the tool is going: motion into it is a
            # guarded approach, down to the approach speed (a bias or a pull reads as a weak contact,
            # and the integral would drive the tool at the contour at full normal speed).
            inward = p.approach_speed_m_s + (p.max_normal_speed_m_s - p.approach_speed_m_s) * self._in_band(
                s, err
            )
            if vn > inward or vn < -p.max_normal_speed_m_s:  # clamp and stop integrating (anti-windup)
                vn = min(max(vn, -p.max_normal_speed_m_s), inward)
                integral = s.integral
        retreat = self._saturated_retreat(pressing_n)
        if retreat is not None:  # admittance saturation: only away from the contact, integral emptied
            vn, integral = min(vn, -retreat), 0.0
        return vn, integral, err

    def _tracking(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p = self.p
        dt = ctx.period_s
        f_xy = math.hypot(s.force_f[0], s.force_f[1])
        normal, rate, accel = self._normal_update(s, ctx, f_xy)
        fn = (
            s.force_f[0] * normal[0] + s.force_f[1] * normal[1]
        )  # normal force pressing the tool out of the object
        pressing = self._pressing_n(s, normal)  # the raw sample counts here too: a collision is a step
        if pressing > p.max_force_n:
            why = f"contact force {pressing:.1f} N above the limit of {p.max_force_n} N"
            ev = Event("over_force", Severity.FAULT, why + "; retracting")
            s = self._enter(s, ContourPhase.RETRACT, ctx.t_s, fault=why, normal=normal, normal_force_n=fn)
            return self._retract(s, ctx, (*events, ev))
        trusted = self._trusted(s)
        counting = fresh_sample(ctx) and trusted
        low = s.low_force_cycles + (1 if counting else 0) if fn < p.contact_lost_force_n else 0
        if low >= p.contact_lost_cycles:
            return self._lose_contact(
                replace(s, normal=normal, normal_rate_rad_s=rate, normal_accel_rad_s2=accel), ctx, events
            )
        speed = self._tangential_speed(s, rate, s.force_setpoint_n - fn, dt)
        at_speed, share = self._integral_at_speed(s, speed)
        vn, integral, err = self._normal_speed(at_speed, ctx, fn, pressing, share)
        # A real contact answers motion into it (stiffness >= 1e4 N/m here: 1 N in 0.1 mm). Millimetres
        # of it without the force rising mean the force is not a contact's (a drifting bias, a pull on
        # the tool): the contact is lost, whatever the force reads.
        # Counted only while the force is below its band: within it the law always pushes in a little
        # (on a convex contour the tangent leaves it), and the force answers.
        ref_n = min(s.push_ref_n, fn)
        pushed = s.pushed_m + max(vn, 0.0) * dt
        if fn >= ref_n + STIFFNESS_PROBE_N or fn >= (1.0 - FORCE_BAND_FRACTION) * s.force_setpoint_n:
            pushed, ref_n = 0.0, fn
        if pushed >= p.max_push_without_force_m:
            why = (
                f"no contact stiffness: {pushed * 1000:.1f} mm into the contact with the force staying near "
                f"{fn:.1f} N"
            )
            return self._lose_contact(
                replace(s, normal=normal, normal_rate_rad_s=rate, normal_accel_rad_s2=accel), ctx, events, why
            )
        s = replace(s, pushed_m=pushed, push_ref_n=ref_n)
        t = (-normal[1] * p.direction, normal[0] * p.direction)
        v = (speed * t[0] - vn * normal[0], speed * t[1] - vn * normal[1], 0.0)  # z held at height_m
        # The line a re-approach would take: the normal of a contact that has been good for a while,
        # so that the moments of a disturbance (which tilt the force's direction) never become it.
        # ... and only while the tool's measured motion runs along the tangent this normal implies: a
        # force disturbance tilts the normal, but the contour, not the estimate, guides the tool.
        tcp = ctx.tcp_measured_m or s.p_cmd
        along = self._moves_along_tangent(s, normal, tcp, dt)
        settled = (
            s.settled_cycles + 1
            if trusted and along and 0.5 * s.force_setpoint_n <= fn <= 2.0 * s.force_setpoint_n
            else 0
        )
        good = settled * dt >= SETTLED_CONTACT_S
        # A force out of its band marks the contour as irregular here (a notch's edge, a bump, a
        # disturbance): the next creep_distance_m go at creep speed, so that what comes next (a
        # notch's far wall: a concave corner, whose impact no reaction can catch at full speed) is
        # met slowly.
        out_of_band = (
            trusted and abs(err) > FORCE_BAND_FRACTION * s.force_setpoint_n and s.contact_point is not None
        )
        creep = p.creep_distance_m if out_of_band else max(0.0, s.creep_m - speed * dt)
        s = replace(
            s,
            speed_m_s=speed,
            creep_m=creep,
            normal=normal,
            normal_rate_rad_s=rate,
            normal_accel_rad_s2=accel,
            integral=integral,
            normal_force_n=fn,
            force_error_n=err,
            low_force_cycles=low,
            settled_cycles=settled,
            contact_normal=normal if good else s.contact_normal,
            contact_point=(tcp[0], tcp[1]) if good else s.contact_point,
        )
        s, lap_events = self._count_laps(s, ctx)
        events = events + lap_events
        if s.lap >= self.laps:
            ev = Event("contour", Severity.INFO, "all laps done; retracting")
            s = self._enter(s, ContourPhase.RETRACT, ctx.t_s)
            return self._retract(s, ctx, (*events, ev))
        return self._moving(s, v, dt, on_path=True, events=events)

    def _count_laps(self, s: ContourState, ctx: TaskContext) -> tuple[ContourState, tuple[Event, ...]]:
        """Laps by the angle swept about a point inside the contour (see the module's text)."""
        tcp = ctx.tcp_measured_m or s.p_cmd
        x, y = tcp[0], tcp[1]
        ds = math.hypot(x - s.last_xy[0], y - s.last_xy[1]) if s.last_xy is not None else 0.0
        centre = s.centre
        angle = math.atan2(y - centre[1], x - centre[0])
        swept = s.swept_rad + (_wrap(angle - s.last_angle) if s.last_angle is not None else 0.0)
        lap = int(abs(swept) // (2.0 * math.pi))
        sums = s.path_sums
        events: tuple[Event, ...] = ()
        if s.lap == 0:
            sums = (sums[0] + x * ds, sums[1] + y * ds, sums[2] + ds)
        if lap > s.lap:
            events = (
                Event(
                    "lap",
                    Severity.INFO,
                    f"lap {s.lap + 1} of {self.laps} done ({s.arc_m * 1000 + ds * 1000:.0f} mm traced)",
                ),
            )
            if s.lap == 0 and sums[2] > 0.0:  # count about the traced contour's own centroid from now on
                centre = (sums[0] / sums[2], sums[1] / sums[2])
                angle = math.atan2(y - centre[1], x - centre[0])
        s = replace(
            s,
            swept_rad=swept,
            last_angle=angle,
            lap=lap,
            centre=centre,
            path_sums=sums,
            last_xy=(x, y),
            arc_m=s.arc_m + ds,
        )
        return s, events

    def _lose_contact(
        self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...], why: str = ""
    ) -> TaskStep:
        p = self.p
        losses = list(s.contact_losses)
        losses[min(s.lap, len(losses) - 1)] += 1
        s = replace(
            s,
            contact_losses=tuple(losses),
            low_force_cycles=0,
            integral=0.0,
            attempts=0,
            last_xy=None,
            pushed_m=0.0,
        )
        where = f"in lap {s.lap + 1} after {s.arc_m * 1000:.0f} mm" + (f" ({why})" if why else "")
        if not p.reapproach_on_contact_loss:
            ev = Event(
                "contact_lost", Severity.WARNING, f"contact lost {where}; retracting (on_contact_loss = stop)"
            )
            s = self._enter(s, ContourPhase.RETRACT, ctx.t_s)
            return self._retract(s, ctx, (*events, ev))
        n = s.contact_normal
        ev = Event(
            "contact_lost",
            Severity.WARNING,
            f"contact lost {where}; braking, then re-approaching along ({n[0]:.3f}, {n[1]:.3f})",
        )
        s = self._enter(s, ContourPhase.CONTACT_LOST, ctx.t_s)
        return self._contact_lost(s, ctx, (*events, ev))

    def _contact_lost(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        """Brake the tangential motion along the tangent it had; no motion into the contact."""
        p, dt = self.p, ctx.period_s
        speed = self._braked(s.speed_m_s, dt)
        n = s.normal
        t = (-n[1] * p.direction, n[0] * p.direction)
        retreat = self._saturated_retreat(self._pressing_n(s, n)) or 0.0
        v = (speed * t[0] + retreat * n[0], speed * t[1] + retreat * n[1], 0.0)
        s = replace(s, speed_m_s=speed)
        if speed == 0.0:
            s = self._start_reapproach(s, ctx)
            events = (*events, self._attempt_event(s))
        return self._moving(s, v, dt, events=events)

    def _attempt_event(self, s: ContourState) -> Event:
        d = s.reapproach_direction
        return Event(
            "reapproach",
            Severity.INFO,
            f"re-approach {s.attempts + 1} of {self.p.max_reacquire_attempts} along ({d[0]:.3f}, {d[1]:.3f}), "
            f"guarded, at most {s.reapproach_m * 1000:.1f} mm",
        )

    def _start_reapproach(self, s: ContourState, ctx: TaskContext) -> ContourState:
        """Aim ``reapproach_distance_m`` behind the last good contact point, along its normal.

        From where the loss was noticed that is straight along -n; from wherever braking (or a
        disturbance before it) took the tool, the line still meets the contour near the point it
        was last known at. Without a good contact point yet: along -n from here.
        """
        n, depth = s.contact_normal, self.p.reapproach_distance_m
        x, y = s.p_cmd[0], s.p_cmd[1]
        f = s.force_f
        if self._trusted(s) and math.hypot(f[0], f[1]) < RETARE_MAX_FRACTION * s.force_setpoint_n:
            # Out of contact and standing: what the sensor reads is its own offset (a drifted bias).
            s = replace(
                s,
                offset=(s.offset[0] + f[0], s.offset[1] + f[1], s.offset[2] + f[2]),
                force_f=(0.0, 0.0, 0.0),
                raw_force=None,
            )
        cp = s.contact_point if s.contact_point is not None else (x, y)
        target = (cp[0] - n[0] * depth, cp[1] - n[1] * depth)
        dx, dy = target[0] - x, target[1] - y
        distance = math.hypot(dx, dy)
        direction = (dx / distance, dy / distance) if distance > 1e-6 else (-n[0], -n[1])
        return self._enter(
            s,
            ContourPhase.REAPPROACH,
            ctx.t_s,
            normal=n,
            normal_rate_rad_s=0.0,
            normal_accel_rad_s2=0.0,
            speed_m_s=0.0,
            reapproach_direction=direction,
            reapproach_m=max(distance, depth),
        )

    def _reapproach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        """A guarded move towards behind the last good contact point, at the approach speed."""
        p, dt = self.p, ctx.period_s
        f_contact = self._in_contact(s, s.contact_normal)
        if f_contact is not None:
            ev = Event(
                "contact",
                Severity.INFO,
                f"contact re-acquired at {f_contact:.2f} N after "
                f"{s.travel_m * 1000:.1f} mm (attempt {s.attempts + 1}); tracking on",
            )
            tcp = (
                ctx.tcp_measured_m or s.p_cmd
            )  # where the contour was found again: the next re-approach's aim
            s = self._enter(
                s,
                ContourPhase.TRACKING,
                ctx.t_s,
                integral=0.0,
                low_force_cycles=0,
                attempts=0,
                settled_cycles=0,
                creep_m=p.creep_distance_m,
                push_ref_n=f_contact,
                contact_point=(tcp[0], tcp[1]),
            )
            return self._tracking(s, ctx, (ev,))
        if s.travel_m >= s.reapproach_m:
            ev = Event(
                "reapproach_failed",
                Severity.WARNING,
                f"no contact within {s.reapproach_m * 1000:.1f} mm (attempt {s.attempts + 1} of "
                f"{p.max_reacquire_attempts}); backing off",
            )
            s = self._enter(s, ContourPhase.BACK_OFF, ctx.t_s, attempts=s.attempts + 1)
            return self._back_off(s, ctx, (ev,))
        speed = p.approach_speed_m_s if self._trusted(s) else 0.0
        d = s.reapproach_direction
        return self._moving(s, (d[0] * speed, d[1] * speed, 0.0), dt, travel_m=speed * dt)

    def _back_off(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        """Back along the re-approach's line to where it started; then the next attempt or the end."""
        p, dt = self.p, ctx.period_s
        if s.travel_m >= s.reapproach_m:
            if s.attempts >= p.max_reacquire_attempts:
                why = (
                    f"contact lost in lap {s.lap + 1} and not re-acquired in {s.attempts} guarded re-approaches "
                    f"to {p.reapproach_distance_m * 1000:.0f} mm behind the last contact point"
                )
                ev = Event("contact_not_reacquired", Severity.FAULT, why + "; retracting")
                s = self._enter(s, ContourPhase.RETRACT, ctx.t_s, fault=why)
                return self._retract(s, ctx, (*events, ev))
            s = self._start_reapproach(s, ctx)
            events = (*events, self._attempt_event(s))
            return self._moving(s, (0.0, 0.0, 0.0), dt, events=events)
        d = s.reapproach_direction
        speed = p.retract_speed_m_s
        return self._moving(s, (-d[0] * speed, -d[1] * speed, 0.0), dt, events=events, travel_m=speed * dt)

    def _sensor_breach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        """Someone else sends on the sensor's COB-ID (the law names it): no force sample can be trusted
        any more. Before the approach the tool is nowhere near the contour: the fault at once. After
        it, the retract along the last normal needs no force (distance and speed are the retract's):
        it moves the tool out of the contact before the fault."""
        why = f"force sensor not trusted: {ctx.sensor_breach}"
        if s.phase in (ContourPhase.MOVE_TO_START, ContourPhase.TARE):
            s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
            return TaskStep(s, ref, fault=why)
        ev = Event("sensor_breach", Severity.FAULT, why + "; retracting without force data")
        s = self._enter(s, ContourPhase.RETRACT, ctx.t_s, fault=why)
        return self._retract(s, ctx, (ev,))

    def _retract(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p = self.p
        if s.travel_m >= p.retract_distance_m:
            s = replace(s, phase=ContourPhase.FINISHED, phase_start_s=ctx.t_s)
            return self._finished(s, ctx, (*events, Event("contour", Severity.INFO, "retracted")))
        v = (s.normal[0] * p.retract_speed_m_s, s.normal[1] * p.retract_speed_m_s, 0.0)
        s = replace(s, speed_m_s=0.0)
        return self._moving(s, v, ctx.period_s, events=events, travel_m=p.retract_speed_m_s * ctx.period_s)

    def _finished(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        return TaskStep(s, ref, finished=True, fault=s.fault, events=events)
