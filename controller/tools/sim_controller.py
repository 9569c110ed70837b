"""A controller with its Zenoh publisher on the in-process simulated devices, in real time.

For the monitoring tests and the latency benchmark: the loop shell, the control law and the
publisher are the production ones; the devices are ``sim_backend.loopback`` (no bus, no
simulator process), run on the monotonic clock so samples flow at the configured rate.

    python -m controller.tools.sim_controller --set monitoring.listen='"tcp/127.0.0.1:7600"'

prints ``READY <robot id> <listen endpoints>`` once the publisher is up and, at the end, one
JSON line with the final mode and the events. SIGTERM or SIGINT request a controlled stop.
A start refused (a robot id already taken) ends with one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable

from controller.assembly import build_law
from controller.config import Config, load_config, parse_override
from controller.core.controller_state import ControllerState
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
from controller.core.ports import CycleTiming
from controller.errors import CheopeError
from controller.monitoring.publisher import monitoring_publisher
from controller.realtime import RealtimeOptions, apply_realtime, granted_realtime
from controller.shell.loop import CycleLoop
from controller.shell.service import publisher_settings
from controller.signal_relay import stop_event_on_signals
from drivers.pacing import DeadlineSleeper

READY = "READY"


def run_simulated(
    cfg: Config,
    stop_event: threading.Event,
    max_duration_s: float,
    on_ready: Callable[[str, tuple[str, ...]], None] = lambda robot_id, endpoints: None,
    realtime: RealtimeOptions | None = None,
) -> dict[str, object]:
    from sim_backend.loopback import LoopbackExchange

    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, time.monotonic)
    events: list[str] = []

    class _Events:
        def on_cycle(
            self,
            cycle: int,
            t: float,
            inputs: CycleInputs,
            state: ControllerState,
            outputs: CycleOutputs,
            evs: tuple[Event, ...],
            timing: CycleTiming,
        ) -> None:
            events.extend(f"{e.severity.name}: {e.message}" for e in evs)

    with monitoring_publisher(publisher_settings(cfg), stop_event, law.task) as pub:
        on_ready(pub.settings.robot_id, pub.listen_endpoints)
        loop = CycleLoop(
            law,
            exchange,
            cfg.period_s,
            cfg.loop.collect_fraction,
            DeadlineSleeper(cfg.loop.spin_us * 1e-6),
            time.monotonic,
            observers=(_Events(), pub),
            stop_event=stop_event,
            commands=pub.commands,
            observers_in_window=True,  # over a bus (controller/shell/loop.py, step 5)
        )
        # on this thread only: the publisher's (Zenoh's) threads are already running under the normal scheduler
        restore = apply_realtime(realtime) if realtime is not None else None
        granted = granted_realtime()
        try:
            final, stats = loop.run(
                law.initial_state(), max_duration_s, exit_on_fault=not cfg.loop.stay_in_fault
            )
        finally:
            if restore is not None:
                restore()
        counters = pub.counters()
    return {
        "robot_id": pub.settings.robot_id,
        "final_mode": final.mode.name,
        "fault_reason": final.fault_reason,
        "events": events,
        "cycles": stats.cycles,
        "publisher": counters,
        "realtime": granted,
        "late_cycles": stats.late_cycles(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m controller.tools.sim_controller")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--max-duration", type=float, default=60.0)
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="the loop thread as cheope run's default: SCHED_FIFO 80 on the last CPU, memory locked, "
        "where permitted (one warning line where refused)",
    )
    args = ap.parse_args(argv)
    cfg = load_config(overrides=dict(parse_override(s) for s in args.set))
    stop = stop_event_on_signals()  # no lock in a handler (controller/signal_relay.py)
    try:
        result = run_simulated(
            cfg,
            stop,
            args.max_duration,
            lambda rid, eps: print(f"{READY} {rid} {' '.join(eps)}", flush=True),
            RealtimeOptions.default() if args.realtime else None,
        )
    except (
        CheopeError
    ) as err:  # a robot id already taken, a session that cannot open: one line, as cheope run
        print(f"sim_controller: error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
