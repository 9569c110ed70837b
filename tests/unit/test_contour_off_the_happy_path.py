"""The contour task off its happy path (issue "Force control that holds"), in simulated time.

The two injections that ended in the workpiece before (157 N and 137 N against a 60 N limit),
the designed phases of a contact loss, admittance saturation, implausible force steps, a
drifting bias, and the workpiece shapes. Deterministic: no bus, no wall clock.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from controller.assembly import build_robot, build_task
from controller.config import load_config
from controller.configured_robot import actuator_units
from controller.core.cycle_data import CycleInputs, DriveFeedback, SensorFeedback
from controller.core.periods import cycles_in
from controller.core.ports import TaskContext
from controller.core.setpoint_smoothing import Setpoint
from controller.tasks.contour_tracking import MOTION_GATE_DEG, ContourPhase, ContourState, track_normal
from controller.tools.contour.scan import (
    ContourScenario,
    run_contour_scenario,
    run_shape,
    scan_config,
    shapes_met,
)

DT = 0.0025
LIMIT_N = 60.0


def _task(**overrides):
    cfg = load_config(overrides={"task.kind": "contour", **overrides})
    return build_task(cfg, build_robot(cfg), actuator_units(cfg)).task, cfg


def _ctx(force, tcp=(0.07, 0.0, 0.5), fresh=True, t_s=1.0) -> TaskContext:
    sensor = SensorFeedback(tuple(force), (0.0, 0.0, 0.0), 0, 1, fresh)
    drives = tuple(DriveFeedback(0x1637, 0.55, True) for _ in range(3))
    return TaskContext(t_s, DT, Setpoint.at_rest((0.55,) * 3), CycleInputs(drives, sensor), tcp)


def _tracking(task, **fields) -> ContourState:
    s = replace(
        task.start(),
        phase=ContourPhase.TRACKING,
        p_cmd=(0.07, 0.0, 0.5),
        normal=(1.0, 0.0),
        contact_normal=(1.0, 0.0),
        contact_point=(0.07, 0.0),
        speed_m_s=0.04,
        force_f=(10.0, 0.0, 0.0),
        raw_force=(10.0, 0.0, 0.0),
    )
    return replace(s, **fields)


# -- the failures the issue found, end to end in simulated time ----------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["force=-12@33+0.12", "force=12@36+0.12"])
def test_the_two_injections_that_drove_the_tool_into_the_disk_now_end_done(fault):
    cfg = load_config(overrides={"task.kind": "contour"})
    row = run_contour_scenario(cfg, ContourScenario(fault, (fault,)), None)
    assert row["outcome"] == "DONE", row["cause"]
    assert row["max_true_contact_force_n"] < 0.5 * LIMIT_N


SCAN_WORST = [
    ContourScenario("spike -12 N for 0.3 s", ("force=-12@15.832+0.3",)),
    ContourScenario("spike +5 N for 0.2 s", ("force=5@21.315+0.2",)),
    ContourScenario("spike -8 N for 0.2 s", ("force=-8@14.615+0.2",)),
    ContourScenario(
        "notch 3 mm x 20 mm", features=({"angle_deg": 200.0, "length_m": 0.02, "depth_m": 0.003},)
    ),
    ContourScenario(
        "bump 2 mm x 30 mm", features=({"angle_deg": 270.0, "length_m": 0.03, "depth_m": -0.002},)
    ),
    ContourScenario("10 stale samples", ("freeze@24.968+0.02625",)),
]


@pytest.mark.slow
@pytest.mark.parametrize("scenario", SCAN_WORST, ids=lambda s: s.name)
def test_the_scans_hardest_scenarios_end_done_under_the_limit(scenario):
    """The scenarios that failed on the way to the design (contour_scan.py), each once more."""
    row = run_contour_scenario(scan_config(load_config()), scenario, None)
    assert row["outcome"] == "DONE", row["cause"]
    assert row["laps_done"] == 3
    # The braking these scenarios cause pushed the tool in while the integral kept the velocity into
    # the contour it had learnt at speed (_integral_at_speed): 43.0 N (the -8 N spike) and 33.5 N
    # (the stale samples) before, at most 35.2 N since.
    assert row["max_true_contact_force_n"] < 40.0


@pytest.mark.slow
@pytest.mark.parametrize("rate_n_s", [0.3, -0.3])
def test_a_drifting_bias_ends_done_or_in_a_controlled_retract_never_in_the_workpiece(rate_n_s):
    """The drift walked the tool out of the workspace once; now the law finds the phantom contact out."""
    row = run_contour_scenario(
        scan_config(load_config()), ContourScenario("drift", (f"drift={rate_n_s}@8.33+15",)), None
    )
    assert not row["over_limit"], row["max_true_contact_force_n"]
    assert row["outcome"] == "DONE" or (
        row["outcome"] == "retracted" and "not re-acquired" in str(row["cause"])
    )


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["ellipse", "rounded_rectangle", "kidney"])
def test_any_contour_is_followed_without_knowing_it(shape):
    row = run_shape(load_config(), shape)
    assert shapes_met([row]), row


@pytest.mark.slow
def test_the_rounded_star_is_followed_without_contact_loss():
    """Its force error away from corners is 0.88 N RMS against the 1 N target (docs/measurements/history.md)."""
    row = run_shape(load_config(), "rounded_star")
    assert row["outcome"] == "DONE" and row["contact_losses"] == 0 and not row["over_limit"], row
    assert float(row["force_error_rms_elsewhere_n"]) < 1.1  # type: ignore[arg-type]


# -- the designed phases, step by step ------------------------------------------------------------


def test_a_contact_loss_re_approaches_backs_off_and_gives_up_with_a_named_cause():
    task, cfg = _task()
    c = cfg.task.model("contour")
    s = _tracking(task)
    phases, kinds = [], []
    for k in range(200000):
        out = task.step(
            replace(s, force_f=(0.0, 0.0, 0.0)) if s.phase == ContourPhase.TRACKING else s,
            _ctx((0.0, 0.0, 0.0), tcp=s.p_cmd, t_s=1.0 + k * DT),
        )
        s = out.state
        kinds += [e.kind for e in out.events]
        if not phases or phases[-1] != s.phase:
            phases.append(s.phase)
        if out.finished:
            break
    # the fading force already braked the tangential motion (force band), so CONTACT_LOST passes at
    # once; out into free space and a re-tare first (the loss may have been the sensor's offset)
    assert phases[:4] == [
        ContourPhase.TRACKING,
        ContourPhase.RETARE,
        ContourPhase.REAPPROACH,
        ContourPhase.BACK_OFF,
    ]
    assert phases[-2:] == [ContourPhase.RETRACT, ContourPhase.FINISHED]
    assert kinds.count("reapproach") == c.max_reacquire_attempts
    assert kinds.count("reapproach_failed") == c.max_reacquire_attempts
    assert "contact_not_reacquired" in kinds and "contact_lost" in kinds
    assert out.fault.startswith("contact lost in lap 1 and not re-acquired in 3")


def _through_retare(task, s, force=(0.0, 0.0, 0.0)):
    """Steps (the clock advancing) until the task leaves CONTACT_LOST and RETARE: (state, events)."""
    events = []
    for k in range(20000):
        if s.phase not in (ContourPhase.CONTACT_LOST, ContourPhase.RETARE):
            break
        out = task.step(s, _ctx(force, tcp=s.p_cmd, t_s=1.0 + k * DT))
        s = out.state
        events += list(out.events)
    return s, events


def _way_out(task, offset, wall_x, stiffness_n_m, offset_step=(0.0, 0.0, 0.0)):
    """A re-tare from (0.073, 0) m along +x, a wall at ``wall_x`` beyond; the sensor reads the wall's
    force plus ``offset`` (and ``offset_step`` from the way out's first millimetre on), the drives'
    effort the wall's alone. (state at the re-approach, events, the most the wall was pressed [N])."""
    s = replace(_tracking(task, speed_m_s=0.0, p_cmd=(0.073, 0.0, 0.5)), phase=ContourPhase.CONTACT_LOST)
    events, pressed_n = [], 0.0
    for k in range(20000):
        if s.phase not in (ContourPhase.CONTACT_LOST, ContourPhase.RETARE):
            break
        wall_n = stiffness_n_m * max(0.0, s.p_cmd[0] - wall_x)  # the commanded TCP as the true one
        pressed_n = max(pressed_n, wall_n)
        step = offset_step if s.p_cmd[0] > 0.0731 else (0.0, 0.0, 0.0)
        force = (offset[0] + step[0] - wall_n, offset[1] + step[1], offset[2] + step[2])
        ctx = replace(_ctx(force, tcp=s.p_cmd, t_s=1.0 + k * DT), force_witness_n=(-wall_n, 0.0, 0.0))
        out = task.step(s, ctx)
        s = out.state
        events += [e.message for e in out.events]
    return s, events, pressed_n


def test_a_re_tares_way_out_stops_at_another_surface_and_tares_halfway_back():
    """The way out of a contact is a guarded move: a wall 1 mm out along it (a slot's other side) is
    felt at its first newtons, and once the drives' effort agrees, the tare is taken halfway between,
    where nothing touches (before: 2 mm out, 1 mm into the wall, the tare took -199.7 N as offset)."""
    task, cfg = _task()
    c = cfg.task.model("contour")
    offset = (0.3, -0.2, 0.0)  # the sensor's own, that the tare must find
    s, events, pressed_n = _way_out(task, offset, wall_x=0.074, stiffness_n_m=2.0e5)
    assert s.phase == ContourPhase.REAPPROACH
    assert sum("met another surface" in e for e in events) == 1, events
    # stopped within two cycles' advance into the wall (5 N each at this stiffness), not 1 mm into it
    assert pressed_n <= 2.0e5 * 2.0 * c.search_speed_m_s * DT + 1e-9
    assert 0.0732 < s.p_cmd[0] < 0.074 - 0.0002  # re-tared between the two, clear of the wall
    assert all(abs(a - b) < 0.01 for a, b in zip(s.offset, offset, strict=True))


def test_a_sensor_step_against_the_way_out_that_the_effort_does_not_feel_is_no_surface():
    """A re-tare doubts its sensor: its offset stepping by 10 N against the way out (an outside
    scan's step, read as another surface 0.2 mm out: the tare was refused in contact, the retract
    met 126 N) is judged against the drives' effort, which feels nothing, and the way out goes on."""
    task, cfg = _task()
    out_m = cfg.task.model("contour").retare_clearance_m
    s, events, _ = _way_out(
        task, (0.0, 0.0, 0.0), wall_x=1.0, stiffness_n_m=2.0e5, offset_step=(-10.0, 0.0, 0.0)
    )
    assert s.phase == ContourPhase.REAPPROACH
    assert not any("met another surface" in e for e in events), events
    assert any("the sensor's own" in e for e in events), events
    assert s.p_cmd[0] == pytest.approx(0.073 + out_m)  # the whole way out, the tare there
    assert s.offset[0] == pytest.approx(-10.0, abs=0.01)


def test_a_re_tares_way_out_holds_still_while_its_sensor_is_blind():
    """A sensor 90 ms stale in a slot's way out let it go on into the far wall at 108 N (an outside
    tester's): without a fresh sample for ``stale_hold_s`` the way out stands still, then goes on."""
    task, cfg = _task()
    c = cfg.task.model("contour")
    s = replace(_tracking(task, speed_m_s=0.0, p_cmd=(0.073, 0.0, 0.5)), phase=ContourPhase.CONTACT_LOST)
    blind = range(20, 60)  # cycles without a fresh sample, once the way out is under way (80 cycles)
    moved_blind_m, x_last = 0.0, s.p_cmd[0]
    for k in range(20000):
        if s.phase not in (ContourPhase.CONTACT_LOST, ContourPhase.RETARE):
            break
        out = task.step(s, _ctx((0.0, 0.0, 0.0), tcp=s.p_cmd, fresh=k not in blind, t_s=1.0 + k * DT))
        s = out.state
        if k in blind:
            moved_blind_m += abs(s.p_cmd[0] - x_last)
        x_last = s.p_cmd[0]
    assert s.phase == ContourPhase.REAPPROACH
    # on only until the last sample is stale_hold_s old: the cycles before it, one step each
    assert moved_blind_m <= cycles_in(c.stale_hold_s, DT) * c.search_speed_m_s * DT + 1e-12


def test_a_contact_lost_at_speed_is_braked_along_its_tangent_first():
    task, cfg = _task()
    s = replace(_tracking(task, speed_m_s=0.06, normal=(1.0, 0.0)), phase=ContourPhase.CONTACT_LOST)
    speeds = []
    while s.phase == ContourPhase.CONTACT_LOST:
        s = task.step(s, _ctx((0.0, 0.0, 0.0), tcp=s.p_cmd)).state
        speeds.append(s.speed_m_s)
    decel = cfg.task.model("contour").stop_deceleration_m_s2
    assert speeds[0] == pytest.approx(0.06 - decel * DT)
    assert s.phase == ContourPhase.RETARE  # then out into free space for a re-tare
    assert abs(len(speeds) - 0.06 / (decel * DT)) <= 1.0  # to rest at the stop deceleration (+- rounding)


def test_a_re_approach_aims_behind_the_last_good_contact_point_and_resumes_tracking_there():
    task, cfg = _task()
    # braked 10 mm further along the tangent and 3 mm out: the line still meets the contour near the point
    s = replace(_tracking(task, speed_m_s=0.0, p_cmd=(0.073, 0.01, 0.5)), phase=ContourPhase.CONTACT_LOST)
    s, _ = _through_retare(task, s)
    assert s.phase == ContourPhase.REAPPROACH
    # re-tared retare_clearance_m further out along the normal, and from there:
    out_m = cfg.task.model("contour").retare_clearance_m
    start = (0.073 + out_m, 0.01)
    assert s.p_cmd[0] == pytest.approx(start[0]) and s.p_cmd[1] == pytest.approx(start[1])
    aim = (0.07 - 0.008, 0.0)  # reapproach_distance_m behind the contact point, along -n
    d = s.reapproach_direction
    to_aim = (aim[0] - start[0], aim[1] - start[1])
    assert d[0] * to_aim[1] - d[1] * to_aim[0] == pytest.approx(0.0, abs=1e-9)  # along the line to the aim
    assert s.reapproach_m == pytest.approx(math.hypot(*to_aim))
    s = replace(s, lap=1, swept_rad=7.0)
    out = task.step(replace(s, force_f=(3.0, 0.0, 0.0), raw_force=(3.0, 0.0, 0.0)), _ctx((3.0, 0.0, 0.0)))
    assert out.state.phase == ContourPhase.TRACKING
    assert out.state.lap == 1 and out.state.swept_rad >= 7.0  # lap counting goes on where it stopped
    assert out.state.creep_m > 0.0  # and the contour there is taken slowly
    assert any("re-acquired" in e.message for e in out.events)


def test_above_the_saturation_force_the_law_only_moves_away_from_the_contact():
    task, cfg = _task()
    sat = cfg.task.model("contour").admittance_saturation_fraction * cfg.safety.max_contact_force_n
    # a large integral that would push in, and a force just over the saturation force
    s = _tracking(task, integral=5.0, force_f=(sat + 1.0, 0.0, 0.0), raw_force=(sat + 1.0, 0.0, 0.0))
    out = task.step(s, _ctx((sat + 1.0, 0.0, 0.0)))
    assert out.state.p_cmd[0] > s.p_cmd[0]  # along +n: away from the contact
    assert out.state.integral == 0.0
    below = _tracking(task, integral=5.0, force_f=(sat - 15.0, 0.0, 0.0), raw_force=(sat - 15.0, 0.0, 0.0))
    assert (
        task.step(below, _ctx((sat - 15.0, 0.0, 0.0))).state.p_cmd[0] < below.p_cmd[0]
    )  # the integral pushes in


def test_an_implausible_step_is_held_off_and_a_spike_that_steps_back_leaves_no_trace():
    task, cfg = _task()
    c = cfg.task.model("contour")
    s = _tracking(task)
    jump = (10.0 - c.max_force_step_n - 2.0, 0.0, 0.0)  # the force vanishes in one sample
    out = task.step(s, _ctx(jump))
    assert [e.kind for e in out.events] == ["force_implausible"]
    held = out.state
    assert held.force_f == s.force_f  # kept out of the filter
    assert held.p_cmd[0] >= s.p_cmd[0]  # no motion into the contact
    assert held.speed_m_s < s.speed_m_s  # tangential braking
    back = task.step(held, _ctx((10.0, 0.0, 0.0)))
    assert [e.kind for e in back.events] == ["force_plausible"] and "back at its level" in back.events[
        0
    ].message
    assert back.state.held_force is None


def test_a_new_level_that_holds_is_taken_as_real_after_the_hold():
    task, cfg = _task()
    hold_cycles = round(cfg.task.model("contour").implausible_hold_s / DT)
    s = _tracking(task)
    level = (25.0, 0.0, 0.0)
    kinds = []
    for _ in range(hold_cycles + 2):
        out = task.step(s, _ctx(level))
        s = out.state
        kinds += [e.kind for e in out.events]
    assert kinds == ["force_implausible", "force_plausible"]
    assert s.force_f[0] == pytest.approx(25.0, abs=0.5)


def test_a_bias_that_reads_as_a_weak_contact_is_found_out_by_its_missing_stiffness():
    task, cfg = _task()
    c = cfg.task.model("contour")
    bias = (3.0, 0.0, 0.0)  # no contact: the sensor reads its drifted bias, below the force band
    s = _tracking(task, force_f=bias, raw_force=bias, speed_m_s=0.0, integral=0.0)
    lost_after = None
    for k in range(4000):
        out = task.step(s, _ctx(bias, tcp=s.p_cmd))
        s = out.state
        if any(e.kind == "contact_lost" for e in out.events):
            lost_after = k
            assert "no contact stiffness" in next(e.message for e in out.events if e.kind == "contact_lost")
            break
    assert lost_after is not None
    # while it probed, it moved in no faster than the approach speed (a guarded move), and not sideways
    assert s.speed_m_s == 0.0
    assert lost_after * DT * c.approach_speed_m_s >= c.max_push_without_force_m * 0.99


def test_a_re_approach_from_free_space_re_tares_the_drifted_bias():
    task, _ = _task()
    bias = (2.5, -1.0, 0.0)
    s = replace(_tracking(task, speed_m_s=0.0, force_f=bias, raw_force=bias), phase=ContourPhase.CONTACT_LOST)
    s, events = _through_retare(task, s, bias)
    assert s.phase == ContourPhase.REAPPROACH
    assert s.offset[0] == pytest.approx(2.5) and s.offset[1] == pytest.approx(-1.0)
    assert s.force_f == (0.0, 0.0, 0.0)
    assert any(e.message.startswith("sensor re-tared in free space") for e in events)


def test_stale_samples_stop_the_motion_into_the_contact_for_the_force_but_not_the_course():
    """Blind (no fresh sample for ``stale_hold_s``), the tool brakes and the force's error (6 N under
    the setpoint here) moves it no deeper; the integral's push at the braking speed goes on, the
    motion the friction's tilt takes off the contour, and fades with the speed: none at rest
    (tests/unit/test_loop_held_up.py has the contact it keeps)."""
    task, _ = _task()
    ki = task.p.force_ki_m_s2_per_n
    s = _tracking(task, force_f=(4.0, 0.0, 0.0), raw_force=(4.0, 0.0, 0.0), integral=3.0)
    # the first stale cycles run on the last sample (a few late frames cost nothing); from the
    # stale_hold_s-th on, the law holds
    for _ in range(cycles_in(task.p.stale_hold_s, DT) - 1):
        s = task.step(s, _ctx((4.0, 0.0, 0.0), fresh=False)).state
    for _ in range(3):
        out = task.step(s, _ctx((4.0, 0.0, 0.0), fresh=False))
        into_m = s.p_cmd[0] - out.state.p_cmd[0]  # n = +x: into the contact is -x
        share = min(1.0, out.state.speed_m_s / task.p.min_tangential_speed_m_s)
        assert out.state.speed_m_s < s.speed_m_s  # braking
        assert into_m == pytest.approx(ki * share * out.state.integral * DT, rel=1e-9)
        s = out.state
    assert s.speed_m_s < 0.04
    rest = task.step(replace(s, speed_m_s=0.0), _ctx((4.0, 0.0, 0.0), fresh=False)).state
    assert rest.p_cmd[0] >= s.p_cmd[0] - 1e-12  # at rest: nothing into the contact


def test_the_integrals_velocity_into_the_contour_follows_the_tangential_speed():
    """At speed the integral holds a velocity into the contour proportional to the speed (the
    friction the normal estimate gets wrong tilts the tangent out of it): a braking tool keeps its
    share, a tool speeding up gets it back, and a tool at rest is not moved into the contact by it."""
    task, _ = _task()
    # the force at its setpoint, the raw sample 7 N over it: beyond the force band's stop fraction,
    # the speed brakes
    s = _tracking(task, speed_m_s=0.06, integral=1.12, raw_force=(17.0, 0.0, 0.0))
    out = task.step(s, _ctx((17.0, 0.0, 0.0)))
    assert 0.0 < out.state.speed_m_s < s.speed_m_s
    assert out.state.integral == pytest.approx(s.integral * out.state.speed_m_s / s.speed_m_s, rel=0.02)
    # speeding up again towards the lap's speed
    slow = replace(s, speed_m_s=0.03, integral=0.56, raw_force=(10.0, 0.0, 0.0), lap=2)  # 60 mm/s
    up = task.step(slow, _ctx((10.0, 0.0, 0.0))).state
    assert up.speed_m_s > slow.speed_m_s
    assert up.integral == pytest.approx(slow.integral * up.speed_m_s / slow.speed_m_s, rel=1e-3)
    # at rest with the integral of 60 mm/s (3.9 mm/s into the contact, 10 um a cycle before)
    rest = replace(s, speed_m_s=0.0, raw_force=(10.0, 0.0, 0.0))
    out = task.step(rest, _ctx((10.0, 0.0, 0.0)))
    assert out.state.p_cmd[0] - rest.p_cmd[0] > -1e-6  # n = +x: into the contact is -x


def test_a_force_direction_the_tools_motion_contradicts_turns_the_normal_less():
    """Sliding at speed, the contour guides the tool: a plausible pull tilting the force 25 deg is taken
    only up to MOTION_GATE_DEG from the normal the motion implies."""
    task, _ = _task()
    tilt = math.radians(25.0)
    pulled = (10.0 * math.cos(tilt), 10.0 * math.sin(tilt), 0.0)
    s = _tracking(task, speed_m_s=0.06, last_xy=(0.07, -0.00015), force_f=pulled, raw_force=pulled)
    contradicted = task.step(s, _ctx(pulled, tcp=(0.07, 0.0, 0.5))).state  # moved along +y: n = +x
    t = (-math.sin(tilt), math.cos(tilt))
    agreeing = task.step(
        replace(s, last_xy=(0.07 - 0.00015 * t[0], -0.00015 * t[1])), _ctx(pulled, tcp=(0.07, 0.0, 0.5))
    ).state  # moved along the pulled tangent
    turn = [math.atan2(x.normal[1], x.normal[0]) for x in (contradicted, agreeing)]
    assert 0.0 < turn[0] < turn[1]
    # no more than the tracker's step for a direction MOTION_GATE_DEG off
    assert turn[0] == pytest.approx(
        track_normal(0.0, 0.0, 0.0, math.radians(MOTION_GATE_DEG), DT, task.p.normal_tracker_hz)[0], rel=1e-9
    )


def _row(outcome: str, ride_through: bool = True, force_n: float = 20.0) -> dict[str, object]:
    return {
        "outcome": outcome,
        "ride_through": ride_through,
        "over_limit": force_n > LIMIT_N,
        "max_true_contact_force_n": force_n,
    }


def test_the_scans_verdict_counts_the_integrity_breaches_apart():
    """A spoofed sensor must end in the retract (issue "No impostor data"), never DONE: the 95 %
    is of the disturbances to ride through, and a breach that does not retract fails the scan."""
    from controller.tools.contour.scan import summary

    ride = [_row("DONE")] * 34
    assert summary([*ride, _row("retracted", False), _row("retracted", False)], LIMIT_N)["targets_met"]
    assert not summary([*ride, _row("retracted", False), _row("DONE", False)], LIMIT_N)["targets_met"]
    assert not summary([*ride, _row("retracted", False), _row("FAULT", False)], LIMIT_N)["targets_met"]
    # 95 % of those to ride through: 19 of 20 is enough (with the other one retracted), 18 is not
    assert summary([_row("DONE")] * 19 + [_row("retracted")], LIMIT_N)["targets_met"]
    assert not summary([_row("DONE")] * 18 + [_row("retracted")] * 2, LIMIT_N)["targets_met"]
    assert not summary([*ride, _row("DONE", force_n=61.0)], LIMIT_N)["targets_met"]  # over the limit


def test_the_stress_verdict_fails_a_run_that_left_the_tool_pressed_past_the_limit():
    """A quick stop that leaves the tool pressed into the part (112 N after a jammed carriage, an
    outside tester, 2026-12-06) is a breach even where the run ended named and its peak was counted."""
    from controller.tools.contour.stress import summary

    def row(end_n: float) -> dict[str, object]:
        return {
            "scenario": f"ends at {end_n:g} N",
            "outcome": "backed off",
            "ride_through": False,
            "over_limit": False,
            "max_true_contact_force_n": 59.0,
            "final_true_contact_force_n": end_n,
            "max_off_part_mm": 0.0,
            "final_off_part_mm": 0.0,
        }

    assert summary([row(10.0)], LIMIT_N, 0.012)["targets_met"]
    pressed = summary([row(10.0), row(LIMIT_N + 1.0)], LIMIT_N, 0.012)
    assert not pressed["targets_met"] and pressed["left_pressed"] == [f"ends at {LIMIT_N + 1.0:g} N"]


def test_every_scan_injection_passes_the_configurations_check():
    """An injection shorter than a cycle is refused by the configuration (it may hold no SYNC): the
    scan's own must all pass, or their recordings lose the 3D scene."""
    from controller.sim_config.fault_specs import check_fault
    from controller.tools.contour.scan import scenarios

    cfg = load_config(overrides={"task.kind": "contour"})
    places = [14.0 + 0.6125 * k for k in range(12)]  # the 12 places; the check is about durations
    for sc in scenarios(places, cfg.period_s):
        for fault in sc.faults:
            check_fault(fault, cfg.actuators.node_ids, cfg.sensor.node_id, cfg.period_s)


def test_every_stress_injection_passes_the_configurations_check():
    """The stress scan's scenarios are placed by an undisturbed run's times (its tare, approach,
    first contact, 8 places): each injection they give must be one the configuration accepts."""
    from controller.sim_config.fault_specs import check_fault
    from controller.tools.contour.stress import scenarios

    cfg = load_config(overrides={"task.kind": "contour"})
    times = {"TARE": 0.228, "APPROACH": 0.328, "TRACKING": 3.337}
    times.update({f"place{k}": 25.0 + 1.8 * k for k in range(1, 9)})
    kinds = set()
    for sc in scenarios(times, cfg.period_s):
        for fault in sc.faults:
            check_fault(fault, cfg.actuators.node_ids, cfg.sensor.node_id, cfg.period_s)
            kinds.add(fault.split("@")[0].split("=")[0])
    assert "stuck" in kinds  # the sensor stuck at a plausible value is among them
