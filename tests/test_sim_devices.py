"""The simulated drive and force sensor on their own, with time as an argument."""

from __future__ import annotations

import numpy as np
import pytest

from controller.config import load_config
from drivers.cia402 import (
    CW_ENABLE_OPERATION,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    SW_FOLLOWING_COMMAND,
    PowerState,
    decode_statusword,
)
from drivers.pdo_codec import FORCE_N_PER_COUNT, SENSOR_FORCE_SATURATED, decode_sensor_frame
from sim_backend.drive import EMCY_HEARTBEAT_LOST, EMCY_POSITION_RANGE, EMCY_SYNC_LOST, SimulatedDrive
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor
from sim_backend.plant import drive_params_from_config

PERIOD = 0.0025
COUNTS = 1e7


def enabled_drive(position=0.55) -> tuple[SimulatedDrive, float]:
    d = SimulatedDrive(drive_params_from_config(load_config()), position=position)
    d.mode_of_operation = 8
    t = 0.0
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        d.on_rpdo(cw, round(position * COUNTS))
        d.on_sync(t)
        t += PERIOD
    assert d.power == PowerState.OPERATION_ENABLED
    return d, t


def cycle(d: SimulatedDrive, t: float, target_m: float) -> float:
    d.on_rpdo(CW_ENABLE_OPERATION, round(target_m * COUNTS))
    d.on_sync(t)
    return t + PERIOD


def test_follows_a_ramp_with_small_lag_and_reports_following():
    d, t = enabled_drive()
    for k in range(400):  # 0.1 m/s for 1 s
        t = cycle(d, t, 0.55 + 0.1 * k * PERIOD)
    # latched 0.6475 at the last SYNC, reached one interpolation period later
    d.advance(t)
    assert d.position == pytest.approx(0.55 + 0.1 * 399 * PERIOD, abs=5e-6)
    assert d.statusword() & SW_FOLLOWING_COMMAND
    assert decode_statusword(d.statusword()) == PowerState.OPERATION_ENABLED


def test_encoder_is_quantised():
    d, _ = enabled_drive(position=0.5500000437)
    assert d.position_counts() == 5500000
    assert d.position_counts() / COUNTS != d.position


def test_quick_stops_when_sync_stops():
    d, t = enabled_drive()
    for k in range(100):
        t = cycle(d, t, 0.55 + 0.2 * k * PERIOD)  # moving at 0.2 m/s
    d.advance(t + 0.04)  # within the 50 ms SYNC timeout: still enabled
    assert d.power == PowerState.OPERATION_ENABLED
    d.advance(t + 0.06)
    assert d.power == PowerState.QUICK_STOP_ACTIVE
    assert EMCY_SYNC_LOST in d.pending_emcy
    d.advance(t + 0.2)  # 0.2 m/s at 5 m/s^2 stops within 40 ms
    assert d.velocity == 0.0


def test_quick_stops_when_the_controller_heartbeat_stops():
    d, t = enabled_drive()
    d.heartbeat_consumer_s = 0.3
    d.on_controller_heartbeat(t)
    for _ in range(160):  # SYNC keeps coming for 0.4 s, heartbeat does not
        t = cycle(d, t, 0.55)
    assert d.power == PowerState.QUICK_STOP_ACTIVE
    assert EMCY_HEARTBEAT_LOST in d.pending_emcy


def test_end_stop_faults_the_drive():
    d, t = enabled_drive(position=0.88)
    for k in range(200):
        t = cycle(d, t, 0.88 + 0.2 * k * PERIOD)  # towards the 0.90 m end stop
    assert d.power == PowerState.FAULT
    assert d.position == pytest.approx(0.90)
    assert EMCY_POSITION_RANGE in d.pending_emcy


def test_not_in_csp_mode_holds_position():
    d, t = enabled_drive()
    d.mode_of_operation = 1
    for _ in range(40):
        t = cycle(d, t, 0.60)
    assert d.position == pytest.approx(0.55)


def test_force_sensor_bias_noise_saturation_and_counter():
    s = SimulatedForceSensor(SensorParams(noise_std_n=0.5, bias_n=(1.0, -2.0, 0.5), range_n=100.0, seed=3))
    samples = []
    counters = []
    for _ in range(2000):
        f, _t = s.sample(np.array([10.0, 0.0, 0.0]), np.zeros(3))
        x, y, z, status, counter = decode_sensor_frame(f, FORCE_N_PER_COUNT)
        samples.append((x, y, z))
        counters.append(counter)
        assert status == 0
    a = np.array(samples)
    assert np.allclose(a.mean(axis=0), [11.0, -2.0, 0.5], atol=0.05)
    assert np.allclose(a.std(axis=0), 0.5, atol=0.05)
    assert counters[:3] == [1, 2, 3] and counters[255] == 0  # rolls over after 255
    f, _ = s.sample(np.array([150.0, 0.0, 0.0]), np.zeros(3))
    x, _, _, status, _ = decode_sensor_frame(f, FORCE_N_PER_COUNT)
    assert status & SENSOR_FORCE_SATURATED and x == pytest.approx(100.0)
