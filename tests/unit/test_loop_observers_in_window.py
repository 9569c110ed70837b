"""Over a bus the loop hands cycle k to its observers inside cycle k+1's answer window.

Simulated time and the in-process devices: deterministic, no wall clock. A stand-in exchange and
observer write one shared log of what happened in which order.
"""

from __future__ import annotations

import contextlib

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange

CYCLES = 200


class LoggingExchange:
    def __init__(self, inner: LoopbackExchange, log: list[tuple[str, int]]) -> None:
        self.inner, self.log, self.sends = inner, log, 0

    def send(self, outputs, send_by_s=float("inf")):
        self.log.append(("send", self.sends))
        self.sends += 1
        return self.inner.send(outputs, send_by_s)

    def collect(self, deadline_s):
        self.log.append(("collect", self.sends - 1))
        return self.inner.collect(deadline_s)


class LoggingObserver:
    """Logs each cycle it sees; ``cost_s`` of the clock per call; what it saw, for comparison."""

    def __init__(self, log: list[tuple[str, int]], clock: SimulatedTime, cost_s: float = 0.0) -> None:
        self.log, self.clock, self.cost_s = log, clock, cost_s
        self.seen: list[tuple] = []

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing) -> None:
        self.clock.now_s += self.cost_s
        self.log.append(("observe", cycle))
        self.seen.append((cycle, t, inputs, state, outputs, events, timing.wake_error_s))


class FailingLaw:
    """The real law, raising in the step of cycle ``fail_at``."""

    def __init__(self, law, fail_at: int) -> None:
        self.law, self.fail_at, self.cycles = law, fail_at, 0

    def step(self, state, inputs, t):
        if self.cycles == self.fail_at:
            raise RuntimeError("a step that fails")
        self.cycles += 1
        return self.law.step(state, inputs, t)


def _run(in_window: bool, cost_s: float = 0.0, fail_at: int | None = None, plans_ready=None, clock=None):
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = clock or SimulatedTime()
    law = build_law(cfg)
    log: list[tuple[str, int]] = []
    exchange = LoggingExchange(LoopbackExchange(cfg, clock.clock), log)
    observer = LoggingObserver(log, clock, cost_s)
    loop = CycleLoop(
        law if fail_at is None else FailingLaw(law, fail_at),
        exchange,
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        observers=(observer,),
        observers_in_window=in_window,
        plans_ready=plans_ready,
    )
    stats = None
    with contextlib.suppress(RuntimeError):
        _, stats = loop.run(law.initial_state(), CYCLES * cfg.period_s)
    return log, observer, stats


def test_each_cycle_is_observed_once_between_the_next_cycle_s_send_and_its_collect():
    log, observer, _ = _run(in_window=True)
    cycles = [c for what, c in log if what == "observe"]
    assert cycles == sorted(set(cycles)) and len(cycles) == len(observer.seen) > CYCLES
    for k in cycles[:-1]:
        i = log.index(("observe", k))
        assert log[i - 1] == ("send", k + 1) and log[i + 1] == ("collect", k + 1)
    assert log[-1] == ("observe", cycles[-1])  # the last one, after the loop: nothing after it


def test_the_observers_see_what_they_see_right_after_the_step():
    """The same cycles, inputs, states, outputs and events in either order: only when differs."""
    _, in_window, _ = _run(in_window=True)
    _, after_step, _ = _run(in_window=False)
    assert in_window.seen == after_step.seen


def test_observers_in_the_window_do_not_lengthen_the_cycle_s_work():
    """0.3 ms of observers a cycle: after the step they are part of the work the next windows make
    room for; in the window they are not, and the windows stay where collect_fraction puts them."""
    cost_s = 300e-6
    _, _, stats_after = _run(in_window=False, cost_s=cost_s)
    _, _, stats_in = _run(in_window=True, cost_s=cost_s)
    assert stats_after is not None and stats_in is not None
    assert stats_in.observers_s[100] == pytest.approx(cost_s)  # measured, for the cycle observed
    assert stats_in.longest_cycle["observers_s"] == pytest.approx(cost_s)  # and inside the next one
    assert stats_in.late_cycles() == stats_after.late_cycles() == 0


def test_a_step_that_fails_leaves_the_cycle_before_it_observed():
    """Nothing observed so far is lost: the cycle waiting for the next answer window is observed
    on the way out, as it would have been right after its step."""
    log, _observer, stats = _run(in_window=True, fail_at=50)
    assert stats is None  # the error went up
    assert [c for what, c in log if what == "observe"] == list(range(50))


def test_observers_that_run_past_the_window_are_not_counted_again_as_the_collect_s():
    """The longest cycle's parts do not overlap: observers that end past the answer window's end hold
    the collect back, and that time is theirs, not the collect's (an outside tester's summary read
    "collect past window 5.39 ms, observers 6.94 ms" in a cycle of 7.7 ms)."""
    cost_s = 2.4e-3  # past the window's end: 2 ms after the deadline at 400 Hz (loop.collect_fraction)
    _, _, stats = _run(in_window=True, cost_s=cost_s)
    assert stats is not None
    longest = stats.longest_cycle
    assert longest["observers_s"] == pytest.approx(cost_s)
    assert sum(longest[p] for p in PARTS) == pytest.approx(longest["span_s"], abs=1e-9)
    assert longest["collect_over_s"] == pytest.approx(0.0, abs=1e-9)  # the collect itself took no time


PARTS = ("send_s", "window_s", "observers_s", "collect_over_s", "inputs_s", "step_s", "after_step_s", "gc_s")


@pytest.mark.parametrize("in_window", [True, False])
def test_the_longest_cycle_s_parts_add_up_to_its_span(in_window):
    """A hold-up between the named parts is named too: 3 ms held up while the loop gathers the
    step's inputs (here in the planner's progress it reads) shows as the inputs' part, and the
    parts, the answer window's wait among them, add up to the cycle (a `make demo`'s longest cycle
    of 9.0 ms had 0.4 ms in the parts named before)."""
    held_s, slow_call = 3e-3, 120
    clock = SimulatedTime()
    calls = iter(range(10**6))

    def plans_ready() -> int:
        if next(calls) == slow_call:
            clock.hold_up(held_s)
        return 0

    _, _, stats = _run(in_window=in_window, cost_s=100e-6, plans_ready=plans_ready, clock=clock)
    assert stats is not None
    longest = stats.longest_cycle
    assert longest["inputs_s"] == pytest.approx(held_s)
    assert longest["observers_s"] == pytest.approx(100e-6)
    assert sum(longest[p] for p in PARTS) == pytest.approx(longest["span_s"], abs=1e-9)
    assert all(longest[p] >= 0.0 for p in PARTS)
