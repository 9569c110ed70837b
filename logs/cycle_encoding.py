"""A cycle as its ``/cycle`` record (``cheope.v1.Cycle``), on the loop's thread.

The recorder (logs/recorder.py) turns every cycle into this message before it hands the cycle to
its writer process, so this is the part of the recording the loop pays for: in service it was
most of the observers' time (``observers_us`` p50 310 µs with the recording, 45-48 µs without,
``cheope demo --json`` and ``--set recording.enabled=false``, contour, 400 Hz). It is compiled
with the law (controller/compiled_law.py): the contour's record then takes 0.70-0.73 of the
interpreted one's time (in process, interleaved, 3 runs; the messages are equal). The messages
the writer builds, and the way back from Protobuf, are in logs/messages.py.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from controller.core.records import values_getter
from controller.messages import cheope_pb2 as pb

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


def task_values(task_state: object) -> dict[str, float]:
    """The scalar fields of a task state dataclass: numbers, and numeric tuples of 1 to 4 as name.i
    (bool and IntEnum are ints: recorded as numbers). Anything else (None, text, longer tuples,
    records) is not recorded per cycle; a keyframe holds the whole state (logs/keyframe.py)."""
    if task_state is None:
        return {}
    cls = type(task_state)
    plan = _TASK_FIELD_PLANS.get(cls)
    if plan is None:
        if not dataclasses.is_dataclass(task_state):
            return {}
        plan = _TASK_FIELD_PLANS[cls] = _task_field_plan(cls)
    getter, names, element_keys = plan
    values = getter(task_state)
    out: dict[str, float] = {}
    for i in range(len(names)):
        v = values[i]
        if isinstance(v, float):
            out[names[i]] = v
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
    return out


def inputs_to_pb(inputs: CycleInputs, out: Any) -> None:
    """``inputs`` into ``out``, a ``cheope.v1.CycleInputs`` (logs.messages.inputs_from_pb: the way back)."""
    for d in inputs.drives:
        drive = out.drives.add(statusword=d.statusword, position=d.position, fresh=d.fresh)
        if not math.isnan(d.effort_n):  # absent: the TPDO does not map 0x6077 (older sessions neither)
            drive.effort_n = d.effort_n
    s = inputs.sensor
    if s is not None:
        out.sensor.force_n.extend(s.force_n)
        out.sensor.torque_nm.extend(s.torque_nm)
        out.sensor.status, out.sensor.counter, out.sensor.fresh = s.status, s.counter, s.fresh
    for e in inputs.emcy:
        out.emcy.add(node_id=e.node_id, error_code=e.error_code, error_register=e.error_register)
    out.stop_requested = inputs.stop_requested
    out.command = inputs.command
    out.command_value = inputs.command_value
    out.lost_heartbeats.extend(inputs.lost_heartbeats)
    out.error_frames = inputs.error_frames
    out.bus_off = inputs.bus_off
    out.late = inputs.late
    for a in inputs.anomalies:
        out.anomalies.add(
            kind=a.kind.value, cob_id=a.cob_id, count=a.count, node_id=a.node_id, command=a.command
        )
    for r in inputs.nmt_reports:
        out.nmt_reports.add(node_id=r.node_id, state=r.state)
    out.plans_ready = inputs.plans_ready
    out.targets_withheld = inputs.targets_withheld
    k = inputs.tracker
    if k is not None:
        out.tracker.position_m.extend(k.position_m)
        out.tracker.rotation_vector_rad.extend(k.rotation_vector_rad)
        out.tracker.status, out.tracker.counter, out.tracker.fresh = k.status, k.counter, k.fresh


def cycle_to_pb(
    cycle: int,
    t: float,
    inputs: CycleInputs,
    state: ControllerState,
    outputs: CycleOutputs,
    timing: CycleTimingLike,
    phase_name: Callable[[object], str] | None = None,
) -> Any:
    """The ``cheope.v1.Cycle`` of one cycle: what the step got, gave and holds (its task's numbers)."""
    msg = pb.Cycle(cycle=cycle, t_s=t)
    inputs_to_pb(inputs, msg.inputs)
    msg.outputs.controlwords.extend(outputs.controlwords)
    msg.outputs.targets.extend(outputs.targets)
    st = msg.state
    st.mode = state.mode.name
    st.setpoint_position.extend(state.setpoint.position)
    st.setpoint_velocity.extend(state.setpoint.velocity)
    st.setpoint_acceleration.extend(state.setpoint.acceleration)
    if state.tcp_reference_m is not None:
        st.tcp_reference_m.extend(state.tcp_reference_m)
    if state.tcp_measured_m is not None:
        st.tcp_measured_m.extend(state.tcp_measured_m)
    st.fault_reason = state.fault_reason
    if state.task_state is not None:
        if phase_name is not None:
            try:
                st.task_phase = phase_name(state.task_state)
            except Exception:  # a task's display helper must never stop the recording
                st.task_phase = "?"
        values = st.task_values  # the map's wrapper once, not once per value
        for key, value in task_values(state.task_state).items():
            values[key] = value
    msg.timing.wake_error_s = timing.wake_error_s
    msg.timing.step_s = timing.step_s
    return msg
