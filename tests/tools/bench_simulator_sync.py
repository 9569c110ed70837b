"""What one SYNC costs the simulator's cyclic thread while its drives are not enabled.

    .venv/bin/python tests/tools/bench_simulator_sync.py [--idle-s 1.0] [--syncs 3000]

The simulator (``sim_backend/server.py``, Cheope's default configuration, a python-can virtual
bus) is started, left idle for ``--idle-s`` (the controller's node set-up takes about that long
before the drives are enabled), stopped, and then its SYNC handler is called ``--syncs`` times
directly: p50 / p90 / p99 of ``_on_sync`` in µs (the first 500 calls not counted). Before
d299c9a a drive that was not enabled integrated the whole time since its first SYNC again at
every SYNC: this cost grew with ``--idle-s`` (550 µs after 1 s), now it does not.
"""

from __future__ import annotations

import argparse
import time

import can
import numpy as np

from controller.config import load_config
from sim_backend.server import Simulator


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--idle-s", type=float, default=1.0)
    ap.add_argument("--syncs", type=int, default=3000)
    args = ap.parse_args()
    bus = can.Bus(interface="virtual", channel="bench-simulator-sync")
    try:
        sim = Simulator(load_config(), bus)
        sim.start()
        time.sleep(args.idle_s)
        sim.stop()
        cost_s = np.empty(args.syncs)
        for k in range(args.syncs):
            t0 = time.perf_counter()
            sim._on_sync(bytearray(), time.monotonic())
            cost_s[k] = time.perf_counter() - t0
    finally:
        bus.shutdown()
    us = cost_s[min(500, args.syncs // 2) :] * 1e6
    p50, p90, p99 = np.percentile(us, [50, 90, 99])
    print(
        f"simulator _on_sync after {args.idle_s:g} s idle: p50 {p50:.1f} us, p90 {p90:.1f} us, p99 {p99:.1f} us "
        f"({us.size} SYNCs)"
    )


if __name__ == "__main__":
    main()
