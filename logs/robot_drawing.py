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

import contextlib
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


def _v(a: Sequence[float] | np.ndarray) -> Vec3:
    return (float(a[0]), float(a[1]), float(a[2]))


def _margin_color(fraction_used: float) -> Rgba:
    """Green at 0 (far from the limit), through yellow, red at 1 (at the limit) and beyond."""
    f = min(max(fraction_used, 0.0), 1.0)
    if f < 0.5:
        return (0.2 + 1.6 * f, 0.75, 0.25, 1.0)
    return (1.0, 0.75 * (1.0 - f) * 2.0, 0.15, 1.0)


def _force_arrow(pose: MeasuredPose) -> list[Primitive]:
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
            end=_v(tip),
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


def _workpiece(cfg: Config) -> list[Primitive]:
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


def _box_between(
    entity: str,
    a: np.ndarray,
    axis: np.ndarray,
    length_m: float,
    width_m: float,
    color: Rgba,
    label: str = "",
) -> Primitive:
    return Primitive(
        entity, Shape.BOX, color, start=_v(a), end=_v(axis), length_m=length_m, width_m=width_m, label=label
    )


# -- Cheope (seed 001) ------------------------------------------------------------------------------


@dataclass
class CheopeDrawing:
    """Three carriages on prismatic guides along the cone of axes n_j, rods to the platform joints."""

    cfg: Config
    robot_kind: str = "cheope"

    def __post_init__(self) -> None:
        from controller.robots.builtin import build_cheope

        self.robot = build_cheope(self.cfg.robot.model("cheope"))
        self.section = self.cfg.robot.model("cheope")
        self.trail = ReferenceTrail()

    def fixed(self) -> list[Primitive]:
        g, c = self.robot.geometry, self.section
        out = [
            Primitive(
                "base",
                Shape.CYLINDER,
                DARK,
                start=(0.0, 0.0, -0.02),
                end=(0.0, 0.0, 1.0),
                radius_m=0.12,
                length_m=0.04,
                label="base {0}",
            )
        ]
        for j, n in enumerate(g.axes):
            out.append(
                Primitive(
                    "guides",
                    Shape.CAPSULE,
                    GREY,
                    start=_v(c.stroke_min_m * n - 0.03 * n),
                    end=_v(c.stroke_max_m * n + 0.03 * n),
                    radius_m=0.012,
                    label=f"guide {j + 1}",
                )
            )
            out.append(
                Primitive(
                    "guides",
                    Shape.CAPSULE,
                    STEEL,
                    start=_v(0.0 * n),
                    end=_v(c.stroke_min_m * n),
                    radius_m=0.008,
                )
            )
        return out + _workpiece(self.cfg)

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three linear motors: a carriage sliding along its prismatic axis n_j (seed 001 §3)."""
        return tuple(
            ActuatedJoint(
                f"slider_{j + 1}",
                "prismatic",
                _v(n),
                visuals=(_box_between("sliders", np.zeros(3), n, 0.06, 0.04, BLUE),),
            )
            for j, n in enumerate(self.robot.geometry.axes)
        )

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.robots.cheope import joint_swing_rad

        g = self.robot.geometry
        self.trail.add(pose.reference_m)
        out: list[Primitive] = []
        q = np.asarray(pose.q, dtype=float)
        if q.shape != (3,) or not np.isfinite(q).all():
            return out + self.trail.primitive()
        sliders = q[:, None] * g.axes
        for j, s in enumerate(sliders):
            out.append(_box_between("sliders", s, g.axes[j], 0.06, 0.04, BLUE, f"q{j + 1} = {q[j]:.4f} m"))
        if pose.tcp_m is not None:
            tcp = np.asarray(pose.tcp_m, dtype=float)
            joints = tcp + g.platform_vectors
            swing = joint_swing_rad(g, tcp, q)
            limit = self.robot.limits.joint_swing_limit_rad
            for j in range(3):
                out.append(
                    Primitive(
                        "rods",
                        Shape.CAPSULE,
                        _margin_color(float(swing[j]) / limit),
                        start=_v(sliders[j]),
                        end=_v(joints[j]),
                        radius_m=0.007,
                        label=f"rod {j + 1}: joint swing {math.degrees(float(swing[j])):.1f} of "
                        f"{math.degrees(limit):.0f} deg",
                    )
                )
                out.append(Primitive("platform", Shape.SPHERE, STEEL, start=_v(joints[j]), radius_m=0.011))
            out.append(
                Primitive(
                    "platform",
                    Shape.CYLINDER,
                    STEEL,
                    start=_v((*tcp, 0.0, 0.0, 0.03)),
                    end=(0.0, 0.0, 1.0),
                    radius_m=g.platform_radius_m * 1.15,
                    length_m=0.012,
                )
            )
            out.append(
                Primitive(
                    "tool",
                    Shape.CYLINDER,
                    ORANGE,
                    start=_v((*tcp, 0.0, 0.0, 0.012)),
                    end=(0.0, 0.0, 1.0),
                    radius_m=0.004,
                    length_m=0.024,
                    label="tool",
                )
            )
            out.append(Primitive("tool", Shape.SPHERE, ORANGE, start=_v(tcp), radius_m=0.005))
        return out + _force_arrow(pose) + self.trail.primitive()


# -- 3-URU (seed 003) -------------------------------------------------------------------------------


@dataclass
class UruDrawing:
    """Three motors at A_i = d_b e_i, proximal links A_i C_i, distal links C_i B_i, platform at P."""

    cfg: Config
    robot_kind: str = "uru"

    def __post_init__(self) -> None:
        from controller.robots.builtin import build_uru

        self.robot = build_uru(self.cfg.robot.model("uru"))
        self.min_sin_th3 = self.cfg.robot.model("uru").min_sin_th3
        self.trail = ReferenceTrail()

    def fixed(self) -> list[Primitive]:
        g = self.robot.geometry
        e = np.eye(3)
        out = [Primitive("base", Shape.SPHERE, DARK, start=(0.0, 0.0, 0.0), radius_m=0.015, label="O")]
        for i in range(3):
            a = g.base_offset_m * e[i]
            out.append(
                Primitive("base", Shape.CAPSULE, GREY, start=(0.0, 0.0, 0.0), end=_v(a), radius_m=0.008)
            )
            out.append(
                Primitive(
                    "motors",
                    Shape.CYLINDER,
                    DARK,
                    start=_v(a - 0.03 * e[i]),
                    end=_v(e[i]),
                    radius_m=0.025,
                    length_m=0.05,
                    label=f"motor {i + 1}",
                )
            )
        return out + _workpiece(self.cfg)

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three motors on the base: a shaft turning about e_i at A_i with a crank mark; the links
        it drives through the bevel gears (seed 003 eq. (7)-(13)) are passive, computed from the pose."""
        g = self.robot.geometry
        e = np.eye(3)
        out = []
        for i in range(3):
            across = e[(i + 1) % 3]
            out.append(
                ActuatedJoint(
                    f"motor_{i + 1}",
                    "revolute",
                    _v(e[i]),
                    origin=_v(g.base_offset_m * e[i]),
                    visuals=(
                        Primitive(
                            "motors", Shape.CYLINDER, STEEL, end=_v(e[i]), radius_m=0.012, length_m=0.02
                        ),
                        _box_between("motors", 0.02 * across, across, 0.03, 0.008, ORANGE),
                    ),
                )
            )
        return tuple(out)

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.errors import NoSolutionError
        from controller.robots import uru

        self.trail.add(pose.reference_m)
        out: list[Primitive] = []
        if pose.tcp_m is None:
            return out + self.trail.primitive()
        g = self.robot.geometry
        p = np.asarray(pose.tcp_m, dtype=float)
        try:
            conf = uru.configuration(g, p)
        except (NoSolutionError, ValueError):
            return out + self.trail.primitive()
        e = np.eye(3)
        for i in range(3):
            a = g.base_offset_m * e[i]
            c = a + g.f[i] * conf.u[i]  # seed 003 §2: c_i = a_i + f_i u_i
            b = p + g.platform_offset_m * e[i]  # b_i = p + d_p e_i
            serial = abs(math.sin(float(conf.th3_rad[i])))
            used = (1.0 - serial) / max(1.0 - self.min_sin_th3, 1e-9)
            out.append(
                Primitive(
                    "proximal_links",
                    Shape.CAPSULE,
                    BLUE,
                    start=_v(a),
                    end=_v(c),
                    radius_m=0.008,
                    label=f"link {i + 1}",
                )
            )
            out.append(
                Primitive(
                    "distal_links",
                    Shape.CAPSULE,
                    _margin_color(used),
                    start=_v(c),
                    end=_v(b),
                    radius_m=0.007,
                    label=f"limb {i + 1}: sin th3 = {serial:.2f}",
                )
            )
            out.append(Primitive("joints", Shape.SPHERE, STEEL, start=_v(c), radius_m=0.011))
            out.append(Primitive("platform", Shape.CAPSULE, STEEL, start=_v(p), end=_v(b), radius_m=0.009))
        out.append(Primitive("tool", Shape.SPHERE, ORANGE, start=_v(p), radius_m=0.014, label="P"))
        return out + _force_arrow(pose) + self.trail.primitive()


# -- 3-nSPU (seeds 000, 004) ------------------------------------------------------------------------


@dataclass
class NspuDrawing:
    """Spheres at A_i with their nS planes, prismatic legs A_i B_i, the platform triangle B_1 B_2 B_3.

    The pose is not a function of the leg lengths (non-holonomic joints): the drawing integrates
    it from the configured start pose through the leg lengths it is given, one RKMK4 step per
    call (``advance_pose_to_leg_lengths``, seed 000), as the controller's odometry does with
    smaller steps; at ``DEFAULT_SCENE_RATE_HZ`` that is one 1.7 ms step per 50 ms.
    """

    cfg: Config
    robot_kind: str = "nspu"

    def __post_init__(self) -> None:
        from controller.robots.builtin import build_nspu

        self.robot = build_nspu(self.cfg.robot.model("nspu"))
        self.pose = self.robot.start
        self.last: tuple[float, np.ndarray] | None = None

    def fixed(self) -> list[Primitive]:
        g = self.robot.geometry
        out: list[Primitive] = []
        for i in range(3):
            out.append(
                Primitive("base", Shape.SPHERE, DARK, start=_v(g.a_m[i]), radius_m=0.012, label=f"A{i + 1}")
            )
            out.append(
                Primitive(
                    "base",
                    Shape.CYLINDER,
                    (0.5, 0.5, 0.55, 0.35),
                    start=_v(g.a_m[i]),
                    end=_v(g.r[i]),
                    radius_m=0.05,
                    length_m=0.002,
                    label=f"nS plane {i + 1}",
                )
            )
        return out

    def actuated_joints(self) -> tuple[ActuatedJoint, ...]:
        """The three legs: each a prismatic joint along the leg, from A_i (its direction set by the
        passive nS joint, computed: the leg's drawn part ``legs_<i>``) to B_i, a rod of the shortest
        leg length ending at B_i."""
        rod_m = self.cfg.robot.model("nspu").leg_min_m
        return tuple(
            ActuatedJoint(
                f"leg_{i + 1}",
                "prismatic",
                (0.0, 0.0, 1.0),
                parent=f"legs_{i}",
                visuals=(
                    Primitive(
                        "legs",
                        Shape.CAPSULE,
                        BLUE,
                        start=(0.0, 0.0, -rod_m),
                        end=(0.0, 0.0, 0.0),
                        radius_m=0.006,
                    ),
                ),
            )
            for i in range(3)
        )

    def moving(self, pose: MeasuredPose) -> list[Primitive]:
        from controller.errors import NoSolutionError
        from controller.robots.nspu import NspuModelError, advance_pose_to_leg_lengths, limb_state

        q = np.asarray(pose.q, dtype=float)
        if q.shape != (3,) or not np.isfinite(q).all():
            return []
        if self.last is not None and pose.t_s > self.last[0]:
            # keep the last pose when this one does not solve: a drawing never stops a recording
            with contextlib.suppress(NspuModelError, NoSolutionError, ValueError):
                self.pose = advance_pose_to_leg_lengths(
                    self.robot.geometry, self.pose, q, pose.t_s - self.last[0]
                )
        self.last = (pose.t_s, q)
        g = self.robot.geometry
        limbs = limb_state(g, self.pose.p_m, self.pose.R)
        out: list[Primitive] = []
        for i in range(3):
            b = limbs.b[i]
            out.append(
                Primitive(
                    "legs",
                    Shape.CAPSULE,
                    BLUE,
                    start=_v(g.a_m[i]),
                    end=_v(b),
                    radius_m=0.006,
                    label=f"leg {i + 1}: {q[i]:.4f} m",
                )
            )
            out.append(Primitive("platform", Shape.SPHERE, STEEL, start=_v(b), radius_m=0.008))
        ring = (*(_v(limbs.b[i]) for i in range(3)), _v(limbs.b[0]))
        out.append(Primitive("platform", Shape.LINE, STEEL, points=ring, radius_m=0.004))
        out.append(
            Primitive("tool", Shape.SPHERE, ORANGE, start=_v(self.pose.p_m), radius_m=0.006, label="P")
        )
        return out


def drawing_for_config(cfg: Config) -> RobotDrawing | None:
    """The drawing of the configured robot (its ``cheope.scene_drawings`` hook, controller/plugins.py);
    None for a robot that declares none (the viewers then show the numbers without a scene)."""
    from controller.plugins import SCENE_DRAWINGS

    factory = SCENE_DRAWINGS.get(cfg.robot.kind)
    drawing: RobotDrawing | None = None if factory is None else factory(cfg)
    return drawing
