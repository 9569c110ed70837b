"""A recording whose ``cheope.config`` metadata record holds no configuration table: ``cheope replay
--verify`` names the file, the record and what the record holds, in one line with exit code 2.

An outside tester's files, rewritten from a shipped recording: JSON that is a list ended in an
AttributeError traceback, JSON nested 100 000 deep in a RecursionError, text that is no JSON in an
error naming neither the file nor the record.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from controller.cli import main

SHIPPED = Path(__file__).parents[1] / "data" / "contour_contact.mcap"


def _with_config_record(dst: Path, text: str) -> Path:
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


@pytest.mark.parametrize(
    "text,what",
    [
        ("[1, 2, 3]", "the configuration is a JSON array, not an object of sections"),
        ('"loop"', "the configuration is a JSON string, not an object of sections"),
        ("[" * 100_000 + "]" * 100_000, "the configuration is nested more than 32 levels deep"),
        ('{"loop": ' * 40 + "1" + "}" * 40, "the configuration is nested more than 32 levels deep"),
        ("{not json", "the configuration is not JSON: Expecting property name"),
    ],
    ids=["list", "string", "deep-list", "deep-object", "not-json"],
)
def test_verify_names_the_file_the_record_and_what_is_wrong(tmp_path: Path, capsys, text: str, what: str):
    path = _with_config_record(tmp_path / "rec.mcap", text)
    assert main(["replay", str(path), "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{path}: metadata record cheope.config: {what}" in err


def test_the_shipped_record_still_verifies(tmp_path: Path, capsys):
    """The rewrite itself keeps a recording that verifies: what fails above is the record."""
    text = _shipped_config_json()
    assert main(["replay", str(_with_config_record(tmp_path / "rec.mcap", text)), "--verify"]) == 0


def _shipped_config_json() -> str:
    with SHIPPED.open("rb") as src:
        return next(r.metadata["json"] for r in make_reader(src).iter_metadata() if r.name == "cheope.config")
