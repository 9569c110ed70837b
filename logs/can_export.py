"""``cheope logs export FILE --format asc|blf|log|trc|csv|mf4``: a recording's CAN frames for the usual CAN tools.

Vector CANalyzer/CANoe read ``.asc`` and ``.blf``, can-utils (``canplayer``, ``log2asc``) and
SavvyCAN read candump's ``.log``, PEAK's tools ``.trc``, ASAM MDF tools (asammdf, CANape,
CANalyzer) ``.mf4``; python-can reads every one back (``can.LogReader``). The files are written by
python-can's own writers, so they are what those tools expect from python-can. ``mf4`` needs
asammdf (``pip install 'cheope-controller[mf4]'``, python-can's ``mf4`` extra).

Every recorded frame is written once, in recorded order, with the recording's time (the frame's
``unix_time_ns``: the controller's monotonic reading plus the session's clock offset), so the
timestamps are Unix times and line up with the MCAP's ``log_time``. The direction is the
controller's: a frame it sent is Tx, one it received is Rx.

What a format cannot hold (python-can's writers, version 4.6):

| format | direction | CAN FD | error frames | remote frames | time resolution |
| --- | --- | --- | --- | --- | --- |
| asc | Rx/Tx | yes | yes | yes | 1 us after the first frame; the start to 1 ms (the ``date`` line) |
| blf | the DIR flag | yes | yes | yes | 1 ns after a start truncated to 1 ms |
| log | R/T (``candump -L``) | yes | yes | without their DLC (``#R``) | 1 us |
| trc | Rx/Tx | no: not written | no: not written | no: not written | 1 us (offsets in ms with 3 decimals) |
| csv | no column for it | no flag (length only) | yes | yes | full (``repr`` of the float) |
| mf4 | the Dir channel | yes | yes | yes | float64 seconds after the start (the header's start time) |

A frame the format cannot hold is counted in ``frames_not_written`` by reason, never silently
dropped; the command says so and exits 1.
"""

from __future__ import annotations

import datetime as _dt
import os
import tempfile
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can

from controller import mf4_support
from controller.errors import InputError
from controller.output_paths import publish_new_file, refuse_existing_output
from logs import messages as m
from logs.bus_traffic import RecordedFrame, as_message, recorded_frames
from logs.reader import ReadReport, same_file

FORMATS = ("asc", "blf", "log", "trc", "csv", "mf4")
PROGRESS_EVERY_FRAMES = 2000
NO_DIRECTION = ("csv",)  # python-can's CSV columns have no direction

# The frames each format's python-can writer leaves out (it logs a warning and returns).
_UNWRITABLE: dict[str, tuple[tuple[str, Callable[[RecordedFrame], bool]], ...]] = {
    "trc": (
        ("CAN FD frames (python-can's TRC writer has none)", lambda f: f.is_fd),
        ("error frames (python-can's TRC writer has none)", lambda f: f.is_error_frame),
        ("remote frames (python-can's TRC writer has none)", lambda f: f.is_remote_frame),
    ),
}


class ExportError(InputError):
    """The export cannot be written (unknown format, output not writable)."""


@dataclass(frozen=True)
class ExportResult:
    output: Path
    file_written: bool  # False when no frame could be written: no file is left then
    format: str
    frames_written: int
    frames_out: int  # of those, sent by the controller (Tx)
    frames_not_written: dict[str, int]  # reason -> frames the format cannot hold
    note: str  # what the format loses for every frame ("" when nothing)
    report: ReadReport


class _RecordedAscWriter(can.ASCWriter):
    """python-can's ASC writer dates the file with the time of the export (``datetime.now()`` in its
    ``date`` header line, which ASC readers take as the measurement's start); this one with the
    recording's first frame, so absolute times read back are the recording's."""

    def __init__(self, file: Path, start_unix_s: float) -> None:
        self._recorded_start = _dt.datetime.fromtimestamp(start_unix_s)
        super().__init__(file)

    def _format_header_datetime(self, dt: _dt.datetime) -> str:
        return super()._format_header_datetime(self._recorded_start)


class _RecordedMf4Writer(can.MF4Writer):
    """python-can's MF4 writer starts the measurement at the time of the export (``datetime.now()``,
    and every timestamp relative to it); this one at the recording's first frame."""

    def __init__(self, file: Path, start_unix_s: float) -> None:
        super().__init__(file)
        start = _dt.datetime.fromtimestamp(start_unix_s, tz=_dt.UTC)
        self._mdf.header.start_time = start
        self.last_timestamp = self._start_time = start.timestamp()


def default_output(path: Path, fmt: str) -> Path:
    return path.with_suffix(f".{fmt}")


def _candump_channel(report: ReadReport) -> str:
    """The interface name candump would print: the recorded SocketCAN channel, else ``can0``."""
    bus = report.metadata.get(m.META_SESSION, {}).get("bus", "")
    interface, _, channel = bus.partition(":")
    return channel if interface == "socketcan" and channel else "can0"


def _writer(fmt: str, out: Path, first_unix_s: float, report: ReadReport) -> can.io.generic.MessageWriter:
    if fmt == "asc":
        return _RecordedAscWriter(out, first_unix_s)
    if fmt == "blf":
        return can.BLFWriter(out)
    if fmt == "log":
        return can.CanutilsLogWriter(out, channel=_candump_channel(report))
    if fmt == "trc":
        return can.TRCWriter(out)
    if fmt == "mf4":
        try:
            mf4_support.load()  # python-can's MF4 writer with asammdf (kept out of other runs)
        except ImportError:
            raise ExportError(
                "--format mf4 needs asammdf: pip install 'cheope-controller[mf4]' (python-can's mf4 extra)"
            ) from None
        return _RecordedMf4Writer(out, first_unix_s)
    return can.CSVWriter(out)


def export_frames(
    path: str | Path, fmt: str, out: str | Path | None = None, progress: Callable[[int], None] | None = None
) -> ExportResult:
    """Write every CAN frame of ``path`` to ``out`` (default: beside it, the format's suffix)."""
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r}: must be one of {', '.join(FORMATS)}")
    path = Path(path)
    target = Path(out) if out else default_output(path, fmt)
    if same_file(path, target):
        raise ExportError(f"-o {target}: is the recording itself")
    command = f"logs export {path}"
    refuse_existing_output(command, target)  # before the work: never another file overwritten
    report = ReadReport(path)
    unwritable = _UNWRITABLE.get(fmt, ())
    skipped: Counter[str] = Counter()
    written = sent = 0
    writer: can.io.generic.MessageWriter | None = None
    # written under a name of its own and named `target` once there is something in it: a run that
    # exported nothing (or failed) leaves no file behind
    partial = _partial_file(target)
    try:
        try:
            for f in recorded_frames(path, report):
                if writer is None:  # the session's metadata comes before the first chunk of frames
                    writer = _open(fmt, partial, target, f.unix_time_ns * 1e-9, report)
                reason = next((why for why, cannot in unwritable if cannot(f)), None)
                if reason is not None:
                    skipped[reason] += 1
                    continue
                writer.on_message_received(as_message(f))
                written += 1
                sent += f.outgoing
                if progress is not None and written % PROGRESS_EVERY_FRAMES == 0:
                    progress(report.end_offset)
        finally:
            if writer is not None:
                writer.stop()
        if written:
            publish_new_file(command, partial, target)
    finally:
        partial.unlink(missing_ok=True)
    note = (
        "python-can's CSV has no direction column: use asc, blf, log, trc or mf4 to keep Rx/Tx"
        if fmt in NO_DIRECTION
        else ""
    )
    return ExportResult(target, written > 0, fmt, written, sent, dict(skipped), note, report)


def _partial_file(target: Path) -> Path:
    """A new file beside ``target``, with its suffix (asammdf names an MF4 file by it)."""
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix, dir=target.parent)
    except OSError as err:
        raise ExportError(f"cannot write {target}: {err.strerror or err}") from err
    os.close(fd)
    return Path(name)


def _open(
    fmt: str, partial: Path, target: Path, first_unix_s: float, report: ReadReport
) -> can.io.generic.MessageWriter:
    try:
        return _writer(fmt, partial, first_unix_s, report)
    except OSError as err:
        raise ExportError(f"cannot write {target}: {err.strerror or err}") from err
