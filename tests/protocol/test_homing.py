"""CiA 402 homing (mode 6): the simulated drive's incremental encoder and switches, and the
controller's set-up homing every drive over SDO before the first cycle."""

from __future__ import annotations

import pytest

from controller.config import ConfigError, load_config
from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_HOMING_START,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    MODE_HOMING,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_TARGET_REACHED,
    PowerState,
)
from controller.node_plan import node_setup_plan
from drivers.node_setup import NodeSetupError, configure_nodes
from sim_backend.drive import SimulatedDrive
from sim_backend.homing import HomingSettings
from sim_backend.plant import drive_params_from_config
from sim_backend.server import Simulator

COUNTS = 1e7
SUBSTEP_S = 0.001


def homing_drive(position: float, encoder_offset: float, settings: HomingSettings) -> SimulatedDrive:
    d = SimulatedDrive(
        drive_params_from_config(load_config()), position=position, encoder_offset=encoder_offset
    )
    d.homing_settings = settings
    d.set_mode(MODE_HOMING)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        d.on_controlword(cw)
    assert d.power == PowerState.OPERATION_ENABLED
    return d


def run_until_done(d: SimulatedDrive, limit_s: float = 60.0) -> float:
    t = 0.0
    d.advance(t)
    d.on_controlword(CW_ENABLE_OPERATION | CW_HOMING_START)
    while not d.statusword() & (SW_HOMING_ATTAINED | SW_HOMING_ERROR) and t < limit_s:
        t += SUBSTEP_S * 10
        d.advance(t)
    return t


def test_current_position_homing_sets_the_reported_position_to_the_home_offset():
    d = homing_drive(0.6, encoder_offset=0.0371, settings=HomingSettings(method=37, home_offset=0.6))
    assert d.position_counts() == round(0.6371 * COUNTS)  # the unknown offset before homing
    run_until_done(d)
    sw = d.statusword()
    assert sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED and not sw & SW_HOMING_ERROR
    assert d.position == 0.6  # did not move
    assert d.position_counts() == round(0.6 * COUNTS)


@pytest.mark.parametrize(("method", "switch_edge"), [(17, 0.32), (18, 0.88)])
def test_limit_switch_homing_finds_the_switch_edge_and_reports_the_home_offset_there(method, switch_edge):
    settings = HomingSettings(
        method=method, home_offset=0.25, switch_speed=0.2, zero_speed=0.005, acceleration=2.0
    )
    d = homing_drive(0.55, encoder_offset=-0.0123, settings=settings)
    run_until_done(d)
    assert d.statusword() & SW_HOMING_ATTAINED
    # it stopped just off the switch, on the side it came from, and that place now reads 0.25 m
    assert d.position == pytest.approx(switch_edge, abs=0.0005)
    assert d.position_counts() == pytest.approx(0.25 * COUNTS, abs=0.0005 * COUNTS)
    # CSP afterwards: a target in the homed coordinates is the true place it names
    d.on_controlword(CW_DISABLE_VOLTAGE)
    d.set_mode(8)
    assert d.from_counts(d.position_counts()) == pytest.approx(d.position, abs=1e-7)


def test_a_limit_switch_beyond_the_stroke_is_a_homing_error():
    cfg = load_config(overrides={"sim.drive.limit_switches_m": [0.10, 0.95]})  # both outside 0.30..0.90
    d = SimulatedDrive(drive_params_from_config(cfg), position=0.55)
    d.homing_settings = HomingSettings(
        method=17, home_offset=0.0, switch_speed=0.5, zero_speed=0.01, acceleration=5.0
    )
    d.set_mode(MODE_HOMING)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        d.on_controlword(cw)
    run_until_done(d)
    assert d.statusword() & SW_HOMING_ERROR and not d.statusword() & SW_HOMING_ATTAINED
    assert d.position == pytest.approx(0.30)  # at the end stop


OFFSETS = (0.0123, -0.0201, 0.0057)


def test_set_up_homes_every_drive_before_the_first_cycle(buses):
    cfg = load_config(
        overrides={
            "sensor.enabled": False,
            "actuators.homing_method": 17,
            "actuators.home_offsets_m": [0.32] * 3,
            "actuators.homing_switch_speed_m_s": 0.2,
            "actuators.homing_acceleration_m_s2": 5.0,
            "actuators.homing_zero_speed_m_s": 0.01,
            "sim.drive.encoder_offsets_m": list(OFFSETS),
        }
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        before = [d.position_counts() / COUNTS - d.position for d in sim.drives]
        assert before == pytest.approx(OFFSETS, abs=1e-7)
        report = configure_nodes(bus, node_setup_plan(cfg))
        # the positions the controller starts from are the true ones: the encoders' offsets are gone
        for counts, d in zip(report.initial_positions_counts, sim.drives, strict=True):
            assert counts / COUNTS == pytest.approx(d.position, abs=0.001)
            assert d.position == pytest.approx(0.32, abs=0.001)  # at the negative switch's edge
            assert d.power == PowerState.SWITCH_ON_DISABLED and d.mode_of_operation == 8


@pytest.mark.parametrize(
    ("key", "value", "kind"),
    [
        ("actuators.home_offsets_m", [1e300, 0.0, 0.0], "INTEGER32"),
        ("actuators.home_offsets_m", [0.0, -300.0, 0.0], "INTEGER32"),  # 3e9 counts: beyond +-2**31
        ("actuators.homing_switch_speed_m_s", 50.0, "UNSIGNED32"),  # at 1e9 counts/m below
        ("actuators.following_error_window_m", 5.0, "UNSIGNED32"),
    ],
)
def test_a_value_that_does_not_fit_its_drive_object_is_named_before_the_bus(key, value, kind):
    """A home offset of 1e300 m passed the configuration and failed at its SDO write with
    canopen's "Value does not fit in specified type", naming nothing."""
    cfg = load_config(overrides={"actuators.homing_method": 17, "actuators.counts_per_m": 1e9, key: value})
    with pytest.raises(
        ConfigError, match=rf"^{key} = .*counts per unit do not fit the drive's {kind} object"
    ):
        node_setup_plan(cfg)


def test_a_homing_error_stops_the_start_naming_node_and_statusword(buses):
    cfg = load_config(
        overrides={
            "sensor.enabled": False,
            "actuators.homing_method": 18,
            "sim.drive.limit_switches_m": [0.32, 0.95],
            "actuators.homing_switch_speed_m_s": 0.5,
            "actuators.homing_acceleration_m_s2": 5.0,
        }
    )
    sim_bus, bus = buses
    with (
        Simulator(cfg, sim_bus),
        pytest.raises(
            NodeSetupError,
            match=r"node 1: homing method 18 failed: statusword 0x6041 = 0x[0-9A-F]{4} \(bit 13",
        ),
    ):
        configure_nodes(bus, node_setup_plan(cfg))


def _run_in_simulated_time(cfg):
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from controller.shell.run_summary import RunRecorder
    from sim_backend.loopback import LoopbackExchange

    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    recorder = RunRecorder()
    loop = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(recorder,)
    )
    final, _ = loop.run(law.initial_state(), 60.0)
    return final, recorder, exchange


@pytest.mark.parametrize("method", [17, 37])
def test_the_path_task_runs_after_homing_drives_with_unknown_encoder_offsets(method):
    from controller.core.controller_state import Mode

    # 17: the negative switch's edge; 37: the carriages stand at a known place (the simulator's start)
    base = load_config()
    home = [0.32] * 3 if method == 17 else list(base.sim.drive.initial_positions_m)
    cfg = load_config(
        overrides={
            "task.path.laps": 0.5,
            "sim.drive.encoder_offsets_m": list(OFFSETS),
            "actuators.homing_method": method,
            "actuators.home_offsets_m": home,
        }
    )
    final, recorder, exchange = _run_in_simulated_time(cfg)
    assert final.mode == Mode.DONE, final.fault_reason
    assert max(recorder.tracking_error_m) < 80e-6
    for d in exchange.drives:  # the drives report their true positions after homing, to the
        # resolution of finding the switch's edge (zero search speed x the simulator's step: 25 um)
        assert d.position_counts() / COUNTS == pytest.approx(d.position, abs=30e-6)


def test_a_stop_while_the_drive_is_being_enabled_for_homing_leaves_it_disabled():
    """The stop request ends homing's waits (drivers/node_setup.py); one that came while the drive
    was still being enabled (a slow brake release) left it enabled: the disabling `finally` began
    after the enabling (a review's finding)."""
    from drivers.homing import HomingPlan, home_drive

    class StopRequestedError(Exception):
        pass

    writes: list[tuple[int, int, int]] = []

    def read(index: int, subindex: int) -> int:
        return {0x6061: MODE_HOMING, 0x6041: 0x0021}.get(index, 0)  # READY TO SWITCH ON, then stays

    def sleep(_: float) -> None:
        raise StopRequestedError  # the stop request, at the first wait

    plan = HomingPlan(17, 0, 1000, 100, 10000, 30.0)
    with pytest.raises(StopRequestedError):
        home_drive(1, plan, lambda i, s, v: writes.append((i, s, v)), read, clock=lambda: 0.0, sleep=sleep)
    assert (0x6040, 0, CW_SWITCH_ON) in writes and writes[-1] == (0x6040, 0, CW_DISABLE_VOLTAGE)
