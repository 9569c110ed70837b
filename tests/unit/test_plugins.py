"""Plug-ins by entry point: a robot and a task from a distribution of their own, next to the built-ins.

The distribution is what ``pip install`` leaves behind: a ``*.dist-info`` folder with its
``entry_points.txt`` on ``sys.path``, beside its modules (tests/plugins/). Nothing of the
product's own files changes for it; the tests run the plug-in task on a built-in robot and the
plug-in robot, in simulated time.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from controller.assembly import build_law
from controller.config import ConfigError, config_from_dict, load_config
from controller.core.controller_state import Mode
from controller.plugins import PluginError
from controller.robot_registry import ROBOTS, register_robot, robot_kinds, unregister_robot
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.tasks.registry import TASKS, task_kinds
from sim_backend.loopback import LoopbackExchange

PLUGINS = Path(__file__).resolve().parents[1] / "plugins"
DATA = Path(__file__).resolve().parents[1] / "data"


def _install(site: Path, name: str, entry_points: str) -> None:
    info = site / f"{name}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(entry_points)


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """The plug-in distribution installed: found at the registries' next lookup."""
    _install(
        tmp_path,
        "cheope_gantry_plugins",
        "[cheope.robots]\ngantry = cheope_gantry_robot:GANTRY\n\n[cheope.tasks]\nsquare = cheope_square_task:SQUARE\n"
        "\n[cheope.sim_kinematics]\ngantry = cheope_gantry_robot:gantry_kinematics\n"
        "\n[cheope.scene_drawings]\ngantry = cheope_gantry_robot:GantryDrawing\n",
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(PLUGINS))
    ROBOTS.rediscover()
    TASKS.rediscover()
    yield tmp_path
    monkeypatch.undo()
    ROBOTS.rediscover()
    TASKS.rediscover()


def _run(cfg, max_s: float = 40.0):
    law = build_law(cfg)
    clock = SimulatedTime()
    exchange = LoopbackExchange(cfg, clock.clock)
    loop = CycleLoop(law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock)
    final, _ = loop.run(law.initial_state(), max_s)
    return final, exchange


def test_the_plugins_are_found_next_to_the_built_ins(installed):
    assert {"cheope", "uru", "nspu", "gantry"} <= set(robot_kinds())  # and any other installed
    assert {"path", "contour", "planned", "square"} <= set(task_kinds())


def test_a_plugin_task_runs_on_a_built_in_robot(installed):
    cfg = load_config(
        overrides={"task.kind": "square", "task.square.side_m": 0.06, "task.square.side_s": 0.6}
    )
    final, exchange = _run(cfg)
    assert final.mode == Mode.DONE, final.fault_reason
    # the square ends where it started: the first corner, (+h, -h) off its centre
    assert np.allclose(exchange.plant.tcp_m, [0.03, -0.03, 0.5], atol=2e-4)


def test_a_plugin_robot_runs_a_built_in_task_and_the_plugin_task(installed):
    for task in ("path", "square"):
        cfg = config_from_dict(
            {
                "robot": {"kind": "gantry"},
                "task": {
                    "kind": task,
                    "path": {"center_m": [0.1, 0.0, 0.3], "radius_m": 0.05},
                    "square": {"center_m": [0.1, 0.0, 0.3], "side_m": 0.05, "side_s": 0.5},
                },
                "sensor": {"enabled": False},
                "recording": {"enabled": False},
                "monitoring": {"enabled": False},
            }
        )
        final, _ = _run(cfg)
        assert final.mode == Mode.DONE, (task, final.fault_reason)


def test_a_task_runs_only_on_the_robots_it_names(installed):
    with pytest.raises(ConfigError, match=re.escape("task.kind = 'square': robot.kind = 'uru' runs 'path'")):
        config_from_dict({"robot": {"kind": "uru"}, "task": {"kind": "square"}})


def test_registering_a_robot_before_the_first_lookup_keeps_the_built_ins(installed):
    from cheope_gantry_robot import GANTRY

    register_robot(GANTRY)
    try:
        assert {"cheope", "uru", "nspu", "gantry"} <= set(robot_kinds())
    finally:
        unregister_robot("gantry")


def test_a_plugin_that_does_not_load_is_named(tmp_path, monkeypatch):
    _install(tmp_path, "broken_plugin", "[cheope.robots]\nbroken = no_such_module:ROBOT\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ROBOTS.rediscover()
    try:
        with pytest.raises(
            PluginError, match=r"entry point broken = 'no_such_module:ROBOT' of broken_plugin"
        ):
            robot_kinds()
    finally:
        monkeypatch.undo()
        ROBOTS.rediscover()


@pytest.mark.parametrize("group", ["cheope.robots", "cheope.tasks", "cheope.sim_kinematics"])
def test_a_name_another_distribution_declares_too_is_refused_naming_both(tmp_path, monkeypatch, group):
    """A plug-in named ``cheope`` took the built-in robot's simulator kinematics, or its model,
    depending on the order of sys.path, with no word (an outside tester's)."""
    from controller.plugins import SIM_KINEMATICS

    name, target = {"cheope.robots": ("cheope", "x:R"), "cheope.tasks": ("path", "x:T")}.get(
        group, ("cheope", "x:k")
    )
    _install(tmp_path, "clashing_plugin", f"[{group}]\n{name} = {target}\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ROBOTS.rediscover()
    TASKS.rediscover()
    try:
        lookup = {
            "cheope.robots": robot_kinds,
            "cheope.tasks": lambda: TASKS.entries(),
            "cheope.sim_kinematics": lambda: SIM_KINEMATICS.get("cheope"),
        }[group]
        with pytest.raises(PluginError, match="declare the same name: uninstall one of them") as raised:
            lookup()
        said = str(raised.value)
        from controller.plugins import listing_what_loads

        with listing_what_loads() as skipped:  # the command line's listing: a warning, not an end
            lookup()
        assert skipped == [said]
        assert f"entry point {name} = '{target}' of clashing_plugin (group {group})" in said
        assert re.search(rf"entry point {name} = '[\w.:]+' of cheope-controller \(group {group}\)", said)
    finally:
        monkeypatch.undo()
        ROBOTS.rediscover()
        TASKS.rediscover()


def test_a_plugin_that_does_not_load_is_named_and_stops_only_what_needs_it(tmp_path):
    """The parser lists every plug-in's robots and tasks: one that does not load ended every command
    with a 41-line traceback (``cheope stop`` and ``--help`` too), its one line naming it last. Now
    each command warns in one line; those that use robots and tasks refuse with it, exit 2."""
    _install(tmp_path, "broken_plugin", "[cheope.tasks]\nbad = no_such_module:BAD\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    said = (
        "entry point bad = 'no_such_module:BAD' of broken_plugin (group cheope.tasks) "
        "does not load: ModuleNotFoundError: No module named 'no_such_module'"
    )

    def cheope(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "controller", *args],
            capture_output=True,
            text=True,
            timeout=120,
            env=env,
            check=False,
        )

    demo = cheope("demo", "--simulated-time")
    assert demo.returncode == 2
    assert demo.stderr.splitlines() == [
        f"cheope: warning: {said}; the commands that use robots and tasks refuse",
        f"cheope demo: error: {said}",
    ]
    info = cheope("logs", "info", str(DATA / "path_quarter_lap.mcap"))
    assert info.returncode == 0 and "status     complete" in info.stdout
    assert info.stderr.splitlines() == [
        f"cheope: warning: {said}; the commands that use robots and tasks refuse"
    ]


def test_a_plugin_reusing_the_built_in_robots_name_is_named_where_the_robot_is_asked_for(tmp_path):
    """The clash was swallowed by the command line's listing, and the demo said only "robot.kind =
    'cheope': must be one of nspu, uru" (an outside tester, 44dbcbc)."""
    _install(tmp_path, "clashing_plugin", "[cheope.robots]\ncheope = x:R\n")
    demo = subprocess.run(
        [sys.executable, "-m", "controller", "demo", "--simulated-time"],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(tmp_path)},
        check=False,
    )
    assert demo.returncode == 2
    last = demo.stderr.splitlines()[-1]
    assert "error: robot.kind = 'cheope': must be one of" in last, demo.stderr
    assert "entry point cheope = 'x:R' of clashing_plugin (group cheope.robots)" in last, last
    assert "declare the same name: uninstall one of them" in last


def test_a_robots_simulator_hook_is_found_by_its_kind_and_one_that_does_not_load_is_named(
    installed, tmp_path, monkeypatch
):
    from cheope_gantry_robot import gantry_kinematics

    from controller.plugins import SIM_KINEMATICS

    assert SIM_KINEMATICS.get("gantry") is gantry_kinematics  # from the distribution's entry point
    assert SIM_KINEMATICS.get("no_such_robot") is None  # rigid kinematics, the simulator's default
    _install(tmp_path / "other", "broken_hooks", "[cheope.sim_kinematics]\nbroken = no_such_module:f\n")
    monkeypatch.syspath_prepend(str(tmp_path / "other"))
    with pytest.raises(PluginError, match=r"entry point broken = 'no_such_module:f' of broken_hooks"):
        SIM_KINEMATICS.get("broken")


def test_a_tasks_experiment_is_what_demo_runs_for_it_and_a_task_without_one_runs_plain(capsys):
    """``cheope demo --simulated-time`` runs the experiment declared for the task's kind
    (cheope.experiments), not a branch on "contour"; a task without one runs as it is."""
    from controller.cli import main
    from controller.experiments import EXPERIMENTS, Experiment

    assert main(["demo", "--task", "path", "--simulated-time", "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert plain["final_mode"] == "DONE" and plain["simulated_time"] is True
    assert plain["tracking_error_m"]["samples"] > 1000 and plain["tracking_error_m"]["max"] < 1e-4
    ran: list[str] = []

    def laps_in_simulated_time(cfg, max_duration_s, plot_dir):
        ran.append(cfg.task.kind)
        return {"final_mode": "DONE", "laps": 1}

    EXPERIMENTS.register("path", Experiment(over_bus=lambda *a: {}, simulated_time=laps_in_simulated_time))
    try:
        assert main(["demo", "--task", "path", "--simulated-time", "--json"]) == 0
    finally:
        EXPERIMENTS.unregister("path")
    assert ran == ["path"]
    assert json.loads(capsys.readouterr().out) == {"final_mode": "DONE", "laps": 1}


def test_a_plugin_robot_brings_its_scene_and_a_robot_without_one_records_none(installed, tmp_path):
    """The recording's scene (logs/scene_sampler.py) draws the gantry from its distribution's hook."""
    from cheope_gantry_robot import GantryDrawing

    from logs.robot_drawing import drawing_for_config
    from logs.scene_sampler import SceneSampler

    cfg = config_from_dict(
        {
            "robot": {"kind": "gantry"},
            "task": {"path": {"center_m": [0.1, 0.0, 0.3], "radius_m": 0.05}},
            "sensor": {"enabled": False},
        }
    )
    drawing = drawing_for_config(cfg)
    assert isinstance(drawing, GantryDrawing)
    sampler = SceneSampler.for_config(cfg)
    assert sampler is not None and [p.entity for p in sampler.fixed_once() or []] == ["base"]
    from logs.robot_drawing import MeasuredPose

    moved = drawing.moving(MeasuredPose(0.0, (0.1, 0.0, 0.05), None, None))
    assert moved[-1].entity == "tool" and np.allclose(moved[-1].start, (0.1, 0.0, 0.25))
    from controller.plugins import SCENE_DRAWINGS

    SCENE_DRAWINGS.register("gantry", None)  # a robot that declares no scene: the viewers show none
    try:
        assert drawing_for_config(cfg) is None and SceneSampler.for_config(cfg) is None
    finally:
        SCENE_DRAWINGS.unregister("gantry")


def test_a_plugin_brings_a_command_that_reads_its_robots_configuration(installed, capsys):
    """cheope.commands: ``cheope NAME`` with the configuration options, its robot by default, another
    robot's configuration refused naming both; the 3-nSPU's plan commands are declared the same way."""
    from controller.cli import build_parser, main
    from controller.commands import COMMANDS, Command

    def home(args, cfg):
        print(f"{cfg.robot.kind} offset {list(cfg.robot.model().offset_m)} verbose={args.loud}")
        return 0

    COMMANDS.register(
        "gantry-home",
        Command(
            "gantry: where home is",
            lambda p: p.add_argument("--loud", action="store_true"),
            home,
            ("gantry",),
        ),
    )
    try:
        assert main(["gantry-home", "--loud", "--set", "robot.gantry.offset_m=[0.0,0.0,0.1]"]) == 0
        assert capsys.readouterr().out.strip() == "gantry offset [0.0, 0.0, 0.1] verbose=True"
        cheope_toml = Path(__file__).resolve().parents[2] / "controller" / "configs" / "cheope.toml"
        assert main(["gantry-home", "--config", str(cheope_toml)]) != 0
        assert (
            "cheope gantry-home runs on robot.kind 'gantry'; robot.kind is 'cheope'"
            in capsys.readouterr().err
        )
    finally:
        COMMANDS.unregister("gantry-home")
    commands = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert {"plan", "plan-bench"} <= set(commands) and "gantry-home" not in commands


def test_the_contours_commands_are_its_own_and_the_old_spelling_reaches_them(capsys):
    """cheope contour-scan/-shapes/-stress are the contour's plug-in commands (cheope.commands), not the
    command line's; ``cheope faults --contour-shapes``, their spelling before, runs the same command."""
    from controller.cli import build_parser, main
    from controller.commands import COMMANDS, Command

    commands = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert {"contour-scan", "contour-shapes", "contour-stress"} <= set(commands)
    ran: list[tuple[str, bool]] = []

    def shapes(args, cfg):
        ran.append((cfg.task.kind, args.json))
        return 0

    COMMANDS.register("contour-shapes", Command("stand-in", lambda p: None, shapes))
    try:
        assert main(["faults", "--contour-shapes", "--json", "--set", 'task.kind="contour"']) == 0
    finally:
        COMMANDS.unregister("contour-shapes")
    assert ran == [("contour", True)]


def _bad_build(section, robot, shared):
    raise RuntimeError("bad task constructor exploded")


@pytest.mark.parametrize(
    ("build", "said"),
    [
        (_bad_build, "task bad could not be built: RuntimeError: bad task constructor exploded"),
        (lambda section, robot, shared: None, "task bad's build gave NoneType, not a BuiltTask"),
    ],
    ids=["raises", "gives-none"],
)
def test_a_task_whose_build_goes_wrong_is_refused_naming_it(build, said):
    """A plug-in task's build that raised, or gave None, ended the command with a traceback."""
    from controller.assembly import build_task
    from controller.configured_robot import actuator_units
    from controller.errors import RefusedError
    from controller.tasks.registry import TaskEntry

    TASKS.register(TaskEntry(kind="bad", section=None, build=build, robots=("cheope",)))
    try:
        cfg = load_config(overrides={"task.kind": "bad"})
        with pytest.raises(RefusedError) as raised:
            build_task(cfg, build_law(load_config()).robot, actuator_units(cfg))
        assert str(raised.value) == said
    finally:
        TASKS.unregister("bad")


def test_the_parser_scans_each_group_of_entry_points_once(monkeypatch):
    """Listing what loads (a0eefed) kept nothing, and the parser asks for the robots once per
    command: 61 scans of every distribution's entry points a start, where one per group is
    enough; in CI's emulated VM each took long enough to make its tests 2.5 times slower."""
    import controller.plugins as plugins
    from controller.cli import build_parser
    from controller.plugins import listing_what_loads

    scans: list[str] = []

    def counting(**selection: str):
        scans.append(selection.get("group", ""))
        return plugins_entry_points(**selection)

    plugins_entry_points = plugins.entry_points
    monkeypatch.setattr(plugins, "entry_points", counting)
    ROBOTS.rediscover()
    TASKS.rediscover()
    try:
        with listing_what_loads() as skipped:
            build_parser()
        assert skipped == []
        assert sorted(scans) == sorted(set(scans)), scans  # each group once
    finally:
        monkeypatch.undo()
        ROBOTS.rediscover()
        TASKS.rediscover()


@pytest.mark.parametrize(
    "masses,said",
    [
        (
            {"tool_kg": 0.0, "cable_kg": 0.0},
            "robot.weighed.tool_kg = 0.0, robot.weighed.carriage_kg = 0.5, robot.weighed.cable_kg = 0.0: "
            "the mass that moves with the tool (translating_kg) is 0 kg: it must be more than 0 kg "
            "(the simulated structure divides by it)",
        ),
        (
            {"carriage_kg": -1.0},
            "robot.weighed.tool_kg = 2.0, robot.weighed.carriage_kg = -1.0, robot.weighed.cable_kg = 0.2: "
            "the mass that moves with each actuator (per_actuator_kg) is -0.9 kg: it must be at least 0 kg",
        ),
    ],
    ids=["no-mass-with-the-tool", "negative"],
)
def test_a_plugin_robots_masses_are_checked_as_the_built_in_robots_are(tmp_path, monkeypatch, masses, said):
    """A plug-in robot's masses come from keys only its model reads: they were not checked, where
    Cheope's all at 0 are refused (a ZeroDivisionError in the simulated structure). The one check
    of every robot's masses (controller/robot_masses.py) refuses them when its model is built."""
    _install(tmp_path, "cheope_weighed_plugin", "[cheope.robots]\nweighed = cheope_weighed_gantry:WEIGHED\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ROBOTS.rediscover()
    try:
        cfg = config_from_dict(
            {"robot": {"kind": "weighed", "weighed": masses}, "sensor": {"enabled": False}}
        )
        with pytest.raises(ConfigError) as refused:
            build_law(cfg)
        assert str(refused.value) == said
    finally:
        monkeypatch.undo()
        ROBOTS.rediscover()
