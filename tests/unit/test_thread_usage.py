"""The loop says whether its longest cycle's work was work, or waiting for another thread.

Simulated time for the loop's clock, and the loop thread's real usage (``getrusage``): the
work is held up at one cycle, by a lock that another thread holds, or by the CPU's own work.
What is asserted is the thread's CPU time and context switches, never the wall clock.
"""

from __future__ import annotations

import mmap
import threading
import time

import pytest

from controller.cli import _longest_cycle_line
from controller.config import load_config
from controller.shell.run_summary import _longest_cycle_us
from controller.shell.simulated_rig import SimulatedRig
from controller.shell.thread_usage import thread_usage_readers
from controller.tools.bench.report import _longest

SLOW_CALL = 50  # the call of plans_ready (one a cycle) that is held up
CYCLES = 120


def _run(hold_up, read_usage=True):
    """Cycles whose step's inputs (the planner's progress) are held up by ``hold_up()`` once."""
    rig = SimulatedRig(load_config(overrides={"recording.enabled": False, "monitoring.enabled": False}))
    calls = iter(range(10**6))

    def plans_ready() -> int:
        if next(calls) == SLOW_CALL:
            rig.clock.hold_up(1e-3)  # the longest cycle of the run, on the loop's clock
            hold_up()
        return 0

    loop = rig.loop(plans_ready=plans_ready, thread_usage=thread_usage_readers() if read_usage else None)
    _, stats = loop.run(rig.law.initial_state(), CYCLES * rig.cfg.period_s)
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
    assert longest["waits"] >= 1
    # 50 ms blocked in the work, and it was not on the CPU for them
    assert longest["on_cpu_s"] < 0.05


def test_work_that_is_work_is_on_its_cpu_and_does_not_wait():
    def spin() -> None:
        start = time.thread_time()
        while time.thread_time() - start < 0.02:  # 20 ms of the thread's own CPU time
            pass

    longest = _run(spin)
    assert longest["on_cpu_s"] >= 0.02
    # a spin blocks on nothing (a thread of the test runner that wants the interpreter lock can
    # take a turn, 5 ms apart at the least: not 4 times in 20 ms)
    assert longest["waits"] < 4


def test_work_shorter_than_a_scheduler_tick_is_counted():
    """0.3 ms of work that reads no CPU clock itself: getrusage's CPU time of a running thread
    stands where the scheduler last counted (a tick: 4 ms on this guest), and a first version
    that read it showed 0 µs for 200-600 µs of a demo's work. (A spin on the thread's CPU clock
    would hide that: reading it brings the count up to date.)"""

    def spin() -> None:
        start = time.monotonic()
        while time.monotonic() - start < 0.3e-3:
            pass

    longest = _run(spin)
    assert longest["on_cpu_s"] > 0.0  # the spin ran, however often it was preempted


def test_memory_first_touched_in_the_cycle_counts_its_page_faults():
    pages = 256
    kept: list[mmap.mmap] = []

    def touch() -> None:
        # fresh anonymous pages, not yet touched (a bytearray may come from memory malloc reuses)
        memory = mmap.mmap(-1, pages * mmap.PAGESIZE)
        for page in range(pages):
            memory[page * mmap.PAGESIZE] = 1  # one write a page
        kept.append(memory)

    longest = _run(touch)
    for memory in kept:
        memory.close()
    assert longest["page_faults"] >= pages // 2  # the kernel may map some in larger pieces


def test_in_simulated_time_nothing_is_read_and_nothing_said():
    longest = _run(lambda: None, read_usage=False)
    assert longest["inputs_s"] == pytest.approx(1e-3)  # the hold-up, on the loop's clock
    assert not any(k in ("on_cpu_s", "waits", "preemptions") for k in longest)


def test_the_summary_keeps_counts_as_counts_and_times_in_microseconds():
    summary = _longest_cycle_us({"cycle": 7.0, "span_s": 0.0025, "waits": 3.0, "on_cpu_s": 1e-4})
    assert summary == {"cycle": 7, "span": 2500.0, "waits": 3, "on_cpu": 100.0}


LONGEST = {
    "cycle": 5099,
    "span": 8075.6,
    "wake_error": 0.8,
    "send": 183.5,
    "collect_over": 244.8,
    "step": 427.8,
    "observers": 7170.6,
    "gc": 0.0,
    "window": 15.2,
    "inputs": 14.5,
    "after_step": 19.3,
    "on_cpu": 1345.4,
    "waits": 0,
    "preemptions": 0,
    "page_faults": 0,
}  # a demo's beside two CPU hogs (2026-12-07): 8.06 ms awake, 1.35 on its CPU, no switch, no fault


def test_the_summary_line_says_how_much_of_the_cycle_was_on_its_cpu():
    line = _longest_cycle_line(
        {"longest_cycle_us": LONGEST, "garbage_collections": {"count": 0, "max_us": 0}}
    )
    assert "window 15," in line and "observers 7171," in line and "after step 19," in line
    assert (
        "awake 8060 us (all but the window's wait), 1345 on its CPU, 0 wait(s) (the window's sleep among"
        " them), 0 preemption(s), 0 page fault(s)" in line
    )


def test_the_bench_names_a_part_of_the_time_as_the_largest_not_the_usage():
    assert _longest({**LONGEST, "on_cpu": 9000.0, "page_faults": 9000}) == "8076 (observers 7171)"
