"""A fourth robot, registered from this one file: what docs/tutorial/own-robot.md promises.

A toy Cartesian gantry (three orthogonal linear axes: the TCP is the axes' positions plus an
offset) with its configuration section, its model, its simulator hook and its registry entry,
all in tests/plugins/cheope_gantry_robot.py, registered here from a script. The test counts the
files the registration touched and runs the robot's path task to DONE against the simulated
drives, in simulated time.
"""

from __future__ import annotations

import inspect
import sys
from pathlib import Path

import numpy as np
import pytest
from cheope_gantry_robot import GANTRY, GantryRobot, gantry_kinematics

from controller.assembly import build_law
from controller.config import ConfigError, config_from_dict, config_to_dict, load_config
from controller.core.controller_state import Mode
from controller.errors import WorkspaceError
from controller.plugins import SIM_KINEMATICS
from controller.robot_registry import register_robot, robot_entry, unregister_robot
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import RunRecorder
from sim_backend.loopback import LoopbackExchange

REPO = Path(__file__).resolve().parents[2]


# -- the tests -----------------------------------------------------------------------------------


@pytest.fixture
def gantry():
    register_robot(GANTRY)
    SIM_KINEMATICS.register("gantry", gantry_kinematics)
    yield GANTRY
    unregister_robot("gantry")
    SIM_KINEMATICS.unregister("gantry")


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
    hook = SIM_KINEMATICS.get("gantry")
    assert hook is gantry_kinematics
    hook_module = sys.modules[hook.__module__]
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
    with pytest.raises(ConfigError, match=r"robot.kind = 'gantry': must be one of ") as refused:
        config_from_dict({"robot": {"kind": "gantry"}})
    known = str(refused.value).split("must be one of ")[1].split(", ")
    assert {"cheope", "nspu", "uru"} <= set(known) and "gantry" not in known  # and any plug-in installed


class TwinColumnGantry(GantryRobot):
    """Four axes: x, y and two z columns side by side, commanded alike (a gantry's twin columns)."""

    n_actuators = 4

    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        q = np.asarray(tcp_m, dtype=float) - self.offset
        return np.array([q[0], q[1], q[2], q[2]])

    def direct_kinematics(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.array([q[0], q[1], 0.5 * (q[2] + q[3])]) + self.offset


@pytest.fixture
def twin():
    from dataclasses import replace

    entry = replace(GANTRY, kind="twin", build=TwinColumnGantry)
    register_robot(entry)
    yield entry
    unregister_robot("twin")


def twin_config(**sections):
    return config_from_dict(
        {
            "robot": {"kind": "twin", "twin": {"offset_m": [0.0, 0.0, 0.2]}},
            "task": {"kind": "path", "path": {"center_m": [0.1, 0.0, 0.3], "radius_m": 0.05, "laps": 1.0}},
            "sensor": {"enabled": False},
            "recording": {"enabled": False},
            "monitoring": {"enabled": False},
            **sections,
        }
    )


def test_a_robot_of_four_axes_is_configured_with_four_node_ids_and_runs_its_path(twin):
    """The per-actuator lists have any length: four drives on the bus (nodes 1-4), four setpoints
    streamed, the twin columns at the same height all the way."""
    cfg = twin_config(
        actuators={"node_ids": [1, 2, 3, 4], "home_offsets_m": [0.0] * 4},
        sim={"drive": {"initial_positions_m": [0.1, 0.0, 0.1, 0.1], "encoder_offsets_m": [0.0] * 4}},
    )
    law = build_law(cfg)
    clock = SimulatedTime()
    exchange = LoopbackExchange(cfg, clock.clock)
    heights: list[tuple[float, float]] = []

    class Columns:
        def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
            assert len(outputs.targets) == 4 and len(inputs.drives) == 4
            heights.append((outputs.targets[2], outputs.targets[3]))

    final, _ = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(Columns(),)
    ).run(law.initial_state(), 30.0)
    assert final.mode == Mode.DONE, final.fault_reason
    assert np.allclose(exchange.plant.tcp_m, [0.15, 0.0, 0.3], atol=1e-4)
    assert heights and all(a == b for a, b in heights)


def test_a_per_actuator_list_of_the_wrong_length_is_named(twin):
    with pytest.raises(
        ConfigError, match=r"actuators.node_ids = \[1, 2, 3\]: 3 value\(s\) for the 4 actuators"
    ):
        build_law(twin_config())


def test_a_robot_without_a_capability_its_task_needs_is_refused_at_start_naming_it(gantry):
    """A robot that claims the contour but has no joint_motion: refused when the law is built, naming
    the capability and the member, never an AttributeError in the middle of the run."""
    from dataclasses import replace

    register_robot(replace(GANTRY, tasks=("path", "contour")))
    cfg = config_from_dict(
        {
            "robot": {"kind": "gantry"},
            "task": {"kind": "contour", "contour": {"expected_centre_m": [0.1, 0.0], "height_m": 0.3}},
            "safety": {"contact": {"witness_required": False}},
            "recording": {"enabled": False},
            "monitoring": {"enabled": False},
        }
    )
    with pytest.raises(
        ConfigError, match=r"needs the robot's JointMotion \(joint_motion\(\).*lacks joint_motion\(\)"
    ):
        build_law(cfg)


def test_the_simulated_workpiece_needs_the_robots_own_structure(gantry):
    """The simulator loads a robot's structure with that robot's masses and stiffness, never Cheope's:
    a robot without them (CompliantStructure) runs in free space, and a workpiece is refused naming
    what it lacks."""
    from sim_backend.plant import RobotPlant

    free = RobotPlant(gantry_config())
    assert free.tool is None and not free.loaded
    with pytest.raises(ValueError, match=r"lacks jacobian\(\), masses, actuator_stiffness_n_m"):
        RobotPlant(config_from_dict({**config_to_dict(gantry_config()), "sim": {"environment": "workpiece"}}))
    cheope = RobotPlant(load_config(overrides={"robot.mass.actuator_stiffness_n_m": 3.0e5}))
    assert cheope._compliance is not None and cheope._compliance.actuator_stiffness_n_m == 3.0e5


def test_a_robot_that_starts_inside_the_simulated_part_is_refused_naming_it():
    """A start inside the part (a plug-in robot's home in the disk faulted at 424 N mid-run) is refused
    when the simulator places the part, naming the start and the keys that move either."""
    from sim_backend.plant import RobotPlant

    start = RobotPlant(load_config(overrides={"sim.environment": "free"})).tcp_m
    inside = {
        "sim.environment": "workpiece",
        "sim.workpiece.centre_m": [float(start[0]) + 0.01, float(start[1])],  # 1 cm in, 6 cm from the rim
        "sim.workpiece.height_m": float(start[2]),
    }
    with pytest.raises(
        ValueError, match=r"starts inside the workpiece.*\[sim.workpiece\] centre_m, height_m"
    ):
        RobotPlant(load_config(overrides=inside))
    RobotPlant(
        load_config(overrides={**inside, "sim.workpiece.height_m": float(start[2]) + 0.05})
    )  # above it


def test_a_simulator_hook_that_starts_another_number_of_drives_is_refused_by_name(gantry):
    from controller.plugins import PluginError
    from sim_backend.plant import RobotPlant
    from sim_backend.plant_kinematics import RigidKinematics

    def two_drives(cfg, robot):
        return RigidKinematics(robot, (0.1, 0.2))

    SIM_KINEMATICS.unregister("gantry")
    SIM_KINEMATICS.register("gantry", two_drives)
    with pytest.raises(PluginError, match=r"robot.kind = 'gantry' starts 2 drive\(s\) for its 3 actuators"):
        RobotPlant(gantry_config())
