"""Bus-load calculator against hand-computed frame lengths and loads."""

from __future__ import annotations

import re

import pytest

from drivers.bus_load import (
    BusLoadError,
    FrameSpec,
    check_bus_load,
    classical_frame_bits,
    compute_bus_load,
    cyclic_frames,
    fd_frame_time_s,
    fd_padded_length,
)


def test_classical_frame_lengths_by_hand():
    # 8 bytes: 47 + 64 = 111 bits; stuffing of the 98 stuffable bits: floor(97 / 4) = 24 -> 135
    assert classical_frame_bits(8, worst_case_stuffing=False) == 111
    assert classical_frame_bits(8) == 135
    # SYNC, 0 bytes: 47 bits, floor(33 / 4) = 8 stuff bits -> 55
    assert classical_frame_bits(0) == 55
    # 6-byte PDO: 95 bits + floor(81 / 4) = 20 -> 115
    assert classical_frame_bits(6) == 115
    with pytest.raises(ValueError, match=re.escape("0..8")):
        classical_frame_bits(9)


def test_project_cycle_at_400_hz_by_hand():
    # per cycle: SYNC 55 + 3 RPDO 115 + 3 TPDO 115 + 2 sensor 135 = 1015 bits -> 406 000 bit/s at 400 Hz
    # heartbeats: 5 nodes (3 drives, sensor, controller) at 10 Hz, 1 byte: 47 + 8 + floor(41/4)=10 -> 65 bits
    frames = cyclic_frames(400.0, 3, True, 10.0)
    load = compute_bus_load(frames, 1e6)
    assert load.bits_per_second == pytest.approx(406_000 + 5 * 10 * 65)
    assert load.percent == pytest.approx(40.925)


def test_1khz_classical_is_over_the_limit_and_fd_is_not():
    frames = cyclic_frames(1000.0, 3, True, 10.0)
    with pytest.raises(BusLoadError, match=re.escape("exceeds the limit of 70.0 %")):
        check_bus_load(compute_bus_load(frames, 1e6), 70.0)
    check_bus_load(compute_bus_load(frames, 1e6, fd=True, data_bit_s=5e6), 70.0)


def test_fd_frame_by_hand():
    # 8 bytes, BRS at 5 Mbit/s, nominal 1 Mbit/s, no stuffing:
    # nominal: 17 + 12 = 29 bits -> 29 us; data: 1 + 4 + 64 + 27 + 1 = 97 bits -> 19.4 us
    t = fd_frame_time_s(8, 1e6, 5e6, worst_case_stuffing=False)
    assert t == pytest.approx(29e-6 + 97 / 5e6)
    # 20 bytes is padded to 20 and uses CRC-21 (32-bit CRC field)
    assert fd_padded_length(17) == 20
    assert fd_frame_time_s(20, 1e6, 1e6, bitrate_switch=False, worst_case_stuffing=False) == pytest.approx(
        (17 + 12 + 1 + 4 + 160 + 32 + 1) / 1e6
    )


def test_load_is_linear_in_rate():
    one = compute_bus_load((FrameSpec("x", 8, 100.0),), 5e5)
    two = compute_bus_load((FrameSpec("x", 8, 200.0),), 5e5)
    assert two.load_fraction == pytest.approx(2 * one.load_fraction)
    assert one.load_fraction == pytest.approx(100 * 135 / 5e5)


def test_the_pose_tracker_adds_its_two_frames_at_its_own_rate():
    from drivers.bus_load import compute_bus_load, cyclic_frames

    base = cyclic_frames(400.0, 3, False, 10.0)
    tracked = cyclic_frames(400.0, 3, False, 10.0, tracker_hz=100.0)
    extra = [f for f in tracked if f not in base]
    assert len(extra) == 1 and extra[0].rate_hz == 200.0
    more = compute_bus_load(tracked, 1_000_000).percent - compute_bus_load(base, 1_000_000).percent
    assert 2.0 < more < 3.0  # 200 frames of 8 bytes, about 111-135 bits each, of 1 Mbit/s


def test_the_planned_load_counts_the_drives_pdos_as_the_configuration_maps_them():
    """Cheope's drives send their effort (0x6077) with statusword and position: 8 bytes, and the
    whole cyclic traffic still fits the default 70 % at 400 Hz on classical CAN."""
    from controller.assembly import planned_bus_load
    from controller.config import load_config

    with_effort = planned_bus_load(load_config())
    without = planned_bus_load(load_config(overrides={"actuators.tpdo_objects": []}))
    sizes = {f.name: f.n_bytes for f in with_effort.frames}
    assert sizes["drive TPDO1"] == 8 and sizes["drive RPDO1"] == 6
    assert {f.name: f.n_bytes for f in without.frames}["drive TPDO1"] == 6
    assert without.load_fraction < with_effort.load_fraction < 0.70
