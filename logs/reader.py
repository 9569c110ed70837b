"""Reading a session recording, whole, truncated or damaged, without ever raising mid-way.

``iter_messages`` walks the file record by record (it does not trust the summary at the end,
which a killed controller never wrote). Every record's length is known before its body is
parsed, so a damaged chunk (bad compression, CRC mismatch) is skipped and counted, and the
walk goes on with the next record. A damaged record header (an impossible length or opcode)
makes the walk search forward for the next chunk that decodes and passes its CRC. A file
that simply stops (SIGKILL, full disk) ends the walk at the last complete record. Whatever
happened is in the ``ReadReport``: never a traceback.

Only a file that is not MCAP at all (or cannot be opened) raises ``LogFileError``.
"""

from __future__ import annotations

import errno
import io
import mmap
import os
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import breakup_chunk

from controller.config import Config, ConfigError, config_table_from_json, recorded_config_from_dict
from controller.errors import InputError
from controller.messages import cheope_pb2 as pb
from logs.can_frame_batch import unpack_frames
from logs.file_ending import FileEnding, file_ending
from logs.messages import META_CONFIG, frame_from_legacy

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")
_KNOWN_OPCODES = {int(o) for o in Opcode}

# Our own topics decode with the generated classes (fast, no descriptor pool).
_CLASSES: dict[str, Any] = {
    "cheope.v1.CanFrame": pb.CanFrame,
    "cheope.v1.Cycle": pb.Cycle,
    "cheope.v1.Event": pb.Event,
    "foxglove.Log": Log,
    "foxglove.FrameTransform": FrameTransform,
    "foxglove.PoseInFrame": PoseInFrame,
    "cheope.v1.CanFrames": pb.CanFrames,
    "cheope.v1.CanFrameBatch": pb.CanFrameBatch,
    "cheope.v1.Keyframe": pb.Keyframe,
}


class LogFileError(InputError):
    """The file cannot be read as an MCAP recording at all (missing, unreadable, not MCAP)."""


def same_file(recording: Path, output: Path) -> bool:
    """Whether ``output`` names the file ``recording`` is, by any path: the same path, a symbolic
    link, and also a hard link or a bind mount (by device and inode), which a comparison of the
    paths missed: an export written "beside" it overwrote the recording (an outside tester's
    finding)."""
    if recording.resolve() == output.resolve():
        return True
    try:
        return os.path.samefile(recording, output)
    except OSError:  # the output does not exist yet (the recording's own errors are its reader's)
        return False


@dataclass
class ReadReport:
    """What a walk through a recording found; filled in while iterating."""

    path: Path
    size_bytes: int = 0
    profile: str = ""
    library: str = ""
    complete: bool = False  # the footer was reached: the recorder finished the file
    chunks: int = 0  # chunks read intact
    damaged_chunks: int = 0  # chunks skipped (bad compression or CRC)
    skipped_bytes: int = 0  # bytes passed over while searching for the next chunk after damage
    end_offset: int = 0  # where the last intact record ended
    problems: list[str] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    message_counts: Counter[str] = field(default_factory=Counter)  # by topic
    orphan_messages: int = 0  # messages whose channel record was lost (and the summary has none)
    channels_from_summary: int = 0  # channels whose record was lost, taken from the summary section
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None
    chunks_checked: bool = True  # False: answered from the summary, no chunk read (logs info without --check)

    @property
    def messages(self) -> int:
        return sum(self.message_counts.values())

    @property
    def duration_s(self) -> float:
        if self.first_log_time_ns is None or self.last_log_time_ns is None:
            return 0.0
        return (self.last_log_time_ns - self.first_log_time_ns) * 1e-9

    @property
    def damaged(self) -> bool:
        return bool(self.problems)

    @property
    def data_lost(self) -> bool:
        """Part of the data section was passed over (a damaged chunk, or bytes skipped after a damaged
        record header): what it held is lost, as the problems name."""
        return self.damaged_chunks > 0 or self.skipped_bytes > 0

    def ending(self) -> FileEnding:
        """How the file ended (``logs list`` says the same word): a complete file is not always a
        closed session."""
        return file_ending(self.metadata, self.complete)

    def status(self) -> str:
        if not self.problems:
            return (
                "complete"
                if self.chunks_checked
                else "complete by its summary; chunks not checked (--check reads and checks every one)"
            )
        return "; ".join(self.problems)


def _parse(opcode: int, body: bytes) -> Any:
    s = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.CHUNK:
        return Chunk.read(s)
    if opcode == Opcode.MESSAGE:
        return Message.read(s, len(body))
    if opcode == Opcode.CHANNEL:
        return Channel.read(s)
    if opcode == Opcode.SCHEMA:
        return Schema.read(s)
    if opcode == Opcode.METADATA:
        return Metadata.read(s)
    if opcode == Opcode.HEADER:
        return Header.read(s)
    if opcode == Opcode.FOOTER:
        return Footer.read(s)
    if opcode == Opcode.DATA_END:
        return DataEnd.read(s)
    return None  # indexes, statistics, attachments: rebuilt or not needed


def _chunk_records(chunk: Chunk) -> list[Any]:
    if len(chunk.data) == 0 and chunk.uncompressed_size:
        raise ValueError("empty chunk data")
    return breakup_chunk(chunk, validate_crc=True)


def _resync(raw: bytes | mmap.mmap, start: int) -> int | None:
    """The offset of the next chunk record at or after ``start`` that parses and passes its CRC."""
    n = len(raw)
    pos = raw.find(b"\x06", start)
    while pos >= 0 and pos + 9 <= n:
        _, length = _HEAD.unpack_from(raw, pos)
        if 0 < length <= n - pos - 9:
            try:
                _chunk_records(_parse(Opcode.CHUNK, raw[pos + 9 : pos + 9 + length]))
                return pos
            except Exception:  # any failure means "not a chunk here"
                pass
        pos = raw.find(b"\x06", pos + 1)
    return None


def iter_messages(path: str | Path, report: ReadReport | None = None) -> Iterator[tuple[Channel, Message]]:
    """Yield ``(channel, message)`` in file order from every intact part of the file."""
    report = report if report is not None else ReadReport(Path(path))
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            raw = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    except OSError as err:
        raise LogFileError(f"cannot read {p}: {err.strerror or err}") from err
    report.size_bytes = len(raw)
    if raw[:8] != MAGIC:
        if isinstance(raw, mmap.mmap):
            raw.close()
        raise LogFileError(f"{p} is not an MCAP file (it does not start with the MCAP magic bytes)")
    try:
        yield from _walk(raw, report)
    finally:
        if isinstance(raw, mmap.mmap):
            raw.close()


_FOOTER = struct.Struct("<BQQQI")  # opcode, length (20), summary_start, summary_offset_start, summary_crc


def summary_definitions(
    raw: bytes | mmap.mmap, report: ReadReport
) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """The schemas and channels the summary section at the end repeats, when the file has a footer
    and the summary passes its CRC (a mismatch is reported, and the summary not used).

    They stand in for the records of a damaged chunk: the channel of a message in an intact chunk
    was defined in the first chunk, which a zeroed or flipped byte made unreadable, and the whole
    recording was lost although its other chunks were intact."""
    n = len(raw)
    footer_at = n - 8 - _FOOTER.size
    if footer_at < 8 or raw[n - 8 :] != MAGIC:
        return {}, {}
    opcode, length, start, _, crc = _FOOTER.unpack_from(raw, footer_at)
    if opcode != Opcode.FOOTER or length != _FOOTER.size - 9 or not 8 <= start <= footer_at:
        return {}, {}
    if start == 0:
        return {}, {}
    # MCAP: the CRC of the summary section through the footer's summary_offset_start (0: none written)
    if crc and zlib.crc32(raw[start : footer_at + 9 + 16]) != crc:
        report.problems.append(
            f"the summary section (offset {start}) does not match its CRC: its schemas and channels are not used"
        )
        return {}, {}
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    pos = start
    while pos + 9 <= footer_at:
        op, size = _HEAD.unpack_from(raw, pos)
        if size > footer_at - pos - 9:
            break
        if op in (Opcode.SCHEMA, Opcode.CHANNEL):
            try:
                record = _parse(op, raw[pos + 9 : pos + 9 + size])
            except Exception:  # the CRC passed: a record the library cannot read is left out
                record = None
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
        pos += 9 + size
    return schemas, channels


def _walk(raw: bytes | mmap.mmap, report: ReadReport) -> Iterator[tuple[Channel, Message]]:  # noqa: C901  (every MCAP record kind and every way a file can be damaged)
    pos = 8
    report.end_offset = pos
    n = len(raw)
    summary_schemas, summary_channels = summary_definitions(raw, report)
    summary_at: int | None = None  # where the summary section starts (after DataEnd)

    def from_summary(channel_id: int) -> Channel | None:
        ch = summary_channels.get(channel_id)
        if ch is not None:
            report.channels[channel_id] = ch
            report.channels_from_summary += 1
            schema = summary_schemas.get(ch.schema_id)
            if schema is not None and ch.schema_id not in report.schemas:
                report.schemas[ch.schema_id] = schema
        return ch

    def emit(records: Iterable[Any]) -> Iterator[tuple[Channel, Message]]:
        for r in records:
            if isinstance(r, Message):
                ch = report.channels.get(r.channel_id) or from_summary(r.channel_id)
                if ch is None:
                    report.orphan_messages += 1
                    continue
                report.message_counts[ch.topic] += 1
                if report.first_log_time_ns is None or r.log_time < report.first_log_time_ns:
                    report.first_log_time_ns = r.log_time
                if report.last_log_time_ns is None or r.log_time > report.last_log_time_ns:
                    report.last_log_time_ns = r.log_time
                yield ch, r
            elif isinstance(r, Channel):
                report.channels[r.id] = r
            elif isinstance(r, Schema):
                report.schemas[r.id] = r

    while pos < n:
        if pos + 9 > n:
            report.problems.append(
                f"truncated: {n - pos} stray byte(s) at offset {pos} after the last record"
            )
            break
        opcode, length = _HEAD.unpack_from(raw, pos)
        if opcode not in _KNOWN_OPCODES or length > n - pos - 9:
            nxt = _resync(raw, pos + 1)
            if nxt is None:
                if opcode in _KNOWN_OPCODES:
                    report.problems.append(
                        f"truncated: the {Opcode(opcode).name} record at offset {pos} needs "
                        f"{length} bytes, the file has {n - pos - 9} after its header"
                    )
                else:
                    report.problems.append(
                        f"damaged record header at offset {pos}; nothing readable after it"
                    )
                break
            report.problems.append(f"damaged record header at offset {pos}; resumed at offset {nxt}")
            report.skipped_bytes += nxt - pos
            pos = nxt
            continue
        body = raw[pos + 9 : pos + 9 + length]
        start, pos = pos, pos + 9 + length
        try:
            record = _parse(opcode, body)
        except Exception as err:  # damaged input: report it, go on with the next record
            report.problems.append(
                f"damaged {Opcode(opcode).name} record at offset {start}: {err or type(err).__name__}"
            )
            continue
        if isinstance(record, Chunk):
            try:
                records = _chunk_records(record)
            except Exception as err:
                report.damaged_chunks += 1
                report.problems.append(
                    f"damaged chunk at offset {start} skipped: {err or type(err).__name__}"
                )
                continue
            report.chunks += 1
            report.end_offset = pos
            yield from emit(records)
            continue
        report.end_offset = pos
        if isinstance(record, Header):
            report.profile, report.library = record.profile, record.library
        elif isinstance(record, Metadata):
            report.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, (Message, Channel, Schema)):
            yield from emit([record])
        elif isinstance(record, DataEnd):
            summary_at = pos  # the summary, if any, follows the data section's end
        elif isinstance(record, Footer):
            report.complete = True
            if raw[pos : pos + 8] != MAGIC:
                report.problems.append("the footer is not followed by the closing magic bytes")
            elif n > pos + 8:
                # bytes appended to a finished file: no writer puts them there (the file was changed)
                report.problems.append(
                    f"{n - pos - 8} byte(s) after the closing magic bytes at offset {pos + 8}: the file "
                    "was changed after it was finished"
                )
            expected = summary_at if summary_at is not None and summary_at < start else 0
            if record.summary_start not in (0, expected):
                # a reader that seeks by it (logs info without --check, other MCAP tools) fails
                report.problems.append(
                    f"the footer's summary_start {record.summary_start} is not where the summary starts ({expected})"
                )
            break
    if not report.complete and not any(p.startswith("truncated") for p in report.problems):
        report.problems.append(f"truncated: the file ends at byte {n} without its summary and footer")
    if report.channels_from_summary:
        report.problems.append(
            f"{report.channels_from_summary} channel definition(s) lost with a damaged part, taken from the summary"
        )
    if report.orphan_messages:
        report.problems.append(f"{report.orphan_messages} message(s) whose channel definition was lost")
    if report.complete:
        _check_the_writers_count(report)


def _check_the_writers_count(report: ReadReport) -> None:
    """A finished file against the count its writer put in ``cheope.recording`` (``file_written``):
    messages removed by hand from a complete file (its index and summary rewritten to match) read as
    complete, and only ``replay --verify`` found the gap. A recovered file's ``cheope.recovery``
    says what it lost; an older file without the count is not checked."""
    written = report.metadata.get("cheope.recording", {}).get("file_written", "")
    if not written.isdigit() or "cheope.recovery" in report.metadata:
        return
    held = report.messages + report.orphan_messages
    if held != int(written):
        why = (  # a damaged part (a flipped bit fails its chunk's CRC) is read past, not changed by hand
            "the rest were in the damaged part(s) named before"
            if report.problems and held < int(written)
            else "it was changed after it was written"
        )
        report.problems.append(
            f"the file holds {held} message(s) where its writer wrote {int(written)} "
            f"(cheope.recording file_written): {why}"
        )


def decoder_for(schema: Schema | None) -> Callable[[bytes], Any] | None:
    if schema is None or schema.encoding != "protobuf":
        return None
    cls = _CLASSES.get(schema.name)
    if cls is not None:
        decode: Callable[[bytes], Any] = cls.FromString  # a generated Protobuf class (untyped)
        return decode
    from mcap_protobuf.decoder import DecoderFactory

    try:
        return DecoderFactory().decoder_for("protobuf", schema)
    except Exception:  # an unknown or broken schema: the channel stays raw
        return None


@dataclass(frozen=True)
class Decoded:
    topic: str
    log_time_ns: int
    sequence: int
    message: Any


def iter_decoded(
    path: str | Path, topics: Iterable[str] | None = None, report: ReadReport | None = None
) -> Iterator[Decoded]:
    """Decoded Protobuf messages of ``topics`` (all when None); undecodable ones are counted as problems."""
    report = report if report is not None else ReadReport(Path(path))
    wanted = set(topics) if topics is not None else None
    decoders: dict[int, Callable[[bytes], Any] | None] = {}
    bad: Counter[str] = Counter()
    for ch, msg in iter_messages(path, report):
        if wanted is not None and ch.topic not in wanted:
            continue
        if ch.id not in decoders:
            decoders[ch.id] = decoder_for(report.schemas.get(ch.schema_id))
        dec = decoders[ch.id]
        if dec is None:
            bad[ch.topic] += 1
            continue
        try:
            value = dec(msg.data)
        except Exception:  # a damaged message inside an intact chunk: count, go on
            bad[ch.topic] += 1
            continue
        if isinstance(value, (pb.CanFrames, pb.CanFrameBatch, pb.CanFrame)):
            try:
                yield from _frames(ch.topic, msg, value)
            except (ValueError, OverflowError):  # a batch that does not add up, a time that is no number
                bad[ch.topic] += 1
            continue
        yield Decoded(ch.topic, msg.log_time, msg.sequence, value)
    for topic, k in bad.items():
        report.problems.append(f"{k} message(s) on {topic} could not be decoded")


def _frames(topic: str, msg: Message, value: Any) -> Iterator[Decoded]:
    """One ``Decoded`` ``CanFrames.Frame`` per CAN frame, whichever format the file has (logs/messages.py),
    its log time the frame's own time."""
    if isinstance(value, pb.CanFrames):
        for f in value.frames:
            yield Decoded(topic, f.unix_time_ns, 0, f)
    elif isinstance(value, pb.CanFrame):  # the oldest files: a message per frame, at the frame's time
        yield Decoded(topic, msg.log_time, msg.sequence, frame_from_legacy(value, msg.log_time))
    else:  # a CanFrameBatch: the batch's log time is its first frame's
        frames = list(unpack_frames(value.frames))  # all or none: a batch that does not add up is refused
        offset_ns = msg.log_time - round(frames[0].monotonic_s * 1e9) if frames else 0
        for f in frames:
            ns = round(f.monotonic_s * 1e9) + offset_ns
            yield Decoded(topic, ns, 0, frame_from_legacy(f, ns))


def read_info(path: str | Path) -> ReadReport:
    """Walk the whole file: channels, counts, metadata, duration, damage."""
    report = ReadReport(Path(path))
    for _ in iter_messages(path, report):
        pass
    return report


def read_head(path: str | Path) -> ReadReport:
    """The header and the metadata written before the first chunk (the session's configuration and
    ``cheope.file``): a few records from the start, for any file, finished, open or cut short."""
    p = Path(path)
    report = ReadReport(p)
    try:
        with open(p, "rb") as fh:
            report.size_bytes = os.fstat(fh.fileno()).st_size
            if fh.read(8) != MAGIC:
                raise LogFileError(f"{p} is not an MCAP file (it does not start with the MCAP magic bytes)")
            while True:
                head = fh.read(9)
                if len(head) < 9:
                    break
                opcode, length = _HEAD.unpack(head)
                if (
                    opcode not in (Opcode.HEADER, Opcode.METADATA, Opcode.SCHEMA, Opcode.CHANNEL)
                    or length > 1 << 26
                ):
                    break  # the first chunk (or damage): the head ends here
                body = fh.read(length)
                if len(body) < length:
                    break
                try:
                    record = _parse(opcode, body)
                except Exception:  # a damaged head: what was read so far is the answer
                    break
                if isinstance(record, Header):
                    report.profile, report.library = record.profile, record.library
                elif isinstance(record, Metadata):
                    report.metadata[record.name] = dict(record.metadata)
    except OSError as err:
        raise LogFileError(f"cannot read {p}: {err.strerror or err}") from err
    return report


def read_info_from_summary(path: str | Path) -> ReadReport | None:
    """Channels, counts, metadata and duration from the summary section at the end of the file,
    reading the header, the footer, the summary and the metadata records only (milliseconds
    for any size, where ``read_info`` walks every chunk). None when the file has no usable
    summary (a killed writer never wrote one; a damaged end): then ``read_info`` is the answer.

    It trusts the summary: a chunk damaged in the middle of a finished file shows only in
    ``read_info`` (``cheope logs info --check``).
    """
    from mcap.exceptions import McapError
    from mcap.reader import SeekingReader

    p = Path(path)
    report = ReadReport(p)
    try:
        with open(p, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size < 16 or fh.read(8) != MAGIC:
                return None
            fh.seek(-8, os.SEEK_END)
            if fh.read(8) != MAGIC:
                return None
            fh.seek(0)
            reader = SeekingReader(fh)
            header = reader.get_header()
            if not _summary_crc_matches(fh, size):
                return None  # the walk reports it (read_info)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return None
            if any(ci.chunk_start_offset + ci.chunk_length > size for ci in summary.chunk_indexes):
                return None
            report.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    except OSError as err:
        if err.errno == errno.EINVAL:  # a seek the damaged footer asked for (summary_start 2**60)
            return None
        raise LogFileError(f"cannot read {p}: {err.strerror or err}") from err
    except (McapError, ValueError, struct.error, StopIteration):  # EndOfFile is an McapError
        return None  # a damaged summary: walk the file instead
    stats = summary.statistics
    report.size_bytes = size
    report.profile, report.library = header.profile, header.library
    report.complete = True
    report.chunks_checked = False
    report.chunks = len(summary.chunk_indexes)
    report.end_offset = size
    report.schemas = dict(summary.schemas)
    report.channels = dict(summary.channels)
    for cid, count in stats.channel_message_counts.items():
        ch = summary.channels.get(cid)
        if ch is not None:
            report.message_counts[ch.topic] += count
    if stats.message_count:
        report.first_log_time_ns, report.last_log_time_ns = stats.message_start_time, stats.message_end_time
    _check_the_writers_count(report)
    return report


def _summary_crc_matches(fh: Any, size: int) -> bool:
    """The summary section against the footer's CRC (True when there is none to check)."""
    footer_at = size - 8 - _FOOTER.size
    fh.seek(footer_at)
    opcode, _, start, _, crc = _FOOTER.unpack(fh.read(_FOOTER.size))
    if opcode != Opcode.FOOTER or not crc or not 8 <= start <= footer_at:
        return True
    fh.seek(start)
    ok: bool = zlib.crc32(fh.read(footer_at + 9 + 16 - start)) == crc
    fh.seek(0)
    return ok


def format_info(r: ReadReport) -> str:
    lines = [
        f"file       {r.path} ({r.size_bytes} bytes)",
        f"status     {r.status()}",
        f"ended      {r.ending()}",
        f"duration   {r.duration_s:.3f} s, {r.messages} messages, {r.chunks} chunks"
        + (f", {r.damaged_chunks} damaged" if r.damaged_chunks else ""),
        "channels",
    ]
    for ch in sorted(r.channels.values(), key=lambda c: c.id):
        schema = r.schemas.get(ch.schema_id)
        lines.append(
            f"  {ch.topic:<16} {r.message_counts.get(ch.topic, 0):>9}  "
            f"{schema.name if schema else '(no schema)'} [{ch.message_encoding}]"
        )
    lines.append("metadata")
    for name, data in r.metadata.items():
        for k, v in data.items():
            text = v if len(v) <= 100 else v[:97] + "..."
            lines.append(f"  {name}.{k} = {text}")
    return "\n".join(lines)


def info_dict(r: ReadReport) -> dict[str, Any]:
    return {
        "path": str(r.path),
        "size_bytes": r.size_bytes,
        "complete": r.complete,
        "ended": r.ending().word,
        "problems": list(r.problems),
        "chunks_checked": r.chunks_checked,
        "duration_s": r.duration_s,
        "messages": r.messages,
        "chunks": r.chunks,
        "damaged_chunks": r.damaged_chunks,
        "channels_from_summary": r.channels_from_summary,
        "channels": {
            ch.topic: {
                "count": r.message_counts.get(ch.topic, 0),
                "schema": r.schemas[ch.schema_id].name if ch.schema_id in r.schemas else None,
                "encoding": ch.message_encoding,
            }
            for ch in r.channels.values()
        },
        "metadata": r.metadata,
    }


def recorded_config(report: ReadReport) -> Config | None:
    """The configuration a recording was made with (its ``cheope.config`` metadata, as this version
    reads an earlier one's), once ``report`` has seen the metadata; None without a readable one."""
    try:
        table = recorded_config_table(report)
        return None if table is None else recorded_config_from_dict(table)
    except (ConfigError, LogFileError):
        return None


def recorded_config_table(report: ReadReport) -> dict[str, Any] | None:
    """The table of the recording's ``cheope.config`` metadata record, None without one; a
    ``LogFileError`` naming the file and the record when it holds no configuration table."""
    meta = report.metadata.get(META_CONFIG)
    if meta is None:
        return None
    where = f"{report.path}: metadata record {META_CONFIG}"
    if "json" not in meta:
        raise LogFileError(f"{where}: has no 'json' entry (it has {', '.join(map(repr, meta)) or 'none'})")
    try:
        return config_table_from_json(meta["json"])
    except ConfigError as err:
        raise LogFileError(f"{where}: {err}") from None
