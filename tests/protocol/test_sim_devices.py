"""The simulated drive and force sensor on their own, with time as an argument."""

from __future__ import annotations

import numpy as np
import pytest

from controller.assembly import build_robot
from controller.config import load_config
from controller.core.cia402 import (
    CW_ENABLE_OPERATION,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    SW_FOLLOWING_COMMAND,
    PowerState,
    decode_statusword,
)
from controller.core.cycle_data import SENSOR_FORCE_SATURATED
from controller.robots.performance import MassModel, cartesian_mass_matrix
from drivers.pdo_codec import FORCE_N_PER_COUNT, decode_sensor_frame
from sim_backend.drive import (
    ABORT_DISABLE_VOLTAGE,
    ABORT_FAULT,
    ABORT_NO_ACTION,
    ABORT_QUICK_STOP,
    EMCY_HEARTBEAT_LOST,
    EMCY_POSITION_RANGE,
    EMCY_SYNC_LOST,
    EMCY_SYNC_PERIOD,
    MAX_EXTRAPOLATION_PERIODS,
    SimulatedDrive,
)
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor
from sim_backend.mechanics import ComplianceParams, CompliantTool
from sim_backend.plant import RobotPlant, drive_params_from_config
from sim_backend.server import STARVED_TICK_S, WATCHDOG_PERIOD_S, watchdog_due

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
    timeout = d.params.sync_timeout_s
    d.advance(t + 0.8 * timeout)  # within the SYNC timeout: still enabled
    assert d.power == PowerState.OPERATION_ENABLED
    d.advance(t + 1.2 * timeout)
    assert d.power == PowerState.QUICK_STOP_ACTIVE
    assert EMCY_SYNC_LOST in d.pending_emcy
    d.advance(t + 1.2 * timeout + 0.15)  # 0.2 m/s at 5 m/s^2 stops within 40 ms
    assert d.velocity == 0.0


def test_object_0x2011_sets_the_sync_watchdog_time_in_ms():
    d, t = enabled_drive()
    for k in range(10):
        t = cycle(d, t, 0.55 + 0.2 * k * PERIOD)
    assert d.sync_timeout_s == d.params.sync_timeout_s  # its own at power-on
    assert d.write_object(0x2011, 0, 300)
    d.advance(t + 0.28)  # past the power-on time, within the written one: still enabled
    assert d.power == PowerState.OPERATION_ENABLED
    d.advance(t + 0.32)
    assert d.power == PowerState.QUICK_STOP_ACTIVE and EMCY_SYNC_LOST in d.pending_emcy
    assert not d.write_object(0x2011, 0, 0)  # a watchdog that never fires is refused
    assert not d.write_object(0x2011, 0, 0x10000)
    assert d.sync_timeout_s == 0.3
    d.reboot()
    assert d.sync_timeout_s == d.params.sync_timeout_s  # a power cycle forgets it, as 0x2010


def test_a_sync_handled_late_is_not_a_lost_sync():
    # The simulator's process was not scheduled for 60 ms; the SYNC waited in its socket.
    d, t = enabled_drive()
    t = cycle(d, t, 0.55)
    d.on_rpdo(CW_ENABLE_OPERATION, round(0.55 * COUNTS))
    d.on_sync(t + 0.06)
    assert d.power == PowerState.OPERATION_ENABLED
    assert EMCY_SYNC_LOST not in d.pending_emcy


def test_the_watchdog_thread_skips_the_tick_after_a_stall_of_its_process():
    timeout = 0.05
    on_time = 10.0 - WATCHDOG_PERIOD_S
    assert not watchdog_due(10.0, on_time, last_sync_s=9.99, sync_timeout_s=timeout)  # SYNC recent
    assert watchdog_due(10.0, on_time, last_sync_s=9.97, sync_timeout_s=timeout)  # overdue by half
    assert watchdog_due(10.0, on_time, last_sync_s=None, sync_timeout_s=timeout)  # never had one
    stalled = 10.0 - STARVED_TICK_S - 0.001
    assert not watchdog_due(10.0, stalled, last_sync_s=9.9, sync_timeout_s=timeout)


@pytest.mark.parametrize(
    ("option", "power"),
    [
        (ABORT_QUICK_STOP, PowerState.QUICK_STOP_ACTIVE),
        (ABORT_FAULT, PowerState.FAULT),
        (ABORT_DISABLE_VOLTAGE, PowerState.SWITCH_ON_DISABLED),
        (ABORT_NO_ACTION, PowerState.OPERATION_ENABLED),
    ],
)
def test_the_controller_heartbeat_lost_gets_the_abort_connection_reaction_of_0x6007(option, power):
    d, t = enabled_drive()
    d.abort_connection_option = option
    d.heartbeat_consumer_s = 0.3
    d.on_controller_heartbeat(t)
    for _ in range(160):  # SYNC keeps coming for 0.4 s, heartbeat does not
        t = cycle(d, t, 0.55)
    assert d.power == power
    assert (EMCY_HEARTBEAT_LOST in d.pending_emcy) == (option != ABORT_NO_ACTION)


@pytest.mark.parametrize(
    ("option", "power"),
    [
        (ABORT_QUICK_STOP, PowerState.QUICK_STOP_ACTIVE),
        (ABORT_FAULT, PowerState.FAULT),
        (ABORT_NO_ACTION, PowerState.OPERATION_ENABLED),
    ],
)
def test_nmt_leaving_operational_while_enabled_gets_the_abort_connection_reaction(option, power):
    d, _ = enabled_drive()
    d.abort_connection_option = option
    d.on_nmt_left_operational()  # PRE-OPERATIONAL: its RPDOs (and their quick stop) no longer reach it
    assert d.power == power


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


def test_a_disabled_drive_integrates_only_the_time_since_its_last_advance():
    # Found in stop 24: a drive not enabled never moved its clock on, so every SYNC integrated the
    # whole time since its first one again (2 000 sub-steps per drive and SYNC 1 s into a run),
    # and in the emulated vcan VM the simulator fell behind its TPDOs while the drives were enabled.
    d = SimulatedDrive(drive_params_from_config(load_config()), position=0.55)
    d.advance(0.0)
    d.advance(1.0)
    trace: list[float] = []
    d.advance(1.0 + 4 * d.params.substep_s, trace=trace)
    assert d.power != PowerState.OPERATION_ENABLED
    assert len(trace) == 2 * 4  # position and acceleration per sub-step
    assert d.time_s == 1.0 + 4 * d.params.substep_s


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


def test_cogging_moves_the_tool_by_the_inverse_jacobian_of_the_carriage_displacement():
    """A carriage force f through the lumped stiffness k J^T J: the tool moves by J^-1 f / k."""
    amplitude, period, phases = 4.0, 0.024, (0.0, 120.0, 240.0)
    cfg = load_config(
        overrides={
            "task.kind": "contour",
            "sim.drive.cogging_force_n": amplitude,
            "sim.drive.cogging_period_m": period,
            "sim.drive.cogging_phases_deg": list(phases),
        }
    )
    plant = RobotPlant(cfg)  # drives disabled, brakes holding; the TCP is clear of the disk
    plant.advance(0.0)
    plant.advance(3.0)  # the structure's modes have settled
    assert plant.force_n is not None and not np.any(plant.force_n)  # no contact
    q = np.array([d.position for d in plant.drives])
    f = amplitude * np.sin(2.0 * np.pi * q / period + np.radians(phases))
    jac = plant.robot.jacobian(plant.tcp_kinematic_m)
    expected = np.linalg.solve(jac, f) / cfg.robot.model("cheope").mass.actuator_stiffness_n_m
    assert np.max(np.abs(expected)) > 1e-6  # a visible test: micrometres
    assert np.asarray(plant.tool.deflection_m) == pytest.approx(expected, rel=1e-3, abs=1e-10)


def test_without_cogging_the_unloaded_structure_stays_put():
    plant = RobotPlant(load_config(overrides={"task.kind": "contour", "sim.drive.cogging_force_n": 0.0}))
    plant.advance(0.0)
    plant.advance(0.5)
    assert plant.tool.deflection_m == (0.0, 0.0, 0.0)


def test_inertial_load_deflects_the_structure_by_its_mass_times_the_base_acceleration():
    cfg = load_config()
    jac = build_robot(cfg).jacobian(np.array([0.03, -0.02, 0.5]))
    masses = MassModel(
        cfg.robot.model("cheope").mass.platform_kg,
        cfg.robot.model("cheope").mass.slider_kg,
        cfg.robot.model("cheope").mass.rod_pair_kg,
    )
    k = cfg.robot.model("cheope").mass.actuator_stiffness_n_m
    tool = CompliantTool(ComplianceParams(k, 0.2, masses))
    tool.set_structure(jac)
    a = (0.3, -0.2, 0.1)
    for _ in range(10000):  # 5 s: settled
        tool.step((0.0, 0.0, 0.0), 5e-4, a)
    expected = -np.linalg.solve(k * jac.T @ jac, cartesian_mass_matrix(jac, masses) @ np.array(a))
    assert np.asarray(tool.deflection_m) == pytest.approx(expected, rel=1e-3)


def test_the_drives_effort_holds_the_structure_against_a_static_load():
    """The motors' forces (0x6077) carry what the structure carries: J^T tau = -K x. With the cogging
    as the only load, the structure deflects by K^-1 J^T f and the efforts cancel the cogging."""
    cfg = load_config(overrides={"task.kind": "contour"})
    plant = RobotPlant(cfg)  # the TCP clear of the disk: cogging is the only load
    plant.advance(0.0)
    plant.advance(3.0)  # settled
    plant.sync(3.0)
    q = np.array([d.position for d in plant.drives])
    d = cfg.sim.drive
    cogging = d.cogging_force_n * np.sin(
        2.0 * np.pi * q / d.cogging_period_m + np.radians(d.cogging_phases_deg)
    )
    efforts = np.array([drive.effort_n for drive in plant.drives])
    assert np.max(np.abs(cogging)) > 0.5  # a visible test
    assert efforts == pytest.approx(-cogging, abs=1e-3)


def test_in_free_space_the_drives_effort_accelerates_the_structures_mass():
    """tau = J^-T M J^-1 q'' with M = m0 I + mq J^T J (controller/robots/performance.py), q'' each
    carriage's mean acceleration over the SYNC interval (a drive's torque actual value is filtered)."""
    cfg = load_config()  # the path task: free space, no structure integrated
    plant = RobotPlant(cfg)
    plant.advance(0.0)
    plant.sync(0.0)  # the carriages' velocities at this SYNC: at rest
    interval_s = 0.0025
    for drive, a in zip(plant.drives, (0.4, -0.3, 0.2), strict=True):
        drive.velocity = a * interval_s  # the mean acceleration over the interval to the next SYNC
    plant._free_efforts(interval_s)  # what the next SYNC computes (the disabled drives would not move)
    jac = plant.robot.jacobian(plant.tcp_kinematic_m)
    masses = MassModel(
        cfg.robot.model("cheope").mass.platform_kg,
        cfg.robot.model("cheope").mass.slider_kg,
        cfg.robot.model("cheope").mass.rod_pair_kg,
    )
    tcp_acceleration = np.linalg.solve(jac, np.array([0.4, -0.3, 0.2]))
    efforts = np.array([drive.effort_n for drive in plant.drives])
    assert jac.T @ efforts == pytest.approx(cartesian_mass_matrix(jac, masses) @ tcp_acceleration, rel=1e-9)


def test_drive_reports_the_acceleration_of_its_last_substep():
    d, t = enabled_drive()
    t = cycle(d, t, 0.55)
    t = cycle(d, t, 0.55 + 0.1 * PERIOD)  # start a 0.1 m/s ramp: the carriage accelerates
    h = d.params.substep_s
    v0 = d.velocity
    d.advance(d.time_s + h)
    assert d.acceleration > 1.0
    assert d.acceleration == pytest.approx((d.velocity - v0) / h)
    for _k in range(2, 400):
        t = cycle(d, t, 0.55 + 0.1 * PERIOD)  # hold: it settles
    assert abs(d.acceleration) < 1e-3


# -- a late or missing setpoint (a CSP drive's interpolator, sim_backend/drive.py) ------------


def moving_drive(speed_m_s: float = 0.1, cycles: int = 200) -> tuple[SimulatedDrive, float, float]:
    """A drive following a ramp with 0x60C2 set to the period; returns it, the time and the last target."""
    d, t = enabled_drive()
    d.interpolation_period_s = PERIOD
    target = 0.55
    for _ in range(cycles):
        target += speed_m_s * PERIOD
        t = cycle(d, t, target)
    return d, t, target


def test_a_sync_without_a_new_target_extrapolates_the_last_step_once_then_holds():
    d, t, target = moving_drive()
    step = 0.1 * PERIOD
    d.on_sync(t)  # no RPDO since the last SYNC: the reference runs on along the segment
    assert d._reference(t + PERIOD) == pytest.approx(target + step, abs=1e-12)
    d.advance(t + PERIOD)
    assert d.velocity == pytest.approx(0.1, rel=0.02)  # the carriage did not stop
    d.on_sync(t + PERIOD)  # silent again: hold (one period of extrapolation, 0x2010 at power-on)
    assert d._reference(t + 2 * PERIOD) == pytest.approx(target + step, abs=1e-12)
    d.advance(t + 15 * PERIOD, check_sync_timeout=False)  # (37.5 ms: within the SYNC watchdog anyway)
    assert d.position == pytest.approx(target + step, abs=2e-6) and abs(d.velocity) < 1e-3
    # the next target is taken as it comes
    t2 = cycle(d, t + 15 * PERIOD, target + 2 * step)
    assert d.latched_target == pytest.approx(target + 2 * step, abs=1e-12)
    assert t2 > t


@pytest.mark.parametrize("periods", [0, 1, 3])
def test_object_0x2010_sets_how_many_periods_the_reference_runs_on_blind(periods):
    """Written at set-up (drivers/node_setup.py): SYNCs without a new target, or none at all, leave
    the reference on its segment for this many periods past the last target; then it holds."""
    d, t, target = moving_drive()
    step = 0.1 * PERIOD
    assert d.write_object(0x2010, 0, periods)
    for k in range(1, periods + 3):
        if k % 2:
            d.on_sync(t + k * PERIOD)  # a SYNC without a target (every other period: none at all)
        assert d._reference(t + k * PERIOD) == pytest.approx(target + min(k, periods) * step, abs=1e-12)
    d.advance(t + (periods + 12) * PERIOD, check_sync_timeout=False)
    assert d.position == pytest.approx(target + periods * step, abs=2e-6) and abs(d.velocity) < 1e-3
    # a new target starts its segment where the reference is: no jump back along the way
    t2 = t + (periods + 12) * PERIOD
    d.on_rpdo(CW_ENABLE_OPERATION, round((target + (periods + 1) * step) * COUNTS))
    d.on_sync(t2)
    assert d._reference(t2) == pytest.approx(target + periods * step, abs=1e-12)
    assert not d.write_object(0x2010, 0, MAX_EXTRAPOLATION_PERIODS + 1)  # more than the drive allows: refused
    assert d.extrapolation_periods == periods


def test_past_a_missing_target_the_drive_runs_on_at_the_commanded_speed_not_the_jump_between_targets():
    """A target after a SYNC without one lies two steps on: the commanded speed is the targets'
    difference over the time between their SYNCs. Taken as one period's step, the reference ran on
    at twice the speed: drives 2 steps ahead of the controller's model after every such gap."""
    d, t, target = moving_drive()
    step = 0.1 * PERIOD
    assert d.write_object(0x2010, 0, 4)
    d.on_sync(t)  # no target
    d.on_rpdo(CW_ENABLE_OPERATION, round((target + 2 * step) * COUNTS))
    d.on_sync(t + PERIOD)
    assert d._reference(t + 2 * PERIOD) == pytest.approx(target + 2 * step, abs=1e-9)
    assert d._reference(t + 3 * PERIOD) == pytest.approx(target + 3 * step, abs=1e-9)


def test_a_late_sync_lets_the_reference_run_on_for_one_period_at_the_segment_speed():
    d, t, target = moving_drive()
    step = 0.1 * PERIOD
    # the next SYNC comes 1.5 periods late: the reference went on past the target at 0.1 m/s
    assert d._reference(t - PERIOD + PERIOD) == pytest.approx(target, abs=1e-12)  # end of the segment
    assert d._reference(t + 0.5 * PERIOD) == pytest.approx(target + 0.5 * step, abs=1e-12)
    assert d._reference(t + 5 * PERIOD) == pytest.approx(target + step, abs=1e-12)  # then it holds
    d.advance(t + 0.5 * PERIOD)
    assert d.velocity == pytest.approx(0.1, rel=0.02)
    # with the next target (one step on) it goes on without turning back
    cycle(d, t + 0.5 * PERIOD, target + step)
    x = d.position
    d.advance(t + 1.5 * PERIOD)
    assert d.position > x and d.velocity > 0.0


def test_a_sync_later_than_the_extrapolation_finds_the_carriage_standing_at_the_held_reference():
    # A real drive's interpolator gives a held reference zero velocity: the carriage stops there.
    # Fed the segment's speed forward instead, it settled 2 zeta v / wn past it: 0.48 mm at 0.1 m/s.
    d, t, target = moving_drive()
    step = 0.1 * PERIOD
    held = target + step  # the segment's end plus one period of extrapolation
    d.advance(t + 10 * PERIOD, check_sync_timeout=False)  # 25 ms without a SYNC
    assert d.position == pytest.approx(held, abs=5e-6)
    assert abs(d.velocity) < 1e-3


def test_the_interpolation_period_is_0x60c2_not_the_measured_sync_interval():
    d, t, target = moving_drive()
    # a SYNC 1 ms early: with 0x60C2 the drive still interpolates over 2.5 ms
    t_early = t - 0.001
    d.on_rpdo(CW_ENABLE_OPERATION, round((target + 0.1 * PERIOD) * COUNTS))
    d.on_sync(t_early)
    assert d.segment_period_s == PERIOD
    d.interpolation_period_s = 0.0  # not configured: the measured SYNC interval
    assert d.segment_period_s == pytest.approx(PERIOD - 0.001)


def test_interpolation_time_period_as_written_by_the_set_up():
    from drivers.node_setup import interpolation_time_period

    assert interpolation_time_period(0.0025) == (25, -4)
    assert interpolation_time_period(0.001) == (1, -3)
    assert interpolation_time_period(0.00025) == (25, -5)
    value, index = interpolation_time_period(1 / 300)  # no exact form: the finest that fits 8 bits
    assert value <= 255 and value * 10.0**index == pytest.approx(1 / 300, rel=0.02)


def _syncs(d: SimulatedDrive, t: float, intervals_s: list[float]) -> float:
    for dt in intervals_s:
        t += dt
        d.on_rpdo(CW_ENABLE_OPERATION, d.position_counts())
        d.on_sync(t)
    return t


def test_a_sync_period_other_than_the_configured_one_is_reported_once_by_emcy():
    d, t = enabled_drive()
    d.communication_cycle_period_s = PERIOD  # 0x1006 as set-up writes it
    t = _syncs(d, t, [PERIOD] * 128 + [1.7 * PERIOD] * 128)  # a loaded machine's loop: no mismatch
    assert EMCY_SYNC_PERIOD not in d.pending_emcy
    t = _syncs(d, t, [4 * PERIOD] * 128)  # the master runs at a quarter of the rate it configured
    assert d.pending_emcy.count(EMCY_SYNC_PERIOD) == 1
    assert d.sync_period_mismatch
    t = _syncs(d, t, [PERIOD] * 128)
    assert not d.sync_period_mismatch and d.pending_emcy.count(EMCY_SYNC_PERIOD) == 1
    _syncs(d, t, [0.4 * PERIOD] * 128)  # 2.5 times the rate
    assert d.pending_emcy.count(EMCY_SYNC_PERIOD) == 2


def test_single_late_syncs_are_not_a_period_mismatch():
    d, t = enabled_drive()
    d.interpolation_period_s = PERIOD  # 0x60C2 only: it is the expected period then
    intervals = [PERIOD] * 200
    for k in range(0, 200, 5):  # every fifth interval 4 ms (160 %) longer (a descheduled master)
        intervals[k] += 0.004
    _syncs(d, t, intervals)
    assert EMCY_SYNC_PERIOD not in d.pending_emcy
