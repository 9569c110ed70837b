"""The 3-nSPU in the controller: time scaling, the streamed plan in simulated time, demo end to end."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from busy_machine import TOLERANT

from controller.assembly import assemble, build_law
from controller.config import CONFIG_DIR, load_config
from controller.core.control_law import Mode
from controller.planning.nonholonomic import PlanningError
from controller.robots.nspu import leg_lengths_batch
from controller.robots.nspu_robot import pose_errors
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import RunRecorder
from sim_backend.loopback import LoopbackExchange

# a planned 2 s motion streamed in simulated time, and a demo over the bus: the slow tier (make test-all)
pytestmark = pytest.mark.slow

NSPU_TOML = CONFIG_DIR / "nspu.toml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(NSPU_TOML, {"recording.enabled": False, "monitoring.enabled": False})


@pytest.fixture(scope="module")
def streamed_run(cfg):
    """One plan (about 2 s), streamed through Ruckig to the simulated drives and mechanics."""
    clock = SimulatedTime()
    assembly = assemble(cfg)
    law, (report,) = assembly.law, assembly.reports
    exchange = LoopbackExchange(cfg, clock.clock)
    loop = CycleLoop(law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock,
                     observers=(RunRecorder(), report))
    final, _ = loop.run(law.initial_state(), 20.0)
    return law, exchange, final, report.summary(), report


def test_time_scaling_keeps_the_limits_and_the_path(streamed_run, cfg):
    law = streamed_run[0]
    s = law.task.streamed
    a = cfg.actuators
    f = cfg.robot.model("nspu").limit_fraction
    v, acc, j = s.peaks
    assert v <= f * a.max_velocity_m_s * 1.001 and acc <= f * a.max_acceleration_m_s2 * 1.001
    assert j <= f * a.max_jerk_m_s3 * 1.001
    assert max(v / (f * a.max_velocity_m_s), acc / (f * a.max_acceleration_m_s2), j / (f * a.max_jerk_m_s3)) > 0.99
    # zero velocity at both ends, start/end legs are the plan's
    assert np.allclose(s.rates_m_s[[0, -1]], 0.0, atol=1e-12)
    plan = streamed_run[4].plan
    assert np.allclose(s.legs_m[0], plan.legs_m[0], atol=1e-9)
    assert np.allclose(s.legs_m[-1], plan.legs_m[-1], atol=1e-6)
    # velocities are the derivative of the positions
    d = np.gradient(s.legs_m, s.t_s, axis=0)
    assert np.max(np.abs(d[2:-2] - s.rates_m_s[2:-2])) < 1e-3 * v
    # the streamed legs are those of the planned poses (time reparametrised, same path)
    assert np.allclose(leg_lengths_batch(plan.geometry, plan.p_m, plan.R)[[0, -1]], s.legs_m[[0, -1]], atol=1e-6)


def test_streamed_execution_reaches_the_goal(streamed_run):
    law, exchange, final, summary, _ = streamed_run
    assert final.mode == Mode.DONE, final.fault_reason
    assert summary["plan"]["status"] == "converged"
    # the simulated platform's own pose (integrated from the drives' actual positions)
    pe, ae = pose_errors(exchange.plant.kinematics.pose, law.robot.goal)
    assert pe < 1e-4 and ae < 1e-3
    # the controller's figure (integrated from the encoder readings) agrees with the simulator
    assert summary["position_error_m"] == pytest.approx(pe, abs=1e-6)
    assert summary["angle_error_rad"] == pytest.approx(ae, abs=1e-5)
    # the streaming adds to the plan's own end error, which is smaller
    assert summary["plan_end_position_error_m"] < pe
    assert summary["leg_tracking_error_m"]["max"] < 1e-4
    assert "non-holonomic" in summary["explanation"]


def test_planning_failure_is_refused_before_anything_moves():
    cfg = load_config(NSPU_TOML, {"robot.nspu.goal_position_m": [-0.004, -0.002, 0.35],
                                  "robot.nspu.goal_rpy_rad": [0.0, 0.0, -1.5708]})  # the paper's goal
    with pytest.raises(PlanningError, match="type-II"):
        build_law(cfg)


def test_legs_not_at_the_plan_start_fault(cfg):
    law = build_law(load_config(NSPU_TOML, {"robot.nspu.max_iterations": 50}))
    moved = load_config(NSPU_TOML, {"robot.nspu.start_position_m": [0.0, 0.0, 0.26]})  # the simulator starts here
    clock = SimulatedTime()
    exchange = LoopbackExchange(moved, clock.clock)
    loop = CycleLoop(law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock)
    final, _ = loop.run(law.initial_state(), 3.0)
    assert final.mode == Mode.FAULT and "not at the plan's start" in final.fault_reason


def test_demo_end_to_end(tmp_path):
    cmd = [sys.executable, "-m", "controller", "demo", "--robot", "nspu", "--json", "--max-duration", "60",
           *TOLERANT, "--set", f'recording.directory="{tmp_path}"',
           "--set", "monitoring.enabled=false"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    s = json.loads(out.stdout)
    assert s["final_mode"] == "DONE"
    assert s["plan"]["status"] == "converged"
    assert s["position_error_m"] < 2e-3 and s["angle_error_rad"] < 2e-2  # accuracy: see the simulated-time test
    assert "explanation" in s and s["reached_pose"] is not None
