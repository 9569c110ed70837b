"""The recorder's writer process: records from a pipe in, one MCAP file out.

Why a process and not a thread: the MCAP writer, the Protobuf messages of every CAN frame and
the compression are pure-Python work of about 150 µs per 1 kHz cycle. On a thread it holds the
GIL the loop thread needs the moment it wakes; at 1 kHz that alone took the period error p99
from 37 µs to 634 µs (docs/measurements/speed.md). In its own process it has its own GIL and the loop only
pays for turning a cycle into bytes and one ``write`` to a pipe (logs/recorder.py).

The wire format, loop -> writer, on the writer's standard input: records of a 4-byte
little-endian length and a pickle of a tuple whose first item is the kind:

    (SETUP, settings dict)                                     first, once
    (CYCLE, dropped, frames, cycle, t, mono_s, seq, values, events, tcp_measured, tcp_reference)
    (FRAMES, dropped, frames)                                  frames without a cycle after them
    (KEYFRAME, dropped, cycle, t, mono_s, seq, encoding, state, problem)   asked for: see below
    (END, queued, dropped)                                     the recorder's close

``frames`` is a list of ``logs.messages.FrameRecord`` (outgoing, monotonic_s, arbitration_id, data, flags),
``values`` the cycle's values (logs/cycle_encoding.py ``cycle_values``: numbers, text, tuples),
which the writer turns into the ``cheope.v1.Cycle`` (logs/messages.py ``cycle_pb``); their task
fields carry their names only when these changed (None: the names of the last record that had
them; a record of None before any names stops the recording, nothing of that cycle written), and
``dropped`` the loop's running count of items it could not hand over. Writer -> loop, on
standard output, JSON lines: ``{"ready": ...}`` or ``{"error": ...}`` after SETUP, and ``{"written": n, "chunks": n, "error": "", "files": [...],
"deleted": [...]}`` at the end; in between ``{"keyframe": n}``, ``{"file": path}``, ``{"stopped": why}``
and ``{"command": "stop"}`` (the live Foxglove server's stop service, logs/live_views.py).

A long session is split into files (``recording.max_file_size_mb``, ``max_file_duration_s``).
Past a limit the writer asks the controller for a keyframe (``{"keyframe": n}``); the recorder
answers after its next cycle with the controller's state after that cycle (logs/keyframe.py),
and the writer closes the file there and opens the next one (``NAME.002.mcap``, ...) with the
same metadata, ``cheope.file`` (session id, sequence, previous file) and the keyframe first, so
``cheope replay FILE --verify`` can start from any file. After each new file the oldest
recordings of the directory are deleted past ``recording.keep_total_size_gb`` (never an open
one), and after each chunk the free space is checked: below ``recording.min_free_space_mb`` the
writer names the reason on /events and to the controller (``{"stopped": why}``), closes the file
cleanly and its input, so the controller's next write fails and ``recording.on_failure`` decides.
So does a cycle whose values do not fit its message (a plug-in's setpoint of text): nothing of
that cycle is written.

The writer ends at END or at the end of its input. A controller killed with SIGKILL closes the
pipe, so the writer still writes the index and footer: the file is complete up to the last
record the controller handed over. SIGINT and SIGHUP are ignored (a Ctrl-C or a hang-up in the terminal reaches the
whole process group; the controller stops the run and closes the pipe), SIGTERM finishes the
file and exits. Only a killed writer leaves a truncated file (``cheope logs recover``).
"""

from __future__ import annotations

import json
import math
import os
import pickle
import re
import select
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, BinaryIO, TextIO

from logs.cycle_encoding import TASK_FIELDS_AT, with_task_names
from logs.task_values_wire import TaskValuesWire

if TYPE_CHECKING:
    from controller.config import Config
    from controller.core.cycle_data import Event
    from controller.core.linalg3 import Vector3
    from logs.cycle_encoding import CycleValues
    from logs.messages import FrameRecord
    from logs.scene_sampler import SceneFrame, SceneSampler

SETUP, CYCLE, FRAMES, END, KEYFRAME = range(5)
_LENGTH = struct.Struct("<I")
DEFAULT_VIEW_RATE_HZ = 20.0  # /tcp, /tcp_reference of a recording without a configuration
_WRITER_CHUNK_LIMIT = 1 << 40  # chunks are closed by this module, never by mcap's own size rule

Record = tuple[Any, ...]  # (kind, ...): the records listed in the module doc


def pack_record(record: Record) -> bytes:
    body = pickle.dumps(record, pickle.HIGHEST_PROTOCOL)
    return _LENGTH.pack(len(body)) + body


# The pipe is read at most this often: the records of several cycles arrive in one read. Read
# as they came, 400 Hz of cycle records cost a wake-up, a select and a read each, and the
# writer took 13 % of a core. Every 20 ms it took 4.3 and 4.6 % (the contour at 400 Hz, `cheope
# bench`), every 100 ms 3.8 and 3.8 (the same runs alternating): the same records cost the writer
# 70 us each back to back and about 1.5 times that paced at 400 Hz, and a longer batch keeps
# more of them on the caches the batch before warmed. The live views (logs/live_views.py) get
# their frames when their records are read, so with a live view the pipe is read every 20 ms:
# 100 ms would hand a viewer its 20-Hz scene two frames at a time. At 2.5 kB a contour cycle,
# 100 ms at 1 kHz are 250 kB, inside the controller's pipe (``recording.buffer_bytes``, 4 MiB,
# or the system's most).
READ_BATCH_S = 0.1
LIVE_READ_BATCH_S = 0.02


class UnreadableRecordError(ValueError):
    """A record whose bytes do not unpickle here: the recording stops, the file sound (``serve``)."""


class RecordReader:
    """Whole records from a file descriptor; ``next(timeout)`` returns None on timeout, raises EOFError at the end."""

    def __init__(self, fd: int, batch_s: float = READ_BATCH_S) -> None:
        self.fd = fd
        self._buf = bytearray()
        self.batch_s = batch_s
        self._last_read_s = -1.0

    def _take(self) -> Record | None:
        if len(self._buf) < 4:
            return None
        (n,) = _LENGTH.unpack_from(self._buf)
        if len(self._buf) < 4 + n:
            return None
        body = bytes(self._buf[4 : 4 + n])
        del self._buf[: 4 + n]
        try:
            record: Record = pickle.loads(body)
        except Exception as err:  # a value of a class this process cannot import, or no pickle at all
            raise UnreadableRecordError(
                f"a record of {n} bytes could not be read ({type(err).__name__}: {err})"
            ) from err
        return record

    def next(self, timeout_s: float | None) -> Record | None:
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            record = self._take()
            if record is not None:
                return record
            now = time.monotonic()
            pause = self._last_read_s + self.batch_s - now
            if pause > 0.0:  # let more records arrive (READ_BATCH_S)
                time.sleep(pause if deadline is None else max(0.0, min(pause, deadline - now)))
            wait = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _, _ = select.select([self.fd], [], [], wait)
            if not ready:
                return None
            data = os.read(self.fd, 1 << 20)
            self._last_read_s = time.monotonic()
            if not data:
                if self._buf:
                    raise EOFError(f"input ended inside a record ({len(self._buf)} bytes left)")
                raise EOFError("end of input")
            self._buf += data


class SessionWriter:
    """The MCAP side: channels, metadata, chunking; ``write(record)`` for each CYCLE/FRAMES/KEYFRAME record.

    ``notify`` sends a JSON line to the controller (a keyframe request, a new file, a stop).
    """

    def __init__(
        self,
        settings: dict[str, Any],
        notify: Callable[..., None] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        from mcap.writer import CompressionType

        from controller.messages import cheope_pb2 as pb
        from logs import messages as m
        from logs.can_frames_wire import can_frames_bytes

        self.m = m
        self.can_frames_bytes = can_frames_bytes  # /can without upb (logs/can_frames_wire.py)
        self.pb = pb
        self.settings = settings
        self.notify = notify or (lambda **_: None)
        # when chunks close (flush_interval_s); a rewrite at full speed passes the session's clock
        self.clock = clock
        self.first_path = self.path = str(settings["path"])
        self.offset_ns: int = settings["clock_offset_ns"]
        self.chunk_size_bytes: int = settings["chunk_size_bytes"]
        self.flush_interval_s: float = settings["flush_interval_s"]
        self.limits = FileLimits.from_settings(settings)
        self.session_id: str = settings.get("session_id", "")
        self.compression = {
            "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE,
        }[settings["compression"]]
        self.written = 0
        self.chunks = 0
        self.error = ""
        self.stopped = (
            ""  # why the recording stopped with the file sound (free space, a cycle that does not fit)
        )
        self.reported_drops = 0
        self.task_names: tuple[str, ...] | None = None  # the last task fields' names received
        self.task_wire: TaskValuesWire | None = None  # their map entries' bytes (logs/task_values_wire.py)
        self.last_cycle: tuple[int, float] = (0, 0.0)
        self.last_mono_s = 0.0
        self.pending = 0  # bytes in the open chunk
        self.last_flush = clock()
        self.files: list[str] = []
        self.deleted: list[str] = []  # by the retention (recording.keep_total_size_gb)
        self.keyframe_asked_s: float | None = None  # monotonic time of the open request, None when none
        self.file_written = 0
        self._open(self.path, None)
        cfg = _recorded_config(settings)
        self.scene = None if cfg is None else _scene_sampler(cfg)
        # Every cycle's TCP is in /cycle (state.tcp_measured_m, tcp_reference_m); the viewers' own
        # copies follow the 3D scene's rate: at the loop's rate they were a fifth of the file.
        self.view_interval_s = 1.0 / (
            cfg.recording.scene_rate_hz if cfg is not None else DEFAULT_VIEW_RATE_HZ
        )
        self.view_next_t = -math.inf
        self.live = None
        if cfg is not None and (cfg.recording.live_rerun or cfg.recording.live_foxglove):
            from logs.live_views import LiveViews

            live = LiveViews(cfg, self._remote_stop)
            self.live = live if live.active else None
        self.live_can_interval_ns = (
            round(1e9 / cfg.recording.live_can_rate_hz)
            if cfg is not None and cfg.recording.live_can_rate_hz
            else 0
        )
        self.live_frames: list[FrameRecord] = []  # /can live: the frames since its last message
        self.live_can_next_ns = 0
        self.live_can_first_ns = 0
        self.joint_names = _joint_names(self.scene)
        self.joint_velocities = self.m.JointVelocities()
        self._retain()

    def _remote_stop(self) -> tuple[bool, str]:
        """The live Foxglove server's stop service (its thread): the controller's stop, as ``cheope stop``'s."""
        self.notify(command="stop")
        return True, "stop requested: the controller brings the robot to a controlled stop"

    def _open(self, path: str, keyframe: Any) -> None:
        """A new file: header, schemas, channels, the session's metadata and this file's place in
        the session (``cheope.file``), flushed before anything else; then the keyframe, if any."""
        from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
        from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
        from foxglove_schemas_protobuf.Log_pb2 import Log
        from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
        from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
        from mcap.well_known import MessageEncoding
        from mcap.writer import Writer
        from mcap_protobuf.schema import register_schema

        from logs.mcap_append import MessageAppender

        m, pb = self.m, self.pb
        previous = self.files[-1] if self.files else ""
        self.stream: BinaryIO = open(path, "wb")  # noqa: SIM115  (open for the file's life, closed at rotation)
        self.path = path
        self.files.append(path)
        w = Writer(self.stream, chunk_size=_WRITER_CHUNK_LIMIT, compression=self.compression)
        w.start(profile="", library="cheope logs.recorder")
        self.channels: dict[str, int] = {}
        for topic, cls in (
            (m.TOPIC_CAN, pb.CanFrames),
            (m.TOPIC_CYCLE, pb.Cycle),
            (m.TOPIC_EVENTS, pb.Event),
            (m.TOPIC_LOG, Log),
            (m.TOPIC_TCP, FrameTransform),
            (m.TOPIC_TCP_REFERENCE, PoseInFrame),
            (m.TOPIC_SCENE, SceneUpdate),
            (m.TOPIC_JOINT_STATES, JointStates),
            (m.TOPIC_KEYFRAME, pb.Keyframe),
        ):
            sid = register_schema(w, cls)
            self.channels[topic] = w.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=sid
            )
        for name, data in self.settings["metadata"].items():
            w.add_metadata(name, data)
        w.add_metadata(
            m.META_FILE,
            {
                "session_id": self.session_id,
                "sequence": str(len(self.files)),
                "previous": os.path.basename(previous),
            },
        )
        self.writer = w
        self.append = MessageAppender(w).add  # w.add_message, one pack a message (logs/mcap_append.py)
        self.file_written = 0
        self.pending = 0  # the last file's open chunk was closed with it
        if keyframe is not None:
            self._add(m.TOPIC_KEYFRAME, keyframe[0], keyframe[1])
            self.writer.flush()  # the keyframe in a chunk of its own: a file cut short still has it
        self.stream.flush()  # the configuration first: it survives anything that follows
        self.file_bytes = self.stream.tell()  # then after each chunk (maybe_flush)

    # -- records -----------------------------------------------------------------------------

    def write(self, record: Record) -> None:
        if self.error or self.stopped:
            return  # keep reading: the loop must never find the pipe full because the disk failed
        try:
            if record[0] == CYCLE:
                _, _, frames, cycle, t, mono_s, seq, values, events, tcp_measured, tcp_reference = record
                cycle_pb = self._cycle_pb(cycle, values)
                if cycle_pb is None:
                    return
                self.pending += self._frames(frames) + self._cycle(
                    cycle, t, mono_s, seq, cycle_pb, events, tcp_measured, tcp_reference
                )
                self._ask_keyframe_when_due()
            elif record[0] == FRAMES:
                self.pending += self._frames(record[2])
            elif record[0] == KEYFRAME:
                self._rotate(*record[2:])
            if record[1] != self.reported_drops:
                self.pending += self._report_drops(record[1])
            self.maybe_flush()
        except (OSError, ValueError) as err:
            self._fail(f"writing {self.path} failed: {err}")

    def _ask_keyframe_when_due(self) -> None:
        """Past the size limit, ask the controller for its state (again after a second: it may have
        been dropped); the file goes on until the keyframe comes. (The duration limit is the
        recorder's: it knows the time without asking.) The file's size is read after each chunk
        (``maybe_flush``), the only time it grows; a ``tell`` here, once a cycle, was a system
        call and 12 % of the writer's samples in a profile (issue 37)."""
        if not self.limits.max_file_bytes or self.file_bytes < self.limits.max_file_bytes:
            return
        now = self.clock()
        if self.keyframe_asked_s is None or now - self.keyframe_asked_s >= KEYFRAME_RETRY_S:
            self.keyframe_asked_s = now
            self.notify(keyframe=len(self.files) + 1)

    def _rotate(
        self, cycle: int, t: float, mono_s: float, seq: int, encoding: str, state: bytes, problem: str
    ) -> None:
        """Close this file, open the session's next one with the keyframe: the state after ``cycle``."""
        self.keyframe_asked_s = None
        ns = self.m.unix_time_ns_of(mono_s, self.offset_ns)
        if problem:
            self._event(
                "keyframe_missing",
                f"the controller's state could not be recorded: {problem}; "
                "the next file cannot be verified alone",
                warning=True,
            )
        keyframe = self.pb.Keyframe(cycle=cycle, t_s=t, sequence=seq, encoding=encoding, state=state)
        nxt = next_file_path(self.first_path, len(self.files) + 1)
        self._close_file({"next": os.path.basename(nxt), "complete": "true"})
        try:
            self._open(nxt, (keyframe.SerializeToString(), ns))
        except OSError as err:
            self._fail(f"cannot create the recording's next file {nxt}: {err.strerror or err}")
            return
        self.notify(file=nxt)
        if self.scene is not None:
            self.scene.resend_fixed()  # each file draws the whole robot
        self.view_next_t = -math.inf
        self._retain()

    def _retain(self) -> None:
        """recording.keep_total_size_gb: the oldest recordings of the directory go first, this
        session's earlier files too (each later file starts from a keyframe); never the open one.
        Keeping every file of the session (before) let a service's session of hourly files grow
        past the limit until min_free_space_mb stopped it (an outside tester's finding)."""
        if not self.limits.keep_total_bytes:
            return
        for path, size in enforce_retention(
            os.path.dirname(self.path) or ".", self.limits.keep_total_bytes, {self.path}
        ):
            self.deleted.append(path)
            # ``files`` (the run's summary) names what is still on disk
            self.files = [f for f in self.files if os.path.normpath(f) != os.path.normpath(path)]
            self._event(
                "recording_deleted",
                f"{os.path.basename(path)} ({size / 1e6:.1f} MB) deleted: the "
                f"recordings exceeded recording.keep_total_size_gb = {self.limits.keep_total_bytes / 1e9:.10g}",
            )

    def maybe_flush(self) -> None:
        if self.error or not self.pending:
            return
        if self.pending >= self.chunk_size_bytes or self.clock() - self.last_flush >= self.flush_interval_s:
            try:
                self.writer.flush()
            except (OSError, ValueError) as err:
                self._fail(f"writing {self.path} failed: {err}")
                return
            self.file_bytes = self.stream.tell()
            self.chunks += 1
            self.pending = 0
            self.last_flush = self.clock()
            self._guard_free_space()
            self._guard_removed()

    def _guard_removed(self) -> None:
        """A file removed while it is written (its directory deleted) takes every later byte into
        nothing: the recording stops, named, and ``recording.on_failure`` decides. Before, the
        run ended DONE, exit 0, its summary naming a file that no longer existed (an outside
        tester's finding). One ``fstat`` a chunk."""
        if self.stopped:
            return
        try:
            removed = os.fstat(self.stream.fileno()).st_nlink == 0
        except (OSError, ValueError):
            return
        if removed:
            self.stop(f"{self.path} was removed while it was written: recording stopped")

    def _guard_free_space(self) -> None:
        """Below recording.min_free_space_mb the recording stops, the file closed cleanly while it can be."""
        if not self.limits.min_free_bytes or self.stopped:
            return
        free = free_bytes(self.path)
        if free is None or free >= self.limits.min_free_bytes:
            return
        self.stop(
            f"free space on the file system of {self.path} is {free / 1e6:.1f} MB, below "
            f"recording.min_free_space_mb = {self.limits.min_free_bytes / 1e6:.10g}: recording stopped"
        )

    def stop(self, why: str) -> None:
        """Stop recording, the file sound: ``why`` on /events and to the controller, whose next write
        then fails and whose ``recording.on_failure`` decides (``serve`` closes the input)."""
        self.stopped = why
        self._event("recording_stopped", why, warning=True)
        print(f"recording stopped: {why}", file=sys.stderr, flush=True)
        self.notify(stopped=why)

    def _cycle_pb(self, cycle: int, values: CycleValues) -> bytes | None:
        """The cycle's ``/cycle`` message, built here and not on the loop's thread; None, and the
        recording stopped, when its values do not fit it (a plug-in's setpoint of text): nothing of
        that cycle is written, and the file stays complete up to the cycle before."""
        try:
            return self.m.cycle_bytes(self._named(values), self.task_wire)
        except (TypeError, ValueError, OverflowError) as err:
            self.stop(f"cycle {cycle} cannot be recorded ({type(err).__name__}: {err}): recording stopped")
            return None

    def _named(self, values: CycleValues) -> CycleValues:
        """``values`` with its task fields' names, the last ones sent when it has None."""
        fields = values[TASK_FIELDS_AT]
        if fields is None:
            return values
        names: tuple[str, ...] | None = fields[0]  # type: ignore[index]
        if names is not None:
            self.task_names = names
            if self.task_wire is None or self.task_wire.names != names:  # laid out once per names
                self.task_wire = TaskValuesWire(names)
            return values
        if self.task_names is None:
            raise ValueError("task values without their names, and no names received before")
        return with_task_names(values, self.task_names)

    def finish(self, queued: int | None, dropped: int) -> None:
        """The drop count, ``cheope.recording``, the index and the footer; closes the file."""
        if not self.error and dropped != self.reported_drops:
            try:
                self._report_drops(dropped)
            except (OSError, ValueError) as err:
                self._fail(f"cannot finish {self.path}: {err}")
        self._close_file(
            {
                "queued": "unknown" if queued is None else str(queued),
                "dropped": str(dropped),
                "complete": "true",
                **({"stopped": self.stopped} if self.stopped else {}),
                # no END after a stop is the writer's doing (it stopped reading), not the controller's
                **(
                    {}
                    if queued is not None or self.stopped
                    else {"ended": "the controller closed the pipe without END"}
                ),
            }
        )

    def _close_file(self, recording: dict[str, str]) -> None:
        """``cheope.recording`` (this file's count, the session's so far), the index, the footer."""
        try:
            if not self.error:
                self.writer.add_metadata(
                    self.m.META_RECORDING,
                    {"written": str(self.written), "file_written": str(self.file_written), **recording},
                )
                self.writer.finish()
        except (OSError, ValueError) as err:
            self._fail(f"cannot finish {self.path}: {err}")
        finally:
            try:
                self.stream.close()
            except OSError as err:
                self.error = self.error or f"cannot close {self.path}: {err}"

    def _event(self, kind: str, message: str, warning: bool = False) -> None:
        """The recorder's own event on /events and /log, at the last cycle; its kind one of
        ``messages.RECORDER_EVENT_KINDS``, which a replay does not compare as the law's."""
        from controller.core.cycle_data import Event, Severity

        cycle, t = self.last_cycle
        e = Event(kind, Severity.WARNING if warning else Severity.INFO, message)
        ns = self.m.unix_time_ns_of(self.last_mono_s, self.offset_ns)
        self.pending += self._add(
            self.m.TOPIC_EVENTS, self.m.event_to_pb(cycle, t, e).SerializeToString(), ns
        ) + self._add(self.m.TOPIC_LOG, self.m.event_to_log(ns, e).SerializeToString(), ns)

    # -- conversions -------------------------------------------------------------------------

    def _fail(self, message: str) -> None:
        self.error = message
        print(f"recording stopped: {message}", file=sys.stderr, flush=True)
        # before ``serve`` stops reading: the controller's write then fails (EPIPE), and its summary
        # names this (a full disk), not the broken pipe it met
        self.notify(stopped=message)

    def _add(self, topic: str, data: bytes, unix_ns: int, sequence: int = 0) -> int:
        added = self.append(self.channels[topic], unix_ns, data, unix_ns, sequence)
        self.written += 1
        self.file_written += 1
        return added

    def _frames(self, frames: list[FrameRecord]) -> int:
        """The frames as one ``CanFrames`` (one MCAP message, one index entry, for all of them)."""
        if not frames:
            return 0
        batch = self.can_frames_bytes(frames, self.offset_ns)
        self.last_mono_s = frames[-1][1]
        ns = self.m.unix_time_ns_of(frames[0][1], self.offset_ns)
        if self.live is not None and self.live_can_interval_ns:
            self._live_can(frames, ns)
        return self._add(self.m.TOPIC_CAN, batch, ns)

    def _live_can(self, frames: list[FrameRecord], ns: int) -> None:
        """``/can`` live: the frames gathered since the last message, at most ``live_can_rate_hz``."""
        if not self.live_frames:
            self.live_can_first_ns = ns  # the message's log time: its first frame's
        self.live_frames += frames
        if ns >= self.live_can_next_ns:
            assert self.live is not None
            self.live.can(
                self.can_frames_bytes(self.live_frames, self.offset_ns),
                self.live_can_first_ns,
            )
            self.live_frames = []
            self.live_can_next_ns = ns + self.live_can_interval_ns

    def _cycle(
        self,
        cycle: int,
        t: float,
        mono_s: float,
        seq: int,
        cycle_pb: bytes,
        events: tuple[Event, ...],
        tcp_measured: Vector3 | None,
        tcp_reference: Vector3 | None,
    ) -> int:
        m = self.m
        ns = self.m.unix_time_ns_of(mono_s, self.offset_ns)
        self.last_cycle = (cycle, t)
        self.last_mono_s = mono_s
        n = self._add(m.TOPIC_CYCLE, cycle_pb, ns, seq)
        for e in events:
            event_pb = m.event_to_pb(cycle, t, e).SerializeToString()
            n += self._add(m.TOPIC_EVENTS, event_pb, ns)
            log_pb = m.event_to_log(ns, e).SerializeToString()
            n += self._add(m.TOPIC_LOG, log_pb, ns)
            if self.live is not None:
                self.live.event(t, cycle, int(e.severity), f"[{e.kind}] {e.message}", log_pb, event_pb, ns)
        frame = None
        if self.scene is not None:
            n_scene, frame = self._scene(cycle_pb, t, ns)
            n += n_scene
            due = frame is not None  # the viewers' TCP with the 3D scene, on the same cycles
        else:
            due = t >= self.view_next_t
            if due:
                nxt = self.view_next_t + self.view_interval_s
                self.view_next_t = nxt if nxt > t else t + self.view_interval_s  # the first, or after a gap
        tcp_pb = None
        if due:  # /tcp and /tcp_reference for viewers, at the scene's rate
            if tcp_measured is not None:
                tcp_pb = m.tcp_transform(ns, tcp_measured).SerializeToString()
                n += self._add(m.TOPIC_TCP, tcp_pb, ns)
            if tcp_reference is not None:
                n += self._add(m.TOPIC_TCP_REFERENCE, m.tcp_pose(ns, tcp_reference).SerializeToString(), ns)
        if frame is not None:  # the joints by the robot's names, with the 3D scene's rate
            joints_pb = self.m.joint_states(
                ns,
                self.joint_names,
                positions := tuple(d.position for d in frame.message.inputs.drives),
                self.joint_velocities.update(ns, positions),
                self.m.recorded_efforts(frame.message.inputs.drives),
            ).SerializeToString()
            n += self._add(m.TOPIC_JOINT_STATES, joints_pb, ns)
            if self.live is not None:
                self.live.joint_states(joints_pb, ns)
        if frame is not None and self.live is not None:
            self.live.frame(frame, frame.message, cycle_pb, frame.scene_pb, tcp_pb, ns)
        return n

    def _scene(self, cycle_pb: bytes, t: float, ns: int) -> tuple[int, SceneFrame | None]:
        """The robot for Foxglove: the fixed parts once, the moving ones when the sampler says
        (decimated); the bytes written and the frame drawn, if any (the live views get it too,
        logs/live_views.py)."""
        from logs.foxglove_scene import scene_update

        assert self.scene is not None
        n = 0
        fixed = self.scene.fixed_once()
        if fixed is not None:
            data = scene_update(fixed, ns).SerializeToString()
            n += self._add(self.m.TOPIC_SCENE, data, ns)
            if self.live is not None:
                self.live.fixed(fixed, data, ns)
        frame = self.scene.sample(cycle_pb, t)
        if frame is not None:
            frame.scene_pb = scene_update(
                frame.moving, ns, tuple(sorted(self.scene.moving_entities - frame.kept))
            ).SerializeToString()
            n += self._add(self.m.TOPIC_SCENE, frame.scene_pb, ns)
        return n, frame

    def _report_drops(self, dropped: int) -> int:
        from controller.core.cycle_data import Event, Severity

        new = dropped - self.reported_drops
        self.reported_drops = dropped
        cycle, t = self.last_cycle
        e = Event(
            "recorder_drop",
            Severity.WARNING,
            f"recorder queue full: {new} item(s) dropped after cycle {cycle} ({dropped} in total)",
        )
        ns = self.m.unix_time_ns_of(self.last_mono_s, self.offset_ns)
        return self._add(
            self.m.TOPIC_EVENTS, self.m.event_to_pb(cycle, t, e).SerializeToString(), ns
        ) + self._add(self.m.TOPIC_LOG, self.m.event_to_log(ns, e).SerializeToString(), ns)


KEYFRAME_RETRY_S = 1.0
_RECORDING_NAME = re.compile(r"^cheope-\d{8}-\d{6}(-\d+)?(\.\d{3,})?\.mcap$")
# A file written to this recently may be another recorder's open file: retention leaves it.
OPEN_FILE_AGE_S = 120.0


@dataclass(frozen=True)
class FileLimits:
    """recording.max_file_size_mb, max_file_duration_s, keep_total_size_gb, min_free_space_mb (0: none)."""

    max_file_bytes: int = 0
    max_file_duration_s: float = 0.0
    keep_total_bytes: int = 0
    min_free_bytes: int = 0

    @classmethod
    def from_settings(cls, settings: dict[str, Any]) -> FileLimits:
        return cls(
            int(settings.get("max_file_bytes", 0)),
            float(settings.get("max_file_duration_s", 0.0)),
            int(settings.get("keep_total_bytes", 0)),
            int(settings.get("min_free_bytes", 0)),
        )


def next_file_path(first: str, sequence: int) -> str:
    """The session's file number ``sequence`` (2, 3...): beside the first, ``NAME.002.mcap``."""
    root, ext = os.path.splitext(first)
    return f"{root}.{sequence:03d}{ext}"


def free_bytes(path: str) -> int | None:
    """Free space for unprivileged writers on ``path``'s file system; None when it cannot be known."""
    try:
        st = os.statvfs(os.path.dirname(path) or ".")
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def enforce_retention(
    directory: str, keep_bytes: int, open_paths: set[str], now: float | None = None
) -> list[tuple[str, int]]:
    """Delete the oldest recordings (``cheope-*.mcap`` as the recorder names them) in ``directory``
    until they total at most ``keep_bytes``; never one of ``open_paths`` nor one written to in the
    last ``OPEN_FILE_AGE_S`` (another controller's open file). Returns (path, size) deleted."""
    now = time.time() if now is None else now
    files = []
    try:
        with os.scandir(directory) as it:
            for e in it:
                if _RECORDING_NAME.match(e.name) and e.is_file(follow_symlinks=False):
                    st = e.stat(follow_symlinks=False)
                    files.append((st.st_mtime, e.name, e.path, st.st_size))
    except OSError:
        return []
    total = sum(f[3] for f in files)
    deleted = []
    keep = {os.path.abspath(p) for p in open_paths}
    for mtime, _, path, size in sorted(files):
        if total <= keep_bytes:
            break
        if os.path.abspath(path) in keep or now - mtime < OPEN_FILE_AGE_S:
            continue
        try:
            os.unlink(path)
        except OSError:
            continue
        total -= size
        deleted.append((path, size))
    return deleted


def _joint_names(scene: SceneSampler | None) -> tuple[str, ...]:
    """The robot's actuated joints' names (its drawing's: as the ROS 2 bridge names them), or none."""
    from logs.robot_drawing import JointedDrawing

    drawing = scene.drawing if scene is not None else None
    return tuple(j.name for j in drawing.actuated_joints()) if isinstance(drawing, JointedDrawing) else ()


def _recorded_config(settings: dict[str, Any]) -> Config | None:
    """The session's configuration from the metadata; None without one (then no 3D scene)."""
    from controller.config import ConfigError, recorded_config_from_dict
    from logs import messages as m

    meta = settings["metadata"].get(m.META_CONFIG)
    if meta is None:
        return None
    try:
        return recorded_config_from_dict(json.loads(meta["json"]))
    except (ConfigError, ValueError, KeyError) as err:
        print(f"recording without the 3D scene: {err}", file=sys.stderr, flush=True)
        return None


def _scene_sampler(cfg: Config) -> SceneSampler | None:
    """The drawing of the recorded robot; None for a robot without one."""
    from logs.scene_sampler import SceneSampler

    try:
        return SceneSampler.for_config(cfg, cfg.recording.scene_rate_hz)
    except ValueError as err:
        print(f"recording without the 3D scene: {err}", file=sys.stderr, flush=True)
        return None


_REPLY_LOCK = threading.Lock()  # the live Foxglove server's stop comes on the SDK's thread


def _reply(out: TextIO, **fields: object) -> None:
    """One JSON line to the controller; nothing when it is gone (killed: the file is finished all the same)."""
    with _REPLY_LOCK:
        _write_line(out, fields)


def _write_line(out: TextIO, fields: dict[str, object]) -> None:
    try:
        out.write(json.dumps(fields) + "\n")
        out.flush()
    except BrokenPipeError:
        # no reader: point stdout at /dev/null so that the interpreter's own flush at exit does
        # not print a BrokenPipeError traceback either
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, out.fileno())
        os.close(devnull)


def serve(fd: int, out: TextIO) -> int:
    """Read SETUP, write the file until END or the end of input; returns the exit status."""
    # The controller stops the run on each of these and closes the pipe, and the writer then
    # finishes the file with the stop's last cycles. Sent to the controller's whole process group
    # (a terminal's Ctrl-C, `kill -TERM -- -PGID`, GNU timeout, systemd's default KillMode), a
    # SIGTERM that ended the writer at once had the controller's next write meet a closed pipe:
    # "DONE, but the recording was lost" (exit 3) of a complete file. The writer ends with its
    # input (the controller gone, however it ended), or by SIGKILL.
    for signum in (signal.SIGINT, signal.SIGHUP, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    reader = RecordReader(fd)
    try:
        setup = reader.next(None)
    except EOFError:
        return 1
    if setup is None or setup[0] != SETUP:
        _reply(out, error=f"the first record must be SETUP, got {setup!r:.80}")
        return 1
    try:
        writer = SessionWriter(setup[1], lambda **fields: _reply(out, **fields))
    except OSError as err:
        _reply(out, error=f"cannot create the recording {setup[1].get('path')}: {err.strerror or err}")
        return 1
    if writer.live is not None:
        reader.batch_s = LIVE_READ_BATCH_S
    _reply(out, ready=str(writer.path))
    queued: int | None = None
    dropped = 0
    while True:
        try:
            record = reader.next(writer.flush_interval_s / 2)
        except EOFError:  # the controller is gone; a record it was cut off in is lost
            break
        except UnreadableRecordError as err:
            writer.stop(f"{err}: recording stopped")
            break
        if record is None:
            writer.maybe_flush()  # a quiet loop still gets its last messages on disk in time
            if writer.error:
                break
            continue
        if record[0] == END:
            queued, dropped = record[1], record[2]
            break
        dropped = record[1]
        writer.write(record)
        if writer.stopped:
            # the free-space guard: the file is closed cleanly, and the controller's next write
            # fails at once (EPIPE) so that its recording.on_failure decides, with the reason it was sent
            break
        if writer.error:
            # stop reading: the controller's next write fails (EPIPE) and its recording.on_failure
            # policy decides, instead of the loop running on with a recording that only looks alive
            break
    if writer.stopped:
        os.close(fd)
    writer.finish(queued, dropped)
    global _VIEWS_LEFT_OPEN
    _VIEWS_LEFT_OPEN = writer.live is not None and not writer.live.close()
    _reply(
        out,
        written=writer.written,
        chunks=writer.chunks,
        error=writer.error or writer.stopped,
        files=writer.files,
        deleted=writer.deleted,
    )
    return 0 if not writer.error else 2


# A live view that did not close (a viewer that takes no data) keeps the process from exiting:
# rerun's exit handler waits for that viewer without end. The file is finished and the answer
# sent by then, so the process ends without the exit handlers.
_VIEWS_LEFT_OPEN = False


if __name__ == "__main__":
    code = serve(sys.stdin.buffer.fileno(), sys.stdout)
    if _VIEWS_LEFT_OPEN:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
