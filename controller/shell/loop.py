"""The thin loop shell around the pure step: sleep to the deadline, exchange, step, hand off.

Per cycle k, with deadline d_k = d_0 + k * period on a monotonic clock:
  1. sleep until d_k (``Sleeper``: coarse sleep, then a short spin);
  2. send the RPDOs computed in cycle k-1, then SYNC (the exchange);
  3. collect this cycle's TPDOs for collect_fraction * period after the SYNC went out (from
     the actual send time: a late wake-up must not shrink the drives' time to answer);
  4. ``law.step(state, inputs, k * period)``;
  5. hand copies to the observers (recorder, publisher, statistics): they must not block.
If the loop falls more than one period behind, it skips the missed deadlines (counted as
overruns) rather than running a burst of late cycles, as ros2_control's loop does.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from controller.core.control_law import ControlLaw, ControllerState, Mode
from controller.core.cycle_data import BusFeedback, Command, CycleInputs, CycleOutputs, Event, cycle_inputs


class Sleeper(Protocol):
    def sleep_until(self, deadline_s: float) -> None: ...


class Exchange(Protocol):
    def send(self, outputs: CycleOutputs | None) -> None: ...

    def collect(self, deadline_s: float) -> BusFeedback: ...


@dataclass(frozen=True, slots=True)
class CycleTiming:
    wake_error_s: float  # actual wake-up minus the deadline
    step_s: float  # compute time of law.step


class CycleObserver(Protocol):
    """Receives every cycle. Runs on the loop's thread: it must hand off and return in microseconds."""

    def on_cycle(self, cycle: int, t: float, inputs: CycleInputs, state: ControllerState,
                 outputs: CycleOutputs, events: tuple[Event, ...], timing: CycleTiming) -> None: ...


@dataclass
class LoopStats:
    """Timing of the run; arrays hold one entry per executed cycle."""

    period_s: float
    capacity: int
    wake_error_s: np.ndarray = field(init=False)  # actual wake-up minus deadline
    step_s: np.ndarray = field(init=False)  # compute time of law.step
    observers_s: np.ndarray = field(init=False)  # time spent handing the cycle to the observers
    deadline_index: np.ndarray = field(init=False)  # k of each executed cycle (skipped deadlines leave gaps)
    cycles: int = 0
    overruns: int = 0  # deadlines skipped because the loop fell behind
    started_s: float = 0.0
    finished_s: float = 0.0

    def __post_init__(self) -> None:
        self.wake_error_s = np.zeros(self.capacity)
        self.step_s = np.zeros(self.capacity)
        self.observers_s = np.zeros(self.capacity)
        self.deadline_index = np.zeros(self.capacity, dtype=np.int64)

    def record(self, wake_error_s: float, step_s: float, deadline_index: int) -> None:
        if self.cycles < self.capacity:
            self.wake_error_s[self.cycles] = wake_error_s
            self.step_s[self.cycles] = step_s
            self.deadline_index[self.cycles] = deadline_index
        self.cycles += 1

    def record_observers(self, observers_s: float) -> None:
        """Time of the observers of the cycle recorded last."""
        if 0 < self.cycles <= self.capacity:
            self.observers_s[self.cycles - 1] = observers_s

    @property
    def achieved_rate_hz(self) -> float:
        elapsed = self.finished_s - self.started_s
        return (self.cycles - 1) / elapsed if elapsed > 0 and self.cycles > 1 else 0.0

    def late_cycles(self, tolerance_fraction: float = 0.1) -> int:
        """Cycles that woke more than ``tolerance_fraction`` of a period after their deadline."""
        n = min(self.cycles, self.capacity)
        return int(np.count_nonzero(self.wake_error_s[:n] > tolerance_fraction * self.period_s)) + self.overruns

    def period_error_us(self) -> np.ndarray:
        """|actual period - nominal period| between consecutive wake-ups [us].

        Across skipped deadlines too: a cycle that stalled for 50 ms shows as a 47.5 ms error
        at 400 Hz, not as the small wake errors on either side of the gap.
        """
        n = min(self.cycles, self.capacity)
        return period_error_us(self.deadline_index[:n] * self.period_s + self.wake_error_s[:n], self.period_s)


def period_error_us(wake_s: np.ndarray, period_s: float) -> np.ndarray:
    """|actual - nominal period| between consecutive wake-ups [us], from wake times on one clock."""
    w = np.asarray(wake_s, dtype=float)
    if w.size < 2:
        return np.zeros(0)
    return np.abs(np.diff(w) - period_s) * 1e6


CommandSource = Callable[[], "tuple[str, float] | None"]  # one pending remote command, or None


class CycleLoop:
    def __init__(self, law: ControlLaw, exchange: Exchange, period_s: float, collect_fraction: float,
                 sleeper: Sleeper, clock: Callable[[], float] = time.monotonic,
                 observers: tuple[CycleObserver, ...] = (), stop_event: threading.Event | None = None,
                 commands: CommandSource | None = None, late_tolerance_s: float = float("inf")) -> None:
        self.law = law
        self.exchange = exchange
        self.period_s = period_s
        self.collect_s = collect_fraction * period_s
        self.sleeper = sleeper
        self.clock = clock
        self.observers = observers
        self.stop_event = stop_event or threading.Event()
        self.commands = commands
        self.late_tolerance_s = late_tolerance_s

    def run(self, state: ControllerState, max_duration_s: float, linger_after_end_s: float = 0.1,
            exit_on_fault: bool = True) -> tuple[ControllerState, LoopStats]:
        """Run until the law reaches DONE or FAULT (plus ``linger_after_end_s``) or the time is up.

        With ``exit_on_fault=False`` the loop keeps cycling in FAULT (quick stop held) so that a
        remote ``reset`` can recover, until the stop event is set.
        """
        period = self.period_s
        max_cycles = int(max_duration_s / period) + 1
        stats = LoopStats(period_s=period, capacity=max_cycles)
        clock = self.clock
        outputs: CycleOutputs | None = None
        first_deadline = clock() + period
        stats.started_s = first_deadline
        k = 0
        end_cycle: int | None = None
        linger = max(1, int(linger_after_end_s / period))
        while k < max_cycles:
            deadline = first_deadline + k * period
            self.sleeper.sleep_until(deadline)
            woke = clock()
            self.exchange.send(outputs)
            feedback = self.exchange.collect(clock() + self.collect_s)
            pending = self.commands() if self.commands is not None else None
            command, value = (Command(pending[0]), pending[1]) if pending is not None else (Command.NONE, 0.0)
            inputs = cycle_inputs(feedback, self.stop_event.is_set(), command, value,
                                  late=woke - deadline > self.late_tolerance_s)
            t = k * period
            c0 = clock()
            state, outputs, events = self.law.step(state, inputs, t)
            timing = CycleTiming(woke - deadline, clock() - c0)
            stats.record(timing.wake_error_s, timing.step_s, k)
            o0 = clock()
            for obs in self.observers:
                obs.on_cycle(k, t, inputs, state, outputs, events, timing)
            stats.record_observers(clock() - o0)
            ending = state.mode == Mode.DONE or (
                state.mode == Mode.FAULT and (exit_on_fault or self.stop_event.is_set()))
            if end_cycle is None and ending:
                end_cycle = k  # keep cycling a little so the last commands reach the drives
            elif end_cycle is not None and not ending:
                end_cycle = None  # recovered (a reset) before the end
            if end_cycle is not None and k - end_cycle >= linger:
                break
            k += 1
            behind = clock() - (first_deadline + k * period)
            if behind > period:
                skipped = int(behind / period)
                stats.overruns += skipped
                k += skipped
        stats.finished_s = clock()
        return state, stats


class SimulatedTime:
    """Clock and sleeper for runs in simulated time (tests, replay): sleeping jumps the clock."""

    def __init__(self, start_s: float = 0.0) -> None:
        self.now_s = start_s

    def clock(self) -> float:
        return self.now_s

    def sleep_until(self, deadline_s: float) -> None:
        self.now_s = max(self.now_s, deadline_s)
