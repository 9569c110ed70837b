"""The committed generated code matches cheope.proto, and messages round-trip."""

from __future__ import annotations

import struct

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.messages import cheope_pb2 as pb
from controller.messages.generate import HERE, generate


def test_generated_code_is_up_to_date(tmp_path):
    fresh = generate(tmp_path)
    assert fresh.read_text() == (HERE / "cheope_pb2.py").read_text(), (
        "cheope_pb2.py is stale: run python -m controller.messages.generate"
    )


def test_cycle_round_trips_doubles_exactly():
    c = pb.Cycle(cycle=7, t_s=7 * 0.0025)
    c.inputs.drives.add(statusword=0x1637, position=0.1 + 0.2, fresh=True)
    c.outputs.targets.extend([1 / 3, 2 / 3, 0.58230929])
    back = pb.Cycle.FromString(c.SerializeToString())
    assert back.inputs.drives[0].position == 0.1 + 0.2
    assert list(back.outputs.targets) == [1 / 3, 2 / 3, 0.58230929]
    assert not back.inputs.HasField("sensor")


def test_the_tracker_plans_ready_and_withheld_targets_round_trip_into_the_steps_inputs():
    """Replay feeds the step what it got: the tracker's sample, the off-loop planner's progress and
    whether the cycle's SYNC went without the targets."""
    from controller.core.cycle_data import CycleInputs, DriveFeedback, TrackerFeedback
    from logs.cycle_encoding import inputs_values
    from logs.messages import inputs_from_pb, inputs_pb

    inputs = CycleInputs(
        drives=(DriveFeedback(0x1637, 0.1 + 0.2, True),),
        tracker=TrackerFeedback((1 / 3, -0.0251, 0.2713), (0.075, 0.31, -0.532), 0, 42, True),
        plans_ready=2,
        targets_withheld=True,
    )
    msg = pb.CycleInputs()
    inputs_pb(inputs_values(inputs), msg)
    assert inputs_from_pb(pb.CycleInputs.FromString(msg.SerializeToString())) == inputs
    without = CycleInputs(drives=inputs.drives)
    msg = pb.CycleInputs()
    inputs_pb(inputs_values(without), msg)
    assert inputs_from_pb(msg) == without and not msg.HasField("tracker")


_frame = st.tuples(
    st.booleans(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=64),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)


def _exact(frames):
    return [(o, struct.pack("<d", t), i, bytes(d), fd, brs, err) for o, t, i, d, fd, brs, err in frames]


@settings(deadline=None)  # a shared machine's pause is not a failure of the packing
@given(
    st.lists(_frame, max_size=40)
    | st.lists(st.builds(lambda k, f: (f[0], k / 1e9, *f[2:]), st.integers(0, 10**15), _frame), max_size=40)
)
def test_an_older_files_packed_batch_comes_back_bit_for_bit(frames):
    """Every frame with its direction, time (any double: nanoseconds or not, -0.0, nan), id, data and flags."""
    from can_frame_batch_packing import pack_frames

    from logs.can_frame_batch import unpack_frames

    back = [
        (f.outgoing, f.monotonic_s, f.arbitration_id, f.data, f.is_fd, f.bitrate_switch, f.is_error_frame)
        for f in unpack_frames(pack_frames(frames))
    ]
    assert _exact(back) == _exact(frames)


def test_a_cut_batch_is_refused_not_misread():
    from can_frame_batch_packing import pack_frames

    from logs.can_frame_batch import unpack_frames

    packed = pack_frames([(True, 1.5, 0x181, b"\x01\x02", False, False, False)] * 3)
    for cut in (2, len(packed) - 1):
        with pytest.raises(ValueError, match="CAN frame batch"):
            list(unpack_frames(packed[:cut]))


_can_message = st.builds(
    lambda ext, rtr, fd, brs, esi, err, arb, data, dlc: can.Message(
        arbitration_id=arb if ext else arb & 0x7FF,
        is_extended_id=ext,
        is_remote_frame=rtr and not fd,
        dlc=dlc if rtr and not fd else None,
        data=None if rtr and not fd else data[: 64 if fd else 8],
        is_fd=fd,
        bitrate_switch=brs and fd,
        error_state_indicator=esi and fd,
        is_error_frame=err,
        check=False,
    ),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=64),
    st.integers(0, 8),
)


@settings(deadline=None)
@given(
    st.lists(st.tuples(st.booleans(), st.integers(0, 10**15), _can_message), max_size=20),
    st.integers(0, 2 * 10**18),
)
def test_a_cycles_frames_come_back_frame_by_frame_with_every_flag(frames, offset_ns):
    """Direction, time (the monotonic nanoseconds on the wall clock), id, data, extended id, RTR and the
    length it requests, FD, BRS, ESI and error frames: in one CanFrames message, decoded field by field."""
    from logs.bus_traffic import as_message
    from logs.messages import can_frames, frame_record

    records = [frame_record(out, ns / 1e9, msg) for out, ns, msg in frames]
    back = pb.CanFrames.FromString(can_frames(records, offset_ns).SerializeToString()).frames
    assert len(back) == len(frames)
    for (outgoing, ns, sent), f in zip(frames, back, strict=True):
        assert f.unix_time_ns == ns + offset_ns and f.outgoing is outgoing
        again = as_message(f)
        assert again.is_rx is not outgoing and again.timestamp == pytest.approx((ns + offset_ns) * 1e-9)
        for name in (
            "arbitration_id",
            "is_extended_id",
            "is_remote_frame",
            "dlc",
            "data",
            "is_fd",
            "bitrate_switch",
            "error_state_indicator",
            "is_error_frame",
        ):
            assert getattr(again, name) == getattr(sent, name), name


def test_recorded_cycles_are_the_values_the_recorder_hands_its_writer():
    """cycle_pb of a recorded cycle's values is the recorded cycle: what the writer builds from the
    loop's values is what the file holds (tests/tools/bench_recording_size.py writes sessions anew)."""
    from pathlib import Path

    from logs.messages import TOPIC_CYCLE, cycle_pb, cycle_values_of_pb
    from logs.reader import iter_decoded

    data = Path(__file__).resolve().parents[1] / "data"
    n = 0
    for name in ("contour_contact.mcap", "path_quarter_lap.mcap"):
        for d in iter_decoded(data / name, [TOPIC_CYCLE]):
            assert cycle_pb(cycle_values_of_pb(d.message)) == d.message
            n += 1
    assert n > 1000
