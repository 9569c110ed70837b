"""Running the simulator until told to stop (the body of ``cheope sim``)."""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable

from controller.config import Config
from controller.errors import DeviceError
from controller.realtime import (
    RealtimeOptions,
    apply_realtime,
    freeze_garbage_collector,
    unfreeze_garbage_collector,
)
from controller.sim_config.fault_specs import refuse_in_process_only
from drivers import cob_ids
from drivers.bus import BusSpec, open_bus
from drivers.bus_presence import check_node_ids_free
from drivers.local_multicast import LocalUdpMulticastBus
from sim_backend.server import Simulator
from sim_backend.true_force_tap import TrueForceTap

READY_LINE = "cheope-sim ready"
STOPPED_LINE = "cheope-sim stopped"  # then what it saw:
CONTACT_FORCE_REPORT = "max true contact force per controller session"  # the numbers, then "N"
FAULTS_NOT_REACHED_REPORT = "faults not reached"  # then their specs (``FaultSchedule.not_reached``)
FAULTS_MISSED_REPORT = "faults missed"  # then their specs (``FaultSchedule.missed``)


def sdo_node_ids(cfg: Config) -> tuple[int, ...]:
    """The simulated devices with an object dictionary: the drives and, when enabled, the sensor."""
    return (*cfg.actuators.node_ids, *((cfg.sensor.node_id,) if cfg.sensor.enabled else ()))


def device_node_ids(cfg: Config) -> tuple[int, ...]:
    """Every node id the simulator sends as: its SDO devices and, when enabled, the pose tracker."""
    return (*sdo_node_ids(cfg), *((cfg.tracker.node_id,) if cfg.tracker.enabled else ()))


def serve(
    cfg: Config,
    spec: BusSpec,
    stop_event: threading.Event,
    announce: Callable[[str], None],
    realtime: RealtimeOptions | None = None,
    true_force_tap: str = "",
) -> None:
    """Set up, then go real-time, then start the devices and announce READY; back to the normal
    scheduler when stopped.

    Everything before ``apply_realtime`` (the bus, the EDS files, the plant, the canopen nodes,
    the garbage collection) runs under the normal scheduler: at SCHED_FIFO it would take the CPU
    from another simulator on this host that answers its SYNCs there (a second ``cheope sim``
    faulted the first's controller with missing TPDOs). The device threads start after it, and
    inherit its priority and affinity (the simulated hardware is real time as a whole).
    """
    refuse_in_process_only(cfg.sim.faults, "cheope sim")  # before the bus opens
    # the SYNC handler competes with heartbeat and watchdog threads for the GIL
    sys.setswitchinterval(cfg.loop.gil_switch_interval_us * 1e-6)
    with open_bus(spec) as bus:
        # one device per node id: a second simulator on this bus refuses before it sends a frame
        check_node_ids_free(
            bus, spec.place, device_node_ids(cfg), sdo_node_ids(cfg), cfg.bus.presence_listen_s
        )
        if isinstance(bus, LocalUdpMulticastBus):
            # The drives act on their RPDOs at the SYNC after them: only the SYNC (and every frame
            # outside the PDOs) wakes the cyclic thread, which then reads the RPDOs before it. The
            # loop's sends of the RPDOs then wake no thread on another CPU (drivers/local_multicast.py).
            bus.defer_wakeups(cob_ids.RPDO1_TO_RPDO4)
        tap = TrueForceTap(true_force_tap) if true_force_tap else None
        simulator = Simulator(cfg, bus, true_force_tap=tap)
        simulator.build_nodes()
        simulator.on_failure = stop_event.set  # the devices' thread ended: the process ends, loudly
        if cfg.loop.freeze_gc:
            # as in the controller: a full collection of the simulator's start-up heap took
            # 21 ms, five missing TPDOs at 400 Hz (the contour demo faulted so in lap 5)
            freeze_garbage_collector()
        drop_realtime = apply_realtime(realtime) if realtime is not None else lambda: None
        with simulator:  # start(): boot-up, heartbeats, the cyclic thread
            announce(
                f"{READY_LINE} on {spec}: drives {list(cfg.actuators.node_ids)}"
                + (f", sensor {cfg.sensor.node_id}" if cfg.sensor.enabled else "")
            )
            stop_event.wait()
            # the shut-down (threads joined, the heap freed at exit) is no real-time work either:
            # at SCHED_FIFO it starved another simulator on this CPU as the start-up did
            drop_realtime()
        maxima = simulator.max_contact_force_n or [0.0]
        announce(f"{STOPPED_LINE}: {CONTACT_FORCE_REPORT} " + " ".join(f"{m:.3f}" for m in maxima) + " N")
        # the demo's summary names them (controller/shell/demo.py simulator_report)
        for report, specs in (
            (FAULTS_NOT_REACHED_REPORT, simulator.faults.not_reached()),
            (FAULTS_MISSED_REPORT, simulator.faults.missed()),
        ):
            if specs:
                announce(f"{STOPPED_LINE}: {report} " + " ".join(specs))
    if tap is not None:
        tap.close()
    if cfg.loop.freeze_gc:
        unfreeze_garbage_collector()
    if simulator.failure is not None:
        err = simulator.failure
        raise DeviceError(
            f"the simulated devices stopped answering: their thread ended on {type(err).__name__}: {err}"
        )
