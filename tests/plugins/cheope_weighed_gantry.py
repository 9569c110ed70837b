"""A plug-in robot with a structure: the toy gantry (cheope_gantry_robot.py) with masses and a servo
stiffness of its own keys, so the simulator and the configuration see a ``CompliantStructure``.
Declared in a distribution's metadata as ``[cheope.robots] weighed = cheope_weighed_gantry:WEIGHED``
(tests/unit/test_plugins.py: its masses are checked as the built-in robots' are)."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from cheope_gantry_robot import GantryRobot, GantrySection

from controller.plugin_api import ActuatorUnit, MassModel, RobotEntry, Section, rng


class WeighedSection(Section, frozen=True):
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.2)
    stroke_min_m: Annotated[float, rng(-10.0, 10.0)] = -0.3
    stroke_max_m: Annotated[float, rng(-10.0, 10.0)] = 0.3
    tool_kg: float = 2.0  # no range: a plug-in need not give one
    carriage_kg: float = 0.5
    cable_kg: float = 0.2
    actuator_stiffness_n_m: Annotated[float, rng(1.0, 1e12)] = 2.0e5


class WeighedGantry(GantryRobot):
    def __init__(self, s: WeighedSection) -> None:
        super().__init__(GantrySection(s.offset_m, s.stroke_min_m, s.stroke_max_m))
        self.masses = MassModel(s.tool_kg, s.carriage_kg, s.cable_kg)
        self.actuator_stiffness_n_m = s.actuator_stiffness_n_m

    def jacobian(self, tcp_m: np.ndarray) -> np.ndarray:
        return np.eye(3)  # each axis moves the TCP along itself


WEIGHED = RobotEntry(
    kind="weighed",
    section=WeighedSection,
    build=WeighedGantry,
    unit=ActuatorUnit.METRE,
    stroke=lambda s: (s.stroke_min_m, s.stroke_max_m),
    tasks=("path",),
)
