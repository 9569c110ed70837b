"""What a peer sends the tools and the controller is bounded and shown safely (an outside
tester's findings: a terminal cleared by an ESC in a mode, `cheope list` ended by a deep JSON,
a 1-MB command name echoed whole, a monitor grown to 480 MB under 90 000 robot ids)."""

from __future__ import annotations

import pytest

from controller.cli_output import printable
from controller.messages import cheope_pb2 as pb
from controller.monitoring.command_gate import decide_command
from controller.monitoring.commands import status_config
from controller.monitoring.monitor_view import (
    MAX_ROBOTS,
    AliveUpdate,
    DroppedSamplesUpdate,
    FleetView,
    render_fleet,
    update_to_json,
)
from controller.monitoring.zenoh_session import MonitoringConnectionError


def test_a_peers_control_characters_are_shown_as_escapes_and_long_text_is_cut():
    assert printable("RUNNING") == "RUNNING"
    assert printable("PWNED\x1b[2J\x1b[31m\n") == "PWNED\\x1b[2J\\x1b[31m\\n"
    assert printable("x" * 1000, limit=10) == "x" * 10 + "... (1000 characters)"


def test_a_config_json_that_nests_too_deeply_is_named_not_a_traceback():
    deep = pb.Status(config_json='{"a":' * 5000 + "1" + "}" * 5000)
    with pytest.raises(MonitoringConnectionError, match="nests too deeply"):
        status_config(deep, "cheope/x/status")


def test_an_unknown_command_is_named_by_its_first_40_characters():
    decision = decide_command("x" * 1_000_000, 0.0, False, None)
    assert (
        not decision.accepted and len(decision.message) < 200 and "(1000000 characters)" in decision.message
    )


def test_a_fleet_view_shows_at_most_max_robots_and_counts_the_rest():
    fleet = FleetView("cheope")
    for i in range(MAX_ROBOTS + 50):
        fleet.apply(AliveUpdate(f"cheope/bot-{i}/alive", True, 0.0))
    assert len(fleet.robots) == MAX_ROBOTS and fleet.unshown == 50
    assert f"the first {MAX_ROBOTS} shown" in str(render_fleet(fleet, 0.0).title)


def test_dropped_samples_are_counted_for_the_fleet_not_shown_as_a_robot():
    """Keyed by the subscription (cheope/*), they made a phantom robot "cheope" (a review's finding)."""
    fleet = FleetView("cheope")
    for rid in ("a", "b"):
        fleet.apply(AliveUpdate(f"cheope/{rid}/alive", True, 0.0))
    fleet.apply(DroppedSamplesUpdate("cheope/*", 7, 1.0))
    assert sorted(fleet.robots) == ["a", "b"] and fleet.dropped == 7
    assert "7 sample(s) dropped" in str(render_fleet(fleet, 1.0).title)
    assert '"type": "dropped_samples"' in update_to_json(DroppedSamplesUpdate("cheope/*", 7, 1.0))
