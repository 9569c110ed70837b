"""The controller's state as bytes: what a rotated recording file starts with (its keyframe).

``cheope replay FILE --verify`` rebuilds the law from the configuration and needs the state the
law had before the file's first cycle; the first file of a session starts from
``law.initial_state()``, every later one from the keyframe the recorder wrote at its start.

The state is a tree of frozen dataclasses, enums, tuples, frozensets, numbers, strings and,
for planned tasks, NumPy arrays. It is written as JSON with type tags: floats by ``repr``
(which round-trips every double bit for bit, -0.0, inf and nan included), arrays as their
raw bytes. Not pickle: a recording is a file from anywhere, and reading it must not run
code. Decoding builds only dataclasses and enums of modules already imported (the law's own,
once ``build_law`` has run), so a file cannot make the reader import anything.
"""

from __future__ import annotations

import base64
import dataclasses
import enum
import json
import math
import sys
from typing import Any

import numpy as np

ENCODING = "cheope-state-json-2"
# Read too: the encoding of keyframes recorded before a58564c, whose contact guard kept its median
# windows as tuples of samples (x, y, z) where it now keeps a tuple per axis (_UPGRADES).
ENCODINGS = ("cheope-state-json-1", ENCODING)


class KeyframeError(ValueError):
    """The keyframe cannot be turned back into a state (unknown type, damaged JSON)."""


def _qualified(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _float(x: float) -> Any:
    # JSON has no nan/inf and json.dumps would write bare NaN: keep every double as its repr then
    return x if math.isfinite(x) else {"f": repr(x)}


def _encode(v: Any) -> Any:
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, enum.Enum):  # before int: IntEnum is an int
        return {"e": _qualified(type(v)), "v": v.name}
    if isinstance(v, int):
        return v
    if isinstance(v, float):
        return _float(v)
    if isinstance(v, tuple):
        return {"t": [_encode(x) for x in v]}
    if isinstance(v, frozenset):
        return {"s": sorted((_encode(x) for x in v), key=json.dumps)}
    if isinstance(v, np.ndarray):
        return {
            "a": str(v.dtype),
            "shape": list(v.shape),
            "b": base64.b64encode(np.ascontiguousarray(v).tobytes()).decode("ascii"),
        }
    if isinstance(v, np.generic):
        return _encode(v.item())
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {
            "d": _qualified(type(v)),
            "f": {f.name: _encode(getattr(v, f.name)) for f in dataclasses.fields(v) if f.init},
        }
    raise KeyframeError(f"cannot record a state value of type {type(v).__name__}: {v!r:.80}")


def encode_state(state: object) -> bytes:
    """The state as compact JSON bytes (see the module doc); KeyframeError when it has none.

    A state nested deeper than the interpreter's recursion limit, or one that holds itself (a task's
    linked list of frozen nodes), raised RecursionError out of the recorder and ended the loop at
    the recording's first split (an outside tester's): it is a state without a keyframe, as one
    of a class the keyframe cannot write."""
    try:
        return json.dumps(_encode(state), separators=(",", ":"), allow_nan=False).encode()
    except KeyframeError:
        raise
    except RecursionError:
        raise KeyframeError("the state nests too deep to be written (or holds itself)") from None
    except (ValueError, TypeError) as err:  # a non-finite number (allow_nan), a key json cannot write
        raise KeyframeError(f"the state cannot be written as JSON: {err}") from None


# Classes that moved since a recording may have named them: the old name reads as the new one.
MOVED_CLASSES = {
    "controller.robots.nspu.planned_legs:StreamedPlan": "controller.robots.nspu.streamed_plan:StreamedPlan",
    "drivers.cia402:PowerState": "controller.core.cia402:PowerState",
    "controller.core.control_law:ControllerState": "controller.core.controller_state:ControllerState",
    "controller.core.control_law:Mode": "controller.core.controller_state:Mode",
}


def _loaded_class(name: str) -> type:
    module, _, qualname = MOVED_CLASSES.get(name, name).partition(":")
    mod = sys.modules.get(module)
    obj: Any = mod
    for part in qualname.split("."):
        obj = getattr(obj, part, None)
    if not isinstance(obj, type):
        raise KeyframeError(f"the keyframe names {name!r}, which is not a class of a loaded module")
    return obj


def _per_axis(samples: tuple[tuple[float, ...], ...]) -> tuple[tuple[float, ...], ...]:
    """A window of samples (x, y, z), oldest first, as the tuple per axis it is kept as now."""
    if not all(len(sample) == 3 for sample in samples):
        raise KeyframeError(f"a contact guard window of samples that are not 3 forces each: {samples!r:.80}")
    return tuple(tuple(sample[axis] for sample in samples) for axis in range(3))


# What an older encoding's dataclass fields were, as now: encoding -> class -> field -> upgrade.
_UPGRADES: dict[str, dict[str, dict[str, Any]]] = {
    "cheope-state-json-1": {
        "controller.core.contact_guard:ContactWatch": {
            "witness_window": _per_axis,
            "sensor_window": _per_axis,
        },
    },
}


def _decode(v: Any, upgrades: dict[str, dict[str, Any]]) -> Any:
    if not isinstance(v, dict):
        if isinstance(v, list):
            raise KeyframeError("a bare list in the keyframe (tuples are tagged)")
        return v
    if "t" in v:
        return tuple(_decode(x, upgrades) for x in v["t"])
    if "s" in v:
        return frozenset(_decode(x, upgrades) for x in v["s"])
    if "f" in v and "d" not in v:
        return float(v["f"])
    if "e" in v:
        cls = _loaded_class(v["e"])
        if not issubclass(cls, enum.Enum):
            raise KeyframeError(f"{v['e']!r} in the keyframe is not an enum")
        return cls[v["v"]]
    if "a" in v:
        return np.frombuffer(base64.b64decode(v["b"]), dtype=np.dtype(v["a"])).reshape(v["shape"]).copy()
    if "d" in v:
        cls = _loaded_class(v["d"])
        if not dataclasses.is_dataclass(cls):
            raise KeyframeError(f"{v['d']!r} in the keyframe is not a dataclass")
        fields = {k: _decode(x, upgrades) for k, x in v["f"].items()}
        for name, upgrade in upgrades.get(v["d"], {}).items():
            if name in fields:
                fields[name] = upgrade(fields[name])
        return cls(**fields)
    raise KeyframeError(f"unknown value in the keyframe: {json.dumps(v)[:80]}")


def decode_state(data: bytes, encoding: str = ENCODING) -> Any:
    """The state ``encode_state`` wrote in ``encoding`` (one of ``ENCODINGS``), as the law keeps it
    now; ``KeyframeError`` when it cannot be rebuilt."""
    if encoding not in ENCODINGS:
        raise KeyframeError(f"keyframe encoding {encoding!r}: this version reads {', '.join(ENCODINGS)}")
    try:
        return _decode(json.loads(data), _UPGRADES.get(encoding, {}))
    except KeyframeError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError) as err:
        raise KeyframeError(f"damaged keyframe: {err}") from err
