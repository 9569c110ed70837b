"""Statistics of a run, gathered by an observer of the loop, and the summary it reports.

Tracking error: the setpoint computed in cycle k aims at the path point for the instant the
drives reach it, two periods later (``control_law.PIPELINE_PERIODS``). The TCP measured at
cycle k + 2 (direct kinematics of the positions the drives sampled at that SYNC) is compared
with it, so the error includes the drives' following error, as a user of the robot sees it.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from controller.compiled_law import LAW_BUILD
from controller.core.control_law import PIPELINE_PERIODS
from controller.core.controller_state import ControllerState
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event, Severity
from controller.core.ports import CycleTiming
from controller.shell.loop import LoopStats
from controller.shell.streaming_stats import FloatRing, LogHistogram, RunningMoments
from drivers.cyclic_exchange import ExchangeCounters

if TYPE_CHECKING:
    from sim_backend.fault_injection import FaultSchedule

TRACKING_RING = 65536  # the last tracking errors kept as measured (tests, plots), about 160 s at 400 Hz
EVENT_RING = 1000  # the last events kept for the summary; older ones are counted, not kept


def task_finished_event(e: Event) -> bool:
    """The law's mode event of a task that finished ("RUNNING -> STOPPING: task <name> finished",
    controller/core/control_law.py); a run that ends DONE without it was stopped first."""
    return e.kind == "mode" and "-> STOPPING: task " in e.message and e.message.endswith(" finished")


# A gap this long between two steps, on the loop's clock, is the loop itself held up (a stopped
# process, a suspended VM), not a late cycle; a fault within HOLDUP_BLAME_S after it, on the same
# clock (a cycle's t jumps over the deadlines skipped), is said to follow it: the drives'
# heartbeats, SYNC watchdog and frames go missing while the controller is not listening, and the
# fault then names the drives (an outside tester's SIGSTOP of 5 s read "heartbeat lost from node(s)
# [1, 2, 16]").
HOLDUP_NOTE_S = 0.25
HOLDUP_BLAME_S = 1.0


def fault_event(e: Event) -> bool:
    """The law's mode event of a fault ("RUNNING -> FAULT: ...", controller/core/control_law.py)."""
    return e.kind == "mode" and "-> FAULT" in e.message


@dataclass
class RunRecorder:
    """Collects the per-cycle figures a summary needs (the loop's observer), in bounded memory:
    running moments and a ring of the last tracking errors, the last ``EVENT_RING`` events."""

    tracking: RunningMoments = field(default_factory=RunningMoments)
    tracking_ring: FloatRing = field(default_factory=lambda: FloatRing(TRACKING_RING))
    events: deque[tuple[float, Event]] = field(default_factory=lambda: deque(maxlen=EVENT_RING))
    events_seen: int = 0
    task_finished: bool = False  # the task's own end was seen (task_finished_event)
    # the loop's own hold-up that a fault followed (HOLDUP_BLAME_S), said in the summary; "" if none
    fault_after_holdup: str = ""
    _last_stepped_s: float | None = None
    # the last gap of HOLDUP_NOTE_S or more: (length [s], its cycle's t, the loop's clock at its step's end)
    _holdup: tuple[float, float, float] | None = None
    _references: deque[tuple[float, float, float] | None] = field(
        default_factory=lambda: deque([None] * PIPELINE_PERIODS, maxlen=PIPELINE_PERIODS)
    )

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        ref = self._references[0]
        if ref is not None and state.tcp_measured_m is not None and all(d.fresh for d in inputs.drives):
            error_m = math.dist(ref, state.tcp_measured_m)
            self.tracking.add(error_m)
            self.tracking_ring.append(error_m)
        self._references.append(state.tcp_reference_m)
        # between two steps, by the loop's clock: a hold-up in the sleep (the deadlines skipped) or
        # inside the cycle (a process stopped in its collect), both
        stepped_s = timing.stepped_s if timing is not None else math.nan
        if self._last_stepped_s is not None and stepped_s - self._last_stepped_s >= HOLDUP_NOTE_S:
            self._holdup = (stepped_s - self._last_stepped_s, t, stepped_s)
        if not math.isnan(stepped_s):
            self._last_stepped_s = stepped_s
        for e in events:
            self.events.append((t, e))
            if task_finished_event(e):
                self.task_finished = True
            if (
                fault_event(e)
                and not self.fault_after_holdup
                and self._holdup is not None
                and stepped_s - self._holdup[2] <= HOLDUP_BLAME_S
            ):
                self.fault_after_holdup = (
                    f"the loop itself was held up {self._holdup[0]:.2f} s (its cycle at t = {self._holdup[1]:.4f} s, "
                    f"the fault's {t:.4f} s): a stopped or starved controller process or a suspended machine, "
                    "not the devices, may be its cause"
                )
        self.events_seen += len(events)

    @property
    def tracking_error_m(self) -> np.ndarray:
        """The last ``TRACKING_RING`` tracking errors [m], oldest first (the whole run when shorter)."""
        return self.tracking_ring.values()


def simulated_time_summary(
    final: ControllerState,
    recorder: RunRecorder,
    stats: LoopStats,
    counters: ExchangeCounters,
    faults: FaultSchedule,
) -> dict[str, object]:
    """The head of a run's summary in simulated time (``cheope demo --simulated-time``, a task's own
    or an experiment's): how it ended, whether its task finished, the hold-ups the ``stall`` and
    ``send_stall`` faults made (as ``run_summary`` names them over a bus), and which law ran; the
    injected ``faults`` that injected nothing, when there are any (``faults_that_injected_nothing``)."""
    return {
        "final_mode": final.mode.name,
        "fault_reason": final.fault_reason,
        "task_finished": recorder.task_finished,
        "cycles": stats.cycles,
        "simulated_time": True,
        "overruns": stats.overruns,
        "syncs_held_up": stats.syncs_held_up,
        "targets_withheld": stats.targets_withheld,
        "late_sends": stats.late_sends,
        "rpdos_resent": counters.rpdos_resent,
        **_answers_missed(counters),  # a `drop:` fault's, and the answers of unknown age after it
        "law": LAW_BUILD.describe(),  # the time it took, not what it computed (controller/compiled_law.py)
        **faults_that_injected_nothing(faults),
    }


def _answers_missed(c: ExchangeCounters) -> dict[str, object]:
    """The devices' answers no cycle used, over a bus or in simulated time (``cyclic_exchange``)."""
    return {
        "missing_frames": {"drive": c.missing_drive_frames, "sensor": c.missing_sensor_frames},
        # of them, lone answers of a device still owing two or more: maybe a burst's oldest
        "answers_of_unknown_age": c.answers_of_unknown_age,
        "longest_silence_cycles": {
            "drive": c.longest_drive_silence_cycles,
            "sensor": c.longest_sensor_silence_cycles,
        },
    }


def faults_that_injected_nothing(faults: FaultSchedule) -> dict[str, object]:
    """``{"faults_not_reached": [spec, ...]}`` for the injected faults that started after the run's
    last SYNC, and ``{"faults_missed": [...]}`` for those it reached that were active at no SYNC
    (none: nothing); said on stderr by ``controller.cli.say_run_notes``."""
    late, missed = faults.not_reached(), faults.missed()
    return {
        **({"faults_not_reached": list(late)} if late else {}),
        **({"faults_missed": list(missed)} if missed else {}),
    }


def _hist_us(h: LogHistogram, *qs: float, with_max: bool = True) -> dict[str, float]:
    out = {f"p{q:g}": h.percentile(q) for q in qs}
    if with_max:
        out["max"] = h.max if h.count else 0.0
    return out


def _longest_cycle_us(longest: dict[str, float]) -> dict[str, float]:
    """Its times in microseconds; its cycle and counts (the work's waits, preemptions) as they are."""
    return {
        k.removesuffix("_s"): (round(v * 1e6, 1) if k.endswith("_s") else int(v)) for k, v in longest.items()
    }


def summarize(
    stats: LoopStats,
    recorder: RunRecorder,
    final: ControllerState,
    counters: ExchangeCounters | None,
    bus_load_percent: float,
    extra: dict[str, object] | None = None,
) -> dict[str, object]:
    """The demo's summary as one JSON-ready dict (SI units and microseconds in the names).

    Timing percentiles come from the loop's fixed-size histograms: each is the upper edge of its
    bin, at most 1 % (or 0.1 µs) above the true value (``statistics_resolution``).
    """
    stats.fold()
    te = recorder.tracking
    c = counters if counters is not None else ExchangeCounters()  # None: all zero
    out: dict[str, object] = {
        "final_mode": final.mode.name,
        "fault_reason": final.fault_reason,
        "task_finished": recorder.task_finished,  # DONE without it: stopped first (--duration, a signal)
        **({"fault_after_holdup": recorder.fault_after_holdup} if recorder.fault_after_holdup else {}),
        "cycles": stats.cycles,
        "nominal_rate_hz": 1.0 / stats.period_s,
        "achieved_rate_hz": round(stats.achieved_rate_hz, 3),
        "period_error_us": _hist_us(stats.period_error_hist_us, 50, 99),
        "wake_latency_us": _hist_us(stats.wake_hist_us, 50, 99),
        "step_compute_us": _hist_us(stats.step_hist_us, 50, 99, with_max=False),
        # the recorder, publisher and statistics on the loop's thread: they must only hand off
        "observers_us": _hist_us(stats.observers_hist_us, 50, 99),
        "statistics_resolution": "percentiles: upper edge of 1 % bins (at most 1 % or 0.1 us above)",
        # collections run by the loop after a cycle's work (the automatic collector is off in the loop)
        "garbage_collections": {"count": stats.gc_collections, "max_us": round(stats.gc_max_s * 1e6, 1)},
        # the cycle with the longest span from its wake-up to the end of its work, and its parts
        "longest_cycle_us": _longest_cycle_us(stats.longest_cycle),
        "late_cycles": stats.late_cycles(),
        "overruns": stats.overruns,
        # of the cycles that skipped deadlines: held up between their wake-up and their SYNC
        "syncs_held_up": stats.syncs_held_up,
        # SYNCs in time for their deadline that went without the targets: too long after the last
        "targets_withheld": stats.targets_withheld,
        # cycles that woke in time whose send ended past the late tolerance (LoopStats.late_sends)
        "late_sends": stats.late_sends,
        # cycles whose RPDOs went again before their SYNC: held up after they went (cyclic_exchange)
        "rpdos_resent": c.rpdos_resent,
        **_answers_missed(c),
        "rejected_frames": c.rejected_frames,
        "rejected_frames_by_node": {str(node): n for node, n in sorted(c.rejected_by_node.items())},
        "foreign_frames": c.foreign_frames,
        "send_errors": c.send_errors,  # e.g. ENOBUFS: a full transmit queue
        "error_frames": c.error_frames,
        "bus_load_percent": round(bus_load_percent, 2),
        "tracking_error_m": {"rms": te.rms, "max": te.maximum, "samples": te.count},
        "events": [
            f"{t:.4f}s {e.severity.name}: {e.message}"
            for t, e in recorder.events
            if e.severity >= Severity.INFO
        ],
        "events_not_kept": recorder.events_seen - len(recorder.events),
        # the step's modules compiled by mypyc, or from their sources and why (controller/compiled_law.py)
        "law": LAW_BUILD.describe(),
    }
    if extra:
        out.update(extra)
    return out
