"""How the simulated plant turns its drives' positions into the tool's position: one hook per robot.

A robot's hook is declared by kind under the entry-point group ``cheope.sim_kinematics``
(``controller/plugins.py``; the built-ins in ``pyproject.toml``); a robot without one is rigid: the TCP is its direct kinematics, and the drives start at
``sim.drive.initial_positions_m``. The hook also says where the simulated drives start (where
the robot stands at power-on) and whether its linear motors' cogging loads the compliant
structure (``sim_backend/plant.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from controller.plugins import SIM_KINEMATICS, PluginError
from controller.robot_registry import check_axes

if TYPE_CHECKING:
    from controller.config import Config


class PlantKinematics(Protocol):
    cogging: bool  # the actuators are iron-core linear motors whose cogging the structure feels

    def initial_positions(self) -> tuple[float, ...]:
        """Where the simulated drives start [actuator unit]."""
        ...

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        """The TCP for drive positions ``q`` at ``t_s``; raises NoSolutionError where there is none."""
        ...


class RigidKinematics:
    """The TCP is the robot model's direct kinematics of the drives' positions."""

    def __init__(self, robot: Any, initial: tuple[float, ...], cogging: bool = False) -> None:
        self.robot = robot
        self._initial = tuple(float(x) for x in initial)
        self.cogging = cogging

    def initial_positions(self) -> tuple[float, ...]:
        return self._initial

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        return np.asarray(self.robot.direct_kinematics(q))


def plant_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    """The configured robot's hook, or rigid kinematics from ``sim.drive.initial_positions_m``."""
    factory = SIM_KINEMATICS.get(cfg.robot.kind)
    if factory is None:
        check_axes(
            cfg.robot.kind,
            robot.n_actuators,
            {"sim.drive.initial_positions_m": cfg.sim.drive.initial_positions_m},
        )
        return RigidKinematics(robot, cfg.sim.drive.initial_positions_m)
    kinematics: PlantKinematics = factory(cfg, robot)
    start = kinematics.initial_positions()
    if len(start) != robot.n_actuators:
        # the plant pairs each drive with its start positionally (plant.py): checked here, once
        raise PluginError(
            f"the simulator hook of robot.kind = {cfg.robot.kind!r} starts {len(start)} drive(s) "
            f"for its {robot.n_actuators} actuators: {list(start)}"
        )
    return kinematics
