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
    """The homing objects in the drive's units (counts), and how to judge the end, from configuration."""

    method: int
    home_offset_counts: int
    switch_speed_counts_s: int
    zero_speed_counts_s: int
    acceleration_counts_s2: int
    timeout_s: float
    # "attained": statusword bit 12 (CiA 402); "position": bit 10 and the position at the home offset
    # within position_window_counts on two reads in a row, for a drive that never sets bit 12
    done: str = "attained"
    position_window_counts: int = 1000
    skip_if_homed: bool = False  # a drive that reports itself homed (mode 6, bit 12) is not homed again
    enable_timeout_s: float = 2.0  # each power-state transition before the start may take this long


class HomingError(DeviceError):
    """Homing ended in an error or did not end; the message names the node and the statusword."""


# (index, subindex, value) writes, and reads, are given by the caller: node_setup's checked SDO helpers
Write = Callable[[int, int, int], None]
Read = Callable[[int, int], int]


def reports_homed(read: Read) -> bool:
    """Whether a drive in mode 6 and not homing says it is homed (bit 12), as canopen's ``is_homed``."""
    return bool(read(0x6041, 0) & SW_HOMING_ATTAINED)


def _enable(
    node_id: int,
    plan: HomingPlan,
    write: Write,
    read: Read,
    clock: Callable[[], float],
    sleep: Callable[[float], None],
) -> None:
    """Shutdown, switch on, enable operation, each awaited: a drive may take its time (brake release)."""
    for cw, wanted in (
        (CW_SHUTDOWN, PowerState.READY_TO_SWITCH_ON),
        (CW_SWITCH_ON, PowerState.SWITCHED_ON),
        (CW_ENABLE_OPERATION, PowerState.OPERATION_ENABLED),
    ):
        write(0x6040, 0, cw)
        deadline = clock() + plan.enable_timeout_s
        while decode_statusword(sw := read(0x6041, 0)) != wanted:
            if clock() > deadline:
                raise HomingError(
                    f"node {node_id}: statusword 0x6041 = 0x{sw:04X} ({decode_statusword(sw).name}) "
                    f"{plan.enable_timeout_s} s after controlword 0x{cw:04X}, expected {wanted.name} "
                    f"before homing (loop.enable_timeout_s)"
                )
            sleep(HOMING_POLL_S)


def home_drive(
    node_id: int,
    plan: HomingPlan,
    write: Write,
    read: Read,
    clock: Callable[[], float] = time.monotonic,
    poll_s: float = HOMING_POLL_S,
    sleep: Callable[[float], None] = time.sleep,
) -> bool:
    """Home the drive; False when it reported itself homed and ``plan.skip_if_homed`` (canopen #248)."""
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
    if plan.skip_if_homed and reports_homed(read):
        return False
    at_home = 0  # reads in a row that found the drive at rest at its home offset (done = "position")
    try:  # from the enabling on: however it ends (a stop requested while a brake releases), disabled
        _enable(node_id, plan, write, read, clock, sleep)
        write(0x6040, 0, CW_ENABLE_OPERATION | CW_HOMING_START)
        deadline = clock() + plan.timeout_s
        while True:
            sw = read(0x6041, 0)
            if sw & SW_HOMING_ERROR:
                raise HomingError(
                    f"node {node_id}: homing method {plan.method} failed: statusword 0x6041 = "
                    f"0x{sw:04X} (bit 13 homing error)"
                )
            if plan.done == "attained" and sw & SW_HOMING_ATTAINED and sw & SW_TARGET_REACHED:
                return True
            if plan.done == "position":
                near = abs(read(0x6064, 0) - plan.home_offset_counts) <= plan.position_window_counts
                at_home = at_home + 1 if near and sw & SW_TARGET_REACHED else 0
                if at_home >= 2:
                    return True
            if clock() > deadline:
                raise HomingError(
                    f"node {node_id}: homing method {plan.method} not "
                    + (
                        "attained"
                        if plan.done == "attained"
                        else f"at its home offset {plan.home_offset_counts} counts at rest"
                    )
                    + f" within {plan.timeout_s} s (actuators.homing_timeout_s): statusword 0x6041 = "
                    f"0x{sw:04X}"
                    + (
                        " (bit 10 set, bit 12 never: a drive that does not signal it, "
                        'actuators.homing_done = "position")'
                        if plan.done == "attained" and sw & SW_TARGET_REACHED
                        else ""
                    )
                )
            sleep(poll_s)  # nothing signals the end but the statusword
    finally:
        write(0x6040, 0, CW_DISABLE_VOLTAGE)  # stopped and switched off, attained or not
