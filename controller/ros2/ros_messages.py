"""A ``BridgeSample`` and the robot's drawing as ROS 2 messages (needs the ``ros2`` extra).

Times are ROS time, integer nanoseconds on the wall clock (samples.py). Frames: everything is in
``base`` ({0}, as ``/scene`` and ``/tcp`` in the recordings); set rviz2's fixed frame to ``base``. The drawing (logs/robot_drawing.py) becomes a ``MarkerArray`` that starts
with a DELETEALL and holds the fixed and the moving parts, one marker namespace per drawing
entity, so each array replaces the last whole and a late subscriber gets the whole robot with
the next sample. A capsule is a cylinder and a sphere at each end (rviz2 has no capsule), as
in logs/foxglove_scene.py.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped, TransformStamped, WrenchStamped
from rcl_interfaces.msg import Log
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header, String
from visualization_msgs.msg import Marker, MarkerArray

from controller.ros2.robot_description import Transform
from controller.ros2.samples import BridgeSample, Vec3, diagnostic_level
from logs.foxglove_scene import BASE_FRAME, quaternion_from_to
from logs.robot_drawing import Primitive, Shape

LOG_LEVELS = {0: Log.INFO, 1: Log.WARN, 2: Log.ERROR}  # cheope.v1.Severity -> rcl_interfaces/Log level
_Z: Vec3 = (0.0, 0.0, 1.0)
_X: Vec3 = (1.0, 0.0, 0.0)


def stamp(t_ns: int) -> Time:
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def header(t_ns: int, frame_id: str = BASE_FRAME) -> Header:
    return Header(stamp=stamp(t_ns), frame_id=frame_id)


def joint_state(s: BridgeSample, names: tuple[str, ...], velocities: tuple[float, ...]) -> JointState:
    """Measured actuator positions under the robot's joint names, with their velocities (samples.py:
    empty for the first sample) and the drives' efforts (0x6077; empty where a drive does not map it)."""
    return JointState(
        header=header(s.stamp_ns, ""),
        name=list(names),
        position=list(s.positions),
        velocity=list(velocities),
        effort=list(s.efforts),
    )


def robot_description(urdf: str) -> String:
    return String(data=urdf)


def clock(t_ns: int) -> Clock:
    return Clock(clock=stamp(t_ns))


def transforms(t_ns: int, tfs: list[Transform]) -> list[TransformStamped]:
    out = []
    for tf in tfs:
        m = TransformStamped(header=header(t_ns, tf.parent), child_frame_id=tf.child)
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = tf.translation
        r = m.transform.rotation
        r.x, r.y, r.z, r.w = tf.rotation
        out.append(m)
    return out


def wrench(s: BridgeSample) -> WrenchStamped | None:
    if s.force_n is None:
        return None
    msg = WrenchStamped(header=header(s.stamp_ns))
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = s.force_n
    # NaN where the torque is not known (the Zenoh state carries the forces only), not a measured zero
    torque = s.torque_nm if s.torque_nm is not None else (math.nan, math.nan, math.nan)
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = torque
    return msg


def pose(t_ns: int, p: Vec3 | None) -> PoseStamped | None:
    if p is None:
        return None
    msg = PoseStamped(header=header(t_ns))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = p
    msg.pose.orientation.w = 1.0  # a translational robot: the platform keeps the base's orientation
    return msg


def diagnostics(s: BridgeSample, node_name: str) -> DiagnosticArray:
    """diagnostic_msgs conventions: one status per component, named ``<node>: <component>``, its
    ``hardware_id`` the robot, level OK/WARN/ERROR, a one-line message and key/values."""
    level = diagnostic_level(s)
    values = [
        KeyValue(key="mode", value=s.mode),
        KeyValue(key="task", value=s.task),
        KeyValue(key="task_phase", value=s.task_phase),
        KeyValue(key="cycle", value=str(s.cycle)),
        KeyValue(key="t_s", value=repr(s.t_s)),
    ]
    values += [KeyValue(key=k, value=repr(v)) for k, v in s.counters.items()]
    values += [KeyValue(key=f"alarm_{i + 1}", value=a) for i, a in enumerate(s.alarms)]
    status = DiagnosticStatus(
        level=bytes([level]),
        name=f"{node_name}: controller {s.robot_id}",
        hardware_id=s.robot_id,
        message=s.mode + (f": {'; '.join(s.alarms)}" if s.alarms else ""),
        values=values,
    )
    return DiagnosticArray(header=header(s.stamp_ns, ""), status=[status])


def event_log(t_ns: int, severity: int, kind: str, text: str, logger_name: str) -> Log:
    """An event as a ``/rosout`` line of the bridge's logger, stamped with the event's own time."""
    return Log(
        stamp=stamp(t_ns),
        level=LOG_LEVELS.get(severity, Log.ERROR),
        name=logger_name,
        msg=f"[{kind}] {text}",
        file="",
        function=kind,
        line=0,
    )


def _color(rgba: tuple[float, float, float, float]) -> ColorRGBA:
    return ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _marker(kind: int, p: Primitive, t_s: int, at: Vec3, direction: Vec3 = _Z, axis: Vec3 = _Z) -> Marker:
    m = Marker(header=header(t_s), ns=p.entity, type=kind, action=Marker.ADD, color=_color(p.color))
    m.pose.position.x, m.pose.position.y, m.pose.position.z = at
    q = quaternion_from_to(axis, direction)
    m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w = q
    return m


def _sphere(p: Primitive, t_s: int, at: Vec3) -> Marker:
    m = _marker(Marker.SPHERE, p, t_s, at)
    m.scale.x = m.scale.y = m.scale.z = 2.0 * p.radius_m
    return m


def _cylinder(p: Primitive, t_s: int, centre: Vec3, direction: Vec3, length_m: float) -> Marker:
    m = _marker(Marker.CYLINDER, p, t_s, centre, direction)
    m.scale.x = m.scale.y = 2.0 * p.radius_m
    m.scale.z = length_m
    return m


_POINTS: dict[Vec3, Point] = {}  # the reference trail's points, reused while they stay in its window
_POINTS_KEPT = 4096


def _points(points: tuple[Vec3, ...]) -> list[Point]:
    """``Point`` messages for ``points``; building one costs microseconds of Python, and a 600-point trail
    that moves one point a sample cost most of a sample's time."""
    if len(_POINTS) > _POINTS_KEPT:
        _POINTS.clear()
    out = []
    for v in points:
        pt = _POINTS.get(v)
        if pt is None:
            pt = _POINTS[v] = Point(x=v[0], y=v[1], z=v[2])
        out.append(pt)
    return out


def primitive_markers(p: Primitive, t_s: int) -> list[Marker]:
    """``p`` as rviz2 markers (ids are set by ``markers``)."""
    out: list[Marker] = []
    if p.shape == Shape.CAPSULE:
        d = (p.end[0] - p.start[0], p.end[1] - p.start[1], p.end[2] - p.start[2])
        centre = ((p.start[0] + p.end[0]) / 2, (p.start[1] + p.end[1]) / 2, (p.start[2] + p.end[2]) / 2)
        out += [
            _sphere(p, t_s, p.start),
            _sphere(p, t_s, p.end),
            _cylinder(p, t_s, centre, d, math.sqrt(sum(x * x for x in d))),
        ]
    elif p.shape == Shape.CYLINDER:
        out.append(_cylinder(p, t_s, p.start, p.end, p.length_m))
    elif p.shape == Shape.BOX:
        m = _marker(Marker.CUBE, p, t_s, p.start, p.end)
        m.scale.x = m.scale.y = p.width_m
        m.scale.z = p.length_m
        out.append(m)
    elif p.shape == Shape.SPHERE:
        out.append(_sphere(p, t_s, p.start))
    elif p.shape == Shape.LINE:
        m = _marker(Marker.LINE_STRIP, p, t_s, (0.0, 0.0, 0.0))
        m.scale.x = 2.0 * p.radius_m
        m.points = _points(p.points)
        out.append(m)
    elif p.shape == Shape.ARROW:
        m = _marker(Marker.ARROW, p, t_s, (0.0, 0.0, 0.0), _X, _X)
        m.points = [
            Point(x=p.start[0], y=p.start[1], z=p.start[2]),
            Point(x=p.end[0], y=p.end[1], z=p.end[2]),
        ]
        m.scale.x, m.scale.y, m.scale.z = 2.0 * p.radius_m, 5.0 * p.radius_m, 0.02
        out.append(m)
    if p.label:
        at = p.end if p.shape in (Shape.CAPSULE, Shape.ARROW) else p.start
        t = Marker(
            header=header(t_s),
            ns=f"{p.entity}/labels",
            type=Marker.TEXT_VIEW_FACING,
            action=Marker.ADD,
            text=p.label,
            color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0),
        )
        t.pose.position.x, t.pose.position.y, t.pose.position.z = at[0], at[1], at[2] + 0.02
        t.pose.orientation.w = 1.0
        t.scale.z = 0.015  # text height [m]
        out.append(t)
    return out


def markers(primitives: Iterable[Primitive], t_s: int) -> list[Any]:
    """Every primitive's markers, numbered within their namespace."""
    out: list[Any] = []
    ids: dict[str, int] = {}
    for p in primitives:
        for m in primitive_markers(p, t_s):
            m.id = ids.get(m.ns, 0)
            ids[m.ns] = m.id + 1
            out.append(m)
    return out


def restamp(markers_: list[Any], t_s: int) -> list[Any]:
    """``markers_`` (built once: the fixed parts) stamped ``t_s``."""
    t = stamp(t_s)
    for m in markers_:
        m.header.stamp = t
    return markers_


def marker_array(t_s: int, *groups: list[Any]) -> MarkerArray:
    """DELETEALL, then the groups' markers (groups of distinct namespaces: the fixed and the moving parts)."""
    return MarkerArray(
        markers=[Marker(header=header(t_s), action=Marker.DELETEALL)] + [m for g in groups for m in g]
    )
