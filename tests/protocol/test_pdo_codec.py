"""Cyclic PDO codecs: golden bytes, round trips, bad lengths."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.core.cycle_data import SENSOR_FORCE_SATURATED
from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    TORQUE_NM_PER_COUNT,
    FrameError,
    PositionScale,
    decode_drive_rpdo,
    decode_drive_tpdo,
    decode_sensor_frame,
    encode_drive_rpdo,
    encode_drive_tpdo,
    encode_sensor_frame,
)


def test_drive_rpdo_golden_bytes():
    # controlword 0x000F, target 5 823 093 counts (0.5823093 m at 1e7 counts/m), little endian
    assert encode_drive_rpdo(0x000F, 5823093) == bytes.fromhex("0f00 75da5800")
    assert encode_drive_rpdo(0x0006, -1) == bytes.fromhex("0600 ffffffff")


def test_drive_tpdo_golden_bytes():
    assert decode_drive_tpdo(bytes.fromhex("3716 75da5800")) == (0x1637, 5823093)


def test_sensor_frame_golden_bytes():
    data = encode_sensor_frame((1.0, -2.5, 300.0), FORCE_N_PER_COUNT, 0, 7)
    assert data == bytes.fromhex("6400 06ff 3075 00 07")  # 100, -250, 30000 counts


@given(st.integers(0, 0xFFFF), st.integers(-(2**31), 2**31 - 1))
def test_drive_frames_round_trip(cw, counts):
    assert decode_drive_rpdo(encode_drive_rpdo(cw, counts)) == (cw, counts)
    assert decode_drive_tpdo(encode_drive_tpdo(cw, counts)) == (cw, counts)


@given(st.tuples(*[st.floats(-327.0, 327.0)] * 3), st.integers(0, 255))
def test_force_frame_round_trip_within_half_a_count(values, counter):
    x, y, z, status, c = decode_sensor_frame(
        encode_sensor_frame(values, FORCE_N_PER_COUNT, 0, counter), FORCE_N_PER_COUNT
    )
    assert c == counter and status == 0
    for got, want in zip((x, y, z), values, strict=True):
        assert abs(got - want) <= FORCE_N_PER_COUNT / 2 + 1e-12


def test_sensor_frame_saturates_and_flags_it():
    x, _, _, status, _ = decode_sensor_frame(
        encode_sensor_frame((1000.0, 0, 0), FORCE_N_PER_COUNT, 0, 1), FORCE_N_PER_COUNT
    )
    assert x == pytest.approx(327.67)
    assert status & SENSOR_FORCE_SATURATED
    _, _, _, tstatus, _ = decode_sensor_frame(
        encode_sensor_frame((0, 0, 99.0), TORQUE_NM_PER_COUNT, 0, 1), TORQUE_NM_PER_COUNT
    )
    assert tstatus & 0x02


@pytest.mark.parametrize("n", [0, 5, 7, 8])
def test_wrong_length_is_a_frame_error(n):
    with pytest.raises(FrameError, match="6 data bytes"):
        decode_drive_tpdo(bytes(n))


def test_position_scale():
    scale = PositionScale(1e7)
    assert scale.to_counts(0.5823093) == 5823093
    assert scale.to_unit(5823093) == pytest.approx(0.5823093)
    with pytest.raises(ValueError, match="int32"):
        scale.to_counts(300.0)
    with pytest.raises(ValueError, match="positive"):
        PositionScale(0)
