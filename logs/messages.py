"""Topics of a session recording and the conversions between the step's dataclasses and Protobuf.

The recording's channels (all Protobuf, schemas embedded):

| topic | schema | what |
| --- | --- | --- |
| ``/can`` | ``cheope.v1.CanFrames`` | every frame in and out, with its time, direction and flags: one message per cycle |
| ``/cycle`` | ``cheope.v1.Cycle`` | per cycle: the step's inputs, outputs, state sample and timing |
| ``/events`` | ``cheope.v1.Event`` | the step's events, and the recorder's own drop reports |
| ``/log`` | ``foxglove.Log`` | the same events as log lines, for viewers |
| ``/tcp`` | ``foxglove.FrameTransform`` | ``base`` -> ``tcp``: the measured TCP (direct kinematics) |
| ``/tcp_reference`` | ``foxglove.PoseInFrame`` | the path point the last setpoint aims at, in ``base`` |
| ``/scene`` | ``foxglove.SceneUpdate`` | the robot in 3D (logs/robot_drawing.py): the fixed parts once, the moving ones at 20 Hz |
| ``/joint_states`` | ``foxglove.JointStates`` | the actuated joints by the robot's names, position and velocity, at the scene's rate |

MCAP ``log_time``/``publish_time`` are Unix nanoseconds: the controller's monotonic reading
plus the offset between the wall clock and the monotonic clock taken when the recording
started (``cheope.session`` metadata, ``clock_offset_ns``). The ``/cycle`` messages carry the
on_cycle call index as their MCAP ``sequence``: a gap in it is a cycle the recorder dropped,
not one the loop skipped (skipped cycles show as gaps in ``Cycle.cycle`` only).

``/can`` holds the frames that came before each cycle in one ``CanFrames`` (one entry per
frame). Older files hold a ``cheope.v1.CanFrameBatch`` per cycle (packed by column,
logs/can_frame_batch.py) or one ``cheope.v1.CanFrame`` per frame: ``logs.reader.iter_decoded``
gives every format back as one ``CanFrames.Frame`` per frame, with the frame's time as its log
time. A rotated file starts with ``/keyframe`` (``cheope.v1.Keyframe``: the controller's state,
logs/keyframe.py).

A cycle's ``/cycle`` record is built on the loop's thread, compiled with the law
(logs/cycle_encoding.py); this module has the way back (``inputs_from_pb``) and what the writer builds.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, Protocol, cast

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from controller.core.cycle_data import (
    Anomaly,
    BusAnomaly,
    Command,
    CycleInputs,
    CycleOutputs,
    DriveFeedback,
    EmcyReport,
    Event,
    NmtReport,
    SensorFeedback,
    Severity,
    TrackerFeedback,
)
from controller.messages import cheope_pb2 as pb
from logs.cycle_encoding import TASK_FIELDS_AT, CycleValues, InputsValues, inputs_values
from logs.task_values_wire import TaskValuesWire, length_delimited

if TYPE_CHECKING:
    import can


TOPIC_CAN = "/can"
TOPIC_CYCLE = "/cycle"
TOPIC_EVENTS = "/events"
TOPIC_LOG = "/log"
TOPIC_TCP = "/tcp"
TOPIC_TCP_REFERENCE = "/tcp_reference"
TOPIC_SCENE = "/scene"
TOPIC_KEYFRAME = "/keyframe"
TOPIC_JOINT_STATES = "/joint_states"

# The events the recorder writes itself on /events (logs/session_writer.py), not the law's: a replay
# compares the law's only. "recording_stopped" compared as the law's made `replay --verify` report a
# divergence where the recording had stopped for free space (an outside tester, 44dbcbc).
RECORDER_EVENT_KINDS = frozenset(
    {"recorder_drop", "recording_stopped", "recording_deleted", "keyframe_missing"}
)

BASE_FRAME = "base"
TCP_FRAME = "tcp"

META_CONFIG = "cheope.config"  # {"json": config_to_dict(cfg) as JSON}
META_GEOMETRY = "cheope.geometry"  # {"robot_kind", "json": the [robot] section as JSON}
META_VERSIONS = "cheope.versions"  # {"package": "version", ...}
META_SESSION = "cheope.session"  # {"started_utc", "clock_offset_ns", "period_s", ...}
META_RECORDING = "cheope.recording"  # written at close: {"dropped", "written", "complete"}
# the files of one session: {"session_id", "sequence" (1, 2, ...), "previous" (file name), "next" (at close)}
META_FILE = "cheope.file"

_DOUBLE = struct.Struct("<d")
_LOG_LEVEL = {
    Severity.INFO: Log.Level.INFO,
    Severity.WARNING: Log.Level.WARNING,
    Severity.FAULT: Log.Level.ERROR,
}


class _Timestamp(Protocol):
    """google.protobuf.Timestamp (the protobuf package has no type information here)."""

    seconds: int
    nanos: int


def _set_time(stamp: _Timestamp, unix_ns: int) -> None:
    stamp.seconds, stamp.nanos = divmod(unix_ns, 1_000_000_000)


# A CAN frame as the recorder hands it to the writer (logs/recorder.py, on the loop's thread: a
# plain tuple, the cheapest to build): (outgoing, monotonic_s, arbitration_id, data,
# is_extended_id, is_remote_frame, remote_length, is_fd, bitrate_switch, error_state_indicator,
# is_error_frame).
FrameRecord = tuple[bool, float, int, bytes, bool, bool, int, bool, bool, bool, bool]


def frame_record(outgoing: bool, monotonic_s: float, msg: can.Message) -> FrameRecord:
    """``msg`` as a ``FrameRecord``: its bytes copied (the exchange rewrites its outgoing messages)."""
    return (
        outgoing,
        monotonic_s,
        msg.arbitration_id,
        bytes(msg.data),
        msg.is_extended_id,
        msg.is_remote_frame,
        msg.dlc if msg.is_remote_frame else 0,
        msg.is_fd,
        msg.bitrate_switch,
        msg.error_state_indicator,
        msg.is_error_frame,
    )


def can_frames(frames: list[FrameRecord], offset_ns: int) -> pb.CanFrames:
    """One ``/can`` message: ``frames`` with their times on the wall clock (``unix_time_ns_of``)."""
    out = pb.CanFrames()
    add = out.frames.add
    for outgoing, mono_s, arb, data, ext, rtr, rlen, fd, brs, esi, err in frames:
        if ext or rtr or rlen or fd or brs or esi or err:
            add(
                unix_time_ns=unix_time_ns_of(mono_s, offset_ns),
                arbitration_id=arb,
                data=data,
                outgoing=outgoing,
                is_extended_id=ext,
                is_remote_frame=rtr,
                remote_length=rlen,
                is_fd=fd,
                bitrate_switch=brs,
                error_state_indicator=esi,
                is_error_frame=err,
            )
        else:  # a classic data frame, nearly all of them: the flags at their defaults (7 of 11 µs for 9 frames)
            add(
                unix_time_ns=unix_time_ns_of(mono_s, offset_ns),
                arbitration_id=arb,
                data=data,
                outgoing=outgoing,
            )
    return out


def frame_from_legacy(f: pb.CanFrame, unix_time_ns: int) -> pb.CanFrames.Frame:
    """A frame of a recording written before ``CanFrames`` (``CanFrame``, one per message or packed in a
    ``CanFrameBatch``) as the frames are now. Those files did not record the id's format, remote frames
    nor ESI: an id above 0x7FF is taken for an extended one, the rest as data frames without ESI."""
    return pb.CanFrames.Frame(
        unix_time_ns=unix_time_ns,
        arbitration_id=f.arbitration_id,
        data=f.data,
        outgoing=f.outgoing,
        is_extended_id=f.arbitration_id > 0x7FF,
        is_fd=f.is_fd,
        bitrate_switch=f.bitrate_switch,
        is_error_frame=f.is_error_frame,
    )


def unix_time_ns_of(monotonic_s: float, offset_ns: int) -> int:
    """A monotonic reading on the wall clock (``clock_offset_ns``): the MCAP log time of what happened
    then, and a frame's ``unix_time_ns``. Rounded: ``time.monotonic()`` is integer nanoseconds / 1e9,
    which comes back whole (recordings before ``CanFrames`` truncated, at most 1 ns earlier)."""
    return round(monotonic_s * 1e9) + offset_ns


def inputs_pb(values: InputsValues, out: pb.CycleInputs) -> None:
    """The step's inputs as plain values (logs.cycle_encoding.inputs_values, which says their order)
    into ``out``; ``inputs_from_pb`` is the way back."""
    (
        drives,
        sensor,
        emcy,
        stop_requested,
        command,
        command_value,
        lost_heartbeats,
        error_frames,
        bus_off,
        late,
        anomalies,
        nmt_reports,
        plans_ready,
        targets_withheld,
        tracker,
    ) = cast(Any, values)  # the order above; numbers, text, tuples
    for statusword, position, fresh, effort_n in drives:
        drive = out.drives.add(statusword=statusword, position=position, fresh=fresh)
        if not math.isnan(effort_n):  # absent: the TPDO does not map 0x6077 (older sessions neither)
            drive.effort_n = effort_n
    if sensor is not None:
        force_n, torque_nm, status, counter, fresh = sensor
        out.sensor.force_n.extend(force_n)
        out.sensor.torque_nm.extend(torque_nm)
        out.sensor.status, out.sensor.counter, out.sensor.fresh = status, counter, fresh
    for node_id, error_code, error_register in emcy:
        out.emcy.add(node_id=node_id, error_code=error_code, error_register=error_register)
    out.stop_requested = stop_requested
    out.command = command
    out.command_value = command_value
    out.lost_heartbeats.extend(lost_heartbeats)
    out.error_frames = error_frames
    out.bus_off = bus_off
    out.late = late
    for kind, cob_id, count, node_id, anomaly_command in anomalies:
        out.anomalies.add(kind=kind, cob_id=cob_id, count=count, node_id=node_id, command=anomaly_command)
    for node_id, nmt_state in nmt_reports:
        out.nmt_reports.add(node_id=node_id, state=nmt_state)
    out.plans_ready = plans_ready
    out.targets_withheld = targets_withheld
    if tracker is not None:
        position_m, rotation_vector_rad, status, counter, fresh = tracker
        out.tracker.position_m.extend(position_m)
        out.tracker.rotation_vector_rad.extend(rotation_vector_rad)
        out.tracker.status, out.tracker.counter, out.tracker.fresh = status, counter, fresh


def cycle_pb(values: CycleValues) -> pb.Cycle:
    """The ``cheope.v1.Cycle`` of one cycle's values (logs.cycle_encoding.cycle_values, which says their
    order): built in the writer's process, not on the loop's thread. The writer writes
    ``cycle_bytes`` of them, the same message."""
    msg = _cycle_head(values)
    _state_pb(values, msg.state)
    task_fields = values[TASK_FIELDS_AT]
    if task_fields is not None:
        task_values = msg.state.task_values
        for name, value in zip(
            *cast(Any, task_fields), strict=True
        ):  # names and values (cycle_encoding.task_fields)
            task_values[name] = value
    _timing_pb(values, msg.timing)
    return msg


def cycle_bytes(values: CycleValues, wire: TaskValuesWire | None = None) -> bytes:
    """``cycle_pb(values).SerializeToString()`` with the task values written by ``wire`` (made for their
    names when it is not) instead of through upb's map (logs/task_values_wire.py says why): the same
    message, its fields in their order (``state`` and ``timing`` are the last two, the map the last
    field of ``state``)."""
    task_fields = cast(Any, values[TASK_FIELDS_AT])
    if task_fields is None:
        return cast(bytes, cycle_pb(values).SerializeToString())
    names, task_values = task_fields
    if wire is None or (
        wire.names is not names and wire.names != tuple(names)
    ):  # the writer's: the same tuple
        wire = TaskValuesWire(names)
    state = pb.StateSample()
    _state_pb(values, state)
    timing = pb.CycleTiming()
    _timing_pb(values, timing)
    return b"".join(
        (
            _cycle_head(values).SerializeToString(),
            length_delimited(CYCLE_STATE_FIELD, state.SerializeToString() + wire.entries(task_values)),
            length_delimited(CYCLE_TIMING_FIELD, timing.SerializeToString()),
        )
    )


CYCLE_STATE_FIELD, CYCLE_TIMING_FIELD = 5, 6  # Cycle.state, Cycle.timing: its last two fields


def _cycle_head(values: CycleValues) -> pb.Cycle:
    """A ``Cycle`` of ``values``' cycle, time, inputs and outputs (``cycle_pb``'s fields 1-4)."""
    cycle, t, inputs, controlwords, targets = cast(Any, values[:5])  # cycle_encoding.cycle_values's order
    msg = pb.Cycle(cycle=cycle, t_s=t)
    inputs_pb(inputs, msg.inputs)
    msg.outputs.controlwords.extend(controlwords)
    msg.outputs.targets.extend(targets)
    return msg


def _state_pb(values: CycleValues, st: pb.StateSample) -> None:
    """``values``' state sample into ``st``, all but the task values (their phase when there are any)."""
    (
        mode,
        setpoint_position,
        setpoint_velocity,
        setpoint_acceleration,
        tcp_reference_m,
        tcp_measured_m,
        fault_reason,
        task_phase,
        task_fields,
    ) = cast(Any, values[5:14])  # cycle_encoding.cycle_values's order
    st.mode = mode
    st.setpoint_position.extend(setpoint_position)
    st.setpoint_velocity.extend(setpoint_velocity)
    st.setpoint_acceleration.extend(setpoint_acceleration)
    if tcp_reference_m is not None:
        st.tcp_reference_m.extend(tcp_reference_m)
    if tcp_measured_m is not None:
        st.tcp_measured_m.extend(tcp_measured_m)
    st.fault_reason = fault_reason
    if task_fields is not None:
        st.task_phase = task_phase


def _timing_pb(values: CycleValues, timing: pb.CycleTiming) -> None:
    timing.wake_error_s, timing.step_s = cast(Any, values[14:16])


def cycle_values_of_pb(msg: pb.Cycle) -> CycleValues:
    """A recorded ``cheope.v1.Cycle`` as the values the recorder hands its writer (``cycle_pb`` of them is
    ``msg`` again): to write a recorded session's cycles anew (controller/tools/bench/writer_work.py, tests/tools/bench_recording_size.py)."""
    st = msg.state
    task_values = st.task_values
    return (
        msg.cycle,
        msg.t_s,
        inputs_values(inputs_from_pb(msg.inputs)),
        tuple(msg.outputs.controlwords),
        tuple(msg.outputs.targets),
        st.mode,
        tuple(st.setpoint_position),
        tuple(st.setpoint_velocity),
        tuple(st.setpoint_acceleration),
        tuple(st.tcp_reference_m) or None,
        tuple(st.tcp_measured_m) or None,
        st.fault_reason,
        st.task_phase,
        (tuple(task_values), tuple(task_values.values())) if task_values or st.task_phase else None,
        msg.timing.wake_error_s,
        msg.timing.step_s,
    )


def inputs_from_pb(msg: pb.CycleInputs) -> CycleInputs:
    """The exact ``CycleInputs`` the step received (doubles round-trip bit for bit)."""
    sensor = None
    if msg.HasField("sensor"):
        s = msg.sensor
        sensor = SensorFeedback(tuple(s.force_n), tuple(s.torque_nm), s.status, s.counter, s.fresh)
    tracker = None
    if msg.HasField("tracker"):
        k = msg.tracker
        tracker = TrackerFeedback(
            tuple(k.position_m), tuple(k.rotation_vector_rad), k.status, k.counter, k.fresh
        )
    return CycleInputs(
        drives=tuple(
            DriveFeedback(
                d.statusword, d.position, d.fresh, d.effort_n if d.HasField("effort_n") else math.nan
            )
            for d in msg.drives
        ),
        sensor=sensor,
        emcy=tuple(EmcyReport(e.node_id, e.error_code, e.error_register) for e in msg.emcy),
        stop_requested=msg.stop_requested,
        command=Command(msg.command),
        command_value=msg.command_value,
        lost_heartbeats=tuple(msg.lost_heartbeats),
        error_frames=msg.error_frames,
        bus_off=msg.bus_off,
        late=msg.late,
        anomalies=tuple(
            BusAnomaly(Anomaly(a.kind), a.cob_id, a.count, a.node_id, a.command) for a in msg.anomalies
        ),
        nmt_reports=tuple(NmtReport(r.node_id, r.state) for r in msg.nmt_reports),
        tracker=tracker,
        plans_ready=msg.plans_ready,
        targets_withheld=msg.targets_withheld,
    )


def outputs_from_pb(msg: pb.CycleOutputs) -> CycleOutputs:
    return CycleOutputs(controlwords=tuple(msg.controlwords), targets=tuple(msg.targets))


def event_to_pb(cycle: int, t: float, event: Event) -> pb.Event:
    return pb.Event(cycle=cycle, t_s=t, kind=event.kind, severity=int(event.severity), message=event.message)


def event_to_log(unix_ns: int, event: Event) -> Log:
    msg = Log(
        level=_LOG_LEVEL.get(event.severity, Log.Level.UNKNOWN),
        message=event.message,
        name=f"cheope.{event.kind}",
    )
    _set_time(msg.timestamp, unix_ns)
    return msg


def tcp_transform(unix_ns: int, tcp_m: tuple[float, float, float]) -> FrameTransform:
    msg = FrameTransform(parent_frame_id=BASE_FRAME, child_frame_id=TCP_FRAME)
    _set_time(msg.timestamp, unix_ns)
    msg.translation.x, msg.translation.y, msg.translation.z = tcp_m
    msg.rotation.w = 1.0  # the platform of a translational robot does not rotate
    return msg


def joint_states(
    unix_ns: int,
    names: tuple[str, ...],
    positions: tuple[float, ...],
    velocities: tuple[float, ...],
    efforts: tuple[float, ...] = (),
) -> JointStates:
    """``foxglove.JointStates``: each actuated joint by the robot's name for it (``actuator_j`` without
    one), its position, from the second sample on its velocity (``JointVelocities``), and the
    drive's effort where its TPDO maps 0x6077."""
    msg = JointStates()
    _set_time(msg.timestamp, unix_ns)
    for j, q in enumerate(positions):
        joint = msg.joints.add(name=names[j] if j < len(names) else f"actuator_{j + 1}", position=q)
        if j < len(velocities):
            joint.velocity = velocities[j]
        if j < len(efforts):
            joint.effort = efforts[j]
    return msg


def recorded_efforts(drives: Iterable[pb.DriveFeedback]) -> tuple[float, ...]:
    """A recorded cycle's drive efforts (0x6077), one per drive, or none where one is not mapped
    (older sessions, a drive whose TPDO leaves it out)."""
    drives = list(drives)
    if not drives or not all(d.HasField("effort_n") for d in drives):
        return ()
    return tuple(d.effort_n for d in drives)


@dataclasses.dataclass
class JointVelocities:
    """The measured actuators' velocities: each position's difference from the previous sample's over
    the time between them (the drives report no velocity); empty for the first sample and after a
    change in the number of actuators."""

    _last: tuple[int, tuple[float, ...]] | None = None

    def update(self, stamp_ns: int, positions: tuple[float, ...]) -> tuple[float, ...]:
        last, self._last = self._last, (stamp_ns, positions)
        if last is None or len(last[1]) != len(positions) or stamp_ns <= last[0]:
            return ()
        dt_s = (stamp_ns - last[0]) * 1e-9
        return tuple((p - p0) / dt_s for p, p0 in zip(positions, last[1], strict=True))


def tcp_pose(unix_ns: int, tcp_m: tuple[float, float, float]) -> PoseInFrame:
    msg = PoseInFrame(frame_id=BASE_FRAME)
    _set_time(msg.timestamp, unix_ns)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = tcp_m
    msg.pose.orientation.w = 1.0
    return msg


def same_double(a: float, b: float) -> bool:
    """Bit-for-bit equality of two doubles (so -0.0 != 0.0 and a NaN equals only the same NaN)."""
    return _DOUBLE.pack(a) == _DOUBLE.pack(b)
