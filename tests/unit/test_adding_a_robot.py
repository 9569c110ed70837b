"""A fourth robot, registered from this one file: what docs/tutorial/own-robot.md promises.

A toy Cartesian gantry (three orthogonal linear axes: the TCP is the axes' positions plus an
offset) with its configuration section, its model, its simulator hook and its registry entry,
all below. The test counts the files the registration touched and runs the robot's path task
to DONE against the simulated drives, in simulated time.
"""

from __future__ import annotations

import inspect
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import pytest

from controller.assembly import build_law
from controller.config import ConfigError, config_from_dict, config_to_dict
from controller.config_schema import Section, rng
from controller.core.control_law import Mode
from controller.robots.cheope import POSE_OK, PoseStatus, WorkspaceError
from controller.robots.registry import RobotEntry, register_robot, robot_entry, unregister_robot
from controller.robots.robot import ActuatorUnit
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import RunRecorder
from sim_backend.loopback import LoopbackExchange
from sim_backend.plant_kinematics import RigidKinematics

REPO = Path(__file__).resolve().parents[2]


# -- the robot: section, model, simulator hook, entry -------------------------------------------


class GantrySection(Section, frozen=True):
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.2)  # TCP when every axis is at 0
    stroke_min_m: Annotated[float, rng(-10.0, 10.0)] = -0.3
    stroke_max_m: Annotated[float, rng(-10.0, 10.0)] = 0.3
    home_m: tuple[float, float, float] = (0.1, 0.0, 0.3)  # where the simulated axes start


class GantryRobot:
    n_actuators = 3

    def __init__(self, section: GantrySection) -> None:
        self.offset = np.asarray(section.offset_m)
        self.lo, self.hi = section.stroke_min_m, section.stroke_max_m

    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        return np.asarray(tcp_m, dtype=float) - self.offset

    def direct_kinematics(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(q, dtype=float) + self.offset

    def check_pose(self, tcp_m: np.ndarray) -> PoseStatus:
        q = self.inverse_kinematics(tcp_m)
        if np.all((q >= self.lo) & (q <= self.hi)):
            return POSE_OK
        return PoseStatus(False, f"axis positions {q.round(4).tolist()} m outside [{self.lo}, {self.hi}] m")

    def check_path(self, points_m: np.ndarray) -> None:
        for i, p in enumerate(points_m):
            status = self.check_pose(p)
            if not status.ok:
                raise WorkspaceError(f"path sample {i} at {np.round(p, 4).tolist()} m: {status.reason}")


def gantry_kinematics(cfg, robot):  # the simulator hook: rigid, starting at home
    section: GantrySection = cfg.robot.model("gantry")
    return RigidKinematics(robot, tuple(robot.inverse_kinematics(np.asarray(section.home_m)).tolist()))


GANTRY = RobotEntry(
    kind="gantry",
    section=GantrySection,
    build=lambda cfg: GantryRobot(cfg.robot.model("gantry")),
    unit=ActuatorUnit.METRE,
    stroke=lambda s: (s.stroke_min_m, s.stroke_max_m),
    tasks=("path",),
    sim_hook=f"{__name__}:gantry_kinematics",
)


# -- the tests -----------------------------------------------------------------------------------


@pytest.fixture
def gantry():
    register_robot(GANTRY)
    yield GANTRY
    unregister_robot("gantry")


def gantry_config(**task_path):
    path = {"center_m": [0.1, 0.0, 0.3], "radius_m": 0.05, "speed_m_s": 0.1, "laps": 1.0, **task_path}
    return config_from_dict(
        {
            "robot": {"kind": "gantry", "gantry": {"offset_m": [0.0, 0.0, 0.2]}},
            "task": {"kind": "path", "path": path},
            "sensor": {"enabled": False},
            "recording": {"enabled": False},
            "monitoring": {"enabled": False},
        }
    )


def test_a_new_robot_is_registered_from_at_most_three_files(gantry):
    entry = robot_entry("gantry")
    hook_module = sys.modules[entry.sim_hook.partition(":")[0]]
    files = {
        Path(inspect.getsourcefile(obj)).resolve()
        for obj in (entry.section, entry.build, hook_module, GantryRobot)  # type: ignore[arg-type]
    }
    assert len(files) <= 3
    # and none of the product's own files had to change for it
    assert not any(
        f.is_relative_to(REPO / d) for f in files for d in ("controller", "drivers", "sim_backend", "logs")
    )


def test_the_new_robot_runs_its_path_task_on_the_simulated_drives(gantry):
    cfg = gantry_config()
    assert config_to_dict(cfg)["robot"]["gantry"]["offset_m"] == (0.0, 0.0, 0.2)
    law = build_law(cfg)
    clock = SimulatedTime()
    exchange = LoopbackExchange(cfg, clock.clock)
    recorder = RunRecorder()
    loop = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(recorder,)
    )
    final, _ = loop.run(law.initial_state(), 30.0)
    assert final.mode == Mode.DONE, final.fault_reason
    tcp = exchange.plant.tcp_m  # the simulated gantry is back where the circle starts and ends
    assert np.allclose(tcp, [0.15, 0.0, 0.3], atol=1e-4)


def test_the_registry_refuses_what_the_new_robot_cannot_do(gantry):
    with pytest.raises(ConfigError, match=r"task.kind = 'contour': robot.kind = 'gantry' runs 'path'"):
        config_from_dict({"robot": {"kind": "gantry"}, "task": {"kind": "contour"}})
    with pytest.raises(ConfigError, match=r"unknown key\(s\) reach_m in \[robot.gantry\]"):
        config_from_dict({"robot": {"kind": "gantry", "gantry": {"reach_m": 1.0}}})
    with pytest.raises(WorkspaceError, match="path sample"):
        build_law(gantry_config(radius_m=0.5))


def test_an_unregistered_robot_is_named_with_the_known_ones():
    with pytest.raises(ConfigError, match=r"robot.kind = 'gantry': must be one of cheope, uru, nspu"):
        config_from_dict({"robot": {"kind": "gantry"}})
