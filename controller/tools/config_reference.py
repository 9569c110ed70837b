"""``python -m controller.tools.config_reference``: the configuration keys as a Markdown table.

Walks the default configuration of each built-in robot (its shipped TOML file) and every
section's declared type (msgspec's ``inspect``), so the reference says what the loader checks:
type, allowed range or choices, default. Written to ``docs/reference/configuration-keys.md``;
``tests/unit/test_docs.py`` fails when that page is not what this prints.
"""

from __future__ import annotations

import argparse
import enum
import math
from collections.abc import Iterator, Mapping
from typing import Any

import msgspec
import msgspec.inspect as mi

from controller.config import Config, load_config
from controller.robot_registry import robot_entry, robot_kinds

HEADER = """# Configuration keys

Every key the configuration loader accepts, with its type, what it allows and its default (the
value in Cheope's shipped file, `controller/configs/cheope.toml`; `uru.toml` and `nspu.toml` set their own robot sections).
Generated from the sections' declarations by `python -m controller.tools.config_reference`;
`tests/unit/test_docs.py` checks that this page is current. What the sections are for:
[Configuration](configuration.md).
"""


def _allowed(t: mi.Type) -> str:
    if isinstance(t, (mi.FloatType, mi.IntType)):
        lo = f">= {t.ge:g}" if t.ge is not None else (f"> {t.gt:g}" if t.gt is not None else "")
        hi = f"<= {t.le:g}" if t.le is not None else (f"< {t.lt:g}" if t.lt is not None else "")
        return ", ".join(x for x in (lo, hi) if x)
    if isinstance(t, mi.StrType):
        return _lengths(t, "characters")
    if isinstance(t, mi.LiteralType):
        return " \\| ".join(f"`{v!r}`".replace("'", '"') for v in t.values)
    if isinstance(t, mi.EnumType):
        return " \\| ".join(f'`"{m.value}"`' for m in t.cls)
    if isinstance(t, mi.UnionType):
        return ", ".join(x for x in (_allowed(u) for u in t.types) if x)
    if isinstance(t, mi.DictType):
        return f"each value {_allowed(t.value_type)}"
    if isinstance(t, (mi.ListType, mi.TupleType, mi.VarTupleType)):
        items = getattr(t, "item_type", None)
        each = f"each {_allowed(items)}" if items is not None and _allowed(items) else ""
        return ", ".join(x for x in (_lengths(t, "items"), each) if x)
    return ""


def _lengths(t: mi.Type, unit: str) -> str:
    """A text's or a list's length bounds (``msgspec.Meta(min_length=, max_length=)``)."""
    lo, hi = getattr(t, "min_length", None), getattr(t, "max_length", None)
    bounds = ([f">= {lo} {unit}"] if lo is not None else []) + ([f"<= {hi} {unit}"] if hi is not None else [])
    return ", ".join(bounds)


def _type_name(t: mi.Type) -> str:
    names = {
        mi.FloatType: "number",
        mi.IntType: "integer",
        mi.BoolType: "bool",
        mi.StrType: "string",
        mi.LiteralType: "choice",
        mi.EnumType: "choice",
    }
    for cls, name in names.items():
        if isinstance(t, cls):
            return name
    if isinstance(t, mi.TupleType):
        return f"list of {len(t.item_types)}"
    if isinstance(t, (mi.ListType, mi.VarTupleType)):
        return "list"
    if isinstance(t, mi.UnionType):
        return " or ".join(_type_name(x) for x in t.types if not isinstance(x, mi.NoneType)) + (
            " (optional)" if any(isinstance(x, mi.NoneType) for x in t.types) else ""
        )
    if isinstance(t, mi.DictType):
        return "table"
    return type(t).__name__.removesuffix("Type").lower()


def _value(v: Any) -> str:
    if isinstance(v, enum.Enum):
        v = v.value
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if v is None:
        return "unset"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_value(k)} = {_value(x)}" for k, x in v.items()) + "}"
    return repr(v)


def rows(section: msgspec.Struct, prefix: str) -> Iterator[tuple[str, str, str, str]]:
    """(key, type, allowed, default) of every leaf key under ``section``."""
    fields = {f.name: f for f in mi.type_info(type(section)).fields}  # type: ignore[attr-defined]
    for name in section.__struct_fields__:
        value = getattr(section, name)
        key = f"{prefix}.{name}" if prefix else name
        if isinstance(value, msgspec.Struct):
            yield from rows(value, key)
            continue
        if isinstance(value, Mapping) and name == "models":  # [robot.<kind>], [task.<kind>]
            for kind, sub in value.items():
                if isinstance(sub, msgspec.Struct):
                    yield from rows(sub, f"{prefix}.{kind}")
            continue
        t = fields[name].type
        item = getattr(t, "item_type", None)
        if isinstance(item, mi.StructType):  # a list of tables ([[node]], features): each table's keys
            yield key, "list of tables", "", _value(value)
            for f in item.fields:
                default = "required" if f.required else _value(f.default)
                yield f"{key}[].{f.name}", _type_name(f.type), _allowed(f.type), default
            continue
        yield key, _type_name(t), _allowed(t), _value(value)


def page() -> str:
    out = [HEADER]
    seen: dict[str, str] = {}
    for kind in robot_kinds():
        cfg: Config = load_config(robot_entry(kind).config_file)
        for key, typ, allowed, default in rows(cfg, ""):
            seen.setdefault(key, f"| `{key}` | {typ} | {allowed} | `{default}` |")
    out.append("| key | type | allowed | default |\n| --- | --- | --- | --- |")
    out.extend(seen[k] for k in sorted(seen))
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(
        prog="config_reference",
        description="The configuration keys as a Markdown table on stdout "
        "(python -m controller.tools.config_reference > docs/reference/configuration-keys.md).",
    ).parse_args(argv)
    print(page(), end="")


if __name__ == "__main__":
    main()
