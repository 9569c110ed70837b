"""What each robot looks like in 3D: solid primitives in the base frame {0}, from its configured geometry.

One description for every viewer: ``logs/foxglove_scene.py`` turns it into ``foxglove.SceneUpdate``
messages (recordings, the live Foxglove server) and ``logs/rerun_scene.py`` into Rerun archetypes
(``cheope replay --rerun``, the live Rerun stream). A drawing has two halves:

- ``fixed()``: what does not move during a session (the base, the prismatic guides or the motors,
  the workpiece disk, the expected contour); a viewer gets it once;
- ``moving(pose)``: what a cycle moves (sliders, rods or links, platform, tool, the measured
  force as an arrow), drawn from the measured actuator positions and TCP; a viewer gets it
  decimated (``DEFAULT_SCENE_RATE_HZ``).

Every primitive belongs to an entity (``Primitive.entity``: ``base``, ``guides``, ``sliders``,
``rods``, ...): the Foxglove scene entity or the Rerun entity path under ``/world``. Where it helps,
a colour carries a margin: Cheope's rods turn from green to red as their spherical joints swing
towards the configured limit (seed 001 §5.2, 22 deg), the 3-URU's distal links as the serial
measure sin(th_i3) falls towards its minimum (seed 003 eq. (27)).

Units: metres, newtons; the force arrow is ``FORCE_ARROW_M_PER_N`` metres per newton.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from controller.config import Config

Vec3 = tuple[float, float, float]
Rgba = tuple[float, float, float, float]  # 0..1 each

FORCE_ARROW_M_PER_N = 0.002
DEFAULT_SCENE_RATE_HZ = 20.0  # moving parts: smooth to the eye, about 1/20 of a 400 Hz loop's cycles
# The reference trail is the one moving part that grows: 600 points, about 17 kB a drawing. Redrawn
# at the scene rate it was 85 % of /scene's bytes and made a 30-minute session's record 10 % larger;
# a line that gains one point a frame loses nothing to the eye redrawn twice a second.
TRAIL_ENTITY = "reference_path"
DEFAULT_TRAIL_INTERVAL_S = 0.5

GREY: Rgba = (0.55, 0.57, 0.60, 1.0)
DARK: Rgba = (0.30, 0.32, 0.35, 1.0)
STEEL: Rgba = (0.70, 0.72, 0.75, 1.0)
BLUE: Rgba = (0.25, 0.50, 0.90, 1.0)
ORANGE: Rgba = (0.90, 0.55, 0.20, 1.0)
YELLOW: Rgba = (1.00, 0.80, 0.00, 1.0)
RED: Rgba = (0.90, 0.15, 0.15, 1.0)
GREEN_FAINT: Rgba = (0.30, 0.75, 0.35, 0.8)
DISK: Rgba = (0.60, 0.45, 0.30, 0.85)


class Shape(StrEnum):
    CAPSULE = "capsule"  # a rod from start to end, radius
    CYLINDER = "cylinder"  # a disk or drum: centre, axis (unit), radius, length
    BOX = "box"  # centre, axis (its long side's direction), size along (axis, across, across)
    SPHERE = "sphere"  # centre, radius
    LINE = "line"  # a polyline through points, radius = half its width
    ARROW = "arrow"  # from start along vector


@dataclass(frozen=True)
class Primitive:
    entity: str
    shape: Shape
    color: Rgba
    start: Vec3 = (0.0, 0.0, 0.0)  # capsule / arrow start; centre of cylinder, box, sphere
    end: Vec3 = (0.0, 0.0, 0.0)  # capsule end; arrow tip; unit axis of cylinder and box
    radius_m: float = 0.0
    length_m: float = 0.0  # cylinder length; box size along its axis
    width_m: float = 0.0  # box size across its axis
    points: tuple[Vec3, ...] = ()
    label: str = ""


@dataclass(frozen=True)
class MeasuredPose:
    """One cycle as the drawing needs it: actuator positions and, where known, TCP and force."""

    t_s: float
    q: tuple[float, ...]
    tcp_m: Vec3 | None
    force_n: Vec3 | None
    reference_m: Vec3 | None = None


class RobotDrawing(Protocol):
    robot_kind: str

    def fixed(self) -> list[Primitive]: ...

    def moving(self, pose: MeasuredPose) -> list[Primitive]: ...


@dataclass(frozen=True)
class ActuatedJoint:
    """An actuated joint as a URDF joint (controller/ros2/robot_description.py): the robot's own name
    for it (the ROS JointState name), prismatic [m] or revolute [rad], its axis and origin in its
    parent's frame at joint value 0, its parent (``base``, or a moving part the drawing computes,
    named ``<entity>_<k>``: the k-th primitive of that entity in ``moving()``), and the shape of the
    link it moves, in that link's frame."""

    name: str
    kind: str  # "prismatic" or "revolute"
    axis: Vec3
    origin: Vec3 = (0.0, 0.0, 0.0)
    parent: str = "base"
    visuals: tuple[Primitive, ...] = ()


@runtime_checkable
class JointedDrawing(RobotDrawing, Protocol):
    """A drawing that also names its robot's actuated joints, one per actuator in actuator order (the
    ROS 2 bridge's URDF and JointState); the other moving parts are passive, computed each sample."""

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]: ...


def vec3(a: Sequence[float] | np.ndarray) -> Vec3:
    return (float(a[0]), float(a[1]), float(a[2]))


def margin_color(fraction_used: float) -> Rgba:
    """Green at 0 (far from the limit), through yellow, red at 1 (at the limit) and beyond."""
    f = min(max(fraction_used, 0.0), 1.0)
    if f < 0.5:
        return (0.2 + 1.6 * f, 0.75, 0.25, 1.0)
    return (1.0, 0.75 * (1.0 - f) * 2.0, 0.15, 1.0)


def force_arrow(pose: MeasuredPose) -> list[Primitive]:
    if pose.tcp_m is None or pose.force_n is None or not all(math.isfinite(x) for x in pose.force_n):
        return []
    f = np.asarray(pose.force_n)
    tip = np.asarray(pose.tcp_m) + f * FORCE_ARROW_M_PER_N
    return [
        Primitive(
            "force",
            Shape.ARROW,
            RED,
            start=pose.tcp_m,
            end=vec3(tip),
            radius_m=0.002,
            label=f"{float(np.linalg.norm(f)):.1f} N",
        )
    ]


@dataclass
class ReferenceTrail:
    """The last ``capacity`` reference points (decimated), drawn as one line: the path being followed."""

    capacity: int = 600
    points: list[Vec3] = field(default_factory=list)

    def add(self, p: Vec3 | None) -> None:
        if p is None or not all(math.isfinite(x) for x in p):
            return
        self.points.append(p)
        if len(self.points) > self.capacity:
            del self.points[: len(self.points) - self.capacity]

    def primitive(self) -> list[Primitive]:
        if len(self.points) < 2:
            return []
        return [Primitive(TRAIL_ENTITY, Shape.LINE, YELLOW, points=tuple(self.points), radius_m=0.0008)]


def workpiece_primitives(cfg: Config) -> list[Primitive]:
    """The workpiece where the simulator has it, and the outline the task expects (its entry's)."""
    from controller.tasks.registry import task_entry

    out: list[Primitive] = []
    env = cfg.sim.environment
    if env == "workpiece" or (env == "auto" and task_entry(cfg.task.kind).sim_environment == "workpiece"):
        w = cfg.sim.workpiece
        if w.shape == "disk" and not w.features:
            out.append(
                Primitive(
                    "workpiece/disk",
                    Shape.CYLINDER,
                    DISK,
                    start=(w.centre_m[0], w.centre_m[1], w.height_m),
                    end=(0.0, 0.0, 1.0),
                    radius_m=w.radius_m,
                    length_m=w.thickness_m,
                    label=f"workpiece r = {w.radius_m * 1000:.0f} mm",
                )
            )
        else:
            from sim_backend.plant import (
                workpiece_environment,  # geometry only: the outline the simulator uses
            )

            rim = workpiece_environment(w).contour_points(360)
            for dz in (-w.thickness_m / 2, w.thickness_m / 2):
                out.append(
                    Primitive(
                        "workpiece/outline",
                        Shape.LINE,
                        DISK,
                        radius_m=0.0015,
                        points=tuple((float(x), float(y), float(z) + dz) for x, y, z in rim),
                        label=f"workpiece: {w.shape.replace('_', ' ')}" if dz > 0 else "",
                    )
                )
    outline = task_entry(cfg.task.kind).expected_outline
    if outline is not None:
        out.append(
            Primitive(
                "workpiece/expected_contour",
                Shape.LINE,
                GREEN_FAINT,
                points=outline(cfg.task.model()),
                radius_m=0.0005,
            )
        )
    return out


def box_between(
    entity: str,
    a: np.ndarray,
    axis: np.ndarray,
    length_m: float,
    width_m: float,
    color: Rgba,
    label: str = "",
) -> Primitive:
    return Primitive(
        entity,
        Shape.BOX,
        color,
        start=vec3(a),
        end=vec3(axis),
        length_m=length_m,
        width_m=width_m,
        label=label,
    )


# -- Cheope (seed 001) ------------------------------------------------------------------------------


# -- 3-URU (seed 003) -------------------------------------------------------------------------------


# -- 3-nSPU (seeds 000, 004) ------------------------------------------------------------------------


def drawing_for_config(cfg: Config) -> RobotDrawing | None:
    """The drawing of the configured robot (its ``cheope.scene_drawings`` hook, controller/plugins.py);
    None for a robot that declares none (the viewers then show the numbers without a scene)."""
    from controller.plugins import SCENE_DRAWINGS

    factory = SCENE_DRAWINGS.get(cfg.robot.kind)
    drawing: RobotDrawing | None = None if factory is None else factory(cfg)
    return drawing
