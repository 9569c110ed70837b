"""``cheope bench``: how fast and how regular the loop is, with the simulator beside it.

One command measures everything the timing issue asks for and writes a table (stdout), one
JSON file and PNG plots of the period-error distribution:

1. the cyclic PDO path: this project's ``CyclicExchange`` against the ``canopen`` package's
   own PDO objects doing the same cycle (3 RPDOs + SYNC out, 3 drive + 2 sensor TPDOs in,
   decoded to SI units), CPU time per cycle, on python-can's in-process virtual bus;
2. the step's cost in Python against Ruckig's own reported calculation time, in process on
   simulated time (``sim_backend.loopback``), with a cProfile of the hottest functions;
3. for each configured rate (400 Hz on classical CAN, 1 kHz on CAN FD by default):
   a. the loop shell's sleeper against a naive ``time.sleep(period)`` loop doing the same
      busy work (the step's measured median), in alternating blocks so machine noise hits
      both arms alike: drift and jitter;
   b. the real service (``run_controller``) against the simulator as its own process:
      achieved rate, period error p50/p99/p99.9/max, late cycles per 10 000, step compute
      time, last TPDO in -> outputs ready and -> RPDOs out, CPU use of controller (process
      and loop thread) and simulator, computed and measured bus load.

Definitions (also in the JSON):
- period error: |(wake_k - wake_{k-1}) - period|, wake-ups on the monotonic clock;
- late cycle: woke more than ``late_fraction`` of a period after its deadline, or a deadline
  skipped because the loop fell a whole period behind (an overrun);
- measured bus load: every frame seen on the bus (the udp_multicast bus echoes our own) times
  its duration by ``drivers.bus_load`` with its own FD/BRS flags, worst-case stuffing, per
  second of the run; it counts classical frames where a device answers with classical frames.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import math
import os
import pstats
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, SupportsInt, cast

import numpy as np

from controller.cli_output import strict_json
from controller.errors import InputError
from controller.experiments import experiment_for
from controller.shell.loop import period_error_us
from controller.shell.realtime import RealtimeOptions
from drivers import cob_ids
from drivers.bus_load import measured_bus_load

if TYPE_CHECKING:
    import subprocess
    from queue import SimpleQueue

    import can
    from matplotlib.axes import Axes
    from ruckig import InputParameter

    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
    from controller.core.ports import CycleTiming
    from controller.core.setpoint_smoothing import Setpoint, SmoothingResult
    from drivers.bus import BusSpec

    class StubBus(can.BusABC):
        """The bus ``stub_bus`` returns, declared for the type checker: the class itself is made
        there, so that python-can is imported only when the PDO comparison runs."""

        queue: SimpleQueue[can.Message]
        sent: int


# The benchmark's results are JSON-shaped (bench.json): nested dicts of numbers, strings and lists,
# their keys set where they are built. The code that reads them back (the cyclictest ratios, the
# plots, the table) reads them as Json rather than through one TypedDict per table.
Json = dict[str, Any]


# -- statistics (pure) ------------------------------------------------------------------------


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


# -- the two sleepers, side by side -----------------------------------------------------------


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


# -- probes on the real loop ------------------------------------------------------------------


class LoopProbe:
    """Observer and frame sink of one ``run_controller`` run; preallocated, a few hundred ns a call.

    Per cycle k it keeps: the wake error and step time (from the loop's ``CycleTiming``), the
    arrival of the last TPDO of the cycle, and when the outputs were ready (end of the
    observers' turn); from the frame sink, when the first RPDO of cycle k + 1 went out, and
    how long after this cycle's SYNC went out its last TPDO arrived (the devices' answer). It
    also counts every frame on the bus by COB-ID for the measured bus load, and samples CPU
    times once a second (the loop thread's own, the process's, the simulator's).
    """

    def __init__(
        self,
        capacity: int,
        tpdo_ids: frozenset[int],
        first_rpdo_id: int,
        sim_pid: int | None,
        sample_every: int,
    ) -> None:
        self.capacity = capacity
        self.wake_error_s = np.zeros(capacity)
        self.step_s = np.zeros(capacity)
        self.deadline_index = np.zeros(capacity, dtype=np.int64)
        self.ready_after_tpdo_s = np.full(capacity, np.nan)
        self.rpdo_after_tpdo_s = np.full(capacity, np.nan)
        self.answer_s = np.full(capacity, np.nan)  # SYNC out -> last TPDO in
        self._sync_s = math.nan
        self.n = 0
        self._tpdo_ids = tpdo_ids
        self._first_rpdo_id = first_rpdo_id
        self._last_tpdo_s = math.nan
        self._prev_last_tpdo_s = math.nan
        self._rpdo_index = 0
        self.frames: dict[int, int] = {}  # COB-ID -> frames received once the loop runs
        self.frames_out: dict[int, int] = {}  # COB-ID -> frames sent once the loop runs
        self.frame_shape: dict[int, tuple[int, bool, bool]] = {}  # COB-ID -> (bytes, is_fd, brs)
        self.sim_pid = sim_pid
        self.sample_every = sample_every
        self.samples: list[tuple[float, ...]] = []  # (monotonic, thread, process, sim, writer) [s]
        self.writer_pid: int | None = None  # the MCAP writer process, found among our children

    def sink(self, outgoing: bool, t: float, msg: can.Message) -> None:
        cid = msg.arbitration_id
        if self.n > 0:  # the bus load of the cyclic traffic: node set-up frames are not counted
            counts = self.frames_out if outgoing else self.frames
            k = counts.get(cid)
            if k is None:
                self.frame_shape[cid] = (len(msg.data), bool(msg.is_fd), bool(msg.bitrate_switch))
                k = 0
            counts[cid] = k + 1
        if outgoing:
            if cid == cob_ids.SYNC:
                self._sync_s = t
            elif cid == self._first_rpdo_id:
                i = self._rpdo_index
                if i < self.capacity:
                    self.rpdo_after_tpdo_s[i] = t - self._prev_last_tpdo_s
                self._rpdo_index = i + 1
            return
        if cid in self._tpdo_ids:
            self._last_tpdo_s = t

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
        now = time.monotonic()
        i = self.n
        if i < self.capacity:
            self.wake_error_s[i] = timing.wake_error_s
            self.step_s[i] = timing.step_s
            self.deadline_index[i] = cycle
            self.ready_after_tpdo_s[i] = now - self._last_tpdo_s
            self.answer_s[i] = self._last_tpdo_s - self._sync_s
        self.n = i + 1
        # the first RPDO of the next cycle pairs with this cycle's last TPDO
        self._prev_last_tpdo_s = self._last_tpdo_s
        self._rpdo_index = i + 1
        if i % self.sample_every == 0:
            if self.writer_pid is None:
                self.writer_pid = child_pid("logs.session_writer")
            self.samples.append(
                (
                    now,
                    time.thread_time(),
                    time.process_time(),
                    process_cpu_s(self.sim_pid),
                    process_cpu_s(self.writer_pid),
                )
            )


def process_cpu_s(pid: int | None) -> float:
    """user + system CPU time of ``pid`` from /proc [s] (nan when unknown)."""
    if pid is None:
        return math.nan
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def child_pid(command_fragment: str) -> int | None:
    """The pid of a child of this process whose command line contains ``command_fragment``."""
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
            if ppid != me:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                if command_fragment.encode() in f.read():
                    return int(entry)
        except (OSError, ValueError, IndexError):
            continue
    return None


def cpu_use_percent(samples: list[tuple[float, ...]]) -> dict[str, float | None]:
    """CPU use between the first and the last sample, in % of one CPU."""
    keys = ("loop_thread", "controller_process", "simulator_process", "writer_process")
    if len(samples) < 2:
        return dict.fromkeys(keys)
    first, last = samples[0], samples[-1]
    dt = last[0] - first[0]

    def pct(a: float, b: float) -> float | None:
        return None if math.isnan(a) or math.isnan(b) else round(100.0 * (b - a) / dt, 1)

    # the writer starts after the first sample: take its first known value
    writer0 = next((x[4] for x in samples if not math.isnan(x[4])), math.nan)
    writer_dt = next((last[0] - x[0] for x in samples if not math.isnan(x[4])), dt)
    writer = (
        None
        if math.isnan(writer0) or math.isnan(last[4]) or writer_dt <= 0
        else round(100.0 * (last[4] - writer0) / writer_dt, 1)
    )
    return {
        "loop_thread": pct(first[1], last[1]),
        "controller_process": pct(first[2], last[2]),
        "simulator_process": pct(first[3], last[3]),
        "writer_process": writer,
    }


# -- the simulator process --------------------------------------------------------------------


def simulator(
    spec: BusSpec,
    overrides: list[str],
    config_path: str | None,
    rt: RealtimeOptions,
    ready_timeout_s: float = 120.0,
) -> AbstractContextManager[subprocess.Popen[str]]:
    """``cheope sim`` as a child process with its own real-time options."""
    from controller.tools.demo import simulator_process

    return simulator_process(spec, config_path, overrides, ready_timeout_s, extra_args=rt.cli_args())


# -- one configuration against the simulator --------------------------------------------------


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
) -> dict[str, object]:
    from controller.assembly import planned_bus_load
    from controller.config import load_config, parse_override
    from controller.shell.service import run_controller
    from controller.tasks.registry import task_entry
    from controller.tools.demo import random_udp_port
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
        with machine_floor_beside(case.rate_hz, min(cyclictest_s, duration_s), rt, late_fraction) as floor:
            summary = run_controller(
                cfg,
                spec,
                max_duration_s=duration_s,
                observers=(probe,) if lap_report is None else (probe, lap_report[0]),
                frame_sink=probe.sink,
                realtime=rt,
            )
    if lap_report is not None:
        summary["task_report"] = lap_report[1]()
    n = min(probe.n, capacity)
    skip = min(n // 10, round(cfg.loop.rate_hz))  # the first second: node set-up done, caches cold
    wake = probe.wake_error_s[skip:n]
    overruns = _count(summary.get("overruns", 0))
    samples = probe.samples
    seconds = samples[-1][0] - samples[0][0] if len(samples) > 1 else 0.0
    # each frame once in either direction: the service's bus tap drops the bus's echoes of our own
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
        "simulator_realtime": sim_rt.describe(),  # as asked of the simulator
        "final_mode": summary["final_mode"],
        "fault_reason": summary.get("fault_reason"),
        "cycles": _count(summary["cycles"]),
        "achieved_rate_hz": summary["achieved_rate_hz"],
        "period_error_us": percentiles_us(per_err),
        "wake_latency_us": percentiles_us(wake * 1e6),
        "late_per_10k": round(late_per_10k(wake, period, late_fraction, overruns), 2),
        "late_fraction_of_period": late_fraction,
        "overruns": overruns,
        "step_us": percentiles_us(probe.step_s[skip:n] * 1e6),
        "tpdo_to_ready_us": percentiles_us(_finite(probe.ready_after_tpdo_s[skip:n]) * 1e6),
        "sync_to_last_tpdo_us": percentiles_us(_finite(probe.answer_s[skip:n]) * 1e6),
        "tpdo_to_rpdo_us": percentiles_us(_finite(probe.rpdo_after_tpdo_s[skip + 1 : n]) * 1e6),
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
    from controller.tools.cyclictest import INSTALL_HINT, CyclictestError, cyclictest_beside, cyclictest_path

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
    if above is None:  # the case's threshold differs from the one cyclictest was asked for
        return {**floor, "error": f"no cyclictest rate above {late_us:g} us"}
    wake = case["wake_latency_us"]
    floor["late_us"] = late_us
    floor["late_ratio"] = round(case["late_per_10k"] / above, 2) if above > 0 else None
    floor["wake_p99_ratio"] = (
        round(wake["p99"] / floor["latency_us"]["p99"], 2) if floor["latency_us"]["p99"] > 0 else None
    )
    return floor


def _finite(a: np.ndarray) -> np.ndarray:
    finite: np.ndarray = a[np.isfinite(a)]
    return finite


# -- the step in Python against Ruckig's own calculation time ---------------------------------


def step_breakdown(
    config_path: str | None, overrides: list[str], rate_hz: float, cycles: int, profile_top: int = 12
) -> dict[str, object]:
    """Run the law on the in-process loopback plant (simulated time): step time vs Ruckig's.

    Ruckig's reported time is ``OutputParameter.calculation_duration`` of a second Ruckig
    object fed the same input with ``update`` (``calculate``, which the law uses, reports none).
    """
    from ruckig import OutputParameter, Ruckig, RuckigError

    from controller.assembly import build_law
    from controller.config import load_config, parse_override
    from controller.core.cycle_data import cycle_inputs
    from controller.shell.loop import SimulatedTime
    from sim_backend.loopback import LoopbackExchange

    cfg = load_config(config_path, dict(parse_override(s) for s in [*overrides, f"loop.rate_hz={rate_hz}"]))
    law = build_law(cfg)
    smoother = law.smoother
    dofs = len(cfg.actuators.node_ids)
    twin, out = Ruckig(dofs), OutputParameter(dofs)
    reported_us: list[float] = []
    wrapper_s: list[float] = []
    inner = smoother._calculate

    def timed_calculate(inp: InputParameter, current: Setpoint) -> SmoothingResult:
        t0 = time.perf_counter()
        result = inner(inp, current)
        wrapper_s.append(time.perf_counter() - t0)
        try:
            twin.update(inp, out)
            reported_us.append(out.calculation_duration)
        except RuckigError:
            pass
        return result

    # an instance attribute wrapping the bound method: this law object only
    smoother._calculate = timed_calculate  # type: ignore[method-assign]  # deliberate, see above
    sim = SimulatedTime()
    exchange = LoopbackExchange(cfg, sim.clock)
    state = law.initial_state()
    outputs = None
    period = cfg.period_s
    step_s = np.empty(cycles)
    profiler = cProfile.Profile()
    for k in range(cycles):
        sim.sleep_until(k * period)
        exchange.send(outputs)
        inputs = cycle_inputs(exchange.collect(k * period + period))
        t0 = time.perf_counter()
        state, outputs, _ = law.step(state, inputs, k * period)
        step_s[k] = time.perf_counter() - t0
    # a second pass of the same cycles under cProfile (the timed pass above is unprofiled)
    sim2 = SimulatedTime()
    law2 = build_law(cfg)
    exchange2 = LoopbackExchange(cfg, sim2.clock)
    state2, outputs2 = law2.initial_state(), None
    profiler.enable()
    for k in range(cycles):
        sim2.sleep_until(k * period)
        exchange2.send(outputs2)
        inputs2 = cycle_inputs(exchange2.collect(k * period + period))
        state2, outputs2, _ = law2.step(state2, inputs2, k * period)
    profiler.disable()
    buf = io.StringIO()
    pstats.Stats(profiler, stream=buf).sort_stats("tottime").print_stats(profile_top)
    step_us = step_s * 1e6
    reported = np.asarray(reported_us)
    wrapped = np.asarray(wrapper_s) * 1e6
    return {
        "rate_hz": rate_hz,
        "cycles": cycles,
        "final_mode": state.mode.name,
        "step_us": percentiles_us(step_us),
        "ruckig_calls_per_cycle": round(len(wrapper_s) / cycles, 2),
        "ruckig_reported_calculation_us": percentiles_us(reported),
        "ruckig_call_in_python_us": percentiles_us(wrapped),
        "ruckig_share_of_step_percent": round(100.0 * float(np.sum(reported)) / float(np.sum(step_us)), 1)
        if step_us.sum() > 0
        else 0.0,
        "profile_top_tottime": _profile_lines(buf.getvalue()),
    }


def _profile_lines(text: str) -> list[str]:
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.lstrip().startswith("ncalls")), None)
    return [] if start is None else [line.rstrip() for line in lines[start:] if line.strip()]


# -- the cyclic PDO path against canopen's PDO objects ----------------------------------------


def stub_bus() -> StubBus:
    """A python-can bus that costs (almost) nothing: sends are counted, frames to receive are
    queued by the caller. Lets the PDO comparison measure the PDO path, not a transport
    (python-can's virtual bus deep-copies every frame for every receiver, ~10 us each)."""
    import queue

    import can

    class _StubBus(can.BusABC):
        def __init__(self) -> None:
            self.queue: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
            self.sent = 0
            super().__init__(channel="stub")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            self.sent += 1

        def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
            try:
                return self.queue.get(timeout=timeout) if timeout else self.queue.get_nowait(), False
            except queue.Empty:
                return None, False

    return cast("StubBus", _StubBus())  # the same attributes as StubBus, declared above


def compare_pdo_paths(
    cycles: int, config_path: str | None = None, overrides: list[str] | None = None
) -> dict[str, object]:
    """CPU time per cycle of the cyclic PDO path: this project's exchange vs canopen's PDO objects.

    Both run the same cycle on a stub bus (``stub_bus``): 3 RPDOs and SYNC out, then the 3 drive
    TPDOs and 2 sensor TPDOs (prebuilt frames, queued by the "device") received, decoded and
    turned into SI values. canopen's arm uses ``RemoteNode`` PDO maps read from the shipped EDS
    files: it sets the mapped variables and calls ``transmit`` per RPDO and ``sync.transmit``,
    then waits until its notifier thread has dispatched all five TPDOs (a semaphore released
    by PDO callbacks) and reads the mapped values. CPU time is the process's (both threads).
    """
    import can
    import canopen

    from controller.config import load_config, parse_override
    from controller.core.cycle_data import CycleOutputs
    from drivers.cyclic_exchange import CyclicExchange
    from drivers.pdo_codec import FORCE_N_PER_COUNT, TORQUE_NM_PER_COUNT, PositionScale, encode_drive_tpdo
    from sim_backend.server import DRIVE_EDS, SENSOR_EDS

    cfg = load_config(config_path, dict(parse_override(s) for s in (overrides or [])))
    ids = tuple(cfg.actuators.node_ids)
    sid = cfg.sensor.node_id
    scale = PositionScale(cfg.actuators.counts_per_m)
    tpdos = [
        can.Message(
            arbitration_id=cob_ids.tpdo1(i),
            data=encode_drive_tpdo(0x1237, 5_000_000 + i),
            is_extended_id=False,
        )
        for i in ids
    ]
    tpdos += [
        can.Message(
            arbitration_id=cob_ids.tpdo1(sid), data=bytes([1, 0, 2, 0, 3, 0, 0, 7]), is_extended_id=False
        ),
        can.Message(
            arbitration_id=cob_ids.tpdo2(sid), data=bytes([4, 0, 5, 0, 6, 0, 0, 7]), is_extended_id=False
        ),
    ]
    outputs = CycleOutputs(controlwords=(0x0F,) * len(ids), targets=(0.5,) * len(ids))

    def measure(cycle: Callable[[], None]) -> tuple[float, float]:
        for _ in range(min(500, cycles)):
            cycle()
        c0, w0 = time.process_time(), time.perf_counter()
        for _ in range(cycles):
            cycle()
        return (time.process_time() - c0) / cycles * 1e6, (time.perf_counter() - w0) / cycles * 1e6

    results: dict[str, object] = {
        "cycles": cycles,
        "frames_per_cycle": {"out": len(ids) + 1, "in": len(tpdos)},
    }
    bus = stub_bus()
    # the cost of decoding a cycle, not of waiting out its answer window
    ex = CyclicExchange(
        bus, ids, scale, sid, cfg.loop.controller_node_id, heartbeat_every=10**9, answer_window_s=0.0
    )

    def project_cycle() -> None:
        ex.send(outputs)
        for m in tpdos:
            bus.queue.put(m)
        inputs = ex.collect(time.monotonic() + 0.01)
        if inputs.sensor is None or not inputs.sensor.fresh:
            raise RuntimeError("project arm: sensor frames missing")

    project_cpu_us, project_wall_us = (round(x, 2) for x in measure(project_cycle))
    results["project_cpu_us"], results["project_wall_us"] = project_cpu_us, project_wall_us
    bus.shutdown()
    bus = stub_bus()
    net = canopen.Network(bus)
    net.connect()
    try:
        nodes = [net.add_node(i, str(DRIVE_EDS)) for i in ids]
        sensor = net.add_node(sid, str(SENSOR_EDS))
        arrived = threading.Semaphore(0)
        for node in nodes:
            _read_from_od(node.rpdo)
            _read_from_od(node.tpdo)
            node.tpdo[1].add_callback(lambda _m: arrived.release())
        _read_from_od(sensor.tpdo)
        sensor.tpdo[1].add_callback(lambda _m: arrived.release())
        sensor.tpdo[2].add_callback(lambda _m: arrived.release())
        rpdos = [n.rpdo[1] for n in nodes]
        rvars = [(m["Controlword"], m["Target position"]) for m in rpdos]
        tvars = [(n.tpdo[1]["Statusword"], n.tpdo[1]["Position actual value"]) for n in nodes]
        fvars, tqvars = list(sensor.tpdo[1])[:3], list(sensor.tpdo[2])[:3]

        def canopen_cycle() -> None:
            for m, (cw, tp), c, x in zip(rpdos, rvars, outputs.controlwords, outputs.targets, strict=True):
                cw.raw = c
                tp.raw = scale.to_counts(x)
                m.transmit()
            net.sync.transmit()
            for m in tpdos:
                bus.queue.put(m)
            for _ in range(len(tpdos)):
                if not arrived.acquire(timeout=1.0):
                    raise RuntimeError("canopen arm: a TPDO did not arrive")
            _ = [(sw.raw, scale.to_unit(pos.raw)) for sw, pos in tvars]
            _ = [v.raw * FORCE_N_PER_COUNT for v in fvars] + [v.raw * TORQUE_NM_PER_COUNT for v in tqvars]

        canopen_cpu_us, canopen_wall_us = (round(x, 2) for x in measure(canopen_cycle))
        results["canopen_cpu_us"], results["canopen_wall_us"] = canopen_cpu_us, canopen_wall_us
    finally:
        net.disconnect()
    results["canopen_over_project"] = round(canopen_cpu_us / project_cpu_us, 2)
    return results


class _PdoMaps(Protocol):
    """canopen's ``RPDO``/``TPDO`` map collections (``PdoBase``), whose ``read`` is unannotated."""

    def read(self, from_od: bool = False) -> None: ...


def _read_from_od(maps: _PdoMaps) -> None:
    """Set up the PDO maps from the object dictionary (the EDS), not over SDO."""
    maps.read(from_od=True)


def bus_frame_cost(spec_text: str, fd: bool, frames: int = 2000) -> dict[str, object]:
    """Wall time of python-can's ``send`` and ``recv`` per frame on the configured bus.

    Two buses on the same channel, one frame at a time (send, a 200 µs pause, receive), so
    each ``recv`` finds its frame waiting: the cost of the interface itself (on udp_multicast:
    msgpack and a datagram per frame), not of waiting. Also counts how many of the sender's
    own frames come back to it: every one is a receive the loop pays for and discards.
    """
    import can

    from controller.tools.demo import random_udp_port
    from drivers.bus import open_bus, parse_bus_spec

    spec = parse_bus_spec(spec_text, fd=fd, udp_port=random_udp_port())
    tx, rx = open_bus(spec), open_bus(spec)
    msg = can.Message(arbitration_id=0x201, data=bytes(8), is_extended_id=False, is_fd=fd, bitrate_switch=fd)
    send_us, recv_us = np.empty(frames), np.empty(frames)
    own = 0
    try:
        for k in range(frames):
            t0 = time.perf_counter()
            tx.send(msg)
            t1 = time.perf_counter()
            time.sleep(2e-4)
            t2 = time.perf_counter()
            got = rx.recv(timeout=0.1)
            t3 = time.perf_counter()
            if got is None:
                raise RuntimeError(f"bus_frame_cost: frame {k} did not arrive on {spec}")
            send_us[k], recv_us[k] = (t1 - t0) * 1e6, (t3 - t2) * 1e6
            own += tx.recv(timeout=0.0) is not None
    finally:
        tx.shutdown()
        rx.shutdown()
    return {
        "bus": str(spec),
        "frames": frames,
        "send_us": percentiles_us(send_us),
        "recv_us": percentiles_us(recv_us),
        "own_frames_received_back": own,
    }


# -- the whole benchmark ----------------------------------------------------------------------

# A timing benchmark must run its whole length: a burst of late or missing frames on a loaded
# machine is counted, not turned into a quick stop (``--strict`` keeps the configured reactions).
TOLERANT_SAFETY = (
    "loop.max_missing_cycles=1000",
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
    fd_from_hz: float = 500.0,
    progress: Callable[[str], None] = lambda s: None,
    schedulers: tuple[str, ...] = ("realtime",),
    cyclictest_s: float = 30.0,
    task: str = "path",
    instructions: bool = False,
) -> dict[str, object]:
    from controller.assembly import planned_bus_load
    from controller.config import load_config, parse_override
    from controller.shell.realtime import apply_realtime

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
    from controller.tools.cyclictest import INSTALL_HINT, cyclictest_path

    if cyclictest_s > 0 and cyclictest_path() is None:
        progress(INSTALL_HINT)
    report["work_per_cycle"] = work_per_cycle(task, instructions, progress)
    progress("cyclic PDO path: project vs canopen ...")
    report["pdo_path"] = compare_pdo_paths(20000 if duration_s >= 60 else 5000, config_path, overrides)
    progress("python-can send/recv per frame on the configured bus ...")
    report["bus_frame_cost"] = bus_frame_cost(cfg.bus.can, fd=any(r >= fd_from_hz for r in rates_hz))
    cases: list[dict[str, object]] = []
    breakdowns: list[dict[str, object]] = []
    sleepers: list[dict[str, object]] = []
    has_experiment = experiment_for(cfg.task.kind) is not None
    for rate in rates_hz:
        case = BenchCase(rate, fd=rate >= fd_from_hz)
        progress(f"{rate:g} Hz: step cost and Ruckig in process ...")
        # a task's experiment in process as over the bus (the contour's tracking laps are what it costs)
        bd: Json = step_breakdown(
            config_path,
            [*overrides, "task.path.laps=10.0"],
            rate,
            cycles=int((duration_s if has_experiment else min(10.0, duration_s)) * rate),
        )
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
    """The deterministic figure beside the timed ones (controller/tools/cycle_work.py): the task's
    work per cycle at the default configuration over its fixed window, against the budget;
    machine instructions too with ``instructions`` (valgrind, minutes). None for a task without a window."""
    from controller.tools.cycle_work import (
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


# -- output -----------------------------------------------------------------------------------


def format_table(report: Json) -> str:
    lines = []
    cases = report["cases"]
    header = f"{'':34}" + "".join(f"{c['case']:>24}" for c in cases)
    lines.append(header)

    def row(label: str, fn: Callable[[Json], str]) -> None:
        lines.append(f"{label:34}" + "".join(f"{fn(c):>24}" for c in cases))

    def q(d: Json, keys: tuple[str, ...] = ("p50", "p99", "p99_9", "max")) -> str:
        return "/".join(f"{d[k]:.0f}" for k in keys)

    row("achieved rate [Hz]", lambda c: f"{c['achieved_rate_hz']:.2f}")
    row("period error p50/p99/p99.9/max us", lambda c: q(c["period_error_us"]))
    row("wake latency p50/p99/p99.9/max us", lambda c: q(c["wake_latency_us"]))
    row("late cycles per 10 000", lambda c: f"{c['late_per_10k']:.1f} ({c['overruns']} skipped)")
    row("step compute p50/p99 us", lambda c: q(c["step_us"], ("p50", "p99")))
    row("SYNC out -> last TPDO in p50/p99 us", lambda c: q(c["sync_to_last_tpdo_us"], ("p50", "p99")))
    row("last TPDO -> outputs ready p50/p99", lambda c: q(c["tpdo_to_ready_us"], ("p50", "p99")))
    row("last TPDO -> RPDOs out p50/p99 us", lambda c: q(c["tpdo_to_rpdo_us"], ("p50", "p99")))
    row(
        "CPU loop thread / process [%]",
        lambda c: "{} / {}".format(
            c["cpu_percent_of_one_core"]["loop_thread"], c["cpu_percent_of_one_core"]["controller_process"]
        ),
    )
    row("CPU process excluding the spin [%]", _process_without_spin)
    row("CPU simulator [%]", lambda c: f"{c['cpu_percent_of_one_core']['simulator_process']}")
    row(
        "bus load computed / measured [%]",
        lambda c: "{:.1f} / {:.1f}".format(
            c["bus_load_percent"]["computed"], c["bus_load_percent"]["measured"]["percent"]
        ),
    )
    row("CPU MCAP writer [%]", lambda c: f"{c['cpu_percent_of_one_core'].get('writer_process')}")
    f = report["bus_frame_cost"]
    row("python-can floor ctrl / sim [%]", lambda c: "{} / {}".format(*python_can_floor_percent(c, f)))
    row(
        "missing frames drive/sensor",
        lambda c: "{}/{}".format(
            (c["missing_frames"] or {}).get("drive"), (c["missing_frames"] or {}).get("sensor")
        ),
    )
    row(
        "laps 4-5 force error RMS [N]",
        lambda c: (
            "/".join(f"{lap['force_error_rms_n']:.2f}" for lap in (c.get("task_laps") or [])[3:5]) or "-"
        ),
    )
    row(
        "cyclictest p50/p99/p99.9/max us",
        lambda c: q(c["cyclictest"]["latency_us"]) if "latency_us" in c.get("cyclictest", {}) else "-",
    )
    row(
        "cyclictest late per 10 000",
        lambda c: (
            "{}".format(c["cyclictest"]["per_10k_above_us"][f"{c['cyclictest']['late_us']:g}"])
            if "latency_us" in c.get("cyclictest", {})
            else "-"
        ),
    )
    row(
        "late ratio loop / cyclictest",
        lambda c: f"{c['cyclictest'].get('late_ratio')}" if "latency_us" in c.get("cyclictest", {}) else "-",
    )
    row(
        "wake p99 ratio loop / cyclictest",
        lambda c: (
            f"{c['cyclictest'].get('wake_p99_ratio')}" if "latency_us" in c.get("cyclictest", {}) else "-"
        ),
    )
    row("final mode", lambda c: c["final_mode"])
    for c in cases:
        if c.get("fault_reason"):
            lines.append(f"  {c['case']}: fault: {c['fault_reason']}")
        if "error" in c.get("cyclictest", {}):
            lines.append(f"  {c['case']}: {c['cyclictest']['error']}")
        elif "command" in c.get("cyclictest", {}):
            lines.append(f"  {c['case']}: floor by `{c['cyclictest']['command']}`")
    lines.append("")
    lines.append("loop shell vs naive time.sleep(period), same busy work, alternating blocks:")
    for s in report["sleepers"]:
        for arm in ("deadline", "naive"):
            a = s[arm]
            lines.append(
                f"  {s['rate_hz']:>6g} Hz {arm:8} rate {a['achieved_rate_hz']:>9.2f} Hz  drift "
                f"{a['drift_ms_per_s']:>8.3f} ms/s  period error p50/p99/p99.9/max "
                f"{q(a['period_error_us'])} us  late/10k {a['late_per_10k']:.1f}"
            )
    lines.append("")
    w = report.get("work_per_cycle")
    if w:
        b = w["budget_per_cycle"]
        ipc = w.get("instructions_per_cycle")
        lines.append(
            f"work per cycle, {w['task']} task, cycles {w['skip']}-{w['skip'] + w['cycles'] - 1} (deterministic): "
            f"{w['bytecodes_per_cycle']:.0f} bytecodes (budget {b['bytecodes']}), {w['c_calls_per_cycle']:.0f} C calls "
            f"(budget {b['c_calls']}), {w['python_calls_per_cycle']:.0f} Python calls, "
            + (f"{ipc} instructions (callgrind), " if ipc else "")
            + f"{w['tracked_objects_left_per_cycle']} tracked objects left"
            + (f"; OVER BUDGET: {'; '.join(w['over_budget'])}" if w["over_budget"] else "")
        )
    p = report["pdo_path"]
    lines.append(
        f"cyclic PDO path, CPU per cycle (stub bus, 4 frames out, 5 in): project {p['project_cpu_us']} us, "
        f"canopen PDO objects {p['canopen_cpu_us']} us (x{p['canopen_over_project']}); wall "
        f"{p['project_wall_us']} / {p['canopen_wall_us']} us"
    )
    f = report["bus_frame_cost"]
    lines.append(
        f"python-can per frame on {f['bus']}: send p50/p99 {q(f['send_us'], ('p50', 'p99'))} us, "
        f"recv p50/p99 {q(f['recv_us'], ('p50', 'p99'))} us; own frames received back "
        f"{f['own_frames_received_back']} of {f['frames']}"
    )
    for b in report["step_breakdown"]:
        lines.append(
            f"step at {b['rate_hz']:g} Hz (in process): p50/p99 {q(b['step_us'], ('p50', 'p99'))} us; "
            f"Ruckig reported {q(b['ruckig_reported_calculation_us'], ('p50', 'p99'))} us, "
            f"Ruckig call in Python {q(b['ruckig_call_in_python_us'], ('p50', 'p99'))} us, "
            f"{b['ruckig_calls_per_cycle']} calls/cycle: Ruckig {b['ruckig_share_of_step_percent']} % of step"
        )
    lines.append(
        f"classical CAN 1 Mbit/s at 1 kHz: computed load {report['classical_can_1khz_computed_load_percent']} %"
        " (over the limit: refused)"
    )
    for path in report["plots"]:
        lines.append(f"plot {path}")
    return "\n".join(lines)


def _process_without_spin(case: Json) -> str:
    process, spin = (
        case["cpu_percent_of_one_core"]["controller_process"],
        case.get("spin_percent_of_one_core"),
    )
    return "-" if process is None or spin is None else f"{process - spin:.1f} (spin {spin})"


def python_can_floor_percent(case: Json, cost: Json) -> tuple[float, float]:
    """python-can's own cost per process at the case's rate, from the per-frame costs [% of a core].

    Every frame on the udp_multicast bus reaches every process, its own included: both the
    controller and the simulator receive all of them; each sends its own.
    """
    per_cycle = case["frames_per_cycle"]
    send, recv = cost["send_us"]["p50"], cost["recv_us"]["p50"]
    rate = case["rate_hz"]
    seen, ours = per_cycle["in"], per_cycle["out"]
    controller = rate * (ours * send + seen * recv) * 1e-4
    simulator = rate * (max(0.0, seen - ours) * send + seen * recv) * 1e-4
    return round(controller, 1), round(simulator, 1)


def _bench_tasks() -> tuple[str, ...]:
    """The tasks the bench can run over the bus: those of its robot, the shipped configuration's."""
    from controller.config import load_config, runnable_tasks

    return runnable_tasks(load_config().robot.kind)


def add_bench_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--config", help="TOML configuration (default: the shipped one)")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a configuration key"
    )
    ap.add_argument("--rates", default="400,1000", help="loop rates to measure [Hz], comma-separated")
    ap.add_argument(
        "--duration", type=float, default=300.0, help="seconds per rate with the simulator (default 300)"
    )
    ap.add_argument(
        "--compare", type=float, default=20.0, help="seconds per rate of loop shell vs naive sleep"
    )
    ap.add_argument("--fd-from", type=float, default=500.0, help="rates from this one up run on CAN FD [Hz]")
    ap.add_argument("--late-fraction", type=float, default=0.1, help="late: woke this part of a period after")
    ap.add_argument("--sim-rt-priority", type=int, metavar="N", help="SCHED_FIFO priority of the simulator")
    ap.add_argument("--sim-cpu", metavar="CPUS", help="CPU affinity of the simulator")
    ap.add_argument(
        "--output-dir", default="bench", metavar="DIR", help="directory for bench.json and the PNG plots"
    )
    ap.add_argument("--out", dest="output_dir", help=argparse.SUPPRESS)  # the spelling before --output-dir
    ap.add_argument(
        "--task",
        choices=_bench_tasks(),
        default="path",
        help="the task over the bus: the circle (default), or another task of the configured robot "
        "(a task with an experiment, as the contour, runs its own length)",
    )
    ap.add_argument(
        "--schedulers",
        default="realtime,normal",
        help="run each rate with the real-time options (realtime) and/or without (normal)",
    )
    ap.add_argument(
        "--cyclictest",
        type=float,
        default=30.0,
        metavar="S",
        help="seconds of cyclictest beside each case (0: none)",
    )
    ap.add_argument(
        "--instructions",
        action="store_true",
        help="also machine instructions per cycle (valgrind's callgrind; a few minutes)",
    )
    ap.add_argument("--json", action="store_true", help="print the JSON instead of the table")
    ap.add_argument(
        "--strict",
        action="store_true",
        help="keep the configured safety reactions (default: late/missing frames only warn)",
    )


def checked_bench_arguments(
    args: argparse.Namespace, overrides: list[str]
) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The rates and schedulers, every argument and the configuration at each rate checked before
    any section runs (``--rates 0`` failed after two sections, leaving an empty ./bench)."""
    from controller.config import load_config, parse_override
    from controller.output_paths import check_output_dir

    try:
        rates = tuple(float(r) for r in args.rates.split(","))
    except ValueError:
        raise InputError(
            f"--rates {args.rates!r}: expected loop rates [Hz], comma-separated, e.g. 400,1000"
        ) from None
    for name, value, ok, allowed in (
        ("--duration", args.duration, args.duration > 0, "> 0"),
        ("--compare", args.compare, args.compare >= 0, ">= 0"),
        ("--cyclictest", args.cyclictest, args.cyclictest >= 0, ">= 0"),
        ("--fd-from", args.fd_from, args.fd_from > 0, "> 0"),
        ("--late-fraction", args.late_fraction, 0 < args.late_fraction < 1, "in (0, 1)"),
    ):
        if not (math.isfinite(value) and ok):
            raise InputError(f"{name} {value:g}: must be {allowed}")
    sets = dict(parse_override(s) for s in overrides)
    for rate in rates:  # the configuration's own range check of loop.rate_hz, and the rest at that rate
        try:
            load_config(args.config, {**sets, "loop.rate_hz": rate})
        except InputError as err:
            raise InputError(f"--rates {args.rates}: {err}") from None
    schedulers = tuple(x.strip() for x in args.schedulers.split(",") if x.strip())
    unknown = [x for x in schedulers if x not in ("realtime", "normal")]
    if unknown or not schedulers:
        raise InputError(f"--schedulers {args.schedulers!r}: expected realtime, normal or both")
    check_output_dir(args.output_dir, "--output-dir")
    return rates, schedulers


def run_bench_command(args: argparse.Namespace, rt: RealtimeOptions) -> int:
    from controller.shell.realtime import parse_cpus

    if args.sim_rt_priority is None and not args.sim_cpu:
        sim_rt = rt.for_simulator()  # as the demo gives it: one step below the loop, on the other CPUs
    else:
        sim_rt = RealtimeOptions(
            priority=args.sim_rt_priority,
            cpus=parse_cpus(args.sim_cpu) if args.sim_cpu else (),
            lock_memory=rt.lock_memory,
            required=rt.required,
        )
    overrides = list(args.set) if args.strict else [*TOLERANT_SAFETY, *args.set]
    if args.task != "path":
        overrides.insert(0, f'task.kind="{args.task}"')
    rates, schedulers = checked_bench_arguments(args, overrides)
    report = run_bench(
        rates,
        args.duration,
        args.compare,
        Path(args.output_dir),
        args.config,
        overrides,
        rt,
        sim_rt,
        late_fraction=args.late_fraction,
        fd_from_hz=args.fd_from,
        progress=lambda s: print(s, file=sys.stderr, flush=True),
        schedulers=schedulers,
        cyclictest_s=args.cyclictest,
        task=args.task,
        instructions=args.instructions,
    )
    print(strict_json(report, indent=2) if args.json else format_table(report))
    print(f"JSON: {Path(args.output_dir) / 'bench.json'}", file=sys.stderr)
    return 0
