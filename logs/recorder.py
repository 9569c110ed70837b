"""The session recorder: one MCAP file per session, written on its own thread.

The loop thread only hands over references (``on_cycle``) or a copy of a frame's id, bytes
and flags (``on_frame``, the exchange's ``FrameSink``) with ``queue.Queue.put_nowait``: a few
microseconds, never a wait. A full queue drops the item and counts it; the writer thread
reports every new drop as a ``recorder_drop`` event on ``/events`` and the total in the
``cheope.recording`` metadata written at close. The writer thread converts to Protobuf,
writes, and every ``chunk_size_bytes`` of messages or ``flush_interval_s`` closes the MCAP
chunk and flushes the file to the operating system: a controller killed with SIGKILL leaves a
file whose every flushed chunk is readable (``logs.recovery`` makes it a complete file).

Usage::

    with SessionRecorder.for_config(cfg) as rec:      # or SessionRecorder(path, metadata=...)
        loop = CycleLoop(..., observers=(rec,))
        exchange = CyclicExchange(..., frame_sink=rec.on_frame)
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import platform
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata as _importlib_metadata
from pathlib import Path
from typing import IO, Any

import can
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from controller.config import Config, config_to_dict
from controller.cycle_data import CycleInputs, CycleOutputs, Event, Severity
from controller.messages import cheope_pb2 as pb
from logs import messages as m

log = logging.getLogger(__name__)

DEFAULT_QUEUE_SIZE = 16384
DEFAULT_CHUNK_SIZE_BYTES = 64 * 1024
DEFAULT_FLUSH_INTERVAL_S = 0.5
_WRITER_CHUNK_LIMIT = 1 << 40  # chunks are closed by this module, never by mcap's own size rule

VERSIONED_PACKAGES = ("cheope-controller", "python-can", "canopen", "ruckig", "numpy", "protobuf", "mcap",
                      "mcap-protobuf-support", "foxglove-schemas-protobuf")

_FRAME, _CYCLE = 0, 1
_STOP = None


class RecordingError(OSError):
    """The recording file cannot be created or written."""


def default_sessions_directory() -> Path:
    """``$XDG_DATA_HOME/cheope/sessions`` (``~/.local/share/cheope/sessions`` when unset)."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "cheope" / "sessions"


def open_session_file(directory: str | Path = "", prefix: str = "cheope", now: _dt.datetime | None = None
                      ) -> tuple[Path, IO[bytes]]:
    """Create ``DIR/PREFIX-YYYYmmdd-HHMMSS.mcap`` (``-2``, ``-3``... if taken) exclusively; '' = the default dir."""
    d = Path(directory) if str(directory) else default_sessions_directory()
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RecordingError(f"cannot create the sessions directory {d}: {err.strerror or err}") from err
    stamp = (now or _dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    for n in range(1, 1000):
        path = d / (f"{prefix}-{stamp}.mcap" if n == 1 else f"{prefix}-{stamp}-{n}.mcap")
        try:
            return path, open(path, "xb")
        except FileExistsError:
            continue
        except OSError as err:
            raise RecordingError(f"cannot create the recording {path}: {err.strerror or err}") from err
    raise RecordingError(f"cannot create a recording in {d}: 999 files named {prefix}-{stamp}*.mcap exist")


def software_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in VERSIONED_PACKAGES:
        try:
            out[name] = _importlib_metadata.version(name)
        except _importlib_metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def session_metadata(cfg: Config, extra: dict[str, str] | None = None) -> dict[str, dict[str, str]]:
    """Configuration, geometry and versions: what ``--verify`` needs to rebuild the same law."""
    table = config_to_dict(cfg)
    return {
        m.META_CONFIG: {"json": json.dumps(table, sort_keys=True)},
        m.META_GEOMETRY: {"robot_kind": cfg.robot.kind, "json": json.dumps(table["robot"], sort_keys=True)},
        m.META_VERSIONS: software_versions(),
        m.META_SESSION: {"period_s": repr(cfg.period_s), "task": cfg.task.kind, **(extra or {})},
    }


@dataclass(frozen=True)
class RecorderCounters:
    queued: int  # items handed over by the loop thread
    dropped: int  # items lost because the queue was full
    written: int  # MCAP messages written
    chunks: int  # flushes that closed a chunk


class SessionRecorder:
    """Loop observer and frame sink that records the session to ``path`` (see the module doc)."""

    def __init__(self, path: str | Path, metadata: dict[str, dict[str, str]] | None = None, *,
                 queue_size: int = DEFAULT_QUEUE_SIZE, chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
                 flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S, clock: Callable[[], float] = time.monotonic,
                 phase_name: Callable[[object], str] | None = None, compression: str = "zstd",
                 stream: IO[bytes] | None = None) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size = {queue_size}: must be >= 1")
        if chunk_size_bytes < 1024:
            raise ValueError(f"chunk_size_bytes = {chunk_size_bytes}: must be >= 1024")
        self.path = Path(path)
        self.metadata = dict(metadata or {})
        self.chunk_size_bytes = chunk_size_bytes
        self.flush_interval_s = flush_interval_s
        self.clock = clock
        self.phase_name = phase_name
        self.compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                            "none": CompressionType.NONE}[compression]
        self._stream = stream
        self._queue: queue.Queue[tuple | None] = queue.Queue(maxsize=queue_size)
        self._put = self._queue.put_nowait
        self._full = queue.Full
        self.queued = 0
        self.dropped = 0
        self._cycle_calls = 0
        self.written = 0
        self.chunks = 0
        self.error: str = ""
        self._thread: threading.Thread | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._offset_ns = 0
        self._last_cycle = (0, 0.0)
        self._reported_drops = 0

    @classmethod
    def for_config(cls, cfg: Config, clock: Callable[[], float] = time.monotonic,
                   phase_name: Callable[[object], str] | None = None,
                   extra_metadata: dict[str, str] | None = None) -> SessionRecorder:
        """A recorder for ``cfg.recording`` (directory, queue, chunks) with the session's metadata."""
        r = cfg.recording
        path, stream = open_session_file(r.directory)
        return cls(path, session_metadata(cfg, extra_metadata), queue_size=r.queue_size,
                   chunk_size_bytes=r.chunk_size_bytes, flush_interval_s=r.flush_interval_s, clock=clock,
                   phase_name=phase_name, stream=stream)

    # -- the loop thread's side: hand over, never wait ----------------------------------------

    def on_cycle(self, cycle: int, t: float, inputs: CycleInputs, state: Any, outputs: CycleOutputs,
                 events: tuple[Event, ...], timing: Any) -> None:
        seq = self._cycle_calls
        self._cycle_calls = seq + 1
        try:
            self._put((_CYCLE, cycle, t, inputs, state, outputs, events, timing, self.clock(), seq))
            self.queued += 1
        except self._full:
            self.dropped += 1

    def on_frame(self, outgoing: bool, monotonic_s: float, msg: can.Message) -> None:
        """``FrameSink``: copies the frame now (the exchange rewrites its outgoing messages)."""
        try:
            self._put((_FRAME, outgoing, monotonic_s, msg.arbitration_id, bytes(msg.data), msg.is_fd,
                       msg.bitrate_switch, msg.is_error_frame))
            self.queued += 1
        except self._full:
            self.dropped += 1

    __call__ = on_frame

    @property
    def counters(self) -> RecorderCounters:
        return RecorderCounters(self.queued, self.dropped, self.written, self.chunks)

    # -- lifecycle ---------------------------------------------------------------------------

    def __enter__(self) -> SessionRecorder:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        try:
            stream = self._stream if self._stream is not None else open(self.path, "wb")
        except OSError as err:
            raise RecordingError(f"cannot create the recording {self.path}: {err.strerror or err}") from err
        self._stream = stream
        self._offset_ns = time.time_ns() - int(self.clock() * 1e9)
        w = Writer(stream, chunk_size=_WRITER_CHUNK_LIMIT, compression=self.compression)
        w.start(profile="", library="cheope logs.recorder")
        for topic, cls in ((m.TOPIC_CAN, pb.CanFrame), (m.TOPIC_CYCLE, pb.Cycle), (m.TOPIC_EVENTS, pb.Event),
                           (m.TOPIC_LOG, m.Log), (m.TOPIC_TCP, m.FrameTransform),
                           (m.TOPIC_TCP_REFERENCE, m.PoseInFrame)):
            sid = register_schema(w, cls)
            self._channels[topic] = w.register_channel(topic=topic, message_encoding=MessageEncoding.Protobuf,
                                                       schema_id=sid)
        session = dict(self.metadata.get(m.META_SESSION, {}))
        session.update(started_utc=_dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds"),
                       clock_offset_ns=str(self._offset_ns), hostname=platform.node())
        self.metadata[m.META_SESSION] = session
        for name, data in self.metadata.items():
            w.add_metadata(name, data)
        stream.flush()
        self._writer = w
        self._thread = threading.Thread(target=self._run, name="mcap-recorder", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Drain the queue, write the drop count, the index and the footer; close the file."""
        t = self._thread
        if t is None:
            return
        while t.is_alive():
            try:
                self._queue.put(_STOP, timeout=0.1)
                break
            except queue.Full:
                continue
        t.join()
        self._thread = None
        w = self._writer
        try:
            if w is not None and not self.error:
                w.add_metadata(m.META_RECORDING, {"queued": str(self.queued), "dropped": str(self.dropped),
                                                  "written": str(self.written), "complete": "true"})
                w.finish()
        except (OSError, ValueError) as err:
            self.error = self.error or f"cannot finish {self.path}: {err}"
        finally:
            try:
                if self._stream is not None:
                    self._stream.close()
            except OSError as err:
                self.error = self.error or f"cannot close {self.path}: {err}"
        if self.error:
            log.warning("recording %s: %s", self.path, self.error)

    # -- the writer thread --------------------------------------------------------------------

    def _run(self) -> None:
        get = self._queue.get
        pending = 0
        last_flush = time.monotonic()
        while True:
            timeout = max(0.0, last_flush + self.flush_interval_s - time.monotonic())
            try:
                item = get(timeout=timeout) if pending else get()
            except queue.Empty:
                item = ()
            if item is _STOP:
                break
            if self.error:
                continue  # keep draining: the loop must never find the queue full because the disk failed
            try:
                if item:
                    pending += self._write_item(item)
                if self.dropped != self._reported_drops:
                    pending += self._report_drops()
                if pending and (pending >= self.chunk_size_bytes
                                or time.monotonic() - last_flush >= self.flush_interval_s):
                    self._writer.flush()  # type: ignore[union-attr]
                    self.chunks += 1
                    pending = 0
                    last_flush = time.monotonic()
            except (OSError, ValueError) as err:
                self.error = f"writing {self.path} failed: {err}"
                log.error("recording stopped: %s", self.error)
        if self.dropped != self._reported_drops and not self.error:
            self._report_drops()

    def _add(self, topic: str, msg: Any, unix_ns: int, sequence: int = 0) -> int:
        data = msg.SerializeToString()
        self._writer.add_message(self._channels[topic], unix_ns, data, unix_ns, sequence)  # type: ignore[union-attr]
        self.written += 1
        return len(data) + 31  # record overhead in the chunk

    def _write_item(self, item: tuple) -> int:
        if item[0] == _FRAME:
            _, outgoing, mono_s, arb, data, fd, brs, err = item
            msg = m.can_frame(mono_s, outgoing, arb, data, fd, brs, err)
            return self._add(m.TOPIC_CAN, msg, int(mono_s * 1e9) + self._offset_ns)
        _, cycle, t, inputs, state, outputs, events, timing, mono_s, seq = item
        ns = int(mono_s * 1e9) + self._offset_ns
        self._last_cycle = (cycle, t)
        n = self._add(m.TOPIC_CYCLE, m.cycle_to_pb(cycle, t, inputs, state, outputs, timing, self.phase_name),
                      ns, seq)
        for e in events:
            n += self._add(m.TOPIC_EVENTS, m.event_to_pb(cycle, t, e), ns)
            n += self._add(m.TOPIC_LOG, m.event_to_log(ns, e), ns)
        if state.tcp_measured_m is not None:
            n += self._add(m.TOPIC_TCP, m.tcp_transform(ns, state.tcp_measured_m), ns)
        if state.tcp_reference_m is not None:
            n += self._add(m.TOPIC_TCP_REFERENCE, m.tcp_pose(ns, state.tcp_reference_m), ns)
        return n

    def _report_drops(self) -> int:
        dropped = self.dropped
        new = dropped - self._reported_drops
        self._reported_drops = dropped
        cycle, t = self._last_cycle
        e = Event("recorder_drop", Severity.WARNING,
                  f"recorder queue full: {new} item(s) dropped after cycle {cycle} ({dropped} in total)")
        ns = int(self.clock() * 1e9) + self._offset_ns
        return self._add(m.TOPIC_EVENTS, m.event_to_pb(cycle, t, e), ns) + self._add(m.TOPIC_LOG, m.event_to_log(ns, e), ns)
