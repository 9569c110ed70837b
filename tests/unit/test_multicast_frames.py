"""The simulated bus's datagrams (drivers/multicast_frames.py): ``pack_frame`` writes python-can's
bytes for every message, and ``unpack_frame``'s quick reading of a data frame agrees with the full,
checked one for every datagram, frame or not."""

from __future__ import annotations

import math

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from drivers.multicast_frames import _DATA_FRAME, _unpack_checked, pack_frame, unpack_frame

_FIELDS = (
    "timestamp",
    "arbitration_id",
    "is_extended_id",
    "is_remote_frame",
    "is_error_frame",
    "channel",
    "dlc",
    "data",
    "is_fd",
    "bitrate_switch",
    "error_state_indicator",
    "is_rx",
)

# Messages of every kind, valid or not (python-can builds them unchecked): identifiers past both
# ranges, a dlc that is not the length, flags in any combination, a channel, bytes or bytearray.
_message = st.builds(
    lambda ts, arb, ext, rtr, err, channel, data, dlc, fd, brs, esi: _made(
        ts, arb, ext, rtr, err, channel, data, dlc, fd, brs, esi
    ),
    st.one_of(st.floats(allow_nan=True), st.integers(0, 2**40)),
    st.one_of(st.integers(0, 0x7FF), st.integers(0, 2**32 - 1)),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.one_of(st.none(), st.none(), st.just("vcan0"), st.just(3)),
    st.one_of(st.binary(max_size=70), st.binary(max_size=70).map(bytearray)),
    st.one_of(st.none(), st.integers(0, 70)),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)


def _made(ts, arb, ext, rtr, err, channel, data, dlc, fd, brs, esi) -> can.Message:
    msg = can.Message(
        timestamp=ts,
        arbitration_id=arb,
        is_extended_id=ext,
        is_remote_frame=rtr,
        is_error_frame=err,
        channel=channel,
        dlc=dlc,
        data=data,
        is_fd=fd,
        bitrate_switch=brs,
        error_state_indicator=esi,
    )
    if rtr is False and type(data) is bytes and dlc is None:
        msg.data = data  # a message whose data someone set as bytes
    return msg


# The frames a bus carries: data frames, classic and FD, standard and extended identifiers.
_data_frame = st.builds(
    lambda arb, ext, fd, brs, payload: can.Message(
        timestamp=1.5,
        arbitration_id=arb if ext else arb & 0x7FF,
        is_extended_id=ext,
        data=payload[: 64 if fd else 8],
        is_fd=fd,
        bitrate_switch=brs and fd,
        error_state_indicator=brs and fd,
    ),
    st.integers(0, 0x1FFFFFFF),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.binary(max_size=64),
)


# Data frames as the quick reading's pattern has them, valid or not: any identifier, flags and length.
_any_data_frame = st.builds(
    lambda arb, ext, fd, brs, esi, data: can.Message(
        timestamp=2.0,
        arbitration_id=arb,
        is_extended_id=ext,
        data=data,
        is_fd=fd,
        bitrate_switch=brs,
        error_state_indicator=esi,
    ),
    st.one_of(st.integers(0, 0x900), st.integers(0x1FFFFF00, 0x20000100), st.integers(0, 2**32 - 1)),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.binary(max_size=70),
)


@settings(max_examples=400, deadline=None)
@given(_message)
def test_packed_frames_are_python_cans_bytes(msg):
    assert pack_frame(msg) == pack_message(msg)


@settings(max_examples=200, deadline=None)
@given(_data_frame)
def test_data_frames_take_the_quick_ways_there_and_back(msg):
    datagram = pack_frame(msg)
    assert datagram == pack_message(msg)
    assert _DATA_FRAME.fullmatch(datagram) is not None
    got = unpack_frame(datagram, 7.25)
    assert [getattr(got, f) for f in _FIELDS] == [
        getattr(_unpack_checked(datagram, 7.25), f) for f in _FIELDS
    ]
    assert got.timestamp == 7.25 and bytes(got.data) == bytes(msg.data)


def _outcome(read, datagram: bytes, timestamp_s: float) -> tuple[str, object]:  # type: ignore[no-untyped-def]
    """What ``read`` (``unpack_frame`` or ``_unpack_checked``) makes of ``datagram``: the frame's
    fields, or the refusal's words."""
    try:
        msg = read(datagram, timestamp_s)
    except ValueError as err:
        return "refused", str(err)
    return "frame", [getattr(msg, f) for f in _FIELDS]


@settings(max_examples=500, deadline=None)
@given(
    st.one_of(_message, _data_frame, _any_data_frame),
    st.integers(0, 200),
    st.integers(0, 255),
    st.sampled_from([0.0, 3.5, -1.0, math.inf]),
)
def test_the_quick_reading_agrees_with_the_checked_one(msg, at, byte, timestamp_s):
    """Packed messages of every kind, and each with one byte changed: the same frame, or the same
    refusal with the same words."""
    try:
        datagram = pack_message(msg)
    except (TypeError, ValueError, OverflowError):
        assume(False)  # msgpack cannot pack it (a NaN is fine, an int past 64 bits not)
    for d in (datagram, datagram[:at] + bytes((byte,)) + datagram[at + 1 :]):
        assert _outcome(unpack_frame, d, timestamp_s) == _outcome(_unpack_checked, d, timestamp_s)


@pytest.mark.parametrize(
    "datagram",
    ["a str", None, 5, 2.5, [0x80]],  # what no socket gives, but a caller might hand it
)
def test_what_is_not_bytes_is_refused_with_the_checked_readings_words(datagram):
    """The quick reading's pattern raised TypeError on these (an outside tester); the checked
    reading names them in a ValueError, as it names every datagram that is no frame."""
    outcome = _outcome(unpack_frame, datagram, 1.0)
    assert outcome == _outcome(_unpack_checked, datagram, 1.0)
    assert outcome[0] == "refused" and "not msgpack" in str(outcome[1])


def test_a_frame_in_a_bytearray_or_memoryview_is_read_as_in_bytes():
    datagram = pack_frame(can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False))
    as_bytes = _outcome(unpack_frame, datagram, 1.0)
    assert as_bytes[0] == "frame"
    for view in (bytearray(datagram), memoryview(datagram)):
        assert _outcome(unpack_frame, view, 1.0) == as_bytes


@pytest.mark.parametrize(
    "arbitration_id, ext, fd, data",
    [
        (0x800, False, False, b""),  # a standard identifier past 11 bits
        (0x20000000, True, False, b""),  # an extended one past 29
        (0x181, False, False, bytes(9)),  # nine bytes in a classic frame
    ],
)
def test_frames_out_of_range_are_refused_by_the_checked_reading(arbitration_id, ext, fd, data):
    msg = can.Message(arbitration_id=arbitration_id, is_extended_id=ext, is_fd=fd, data=data)
    with pytest.raises(ValueError, match="not a CAN frame"):
        unpack_frame(pack_frame(msg), 1.0)
