"""A stop ends a process whose loop no longer cycles (controller/shell/stuck_loop.py).

An outside tester's task blocked inside its step: ``cheope stop``, SIGTERM, SIGINT and a second
SIGTERM were ignored, only SIGKILL ended the process. The guard is tested with a stand-in for the
process's end, a counter for the loop's cycles and a clock of its own: no wall-clock assertion,
each wait on an event with a generous bound."""

from __future__ import annotations

import threading

from stepping_clock import SteppingClock

from controller.shell.stuck_loop import StuckLoopGuard


def _guard_clock() -> SteppingClock:
    """Each reading 0.5 s after the last: the guard's notion of time, moved by its own polls."""
    return SteppingClock(0.5)


def test_a_stop_with_a_loop_that_completes_no_cycle_ends_the_process_with_1():
    stop, quick, ended, done = threading.Event(), threading.Event(), [], threading.Event()

    def end_process(code: int) -> None:
        ended.append(code)
        done.set()

    with StuckLoopGuard(lambda: 7, stop, quick, 10.0, 0.0025, end_process=end_process, clock=_guard_clock()):
        stop.set()
        assert done.wait(30.0)
    assert ended == [1]


def test_a_second_signal_ends_a_stuck_loop_sooner_than_the_stop_timeout():
    stop, quick, ended, done = threading.Event(), threading.Event(), [], threading.Event()
    clock = _guard_clock()

    def end_process(code: int) -> None:
        ended.append(clock.now_s)
        done.set()

    with StuckLoopGuard(lambda: 7, stop, quick, 1e9, 0.0025, end_process=end_process, clock=clock):
        stop.set()
        quick.set()
        assert done.wait(30.0)
    assert ended and ended[0] <= 3.0  # 1 s of its clock (a few polls), not the 1e9-s stop timeout


def test_a_loop_that_cycles_after_the_stop_or_returns_is_left_alone():
    stop, quick, ended, cycles = threading.Event(), threading.Event(), [], [0]
    polled = threading.Event()

    def counting() -> int:
        cycles[0] += 1  # a cycle between any two looks: braking as it should
        if cycles[0] > 30:
            polled.set()
        return cycles[0]

    with StuckLoopGuard(counting, stop, quick, 10.0, 0.0025, end_process=ended.append, clock=_guard_clock()):
        stop.set()
        assert polled.wait(60.0)
    assert ended == []  # and the loop's return (the with's end) stopped the guard


def test_a_slow_loop_is_not_taken_for_a_stuck_one_after_a_second_signal():
    """At 1 Hz a cycle comes every second: the 1-s grace after a second signal alone ended a loop
    that was braking as it should (the reviewer's finding); three periods are allowed at least."""
    stop, quick, ended, looks = threading.Event(), threading.Event(), [], [0]
    polled = threading.Event()

    def one_cycle_every_1_5_s() -> int:  # the clock moves 0.5 s a look: a cycle every third look
        looks[0] += 1
        if looks[0] > 30:
            polled.set()
        return looks[0] // 3

    with StuckLoopGuard(
        one_cycle_every_1_5_s, stop, quick, 10.0, 1.0, end_process=ended.append, clock=_guard_clock()
    ):
        stop.set()
        quick.set()
        assert polled.wait(60.0)
    assert ended == []
