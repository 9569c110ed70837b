"""Hybrid force/velocity contour tracking: the law on its own, then closed loop on the simulator."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from controller.analysis.contour_report import ContourObserver, constant_speed_laps, contour_summary
from controller.config import load_config
from controller.control_law import Mode
from controller.cycle_data import CycleInputs, DriveFeedback, SensorFeedback
from controller.loop import CycleLoop, SimulatedTime
from controller.service import build_contour_task, build_law, build_robot
from controller.setpoint_smoothing import Setpoint
from controller.tasks.contour_tracking import ContourPhase, ContourState
from controller.tasks.task import TaskContext
from sim_backend.loopback import LoopbackExchange

FAST = {"task.kind": "contour", "task.contour.lap_speeds_m_s": [0.05, 0.08]}
DT = 0.0025


def _task(**overrides):
    cfg = load_config(overrides={**FAST, **overrides})
    return build_contour_task(cfg, build_robot(cfg)), cfg


def _ctx(force, tcp=(0.07, 0.0, 0.5), t=1.0) -> TaskContext:
    sensor = SensorFeedback(tuple(force), (0.0, 0.0, 0.0), 0, 1, True)
    drives = tuple(DriveFeedback(0x1637, 0.55, True) for _ in range(3))
    return TaskContext(t, DT, Setpoint.at_rest((0.55,) * 3), CycleInputs(drives, sensor), tcp)


def _tracking(task, **fields) -> ContourState:
    s = replace(task.start(), phase=ContourPhase.TRACKING, p_cmd=(0.07, 0.0, 0.5))
    return replace(s, **fields)


def test_normal_estimate_removes_friction_with_the_friction_estimate():
    task, _ = _task(**{"task.contour.friction_estimate": 0.15, "task.contour.force_filter_hz": 1e4})
    true_n = (math.cos(0.3), math.sin(0.3))
    t = (-true_n[1], true_n[0])  # counter-clockwise tangent
    fn, mu = 10.0, 0.15
    force = (fn * (true_n[0] - mu * t[0]), fn * (true_n[1] - mu * t[1]), 0.0)  # F = Fn (n - mu t)
    s = _tracking(task, normal=(math.cos(0.29), math.sin(0.29)), speed_m_s=0.05, force_f=force)
    out = task.step(s, _ctx(force))
    est = out.state.normal
    assert math.atan2(est[1], est[0]) == pytest.approx(0.3, abs=2e-3)  # without compensation: off by 0.149 rad
    assert out.state.normal_force_n == pytest.approx(fn * math.cos(math.atan(mu)) * math.sqrt(1 + mu * mu), rel=1e-2)


def test_force_below_the_setpoint_moves_the_tool_into_the_contour():
    task, cfg = _task()
    s = _tracking(task, normal=(1.0, 0.0), force_f=(4.0, 0.0, 0.0), speed_m_s=0.0)
    out = task.step(s, _ctx((4.0, 0.0, 0.0)))
    dx = out.state.p_cmd[0] - s.p_cmd[0]
    assert dx < 0.0  # inward, along -n
    assert out.state.force_error_n == pytest.approx(cfg.task.contour.force_setpoint_n - 4.0, abs=0.2)
    s = _tracking(task, normal=(1.0, 0.0), force_f=(16.0, 0.0, 0.0), speed_m_s=0.0)
    assert task.step(s, _ctx((16.0, 0.0, 0.0))).state.p_cmd[0] > s.p_cmd[0]  # too hard: back off


def test_small_forces_do_not_turn_the_normal():
    task, cfg = _task()
    s = _tracking(task, normal=(1.0, 0.0), force_f=(0.1, 0.5, 0.0))  # below normal_min_force_n
    assert task.step(s, _ctx((0.1, 0.5, 0.0))).state.normal == (1.0, 0.0)


def test_laps_are_counted_around_the_fitted_centre_and_the_task_retracts_after_the_last():
    task, cfg = _task()
    centre = (0.003, -0.002)  # the contour is not where it was expected
    r = 0.07
    s = _tracking(task, normal=(1.0, 0.0))
    laps_seen = []
    n = 720
    for k in range(int(2.2 * n)):
        th = 2 * math.pi * k / n
        tcp = (centre[0] + r * math.cos(th), centre[1] + r * math.sin(th), 0.5)
        f = (10.0 * math.cos(th), 10.0 * math.sin(th), 0.0)
        out = task.step(replace(s, force_f=f), _ctx(f, tcp))
        s = out.state
        laps_seen += [e.message for e in out.events if e.kind == "lap"]
        if s.phase != ContourPhase.TRACKING:
            break
    assert laps_seen == ["lap 1 of 2 done", "lap 2 of 2 done"]
    assert s.phase in (ContourPhase.RETRACT, ContourPhase.FINISHED)
    assert math.dist(s.centre, centre) < 1e-4  # the least-squares circle found the real centre


def test_over_force_retracts_and_then_faults():
    task, cfg = _task()
    s = _tracking(task, normal=(1.0, 0.0))
    f = (cfg.task.contour.max_force_n + 5.0, 0.0, 0.0)
    out = task.step(replace(s, force_f=f), _ctx(f))
    assert out.state.phase == ContourPhase.RETRACT and not out.fault
    assert any(e.kind == "over_force" for e in out.events)
    s = out.state
    for _ in range(2000):
        out = task.step(replace(s, force_f=(0.0, 0.0, 0.0)), _ctx((0.0, 0.0, 0.0)))
        s = out.state
        if out.finished:
            break
    assert out.finished and "above the limit" in out.fault
    assert s.p_cmd[0] > 0.07 + 0.9 * cfg.task.contour.retract_distance_m  # moved out along the normal


@pytest.mark.parametrize("policy,phase", [("reapproach", ContourPhase.APPROACH), ("stop", ContourPhase.RETRACT)])
def test_contact_loss_is_counted_and_handled_as_configured(policy, phase):
    task, cfg = _task(**{"task.contour.on_contact_loss": policy})
    s = _tracking(task, normal=(1.0, 0.0))
    for _ in range(cfg.task.contour.contact_lost_cycles):
        out = task.step(replace(s, force_f=(0.0, 0.0, 0.0)), _ctx((0.0, 0.0, 0.0)))
        s = out.state
    assert s.phase == phase
    assert s.contact_losses[0] == 1
    assert any(e.kind == "contact_lost" for e in out.events)


def test_approach_without_contact_faults_after_the_configured_distance():
    task, cfg = _task()
    s = replace(task.start(), phase=ContourPhase.APPROACH)
    c = cfg.task.contour
    for k in range(100000):
        out = task.step(s, _ctx((0.0, 0.0, 0.0)))
        s = out.state
        if out.fault:
            break
    assert "no contact within" in out.fault
    assert s.travel_m == pytest.approx(c.approach_clearance_m + c.max_approach_distance_m, abs=c.approach_speed_m_s * DT * 2)


def _closed_loop(**overrides):
    cfg = load_config(overrides={**FAST, **overrides})
    c = cfg.task.contour
    clock = SimulatedTime()
    law = build_law(cfg)
    ex = LoopbackExchange(cfg, clock.clock)
    obs = ContourObserver(c.force_setpoint_n, c.expected_centre_m, len(c.lap_speeds_m_s))
    final, _ = CycleLoop(law, ex, cfg.period_s, 0.8, clock, clock.clock, observers=(obs,)).run(
        law.initial_state(), 120.0)
    summary = contour_summary(obs, build_robot(cfg), cfg.robot.mass.actuator_stiffness_n_m, c.height_m,
                              c.lap_speeds_m_s)
    return final, summary, ex


@pytest.mark.parametrize("centre,radius", [((0.003, -0.002), 0.07), ((-0.002, 0.001), 0.066),
                                           ((0.0, 0.003), 0.073)])
def test_closed_loop_follows_an_off_centre_disk_of_another_radius(centre, radius):
    final, summary, ex = _closed_loop(**{"sim.disk.centre_m": list(centre), "sim.disk.radius_m": radius})
    assert final.mode == Mode.DONE, final.fault_reason
    assert [lap["lap"] for lap in summary["laps"]] == [1, 2]
    for lap, speed, tol in zip(summary["laps"], (0.05, 0.08), (0.08, 0.02)):  # lap 1 includes the ramp from rest
        assert lap["force_error_rms_n"] < 1.0
        assert lap["contact_losses"] == 0
        assert lap["speed_achieved_m_s"] == pytest.approx(speed, rel=tol)
    assert summary["force_error_vs_normal_stiffness_correlation"] is not None
    # the tool ends outside the disk, retracted
    tcp = ex.plant.tcp_m
    assert math.hypot(tcp[0] - centre[0], tcp[1] - centre[1]) > radius


def test_closed_loop_faults_when_there_is_nothing_to_touch():
    final, summary, _ = _closed_loop(**{"sim.disk.radius_m": 0.04})
    assert final.mode == Mode.FAULT and "no contact within" in final.fault_reason


def test_closed_loop_tracks_with_linear_motor_cogging_on():
    """The optional cogging disturbance (sim_backend/plant.py) leaves the task working: laps done, errors < 1.5 N.

    5 N of cogging at 80 mm/s comes at a few hertz, inside the force loop's band; the 10 Hz force
    filter (kept below the structure's modes) rejects it less well than the former 40 Hz: ~1.25 N.
    """
    final, summary, _ = _closed_loop(**{"sim.drive.cogging_force_n": 5.0})
    assert final.mode == Mode.DONE, final.fault_reason
    assert [lap["lap"] for lap in summary["laps"]] == [1, 2]
    for lap in summary["laps"]:
        assert lap["force_error_rms_n"] < 1.5
        assert lap["contact_losses"] == 0


def test_the_stiffness_correlation_uses_the_laps_after_the_last_speed_change():
    # the paper's laps IV and V: lap III starts by accelerating from lap II's speed
    assert constant_speed_laps((0.02, 0.04, 0.06, 0.06, 0.06), 5) == [3, 4]
    assert constant_speed_laps((0.02, 0.04, 0.06, 0.06, 0.06), 4) == [3]  # a run that ended early
    assert constant_speed_laps((0.05, 0.05), 2) == [1]
    assert constant_speed_laps((0.05, 0.08), 2) == [1]  # no lap at constant speed: the last one
    assert constant_speed_laps(None, 1) == [0]  # the position-controlled comparison
