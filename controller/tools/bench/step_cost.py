"""The step's cost in Python against Ruckig's own calculation time, with a profile of its hottest functions."""

from __future__ import annotations

import cProfile
import io
import pstats
import time
from typing import TYPE_CHECKING

import numpy as np

from controller.tools.bench.statistics import percentiles_us

if TYPE_CHECKING:
    from ruckig import InputParameter

    from controller.core.setpoint_smoothing import Setpoint, SmoothingResult


def step_breakdown(
    config_path: str | None, overrides: list[str], rate_hz: float, cycles: int, profile_top: int = 12
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

    # an instance attribute wrapping the bound method: this law object only
    smoother._calculate = timed_calculate  # type: ignore[method-assign]  # deliberate, see above
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
    return {
        "rate_hz": rate_hz,
        "cycles": cycles,
        "final_mode": state.mode.name,
        "step_us": percentiles_us(step_us),
        "ruckig_calls_per_cycle": round(len(wrapper_s) / cycles, 2),
        "ruckig_reported_calculation_us": percentiles_us(reported),
        "ruckig_call_in_python_us": percentiles_us(wrapped),
        "ruckig_share_of_step_percent": round(100.0 * float(np.sum(reported)) / float(np.sum(step_us)), 1)
        if step_us.sum() > 0
        else 0.0,
        "profile_top_tottime": _profile_lines(buf.getvalue()),
    }


def _profile_lines(text: str) -> list[str]:
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.lstrip().startswith("ncalls")), None)
    return [] if start is None else [line.rstrip() for line in lines[start:] if line.strip()]
