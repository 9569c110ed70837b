"""The controller service: everything between a Config and a finished run.

Order matters and is the safety story of the start: validate configuration, compute the
bus load and refuse an over-budget configuration, check the whole task against workspace
and singularity margins, and only then open the bus, configure the devices and start the
loop. Nothing moves before every check has passed.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import resource
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import can

from controller.assembly import assemble, planned_bus_load, position_plausibility
from controller.compiled_law import LAW_BUILD
from controller.config import Config, config_to_dict
from controller.configured_robot import robot_from_config
from controller.core.control_law import ControlLaw
from controller.core.ports import CycleObserver, OffLoopWorker, PlansOffLoop
from controller.monitoring.publisher import PublisherSettings, monitoring_context
from controller.monitoring.robot_identity import resolve_robot_id
from controller.monitoring.zenoh_session import MonitorKeys, SessionSettings, split_endpoints
from controller.node_plan import node_setup_plan
from controller.realtime import (
    RealtimeOptions,
    apply_realtime,
    check_realtime,
    fifo_priority,
    freeze_garbage_collector,
    granted_realtime,
    set_gil_switch_interval,
    unfreeze_garbage_collector,
)
from controller.robot_registry import ActuatorUnits
from controller.shell.cpu_shield import raise_shield
from controller.shell.cpu_steal import steal_s_since, steal_ticks
from controller.shell.helper_threads import HelperThreadWatch, writer_priority
from controller.shell.idle_poll import idle_polling
from controller.shell.log_handoff import log_records_off_the_loop
from controller.shell.loop import CycleLoop
from controller.shell.run_summary import RunRecorder, summarize
from controller.shell.stuck_loop import StuckLoopGuard
from controller.shell.systemd_notify import notify
from controller.shell.thread_usage import thread_usage_readers
from controller.tasks.registry import RunReport
from drivers.bus import BusSpec, open_bus
from drivers.bus_load import BusLoad, check_bus_load
from drivers.bus_presence import check_no_other_master
from drivers.cyclic_exchange import CyclicExchange, FrameSink, targets_sync_gap_s
from drivers.frame_tap import FrameTap
from drivers.kernel_sync import KernelSyncExchange, check_kernel_sync
from drivers.local_multicast import LocalUdpMulticastBus
from drivers.node_setup import NodeSetupPlan, check_device_descriptions, configure_nodes
from drivers.pacing import DeadlineSleeper
from drivers.pdo_codec import PositionScale

if TYPE_CHECKING:
    from logs.recorder import SessionRecorder

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PreparedRun:
    """Everything checked before anything is opened or moved."""

    law: ControlLaw
    reports: tuple[RunReport, ...]  # the task's own (the 3-nSPU's reached pose against its goal)
    bus_load: BusLoad
    setup_plan: NodeSetupPlan
    publisher: PublisherSettings | None  # None: monitoring off
    units: ActuatorUnits  # the actuators' unit and limits (m or rad)


def prepare(cfg: Config, spec: BusSpec, enforce_load_limit: bool = True) -> PreparedRun:
    """Every check of a start that needs no bus: what ``cheope run`` refuses before it opens
    anything, and what ``cheope bus-load`` checks as well (it reports the load itself, so it
    passes ``enforce_load_limit=False``).

    The bus load against its limit, the kernel's SYNC on a bus that has it, the EDS files and
    the PDO mappings built from them, the monitoring settings, the robot and the whole task
    against the workspace and singularity margins.
    """
    if LAW_BUILD.stale:  # an edited source runs interpreted, at its cost per cycle: say so once
        log.warning("the law runs interpreted: %s", LAW_BUILD.why)
    robot_from_config(cfg)  # one node id per actuator before anything counts frames by them
    load = planned_bus_load(cfg)
    if enforce_load_limit:
        check_bus_load(load, cfg.bus.max_load_percent)
    if cfg.bus.sync_producer == "kernel":
        check_kernel_sync(spec.interface)
    setup_plan = node_setup_plan(cfg)
    check_device_descriptions(setup_plan)
    publisher = publisher_settings(cfg) if cfg.monitoring.enabled else None  # prefix, robot id, endpoints
    assembly = assemble(cfg)
    return PreparedRun(
        law=assembly.law,
        reports=assembly.reports,
        bus_load=load,
        setup_plan=setup_plan,
        publisher=publisher,
        units=assembly.units,
    )


def publisher_settings(cfg: Config) -> PublisherSettings:
    """Validated settings from ``[monitoring]`` (ConfigError names a bad key)."""
    m = cfg.monitoring
    robot_id = resolve_robot_id(m.robot_id)
    keys = MonitorKeys.for_robot(m.key_prefix, robot_id)
    session = SessionSettings(
        mode=m.mode,
        listen=split_endpoints(m.listen, "monitoring.listen"),
        connect=split_endpoints(m.connect, "monitoring.connect"),
        config_file=m.config_file,
        on_listen_busy=m.on_listen_busy,
    )
    config = config_to_dict(cfg)
    config["monitoring"]["robot_id"] = robot_id  # the id in use, also when drawn
    return PublisherSettings(
        session=session,
        keys=keys,
        robot_id=robot_id,
        key_prefix=m.key_prefix,
        robot_id_is_default=not m.robot_id,
        period_s=cfg.period_s,
        decimation=max(1, round(cfg.loop.rate_hz / m.publish_rate_hz)),
        allow_remote_commands=m.allow_remote_commands,
        config_json=json.dumps(config),
    )


# The cyclic exchange sleeps through its answer window and reads the answers at its end at this
# period and longer (drivers/cyclic_exchange.py ``collect``): one wake-up of the loop a window, none
# by a frame. It saves the loop 1-2 % of a core at 400 Hz (`cheope bench`, 3 runs each side: path
# 14.0-15.1 % against 16.6-16.9 %), but the answers are then decoded after the window, before the
# step: at 1 kHz that no longer fitted the period (late cycles per 10 000: 54-86 against 10-18),
# and the exchange reads each answer as it comes there, inside the window. Between the two rates
# unmeasured: the shorter periods keep the way measured at 1 kHz.
SLEEP_THROUGH_WINDOW_MIN_PERIOD_S = 2.5e-3


def sleeps_through_window(period_s: float) -> bool:
    """Whether the cyclic exchange sleeps through its answer window at this loop period."""
    return period_s >= SLEEP_THROUGH_WINDOW_MIN_PERIOD_S


def run_controller(
    cfg: Config,
    spec: BusSpec,
    max_duration_s: float | None = None,
    stop_event: threading.Event | None = None,
    observers: tuple[CycleObserver, ...] = (),
    frame_sink: FrameSink | None = None,
    realtime: RealtimeOptions | None = None,
    quick_stop_event: threading.Event | None = None,
    on_loop_built: Callable[[CycleLoop], None] | None = None,
) -> dict[str, object]:
    """Run the configured task on the bus until it ends or is stopped; returns the summary (see
    controller/shell/run_summary.py).

    Every stop goes through STOPPING (brake, disable the drives, DONE): ``stop_event`` (signals,
    ``cheope stop``), the end of ``max_duration_s`` (None: no limit), and a lost recording under
    ``recording.on_failure = "stop"``. ``quick_stop_event`` quick-stops the drives instead.
    ``realtime`` (controller/realtime.py) is checked before anything opens, and applied to
    this thread just before the loop starts, so helper threads started earlier keep SCHED_OTHER.
    ``on_loop_built`` is called with the loop once it is built, before it runs: a bench's
    instruments (controller/tools/bench/loop_cpu_parts.py); the service passes none.
    """
    prepared = prepare(cfg, spec)  # before anything opens
    realtime = realtime or RealtimeOptions()
    check_realtime(realtime)  # RealtimeError names the option and how to get the permission
    set_gil_switch_interval(cfg.loop.gil_switch_interval_us * 1e-6)
    recorder = RunRecorder()
    observers = (*observers, *prepared.reports)
    stop_event = stop_event or threading.Event()  # a remote stop (controller/monitoring) sets it too
    session = _session_recorder(cfg, prepared.law, spec, stop_event)  # the MCAP recording (logs/recorder.py)
    if session is not None:
        observers = (*observers, session)
        frame_sink = session.on_frame if frame_sink is None else _both_sinks(frame_sink, session.on_frame)
    worker = _off_loop_worker(prepared.law.task)  # a task's work off the loop (the 3-nSPU's plans)
    if worker is not None:
        observers = (*observers, worker)
    with (
        session or contextlib.nullcontext(),
        worker or contextlib.nullcontext(),
        monitoring_context(prepared.publisher, stop_event, prepared.law.task) as publisher,
        FrameTap(open_bus(spec), frame_sink) as bus,
        log_records_off_the_loop(),  # a blocked stderr cannot stall the loop (log_handoff.py)
    ):
        # every frame of the session through one tap: set-up included, own echoes dropped
        # one master per bus: nothing is sent while another is heard (drivers/bus_presence.py)
        check_no_other_master(bus, spec.place, cfg.loop.controller_node_id, cfg.bus.presence_listen_s)
        setup = configure_nodes(bus, prepared.setup_plan, stop_event)  # a stop ends a long wait of it
        step_limit, jump_margin = position_plausibility(
            prepared.units, prepared.law.config.safety, cfg.period_s
        )
        exchange = CyclicExchange(
            bus,
            tuple(cfg.actuators.node_ids),
            PositionScale(prepared.units.counts_per_unit),
            cfg.sensor.node_id if cfg.sensor.enabled else None,
            cfg.loop.controller_node_id,
            heartbeat_every=max(1, round(cfg.loop.heartbeat_period_s * cfg.loop.rate_hz)),
            fd=spec.fd,
            heartbeat_timeout_s=cfg.loop.heartbeat_consumer_s,
            drive_codecs=setup.drive_codecs,
            sensor_codecs=setup.sensor_codecs,
            send_sync=cfg.bus.sync_producer == "loop",
            flood_frames_per_cycle=cfg.safety.max_foreign_frames_per_cycle,
            tracker_id=cfg.tracker.node_id if cfg.tracker.enabled else None,
            sync_period_s=cfg.period_s,
            max_position_step=step_limit,
            max_position_jump=jump_margin,
            guarded=prepared.setup_plan.guarded(),
            targets_sync_gap_s=targets_sync_gap_s(cfg.period_s, cfg.drive_extrapolation_periods),
            target_lead_period_s=cfg.period_s,
            drive_extrapolation_periods=cfg.drive_extrapolation_periods,
            window_sleep=DeadlineSleeper(0.0).sleep_until if sleeps_through_window(cfg.period_s) else None,
        )
        kernel_sync = (
            KernelSyncExchange(exchange, cfg.period_s, cfg.bus.sync_lead_fraction * cfg.period_s)
            if cfg.bus.sync_producer == "kernel"
            else None
        )
        if publisher is not None:
            publisher.exchange_counters = exchange.counters
        sleeper = DeadlineSleeper(cfg.loop.spin_us * 1e-6)
        helpers = HelperThreadWatch.for_period(cfg.period_s)  # real-time below the loop (helper_threads.py)
        loop = CycleLoop(
            prepared.law,
            kernel_sync or exchange,
            cfg.period_s,
            cfg.loop.collect_fraction,
            sleeper,
            time.monotonic,
            late_tolerance_s=cfg.safety.late_tolerance_fraction * cfg.period_s,
            observers=(recorder, *observers, *((publisher,) if publisher is not None else ()), helpers),
            stop_event=stop_event,
            commands=publisher.commands if publisher is not None else None,
            quick_stop_event=quick_stop_event,
            stop_timeout_s=cfg.loop.stop_timeout_s,
            plans_ready=worker.ready if worker is not None else None,
            observers_in_window=True,  # over a bus: in the next cycle's answer window (loop.py, step 5)
            thread_usage=thread_usage_readers(),
        )
        if on_loop_built is not None:
            on_loop_built(loop)
        if cfg.loop.freeze_gc:  # start-up work: before the loop takes its real-time priority
            freeze_garbage_collector()

        def restore() -> None:
            return None

        helpers_at_start = 0
        shield_summary: dict[str, object] = {}

        idle_poll_summary: dict[str, object] = {}
        # every CPU this process may use: the loop's, and in the demo the simulated drives'
        polled_cpus = tuple(sorted(os.sched_getaffinity(0))) if realtime.idle_poll else ()
        polling = idle_polling(polled_cpus, idle_poll_summary, required=realtime.required)

        # the shield's guardian is started before the loop thread takes its priority and CPU,
        # which a child process would inherit
        with raise_shield(realtime, shield_summary), polling:
            try:
                restore = apply_realtime(realtime)
                granted = granted_realtime()
                helpers_at_start = helpers.start()
                loop_priority = fifo_priority()
                if session is not None and loop_priority is not None:  # why: helper_threads.py
                    session.raise_writer(writer_priority(loop_priority))
                faults_before = resource.getrusage(resource.RUSAGE_SELF).ru_majflt
                steal_before = steal_ticks()
                notify("READY=1")  # systemd Type=notify: the devices are configured, the loop starts
                with StuckLoopGuard(
                    lambda: loop.cycles_done,
                    loop.stop_event,
                    loop.quick_stop_event,
                    cfg.loop.stop_timeout_s,
                    cfg.period_s,
                ):
                    final, stats = loop.run(
                        prepared.law.initial_state(), max_duration_s, exit_on_fault=not cfg.loop.stay_in_fault
                    )
                notify("STOPPING=1")
                # changed under the run (an outside tester's chrt -o, a CPU taken offline and back):
                # the summary says so beside what was granted, not only what the start got
                at_end = granted_realtime()
                if at_end != granted:
                    log.warning(
                        "the loop's scheduling changed during the run: %s at the start, %s at the end",
                        granted,
                        at_end,
                    )
                # a page the kernel dropped (memory pressure, proactive reclaim) is read back from disk
                # when touched: milliseconds each, inside a cycle (--lock-memory prevents it)
                major_faults = resource.getrusage(resource.RUSAGE_SELF).ru_majflt - faults_before
                # the host's hold on each vCPU over the run (controller/shell/cpu_steal.py)
                steal_s = steal_s_since(steal_before)
            finally:
                if kernel_sync is not None:
                    kernel_sync.stop()
                helpers.restore()
                restore()
                if cfg.loop.freeze_gc:
                    unfreeze_garbage_collector()
    return summarize(
        stats,
        recorder,
        final,
        exchange.counters,
        prepared.bus_load.percent,
        extra={
            "bus": str(spec),
            "sync_producer": cfg.bus.sync_producer,
            "node_setup_s": round(setup.duration_s, 3),
            "node_setup_notes": list(setup.notes),
            "major_page_faults": major_faults,
            "steal_s": steal_s,
            "frames": {
                "sent": bus.sent,
                "received": bus.received,
                "own_echoes_dropped": bus.own_echoes,
                **_datagrams_dropped(bus.bus),
            },
            "recording": _recording_summary(session, cfg),
            "realtime": granted,
            **({"realtime_at_end": at_end} if at_end != granted else {}),
            "cpu_shield": shield_summary,
            **({"idle_poll": idle_poll_summary} if idle_poll_summary else {}),
            "helper_threads_raised": {"at_start": helpers_at_start, "during_run": helpers.raised},
            # the sleeper's spin before each deadline (loop.spin_us): CPU spent on the wake-up's precision
            "spin_s": round(sleeper.spun_s, 3),
            **({"kernel_sync": kernel_sync.report()} if kernel_sync is not None else {}),
            **{k: v for r in prepared.reports for k, v in r.summary().items()},
        },
    )


def _off_loop_worker(task: object) -> OffLoopWorker | None:
    """The worker of a task that plans off the loop (``PlansOffLoop``: the 3-nSPU's corrections)."""
    return task.off_loop_worker() if isinstance(task, PlansOffLoop) else None


def _session_recorder(
    cfg: Config, law: ControlLaw, spec: BusSpec, stop_event: threading.Event
) -> SessionRecorder | None:
    if not cfg.recording.enabled:
        return None
    from logs.recorder import SessionRecorder

    recorder = SessionRecorder.for_config(
        cfg, phase_name=law.task.phase_name, extra_metadata={"bus": str(spec)}
    )
    recorder.on_failure = _on_recording_failure(cfg.recording.on_failure, stop_event)
    # the live Foxglove server's stop service: the stop Zenoh's gate always takes
    recorder.on_remote_stop = stop_event.set
    return recorder


def _on_recording_failure(policy: str, stop_event: threading.Event) -> Callable[[str], None]:
    """recording.on_failure: "stop" ends the run through STOPPING, "warn" runs on unrecorded."""

    def stop(why: str) -> None:
        log.warning('recording lost (%s): stopping the run (recording.on_failure = "stop")', why)
        stop_event.set()

    def warn(why: str) -> None:
        log.warning('recording lost (%s): running on unrecorded (recording.on_failure = "warn")', why)

    return stop if policy == "stop" else warn


def _datagrams_dropped(bus: can.BusABC) -> dict[str, int]:
    """On udp_multicast, the datagrams its receiving socket dropped: from a source that is not this
    host's, and those that are no CAN frame (drivers/local_multicast.py); nothing on other buses."""
    if not isinstance(bus, LocalUdpMulticastBus):
        return {}
    return {
        "foreign_datagrams_dropped": bus.foreign_datagrams,
        "unreadable_datagrams_dropped": bus.unreadable_datagrams,
    }


def _both_sinks(a: FrameSink, b: FrameSink) -> FrameSink:
    def sink(outgoing: bool, monotonic_s: float, msg: can.Message) -> None:
        a(outgoing, monotonic_s, msg)
        b(outgoing, monotonic_s, msg)

    return sink


def _recording_summary(session: SessionRecorder | None, cfg: Config) -> dict[str, object] | None:
    if session is None:
        return None
    lost = ""
    if session.first_lost_cycle is not None:
        cycle, t = session.first_lost_cycle
        what = (
            "every cycle and frame" if session.error else f"{session.dropped} item(s) (cycles, frame batches)"
        )
        lost = f"{what} from cycle {cycle} (t = {t:.3f} s) on" + (
            f" ({session.dropped} items)" if session.error else ""
        )
    return {
        "path": str(session.path),
        "dropped": session.dropped,
        "written": session.written,
        "error": session.error,
        "lost": lost,
        "on_failure": cfg.recording.on_failure,
        "writer_scheduling": session.writer_scheduling,
        "session_id": session.session_id,
        "files": [str(p) for p in session.files],
        "deleted": [str(p) for p in session.deleted],
    }
