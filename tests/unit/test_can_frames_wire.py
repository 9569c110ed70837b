"""The writer's ``/can`` bytes (``can_frames_bytes``, written directly) are upb's serialization of
``can_frames``'s message, byte for byte, for frames of every kind; what upb refuses is refused."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.messages import cheope_pb2 as pb
from logs.can_frames_wire import can_frames_bytes
from logs.messages import can_frames

# Any FrameRecord the message can hold, beyond what a bus delivers: every flag on or off on its own,
# identifiers and remote lengths up to uint32's end, times from 0 ns (left out on the wire) up.
_record = st.tuples(
    st.booleans(),
    st.integers(0, 2**53).map(lambda ns: ns / 1e9),
    st.one_of(st.integers(0, 0x7FF), st.integers(0, 2**32 - 1)),
    st.binary(max_size=64),
    st.booleans(),
    st.booleans(),
    st.one_of(st.just(0), st.integers(0, 2**32 - 1)),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)


@settings(deadline=None, max_examples=300)
@given(st.lists(_record, max_size=12), st.integers(0, 2 * 10**18))
def test_written_frames_are_upbs_bytes(frames, offset_ns):
    assert can_frames_bytes(frames, offset_ns) == can_frames(frames, offset_ns).SerializeToString()


def test_a_cycles_frames_read_back():
    """A classic cycle's frames (the RPDOs and SYNC out, the TPDOs in) parse back to what they were."""
    frames = [
        (True, 12.5, 0x201, bytes([0x0F, 0, 1, 2, 3, 4]), False, False, 0, False, False, False, False),
        (True, 12.50001, 0x80, b"", False, False, 0, False, False, False, False),
        (False, 12.5004, 0x181, bytes(8), False, False, 0, False, False, False, False),
    ]
    back = pb.CanFrames.FromString(can_frames_bytes(frames, 1_700_000_000_000_000_000)).frames
    assert [(f.outgoing, f.arbitration_id, f.data) for f in back] == [(f[0], f[2], f[3]) for f in frames]
    assert back[2].unix_time_ns == 1_700_000_012_500_400_000


@pytest.mark.parametrize(
    "bad",
    [
        (False, 1.0, 2**32, b"", False, False, 0, False, False, False, False),  # identifier past uint32
        (False, 1.0, 0x100, b"", False, True, 2**32, False, False, False, False),  # remote length
        (False, -1.0, 0x100, b"", False, False, 0, False, False, False, False),  # before the epoch
    ],
)
def test_what_the_message_cannot_hold_is_refused_as_upb_refuses_it(bad):
    with pytest.raises(ValueError):
        can_frames([bad], 0).SerializeToString()
    with pytest.raises(ValueError, match="out of range"):
        can_frames_bytes([bad], 0)


# Classic data frames as the bus carries them, the layouts' path (the record above rarely is one).
_classic = st.tuples(
    st.booleans(),
    st.integers(1, 2**40).map(lambda ns: ns / 1e9),
    st.integers(0, 0x800),
    st.binary(max_size=9),
    st.just(False),
    st.just(False),
    st.just(0),
    st.just(False),
    st.just(False),
    st.just(False),
    st.just(False),
)


@settings(deadline=None, max_examples=300)
@given(st.lists(_classic, max_size=12), st.integers(0, 2 * 10**18))
def test_written_classic_frames_are_upbs_bytes(frames, offset_ns):
    assert can_frames_bytes(frames, offset_ns) == can_frames(frames, offset_ns).SerializeToString()
