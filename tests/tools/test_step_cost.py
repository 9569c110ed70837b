"""The step-cost tool: back to back or with the service's wait before each step (--idle-us)."""

from __future__ import annotations

import pytest

from controller.tools.bench.step_cost import main, step_breakdown


def test_the_idle_wait_before_each_step_is_reported_and_the_run_ends_as_back_to_back():
    back_to_back = step_breakdown(None, [], 400.0, 60)
    idle = step_breakdown(None, [], 400.0, 60, idle_us=300.0)
    assert back_to_back["idle_before_step_us"] == 0.0 and idle["idle_before_step_us"] == 300.0
    # the same simulated-time run: only the wall clock between the steps differs
    assert idle["final_mode"] == back_to_back["final_mode"]
    assert idle["step_us"]["p50"] > 0.0


@pytest.mark.parametrize("idle", ["-1", "inf", "nan", "2e6"])
def test_an_idle_wait_out_of_range_is_refused_by_name(capsys, idle):
    with pytest.raises(SystemExit) as exit_:
        main(["--idle-us", idle, "--cycles", "10"])
    assert exit_.value.code == 2
    assert f"--idle-us {float(idle):g}: must be 0 to 1 000 000 (a second)" in capsys.readouterr().err
