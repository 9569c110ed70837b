"""``controller.core.records.replace`` gives what ``dataclasses.replace`` gives, for every kind of class."""

from __future__ import annotations

import dataclasses
import math
import pickle

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.core.controller_state import ControllerState
from controller.core.records import record, replace
from controller.core.setpoint_smoothing import Setpoint
from controller.shell.loop import CycleLoop, SimulatedTime
from sim_backend.loopback import LoopbackExchange


@dataclasses.dataclass(frozen=True, slots=True)
class Slotted:
    a: float
    b: tuple[int, ...] = ()
    c: str = "x"


@dataclasses.dataclass(frozen=True)
class Checked:
    value: float

    def __post_init__(self) -> None:
        if not self.value >= 0.0:
            raise ValueError(f"value = {self.value}: must be >= 0")


@dataclasses.dataclass
class WithInitFalse:
    a: int
    derived: int = dataclasses.field(init=False, default=7)


@dataclasses.dataclass(kw_only=True)
class KeywordOnly:
    a: int
    b: int = 2


@dataclasses.dataclass(frozen=True)
class One:
    only: float


def _same(x: object, y: object) -> bool:
    """Equal field by field, floats bit for bit (NaN included)."""
    if type(x) is not type(y):
        return False
    for f in dataclasses.fields(x):  # type: ignore[arg-type]
        a, b = getattr(x, f.name), getattr(y, f.name)
        if isinstance(a, float) and isinstance(b, float):
            if math.isnan(a) != math.isnan(b) or (not math.isnan(a) and a.hex() != b.hex()):
                return False
        elif a != b:
            return False
    return True


@pytest.mark.parametrize(
    ("record", "changes"),
    [
        (Slotted(1.0, (2,), "y"), {"a": -0.0}),
        (Slotted(1.0), {"b": (1, 2), "c": "z"}),
        (Slotted(float("nan")), {}),
        (Checked(1.0), {"value": 2.0}),
        (WithInitFalse(1), {"a": 3}),
        (KeywordOnly(a=1), {"b": 5}),
        (One(1.0), {"only": 2.5}),
        (One(1.0), {}),
    ],
)
def test_the_same_as_dataclasses_replace(record: object, changes: dict[str, object]):
    ours, theirs = replace(record, **changes), dataclasses.replace(record, **changes)  # type: ignore[type-var]
    assert _same(ours, theirs)
    assert ours is not record


def test_post_init_checks_still_run():
    with pytest.raises(ValueError, match=r"value = -1\.0"):
        replace(Checked(1.0), value=-1.0)


def test_an_unknown_field_is_named():
    with pytest.raises(TypeError, match="'d'"):
        replace(Slotted(1.0), d=2)


def test_a_non_dataclass_is_refused():
    with pytest.raises(TypeError, match="dataclass"):
        replace(3.0)


def test_the_law_s_states_along_a_run_match_dataclasses_replace():
    """Every state of a contour run (enabling, approach, contact), replaced both ways with each field."""
    cfg = load_config(overrides={"task.kind": "contour", "task.contour.approach_clearance_m": 0.003})
    clock = SimulatedTime()
    law = build_law(cfg)
    states = []

    class Keep:
        def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
            if cycle % 50 == 0:
                states.append(state)

    CycleLoop(
        law,
        LoopbackExchange(cfg, clock.clock),
        cfg.period_s,
        cfg.loop.collect_fraction,
        clock,
        clock.clock,
        observers=(Keep(),),
    ).run(law.initial_state(), 1.0)
    assert len(states) > 5
    assert sum(s.task_state is not None for s in states) > 3  # the task's own state too
    for state in states:
        for rec in (r for r in (state, state.task_state, state.setpoint) if r is not None):
            for f in dataclasses.fields(rec):
                value = getattr(rec, f.name)
                assert _same(replace(rec, **{f.name: value}), dataclasses.replace(rec, **{f.name: value}))


@record
class Point:
    x: float
    tags: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True, slots=True)
class FrozenPoint:
    x: float
    tags: tuple[str, ...] = ()


def test_a_record_compares_hashes_and_pickles_as_the_frozen_dataclass():
    a, b = Point(1.0, ("a",)), Point(1.0, ("a",))
    assert a == b and a is not b
    assert hash(a) == hash(b) == hash(FrozenPoint(1.0, ("a",)))  # by the fields, in order
    assert {a, b} == {a}
    assert Point(2.0) != a
    assert pickle.loads(pickle.dumps(a)) == a
    assert repr(a).endswith("Point(x=1.0, tags=('a',))")
    assert not hasattr(a, "__dict__")  # slots: no attribute can be added by mistake
    with pytest.raises(AttributeError):
        a.y = 2.0  # type: ignore[attr-defined]


def test_the_law_s_records_are_records():
    for cls in (ControllerState, Setpoint):
        params = cls.__dataclass_params__  # type: ignore[attr-defined]
        assert params.unsafe_hash and not params.frozen
        assert "__slots__" in cls.__dict__


@record
class CheckedPoint:
    x: float

    def __post_init__(self) -> None:
        if not self.x >= 0.0:
            raise ValueError(f"x = {self.x}: must be >= 0")


@pytest.mark.parametrize("changes", [{}, {"x": -0.0}, {"tags": ("b", "c")}, {"x": float("nan"), "tags": ()}])
def test_a_record_copied_field_by_field_is_dataclasses_replace_s(changes: dict[str, object]):
    old = Point(1.5, ("a",))
    ours = replace(old, **changes)
    assert _same(ours, dataclasses.replace(old, **changes))  # type: ignore[arg-type]
    assert ours is not old and old == Point(1.5, ("a",))  # the old record unchanged
    with pytest.raises(TypeError, match="'y'"):
        replace(old, x=2.0, y=1.0)


def test_a_record_with_post_init_is_still_checked():
    assert replace(CheckedPoint(1.0), x=2.0) == CheckedPoint(2.0)
    with pytest.raises(ValueError, match=r"x = -1\.0"):
        replace(CheckedPoint(1.0), x=-1.0)
