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

import numpy as np

from controller.core.control_law import PIPELINE_PERIODS, ControllerState
from controller.core.cycle_data import CycleInputs, CycleOutputs, Event, Severity
from controller.shell.loop import CycleTiming, LoopStats
from drivers.cyclic_exchange import ExchangeCounters


@dataclass
class RunRecorder:
    """Collects the per-cycle figures a summary needs (the loop's observer)."""

    tracking_error_m: list[float] = field(default_factory=list)
    events: list[tuple[float, Event]] = field(default_factory=list)
    _references: deque[tuple[float, float, float] | None] = field(
        default_factory=lambda: deque([None] * PIPELINE_PERIODS, maxlen=PIPELINE_PERIODS))

    def on_cycle(self, cycle: int, t: float, inputs: CycleInputs, state: ControllerState,
                 outputs: CycleOutputs, events: tuple[Event, ...], timing: CycleTiming) -> None:
        ref = self._references[0]
        if ref is not None and state.tcp_measured_m is not None and all(d.fresh for d in inputs.drives):
            m = state.tcp_measured_m
            self.tracking_error_m.append(math.dist(ref, m))
        self._references.append(state.tcp_reference_m)
        for e in events:
            self.events.append((t, e))


def _percentile_us(values_us: np.ndarray, q: float) -> float:
    return float(np.percentile(values_us, q)) if values_us.size else 0.0


def summarize(stats: LoopStats, recorder: RunRecorder, final: ControllerState,
              counters: ExchangeCounters | None, bus_load_percent: float,
              extra: dict[str, object] | None = None) -> dict[str, object]:
    """The demo's summary as one JSON-ready dict (SI units and microseconds in the names)."""
    per = stats.period_error_us()
    n = min(stats.cycles, stats.capacity)
    wake = stats.wake_error_s[:n] * 1e6
    step = stats.step_s[:n] * 1e6
    observers = stats.observers_s[:n] * 1e6
    err = np.asarray(recorder.tracking_error_m)
    c = counters if counters is not None else ExchangeCounters()  # None: all zero
    out: dict[str, object] = {
        "final_mode": final.mode.name,
        "fault_reason": final.fault_reason,
        "cycles": stats.cycles,
        "nominal_rate_hz": 1.0 / stats.period_s,
        "achieved_rate_hz": round(stats.achieved_rate_hz, 3),
        "period_error_us": {"p50": _percentile_us(per, 50), "p99": _percentile_us(per, 99),
                            "max": float(per.max()) if per.size else 0.0},
        "wake_latency_us": {"p50": _percentile_us(wake, 50), "p99": _percentile_us(wake, 99),
                            "max": float(wake.max()) if wake.size else 0.0},
        "step_compute_us": {"p50": _percentile_us(step, 50), "p99": _percentile_us(step, 99)},
        # the recorder, publisher and statistics on the loop's thread: they must only hand off
        "observers_us": {"p50": _percentile_us(observers, 50), "p99": _percentile_us(observers, 99),
                         "max": float(observers.max()) if observers.size else 0.0},
        "late_cycles": stats.late_cycles(),
        "overruns": stats.overruns,
        "missing_frames": {"drive": c.missing_drive_frames, "sensor": c.missing_sensor_frames},
        "rejected_frames": c.rejected_frames,
        "send_errors": c.send_errors,  # e.g. ENOBUFS: a full transmit queue
        "error_frames": c.error_frames,
        "bus_load_percent": round(bus_load_percent, 2),
        "tracking_error_m": {"rms": float(np.sqrt(np.mean(err**2))) if err.size else None,
                             "max": float(err.max()) if err.size else None, "samples": int(err.size)},
        "events": [f"{t:.4f}s {e.severity.name}: {e.message}" for t, e in recorder.events
                   if e.severity >= Severity.INFO],
    }
    if extra:
        out.update(extra)
    return out
