"""The simulated drive's quirks (sim_backend/quirks.py): each behaves as the behaviour it models,
device alone, time as an argument."""

from __future__ import annotations

import pytest

from controller.config import ConfigError, load_config
from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    MODE_HOMING,
    SW_HOMING_ATTAINED,
    SW_TARGET_REACHED,
    SW_WARNING,
    PowerState,
)
from controller.sim_config.quirk_specs import SCOPE, Quirk
from sim_backend.drive import (
    EMCY_DC_LINK_UNDERVOLTAGE,
    EMCY_NO_ERROR,
    DriveQuirks,
    SimulatedDrive,
    error_register,
)
from sim_backend.plant import configured_drive_quirks, drive_params_from_config
from sim_backend.quirks import BEHAVIOUR, TRACKERS, quirks_of

PARAMS = drive_params_from_config(load_config())


def drive(**quirks: object) -> SimulatedDrive:
    d = SimulatedDrive(PARAMS, position=0.6, quirks=DriveQuirks(**quirks))  # type: ignore[arg-type]
    d.advance(0.0)  # power-on: its clock starts
    return d


def test_every_quirk_is_documented_with_its_scope_and_tracker():
    for q in Quirk:
        assert BEHAVIOUR[q] and TRACKERS[q] and SCOPE[q]


def test_boots_in_fault_until_its_power_stage_is_ready_and_refuses_a_reset_before():
    d = drive(boot_fault_code=EMCY_DC_LINK_UNDERVOLTAGE, power_stage_ready_s=3.0)
    assert d.power == PowerState.FAULT and d.error_code == 0x3220
    assert d.pending_emcy == [0x3220]  # said at boot
    d.pending_emcy.clear()
    for t, expected in (
        (1.0, PowerState.FAULT),
        (2.9, PowerState.FAULT),
        (3.1, PowerState.SWITCH_ON_DISABLED),
    ):
        d.advance(t)
        d.on_controlword(CW_DISABLE_VOLTAGE)
        d.on_controlword(CW_FAULT_RESET)  # a rising edge
        assert d.power == expected, t
    assert d.error_code == EMCY_NO_ERROR and d.pending_emcy == [EMCY_NO_ERROR]


def test_a_reboot_brings_the_boot_fault_back():
    d = drive(boot_fault_code=EMCY_DC_LINK_UNDERVOLTAGE, power_stage_ready_s=0.5)
    d.advance(1.0)
    d.on_controlword(CW_FAULT_RESET)
    assert d.power == PowerState.SWITCH_ON_DISABLED
    d.reboot()
    assert d.power == PowerState.FAULT and d.error_code == 0x3220


def test_a_fault_reset_needs_the_bit_held_for_the_hold_time():
    d = drive(fault_reset_hold_s=0.05)
    d.force_fault(0x5000)
    d.on_controlword(CW_FAULT_RESET)  # the edge, released one 2.5 ms cycle later
    d.advance(0.0025)
    d.on_controlword(CW_DISABLE_VOLTAGE)
    d.advance(0.1)
    assert d.power == PowerState.FAULT  # an edge does nothing
    d.on_controlword(CW_FAULT_RESET)
    d.advance(0.14)
    assert d.power == PowerState.FAULT  # held 40 ms
    d.on_controlword(CW_FAULT_RESET)  # still high (no new edge)
    d.advance(0.151)
    assert d.power == PowerState.SWITCH_ON_DISABLED  # held 51 ms


def test_the_ideal_drive_resets_on_the_edge():
    d = drive()
    d.force_fault(0x5000)
    d.on_controlword(CW_FAULT_RESET)
    assert d.power == PowerState.SWITCH_ON_DISABLED


def test_slow_power_states_take_their_time_up_and_none_down():
    d = drive(transition_delay_s=0.3)
    d.on_controlword(CW_SHUTDOWN)
    assert d.power == PowerState.SWITCH_ON_DISABLED  # the statusword still says so
    d.advance(0.29)
    assert d.power == PowerState.SWITCH_ON_DISABLED
    d.on_controlword(CW_SHUTDOWN)  # the master repeats it: the transition under way goes on
    d.advance(0.31)
    assert d.power == PowerState.READY_TO_SWITCH_ON
    d.on_controlword(CW_SWITCH_ON)
    d.advance(0.62)
    d.on_controlword(CW_ENABLE_OPERATION)
    d.advance(0.9)
    assert d.power == PowerState.SWITCHED_ON
    d.advance(0.93)
    assert d.power == PowerState.OPERATION_ENABLED
    d.on_controlword(CW_DISABLE_VOLTAGE)
    assert d.power == PowerState.SWITCH_ON_DISABLED  # switching off is at once


def test_a_warning_emcy_at_each_enable_with_bit_7_and_the_manufacturer_register_bit():
    d = drive(warning_emcy_code=0xFF01)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        d.on_controlword(cw)
    assert d.power == PowerState.OPERATION_ENABLED
    assert d.pending_emcy == [0xFF01] and error_register(0xFF01) == 0x80
    assert d.statusword() & SW_WARNING
    d.on_controlword(CW_DISABLE_VOLTAGE)
    assert not d.statusword() & SW_WARNING


def _home(d: SimulatedDrive, method: int = 37) -> None:
    d.write_object(0x6098, 0, method)
    d.write_object(0x607C, 0, 6_000_000)
    assert d.write_object(0x6060, 0, MODE_HOMING)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION, CW_ENABLE_OPERATION | 0x10):
        d.on_controlword(cw)
    d.advance(0.1)


def test_homing_without_the_attained_bit_shows_target_reached_and_the_home_position():
    d = drive(homing_attained_bit=False)
    _home(d)
    sw = d.statusword()
    assert sw & SW_TARGET_REACHED and not sw & SW_HOMING_ATTAINED
    assert d.position_counts() == 6_000_000


def test_a_homed_incremental_drive_reports_it_in_mode_6_until_it_reboots():
    d = drive()
    assert not d.homed
    _home(d)
    d.on_controlword(CW_DISABLE_VOLTAGE)
    d.write_object(0x6060, 0, 8)
    d.write_object(0x6060, 0, MODE_HOMING)  # canopen's is_homed: mode 6, then the statusword
    assert d.statusword() & SW_HOMING_ATTAINED
    d.reboot()
    assert not d.statusword() & SW_HOMING_ATTAINED


def test_a_drive_without_homing_refuses_mode_6_and_keeps_its_position_across_a_reboot():
    d = drive(homing_mode=False)
    assert not d.write_object(0x6060, 0, MODE_HOMING)
    before = d.position_counts()
    d.reboot()
    assert d.position_counts() == before and d.homed


def test_quirks_are_given_per_node_and_refused_naming_a_wrong_entry():
    cfg = load_config(overrides={"sim.drive.quirks": ["boots_in_fault:2", "slow_power_states"]})
    q = configured_drive_quirks(cfg)
    assert [x.boot_fault_code for x in q] == [0, 0x3220, 0]
    assert all(x.transition_delay_s == 0.3 for x in q)
    assert Quirk.SLOW_SDO in quirks_of(("slow_sdo:16",), 16, is_drive=False)
    for bad, words in (
        (["boots_in_fault:16"], "node 16 is not one of the drives 1, 2, 3"),
        (["bus_off:1"], "takes no node id"),
        (["sloppy"], "unknown name 'sloppy'"),
        (["slow_sdo:9"], "node 9 is not one of the nodes 1, 2, 3, 16"),
    ):
        with pytest.raises(ConfigError, match=words):
            load_config(overrides={"sim.drive.quirks": bad})
