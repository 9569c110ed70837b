"""How a run ends, in simulated time: every stop goes through STOPPING to DONE with the drives
disabled; a second signal, or a stop that does not end in time, quick-stops them."""

from __future__ import annotations

import signal
import threading

import numpy as np
import pytest

from controller.assembly import build_law
from controller.config import Config, load_config
from controller.core.cia402 import PowerState, decode_statusword
from controller.core.controller_state import ControllerState, Mode
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import RunRecorder
from controller.shell.simulated_rig import SimulatedRig
from controller.shell.stop_signals import StopSignals
from sim_backend.loopback import LoopbackExchange

LONG = {"task.path.laps": 20.0}  # far longer than any test lets it run


def _run(
    cfg: Config,
    max_s: float | None,
    stop_at_s: float | None = None,
    quick_at_s: float | None = None,
    stop_timeout_s: float = 10.0,
    stop: threading.Event | None = None,
) -> tuple[ControllerState, LoopbackExchange, list[Mode], RunRecorder]:
    rig = SimulatedRig(cfg)
    stop = stop or threading.Event()
    quick = threading.Event()
    modes: list[Mode] = []

    class Hook:
        def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
            modes.append(state.mode)
            if stop_at_s is not None and t >= stop_at_s:
                stop.set()
            if quick_at_s is not None and t >= quick_at_s:
                quick.set()

    rec = RunRecorder()
    loop = rig.loop((Hook(), rec), stop_event=stop, quick_stop_event=quick, stop_timeout_s=stop_timeout_s)
    final, _ = loop.run(rig.law.initial_state(), max_s)
    return final, rig.exchange, modes, rec


def _powers(exchange: LoopbackExchange) -> set[PowerState]:
    return {decode_statusword(d.statusword()) for d in exchange.drives}


def test_the_end_of_max_duration_stops_through_stopping_with_the_drives_disabled():
    cfg = load_config(overrides=LONG)
    final, exchange, modes, rec = _run(cfg, max_s=1.5)
    assert final.mode == Mode.DONE, final.fault_reason
    assert Mode.RUNNING in modes and Mode.STOPPING in modes
    assert _powers(exchange) <= {PowerState.READY_TO_SWITCH_ON, PowerState.SWITCH_ON_DISABLED}
    assert all(d.velocity == 0.0 for d in exchange.drives)
    assert any("stop requested" in e.message for _, e in rec.events)
    assert not any("quick stop" in e.message for _, e in rec.events)


def test_a_second_request_quick_stops_the_drives():
    cfg = load_config(overrides=LONG)
    final, exchange, modes, _ = _run(cfg, max_s=None, stop_at_s=1.0, quick_at_s=1.0 + 2 * cfg.period_s)
    assert final.mode == Mode.FAULT
    assert Mode.STOPPING in modes  # the first request was braking when the second came
    assert final.fault_reason == "quick stop requested"
    assert _powers(exchange) == {PowerState.QUICK_STOP_ACTIVE}


def test_a_stop_that_does_not_reach_done_in_time_becomes_a_quick_stop():
    cfg = load_config(overrides=LONG)
    # 10 ms cannot brake carriages moving along the path: the loop must not wait for ever
    final, exchange, _, _ = _run(cfg, max_s=None, stop_at_s=1.0, stop_timeout_s=0.01)
    assert final.mode == Mode.FAULT and final.fault_reason == "quick stop requested"
    assert _powers(exchange) == {PowerState.QUICK_STOP_ACTIVE}


def test_a_stop_before_anything_is_enabled_ends_at_once_in_done():
    cfg = load_config(overrides=LONG)
    stop = threading.Event()
    stop.set()
    final, exchange, modes, _ = _run(cfg, max_s=None, stop=stop)
    assert final.mode == Mode.DONE
    assert Mode.ENABLING not in modes and Mode.RUNNING not in modes
    assert PowerState.OPERATION_ENABLED not in _powers(exchange)


def test_without_max_duration_the_run_goes_on_until_the_task_ends():
    cfg = load_config(overrides={"task.path.laps": 0.25})
    final, _, modes, _ = _run(cfg, max_s=None)
    assert final.mode == Mode.DONE
    assert modes.count(Mode.RUNNING) * cfg.period_s > 1.0  # the quarter lap, not a default limit


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_a_max_duration_that_is_not_positive_is_refused(bad):
    cfg = load_config()
    clock = SimulatedTime()
    law = build_law(cfg)
    loop = CycleLoop(law, LoopbackExchange(cfg, clock.clock), cfg.period_s, 0.8, clock, clock.clock)
    with pytest.raises(ValueError, match="max_duration_s"):
        loop.run(law.initial_state(), bad)


def test_stop_signals_first_stops_then_quick_stops():
    s = StopSignals()
    s.on_signal(signal.SIGTERM)
    assert s.stop.is_set() and not s.quick_stop.is_set()
    s.on_signal(signal.SIGINT)
    assert s.quick_stop.is_set()


def test_the_run_recorder_keeps_bounded_figures():
    cfg = load_config(overrides={"task.path.laps": 0.25})
    _, _, _, rec = _run(cfg, max_s=None)
    err = rec.tracking_error_m
    assert rec.tracking.count == err.size > 300
    assert rec.tracking.rms == pytest.approx(float(np.sqrt(np.mean(err**2))))
    assert rec.tracking.maximum == err.max()


def test_a_fault_after_the_loops_own_hold_up_is_said_to_follow_it():
    """An outside tester stopped the controller 5 s (SIGSTOP): the fault named the drives ("heartbeat
    lost from node(s) [1, 2, 16]"). The summary says the loop was held up just before; a fault
    with no hold-up before it, or long after one, is not blamed on it."""
    from types import SimpleNamespace

    from controller.core.cycle_data import Event, Severity
    from controller.core.ports import CycleTiming
    from controller.shell.run_summary import HOLDUP_BLAME_S

    state = SimpleNamespace(tcp_measured_m=None, tcp_reference_m=None)
    inputs = SimpleNamespace(drives=())
    fault = Event(
        "mode", Severity.FAULT, f"{Mode.RUNNING.name} -> {Mode.FAULT.name}: heartbeat lost from node(s) [1]"
    )

    period = 0.0025

    def run(stepped: list[float]) -> RunRecorder:
        """Cycles whose steps ended at ``stepped`` [s] (the loop's clock), the last one faulting."""
        rec = RunRecorder()
        for k, s in enumerate(stepped):
            last = k == len(stepped) - 1
            rec.on_cycle(
                k, k * period, inputs, state, None, (fault,) if last else (), CycleTiming(0.0, 1e-4, s)
            )
        return rec

    # stopped inside its cycle (the tester's: 5 s in the collect, the fault in that same cycle)
    held = run([0.0, period, 2 * period, 5.0 + 3 * period])
    assert held.fault_after_holdup.startswith("the loop itself was held up 5.00 s (its cycle at t = 0.0075 s")
    assert run([k * period for k in range(400)]).fault_after_holdup == ""  # no hold-up
    # stopped inside its step: the deadlines skipped, the next cycle's t jumps 5 s; it faults then
    skipped = RunRecorder()
    for k, s in ((0, 0.0), (1, period), (2, 5.0 + period)):
        skipped.on_cycle(k, k * period, inputs, state, None, (), CycleTiming(0.0, 1e-4, s))
    skipped.on_cycle(
        2003, 2003 * period, inputs, state, None, (fault,), CycleTiming(0.0, 1e-4, 5.0 + 2 * period)
    )
    assert skipped.fault_after_holdup.startswith("the loop itself was held up 5.00 s")
    steps = int(HOLDUP_BLAME_S / period) + 2
    late = run([0.0, *(5.0 + k * period for k in range(steps))])  # the fault long after it
    assert late.fault_after_holdup == ""
