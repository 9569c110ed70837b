"""A robot drawing (``logs/robot_drawing.py``) as Foxglove ``SceneUpdate`` messages.

Foxglove's 3D panel draws a ``foxglove.SceneUpdate`` with no set-up: each ``SceneEntity`` replaces
the entity of the same id in its frame. The fixed parts go out once per session with no lifetime
(they stay), the moving parts at the drawing rate under the same ids, so each update replaces the
last. All entities are in the frame ``base`` ({0}), the parent of the ``/tcp`` transform.

Foxglove has no capsule: a capsule is a cylinder between its two end points and a sphere at each
end. Cylinders and cubes point their z axis along the primitive's axis; arrows point along x.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import TYPE_CHECKING

from logs.robot_drawing import Primitive, Shape, Vec3

if TYPE_CHECKING:
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

BASE_FRAME = "base"


def quaternion_from_to(a: Vec3, b: Vec3) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the shortest rotation taking direction ``a`` to direction ``b``."""
    ax, ay, az = a
    bx, by, bz = b
    # the sums as ``sum`` adds them (from 0, left to right), without a generator a call
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if na == 0.0 or nb == 0.0:
        return (0.0, 0.0, 0.0, 1.0)
    ax, ay, az = ax / na, ay / na, az / na
    bx, by, bz = bx / nb, by / nb, bz / nb
    d = ax * bx + ay * by + az * bz
    if d < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        px, py, pz = (1.0, 0.0, 0.0) if abs(ax) < 0.9 else (0.0, 1.0, 0.0)
        cx, cy, cz = ay * pz - az * py, az * px - ax * pz, ax * py - ay * px
        n = math.sqrt(cx * cx + cy * cy + cz * cz)
        return (cx / n, cy / n, cz / n, 0.0)
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    w = 1.0 + d
    n = math.sqrt(cx * cx + cy * cy + cz * cz + w * w)
    return (cx / n, cy / n, cz / n, w / n)


def _set_pose(
    pose: object, position: Vec3, q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
) -> None:
    p, o = pose.position, pose.orientation  # type: ignore[attr-defined]
    p.x, p.y, p.z = position
    o.x, o.y, o.z, o.w = q


def _set_color(color: object, rgba: tuple[float, float, float, float]) -> None:
    color.r, color.g, color.b, color.a = rgba  # type: ignore[attr-defined]


def _add(entity: object, p: Primitive) -> None:
    """Append ``p`` to the SceneEntity ``entity`` as Foxglove primitives."""
    e = entity
    if p.shape in (Shape.CAPSULE, Shape.CYLINDER):
        if p.shape == Shape.CAPSULE:
            d = (p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2])
            length = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            centre = ((p.start[0] + p.end[0]) / 2, (p.start[1] + p.end[1]) / 2, (p.start[2] + p.end[2]) / 2)
            for end in (p.start, p.end):
                s = e.spheres.add()  # type: ignore[attr-defined]
                _set_pose(s.pose, end)
                s.size.x = s.size.y = s.size.z = 2.0 * p.radius_m
                _set_color(s.color, p.color)
        else:
            d, length, centre = p.end, p.length_m, p.start
        c = e.cylinders.add()  # type: ignore[attr-defined]
        _set_pose(c.pose, centre, quaternion_from_to((0.0, 0.0, 1.0), d))
        c.size.x = c.size.y = 2.0 * p.radius_m
        c.size.z = length
        c.bottom_scale = c.top_scale = 1.0
        _set_color(c.color, p.color)
    elif p.shape == Shape.BOX:
        b = e.cubes.add()  # type: ignore[attr-defined]
        _set_pose(b.pose, p.start, quaternion_from_to((0.0, 0.0, 1.0), p.end))
        b.size.x = b.size.y = p.width_m
        b.size.z = p.length_m
        _set_color(b.color, p.color)
    elif p.shape == Shape.SPHERE:
        s = e.spheres.add()  # type: ignore[attr-defined]
        _set_pose(s.pose, p.start)
        s.size.x = s.size.y = s.size.z = 2.0 * p.radius_m
        _set_color(s.color, p.color)
    elif p.shape == Shape.LINE:
        ln = e.lines.add()  # type: ignore[attr-defined]
        _set_pose(ln.pose, (0.0, 0.0, 0.0))
        ln.thickness = 2.0 * p.radius_m
        for x, y, z in p.points:
            pt = ln.points.add()
            pt.x, pt.y, pt.z = x, y, z
        _set_color(ln.color, p.color)
    elif p.shape == Shape.ARROW:
        d = (p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2])
        length = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if length == 0.0:
            return
        a = e.arrows.add()  # type: ignore[attr-defined]
        _set_pose(a.pose, p.start, quaternion_from_to((1.0, 0.0, 0.0), d))
        a.head_length = min(0.02, 0.4 * length)
        a.shaft_length = length - a.head_length
        a.shaft_diameter = 2.0 * p.radius_m
        a.head_diameter = 5.0 * p.radius_m
        _set_color(a.color, p.color)
    if p.label:
        t = e.texts.add()  # type: ignore[attr-defined]
        at = p.end if p.shape in (Shape.CAPSULE, Shape.ARROW) else p.start
        _set_pose(t.pose, (at[0], at[1], at[2] + 0.02))
        t.billboard = True
        t.scale_invariant = True
        t.font_size = 12.0
        t.text = p.label
        _set_color(t.color, (1.0, 1.0, 1.0, 1.0))


def scene_update(primitives: list[Primitive], unix_ns: int, entities: tuple[str, ...] = ()) -> SceneUpdate:
    """One SceneUpdate: an entity per ``Primitive.entity``, in frame ``base``.

    ``entities`` are sent even when no primitive is in them (empty): a part that is not drawn
    this time (the force arrow without a force) must replace, not keep, its last drawing.
    """
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    groups: dict[str, list[Primitive]] = defaultdict(list)
    for name in entities:
        groups[name] = []
    for p in primitives:
        groups[p.entity].append(p)
    msg = SceneUpdate()
    for name, parts in groups.items():
        e = msg.entities.add()
        e.timestamp.FromNanoseconds(unix_ns)
        e.frame_id = BASE_FRAME
        e.id = name
        e.frame_locked = False
        for p in parts:
            _add(e, p)
    return msg
