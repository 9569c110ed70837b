"""The end of a Zenoh session never raises out of the run (controller/monitoring/zenoh_session.py).

An outside tester's 300 live subscribers that no longer drained their sessions made Zenoh's
``close`` time out ("close operation timed out!"): the error went out through the demo after its
run had gone well, with no summary printed. These stand-ins raise what Zenoh raised there."""

from __future__ import annotations

import logging

import pytest
import zenoh

from controller.monitoring.zenoh_session import close_session


class _Entity:
    def __init__(self, name: str, undeclared: list[str], fails: bool = False) -> None:
        self.name, self.undeclared, self.fails = name, undeclared, fails

    def undeclare(self) -> None:
        self.undeclared.append(self.name)
        if self.fails:
            raise zenoh.ZError("undeclare timed out!")


class _Session:
    def __init__(self) -> None:
        self.closes = 0

    def close(self) -> None:
        self.closes += 1
        raise zenoh.ZError("close operation timed out!")


def test_a_session_that_does_not_close_is_named_and_every_entity_was_undeclared_first(caplog):
    undeclared: list[str] = []
    entities = [
        _Entity("state", undeclared),
        _Entity("events", undeclared, fails=True),
        _Entity("alive", undeclared),
    ]
    session = _Session()
    with caplog.at_level(logging.WARNING, logger="controller.monitoring.zenoh_session"):
        close_session(session, entities)  # type: ignore[arg-type]  # a stand-in for zenoh.Session
    assert undeclared == ["alive", "events", "state"]  # newest first, on past the one that failed
    assert session.closes == 1
    text = caplog.text
    assert "did not undeclare _Entity: undeclare timed out!" in text
    assert "did not close its session (close operation timed out!)" in text


def test_other_errors_still_raise():
    class _Broken:
        def undeclare(self) -> None:
            raise RuntimeError("a bug of ours")

    with pytest.raises(RuntimeError, match="a bug of ours"):
        close_session(None, [_Broken()])
