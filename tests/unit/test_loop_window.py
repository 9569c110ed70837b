"""Where the loop's answer window closes: after the deadline, and before the cycle's own work.

A fake clock that the step advances (a costly step), a stand-in exchange that records each
window's end: deterministic, no wall clock.
"""

from __future__ import annotations

import itertools

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import WINDOW_MARGIN_S, CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange

PERIOD_S = 0.0025
COLLECT_FRACTION = 0.8


class RecordingExchange:
    """The loopback devices, with every window's end recorded relative to its deadline."""

    def __init__(self, inner: LoopbackExchange, clock: SimulatedTime) -> None:
        self.inner, self.clock, self.ends_after_send_s = inner, clock, []

    def send(self, outputs, send_by_s=float("inf")):
        self.sent_s = self.clock.now_s
        return self.inner.send(outputs, send_by_s)

    def collect(self, deadline_s):
        self.ends_after_send_s.append(deadline_s - self.sent_s)
        return self.inner.collect(deadline_s)


class CostlyLaw:
    """The real law, whose step takes ``cost_s`` of the clock from cycle ``from_cycle`` on."""

    def __init__(self, law, clock: SimulatedTime, cost_s: float, from_cycle: int) -> None:
        self.law, self.clock, self.cost_s, self.from_cycle, self.cycles = law, clock, cost_s, from_cycle, 0

    def step(self, state, inputs, t):
        self.cycles += 1
        if self.cycles >= self.from_cycle:
            self.clock.now_s += self.cost_s
        return self.law.step(state, inputs, t)


def _windows(cost_s: float, cycles: int = 400) -> list[float]:
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = RecordingExchange(LoopbackExchange(cfg, clock.clock), clock)
    loop = CycleLoop(
        CostlyLaw(law, clock, cost_s, 50), exchange, PERIOD_S, COLLECT_FRACTION, clock, clock.clock
    )
    loop.run(law.initial_state(), cycles * PERIOD_S)
    return exchange.ends_after_send_s


def test_a_cheap_step_leaves_the_window_where_collect_fraction_puts_it():
    ends = _windows(0.0)
    assert ends[100] == pytest.approx(COLLECT_FRACTION * PERIOD_S)


def test_a_costly_step_shortens_the_next_windows_so_that_the_cycle_still_ends_in_its_period():
    """A 0.7-ms step after a 2-ms window would end every cycle 0.2 ms into the next: the windows
    close before the next deadline minus the step's recent peak and the margin, and the loop keeps
    its deadlines (the wake-ups are on time: the clock never passes a deadline before the sleep)."""
    cost_s = 0.0007
    ends = _windows(cost_s)
    assert ends[20] == pytest.approx(COLLECT_FRACTION * PERIOD_S)  # before the costly steps
    assert ends[100] == pytest.approx(PERIOD_S - cost_s - WINDOW_MARGIN_S)
    assert max(ends[60:]) <= PERIOD_S - cost_s - WINDOW_MARGIN_S + 1e-12


class DrainingExchange(RecordingExchange):
    """An exchange that reads its answers after the window's end, taking ``drain_s`` of the clock
    from cycle ``from_cycle`` on (one that sleeps through its window: drivers/cyclic_exchange.py)."""

    def __init__(
        self, inner: LoopbackExchange, clock: SimulatedTime, drain_s: float, from_cycle: int
    ) -> None:
        super().__init__(inner, clock)
        self.drain_s, self.from_cycle = drain_s, from_cycle

    def collect(self, deadline_s):
        feedback = super().collect(deadline_s)
        self.clock.now_s = max(self.clock.now_s, deadline_s)
        if len(self.ends_after_send_s) >= self.from_cycle:
            self.clock.now_s += self.drain_s
        return feedback


def test_reading_the_answers_after_the_window_shortens_the_next_windows_as_a_costly_step_does():
    """0.7 ms of reading after a 2-ms window would end every cycle 0.2 ms into the next: the work
    the loop leaves room for counts from the window's end, the reading included."""
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = SimulatedTime()
    law = build_law(cfg)
    drain_s = 0.0007
    exchange = DrainingExchange(LoopbackExchange(cfg, clock.clock), clock, drain_s, 50)
    loop = CycleLoop(law, exchange, PERIOD_S, COLLECT_FRACTION, clock, clock.clock)
    _, stats = loop.run(law.initial_state(), 400 * PERIOD_S)
    ends = exchange.ends_after_send_s
    assert ends[20] == pytest.approx(COLLECT_FRACTION * PERIOD_S)
    assert ends[100] == pytest.approx(PERIOD_S - drain_s - WINDOW_MARGIN_S)
    assert stats.overruns <= 1  # the first drained cycle, before the loop knew of the reading


def test_the_service_sleeps_through_the_window_at_400_hz_and_slower_and_reads_as_frames_come_above():
    from controller.shell.service import sleeps_through_window

    assert [sleeps_through_window(1 / rate) for rate in (100, 250, 400, 500, 1000)] == [
        True,
        True,
        True,
        False,
        False,
    ]


class DeadlineExchange(RecordingExchange):
    """An exchange that wants each cycle's deadline (``CycleDeadlines``: the kernel SYNC's)."""

    def __init__(self, inner: LoopbackExchange, clock: SimulatedTime) -> None:
        super().__init__(inner, clock)
        self.deadlines: list[float] = []
        self.told_before_send: list[bool] = []

    def cycle_deadline(self, deadline_s: float) -> None:
        self.deadlines.append(deadline_s)

    def send(self, outputs, send_by_s=float("inf")):
        self.told_before_send.append(len(self.deadlines) == len(self.told_before_send) + 1)
        return super().send(outputs, send_by_s)


def test_the_loop_tells_an_exchange_that_wants_it_each_cycle_s_deadline_before_its_send():
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = SimulatedTime(start_s=5.0)
    law = build_law(cfg)
    exchange = DeadlineExchange(LoopbackExchange(cfg, clock.clock), clock)
    # a step that costs 1.5 periods from cycle 10: the loop skips deadlines, the grid stays
    loop = CycleLoop(
        CostlyLaw(law, clock, 1.5 * PERIOD_S, 10), exchange, PERIOD_S, COLLECT_FRACTION, clock, clock.clock
    )
    loop.run(law.initial_state(), 40 * PERIOD_S)
    assert all(exchange.told_before_send) and len(exchange.deadlines) > 10
    slots = [(d - exchange.deadlines[0]) / PERIOD_S for d in exchange.deadlines]
    assert all(s == pytest.approx(round(s)) for s in slots)  # every deadline on the loop's grid
    assert any(b - a > 1.5 for a, b in itertools.pairwise(slots))  # and skipped cycles skip their slots


def test_the_sleeper_counts_the_time_it_spins():
    """What the bench subtracts from the loop's CPU use: the spin before each deadline, on the clock."""
    from drivers.pacing import DeadlineSleeper

    now = [0.0]

    def clock() -> float:
        now[0] += 10e-6  # every read takes 10 us of this clock
        return now[0]

    sleeper = DeadlineSleeper(spin_s=1.0, clock=clock)  # the deadline is within the spin: no sleep
    sleeper.sleep_until(1e-3)
    assert now[0] >= 1e-3
    assert sleeper.spun_s == pytest.approx(1e-3, abs=30e-6)
    sleeper.sleep_until(now[0] - 1.0)  # a deadline already past: no spin
    assert sleeper.spun_s == pytest.approx(1e-3, abs=30e-6)
