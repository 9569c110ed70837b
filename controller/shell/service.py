"""The controller service: everything between a Config and a finished run.

Order matters and is the safety story of the start: validate configuration, compute the
bus load and refuse an over-budget configuration, check the whole task against workspace
and singularity margins, and only then open the bus, configure the devices and start the
loop. Nothing moves before every check has passed.
"""

from __future__ import annotations

import contextlib
import logging
import math
import resource
import threading
import time
from dataclasses import dataclass

import numpy as np

from controller.config import Config, ConfigError
from controller.core.control_law import ControlLaw, LawConfig, SafetyConfig
from controller.core.cycle_data import Reaction
from controller.core.setpoint_smoothing import AxisLimits, RuckigSmoother
from controller.monitoring.publisher import monitoring_context
from controller.robots.cheope import CheopeRobot
from controller.robots.registry import actuator_units, robot_from_config
from controller.shell.loop import CycleLoop, CycleObserver
from controller.shell.realtime import (
    RealtimeOptions,
    apply_realtime,
    check_realtime,
    freeze_garbage_collector,
    granted_realtime,
    set_gil_switch_interval,
    unfreeze_garbage_collector,
)
from controller.shell.run_summary import RunRecorder, summarize
from controller.tasks.circle_path import CirclePath
from controller.tasks.contour_tracking import ContourParams, ContourTrackingTask
from controller.tasks.path_task import PathTask
from controller.tasks.task import Task
from drivers.bus import BusSpec, open_bus
from drivers.bus_load import BusLoad, check_bus_load, compute_bus_load, cyclic_frames
from drivers.cyclic_exchange import CyclicExchange, FrameSink
from drivers.node_setup import NodeSetupPlan, configure_nodes
from drivers.pacing import DeadlineSleeper
from drivers.pdo_codec import PositionScale

log = logging.getLogger(__name__)


def planned_bus_load(cfg: Config) -> BusLoad:
    frames = cyclic_frames(cfg.loop.rate_hz, len(cfg.actuators.node_ids), cfg.sensor.enabled,
                           1.0 / cfg.loop.heartbeat_period_s)
    return compute_bus_load(frames, cfg.bus.bitrate_bit_s, fd=cfg.bus.fd,
                            data_bit_s=cfg.bus.data_bitrate_bit_s if cfg.bus.fd else None)


def build_robot(cfg: Config) -> CheopeRobot:  # or UruRobot, NspuRobot (robot.kind)
    try:
        return robot_from_config(cfg)
    except ValueError as err:
        raise ConfigError(f"[robot.{cfg.robot.kind}] geometry is inconsistent: {err}") from err


def build_task(cfg: Config, robot: CheopeRobot) -> Task:
    if cfg.task.kind == "contour":
        return build_contour_task(cfg, robot)
    if cfg.robot.kind == "nspu":  # the planned non-holonomic motion (controller/tasks/planned_legs.py)
        from controller.tasks.planned_legs import build_planned_legs_task

        return build_planned_legs_task(cfg, robot)
    p = cfg.task.path
    try:
        path = CirclePath(center_m=p.center_m, radius_m=p.radius_m, speed_m_s=p.speed_m_s, laps=p.laps,
                          ramp_s=p.ramp_s)
    except ValueError as err:
        raise ConfigError(f"[task.path]: {err}") from err
    if tuple(p.normal[:2]) != (0.0, 0.0):  # a circle in a tilted plane
        from controller.robots.uru_robot import TiltedCirclePath

        path = TiltedCirclePath(path, p.normal)
    robot.check_path(path.points(p.check_samples))  # WorkspaceError names the sample
    return PathTask(robot, path, settle_tolerance=cfg.loop.settle_tolerance_m)


def build_contour_task(cfg: Config, robot: CheopeRobot) -> ContourTrackingTask:
    c = cfg.task.contour
    params = ContourParams(
        expected_centre_m=c.expected_centre_m, height_m=c.height_m, expected_radius_m=c.expected_radius_m,
        approach_direction_rad=math.radians(c.approach_direction_deg), approach_clearance_m=c.approach_clearance_m,
        approach_speed_m_s=c.approach_speed_m_s, max_approach_distance_m=c.max_approach_distance_m,
        contact_force_n=c.contact_force_n, force_setpoint_n=c.force_setpoint_n, lap_speeds_m_s=c.lap_speeds_m_s,
        tangential_acceleration_m_s2=c.tangential_acceleration_m_s2, force_kp_m_s_per_n=c.force_kp_m_s_per_n,
        force_ki_m_s2_per_n=c.force_ki_m_s2_per_n, max_normal_speed_m_s=c.max_normal_speed_m_s,
        force_filter_hz=c.force_filter_hz, normal_min_force_n=c.normal_min_force_n, max_force_n=c.max_force_n,
        contact_lost_force_n=c.contact_lost_force_n, contact_lost_cycles=c.contact_lost_cycles,
        reapproach_on_contact_loss=c.on_contact_loss == "reapproach", retract_distance_m=c.retract_distance_m,
        retract_speed_m_s=c.retract_speed_m_s, tare_s=c.tare_s, settle_tolerance_m=cfg.loop.settle_tolerance_m,
        friction_estimate=c.friction_estimate, direction=c.direction,
        normal_tracker_hz=c.normal_tracker_hz,
    )
    # The whole neighbourhood the task may visit: the expected contour, widened by the approach.
    ring = []
    for r in (c.expected_radius_m - c.max_approach_distance_m, c.expected_radius_m + c.approach_clearance_m):
        for th in np.linspace(0.0, 2.0 * np.pi, 73):
            ring.append((c.expected_centre_m[0] + r * np.cos(th), c.expected_centre_m[1] + r * np.sin(th), c.height_m))
    robot.check_path(np.array(ring))
    return ContourTrackingTask(robot, params)


def safety_config(cfg: Config) -> SafetyConfig:
    s = cfg.safety
    return SafetyConfig(
        max_contact_force_n=s.max_contact_force_n, sensor_stale_cycles=s.sensor_stale_cycles,
        on_sensor_stale=Reaction(s.on_sensor_stale), on_sensor_saturated=Reaction(s.on_sensor_saturated),
        on_heartbeat_lost=Reaction(s.on_heartbeat_lost), on_error_frames=Reaction(s.on_error_frames),
        max_consecutive_late_cycles=s.max_consecutive_late_cycles, on_late_cycles=Reaction(s.on_late_cycles))


def build_law(cfg: Config, robot: CheopeRobot | None = None) -> ControlLaw:
    robot = robot or build_robot(cfg)
    a = actuator_units(cfg)  # m or rad
    n = robot.n_actuators
    limits = AxisLimits((a.max_velocity,) * n, (a.max_acceleration,) * n, (a.max_jerk,) * n)
    law_cfg = LawConfig(period_s=cfg.period_s, enable_timeout_s=cfg.loop.enable_timeout_s,
                        hold_before_task_s=cfg.loop.hold_before_task_s,
                        max_missing_cycles=cfg.loop.max_missing_cycles,
                        settle_tolerance=cfg.loop.settle_tolerance_m, safety=safety_config(cfg))
    return ControlLaw(robot, build_task(cfg, robot), RuckigSmoother(limits, cfg.period_s), law_cfg)


@dataclass(frozen=True)
class PreparedRun:
    """Everything checked before anything is opened or moved."""

    law: ControlLaw
    bus_load: BusLoad


def prepare(cfg: Config) -> PreparedRun:
    load = planned_bus_load(cfg)
    check_bus_load(load, cfg.bus.max_load_percent)
    return PreparedRun(law=build_law(cfg), bus_load=load)


def node_setup_plan(cfg: Config) -> NodeSetupPlan:
    return NodeSetupPlan(
        drive_ids=tuple(cfg.actuators.node_ids),
        sensor_id=cfg.sensor.node_id if cfg.sensor.enabled else None,
        vendor_id=cfg.actuators.vendor_id, drive_product_code=cfg.actuators.product_code,
        sensor_product_code=cfg.sensor.product_code, controller_id=cfg.loop.controller_node_id,
        heartbeat_period_s=cfg.loop.heartbeat_period_s, heartbeat_consumer_s=cfg.loop.heartbeat_consumer_s,
        cycle_period_s=cfg.period_s,
        sdo_timeout_s=cfg.loop.sdo_timeout_s, answer_timeout_s=max(5.0, 3.0 * cfg.loop.sdo_timeout_s),
    )


def run_controller(cfg: Config, spec: BusSpec, max_duration_s: float = 600.0,
                   stop_event: threading.Event | None = None, observers: tuple[CycleObserver, ...] = (),
                   frame_sink: FrameSink | None = None, realtime: RealtimeOptions | None = None
                   ) -> dict[str, object]:
    """Run the configured task on the bus; returns the summary (see controller/shell/run_summary.py).

    ``realtime`` (controller/shell/realtime.py) is checked before anything opens, and applied to
    this thread just before the loop starts, so helper threads started earlier keep SCHED_OTHER.
    """
    prepared = prepare(cfg)
    realtime = realtime or RealtimeOptions()
    check_realtime(realtime)  # RealtimeError names the option and how to get the permission
    set_gil_switch_interval(cfg.loop.gil_switch_interval_us * 1e-6)
    recorder = RunRecorder()
    report = getattr(prepared.law.task, "execution_report", None)  # nSPU: reached pose vs goal
    if report is not None:
        observers = (*observers, report)
    session = _session_recorder(cfg, prepared.law, spec)  # the MCAP recording (logs/recorder.py)
    if session is not None:
        observers = (*observers, session)
        frame_sink = session.on_frame if frame_sink is None else _both_sinks(frame_sink, session.on_frame)
    stop_event = stop_event or threading.Event()  # a remote stop (controller/monitoring) sets it too
    with session or contextlib.nullcontext(), monitoring_context(
            cfg, stop_event, prepared.law.task) as publisher, open_bus(spec) as bus:
        setup = configure_nodes(bus, node_setup_plan(cfg))
        exchange = CyclicExchange(
            bus, tuple(cfg.actuators.node_ids), PositionScale(actuator_units(cfg).counts_per_unit),
            cfg.sensor.node_id if cfg.sensor.enabled else None, cfg.loop.controller_node_id,
            heartbeat_every=max(1, round(cfg.loop.heartbeat_period_s * cfg.loop.rate_hz)), fd=spec.fd,
            frame_sink=frame_sink, heartbeat_timeout_s=cfg.loop.heartbeat_consumer_s,
        )
        if publisher is not None:
            publisher.exchange_counters = exchange.counters
        loop = CycleLoop(prepared.law, exchange, cfg.period_s, cfg.loop.collect_fraction,
                         DeadlineSleeper(cfg.loop.spin_us * 1e-6), time.monotonic,
                         late_tolerance_s=cfg.safety.late_tolerance_fraction * cfg.period_s,
                         observers=(recorder, *observers, *((publisher,) if publisher is not None else ())),
                         stop_event=stop_event, commands=publisher.commands if publisher is not None else None)
        restore = apply_realtime(realtime)
        granted = granted_realtime()
        try:
            if cfg.loop.freeze_gc:
                freeze_garbage_collector()
            faults_before = resource.getrusage(resource.RUSAGE_SELF).ru_majflt
            final, stats = loop.run(prepared.law.initial_state(), max_duration_s,
                                    exit_on_fault=not cfg.loop.stay_in_fault)
            # a page the kernel dropped (memory pressure, proactive reclaim) is read back from disk
            # when touched: milliseconds each, inside a cycle (--lock-memory prevents it)
            major_faults = resource.getrusage(resource.RUSAGE_SELF).ru_majflt - faults_before
        finally:
            restore()
            if cfg.loop.freeze_gc:
                unfreeze_garbage_collector()
    return summarize(stats, recorder, final, exchange.counters, prepared.bus_load.percent,
                     extra={"bus": str(spec), "node_setup_s": round(setup.duration_s, 3),
                            "major_page_faults": major_faults,
                            "recording": _recording_summary(session), "realtime": granted,
                            **(report.summary() if report is not None else {})})


def _session_recorder(cfg: Config, law: ControlLaw, spec: BusSpec):  # -> logs.recorder.SessionRecorder | None
    if not cfg.recording.enabled:
        return None
    from logs.recorder import SessionRecorder

    return SessionRecorder.for_config(cfg, phase_name=law.task.phase_name, extra_metadata={"bus": str(spec)})


def _both_sinks(a: FrameSink, b: FrameSink) -> FrameSink:
    def sink(outgoing: bool, monotonic_s: float, msg) -> None:
        a(outgoing, monotonic_s, msg)
        b(outgoing, monotonic_s, msg)
    return sink


def _recording_summary(session) -> dict[str, object] | None:
    if session is None:
        return None
    return {"path": str(session.path), "dropped": session.dropped, "written": session.written,
            "error": session.error}
