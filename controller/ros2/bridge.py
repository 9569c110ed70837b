"""``cheope ros2``: a controller's Zenoh state, or a recording, published as ROS 2 topics (the ``ros2`` extra).

Its own process, never the loop's: it subscribes to the state and events like ``cheope monitor``
(controller/monitoring/monitor_view.py) and publishes each state sample, as it arrives. Under the
namespace (default ``/cheope``):

| topic | type | what |
| --- | --- | --- |
| ``joint_states`` | sensor_msgs/JointState | measured actuator positions and velocities, named as the robot's model names its actuated joints |
| ``wrench`` | geometry_msgs/WrenchStamped | the force/torque sensor (torque only from a recording, else NaN) |
| ``tcp/measured`` | geometry_msgs/PoseStamped | the measured TCP |
| ``tcp/reference`` | geometry_msgs/PoseStamped | the TCP the actuator targets command (direct kinematics) |
| ``robot_markers`` | visualization_msgs/MarkerArray | the robot, drawn as ``/scene`` is (logs/robot_drawing.py) |
| ``robot_description`` | std_msgs/String | the robot's URDF (robot_description.py), transient local: a late subscriber gets it |

and, as ROS tools expect them, ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, about 1 Hz),
``/rosout`` (rcl_interfaces/Log: the controller's events, stamped with their own time), ``/tf`` and
``/tf_static`` (tf2_msgs/TFMessage: the robot's links, when tf2_msgs is installed: it has no wheel on
the package index, a sourced ROS 2 installation brings it) and, replaying, ``/clock``
(rosgraph_msgs/Clock: the recording's time, for nodes with ``use_sim_time``). Every stamp is ROS
time: the controller's monotonic clock on its wall clock (samples.py).

Services under the namespace, std_srvs/Trigger: ``stop``, ``pause``, ``resume``, ``reset``; the parameter
``force_setpoint_n`` sends ``set_force``. Each goes to the controller's ``command`` queryable, the
gate ``cheope stop`` and ``cheope command`` go through (controller/monitoring/command_gate.py):
stop is always accepted, the others only by a controller started with ``--allow-remote-commands``;
the controller's answer is the service's (``success``, ``message``) or the parameter's. The
node's read-only parameters: ``robot_description`` (the URDF), ``robot_id``, ``robot_kind``.
``--replay FILE`` publishes a recording's cycles the same way, at the recorded monitoring rate
and the recording's pace (``--speed``), with ``/clock`` and no services.

DDS stays on this machine unless the environment says otherwise: ``ROS_AUTOMATIC_DISCOVERY_RANGE``
is set to ``LOCALHOST`` when neither it nor ``ROS_LOCALHOST_ONLY`` is set.
"""

from __future__ import annotations

import contextlib
import faulthandler
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
from controller.monitoring.command_gate import ALWAYS_ACCEPTED, GATED_COMMANDS
from controller.monitoring.zenoh_session import MonitoringConnectionError, MonitorKeys, SessionSettings
from controller.ros2.robot_description import RobotDescription, actuated_joints
from controller.ros2.samples import (
    BridgeSample,
    CycleSampler,
    EveryInterval,
    sample_from_state,
)
from controller.signal_relay import route_signals, stop_signals
from logs.messages import JointVelocities  # the same velocities as the recordings' /joint_states

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
    "robot_description": "std_msgs/msg/String",
}
GLOBAL_TOPICS = {  # absolute names, as every ROS tool expects them
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "/rosout": "rcl_interfaces/msg/Log",
}
TF_TOPICS = {"/tf": "tf2_msgs/msg/TFMessage", "/tf_static": "tf2_msgs/msg/TFMessage"}
CLOCK_TOPIC = "/clock"
# std_srvs/Trigger each: the controller's commands without a value (set_force: the parameter below)
SERVICES = tuple(c for c in (*ALWAYS_ACCEPTED, *GATED_COMMANDS) if c != "set_force")
STOP_SERVICE = "stop"
FORCE_PARAMETER = "force_setpoint_n"
DIAGNOSTICS_INTERVAL_NS = 1_000_000_000  # diagnostic_msgs' convention: about 1 Hz
# the QoS ROS 2's own rosout publisher uses (rcl/logging_rosout.c): reliable, transient local, 1000 deep
ROSOUT_DEPTH = 1000
# rclpy's teardown (executor, node, context) has known deadlocks between a spinning thread and the
# one that destroys (ros2/rclpy issues 255, 944, 1646): a bridge asked to stop ends within this anyway
CLOSE_DEADLINE_S = 5.0
CommandSender = Callable[[str, float], tuple[bool, str]]


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
    kind: str = ""
    strokes: tuple[float, float] = (0.0, 0.0)  # the actuators' range (the URDF joints' limits) [m or rad]


def robot_view(cfg: Config | None) -> RobotView:
    if cfg is None:
        return RobotView(None, None)
    from controller.configured_robot import robot_from_config
    from controller.robot_registry import robot_entry
    from logs.robot_drawing import drawing_for_config

    try:
        robot: Robot | None = robot_from_config(cfg)
    except (ValueError, KeyError):
        robot = None
    strokes = robot_entry(cfg.robot.kind).stroke(cfg.robot.model())
    return RobotView(robot, drawing_for_config(cfg), cfg.robot.kind, strokes)


def tf_message_class() -> Any:
    """tf2_msgs/TFMessage, or None where tf2_msgs is not installed (no wheel on the package index)."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class RosPublisher:
    """The node, its publishers, services and parameters; ``publish`` from one thread (the caller's)."""

    def __init__(
        self,
        namespace: str,
        send: CommandSender | None,
        view: RobotView,
        robot_id: str,
        notice: Callable[[str], None],
        clock_topic: bool = False,
    ) -> None:
        import rclpy
        from rclpy.exceptions import NameValidationException
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from controller.ros2 import ros_messages as rm

        keep_dds_local()
        self.rm = rm
        self.view = view
        self.notice = notice
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = rclpy.create_node(NODE_NAME, namespace=namespace, context=self.context)
        except NameValidationException as err:
            rclpy.shutdown(context=self.context)
            raise InputError(f"--namespace {namespace!r}: {str(err).splitlines()[0]}") from None
        latched = QoSProfile(
            depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
        )
        self.pubs: dict[str, Any] = {}
        for name, type_name in TOPICS.items():
            qos = latched if name == "robot_description" else 10
            self.pubs[name] = self.node.create_publisher(message_class(type_name), name, qos)
        self.pubs["/diagnostics"] = self.node.create_publisher(
            message_class(GLOBAL_TOPICS["/diagnostics"]), "/diagnostics", 10
        )
        self.pubs["/rosout"] = self.node.create_publisher(
            message_class(GLOBAL_TOPICS["/rosout"]),
            "/rosout",
            QoSProfile(
                depth=ROSOUT_DEPTH,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
                reliability=ReliabilityPolicy.RELIABLE,
            ),
        )
        tf_class = tf_message_class()
        if tf_class is not None:
            self.pubs["/tf"] = self.node.create_publisher(tf_class, "/tf", 100)
            self.pubs["/tf_static"] = self.node.create_publisher(tf_class, "/tf_static", latched)
        else:
            notice(
                "/tf and /tf_static not published: tf2_msgs is not installed (no wheel on the package "
                "index; a sourced ROS 2 installation has it)"
            )
        if clock_topic:
            self.pubs[CLOCK_TOPIC] = self.node.create_publisher(
                message_class("rosgraph_msgs/msg/Clock"), CLOCK_TOPIC, 10
            )
        self._tf_class = tf_class
        self.joint_names = tuple(j.name for j in actuated_joints(view.drawing))
        self.description: RobotDescription | None = None
        self._velocities = JointVelocities()
        self._diagnostics = EveryInterval(DIAGNOSTICS_INTERVAL_NS)
        self._fixed_markers: list[Any] | None = None
        self._logger_name = f"{self.node.get_namespace().strip('/').replace('/', '.')}.{NODE_NAME}".lstrip(
            "."
        )
        self._declare_parameters(robot_id, send)
        if send is not None:
            self._create_services(send)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spinner = threading.Thread(target=self._spin, name="ros2-executor", daemon=True)
        self.spinner.start()
        self.namespace = self.node.get_namespace()

    def _declare_parameters(self, robot_id: str, send: CommandSender | None) -> None:
        from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult

        read_only = ParameterDescriptor(read_only=True)
        self.node.declare_parameter("robot_id", robot_id, read_only)
        self.node.declare_parameter("robot_kind", self.view.kind, read_only)
        self.node.declare_parameter(
            "robot_description",
            "",
            ParameterDescriptor(description="the robot's URDF, once the first sample came"),
        )
        if send is None:
            return
        self.node.declare_parameter(
            FORCE_PARAMETER,
            math.nan,
            ParameterDescriptor(
                description="setting it sends set_force [N] to the controller (refused unless it runs with --allow-remote-commands)"
            ),
        )

        def on_set(params: list[Any]) -> Any:  # the executor's thread
            for p in params:
                if p.name == FORCE_PARAMETER:
                    accepted, message = send("set_force", float(p.value))
                    return SetParametersResult(successful=accepted, reason=message)
            return SetParametersResult(successful=True)

        self.node.add_on_set_parameters_callback(on_set)

    def _create_services(self, send: CommandSender) -> None:
        from std_srvs.srv import Trigger

        for name in SERVICES:

            def on_call(_request: Any, response: Any, command: str = name) -> Any:  # the executor's thread
                response.success, response.message = send(command, 0.0)
                return response

            self.node.create_service(Trigger, name, on_call)

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):  # the context went first: the bridge is closing
            self.executor.spin()

    def subscribers(self) -> int:
        return max(int(p.get_subscription_count()) for p in self.pubs.values())

    def publish(self, s: BridgeSample) -> None:
        from logs.robot_drawing import MeasuredPose

        rm = self.rm
        drawing = self.view.drawing
        pose = MeasuredPose(
            t_s=s.t_s, q=s.positions, tcp_m=s.tcp_measured_m, force_n=s.force_n, reference_m=s.tcp_reference_m
        )
        moving = drawing.moving(pose) if drawing is not None else []
        names = (
            self.joint_names
            if len(self.joint_names) == len(s.positions)
            else tuple(f"actuator_{j + 1}" for j in range(len(s.positions)))
        )
        self.pubs["joint_states"].publish(
            rm.joint_state(s, names, self._velocities.update(s.stamp_ns, s.positions))
        )
        for name, msg in (
            ("wrench", rm.wrench(s)),
            ("tcp/measured", rm.pose(s.stamp_ns, s.tcp_measured_m)),
            ("tcp/reference", rm.pose(s.stamp_ns, s.tcp_reference_m)),
        ):
            if msg is not None:
                self.pubs[name].publish(msg)
        if drawing is not None:
            self.pubs["robot_markers"].publish(self._robot_markers(s, drawing, moving))
            self._publish_links(s, drawing, pose, moving)
        if self._diagnostics.due(s.stamp_ns):
            self.pubs["/diagnostics"].publish(rm.diagnostics(s, self.node.get_fully_qualified_name()))
        if CLOCK_TOPIC in self.pubs:
            self.pubs[CLOCK_TOPIC].publish(rm.clock(s.stamp_ns))

    def _publish_links(self, s: BridgeSample, drawing: RobotDrawing, pose: Any, moving: list[Any]) -> None:
        """The URDF once the first sample with a TCP came (the passive parts are drawn from it), then
        the links' transforms of every sample."""
        from rclpy.parameter import Parameter

        if self.description is None:
            if s.tcp_measured_m is None:
                return
            self.description = RobotDescription(drawing, self.view.kind, self.view.strokes, pose)
            self.pubs["robot_description"].publish(self.rm.robot_description(self.description.urdf))
            self.node.set_parameters(
                [Parameter("robot_description", Parameter.Type.STRING, self.description.urdf)]
            )
            if self._tf_class is not None:
                static = self.rm.transforms(s.stamp_ns, self.description.static_transforms())
                self.pubs["/tf_static"].publish(self._tf_class(transforms=static))
        if self._tf_class is not None:
            tfs = self.rm.transforms(s.stamp_ns, self.description.transforms(pose, moving))
            self.pubs["/tf"].publish(self._tf_class(transforms=tfs))

    def _robot_markers(self, s: BridgeSample, drawing: RobotDrawing, moving: list[Any]) -> Any:
        """The whole robot: the fixed parts' markers built once and restamped (they were most of the
        cost of a sample), the moving ones drawn from this sample."""
        rm = self.rm
        if self._fixed_markers is None:
            self._fixed_markers = rm.markers(drawing.fixed(), s.stamp_ns)
        return rm.marker_array(
            s.stamp_ns, rm.restamp(self._fixed_markers, s.stamp_ns), rm.markers(moving, s.stamp_ns)
        )

    def event(self, stamp_ns: int, severity: int, kind: str, text: str) -> None:
        self.pubs["/rosout"].publish(self.rm.event_log(stamp_ns, severity, kind, text, self._logger_name))

    def close(self) -> None:
        import rclpy

        with ends_within(CLOSE_DEADLINE_S):
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
            rclpy.shutdown(context=self.context)
            self.spinner.join(2.0)


@contextmanager
def ends_within(seconds: float) -> Iterator[None]:
    """End the process if the block has not returned after ``seconds``: every thread's stack on
    stderr (``Timeout (0:00:05)!`` first), then exit status 1. faulthandler's watchdog is a C thread
    that needs no interpreter lock, so it ends the process even when the block holds the lock in a
    library's C code."""
    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def message_class(type_name: str) -> Any:
    import importlib

    package, _, cls = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), cls)


@contextmanager
def _ended_by_stop_signals() -> Iterator[threading.Event]:
    """An event set by SIGTERM, Ctrl-C or a hang-up (``stop_signals``): the bridge ends its loop and
    closes. Set on the relay thread of controller/signal_relay.py, not in a handler: a handler that
    set it itself ran, in a CI run, inside the replay's ``done.wait`` while that held the event's
    lock, and the bridge waited for ever on SIGTERM (tests/unit/test_ros2_stopping.py)."""
    signals = stop_signals()
    old = {sig: signal.getsignal(sig) for sig in signals}
    done = threading.Event()
    route_signals(signals, lambda _: done.set())
    try:
        yield done
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


# -- live: a controller's Zenoh state -----------------------------------------------------------------


def _controller_config(status_json: str) -> Config | None:
    from controller.config import ConfigError, config_table_from_json, recorded_config_from_dict

    try:
        return recorded_config_from_dict(config_table_from_json(status_json or "{}"))
    except (ConfigError, KeyError):
        return None


def _wait_for_status(ask: Callable[[], Any], notice: Callable[[str], None], retry_s: float = 1.0) -> Any:
    """The controller's status, asked again every ``retry_s`` until it answers (a bridge may start first, or
    a loaded controller answer late); None when SIGTERM or Ctrl-C came first. Each new reason is noticed once."""
    last = ""
    with _ended_by_stop_signals() as done:
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
    from drivers.pacing import wall_clock_offset_ns

    status = _wait_for_status(
        lambda: query_status(tool, RobotSelector(key_prefix, robot_id), timeout_s), notice
    )
    if status is None:
        return 0
    keys = MonitorKeys.for_robot(key_prefix, status.robot_id)
    view = robot_view(_controller_config(status.config_json))
    offset_ns = status.clock_offset_ns
    if not offset_ns:  # a controller older than the field: this machine's offset, right if it is its machine
        offset_ns = wall_clock_offset_ns()
        notice("the controller does not say its clock offset: stamps use this machine's wall clock")

    def send(command: str, value: float) -> tuple[bool, str]:
        try:
            _, reply = send_command(tool, keys, command, value=value, timeout_s=timeout_s)
        except MonitoringConnectionError as err:
            return False, str(err)
        return reply.accepted, reply.message

    published = 0
    loop_start_ns: int | None = None  # ROS time at the controller's t_s = 0, from its state samples
    with _ended_by_stop_signals() as done, MonitorClient(watch, keys) as client:
        ros = RosPublisher(namespace, send, view, status.robot_id, notice)
        try:
            notice(
                f"bridging {keys.prefix}/ to ROS 2 under {ros.namespace} (topics {', '.join(TOPICS)}, "
                f"{', '.join(GLOBAL_TOPICS)}; services {', '.join(SERVICES)}; parameter {FORCE_PARAMETER})"
            )
            while not done.is_set():
                u = client.next_update(0.2)
                if isinstance(u, StateUpdate):
                    s = sample_from_state(u.msg, view.robot, offset_ns)
                    ros.publish(s)
                    loop_start_ns = s.stamp_ns - round(u.msg.t_s * 1e9)
                    published += 1
                elif isinstance(u, EventUpdate):  # an event carries its cycle's time since the start
                    at_ns = (
                        round(u.received_monotonic_s * 1e9) + wall_clock_offset_ns()
                        if loop_start_ns is None
                        else loop_start_ns + round(u.msg.t_s * 1e9)
                    )
                    ros.event(at_ns, u.msg.severity, u.msg.kind, u.msg.message)
                elif isinstance(u, AliveUpdate) and not u.alive:
                    notice(f"the controller {status.robot_id} is gone; waiting for it to come back")
        finally:
            ros.close()
    return published


# -- replay: a recording ----------------------------------------------------------------------------


def run_replay(
    path: Path, namespace: str, speed: float, wait_subscriber_s: float, notice: Callable[[str], None]
) -> int:
    """Publish the recording's cycles and events, and ``/clock``; returns the number of samples published."""
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
    view = robot_view(cfg)
    robot_id = cfg.monitoring.robot_id or path.stem
    sampler = CycleSampler(robot_id, cfg.task.kind, view.robot, cfg.monitoring.publish_rate_hz)
    published = 0
    with _ended_by_stop_signals() as done:
        ros = RosPublisher(namespace, None, view, robot_id, notice, clock_topic=True)
        try:
            deadline = time.monotonic() + wait_subscriber_s
            while ros.subscribers() == 0 and time.monotonic() < deadline and not done.is_set():
                done.wait(0.05)  # nothing signals a new subscriber in rclpy's API
            notice(
                f"replaying {path} to ROS 2 under {ros.namespace} ({info.message_counts[m.TOPIC_CYCLE]} cycles; "
                f"{CLOCK_TOPIC} for use_sim_time)"
            )
            pace = _Pace(speed)
            for d in iter_decoded(path, (m.TOPIC_CYCLE, m.TOPIC_EVENTS)):
                if done.is_set():
                    break
                if d.topic == m.TOPIC_EVENTS:  # the log time: the controller's clock on its wall clock
                    ros.event(d.log_time_ns, d.message.severity, d.message.kind, d.message.message)
                    continue
                s = sampler.sample(d.message, d.log_time_ns)
                if s is not None:
                    pace.wait(d.log_time_ns * 1e-9, done)
                    ros.publish(s)
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
