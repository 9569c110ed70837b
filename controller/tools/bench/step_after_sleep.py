"""The step after a sleep, with and without the CPUs' wake-up latency limit (PM QoS).

    .venv/bin/python -m controller.tools.bench.step_after_sleep [--task path] [--sleep-ms 2] [--runs 5]

The loop sleeps most of each cycle (before its deadline, while the drives answer); a CPU left
idle may enter a state that takes time to leave (on a VM guest the ``haltpoll`` driver's halt
hands the vCPU back to the host), and the code that runs after it runs slower. Here the law
runs on the in-process simulated devices in simulated time, with a real sleep of ``--sleep-ms``
after every cycle, and its ``step`` is timed on the wall clock over ``--cycles`` cycles of the
task, in runs that alternate between no limit and a limit of 0 (``controller.realtime``'s
``hold_cpu_latency``, what ``--cpu-latency-us 0`` holds). Also a run without the sleep, the
hot floor. Pinned to the last CPU; needs write access to /dev/cpu_dma_latency (root).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from typing import Any

import numpy as np

from controller.realtime import RealtimeError, hold_cpu_latency
from controller.tools.bench.statistics import percentiles_us

DEFAULT_WINDOWS = {"path": (800, 2000), "contour": (3200, 2000)}  # (skip, cycles): the lap, the tracking


def step_times_us(task: str, sleep_s: float, skip: int, cycles: int) -> list[float]:
    """Wall time of each ``step`` of cycles ``[skip, skip + cycles)``, sleeping ``sleep_s`` after each cycle."""
    from controller.shell.simulated_rig import SimulatedRig
    from controller.tools.bench.cycle_work import task_config

    cfg = task_config(task)
    rig = SimulatedRig(cfg)
    inner = rig.law.step
    times: list[float] = []
    clock = time.perf_counter

    def timed(state: Any, inputs: Any, t: float) -> Any:
        t0 = clock()
        out = inner(state, inputs, t)
        times.append(clock() - t0)
        return out

    class Sleep:
        def on_cycle(self, *args: object) -> None:
            if sleep_s > 0.0:
                time.sleep(sleep_s)

    class TimedLaw:
        """The rig's law with its step timed. A wrapper, not an assignment to ``law.step``: a
        compiled law's methods are read-only."""

        def __init__(self, law: Any) -> None:
            self._law = law

        step = staticmethod(timed)

        def __getattr__(self, name: str) -> Any:
            return getattr(self._law, name)

    rig.law = TimedLaw(rig.law)  # type: ignore[assignment]  # the same law, its step timed
    rig.run((Sleep(),), max_duration_s=(skip + cycles) * cfg.period_s)
    return [x * 1e6 for x in times[skip : skip + cycles]]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", choices=sorted(DEFAULT_WINDOWS), default="path")
    ap.add_argument("--sleep-ms", type=float, default=2.0)
    ap.add_argument("--runs", type=int, default=5, help="runs of each kind, alternating")
    args = ap.parse_args(argv)
    skip, cycles = DEFAULT_WINDOWS[args.task]
    cpus = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpus[-1]})
    try:
        os.close(hold_cpu_latency(0))
    except RealtimeError as err:
        print(f"step_after_sleep: {err}", file=sys.stderr)
        return 2
    rows: dict[str, list[tuple[float, float]]] = {"no limit": [], "limit 0": []}
    for _ in range(args.runs):
        for kind in rows:
            fd = hold_cpu_latency(0) if kind == "limit 0" else None
            try:
                t = step_times_us(args.task, args.sleep_ms * 1e-3, skip, cycles)
            finally:
                if fd is not None:
                    os.close(fd)
            q = percentiles_us(np.asarray(t))
            rows[kind].append((q["p50"], q["p99"]))
    hot = percentiles_us(np.asarray(step_times_us(args.task, 0.0, skip, cycles)))
    print(
        f"{args.task} task, step after a {args.sleep_ms:g}-ms sleep, cycles {skip}-{skip + cycles - 1}, CPU {cpus[-1]}:"
    )
    for kind, runs in rows.items():
        p50s = [r[0] for r in runs]
        print(
            f"  {kind:8s} p50 by run "
            + " / ".join(f"{r[0]:.0f}" for r in runs)
            + f" us (median {statistics.median(p50s):.0f}), p99 "
            + " / ".join(f"{r[1]:.0f}" for r in runs)
        )
    ratio = statistics.median(r[0] for r in rows["no limit"]) / statistics.median(
        r[0] for r in rows["limit 0"]
    )
    print(f"  ratio of the medians, no limit / limit 0: {ratio:.2f}")
    print(f"  without the sleep (hot): p50 {hot['p50']:.0f} us, p99 {hot['p99']:.0f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
