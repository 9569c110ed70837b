"""The pose tracker's frames: codec, the simulated tracker's rate and noise, the exchange's decoding."""

from __future__ import annotations

import numpy as np
import pytest

from controller.config import load_config
from controller.core.cycle_data import TRACKER_SATURATED
from controller.core.rotations import so3_log
from controller.robot_registry import robot_entry
from controller.shell.loop import SimulatedTime
from drivers.pdo_codec import (
    TRACKER_M_PER_COUNT,
    TRACKER_RAD_PER_COUNT,
    FrameError,
    decode_tracker_frame,
    encode_tracker_frames,
)
from sim_backend.loopback import LoopbackExchange
from sim_backend.pose_tracker import SimulatedPoseTracker

NSPU_TOML = robot_entry("nspu").config_file  # in the robot's home


def test_tracker_frames_round_trip_to_a_count():
    p, r = (0.0123, -0.0456, 0.3210), (0.075, -0.31, -0.532)
    fp, fr = encode_tracker_frames(p, r, 0, 7)
    xp = decode_tracker_frame(fp, TRACKER_M_PER_COUNT)
    xr = decode_tracker_frame(fr, TRACKER_RAD_PER_COUNT)
    assert np.allclose(xp[:3], p, atol=TRACKER_M_PER_COUNT / 2) and np.allclose(
        xr[:3], r, atol=TRACKER_RAD_PER_COUNT / 2
    )
    assert xp[3:] == (0, 7) and xr[3:] == (0, 7)


def test_tracker_position_beyond_the_range_saturates_and_says_so():
    fp, fr = encode_tracker_frames((0.0, 0.0, 0.9), (0.0, 0.0, 0.0), 0, 1)
    assert decode_tracker_frame(fp, TRACKER_M_PER_COUNT)[3] & TRACKER_SATURATED
    assert decode_tracker_frame(fr, TRACKER_RAD_PER_COUNT)[3] & TRACKER_SATURATED
    with pytest.raises(FrameError, match="pose tracker TPDO must have 8 data bytes"):
        decode_tracker_frame(fp[:6], TRACKER_M_PER_COUNT)


def _run(overrides: dict[str, object], cycles: int) -> tuple[LoopbackExchange, list]:
    cfg = load_config(
        NSPU_TOML,
        {"recording.enabled": False, "monitoring.enabled": False, "tracker.enabled": True, **overrides},
    )
    clock = SimulatedTime()
    ex = LoopbackExchange(cfg, clock.clock)
    out = []
    for k in range(cycles):
        clock.sleep_until(k * cfg.period_s)
        ex.send(None)
        out.append(ex.collect(clock.clock() + cfg.period_s).tracker)
    return ex, out


def test_the_exchange_decodes_the_simulated_pose_at_the_tracker_rate():
    ex, samples = _run(
        {
            "sim.tracker.position_noise_m": 0.0,
            "sim.tracker.angle_noise_rad": 0.0,
            "sim.tracker.rate_hz": 100.0,
        },
        40,
    )
    fresh = [k for k, s in enumerate(samples) if s is not None and s.fresh]
    assert np.all(np.diff(fresh) == 4)  # 100 Hz on a 400 Hz loop: every fourth SYNC
    assert len(fresh) == 10
    last = samples[fresh[-1]]
    pose = ex.plant.kinematics.pose
    assert np.allclose(last.position_m, pose.p_m, atol=TRACKER_M_PER_COUNT / 2)
    assert np.allclose(last.rotation_vector_rad, so3_log(pose.R), atol=TRACKER_RAD_PER_COUNT / 2)


def test_the_simulated_tracker_noise_has_the_configured_spread():
    ex, samples = _run(
        {
            "sim.tracker.position_noise_m": 1e-3,
            "sim.tracker.angle_noise_rad": 2e-3,
            "sim.tracker.rate_hz": 400.0,
        },
        400,
    )
    p = np.array([s.position_m for s in samples if s.fresh])
    truth = ex.plant.kinematics.pose.p_m  # the platform stands still (no targets sent)
    assert p.shape[0] > 350
    assert np.std(p - truth, axis=0) == pytest.approx([1e-3] * 3, rel=0.2)
    assert np.abs(np.mean(p - truth, axis=0)).max() < 3e-4


def test_no_tracker_sample_of_a_pose_integrated_only_up_to_long_before_the_sync():
    """The simulator process integrates the 3-nSPU's pose on a thread behind its answers
    (``RobotPlant.kinematics_sample``); a sample of a pose that thread has not brought up to the
    SYNC would show the platform where it was (sim_backend/plant.py ``tracker_frames``)."""
    from sim_backend.plant import TRACKER_POSE_LAG_S, RobotPlant

    cfg = load_config(
        NSPU_TOML,
        {"recording.enabled": False, "monitoring.enabled": False, "tracker.enabled": True},
    )
    plant = RobotPlant(cfg)
    assert plant.tracker_frames(0.0) is not None  # before any sample: the start pose, known
    q = np.array([d.position for d in plant.drives])
    assert plant.update_kinematics(1.0, q)  # the pose thread at t = 1 s
    assert plant.kinematics.pose_time_s == 1.0
    behind = 1.0 + TRACKER_POSE_LAG_S + 0.5  # a SYNC half a second later: the thread is behind
    assert plant.tracker_frames(behind) is None
    assert plant.update_kinematics(behind - 0.005, q)  # caught up to within a few milliseconds
    assert plant.tracker_frames(behind) is not None


def test_a_sample_carries_the_status_bits_of_both_its_frames():
    """A tracker that flags only the frame that saturated: the rotation frame after it, status 0,
    must not clear the position frame's bit (the exchange kept the last frame's status only)."""
    cfg = load_config(
        NSPU_TOML,
        {"recording.enabled": False, "monitoring.enabled": False, "tracker.enabled": True},
    )
    clock = SimulatedTime()
    ex = LoopbackExchange(cfg, clock.clock)
    fp, _ = encode_tracker_frames((0.9, 0.0, 0.25), (0.0, 0.0, 0.1), 0, 7)  # x beyond +-0.655 m
    _, fr = encode_tracker_frames((0.0, 0.0, 0.25), (0.0, 0.0, 0.1), 0, 7)
    assert decode_tracker_frame(fp, TRACKER_M_PER_COUNT)[3] == TRACKER_SATURATED
    assert decode_tracker_frame(fr, TRACKER_RAD_PER_COUNT)[3] == 0

    class OneFrameFlagged(SimulatedPoseTracker):
        def frames(self, now_s, position_m, rotation):
            return fp, fr  # position first, as the simulator sends them

    ex.plant.tracker = OneFrameFlagged(ex.plant.tracker.params)
    ex.send(None)
    sample = ex.collect(clock.clock() + cfg.period_s).tracker
    assert sample.fresh and sample.status == TRACKER_SATURATED
