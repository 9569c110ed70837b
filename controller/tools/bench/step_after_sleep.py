"""The step after a sleep: without the CPUs' wake-up latency limit (PM QoS), with it, and with the
CPU kept polling (``controller/shell/idle_poll.py``).

    .venv/bin/python -m controller.tools.bench.step_after_sleep [--task path] [--sleep-ms 2] [--runs 5]

The loop sleeps most of each cycle (before its deadline, while the drives answer); a CPU left
idle may enter a state that takes time to leave (on a VM guest the ``haltpoll`` driver's halt
hands the vCPU back to the host), and the code that runs after it runs slower. Here the law
runs on the in-process simulated devices in simulated time, with a real sleep of ``--sleep-ms``
after every cycle, and its ``step`` is timed on the wall clock over ``--cycles`` cycles of the
task, in runs that alternate between no limit, a limit of 0 (``controller.realtime``'s
``hold_cpu_latency``, what ``--cpu-latency-us 0`` holds) and a ``SCHED_IDLE`` poller on the CPU
(what ``--idle-poll`` starts); the sleep's own overshoot is printed too. Also a run without the
sleep, the hot floor. Pinned to the last CPU; needs write access to /dev/cpu_dma_latency (root).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from controller.realtime import RealtimeError, hold_cpu_latency
from controller.shell.idle_poll import idle_polling
from controller.tools.bench.statistics import percentiles_us
from controller.tools.bench.step_hook import StepHookedLaw

DEFAULT_WINDOWS = {"path": (800, 2000), "contour": (3200, 2000)}  # (skip, cycles): the lap, the tracking


def step_times_us(
    task: str, sleep_s: float, skip: int, cycles: int, overshoots: list[float] | None = None
) -> list[float]:
    """Wall time of each ``step`` of cycles ``[skip, skip + cycles)``, sleeping ``sleep_s`` after each
    cycle; ``overshoots`` gets how much later than asked each of those cycles' sleep ended [us]."""
    from controller.shell.simulated_rig import SimulatedRig
    from controller.tools.bench.cycle_work import task_config

    cfg = task_config(task)
    rig = SimulatedRig(cfg)
    times: list[float] = []
    clock = time.perf_counter

    def timed(step: Callable[[Any, Any, float], Any], state: Any, inputs: Any, t: float) -> Any:
        t0 = clock()
        out = step(state, inputs, t)
        times.append(clock() - t0)
        return out

    late: list[float] = []

    class Sleep:
        def on_cycle(self, *args: object) -> None:
            if sleep_s > 0.0:
                t0 = clock()
                time.sleep(sleep_s)
                late.append(clock() - t0 - sleep_s)

    rig.law = StepHookedLaw(rig.law, timed)  # type: ignore[assignment]  # the same law, its step timed
    rig.run((Sleep(),), max_duration_s=(skip + cycles) * cfg.period_s)
    if overshoots is not None:
        overshoots.extend(x * 1e6 for x in late[skip : skip + cycles])
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
    kinds = ("no limit", "limit 0", "idle poll")
    rows: dict[str, list[tuple[float, float]]] = {kind: [] for kind in kinds}
    sleeps: dict[str, list[tuple[float, float]]] = {kind: [] for kind in kinds}
    for _ in range(args.runs):
        for kind in kinds:
            overshoots: list[float] = []
            with contextlib.ExitStack() as held:
                if kind == "limit 0":
                    held.callback(os.close, hold_cpu_latency(0))
                if kind == "idle poll":  # a poller refused is an error, not a run without one
                    held.enter_context(idle_polling((cpus[-1],), {}, required=True))
                t = step_times_us(args.task, args.sleep_ms * 1e-3, skip, cycles, overshoots)
            q = percentiles_us(np.asarray(t))
            rows[kind].append((q["p50"], q["p99"]))
            o = percentiles_us(np.asarray(overshoots))
            sleeps[kind].append((o["p50"], o["p99"]))
    hot = percentiles_us(np.asarray(step_times_us(args.task, 0.0, skip, cycles)))
    print(
        f"{args.task} task, step after a {args.sleep_ms:g}-ms sleep, cycles {skip}-{skip + cycles - 1}, CPU {cpus[-1]}:"
    )
    for kind, runs in rows.items():
        p50s = [r[0] for r in runs]
        print(
            f"  {kind:9s} p50 by run "
            + " / ".join(f"{r[0]:.0f}" for r in runs)
            + f" us (median {statistics.median(p50s):.0f}), p99 "
            + " / ".join(f"{r[1]:.0f}" for r in runs)
        )
    print("  the sleep's end past its time:")
    for kind, runs in sleeps.items():
        print(
            f"  {kind:9s} p50 by run "
            + " / ".join(f"{r[0]:.0f}" for r in runs)
            + " us, p99 "
            + " / ".join(f"{r[1]:.0f}" for r in runs)
        )
    no_limit = statistics.median(r[0] for r in rows["no limit"])
    for kind in kinds[1:]:
        ratio = no_limit / statistics.median(r[0] for r in rows[kind])
        print(f"  ratio of the step's medians, no limit / {kind}: {ratio:.2f}")
    print(f"  without the sleep (hot): p50 {hot['p50']:.0f} us, p99 {hot['p99']:.0f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
