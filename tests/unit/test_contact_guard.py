"""The contact guard (controller/core/contact_guard.py): outside any task, on two witnesses.

Its pure parts against hand-made inputs, Cheope's effort witness against its Jacobian and mass
model, and the law in closed loop with the simulated devices in simulated time (no bus, no clock):
a force where no contact is expected ends the motion with a protective stop that backs off along
the force with the drives enabled, never a quick stop in place.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from controller.assembly import build_law, build_robot
from controller.config import ConfigError, load_config
from controller.core.cia402 import PowerState, decode_statusword
from controller.core.contact_guard import (
    SENSOR_GAP_S,
    TRAIL_POINTS,
    TRAIL_SPACING_M,
    ContactGuardConfig,
    ContactWatch,
    Witness,
    advance_back_off,
    back_off_met_n,
    back_off_summary,
    begin_back_off,
    begin_retrace,
    effort_floor_n,
    extend_trail,
    judged_force_n,
    median_cycles,
    watch,
)
from controller.core.controller_state import Mode
from controller.core.cycle_data import CycleInputs, DriveFeedback, SensorFeedback
from controller.core.periods import cycles_in
from controller.core.ports import ContactExpectation
from controller.core.records import replace
from controller.robots.performance import cartesian_mass_matrix
from controller.shell.loop import CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange

# The cross-check's tests feed one sample again and again; a real sensor's noise changes it every
# sample, and the same sample to the last bit while pressing is a frozen sensor (its own test).
CFG = ContactGuardConfig(sensor_frozen_s=0.0)
DT = 0.0025
MEDIAN = median_cycles(DT)  # the witness's median window at DT, in cycles
NEEDED = cycles_in(CFG.disagreement_s, DT)  # cycles of disagreement that make the sensor suspect


def _inputs(force) -> CycleInputs:
    drives = tuple(DriveFeedback(0x1637, 0.55, True, 0.0) for _ in range(3))
    return CycleInputs(drives, SensorFeedback(tuple(force), (0.0, 0.0, 0.0), 0, 1, True))


def test_the_limits_act_on_the_larger_of_sensor_and_witness():
    """A sensor reading low is no licence: the witness counts, less its own error where contact is
    not expected (its cogging must not stop a free move), as it reads while pressing."""
    sensor, witness = (2.0, 0.0, 0.0), Witness((30.0, 0.0, 0.0), 0.0)
    free = judged_force_n(CFG, ContactExpectation.NONE, sensor, witness, 0.0)
    pressing = judged_force_n(CFG, ContactExpectation.PRESSING, sensor, witness, 0.0)
    assert pressing == pytest.approx(30.0)
    assert free == pytest.approx(2.0)  # in free space the sensor judges the low limit ...
    big = Witness((90.0, 0.0, 0.0), 0.0)
    assert judged_force_n(CFG, ContactExpectation.NONE, sensor, big, 0.0) == pytest.approx(2.0)
    # ... while it is trusted; without it (stale, suspect) the witness judges a collision past the
    # contact limit, less its whole tolerance
    collision = judged_force_n(CFG, ContactExpectation.NONE, sensor, big, 0.0, sensor_trusted=False)
    assert collision == pytest.approx(90.0 - CFG.tolerance_n - CFG.tolerance_fraction * 90.0)
    w = ContactWatch(sensor_n=(0.0, 45.0, 0.0), witness=Witness((0.0, 3.0, 0.0), 0.0))
    assert judged_force_n(CFG, w.expectation, w.sensor_n, w.witness, 0.0) == pytest.approx(
        45.0
    )  # a sensor reading high counts as it reads


def test_in_a_guarded_move_the_drives_outvote_a_trusted_sensor_that_reads_nothing():
    """A sensor stuck at a plausible value is fresh and trusted; a guarded move pushes until it
    reports contact. The witness past the guarded limit and its own tolerance stops it; below that
    (the witness's error) and in free space (the robot's fast motion) the sensor judges alone."""
    sensor = (0.5, 0.0, 0.0)
    pushing = Witness((60.0, 0.0, 0.0), 0.0)
    guarded = judged_force_n(CFG, ContactExpectation.GUARDED, sensor, pushing, 0.0)
    assert guarded == pytest.approx(60.0 - CFG.tolerance_n - CFG.tolerance_fraction * 60.0)
    assert guarded > CFG.guarded_move_force_n
    weak = Witness((35.0, 0.0, 0.0), 0.0)  # 35 - 6 - 8.75 = 20.25 N: within the witness's error
    assert judged_force_n(CFG, ContactExpectation.GUARDED, sensor, weak, 0.0) == pytest.approx(0.5)
    assert judged_force_n(CFG, ContactExpectation.NONE, sensor, pushing, 0.0) == pytest.approx(0.5)
    # the robot's own recent acceleration widens the tolerance
    assert judged_force_n(CFG, ContactExpectation.GUARDED, sensor, pushing, 30.0) == pytest.approx(0.5)


def test_a_back_off_never_follows_a_sensor_force_the_drives_feel_reversed_where_contact_is_expected():
    sensor, witness = (30.0, 0.0, 0.0), Witness((-12.0, 1.0, 0.0), 0.0)
    for expectation in (ContactExpectation.PRESSING, ContactExpectation.GUARDED):
        w = ContactWatch(expectation=expectation, sensor_n=sensor, witness=witness, force_n=30.0)
        d = begin_back_off(CFG, w, "test", (0.0, 0.0, 0.5)).direction
        assert d is not None and d[0] < -0.99  # along the drives' effort
    # the same directions in free space: the witness there is the robot's motion, the sensor's stands
    free = ContactWatch(expectation=ContactExpectation.NONE, sensor_n=sensor, witness=witness, force_n=30.0)
    assert begin_back_off(CFG, free, "test", (0.0, 0.0, 0.5)).direction == pytest.approx((1.0, 0.0, 0.0))
    # a witness within its own error (cogging: 3.5 N in an approach) contradicts nothing: a sudden
    # collision the sensor reads at once, before the witness's median moves, is backed off from
    for expectation in (ContactExpectation.PRESSING, ContactExpectation.GUARDED):
        quiet = ContactWatch(
            expectation=expectation, sensor_n=sensor, witness=Witness((-3.0, 1.0, 1.3), 0.0), force_n=30.0
        )
        assert begin_back_off(CFG, quiet, "test", (0.0, 0.0, 0.5)).direction == pytest.approx((1.0, 0.0, 0.0))
    # the witness judged the force (a sensor stuck at a few newtons within 90 degrees of the truth):
    # the witness's direction
    stuck = ContactWatch(
        expectation=ContactExpectation.GUARDED,
        sensor_n=(3.0, 0.0, 0.0),
        witness=Witness((30.0, 40.0, 0.0), 0.0),
        force_n=judged_force_n(
            CFG, ContactExpectation.GUARDED, (3.0, 0.0, 0.0), Witness((30.0, 40.0, 0.0), 0.0), 0.0
        ),
    )
    assert begin_back_off(CFG, stuck, "test", (0.0, 0.0, 0.5)).direction == pytest.approx((0.6, 0.8, 0.0))
    # agreeing (within 90 degrees): the sensor's direction, the finer of the two
    agree = ContactWatch(
        expectation=ContactExpectation.PRESSING, sensor_n=sensor, witness=Witness((5.0, 8.0, 0.0), 0.0)
    )
    assert begin_back_off(CFG, agree, "test", (0.0, 0.0, 0.5)).direction == pytest.approx((1.0, 0.0, 0.0))


def test_a_sensor_further_from_the_witness_than_the_witness_can_be_from_the_truth_is_not_followed():
    """A sensor with its X and Y swapped reads a contact along the normal (+x here) as one along the
    tangent: 90 degrees from the drives' effort, which is within 36 degrees of the truth at 17 N (its
    error 6 N + a quarter). The back-off slid along the part at 25 N (an outside tester's); it goes
    along the effort. A sensor within the witness's own error of it keeps its finer direction."""
    witness = Witness((17.4, 0.6, 0.0), 0.0)
    for expectation in (ContactExpectation.PRESSING, ContactExpectation.GUARDED):
        swapped = ContactWatch(
            expectation=expectation, sensor_n=(0.6, 25.4, 0.0), witness=witness, force_n=25.4
        )
        d = begin_back_off(CFG, swapped, "test", (0.0, 0.0, 0.5)).direction
        assert d is not None and d[0] > 0.99
        tilted = replace(swapped, sensor_n=(23.9, 8.7, 0.0))  # 20 degrees off the witness
        assert begin_back_off(CFG, tilted, "test", (0.0, 0.0, 0.5)).direction == pytest.approx(
            (0.9397, 0.3420, 0.0), abs=1e-3
        )
    # a weak witness (its error nearly its size) contradicts only a sensor more than 90 degrees off
    weak = ContactWatch(
        expectation=ContactExpectation.PRESSING,
        sensor_n=(0.6, 25.4, 0.0),
        witness=Witness((9.0, 0.0, 0.0), 0.0),
        force_n=25.4,
    )
    assert begin_back_off(CFG, weak, "test", (0.0, 0.0, 0.5)).direction == pytest.approx(
        (0.0236, 0.9997, 0.0), abs=1e-3
    )


def test_a_sensor_turned_against_the_force_both_agreed_on_is_not_backed_off_along_while_the_witness_cannot_tell():
    """An outside tester's +60 N step of the sensor's offset in lap 2 (44dbcbc): the task braked on
    the implausible step, the robot's ringing (27.8 N of |M a|) hid the drives' 14.8 N of contact in
    their own error, and the back-off followed the sensor into the part: 156 N true. The direction
    both witnesses agreed on while pressing says where the part is."""
    w = ContactWatch(expectation=ContactExpectation.PRESSING, baseline_set=True)
    truth = (-9.5, 4.0, 0.0)  # the part pushes the tool towards -x
    for cycle in range(MEDIAN + NEEDED):
        w, _ = watch(CFG, w, _inputs(truth), False, Witness((-12.9, 6.5, 1.0), 0.0), False, cycle, DT)
    assert w.contact_normal is not None and w.contact_normal[0] < -0.9
    ringing = Witness((-12.9, 7.2, 0.2), 27.8)  # within its own error (6 + 0.25 x 14.8 + 27.8 N)
    stepped = _inputs((60.1, 0.2, -0.1))
    cause = ""
    for cycle in range(100, 100 + MEDIAN):
        w, cause = watch(CFG, w, stepped, False, ringing, False, cycle, DT)
        if cause:
            break
    assert "above 60 N" in cause
    d = begin_back_off(CFG, w, cause, (0.0, 0.0, 0.5)).direction
    assert d is not None and d[0] < -0.9  # away from the part, not along the sensor's +x
    # the same step with no agreed contact yet (a collision the sensor reads before the witness's
    # median moves): the sensor's direction, as before
    fresh = replace(w, contact_normal=None)
    assert begin_back_off(CFG, fresh, cause, (0.0, 0.0, 0.5)).direction == pytest.approx(
        (1.0, 0.0, 0.0), abs=0.01
    )
    # free space forgets the contact
    w, _ = watch(
        CFG,
        replace(w, expectation=ContactExpectation.NONE),
        _inputs((0.0, 0.0, 0.0)),
        False,
        ringing,
        False,
        200,
        DT,
    )
    assert w.contact_normal is None


def test_a_witness_within_its_own_error_gives_no_direction_to_back_off_along():
    """The sensor untrusted (an implausible step) and the witness at 3.4 N, pointing up and sideways
    (cogging, ringing): a back-off along it went 1.7 mm into the part, 118 N true (44dbcbc). Without
    a contact both agreed on, the tool brakes in place; with one, it backs off along that."""
    noise = Witness((-0.8, 2.9, 1.5), 20.3)
    w = ContactWatch(
        expectation=ContactExpectation.PRESSING, sensor_n=(-60.0, 0.1, -0.1), witness=noise, force_n=60.0
    )
    assert begin_back_off(CFG, w, "test", (0.0, 0.0, 0.5), sensor_trusted=False).direction is None
    known = replace(w, contact_normal=(0.94, -0.34, 0.0))
    assert begin_back_off(CFG, known, "test", (0.0, 0.0, 0.5), sensor_trusted=False).direction == (
        0.94,
        -0.34,
        0.0,
    )
    # trusted, the sensor's -x against the agreed +x: the agreed direction too
    assert begin_back_off(CFG, known, "test", (0.0, 0.0, 0.5)).direction == (0.94, -0.34, 0.0)
    free = replace(w, expectation=ContactExpectation.NONE)
    assert begin_back_off(CFG, free, "test", (0.0, 0.0, 0.5), sensor_trusted=False).direction is None


def test_a_force_where_no_contact_is_expected_trips_the_guard_and_names_both_witnesses():
    w = ContactWatch(expectation=ContactExpectation.NONE)
    w, cause = watch(CFG, w, _inputs((0.1, 0.0, 0.0)), False, Witness((0.0, 0.0, 0.0), 0.0), False, 1, DT)
    assert not cause and w.baseline_set  # the first sample at rest: the baseline
    w, cause = watch(CFG, w, _inputs((12.0, 0.0, 0.0)), False, Witness((9.0, 0.0, 0.0), 0.0), False, 2, DT)
    assert "in free space" in cause and "sensor 11.9 N" in cause and "drives' effort 9.0 N" in cause
    w = replace(w, expectation=ContactExpectation.NONE)  # the drives' effort alone, within its error: no trip
    w, cause = watch(CFG, w, _inputs((0.1, 0.0, 0.0)), False, Witness((40.0, 0.0, 0.0), 30.0), False, 3, DT)
    assert not cause
    # the same force while pressing is within the contact's limit
    w = replace(w, expectation=ContactExpectation.PRESSING)
    w, cause = watch(CFG, w, _inputs((12.0, 0.0, 0.0)), False, Witness((9.0, 0.0, 0.0), 0.0), False, 3, DT)
    assert not cause


def _fed(cfg: ContactGuardConfig, expectation: ContactExpectation, samples) -> list[str]:
    """The guard's causes for the samples (cycle, force along x), the drives' effort agreeing."""
    w = ContactWatch(expectation=expectation, baseline_set=True)
    causes = []
    for cycle, fx in samples:
        w, cause = watch(
            cfg, w, _inputs((fx, 0.0, 0.0)), False, Witness((fx, 0.0, 0.0), 0.0), False, cycle, DT
        )
        causes.append(cause)
    return causes


def test_a_force_rising_sample_after_sample_trips_the_guard_before_it_reaches_the_limit():
    """A carriage jammed at lap speed drove the part's force from 10 to 63 N in 7 cycles; tripped at
    the limit, the force went on to 78.4 N. Rising 10 N a cycle (4 N/ms), 38 N is 68 N when a
    reaction (reaction_s, 7.5 ms) can stop it; 28 N is 58 N: the guard trips on the 38-N sample."""
    ramp = [(0, 8.0), (1, 8.05), (2, 7.98), (3, 18.0), (4, 28.0), (5, 38.0), (6, 48.0)]
    causes = _fed(CFG, ContactExpectation.PRESSING, ramp)
    assert causes[:5] == [""] * 5
    assert "contact force 38.0 N in contact rising 4.0 N/ms: 68.0 N" in causes[5], causes[5]
    assert "(7.5 ms), above 60 N" in causes[5]
    # the same in a guarded move, against its own limit (25 N): 18 N is not judged (the step before
    # it did not rise), 28 N is past it already, and a slower rise trips below it
    guarded = _fed(CFG, ContactExpectation.GUARDED, ramp)
    assert not guarded[3] and "28.0 N in a guarded move, above 25 N" in guarded[4]
    slow = [(0, 5.0), (1, 10.0), (2, 15.0), (3, 20.0)]  # 2 N/ms: 15 N is 30 N
    assert (
        "15.0 N in a guarded move rising 2.0 N/ms: 30.0 N" in _fed(CFG, ContactExpectation.GUARDED, slow)[2]
    )
    # without the reaction's time, the limit alone
    assert not any(_fed(replace(CFG, reaction_s=0.0), ContactExpectation.PRESSING, ramp))


def test_a_single_step_of_the_sensor_is_no_rise_only_samples_rising_one_after_another():
    """A sensor's offset jumping 35 N (or a spike, or the first sample after a hold-up) is one step: the
    slower of the last two steps is the rise. A frame that went missing spreads the step over its
    cycles."""
    step = [(0, 10.0), (1, 10.02), (2, 45.0), (3, 45.03), (4, 44.98), (5, 45.01)]
    assert not any(_fed(CFG, ContactExpectation.PRESSING, step))
    # 20, 30, then 50 two cycles later (a frame missing): 4 N/ms, not 8
    gap = [(0, 20.0), (1, 30.0), (3, 50.0)]
    assert "rising 4.0 N/ms" in _fed(CFG, ContactExpectation.PRESSING, gap)[2]


def test_a_rise_the_drives_do_not_feel_is_the_sensors_own():
    """A sensor's offset ramping 40 N in 10 ms rose 10 N a sample while the drives' effort stood at
    12.5 N (the contour-stress row "offset step +40 N"): no trip before the limit itself."""
    w = ContactWatch(expectation=ContactExpectation.PRESSING, baseline_set=True)
    causes = []
    for cycle, fx in enumerate((12.0, 12.02, 11.98, 22.0, 32.0, 42.0, 52.0, 52.01)):
        effort = Witness((12.5 + 0.3 * (cycle % 2), 0.0, 0.0), 0.0)  # the cogging's ripple, no more
        w, cause = watch(CFG, w, _inputs((fx, 0.0, 0.0)), False, effort, False, cycle, DT)
        causes.append(cause)
    assert not any(causes), causes


def test_the_efforts_floor_is_a_force_held_three_samples_not_one_jolt():
    """A back-off judged by the drives alone reads the least of their last three samples: a late
    SYNC's jolt of one sample is not there, a wall met is, two samples after it is felt."""
    jolt: tuple[tuple[float, ...], ...] = ((5.0, 155.0, 5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert effort_floor_n(jolt) == pytest.approx(5.0)
    wall = ((9.0, 30.0, 40.0, 55.0), (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))
    assert effort_floor_n(wall) == pytest.approx(30.0)
    assert effort_floor_n(((1.0, 2.0), (0.0, 0.0), (0.0, 0.0))) == 0.0  # not yet three samples


def test_a_back_off_meets_the_sensors_sample_or_the_efforts_floor_never_their_lagging_medians():
    """What a back-off meets: the larger of the sensor's last sample and the efforts' floor; the
    floor alone when the sensor is suspect or was overruled. Not the medians, which still held the
    first wall's 44.8 N when the sensor read 6.4 N on the way to the other one."""
    window = ((40.0, 45.0, 50.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    w = ContactWatch(sensor_n=(0.0, 6.4, 0.0), witness=Witness((44.8, 0.0, 0.0), 0.0), witness_window=window)
    assert back_off_met_n(w, effort_only=False) == pytest.approx(40.0)
    quiet = replace(w, witness_window=((1.0, 2.0, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    assert back_off_met_n(quiet, effort_only=False) == pytest.approx(6.4)
    assert back_off_met_n(quiet, effort_only=True) == pytest.approx(1.0)


def test_a_force_rising_in_free_space_is_judged_by_the_free_space_limit_alone():
    """In free space the robot moves fast and the sensor feels the tool's own acceleration: the rise is
    not judged there (and a collision's force is past the free-space limit at once)."""
    rising = [(k, 2.0 * k) for k in range(5)]  # up to 8 N, rising 0.8 N/ms
    assert not any(_fed(CFG, ContactExpectation.NONE, rising))


def test_a_missing_sensor_frame_leaves_the_last_sample_in_charge_for_a_while_in_free_space():
    """Over a bus a hold-up loses a few frames while the drives' efforts jolt (a path run at 1 kHz read
    93.6 N of effort with nothing touching): a missing frame is no collision. A sensor silent longer
    than SENSOR_GAP_S, or one whose sample is stale, leaves the witness to judge, as before."""
    jolt = Witness((120.0, 0.0, 0.0), 0.0)  # past the contact limit less the witness's tolerance
    w = ContactWatch(expectation=ContactExpectation.NONE)
    for k in range(MEDIAN):  # the sensor fresh and near nothing: it judges
        w, cause = watch(CFG, w, _inputs((0.1, 0.0, 0.0)), False, jolt, False, k, DT)
        assert not cause
    drives = _inputs((0.0, 0.0, 0.0)).drives
    # the last sample repeated, not fresh: its frame did not come (the safety monitor counts them)
    silent = CycleInputs(drives, SensorFeedback((0.1, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 1, False))
    within = int(SENSOR_GAP_S / DT)
    after_sample = w
    for k in range(1, within + 1):  # frames missing, the last sample recent: still no collision
        w, cause = watch(CFG, w, silent, False, jolt, False, 100 + k, DT, missing_cycles=k)
        assert not cause, k
    # silent longer: the witness judges
    w, cause = watch(CFG, w, silent, False, jolt, False, 200, DT, missing_cycles=within + 1)
    assert "in free space" in cause and "drives' effort 120.0 N" in cause
    # a sample that came but is stale (its counter stood still) is no alibi even for one cycle
    _, cause = watch(CFG, after_sample, _inputs((0.1, 0.0, 0.0)), True, jolt, False, 300, DT)
    assert "in free space" in cause


@pytest.mark.parametrize("rate_hz", [400.0, 1000.0])
def test_a_sensor_that_repeats_its_sample_to_the_last_bit_while_pressing_is_frozen(rate_hz):
    """Stuck at 10 N (its counter still rolling) it met a notch's far wall at 100 N true before the
    cross-check said anything (an outside tester, 2026-12-06). A sensor's own noise changes its counts
    every sample; the same sample sensor_frozen_s long while pressing ends the contact."""
    cfg = ContactGuardConfig()
    dt = 1.0 / rate_hz
    agree = Witness((10.2, 0.0, 0.0), 0.0)
    rng = np.random.default_rng(1)
    w = ContactWatch(expectation=ContactExpectation.PRESSING, baseline_set=True)
    for cycle in range(round(1.0 / dt)):  # a second of noisy samples (0.05 N, in 0.01 N counts): never
        x, y, z = (round(float(v), 2) for v in np.array((10.0, 0.0, 0.0)) + rng.normal(0.0, 0.05, 3))
        w, cause = watch(cfg, w, _inputs((x, y, z)), False, agree, False, cycle, dt)
        assert not cause and not w.suspect
    stuck = _inputs((10.01, 0.02, -0.01))
    cycles = 0
    cause = ""
    while not cause:
        w, cause = watch(cfg, w, stuck, False, agree, False, 10_000 + cycles, dt)
        cycles += 1
    assert cause.startswith("force sensor frozen") and "(10.01, 0.02, -0.01) N" in cause
    assert (cycles - 1) * dt == pytest.approx(cfg.sensor_frozen_s, abs=dt)  # a time, alike at every rate
    # its direction is not the frozen sensor's: the suspect sensor gives none
    assert w.suspect
    # in free space (at rest, a noiseless sensor may repeat itself) the same samples are no verdict
    w = ContactWatch(expectation=ContactExpectation.NONE, baseline_set=True)
    for cycle in range(200):
        w, cause = watch(cfg, w, _inputs((0.0, 0.0, 0.0)), False, None, True, cycle, dt)
        assert not cause


def test_a_noiseless_simulated_sensor_is_refused_beside_the_frozen_check_and_taken_without_it():
    with pytest.raises(
        ConfigError, match=r"sim\.sensor\.noise_std_n = 0 with safety\.contact\.sensor_frozen_s"
    ):
        load_config(overrides={"sim.sensor.noise_std_n": 0.0})
    cfg = load_config(overrides={"sim.sensor.noise_std_n": 0.0, "safety.contact.sensor_frozen_s": 0.0})
    assert cfg.safety.contact.sensor_frozen_s == 0.0


def test_a_sensor_that_disagrees_with_the_witness_becomes_suspect_and_agreeing_clears_it():
    w = ContactWatch(expectation=ContactExpectation.PRESSING, baseline_set=True)
    lie = _inputs((40.0, 0.0, 0.0))  # the drives feel 10 N
    for cycle in range(NEEDED):
        assert not w.suspect
        w, _ = watch(CFG, w, lie, False, Witness((10.0, 0.0, 0.0), 0.0), False, cycle, DT)
    assert w.suspect and "40.0 N where the drives' effort says 10.0 N" in w.suspect
    # agreeing clears it once the median of the window agrees for disagreement_s in a row
    for cycle in range(MEDIAN // 2 + NEEDED):
        assert w.suspect
        w, _ = watch(
            CFG, w, _inputs((11.0, 0.0, 0.0)), False, Witness((10.0, 0.0, 0.0), 0.0), False, 50 + cycle, DT
        )
    assert not w.suspect
    # suspect for longer than sensor_suspect_s: the guard backs off
    for cycle in range(100, 100 + int(CFG.sensor_suspect_s / DT) + NEEDED + MEDIAN):
        w, cause = watch(CFG, w, lie, False, Witness((10.0, 0.0, 0.0), 0.0), False, cycle, DT)
    assert cause.startswith("force sensor suspect")


@pytest.mark.parametrize("rate_hz", [400.0, 1000.0, 250.0])
def test_the_cross_checks_windows_are_times_alike_at_every_loop_rate(rate_hz):
    """A jolt of the drives' effort as long as the longest measured over a bus at 400 Hz (9 cycles,
    22.5 ms) passes the witness's median at every rate, and 25 ms of true disagreement make the
    sensor suspect at every rate. Counted in cycles (19 and 10), at 1 kHz the same jolt filled more
    than half the median's 19 ms and made the sensor suspect after 10 ms."""
    dt = 1.0 / rate_hz
    pressing = _inputs((10.0, 0.0, 0.0))
    w = ContactWatch(expectation=ContactExpectation.PRESSING, baseline_set=True)
    cycle = 0
    for _ in range(round(0.1 / dt)):  # 100 ms pressing, sensor and drives agreeing
        w, cause = watch(CFG, w, pressing, False, Witness((10.5, 0.0, 0.0), 0.0), False, cycle, dt)
        cycle += 1
        assert not cause and not w.suspect
    for _ in range(math.ceil(0.0225 / dt)):  # the jolt: the motors carry it, the sensor does not
        w, cause = watch(CFG, w, pressing, False, Witness((60.0, 0.0, 0.0), 0.0), False, cycle, dt)
        cycle += 1
        assert not cause and not w.suspect and w.disagreeing == 0, cycle
    for _ in range(round(0.1 / dt)):
        w, cause = watch(CFG, w, pressing, False, Witness((10.5, 0.0, 0.0), 0.0), False, cycle, dt)
        cycle += 1
        assert not cause and not w.suspect
    # a sensor that truly reads 30 N where the drives feel 10: suspect once the median has turned
    # (half the median's window) and the disagreement lasted 25 ms, at every rate
    lie = _inputs((30.0, 0.0, 0.0))
    start = cycle
    while not w.suspect:
        w, _ = watch(CFG, w, lie, False, Witness((10.0, 0.0, 0.0), 0.0), False, cycle, dt)
        cycle += 1
        assert cycle - start < 1000
    took_s = (cycle - start) * dt
    assert took_s == pytest.approx(0.0475 / 2 + 0.025, abs=2.0 * dt)
    assert "ms)" in w.suspect


@pytest.mark.parametrize("rate_hz", [25.0, 40.0, 50.0, 400.0])
def test_one_cycles_jolt_never_judges_alone_at_any_rate(rate_hz):
    """Without a sensor, in free space, the witness judges past the contact limit. Below 42 Hz its
    47.5-ms median was one sample: one late SYNC's jolt (121.4 N of effort, nothing touching)
    stopped the 25-Hz path of the vcan test with kernel SYNC. One cycle of it now passes at every
    rate, and a collision that lasts trips within the median's half (two cycles at 25 Hz)."""
    dt = 1.0 / rate_hz
    no_sensor = CycleInputs(_inputs((0.0, 0.0, 0.0)).drives, None)
    quiet, jolt = Witness((1.0, 0.0, 0.0), 0.0), Witness((121.4, 0.0, 0.0), 0.0)
    w = ContactWatch(expectation=ContactExpectation.NONE)
    cycle = 0
    for witness in [quiet] * 10 + [jolt] + [quiet] * 10:
        w, cause = watch(CFG, w, no_sensor, False, witness, False, cycle, dt)
        cycle += 1
        assert not cause, (cycle, w.force_n)
    tripped_after = None
    for k in range(1, 200):  # a collision: the effort stays up
        w, cause = watch(CFG, w, no_sensor, False, jolt, False, cycle, dt)
        cycle += 1
        if cause:
            tripped_after = k
            break
    assert tripped_after == median_cycles(dt) // 2 + 1
    assert "in free space" in cause and "drives' effort 121.4 N" in cause
    assert median_cycles(dt) >= 3


def _run_back_off(b, cycles: int = 2000):
    """``advance_back_off`` until it brakes: the last state, each period's speed and position."""
    speeds, positions = [], []
    for _ in range(cycles):
        b, p, v = advance_back_off(CFG, b, DT)
        speeds.append(math.hypot(*v))
        positions.append(p)
        if b.braking:
            break
    return b, speeds, positions


def test_the_back_off_moves_along_the_trusted_force_within_its_speed_and_acceleration_then_stops():
    w = ContactWatch(sensor_n=(0.0, 30.0, 0.0), witness=Witness((0.0, 29.0, 0.0), 0.0), force_n=30.0)
    b = begin_back_off(CFG, w, "test", (0.07, 0.0, 0.5))
    assert b.direction == pytest.approx((0.0, 1.0, 0.0))
    b, speeds, positions = _run_back_off(b)
    assert b.braking and b.travelled_m == pytest.approx(CFG.back_off_distance_m)
    assert positions[-1][1] == pytest.approx(CFG.back_off_distance_m) and positions[-1][0] == 0.07
    assert max(speeds) <= CFG.back_off_speed_m_s + 1e-12
    assert (
        max(abs(b - a) for a, b in zip([0.0, *speeds], speeds, strict=False))
        <= CFG.back_off_acceleration_m_s2 * DT + 1e-12
    )
    # a suspect sensor: the witness gives the direction; no force at all: brake in place
    suspect = replace(w, suspect="test", witness=Witness((-20.0, 0.0, 0.0), 0.0))
    assert begin_back_off(CFG, suspect, "test", (0.0, 0.0, 0.5)).direction == pytest.approx((-1.0, 0.0, 0.0))
    none = ContactWatch(sensor_n=(0.5, 0.0, 0.0), witness=Witness((0.3, 0.0, 0.0), 0.0))
    assert begin_back_off(CFG, none, "test", (0.0, 0.0, 0.5)).direction is None


def test_the_trail_keeps_a_point_each_spacing_the_tool_moved_and_only_the_last_ones():
    trail: tuple[tuple[float, float, float, float], ...] = ()
    for k in range(400):  # 0.1 mm a cycle along x: a point every 5 cycles
        trail = extend_trail(trail, (0.0001 * k, 0.0, 0.5), 10.0)
    assert len(trail) == TRAIL_POINTS
    gaps = [b[0] - a[0] for a, b in itertools.pairwise(trail)]
    # at least the spacing, at most a cycle's step more (0.0005 is not 5 * 0.0001 to the last bit)
    assert all(TRAIL_SPACING_M - 1e-12 <= g <= TRAIL_SPACING_M + 0.0001 + 1e-12 for g in gaps)
    assert trail[-1][0] >= 0.0399 - TRAIL_SPACING_M - 0.0001
    # standing still, or no measured pose: the same tuple, no new one
    assert extend_trail(trail, trail[-1][:3], 10.0) is trail
    assert extend_trail(trail, None, 10.0) is trail
    assert trail[-1][3] == 10.0  # the force judged where the point was taken


def test_a_back_off_that_met_more_force_retraces_the_path_it_came_in_on_then_stops():
    """Along +x at 10 N into a wall at x = 20 mm (40 and 65 N in its last millimetre), then the
    back-off 1 mm along -y into more force (the other wall of a slot, 72 N): the retrace heads
    straight for the last point of the way in at 30 N or less (x = 19 mm), passing over the wall's,
    then back along -x back_off_distance_m, at the back-off's speed."""
    along_x = tuple((0.019 - 0.0005 * k, 0.0, 0.5, 10.0) for k in range(TRAIL_POINTS - 3, -1, -1))
    wall = ((0.0195, 0.0, 0.5, 40.0), (0.02, 0.0, 0.5, 65.0))
    trail = (*along_x, *wall)  # as the back-off began: the back-off's own way is not in it
    assert len(trail) == TRAIL_POINTS
    b = begin_retrace(CFG, _straight_back_off_that_went(0.001, trail), (0.02, -0.001, 0.5), 72.0)
    assert b is not None and b.entry_force_n == 72.0
    to_calm = math.hypot(0.001, 0.001)
    assert b.direction == pytest.approx((-1.0 / math.sqrt(2.0), 1.0 / math.sqrt(2.0), 0.0))
    assert b.distance_m == pytest.approx(to_calm + CFG.back_off_distance_m)
    b, speeds, positions = _run_back_off(b)
    assert b.braking and b.travelled_m == pytest.approx(to_calm + CFG.back_off_distance_m)
    # at the last calm point, then 5 mm back along the way in
    assert positions[-1] == pytest.approx((0.019 - CFG.back_off_distance_m, 0.0, 0.5), abs=1e-9)
    assert max(p[0] for p in positions) <= 0.02 + 1e-12  # never further into the wall
    assert max(speeds) <= CFG.back_off_speed_m_s + 1e-12
    assert "met 72.0 N backing off; retraced 6.4 mm of the path it came in on" in back_off_summary(b)


def _straight_back_off_that_went(travelled_m: float, trail: object = ()) -> object:
    w = ContactWatch(
        sensor_n=(0.0, 30.0, 0.0), witness=Witness((0.0, 29.0, 0.0), 0.0), force_n=30.0, trail_m=trail
    )
    b = begin_back_off(CFG, w, "test", (0.0, 0.0, 0.5))
    assert b.trail_m is trail  # the way in, as the back-off began
    return replace(b, travelled_m=travelled_m)


def test_a_retrace_without_a_calm_path_behind_it_is_none_the_quick_stop():
    assert begin_retrace(CFG, _straight_back_off_that_went(0.0), (0.0, 0.0, 0.5), 80.0) is None
    # a trail of one spacing, all about where the tool stands: nothing to follow
    short = ((0.0, 0.0, 0.5, 10.0), (0.0005, 0.0, 0.5, 10.0))
    assert begin_retrace(CFG, _straight_back_off_that_went(0.0, short), (0.0005, 0.0, 0.5), 80.0) is None
    # every point of the trail pressed past half the limit: no way back known to be free
    pressed = tuple((0.0005 * k, 0.0, 0.5, 45.0) for k in range(10))
    assert begin_retrace(CFG, _straight_back_off_that_went(0.0, pressed), (0.005, 0.0, 0.5), 80.0) is None


def test_cheopes_witness_is_the_force_its_efforts_balance_plus_its_own_inertia():
    cfg = load_config()
    robot = build_robot(cfg)
    tcp = np.array([0.03, -0.02, 0.5])
    q = robot.inverse_kinematics(tcp)
    jac = robot.jacobian(tcp)
    contact = np.array([7.0, -3.0, 1.0])
    tau = -np.linalg.solve(jac.T, contact)  # static: J^T tau = -F
    force, inertia = robot.contact_force_from_efforts(tuple(tcp), tuple(q), tuple(tau), (0.0, 0.0, 0.0))
    assert force == pytest.approx(contact, abs=1e-9) and inertia == 0.0
    qdd = np.array([0.3, -0.1, 0.2])
    force, inertia = robot.contact_force_from_efforts(tuple(tcp), tuple(q), tuple(tau), tuple(qdd))
    m_a = cartesian_mass_matrix(jac, robot.masses) @ np.linalg.solve(jac, qdd)
    assert force == pytest.approx(contact + m_a, abs=1e-9) and inertia == pytest.approx(np.linalg.norm(m_a))


def test_a_task_that_reads_the_sensor_is_refused_without_the_drives_effort():
    with pytest.raises(ConfigError, match=r"0x6077.*witness_required"):
        build_law(load_config(overrides={"task.kind": "contour", "actuators.tpdo_objects": []}))
    build_law(  # on the sensor alone, when the operator says so
        load_config(
            overrides={
                "task.kind": "contour",
                "actuators.tpdo_objects": [],
                "safety.contact.witness_required": False,
            }
        )
    )


class _Trace:
    def __init__(self, exchange: LoopbackExchange) -> None:
        self.exchange = exchange
        self.rows: list[tuple[Mode, tuple[int, ...], tuple[float, ...], tuple[float, ...]]] = []
        self.events: list[str] = []

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
        tcp = tuple(self.exchange.plant.tcp_m.tolist())
        powers = tuple(int(decode_statusword(d.statusword)) for d in inputs.drives)
        self.rows.append((state.mode, powers, tcp, outputs.controlwords))
        self.events += [e.message for e in events]


class _ShortInverse:
    """A robot plug-in whose inverse kinematics answers one position short."""

    def __init__(self, robot) -> None:
        self._robot = robot

    def __getattr__(self, name: str):
        return getattr(self._robot, name)

    def inverse_kinematics(self, tcp_m):
        return self._robot.inverse_kinematics(tcp_m)[:-1]


def _run_path(faults: tuple[str, ...], short_inverse: bool = False):
    cfg = load_config(overrides={"sim.faults": list(faults), "task.path.laps": 0.5})
    clock = SimulatedTime()
    law = build_law(cfg)
    if short_inverse:
        law.robot = _ShortInverse(law.robot)
    exchange = LoopbackExchange(cfg, clock.clock)
    trace = _Trace(exchange)
    final, _ = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(trace,)
    ).run(law.initial_state(), 20.0)
    return final, trace


def test_a_force_in_free_space_ends_the_move_with_a_back_off_along_it_the_drives_enabled():
    """The path task moves in free space; 20 N appear on the sensor along +X (something touches the
    tool): the law backs off 5 mm along +X, its drives in OPERATION ENABLED all the way, then faults
    naming it. Never a quick stop in place."""
    final, trace = _run_path(("force=20@2.0",))
    assert final.mode == Mode.FAULT and final.fault_reason.startswith("protective stop: contact force")
    assert "backed off 5.0 mm along (1.00" in final.fault_reason
    backing = [r for r in trace.rows if r[0] == Mode.BACKING_OFF]
    assert len(backing) > 50  # 5 mm at 20 mm/s, with its ramps
    assert all(p == int(PowerState.OPERATION_ENABLED) for r in backing for p in r[1])
    start, end = backing[0][2], backing[-1][2]
    assert end[0] - start[0] == pytest.approx(0.005, abs=0.0015)  # along +X, the force's direction
    assert abs(end[1] - start[1]) < 0.001 and abs(end[2] - start[2]) < 0.001


def test_a_back_off_whose_robot_answers_the_wrong_axis_count_brakes_in_place_and_says_why():
    """The back-off zips the robot's inverse kinematics with itself axis by axis: an answer of
    another length brakes to rest where the robot is, the drives enabled, as an unreachable one does
    (before a58564c, zip(strict=True) raised inside the step)."""
    final, trace = _run_path(("force=20@2.0",), short_inverse=True)
    assert final.mode == Mode.FAULT and final.fault_reason.startswith("protective stop: contact force")
    assert "back-off brakes: the robot's inverse kinematics gave 2 positions for 3 actuators" in trace.events
    backing = [r for r in trace.rows if r[0] == Mode.BACKING_OFF]
    assert backing and all(p == int(PowerState.OPERATION_ENABLED) for r in backing for p in r[1])
