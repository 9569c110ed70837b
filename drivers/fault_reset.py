"""A drive's fault reset over SDO before the cyclic loop: edge, hold, wait and verify.

A drive found in FAULT at start (a power stage not yet up, a fault left from before) has its
error code read (0x603F), then bit 7 of the controlword goes low, high for ``hold_s`` (some
drives reset on the rising edge, some only after the bit was held: ros_canopen #138/#139), low
again, and the statusword has ``wait_s`` to leave FAULT. That reading is the verification
(canopen #261: a reset that is not verified is no reset); another attempt follows until the
configured attempts or time are used up, and a fault whose cause is still present is refused
naming the drive and its error code.

Reads, writes and time are given by the caller: drivers/node_setup.py's checked SDO helpers on
the wall clock; the in-process loopback's device calls in simulated time (sim_backend/loopback.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable

from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_FAULT_RESET,
    FaultResetConfig,
    PowerState,
    decode_statusword,
)
from controller.errors import DeviceError

POLL_S = 0.01  # between statusword reads while a reset is verified

Write = Callable[[int, int, int], None]
Read = Callable[[int, int], int]


class FaultResetError(DeviceError):
    """The drive stays in FAULT; the message names it, its statusword and error code."""


def reset_fault(
    node_id: int,
    cfg: FaultResetConfig,
    timeout_s: float,
    write: Write,
    read: Read,
    has_error_code: bool = True,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> str:
    """Reset the drive's fault; "" when it was not in FAULT, else one line saying what was done."""
    sw = read(0x6041, 0)
    if decode_statusword(sw) != PowerState.FAULT:
        return ""
    code = read(0x603F, 0) if has_error_code else 0
    first_code = code
    t0 = clock()
    attempts = 0
    write(0x6040, 0, CW_DISABLE_VOLTAGE)  # bit 7 low first: the reset is its rising edge
    while not cfg.attempts or attempts < cfg.attempts:
        attempts += 1
        write(0x6040, 0, CW_FAULT_RESET)
        sleep(cfg.hold_s)
        write(0x6040, 0, CW_DISABLE_VOLTAGE)
        wait_until = clock() + max(cfg.wait_s, POLL_S)
        while decode_statusword(sw := read(0x6041, 0)) == PowerState.FAULT and clock() < wait_until:
            sleep(POLL_S)
        if decode_statusword(sw) != PowerState.FAULT:
            left = read(0x603F, 0) if has_error_code else 0
            return (
                f"node {node_id}: was in FAULT at start"
                + (f" (0x603F = 0x{first_code:04X})" if has_error_code else "")
                + f"; reset after {attempts} attempt(s) in {clock() - t0:.1f} s"
                + (f"; 0x603F still reads 0x{left:04X}" if left else "")
            )
        if has_error_code:
            code = read(0x603F, 0)
        if clock() - t0 >= timeout_s:
            break
    raise FaultResetError(
        f"node {node_id} stays in FAULT after {attempts} fault reset(s) in {clock() - t0:.1f} s: "
        f"statusword 0x{sw:04X}"
        + (f", error code 0x603F = 0x{code:04X}" if has_error_code else "")
        + " (its cause is still present, or the drive needs bit 7 held longer: actuators.fault_reset_hold_s, "
        "fault_reset_wait_s, fault_reset_attempts, loop.enable_timeout_s)"
    )
