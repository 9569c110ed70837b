"""``cheope ros2``: a controller's Zenoh state, or a recording, published as ROS 2 topics (the ``ros2`` extra).

Its own process, never the loop's: it subscribes to the state and events like ``cheope monitor``
(controller/monitoring/monitor_view.py) and publishes each state sample, as it arrives, under the
namespace (default ``/cheope``):

| topic | type | what |
| --- | --- | --- |
| ``joint_states`` | sensor_msgs/JointState | measured actuator positions, ``actuator_1..n`` |
| ``wrench`` | geometry_msgs/WrenchStamped | the force/torque sensor (torque only from a recording, else NaN) |
| ``tcp/measured`` | geometry_msgs/PoseStamped | the measured TCP |
| ``tcp/reference`` | geometry_msgs/PoseStamped | the TCP the actuator targets command (direct kinematics) |
| ``robot_markers`` | visualization_msgs/MarkerArray | the robot, drawn as ``/scene`` is (logs/robot_drawing.py) |
| ``diagnostics`` | diagnostic_msgs/DiagnosticArray | mode, task phase, alarms, loop counters |
| ``events`` | rcl_interfaces/Log | the controller's events |

and serves ``stop`` (std_srvs/Trigger): a stop request sent to the controller's ``command``
queryable, the gate ``cheope stop`` goes through (controller/monitoring/command_gate.py). Every
header is stamped with the controller's monotonic clock at that cycle (samples.py), in frame
``base``. ``--replay FILE`` publishes a recording's cycles the same way, at the recorded
monitoring rate and the recording's pace (``--speed``), with no stop service.

DDS stays on this machine unless the environment says otherwise: ``ROS_AUTOMATIC_DISCOVERY_RANGE``
is set to ``LOCALHOST`` when neither it nor ``ROS_LOCALHOST_ONLY`` is set.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from controller.errors import InputError
from controller.monitoring.zenoh_session import MonitoringConnectionError, MonitorKeys, SessionSettings
from controller.ros2.samples import BridgeSample, CycleSampler, sample_from_state

if TYPE_CHECKING:
    from controller.config import Config
    from controller.core.ports import Robot
    from logs.robot_drawing import RobotDrawing

DEFAULT_NAMESPACE = "/cheope"
NODE_NAME = "cheope_bridge"
TOPICS = {  # relative name -> ROS type, as ``ros2 topic list -t`` prints it
    "joint_states": "sensor_msgs/msg/JointState",
    "wrench": "geometry_msgs/msg/WrenchStamped",
    "tcp/measured": "geometry_msgs/msg/PoseStamped",
    "tcp/reference": "geometry_msgs/msg/PoseStamped",
    "robot_markers": "visualization_msgs/msg/MarkerArray",
    "diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "events": "rcl_interfaces/msg/Log",
}
STOP_SERVICE = "stop"


class Ros2UnavailableError(InputError):
    """The ROS 2 Python packages are not installed (the ``ros2`` extra)."""


def keep_dds_local() -> None:
    """DDS discovery on this machine only, unless the user chose a range."""
    if "ROS_AUTOMATIC_DISCOVERY_RANGE" not in os.environ and "ROS_LOCALHOST_ONLY" not in os.environ:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


def check_ros2() -> None:
    try:
        import rclpy  # noqa: F401  (imported to find out whether it can be)
    except ImportError as err:
        raise Ros2UnavailableError(
            f"cheope ros2 needs the ROS 2 Python packages: pip install 'cheope-controller[ros2]' "
            f"(Python 3.11 on Linux x86_64); {err}"
        ) from None


@dataclass(frozen=True)
class RobotView:
    """What the bridge draws with: the robot's model and drawing, from the controller's configuration."""

    robot: Robot | None
    drawing: RobotDrawing | None


def robot_view(cfg: Config | None) -> RobotView:
    if cfg is None:
        return RobotView(None, None)
    from controller.robots.registry import robot_from_config
    from logs.robot_drawing import drawing_for_config

    try:
        robot: Robot | None = robot_from_config(cfg)
    except (ValueError, KeyError):
        robot = None
    return RobotView(robot, drawing_for_config(cfg))


class RosPublisher:
    """The node, its publishers and the stop service; ``publish`` from one thread (the caller's)."""

    def __init__(self, namespace: str, stop: Callable[[], tuple[bool, str]] | None) -> None:
        import rclpy
        from rclpy.exceptions import NameValidationException
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from controller.ros2 import ros_messages as rm

        keep_dds_local()
        self.rm = rm
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = rclpy.create_node(NODE_NAME, namespace=namespace, context=self.context)
        except NameValidationException as err:
            rclpy.shutdown(context=self.context)
            raise InputError(f"--namespace {namespace!r}: {str(err).splitlines()[0]}") from None
        self.pubs: dict[str, Any] = {}
        self._fixed_markers: list[Any] | None = None
        for name, type_name in TOPICS.items():
            self.pubs[name] = self.node.create_publisher(message_class(type_name), name, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        if stop is not None:
            from std_srvs.srv import Trigger

            def on_stop(_request: Any, response: Any) -> Any:  # the executor's thread
                response.success, response.message = stop()
                return response

            self.node.create_service(Trigger, STOP_SERVICE, on_stop)
        self.spinner = threading.Thread(target=self._spin, name="ros2-executor", daemon=True)
        self.spinner.start()
        self.namespace = self.node.get_namespace()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):  # the context went first: the bridge is closing
            self.executor.spin()

    def subscribers(self) -> int:
        return max(int(p.get_subscription_count()) for p in self.pubs.values())

    def publish(self, s: BridgeSample, drawing: RobotDrawing | None) -> None:
        rm = self.rm
        self.pubs["joint_states"].publish(rm.joint_state(s))
        for name, msg in (
            ("wrench", rm.wrench(s)),
            ("tcp/measured", rm.pose(s.stamp_s, s.tcp_measured_m)),
            ("tcp/reference", rm.pose(s.stamp_s, s.tcp_reference_m)),
        ):
            if msg is not None:
                self.pubs[name].publish(msg)
        if drawing is not None:
            self.pubs["robot_markers"].publish(self._robot_markers(s, drawing))
        self.pubs["diagnostics"].publish(rm.diagnostics(s))

    def _robot_markers(self, s: BridgeSample, drawing: RobotDrawing) -> Any:
        """The whole robot: the fixed parts' markers built once and restamped (they were most of the
        cost of a sample), the moving ones drawn from this sample."""
        from logs.robot_drawing import MeasuredPose

        rm = self.rm
        if self._fixed_markers is None:
            self._fixed_markers = rm.markers(drawing.fixed(), s.stamp_s)
        pose = MeasuredPose(
            t_s=s.t_s, q=s.positions, tcp_m=s.tcp_measured_m, force_n=s.force_n, reference_m=s.tcp_reference_m
        )
        return rm.marker_array(
            s.stamp_s, rm.restamp(self._fixed_markers, s.stamp_s), rm.markers(drawing.moving(pose), s.stamp_s)
        )

    def event(self, stamp_s: float, severity: int, kind: str, text: str, robot_id: str) -> None:
        self.pubs["events"].publish(self.rm.event_log(stamp_s, severity, kind, text, robot_id))

    def close(self) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        self.spinner.join(2.0)


def message_class(type_name: str) -> Any:
    import importlib

    package, _, cls = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), cls)


@contextmanager
def _terminated_by_sigterm() -> Iterator[threading.Event]:
    """An event set by SIGTERM or Ctrl-C: the bridge ends its loop and closes."""
    done = threading.Event()
    old = signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        yield done
    except KeyboardInterrupt:
        done.set()
    finally:
        signal.signal(signal.SIGTERM, old)


# -- live: a controller's Zenoh state -----------------------------------------------------------------


def _controller_config(status_json: str) -> Config | None:
    from controller.config import ConfigError, recorded_config_from_dict

    try:
        return recorded_config_from_dict(json.loads(status_json or "{}"))
    except (ConfigError, ValueError, KeyError):
        return None


def _wait_for_status(ask: Callable[[], Any], notice: Callable[[str], None], retry_s: float = 1.0) -> Any:
    """The controller's status, asked again every ``retry_s`` until it answers (a bridge may start first, or
    a loaded controller answer late); None when SIGTERM or Ctrl-C came first. Each new reason is noticed once."""
    last = ""
    with _terminated_by_sigterm() as done:
        while not done.is_set():
            try:
                return ask()
            except MonitoringConnectionError as err:
                if str(err) != last:
                    notice(f"{err}; asking again (Ctrl-C to stop)")
                    last = str(err)
            done.wait(retry_s)
    return None


def run_live(
    tool: SessionSettings,
    watch: SessionSettings,
    key_prefix: str,
    robot_id: str | None,
    namespace: str,
    timeout_s: float,
    notice: Callable[[str], None],
) -> int:
    """Bridge one controller until SIGTERM or Ctrl-C; returns the number of state samples published."""
    from controller.monitoring.commands import RobotSelector, query_status, send_command
    from controller.monitoring.monitor_view import AliveUpdate, EventUpdate, MonitorClient, StateUpdate

    status = _wait_for_status(
        lambda: query_status(tool, RobotSelector(key_prefix, robot_id), timeout_s), notice
    )
    if status is None:
        return 0
    keys = MonitorKeys.for_robot(key_prefix, status.robot_id)
    view = robot_view(_controller_config(status.config_json))

    def stop() -> tuple[bool, str]:
        try:
            _, reply = send_command(tool, keys, "stop", timeout_s=timeout_s)
        except MonitoringConnectionError as err:
            return False, str(err)
        return reply.accepted, reply.message

    published = 0
    loop_start_s: float | None = None  # the controller's monotonic clock at t_s = 0, from its state samples
    with _terminated_by_sigterm() as done, MonitorClient(watch, keys) as client:
        ros = RosPublisher(namespace, stop)
        try:
            notice(
                f"bridging {keys.prefix}/ to ROS 2 under {ros.namespace} (topics {', '.join(TOPICS)}; "
                f"service {STOP_SERVICE})"
            )
            while not done.is_set():
                u = client.next_update(0.2)
                if isinstance(u, StateUpdate):
                    ros.publish(sample_from_state(u.msg, view.robot), view.drawing)
                    loop_start_s = u.msg.cycle_monotonic_s - u.msg.t_s
                    published += 1
                elif isinstance(u, EventUpdate):  # an event carries its cycle's time since the start
                    at_s = u.received_monotonic_s if loop_start_s is None else loop_start_s + u.msg.t_s
                    ros.event(at_s, u.msg.severity, u.msg.kind, u.msg.message, status.robot_id)
                elif isinstance(u, AliveUpdate) and not u.alive:
                    notice(f"the controller {status.robot_id} is gone; waiting for it to come back")
        finally:
            ros.close()
    return published


# -- replay: a recording ----------------------------------------------------------------------------


def run_replay(
    path: Path, namespace: str, speed: float, wait_subscriber_s: float, notice: Callable[[str], None]
) -> int:
    """Publish the recording's cycles and events; returns the number of samples published."""
    from logs import messages as m
    from logs.reader import iter_decoded, read_info

    info = read_info(path)
    meta = info.metadata
    cfg = _controller_config(meta.get(m.META_CONFIG, {}).get("json", ""))
    if cfg is None:
        raise InputError(
            f"{path}: no readable {m.META_CONFIG} metadata (the robot's configuration); "
            "is it a cheope recording?"
        )
    offset_s = int(meta.get(m.META_SESSION, {}).get("clock_offset_ns", "0")) * 1e-9
    view = robot_view(cfg)
    robot_id = cfg.monitoring.robot_id or path.stem
    sampler = CycleSampler(robot_id, cfg.task.kind, view.robot, cfg.monitoring.publish_rate_hz)
    published = 0
    with _terminated_by_sigterm() as done:
        ros = RosPublisher(namespace, None)
        try:
            deadline = time.monotonic() + wait_subscriber_s
            while ros.subscribers() == 0 and time.monotonic() < deadline and not done.is_set():
                done.wait(0.05)  # nothing signals a new subscriber in rclpy's API
            notice(
                f"replaying {path} to ROS 2 under {ros.namespace} ({info.message_counts[m.TOPIC_CYCLE]} cycles)"
            )
            pace = _Pace(speed)
            for d in iter_decoded(path, (m.TOPIC_CYCLE, m.TOPIC_EVENTS)):
                if done.is_set():
                    break
                stamp_s = d.log_time_ns * 1e-9 - offset_s
                if d.topic == m.TOPIC_EVENTS:
                    ros.event(stamp_s, d.message.severity, d.message.kind, d.message.message, robot_id)
                    continue
                s = sampler.sample(d.message, stamp_s)
                if s is not None:
                    pace.wait(stamp_s, done)
                    ros.publish(s, view.drawing)
                    published += 1
        finally:
            ros.close()
    return published


class _Pace:
    """Waits so that recorded time ``t_s`` is published ``(t_s - first) / speed`` after the first; 0: no wait."""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.start: tuple[float, float] | None = None

    def wait(self, t_s: float, done: threading.Event) -> None:
        if self.speed <= 0.0 or not math.isfinite(self.speed):
            return
        if self.start is None:
            self.start = (t_s, time.monotonic())
            return
        due = self.start[1] + (t_s - self.start[0]) / self.speed
        done.wait(max(0.0, due - time.monotonic()))
