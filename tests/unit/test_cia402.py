"""CiA 402 power state machine, master and device side together."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    PowerState,
    controlword_towards,
    decode_statusword,
    device_transition,
    statusword_bits,
)

S = PowerState


@pytest.mark.parametrize("state", [s for s in S if s != S.UNKNOWN])
def test_statusword_encoding_round_trips(state):
    assert decode_statusword(statusword_bits(state)) == state
    # extra bits outside the state coding do not change the state
    assert decode_statusword(statusword_bits(state) | 0x1610) == state


def test_canopen_package_agrees_on_the_state_coding():
    from canopen.profiles.p402 import State402

    names = {
        S.NOT_READY_TO_SWITCH_ON: "NOT READY TO SWITCH ON",
        S.SWITCH_ON_DISABLED: "SWITCH ON DISABLED",
        S.READY_TO_SWITCH_ON: "READY TO SWITCH ON",
        S.SWITCHED_ON: "SWITCHED ON",
        S.OPERATION_ENABLED: "OPERATION ENABLED",
        S.QUICK_STOP_ACTIVE: "QUICK STOP ACTIVE",
        S.FAULT_REACTION_ACTIVE: "FAULT REACTION ACTIVE",
        S.FAULT: "FAULT",
    }
    for state, name in names.items():
        mask, bits = State402.SW_MASK[name]
        assert statusword_bits(state) & mask == bits


@pytest.mark.parametrize(
    "start,cw,end",
    [
        (S.SWITCH_ON_DISABLED, CW_SHUTDOWN, S.READY_TO_SWITCH_ON),  # 2
        (S.READY_TO_SWITCH_ON, CW_SWITCH_ON, S.SWITCHED_ON),  # 3
        (S.SWITCHED_ON, CW_ENABLE_OPERATION, S.OPERATION_ENABLED),  # 4
        (S.OPERATION_ENABLED, CW_SWITCH_ON, S.SWITCHED_ON),  # 5
        (S.SWITCHED_ON, CW_SHUTDOWN, S.READY_TO_SWITCH_ON),  # 6
        (S.READY_TO_SWITCH_ON, CW_DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),  # 7
        (S.OPERATION_ENABLED, CW_SHUTDOWN, S.READY_TO_SWITCH_ON),  # 8
        (S.OPERATION_ENABLED, CW_DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),  # 9
        (S.SWITCHED_ON, CW_DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),  # 10
        (S.OPERATION_ENABLED, CW_QUICK_STOP, S.QUICK_STOP_ACTIVE),  # 11
        (S.QUICK_STOP_ACTIVE, CW_DISABLE_VOLTAGE, S.SWITCH_ON_DISABLED),  # 12
        (S.QUICK_STOP_ACTIVE, CW_ENABLE_OPERATION, S.OPERATION_ENABLED),  # 16
        (S.SWITCH_ON_DISABLED, CW_ENABLE_OPERATION, S.SWITCH_ON_DISABLED),  # no shortcut
    ],
)
def test_device_transitions(start, cw, end):
    assert device_transition(start, cw, 0) == end


def test_fault_reset_needs_a_rising_edge():
    assert device_transition(S.FAULT, CW_FAULT_RESET, 0) == S.SWITCH_ON_DISABLED
    assert device_transition(S.FAULT, CW_FAULT_RESET, CW_FAULT_RESET) == S.FAULT


@given(
    st.sampled_from(
        [
            S.SWITCH_ON_DISABLED,
            S.READY_TO_SWITCH_ON,
            S.SWITCHED_ON,
            S.OPERATION_ENABLED,
            S.QUICK_STOP_ACTIVE,
            S.FAULT,
        ]
    ),
    st.sampled_from([S.OPERATION_ENABLED, S.READY_TO_SWITCH_ON, S.SWITCH_ON_DISABLED]),
)
def test_master_reaches_the_wanted_state_from_anywhere(start, wanted):
    state, cw = start, 0
    for _ in range(8):
        if state == wanted:
            break
        new_cw = controlword_towards(state, wanted, cw)
        state, cw = device_transition(state, new_cw, cw), new_cw
    assert state == wanted


def test_quick_stop_from_operation_enabled():
    cw = controlword_towards(S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE)
    assert device_transition(S.OPERATION_ENABLED, cw, CW_ENABLE_OPERATION) == S.QUICK_STOP_ACTIVE


def test_the_decoding_table_agrees_with_the_state_coding_for_every_statusword():
    """decode_statusword looks the state up by the coding's bits: the same as the first row of
    CiA 402-2's table whose mask matches, for every 16-bit statusword."""
    from controller.core.cia402 import _SW_CODING

    for sw in range(1 << 16):
        expected = next(
            (state for state, mask, value in _SW_CODING if sw & mask == value), PowerState.UNKNOWN
        )
        assert decode_statusword(sw) is expected, hex(sw)
