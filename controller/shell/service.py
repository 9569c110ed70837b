"""The controller service: everything between a Config and a finished run.

Order matters and is the safety story of the start: validate configuration, compute the
bus load and refuse an over-budget configuration, check the whole task against workspace
and singularity margins, and only then open the bus, configure the devices and start the
loop. Nothing moves before every check has passed.
"""

from __future__ import annotations

import contextlib
import logging
import resource
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import can

from controller.assembly import assemble
from controller.config import Config
from controller.core.control_law import ControlLaw
from controller.monitoring.publisher import monitoring_context
from controller.robots.registry import actuator_units
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
from controller.tasks.registry import RunReport
from drivers.bus import BusSpec, open_bus
from drivers.bus_load import BusLoad, check_bus_load, compute_bus_load, cyclic_frames
from drivers.cyclic_exchange import CyclicExchange, FrameSink
from drivers.node_setup import NodeSetupPlan, configure_nodes
from drivers.pacing import DeadlineSleeper
from drivers.pdo_codec import PositionScale

if TYPE_CHECKING:
    from logs.recorder import SessionRecorder

log = logging.getLogger(__name__)


def planned_bus_load(cfg: Config) -> BusLoad:
    frames = cyclic_frames(cfg.loop.rate_hz, len(cfg.actuators.node_ids), cfg.sensor.enabled,
                           1.0 / cfg.loop.heartbeat_period_s)
    return compute_bus_load(frames, cfg.bus.bitrate_bit_s, fd=cfg.bus.fd,
                            data_bit_s=cfg.bus.data_bitrate_bit_s if cfg.bus.fd else None)


@dataclass(frozen=True)
class PreparedRun:
    """Everything checked before anything is opened or moved."""

    law: ControlLaw
    reports: tuple[RunReport, ...]  # the task's own (the 3-nSPU's reached pose against its goal)
    bus_load: BusLoad


def prepare(cfg: Config) -> PreparedRun:
    load = planned_bus_load(cfg)
    check_bus_load(load, cfg.bus.max_load_percent)
    assembly = assemble(cfg)
    return PreparedRun(law=assembly.law, reports=assembly.reports, bus_load=load)


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
    observers = (*observers, *prepared.reports)
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
                            **{k: v for r in prepared.reports for k, v in r.summary().items()}})


def _session_recorder(cfg: Config, law: ControlLaw, spec: BusSpec) -> SessionRecorder | None:
    if not cfg.recording.enabled:
        return None
    from logs.recorder import SessionRecorder

    return SessionRecorder.for_config(cfg, phase_name=law.task.phase_name, extra_metadata={"bus": str(spec)})


def _both_sinks(a: FrameSink, b: FrameSink) -> FrameSink:
    def sink(outgoing: bool, monotonic_s: float, msg: can.Message) -> None:
        a(outgoing, monotonic_s, msg)
        b(outgoing, monotonic_s, msg)
    return sink


def _recording_summary(session: SessionRecorder | None) -> dict[str, object] | None:
    if session is None:
        return None
    return {"path": str(session.path), "dropped": session.dropped, "written": session.written,
            "error": session.error}
