"""A robot's URDF, generated from its drawing, and the transforms of its links for every sample (no ROS here).

URDF describes a tree; a parallel robot is closed chains. As the convention allows: the actuated
joints are real URDF joints (prismatic or revolute, named as the robot's drawing names them:
``slider_j`` of Cheope, ``motor_j`` of the 3-URU, ``leg_j`` of the 3-nSPU; their positions are the
JointState), and every other moving part (rods, links, platform, tool) hangs from ``base`` by a
``floating`` joint whose pose the bridge computes each sample from the measured actuator positions
and TCP (the drawing's own kinematics, logs/robot_drawing.py) and publishes on ``/tf``. The fixed
parts are links on ``fixed`` joints (``/tf_static``), the measured TCP the link ``tcp``. So a
viewer that knows URDF and tf (rviz2's RobotModel, Foxglove's URDF layer) shows the robot from
``robot_description`` and ``/tf`` alone; no robot_state_publisher is needed (it would publish the
fixed and actuated links' transforms again, the same).

Link names: ``<entity>_<k>``, the k-th primitive of that drawing entity (``rods_0``, ``guides_3``),
``<joint>_link`` for the actuated joints. Shapes: a capsule is a cylinder and two spheres, as in
logs/foxglove_scene.py; polylines and arrows (the force, the reference trail) stay in the
``robot_markers`` topic. The sizes of passive parts are taken from the first sample (rigid parts).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from logs.foxglove_scene import BASE_FRAME, quaternion_from_to
from logs.robot_drawing import ActuatedJoint, JointedDrawing, MeasuredPose, Primitive, RobotDrawing, Shape

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # x, y, z, w
TCP_FRAME = "tcp"
_IDENTITY: Quat = (0.0, 0.0, 0.0, 1.0)
_Z: Vec3 = (0.0, 0.0, 1.0)
_DRAWN_AS_MARKERS = (Shape.LINE, Shape.ARROW)


@dataclass(frozen=True)
class Transform:
    """``child``'s pose in ``parent``'s frame: a tf2 TransformStamped without its stamp."""

    parent: str
    child: str
    translation: Vec3
    rotation: Quat = _IDENTITY


def _mul(a: Quat, b: Quat) -> Quat:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotate(q: Quat, v: Vec3) -> Vec3:
    x, y, z, _ = _mul(_mul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def _axis_angle(axis: Vec3, angle_rad: float) -> Quat:
    n = math.sqrt(sum(a * a for a in axis)) or 1.0
    s = math.sin(angle_rad / 2.0) / n
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle_rad / 2.0))


def rpy(q: Quat) -> Vec3:
    """URDF's fixed-axis roll, pitch, yaw of ``q`` [rad]."""
    x, y, z, w = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (roll, pitch, yaw)


def _scaled(v: Vec3, k: float) -> Vec3:
    return (v[0] * k, v[1] * k, v[2] * k)


def _add(a: Vec3, b: Vec3) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def primitive_frame(p: Primitive) -> tuple[Vec3, Quat]:
    """The frame a primitive is drawn in: at its start (centre), z along its axis."""
    if p.shape == Shape.CAPSULE:
        return p.start, quaternion_from_to(
            _Z, (p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2])
        )
    if p.shape in (Shape.CYLINDER, Shape.BOX):
        return p.start, quaternion_from_to(_Z, p.end)
    return p.start, _IDENTITY


def _geometry(p: Primitive) -> list[tuple[Vec3, str]]:
    """(offset along the primitive's frame, URDF geometry element) of each solid ``p`` is made of."""
    if p.shape == Shape.CAPSULE:
        length = math.dist(p.start, p.end)
        sphere = f'<sphere radius="{p.radius_m:.6g}"/>'
        return [
            ((0.0, 0.0, length / 2), f'<cylinder radius="{p.radius_m:.6g}" length="{length:.6g}"/>'),
            ((0.0, 0.0, 0.0), sphere),
            ((0.0, 0.0, length), sphere),
        ]
    if p.shape == Shape.CYLINDER:
        return [((0.0, 0.0, 0.0), f'<cylinder radius="{p.radius_m:.6g}" length="{p.length_m:.6g}"/>')]
    if p.shape == Shape.BOX:
        return [((0.0, 0.0, 0.0), f'<box size="{p.width_m:.6g} {p.width_m:.6g} {p.length_m:.6g}"/>')]
    if p.shape == Shape.SPHERE:
        return [((0.0, 0.0, 0.0), f'<sphere radius="{p.radius_m:.6g}"/>')]
    return []


def _xyz(v: Vec3) -> str:
    return " ".join(f"{x:.9g}" for x in v)


def _visuals(p: Primitive, frame: tuple[Vec3, Quat] = ((0.0, 0.0, 0.0), _IDENTITY)) -> list[str]:
    """``p``'s URDF visuals in a link whose frame puts ``p``'s own frame at ``frame``."""
    t, q = frame
    r, g, b, a = p.color
    out = []
    for offset, geometry in _geometry(p):
        at = _add(t, rotate(q, offset))
        out.append(
            f'    <visual><origin xyz="{_xyz(at)}" rpy="{_xyz(rpy(q))}"/><geometry>{geometry}</geometry>'
            f'<material name=""><color rgba="{r:.3g} {g:.3g} {b:.3g} {a:.3g}"/></material></visual>'
        )
    return out


def _link_names(primitives: Iterable[Primitive]) -> list[tuple[str, Primitive]]:
    counts: dict[str, int] = {}
    out = []
    for p in primitives:
        if p.shape in _DRAWN_AS_MARKERS:
            continue
        k = counts.get(p.entity, 0)
        counts[p.entity] = k + 1
        out.append((f"{p.entity.replace('/', '_')}_{k}", p))
    return out


def actuated_joints(drawing: RobotDrawing | None) -> tuple[ActuatedJoint, ...]:
    """The drawing's actuated joints, or none (a drawing that does not name them)."""
    return drawing.actuated_joints() if isinstance(drawing, JointedDrawing) else ()


class RobotDescription:
    """The URDF of ``drawing``'s robot and the transforms of its links, from its first sample ``first``."""

    def __init__(
        self, drawing: RobotDrawing, robot_name: str, strokes: tuple[float, float], first: MeasuredPose
    ) -> None:
        self.drawing = drawing
        self.joints = actuated_joints(drawing)
        self.joint_names = tuple(j.name for j in self.joints)
        self._actuated_entities = {v.entity for j in self.joints for v in j.visuals}
        self._parents = {j.parent for j in self.joints}
        self.fixed_links = _link_names(drawing.fixed())
        moving = self._passive(drawing.moving(first))
        self.passive_names = [name for name, _ in moving]
        self.urdf = self._urdf(robot_name, strokes, moving)

    def _passive(self, primitives: Iterable[Primitive]) -> list[tuple[str, Primitive]]:
        """The moving parts that are passive links: all but those an actuated joint draws, unless a joint
        hangs from them (then they are its computed frame)."""
        return [
            (name, p)
            for name, p in _link_names(primitives)
            if p.entity not in self._actuated_entities or name in self._parents
        ]

    def _urdf(
        self, robot_name: str, strokes: tuple[float, float], moving: list[tuple[str, Primitive]]
    ) -> str:
        lines = [
            '<?xml version="1.0"?>',
            "<!-- Generated by cheope (controller/ros2/robot_description.py) from the configured geometry.",
            "     Closed chains as URDF allows: the actuated joints are real joints (their positions in",
            "     JointState), the passive parts floating joints whose poses cheope ros2 computes and",
            "     publishes on /tf; the fixed parts fixed joints (/tf_static). -->",
            f"<robot name={quoteattr(robot_name)}>",
            f"  <link name={quoteattr(BASE_FRAME)}/>",
        ]
        for name, p in self.fixed_links:
            t, q = primitive_frame(p)
            lines += [
                f'  <joint name="{name}_fixed" type="fixed"><parent link="{BASE_FRAME}"/><child link="{name}"/>'
                f'<origin xyz="{_xyz(t)}" rpy="{_xyz(rpy(q))}"/></joint>',
                f'  <link name="{name}">',
                *_visuals(p),
                "  </link>",
            ]
        lo, hi = strokes
        for name, p in moving:
            lines += [
                f'  <joint name="{name}_passive" type="floating"><parent link="{BASE_FRAME}"/><child link="{name}"/></joint>',
                f'  <link name="{name}">',
                *([] if name in self._parents else _visuals(p)),
                "  </link>",
            ]
        for j in self.joints:
            lines += [
                f'  <joint name={quoteattr(j.name)} type="{j.kind}"><parent link="{j.parent}"/>'
                f'<child link="{j.name}_link"/><origin xyz="{_xyz(j.origin)}" rpy="0 0 0"/>'
                f'<axis xyz="{_xyz(j.axis)}"/><limit lower="{lo:.9g}" upper="{hi:.9g}" effort="0" velocity="0"/></joint>',
                f'  <link name="{j.name}_link">',
                *[v for p in j.visuals for v in _visuals(p, primitive_frame(p))],
                "  </link>",
            ]
        lines += [
            f'  <joint name="{TCP_FRAME}_passive" type="floating"><parent link="{BASE_FRAME}"/><child link="{TCP_FRAME}"/></joint>',
            f'  <link name="{TCP_FRAME}"/>',
            "</robot>",
        ]
        return "\n".join(lines) + "\n"

    def static_transforms(self) -> list[Transform]:
        """The fixed links (``/tf_static``)."""
        out = []
        for name, p in self.fixed_links:
            t, q = primitive_frame(p)
            out.append(Transform(BASE_FRAME, name, t, q))
        return out

    def transforms(self, pose: MeasuredPose, moving: Iterable[Primitive]) -> list[Transform]:
        """Every moving link at ``pose`` (``/tf``): the passive parts from ``moving`` (the drawing of this
        sample), the actuated links from the positions, the measured TCP. A part the drawing left out
        (no TCP known yet) is left out here too."""
        out = []
        for name, p in self._passive(moving):
            if name in self.passive_names:
                t, q = primitive_frame(p)
                out.append(Transform(BASE_FRAME, name, t, q))
        for j, value in zip(self.joints, pose.q, strict=False):
            if not math.isfinite(value):
                continue
            if j.kind == "prismatic":
                out.append(Transform(j.parent, f"{j.name}_link", _add(j.origin, _scaled(j.axis, value))))
            else:
                out.append(Transform(j.parent, f"{j.name}_link", j.origin, _axis_angle(j.axis, value)))
        if pose.tcp_m is not None:
            out.append(Transform(BASE_FRAME, TCP_FRAME, pose.tcp_m))
        return out
