"""How long the controller's device set-up takes against the in-process simulator (virtual bus).

``python -m controller.tools.bench.node_setup_time [RUNS]`` prints each run's ``configure_nodes``
duration and the median, with the shipped configuration (three drives and the sensor).
"""

from __future__ import annotations

import argparse
import statistics
import time

import can

from controller.config import load_config
from controller.node_plan import node_setup_plan
from drivers.node_setup import configure_nodes
from sim_backend.server import Simulator


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="node_setup_time", description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="?", type=int, default=7, help="set-ups to time (default 7)")
    runs = parser.parse_args(argv).runs
    if runs < 1:
        parser.error(f"runs {runs}: must be 1 or more")
    cfg = load_config()
    durations_ms = []
    for _ in range(runs):
        channel = f"setup-time-{time.monotonic_ns()}"
        sim_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=True)
        try:
            with Simulator(cfg, sim_bus):
                durations_ms.append(configure_nodes(bus, node_setup_plan(cfg)).duration_s * 1000.0)
        finally:
            sim_bus.shutdown()
            bus.shutdown()
    print(
        f"configure_nodes ms: {[round(d) for d in durations_ms]}, median {statistics.median(durations_ms):.0f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
