"""A ROS 2 subscriber in its own process, for tests/integration/test_ros2_bridge.py: prints what it receives.

    python tests/ros2_probe.py --namespace /ns --count 5 [--call-stop] [--timeout 60]

Subscribes to every topic of the bridge (controller/ros2/bridge.py TOPICS) with its ROS type and
prints one JSON line per message (topic, stamp in seconds, the fields the test compares), then
``{"graph": {topic: [types]}}`` from the ROS graph. With ``--call-stop``, once ``--count`` messages
of each state topic arrived, it calls the ``stop`` service (std_srvs/Trigger), prints
``{"stop": {...}}`` and waits for one message on ``events``. Exit code 0, or 1 at the timeout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import rclpy
from rclpy.node import Node

from controller.ros2.bridge import STOP_SERVICE, TOPICS, message_class


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + header.stamp.nanosec * 1e-9


def _fields(topic: str, msg: Any) -> dict[str, Any]:
    if topic == "joint_states":
        return {
            "stamp": _stamp(msg.header),
            "frame": msg.header.frame_id,
            "name": list(msg.name),
            "position": list(msg.position),
        }
    if topic == "wrench":
        f, t = msg.wrench.force, msg.wrench.torque
        return {
            "stamp": _stamp(msg.header),
            "frame": msg.header.frame_id,
            "force": [f.x, f.y, f.z],
            "torque": [t.x, t.y, t.z],
        }
    if topic.startswith("tcp/"):
        p = msg.pose.position
        return {"stamp": _stamp(msg.header), "frame": msg.header.frame_id, "position": [p.x, p.y, p.z]}
    if topic == "robot_markers":
        return {
            "stamp": _stamp(msg.markers[0].header) if msg.markers else None,
            "namespaces": sorted({m.ns for m in msg.markers if m.ns}),
            "first_action": msg.markers[0].action if msg.markers else None,
            "count": len(msg.markers),
        }
    if topic == "diagnostics":
        (st,) = msg.status
        return {
            "stamp": _stamp(msg.header),
            "level": st.level[0] if isinstance(st.level, bytes) else int(st.level),
            "message": st.message,
            "values": {kv.key: kv.value for kv in st.values},
        }
    return {"stamp": float(msg.stamp.sec) + msg.stamp.nanosec * 1e-9, "level": int(msg.level), "msg": msg.msg}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", required=True)
    ap.add_argument("--count", type=int, default=5)
    ap.add_argument("--call-stop", action="store_true")
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args()
    rclpy.init()
    node = Node("cheope_test_probe")
    got: dict[str, int] = dict.fromkeys(TOPICS, 0)

    def on_message(topic: str) -> Any:
        def handle(msg: Any) -> None:
            got[topic] += 1
            print(json.dumps({"topic": topic, **_fields(topic, msg)}), flush=True)

        return handle

    for topic, type_name in TOPICS.items():
        node.create_subscription(message_class(type_name), f"{args.namespace}/{topic}", on_message(topic), 50)
    deadline = time.monotonic() + args.timeout
    state_topics = [t for t in TOPICS if t != "events"]
    while any(got[t] < args.count for t in state_topics):
        if time.monotonic() > deadline:
            print(json.dumps({"timeout": got}), flush=True)
            return 1
        rclpy.spin_once(node, timeout_sec=0.1)
    graph = {
        name: types for name, types in node.get_topic_names_and_types() if name.startswith(args.namespace)
    }
    print(json.dumps({"graph": graph}), flush=True)
    if args.call_stop:
        from std_srvs.srv import Trigger

        client = node.create_client(Trigger, f"{args.namespace}/{STOP_SERVICE}")
        while not client.wait_for_service(timeout_sec=0.1):
            if time.monotonic() > deadline:
                print(json.dumps({"timeout": "the stop service"}), flush=True)
                return 1
        future = client.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, future, timeout_sec=max(0.1, deadline - time.monotonic()))
        reply = future.result()
        print(
            json.dumps(
                {"stop": None if reply is None else {"success": reply.success, "message": reply.message}}
            ),
            flush=True,
        )
        events_before = got["events"]
        while got["events"] == events_before and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
