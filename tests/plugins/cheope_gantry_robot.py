"""A robot brought by a plug-in: a toy Cartesian gantry, in this one file.

Three orthogonal linear axes, the TCP is the axes' positions plus an offset: its configuration
section, its model, its simulator hook, its 3D scene and its registry entry. Registered from a script with
``register_robot(GANTRY)`` (tests/unit/test_adding_a_robot.py), or declared in a distribution's
metadata as ``[cheope.robots] gantry = cheope_gantry_robot:GANTRY`` (tests/unit/test_plugins.py).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np

from controller.plugin_api import (
    DARK,
    ORANGE,
    POSE_OK,
    ActuatorUnit,
    MeasuredPose,
    PoseStatus,
    Primitive,
    RigidKinematics,
    RobotEntry,
    Section,
    Shape,
    WorkspaceError,
    rng,
)


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


class GantryDrawing:  # its 3D scene (logs/robot_drawing.py): a base plate, the three axes, the tool
    robot_kind = "gantry"

    def __init__(self, cfg) -> None:
        self.robot = GantryRobot(cfg.robot.model("gantry"))

    def fixed(self) -> list[Primitive]:
        return [Primitive("base", Shape.BOX, DARK, end=(1.0, 0.0, 0.0), length_m=0.6, width_m=0.6)]

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        o = self.robot.offset
        x, y, z = (float(v) for v in np.asarray(pose.q[:3]) + o)
        corners = (
            (float(o[0]), float(o[1]), float(o[2])),
            (x, float(o[1]), float(o[2])),
            (x, y, float(o[2])),
            (x, y, z),
        )
        return [
            Primitive("axes", Shape.LINE, DARK, points=corners, radius_m=0.004),
            Primitive("tool", Shape.SPHERE, ORANGE, start=(x, y, z), radius_m=0.01),
        ]


GANTRY = RobotEntry(
    kind="gantry",
    section=GantrySection,
    build=GantryRobot,
    unit=ActuatorUnit.METRE,
    stroke=lambda s: (s.stroke_min_m, s.stroke_max_m),
    tasks=("path",),
)
