"""replay --verify's comparison: a divergence is reported, never an exception."""

from __future__ import annotations

from controller.core.cycle_data import Event, Severity
from controller.messages import cheope_pb2 as pb
from logs.replay_verify import _Compare, _compare_events


def test_a_different_number_of_events_is_a_divergence_named_events():
    recorded = [
        pb.Event(kind="mode", severity=0, message="a"),
        pb.Event(kind="mode", severity=0, message="b"),
    ]
    c = _Compare(7, 0.0175)
    _compare_events(c, recorded, (Event("mode", Severity.INFO, "a"),))
    assert c.diff is not None and c.diff.field == "events" and c.diff.cycle == 7
