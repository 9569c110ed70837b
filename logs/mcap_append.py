"""Messages into the open chunk of an ``mcap.writer.Writer``, each record packed in one call.

Why: mcap's ``Writer.add_message`` builds a ``Message`` dataclass and writes it field by field (seven
``BytesIO.write`` calls, six ``struct.pack`` calls and a seek back for the record's length), at 2.2
messages a cycle a tenth of the recorder's writer process's instructions (docs/measurements/speed.md,
"The writer's reads"). ``MessageAppender.add`` appends the same bytes, the same message-index entry and
the same statistics with one ``struct.pack`` and two writes, and its chunk's message indexes are
written with one pack each at the chunk's end (``PackedMessageIndex``).

It reaches into the Writer's private state (mcap 1.x's name-mangled attributes, which the package
has kept since 1.0): when that state is not what it expects (another mcap version, a writer without
chunks) it says so in ``fast`` and hands every message to ``Writer.add_message``.
tests/unit/test_mcap_append.py writes the same messages both ways and compares the files byte for
byte, so a change in mcap's layout fails there, not in a recording.
"""

from __future__ import annotations

import struct
from itertools import chain
from typing import Any

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex, Statistics
from mcap.writer import Writer

# opcode, record length, then the Message record's fields (MCAP spec, "Message (op=0x05)")
_HEADER = struct.Struct("<BQHIQQ")
_FIELDS_BYTES = 2 + 4 + 8 + 8  # channel id, sequence, log time, publish time
_MESSAGE = int(Opcode.MESSAGE)  # read once, not an enum lookup a message
_INDEX_HEAD = struct.Struct("<HI")  # a MessageIndex's channel id and its entries' byte length


class PackedMessageIndex(MessageIndex):
    """mcap's ``MessageIndex``, written with one ``struct.pack`` for all its entries where mcap writes
    two a message (at every chunk's end, 2.2 messages a cycle in the recorder's writer)."""

    def write(self, stream: RecordBuilder) -> None:
        records = self.records
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write(_INDEX_HEAD.pack(self.channel_id, len(records) * 16))
        stream.write(struct.pack(f"<{2 * len(records)}Q", *chain.from_iterable(records)))
        stream.finish_record()


class MessageAppender:
    """``add`` is ``writer.add_message`` (same arguments, same file), faster."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        stats: Any = getattr(writer, "_Writer__statistics", None)
        builder: Any = getattr(writer, "_Writer__chunk_builder", None)
        chunk_size = getattr(writer, "_Writer__chunk_size", None)
        finalize: Any = getattr(writer, "_Writer__maybe_finalize_chunk", None)
        self.fast = (
            isinstance(stats, Statistics)
            and builder is not None
            and isinstance(getattr(builder, "record_writer", None), RecordBuilder)
            and isinstance(getattr(builder, "message_indices", None), dict)
            and isinstance(chunk_size, int)
            and callable(finalize)
        )
        self._stats = stats
        self._builder = builder
        self._chunk_size = chunk_size if isinstance(chunk_size, int) else 0
        self._maybe_finalize_chunk = finalize

    def add(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0) -> int:
        """The message into the file; returns the bytes its record takes (data and header)."""
        if not self.fast:
            self.writer.add_message(channel_id, log_time, data, publish_time, sequence)
            return _HEADER.size + len(data)
        st = self._stats  # as Writer.add_message
        if st.message_count == 0 or log_time < st.message_start_time:
            st.message_start_time = log_time
        if log_time > st.message_end_time:
            st.message_end_time = log_time
        st.channel_message_counts[channel_id] += 1
        st.message_count += 1
        b = self._builder  # as ChunkBuilder.add_message
        if b.num_messages == 0 or log_time < b.message_start_time:
            b.message_start_time = log_time
        if log_time > b.message_end_time:
            b.message_end_time = log_time
        index = b.message_indices.get(channel_id)
        if index is None:
            index = b.message_indices[channel_id] = PackedMessageIndex(channel_id=channel_id, records=[])
        buf = b.record_writer._buffer  # replaced at every chunk's end: read it each time
        index.records.append((log_time, buf.tell()))
        b.num_messages += 1
        header = _HEADER.pack(
            _MESSAGE, _FIELDS_BYTES + len(data), channel_id, sequence, log_time, publish_time
        )
        buf.write(header)
        buf.write(data)
        if buf.tell() > self._chunk_size:
            self._maybe_finalize_chunk()
        return len(header) + len(data)
