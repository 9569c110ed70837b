"""A ROS 2 node of our own in its own process, for tests/integration/test_ros2_bridge.py: prints what it receives.

    python tests/ros2_probe.py --namespace /ns --count 5 [--call-stop] [--sim-time] [--timeout 60]

Subscribes to every topic of the bridge (controller/ros2/bridge.py: TOPICS under the namespace,
GLOBAL_TOPICS, and ``/clock``) with its ROS type and prints one JSON line per message (topic, stamp
in integer nanoseconds, the fields the test compares); ``robot_description`` with its QoS
(transient local: it came before this node). Once ``--count`` messages of each per-sample topic
arrived, and two ``/diagnostics``, it prints ``{"graph": {topic: [types]}}`` and, with ``--sim-time`` (the node's
``use_sim_time``: its clock follows ``/clock``), ``{"now": ns}``; where tf2_ros is installed, the
TCP from a tf2 buffer (``{"tf_tcp": [x, y, z]}``). With ``--call-stop`` it calls ``pause`` (which a
controller without --allow-remote-commands refuses), sets the ``force_setpoint_n`` parameter (the
same), then calls ``stop`` and waits for one more event on ``/rosout``. Exit code 0, or 1 at the timeout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from controller.ros2.bridge import (
    CLOCK_TOPIC,
    FORCE_PARAMETER,
    GLOBAL_TOPICS,
    NODE_NAME,
    STOP_SERVICE,
    TOPICS,
    message_class,
)

PER_SAMPLE = ("joint_states", "wrench", "tcp/measured", "tcp/reference", "robot_markers")


def _ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _fields(topic: str, msg: Any) -> dict[str, Any]:
    if topic == "joint_states":
        return {
            "stamp": _ns(msg.header.stamp),
            "name": list(msg.name),
            "position": list(msg.position),
            "velocity": list(msg.velocity),
            "effort": list(msg.effort),
        }
    if topic == "wrench":
        f, t = msg.wrench.force, msg.wrench.torque
        return {"stamp": _ns(msg.header.stamp), "force": [f.x, f.y, f.z], "torque": [t.x, t.y, t.z]}
    if topic.startswith("tcp/"):
        p = msg.pose.position
        return {"stamp": _ns(msg.header.stamp), "frame": msg.header.frame_id, "position": [p.x, p.y, p.z]}
    if topic == "robot_markers":
        return {
            "stamp": _ns(msg.markers[0].header.stamp) if msg.markers else None,
            "namespaces": sorted({m.ns for m in msg.markers if m.ns}),
            "first_action": msg.markers[0].action if msg.markers else None,
        }
    if topic == "robot_description":
        return {"urdf": msg.data}
    if topic == "/diagnostics":
        (st,) = msg.status
        return {
            "stamp": _ns(msg.header.stamp),
            "level": st.level[0] if isinstance(st.level, bytes) else int(st.level),
            "name": st.name,
            "hardware_id": st.hardware_id,
            "values": {kv.key: kv.value for kv in st.values},
        }
    if topic == CLOCK_TOPIC:
        return {"stamp": _ns(msg.clock)}
    return {"stamp": _ns(msg.stamp), "level": int(msg.level), "name": msg.name, "msg": msg.msg}


def _call(node: Node, name: str, deadline: float) -> dict[str, Any] | None:
    from std_srvs.srv import Trigger

    client = node.create_client(Trigger, name)
    while not client.wait_for_service(timeout_sec=0.1):
        if time.monotonic() > deadline:
            return None
    future = client.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, future, timeout_sec=max(0.1, deadline - time.monotonic()))
    reply = future.result()
    return None if reply is None else {"success": reply.success, "message": reply.message}


def _set_force(node: Node, bridge: str, deadline: float) -> dict[str, Any] | None:
    from rcl_interfaces.srv import SetParameters

    client = node.create_client(SetParameters, f"{bridge}/set_parameters")
    while not client.wait_for_service(timeout_sec=0.1):
        if time.monotonic() > deadline:
            return None
    request = SetParameters.Request(
        parameters=[Parameter(FORCE_PARAMETER, Parameter.Type.DOUBLE, 12.5).to_parameter_msg()]
    )
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=max(0.1, deadline - time.monotonic()))
    reply = future.result()
    if reply is None:
        return None
    (result,) = reply.results
    return {"successful": result.successful, "reason": result.reason}


def _tf_tcp(node: Node, deadline: float) -> list[float] | None:
    """base -> tcp from a tf2 buffer, where tf2_ros is installed (a ROS 2 installation; no wheel)."""
    try:
        from tf2_ros import Buffer, TransformListener
    except ImportError:
        return None
    buffer = Buffer()
    TransformListener(buffer, node)
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        if buffer.can_transform("base", "tcp", rclpy.time.Time()):
            t = buffer.lookup_transform("base", "tcp", rclpy.time.Time()).transform.translation
            return [t.x, t.y, t.z]
    return None


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", required=True)
    ap.add_argument("--count", type=int, default=5)
    ap.add_argument("--call-stop", action="store_true")
    ap.add_argument("--sim-time", action="store_true")
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args()
    rclpy.init()
    node = Node(
        "cheope_test_probe",
        parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, args.sim_time)],
    )
    got: dict[str, int] = {}

    def on_message(topic: str) -> Any:
        def handle(msg: Any) -> None:
            got[topic] = got.get(topic, 0) + 1
            print(json.dumps({"topic": topic, **_fields(topic, msg)}), flush=True)

        return handle

    latched = QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
    )
    for topic, type_name in TOPICS.items():
        qos = latched if topic == "robot_description" else 50
        node.create_subscription(
            message_class(type_name), f"{args.namespace}/{topic}", on_message(topic), qos
        )
    for topic, type_name in {**GLOBAL_TOPICS, CLOCK_TOPIC: "rosgraph_msgs/msg/Clock"}.items():
        if topic != CLOCK_TOPIC or not args.sim_time:  # with use_sim_time the node's own clock subscribes
            node.create_subscription(message_class(type_name), topic, on_message(topic), 50)
    deadline = time.monotonic() + args.timeout
    # and two /diagnostics (about 1 Hz: the spacing is checked), the URDF (transient local)
    while (
        any(got.get(t, 0) < args.count for t in PER_SAMPLE)
        or got.get("/diagnostics", 0) < 2
        or not got.get("robot_description")
    ):
        if time.monotonic() > deadline:
            print(json.dumps({"timeout": got}), flush=True)
            return 1
        rclpy.spin_once(node, timeout_sec=0.1)
    graph = {name: types for name, types in node.get_topic_names_and_types()}
    print(json.dumps({"graph": graph}), flush=True)
    if args.sim_time:
        print(json.dumps({"now": node.get_clock().now().nanoseconds}), flush=True)
    tcp = _tf_tcp(node, min(deadline, time.monotonic() + 10.0))
    if tcp is not None:
        print(json.dumps({"tf_tcp": tcp}), flush=True)
    if args.call_stop:
        bridge = f"{args.namespace}/{NODE_NAME}"
        print(json.dumps({"pause": _call(node, f"{args.namespace}/pause", deadline)}), flush=True)
        print(json.dumps({"set_force": _set_force(node, bridge, deadline)}), flush=True)
        events_before = got.get("/rosout", 0)
        print(json.dumps({"stop": _call(node, f"{args.namespace}/{STOP_SERVICE}", deadline)}), flush=True)
        while got.get("/rosout", 0) == events_before and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
