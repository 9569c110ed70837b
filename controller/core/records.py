"""The law's records: immutable value types, declared with ``@record``, changed with ``replace``.

The law passes its state to itself as records (``ControllerState``, a task's state, the setpoint,
the cycle's inputs and outputs), a new one each time a field changes, several times a cycle.

``@record`` is a dataclass with slots, immutable for the type checker (``dataclass_transform``
with ``frozen_default``: mypy rejects an assignment to a field) but not guarded at run time.
A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` (its own
``__setattr__`` refuses), a call per field: 16.6 us for 40 fields where a slotted class's plain
assignments take 1.9 us (``timeit``, this VM), and the contour task builds its 57-field state
seven times a tracking cycle. Equality, hashing (``unsafe_hash``: by the fields, as a frozen one),
``repr``, pickling and ``dataclasses.fields``/``replace`` are those of the frozen dataclass.

``replace(record, **changes)`` is ``dataclasses.replace`` without its per-call walk of the class's
fields (is it an init field, an InitVar?) and its keyword dict of every value: in the contour task
11 645 of the step's 23 091 bytecodes a cycle were that walk, in the path task 1 953 of 9 688
(``python -m controller.tools.bench.cycle_work``, issue 37). Here the walk is done once per class: the
init fields' current values come from one ``operator.attrgetter`` call, the changes overwrite
theirs by index, and the class is called with them positionally. That is the same ``__init__``
(with its ``__post_init__``) that ``dataclasses.replace`` calls with the same values: the same
record, bit for bit. A class whose ``__init__`` is not one positional parameter per field, in
field order (keyword-only fields, ``init=False`` fields, InitVars, a hand-written ``__init__``),
is left to ``dataclasses.replace``. A name that is no field raises ``TypeError`` naming it, as
``dataclasses.replace`` does.

A ``@record`` class without ``__post_init__`` skips ``__init__`` too: its ``__init__`` only assigns
each field, so a copy made by assigning each field from the old record, then the changes, is the
same record. That copy is a function written for the class once (as ``dataclasses`` writes
``__init__``): one load and one store per field, no argument tuple. For the contour task's
57-field state it takes 0.9 us where the call of ``__init__`` with the fields' values took 2.4 us
(``timeit``, this VM); the contour step replaces 14 records a tracking cycle (issue 37).
"""

from __future__ import annotations

import dataclasses
import inspect
import operator
from collections.abc import Callable, Sequence
from typing import Any, TypeVar, dataclass_transform

T = TypeVar("T")


@dataclass_transform(frozen_default=True)
def record(cls: type[T]) -> type[T]:
    """A record class (module text): a slotted dataclass, read-only for the type checker."""
    return dataclasses.dataclass(slots=True, unsafe_hash=True)(cls)


@dataclasses.dataclass(frozen=True, slots=True)
class _Plan:
    values: Callable[[Any], tuple[Any, ...]]  # the init fields' values, in __init__'s order
    index: dict[str, int]  # field name -> position
    copy: Callable[[Any], Any] | None = None  # a @record class's field-by-field copy (module text)


_PLANS: dict[type, _Plan | None] = {}  # None: the class is left to dataclasses.replace


def _plan(cls: type) -> _Plan | None:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"replace() should be called on dataclass instances, not {cls.__name__}")
    fields = dataclasses.fields(cls)
    names = [f.name for f in fields]
    try:
        params = list(inspect.signature(cls).parameters.values())
    except (TypeError, ValueError):
        return None
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    if [p.name for p in params] != names or any(p.kind not in positional for p in params):
        return None
    if not all(f.init for f in fields):
        return None
    return _Plan(values_getter(names), {n: i for i, n in enumerate(names)}, _copier(cls, names))


def _copier(cls: type, names: Sequence[str]) -> Callable[[Any], Any] | None:
    """A function that copies a record of ``cls`` field by field, for a ``@record`` class whose
    ``__init__`` only assigns the fields; None for any other class."""
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or params.frozen or "__slots__" not in cls.__dict__ or hasattr(cls, "__post_init__"):
        return None
    if not all(name.isidentifier() for name in names):
        return None
    body = "".join(f"    new.{name} = old.{name}\n" for name in names)
    namespace: dict[str, Any] = {"new_record": object.__new__, "cls": cls}
    # written and compiled once per class, as dataclasses writes __init__
    exec(f"def copy(old):\n    new = new_record(cls)\n{body}    return new\n", namespace)
    copy: Callable[[Any], Any] = namespace["copy"]
    return copy


def values_getter(names: Sequence[str]) -> Callable[[Any], tuple[Any, ...]]:
    """One call that returns the attributes ``names`` of an object as a tuple (``attrgetter``'s
    speed; it returns a bare value, not a tuple, for a single name)."""
    if len(names) == 1:
        name = names[0]
        return lambda obj: (getattr(obj, name),)
    if not names:
        return lambda obj: ()
    return operator.attrgetter(*names)


def replace(record: T, /, **changes: Any) -> T:
    """A copy of the dataclass instance ``record`` with ``changes`` (``dataclasses.replace``'s meaning)."""
    cls = type(record)
    try:
        plan = _PLANS[cls]
    except KeyError:
        plan = _PLANS[cls] = _plan(cls)
    if plan is None:
        return dataclasses.replace(record, **changes)  # type: ignore[type-var]  # a dataclass: checked in _plan
    copy = plan.copy
    if copy is not None:
        new = copy(record)  # a fresh record: a refused name below leaves nothing half changed
        for name, value in changes.items():
            if name not in plan.index:
                raise TypeError(f"{cls.__name__} has no field {name!r} to replace")
            setattr(new, name, value)
        return new  # type: ignore[no-any-return]
    values = plan.values(record)
    if changes:
        values_list = list(values)
        index = plan.index
        for name, value in changes.items():
            i = index.get(name)
            if i is None:
                raise TypeError(f"{cls.__name__} has no field {name!r} to replace")
            values_list[i] = value
        return cls(*values_list)
    return cls(*values)
