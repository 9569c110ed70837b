"""Topics of a session recording and the conversions between the step's dataclasses and Protobuf.

The recording's channels (all Protobuf, schemas embedded):

| topic | schema | what |
| --- | --- | --- |
| ``/can`` | ``cheope.v1.CanFrameBatch`` | every frame in and out, with its send/receive time: one message per cycle |
| ``/cycle`` | ``cheope.v1.Cycle`` | per cycle: the step's inputs, outputs, state sample and timing |
| ``/events`` | ``cheope.v1.Event`` | the step's events, and the recorder's own drop reports |
| ``/log`` | ``foxglove.Log`` | the same events as log lines, for viewers |
| ``/tcp`` | ``foxglove.FrameTransform`` | ``base`` -> ``tcp``: the measured TCP (direct kinematics) |
| ``/tcp_reference`` | ``foxglove.PoseInFrame`` | the path point the last setpoint aims at, in ``base`` |
| ``/scene`` | ``foxglove.SceneUpdate`` | the robot in 3D (logs/robot_drawing.py): the fixed parts once, the moving ones at 20 Hz |

MCAP ``log_time``/``publish_time`` are Unix nanoseconds: the controller's monotonic reading
plus the offset between the wall clock and the monotonic clock taken when the recording
started (``cheope.session`` metadata, ``clock_offset_ns``). The ``/cycle`` messages carry the
on_cycle call index as their MCAP ``sequence``: a gap in it is a cycle the recorder dropped,
not one the loop skipped (skipped cycles show as gaps in ``Cycle.cycle`` only).

``/can`` holds the frames that came before each cycle in one ``CanFrameBatch`` (packed, see
``pack_frames``); files written before it hold one ``cheope.v1.CanFrame`` per frame.
``logs.reader.iter_decoded`` gives both back as one ``CanFrame`` per frame, with the log time
each frame had in the older files. A rotated file starts with ``/keyframe``
(``cheope.v1.Keyframe``: the controller's state, logs/keyframe.py).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import struct
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Protocol

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
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

if TYPE_CHECKING:
    from controller.core.controller_state import ControllerState

TOPIC_CAN = "/can"
TOPIC_CYCLE = "/cycle"
TOPIC_EVENTS = "/events"
TOPIC_LOG = "/log"
TOPIC_TCP = "/tcp"
TOPIC_TCP_REFERENCE = "/tcp_reference"
TOPIC_SCENE = "/scene"
TOPIC_KEYFRAME = "/keyframe"

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


class CycleTimingLike(Protocol):
    """controller.shell.loop.CycleTiming, without importing the shell."""

    @property
    def wake_error_s(self) -> float: ...

    @property
    def step_s(self) -> float: ...


def _set_time(stamp: _Timestamp, unix_ns: int) -> None:
    stamp.seconds, stamp.nanos = divmod(unix_ns, 1_000_000_000)


def can_frame(
    monotonic_s: float,
    outgoing: bool,
    arbitration_id: int,
    data: bytes,
    is_fd: bool,
    bitrate_switch: bool,
    is_error_frame: bool,
) -> pb.CanFrame:
    return pb.CanFrame(
        monotonic_s=monotonic_s,
        outgoing=outgoing,
        arbitration_id=arbitration_id,
        data=data,
        is_fd=is_fd,
        bitrate_switch=bitrate_switch,
        is_error_frame=is_error_frame,
    )


# CanFrameBatch.frames, little-endian, by column (each compresses better among its likes): the
# time encoding (uint8) and the count n (uint32), n times, n arbitration ids (uint32), n flags
# (uint8: 1 outgoing, 2 FD, 4 bitrate switch, 8 error frame), n data lengths (uint8), the data.
# The times: TIMES_NS (uint64): the first frame's integer nanoseconds, then each one's difference
# from the one before (small numbers, mostly zero bytes), when every double monotonic_s is its
# nanoseconds / 1e9, as time.monotonic() makes them; else TIMES_BITS: each double's bits XOR the
# previous one's. Either way every double comes back bit for bit.
_HEAD = struct.Struct("<BI")
TIMES_NS, TIMES_BITS = 1, 2
_OUTGOING, _FD, _BRS, _ERROR = 1, 2, 4, 8
_U64 = (1 << 64) - 1
_NS_LIMIT = 1 << 62  # nanoseconds whose differences stay within int64 (146 years)

FrameTuple = tuple[
    bool, float, int, bytes, bool, bool, bool
]  # (outgoing, monotonic_s, id, data, fd, brs, error)


def _time_column(times: list[float]) -> tuple[int, list[int]]:
    try:
        ns = [round(t * 1e9) for t in times]
    except (ValueError, OverflowError):  # nan, inf
        ns = []
    if ns and all(
        abs(k) < _NS_LIMIT and k / 1e9 == t and (k or math.copysign(1.0, t) > 0)  # -0.0: bits
        for k, t in zip(ns, times, strict=True)
    ):
        return TIMES_NS, [(b - a) & _U64 for a, b in itertools.pairwise((0, *ns))]  # deltas
    bits = struct.unpack(f"<{len(times)}Q", struct.pack(f"<{len(times)}d", *times))
    return TIMES_BITS, [b ^ a for a, b in itertools.pairwise((0, *bits))]  # XOR with the last


def _times(encoding: int, column: tuple[int, ...]) -> tuple[float, ...]:
    acc, out = 0, []
    for x in column:
        acc = (acc + x) & _U64 if encoding == TIMES_NS else acc ^ x
        out.append(acc)
    if encoding == TIMES_NS:
        return tuple((k - (1 << 64) if k >> 63 else k) / 1e9 for k in out)
    if encoding == TIMES_BITS:
        return struct.unpack(f"<{len(out)}d", struct.pack(f"<{len(out)}Q", *out))
    raise ValueError(f"a CAN frame batch with an unknown time encoding {encoding}")


def pack_frames(frames: list[FrameTuple]) -> bytes:
    """``frames`` as ``CanFrameBatch.frames`` (see above): exact, every double bit for bit."""
    n = len(frames)
    encoding, times = _time_column([f[1] for f in frames])
    flags = [outgoing | fd << 1 | brs << 2 | err << 3 for outgoing, _, _, _, fd, brs, err in frames]
    return b"".join(
        (
            struct.pack(
                f"<BI{n}Q{n}I{n}B{n}B",
                encoding,
                n,
                *times,
                *[f[2] for f in frames],
                *flags,
                *[len(f[3]) for f in frames],
            ),
            *[f[3] for f in frames],
        )
    )


def unpack_frames(packed: bytes) -> Iterator[pb.CanFrame]:
    """The frames of ``CanFrameBatch.frames``, each as the ``CanFrame`` an older file held;
    ``ValueError`` when the bytes do not hold what their count says."""
    if len(packed) < _HEAD.size:
        raise ValueError(f"a CAN frame batch of {len(packed)} bytes has no frame count")
    encoding, n = _HEAD.unpack_from(packed)
    columns = struct.Struct(f"<{n}Q{n}I{n}B{n}B")
    if _HEAD.size + columns.size > len(packed):
        raise ValueError(f"a CAN frame batch of {len(packed)} bytes is too short for its {n} frames")
    cols = columns.unpack_from(packed, _HEAD.size)
    ids, flags, lengths = cols[n : 2 * n], cols[2 * n : 3 * n], cols[3 * n :]
    times = _times(encoding, cols[:n])
    pos = _HEAD.size + columns.size
    if pos + sum(lengths) != len(packed):
        raise ValueError(f"a CAN frame batch holds {len(packed) - pos} data bytes, its frames {sum(lengths)}")
    for t, arb, f, length in zip(times, ids, flags, lengths, strict=True):
        yield pb.CanFrame(
            monotonic_s=t,
            outgoing=bool(f & _OUTGOING),
            arbitration_id=arb,
            data=packed[pos : pos + length],
            is_fd=bool(f & _FD),
            bitrate_switch=bool(f & _BRS),
            is_error_frame=bool(f & _ERROR),
        )
        pos += length


def frame_log_time_ns(monotonic_s: float, offset_ns: int) -> int:
    """A frame's MCAP log time: its monotonic time on the wall clock (``clock_offset_ns``)."""
    return int(monotonic_s * 1e9) + offset_ns


def inputs_to_pb(inputs: CycleInputs, out: pb.CycleInputs) -> None:
    for d in inputs.drives:
        out.drives.add(statusword=d.statusword, position=d.position, fresh=d.fresh)
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
    k = inputs.tracker
    if k is not None:
        out.tracker.position_m.extend(k.position_m)
        out.tracker.rotation_vector_rad.extend(k.rotation_vector_rad)
        out.tracker.status, out.tracker.counter, out.tracker.fresh = k.status, k.counter, k.fresh


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
        drives=tuple(DriveFeedback(d.statusword, d.position, d.fresh) for d in msg.drives),
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
    )


def outputs_from_pb(msg: pb.CycleOutputs) -> CycleOutputs:
    return CycleOutputs(controlwords=tuple(msg.controlwords), targets=tuple(msg.targets))


def task_values(task_state: object) -> dict[str, float]:
    """The scalar fields of a task state dataclass (numbers, and numeric tuples of up to 4 as name.i)."""
    if task_state is None or not dataclasses.is_dataclass(task_state):
        return {}
    out: dict[str, float] = {}
    for f in dataclasses.fields(task_state):
        v = getattr(task_state, f.name)
        if isinstance(v, (int, float)):
            out[f.name] = float(v)
        elif isinstance(v, tuple) and 0 < len(v) <= 4 and all(isinstance(x, (int, float)) for x in v):
            for i, x in enumerate(v):
                out[f"{f.name}.{i}"] = float(x)
    return out


def cycle_to_pb(
    cycle: int,
    t: float,
    inputs: CycleInputs,
    state: ControllerState,
    outputs: CycleOutputs,
    timing: CycleTimingLike,
    phase_name: Callable[[object], str] | None = None,
) -> pb.Cycle:
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
        for k, v in task_values(state.task_state).items():
            st.task_values[k] = v
    msg.timing.wake_error_s = timing.wake_error_s
    msg.timing.step_s = timing.step_s
    return msg


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


def tcp_pose(unix_ns: int, tcp_m: tuple[float, float, float]) -> PoseInFrame:
    msg = PoseInFrame(frame_id=BASE_FRAME)
    _set_time(msg.timestamp, unix_ns)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = tcp_m
    msg.pose.orientation.w = 1.0
    return msg


def same_double(a: float, b: float) -> bool:
    """Bit-for-bit equality of two doubles (so -0.0 != 0.0 and a NaN equals only the same NaN)."""
    return _DOUBLE.pack(a) == _DOUBLE.pack(b)
