"""CiA 402 power state machine: statusword decoding, controlword commands, both sides.

Pure protocol code shared by the controller (master side: which controlword moves a drive
towards a wanted state) and the simulated drives (device side: how a controlword moves the
state). Bit layouts follow CiA 402-2 (the same masks as ``canopen.profiles.p402.State402``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class PowerState(IntEnum):
    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7
    UNKNOWN = 8


# Statusword masks and values (CiA 402-2, table "state coding").
_SW_CODING: tuple[tuple[PowerState, int, int], ...] = (
    (PowerState.NOT_READY_TO_SWITCH_ON, 0x4F, 0x00),
    (PowerState.SWITCH_ON_DISABLED, 0x4F, 0x40),
    (PowerState.READY_TO_SWITCH_ON, 0x6F, 0x21),
    (PowerState.SWITCHED_ON, 0x6F, 0x23),
    (PowerState.OPERATION_ENABLED, 0x6F, 0x27),
    (PowerState.QUICK_STOP_ACTIVE, 0x6F, 0x07),
    (PowerState.FAULT_REACTION_ACTIVE, 0x4F, 0x0F),
    (PowerState.FAULT, 0x4F, 0x08),
)
_SW_STATE_BITS = {state: value for state, _, value in _SW_CODING}

# Statusword bits outside the state coding.
SW_VOLTAGE_ENABLED = 1 << 4
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_FOLLOWING_COMMAND = 1 << 12  # CSP: the drive follows the target position
SW_FOLLOWING_ERROR = 1 << 13
SW_HOMING_ATTAINED = 1 << 12  # homing mode (6): the same bit as SW_FOLLOWING_COMMAND in CSP
SW_HOMING_ERROR = 1 << 13

# Controlword commands (CiA 402-2, table "device control commands").
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080

MODE_CYCLIC_SYNC_POSITION = 8
MODE_HOMING = 6
CW_HOMING_START = 1 << 4  # homing mode: a rising edge of bit 4 starts the homing method (0x6098)


def _decode_state_bits(statusword: int) -> PowerState:
    for state, mask, value in _SW_CODING:
        if statusword & mask == value:
            return state
    return PowerState.UNKNOWN


_SW_CODING_BITS = 0x7F  # every mask of the state coding lies within these bits
# decoded once for each value of those bits: three statuswords a cycle become three look-ups
_POWER_STATES = tuple(_decode_state_bits(bits) for bits in range(_SW_CODING_BITS + 1))


def decode_statusword(statusword: int) -> PowerState:
    return _POWER_STATES[statusword & _SW_CODING_BITS]


def statusword_bits(state: PowerState) -> int:
    """The state-coding bits of ``state`` (bit 5 'quick stop' is active low: set unless QSA)."""
    bits = _SW_STATE_BITS[state]
    if state in (PowerState.READY_TO_SWITCH_ON, PowerState.SWITCHED_ON, PowerState.OPERATION_ENABLED):
        bits |= 0x20
    return bits


# --- master side -------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultResetConfig:
    """How ENABLING resets one drive's fault (config ``actuators.fault_reset_*``): bit 7 high for
    ``hold_s`` (at least one cycle: the rising edge), low again, then up to ``wait_s`` for the
    statusword to leave FAULT before the next attempt; at most ``attempts`` (0: until
    ``enable_timeout_s``). The defaults are the edge of every other cycle."""

    hold_s: float = 0.0
    wait_s: float = 0.0
    attempts: int = 0


def controlword_towards(current: PowerState, wanted: PowerState, previous_controlword: int = 0) -> int:
    """The controlword that moves a drive one transition from ``current`` towards ``wanted``.

    ``wanted`` is OPERATION_ENABLED, READY_TO_SWITCH_ON, SWITCH_ON_DISABLED or QUICK_STOP_ACTIVE.
    A fault reset needs a rising edge of bit 7, so from FAULT the command alternates between
    0 and CW_FAULT_RESET depending on ``previous_controlword``.
    """
    if wanted == PowerState.QUICK_STOP_ACTIVE:
        if current in (PowerState.OPERATION_ENABLED, PowerState.QUICK_STOP_ACTIVE):
            return CW_QUICK_STOP
        return CW_DISABLE_VOLTAGE
    if current == PowerState.FAULT:
        return CW_DISABLE_VOLTAGE if previous_controlword & CW_FAULT_RESET else CW_FAULT_RESET
    if current in (PowerState.FAULT_REACTION_ACTIVE, PowerState.NOT_READY_TO_SWITCH_ON, PowerState.UNKNOWN):
        return CW_DISABLE_VOLTAGE
    if wanted == PowerState.SWITCH_ON_DISABLED:
        return CW_DISABLE_VOLTAGE
    if wanted == PowerState.READY_TO_SWITCH_ON:
        return CW_SHUTDOWN if current != PowerState.QUICK_STOP_ACTIVE else CW_DISABLE_VOLTAGE
    if wanted == PowerState.OPERATION_ENABLED:
        return {
            PowerState.SWITCH_ON_DISABLED: CW_SHUTDOWN,
            PowerState.READY_TO_SWITCH_ON: CW_SWITCH_ON,
            PowerState.SWITCHED_ON: CW_ENABLE_OPERATION,
            PowerState.OPERATION_ENABLED: CW_ENABLE_OPERATION,
            PowerState.QUICK_STOP_ACTIVE: CW_DISABLE_VOLTAGE,
        }[current]
    raise ValueError(f"unsupported wanted state {wanted.name}")


# --- device side -------------------------------------------------------------------------


def _is_shutdown(cw: int) -> bool:
    return cw & 0x87 == 0x06


def _is_switch_on(cw: int) -> bool:
    return cw & 0x8F == 0x07


def _is_enable_operation(cw: int) -> bool:
    return cw & 0x8F == 0x0F


def _is_disable_voltage(cw: int) -> bool:
    return cw & 0x82 == 0x00


def _is_quick_stop(cw: int) -> bool:
    return cw & 0x86 == 0x02


def device_transition(state: PowerState, controlword: int, previous_controlword: int) -> PowerState:  # noqa: C901  (CiA 402's device-side state table, one branch per transition)
    """Next device state after receiving ``controlword`` (CiA 402-2 transitions 2-16).

    FAULT_REACTION_ACTIVE -> FAULT and QUICK_STOP_ACTIVE's stop ramp are timed by the device
    and handled by its owner, not here. The quick stop option code is 6 (stop on the quick
    stop ramp and stay in QUICK_STOP_ACTIVE).
    """
    fault_reset_edge = bool(controlword & CW_FAULT_RESET) and not (previous_controlword & CW_FAULT_RESET)
    if state == PowerState.FAULT:
        return PowerState.SWITCH_ON_DISABLED if fault_reset_edge else state  # transition 15
    if state in (PowerState.FAULT_REACTION_ACTIVE, PowerState.NOT_READY_TO_SWITCH_ON, PowerState.UNKNOWN):
        return state
    if state == PowerState.SWITCH_ON_DISABLED:
        return PowerState.READY_TO_SWITCH_ON if _is_shutdown(controlword) else state  # 2
    if state == PowerState.READY_TO_SWITCH_ON:
        if _is_switch_on(controlword) or _is_enable_operation(controlword):
            return PowerState.SWITCHED_ON  # 3
        if _is_disable_voltage(controlword) or _is_quick_stop(controlword):
            return PowerState.SWITCH_ON_DISABLED  # 7
        return state
    if state == PowerState.SWITCHED_ON:
        if _is_enable_operation(controlword):
            return PowerState.OPERATION_ENABLED  # 4
        if _is_shutdown(controlword):
            return PowerState.READY_TO_SWITCH_ON  # 6
        if _is_disable_voltage(controlword) or _is_quick_stop(controlword):
            return PowerState.SWITCH_ON_DISABLED  # 10
        return state
    if state == PowerState.OPERATION_ENABLED:
        if _is_switch_on(controlword):
            return PowerState.SWITCHED_ON  # 5
        if _is_shutdown(controlword):
            return PowerState.READY_TO_SWITCH_ON  # 8
        if _is_disable_voltage(controlword):
            return PowerState.SWITCH_ON_DISABLED  # 9
        if _is_quick_stop(controlword):
            return PowerState.QUICK_STOP_ACTIVE  # 11
        return state
    if state == PowerState.QUICK_STOP_ACTIVE:
        if _is_enable_operation(controlword):
            return PowerState.OPERATION_ENABLED  # 16
        if _is_disable_voltage(controlword):
            return PowerState.SWITCH_ON_DISABLED  # 12
        return state
    return state
