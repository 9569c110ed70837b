"""Where the loop thread's CPU goes in the service: its CPU time in each part of the cycle.

    .venv/bin/python -m controller.tools.bench.loop_cpu_parts [--rate 400] [--duration 20] [--task path] [--runs 3] [--json]

``cheope bench`` gives the loop's process as one figure (% of a core, the final spin apart) and
the step's wall time; the cycle has more parts than the step. This runs the bench's case (the
service against ``cheope sim`` over the configured bus, the real-time defaults, the bench's
tolerant safety settings: controller/tools/bench/case.py) with each part of the loop wrapped in
readings of the loop thread's own CPU clock (``time.thread_time``, ``CLOCK_THREAD_CPUTIME_ID``):

- ``sleep`` to the deadline, its final spin included (``DeadlineSleeper``; the spin's own share
  is the service's ``spin_s``, given apart);
- ``send``: the exchange's RPDOs and SYNC (drivers/cyclic_exchange.py);
- ``collect``: the answer window's sleep, reading and decoding the answers;
- ``step``: the law's;
- each observer (the run summary's, the recording's hand-off, the monitoring publisher, ...);
- the exchange's optional methods, where it has them, under their own names (``cycle_deadline``
  with the kernel's SYNC, ``send_controlword_by_sdo`` for a quick stop's SDOs: exchange_hook.py);
- ``shell``: the rest of the loop thread's CPU over ``CycleLoop.run``: the step's inputs, the
  statistics, a garbage collection between cycles.

CPU time, not wall time: a sleep counts only what entering and leaving it cost. Each part is the
mean per cycle over the whole run. A reading is a system call (0.7 µs, controller/shell/
thread_usage.py), two a part and about 18 a cycle, so the total is that much above the bench's
figure of a run without them: this is where the loop's CPU goes, not the bench's figure of it.
Nothing else should run beside it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from controller.errors import InputError
from controller.tools.bench.exchange_hook import WrappedExchange
from controller.tools.bench.step_hook import StepHookedLaw

if TYPE_CHECKING:
    from controller.core.cycle_data import BusFeedback, CycleOutputs
    from controller.shell.loop import CycleLoop, Exchange, Sleeper


class PartClocks:
    """The loop thread's CPU time per named part, summed over the calls of each."""

    def __init__(self, clock: Callable[[], float] = time.thread_time) -> None:
        self.clock = clock
        self.cpu_s: defaultdict[str, float] = defaultdict(float)
        self.calls: defaultdict[str, int] = defaultdict(int)

    def timed(self, part: str, call: Callable[..., Any]) -> Callable[..., Any]:
        """``call``, its CPU time added to ``part``'s."""
        clock, cpu_s, calls = self.clock, self.cpu_s, self.calls

        def timed_call(*args: Any, **kwargs: Any) -> Any:
            c0 = clock()
            try:
                return call(*args, **kwargs)
            finally:
                cpu_s[part] += clock() - c0
                calls[part] += 1

        return timed_call


class TimedExchange(WrappedExchange):
    """The loop's exchange with its send and collect timed, and the optional methods the loop
    checks for, where the exchange has them, under their own names (exchange_hook.py)."""

    def __init__(self, exchange: Exchange, clocks: PartClocks) -> None:
        super().__init__(exchange, clocks.timed)
        self._send = clocks.timed("send", exchange.send)
        self._collect = clocks.timed("collect", exchange.collect)

    def send(self, outputs: CycleOutputs | None, send_by_s: float = math.inf) -> bool:
        return bool(self._send(outputs, send_by_s))

    def collect(self, deadline_s: float) -> BusFeedback:
        feedback: BusFeedback = self._collect(deadline_s)
        return feedback


class TimedSleeper:
    """The loop's sleeper, each sleep to a deadline timed (its final spin included)."""

    def __init__(self, sleeper: Sleeper, clocks: PartClocks) -> None:
        self.inner = sleeper
        self._sleep_until = clocks.timed("sleep", sleeper.sleep_until)

    def sleep_until(self, deadline_s: float) -> None:
        self._sleep_until(deadline_s)


class TimedObserver:
    """An observer, each of its cycles timed under ``part``."""

    def __init__(self, observer: Any, part: str, clocks: PartClocks) -> None:
        self.inner = observer
        self.on_cycle = clocks.timed(part, observer.on_cycle)


def observer_parts(observers: tuple[Any, ...]) -> list[str]:
    """Each observer's part: ``observer`` and its class's name, numbered where a class repeats."""
    names = [type(o).__name__ for o in observers]
    seen: dict[str, int] = {}
    parts = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        parts.append(f"observer {name}" + (f" {seen[name]}" if names.count(name) > 1 else ""))
    return parts


class LoopCpuParts:
    """Instruments a built loop (``run_controller``'s ``on_loop_built``) and reports its parts."""

    def __init__(self, clock: Callable[[], float] = time.thread_time) -> None:
        self.clocks = PartClocks(clock)
        self.loop: CycleLoop | None = None

    def instrument(self, loop: CycleLoop) -> None:
        clocks = self.clocks
        self.loop = loop
        loop.exchange = TimedExchange(loop.exchange, clocks)
        loop.sleeper = TimedSleeper(loop.sleeper, clocks)
        loop.law = StepHookedLaw(  # type: ignore[assignment]  # the same law, its step timed
            loop.law, clocks.timed("step", lambda step, *args: step(*args))
        )
        loop.observers = tuple(
            TimedObserver(o, part, clocks)
            for o, part in zip(loop.observers, observer_parts(loop.observers), strict=True)
        )
        loop.run = clocks.timed("run", loop.run)  # type: ignore[method-assign]  # the whole run: the total

    def report(self, rate_hz: float) -> dict[str, object]:
        """Mean CPU time per cycle [us] of each part, and of the whole run; ``shell`` is the rest.
        Also in % of one core at ``rate_hz``."""
        loop = self.loop
        if loop is None or loop.cycles_done == 0:
            return {"cycles": 0}
        cycles = loop.cycles_done
        parts = dict(self.clocks.cpu_s)
        total = parts.pop("run", 0.0)
        parts["shell"] = total - sum(parts.values())
        sleeper = loop.sleeper.inner if isinstance(loop.sleeper, TimedSleeper) else loop.sleeper
        spun_s = getattr(sleeper, "spun_s", None)
        per_cycle = {name: 1e6 * s / cycles for name, s in parts.items()}
        out: dict[str, object] = {
            "cycles": cycles,
            "total_us_per_cycle": round(1e6 * total / cycles, 1),
            "total_percent_of_one_core": round(100.0 * total / cycles * rate_hz, 1),
            "parts_us_per_cycle": {name: round(us, 1) for name, us in per_cycle.items()},
            "parts_percent_of_one_core": {
                name: round(us * rate_hz * 1e-4, 2) for name, us in per_cycle.items()
            },
        }
        if isinstance(spun_s, float):  # the sleeper's final spin: its wall time
            out["spin_us_per_cycle"] = round(1e6 * spun_s / cycles, 1)
        return out


def case_overrides(task: str, overrides: list[str]) -> list[str]:
    """The configuration overrides of a case of ``task``: the bench's tolerant safety, then ``overrides``."""
    from controller.tools.bench.runner import TOLERANT_SAFETY

    return [*([f'task.kind="{task}"'] if task != "path" else []), *TOLERANT_SAFETY, *overrides]


def checked_case(rate_hz: float, task: str, overrides: list[str]) -> None:
    """The case's configuration at ``rate_hz`` loaded, before anything starts: ``InputError`` names
    what is wrong (an unknown task, an override that is no KEY=VALUE or out of range)."""
    from controller.config import load_config, parse_override

    sets = dict(parse_override(s) for s in case_overrides(task, overrides))
    load_config(None, {**sets, "loop.rate_hz": rate_hz})


def measure(
    rate_hz: float, duration_s: float, task: str, overrides: list[str], realtime: bool
) -> dict[str, object]:
    """One bench case with the loop's parts timed: the case's figures and the parts'."""
    from controller.realtime import RealtimeOptions
    from controller.tools.bench.case import BenchCase, run_case
    from controller.tools.bench.runner import FD_FROM_HZ

    rt = RealtimeOptions.default() if realtime else RealtimeOptions()
    sim_rt = rt.for_simulator() if realtime else RealtimeOptions()
    sets = case_overrides(task, overrides)
    parts = LoopCpuParts()
    case = run_case(
        BenchCase(rate_hz, fd=rate_hz >= FD_FROM_HZ, realtime=realtime),
        duration_s,
        sets,
        None,
        rt,
        sim_rt,
        0.1,
        on_loop_built=parts.instrument,
    )
    cpu = case["cpu_percent_of_one_core"]
    return {
        "case": case["case"],
        "final_mode": case["final_mode"],
        "step_us_p50": case["step_us"]["p50"],  # type: ignore[index]  # percentiles_us: a dict
        "cpu_percent_of_one_core": cpu,
        "spin_percent_of_one_core": case["spin_percent_of_one_core"],
        "loop_cpu_parts": parts.report(rate_hz),
    }


def _table(runs: list[dict[str, Any]]) -> str:
    names = sorted({n for r in runs for n in r["loop_cpu_parts"].get("parts_us_per_cycle", {})})
    lines = [
        f"{'CPU per cycle [us], mean':34s}" + "".join(f"{'run ' + str(i + 1):>10s}" for i in range(len(runs)))
    ]
    for name in names:
        lines.append(
            f"{name:34s}"
            + "".join(f"{r['loop_cpu_parts']['parts_us_per_cycle'].get(name, 0.0):10.1f}" for r in runs)
        )
    rows: list[tuple[str, Callable[[dict[str, Any]], str]]] = [
        (
            "  of it the sleep's final spin",
            lambda r: f"{r['loop_cpu_parts'].get('spin_us_per_cycle', 0.0):.1f}",
        ),
        ("loop thread, all [us]", lambda r: f"{r['loop_cpu_parts'].get('total_us_per_cycle', 0.0):.1f}"),
        (
            "loop thread, all [% of a core]",
            lambda r: f"{r['loop_cpu_parts'].get('total_percent_of_one_core', 0.0)}",
        ),
        ("case: step p50 [us] (wall)", lambda r: f"{r['step_us_p50']}"),
        ("case: loop process [%]", lambda r: f"{r['cpu_percent_of_one_core']['controller_process']}"),
        ("case: spin [%]", lambda r: f"{r['spin_percent_of_one_core']}"),
        ("case: final mode", lambda r: f"{r['final_mode']}"),
    ]
    for label, cell in rows:
        lines.append(f"{label:34s}" + "".join(f"{cell(r):>10s}" for r in runs))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m controller.tools.bench.loop_cpu_parts",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--rate", type=float, default=400.0, help="loop rate [Hz] (on CAN FD as cheope bench's)")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of each run")
    ap.add_argument("--task", default="path", help="the task over the bus (as cheope bench --task)")
    ap.add_argument("--runs", type=int, default=1, help="runs, one after the other")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="configuration override")
    ap.add_argument("--no-realtime", action="store_true", help="the loop and simulator under SCHED_OTHER")
    ap.add_argument("--json", action="store_true", help="print the runs as JSON")
    args = ap.parse_args(argv)
    if not (args.rate > 0 and args.duration > 0 and args.runs >= 1):
        ap.error(f"--rate {args.rate:g}, --duration {args.duration:g}, --runs {args.runs}: each must be > 0")
    try:
        checked_case(args.rate, args.task, args.set)
    except InputError as err:
        ap.error(str(err))
    runs = [
        measure(args.rate, args.duration, args.task, args.set, realtime=not args.no_realtime)
        for _ in range(args.runs)
    ]
    print(json.dumps(runs, indent=1) if args.json else _table(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
