"""CiA 402 homing (mode 6) of a drive over SDO, before the cyclic loop starts.

Linear motors with incremental encoders do not know where they are at power-up; homing finds a
known place and makes the drive report the home offset there. The sequence (CiA 402-2 §
homing mode): homing objects (0x607C home offset, 0x6098 method, 0x6099 speeds, 0x609A
acceleration), mode 6, the power state machine to OPERATION ENABLED by controlword, a rising
edge of controlword bit 4, then the statusword until bit 12 "homing attained" with bit 10
"target reached" or bit 13 "homing error"; then the drive is switched off again (disable
voltage: SWITCH ON DISABLED, where the control law's enabling starts) and goes back to CSP.

Runs while the nodes are PRE-OPERATIONAL with only SDO on the bus; polling the statusword is
the only way to see the end without PDOs. The drive's own watchdogs do not run yet: no SYNC
and no controller heartbeat have been seen.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

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
    decode_statusword,
)
from controller.errors import DeviceError

HOMING_POLL_S = 0.01  # between statusword reads while the drive homes


@dataclass(frozen=True)
class HomingPlan:
    """The homing objects in the drive's units (counts), from configuration."""

    method: int
    home_offset_counts: int
    switch_speed_counts_s: int
    zero_speed_counts_s: int
    acceleration_counts_s2: int
    timeout_s: float


class HomingError(DeviceError):
    """Homing ended in an error or did not end; the message names the node and the statusword."""


# (index, subindex, value) writes, and reads, are given by the caller: node_setup's checked SDO helpers
Write = Callable[[int, int, int], None]
Read = Callable[[int, int], int]


def home_drive(
    node_id: int,
    plan: HomingPlan,
    write: Write,
    read: Read,
    clock: Callable[[], float] = time.monotonic,
    poll_s: float = HOMING_POLL_S,
) -> None:
    write(0x607C, 0, plan.home_offset_counts)
    write(0x6098, 0, plan.method)
    write(0x6099, 1, plan.switch_speed_counts_s)
    write(0x6099, 2, plan.zero_speed_counts_s)
    write(0x609A, 0, plan.acceleration_counts_s2)
    write(0x6060, 0, MODE_HOMING)
    mode = read(0x6061, 0)
    if mode != MODE_HOMING:
        raise HomingError(
            f"node {node_id}: mode of operation display 0x6061 reads {mode}, expected 6 (homing)"
        )
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        write(0x6040, 0, cw)
    sw = read(0x6041, 0)
    if decode_statusword(sw) != PowerState.OPERATION_ENABLED:
        raise HomingError(
            f"node {node_id}: statusword 0x6041 = 0x{sw:04X} ({decode_statusword(sw).name}) "
            f"after enable operation, expected OPERATION_ENABLED before homing"
        )
    write(0x6040, 0, CW_ENABLE_OPERATION | CW_HOMING_START)
    deadline = clock() + plan.timeout_s
    try:
        while True:
            sw = read(0x6041, 0)
            if sw & SW_HOMING_ERROR:
                raise HomingError(
                    f"node {node_id}: homing method {plan.method} failed: statusword 0x6041 = "
                    f"0x{sw:04X} (bit 13 homing error)"
                )
            if sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED:
                return
            if clock() > deadline:
                raise HomingError(
                    f"node {node_id}: homing method {plan.method} not attained within "
                    f"{plan.timeout_s} s (actuators.homing_timeout_s): statusword 0x6041 = 0x{sw:04X}"
                )
            time.sleep(poll_s)  # nothing signals the end but the statusword
    finally:
        write(0x6040, 0, CW_DISABLE_VOLTAGE)  # stopped and switched off, attained or not
