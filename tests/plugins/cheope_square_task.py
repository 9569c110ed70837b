"""A task brought by a plug-in: a square in a plane parallel to XY, one module and one section.

What a person who brings a task writes: its configuration section, its trajectory, the factory
that builds the task for a robot, and its entry. The path task's machinery (move to the start,
inverse kinematics, the law's checks) does the rest. Declared in a distribution's metadata as

    [cheope.tasks]
    square = cheope_square_task:SQUARE

(tests/unit/test_plugins.py installs it that way, next to the built-ins).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from controller.plugin_api import BuiltTask, PathTask, Section, TaskEntry, TaskSettings, rng


class SquareSection(Section, frozen=True):
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.50)
    side_m: Annotated[float, rng(0.0, 1.0, lo_open=True)] = 0.08
    side_s: Annotated[float, rng(0.01, 600.0)] = 1.0  # each side, from rest to rest


@dataclass(frozen=True)
class SquarePath:
    """Corner to corner, each side with the quintic smoothstep: at rest in every corner."""

    center_m: tuple[float, float, float]
    side_m: float
    side_s: float

    @property
    def duration_s(self) -> float:
        return 4.0 * self.side_s

    def _corner(self, k: int) -> np.ndarray:
        h = self.side_m / 2.0
        dx, dy = ((h, -h), (h, h), (-h, h), (-h, -h))[k % 4]
        return np.asarray(self.center_m, dtype=float) + np.array([dx, dy, 0.0])

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tau = min(max(tau, 0.0), self.duration_s)
        k = min(int(tau / self.side_s), 3)
        x = tau / self.side_s - k
        a, b = self._corner(k), self._corner(k + 1)
        s = x**3 * (10 - 15 * x + 6 * x * x)
        ds = 30 * x * x * (1 - x) ** 2 / self.side_s
        dds = 60 * x * (1 - x) * (1 - 2 * x) / self.side_s**2
        return a + s * (b - a), ds * (b - a), dds * (b - a)

    def points(self, n: int) -> np.ndarray:
        return np.array([self.sample(t)[0] for t in np.linspace(0.0, self.duration_s, n)])


def build_square_task(s: SquareSection, robot, shared: TaskSettings) -> BuiltTask:
    path = SquarePath(s.center_m, s.side_m, s.side_s)
    robot.check_path(path.points(max(8, math.ceil(path.duration_s * 100))))
    return BuiltTask(PathTask(robot, path, settle_tolerance=shared.settle_tolerance_m))


SQUARE = TaskEntry(kind="square", section=SquareSection, build=build_square_task, robots=("cheope", "gantry"))
