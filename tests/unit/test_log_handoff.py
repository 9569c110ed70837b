"""A log stream that blocks does not block whoever logs during a run (controller/shell/log_handoff.py)."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from controller.shell.log_handoff import DroppingQueueHandler, log_records_off_the_loop


class BlockedHandler(logging.Handler):
    """A stream nobody reads: every write waits until ``unblock`` is set."""

    def __init__(self) -> None:
        super().__init__()
        self.unblock = threading.Event()
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        assert self.unblock.wait(30.0)
        self.records.append(record.getMessage())


@pytest.fixture
def blocked_root():
    root = logging.getLogger()
    before = (list(root.handlers), root.level)
    handler = BlockedHandler()
    root.handlers = [handler]
    root.setLevel(logging.INFO)
    yield handler
    handler.unblock.set()
    root.handlers, _ = before
    root.setLevel(before[1])


def test_logging_returns_at_once_while_the_stream_blocks_and_nothing_kept_is_lost(blocked_root):
    log = logging.getLogger("test.loop")
    with log_records_off_the_loop(capacity=10) as handoff:
        assert handoff is not None
        t0 = time.monotonic()
        for i in range(25):  # the listener holds one record in the blocked write, 10 wait, the rest drop
            log.warning("cycle %d: something", i)
        assert time.monotonic() - t0 < 5.0  # would wait for ever on the blocked stream without the hand-off
        assert handoff.dropped >= 25 - 10 - 1
        blocked_root.unblock.set()
    assert blocked_root.records[0] == "cycle 0: something"
    kept = [r for r in blocked_root.records if r.startswith("cycle")]
    assert len(kept) == 25 - handoff.dropped  # queued ones written out at the end, in order
    assert kept == sorted(kept, key=lambda r: int(r.split()[1].rstrip(":")))
    assert "log record(s) dropped during the run" in blocked_root.records[-1]
    handlers = logging.getLogger().handlers  # put back (pytest's capture handlers come and go beside it)
    assert blocked_root in handlers and not any(isinstance(h, DroppingQueueHandler) for h in handlers)


def test_without_a_handler_nothing_is_set_up():
    root = logging.getLogger()
    before = list(root.handlers)
    root.handlers = []
    try:
        with log_records_off_the_loop() as handoff:
            assert handoff is None
            assert not any(isinstance(h, DroppingQueueHandler) for h in root.handlers)
    finally:
        root.handlers = before
