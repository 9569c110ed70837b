"""Percentiles, late cycles per 10 000 and the schedule of wake-ups: the figures every part reports (pure)."""

from __future__ import annotations

from typing import Any

import numpy as np

from controller.shell.loop import period_error_us

# The benchmark's results are JSON-shaped (bench.json): nested dicts of numbers, strings and lists,
# their keys set where they are built. The code that reads them back (the cyclictest ratios, the
# plots, the table) reads them as Json rather than through one TypedDict per table.
Json = dict[str, Any]


def percentiles_us(values_us: np.ndarray) -> dict[str, float]:
    """p50, p99, p99.9 and max of ``values_us``, rounded to 0.1 us (zeros when empty)."""
    v = np.asarray(values_us, dtype=float)
    if v.size == 0:
        return {"p50": 0.0, "p99": 0.0, "p99_9": 0.0, "max": 0.0}
    p50, p99, p999 = np.percentile(v, [50.0, 99.0, 99.9])
    return {
        "p50": round(float(p50), 1),
        "p99": round(float(p99), 1),
        "p99_9": round(float(p999), 1),
        "max": round(float(v.max()), 1),
    }


def late_per_10k(wake_error_s: np.ndarray, period_s: float, late_fraction: float, overruns: int = 0) -> float:
    """Late cycles per 10 000 deadlines (executed + skipped)."""
    e = np.asarray(wake_error_s, dtype=float)
    deadlines = e.size + overruns
    if deadlines == 0:
        return 0.0
    late = int(np.count_nonzero(e > late_fraction * period_s)) + overruns
    return 1e4 * late / deadlines


def schedule_stats(wake_s: np.ndarray, period_s: float, late_fraction: float = 0.1) -> dict[str, object]:
    """Timing of a loop whose k-th wake-up was meant for ``wake_s[0] + k * period_s``."""
    w = np.asarray(wake_s, dtype=float)
    if w.size < 2:
        raise ValueError(f"schedule_stats needs at least 2 wake-ups, got {w.size}")
    nominal = w[0] + period_s * np.arange(w.size)
    error = w - nominal
    return {
        "cycles": int(w.size),
        "achieved_rate_hz": round((w.size - 1) / (w[-1] - w[0]), 3),
        "drift_ms": round(float(error[-1]) * 1e3, 3),  # behind the nominal schedule at the end
        "period_error_us": percentiles_us(period_error_us(w, period_s)),
        "late_per_10k": round(late_per_10k(error[1:], period_s, late_fraction), 2),
    }
