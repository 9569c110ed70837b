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
from recorded_config_record import SHIPPED, with_config_record

from controller.cli import main


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
    path = with_config_record(tmp_path / "rec.mcap", text)
    assert main(["replay", str(path), "--verify"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"{path}: metadata record cheope.config: {what}" in err


def test_the_shipped_record_still_verifies(tmp_path: Path, capsys):
    """The rewrite itself keeps a recording that verifies: what fails above is the record."""
    text = _shipped_config_json()
    assert main(["replay", str(with_config_record(tmp_path / "rec.mcap", text)), "--verify"]) == 0


def _shipped_config_json() -> str:
    with SHIPPED.open("rb") as src:
        return next(r.metadata["json"] for r in make_reader(src).iter_metadata() if r.name == "cheope.config")
