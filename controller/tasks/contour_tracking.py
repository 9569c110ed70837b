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
  treated the same way after ``stale_hold_s``, but for the integral's push at the braking
  speed: blind, the tool holds its course (``_normal_speed``).
- **Contact loss** (normal force under ``contact_lost_force_n`` in the fresh samples of
  ``contact_lost_s``, counted in cycles): CONTACT_LOST brakes the tangential motion; REAPPROACH moves along the last
  normal measured in good contact, at the approach speed, guarded by the contact force, at
  most ``reapproach_distance_m``; BACK_OFF returns to where that attempt started. After
  ``max_reacquire_attempts`` failed attempts the tool retracts and the task ends with a fault
  naming the cause. A re-acquired contact resumes tracking and lap counting where they stopped.
- **Stall.** Each of the task's own slow-downs is by design (the force out of its band, a
  creep after an irregular stretch, a held step), but together they can hold the tool to a
  crawl for ever: a force sensor mounted 30-45 degrees about the tool's axis, or a part with
  friction 1.0 where the task estimates 0.1, tilt the measured normal, and the tool crept at
  0-4 mm/s for 120 s without a lap or an event, ending DONE (an outside tester, 44dbcbc).
  Tracking that covers less than ``stall_speed_fraction`` of the slowest lap's speed (the
  exploring one) over ``stall_window_s`` (measured travel, task time) retracts and faults
  naming both speeds; ``stall_speed_fraction = 0`` lets it crawl. The slowest, not the lap's
  own: a loop held up on a busy machine slows the task by design (a demo over the bus on a
  noisy host averaged 12.9 mm/s over 10 s of lap 4, where 60 were asked). A window with
  ``STALL_HELD_UP_FRACTION`` of its cycles held up names them, not the force's direction.

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

from controller.core.contact_guard import WITNESS_MEDIAN_S
from controller.core.cycle_data import Command, CycleInputs, Event, Severity
from controller.core.periods import cycles_in
from controller.core.ports import (
    ContactExpectation,
    ForceSetpointLimit,
    JointMotion,
    JointReference,
    Robot,
    TaskContext,
    TaskStep,
)
from controller.core.records import record, replace


class ContourRobot(Robot, JointMotion, Protocol):
    """What the task calls on its robot: the model, and the joint motion of a TCP motion every cycle."""


SETTLED_CONTACT_S = 0.25  # a contact this long near the setpoint and trusted gives the re-approach's normal
STIFFNESS_PROBE_N = 1.0  # a rise of the normal force this large shows a contact answering the motion
MOTION_WITNESS_SPEED_M_S = 0.02  # sliding faster than this, the measured motion witnesses the tangent
# A force direction is taken at most this far from the motion's normal: 15 let a force spike tilt the
# type-3 tracker into the task's retract, 5 ended a drifting bias in the safety fault (the contour scan).
MOTION_GATE_DEG = 10.0
CONSISTENCY_MAX_DEG = 8.0  # the measured motion's angle to the tangent for a contact normal to be trusted
CONSISTENCY_MIN_SPEED_M_S = 0.005  # slower motion says nothing about the tangent
STALE_CONTACT_POINT_M = 0.015  # a last good contact point further than this is not where to re-approach
ENVELOPE_SPACING_M = 0.002  # the first lap's traced contour keeps a point this often (the envelope's)
ENVELOPE_SEARCH = 8  # segments each side of the last nearest one searched every cycle
MOVE_ACCELERATION_M_S2 = 0.2  # the move to the staging point speeds up and brakes at this
TRACE_BACKFILL = 2  # trace points before an irregular one that get its speed too (4 mm)
LOOK_AHEAD_VERTICES = 6  # of the lap-1 trace: 12 mm, more than braking from 60 mm/s takes at ...
LOOK_AHEAD_DECELERATION_M_S2 = 0.5  # ... this (3.6 mm): gentle, the structure does not ring
MIN_BIAS_SPEED_M_S = 0.015  # slower, the cogging does not average out of the sensor-minus-witness filter
FORCE_BAND_FRACTION = 0.3  # of the force setpoint: a larger error derates the tangential speed ...
FORCE_STOP_FRACTION = 0.6  # ... down to zero at this one (the disk's laps stay within 0.17 at 60 mm/s)
# After the loop was held up (a late wake-up, skipped deadlines, a missing frame) the force leaves its
# band for a while though the contour is regular: no setpoint came, the drives (then running on one
# period) held, and the contact's stiffness (0.4-1.1 N/um on the disk) makes newtons of microns. Every
# sample out of the band of a demo beside two CPU hogs came within 35 cycles (88 ms) of such a
# hold-up (54 samples), up to 7.4 N, and one lasted past 0.1 s. An excursion that begins within
# this long after a hold-up is the loop's until the force is back in its band: meanwhile the band
# is TIMING_BAND_FRACTION wide (derating to zero at twice that) and an excursion inside it marks
# nothing as irregular (``_timing_window``, ``ContourState.excused``); the limits (max_force_n, the
# safety layer's) are not widened.
TIMING_RECOVERY_S = 0.1
TIMING_BAND_FRACTION = 1.0
# A hold-up long enough that the drives ran out of setpoints stops the tool dead (ctx.drives_held): the
# tangential speed restarts from zero and climbs back to what it was at this, not at the laps' gentle
# tangential_acceleration_m_s2 (0 to 60 mm/s in 0.12 s and 3.6 mm): a step back to full speed would
# jolt the structure, a slow climb would cost every lap with a hold-up its speed.
HOLD_RESTART_ACCELERATION_M_S2 = 0.5
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
    RETARE = 9  # out of contact along the last normal, then the sensor's offset measured again


# What each phase's reference says about contact (the law's contact guard, controller/core/contact_guard.py).
PHASE_CONTACT = {
    ContourPhase.MOVE_TO_START: ContactExpectation.NONE,
    ContourPhase.TARE: ContactExpectation.NONE,
    ContourPhase.APPROACH: ContactExpectation.GUARDED,
    ContourPhase.TRACKING: ContactExpectation.PRESSING,
    ContourPhase.RETRACT: ContactExpectation.PRESSING,
    ContourPhase.FINISHED: ContactExpectation.NONE,
    ContourPhase.CONTACT_LOST: ContactExpectation.PRESSING,  # braking, still in contact or near
    ContourPhase.REAPPROACH: ContactExpectation.GUARDED,
    ContourPhase.BACK_OFF: ContactExpectation.PRESSING,  # leaving where the re-approach went
    ContourPhase.RETARE: ContactExpectation.PRESSING,  # leaving the contact; NONE once out, for the tare
}


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
    contact_lost_s: float
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
    stale_hold_s: float = 0.01  # without a fresh sample this long, the law holds as for a suspect one
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
    # Off the happy path, by design (the module's text, "Safe by design")
    placement_tolerance_m: float = 0.015  # the part may lie this far from where it is expected
    search_speed_m_s: float = 0.01  # a guarded move's speed until the nominal start point
    move_speed_m_s: float = 0.015  # the move to the staging point, in free space: bounded all the same
    explore_speed_m_s: float = 0.02  # the first lap's speed at most: the contour is not known yet
    min_contact_stiffness_n_m: float = (
        2000.0  # a contact's force rises at least this steeply with the advance
    )
    envelope_margin_m: float = 0.012  # the tool stays this close to the contour traced in lap 1
    retare_clearance_m: float = 0.002  # after a contact loss: this far out along the normal, then the tare
    max_retares_per_lap: int = 3
    sensor_bias_limit_n: float = 4.0  # the tared sensor minus the effort witness, filtered: a drifted offset
    sensor_bias_time_constant_s: float = 2.0
    witness_verdict_s: float = (
        0.02  # after an implausible step, the witness decides: real or the sensor's offset
    )
    witness_tolerance_n: float = 6.0  # safety.contact.tolerance_n: the effort witness's own error
    stall_window_s: float = 10.0  # tracking progress is judged over this much task time
    stall_speed_fraction: float = 0.25  # ... and cover this share of the slowest lap's speed (0: never)


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
    start_checked: bool = False  # the way to the staging point was checked clear of the part
    guard_base_n: float = 0.0  # a guarded move: the lowest force against its direction since it began
    guard_rise_m: float | None = None  # its travel when that force first rose half the contact force
    verdict: str = ""  # what the effort witness says of a held step ("real", "offset", ""), ...
    verdict_cycles: int = 0  # ... for this many cycles in a row
    bias_n: tuple[float, float] = (0.0, 0.0)  # tared sensor minus the effort witness, filtered (XY)
    retares: tuple[int, ...] = ()  # re-tares in free space per lap
    retare_why: str = ""  # why the current re-tare
    offset_doubt: str = ""  # a held step the witness says was the sensor's offset: re-tare (why)
    approached_m: float = -1.0  # a re-tare during the approach: how far it had gone (-1: none)
    # the contour traced in lap 1, every ENVELOPE_SPACING_M, with the speed the first lap found for it
    trace: tuple[TracePoint, ...] = ()
    trace_index: int = 0  # the trace's segment nearest the tool at the last cycle
    retract_direction: tuple[float, float] = (1.0, 0.0)  # unit: along the measured force when it began
    retare_direction: tuple[float, float] = (1.0, 0.0)  # unit: a re-tare's way out (_way_out)
    retare_met_m: float = -1.0  # the way out met another surface: back to this far out, tare there (-1: none)
    retare_free_m: float = -1.0  # ... the way out's travel where the contact left behind stopped pushing
    retare_held_cycles: int = 0  # ... held still this long for the drives' effort to confirm it (_judge_met)
    # cycles left in which a hold-up of the loop explains the force (TIMING_RECOVERY_S), and whether
    # the force left its band in that window and has not come back yet
    timing_window_cycles: int = 0
    excused: bool = False
    restart_speed_m_s: float = 0.0  # the speed the drives were stopped from by a hold-up, until regained
    # (task time, arc_m) where the stall window began; None outside TRACKING (every phase change)
    progress_from: tuple[float, float] | None = None
    window_held_up: int = 0  # cycles of that window in which the loop was held up (loop_held_up)


def _unit2(x: float, y: float) -> tuple[float, float] | None:
    n = math.hypot(x, y)
    return (x / n, y / n) if n > 1e-12 else None


def _against(force: tuple[float, float, float], moving: tuple[float, float], leaving: bool) -> float:
    """The force opposing a move along ``moving`` (unit) [N]. Leaving a contact, a force along the move
    counts as none: the contact left behind pushes the tool on, and its fading is no rise."""
    f = -(force[0] * moving[0] + force[1] * moving[1])
    return max(f, 0.0) if leaving else f


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


TracePoint = tuple[float, float, float]  # x, y [m] and the speed at most there in later laps [m/s]


def _closed(trace: tuple[TracePoint, ...]) -> tuple[TracePoint, ...]:
    """The first lap's trace as a closed polyline: its last points back over its first dropped."""
    if len(trace) < 4:
        return trace
    first = trace[0]
    end = len(trace)
    while (
        end > 3
        and math.hypot(trace[end - 1][0] - first[0], trace[end - 1][1] - first[1]) < ENVELOPE_SPACING_M
    ):
        end -= 1
    return trace[:end]


def _nearest_on_trace(
    trace: tuple[TracePoint, ...], x: float, y: float, around: int, span: int
) -> tuple[float, int]:
    """(distance, segment) of the point nearest (x, y) on the closed polyline ``trace``, searched
    ``span`` segments each side of ``around`` (the whole of it when span covers it)."""
    n = len(trace)
    best, best_k = math.inf, around
    for k in range(around - span, around + span + 1) if 2 * span + 1 < n else range(n):
        i = k % n
        ax, ay, _ = trace[i]
        bx, by, _ = trace[(i + 1) % n]
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        u = min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / length2)) if length2 > 0.0 else 0.0
        d = math.hypot(x - ax - u * dx, y - ay - u * dy)
        if d < best:
            best, best_k = d, i
    return best, best_k


def trace_normal(s: ContourState, direction: int) -> tuple[float, float] | None:
    """The contour's outward normal where the tool is, from the trace of its measured positions (no
    force in it): the last segment in the first lap, the nearest one after; None without a segment of
    at least half the trace's spacing. The part lies to the -normal side of the way the tool travels
    (``direction``: +1 counter-clockwise), as the tracker's tangent t = (-n_y, n_x) * direction."""
    trace = s.trace
    n = len(trace)
    if n < 2:
        return None
    if s.lap == 0:
        a, b = trace[-2], trace[-1]
    else:
        a, b = trace[s.trace_index % n], trace[(s.trace_index + 1) % n]
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(dx, dy)
    if length < 0.5 * ENVELOPE_SPACING_M:
        return None
    return (direction * dy / length, -direction * dx / length)


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


# A stall whose window had at least this share of held-up cycles names them, not the force's
# direction: the quiet demo's hold-ups are well under 1 % of its cycles.
STALL_HELD_UP_FRACTION = 0.05


def loop_held_up(inputs: CycleInputs) -> bool:
    """The loop was held up this cycle: it woke late or after skipped deadlines (``inputs.late``),
    or a drive's or the sensor's frame is missing (the hold-up window, ``_timing_window``)."""
    return (
        inputs.late
        or not all(d.fresh for d in inputs.drives)
        or (inputs.sensor is not None and not inputs.sensor.fresh)
    )


def fresh_sample(ctx: TaskContext) -> bool:
    """Whether this cycle brought a new force sample (else the task runs on the last good one)."""
    return ctx.inputs.sensor is not None and ctx.inputs.sensor.fresh


def force_setpoint_limit(
    saturation_force_n: float, max_force_n: float, contact_lost_force_n: float
) -> ForceSetpointLimit:
    """What a force setpoint must stay below: its band (FORCE_BAND_FRACTION above it, where the law
    tracks at full speed) below the admittance saturation (above it the law only moves away from the
    contact) and below the task's own limit (``max_force_n``: it faults there). A setpoint of 29 N
    under a saturation of 30 N was accepted, crawled at 5 mm/s and ended in a stall blamed on the
    sensor's mounting or friction, with 22 N of force error (an outside tester). And above
    ``contact_lost_force_n``: a setpoint under it reads as contact lost once held (a remote
    set_force of 0.3 N passed the gate under the 1 N the configured setpoint must exceed)."""
    headroom = 1.0 + FORCE_BAND_FRACTION
    floor = (
        contact_lost_force_n,
        f"task.contour.contact_lost_force_n = {contact_lost_force_n:g} N (the task takes a force below "
        "it for contact lost)",
    )
    if saturation_force_n < max_force_n:
        return ForceSetpointLimit(
            saturation_force_n / headroom,
            f"the task's admittance saturation ({saturation_force_n:g} N = "
            "task.contour.admittance_saturation_fraction x safety.max_contact_force_n; its limit "
            f"task.contour.max_force_n = {max_force_n:g} N), less the force's band of "
            f"{FORCE_BAND_FRACTION:.0%} above the setpoint",
            *floor,
        )
    return ForceSetpointLimit(
        max_force_n / headroom,
        f"the task's limit task.contour.max_force_n = {max_force_n:g} N, less the force's band of "
        f"{FORCE_BAND_FRACTION:.0%} above the setpoint",
        *floor,
    )


class ContourTrackingTask:
    name = "contour"

    def __init__(self, robot: ContourRobot, params: ContourParams) -> None:
        self.robot = robot
        self.p = params
        u = (math.cos(params.approach_direction_rad), math.sin(params.approach_direction_rad))
        c = params.expected_centre_m
        # The staging point: outside the expected contour by the approach clearance and the part's
        # placement tolerance. Nearer than that the part may be anywhere: only guarded moves go there.
        self.zone_radius_m = (
            params.expected_radius_m + params.approach_clearance_m + params.placement_tolerance_m
        )
        r = self.zone_radius_m
        self.start_m = (c[0] + r * u[0], c[1] + r * u[1], params.height_m)
        robot.inverse_kinematics(np.array(self.start_m))  # reachable, or the task is refused at start

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
        """``force_setpoint_limit`` of the task's parameters (a remote ``set_force`` and the configured
        setpoint alike)."""
        return force_setpoint_limit(
            self.p.saturation_force_n, self.p.max_force_n, self.p.contact_lost_force_n
        )

    def phase_name(self, state: ContourState) -> str:
        return state.phase.name

    # -- helpers ------------------------------------------------------------------------------

    def _reference(
        self,
        s: ContourState,
        v: tuple[float, float, float],
        on_path: bool,
        dt: float,
        contact: ContactExpectation | None = None,
    ) -> tuple[ContourState, JointReference]:
        q, qd = self.robot.joint_motion(s.p_cmd, v)
        qdd = tuple((a - b) / dt for a, b in zip(qd, s.qd_ref)) if s.qd_ref else (0.0,) * len(qd)
        expected = PHASE_CONTACT[s.phase] if contact is None else contact
        ref = JointReference(q, qd, qdd, s.p_cmd, on_path, reactive=True, contact=expected)
        return replace(s, qd_ref=qd), ref

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
        return replace(
            s,
            phase=phase,
            phase_start_s=t_s,
            travel_m=0.0,
            restart_speed_m_s=0.0,
            progress_from=None,
            **fields,
        )

    @staticmethod
    def _timing_window(s: ContourState, ctx: TaskContext) -> ContourState:
        """Restart the window of TIMING_RECOVERY_S when the loop was held up this cycle: it woke late or
        after skipped deadlines (``inputs.late``), or a drive's or the sensor's frame is missing."""
        n = (
            math.ceil(TIMING_RECOVERY_S / ctx.period_s - 1e-9)
            if loop_held_up(ctx.inputs) or s.restart_speed_m_s > 0.0  # or the tool regains its speed
            else max(0, s.timing_window_cycles - 1)
        )
        return s if n == s.timing_window_cycles else replace(s, timing_window_cycles=n)

    def _filter_force(self, s: ContourState, ctx: TaskContext) -> tuple[ContourState, tuple[Event, ...]]:
        """The sample into the filter, unless it is a step the sensor and structure cannot make.

        After such a step the signal is suspect: samples stay out of the filter until it returns to
        within ``max_force_step_n`` of the level before the step (a spike), or until it has held
        the new level for ``implausible_hold_s`` (a real change: the filter restarts from it).
        Before the tare there is no offset yet, and the tare averages raw samples itself.
        """
        sensor = ctx.inputs.sensor
        if sensor is None or not sensor.fresh:
            # A period the drives ran on through a hold-up of the loop (``TaskContext.drives_ran_on``)
            # is past: no sample was missed in it, the loop was. Counted as stale, a hold-up longer
            # than ``stale_hold_s`` braked the tangent and dropped the integral's push (the tilt the
            # friction gives the normal estimate) in periods the drives had run on at full speed: the
            # next target pulled them back (a single 15-ms hold-up with 20 ms of extrapolation: 10 ->
            # 0 -> 19 N).
            return replace(s, stale_cycles=s.stale_cycles + (0 if ctx.drives_ran_on else 1)), ()
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
            s, verdict = self._witness_verdict(s, ctx, raw, held)
            size = math.hypot(raw[0] - held[0], raw[1] - held[1])
            if verdict == "real":
                return replace(s, held_force=None, suspect_cycles=0, force_f=raw), (
                    Event(
                        "force_plausible",
                        Severity.WARNING,
                        f"force step of {size:.1f} N is real: the drives' effort moved with it",
                    ),
                )
            if elapsed_s >= p.implausible_hold_s and verdict == "offset":
                # The sensor's offset stepped: the force is still what it was before the step, and the
                # offset is measured again in free space (``_sensor_doubt``, the re-tare).
                why = f"the force sensor's offset stepped by {size:.1f} N and the drives' effort did not"
                return replace(s, held_force=None, suspect_cycles=0, raw_force=held, offset_doubt=why), (
                    Event("sensor_offset_step", Severity.WARNING, why + ": re-taring in free space"),
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
                s,
                held_force=last,
                held_step=(raw[0] - last[0], raw[1] - last[1]),
                suspect_cycles=0,
                verdict_cycles=0,
            ), (
                Event(
                    "force_implausible",
                    Severity.WARNING,
                    f"force step of {step:.1f} N in one sample (> {p.max_force_step_n} N): held off, "
                    f"no motion into the contact, tangential motion braking",
                ),
            )
        return self._filtered(s, raw, ctx), ()

    def _witness_verdict(
        self,
        s: ContourState,
        ctx: TaskContext,
        raw: tuple[float, float, float],
        held: tuple[float, float, float],
    ) -> tuple[ContourState, str]:
        """What the drives' effort witness says of a step held as implausible: "real" when it agrees with
        the new level and not with the old one, "offset" (the sensor's own) the other way round, within
        its tolerance (``witness_tolerance_n`` and a quarter of the force); "" while it cannot tell. A
        verdict counts once it has stood ``witness_verdict_s`` in a row: a braking tool makes the
        structure ring, and the motors feel the ringing for a few cycles where the sensor does not."""
        w = ctx.force_witness_n
        if w is None:
            return replace(s, verdict="", verdict_cycles=0), ""
        tol = self._witness_tolerance_n(math.hypot(raw[0], raw[1]), math.hypot(held[0], held[1]))
        agrees_new = math.hypot(raw[0] - w[0], raw[1] - w[1]) <= tol
        agrees_old = math.hypot(held[0] - w[0], held[1] - w[1]) <= tol
        verdict = (
            "real" if agrees_new and not agrees_old else "offset" if agrees_old and not agrees_new else ""
        )
        n = s.verdict_cycles + 1 if verdict and verdict == s.verdict else (1 if verdict else 0)
        s = replace(s, verdict=verdict, verdict_cycles=n)
        return s, verdict if n >= cycles_in(self.p.witness_verdict_s, ctx.period_s) else ""

    def _witness_tolerance_n(self, a_n: float, b_n: float) -> float:
        """How far the sensor and the drives' effort may disagree where the larger force of ``a_n`` and
        ``b_n`` acts: the effort's own error and a quarter of that force (the safety layer's
        ``tolerance_n`` without its inertia term)."""
        return self.p.witness_tolerance_n + 0.25 * max(a_n, b_n)

    def _filtered(self, s: ContourState, raw: tuple[float, float, float], ctx: TaskContext) -> ContourState:
        a = 1.0 - math.exp(-2.0 * math.pi * self.p.force_filter_hz * ctx.period_s)
        f = s.force_f
        return replace(
            s, force_f=(f[0] + a * (raw[0] - f[0]), f[1] + a * (raw[1] - f[1]), f[2] + a * (raw[2] - f[2]))
        )

    def _blind(self, s: ContourState, period_s: float) -> bool:
        """No fresh sample for ``stale_hold_s``: nothing to see with."""
        return s.stale_cycles >= cycles_in(self.p.stale_hold_s, period_s)

    def _trusted(self, s: ContourState, period_s: float) -> bool:
        """Whether this cycle's force may steer the law: no implausible step held, no run of stale cycles
        as long as ``stale_hold_s``."""
        return s.held_force is None and not self._blind(s, period_s)

    def _pressing_n(self, s: ContourState, normal: tuple[float, float], ctx: TaskContext) -> float:
        """The contact force along the normal that saturation and the task's limit judge: the largest of
        the filtered force, the latest raw sample (a collision is a step), unless it is a step held as
        implausible, and the drives' effort witness (a sensor reading low is no licence to push)."""
        filtered = s.force_f[0] * normal[0] + s.force_f[1] * normal[1]
        raw = (
            s.raw_force[0] * normal[0] + s.raw_force[1] * normal[1]
            if s.raw_force is not None and s.held_force is None
            else filtered
        )
        w = ctx.force_witness_n
        # less its own error (the cogging, the structure ringing after the tool brakes): it must not
        # retract a tool the sensor rightly says presses within its limit
        witness = (
            w[0] * normal[0] + w[1] * normal[1] - self.p.witness_tolerance_n if w is not None else filtered
        )
        return max(filtered, raw, witness)

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
    def _band_fractions(s: ContourState) -> tuple[float, float]:
        """(band, stop) as fractions of the setpoint for the tangential speed and the creep: wider
        while the loop's hold-up explains the force (TIMING_RECOVERY_S)."""
        if s.timing_window_cycles > 0 or s.excused:
            return TIMING_BAND_FRACTION, 2.0 * TIMING_BAND_FRACTION
        return FORCE_BAND_FRACTION, FORCE_STOP_FRACTION

    @staticmethod
    def _in_band(s: ContourState, force_error_n: float, band: float, stop: float) -> float:
        """1 with the force error within ``band`` (a fraction of the setpoint), falling linearly to 0 at
        ``stop``."""
        band, stop = band * s.force_setpoint_n, stop * s.force_setpoint_n
        return min(1.0, max(0.0, (stop - abs(force_error_n)) / (stop - band)))

    def _integral_at_speed(self, s: ContourState, speed_m_s: float) -> tuple[float, float]:
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
        return s.integral * ratio, min(1.0, speed_m_s / floor)

    def _restart_speed(self, s: ContourState, speed: float, trusted: bool, period_s: float) -> float:
        """The speed a hold-up stopped, while the tool climbs back to it (HOLD_RESTART_ACCELERATION_M_S2).

        The restart lasts while the speed climbs back: it ends where it reaches the old speed, or
        stops climbing (a lower target: a corner, the band, the creep rule). A brake on a force not
        trusted while a hold-up's window is open (``_timing_window``: samples that stopped coming,
        or a step the hold-up's jolt made, held off as implausible) is no lower target: the speed it
        brakes from is kept, and after it the tool climbs back as after the drives stood. Over the
        bus, in two default demos (2026-12-05), that brake ended the restart, and the tool went on
        at the laps' gentle 0.05 m/s2: the blind periods of a 23-ms hold-up braked it to rest before
        the drives stood (lap 3 at 43.5 mm/s of 60), and a second hold-up 0.1 s after a first braked
        the climb back (54.6 mm/s). Outside a hold-up's window (a step with no hold-up to explain
        it: an impact, a lying sensor) the brake ends the restart as before; so it does where the
        hold-ups are many (``STALL_HELD_UP_FRACTION`` of the stall window's cycles held up so far):
        on a machine that does not keep up the tool creeps, and the stall rule names the hold-ups.
        Every device silent 15 cycles in 60 finished the laps with the speed kept, at 23.9 N of true
        force where 13.1 N and a named stall were the cautious end.
        """
        if (
            not trusted
            and s.timing_window_cycles > 0
            and s.window_held_up < STALL_HELD_UP_FRACTION * cycles_in(self.p.stall_window_s, period_s)
        ):
            return max(s.restart_speed_m_s, s.speed_m_s)
        return s.restart_speed_m_s if s.speed_m_s < speed < s.restart_speed_m_s else 0.0

    def _braked(self, speed: float, dt: float) -> float:
        return max(0.0, speed - self.p.stop_deceleration_m_s2 * dt)

    # -- the step -------------------------------------------------------------------------------

    def step(self, state: ContourState, ctx: TaskContext) -> TaskStep:
        s, signal_events = self._filter_force(self._timing_window(state, ctx), ctx)
        if ctx.drives_held and s.phase == ContourPhase.TRACKING and s.speed_m_s > 0.0:
            restart = max(s.restart_speed_m_s, s.speed_m_s)
            integral, _ = self._integral_at_speed(s, 0.0)  # the tool stopped: so does what it made up for
            s = replace(s, integral=integral, restart_speed_m_s=restart, speed_m_s=0.0)
        if ctx.sensor_breach and s.phase not in (ContourPhase.RETRACT, ContourPhase.FINISHED):
            return self._sensor_breach(s, ctx)
        if ctx.inputs.command == Command.SET_FORCE and self.force_setpoint_limit().accepts(
            ctx.inputs.command_value
        ):  # the command gate refuses the others already; the step takes no setpoint it cannot track
            s = replace(s, force_setpoint_n=ctx.inputs.command_value)
        if s.phase in (ContourPhase.APPROACH, ContourPhase.REAPPROACH):
            doubt = self._sensor_doubt(s, ctx)
            if doubt:  # a guarded move on a doubtful offset would meet a phantom contour: re-tare first
                out = self._begin_retare(replace(s, retare_why=doubt), ctx, ())
                return replace(out, events=(*signal_events, *out.events))
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
            ContourPhase.RETARE: self._retare,
        }[s.phase]
        out = handler(s, ctx)
        return replace(out, events=signal_events + out.events) if signal_events else out

    def _start_path_blocked(self, from_m: tuple[float, float, float]) -> str:
        """Why the straight move from ``from_m`` to the staging point may not go (it passes nearer the
        expected contour than the part may lie), or "". A tool that already stands in that zone (a
        part expected larger than the one the home was chosen for) may leave it: the move is refused
        only where it comes nearer the centre than it starts."""
        c, (x0, y0), (x1, y1) = self.p.expected_centre_m, from_m[:2], self.start_m[:2]
        dx, dy = x1 - x0, y1 - y0
        length2 = dx * dx + dy * dy
        u = min(1.0, max(0.0, ((c[0] - x0) * dx + (c[1] - y0) * dy) / length2)) if length2 > 0.0 else 0.0
        d = math.hypot(x0 + u * dx - c[0], y0 + u * dy - c[1])
        if d >= min(self.zone_radius_m, math.hypot(x0 - c[0], y0 - c[1])) - 1e-4:
            return ""
        return (
            f"the move to the contour's start point ({self.start_m[0]:.3f}, {self.start_m[1]:.3f}) m passes "
            f"{d * 1000:.0f} mm from the expected centre, inside the {self.zone_radius_m * 1000:.0f} mm where "
            f"the part may lie (expected radius + approach clearance + placement tolerance): move the robot "
            f"or choose another task.contour.approach_direction_deg"
        )

    def _move_to_start(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        """A straight line to the staging point at ``move_speed_m_s`` at most, in free space.

        Bounded, because a part misplaced by more than its tolerance may be in the way: the safety
        layer's guard stops a move that meets it, and the slower the move the less it meets it with."""
        p, dt = self.p, ctx.period_s
        if not s.start_checked:
            here = ctx.tcp_measured_m or s.p_cmd
            blocked = self._start_path_blocked(here)
            if blocked:
                return TaskStep(s, JointReference.at_rest(ctx.setpoint.position, here), fault=blocked)
            s = replace(s, start_checked=True, p_cmd=here, speed_m_s=0.0)
        d = (self.start_m[0] - s.p_cmd[0], self.start_m[1] - s.p_cmd[1], self.start_m[2] - s.p_cmd[2])
        left = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        settled = all(abs(v) <= p.settle_tolerance_m for v in ctx.setpoint.velocity)
        if left <= 1e-6 and settled:
            s = self._enter(replace(s, p_cmd=self.start_m, speed_m_s=0.0), ContourPhase.TARE, ctx.t_s)
            s, ref = self._reference(s, (0.0, 0.0, 0.0), False, dt)
            return TaskStep(s, ref)
        a = MOVE_ACCELERATION_M_S2
        speed = min(p.move_speed_m_s, s.speed_m_s + a * dt, math.sqrt(2.0 * a * left), left / dt)
        v = (
            (d[0] / left * speed, d[1] / left * speed, d[2] / left * speed)
            if left > 1e-6
            else (0.0, 0.0, 0.0)
        )
        return self._moving(replace(s, speed_m_s=speed), v, dt)

    def _tare(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        s, offset, fault = self._taring(s, ctx)
        if fault:
            return TaskStep(s, ref, fault=fault)
        if offset is None:
            return TaskStep(s, ref)
        event = Event(
            "contour", Severity.INFO, f"sensor offset {tuple(round(o, 3) for o in offset)} N; approaching"
        )
        s = self._enter(
            s,
            ContourPhase.APPROACH,
            ctx.t_s,
            offset=offset,
            force_f=(0.0, 0.0, 0.0),
            raw_force=None,
            guard_base_n=0.0,
            guard_rise_m=None,
        )
        return TaskStep(s, ref, events=(event,))

    def _taring(
        self, s: ContourState, ctx: TaskContext
    ) -> tuple[ContourState, tuple[float, float, float] | None, str]:
        """Average the sensor at rest in free space for ``tare_s``: (state, the offset when done, a fault).

        Free space is the drives' word too: a sample the effort witness says is in contact (beyond its
        own error) is no offset; a tare that finds no such sample within a second more is refused."""
        sensor = ctx.inputs.sensor
        witness = ctx.force_witness_n
        touching = witness is not None and math.hypot(witness[0], witness[1]) > self.p.witness_tolerance_n
        if sensor is not None and sensor.fresh and not touching:
            fx, fy, fz, n = s.tare_sum
            s = replace(
                s, tare_sum=(fx + sensor.force_n[0], fy + sensor.force_n[1], fz + sensor.force_n[2], n + 1)
            )
        elapsed = ctx.t_s - s.phase_start_s
        fx, fy, fz, n = s.tare_sum
        if elapsed < self.p.tare_s or (
            n < 0.5 * self.p.tare_s / ctx.period_s and elapsed < self.p.tare_s + 1.0
        ):
            return s, None, ""
        if n == 0:
            if touching and witness is not None:
                return (
                    s,
                    None,
                    (
                        f"tare refused: the drives' effort says {math.hypot(witness[0], witness[1]):.1f} N of contact "
                        "where the tool should be in free space"
                    ),
                )
            return s, None, "no force-sensor samples during the tare"
        return replace(s, tare_sum=(0.0, 0.0, 0.0, 0)), (fx / n, fy / n, fz / n), ""

    def _guarded_contact(
        self, s: ContourState, moving: tuple[float, float], speed_m_s: float, dt: float, leaving: bool = False
    ) -> tuple[ContourState, float | None, tuple[Event, ...]]:
        """A guarded move along ``moving`` (unit): (state, the contact force [N] once met, events).

        Contact is what a contact does: the force against the motion rises as the tool advances, at
        least ``min_contact_stiffness_n_m`` steep (from half the contact force above the lowest it read
        during this move to the whole of it), and points against the motion (within 60 degrees). A
        force that creeps up slower is the sensor drifting, not a contour: the move goes on from the new
        level. The latest raw sample counts: the filter would add its lag to the guarded move's stop.

        ``leaving``: the move leaves a contact, whose force pushes the tool along the motion and fades as
        it goes; only a force that rises against the motion after that is another surface's."""
        p = self.p
        # leaving, a step held as implausible still counts: the way out judges a rise against the
        # drives' effort (_judge_met), and an offset step it re-tares for stays held until the tare
        seeing = not self._blind(s, dt) if leaving else self._trusted(s, dt)
        if not seeing or s.raw_force is None:
            return s, None, ()
        raw = s.raw_force
        against = _against(raw, moving, leaving)  # the force opposing the motion
        base = min(s.guard_base_n, against)
        if s.guard_rise_m is None and against < base + 0.5 * p.contact_force_n:
            return replace(s, guard_base_n=base), None, ()
        rise_at = s.guard_rise_m if s.guard_rise_m is not None else s.travel_m
        s = replace(s, guard_base_n=base, guard_rise_m=rise_at)
        if against < base + p.contact_force_n:
            return s, None, ()
        f_xy = math.hypot(raw[0], raw[1])
        steep = (s.travel_m - rise_at) * p.min_contact_stiffness_n_m <= 0.5 * p.contact_force_n + 1e-12
        # a strong force is a contact met at any angle to the motion (a wall met obliquely); a weak one
        # counts only against it. Never one along the motion: a part pushes back, it cannot pull the
        # tool on. Such a force is the sensor's (a -5 N offset step as the tool touched: the contact
        # taken from it, its normal reversed, and the re-approaches went the wrong way; an outside
        # tester's scenario, 7dcefb5)
        facing = against >= 0.5 * f_xy or (against > 0.0 and f_xy >= 3.0 * p.contact_force_n)
        if steep and facing:
            return s, f_xy, ()
        why = (
            f"force rose {against - base:.2f} N over {(s.travel_m - rise_at) * 1000:.2f} mm"
            if not steep
            else f"force of {f_xy:.2f} N not against the motion"
        )
        ev = Event(
            "contact_doubtful", Severity.WARNING, f"{why}: no contact's answer to the advance; moving on"
        )
        return replace(s, guard_base_n=against, guard_rise_m=None), None, (ev,)

    def _approach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        p = self.p
        moving = (-s.normal[0], -s.normal[1])
        # From the staging point at the search speed; from the nominal start point (the approach
        # clearance outside the expected contour) at the approach speed.
        speed = p.search_speed_m_s if s.travel_m < p.placement_tolerance_m else p.approach_speed_m_s
        s, f_contact, guard_events = self._guarded_contact(s, moving, speed, ctx.period_s)
        if f_contact is not None and s.raw_force is not None:
            raw = s.raw_force
            n = _unit2(raw[0], raw[1]) or s.normal
            event = Event(
                "contact", Severity.INFO, f"contact at {f_contact:.2f} N after {s.travel_m * 1000:.1f} mm"
            )
            s = self._enter(
                s,
                ContourPhase.TRACKING,
                ctx.t_s,
                force_f=raw,  # the filter restarts from the contact's sample: no lag into the first cycles
                normal=n,
                contact_normal=n,
                normal_rate_rad_s=0.0,
                normal_accel_rad_s2=0.0,
                integral=0.0,
                low_force_cycles=0,
            )
            return self._tracking(s, ctx, (event,))
        limit = p.placement_tolerance_m + p.approach_clearance_m + p.max_approach_distance_m
        if s.travel_m > limit:
            f_xy = math.hypot(s.force_f[0], s.force_f[1])
            why = f"no contact within {limit * 1000:.0f} mm of approach (force {f_xy:.2f} N < {p.contact_force_n} N)"
            if f_xy >= p.contact_force_n:  # a force, but none that rose as a contact's (_guarded_contact)
                why = (
                    f"no contact within {limit * 1000:.0f} mm of approach: the force ({f_xy:.2f} N) did not rise "
                    f"as a contact's does as the tool advanced (task.contour.min_contact_stiffness_n_m = "
                    f"{p.min_contact_stiffness_n_m:g} N/m at least): a softer part, or the sensor drifting"
                )
            s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
            return TaskStep(s, ref, fault=why)
        speed = speed if self._trusted(s, ctx.period_s) else 0.0
        v = (moving[0] * speed, moving[1] * speed, 0.0)
        return self._moving(s, v, ctx.period_s, events=guard_events, travel_m=speed * ctx.period_s)

    def _normal_update(
        self, s: ContourState, ctx: TaskContext, f_xy: float
    ) -> tuple[tuple[float, float], float, float]:
        """The normal estimate, its turn rate and the rate's change after this cycle's force (gated, see
        the module's text)."""
        p, dt = self.p, ctx.period_s
        normal, rate, accel = s.normal, s.normal_rate_rad_s, s.normal_accel_rad_s2
        angle = math.atan2(normal[1], normal[0])
        if s.restart_speed_m_s > 0.0:
            # Regaining the speed a hold-up stopped: the normal turns as far as the tool goes (the
            # rate kept is the one at that speed), and the force's direction, tilted by the stop's
            # jolt, is no measurement of the contour until then.
            angle += rate * (s.speed_m_s / s.restart_speed_m_s) * dt
            return (math.cos(angle), math.sin(angle)), rate, accel
        predicted = predict_normal(angle, rate, accel, dt)
        measured = predicted  # a repeated or suspect sample is no new direction: the tracker only predicts
        if not self._trusted(s, ctx.period_s):
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

    def _tangential_speed(
        self,
        s: ContourState,
        rate_rad_s: float,
        force_error_n: float,
        dt: float,
        tcp_xy: tuple[float, float],
        bands: tuple[float, float],
    ) -> float:
        """The lap's speed, derated where the normal turns fast or the force leaves its band, braked
        while the force is not trusted.

        A force error beyond ``FORCE_BAND_FRACTION`` of the setpoint means the contour is not where
        the tool is going: the edge of a notch (the force fades) or the ramp of a bump (it climbs).
        The speed falls linearly to zero at ``FORCE_STOP_FRACTION``: the tool then goes down into the
        notch or backs off the ramp along the normal before it goes on, instead of meeting the
        notch's far wall or the bump's face at full speed.
        """
        p = self.p
        if not self._trusted(s, dt):
            return self._braked(s.speed_m_s, dt)
        target = self._lap_speed(s)
        if s.creep_m > 0.0:
            target = min(target, p.creep_speed_m_s)
        target = min(target, self._look_ahead_speed(s, tcp_xy))
        raw_error_n = (
            force_error_n
            if s.raw_force is None
            else s.force_setpoint_n - (s.raw_force[0] * s.normal[0] + s.raw_force[1] * s.normal[1])
        )
        # the raw sample too: a contact surprise shows there about 15 ms before it does through the filter
        band, stop = bands  # _band_fractions
        target *= min(self._in_band(s, force_error_n, band, stop), self._in_band(s, raw_error_n, band, stop))
        up, down = p.tangential_acceleration_m_s2 * dt, p.stop_deceleration_m_s2 * dt
        if s.speed_m_s < s.restart_speed_m_s:  # back to the speed a hold-up stopped (HOLD_RESTART_...)
            up = max(up, HOLD_RESTART_ACCELERATION_M_S2 * dt)
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
        self, s: ContourState, ctx: TaskContext, fn: float, pressing_n: float, at_speed: tuple[float, float]
    ) -> tuple[float, float, float]:
        """(v_n into the contact [m/s], the new integral, the force error): PI admittance, saturated;
        ``at_speed`` is the integral at this speed and the share of it that acts (``_integral_at_speed``)."""
        p = self.p
        held, share = at_speed
        err = s.force_setpoint_n - fn
        if not self._trusted(s, ctx.period_s):  # no new evidence: no motion into the contact for the
            # force's error; the integral kept. Blind (samples missing, no suspect one held), the tool
            # still holds its course: the integral's push at this speed is the motion the friction's
            # tilt takes off the contour, not a push into it, and it fades as the tool brakes.
            # Dropped, the tool left the contour at 3.9 mm/s: 6 cycles without samples after a
            # hold-up, 3 of them blind, took the true force from 10 to 0 N and lost the contact.
            course = p.force_ki_m_s2_per_n * share * held if s.held_force is None else 0.0
            vn = min(course, p.force_kp_m_s_per_n * err + p.force_ki_m_s2_per_n * share * held)
            integral = held
        else:
            # A cycle without a new force sample uses the last filtered force but adds nothing to the
            # integral: the same error integrated twice would be a force spike made by the bus. Nor
            # does a tool too slow for its integral to act fully: it would wind up unseen.
            learning = fresh_sample(ctx) and share == 1.0
            integral = held + err * ctx.period_s if learning else held
            vn = p.force_kp_m_s_per_n * err + p.force_ki_m_s2_per_n * share * integral
            # Out of the force band the contact is not where the tool is going: motion into it is a
            # guarded approach, down to the approach speed (a bias or a pull reads as a weak contact,
            # and the integral would drive the tool at the contour at full normal speed).
            # (the band a hold-up of the loop widens is the tangent's: motion into the contact keeps it)
            inward = p.approach_speed_m_s + (p.max_normal_speed_m_s - p.approach_speed_m_s) * self._in_band(
                s, err, FORCE_BAND_FRACTION, FORCE_STOP_FRACTION
            )
            if vn > inward or vn < -p.max_normal_speed_m_s:  # clamp and stop integrating (anti-windup)
                vn = min(max(vn, -p.max_normal_speed_m_s), inward)
                integral = held
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
        pressing = self._pressing_n(s, normal, ctx)  # the raw sample counts here too: a collision is a step
        if pressing > p.max_force_n:
            why = f"contact force {pressing:.1f} N above the limit of {p.max_force_n} N"
            ev = Event("over_force", Severity.FAULT, why + "; retracting")
            s = replace(s, normal=normal, normal_force_n=fn)
            return self._begin_retract(s, ctx, (*events, ev), why)
        trusted = self._trusted(s, ctx.period_s)
        counting = fresh_sample(ctx) and trusted
        low = s.low_force_cycles + (1 if counting else 0) if fn < p.contact_lost_force_n else 0
        s = self._bias(s, ctx)
        doubt = self._sensor_doubt(s, ctx)
        if low >= cycles_in(p.contact_lost_s, ctx.period_s) or doubt:
            s = replace(s, normal=normal, normal_rate_rad_s=rate, normal_accel_rad_s2=accel, retare_why=doubt)
            return self._lose_contact(s, ctx, events, doubt)
        s, outside = self._envelope(s, ctx)
        if outside:
            ev = Event("envelope", Severity.FAULT, outside + "; retracting")
            return self._begin_retract(replace(s, normal=normal), ctx, (*events, ev), outside)
        tcp = ctx.tcp_measured_m or s.p_cmd
        bands = self._band_fractions(s)  # the speed's derating and the creep below: one verdict a cycle
        speed = self._tangential_speed(s, rate, s.force_setpoint_n - fn, dt, (tcp[0], tcp[1]), bands)
        vn, integral, err = self._normal_speed(s, ctx, fn, pressing, self._integral_at_speed(s, speed))
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
        out_of_band = trusted and abs(err) > bands[0] * s.force_setpoint_n and s.contact_point is not None
        # an excursion that began while a hold-up of the loop explained it stays excused until it ends
        excused = abs(err) > FORCE_BAND_FRACTION * s.force_setpoint_n and (
            s.excused or s.timing_window_cycles > 0
        )
        creep = p.creep_distance_m if out_of_band else max(0.0, s.creep_m - speed * dt)
        s = replace(
            s,
            speed_m_s=speed,
            restart_speed_m_s=self._restart_speed(s, speed, trusted, dt),
            creep_m=creep,
            excused=excused,
            normal=normal,
            normal_rate_rad_s=rate,
            normal_accel_rad_s2=accel,
            integral=integral,
            normal_force_n=fn,
            force_error_n=err,
            pushed_m=pushed,
            push_ref_n=ref_n,
            low_force_cycles=low,
            settled_cycles=settled,
            contact_normal=normal if good else s.contact_normal,
            contact_point=(tcp[0], tcp[1]) if good else s.contact_point,
        )
        s, lap_events = self._count_laps(s, ctx)
        events = events + lap_events
        s, stalled = self._stalled(s, ctx)
        if stalled:
            ev = Event("stall", Severity.FAULT, stalled + "; retracting")
            return self._begin_retract(s, ctx, (*events, ev), stalled)
        if s.lap >= self.laps:
            ev = Event("contour", Severity.INFO, "all laps done; retracting")
            return self._begin_retract(s, ctx, (*events, ev))
        return self._moving(s, v, dt, on_path=True, events=events)

    def _lap_speed(self, s: ContourState) -> float:
        """The lap's tangential speed before the task's own slow-downs."""
        p = self.p
        target = p.lap_speeds_m_s[min(s.lap, len(p.lap_speeds_m_s) - 1)]
        if s.lap == 0:  # the contour is unknown: what it holds is met at the exploring speed at most
            target = min(target, p.explore_speed_m_s)
        return target

    def _stalled(self, s: ContourState, ctx: TaskContext) -> tuple[ContourState, str]:
        """The stall rule (module text): every ``stall_window_s`` of tracking, the measured travel
        against the slowest lap's speed; the reason to retract, or ""."""
        p = self.p
        if p.stall_speed_fraction <= 0.0:
            return s, ""
        if s.progress_from is None:
            return replace(s, progress_from=(ctx.t_s, s.arc_m), window_held_up=0), ""
        t0, arc0 = s.progress_from
        if loop_held_up(ctx.inputs):
            s = replace(s, window_held_up=s.window_held_up + 1)
        elapsed = ctx.t_s - t0
        if elapsed < p.stall_window_s:
            return s, ""
        held_up = s.window_held_up
        s = replace(s, progress_from=(ctx.t_s, s.arc_m), window_held_up=0)
        achieved, slowest = (s.arc_m - arc0) / elapsed, min(p.explore_speed_m_s, *p.lap_speeds_m_s)
        if achieved >= p.stall_speed_fraction * slowest:
            return s, ""
        head = (
            f"stalled: {achieved * 1000:.1f} mm/s along the contour over the last {elapsed:.0f} s, under "
            f"{p.stall_speed_fraction:g} of the slowest lap's {slowest * 1000:.0f} mm/s"
        )
        cycles = max(1, round(elapsed / ctx.period_s))
        if held_up >= STALL_HELD_UP_FRACTION * cycles:
            # the task's hold-up rules slowed it (a writer of gigabytes beside the demo starved the
            # simulated drives: 6 601 missing frames, and the fault blamed the sensor's mounting)
            return s, (
                f"{head}, {held_up} of its {cycles} cycles held up (a drive's or the sensor's frame "
                "missing, or the loop late: the devices, the bus or this machine did not keep up)"
            )
        return s, (
            f"{head} (the force's direction off the contour's normal: the sensor's mounting, or friction "
            "beyond task.contour.friction_estimate?)"
        )

    def _bias(self, s: ContourState, ctx: TaskContext) -> ContourState:
        """The tared sensor minus the effort witness, filtered (XY), while sliding: a drifted offset shows
        there. The witness's own error is mostly the cogging, periodic along each carriage's stroke: it
        averages out of the filter while the tool slides, not while it stands."""
        w, raw = ctx.force_witness_n, s.raw_force
        if w is None or raw is None or not fresh_sample(ctx) or not self._trusted(s, ctx.period_s):
            return s
        if s.speed_m_s < MIN_BIAS_SPEED_M_S:
            return s
        a = 1.0 - math.exp(-ctx.period_s / self.p.sensor_bias_time_constant_s)
        b = s.bias_n
        return replace(s, bias_n=(b[0] + a * (raw[0] - w[0] - b[0]), b[1] + a * (raw[1] - w[1] - b[1])))

    def _sensor_doubt(self, s: ContourState, ctx: TaskContext) -> str:
        """Why the sensor's offset is in doubt, or "": a step the witness did not follow, the law's
        cross-check (unless a held step is being judged: the hold's own verdict comes first), or the
        filtered bias."""
        if s.offset_doubt:
            return s.offset_doubt
        if ctx.sensor_suspect and s.held_force is None:
            return f"the safety layer finds the force sensor suspect: {ctx.sensor_suspect}"
        bias = math.hypot(s.bias_n[0], s.bias_n[1])
        if bias > self.p.sensor_bias_limit_n:
            return f"the tared sensor reads {bias:.1f} N off the drives' effort (filtered)"
        return ""

    def _envelope(self, s: ContourState, ctx: TaskContext) -> tuple[ContourState, str]:
        """Inside the envelope? Before the first lap is done: the expected contour widened by the part's
        placement tolerance and the margin; after it: within ``envelope_margin_m`` of the contour the
        tool traced in lap 1 (kept every ENVELOPE_SPACING_M). Else the reason to retract."""
        tcp = ctx.tcp_measured_m
        if tcp is None:
            return s, ""
        p = self.p
        x, y = tcp[0], tcp[1]
        if s.lap == 0 or len(s.trace) < 3:
            if s.lap == 0 and (
                not s.trace or math.hypot(x - s.trace[-1][0], y - s.trace[-1][1]) >= ENVELOPE_SPACING_M
            ):
                s = replace(s, trace=self._traced(s, x, y))
            c = p.expected_centre_m
            r = math.hypot(x - c[0], y - c[1])
            band = p.placement_tolerance_m + p.envelope_margin_m
            if abs(r - p.expected_radius_m) <= band:
                return s, ""
            return s, (
                f"the tool left the envelope: {r * 1000:.0f} mm from the expected centre, where the contour is "
                f"expected at {p.expected_radius_m * 1000:.0f} +- {band * 1000:.0f} mm"
            )
        distance, index = _nearest_on_trace(s.trace, x, y, s.trace_index, ENVELOPE_SEARCH)
        if distance > p.envelope_margin_m:
            distance, index = _nearest_on_trace(s.trace, x, y, 0, len(s.trace))  # the whole trace, once
        s = replace(s, trace_index=index)
        if distance <= p.envelope_margin_m:
            return s, ""
        return s, (
            f"the tool left the envelope: {distance * 1000:.1f} mm from the contour traced in lap 1 "
            f"(at most {p.envelope_margin_m * 1000:.0f} mm)"
        )

    def _traced(self, s: ContourState, x: float, y: float) -> tuple[TracePoint, ...]:
        """The trace with (x, y) added. Where the first lap found the contour irregular (the force out
        of its band, a step held, the creep after either) the point keeps the creep speed for later
        laps, and so do the TRACE_BACKFILL points before it: the force rises on a bump's flank, which
        began before."""
        irregular = s.creep_m > 0.0 or s.held_force is not None
        if not irregular:
            return (*s.trace, (x, y, math.inf))
        cap = self.p.creep_speed_m_s
        k = max(0, len(s.trace) - TRACE_BACKFILL)
        marked = tuple((a, b, min(c, cap)) for a, b, c in s.trace[k:])
        return (*s.trace[:k], *marked, (x, y, cap))

    def _look_ahead_speed(self, s: ContourState, tcp: tuple[float, float]) -> float:
        """After the first lap, the speed from which the tool at ``tcp`` still brakes (at
        LOOK_AHEAD_DECELERATION_M_S2) to what the traced contour ahead allows: at each vertex what the
        first lap found there (``_traced``: the creep speed where it was irregular), and a normal turning
        at most at ``max_normal_turn_rate_rad_s`` (a bump's flank, a corner). Found in lap 1, met slowly
        from then on, instead of at the lap's speed with only the force to tell."""
        trace = s.trace
        n = len(trace)
        if s.lap == 0 or n < 8:
            return math.inf
        p = self.p
        i = s.trace_index
        best = max(p.min_tangential_speed_m_s, min(trace[i][2], trace[(i + 1) % n][2]))  # this segment's
        travelled = -math.hypot(tcp[0] - trace[i][0], tcp[1] - trace[i][1])  # from the tool on
        for k in range(1, LOOK_AHEAD_VERTICES + 1):
            a, b, c = trace[(i + k - 1) % n], trace[(i + k) % n], trace[(i + k + 1) % n]
            first, second = (b[0] - a[0], b[1] - a[1]), (c[0] - b[0], c[1] - b[1])
            travelled += math.hypot(*first)
            there = b[2]  # what the first lap found there
            if min(math.hypot(*first), math.hypot(*second)) >= 0.5 * ENVELOPE_SPACING_M:  # else: where the
                turn = abs(_wrap(math.atan2(second[1], second[0]) - math.atan2(first[1], first[0])))  # trace
                if turn > 1e-9:  # closes on itself, no direction worth a turn
                    there = min(there, p.max_normal_turn_rate_rad_s * math.hypot(*second) / turn)
            if there == math.inf:
                continue
            there = max(p.min_tangential_speed_m_s, there)
            best = min(
                best, math.sqrt(there * there + 2.0 * LOOK_AHEAD_DECELERATION_M_S2 * max(0.0, travelled))
            )
        return best

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
                s = replace(s, trace=_closed(s.trace))
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
            return self._begin_retract(s, ctx, (*events, ev))
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
        retreat = self._saturated_retreat(self._pressing_n(s, n, ctx)) or 0.0
        v = (speed * t[0] + retreat * n[0], speed * t[1] + retreat * n[1], 0.0)
        s = replace(s, speed_m_s=speed)
        if speed == 0.0:
            return self._begin_retare(s, ctx, events)
        return self._moving(s, v, dt, events=events)

    def _begin_retare(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...]) -> TaskStep:
        """Out of contact: along the last good normal into free space, there the sensor's offset anew.

        The offset found at the start may have drifted, or a step of it may have been taken for a
        contact: a re-approach on a stale offset meets a phantom contour (or presses a real one
        harder than it reads). At most ``max_retares_per_lap`` in a lap: a sensor that needs more is
        drifting faster than the task can work with, and the tool retracts naming it."""
        p = self.p
        lap = min(s.lap, self.laps - 1)
        retares = s.retares or (0,) * self.laps
        if retares[lap] >= p.max_retares_per_lap:
            why = (
                f"the force sensor needed more than {p.max_retares_per_lap} re-tares in free space in lap "
                f"{lap + 1} (last: {s.retare_why or 'contact lost'})"
            )
            ev = Event("sensor_retares", Severity.FAULT, why + "; retracting")
            return self._begin_retract(s, ctx, (*events, ev), why)
        counted = tuple(r + (1 if k == lap else 0) for k, r in enumerate(retares))
        # Before the first contact, the approach goes on afterwards from where it was (less the way out).
        approached = s.travel_m if s.phase == ContourPhase.APPROACH else -1.0
        way_out = self._way_out(s)
        s = self._enter(
            s,
            ContourPhase.RETARE,
            ctx.t_s,
            retares=counted,
            tare_sum=(0.0, 0.0, 0.0, 0),
            speed_m_s=0.0,
            approached_m=approached,
            retare_direction=way_out,
            retare_met_m=-1.0,
            retare_held_cycles=0,
            retare_free_m=-1.0,
            # the way out is a guarded move (_retare) from the force read as it begins
            guard_base_n=_against(s.raw_force, way_out, True) if s.raw_force is not None else 0.0,
            guard_rise_m=None,
        )
        return self._retare(s, ctx, events)

    def _way_out(self, s: ContourState) -> tuple[float, float]:
        """A re-tare's way into free space. Not the force's: a re-tare doubts the sensor, and the normal
        the tracker estimates from it turns with its offset (a +20 N step of it in lap 2: the way "out"
        pressed the part to 70 N before the guard backed off). Before the first contact the approach's
        own line back; in contact the outward normal of the contour the tool has traced."""
        if s.phase in (ContourPhase.APPROACH, ContourPhase.REAPPROACH) or s.contact_point is None:
            return s.normal
        return trace_normal(s, self.p.direction) or s.contact_normal

    def _judge_met(
        self, s: ContourState, ctx: TaskContext, met_n: float
    ) -> tuple[ContourState, tuple[Event, ...]]:
        """A re-tare doubts its sensor: a surface it reads on the way out counts once the drives' effort
        agrees with it (``_witness_tolerance_n``, as ``_verdict`` judges). The tool holds still for the effort's median window
        (the contact left behind still fills it) and then judges. An offset step pointing against the
        way out read, as the contact left behind faded, as another surface's rise (+10 N: the way out
        stopped 0.2 mm out, the tare was refused in contact, and the retract after it met 126 N).
        Without the witness, the sensor's word stands."""
        w, raw = ctx.force_witness_n, s.raw_force
        if w is None or raw is None:
            return self._met_on_way_out(replace(s, retare_held_cycles=0), met_n)
        if s.retare_held_cycles < cycles_in(WITNESS_MEDIAN_S, ctx.period_s):
            return replace(s, retare_held_cycles=s.retare_held_cycles + 1), ()
        s = replace(s, retare_held_cycles=0)
        tol = self._witness_tolerance_n(math.hypot(raw[0], raw[1]), math.hypot(w[0], w[1]))
        if math.hypot(raw[0] - w[0], raw[1] - w[1]) <= tol:
            return self._met_on_way_out(s, met_n)
        ev = Event(
            "contact_doubtful",
            Severity.WARNING,
            f"{met_n:.2f} N met on the way out of the contact, where the drives' effort says "
            f"{math.hypot(w[0], w[1]):.2f} N: the sensor's own; moving on",
        )
        return replace(s, guard_base_n=_against(raw, s.retare_direction, True), guard_rise_m=None), (ev,)

    def _met_on_way_out(self, s: ContourState, met_n: float) -> tuple[ContourState, tuple[Event, ...]]:
        """The way out of a contact met another surface (a slot's other wall, across from the one it
        pressed): the tare is taken halfway between the two, where the force began to rise being the
        other's. Going on pressed it at 84 N, with the guard's limit for leaving a contact, 60 N (an
        outside tester's 2 mm x 10 mm slot, 2026-12-06). Halfway from where the contact left behind
        stopped pushing (``retare_free_m``), not from where the way out began: the tool pressed that
        one there, and halfway from it took a tool whose other "surface" was a -5 N offset step back
        into the first contact at 21.6 N."""
        rise_m = s.guard_rise_m if s.guard_rise_m is not None else s.travel_m
        free_m = min(max(s.retare_free_m, 0.0), rise_m)
        back_to_m = 0.5 * (free_m + rise_m)
        ev = Event(
            "contour",
            Severity.WARNING,
            f"the way out of the contact met another surface at {met_n:.2f} N after {s.travel_m * 1000:.1f} mm; "
            f"back to {back_to_m * 1000:.1f} mm out, halfway from where the contact left behind let go, "
            "to re-tare there",
        )
        return replace(s, retare_met_m=back_to_m), (ev,)

    def _leaving(
        self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...]
    ) -> tuple[ContourState, tuple[Event, ...], TaskStep | None]:
        """A re-tare's motion: out along ``retare_direction`` for ``retare_clearance_m``, a guarded move
        (``_guarded_contact``, ``_judge_met``), or back to where another surface met on the way sends it
        (``_met_on_way_out``). (state, events, this cycle's step; None once there, for the tare)."""
        p, dt = self.p, ctx.period_s
        n = s.retare_direction  # _way_out, chosen as the re-tare began
        if s.retare_met_m < 0.0 and s.travel_m < p.retare_clearance_m:
            if (
                s.retare_free_m < 0.0
                and s.raw_force is not None
                and -_against(s.raw_force, n, False) < p.contact_force_n
            ):
                s = replace(s, retare_free_m=s.travel_m)  # the contact left behind no longer pushes
            s, met_n, guard_events = self._guarded_contact(s, n, p.search_speed_m_s, dt, leaving=True)
            events = (*events, *guard_events)
            if met_n is not None:
                s, judged = self._judge_met(s, ctx, met_n)
                events = (*events, *judged)
                if s.retare_held_cycles > 0:  # still for the drives' effort to tell
                    return s, events, self._moving(s, (0.0, 0.0, 0.0), dt, events=events)
        if s.retare_met_m >= 0.0 and s.travel_m > s.retare_met_m:  # back from the other surface
            step = min(p.search_speed_m_s * dt, s.travel_m - s.retare_met_m)
            if s.travel_m - step <= s.retare_met_m:  # there after this step: the tare's time starts now
                s = replace(s, phase_start_s=ctx.t_s, travel_m=s.retare_met_m + step)
            return (
                s,
                events,
                self._moving(
                    s, (-n[0] * step / dt, -n[1] * step / dt, 0.0), dt, events=events, travel_m=-step
                ),
            )
        if s.retare_met_m < 0.0 and s.travel_m < p.retare_clearance_m:
            if self._blind(s, dt):
                # blind, the way out would go on into whatever it meets: a sensor 90 ms stale took a
                # slot's way out into its far wall at 108 N (an outside tester's); still until it sees
                return s, events, self._moving(s, (0.0, 0.0, 0.0), dt, events=events)
            step = min(p.search_speed_m_s * dt, p.retare_clearance_m - s.travel_m)
            if s.travel_m + step >= p.retare_clearance_m:  # out after this step: the tare's time starts now
                s = replace(s, phase_start_s=ctx.t_s, travel_m=p.retare_clearance_m - step)
            return (
                s,
                events,
                self._moving(s, (n[0] * step / dt, n[1] * step / dt, 0.0), dt, events=events, travel_m=step),
            )
        return s, events, None

    def _retare(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p, dt = self.p, ctx.period_s
        s, events, moving = self._leaving(s, ctx, events)
        if moving is not None:
            return moving
        # Out of contact and at rest: free space, where the safety layer takes its own baseline too.
        settled = all(abs(v) <= p.settle_tolerance_m for v in ctx.setpoint.velocity)
        contact = ContactExpectation.NONE if settled else ContactExpectation.PRESSING
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, dt, contact)
        if not settled:
            return TaskStep(replace(s, phase_start_s=ctx.t_s), ref, events=events)
        s, offset, fault = self._taring(s, ctx)
        if fault:
            ev = Event("sensor_retare", Severity.FAULT, fault + "; retracting")
            return self._begin_retract(s, ctx, (*events, ev), fault)
        if offset is None:
            return TaskStep(s, ref, events=events)
        moved = math.sqrt(sum((a - b) ** 2 for a, b in zip(offset, s.offset)))
        ev = Event(
            "contour",
            Severity.INFO,
            f"sensor re-tared in free space: offset {tuple(round(o, 2) for o in offset)} N "
            f"({moved:.2f} N from the last)",
        )
        s = replace(
            s,
            offset=offset,
            force_f=(0.0, 0.0, 0.0),
            raw_force=None,
            held_force=None,
            suspect_cycles=0,
            bias_n=(0.0, 0.0),
            retare_why="",
            offset_doubt="",
        )
        if s.approached_m >= 0.0:  # back to the approach, with what it had travelled less the way out
            out_m = s.travel_m
            s = self._enter(s, ContourPhase.APPROACH, ctx.t_s, guard_base_n=0.0, guard_rise_m=None)
            s = replace(s, travel_m=max(0.0, s.approached_m - out_m), approached_m=-1.0)
            return self._moving(s, (0.0, 0.0, 0.0), dt, events=(*events, ev))
        s = self._start_reapproach(s, ctx)
        return self._moving(s, (0.0, 0.0, 0.0), dt, events=(*events, ev, self._attempt_event(s)))

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
        cp = s.contact_point if s.contact_point is not None else (x, y)
        if math.hypot(cp[0] - x, cp[1] - y) > STALE_CONTACT_POINT_M:
            # The last good contact is far back along the contour (the force was in doubt since): the
            # line to it would cut across the part. From here, along the normal estimated now.
            cp, n = (x, y), s.normal
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
            guard_base_n=0.0,
            guard_rise_m=None,
        )

    def _reapproach(self, s: ContourState, ctx: TaskContext) -> TaskStep:
        """A guarded move towards behind the last good contact point, at the approach speed."""
        p, dt = self.p, ctx.period_s
        d = s.reapproach_direction
        s, f_contact, guard_events = self._guarded_contact(s, d, p.approach_speed_m_s, dt)
        if f_contact is not None and s.raw_force is not None:
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
                force_f=s.raw_force,
            )
            return self._tracking(s, ctx, (*guard_events, ev))
        if s.travel_m >= s.reapproach_m:
            ev = Event(
                "reapproach_failed",
                Severity.WARNING,
                f"no contact within {s.reapproach_m * 1000:.1f} mm (attempt {s.attempts + 1} of "
                f"{p.max_reacquire_attempts}); backing off",
            )
            s = self._enter(s, ContourPhase.BACK_OFF, ctx.t_s, attempts=s.attempts + 1)
            return self._back_off(s, ctx, (*guard_events, ev))
        speed = p.approach_speed_m_s if self._trusted(s, ctx.period_s) else 0.0
        return self._moving(
            s, (d[0] * speed, d[1] * speed, 0.0), dt, events=guard_events, travel_m=speed * dt
        )

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
                return self._begin_retract(s, ctx, (*events, ev), why)
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
        ev = Event("sensor_breach", Severity.FAULT, why + "; retracting without the sensor's data")
        return self._begin_retract(replace(s, raw_force=None), ctx, (ev,), why)

    def _begin_retract(
        self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...], fault: str = ""
    ) -> TaskStep:
        """Away from the contour along the force measured now: the flank of a bump or a step, not the
        normal the task last estimated. The sensor's latest sample when it is trusted and strong
        enough to have a direction; else the drives' effort witness beyond its own error; else the
        last normal estimate."""
        p = self.p
        direction = s.normal
        raw, witness = s.raw_force, ctx.force_witness_n
        if (
            raw is not None
            and self._trusted(s, ctx.period_s)
            and math.hypot(raw[0], raw[1]) >= p.normal_min_force_n
        ):
            direction = _unit2(raw[0], raw[1]) or direction
        elif witness is not None and math.hypot(witness[0], witness[1]) > p.witness_tolerance_n:
            direction = _unit2(witness[0], witness[1]) or direction
        s = self._enter(s, ContourPhase.RETRACT, ctx.t_s, fault=fault or s.fault, retract_direction=direction)
        return self._retract(s, ctx, events)

    def _retract(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        p = self.p
        if s.travel_m >= p.retract_distance_m:
            s = replace(s, phase=ContourPhase.FINISHED, phase_start_s=ctx.t_s)
            return self._finished(s, ctx, (*events, Event("contour", Severity.INFO, "retracted")))
        d = s.retract_direction
        v = (d[0] * p.retract_speed_m_s, d[1] * p.retract_speed_m_s, 0.0)
        s = replace(s, speed_m_s=0.0)
        return self._moving(s, v, ctx.period_s, events=events, travel_m=p.retract_speed_m_s * ctx.period_s)

    def _finished(self, s: ContourState, ctx: TaskContext, events: tuple[Event, ...] = ()) -> TaskStep:
        s, ref = self._reference(s, (0.0, 0.0, 0.0), False, ctx.period_s)
        return TaskStep(s, ref, finished=True, fault=s.fault, events=events)
