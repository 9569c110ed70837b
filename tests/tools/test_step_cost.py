"""The step-cost tool: back to back or with the service's wait before each step (--idle-us)."""

from __future__ import annotations

import pytest

from controller.tools.bench.step_cost import main, step_breakdown


def test_the_idle_wait_before_each_step_is_reported_and_changes_nothing_the_law_does():
    back_to_back = step_breakdown(None, [], 400.0, 60)
    idle = step_breakdown(None, [], 400.0, 60, idle_us=300.0)
    assert back_to_back["idle_before_step_us"] == 0.0 and idle["idle_before_step_us"] == 300.0
    # the same simulated-time run: only the wall clock between the steps differs
    assert idle["final_mode"] == back_to_back["final_mode"]
    assert idle["step_us"]["p50"] > 0.0


def test_a_negative_idle_wait_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--idle-us", "-1", "--cycles", "10"])
    assert exit_.value.code == 2
    assert "--idle-us -1: must be 0 or more" in capsys.readouterr().err
