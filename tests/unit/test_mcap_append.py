"""logs/mcap_append.py: the recorder's one-pack message path writes the file mcap's own
``Writer.add_message`` writes, byte for byte, and every tool reads it back."""

from __future__ import annotations

import io

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from logs.mcap_append import MessageAppender

Message = tuple[int, int, bytes, int, int]  # channel index, log time, data, publish time, sequence

messages = st.lists(
    st.tuples(
        st.integers(0, 2),
        st.integers(0, 2**63 - 1),
        st.binary(max_size=300),
        st.integers(0, 2**63 - 1),
        st.integers(0, 2**32 - 1),
    ),
    max_size=60,
)


def _written(batch: list[Message], fast: bool, chunk_size: int, flush_every: int) -> bytes:
    out = io.BytesIO()
    w = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
    w.start(profile="", library="test")
    schema = w.register_schema("s", "protobuf", b"")
    channels = [w.register_channel(f"/t{i}", "protobuf", schema) for i in range(3)]
    appender = MessageAppender(w)
    for i, (c, log_ns, data, pub_ns, seq) in enumerate(batch):
        if fast:
            before = w._Writer__chunk_builder.count if chunk_size > 1 << 20 else None  # type: ignore[attr-defined]
            added = appender.add(channels[c], log_ns, data, pub_ns, seq)
            if before is not None:  # no chunk closed in between: the record's bytes, as returned
                assert w._Writer__chunk_builder.count - before == added  # type: ignore[attr-defined]
        else:
            w.add_message(channels[c], log_ns, data, pub_ns, seq)
        if flush_every and i % flush_every == flush_every - 1:
            w.flush()  # as the recorder's writer closes its chunks
    w.finish()
    return out.getvalue()


@settings(max_examples=60, deadline=None)
@given(batch=messages, chunk_size=st.sampled_from([64, 1 << 40]), flush_every=st.integers(0, 7))
def test_the_appender_writes_what_mcap_writes_byte_for_byte(
    batch: list[Message], chunk_size: int, flush_every: int
) -> None:
    """Times out of order, empty messages, chunks closed by mcap's size rule (64 bytes) and by
    flushes: the same bytes, the statistics, chunk indexes and message indexes included."""
    fast = _written(batch, True, chunk_size, flush_every)
    assert fast == _written(batch, False, chunk_size, flush_every)
    reader = make_reader(io.BytesIO(fast))
    read = [
        (ch.topic, m.log_time, m.data, m.sequence) for _, ch, m in reader.iter_messages(log_time_order=False)
    ]
    assert read == [(f"/t{c}", ns, d, seq) for c, ns, d, _, seq in batch]


def test_the_appender_is_fast_on_this_mcap_and_falls_back_where_the_writer_has_no_chunks() -> None:
    """Its private reads hold on the installed mcap (else the recorder would silently lose the
    speed); a writer without chunks, whose state it does not know, gets mcap's own path."""
    assert MessageAppender(Writer(io.BytesIO())).fast
    out = io.BytesIO()
    w = Writer(out, use_chunking=False)
    appender = MessageAppender(w)
    assert not appender.fast
    w.start()
    ch = w.register_channel("/t", "json", w.register_schema("s", "jsonschema", b"{}"))
    assert appender.add(ch, 5, b"{}", 5, 1) == 31 + 2  # header and data, as on the fast path
    w.finish()
    [(_, _, m)] = list(make_reader(io.BytesIO(out.getvalue())).iter_messages())
    assert (m.log_time, m.data, m.sequence) == (5, b"{}", 1)
