"""The plug-in API: everything a robot, a task or a command of your own imports, from this one module.

A plug-in is an installable distribution that declares entry points (controller/plugins.py; the
tutorial: docs/tutorial/own-robot.md). What it may use is re-exported here, and only this module's
names are promised to stay: the product's other modules may move.

- A robot: a ``RobotEntry`` (``cheope.robots``) with its ``Section`` (typed keys, ``rng`` ranges) and
  a model with the ``Robot`` port (``PoseStatus``, ``POSE_OK``, ``ActuatorUnit``, ``NoSolutionError``,
  ``WorkspaceError``). Its optional capabilities, checked at start against what its tasks
  (``TaskEntry.needs``) and the simulator ask: ``JointMotion`` (the contour task),
  ``CompliantStructure`` (the simulated workpiece presses on it; ``LumpedMasses``),
  ``ForceWitnessModel`` (the force sensor's second witness; ``contact_force_from_efforts`` computes it
  for any translational robot from its Jacobian and its ``MassModel``).
- Its simulator hook (``cheope.sim_kinematics``): ``(cfg, robot) -> PlantKinematics``, e.g.
  ``RigidKinematics``; its 3D scene (``cheope.scene_drawings``): ``cfg -> RobotDrawing`` drawing
  ``Primitive`` shapes; its analysis plots (``cheope.analyses``): ``(cfg, out_dir) -> dict``.
- A task: a ``TaskEntry`` (``cheope.tasks``) whose factory returns a ``BuiltTask`` holding a ``Task``
  (``TaskContext`` -> ``TaskStep`` with a ``JointReference``); ``PathTask`` follows any Cartesian
  trajectory. A task's own experiment for ``cheope demo``: an ``Experiment`` (``cheope.experiments``).
- A command: a ``Command`` (``cheope.commands``), ``cheope NAME``.
- From a script or a test instead of a distribution: ``register_robot``, ``register_task``,
  ``SIM_KINEMATICS.register``, ``SCENE_DRAWINGS.register``, ``ANALYSES.register``,
  ``EXPERIMENTS.register``, ``COMMANDS.register``.
"""

from __future__ import annotations

from controller.commands import COMMANDS, Command
from controller.config_schema import ConfigError, Section, rng
from controller.core.ports import (
    POSE_OK,
    ActuatorUnit,
    CompliantStructure,
    ContactExpectation,
    CycleObserver,
    CycleTiming,
    ForceWitnessModel,
    JointMotion,
    JointReference,
    LumpedMasses,
    PoseStatus,
    Robot,
    Task,
    TaskContext,
    TaskStep,
    missing_capability,
)
from controller.errors import NoSolutionError, WorkspaceError
from controller.experiments import EXPERIMENTS, Experiment
from controller.plugins import ANALYSES, SCENE_DRAWINGS, SIM_KINEMATICS, PluginError
from controller.robot_registry import RobotEntry, register_robot, unregister_robot
from controller.robots.performance import MassModel, contact_force_from_efforts
from controller.tasks.path_task import PathTask
from controller.tasks.registry import BuiltTask, TaskEntry, TaskSettings, register_task, unregister_task
from logs.robot_drawing import (
    BLUE,
    DARK,
    GREY,
    ORANGE,
    STEEL,
    YELLOW,
    MeasuredPose,
    Primitive,
    RobotDrawing,
    Shape,
)
from sim_backend.plant_kinematics import PlantKinematics, RigidKinematics

__all__ = [
    "ANALYSES",
    "BLUE",
    "COMMANDS",
    "DARK",
    "EXPERIMENTS",
    "GREY",
    "ORANGE",
    "POSE_OK",
    "SCENE_DRAWINGS",
    "SIM_KINEMATICS",
    "STEEL",
    "YELLOW",
    "ActuatorUnit",
    "BuiltTask",
    "Command",
    "CompliantStructure",
    "ConfigError",
    "ContactExpectation",
    "CycleObserver",
    "CycleTiming",
    "Experiment",
    "ForceWitnessModel",
    "JointMotion",
    "JointReference",
    "LumpedMasses",
    "MassModel",
    "MeasuredPose",
    "NoSolutionError",
    "PathTask",
    "PlantKinematics",
    "PluginError",
    "PoseStatus",
    "Primitive",
    "RigidKinematics",
    "Robot",
    "RobotDrawing",
    "RobotEntry",
    "Section",
    "Shape",
    "Task",
    "TaskContext",
    "TaskEntry",
    "TaskSettings",
    "TaskStep",
    "WorkspaceError",
    "contact_force_from_efforts",
    "missing_capability",
    "register_robot",
    "register_task",
    "rng",
    "unregister_robot",
    "unregister_task",
]
