"""The SYNC period as a second node on the bus sees it: produced by the Python loop or by the kernel.

``python -m controller.tools.bench.sync_jitter --can socketcan:vcan0 --producer kernel --duration 10``
prints how far each SYNC interval is from the period (receive timestamps of the kernel, µs):
p50 / p99 / max of |interval - period|, and the achieved mean period. ``--producer loop`` paces
``send`` with the loop shell's ``DeadlineSleeper`` (the loop's own SYNC, without a control step:
its best case); ``--producer kernel`` hands the frame to the broadcast manager
(``drivers/kernel_sync.py``) and only reads. Run it beside ``cyclictest`` for the machine's floor;
``--fifo`` asks for SCHED_FIFO like the controller's loop.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import can
import numpy as np

from drivers.bus import open_bus, parse_bus_spec
from drivers.kernel_sync import check_kernel_sync, sync_message
from drivers.pacing import DeadlineSleeper

SYNC_COB_ID = 0x080


def measure(
    spec_text: str, producer: str, rate_hz: float, duration_s: float, spin_us: float = 300.0
) -> dict[str, object]:
    spec = parse_bus_spec(spec_text)
    if producer == "kernel":
        check_kernel_sync(spec.interface)
    period = 1.0 / rate_hz
    stamps: list[float] = []
    with open_bus(spec) as tx, open_bus(spec) as rx:
        rx.set_filters([{"can_id": SYNC_COB_ID, "can_mask": 0x7FF, "extended": False}])

        def drain(timeout_s: float) -> None:
            msg = rx.recv(timeout=timeout_s)
            while msg is not None:
                if msg.arbitration_id == SYNC_COB_ID and not msg.is_error_frame:
                    stamps.append(msg.timestamp)
                msg = rx.recv(timeout=0.0)

        end = time.monotonic() + duration_s
        if producer == "kernel":
            task = tx.send_periodic(sync_message(spec.fd), period)
            try:
                while time.monotonic() < end:
                    drain(0.1)
            finally:
                task.stop()
        else:
            sleeper, msg = DeadlineSleeper(spin_us * 1e-6), sync_message(spec.fd)
            first = time.monotonic() + period
            k = 0
            while (deadline := first + k * period) < end:
                sleeper.sleep_until(deadline)
                tx.send(msg)
                drain(0.0)  # what the loop does after its SYNC: read the bus
                k += 1
        drain(0.05)
    intervals = np.diff(np.asarray(stamps))
    if intervals.size < 2:
        raise SystemExit(f"only {len(stamps)} SYNC frames received on {spec}")
    dev_us = np.abs(intervals - period) * 1e6
    return {
        "producer": producer,
        "bus": str(spec),
        "rate_hz": rate_hz,
        "syncs": len(stamps),
        "mean_period_us": round(float(intervals.mean()) * 1e6, 3),
        "period_error_us": {
            "p50": round(float(np.percentile(dev_us, 50)), 1),
            "p99": round(float(np.percentile(dev_us, 99)), 1),
            "max": round(float(dev_us.max()), 1),
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m controller.tools.bench.sync_jitter", description=__doc__)
    parser.add_argument("--can", default="socketcan:vcan0")
    parser.add_argument("--producer", choices=("loop", "kernel"), default="kernel")
    parser.add_argument("--rate", type=float, default=400.0, help="SYNC rate [Hz]")
    parser.add_argument("--duration", type=float, default=10.0, help="[s]")
    parser.add_argument(
        "--fifo", action="store_true", help="SCHED_FIFO 80 for this process (needs permission)"
    )
    args = parser.parse_args(argv)
    if args.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(80))
    try:
        result = measure(args.can, args.producer, args.rate, args.duration)
    except (can.CanError, ValueError) as err:
        parser.error(str(err))
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
