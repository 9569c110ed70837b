"""The controller's state as a keyframe: every value comes back as it was, and nothing else is built."""

from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass, field

import numpy as np
import pytest

from logs.keyframe import KeyframeError, decode_state, encode_state


class Phase(enum.Enum):
    A = 1
    B = 2


@dataclass(frozen=True)
class Inner:
    plan: np.ndarray
    peaks: tuple[float, ...]


@dataclass(frozen=True)
class State:
    phase: Phase
    values: tuple[float, ...]
    warned: frozenset[str]
    inner: Inner | None
    name: str = ""
    count: int = 0
    nothing: None = None
    derived: int = field(default=0, init=False)  # recomputed, not recorded


def _bits(xs):
    return [struct.pack("<d", x) for x in xs]


def test_every_value_comes_back_bit_for_bit():
    plan = np.linspace(0.0, 1.0, 12).reshape(4, 3) / 3.0
    s = State(
        Phase.B,
        (0.1 + 0.2, -0.0, math.inf, -math.inf, math.nan, 5e-324),
        frozenset({"b", "a"}),
        Inner(plan, (1 / 3,)),
        "x\u00e9",
        2**70,
    )
    back = decode_state(encode_state(s))
    assert back.phase is Phase.B and back.warned == s.warned and back.name == s.name and back.count == 2**70
    assert _bits(back.values) == _bits(s.values)  # -0.0 and nan included
    assert back.inner.plan.dtype == plan.dtype and back.inner.plan.tobytes() == plan.tobytes()
    assert back.inner.plan.shape == (4, 3) and back.inner.plan.flags.writeable
    assert encode_state(back) == encode_state(s)


def test_only_dataclasses_and_enums_of_loaded_modules_are_built():
    with pytest.raises(KeyframeError, match="not a class of a loaded module"):
        decode_state(b'{"d":"no_such_module:Thing","f":{}}')
    with pytest.raises(KeyframeError, match="not a dataclass"):
        decode_state(b'{"d":"builtins:dict","f":{}}')
    with pytest.raises(KeyframeError, match="not an enum"):
        decode_state(b'{"e":"builtins:dict","v":"A"}')
    with pytest.raises(KeyframeError, match="damaged keyframe"):
        decode_state(b"{not json")
    with pytest.raises(KeyframeError, match="cannot record a state value of type"):
        encode_state(State(Phase.A, (), frozenset(), None, name=object()))  # type: ignore[arg-type]


def test_a_keyframe_written_before_a_class_moved_still_reads():
    from controller.core.cia402 import PowerState

    old = b'{"e":"drivers.cia402:PowerState","v":"OPERATION_ENABLED"}'  # the module it had then
    assert decode_state(old) is PowerState.OPERATION_ENABLED


def test_a_keyframe_of_the_law_s_state_before_it_moved_to_controller_state_still_reads():
    from controller.assembly import build_law
    from controller.config import load_config
    from controller.core.controller_state import ControllerState, Mode

    state = build_law(load_config()).initial_state()
    new = encode_state(state)
    old = new.replace(b"controller.core.controller_state:", b"controller.core.control_law:")
    assert old != new and b"controller.core.controller_state:" not in old
    back = decode_state(old)
    assert isinstance(back, ControllerState) and back.mode is Mode.CONFIGURING
    assert encode_state(back) == new  # the same state (its NaNs compare unequal as values)


@pytest.mark.parametrize("samples", [0, 3, 5, 19])
def test_a_keyframe_of_the_contact_guard_s_windows_as_samples_reads_as_windows_per_axis(samples):
    """Before a58564c (encoding cheope-state-json-1) the guard kept its median windows as tuples of
    samples (x, y, z); it keeps a tuple per axis now. Three samples of three forces look alike in
    both shapes: the encoding, not the shape, says which one a keyframe holds."""
    import json

    from controller.assembly import build_law
    from controller.config import load_config
    from controller.core.contact_guard import ContactWatch
    from controller.core.records import replace

    witness = tuple((1.0 * k, 10.0 + k, -float(k)) for k in range(samples))
    sensor = tuple((0.5 * k, 0.25, 100.0 - k) for k in range(samples))

    def per_axis(window):
        return tuple(tuple(sample[axis] for sample in window) for axis in range(3))

    state = build_law(load_config()).initial_state()
    state = replace(
        state, contact=ContactWatch(witness_window=per_axis(witness), sensor_window=per_axis(sensor))
    )
    tree = json.loads(encode_state(state))
    watch = tree["f"]["contact"]["f"]
    for name, window in (("witness_window", witness), ("sensor_window", sensor)):
        watch[name] = json.loads(encode_state(window))  # the old shape, as the old encoder wrote it
    old = json.dumps(tree, separators=(",", ":")).encode()
    assert encode_state(decode_state(old, "cheope-state-json-1")) == encode_state(state)


def test_a_keyframe_of_an_unknown_encoding_is_refused_by_name():
    with pytest.raises(KeyframeError, match="keyframe encoding 'cheope-state-json-9': this version reads"):
        decode_state(b"{}", "cheope-state-json-9")


def test_an_old_window_of_samples_that_are_not_three_forces_is_refused():
    old = b'{"d":"controller.core.contact_guard:ContactWatch","f":{"witness_window":{"t":[{"t":[1.0,2.0]}]}}}'
    with pytest.raises(KeyframeError, match="not 3 forces each"):
        decode_state(old, "cheope-state-json-1")


@dataclass
class _Node:
    next: object = None


def test_a_state_nested_too_deep_or_holding_itself_is_a_keyframe_error_not_a_recursion_error():
    """A task's state of 5 000 nested tuples, or a list that holds itself, ended the loop with a
    RecursionError at the recording's first split (the recorder catches KeyframeError)."""
    deep: object = 0.0
    for _ in range(5000):
        deep = (deep,)
    itself = _Node()
    itself.next = itself
    for state in (deep, itself):
        with pytest.raises(KeyframeError, match="nests too deep"):
            encode_state(state)
