"""The step's cost in process against Ruckig's own calculation time, with a profile of its hottest
functions; for the law as this process runs it (compiled by mypyc or not: controller/compiled_law.py)
and, beside a compiled one, for its sources interpreted in a child process (``interpreted_step_breakdown``).

    .venv/bin/python -m controller.tools.bench.step_cost [--rate 400] [--cycles 4000] [--set KEY=VALUE]
        [--idle-us US]

Back to back (the default) each step finds the caches as the last one left them. In the service
the loop's thread waits for its next deadline between two steps: ``--idle-us`` sleeps that long
before each timed step (wall-clock; the simulated time goes on as before), the same steps with the
same inputs, so that the two figures side by side say what the wait alone costs the step.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import sys
import time
from typing import TYPE_CHECKING

import numpy as np

from controller.compiled_law import LAW_BUILD, run_interpreted
from controller.tools.bench.statistics import percentiles_us

if TYPE_CHECKING:
    from ruckig import InputParameter

    from controller.core.setpoint_smoothing import Setpoint, SmoothingResult


def step_breakdown(
    config_path: str | None,
    overrides: list[str],
    rate_hz: float,
    cycles: int,
    profile_top: int = 12,
    idle_us: float = 0.0,
) -> dict[str, object]:
    """Run the law on the in-process loopback plant (simulated time): step time vs Ruckig's.

    Ruckig's reported time is ``OutputParameter.calculation_duration`` of a second Ruckig
    object fed the same input with ``update`` (``calculate``, which the law uses, reports none).
    """
    from ruckig import OutputParameter, Ruckig, RuckigError

    from controller.assembly import build_law
    from controller.config import load_config, parse_override
    from controller.core.cycle_data import cycle_inputs
    from controller.shell.loop import SimulatedTime
    from sim_backend.loopback import LoopbackExchange

    cfg = load_config(config_path, dict(parse_override(s) for s in [*overrides, f"loop.rate_hz={rate_hz}"]))
    law = build_law(cfg)
    smoother = law.smoother
    dofs = len(cfg.actuators.node_ids)
    twin, out = Ruckig(dofs), OutputParameter(dofs)
    reported_us: list[float] = []
    wrapper_s: list[float] = []
    inner = smoother._calculate

    def timed_calculate(inp: InputParameter, current: Setpoint) -> SmoothingResult:
        t0 = time.perf_counter()
        result = inner(inp, current)
        wrapper_s.append(time.perf_counter() - t0)
        try:
            twin.update(inp, out)
            reported_us.append(out.calculation_duration)
        except RuckigError:
            pass
        return result

    # an instance attribute wrapping the bound method: this law object only. A compiled smoother has
    # no instance dictionary: its Ruckig figures come from the interpreted run.
    try:
        smoother._calculate = timed_calculate  # type: ignore[method-assign]  # deliberate, see above
        wrapped_ruckig = True
    except AttributeError:
        wrapped_ruckig = False
    sim = SimulatedTime()
    exchange = LoopbackExchange(cfg, sim.clock)
    state = law.initial_state()
    outputs = None
    period = cfg.period_s
    step_s = np.empty(cycles)
    profiler = cProfile.Profile()
    for k in range(cycles):
        sim.sleep_until(k * period)
        exchange.send(outputs)
        inputs = cycle_inputs(exchange.collect(k * period + period))
        if idle_us:
            time.sleep(idle_us * 1e-6)
        t0 = time.perf_counter()
        state, outputs, _ = law.step(state, inputs, k * period)
        step_s[k] = time.perf_counter() - t0
    # a second pass of the same cycles under cProfile (the timed pass above is unprofiled)
    sim2 = SimulatedTime()
    law2 = build_law(cfg)
    exchange2 = LoopbackExchange(cfg, sim2.clock)
    state2, outputs2 = law2.initial_state(), None
    profiler.enable()
    for k in range(cycles):
        sim2.sleep_until(k * period)
        exchange2.send(outputs2)
        inputs2 = cycle_inputs(exchange2.collect(k * period + period))
        state2, outputs2, _ = law2.step(state2, inputs2, k * period)
    profiler.disable()
    buf = io.StringIO()
    pstats.Stats(profiler, stream=buf).sort_stats("tottime").print_stats(profile_top)
    step_us = step_s * 1e6
    reported = np.asarray(reported_us)
    wrapped = np.asarray(wrapper_s) * 1e6
    ruckig: dict[str, object] = (
        {
            "ruckig_calls_per_cycle": round(len(wrapper_s) / cycles, 2),
            "ruckig_reported_calculation_us": percentiles_us(reported),
            "ruckig_call_in_python_us": percentiles_us(wrapped),
            "ruckig_share_of_step_percent": round(100.0 * float(np.sum(reported)) / float(np.sum(step_us)), 1)
            if step_us.sum() > 0
            else 0.0,
        }
        if wrapped_ruckig
        else {}
    )
    return {
        "rate_hz": rate_hz,
        "cycles": cycles,
        "law": LAW_BUILD.describe(),
        "final_mode": state.mode.name,
        "idle_before_step_us": idle_us,
        "step_us": percentiles_us(step_us),
        **ruckig,
        "profile_top_tottime": _profile_lines(buf.getvalue()),
    }


def interpreted_step_breakdown(
    config_path: str | None, overrides: list[str], rate_hz: float, cycles: int
) -> dict[str, object]:
    """``step_breakdown`` of the law's sources, in a child process that runs them interpreted."""
    args = [
        "--rate",
        repr(rate_hz),
        "--cycles",
        str(cycles),
        *(["--config", config_path] if config_path else []),
    ]
    result: dict[str, object] = run_interpreted(
        "controller.tools.bench.step_cost", [*args, *(a for o in overrides for a in ("--set", o))]
    )
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="step_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", help="TOML configuration (default: the shipped one)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    ap.add_argument("--rate", type=float, default=400.0, help="loop rate [Hz]")
    ap.add_argument("--cycles", type=int, default=4000, help="cycles of simulated time")
    ap.add_argument(
        "--idle-us", type=float, default=0.0, help="sleep this long before each timed step [us] (default 0)"
    )
    args = ap.parse_args(argv)
    if not 0.0 <= args.idle_us <= 1e6:
        ap.error(f"--idle-us {args.idle_us:g}: must be 0 to 1 000 000 (a second)")
    print(json.dumps(step_breakdown(args.config, args.set, args.rate, args.cycles, idle_us=args.idle_us)))
    return 0


def _profile_lines(text: str) -> list[str]:
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.lstrip().startswith("ncalls")), None)
    return [] if start is None else [line.rstrip() for line in lines[start:] if line.strip()]


if __name__ == "__main__":
    sys.exit(main())
