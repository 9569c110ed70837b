"""The 3-URU in the controller: adapter, path refusal, closed loop in simulated time, demo end to end."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from busy_machine import TOLERANT

from controller.assembly import build_law
from controller.config import ConfigError, load_config
from controller.configured_robot import actuator_units
from controller.core.controller_state import Mode
from controller.robot_registry import robot_entry
from controller.robots.uru import kinematics as uru
from controller.robots.uru.entry import build_uru
from controller.robots.uru.model import UruWorkspaceError
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import RunRecorder
from sim_backend.loopback import LoopbackExchange

URU_TOML = robot_entry("uru").config_file  # in the robot's home
SHORT = {"task.path.laps": 0.25, "task.path.speed_m_s": 0.05, "task.path.ramp_s": 0.3}


def _cfg(**overrides):
    return load_config(URU_TOML, {**SHORT, **overrides})


ROBOT = build_uru(_cfg().robot.model("uru"))


def test_fast_kinematics_and_checks_agree_with_the_model():
    rng = np.random.default_rng(1)
    g = ROBOT.geometry
    n = 0
    for p in rng.uniform(0.04, 0.22, size=(200, 3)):
        if uru.workspace_margin_m(g, p) < 0.02:
            continue
        n += 1
        q = ROBOT.inverse_kinematics(p)
        assert np.allclose(q, uru.inverse_kinematics(g, p), atol=1e-12)
        assert np.allclose(ROBOT.direct_kinematics(q), p, atol=1e-9)
        m = uru.singularity_measures(g, p)
        ok = (
            m.workspace_margin_m >= 0.02
            and np.min(np.abs(p)) >= 0.02
            and m.serial_min_sin_th3 >= 0.1
            and abs(m.translation_det_v) >= 0.05
            and abs(m.actuation_det_s) >= 0.05
            and abs(m.combined_det_a) >= 0.05
        )
        assert ROBOT.check_pose(p).ok == ok, (p, ROBOT.check_pose(p))
    assert n > 50


def test_jacobian_matches_finite_differences_of_the_motor_angles():
    p = np.array([0.12, 0.10, 0.14])
    h = 1e-6
    fd = np.column_stack(
        [
            (ROBOT.inverse_kinematics(p + h * e) - ROBOT.inverse_kinematics(p - h * e)) / (2 * h)
            for e in np.eye(3)
        ]
    )
    assert np.allclose(ROBOT.jacobian(p), fd, rtol=1e-6, atol=1e-6)


def test_rotary_units_come_from_the_rad_keys():
    u = actuator_units(_cfg())
    assert u.unit == "rad" and u.counts_per_unit == pytest.approx(2**20 / (2 * np.pi), rel=1e-6)
    assert (u.stroke_min, u.stroke_max) == (-3.2, 4.8)
    with pytest.raises(ConfigError, match="motor_min_rad"):
        _cfg(**{"robot.uru.motor_min_rad": 5.0})
    with pytest.raises(ConfigError, match="knee_sign"):
        _cfg(**{"robot.uru.knee_sign": 0})


def test_path_crossing_a_coordinate_plane_is_refused_and_names_the_locus():
    ok_cfg = _cfg(
        **{
            "task.path.center_m": [0.12, 0.08, 0.12],
            "task.path.normal": [0.0, 0.0, 1.0],
            "task.path.radius_m": 0.04,
            "task.path.laps": 1.0,
        }
    )
    build_law(ok_cfg)  # keeps 0.04 m from y = 0: accepted
    cfg = _cfg(
        **{
            "task.path.center_m": [0.12, 0.02, 0.12],
            "task.path.normal": [0.0, 0.0, 1.0],
            "task.path.radius_m": 0.04,
            "task.path.laps": 1.0,
        }
    )  # a full lap crosses y = 0
    with pytest.raises(UruWorkspaceError, match=r"plane y=0 \(eq. \(17\)\)") as err:
        build_law(cfg)
    assert "rotation singularity" in err.value.locus


def test_path_near_the_workspace_boundary_is_refused():
    cfg = _cfg(**{"task.path.center_m": [0.22, 0.22, 0.22], "task.path.radius_m": 0.04})
    with pytest.raises(UruWorkspaceError, match="workspace"):
        build_law(cfg)


def test_closed_loop_in_simulated_time_tracks_the_octant_circle():
    cfg = _cfg()
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    rec = RunRecorder()
    loop = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(rec,)
    )
    final, _ = loop.run(law.initial_state(), 20.0)
    assert final.mode == Mode.DONE, final.fault_reason
    err = np.asarray(rec.tracking_error_m)
    assert err.size > 300
    assert np.sqrt(np.mean(err**2)) < 5e-6 and err.max() < 3e-5  # m
    # the simulated platform (URU direct kinematics of the drives' motor angles) is where the path ends
    end = uru.default_path(0.25)
    assert np.linalg.norm(exchange.plant.tcp_m - end) < 1e-4


# A demo over the bus with the default real-time options, so with the CPU shield, whose guardian
# sweeps every normal task of the machine: run with the bus-process tests, one at a time, not in
# the in-process stage beside the other worker's shield scenarios (tests/cpu_shield_scenarios.py),
# whose processes it swept there (a fresh-clone CI run failed on it, 2026-11-30).
@pytest.mark.slow
@pytest.mark.bus_processes
def test_demo_end_to_end(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "controller",
        "demo",
        "--robot",
        "uru",
        "--json",
        "--duration",
        "60",
        *TOLERANT,
        "--set",
        f'recording.directory="{tmp_path}"',
        "--set",
        "monitoring.enabled=false",
    ] + [a for k, v in SHORT.items() for a in ("--set", f"{k}={v}")]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    summary = json.loads(out.stdout)
    assert summary["final_mode"] == "DONE"
    te = summary["tracking_error_m"]
    assert te["samples"] > 200 and te["rms"] < 5e-4  # m; over a real-time multicast bus (late cycles count)
