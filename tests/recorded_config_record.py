"""A shipped recording rewritten with another ``cheope.config`` record: the tests of a bad record
(tests/integration/test_recorded_config_record.py, tests/unit/test_rerun_scene_left_out.py)."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import Writer

SHIPPED = Path(__file__).parent / "data" / "contour_contact.mcap"


def with_config_record(dst: Path, text: str) -> Path:
    """The shipped recording, its ``cheope.config`` record's JSON replaced by ``text``."""
    with SHIPPED.open("rb") as src:
        reader = make_reader(src)
        summary = reader.get_summary()
        assert summary is not None
        meta = {r.name: dict(r.metadata) for r in reader.iter_metadata()}
        meta["cheope.config"]["json"] = text
        with dst.open("wb") as out:
            w = Writer(out)
            w.start(profile="", library="test")
            schemas = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
            channels = {
                i: w.register_channel(
                    c.topic, c.message_encoding, schemas.get(c.schema_id, 0), dict(c.metadata)
                )
                for i, c in summary.channels.items()
            }
            for name, record in meta.items():
                w.add_metadata(name, record)
            for _, ch, msg in reader.iter_messages():
                w.add_message(channels[ch.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
            w.finish()
    return dst
