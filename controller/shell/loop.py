"""The thin loop shell around the pure step: sleep to the deadline, exchange, step, hand off.

Per cycle k, with deadline d_k = d_0 + k * period on a monotonic clock:
  1. sleep until d_k (``Sleeper``: coarse sleep, then a short spin);
  2. send the RPDOs computed in cycle k-1, then SYNC (the exchange);
  3. collect this cycle's TPDOs until collect_fraction * period after the deadline (the answer
     window: the exchange listens to its end even when every device has answered, to see a second
     sender). From the deadline, not from the actual send: a window from the send carried every
     late wake-up into the next cycle (2 ms of 2.5 left 0.3 ms to catch up per cycle, and a soak
     at the defaults faulted on 50 late cycles in a row within 30 s). A late wake-up still gives
     the devices half the window after its SYNC. And the window leaves the cycle's own work its
     time: it ends at the latest ``work_peak`` (the recent peak of the time from the window's end
     to the end of the cycle's work, halving every second: the reading of the answers, which an
     exchange that sleeps through the window does after it, the step, and the observers when they
     run after it) plus ``WINDOW_MARGIN_S`` before the next deadline. Without it the contour task's
     step and observers (0.44 + 0.19 ms at their medians on this machine) after a 2-ms window
     overran the 2.5-ms period: the next wake-up was late in 35-77 % of a demo's cycles;
  4. ``law.step(state, inputs, k * period)``;
  5. hand copies to the observers (recorder, publisher, statistics): they must not block. Over a
     bus (``observers_in_window``) cycle k's observers run in cycle k+1, between its send and its
     collect: inside the answer window, where the loop only waits for frames that the socket
     buffers anyway. Their 0.06-0.16 ms after the step made the 1-kHz cycle's work longer than
     the time left after the window; in the window they cost the cycle nothing until they take
     longer than it. In simulated time nothing waits in the window, and the observers run right
     after the step (an observer that reads the in-process simulator sees it at this cycle's SYNC);
  6. collect garbage, when there is any to collect, here and nowhere else (``collect_garbage``).
If the loop falls more than one period behind, it skips the missed deadlines (counted as
overruns) rather than running a burst of late cycles, as ros2_control's loop does: a wake-up
more than a period late runs as the cycle of the latest deadline passed, and a cycle whose work
overran goes on at the next deadline still ahead. The first cycle after skipped deadlines sends
its SYNC without RPDOs: the last step's targets were meant for a SYNC that is gone, and the
drives run on without them as the next step expects (control_law ``_after_hold_up``).

A hold-up can also strike after the wake-up's clock reading and before the frames go out: the
loop cannot see it, and a SYNC sent then with the last step's targets pulled drives that had
run on back to them (a force step of 10.5 N beside two CPU hogs). So the exchange decides, from
its own clock reading just before the RPDOs go out: past ``send_by_s`` (the next deadline) it
sends the SYNC without them and says so, and the loop runs the cycle as the latest deadline's,
as after a late wake-up (``LoopStats.syncs_held_up``). The exchange also sends a SYNC without the
targets when it goes more than 1.5 periods after the SYNC before (a wake-up 2.4 ms late of 2.5,
after one on time): drives that take the commanded speed from the time between their targets
would read half of it and, should deadlines be skipped next, run on at that speed
(drivers/cyclic_exchange.py ``targets_sync_gap_s``). That cycle keeps its deadline; the step is
told its SYNC went without them (``CycleInputs.targets_withheld``, ``LoopStats.targets_withheld``)
and counts the period as one the drives ran on blind.

Garbage collection. CPython's collector runs whenever the young generation has grown by its
threshold (700 tracked objects), inside whatever allocation crosses it: in the middle of a
step, where a full collection once took 31 ms (path task, simulated time). During ``run`` the
automatic collector is off (``gc.disable``) and the loop collects after the cycle's observers,
when the cycle's outputs are ready and only the sleep to the next deadline is left, the
generation CPython would have chosen. A cycle in its steady state allocates as many tracked
objects as it frees (``cheope bench --work`` counts them), so these collections are rare; each is
counted and timed (``LoopStats.gc_collections``, ``gc_max_s``).

Where the time of a long cycle went: each cycle's send, its collect past the window's end, its
step and its observers are kept in the ring beside its wake-up error, and the longest cycle of
the run (wake-up to the end of its work) with its parts (``LoopStats.longest_cycle``; its
``observers_s`` are those that ran inside it: the cycle before's, in the answer window), and the
time between them (``CycleMarks``: the window's wait, the step's inputs, the bookkeeping after
the step), so that the parts add up to the span: a cycle stalled by something beside the loop
shows which part of it waited. Over a bus the loop thread's own usage over that cycle says
whether it waited, was preempted, or was off its CPU without either: the host
(``controller/shell/thread_usage.py``).
"""

from __future__ import annotations

import gc
import math
import resource
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from controller.core.control_law import ControlLaw
from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import BusFeedback, Command, CycleInputs, CycleOutputs, Event, cycle_inputs
from controller.core.periods import DEADLINE_ROUNDING_S
from controller.core.ports import CycleObserver, CycleTiming
from controller.shell.streaming_stats import LogHistogram
from controller.shell.thread_usage import ThreadUsageReaders, UsageBetween

# The answer window closes at least this long, plus the cycle's own recent work, before the next
# deadline: room for the sleeper to start its coarse sleep and spin before it.
WINDOW_MARGIN_S = 100e-6
WORK_PEAK_HALF_LIFE_S = 1.0  # the work peak forgets a slow cycle in seconds, not in one cycle


class Sleeper(Protocol):
    def sleep_until(self, deadline_s: float) -> None: ...


class Exchange(Protocol):
    def send(self, outputs: CycleOutputs | None, send_by_s: float = math.inf) -> bool:
        """RPDOs of ``outputs``, then SYNC. When its clock reads past ``send_by_s`` just before the
        RPDOs would go out, the SYNC goes without them and it returns False (module text)."""
        ...

    def collect(self, deadline_s: float) -> BusFeedback: ...


@runtime_checkable
class SdoControlwords(Protocol):
    """An exchange that can also write a drive's controlword by SDO (drivers/cyclic_exchange.py)."""

    def send_controlword_by_sdo(self, drive_index: int, controlword: int) -> None: ...


@runtime_checkable
class CycleDeadlines(Protocol):
    """An exchange that is told each cycle's deadline before its send: with SYNC from the kernel
    (drivers/kernel_sync.py) the SYNC comes on the loop's grid, not at the send, which may be late."""

    def cycle_deadline(self, deadline_s: float) -> None: ...


DEFAULT_RING_CYCLES = 4096  # about 10 s at 400 Hz of per-cycle timing kept as it was measured
# The ring goes into the histograms this many cycles at a time. The whole ring at once took about
# 1 ms inside a cycle every 4 096 cycles (0.4 ms back to back): at 1 kHz 49 of a run's 144 late
# cycles came within 4 cycles after one of those folds (the contour, `cheope bench`, 60 s); 256
# cycles take 70 us back to back.
DEFAULT_FOLD_CYCLES = 256


def _nothing() -> None:
    """What the loop reads of its thread's usage in simulated time: nothing."""
    return None


class CycleMarks(NamedTuple):
    """A cycle's clock readings between its named parts [s]: what the longest cycle's time between
    them is taken from (``LoopStats.record_span``), so that its parts add up to its span. A cycle of
    9.0 ms whose send, collect past the window, step and observers came to 0.4 ms (a `make demo`)
    had ~6.6 ms that nothing in its summary named."""

    sent: float  # the send's end
    collect_from: float  # the window's end, or the observers' when they ran past it
    collected: float  # the collect's return
    stepping: float  # the step's call, after its inputs were gathered
    stepped: float  # the step's return
    worked: float  # the cycle's end, before a collection
    observers_in_window: bool  # the observers ran in the window (else after the step)
    usage_cpu_s: float | None  # the loop thread's CPU time at the wake-up ...
    usage_switches: resource.struct_rusage | None  # ... and its context switches (thread_usage.py)
    readers: ThreadUsageReaders | None  # what read them, to read their end (None: simulated time)

    def gaps(self, observers_s: float) -> dict[str, float]:
        """The time between the named parts: the window's wait (less the observers in it), the
        step's inputs (the command, the plans), and the bookkeeping after the step (SDOs, the ring);
        and, where the thread's usage was read, over the cycle (from its wake-up): the thread's CPU
        time, and how often it waited (the window's sleep is one) or was preempted."""
        in_window = observers_s if self.observers_in_window else 0.0
        gaps = {
            "window_s": min(self.collected, self.collect_from) - self.sent - in_window,
            "inputs_s": self.stepping - self.collected,
            "after_step_s": self.worked - self.stepped - (observers_s - in_window),
        }
        if self.readers is not None and self.usage_cpu_s is not None and self.usage_switches is not None:
            # from the wake-up to now (the cycle's end): asleep in the window (a wait), else on the
            # CPU, or waiting, or off it without knowing
            gaps |= UsageBetween.since(self.usage_cpu_s, self.usage_switches, self.readers)._asdict()
        return gaps


@dataclass
class LoopStats:
    """Timing of the run in bounded memory: the last ``ring_cycles`` cycles as measured, and
    histograms of the whole run (controller/shell/streaming_stats.py) into which the ring is
    folded ``fold_cycles`` cycles at a time, so a run of days costs no more memory than one of
    seconds, and no cycle pays for folding a whole ring.

    Percentiles are known to 1 % of their value or 0.1 µs, whichever is larger (``LogHistogram``).
    """

    period_s: float
    ring_cycles: int = DEFAULT_RING_CYCLES
    fold_cycles: int = DEFAULT_FOLD_CYCLES  # at most ring_cycles (a smaller ring folds when full)
    late_fraction: float = 0.1  # a cycle is late when it wakes more than this fraction of a period late
    wake_error_s: np.ndarray = field(init=False)  # ring: actual wake-up minus deadline
    step_s: np.ndarray = field(init=False)  # ring: compute time of law.step
    observers_s: np.ndarray = field(init=False)  # ring: time spent handing the cycle to the observers
    send_s: np.ndarray = field(init=False)  # ring: time the exchange took to send the outputs and SYNC
    # ring: how long after its answer window's end the collect returned (it should return at it); after
    # the observers' end instead when they ran in the window and ended past it (their time is theirs)
    collect_over_s: np.ndarray = field(init=False)
    deadline_index: np.ndarray = field(
        init=False
    )  # ring: k of each executed cycle (skipped deadlines leave gaps)
    wake_hist_us: LogHistogram = field(init=False)
    step_hist_us: LogHistogram = field(init=False)
    observers_hist_us: LogHistogram = field(init=False)
    period_error_hist_us: LogHistogram = field(init=False)  # |actual - nominal period| between wake-ups
    cycles: int = 0
    overruns: int = 0  # deadlines skipped because the loop fell behind
    syncs_held_up: int = 0  # cycles held up between the wake-up and the SYNC past the next deadline
    targets_withheld: int = 0  # SYNCs in time for their deadline sent without the targets (module text)
    # Cycles that woke in time (not late for the step) whose send, RPDOs and SYNC, ended past the
    # late tolerance after their deadline: held up inside the send. The step is not told: it ran on
    # time, and the SYNC's targets are led by its lateness (drivers/cyclic_exchange.py
    # ``_before_sync``); a SYNC as late every cycle keeps its period. Counted so that such hold-ups
    # show: 200 SYNCs sent 2 ms late each (a `send_stall` of 0.5 s) ended DONE with nothing in the
    # summary to say so (an outside tester).
    late_sends: int = 0
    gc_collections: int = 0  # garbage collections the loop ran between cycles (module text)
    gc_max_s: float = 0.0  # the longest of them
    # the cycle with the longest span from its wake-up to the end of its work, and its parts [s]
    longest_cycle: dict[str, float] = field(default_factory=dict)
    started_s: float = 0.0
    finished_s: float = 0.0
    _folded: int = field(init=False, default=0)  # cycles already in the histograms
    _late: int = field(init=False, default=0)  # late cycles among the folded ones
    _last_wake_s: float | None = field(init=False, default=None)  # wake time of the last folded cycle

    def __post_init__(self) -> None:
        if self.ring_cycles < 2:
            raise ValueError(f"LoopStats: ring_cycles = {self.ring_cycles}: must be >= 2")
        if self.fold_cycles < 1:
            raise ValueError(f"LoopStats: fold_cycles = {self.fold_cycles}: must be >= 1")
        self.fold_cycles = min(self.fold_cycles, self.ring_cycles)
        self.wake_error_s = np.zeros(self.ring_cycles)
        self.step_s = np.zeros(self.ring_cycles)
        self.observers_s = np.zeros(self.ring_cycles)
        self.send_s = np.zeros(self.ring_cycles)
        self.collect_over_s = np.zeros(self.ring_cycles)
        self.deadline_index = np.zeros(self.ring_cycles, dtype=np.int64)
        self.wake_hist_us, self.step_hist_us, self.observers_hist_us, self.period_error_hist_us = (
            LogHistogram(0.1, 1e8) for _ in range(4)
        )  # 0.1 µs .. 100 s

    def record(self, wake_error_s: float, step_s: float, deadline_index: int) -> None:
        if self.cycles - self._folded >= self.fold_cycles:
            self.fold()  # once per fold_cycles cycles (DEFAULT_FOLD_CYCLES)
        i = self.cycles % self.ring_cycles
        self.wake_error_s[i] = wake_error_s
        self.step_s[i] = step_s
        self.deadline_index[i] = deadline_index
        self.observers_s[i] = 0.0
        self.cycles += 1

    def record_observers(self, observers_s: float) -> None:
        """Time of the observers of the cycle recorded last."""
        if self.cycles > self._folded:
            self.observers_s[(self.cycles - 1) % self.ring_cycles] = observers_s

    def record_exchange(self, send_s: float, collect_over_s: float) -> None:
        """The exchange's part of the cycle recorded last: its send, and its collect past the window."""
        if self.cycles > self._folded:
            i = (self.cycles - 1) % self.ring_cycles
            self.send_s[i] = send_s
            self.collect_over_s[i] = collect_over_s

    def record_span(
        self, span_s: float, gc_s: float, observers_s: float, marks: tuple[object, ...] | CycleMarks
    ) -> None:
        """The span of the cycle recorded last (wake-up to the end of its work, a collection
        included): kept with its parts when it is the longest of the run so far. ``observers_s``:
        the observers that ran inside it (the cycle before's, when they run in the answer window);
        ``marks``: its clock readings, for the time between the named parts (``CycleMarks``'
        fields; made one only for a longest cycle: the loop's path pays for a tuple, not a class)."""
        if span_s <= self.longest_cycle.get("span_s", 0.0) or self.cycles <= self._folded:
            return
        i = (self.cycles - 1) % self.ring_cycles
        self.longest_cycle = {
            "cycle": float(self.deadline_index[i]),
            "span_s": span_s,
            "wake_error_s": float(self.wake_error_s[i]),
            "send_s": float(self.send_s[i]),
            "collect_over_s": float(self.collect_over_s[i]),
            "step_s": float(self.step_s[i]),
            "observers_s": observers_s,
            "gc_s": gc_s,
            **CycleMarks(*marks).gaps(observers_s),
        }

    def record_gc(self, duration_s: float) -> None:
        self.gc_collections += 1
        self.gc_max_s = max(self.gc_max_s, duration_s)

    def fold(self) -> None:
        """Move the cycles not yet counted into the histograms (the ring keeps them as the last cycles)."""
        if self.cycles == self._folded:
            return
        idx = np.arange(self._folded, self.cycles) % self.ring_cycles
        wake = self.wake_error_s[idx]
        self.wake_hist_us.add(wake * 1e6)
        self.step_hist_us.add(self.step_s[idx] * 1e6)
        self.observers_hist_us.add(self.observers_s[idx] * 1e6)
        self._late += int(np.count_nonzero(wake > self.late_fraction * self.period_s))
        # across skipped deadlines too: a cycle that stalled for 50 ms shows as a 47.5 ms error at
        # 400 Hz, not as the small wake errors on either side of the gap
        wake_times = self.deadline_index[idx] * self.period_s + wake
        if self._last_wake_s is not None:
            wake_times = np.concatenate(([self._last_wake_s], wake_times))
        self.period_error_hist_us.add(period_error_us(wake_times, self.period_s))
        self._last_wake_s = float(wake_times[-1])
        self._folded = self.cycles

    def last_cycles(self) -> dict[str, np.ndarray]:
        """The last ``min(cycles, ring_cycles)`` cycles as measured, oldest first."""
        n = min(self.cycles, self.ring_cycles)
        idx = np.arange(self.cycles - n, self.cycles) % self.ring_cycles
        return {
            "wake_error_s": self.wake_error_s[idx],
            "step_s": self.step_s[idx],
            "observers_s": self.observers_s[idx],
            "send_s": self.send_s[idx],
            "collect_over_s": self.collect_over_s[idx],
            "deadline_index": self.deadline_index[idx],
        }

    @property
    def achieved_rate_hz(self) -> float:
        elapsed = self.finished_s - self.started_s
        return (self.cycles - 1) / elapsed if elapsed > 0 and self.cycles > 1 else 0.0

    def late_cycles(self) -> int:
        """Cycles that woke more than ``late_fraction`` of a period after their deadline, plus skipped ones."""
        self.fold()
        return self._late + self.overruns


def period_error_us(wake_s: np.ndarray, period_s: float) -> np.ndarray:
    """|actual - nominal period| between consecutive wake-ups [us], from wake times on one clock."""
    w = np.asarray(wake_s, dtype=float)
    if w.size < 2:
        return np.zeros(0)
    return np.abs(np.diff(w) - period_s) * 1e6


# what one cycle hands its observers: cycle, t, inputs, state, outputs, events, timing
Observation = tuple[int, float, CycleInputs, ControllerState, CycleOutputs, tuple[Event, ...], CycleTiming]
CommandSource = Callable[[], "tuple[str, float] | None"]  # one pending remote command, or None


DEFAULT_STOP_TIMEOUT_S = 10.0


class CycleLoop:
    """Runs the law at a fixed rate until it ends; see ``run`` for how a run ends.

    ``stop_event`` (a first SIGTERM/SIGINT, ``cheope stop``, a recording lost under
    ``recording.on_failure = "stop"``) asks the law to stop: STOPPING brakes within the limits
    and disables the drives, then DONE. ``quick_stop_event`` (a second signal) makes the law
    quick-stop the drives (FAULT). A stop that has not ended the run within ``stop_timeout_s``
    becomes a quick stop, so the loop ends in bounded time whatever the drives do.
    """

    def __init__(
        self,
        law: ControlLaw,
        exchange: Exchange,
        period_s: float,
        collect_fraction: float,
        sleeper: Sleeper,
        clock: Callable[[], float] = time.monotonic,
        observers: tuple[CycleObserver, ...] = (),
        stop_event: threading.Event | None = None,
        commands: CommandSource | None = None,
        late_tolerance_s: float = float("inf"),
        quick_stop_event: threading.Event | None = None,
        stop_timeout_s: float = DEFAULT_STOP_TIMEOUT_S,
        plans_ready: Callable[[], int] | None = None,
        collect_garbage: bool = True,
        observers_in_window: bool = False,
        thread_usage: ThreadUsageReaders | None = None,
    ) -> None:
        if not stop_timeout_s > 0:
            raise ValueError(f"stop_timeout_s = {stop_timeout_s}: must be > 0")
        self.law = law
        self.exchange = exchange
        self.period_s = period_s
        self.collect_s = collect_fraction * period_s
        self.sleeper = sleeper
        self.clock = clock
        self.observers = observers
        self.stop_event = stop_event or threading.Event()
        self.quick_stop_event = quick_stop_event or threading.Event()
        self.commands = commands
        self.plans_ready = (
            plans_ready  # an off-loop planner's progress (plan_worker.py), an input of the step
        )
        self.late_tolerance_s = late_tolerance_s
        self.stop_timeout_s = stop_timeout_s
        self.collect_garbage = collect_garbage  # the loop, not the allocator, decides when (module text)
        self.observers_in_window = observers_in_window  # step 5 of the module text
        self.thread_usage = thread_usage  # read by the loop thread each cycle (thread_usage.py)
        self.cycles_done = 0  # completed cycles: what controller/shell/stuck_loop.py watches

    def _window_end(self, deadline: float, work_peak_s: float) -> float:
        """When this cycle's answer window closes (step 3 of the module's text)."""
        end = min(deadline + self.collect_s, deadline + self.period_s - work_peak_s - WINDOW_MARGIN_S)
        return max(end, self.clock() + 0.5 * self.collect_s)

    def run(
        self,
        state: ControllerState,
        max_duration_s: float | None = None,
        linger_after_end_s: float = 0.1,
        exit_on_fault: bool = True,
    ) -> tuple[ControllerState, LoopStats]:
        """Run until the law reaches DONE or FAULT, plus ``linger_after_end_s`` so that the last
        controlwords reach the drives.

        ``max_duration_s`` (None: no limit) is a stop like any other: when it is up the law is
        asked to stop and the run ends through STOPPING, never with the drives left enabled.
        With ``exit_on_fault=False`` the loop keeps cycling in FAULT (quick stop held) so that a
        remote ``reset`` can recover, until a stop is requested.
        """
        if max_duration_s is not None and not max_duration_s > 0:
            raise ValueError(f"max_duration_s = {max_duration_s}: must be > 0 (or None: until stopped)")
        period = self.period_s
        time_up_cycle = int(max_duration_s / period) + 1 if max_duration_s is not None else None
        stop_timeout_cycles = max(1, int(self.stop_timeout_s / period))
        stats = LoopStats(period_s=period)
        clock = self.clock
        stats.started_s = clock() + period  # the first deadline
        linger = max(1, int(linger_after_end_s / period))
        deadlines = self.exchange if isinstance(self.exchange, CycleDeadlines) else None
        collector_was_on = gc.isenabled()
        if self.collect_garbage:
            gc.disable()
        try:
            state = self._cycles(
                state, stats, time_up_cycle, stop_timeout_cycles, linger, exit_on_fault, deadlines
            )
        finally:
            if collector_was_on:
                gc.enable()
        stats.finished_s = clock()
        stats.fold()
        return state, stats

    def _cycles(
        self,
        state: ControllerState,
        stats: LoopStats,
        time_up_cycle: int | None,
        stop_timeout_cycles: int,
        linger: int,
        exit_on_fault: bool,
        deadlines: CycleDeadlines | None,
    ) -> ControllerState:
        """The cycles of ``run`` until the run ends; the state it ends in."""
        period = self.period_s
        clock = self.clock
        outputs: CycleOutputs | None = None
        first_deadline = stats.started_s
        k = 0
        end_cycle: int | None = None
        stop_cycle: int | None = None  # the cycle a stop was first asked for
        work_peak_s = 0.0  # recent peak of the cycle's work from its window's end [s] (step 3)
        work_decay = 0.5 ** (period / WORK_PEAK_HALF_LIFE_S)
        collect_garbage = self.collect_garbage
        young_limit = gc.get_threshold()[0]
        skipped_before = False  # deadlines were skipped before this cycle
        in_window = self.observers_in_window
        usage = self.thread_usage
        cpu_s, switches = (usage.cpu_s, usage.switches) if usage is not None else (_nothing, _nothing)
        unobserved: Observation | None = None  # the cycle before's, for this cycle's answer window
        try:
            while True:
                deadline = first_deadline + k * period
                self.sleeper.sleep_until(deadline)
                woke = clock()
                # the loop thread's own usage from here: was a long cycle waiting? (thread_usage.py)
                usage_cpu_s, usage_switches = cpu_s(), switches()
                # held up to the next deadline or past it (DEADLINE_ROUNDING_S): this cycle is the latest
                if woke - deadline > period - DEADLINE_ROUNDING_S:
                    k, deadline = self._latest_deadline(stats, k, deadline, woke)
                    skipped_before = True
                if deadlines is not None:
                    deadlines.cycle_deadline(deadline)
                # after skipped deadlines: a SYNC without the stale RPDOs (module doc)
                sent_in_time = self.exchange.send(None if skipped_before else outputs, deadline + period)
                sent = clock()
                late_s = woke - deadline
                withheld = skipped_before
                if not sent_in_time and sent > deadline + period - DEADLINE_ROUNDING_S:
                    # held up before the SYNC went: it went late, without the targets
                    k, deadline = self._latest_deadline(stats, k, deadline, sent)
                    stats.syncs_held_up += 1
                    skipped_before = withheld = True
                    late_s = sent - deadline  # the bus saw this cycle begin at its SYNC
                elif not sent_in_time and not skipped_before:
                    # in time for its deadline, but too long after the SYNC before: without the targets
                    stats.targets_withheld += 1
                    withheld = True
                window_end = self._window_end(deadline, work_peak_s)
                observed_s = 0.0  # the observers' turn inside this cycle
                collect_from = window_end  # the collect's own lateness is counted from here ...
                if unobserved is not None:  # the cycle before's, in this one's answer window (step 5)
                    observed_s = self._observe(stats, unobserved)
                    unobserved = None
                    # ... or from the observers' end, when they ran past the window: that wait is
                    # theirs, and counted as the collect's too, the longest cycle's parts overlapped
                    # ("collect past window 5.39 ms, observers 6.94 ms" in a 7.7-ms cycle)
                    collect_from = max(window_end, clock())
                feedback = self.exchange.collect(window_end)
                collected = clock()
                stop = self.stop_event.is_set() or (time_up_cycle is not None and k >= time_up_cycle)
                if stop and stop_cycle is None:
                    stop_cycle = k
                command, value = self._command(k, stop_cycle, stop_timeout_cycles)
                inputs = cycle_inputs(
                    feedback,
                    stop,
                    command,
                    value,
                    # late: woke late, or the first cycle after deadlines the loop skipped (it fell behind)
                    late=late_s > self.late_tolerance_s or skipped_before,
                    plans_ready=self.plans_ready() if self.plans_ready is not None else 0,
                    targets_withheld=withheld,
                )
                if not inputs.late and sent - deadline > self.late_tolerance_s:
                    stats.late_sends += 1
                t = k * period
                c0 = clock()
                state, outputs, events = self.law.step(state, inputs, t)
                stepped = clock()
                timing = CycleTiming(late_s, stepped - c0, stepped)
                if outputs.sdo_controlwords:
                    self._write_controlwords_by_sdo(outputs)
                stats.record(timing.wake_error_s, timing.step_s, k)
                stats.record_exchange(sent - woke, max(0.0, collected - collect_from))
                observation = (k, t, inputs, state, outputs, events, timing)
                if in_window:
                    unobserved = observation
                else:
                    observed_s = self._observe(stats, observation)
                worked = clock()
                work_peak_s = max(worked - min(collected, window_end), work_peak_s * work_decay)
                gc_s = 0.0
                if collect_garbage and gc.get_count()[0] >= young_limit:
                    gc_s = self._collect_garbage(stats, worked)
                marks = (
                    sent,
                    collect_from,
                    collected,
                    c0,
                    stepped,
                    worked,
                    in_window,
                    usage_cpu_s,
                    usage_switches,
                    usage,
                )
                stats.record_span(worked + gc_s - woke, gc_s, observed_s, marks)
                ending = state.mode == Mode.DONE or (state.mode == Mode.FAULT and (exit_on_fault or stop))
                # from the first cycle that ends the run, a little more so the last commands reach the
                # drives; a recovery (a reset) before the end forgets it
                end_cycle = (k if end_cycle is None else end_cycle) if ending else None
                self.cycles_done += 1
                if end_cycle is not None and k - end_cycle >= linger:
                    break
                k += 1
                behind = clock() - (first_deadline + k * period)
                skipped_before = behind > period
                if skipped_before:
                    skipped = int(behind / period)
                    stats.overruns += skipped
                    k += skipped
        finally:  # the last cycle has no answer window after it; nor has one the loop left by an error
            if unobserved is not None:
                self._observe(stats, unobserved)
        return state

    def _command(self, k: int, stop_cycle: int | None, stop_timeout_cycles: int) -> tuple[Command, float]:
        """Cycle ``k``'s command: a quick stop (a second signal, or a stop asked for at ``stop_cycle``
        that has not ended the run in time), else one pending remote command, else none."""
        pending = self.commands() if self.commands is not None else None  # taken, even when overruled
        if self.quick_stop_event.is_set() or (
            stop_cycle is not None and k - stop_cycle > stop_timeout_cycles
        ):
            return Command.QUICK_STOP, 0.0
        return (Command(pending[0]), pending[1]) if pending is not None else (Command.NONE, 0.0)

    def _collect_garbage(self, stats: LoopStats, worked_s: float) -> float:
        """The generation CPython would collect, after the cycle's work instead of inside it; how long it took."""
        _, middle_limit, old_limit = gc.get_threshold()
        counts = gc.get_count()
        gc.collect(2 if counts[2] >= old_limit else 1 if counts[1] >= middle_limit else 0)
        gc_s = self.clock() - worked_s
        stats.record_gc(gc_s)
        return gc_s

    def _observe(self, stats: LoopStats, observation: Observation) -> float:
        """One cycle handed to every observer; the time it took, recorded for the cycle recorded last."""
        o0 = self.clock()
        for obs in self.observers:
            obs.on_cycle(*observation)
        observers_s = self.clock() - o0
        stats.record_observers(observers_s)
        return observers_s

    def _latest_deadline(self, stats: LoopStats, k: int, deadline: float, now: float) -> tuple[int, float]:
        """Cycle ``k`` (deadline ``deadline``) held up until ``now``, past its next deadline: the cycle
        and deadline of the latest deadline passed; the ones before it are skipped (overruns)."""
        # the rounding in (DEADLINE_ROUNDING_S): held up for 8.000 periods (simulated time's
        # `stall=0.02` at 400 Hz) read 7.999999999999999 of them, and the cycle after the 7 skipped
        # went at the same instant as this one: two SYNCs at once
        skipped = max(1, int((now - deadline + DEADLINE_ROUNDING_S) / self.period_s))
        stats.overruns += skipped
        return k + skipped, deadline + skipped * self.period_s

    def _write_controlwords_by_sdo(self, outputs: CycleOutputs) -> None:
        """What the step asks for on top of the RPDOs (a quick stop to a drive that may not process
        them): one expedited SDO each, sent now, not waited for; an exchange without SDO cannot."""
        if not isinstance(self.exchange, SdoControlwords):
            return
        for drive_index, controlword in outputs.sdo_controlwords:
            self.exchange.send_controlword_by_sdo(drive_index, controlword)


class SimulatedTime:
    """Clock and sleeper for runs in simulated time (tests, replay): sleeping jumps the clock.

    ``lateness`` (deadline -> seconds) makes a wake-up come that much after its deadline: the
    simulator's ``stall`` fault (``LoopbackExchange.stall_s``), a machine that holds the loop up,
    reproduced deterministically (the loop then skips the deadlines it missed, as over a bus).
    ``hold_up`` moves the clock on from inside a cycle (``send_stall``).
    """

    def __init__(self, start_s: float = 0.0, lateness: Callable[[float], float] | None = None) -> None:
        self.now_s = start_s
        self.lateness = lateness

    def clock(self) -> float:
        return self.now_s

    def sleep_until(self, deadline_s: float) -> None:
        late_s = self.lateness(deadline_s) if self.lateness is not None else 0.0
        self.now_s = max(self.now_s, deadline_s + late_s)

    def hold_up(self, seconds: float) -> None:
        """The process held up ``seconds`` where it stands (the simulator's ``send_stall`` fault:
        inside the exchange's send, between the RPDOs and their SYNC)."""
        self.now_s += seconds
