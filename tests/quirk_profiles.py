"""The quirk profiles the tests run: the simulated drives' habit (sim.drive.quirks, sim_backend/quirks.py),
the configuration that handles it, and what the start says without that configuration.

docs/reference/canopen.md ("Drives as they really are") has the same table for users;
tests/unit/test_quirk_profiles.py checks that each profile there is one here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Profile:
    name: str
    quirks: tuple[str, ...]
    handling: dict[str, Any]  # configuration overrides that handle it
    unhandled: str  # a regex of the start's error (exit 2) without the handling; "" when it runs anyway
    sim: dict[str, Any] = field(default_factory=dict)  # the quirks' values, where not the defaults
    base: dict[str, Any] = field(default_factory=dict)  # overrides of both runs (homing for the homing ones)


HOMING_37 = {"actuators.homing_method": 37, "actuators.home_offsets_m": [0.71508, 0.56794, 0.42697]}

# The profiles whose habit lives in the simulated drive (sim_backend/drive.py), run in simulated time
# against the in-process loopback, which does set-up's fault reset and homing with the same procedures.
DEVICE_PROFILES = (
    Profile(
        "boots_in_fault",
        ("boots_in_fault",),
        {"loop.enable_timeout_s": 5.0, "actuators.fault_reset_wait_s": 0.5},
        r"node 1 stays in FAULT after \d+ fault reset\(s\) in \d+\.\d s: statusword 0x[0-9A-F]{4}, "
        r"error code 0x603F = 0x3220",
    ),
    Profile(
        "fault_reset_hold",
        ("boots_in_fault", "fault_reset_hold"),
        {"actuators.fault_reset_hold_s": 0.1, "actuators.fault_reset_wait_s": 0.2},
        r"node 1 stays in FAULT after \d+ fault reset\(s\).*error code 0x603F = 0x3220.*fault_reset_hold_s",
        sim={"sim.quirk.power_stage_ready_s": 0.5},
    ),
    Profile(
        "slow_power_states",
        ("slow_power_states",),
        {"loop.enable_timeout_s": 4.0},
        r"drives not enabled within 2\.0 s \(1: (SWITCH_ON_DISABLED|READY_TO_SWITCH_ON|SWITCHED_ON)",
        sim={"sim.quirk.transition_delay_s": 0.8},
    ),
    Profile(
        "homing_not_attained",
        ("homing_not_attained",),
        {"actuators.homing_done": "position"},
        r"node 1: homing method 37 not attained within 2\.0 s .*\(bit 10 set, bit 12 never",
        base={**HOMING_37, "actuators.homing_timeout_s": 2.0},
    ),
    Profile(
        "no_homing",
        ("no_homing:2",),
        {"node": [{"node_id": 2, "homing_method": 0}]},
        r"node 2: writing 0x6060sub0 = 0x6 refused",
        base=HOMING_37,
    ),
    Profile(
        "fixed_mapping",
        ("fixed_mapping",),
        {"actuators.pdo_mapping": "read"},
        r"node 1: writing 0x1600sub0 = 0x0 refused: .*0x06010002.*"
        r'\(a fixed PDO mapping: actuators.pdo_mapping = "read"\)',
    ),
    Profile(
        "warning_emcy_on_enable",
        ("warning_emcy_on_enable",),
        {"actuators.emcy_reactions": {"0xFF01": "warn"}},
        r"EMCY from node 1: error code 0xFF01, register 0x80",
    ),
)
