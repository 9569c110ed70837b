"""PDO mapping from the device description: the simulated devices as CANopen slaves, the
controller's set-up as a master, and a second vendor's drive through configuration alone.

The simulator runs in-process on a python-can ``virtual`` bus; the master side is either the
``canopen`` package alone or this project's ``configure_nodes`` + ``CyclicExchange``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import canopen
import numpy as np
import pytest
from canopen.profiles.p402 import BaseNode402
from waiting import wait_until

from controller.config import load_config
from controller.core.cia402 import PowerState, decode_statusword
from controller.core.controller_state import Mode
from controller.core.cycle_data import CycleOutputs
from drivers.node_setup import DRIVE_EDS, NodeSetupError, configure_nodes
from sim_backend.drive import ABORT_QUICK_STOP, EMCY_SYNC_PERIOD
from sim_backend.pdo_parameters import (
    ABORT_CANNOT_MAP,
    ABORT_DEVICE_STATE,
    ABORT_PDO_LENGTH,
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
)
from sim_backend.server import Simulator

VENDOR_EDS = Path(__file__).resolve().parent.parent / "data" / "vendor_drive.eds"
VENDOR = {
    "actuators.eds_file": str(VENDOR_EDS),
    "actuators.vendor_id": 0x00000A5E,
    "actuators.product_code": 0x00C5D402,
    "actuators.tpdo_objects": [],  # its own default mapping: it has no torque actual value 0x6077
    "actuators.extrapolation_s": 0.0025,  # no 0x2010: it is taken to run on one period, as it must be told
}


def _abort_code(action) -> int:
    with pytest.raises(canopen.SdoAbortedError) as err:
        action()
    return err.value.code


# -- the simulated drive as a slave, remapped by canopen alone ---------------------------------


def test_canopen_remaps_tpdo_and_rpdo_and_the_drive_follows_the_new_layout(sim_and_master):
    sim, network = sim_and_master
    node = BaseNode402(1, str(DRIVE_EDS))
    network.add_node(node)
    node.nmt.state = "PRE-OPERATIONAL"
    node.tpdo.read()
    node.rpdo.read()
    # TPDO1: position, statusword, mode display (7 bytes), in place of statusword, position
    tpdo = node.tpdo[1]
    tpdo.clear()
    tpdo.add_variable(0x6064)
    tpdo.add_variable(0x6041)
    tpdo.add_variable(0x6061)
    tpdo.trans_type = 1
    tpdo.enabled = True
    rpdo = node.rpdo[1]
    rpdo.clear()
    rpdo.add_variable(0x607A)
    rpdo.add_variable(0x6040)
    rpdo.trans_type = 1
    rpdo.enabled = True
    node.tpdo.save()
    node.rpdo.save()
    assert [node.sdo[0x1A00][k].raw for k in range(4)] == [3, 0x60640020, 0x60410010, 0x60610008]
    assert [node.sdo[0x1600][k].raw for k in range(3)] == [2, 0x607A0020, 0x60400010]

    node.setup_402_state_machine(read_pdos=False)  # the PDO maps set above
    node.sdo[0x6060].raw = 8
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)
    drive = sim.drives[0]
    wait_until(lambda: node.tpdo[1]["Position actual value"].raw != 0, "the remapped TPDO1 arrives")
    # canopen decodes the new layout: the simulator sends position, statusword, mode in that order
    assert abs(node.tpdo[1]["Position actual value"].raw - drive.position_counts()) <= 1
    assert decode_statusword(node.tpdo[1]["Statusword"].raw) == PowerState.SWITCH_ON_DISABLED
    assert node.tpdo[1]["Modes of operation display"].raw == 8

    start_counts = node.sdo[0x6064].raw
    rpdo["Target position"].raw = start_counts
    rpdo["Controlword"].raw = 0x0006
    rpdo.start(0.01)
    node.state = "OPERATION ENABLED"  # the controlword now travels in the second slot
    assert drive.power == PowerState.OPERATION_ENABLED
    target = start_counts + 100_000  # +10 mm
    rpdo["Target position"].raw = target
    wait_until(
        lambda: abs(node.tpdo[1]["Position actual value"].raw - target) < 50,
        "the drive reaches the target sent in the remapped RPDO",
    )
    node.state = "SWITCH ON DISABLED"
    rpdo.stop()


def test_invalid_mappings_are_refused_with_cia301_abort_codes(sim_and_master):
    _, network = sim_and_master
    node = network.add_node(1, str(DRIVE_EDS))
    sdo = node.sdo
    # a valid PDO: the remap procedure starts by making it invalid
    assert _abort_code(lambda: setattr(sdo[0x1A00][1], "raw", 0x60640020)) == ABORT_DEVICE_STATE
    assert _abort_code(lambda: setattr(sdo[0x1A00][0], "raw", 0)) == ABORT_DEVICE_STATE
    sdo[0x1800][1].raw = 0x181 | 0x80000000
    # an entry while the count is not 0
    assert _abort_code(lambda: setattr(sdo[0x1A00][1], "raw", 0x60640020)) == ABORT_DEVICE_STATE
    sdo[0x1A00][0].raw = 0
    # entries that cannot be mapped: not mappable (identity), no such object, wrong length
    for entry in (0x10180120, 0x5FFF0020, 0x60640010):
        assert _abort_code(lambda entry=entry: setattr(sdo[0x1A00][1], "raw", entry)) == ABORT_CANNOT_MAP
    # 4 + 4 + 2 bytes do not fit in one PDO: refused when the count enables them
    sdo[0x1A00][1].raw = 0x60640020
    sdo[0x1A00][2].raw = 0x606C0020
    sdo[0x1A00][3].raw = 0x60410010
    assert _abort_code(lambda: setattr(sdo[0x1A00][0], "raw", 3)) == ABORT_PDO_LENGTH
    # more entries than the record has
    assert _abort_code(lambda: setattr(sdo[0x1A00][0], "raw", 5)) == ABORT_VALUE_TOO_HIGH
    # a TPDO transmission type the device does not support (acyclic), a COB-ID change while valid
    assert _abort_code(lambda: setattr(sdo[0x1800][2], "raw", 0)) == ABORT_VALUE_RANGE
    # the RPDO: an object only readable cannot be received
    sdo[0x1400][1].raw = 0x201 | 0x80000000
    sdo[0x1600][0].raw = 0
    assert _abort_code(lambda: setattr(sdo[0x1600][1], "raw", 0x60410010)) == ABORT_CANNOT_MAP
    sdo[0x1600][1].raw = 0x60400010
    sdo[0x1600][2].raw = 0x607A0020
    sdo[0x1600][0].raw = 2
    sdo[0x1400][1].raw = 0x201
    assert _abort_code(lambda: setattr(sdo[0x1400][1], "raw", 0x202)) == ABORT_VALUE_RANGE
    # nothing refused was stored: the count stays 0, the entries and types as last accepted
    assert [sdo[0x1A00][k].raw for k in range(4)] == [0, 0x60640020, 0x606C0020, 0x60410010]
    assert sdo[0x1800][2].raw == 1
    assert sdo[0x1400][1].raw == 0x201


def test_sync_period_mismatch_is_reported_by_emcy(sim_and_master):
    _, network = sim_and_master
    node = network.add_node(1, str(DRIVE_EDS))
    node.sdo[0x1006].raw = 2500  # the master says 2.5 ms...
    node.nmt.state = "OPERATIONAL"
    network.sync.start(0.01)  # ...and sends SYNC every 10 ms
    assert node.emcy.wait(EMCY_SYNC_PERIOD, timeout=30.0) is not None


# -- the controller's set-up as the master -----------------------------------------------------


def _setup_plan(cfg):
    from controller.node_plan import node_setup_plan

    return node_setup_plan(cfg)


def test_set_up_writes_mapping_and_sync_timing_and_reads_them_back(buses):
    cfg = load_config(overrides={"actuators.tpdo_objects": ["0x6064", "0x6041", "0x6061"]})
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        report = configure_nodes(bus, _setup_plan(cfg))
        for j, codec in enumerate(report.drive_codecs):
            assert [o.entry for o in codec.tpdo.objects] == [0x60640020, 0x60410010, 0x60610008]
            assert codec.tpdo.size == 7
            assert codec.tpdo_cob_id == 0x180 + cfg.actuators.node_ids[j]
        assert report.sensor_codecs is not None and report.sensor_codecs[0].is_force
        for d in sim.drives:
            assert d.communication_cycle_period_s == pytest.approx(cfg.period_s)
            assert d.interpolation_period_s == pytest.approx(cfg.period_s)
        sdo_node = sim.nodes[1]
        assert sdo_node.sdo[0x1006].raw == 2500 and sdo_node.sdo[0x1005].raw == 0x80
        # the drives' own reaction to a lost master: quick stop (0x6007), on the controller's heartbeat (0x1016)
        for d in sim.drives:
            assert d.abort_connection_option == ABORT_QUICK_STOP
            assert d.heartbeat_consumer_s == pytest.approx(cfg.loop.heartbeat_consumer_s)


def test_the_effort_is_mapped_scaled_by_the_drives_own_rated_force_and_carries_the_plants_effort(buses):
    """Cheope's configuration maps the torque actual value 0x6077 (the contact force's second
    witness); its scale is read from the drive (0x6076, here the EDS's 200 N: 0.2 N a count)."""
    cfg = load_config()
    assert cfg.actuators.tpdo_objects == ("0x6041", "0x6064", "0x6077")
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        report = configure_nodes(bus, _setup_plan(cfg))
        for j, codec in enumerate(report.drive_codecs):
            assert codec.has_effort and codec.effort_n_per_count == pytest.approx(0.2)
            sim.drives[j].effort_n = -12.34 * (j + 1)
            tpdo = sim.pdos.drive_tpdos()[j]
            assert tpdo is not None
            _, _, effort = codec.decode_tpdo(tpdo[1])
            assert effort == pytest.approx(-12.34 * (j + 1), abs=0.1)  # quantised to 0.2 N


def test_a_mapping_the_device_refuses_stops_the_start_naming_node_object_and_value(tmp_path, buses):
    # The controller's EDS claims the vendor id is mappable; the device's own description does not.
    wrong = tmp_path / "wrong.eds"
    text = DRIVE_EDS.read_text()
    head, _, tail = text.partition("[1018sub1]")
    wrong.write_text(head + "[1018sub1]" + tail.replace("PDOMapping=0", "PDOMapping=1", 1))
    cfg = load_config(overrides={"sensor.enabled": False, "actuators.tpdo_objects": ["0x6041", "0x1018:1"]})
    sim_bus, bus = buses
    plan = _setup_plan(cfg)

    with Simulator(cfg, sim_bus), pytest.raises(NodeSetupError) as err:
        configure_nodes(bus, replace(plan, drive_eds=wrong))
    message = str(err.value)
    assert "\n" not in message
    assert "node 1" in message and "0x1A00sub2" in message and "0x10180120" in message
    assert "0x06040041" in message


def test_a_drive_with_another_identity_is_refused_naming_node_and_0x1018(buses):
    cfg = load_config(overrides={"sensor.enabled": False})
    sim_bus, bus = buses
    vendor_sim = load_config(overrides={"sensor.enabled": False, **VENDOR})
    with (
        Simulator(vendor_sim, sim_bus),
        pytest.raises(NodeSetupError, match=r"node 1: identity 0x1018 reads vendor 0x00000A5E"),
    ):
        configure_nodes(bus, _setup_plan(cfg))


def test_a_mapping_over_8_bytes_is_refused_before_anything_is_written(buses):
    cfg = load_config(
        overrides={"sensor.enabled": False, "actuators.tpdo_objects": ["0x6041", "0x6064", "0x606C"]}
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        with pytest.raises(NodeSetupError, match=r"node 1 TPDO1: mapping .* takes 10 bytes"):
            configure_nodes(bus, _setup_plan(cfg))
        assert sim.nodes[1].sdo[0x1A00][0].raw == 2  # untouched


# -- a second vendor's drive, through configuration alone --------------------------------------


def test_vendor_drive_runs_the_cyclic_exchange_against_the_in_process_simulator(buses):
    from drivers.cyclic_exchange import CyclicExchange
    from drivers.pdo_codec import PositionScale

    cfg = load_config(overrides={"sensor.enabled": False, **VENDOR})
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        report = configure_nodes(bus, _setup_plan(cfg))
        assert [i.vendor_id for i in report.identities] == [0x00000A5E] * 3
        # no 0x2011 in its EDS: it keeps its own SYNC watchdog, and the run's summary says so
        assert [n for n in report.notes if "0x2011" in n] == [
            f"node {i}: its EDS has no SYNC watchdog object 0x2011; it stops on a silent SYNC after its own "
            "time, not actuators.sync_watchdog_s"
            for i in cfg.actuators.node_ids
        ]
        assert {d.sync_timeout_s for d in sim.drives} == {cfg.sim.drive.sync_timeout_s}
        codec = report.drive_codecs[0]
        assert [o.index for o in codec.rpdo.objects] == [0x607A, 0x6040]
        assert [o.index for o in codec.tpdo.objects] == [0x6064, 0x6041, 0x6061]
        scale = PositionScale(cfg.actuators.counts_per_m)
        ex = CyclicExchange(
            bus,
            tuple(cfg.actuators.node_ids),
            scale,
            None,
            cfg.loop.controller_node_id,
            heartbeat_every=1,
            drive_codecs=report.drive_codecs,
            # the answer window (collect waits it out) as the loop's, so that the SYNCs come
            # about at the drives' configured period: a 5 ms window made the CSP drives see
            # SYNC at half their interpolation rate, and they fell behind their targets
            answer_window_s=cfg.loop.collect_fraction * cfg.period_s,
        )
        start = [d.position for d in sim.drives]
        ex.send(None)
        fb = ex.collect(time.monotonic() + 5.0)
        assert all(d.fresh for d in fb.drives)
        assert [d.position for d in fb.drives] == pytest.approx(start, abs=1e-7)
        # enable (shutdown, switch on, enable operation) holding the measured position, then step 5 mm
        targets = tuple(start)
        for cw in (0x06, 0x07, 0x0F, 0x0F):
            ex.send(CycleOutputs(controlwords=(cw,) * 3, targets=targets))
            fb = ex.collect(time.monotonic() + 5.0)
        assert {decode_statusword(d.statusword) for d in fb.drives} == {PowerState.OPERATION_ENABLED}
        goal = tuple(x + 0.005 for x in start)
        settled = 0  # cycles in a row at the goal: a drive passing through it has not arrived
        for _ in range(400):  # 5 mm in 1 mm steps, then hold
            step = tuple(min(g, x + 0.001) for g, x in zip(goal, targets, strict=True))
            targets = step
            ex.send(CycleOutputs(controlwords=(0x0F,) * 3, targets=targets))
            fb = ex.collect(time.monotonic() + 5.0)
            at_goal = all(abs(d.position - g) < 2e-6 for d, g in zip(fb.drives, goal, strict=True))
            settled = settled + 1 if at_goal else 0
            if settled == 10:
                break
        assert [d.position for d in fb.drives] == pytest.approx(goal, abs=2e-6)
        assert [d.position for d in sim.drives] == pytest.approx(goal, abs=2e-6)
        assert ex.counters.rejected_frames == 0


def test_vendor_drive_runs_the_path_task_in_simulated_time():
    from controller.assembly import build_law
    from controller.shell.loop import CycleLoop, SimulatedTime
    from controller.shell.run_summary import RunRecorder
    from sim_backend.loopback import LoopbackExchange

    cfg = load_config(overrides={"task.path.laps": 0.5, **VENDOR})
    clock = SimulatedTime()
    law = build_law(cfg)
    exchange = LoopbackExchange(cfg, clock.clock)
    assert [o.index for o in exchange.codecs[0].tpdo.objects] == [0x6064, 0x6041, 0x6061]
    recorder = RunRecorder()
    loop = CycleLoop(
        law, exchange, cfg.period_s, cfg.loop.collect_fraction, clock, clock.clock, observers=(recorder,)
    )
    final, _ = loop.run(law.initial_state(), 30.0)
    assert final.mode == Mode.DONE, final.fault_reason
    err = np.array(recorder.tracking_error_m)
    assert err.size > 800 and err.max() < 80e-6


def test_set_up_writes_the_drives_following_error_window_and_time_and_reads_them_back(buses):
    cfg = load_config(
        overrides={"actuators.following_error_window_m": 0.004, "actuators.following_error_time_s": 0.02}
    )
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        configure_nodes(bus, _setup_plan(cfg))
        for node_id, d in zip(cfg.actuators.node_ids, sim.drives, strict=True):
            assert sim.nodes[node_id].sdo[0x6065].raw == 40_000  # counts: 4 mm at 0.1 um per count
            assert sim.nodes[node_id].sdo[0x6066].raw == 20  # ms
            assert d.following_error_window == pytest.approx(
                0.004
            ) and d.following_error_time_s == pytest.approx(0.02)


def test_set_up_writes_the_drives_extrapolation_periods_and_reads_them_back(buses):
    cfg = load_config()  # actuators.extrapolation_s = 0.025: 10 periods at 400 Hz
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        assert all(d.extrapolation_periods == 1 for d in sim.drives)  # the drive's own at power-on
        configure_nodes(bus, _setup_plan(cfg))
        for node_id, d in zip(cfg.actuators.node_ids, sim.drives, strict=True):
            assert sim.nodes[node_id].sdo[0x2010].raw == 10
            assert d.extrapolation_periods == 10


def test_set_up_writes_the_drives_sync_watchdog_and_reads_it_back(buses):
    cfg = load_config()  # actuators.sync_watchdog_s = 0.25
    sim_bus, bus = buses
    with Simulator(cfg, sim_bus) as sim:
        assert all(d.sync_timeout_s == cfg.sim.drive.sync_timeout_s for d in sim.drives)  # power-on
        configure_nodes(bus, _setup_plan(cfg))
        for node_id, d in zip(cfg.actuators.node_ids, sim.drives, strict=True):
            assert sim.nodes[node_id].sdo[0x2011].raw == 250
            assert d.sync_timeout_s == 0.25


def test_a_drive_without_0x2011_keeps_its_own_sync_watchdog():
    from sim_backend.loopback import LoopbackExchange

    vendor = LoopbackExchange(load_config(overrides=VENDOR), lambda: 0.0)
    assert {d.sync_timeout_s for d in vendor.plant.drives} == {load_config().sim.drive.sync_timeout_s}
    ours = LoopbackExchange(load_config(), lambda: 0.0)
    assert {d.sync_timeout_s for d in ours.plant.drives} == {0.25}


def test_extrapolation_a_drive_cannot_take_stops_the_start_naming_node_object_and_key(buses):
    sim_bus, bus = buses
    too_long = load_config(overrides={"actuators.extrapolation_s": 0.07})  # 28 periods: the drive allows 25
    with Simulator(too_long, sim_bus), pytest.raises(NodeSetupError) as err:
        configure_nodes(bus, _setup_plan(too_long))
    assert "node 1: writing 0x2010sub0 = 0x1C refused" in str(err.value)
    assert "lower actuators.extrapolation_s" in str(err.value)


def test_a_drive_without_0x2010_is_refused_unless_told_it_runs_on_one_period():
    from sim_backend.loopback import LoopbackExchange

    told = {k: v for k, v in VENDOR.items() if k != "actuators.extrapolation_s"}
    with pytest.raises(NodeSetupError, match=r"node 1: its EDS has no extrapolation periods object 0x2010"):
        LoopbackExchange(load_config(overrides=told), lambda: 0.0)
    LoopbackExchange(load_config(overrides=VENDOR), lambda: 0.0)  # one period: what it is taken to do
    # the in-process simulator refuses what the drive over the bus refuses, with the same hint
    with pytest.raises(NodeSetupError, match=r"0x2010sub0 = 0x1C refused.*lower actuators.extrapolation_s"):
        LoopbackExchange(load_config(overrides={"actuators.extrapolation_s": 0.07}), lambda: 0.0)


def test_a_drive_beyond_its_following_error_window_for_its_time_faults_with_emcy_8611():
    from controller.core.cia402 import CW_ENABLE_OPERATION, CW_SHUTDOWN, CW_SWITCH_ON, PowerState
    from sim_backend.drive import EMCY_FOLLOWING_ERROR
    from sim_backend.plant import RobotPlant

    cfg = load_config()
    drive = RobotPlant(cfg).drives[0]
    drive.following_error_window, drive.following_error_time_s = 0.005, 0.01
    drive.mode_of_operation, drive.interpolation_period_s = 8, cfg.period_s
    t = 0.0
    drive.advance(t)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        drive.on_controlword(cw)
    drive.blocked = True  # the carriage is stuck: the reference runs away from it
    start = drive.position
    while drive.power == PowerState.OPERATION_ENABLED and t < 1.0:
        drive.received_target = drive.latched_target + 0.0005  # 0.2 m/s at 400 Hz
        drive.target_received = True
        t += cfg.period_s
        drive.on_sync(t)
        drive.advance(t)
    assert drive.power == PowerState.FAULT and drive.pending_emcy[-1] == EMCY_FOLLOWING_ERROR
    assert drive.position == start
    # the window (5 mm at 0.5 mm a cycle: 10 cycles) plus the time (10 ms: 4 cycles), within a cycle or two
    assert 0.025 <= t <= 0.045, t
