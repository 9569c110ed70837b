"""The writer's ``/cycle`` bytes (``cycle_bytes``, the task values written by ``TaskValuesWire``) are
``cycle_pb``'s message: the same fields, the same doubles bit for bit."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import pytest
from google.protobuf.internal.encoder import _VarintBytes
from hypothesis import given
from hypothesis import strategies as st

from controller.messages import cheope_pb2 as pb
from logs.cycle_encoding import TASK_FIELDS_AT
from logs.messages import TOPIC_CYCLE, cycle_bytes, cycle_pb, cycle_values_of_pb
from logs.reader import iter_decoded
from logs.task_values_wire import TaskValuesWire, varint

DATA = Path(__file__).resolve().parents[1] / "data"


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


def _same(a: pb.Cycle, b: pb.Cycle) -> None:
    """``a`` and ``b`` hold the same message; task values compared by their bits (NaN is not == NaN)."""
    ta, tb = dict(a.state.task_values), dict(b.state.task_values)
    assert {k: _bits(v) for k, v in ta.items()} == {k: _bits(v) for k, v in tb.items()}
    a.state.ClearField("task_values")
    b.state.ClearField("task_values")
    assert a == b


def _any_cycle() -> tuple[object, ...]:
    """The first cycle of a recorded path session, as the recorder hands it to its writer."""
    return next(
        cycle_values_of_pb(d.message) for d in iter_decoded(DATA / "path_quarter_lap.mcap", [TOPIC_CYCLE])
    )


def _with_task_fields(values: tuple[object, ...], names: tuple[str, ...], numbers: tuple[object, ...]):
    return (*values[:TASK_FIELDS_AT], (names, numbers), *values[TASK_FIELDS_AT + 1 :])


def test_recorded_cycles_written_by_the_writers_path_are_the_recorded_messages():
    n = 0
    wire = None
    for name in ("contour_contact.mcap", "path_quarter_lap.mcap"):
        for d in iter_decoded(DATA / name, [TOPIC_CYCLE]):
            values = cycle_values_of_pb(d.message)
            fields = values[TASK_FIELDS_AT]
            if fields is not None and (wire is None or wire.names != fields[0]):
                wire = TaskValuesWire(fields[0])
            data = cycle_bytes(values, wire)
            _same(pb.Cycle.FromString(data), cycle_pb(values))
            n += 1
    assert n > 1000


_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**53), max_value=2**53),
    st.booleans(),
)


@given(
    st.dictionaries(st.text(min_size=0, max_size=200), _numbers, max_size=40),
    st.floats(allow_nan=False),
    st.text(max_size=20),
)
def test_any_names_and_numbers_give_the_message_upb_builds(fields, wake_error_s, phase):
    """Names of any length and script (a key's length varint of two bytes from 128 UTF-8 bytes on),
    NaN, infinities, -0.0, integers and bools as doubles: decoded, the same map as upb's."""
    values = list(_with_task_fields(_any_cycle(), tuple(fields), tuple(fields.values())))
    values[TASK_FIELDS_AT - 1] = phase
    values[14] = wake_error_s
    values = tuple(values)
    _same(pb.Cycle.FromString(cycle_bytes(values)), cycle_pb(values))
    _same(pb.Cycle.FromString(cycle_bytes(values, TaskValuesWire(tuple(fields)))), cycle_pb(values))


def test_a_wire_made_for_other_names_is_not_used():
    values = _with_task_fields(_any_cycle(), ("a", "b"), (1.0, 2.0))
    got = pb.Cycle.FromString(cycle_bytes(values, TaskValuesWire(("x", "y"))))
    assert dict(got.state.task_values) == {"a": 1.0, "b": 2.0}


def test_values_that_do_not_fit_their_names_are_refused_naming_what_is_wrong():
    wire = TaskValuesWire(("force_n", "speed_m_s"))
    with pytest.raises(ValueError, match="1 task values for 2 names"):
        wire.entries((1.0,))
    with pytest.raises(ValueError, match="'speed_m_s' is no number"):
        wire.entries((1.0, "fast"))
    with pytest.raises(ValueError, match="'speed_m_s' is no number"):
        wire.entries((1.0, 10**400))  # no double holds it
    # upb's map refuses it too (OverflowError): either way the writer stops the recording, naming it
    with pytest.raises(OverflowError):
        cycle_pb(_with_task_fields(_any_cycle(), ("force_n",), (10**400,)))


@given(st.integers(min_value=0, max_value=2**64 - 1))
def test_varints_are_protobufs(n):
    assert varint(n) == _VarintBytes(n)


def test_a_negative_length_is_refused():
    with pytest.raises(ValueError, match="never negative"):
        varint(-1)


def test_nan_keeps_its_bits():
    quiet_with_payload = struct.unpack("<d", struct.pack("<Q", 0x7FF8_0000_0000_0001))[
        0
    ]  # a NaN with a payload
    wire = TaskValuesWire(("x",))
    entry = wire.entries((quiet_with_payload,))
    state = pb.StateSample.FromString(entry)
    assert math.isnan(state.task_values["x"])
    assert _bits(state.task_values["x"]) == _bits(quiet_with_payload)
