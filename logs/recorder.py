"""The session recorder: one MCAP file per session, written by its own process.

The loop thread turns a cycle into bytes (one pickled tuple: the cycle's values,
logs/cycle_encoding.py, its CAN frames, events and TCP points; ``pytest
tests/integration/test_recording.py -k large_buffer -s`` prints its cost) and writes them to a pipe
with one non-blocking ``write``; it never waits. What the pipe cannot take waits in a bounded
backlog; beyond ``buffer_bytes`` the item is dropped and counted. The writer process
(logs/session_writer.py, ``python -m logs.session_writer``) builds the ``/cycle`` Protobuf from
those values and the other messages, writes the MCAP file and every ``chunk_size_bytes`` of messages or ``flush_interval_s`` closes the
chunk and flushes the file to the operating system. It reports every new drop as a
``recorder_drop`` event on ``/events`` and the totals in the ``cheope.recording`` metadata
written at close. A controller killed with SIGKILL closes the pipe and the writer still
finishes the file; a killed writer leaves a file whose every flushed chunk is readable
(``logs.recovery`` makes it complete).

``lossless=True`` (simulated time, tests) makes the write wait instead of dropping: there is
no deadline to keep, and a deterministic run must record every cycle.

Usage::

    with SessionRecorder.for_config(cfg) as rec:      # or SessionRecorder(path, metadata=...)
        loop = CycleLoop(..., observers=(rec,))
        exchange = CyclicExchange(..., frame_sink=rec.on_frame)
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import fcntl
import json
import logging
import os
import platform
import select
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata as _importlib_metadata
from pathlib import Path
from typing import IO, Any, Self

import can

from controller.config import Config, config_to_dict
from controller.errors import DeviceError
from drivers.pacing import wall_clock_offset_ns
from logs import messages as m
from logs.cycle_encoding import cycle_values, without_sent_names
from logs.keyframe import ENCODING as STATE_ENCODING
from logs.keyframe import KeyframeError, encode_state
from logs.messages import FrameRecord, frame_record
from logs.session_writer import CYCLE, END, FRAMES, KEYFRAME, SETUP, FileLimits, free_bytes, pack_record

log = logging.getLogger(__name__)

DEFAULT_BUFFER_BYTES = 4 << 20  # about 4 s of a 1 kHz session in the backlog, as much again in the pipe
DEFAULT_CHUNK_SIZE_BYTES = 1024 * 1024  # at 400 Hz flush_interval_s closes the chunk first (about 600 kB)
DEFAULT_FLUSH_INTERVAL_S = 2.0
# The wait ends on the writer's reply; the bound is for an emulated CPU (the vcan VM), where the
# writer's imports (the scene drawing, the schemas) took longer than 20 s.
WRITER_START_TIMEOUT_S = 120.0
# At close: the writer took no data, or gave no answer, this long. Writing a chunk or the summary
# takes it seconds at most, even on the emulated CPU of the vcan VM; it was 120 s, and a writer
# stopped at the end of a demo held its exit 259 s (two waits in series, an outside tester's).
WRITER_FINISH_TIMEOUT_S = 30.0
# A writer that takes nothing while the backlog overflows (a hung disk, a stopped process) for this
# long is gone: the service's recording.on_failure decides. Items had been dropped for seconds by
# then (the backlog holds about 4 s at 1 kHz); an outside tester's writer stopped for 30 s lost 40 %
# of a run with no error, exit 0.
WRITER_STALL_S = 5.0
STALLED_WRITER_ANSWER_S = 2.0  # at close, a stalled writer's final answer is waited for this long
NO_FILE_LIMITS = FileLimits()  # one file, however long; no retention, no free-space guard
REPLY_POLL_CYCLES = 16  # the writer's notices are looked at every this many cycles (a select, no wait)
_MAX_FRAMES_PER_RECORD = 256  # frames with no cycle after them (node set-up, shutdown) go out in batches
_REPO = str(Path(__file__).resolve().parents[1])  # the writer process imports the same code as this one

VERSIONED_PACKAGES = (
    "cheope-controller",
    "python-can",
    "canopen",
    "ruckig",
    "numpy",
    "protobuf",
    "mcap",
    "mcap-protobuf-support",
    "foxglove-schemas-protobuf",
)


class RecordingError(DeviceError, OSError):
    """The recording file cannot be created or written."""


def default_sessions_directory() -> Path:
    """``$XDG_DATA_HOME/cheope/sessions`` (``~/.local/share/cheope/sessions`` when unset)."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "cheope" / "sessions"


def open_session_file(
    directory: str | Path = "", prefix: str = "cheope", now: _dt.datetime | None = None
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


def _is_answer(reply: dict[str, Any]) -> bool:
    """The writer's answer to SETUP or to the end, as opposed to a notice on the way."""
    return bool({"ready", "error", "written"} & reply.keys())


def file_limits(cfg: Config) -> FileLimits:
    """recording.max_file_size_mb, max_file_duration_s, keep_total_size_gb, min_free_space_mb in bytes and seconds."""
    r = cfg.recording
    return FileLimits(
        int(r.max_file_size_mb * 1e6),
        r.max_file_duration_s,
        int(r.keep_total_size_gb * 1e9),
        int(r.min_free_space_mb * 1e6),
    )


@dataclass(frozen=True)
class RecorderCounters:
    queued: int  # items handed over by the loop thread
    dropped: int  # items lost because the queue was full
    written: int | None  # MCAP messages written; None: the writer did not say (it never answered)
    chunks: int  # flushes that closed a chunk


class SessionRecorder:
    """Loop observer and frame sink that records the session to ``path`` (see the module doc)."""

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, dict[str, str]] | None = None,
        *,
        buffer_bytes: int = DEFAULT_BUFFER_BYTES,
        chunk_size_bytes: int = DEFAULT_CHUNK_SIZE_BYTES,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
        phase_name: Callable[[object], str] | None = None,
        compression: str = "zstd",
        lossless: bool = False,
        on_failure: Callable[[str], None] | None = None,
        limits: FileLimits = NO_FILE_LIMITS,
    ) -> None:
        if buffer_bytes < 4096:
            raise ValueError(f"buffer_bytes = {buffer_bytes}: must be >= 4096")
        if chunk_size_bytes < 1024:
            raise ValueError(f"chunk_size_bytes = {chunk_size_bytes}: must be >= 1024")
        if compression not in ("zstd", "lz4", "none"):
            raise ValueError(f"compression = {compression!r}: must be zstd, lz4 or none")
        self.path = Path(path)
        self.metadata = dict(metadata or {})
        self.buffer_bytes = buffer_bytes
        self.chunk_size_bytes = chunk_size_bytes
        self.flush_interval_s = flush_interval_s
        self.clock = clock
        self.phase_name = phase_name
        self.compression = compression
        self.lossless = lossless
        self.limits = limits
        self.session_id = uuid.uuid4().hex  # in every file's cheope.file metadata: the files of one session
        self.files: list[Path] = [self.path]  # the session's files so far (rotation adds to it)
        self.deleted: list[Path] = []  # recordings the retention deleted (known at close)
        self.queued = 0
        self.dropped = 0
        self.written: int | None = 0  # known when the writer has finished (close); None: it did not say
        self.chunks = 0
        self.error: str = ""
        # called once, on the loop's thread, when the writer is gone (the service's recording.on_failure)
        self.on_failure = on_failure
        # called on the loop's thread when a live view asked for a stop (the live Foxglove server's
        # stop service, logs/live_views.py): the service's stop, as a remote ``cheope stop``
        self.on_remote_stop: Callable[[], None] | None = None
        self.first_lost_cycle: tuple[int, float] | None = None  # (cycle, t) of the first cycle not recorded
        self._last_cycle: tuple[int, float] = (0, 0.0)
        self._cycle_calls = 0
        self._task_names_sent: tuple[str, ...] | None = None  # the task fields' names the writer has
        self._frames: list[FrameRecord] = []
        self._backlog = bytearray()
        self._backlog_items = 0  # items with a record (or its tail) in the backlog
        self._progress_s = 0.0  # when the pipe last took data (or the first drop of a stretch began)
        self._writer_stalled = False  # gone by a stall: it will not answer either (close waits briefly)
        self._proc: subprocess.Popen[bytes] | None = None
        self.writer_scheduling = "normal scheduler"  # raise_writer's outcome, for the run's summary
        self._fd = -1
        self._reply_fd = -1  # the writer's standard output: JSON lines
        self._replies = bytearray()
        self._poll_countdown = 0
        self._keyframe_wanted = False
        self._keyframes_sent = 0  # file 1 + this is the file the last keyframe starts
        self._file_start_mono_s: float | None = None  # the open file's first cycle (max_file_duration_s)
        self._writer_said = ""  # why the writer stopped, when it said so before stopping
        self._answers: list[dict[str, Any]] = []  # answers read while looking for notices

    @classmethod
    def for_config(
        cls,
        cfg: Config,
        clock: Callable[[], float] = time.monotonic,
        phase_name: Callable[[object], str] | None = None,
        extra_metadata: dict[str, str] | None = None,
    ) -> SessionRecorder:
        """A recorder for ``cfg.recording`` (directory, buffer, chunks) with the session's metadata."""
        r = cfg.recording
        path, stream = open_session_file(r.directory)  # exclusive: the name is ours
        stream.close()
        limits = file_limits(cfg)
        free = free_bytes(str(path))
        if free is not None and free < limits.min_free_bytes:
            # refused here, before the bus is opened: the writer would stop the run mid-motion at
            # its first chunk (1.6 s into the motion, with 2 MB free against 1024 MB)
            path.unlink(missing_ok=True)
            raise RecordingError(
                f"recording.min_free_space_mb = {r.min_free_space_mb:g}: only {free / 1e6:.1f} MB free on the "
                f"file system of {path.parent}; free space, lower the key, record elsewhere "
                "(recording.directory) or not at all (recording.enabled = false)"
            )
        return cls(
            path,
            session_metadata(cfg, extra_metadata),
            buffer_bytes=r.buffer_bytes,
            chunk_size_bytes=r.chunk_size_bytes,
            flush_interval_s=r.flush_interval_s,
            clock=clock,
            phase_name=phase_name,
            limits=limits,
        )

    # -- the loop thread's side: hand over, never wait ----------------------------------------

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: Any,
        state: Any,
        outputs: Any,
        events: tuple[Any, ...],
        timing: Any,
    ) -> None:
        seq = self._cycle_calls
        self._cycle_calls = seq + 1
        self._last_cycle = (cycle, t)
        frames = self._frames
        self._frames = []
        values = cycle_values(cycle, t, inputs, state, outputs, timing, self.phase_name)
        # 74 names were 1 060 of a contour record's 2 542 bytes (tests/tools/bench_record_pickle.py)
        values, names = without_sent_names(values, self._task_names_sent)
        mono_s = self.clock()
        dropped = self.dropped
        self._send(
            pack_record(
                (
                    CYCLE,
                    self.dropped,
                    frames,
                    cycle,
                    t,
                    mono_s,
                    seq,
                    values,
                    events,
                    state.tcp_measured_m,
                    state.tcp_reference_m,
                )
            ),
            1 + len(frames),
        )
        if names is not None and self.dropped == dropped:  # the writer has them (or will): it reads in order
            self._task_names_sent = names
        self._poll_countdown -= 1
        if self._poll_countdown <= 0:
            self._poll_countdown = REPLY_POLL_CYCLES
            self._poll_replies()
        if self._file_start_mono_s is None:
            self._file_start_mono_s = mono_s
        elif (
            self.limits.max_file_duration_s
            and mono_s - self._file_start_mono_s >= self.limits.max_file_duration_s
        ):
            self._keyframe_wanted = True  # by the controller's clock: simulated time rotates as a real one
        if self._keyframe_wanted:
            self._keyframe_wanted = False
            self._file_start_mono_s = mono_s
            self._send_keyframe(cycle, t, mono_s, seq, state)

    def _send_keyframe(self, cycle: int, t: float, mono_s: float, seq: int, state: Any) -> None:
        """The state after this cycle, for the writer's next file (about 70 µs for the contour task's
        state, once a file)."""
        try:
            data, problem = encode_state(state), ""
        except KeyframeError as err:
            data, problem = b"", str(err)
        except Exception as err:  # a task state's own code (a property) must never end the loop
            data, problem = b"", f"the state could not be read: {type(err).__name__}: {str(err)[:200]}"
        dropped = self.dropped
        self._send(
            pack_record((KEYFRAME, self.dropped, cycle, t, mono_s, seq, STATE_ENCODING, data, problem)), 1
        )
        if self.dropped == dropped:  # a dropped one is asked for again by the writer, and sent then
            self._keyframes_sent += 1

    def _poll_replies(self) -> None:
        """The writer's notices, without waiting: a keyframe request, a new file, why it stopped
        (an answer that arrives with them, its last, is kept for ``_read_reply``)."""
        for reply in self._take_replies(0.0):
            if _is_answer(reply):
                self._answers.append(reply)
            else:
                self._note(reply)

    def _note(self, reply: dict[str, Any]) -> None:
        # {"keyframe": n}: the writer wants to start file n; a keyframe already sent for it (the
        # duration limit came first, or an answer to an earlier request) is not sent twice
        if "keyframe" in reply and int(reply["keyframe"]) > 1 + self._keyframes_sent:
            self._keyframe_wanted = True
        if "file" in reply:
            self.files.append(Path(reply["file"]))
            log.info("recording continues in %s", reply["file"])
        if "stopped" in reply:
            self._writer_said = str(reply["stopped"])
        if reply.get("command") == "stop" and self.on_remote_stop is not None:
            log.info("recording: the live Foxglove server's stop service asked for a stop")
            self.on_remote_stop()

    def on_frame(self, outgoing: bool, monotonic_s: float, msg: can.Message) -> None:
        """``FrameSink``: copies the frame now (the exchange rewrites its outgoing messages)."""
        self._frames.append(frame_record(outgoing, monotonic_s, msg))
        if len(self._frames) >= _MAX_FRAMES_PER_RECORD:
            self._send_frames()

    __call__ = on_frame

    def _send_frames(self) -> None:
        frames = self._frames
        self._frames = []
        self._send(pack_record((FRAMES, self.dropped, frames)), len(frames))

    def _send(self, record: bytes, items: int) -> None:
        """Into the pipe, or the backlog behind it, or dropped when the backlog is full."""
        if self._fd < 0:
            self._lost(items)  # not started, closed, or the writer is gone: nothing to write to
            return
        if self.lossless:
            self._write_all(record)
            self.queued += items
            return
        backlog = self._backlog
        if backlog:
            if len(backlog) + len(record) > self.buffer_bytes:
                self._lost(items)
                record = b""
            else:
                backlog += record
                self._backlog_items += items
            self._write_backlog()
            if record:
                self.queued += items
            elif self._fd >= 0 and time.monotonic() - self._progress_s > WRITER_STALL_S:
                self._writer_stalled = True
                self._writer_gone(
                    TimeoutError(
                        f"the writer process of {self.path} took no data for {WRITER_STALL_S:g} s "
                        "while the backlog was full"
                    )
                )
            return
        try:
            n = os.write(self._fd, record)
        except BlockingIOError:
            n = 0
        except OSError as err:  # the writer died: the service's policy decides (recording.on_failure)
            self._writer_gone(err)
            self._lost(items)
            return
        if n < len(record):  # only a record larger than the pipe's atomic size is cut
            backlog += record[n:]
            self._backlog_items += items
            self._progress_s = time.monotonic()  # the backlog starts: so does the stall's clock
        self.queued += items

    def _write_backlog(self) -> None:
        try:
            n = os.write(self._fd, self._backlog)
        except BlockingIOError:
            return
        except OSError as err:
            self._writer_gone(err)
            return
        if n > 0:
            self._progress_s = time.monotonic()
        del self._backlog[:n]
        if not self._backlog:
            self._backlog_items = 0

    def _write_all(self, data: bytes | bytearray, timeout_s: float | None = None) -> None:
        """All of ``data``, waiting for the writer; with ``timeout_s`` on a non-blocking pipe, until it
        takes no data for that long (a slow disk still finishes)."""
        view = memoryview(data)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while view:
            try:
                view = view[os.write(self._fd, view) :]
                if timeout_s is not None:
                    deadline = time.monotonic() + timeout_s
            except BlockingIOError:
                if deadline is not None and time.monotonic() > deadline:
                    self._writer_stalled = True
                    self._writer_gone(
                        TimeoutError(f"the writer process of {self.path} took no data for {timeout_s:g} s")
                    )
                    return
                select.select([], [self._fd], [], 1.0)
            except OSError as err:
                self._writer_gone(err)
                return

    def _lost(self, items: int) -> None:
        self.dropped += items
        if self.first_lost_cycle is None:
            self.first_lost_cycle = self._last_cycle

    def _writer_gone(self, err: OSError | TimeoutError) -> None:
        first = not self.error
        if first:
            self._poll_replies()  # a writer that stopped on purpose said why before it closed its input
        self.error = (
            self.error
            or self._writer_said
            or (
                str(err)
                if isinstance(err, TimeoutError)
                else f"the writer process of {self.path} stopped reading: {err.strerror or err}"
            )
        )
        if self._backlog_items:  # handed to the backlog, never to the writer
            self.queued -= self._backlog_items
            self._lost(self._backlog_items)
            self._backlog_items = 0
        self._backlog.clear()
        self._fd = -1
        if first and self.on_failure is not None:
            self.on_failure(self.error)

    @property
    def counters(self) -> RecorderCounters:
        return RecorderCounters(self.queued, self.dropped, self.written, self.chunks)

    # -- lifecycle ---------------------------------------------------------------------------

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def raise_writer(self, priority: int) -> str:
        """The writer process's main thread at ``SCHED_FIFO`` ``priority``, so that no normal task can
        starve it (why, and why its main thread only: controller/shell/helper_threads.py); how it
        runs now (``writer_scheduling``). A refusal is logged and the writer runs on as it was."""
        proc = self._proc
        if proc is None or proc.poll() is not None:
            return self.writer_scheduling
        try:
            # reset on fork: what it starts later (a live view's thread or viewer process) starts under
            # the normal scheduler, as those it started before stay
            policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
            os.sched_setscheduler(proc.pid, policy, os.sched_param(priority))
        except OSError as err:
            log.warning("the recording's writer process left under the normal scheduler: %s", err)
            self.writer_scheduling = (
                f"normal scheduler (SCHED_FIFO {priority} refused: {err.strerror or err})"
            )
            return self.writer_scheduling
        self.writer_scheduling = f"SCHED_FIFO {priority}"
        return self.writer_scheduling

    def start(self) -> None:
        """Start the writer process and wait until it has written the header and the metadata."""
        offset_ns = wall_clock_offset_ns(self.clock)
        session = dict(self.metadata.get(m.META_SESSION, {}))
        session.update(
            started_utc=_dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds"),
            clock_offset_ns=str(offset_ns),
            hostname=platform.node(),
            session_id=self.session_id,
        )
        self.metadata[m.META_SESSION] = session
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(p for p in (_REPO, os.environ.get("PYTHONPATH")) if p),
        }
        try:
            proc = subprocess.Popen(
                [sys.executable, "-P", "-m", "logs.session_writer"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                env=env,
            )
        except OSError as err:
            raise RecordingError(f"cannot start the recording's writer process: {err}") from err
        self._proc = proc
        self._task_names_sent = None  # a new writer has none
        assert proc.stdin is not None  # stdin=PIPE
        self._fd = proc.stdin.fileno()
        try:
            fcntl.fcntl(self._fd, fcntl.F_SETPIPE_SZ, self.buffer_bytes)
        except OSError:  # above /proc/sys/fs/pipe-max-size: the largest allowed is tried next
            with contextlib.suppress(OSError, ValueError):
                fcntl.fcntl(self._fd, fcntl.F_SETPIPE_SZ, int(Path("/proc/sys/fs/pipe-max-size").read_text()))
        assert proc.stdout is not None  # stdout=PIPE
        self._reply_fd = proc.stdout.fileno()  # read with os.read only (never the buffered file object)
        lim = self.limits
        self._write_all(
            pack_record(
                (
                    SETUP,
                    {
                        "path": str(self.path),
                        "metadata": self.metadata,
                        "clock_offset_ns": offset_ns,
                        "chunk_size_bytes": self.chunk_size_bytes,
                        "flush_interval_s": self.flush_interval_s,
                        "compression": self.compression,
                        "session_id": self.session_id,
                        "max_file_bytes": lim.max_file_bytes,
                        "max_file_duration_s": lim.max_file_duration_s,
                        "keep_total_bytes": lim.keep_total_bytes,
                        "min_free_bytes": lim.min_free_bytes,
                    },
                )
            )
        )
        reply = self._read_reply(WRITER_START_TIMEOUT_S)
        if "ready" not in reply:
            self._stop_process()
            raise RecordingError(
                reply.get("error") or f"the recording's writer process did not start: {reply}"
            )
        if not self.lossless:
            os.set_blocking(self._fd, False)

    def close(self) -> None:
        """Hand over what is left, then wait for the writer to write the index and the footer."""
        proc = self._proc
        if proc is None:
            return
        if self._frames:
            self._send_frames()
        if self._fd >= 0:  # a writer that stopped reading must not hang the controller's exit
            os.set_blocking(self._fd, False)
            if self._backlog:
                backlog = bytes(self._backlog)
                self._write_all(backlog, WRITER_FINISH_TIMEOUT_S)
                if self._fd >= 0:
                    self._backlog.clear()
                    self._backlog_items = 0
            if self._fd >= 0:
                self._write_all(pack_record((END, self.queued, self.dropped)), WRITER_FINISH_TIMEOUT_S)
        if proc.stdin is not None:
            proc.stdin.close()  # end of input: the writer finishes even if END did not get through
        self._fd = -1
        reply = self._read_reply(STALLED_WRITER_ANSWER_S if self._writer_stalled else WRITER_FINISH_TIMEOUT_S)
        # a writer that never answered wrote an unknown number, not 0 (the file may hold most of the run)
        self.written = int(reply["written"]) if "written" in reply else None
        self.chunks = int(reply.get("chunks", 0))
        self.error = self.error or str(reply.get("error") or "")
        if "files" in reply:
            self.files = [Path(p) for p in reply["files"]]
        self.deleted = [Path(p) for p in reply.get("deleted", ())]
        self._stop_process()
        if self.error:
            log.warning("recording %s: %s", self.path, self.error)

    def _take_replies(self, timeout_s: float) -> list[dict[str, Any]]:
        """The writer's complete JSON lines within ``timeout_s`` (0: what has arrived); [] at its end."""
        fd = self._reply_fd
        if fd < 0:
            return []
        ready, _, _ = select.select([fd], [], [], timeout_s)
        if ready:
            try:
                data = os.read(fd, 1 << 16)
            except OSError:
                data = b""
            if not data:
                self._reply_fd = -1  # the writer closed its output: it has exited
            self._replies += data
        out = []
        while b"\n" in self._replies:
            line, _, rest = bytes(self._replies).partition(b"\n")
            self._replies[:] = rest
            try:
                reply = json.loads(line)
            except ValueError:
                reply = {"error": f"the recording's writer process said {line[:200]!r}"}
            out.append(
                reply if isinstance(reply, dict) else {"error": f"the writer process said {line[:200]!r}"}
            )
        return out

    def _read_reply(self, timeout_s: float) -> dict[str, Any]:
        """The writer's next answer (ready, error or the final count), notices noted on the way."""
        proc = self._proc
        assert proc is not None
        if self._answers:
            return self._answers.pop(0)
        deadline = time.monotonic() + timeout_s
        while True:
            for reply in self._take_replies(max(0.0, deadline - time.monotonic())):
                if _is_answer(reply):
                    return reply
                self._note(reply)
            if self._reply_fd < 0 or time.monotonic() >= deadline:
                status = proc.poll()
                why = "timed out" if status is None else f"exited with status {status}"
                return {"error": f"the recording's writer process {why} (see its message above)"}

    def _stop_process(self) -> None:
        proc = self._proc
        if proc is None:
            return
        self._proc = None
        self._fd = -1
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        try:
            proc.wait(timeout=2.0)  # it has answered, or it never will
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
