"""The task values of a ``/cycle`` record: which fields of a task's state the recording holds per cycle."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from logs.cycle_encoding import task_values


class _Phase(enum.IntEnum):
    APPROACH = 1
    TRACKING = 2


class _Point(NamedTuple):
    x: float
    y: float


@dataclass(frozen=True)
class _Inner:
    a: float = 1.0


_POINT = _Point(0.25, 0.75)
_GAIN = np.float64(0.125)
_COUNT = np.int64(4)  # not a Python int: not recorded
_INNER = _Inner()


@dataclass(frozen=True)
class _TaskState:
    phase: _Phase = _Phase.TRACKING
    speed_m_s: float = 0.06
    lap: int = 3
    excused: bool = True
    held_force: tuple[float, float, float] | None = None
    p_cmd: tuple[float, float, float] = (0.1, -0.2, 0.5)
    tare_sum: tuple[float, int] = (2.5, 7)
    point: _Point = _POINT
    gain: np.float64 = _GAIN
    fault: str = ""
    trace: tuple[tuple[float, float], ...] = ((0.0, 1.0), (2.0, 3.0))
    five: tuple[float, ...] = (1.0, 2.0, 3.0, 4.0, 5.0)
    empty: tuple[float, ...] = ()
    mixed: tuple[object, ...] = (1.0, "x")
    inner: _Inner = _INNER
    count: np.int64 = _COUNT


def test_numbers_and_short_numeric_tuples_are_recorded_and_nothing_else():
    assert task_values(_TaskState()) == {
        "phase": 2.0,
        "speed_m_s": 0.06,
        "lap": 3.0,
        "excused": 1.0,
        "p_cmd.0": 0.1,
        "p_cmd.1": -0.2,
        "p_cmd.2": 0.5,
        "tare_sum.0": 2.5,
        "tare_sum.1": 7.0,
        "point.0": 0.25,
        "point.1": 0.75,
        "gain": 0.125,
    }


def test_a_field_that_holds_numbers_later_is_recorded_then():
    state = _TaskState(held_force=(1.0, 2.0, 3.0), trace=(), fault="lost")
    values = task_values(state)
    assert (values["held_force.0"], values["held_force.1"], values["held_force.2"]) == (1.0, 2.0, 3.0)
    assert not any(k.startswith(("trace", "fault")) for k in values)


def test_no_task_state_and_no_dataclass_give_no_values():
    assert task_values(None) == {}
    assert task_values((1.0, 2.0)) == {}


def test_float_subclasses_are_recorded_as_floats():
    """Nothing in the values the loop hands the writer needs a class imported there (numpy's float64)."""
    assert type(task_values(_TaskState())["gain"]) is float


class _Look(enum.StrEnum):
    TRACKING = "tracking"


def _failing_phase_name(state: object) -> str:
    raise RuntimeError("a plug-in's display helper failed")


def test_the_task_phase_is_text_whatever_the_task_s_phase_name_returns():
    """A StrEnum gives its text; anything else, or a failure, gives "?": the recording goes on."""
    from controller.assembly import build_law
    from controller.config import load_config
    from controller.core.cycle_data import CycleInputs, CycleOutputs
    from controller.core.records import replace
    from logs.cycle_encoding import cycle_values
    from logs.messages import cycle_pb

    state = replace(build_law(load_config()).initial_state(), task_state=_TaskState())
    inputs, outputs = CycleInputs(drives=()), CycleOutputs(controlwords=(), targets=())
    for phase_name, expected in (
        (lambda s: "TRACKING", "TRACKING"),
        (lambda s: _Look.TRACKING, "tracking"),
        (lambda s: 3, "?"),
        (_failing_phase_name, "?"),
    ):
        values = cycle_values(7, 0.0175, inputs, state, outputs, _Timing(), phase_name)
        assert type(values[12]) is str and values[12] == expected
        assert cycle_pb(values).state.task_phase == expected


def test_the_monitor_publishes_the_same_phase_text_and_survives_a_failing_phase_name():
    """The monitor's publisher called a task's phase_name unguarded: a plug-in's raise, or a
    number, ended the run over the bus (the recorder's text was guarded)."""
    from types import SimpleNamespace

    from controller.assembly import build_law
    from controller.config import load_config
    from controller.core.records import replace
    from controller.monitoring.publisher import MonitorPublisher

    state = replace(build_law(load_config()).initial_state(), task_state=_TaskState())
    for phase_name, expected in (
        (_failing_phase_name, "?"),
        (lambda s: 3, "?"),
        (lambda s: _Look.TRACKING, "tracking"),
    ):
        publisher = SimpleNamespace(task_phase=phase_name)  # what _phase reads of it
        assert MonitorPublisher._phase(publisher, state) == expected


class _Timing:
    wake_error_s = 0.0
    step_s = 0.0


def test_the_names_are_the_same_strings_every_cycle():
    """The recorder compares each cycle's names with those it sent last (logs/recorder.py): the same
    string objects make that an identity check per name, not a comparison of their text."""
    from logs.cycle_encoding import task_fields

    first, _ = task_fields(_TaskState())
    again, values = task_fields(_TaskState(lap=4, p_cmd=(0.0, 0.0, 0.0)))
    assert first == again and all(a is b for a, b in zip(first, again, strict=True))
    assert dict(zip(again, values, strict=True)) == task_values(_TaskState(lap=4, p_cmd=(0.0, 0.0, 0.0)))
