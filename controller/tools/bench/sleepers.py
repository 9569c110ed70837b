"""The loop shell's deadline sleeper against a naive ``time.sleep(period)`` loop doing the same busy work."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from controller.shell.loop import period_error_us
from controller.tools.bench.statistics import percentiles_us, schedule_stats


def busy_work(duration_s: float, clock: Callable[[], float] = time.perf_counter) -> None:
    """Spin for ``duration_s``: a stand-in for the step's compute time."""
    end = clock() + duration_s
    while clock() < end:
        pass


def naive_loop(period_s: float, cycles: int, work_s: float) -> np.ndarray:
    """The loop DESIGN.md warns against: work, then ``time.sleep(period)``. Returns wake times [s]."""
    wake = np.empty(cycles)
    clock = time.monotonic
    for k in range(cycles):
        wake[k] = clock()
        busy_work(work_s)
        time.sleep(period_s)
    return wake


def deadline_loop(period_s: float, cycles: int, work_s: float, spin_s: float) -> np.ndarray:
    """The loop shell's sleeper (``DeadlineSleeper``) on absolute deadlines. Returns wake times [s]."""
    from drivers.pacing import DeadlineSleeper

    sleeper = DeadlineSleeper(spin_s)
    clock = time.monotonic
    wake = np.empty(cycles)
    first = clock() + period_s
    for k in range(cycles):
        sleeper.sleep_until(first + k * period_s)
        wake[k] = clock()
        busy_work(work_s)
    return wake


def compare_sleepers(
    period_s: float,
    duration_s: float,
    work_s: float,
    spin_s: float,
    blocks: int = 4,
    late_fraction: float = 0.1,
) -> dict[str, object]:
    """Alternate blocks of both loops (A B A B ...) for ``duration_s`` in all; stats per loop."""
    per_block = max(2, int(duration_s / (2 * blocks) / period_s))
    arms: dict[str, list[np.ndarray]] = {"deadline": [], "naive": []}
    for _ in range(blocks):
        arms["deadline"].append(deadline_loop(period_s, per_block, work_s, spin_s))
        arms["naive"].append(naive_loop(period_s, per_block, work_s))
    out: dict[str, object] = {
        "work_us": round(work_s * 1e6, 1),
        "blocks": blocks,
        "cycles_per_block": per_block,
    }
    for name, runs in arms.items():
        stats = [schedule_stats(w, period_s, late_fraction) for w in runs]
        errors = np.concatenate([period_error_us(w, period_s) for w in runs])
        out[name] = {
            "achieved_rate_hz": round(float(np.mean([s["achieved_rate_hz"] for s in stats])), 3),
            "drift_ms_per_s": round(
                float(np.mean([s["drift_ms"] for s in stats])) / (per_block * period_s), 3
            ),
            "period_error_us": percentiles_us(errors),
            "late_per_10k": round(float(np.mean([s["late_per_10k"] for s in stats])), 2),
            "_errors_us": errors,
        }
    return out
