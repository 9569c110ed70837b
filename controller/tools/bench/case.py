"""One configuration of the real service against the simulator, and the machine's floor (cyclictest) beside it."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, SupportsInt

import numpy as np

from controller.experiments import experiment_for
from controller.realtime import RealtimeOptions
from controller.shell.loop import period_error_us
from controller.tools.bench.cpu_hogs import cpu_hogs
from controller.tools.bench.probes import LoopProbe, cpu_use_percent
from controller.tools.bench.statistics import Json, late_per_10k, percentiles_us
from drivers import cob_ids
from drivers.bus_load import measured_bus_load

if TYPE_CHECKING:
    import subprocess

    from controller.shell.loop import CycleLoop
    from drivers.bus import BusSpec


def simulator(
    spec: BusSpec,
    overrides: list[str],
    config_path: str | None,
    rt: RealtimeOptions,
    ready_timeout_s: float = 120.0,
) -> AbstractContextManager[subprocess.Popen[str]]:
    """``cheope sim`` as a child process with its own real-time options."""
    from controller.shell.demo import simulator_process

    return simulator_process(spec, config_path, overrides, ready_timeout_s, extra_args=rt.cli_args())


@dataclass(frozen=True)
class BenchCase:
    rate_hz: float
    fd: bool
    realtime: bool = True  # the loop (and simulator) with the bench's real-time options, else SCHED_OTHER

    @property
    def name(self) -> str:
        return (
            f"{self.rate_hz:g} Hz "
            + ("FD" if self.fd else "classic")
            + (" RT" if self.realtime else " normal")
        )


def run_case(
    case: BenchCase,
    duration_s: float,
    base_overrides: list[str],
    config_path: str | None,
    rt: RealtimeOptions,
    sim_rt: RealtimeOptions,
    late_fraction: float,
    cyclictest_s: float = 0.0,
    hogs: int = 0,
    on_loop_built: Callable[[CycleLoop], None] | None = None,
) -> dict[str, object]:
    from controller.assembly import planned_bus_load
    from controller.config import load_config, parse_override
    from controller.shell.demo import random_udp_port
    from controller.shell.service import run_controller
    from controller.tasks.registry import task_entry
    from drivers.bus import parse_bus_spec

    overrides = [*base_overrides, f"loop.rate_hz={case.rate_hz}", f"bus.fd={'true' if case.fd else 'false'}"]
    cfg = load_config(config_path, dict(parse_override(s) for s in overrides))
    lasting = task_entry(cfg.task.kind).lasting
    if lasting is not None:  # enough of the task to keep it moving for the whole run
        overrides += [f"{key}={value!r}" for key, value in lasting(cfg.task.model(), duration_s).items()]
        cfg = load_config(config_path, dict(parse_override(s) for s in overrides))
    spec = parse_bus_spec(cfg.bus.can, fd=cfg.bus.fd, udp_port=random_udp_port())
    period = cfg.period_s
    capacity = int(duration_s / period) + 16
    ids = tuple(cfg.actuators.node_ids)
    tpdo_ids = {cob_ids.tpdo1(i) for i in ids}
    if cfg.sensor.enabled:
        tpdo_ids |= {cob_ids.tpdo1(cfg.sensor.node_id), cob_ids.tpdo2(cfg.sensor.node_id)}
    experiment = experiment_for(cfg.task.kind)
    lap_report = (  # the task's own per-lap report, as its demo gives it (the contour's force error)
        experiment.lap_report(cfg) if experiment is not None and experiment.lap_report is not None else None
    )
    with simulator(spec, overrides, config_path, sim_rt) as proc:
        probe = LoopProbe(
            capacity,
            frozenset(tpdo_ids),
            cob_ids.rpdo1(ids[0]),
            proc.pid,
            sample_every=max(1, round(cfg.loop.rate_hz)),
        )
        with (
            cpu_hogs(hogs),  # busy neighbours at the normal priority (cpu_hogs.py)
            machine_floor_beside(case.rate_hz, min(cyclictest_s, duration_s), rt, late_fraction) as floor,
        ):
            summary = run_controller(
                cfg,
                spec,
                max_duration_s=duration_s,
                observers=(probe,) if lap_report is None else (probe, lap_report[0]),
                frame_sink=probe.sink,
                realtime=rt,
                on_loop_built=on_loop_built,
            )
    if lap_report is not None:
        summary["task_report"] = lap_report[1]()
    n = min(probe.n, capacity)
    skip = min(n // 10, round(cfg.loop.rate_hz))  # the first second: node set-up done, caches cold
    wake = probe.wake_error_s[skip:n]
    overruns = _count(summary.get("overruns", 0))
    samples = probe.samples
    seconds = samples[-1][0] - samples[0][0] if len(samples) > 1 else 0.0
    # each frame once in either direction: the bus (or the service's tap) hands back none of our own
    frames = {
        cid: probe.frames.get(cid, 0) + probe.frames_out.get(cid, 0)
        for cid in probe.frames.keys() | probe.frames_out.keys()
    }
    per_err = period_error_us(
        probe.deadline_index[skip:n] * period + wake, period
    )  # across skipped deadlines
    result: dict[str, object] = {
        "case": case.name,
        "scheduler": "realtime" if case.realtime else "normal",
        "task": cfg.task.kind,
        "rate_hz": case.rate_hz,
        "fd": case.fd,
        "bus": str(spec),
        "realtime": summary.get("realtime"),  # as granted to the loop thread
        "cpu_shield": summary.get("cpu_shield"),  # the loop's CPU kept clear (controller/shell/cpu_shield.py)
        "idle_poll": summary.get("idle_poll"),  # the CPUs kept from halting (controller/shell/idle_poll.py)
        "simulator_realtime": sim_rt.describe(),  # as asked of the simulator
        "cpu_hogs": hogs,
        "final_mode": summary["final_mode"],
        "fault_reason": summary.get("fault_reason"),
        "cycles": _count(summary["cycles"]),
        "achieved_rate_hz": summary["achieved_rate_hz"],
        "period_error_us": percentiles_us(per_err),
        "wake_latency_us": percentiles_us(wake * 1e6),
        "late_per_10k": round(late_per_10k(wake, period, late_fraction, overruns), 2),
        "late_fraction_of_period": late_fraction,
        "overruns": overruns,
        # the cycle with the longest span from wake-up to the end of its work, and where it went
        "longest_cycle_us": summary.get("longest_cycle_us"),
        "step_us": percentiles_us(probe.step_s[skip:n] * 1e6),
        "tpdo_to_ready_us": percentiles_us(_finite(probe.ready_after_tpdo_s[skip:n]) * 1e6),
        "sync_to_last_tpdo_us": percentiles_us(_finite(probe.answer_s[skip:n]) * 1e6),
        "tpdo_to_rpdo_us": percentiles_us(_finite(probe.rpdo_after_tpdo_s[skip:n]) * 1e6),
        "cpu_percent_of_one_core": cpu_use_percent(samples),
        # the loop's spin before each deadline over the run, in % of one core (the service's spin_s)
        "spin_percent_of_one_core": _spin_percent(summary),
        "bus_load_percent": {
            "computed": round(planned_bus_load(cfg).percent, 1),
            "measured": measured_bus_load(
                frames, probe.frame_shape, seconds, cfg.bus.bitrate_bit_s, cfg.bus.data_bitrate_bit_s
            ),
        },
        "missing_frames": summary.get("missing_frames"),
        "frames_per_cycle": {
            "in": round(sum(probe.frames.values()) / max(1, probe.n), 2),
            "out": round(sum(probe.frames_out.values()) / max(1, probe.n), 2),
        },
        "task_laps": _task_laps(summary),
        "_period_errors_us": per_err,
    }
    if cyclictest_s > 0:
        result["cyclictest"] = machine_floor(floor, late_fraction / case.rate_hz * 1e6, result)
    return result


def _spin_percent(summary: dict[str, object]) -> float | None:
    spin_s, cycles, rate = summary.get("spin_s"), summary.get("cycles"), summary.get("achieved_rate_hz")
    if (
        not isinstance(spin_s, float)
        or not isinstance(cycles, int)
        or not isinstance(rate, float)
        or rate <= 0
    ):
        return None
    return round(100.0 * spin_s * rate / cycles, 1) if cycles else None


def _count(value: object) -> int:
    """A count from ``run_controller``'s summary (its values are typed ``object``)."""
    if not isinstance(value, SupportsInt):
        raise TypeError(f"expected a count in the run summary, got {value!r}")
    return int(value)


def _task_laps(summary: dict[str, object]) -> list[dict[str, object]] | None:
    """The laps of the task's own report (``Experiment.lap_report``: the contour's force error)."""
    report = summary.get("task_report")
    return report.get("laps") if isinstance(report, dict) else None


FLOOR_THRESHOLDS_US = (100.0, 250.0)  # besides the late threshold, cyclictest's rates above these


@contextmanager
def machine_floor_beside(
    rate_hz: float, duration_s: float, rt: RealtimeOptions, late_fraction: float = 0.1
) -> Iterator[Json]:
    """cyclictest beside the case's run (``duration_s`` of it from the start; 0: none), on the loop's
    CPU with its memory locking: the machine's floor while the loop runs, in the same run. One
    priority step *above* the loop: below it, cyclictest's wake-ups wait for the loop's own cycle
    (3 912 late wake-ups per 10 000 in one 8-s run at 400 Hz, other work on the machine), a floor that
    measures the loop, not the machine; above it, it takes microseconds a wake-up from the loop.
    Yields the floor's figures (filled when the block ends) or an error."""
    from controller.tools.bench.cyclictest import (
        INSTALL_HINT,
        CyclictestError,
        cyclictest_beside,
        cyclictest_path,
    )

    floor: Json = {}
    if duration_s <= 0 or cyclictest_path() is None:
        if duration_s > 0:
            floor["error"] = INSTALL_HINT
        yield floor
        return
    priority = None if rt.priority is None else min(99, rt.priority + 1)
    late_us = late_fraction * 1e6 / rate_hz  # the case's late threshold
    try:
        with cyclictest_beside(
            rate_hz,
            duration_s,
            priority,
            rt.cpus[0] if rt.cpus else None,
            rt.lock_memory,
            (late_us, *FLOOR_THRESHOLDS_US),
        ) as result:
            yield floor
        floor.update(result)
    except CyclictestError as err:
        floor["error"] = str(err)


def machine_floor(floor: Json, late_us: float, case: Json) -> Json:
    """The case's figures over the floor cyclictest measured beside it."""
    if "error" in floor or "per_10k_above_us" not in floor:
        return floor if floor else {"error": "cyclictest did not run"}
    above = floor["per_10k_above_us"].get(f"{late_us:g}")
    deadlines = floor.get("late_deadlines_per_10k_above_us", {}).get(f"{late_us:g}")
    # None: the case's threshold differs from the one cyclictest was asked for
    if above is None or deadlines is None:
        return {**floor, "error": f"no cyclictest rate above {late_us:g} us"}
    wake = case["wake_latency_us"]
    floor["late_us"] = late_us
    # like with like: the loop's late cycles count the deadlines a late cycle passed, and so does
    # this floor (controller/tools/bench/cyclictest.py); over cyclictest's late wake-ups alone, too
    floor["late_ratio"] = round(case["late_per_10k"] / deadlines, 2) if deadlines > 0 else None
    floor["late_ratio_to_samples"] = round(case["late_per_10k"] / above, 2) if above > 0 else None
    floor["wake_p99_ratio"] = (
        round(wake["p99"] / floor["latency_us"]["p99"], 2) if floor["latency_us"]["p99"] > 0 else None
    )
    return floor


def _finite(a: np.ndarray) -> np.ndarray:
    finite: np.ndarray = a[np.isfinite(a)]
    return finite
