"""The task's fields of a ``/cycle`` message written as Protobuf wire bytes, without building the map.

``StateSample.task_values`` is a ``map<string, double>``: on the wire, one entry per field, each a
length-delimited message of the key (field 1, a string) and the value (field 2, a double). The
contour task records 76 fields a cycle. Filling upb's map one item at a time and serializing it
was 111 000 of the 195 000 machine instructions of one cycle's ``cycle_pb(...).SerializeToString()``
(callgrind, 500 cycles of a default contour demo's tracking; ``update`` with the pairs was no
cheaper): more than a fifth of the recording writer's work.

The names change rarely (the writer receives them once, then only when they change), and every
byte of an entry but the value's eight depends on its name alone. So the entries are laid out once
per tuple of names as a ``struct`` format that alternates each entry's fixed bytes with its double
(little-endian IEEE 754, as Protobuf writes a double): a cycle's entries are one ``pack`` of the
prefixes interleaved with that cycle's values. The bytes parse to the same map as upb's (the entry
order of a map on the wire is unspecified; upb's own follows its hash table). tests/unit/test_task_values_wire.py
compares the two ways over many values, NaN's bits and infinities included.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

_WIRE_LEN = 2  # wire type of a length-delimited field (string, bytes, message)
_WIRE_I64 = 1  # wire type of a double
TASK_VALUES_FIELD = 9  # StateSample.task_values (controller/messages/cheope.proto)
_KEY_FIELD, _VALUE_FIELD = 1, 2  # a map entry's key and value


def varint(n: int) -> bytes:
    """A non-negative integer as a Protobuf base-128 varint."""
    if n < 0:
        raise ValueError(f"a varint here is never negative, got {n}")
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def tag(field: int, wire_type: int) -> bytes:
    return varint(field << 3 | wire_type)


def length_delimited(field: int, payload: bytes) -> bytes:
    """Field ``field`` holding ``payload`` (a string, bytes or an embedded message)."""
    return tag(field, _WIRE_LEN) + varint(len(payload)) + payload


class TaskValuesWire:
    """The wire bytes of ``task_values`` for one tuple of names (module text)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        prefixes = []
        for name in self.names:
            key = length_delimited(_KEY_FIELD, name.encode("utf-8"))
            entry_length = len(key) + 1 + 8  # the value's tag (one byte) and its eight
            prefixes.append(
                tag(TASK_VALUES_FIELD, _WIRE_LEN) + varint(entry_length) + key + tag(_VALUE_FIELD, _WIRE_I64)
            )
        self._format = struct.Struct("<" + "".join(f"{len(p)}sd" for p in prefixes))
        self._arguments: list[object] = [None] * (2 * len(prefixes))
        self._arguments[0::2] = prefixes

    def entries(self, values: Sequence[float]) -> bytes:
        """The map's entries for ``values`` (one per name, in order); ``ValueError`` naming what is
        wrong when they are not that many numbers."""
        if len(values) != len(self.names):
            raise ValueError(f"{len(values)} task values for {len(self.names)} names")
        arguments = self._arguments.copy()
        arguments[1::2] = values
        try:
            return self._format.pack(*arguments)
        except struct.error as err:  # a value that is no number
            bad = next((n for n, v in zip(self.names, values, strict=True) if not _is_number(v)), "?")
            raise ValueError(f"task value {bad!r} is no number ({err})") from err


def _is_number(value: object) -> bool:
    try:
        struct.pack("<d", value)
    except (struct.error, OverflowError):
        return False
    return True
