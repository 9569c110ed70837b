"""``cheope logs recover FILE``: a complete, indexed MCAP file from a truncated or damaged one.

Every message ``logs.reader.iter_messages`` can reach (all intact chunks, in file order) is
copied with its schema, channel, times and sequence into a new file written by the ``mcap``
library, which adds the chunk and message indexes, the statistics and the footer; the
metadata found is copied too, plus a ``cheope.recovery`` record saying what was lost. The metadata of
the source's head (the session, ``cheope.file``) comes first in the new file too, before its first
chunk, where ``cheope logs list`` reads it (logs/session_list.py): a recovered file lists under its
session, not as a session of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.writer import CompressionType, Writer

from controller.output_paths import existing_output_error
from logs.reader import LogFileError, ReadReport, iter_messages, read_head, same_file


@dataclass(frozen=True)
class RecoveryResult:
    source: Path
    output: Path
    messages_saved: int
    report: ReadReport  # what the walk through the source found


def default_output(src: Path) -> Path:
    return src.with_name(f"{src.stem}.recovered.mcap")


def recover(src: str | Path, out: str | Path | None = None) -> RecoveryResult:
    """Write ``out`` (default ``FILE.recovered.mcap`` beside it) from what is readable in ``src``."""
    src = Path(src)
    dst = Path(out) if out is not None else default_output(src)
    if same_file(src, dst):
        raise LogFileError(f"recover {src}: the output must be a new file, not the damaged one")
    report = ReadReport(src)
    try:
        # opened apart from the `with fh` below: its errors are told from the writer's
        fh = open(dst, "xb")  # noqa: SIM115  (closed by the `with fh` below)
    except FileExistsError as err:
        raise existing_output_error(f"recover {src}", dst) from err
    except OSError as err:
        raise LogFileError(f"recover {src}: cannot create {dst}: {err.strerror or err}") from err
    saved = 0
    try:
        with fh:
            w = Writer(fh, compression=CompressionType.ZSTD)
            w.start(profile="", library="cheope logs.recovery")
            head = _head_metadata(src)
            for name, data in head.items():
                w.add_metadata(name, data)
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            for ch, msg in iter_messages(src, report):
                cid = channel_ids.get(ch.id)
                if cid is None:
                    sid = 0
                    schema = report.schemas.get(ch.schema_id)
                    if schema is not None:
                        sid = schema_ids.get(schema.id) or w.register_schema(
                            schema.name, schema.encoding, schema.data
                        )
                        schema_ids[schema.id] = sid
                    cid = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
                    channel_ids[ch.id] = cid
                w.add_message(cid, msg.log_time, msg.data, msg.publish_time, msg.sequence)
                saved += 1
            for name, data in report.metadata.items():
                if head.get(name) != data:  # written above already
                    w.add_metadata(name, data)
            w.add_metadata(
                "cheope.recovery",
                {
                    "source": str(src),
                    "messages_saved": str(saved),
                    "chunks_read": str(report.chunks),
                    "damaged_chunks": str(report.damaged_chunks),
                    "problems": "; ".join(report.problems) or "none",
                },
            )
            w.finish()
    except LogFileError:
        dst.unlink(missing_ok=True)
        raise
    except OSError as err:
        dst.unlink(missing_ok=True)
        raise LogFileError(f"recover {src}: writing {dst} failed: {err.strerror or err}") from err
    return RecoveryResult(src, dst, saved, report)


def _head_metadata(src: Path) -> dict[str, dict[str, str]]:
    """The metadata before the source's first chunk; none when its head cannot be read (``iter_messages``
    then says what is wrong with the file)."""
    try:
        return read_head(src).metadata
    except LogFileError:
        return {}
