"""Running the simulator until told to stop (the body of ``cheope sim``)."""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable

from controller.config import Config
from controller.shell.realtime import (
    RealtimeOptions,
    apply_realtime,
    freeze_garbage_collector,
    unfreeze_garbage_collector,
)
from drivers.bus import BusSpec, open_bus
from sim_backend.server import Simulator

READY_LINE = "cheope-sim ready"


def serve(cfg: Config, spec: BusSpec, stop_event: threading.Event, announce: Callable[[str], None],
          realtime: RealtimeOptions | None = None) -> None:
    # Before any thread starts: canopen's notifier, the heartbeat producers and the watchdog
    # inherit the priority and the affinity (the simulated hardware is real time as a whole).
    if realtime is not None:
        apply_realtime(realtime)
    # the SYNC handler competes with heartbeat and watchdog threads for the GIL
    sys.setswitchinterval(cfg.loop.gil_switch_interval_us * 1e-6)
    with open_bus(spec) as bus, Simulator(cfg, bus):
        if cfg.loop.freeze_gc:
            # as in the controller: a full collection of the simulator's start-up heap took
            # 21 ms, five missing TPDOs at 400 Hz (the contour demo faulted so in lap 5)
            freeze_garbage_collector()
        announce(f"{READY_LINE} on {spec}: drives {list(cfg.actuators.node_ids)}"
                 + (f", sensor {cfg.sensor.node_id}" if cfg.sensor.enabled else ""))
        stop_event.wait()
    if cfg.loop.freeze_gc:
        unfreeze_garbage_collector()
