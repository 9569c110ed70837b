"""DropCounter: every drop counted, at most one warning per interval, naming the last one."""

from __future__ import annotations

import logging

import pytest

from drivers.drop_counter import DropCounter


def test_counts_every_drop_and_warns_at_most_once_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    now = [100.0]
    counter = DropCounter(logging.getLogger("test.drops"), "%d dropped (last %s)", 5.0, lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="test.drops"):
        counter.add("a")  # the first at once
        now[0] = 104.9
        counter.add("b")
        counter.add("c")
        now[0] = 105.0  # the interval past: the count so far and the last one
        counter.add("d")
    assert counter.count == 4
    assert [r.getMessage() for r in caplog.records] == ["1 dropped (last a)", "4 dropped (last d)"]
