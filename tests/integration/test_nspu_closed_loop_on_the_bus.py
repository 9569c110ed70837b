"""The 3-nSPU with a model mismatch, over the bus: the pose tracker closes the loop (issue 20).

The simulator process models a robot that differs from the controller's model (leg offsets,
joint-axis errors) and starts off the plan's start; the tracker's TPDOs reach the controller over
udp_multicast. With corrections the measured end pose is within the correction tolerance; with
none, the tracker measures the open-loop miss. The same runs in simulated time are in
tests/unit/test_nspu_integration.py; here the worker process plans and the frames cross the bus.

The outcome is mostly the planner's and the mismatch's (1.2 mm open-loop miss against a 0.2 mm
tolerance); late cycles are warned, not faulted. On a busy machine the simulator's TPDOs go
missing in runs (up to 22-34 cycles beside two CPU hogs, 2026-12-03): the summary's odometry
bridges them with the drives' setpoints (``odometry_setpoint_samples``), where one step over each
gap put it 0.03 mm (a gap of 4 of its 10-ms steps), 0.25 mm (8) or 2.8 mm (20) off the true pose.
The simulator integrates the platform's pose on a thread behind its answers; on a slow host that
thread fell seconds behind, and tracker samples of the old pose sent the correcting plans 6-542 mm
off the goal (2 of 3 runs beside one CPU hog): the simulated tracker now waits until the pose is integrated up
to its SYNC (sim_backend/plant.py ``tracker_frames``).
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from typing import Any

import pytest
from busy_machine import TOLERANT

pytestmark = [pytest.mark.integration, pytest.mark.slow]

MISMATCH = [
    "--set",
    "tracker.enabled=true",
    "--set",
    "sim.nspu.leg_offset_m=[0.0005,-0.0005,0.0005]",
    "--set",
    "sim.nspu.w4_axis_error_rad=[0.001,-0.001,0.001]",
    "--set",
    "sim.nspu.r_axis_error_rad=[-0.001,0.001,0.001]",
]
TOLERANCE_M, TOLERANCE_RAD = (
    2.0e-4,
    1.0e-3,
)  # robot.nspu.correction_tolerance_* in controller/robots/nspu/nspu.toml


def _demo(*args: str) -> dict[str, Any]:
    port = str(random.SystemRandom().randint(45000, 47999))
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller",
            "demo",
            "--robot",
            "nspu",
            "--json",
            "--udp-port",
            port,
            "--duration",
            "120",
            *TOLERANT,
            *MISMATCH,
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=400,
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert r.returncode == 0, r.stderr + r.stdout
    summary: dict[str, Any] = json.loads(r.stdout)
    assert summary["final_mode"] == "DONE", summary["fault_reason"]
    return summary


def test_with_the_tracker_the_measured_end_is_within_the_tolerance_despite_the_mismatch_and_an_off_start():
    s = _demo("--set", "sim.nspu.start_offset_m=[0.002,0.0,0.0]")
    loop = s["closed_loop"]
    # one plan from the measured start (2 mm off), at least one from the measured end
    assert loop["plans_from_measured_pose"] >= 2, loop
    assert loop["measured_position_error_m"] < TOLERANCE_M, loop
    assert loop["measured_angle_error_rad"] < TOLERANCE_RAD, loop


def test_without_corrections_the_tracker_measures_the_open_loop_miss():
    s = _demo("--set", "robot.nspu.max_corrections=0", "--set", "robot.nspu.correction_tolerance_m=0.01")
    loop = s["closed_loop"]
    assert loop["corrections"] == 0, loop
    # the miss the mismatch makes (1.2 mm in simulated time), seen by the tracker, not by the odometry
    assert loop["measured_position_error_m"] > 3 * TOLERANCE_M, loop
    assert s["position_error_m"] < TOLERANCE_M, s["position_error_m"]
