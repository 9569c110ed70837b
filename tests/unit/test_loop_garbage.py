"""The loop collects garbage between cycles, never inside one, and says where its longest cycle went.

Simulated time and the in-process devices: deterministic, no wall clock. An observer that leaves
reference cycles behind stands for anything that makes garbage (a library, a late joiner).
"""

from __future__ import annotations

import gc

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange

GARBAGE_PER_CYCLE = 150  # reference cycles an observer leaves behind each cycle: a collection every ~5 cycles


class Phases:
    """Where the loop is: inside a cycle (from its send to the end of its last observer) or between."""

    def __init__(self) -> None:
        self.in_cycle = False
        self.collections_in_cycle = 0
        self.collections_between = 0
        self.collector_on_in_cycle: list[bool] = []

    def on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            if self.in_cycle:
                self.collections_in_cycle += 1
            else:
                self.collections_between += 1


class MarkingExchange:
    def __init__(self, inner: LoopbackExchange, phases: Phases) -> None:
        self.inner, self.phases = inner, phases

    def send(self, outputs, send_by_s=float("inf")):
        self.phases.in_cycle = True
        return self.inner.send(outputs, send_by_s)

    def collect(self, deadline_s):
        return self.inner.collect(deadline_s)


SLOW_CYCLE = 20  # the observer takes SLOW_OBSERVER_S of the clock in this cycle, 10 us in the others
SLOW_OBSERVER_S = 500e-6


class GarbageObserver:
    """Leaves ``GARBAGE_PER_CYCLE`` reference cycles each cycle, and ends the cycle's marking."""

    def __init__(self, phases: Phases, clock: SimulatedTime) -> None:
        self.phases, self.clock = phases, clock

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing) -> None:
        self.clock.now_s += SLOW_OBSERVER_S if cycle == SLOW_CYCLE else 10e-6
        self.phases.collector_on_in_cycle.append(gc.isenabled())
        for _ in range(GARBAGE_PER_CYCLE):
            a: list[object] = []
            a.append(a)
        self.phases.in_cycle = False


def _run(collect_garbage: bool, cycles: int = 300):
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = SimulatedTime()
    law = build_law(cfg)
    phases = Phases()
    exchange = MarkingExchange(LoopbackExchange(cfg, clock.clock), phases)
    loop = CycleLoop(
        law,
        exchange,
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        observers=(GarbageObserver(phases, clock),),
        collect_garbage=collect_garbage,
    )
    gc.callbacks.append(phases.on_gc)
    try:
        _, stats = loop.run(law.initial_state(), cycles * cfg.period_s)
    finally:
        gc.callbacks.remove(phases.on_gc)
    return phases, stats


@pytest.fixture(autouse=True)
def _collector_on():
    was = gc.isenabled()
    gc.enable()
    yield
    if not was:
        gc.disable()


def test_garbage_is_collected_between_cycles_only():
    phases, stats = _run(collect_garbage=True)
    assert phases.collections_in_cycle == 0
    assert not any(phases.collector_on_in_cycle)  # the automatic collector is off during the run
    # the garbage was collected all the same, by the loop, and counted
    assert phases.collections_between == stats.gc_collections > 0.5 * 300 * GARBAGE_PER_CYCLE / 700
    assert stats.gc_max_s >= 0.0
    assert gc.isenabled()  # given back as it was


def test_without_the_loop_s_collection_the_collector_strikes_inside_cycles():
    """The control: the same garbage with the automatic collector on lands in the cycles."""
    phases, stats = _run(collect_garbage=False)
    assert phases.collections_in_cycle > 0
    assert stats.gc_collections == 0


def test_the_longest_cycle_is_kept_with_its_parts():
    _, stats = _run(collect_garbage=True, cycles=50)
    longest = stats.longest_cycle
    assert set(longest) == {
        "cycle",
        "span_s",
        "wake_error_s",
        "send_s",
        "window_s",
        "collect_over_s",
        "inputs_s",
        "step_s",
        "after_step_s",
        "observers_s",
        "gc_s",
    }
    assert longest["cycle"] == SLOW_CYCLE
    assert longest["observers_s"] == pytest.approx(SLOW_OBSERVER_S)
    assert longest["span_s"] == pytest.approx(SLOW_OBSERVER_S)  # nothing else takes simulated time
    ring = stats.last_cycles()
    assert len(ring["send_s"]) == len(ring["collect_over_s"]) == stats.cycles
