"""The loop says whether its longest cycle's work was work, or waiting for another thread.

Simulated time for the loop's clock, and the loop thread's real usage (``getrusage``): the
work is held up at one cycle, by a lock that another thread holds, or by the CPU's own work.
What is asserted is the thread's CPU time and context switches, never the wall clock.
"""

from __future__ import annotations

import threading
import time

import pytest

from controller.assembly import build_law
from controller.cli import _longest_cycle_line
from controller.config import load_config
from controller.shell.loop import CycleLoop, SimulatedTime
from controller.shell.run_summary import _longest_cycle_us
from controller.shell.thread_usage import no_usage, thread_usage_reader
from controller.tools.bench.report import _longest
from sim_backend.loopback import LoopbackExchange

SLOW_CALL = 50  # the call of plans_ready (one a cycle) that is held up
CYCLES = 120


def _run(hold_up, reader=None):
    """Cycles whose step's inputs (the planner's progress) are held up by ``hold_up(clock)`` once."""
    cfg = load_config(overrides={"recording.enabled": False, "monitoring.enabled": False})
    clock = SimulatedTime()
    law = build_law(cfg)
    calls = iter(range(10**6))

    def plans_ready() -> int:
        if next(calls) == SLOW_CALL:
            clock.hold_up(1e-3)  # the longest cycle of the run, on the loop's clock
            hold_up()
        return 0

    loop = CycleLoop(
        law,
        LoopbackExchange(cfg, clock.clock),
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        plans_ready=plans_ready,
        thread_usage=reader if reader is not None else thread_usage_reader(),
    )
    _, stats = loop.run(law.initial_state(), CYCLES * cfg.period_s)
    return stats.longest_cycle


def test_work_that_waits_for_a_lock_another_thread_holds_counts_the_waits():
    lock, holding, release = threading.Lock(), threading.Event(), threading.Event()

    def holder() -> None:
        with lock:
            holding.set()
            release.wait(10.0)

    other = threading.Thread(target=holder)
    other.start()
    holding.wait(10.0)

    def wait_for_the_lock() -> None:
        threading.Timer(0.05, release.set).start()
        with lock:  # blocks: the holder lets go when the timer fires
            pass

    try:
        longest = _run(wait_for_the_lock)
    finally:
        release.set()
        other.join(10.0)
    assert longest["work_waits"] >= 1
    # 50 ms blocked in the work, and it was not on the CPU for them
    assert longest["work_on_cpu_s"] < 0.05


def test_work_that_is_work_is_on_its_cpu_and_does_not_wait():
    def spin() -> None:
        start = time.thread_time()
        while time.thread_time() - start < 0.02:  # 20 ms of the thread's own CPU time
            pass

    longest = _run(spin)
    assert longest["work_on_cpu_s"] >= 0.02
    # a spin blocks on nothing (a thread of the test runner that wants the interpreter lock can
    # take a turn, 5 ms apart at the least: not 4 times in 20 ms)
    assert longest["work_waits"] < 4


def test_in_simulated_time_nothing_is_read_and_nothing_said():
    longest = _run(lambda: None, reader=no_usage)
    assert longest["inputs_s"] == pytest.approx(1e-3)  # the hold-up, on the loop's clock
    assert not any(k.startswith("work_") for k in longest)


def test_the_summary_keeps_counts_as_counts_and_times_in_microseconds():
    summary = _longest_cycle_us({"cycle": 7.0, "span_s": 0.0025, "work_waits": 3.0, "work_on_cpu_s": 1e-4})
    assert summary == {"cycle": 7, "span": 2500.0, "work_waits": 3, "work_on_cpu": 100.0}


LONGEST = {
    "cycle": 11997,
    "span": 3957.4,
    "wake_error": 0.5,
    "send": 76.1,
    "window": 1836.8,
    "collect_over": 182.0,
    "inputs": 1337.0,
    "step": 442.0,
    "after_step": 18.7,
    "observers": 64.8,
    "gc": 0.0,
    "work_on_cpu": 226.0,
    "work_waits": 0,
    "work_preemptions": 0,
}  # a demo's (2026-12-07), the work 1 798 us of which 226 on its CPU, without a switch


def test_the_summary_line_says_how_much_of_the_work_was_on_its_cpu():
    line = _longest_cycle_line(
        {"longest_cycle_us": LONGEST, "garbage_collections": {"count": 0, "max_us": 0}}
    )
    assert "window 1837" in line and "inputs 1337" in line and "after step 19" in line
    assert "of its inputs, step and after step 1798 us, 226 on its CPU, 0 wait(s), 0 preemption(s)" in line


def test_the_bench_names_a_part_of_the_time_as_the_largest_not_the_usage():
    assert _longest({**LONGEST, "work_on_cpu": 5000.0}) == "3957 (window 1837)"
