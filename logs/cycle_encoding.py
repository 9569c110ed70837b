"""A cycle as plain values for the recorder's writer, on the loop's thread.

The recorder (logs/recorder.py) hands every cycle to its writer process, and this is what the loop
pays for it: the cycle's inputs, outputs, state sample and timing gathered into tuples of numbers
and text (``cycle_values``), which the recorder pickles into its pipe. The writer builds the
``/cycle`` Protobuf from them (logs/messages.py ``cycle_pb``, and ``cycle_values_of_pb`` the way
back). Built on the loop's thread, that Protobuf was most of the observers' time in the service
(``observers_us`` p50 286-310 µs with the recording, 45-48 µs without; the values: 169-174 µs;
docs/measurements/speed.md). Compiled with the law (controller/compiled_law.py); the task state's
walk (``task_values``) is written for the compiler, whose ``isinstance`` is a C type check.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol, cast

from controller.core.records import values_getter

if TYPE_CHECKING:
    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs


class CycleTimingLike(Protocol):
    """controller.shell.loop.CycleTiming, without importing the shell."""

    @property
    def wake_error_s(self) -> float: ...

    @property
    def step_s(self) -> float: ...


# Per task state class: a getter of all its fields at once, and each field's name with the names
# of its first 4 elements, made once (the field walk and the f-strings per cycle were 2 100 of the
# contour cycle's 18 000 bytecodes, python -m controller.tools.bench.cycle_work).
TaskFieldPlan = tuple[Callable[[object], tuple[object, ...]], tuple[str, ...], tuple[tuple[str, ...], ...]]
_TASK_FIELD_PLANS: dict[type, TaskFieldPlan] = {}


def _task_field_plan(cls: type) -> TaskFieldPlan:
    names = tuple(f.name for f in dataclasses.fields(cls))
    return values_getter(names), names, tuple(tuple(f"{n}.{i}" for i in range(4)) for n in names)


TaskFields = tuple[tuple[str, ...], tuple[float, ...]]


def task_fields(task_state: object) -> TaskFields:
    """The scalar fields of a task state dataclass as names and values: numbers, and numeric tuples
    of 1 to 4 as name.i (bool and IntEnum are ints: recorded as numbers). Anything else (None,
    text, longer tuples, records) is not recorded per cycle; a keyframe holds the whole state
    (logs/keyframe.py). The names are the plan's own strings, the same objects every cycle, so the
    recorder tells unchanged names by a cheap comparison and sends them only when they change."""
    if task_state is None:
        return (), ()
    cls = type(task_state)
    plan = _TASK_FIELD_PLANS.get(cls)
    if plan is None:
        if not dataclasses.is_dataclass(task_state):
            return (), ()
        plan = _TASK_FIELD_PLANS[cls] = _task_field_plan(cls)
    getter, names, element_keys = plan
    values = getter(task_state)
    # gathered in a dict, which keeps the plan's own key strings: a store per value, where two
    # list appends were two calls each (the budget of python -m controller.tools.bench.cycle_work)
    out: dict[str, float] = {}
    for i in range(len(names)):
        v = values[i]
        if isinstance(v, float):
            # a subclass (numpy's float64) as a float: nothing for the writer to import
            out[names[i]] = float(v)
        elif isinstance(v, int):  # bool and IntEnum too
            out[names[i]] = float(v)
        elif isinstance(v, tuple):  # a NamedTuple too
            n = len(v)
            if 0 < n <= 4:
                numbers = True
                for x in v:
                    if not isinstance(x, (float, int)):
                        numbers = False
                        break
                if numbers:
                    keys = element_keys[i]
                    for j in range(n):
                        out[keys[j]] = float(v[j])
    return tuple(out), tuple(out.values())


def task_values(task_state: object) -> dict[str, float]:
    """``task_fields`` as a mapping of name to value (what ``/cycle`` records)."""
    keys, values = task_fields(task_state)
    return dict(zip(keys, values, strict=True))


# What the loop hands the writer for one cycle (``cycle_values``), in this order; logs.messages.cycle_pb
# turns it into the ``cheope.v1.Cycle`` in the writer's process:
#   cycle, t, inputs (``inputs_values``), controlwords, targets, mode, setpoint position,
#   velocity, acceleration, tcp_reference_m or None, tcp_measured_m or None, fault_reason,
#   task_phase ("" without a task state), task fields (``task_fields``: names, values; None
#   without a task state; the recorder sends None for the names while they are those it sent
#   last, logs/recorder.py), wake_error_s, step_s.
# Numbers, text and tuples: what pickle writes fastest, and no class the writer must import.
CycleValues = tuple[object, ...]
TASK_FIELDS_AT = 13  # the task fields' place in ``CycleValues``


def with_task_names(values: CycleValues, names: tuple[str, ...] | None) -> CycleValues:
    """``values`` (with task fields) with their task fields' names set to ``names``: None on the
    loop's side for names the writer has already (logs/recorder.py), those names again on the
    writer's (logs/session_writer.py)."""
    fields = cast(tuple[object, ...], values[TASK_FIELDS_AT])  # names (or None), values
    return (*values[:TASK_FIELDS_AT], (names, fields[1]), *values[TASK_FIELDS_AT + 1 :])


def without_sent_names(
    values: CycleValues, sent: tuple[str, ...] | None
) -> tuple[CycleValues, tuple[str, ...] | None]:
    """``values`` as the recorder sends them when the writer has the names ``sent``: their task
    fields' names None while they equal ``sent``; and the names this record carries (None when left
    out, or without task fields)."""
    fields = values[TASK_FIELDS_AT]
    if fields is None:
        return values, None
    names = cast(tuple[object, ...], fields)[0]
    if names == sent:  # on the loop's side the same strings each cycle: compared by identity
        return with_task_names(values, None), None
    return values, cast("tuple[str, ...] | None", names)


# The step's inputs (``inputs_values``), in this order; logs.messages.inputs_pb:
#   drives ((statusword, position, fresh, effort_n), ...), sensor (force_n, torque_nm, status,
#   counter, fresh) or None, emcy ((node_id, error_code, error_register), ...), stop_requested,
#   command, command_value, lost_heartbeats, error_frames, bus_off, late, anomalies ((kind, cob_id,
#   count, node_id, command), ...), nmt_reports ((node_id, state), ...), plans_ready,
#   targets_withheld, tracker (position_m, rotation_vector_rad, status, counter, fresh) or None.
InputsValues = tuple[object, ...]


def inputs_values(inputs: CycleInputs) -> InputsValues:
    """The step's inputs as plain values (``InputsValues``)."""
    s = inputs.sensor
    k = inputs.tracker
    return (
        tuple((d.statusword, d.position, d.fresh, d.effort_n) for d in inputs.drives),
        None if s is None else (s.force_n, s.torque_nm, s.status, s.counter, s.fresh),
        tuple((e.node_id, e.error_code, e.error_register) for e in inputs.emcy),
        inputs.stop_requested,
        inputs.command.value,
        inputs.command_value,
        inputs.lost_heartbeats,
        inputs.error_frames,
        inputs.bus_off,
        inputs.late,
        tuple((a.kind.value, a.cob_id, a.count, a.node_id, a.command) for a in inputs.anomalies),
        tuple((r.node_id, r.state) for r in inputs.nmt_reports),
        inputs.plans_ready,
        inputs.targets_withheld,
        None if k is None else (k.position_m, k.rotation_vector_rad, k.status, k.counter, k.fresh),
    )


def phase_text(phase_name: Callable[[object], str] | None, task_state: object) -> str:
    """The task's phase for the recording and the monitors: its ``phase_name`` as plain text ("" without
    one), "?" when it raises or gives no text: a task's display helper must never stop the loop (the
    monitor's publisher called it unguarded, and a plug-in's raise ended the run)."""
    if phase_name is None:
        return ""
    try:
        name: object = phase_name(task_state)
    except Exception:
        return "?"
    # text, not a subclass the writer would have to import (a StrEnum: its text); else "?"
    return str.__str__(name) if isinstance(name, str) else "?"


def cycle_values(
    cycle: int,
    t: float,
    inputs: CycleInputs,
    state: ControllerState,
    outputs: CycleOutputs,
    timing: CycleTimingLike,
    phase_name: Callable[[object], str] | None = None,
) -> CycleValues:
    """One cycle's record as plain values (``CycleValues``): what the step got, gave and holds."""
    task_state = state.task_state
    phase = ""
    fields: TaskFields | None = None
    if task_state is not None:
        phase = phase_text(phase_name, task_state)
        fields = task_fields(task_state)
    setpoint = state.setpoint
    return (
        cycle,
        t,
        inputs_values(inputs),
        outputs.controlwords,
        outputs.targets,
        state.mode.name,
        setpoint.position,
        setpoint.velocity,
        setpoint.acceleration,
        state.tcp_reference_m,
        state.tcp_measured_m,
        state.fault_reason,
        phase,
        fields,
        timing.wake_error_s,
        timing.step_s,
    )
