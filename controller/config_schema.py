"""How a configuration section is declared and validated: msgspec Structs with their constraints.

A section is a frozen ``Section`` (a msgspec Struct that refuses unknown keys); each value's
type carries its allowed range (``Annotated[float, rng(0.0, 10.0)]``), choices are ``Literal``
or a ``StrEnum``. ``convert_section`` turns a TOML table into the section, or raises a
``ConfigError`` that names the dotted key, the value and what is allowed. msgspec does the type
and range checks (docs/dependencies.md: why msgspec, and its start-up cost).
"""

from __future__ import annotations

import enum
import math
import re
import typing
from typing import Any, TypeVar

import msgspec

from controller.errors import InputError

S = TypeVar("S")


class ConfigError(InputError):
    """Invalid configuration; the message names the key, the value and what is allowed."""


class Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A configuration section: immutable, every key optional (its default), unknown keys refused."""


def rng(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> msgspec.Meta:
    """A number's allowed range, ``lo`` excluded with ``lo_open``."""
    if lo is None:
        return msgspec.Meta(le=hi)
    return msgspec.Meta(gt=lo, le=hi) if lo_open else msgspec.Meta(ge=lo, le=hi)


def check_finite(value: Any, key: str = "") -> None:
    """Every number of a configuration table is finite, or a ``ConfigError`` names its key.

    TOML reads ``nan`` and ``inf``. A key without a range (a geometry's point, a workpiece's
    centre, a home offset) let them through, and a NaN turns every comparison made with it false:
    a neutral point of ``[0, nan, 0.5]`` made the joint-swing check never trip (an outside tester's
    finding). No key of the product means anything by a number that is not finite."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{key} = {value!r}: must be finite")
    if isinstance(value, dict):
        for name, item in value.items():
            check_finite(item, f"{key}.{name}" if key else str(name))
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            check_finite(item, f"{key}[{i}]")


_WHERE = re.compile(r"^(?P<what>.*?)(?: - at `\$(?P<path>[^`]*)`)?$")


def convert_section(table: dict[str, Any], cls: type[S], prefix: str) -> S:
    """``table`` as a ``cls`` section; ``prefix`` is its dotted name (``loop``, ``robot.cheope``)."""
    try:
        return msgspec.convert(table, cls, strict=True)
    except msgspec.ValidationError as err:
        raise _named(err, table, cls, prefix) from None


def _named(err: msgspec.ValidationError, table: dict[str, Any], cls: type, prefix: str) -> ConfigError:
    m = _WHERE.match(str(err))
    what, path = (m.group("what"), m.group("path") or "") if m else (str(err), "")
    key = (prefix + path) if prefix else path.lstrip(".")
    unknown = re.match(r"Object contains unknown field `(.*)`", what)
    if unknown:
        where = f"[{key}]" if key else "the top level"
        known = ", ".join(sorted(_fields_at(cls, path)))
        return ConfigError(f"unknown key(s) {unknown.group(1)} in {where}; known: {known}")
    if path.endswith("[...]"):  # a value of a table of free keys (a Mapping): name the table
        path = path.removesuffix("[...]")
        key = key.removesuffix("[...]")
        choices = _choices_at(cls, path, mapping_value=True)
        return ConfigError(f"{key}: a value {_plain(what, choices)}")
    value = _value_at(table, path)
    if isinstance(value, dict):
        return ConfigError(f"[{key}]: {_plain(what, ())}")
    return ConfigError(f"{key} = {value!r}: {_plain(what, _choices_at(cls, path))}")


_TYPE_NAMES = {
    "float": "a number",
    "int": "an integer",
    "bool": "true or false",
    "str": "a string",
    "array": "a list",
    "object": "a table",
    "null": "nothing",
}


def _plain(what: str, choices: tuple[object, ...]) -> str:
    """msgspec's message in the words of a TOML file (a number, a list, true or false)."""
    m = re.match(r"Expected `(?:float|int)` (>=|>|<=|<) (.*)$", what)
    if m:
        return f"must be {m.group(1)} {m.group(2)}"
    m = re.match(r"Expected `array` of length (\d+), got (\d+)$", what)
    if m:
        return f"expected a list of {m.group(1)} values, got {m.group(2)}"
    m = re.match(r"Expected `(\w+)`, got `(\w+)`$", what)
    if m:
        return f"expected {_TYPE_NAMES.get(m.group(1), m.group(1))}, got {_TYPE_NAMES.get(m.group(2), m.group(2))}"
    if what.startswith("Invalid enum value") and choices:
        return "must be one of " + ", ".join(str(c) for c in choices)
    return what[:1].lower() + what[1:]


def _choices_at(cls: type, path: str, mapping_value: bool = False) -> tuple[object, ...]:
    """The allowed values of a Literal or enum field at ``path`` (else empty); with
    ``mapping_value``, of the values of the Mapping field there."""
    tp: Any = cls
    for name in re.findall(r"\.(\w+)", path):
        fields = (
            {f.name: f.type for f in msgspec.structs.fields(tp)}
            if isinstance(tp, type) and issubclass(tp, msgspec.Struct)
            else {}
        )
        if name not in fields:
            return ()
        tp = fields[name]
    if mapping_value and typing.get_args(tp):
        tp = typing.get_args(tp)[-1]
    if typing.get_origin(tp) is typing.Literal:
        return typing.get_args(tp)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return tuple(e.value for e in tp)
    return ()


def _value_at(table: Any, path: str) -> Any:
    for part in re.findall(r"\.(\w+)|\[(\d+)\]", path):
        name, index = part
        try:
            table = table[name] if name else table[int(index)]
        except (KeyError, IndexError, TypeError):
            return None
    return table


def _fields_at(cls: type, path: str) -> tuple[str, ...]:
    for name in re.findall(r"\.(\w+)", path):
        field = next((f for f in msgspec.structs.fields(cls) if f.name == name), None)
        inner = _struct_in(field.type) if field is not None else None
        if inner is None:
            break
        cls = inner  # through a table of tables ([[node]]: tuple[NodeSection, ...]) too
    return tuple(f.name for f in msgspec.structs.fields(cls))


def _struct_in(tp: Any) -> type | None:
    """The section class a field's type holds (itself, or inside a tuple, an Optional, Annotated)."""
    if isinstance(tp, type):
        return tp if issubclass(tp, msgspec.Struct) else None
    for arg in typing.get_args(tp):
        found = _struct_in(arg)
        if found is not None:
            return found
    return None
