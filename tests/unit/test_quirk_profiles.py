"""Drives as they really are, in simulated time: each quirk profile whose habit lives in the simulated
drive runs the path task to DONE through configuration alone, and without that configuration the
start fails naming the drive and what it does; two habits that strike mid-run (a fault that needs
the reset bit held, a bus-off) end in FAULT, and the operator's reset brings the task to DONE.

The in-process loopback runs the same device code as the simulator process and does what node
set-up does before the first cycle (a fault found at start reset, homing) with the same procedures
(drivers/fault_reset.py, drivers/homing.py); the set-up's own quirks (boot, SDO, mapping,
supervision) are run over a bus in tests/protocol/test_node_quirks.py.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from quirk_profiles import DEVICE_PROFILES, Profile

from controller.config import Config, load_config
from controller.core.controller_state import Mode
from controller.core.cycle_data import Command, Event
from controller.errors import CheopeError
from controller.shell.simulated_rig import SimulatedRig

SHORT = {"task.path.laps": 0.25, "loop.hold_before_task_s": 0.05}
DOCS = Path(__file__).resolve().parents[2] / "docs" / "reference" / "canopen.md"


class Operator:
    """Records events and modes; resets the controller ``after_s`` after each FAULT, up to ``resets`` times."""

    def __init__(self, after_s: float = 0.0, resets: int = 0) -> None:
        self.events: list[Event] = []
        self.modes: list[Mode] = []
        self.after_s, self.resets = after_s, resets
        self.fault_at_s: float | None = None
        self.pending: tuple[str, float] | None = None

    def on_cycle(self, cycle, t, inputs, state, outputs, events, timing):
        self.events.extend(events)
        self.modes.append(state.mode)
        if state.mode == Mode.FAULT and self.fault_at_s is None:
            self.fault_at_s = t
        if self.fault_at_s is not None and self.resets and t >= self.fault_at_s + self.after_s:
            self.pending, self.resets, self.fault_at_s = (Command.RESET.value, 0.0), self.resets - 1, None

    def command(self) -> tuple[str, float] | None:
        pending, self.pending = self.pending, None
        return pending

    def said(self, kind: str) -> list[str]:
        return [e.message for e in self.events if e.kind == kind]


def run(cfg: Config, max_s: float = 60.0, operator: Operator | None = None):
    rig = SimulatedRig(cfg)  # the devices' set-up: fault reset, homing (raises naming the drive)
    operator = operator or Operator()
    loop = rig.loop((operator,), commands=operator.command)
    final, _ = loop.run(rig.law.initial_state(), max_s, exit_on_fault=operator.resets == 0)
    return final, operator, rig.exchange


def profile_config(p: Profile, handled: bool, extra: dict | None = None) -> Config:
    return load_config(
        overrides={
            **SHORT,
            **p.base,
            **p.sim,
            "sim.drive.quirks": list(p.quirks),
            **(p.handling if handled else {}),
            **(extra or {}),
        }
    )


@pytest.mark.parametrize("profile", DEVICE_PROFILES, ids=lambda p: p.name)
def test_a_quirky_drive_runs_the_path_to_done_through_configuration_alone(profile: Profile):
    final, operator, _ = run(profile_config(profile, handled=True))
    assert final.mode == Mode.DONE, final.fault_reason
    if profile.name == "warning_emcy_on_enable":  # said once per drive, and the run went on
        warnings = operator.said("emcy_warning")
        assert len(warnings) == 3 and all("0xFF01" in w for w in warnings), warnings


@pytest.mark.parametrize("profile", DEVICE_PROFILES, ids=lambda p: p.name)
def test_without_its_configuration_the_start_fails_naming_the_drive_and_the_behaviour(profile: Profile):
    try:
        final, _, _ = run(profile_config(profile, handled=False))
    except CheopeError as err:  # set-up refused it (the CLI: one line, exit 2)
        assert re.search(profile.unhandled, str(err)), str(err)
        return
    assert final.mode == Mode.FAULT  # refused before the task: nothing moved
    assert re.search(profile.unhandled, final.fault_reason), final.fault_reason


def test_each_profile_is_in_the_reference_table():
    text = DOCS.read_text()
    for p in DEVICE_PROFILES:
        assert f"`{p.name}`" in text, p.name


def test_a_drive_that_faults_mid_run_and_needs_the_bit_held_is_reset_by_the_operator_and_finishes():
    """Mid-run: drive 2 faults (EMCY 0x5000) 1 s into the task; the supervision faults the run (quick
    stop); the operator's reset holds bit 7 as configured and the task runs again to DONE."""
    cfg = load_config(
        overrides={
            **SHORT,
            "sim.drive.quirks": ["fault_reset_hold:2"],
            "sim.faults": ["drive_fault:2@1.0+0.01"],
            "actuators.fault_reset_hold_s": 0.1,
            "actuators.fault_reset_wait_s": 0.1,
            "actuators.fault_reset_attempts": 3,
        }
    )
    final, operator, _exchange = run(cfg, operator=Operator(after_s=0.3, resets=1))
    assert final.mode == Mode.DONE, final.fault_reason
    faults = [m for m in operator.said("mode") if "-> FAULT" in m]
    assert len(faults) == 1 and "drive 2 reports FAULT" in faults[0] and "error code 0x5000" in faults[0]
    assert any("FAULT -> ENABLING: reset" in m for m in operator.said("mode"))
    # without the hold the same reset never takes: bounded attempts, then FAULT naming the code
    edge_only = load_config(overrides={**cfg_overrides(cfg), "actuators.fault_reset_hold_s": 0.0})
    final, _, _ = run(edge_only, operator=Operator(after_s=0.3, resets=1))
    assert final.mode == Mode.FAULT
    assert "drive 2 stays in FAULT after 3 fault reset(s)" in final.fault_reason
    assert "error code 0x5000" in final.fault_reason


def cfg_overrides(cfg: Config) -> dict:
    return {
        **SHORT,
        "sim.drive.quirks": list(cfg.sim.drive.quirks),
        "sim.faults": list(cfg.sim.faults),
        "actuators.fault_reset_wait_s": cfg.actuators.fault_reset_wait_s,
        "actuators.fault_reset_attempts": cfg.actuators.fault_reset_attempts,
    }


def test_a_bus_off_mid_run_faults_says_when_the_bus_is_back_and_waits_for_the_operator():
    """Mid-run: the bus goes error passive, then bus-off for 0.5 s, then the interface restarts. The
    run faults on the bus-off; when the drives are heard again one event re-checks them (quick-stopped
    by their own SYNC watchdog); nothing moves until the operator resets; then the task runs to DONE."""
    cfg = load_config(
        overrides={
            **SHORT,
            "sim.drive.quirks": ["bus_off"],
            "sim.quirk.bus_off_after_s": 1.0,
            "loop.stay_in_fault": True,
        }
    )
    final, operator, _exchange = run(cfg, operator=Operator(after_s=1.5, resets=1))
    assert final.mode == Mode.DONE, final.fault_reason
    modes = operator.said("mode")
    assert any("-> FAULT: CAN bus-off" in m for m in modes), modes
    back = operator.said("bus_restored")
    assert len(back) == 1 and "drives re-checked: 1 QUICK_STOP_ACTIVE" in back[0], back
    assert "the task resumes only on the operator's reset" in back[0]
    assert operator.said("error_frames"), "the error passive and restart frames are warned about"
    # the fault held until the reset: no mode change between the bus-off and the operator's reset
    after_fault = modes[next(i for i, m in enumerate(modes) if "-> FAULT" in m) + 1]
    assert "FAULT -> ENABLING: reset" in after_fault


def test_a_fixed_mapping_without_the_position_cannot_be_run_and_says_so():
    cfg = load_config(
        overrides={
            **SHORT,
            "sim.drive.quirks": ["fixed_mapping:3"],
            "sim.quirk.fixed_tpdo_objects": ["0x6041", "0x6061"],
            "node": [{"node_id": 3, "pdo_mapping": "read"}],
        }
    )
    with pytest.raises(CheopeError, match=r"node 3.*0x6064.*") as err:
        run(cfg)
    note = str(err.value)
    assert "position" in note.lower(), note
