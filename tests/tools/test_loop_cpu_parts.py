"""The tool that says where the loop thread's CPU goes in the service, part by part."""

from __future__ import annotations

import pytest
from stepping_clock import SteppingClock

from controller.shell.loop import CycleDeadlines, SdoControlwords
from controller.shell.simulated_rig import SimulatedRig
from controller.tools.bench.cycle_work import task_config
from controller.tools.bench.exchange_hook import OPTIONAL_METHODS
from controller.tools.bench.loop_cpu_parts import (
    LoopCpuParts,
    PartClocks,
    TimedExchange,
    main,
    measure,
    observer_parts,
)


def test_a_part_sums_the_clock_over_its_calls_even_when_a_call_raises():
    clocks = PartClocks(SteppingClock(1.0))
    double = clocks.timed("double", lambda x: 2 * x)
    assert double(3) == 6 and double(4) == 8

    def fail() -> None:
        raise RuntimeError("drive gone")

    with pytest.raises(RuntimeError, match="drive gone"):
        clocks.timed("fail", fail)()
    assert clocks.cpu_s == {"double": 2.0, "fail": 1.0} and clocks.calls == {"double": 2, "fail": 1}


class _ExchangeWithDeadlines:
    def send(self, outputs: object, send_by_s: float = 0.0) -> bool:
        return True

    def collect(self, deadline_s: float) -> object:
        return None

    def cycle_deadline(self, deadline_s: float) -> None:
        return None


def test_the_timed_exchange_answers_the_loops_checks_as_its_exchange():
    rig = SimulatedRig(task_config("path"))
    for exchange in (rig.exchange, _ExchangeWithDeadlines()):
        timed = TimedExchange(exchange, PartClocks())  # type: ignore[arg-type]  # the loop's Exchange
        assert isinstance(timed, CycleDeadlines) == isinstance(exchange, CycleDeadlines)
        assert isinstance(timed, SdoControlwords) == isinstance(exchange, SdoControlwords)
        # set on the wrapper itself: Python 3.12's Protocol checks never call __getattr__
        assert {n for n in OPTIONAL_METHODS if n in vars(timed)} == {
            n for n in OPTIONAL_METHODS if hasattr(exchange, n)
        }
    assert isinstance(TimedExchange(_ExchangeWithDeadlines(), PartClocks()), CycleDeadlines)  # type: ignore[arg-type]


def test_an_optional_method_of_the_exchange_is_timed_under_its_name():
    clocks = PartClocks(SteppingClock(1.0))
    timed = TimedExchange(_ExchangeWithDeadlines(), clocks)  # type: ignore[arg-type]
    timed.cycle_deadline(0.0025)  # type: ignore[attr-defined]  # set where the exchange has it
    assert clocks.cpu_s == {"cycle_deadline": 1.0}


def test_observers_of_one_class_get_a_part_each():
    assert observer_parts((_Counter(), SteppingClock(1.0), _Counter())) == [
        "observer _Counter 1",
        "observer SteppingClock",
        "observer _Counter 2",
    ]


class _Counter:
    def __init__(self) -> None:
        self.cycles = 0

    def on_cycle(self, *args: object) -> None:
        self.cycles += 1


def test_the_parts_of_an_instrumented_run_and_the_run_unchanged():
    plain, timed = SimulatedRig(task_config("path")), SimulatedRig(task_config("path"))
    final, stats = plain.loop().run(plain.law.initial_state(), 0.5)
    counter = _Counter()
    loop = timed.loop((counter,))
    parts = LoopCpuParts()
    parts.instrument(loop)
    timed_final, timed_stats = loop.run(timed.law.initial_state(), 0.5)
    assert timed_final == final and timed_stats.cycles == stats.cycles  # the same cycles, bit for bit

    report = parts.report(400.0)
    per_cycle = report["parts_us_per_cycle"]
    assert isinstance(per_cycle, dict)
    assert set(per_cycle) == {"sleep", "send", "collect", "step", "observer _Counter", "shell"}
    assert report["cycles"] == loop.cycles_done == counter.cycles > 100
    assert per_cycle["step"] > 0.0 and per_cycle["shell"] >= 0.0  # the parts lie inside the run
    for part in ("sleep", "send", "collect", "step", "observer _Counter"):  # once a cycle each
        assert parts.clocks.calls[part] == loop.cycles_done, part
    assert "spin_us_per_cycle" not in report  # simulated time's sleeper spins not


def test_nothing_measured_without_a_loop_or_a_cycle():
    assert LoopCpuParts().report(400.0) == {"cycles": 0}


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--task", "bogus"], "task.kind = 'bogus': must be one of"),
        (["--set", "loop.spin_us"], "--set 'loop.spin_us': expected KEY=VALUE"),
        (["--rate", "0"], "--rate 0"),
    ],
)
def test_bad_input_is_named_before_anything_starts(argv, named, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2 and named in capsys.readouterr().err


@pytest.mark.bus_processes
def test_one_case_over_the_bus_gives_every_part_of_the_service():
    run = measure(400.0, 2.0, "path", [], realtime=False)
    report = run["loop_cpu_parts"]
    assert isinstance(report, dict) and report["cycles"] > 400
    per_cycle = report["parts_us_per_cycle"]
    for part in (
        "sleep",
        "send",
        "collect",
        "step",
        "shell",
        "observer SessionRecorder",
        "observer LoopProbe",
    ):
        assert per_cycle[part] > 0.0, part
    assert report["spin_us_per_cycle"] > 0.0  # the service's DeadlineSleeper spins before each deadline
    assert run["final_mode"] == "DONE"  # its duration ends it through STOPPING
