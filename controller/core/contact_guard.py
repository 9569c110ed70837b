"""The contact guard: the safety layer's watch over contact, outside any task (DESIGN.md, "Off the happy path").

Safety does not rest on the task or on one sensor. Every cycle of an enabled robot the law judges
the contact force against what the task says about contact (``ContactExpectation``, carried by
its reference), with two witnesses:

- the force sensor's sample, less the guard's own **baseline** (the sensor's reading at rest in
  free space: taken while HOLDING, renewed whenever the task holds still in free space and the
  drives agree that nothing touches the tool);
- the **effort witness**: the contact force the drives' efforts (CiA 402 0x6077) imply through
  the robot's model, ``F = M a - J^T tau`` (``ForceWitnessModel``; Cheope's in
  controller/robots/cheope/model.py). It does not come from the sensor; its error is the model's
  (a linear motor's cogging, 2 N a carriage in the simulator: up to about 5.5 N at the tool,
  measured in contact) plus the inertia term's while the robot accelerates.

In a contact by design (``PRESSING``) the **limit acts on the larger of the two** (the witness
less the robot's own inertial load). In free space (``NONE``) the sensor judges while it is
trusted, and the witness, less its whole tolerance, past the contact limit only without it (its
error there is the robot's own fast motion: ``judged_force_n``); in a guarded move (``GUARDED``),
slow by design, that witness counts whatever the sensor says. Past the limit the motion ends with a
**protective back-off** (``BackOff``): the tool moves a few millimetres along the force the guard
trusts (where contact is expected, never along a sensor's force that the witness contradicts), at a
bounded speed and acceleration, comes to rest, and the law faults naming the cause.
A stop in place while pressing is never the reaction to a force: the CiA 402 quick stop stays the
reaction to bus and drive faults.

In contact by design the two are cross-checked every cycle both are fresh, each as the median of
its samples of the last WITNESS_MEDIAN_S (over a bus a late SYNC jolts the drives' efforts for a
few cycles; the sensor's median lags a rising force as much): when they disagree beyond the
witness's tolerance (``tolerance_n`` + ``tolerance_fraction`` of the larger + a share of the
inertia term) for ``disagreement_s`` in a row, the sensor is **suspect**: the task is told
(``TaskContext.sensor_suspect``) and must resolve it (a contour re-tares in free space); past
``sensor_suspect_s`` the law backs off along the witness and faults.

A sensor that goes on sending fresh samples, each the same to the last bit, is **frozen** (a stuck
ADC or firmware that repeats its last value with its counter still rolling): no real contact holds a
force that still, a sensor's own noise alone changes its counts every sample (0.05 N of noise at
0.01 N a count here). Pressing, ``sensor_frozen_s`` of such samples end the contact at once with a
back-off along what the witness and the contact's last normal say. It was only the cross-check that
caught it, once the true force had risen past the witness's tolerance: a sensor stuck at 10 N met a
notch's far wall at 100 N true, the witness's median then at 54 N (an outside tester, 2026-12-06).

Pure: no I/O, no clock; the state lives in ``ContactWatch`` and ``BackOff`` inside the
controller's state, so a recorded session replays bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from controller.core.cycle_data import CycleInputs, SensorFeedback
from controller.core.linalg3 import Vector3, dot3, norm3, sub3
from controller.core.periods import cycles_in
from controller.core.records import record, replace

ZERO3: Vector3 = (0.0, 0.0, 0.0)
PROTECTIVE_STOP = "protective stop"  # how the fault reason of a back-off begins
# The cross-check's windows are times, counted in cycles of the loop's period (core/periods.py), so
# that the guard judges a jolt of the drives' efforts alike at every rate. They were tuned at 400 Hz
# as 19 and 10 cycles; counted in cycles, at 1 kHz a jolt as long as the longest measured at 400 Hz
# (9 cycles, 22.5 ms) filled more than half of a 19-ms median, and 10 ms of disagreement made the
# sensor suspect: the 1-kHz contour demo over CAN FD lost 1.4 s of a lap to a brake and re-approach.
WITNESS_MEDIAN_S = 0.0475  # the witness is the median of its samples of this long (_median_of)
# ... and of three samples at least: below 42 Hz 47.5 ms is one cycle, and a "median" of one sample
# let a single late SYNC's jolt judge alone. The 25-Hz path of the vcan test with kernel SYNC, in
# the emulated VM whose loop wakes 10-40 ms late, stopped 31 cycles in on "contact force 62.7 N in
# free space (no sensor sample, drives' effort 121.4 N)" with nothing touching (CI, 4548c0c).
MIN_MEDIAN_SAMPLES = 3
# A sensor sample that did not arrive leaves the last one in charge this long (a stale or saturated
# one does not: that sensor says itself that something is wrong). Over a bus a hold-up of the loop
# loses the frames of a few cycles while the drives' efforts jolt; judged by the witness alone for
# such a cycle, a path run at 1 kHz on CAN FD met "contact force 62.5 N in free space (sensor
# 0.1 N, drives' effort 93.6 N)" with nothing touching (2 of 3 bench runs, aa8ee07). The sensor's
# longest silence in 24 contour demos over the bus was 1-6 cycles at 400 Hz (up to 15 ms); a sensor
# silent longer is judged without, by the witness, as before, and past safety.sensor_stale_s
# (100 ms of its own silence, loop.max_bus_silence_s of one every device shares) the law faults.
SENSOR_GAP_S = 0.02
# The path the tool came in on: the measured TCP, a point each time it has moved this far from the
# last one, the last TRAIL_POINTS of them (12 mm, more than a back-off's 5 mm). A back-off along the
# force that meets more force (wedged in a groove, backed into its other wall: 74 N; a jammed
# carriage let go mid-back-off: 178 N, the tool left pressed at 112 N by the quick stop; an outside
# tester, 2026-12-06) retraces it instead: the one motion known to be free is the one just made,
# which is also what industrial collision reactions do (they reverse along the path).
TRAIL_SPACING_M = 0.0005
TRAIL_POINTS = 24
# A retrace heads for the last point of the trail where the force was at most this share of the
# contact limit (30 N of 60), passing over those where it was higher (begin_retrace).
RETRACE_FORCE_FRACTION = 0.5
# A straight back-off whose force, having fallen, rises again 10 N past the least it fell to and past
# this share of the contact limit (15 N of 60) has met another wall, and retraces
# (control_law._guard_contact). At half the limit, a 1-mm ball wedged in a 2-mm slot turned at 46 N
# and went on to 81.8 N, a back-off steered by a frozen sensor at 38.8 N and 66.4 N; at a quarter
# 67.3 and 52.7 N (outside testers' scenarios, simulated time).
ANOTHER_WALL_FRACTION = 0.25
# A force rising fast goes on rising while the reaction takes effect: the back-off's first setpoint
# reaches the carriages through the step's pipeline and the drives' interpolation, and they must
# still brake what they were doing. A carriage jammed at lap speed (contour scan's laps, block:1 at
# 35.0 s) drove the part's force from 10 to 63 N in 7 cycles; the guard tripped at 62.9 N and the
# force went on for 5 cycles to 78.4 N. So where contact is sought or made the guard trips on the
# force as it will be when a reaction can stop it: the sample's size and its rise over
# ContactGuardConfig.reaction_s. That time is the reaction's, measured: tripped on the rise, with
# the back-off braking within its ramp (ContactGuardConfig.reaction_ramp_s), the jams at 35.0 and
# 35.2 s rose 27.2 N from 34.5 N at 4.4 N/ms and 31.7 N from 37.5 N at 5.1 N/ms, as a constant rise
# for 6.2 ms: 7.5 ms (3 periods at 400 Hz) holds them. The rise is the slower of the last two steps
# between trusted samples, so a single step (a sensor's offset jump, a spike, the samples of a
# hold-up's end) does not count: only a force rising sample after sample. And the drives must feel it
# rise too (their effort, each of its last two steps at least RISE_FELT_SHARE of the sensor's slower
# step): a sensor's offset ramping 40 N in 10 ms read as a force rising 3.0 N/ms while the drives'
# effort stood within 1 N of 12.5 N (the contour-stress row "offset step +40 N"); in the jam the
# effort rose 3.5 and 8.1 N beside the sensor's 11 and 12.8.
RISE_SAMPLES = 3
RISE_FELT_SHARE = 0.25
# The trail's points: x, y, z [m] of the measured TCP and the contact force judged there [N].
Trail = tuple[tuple[float, float, float, float], ...]
# The last samples of a force, an axis's each in a tuple of its own (oldest first): each median sorts
# one as it is, with no transposition of samples into axes (_median_of runs twice every cycle).
AxisWindows = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]


class ContactExpectation(IntEnum):
    """What a task's reference says about contact; the law's contact guard judges forces by it."""

    NONE = 0  # free space: a force above safety.contact.free_space_force_n is a collision
    GUARDED = 1  # a guarded move seeking contact at a bounded speed (approach, re-approach)
    PRESSING = 2  # in contact by design, up to safety.max_contact_force_n


@dataclass(frozen=True)
class ContactGuardConfig:
    """``[safety.contact]`` (controller/config.py), resolved once at assembly."""

    free_space_force_n: float = 10.0  # NONE: a force above this is a collision
    guarded_move_force_n: float = 25.0  # GUARDED: the task met contact and did not stop pushing
    max_contact_force_n: float = 60.0  # PRESSING: safety.max_contact_force_n
    max_contact_speed_m_s: float = 0.1  # a GUARDED or PRESSING reference faster than this: a fault
    witness_required: bool = True  # a task that reads the sensor runs only with the effort witness
    tolerance_n: float = 6.0  # the witness's own error (cogging, model)
    tolerance_fraction: float = 0.25  # ... plus this share of the larger force
    inertia_fraction: float = 1.0  # ... plus this share of the inertial load |M a|' (its recent peak, below)
    inertia_time_constant_s: float = (
        0.1  # the peak of |M a| fades with this: the structure rings after a move
    )
    disagreement_s: float = 0.025  # beyond the tolerance this long in a row: the sensor is suspect
    sensor_suspect_s: float = 2.0  # the task's time to resolve a suspect sensor; then the law backs off
    sensor_frozen_s: float = 0.025  # pressing, the same sample to the last bit this long: frozen (0: off)
    back_off_distance_m: float = 0.005
    back_off_speed_m_s: float = 0.02
    back_off_acceleration_m_s2: float = 0.5
    back_off_min_force_n: float = 2.0  # a trusted force weaker than this gives no direction: brake in place
    # How long a reaction takes to stop a force's rise (RISE_SAMPLES): 0, the limit alone.
    reaction_s: float = 0.0075


@record
class Witness:
    """The contact force the drives' efforts imply this cycle, and the model's own inertial load."""

    force_n: Vector3
    inertia_n: float  # |M a|: the share of the efforts that accelerates the robot itself


@record
class ContactWatch:
    """The guard's state between two cycles (inside ``ControllerState``)."""

    expectation: ContactExpectation = ContactExpectation.NONE  # the task's last reference's
    baseline_n: Vector3 = ZERO3  # the sensor's reading at rest in free space
    baseline_set: bool = False
    sensor_n: Vector3 | None = None  # the last usable sample, baseline removed
    witness: Witness | None = None  # the last witness
    dynamic_n: float = (
        0.0  # the recent peak of |M a|, fading: the structure rings after the robot accelerates
    )
    # the last setpoints' accelerations, newest last: a sample at this cycle's SYNC shows the drives'
    # motion towards the setpoint of three cycles ago (the step's pipeline, control_law.PIPELINE_PERIODS)
    accelerations: tuple[tuple[float, ...], ...] = ()
    witness_window: AxisWindows = ((), (), ())  # the last raw witnesses, for their median
    sensor_window: AxisWindows = ((), (), ())  # the last usable samples (baseline removed), for theirs
    force_n: float = 0.0  # the contact force the guard judged this cycle (the larger of the two)
    disagreeing: int = 0  # cycles in a row beyond the cross-check's tolerance
    agreeing: int = 0  # cycles in a row within it (``disagreement_s`` of them clear a suspicion)
    suspect: str = ""  # why the sensor is suspect ("" : it is not)
    suspect_cycle: int = 0  # since when
    reference_m: Vector3 | None = None  # the task's last reference TCP (its speed, a back-off's origin)
    # The direction (unit) of the last contact force sensor and witness agreed on while pressing: where
    # the part is. A back-off's direction when the sensor turns against it and the witness cannot
    # tell (back_off_direction); forgotten in free space.
    contact_normal: Vector3 | None = None
    trail_m: Trail = ()  # the measured TCP's path and the force there, newest last (extend_trail)
    last_raw_n: Vector3 | None = None  # the last usable sample as it came (baseline in)
    same_samples: int = 0  # fresh samples in a row, pressing, equal to the one before to the last bit
    # the last RISE_SAMPLES trusted samples' sizes where contact is sought or made, with their cycles,
    # oldest first (rising_n_per_s); emptied in free space
    rise: tuple[tuple[int, float], ...] = ()


@record
class BackOff:
    """A protective back-off in progress: along ``direction`` from ``origin_m`` (or, retracing, through
    ``path_m``), then at rest, then FAULT."""

    cause: str
    direction: Vector3 | None  # unit, the force the guard trusts; None: no force to move away from
    origin_m: Vector3
    entry_force_n: float
    travelled_m: float = 0.0
    speed_m_s: float = 0.0
    braking: bool = False
    cycles: int = 0  # since it began
    # Retracing (begin_retrace): the points of the path the tool came in on, from ``origin_m`` back,
    # and how far along them; empty: a straight back-off of ``back_off_distance_m`` along ``direction``.
    path_m: tuple[Vector3, ...] = ()
    distance_m: float = 0.0
    # The back-off goes against the sensor's force (the witness overruled it): the sensor no longer
    # judges whether the back-off meets more force (control_law, BACK_OFF_WORSE_N).
    sensor_overruled: bool = False
    least_force_n: float = math.inf  # the least force met since it began (control_law: a rise from it)
    # The trail as the back-off began (ContactWatch.trail_m): the way in, without the back-off's own
    # way, which a retrace must not follow back (in a slot it led into the wall backed off from first).
    trail_m: Trail = ()


def median_cycles(period_s: float) -> int:
    """The witness's median window in cycles: WITNESS_MEDIAN_S, an odd count so that the median is
    one sample (19 at 400 Hz, 49 at 1 kHz), and never fewer than MIN_MEDIAN_SAMPLES."""
    return max(MIN_MEDIAN_SAMPLES, cycles_in(WITNESS_MEDIAN_S, period_s)) | 1


def usable_sample(sensor: SensorFeedback | None, stale: bool) -> Vector3 | None:
    """The sensor's force when this cycle brought a usable sample (fresh, its counter advanced)."""
    if sensor is None or not sensor.fresh or stale:
        return None
    return sensor.force_n


def tolerance_n(cfg: ContactGuardConfig, sensor_n: float, witness: Witness, dynamic_n: float) -> float:
    """How far sensor and witness may disagree: the witness's error at this force and after this motion.

    Measured in the simulator (contour scan, 3 laps): in contact at rest or sliding, up to 7.4 N (the
    cogging); while the robot accelerates and for a while after it, the structure's ringing M x'' too,
    which the motors carry and the sensor does not: covered by the fading peak of |M a| (0.84 of it
    was the most any sample needed, with a 0.1-s fade).
    """
    return (
        cfg.tolerance_n
        + cfg.tolerance_fraction * max(sensor_n, norm3(witness.force_n))
        + cfg.inertia_fraction * dynamic_n
    )


def judged_force_n(
    cfg: ContactGuardConfig,
    expectation: ContactExpectation,
    sensor_n: Vector3 | None,
    witness: Witness | None,
    dynamic_n: float,
    sensor_trusted: bool = True,
) -> float:
    """The force the limits act on: the larger of the two witnesses in contact.

    In contact by design (``PRESSING``) the effort witness counts less the share of the robot's own
    motion in it: the limit is a safety limit. Elsewhere the robot moves freely and fast, and the
    witness's error is the drives' own accelerations: on a loaded machine a loopback path run read
    99.5-138 N of "effort" in free space with nothing touching (a median of 19 cycles, the sensor at
    0.1 N: 4 of 7 runs beside a CPU hog or the test suite). There the sensor judges while it is
    trusted (this cycle's sample, or a recent one whose successors went missing: ``SENSOR_GAP_S``;
    not suspect); without it the witness, less its whole tolerance, past the contact limit itself.
    In a guarded move that witness counts beside a trusted sensor too.
    """
    f_sensor = norm3(sensor_n) if sensor_n is not None else 0.0
    if witness is None:
        return f_sensor
    f_witness = norm3(witness.force_n)
    if expectation == ContactExpectation.PRESSING:
        return max(f_sensor, f_witness - cfg.inertia_fraction * dynamic_n)
    if sensor_trusted and expectation == ContactExpectation.NONE:
        return f_sensor
    # Without a trusted sensor, and in a guarded move whatever the sensor says: a guarded move pushes
    # until the sensor reports contact, so a sensor that stops reporting (frozen at a plausible value,
    # its counter still advancing) pushed the approach 40 mm into the part at 4 072 N with the
    # drives' effort at 314 N (an outside tester's scenario, 7dcefb5). Guarded moves are slow, so
    # the witness's free-space error (the robot's own fast motion) is not theirs.
    f_witness -= tolerance_n(cfg, 0.0, witness, dynamic_n)
    bar = cfg.guarded_move_force_n if expectation == ContactExpectation.GUARDED else cfg.max_contact_force_n
    return max(f_sensor, f_witness if f_witness > bar else 0.0)


def rising_n_per_s(rise: tuple[tuple[int, float], ...], period_s: float) -> float:
    """How fast the force rises: the slower of the last two steps between samples (RISE_SAMPLES, their
    cycles apart), 0 unless both rise."""
    if len(rise) < RISE_SAMPLES:
        return 0.0
    (c0, f0), (c1, f1), (c2, f2) = rise[-3:]
    return max(0.0, min((f1 - f0) / ((c1 - c0) * period_s), (f2 - f1) / ((c2 - c1) * period_s)))


def _next_rise(
    w: ContactWatch, fresh_n: Vector3 | None, trusted: bool, cycle: int
) -> tuple[tuple[int, float], ...]:
    """The watch's ``rise`` with this cycle's trusted fresh sample (``fresh_n``, baseline removed): emptied in
    free space and while the sensor is not trusted, so that a rise counts only samples the guard believes."""
    if w.expectation == ContactExpectation.NONE or not trusted:
        return ()
    if fresh_n is None:
        return w.rise
    return (*w.rise, (cycle, norm3(fresh_n)))[-RISE_SAMPLES:]


def _rising_past(cfg: ContactGuardConfig, w: ContactWatch, cycle: int, period_s: float, limit: float) -> str:
    """Why the force, rising sample after sample, will pass ``limit`` before a reaction begun now can
    stop it (``ContactGuardConfig.reaction_s``); "" where it will not."""
    rise = w.rise
    if len(rise) < RISE_SAMPLES or rise[-1][0] != cycle:
        return ""
    rate = rising_n_per_s(rise, period_s)
    ahead = rise[-1][1] + rate * cfg.reaction_s
    if rate <= 0.0 or ahead <= limit or not _felt_rising(w.witness_window, RISE_FELT_SHARE * rate * period_s):
        return ""
    return (
        f"contact force {rise[-1][1]:.1f} N {EXPECTATION_TEXT[w.expectation]} rising {rate / 1000.0:.1f} "
        f"N/ms: {ahead:.1f} N before a reaction can stop it ({cfg.reaction_s * 1000.0:g} ms), above "
        f"{limit:g} N ({_witnesses(w)})"
    )


def _last_sizes(window: AxisWindows) -> tuple[float, ...]:
    """The sizes of the last RISE_SAMPLES samples of ``window`` (oldest first); () with fewer."""
    x, y, z = window
    if len(x) < RISE_SAMPLES:
        return ()
    return tuple(norm3((x[i], y[i], z[i])) for i in range(-RISE_SAMPLES, 0))


def effort_floor_n(window: AxisWindows) -> float:
    """The least of the drives' effort's last RISE_SAMPLES raw sizes (``ContactWatch.witness_window``):
    a force it has held that long, as fast as the samples come. A late SYNC's jolt of the efforts
    lasts one cycle or a few over a bus; the witness's median, which rides those out, lags a force
    that rises by half its window."""
    sizes = _last_sizes(window)
    return min(sizes) if sizes else 0.0


def back_off_met_n(w: ContactWatch, effort_only: bool) -> float:
    """The force a back-off meets, judged as fast as the samples come: the sensor's last sample
    (baseline removed) and the drives' effort's floor (``effort_floor_n``), the larger; the effort's
    alone where the sensor is suspect or the back-off was steered against it. Not the judged force
    of ``watch``: the effort's median in it lags by half its window both ways, and a back-off met the
    other wall of a slot at 14 N a 5 ms, the median at 3.3 N where the efforts read 63.7 (a frozen
    sensor's, 139.6 N true); or it had not yet seen the first contact let go when the ball, wedged
    in a slot, met the other wall (the median at 44.8 N, the sensor at 6.4: 90.0 N true)."""
    floor = effort_floor_n(w.witness_window)
    if effort_only or w.sensor_n is None:
        return floor
    return max(norm3(w.sensor_n), floor)


def _felt_rising(window: AxisWindows, step_n: float) -> bool:
    """Whether the drives' effort (its last raw witnesses, ``ContactWatch.witness_window``) rose at
    least ``step_n`` at each of its last two steps."""
    sizes = _last_sizes(window)
    return bool(sizes) and sizes[1] - sizes[0] >= step_n and sizes[2] - sizes[1] >= step_n


def limit_n(cfg: ContactGuardConfig, expectation: ContactExpectation) -> float:
    if expectation == ContactExpectation.NONE:
        return cfg.free_space_force_n
    if expectation == ContactExpectation.GUARDED:
        return cfg.guarded_move_force_n
    return cfg.max_contact_force_n


EXPECTATION_TEXT = {
    ContactExpectation.NONE: "in free space (no contact expected)",
    ContactExpectation.GUARDED: "in a guarded move",
    ContactExpectation.PRESSING: "in contact",
}


def watch(
    cfg: ContactGuardConfig,
    w: ContactWatch,
    inputs: CycleInputs,
    stale: bool,
    witness: Witness | None,
    at_rest: bool,
    cycle: int,
    period_s: float,
    missing_cycles: int = 0,
    accelerations: tuple[tuple[float, ...], ...] | None = None,
    tcp_m: Vector3 | None = None,
) -> tuple[ContactWatch, str]:
    """One cycle of the guard: the updated watch and, past a limit, the cause of a protective back-off.

    ``missing_cycles``: cycles in a row the sensor's frame did not come (the safety monitor's count,
    ``ControllerState.sensor_missing``); within ``SENSOR_GAP_S`` the last sample still judges.
    ``accelerations``: the watch's new ``accelerations`` (the law's; ``witness`` was found with
    them), set in the same ``replace`` as the rest; None keeps the watch's. ``tcp_m``: the measured
    TCP, added to the trail a retrace follows (``extend_trail``).

    Locals first and one ``replace`` at the end: it runs every enabled cycle (budget: cycle_work.py)."""
    raw = usable_sample(inputs.sensor, stale)
    window, n_median = w.witness_window, median_cycles(period_s)
    if witness is not None:
        window, median = _median_of(window, witness.force_n, n_median)
        witness = Witness(median, witness.inertia_n)
    baseline, baseline_set = w.baseline_n, w.baseline_set
    if raw is not None and not baseline_set and norm3(raw) <= cfg.free_space_force_n:
        # The first usable sample while holding: the baseline is what the sensor reads at rest, unless
        # that already is a collision (the guard then trips on it below).
        baseline, baseline_set = raw, True
    sensor = sub3(raw, baseline) if raw is not None else w.sensor_n
    dynamic = w.dynamic_n * math.exp(-period_s / cfg.inertia_time_constant_s)
    if witness is not None and witness.inertia_n > dynamic:
        dynamic = witness.inertia_n
    if (
        raw is not None
        and at_rest
        and w.expectation == ContactExpectation.NONE
        and witness is not None
        and norm3(witness.force_n) <= tolerance_n(cfg, 0.0, witness, dynamic)
    ):
        # At rest in free space, and the drives feel nothing: what the sensor reads is its own offset
        # (a task re-tares it here too). Below the witness's tolerance a real touch and an offset look
        # alike to the guard; above it the witness says contact, and the baseline stays.
        baseline, sensor = raw, ZERO3
    sensor_window, normal = w.sensor_window, w.contact_normal
    if w.expectation == ContactExpectation.NONE:
        normal = None
    if witness is None:
        witness = w.witness
        check = (w.disagreeing, w.agreeing, w.suspect, w.suspect_cycle)
    elif raw is None or sensor is None:
        check = (w.disagreeing, w.agreeing, w.suspect, w.suspect_cycle)
    else:
        # the sensor's median over the witness's window: a force that rises in a few cycles (a
        # contact's first spike: 0 to 13 N in 30 ms on the kidney shape) is seen by both alike
        sensor_window, sensor_median = _median_of(sensor_window, sensor, n_median)
        check = _cross_check(cfg, w, sensor_median, witness, dynamic, cycle, period_s)
        size = norm3(sensor_median)
        if (
            w.expectation == ContactExpectation.PRESSING
            and check[0] == 0
            and size >= cfg.back_off_min_force_n
        ):
            normal = (sensor_median[0] / size, sensor_median[1] / size, sensor_median[2] / size)
    same, last_raw = w.same_samples, w.last_raw_n
    if raw is not None:
        same = same + 1 if raw == last_raw and w.expectation == ContactExpectation.PRESSING else 0
        last_raw = raw
    frozen = cfg.sensor_frozen_s > 0.0 and same >= cycles_in(cfg.sensor_frozen_s, period_s)
    if frozen and raw is not None:
        why = (
            f"it sent the same sample ({raw[0]:.2f}, {raw[1]:.2f}, {raw[2]:.2f}) N, to the last bit, "
            f"{same + 1} times in a row while pressing"
        )
        check = (check[0], 0, why, cycle)
    # trusted: this cycle's sample, or a recent one where the frame only went missing (SENSOR_GAP_S)
    trusted = not check[2] and (
        raw is not None or (not stale and sensor is not None and missing_cycles * period_s <= SENSOR_GAP_S)
    )
    force = judged_force_n(cfg, w.expectation, sensor, witness, dynamic, trusted)
    rise = _next_rise(w, sensor if raw is not None else None, trusted, cycle)
    w = replace(
        w,
        baseline_n=baseline,
        baseline_set=baseline_set,
        sensor_n=sensor,
        witness=witness,
        witness_window=window,
        sensor_window=sensor_window,
        dynamic_n=dynamic,
        disagreeing=check[0],
        agreeing=check[1],
        suspect=check[2],
        suspect_cycle=check[3],
        force_n=force,
        accelerations=w.accelerations if accelerations is None else accelerations,
        contact_normal=normal,
        trail_m=extend_trail(w.trail_m, tcp_m, force),
        last_raw_n=last_raw,
        same_samples=same,
        rise=rise,
    )
    limit = limit_n(cfg, w.expectation)
    if force > limit:
        return w, (
            f"contact force {force:.1f} N {EXPECTATION_TEXT[w.expectation]}, above {limit:g} N "
            f"({_witnesses(w)})"
        )
    rising = _rising_past(cfg, w, cycle, period_s, limit)
    if rising:
        return w, rising
    if frozen:
        return w, f"force sensor frozen: {w.suspect}"
    if w.suspect and (cycle - w.suspect_cycle) * period_s > cfg.sensor_suspect_s:
        return w, f"force sensor suspect for {cfg.sensor_suspect_s:g} s: {w.suspect}"
    return w, ""


def _median_of(window: AxisWindows, sample: Vector3, n: int) -> tuple[AxisWindows, Vector3]:
    """``sample`` appended to the last ``n`` (``median_cycles``), and each axis's median of them. Over a bus
    the drives' efforts jump for a cycle or a few where a late SYNC jolts a carriage (measured over
    udp_multicast: 25 such jumps in a 40-s contour run, the longest 9 cycles, the largest 155 N
    beside 10 N of contact; in simulated time none): the motors carry the jolt, the sensor does not."""
    x = (*window[0], sample[0])[-n:]
    y = (*window[1], sample[1])[-n:]
    z = (*window[2], sample[2])[-n:]
    k = len(x) // 2
    return (x, y, z), (sorted(x)[k], sorted(y)[k], sorted(z)[k])


def _witnesses(w: ContactWatch) -> str:
    s = f"sensor {norm3(w.sensor_n):.1f} N" if w.sensor_n is not None else "no sensor sample"
    return s + (f", drives' effort {norm3(w.witness.force_n):.1f} N" if w.witness is not None else "")


def _cross_check(
    cfg: ContactGuardConfig,
    w: ContactWatch,
    sensor: Vector3,
    witness: Witness,
    dynamic_n: float,
    cycle: int,
    period_s: float,
) -> tuple[int, int, str, int]:
    """Sensor against witness (both medians of the same cycles), in contact by design: there the
    sensor's word steers the task. In free space and guarded moves the sensor reads about nothing and
    the witness's error is all there is. The watch's (disagreeing, agreeing, suspect, suspect_cycle)
    after this cycle."""
    agreeing, needed = w.agreeing + 1, cycles_in(cfg.disagreement_s, period_s)
    if w.expectation != ContactExpectation.PRESSING:
        suspect = "" if agreeing >= needed else w.suspect
        return 0, agreeing, suspect, w.suspect_cycle
    gap = norm3(sub3(sensor, witness.force_n))
    if gap > tolerance_n(cfg, norm3(sensor), witness, dynamic_n):
        n = w.disagreeing + 1
        if n >= needed and not w.suspect:
            why = (
                f"it reads {norm3(sensor):.1f} N where the drives' effort says {norm3(witness.force_n):.1f} N "
                f"({gap:.1f} N apart for {n} cycles, {n * period_s * 1000.0:.0f} ms)"
            )
            return n, 0, why, cycle
        return n, 0, w.suspect, w.suspect_cycle
    suspect = "" if w.suspect and agreeing >= needed else w.suspect
    return 0, agreeing, suspect, w.suspect_cycle


def back_off_direction(
    cfg: ContactGuardConfig, w: ContactWatch, sensor_trusted: bool = True
) -> tuple[Vector3 | None, float]:
    """The force to move away from (unit) and its size: the sensor's when it is trusted, else the witness's.

    Only a witness beyond its own error (``_felt``) gives a direction: below it, its direction is
    cogging and the robot's own ringing (3.4 N pointing up and sideways backed a tool 1.7 mm into
    the part: 118 N true, 44dbcbc). Where contact is expected (pressing, a guarded move) that witness
    also overrules a sensor whose force points against its own: a spike or an offset step along the
    contact normal reads as a force out of the part, and backing off along it pushed the tool in
    (-75 N for 0.5 s in lap 1: tripped at 64.8 N, 177 N true, 7dcefb5); and it gives the direction
    when it judged the force (a stuck sensor). Where the witness cannot tell (the robot just braked,
    and its ringing is its error), a sensor that turned against the force both agreed on while
    pressing (``ContactWatch.contact_normal``) is not followed either: the part is where that force
    said (a +60 N step of the sensor's offset, backed off along, met 156 N true, 44dbcbc). In free
    space the robot's fast motion is the witness's error, and the sensor's direction stands."""
    sensor = w.sensor_n if sensor_trusted and not w.suspect else None
    if sensor is not None and norm3(sensor) < cfg.back_off_min_force_n:
        sensor = None  # the witness where the sensor tells nothing
    witness = w.witness.force_n if w.witness is not None and _felt(cfg, w.witness, w.dynamic_n) else None
    f = sensor
    if w.expectation == ContactExpectation.NONE:
        f = sensor if sensor is not None else witness
    elif witness is not None and (
        # further from the sensor than the witness can be from the truth, or the one that judged this
        # force (a sensor stuck at a plausible reading may point anywhere within 90 degrees of it)
        sensor is None or _contradicts(cfg, w, sensor, witness) or w.force_n > norm3(sensor)
    ):
        f = witness
    elif w.contact_normal is not None and (sensor is None or dot3(sensor, w.contact_normal) < 0.0):
        return w.contact_normal, max(w.force_n, norm3(sensor) if sensor is not None else 0.0)
    if f is None:
        return None, 0.0
    size = norm3(f)
    return (f[0] / size, f[1] / size, f[2] / size), size


def _contradicts(cfg: ContactGuardConfig, w: ContactWatch, sensor: Vector3, witness: Vector3) -> bool:
    """The witness (felt: beyond its own error) says the sensor's force points the wrong way.

    Within its error ``e`` of the truth, the witness points at most asin(e / |witness|) from it; a
    sensor twice that far from the witness is itself that far from the truth at least. More than
    90 degrees apart is always wrong. A sensor with its X and Y swapped (wired or mounted so) read a
    contact along the normal as one along the tangent, 90 degrees from its effort: the back-off went
    along the sensor's force and slid the tool along the part at 25 N (an outside tester's)."""
    between = dot3(sensor, witness)
    if between < 0.0:
        return True
    sine = min(1.0, tolerance_n(cfg, 0.0, w.witness, w.dynamic_n) / norm3(witness)) if w.witness else 1.0
    # cos(2 asin(sine)) = 1 - 2 sine^2
    return between < (1.0 - 2.0 * sine * sine) * norm3(sensor) * norm3(witness)


def _felt(cfg: ContactGuardConfig, witness: Witness, dynamic_n: float) -> bool:
    """The witness reads more than its own error (``tolerance_n``): a direction of its own. Below it
    (a few newtons of cogging before a sudden collision, which its median has not yet seen) it must
    not steer a back-off away from the sensor's true force."""
    return norm3(witness.force_n) > tolerance_n(cfg, 0.0, witness, dynamic_n)


def begin_back_off(
    cfg: ContactGuardConfig, w: ContactWatch, cause: str, origin_m: Vector3, sensor_trusted: bool = True
) -> BackOff:
    direction, size = back_off_direction(cfg, w, sensor_trusted)
    overruled = direction is not None and w.sensor_n is not None and dot3(direction, w.sensor_n) < 0.0
    return BackOff(
        cause, direction, origin_m, max(size, w.force_n), trail_m=w.trail_m, sensor_overruled=overruled
    )


def extend_trail(trail: Trail, tcp_m: Vector3 | None, force_n: float) -> Trail:
    """``trail`` with the measured TCP ``tcp_m`` and the force judged there added where it has moved
    ``TRAIL_SPACING_M`` from the trail's last point, the oldest dropped past ``TRAIL_POINTS``; as it
    was otherwise (every cycle: no new tuple while the tool stands or creeps)."""
    if tcp_m is None:
        return trail
    if trail:
        last = trail[-1]
        dx, dy, dz = tcp_m[0] - last[0], tcp_m[1] - last[1], tcp_m[2] - last[2]
        if dx * dx + dy * dy + dz * dz < TRAIL_SPACING_M * TRAIL_SPACING_M:
            return trail
    point = (tcp_m[0], tcp_m[1], tcp_m[2], force_n)
    return (*trail[1 - TRAIL_POINTS :], point) if len(trail) >= TRAIL_POINTS else (*trail, point)


def begin_retrace(cfg: ContactGuardConfig, b: BackOff, origin_m: Vector3, met_n: float) -> BackOff | None:
    """The back-off ``b`` met ``met_n``, more force than it started from: from ``origin_m`` (the
    measured TCP) straight to the last point of the path the tool came in on before the back-off
    (``b.trail_m``, newest last) where the force was at most RETRACE_FORCE_FRACTION of the contact
    limit, then on back along that path ``back_off_distance_m``, or all of it there is. The points of
    the collision that began the back-off are passed over, and the back-off's own way is not in it: a
    point probe in a 2-mm slot, backed off from one wall into the other, went back through its own way
    to the first (88 N, quick stop, left pressed at 84 N). None where no such point is left: nothing
    to retrace (the quick stop, as before)."""
    calm = RETRACE_FORCE_FRACTION * cfg.max_contact_force_n
    older = [(p[0], p[1], p[2]) for p in reversed(b.trail_m)]
    forces = [p[3] for p in reversed(b.trail_m)]
    start = next((k for k, f in enumerate(forces) if f <= calm), None)
    if start is None:
        return None
    # the calm point, then back along the way in until back_off_distance_m of it is covered
    points, length = [older[start]], 0.0
    for q in older[start + 1 :]:
        if length >= cfg.back_off_distance_m:
            break
        length += norm3(sub3(q, points[-1]))
        points.append(q)
    if norm3(sub3(points[0], origin_m)) < TRAIL_SPACING_M:  # it is where the tool stands: on from the next
        length -= norm3(sub3(points[1], points[0])) if len(points) > 1 else 0.0
        points.pop(0)
    to_first = norm3(sub3(points[0], origin_m)) if points else 0.0
    if not points or to_first + length < 2 * TRAIL_SPACING_M:
        return None
    d = sub3(points[0], origin_m)
    cause = f"{back_off_summary(b).removeprefix(PROTECTIVE_STOP + ': ')}, and met {met_n:.1f} N backing off"
    return BackOff(
        cause,
        (d[0] / to_first, d[1] / to_first, d[2] / to_first),
        origin_m,
        met_n,
        path_m=tuple(points),
        distance_m=to_first + min(length, cfg.back_off_distance_m),
        trail_m=b.trail_m,
    )


def advance_back_off(
    cfg: ContactGuardConfig, b: BackOff, period_s: float
) -> tuple[BackOff, Vector3, Vector3]:
    """One period of the back-off's TCP motion: (state, position, velocity). Trapezoidal in speed,
    braking to stop at the distance; without a direction the TCP stays where it was."""
    b = replace(b, cycles=b.cycles + 1)
    if b.direction is None or b.braking:
        return replace(b, speed_m_s=0.0, braking=True), _along(b, b.travelled_m)[0], ZERO3
    a, v_max = cfg.back_off_acceleration_m_s2, cfg.back_off_speed_m_s
    distance = b.distance_m if b.path_m else cfg.back_off_distance_m
    left = distance - b.travelled_m
    # up at a, never faster than v_max, nor than what still stops within the rest after this period's
    # step (v T + v^2 / 2a <= left), down at a
    stoppable = a * (math.sqrt(period_s * period_s + 2.0 * left / a) - period_s)
    v = min(v_max, b.speed_m_s + a * period_s, max(b.speed_m_s - a * period_s, stoppable))
    step = min(v * period_s, left)
    travelled = b.travelled_m + step
    done = distance - travelled <= 1e-9
    b = replace(b, travelled_m=travelled, speed_m_s=0.0 if done else v, braking=done)
    p, d = _along(b, travelled)
    velocity = ZERO3 if done else (d[0] * v, d[1] * v, d[2] * v)
    return b, p, velocity


def _along(b: BackOff, s: float) -> tuple[Vector3, Vector3]:
    """The point ``s`` along the back-off and its heading (unit): along ``direction`` from the origin,
    or, retracing, through ``path_m``'s points (past the last, its last)."""
    d, o = b.direction, b.origin_m
    if d is None:
        return o, ZERO3
    for p in b.path_m:
        seg = sub3(p, o)
        n = norm3(seg)
        if n < 1e-12:  # a point where the last one was: no heading of its own
            continue
        heading = (seg[0] / n, seg[1] / n, seg[2] / n)
        if s <= n:
            return (o[0] + heading[0] * s, o[1] + heading[1] * s, o[2] + heading[2] * s), heading
        s, o, d = s - n, p, heading
    if b.path_m:
        return o, d
    return (o[0] + d[0] * s, o[1] + d[1] * s, o[2] + d[2] * s), d


def back_off_summary(b: BackOff) -> str:
    if b.direction is None:
        return f"{PROTECTIVE_STOP}: {b.cause}; no force to move away from, braked in place"
    if b.path_m:
        return (
            f"{PROTECTIVE_STOP}: {b.cause}; retraced {b.travelled_m * 1000:.1f} mm of the path it came in on"
        )
    d = b.direction
    return (
        f"{PROTECTIVE_STOP}: {b.cause}; backed off {b.travelled_m * 1000:.1f} mm along "
        f"({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f})"
    )
