"""The tool that says where the compiled step can hand the interpreter lock over, and how often."""

from __future__ import annotations

import sys

from controller.tools.bench.step_lock_handoffs import handoffs, interpreted_calls, main


def test_the_interpreted_calls_of_a_step_are_named_per_step():
    calls = interpreted_calls("path", 120)
    # the records' copies run interpreted whichever way the law runs (controller/core/records.py)
    assert calls["records.py:replace"] >= 1.0
    assert not any(name.startswith("step_lock_handoffs.py") for name in calls)  # the tool's own wrapper


def test_handoffs_counts_steps_and_puts_the_switch_interval_back():
    before = sys.getswitchinterval()
    handed, steps = handoffs("path", 120, 200e-6)
    assert steps >= 119 and 0 <= handed <= steps
    assert sys.getswitchinterval() == before


def test_the_command_prints_both_figures(capsys):
    assert main(["--task", "path", "--cycles", "60", "--switch-interval-us", "200"]) == 0
    out = capsys.readouterr().out
    assert "records.py:replace" in out and "switch interval 200 us: a spinning thread ran during" in out
