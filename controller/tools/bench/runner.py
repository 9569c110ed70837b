"""The whole benchmark: the parts of this package in their order, one JSON report, and its plots."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from controller.compiled_law import LAW_BUILD
from controller.experiments import experiment_for
from controller.realtime import RealtimeOptions
from controller.tools.bench.case import BenchCase, run_case
from controller.tools.bench.pdo_paths import bus_frame_cost, compare_pdo_paths
from controller.tools.bench.sleepers import compare_sleepers
from controller.tools.bench.statistics import Json

if TYPE_CHECKING:
    from matplotlib.axes import Axes


FD_FROM_HZ = 500.0  # rates from this one up run on CAN FD: classical CAN at 1 kHz is over 100 % load

# A timing benchmark must run its whole length: a burst of late or missing frames on a loaded
# machine is counted, not turned into a quick stop (``--strict`` keeps the configured reactions).
TOLERANT_SAFETY = (
    "loop.max_missing_s=2.5",
    'safety.on_late_cycles="warn"',
    'safety.on_sensor_stale="warn"',
    'safety.on_heartbeat_lost="warn"',
)


def run_bench(
    rates_hz: tuple[float, ...],
    duration_s: float,
    compare_s: float,
    out_dir: Path,
    config_path: str | None,
    overrides: list[str],
    rt: RealtimeOptions,
    sim_rt: RealtimeOptions,
    late_fraction: float = 0.1,
    fd_from_hz: float = FD_FROM_HZ,
    progress: Callable[[str], None] = lambda s: None,
    schedulers: tuple[str, ...] = ("realtime",),
    cyclictest_s: float = 30.0,
    task: str = "path",
    instructions: bool = False,
    hogs: int = 0,
) -> dict[str, object]:
    from controller.assembly import planned_bus_load
    from controller.config import load_config, parse_override
    from controller.realtime import apply_realtime

    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = load_config(config_path, dict(parse_override(s) for s in overrides))
    report: Json = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": sys.version.split()[0],
            "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
        },
        "duration_s": duration_s,
        "compare_s": compare_s,
        "definitions": {
            "period_error": "|(wake_k - wake_k-1) - period|",
            "late": f"woke > {late_fraction:g} x period after the deadline, or a skipped deadline",
            "cpu_percent": "% of one CPU over the run",
        },
    }
    from controller.tools.bench.cyclictest import INSTALL_HINT, cyclictest_path

    if cyclictest_s > 0 and cyclictest_path() is None:
        progress(INSTALL_HINT)
    report["work_per_cycle"] = work_per_cycle(task, instructions, progress)
    progress("cyclic PDO path: project vs canopen ...")
    report["pdo_path"] = compare_pdo_paths(20000 if duration_s >= 60 else 5000, config_path, overrides)
    progress("python-can send/recv per frame on the configured bus ...")
    report["bus_frame_cost"] = bus_frame_cost(cfg.bus.can, fd=any(r >= fd_from_hz for r in rates_hz))
    cases: list[dict[str, object]] = []
    # imported here, not at the top: `python -m controller.tools.bench.step_cost` runs that module as
    # a script, and the package's import of it beforehand made runpy warn on every such run
    from controller.tools.bench.step_cost import interpreted_step_breakdown, step_breakdown

    breakdowns: list[dict[str, object]] = []
    sleepers: list[dict[str, object]] = []
    has_experiment = experiment_for(cfg.task.kind) is not None
    for rate in rates_hz:
        case = BenchCase(rate, fd=rate >= fd_from_hz)
        progress(f"{rate:g} Hz: step cost and Ruckig in process ...")
        # a task's experiment in process as over the bus (the contour's tracking laps are what it costs)
        step_overrides = [*overrides, "task.path.laps=10.0"]
        step_cycles = int((duration_s if has_experiment else min(10.0, duration_s)) * rate)
        bd: Json = step_breakdown(config_path, step_overrides, rate, cycles=step_cycles)
        if LAW_BUILD.compiled:  # the old path beside the new, in the same run
            progress(f"{rate:g} Hz: the same step interpreted, in a child process ...")
            bd["interpreted"] = interpreted_step_breakdown(config_path, step_overrides, rate, step_cycles)
        breakdowns.append(bd)
        progress(f"{case.name}: loop shell vs naive sleep ...")
        restore = apply_realtime(rt)  # the same priority and CPU as the service's loop thread
        try:
            cmp = compare_sleepers(
                1.0 / rate,
                compare_s,
                bd["step_us"]["p50"] * 1e-6,
                cfg.loop.spin_us * 1e-6,
                late_fraction=late_fraction,
            )
        finally:
            restore()
        cmp["rate_hz"] = rate
        sleepers.append(cmp)
        for scheduler in schedulers:
            case = BenchCase(rate, fd=rate >= fd_from_hz, realtime=scheduler == "realtime")
            case_rt, case_sim_rt = (rt, sim_rt) if case.realtime else (RealtimeOptions(), RealtimeOptions())
            progress(
                f"{case.name}: controller + simulator for up to {duration_s:g} s, cyclictest beside it "
                f"for {min(cyclictest_s, duration_s):g} s ..."
            )
            cases.append(
                run_case(
                    case,
                    duration_s,
                    overrides,
                    config_path,
                    case_rt,
                    case_sim_rt,
                    late_fraction,
                    cyclictest_s,
                    hogs,
                )
            )
    classical_1k = load_config(
        config_path, dict(parse_override(s) for s in [*overrides, "loop.rate_hz=1000", "bus.fd=false"])
    )
    report["classical_can_1khz_computed_load_percent"] = round(planned_bus_load(classical_1k).percent, 1)
    report["step_breakdown"] = breakdowns
    report["sleepers"] = sleepers
    report["cases"] = cases
    report["plots"] = plot_distributions(cases, sleepers, out_dir)
    report["machine"]["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
    clean = _strip_private(report)
    (out_dir / "bench.json").write_text(json.dumps(clean, indent=2))
    return clean


def work_per_cycle(task: str, instructions: bool, progress: Callable[[str], None]) -> Json | None:
    """The deterministic figure beside the timed ones (controller/tools/bench/cycle_work.py): the task's
    work per cycle at the default configuration over its fixed window, against the budget;
    machine instructions too with ``instructions`` (valgrind, minutes). None for a task without a window."""
    from controller.tools.bench.cycle_work import (
        BUDGET_PER_CYCLE,
        DEFAULT_TASK_WINDOWS,
        count_instructions,
        count_work,
        over_budget,
    )

    if task not in DEFAULT_TASK_WINDOWS:
        return None
    skip, cycles = DEFAULT_TASK_WINDOWS[task]
    progress(f"work per cycle of the {task} task (interpreter counts, cycles {skip}-{skip + cycles - 1}) ...")
    work: Json = count_work(task, skip, cycles)
    work["budget_per_cycle"] = BUDGET_PER_CYCLE[task]
    work["over_budget"] = over_budget(work)
    if instructions:
        progress("... and machine instructions per cycle under callgrind (minutes) ...")
        work.update(count_instructions(task, skip, cycles))
    return work


def _strip_private(report: Json) -> Json:
    """``report`` without the keys starting with "_" (the raw samples for the plots), at any depth."""
    return {k: _strip_private_value(v) for k, v in report.items() if not k.startswith("_")}


def _strip_private_value(obj: object) -> object:
    if isinstance(obj, dict):
        return _strip_private(obj)
    if isinstance(obj, list):
        return [_strip_private_value(v) for v in obj]
    return obj


def plot_distributions(cases: list[Json], sleepers: list[Json], out_dir: Path) -> list[str]:
    """Period-error histograms and exceedance curves (PNG); returns the file paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for case in cases:
        err = case["_period_errors_us"]
        if err.size == 0:
            continue
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
        bins = np.logspace(np.log10(max(0.1, err.min() + 0.1)), np.log10(err.max() + 1.0), 80)
        ax1.hist(err + 0.1, bins=bins, color="tab:blue")
        ax1.set_xscale("log")
        ax1.set_yscale("log")
        ax1.set_xlabel("period error + 0.1 [µs] (offset for the log axis)")
        ax1.set_ylabel("cycles per bin (log scale)")
        pe = case["period_error_us"]
        for q, style in (("p50", ":"), ("p99", "--"), ("p99_9", "-.")):
            ax1.axvline(
                pe[q] + 0.1, color="k", linestyle=style, label=f"{q.replace('_', '.')}: {pe[q]:.0f} µs"
            )
        ax1.legend(title="period error", fontsize=8, framealpha=0.9, loc="upper right")
        ax1.set_title(f"{case['case']}: period error, {case['cycles']} cycles")
        _exceedance(ax2, err, f"service loop ({case['case']})")
        for s in sleepers:
            if s["rate_hz"] == case["rate_hz"]:
                _exceedance(ax2, s["deadline"]["_errors_us"], "loop shell sleeper, busy work only")
                _exceedance(ax2, s["naive"]["_errors_us"], "naive time.sleep(period)")
        period_us = 1e6 / case["rate_hz"]
        ax2.axvline(0.1 * period_us, color="r", linestyle="--", label="10 % of period")
        ax2.set_title("fraction of cycles with a period error above x")
        ax2.legend(fontsize=8)
        fig.tight_layout()
        path = out_dir / f"period_error_{case['rate_hz']:g}hz_{case['scheduler']}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(str(path))
    return paths


def _exceedance(ax: Axes, err_us: np.ndarray, label: str) -> None:
    if err_us.size == 0:
        return
    x = np.sort(err_us)
    frac = 1.0 - np.arange(x.size) / x.size
    ax.step(x + 0.1, frac, where="post", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylim(max(1e-6, 0.5 / x.size), 1.1)
    ax.set_xlabel("x = period error + 0.1 [µs] (offset for the log axis)")
    ax.set_ylabel("fraction of cycles with an error above x (log scale)")
    ax.grid(True, which="both", alpha=0.3)
