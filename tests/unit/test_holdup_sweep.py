"""The hold-up sweep's verdict on a run (controller/tools/contour/holdup_sweep.py)."""

from __future__ import annotations

import pytest

from controller.tools.contour.holdup_sweep import Lap, Run, main, row_text, within_bound, worst_lap

LAPS = (
    (0.02, 0.0198, 0.284),
    (0.04, 0.0397, 0.226),
    (0.06, 0.0596, 0.416),
    (0.06, 0.0601, 0.395),
    (0.06, 0.0601, 0.415),
)
UNDISTURBED = Run(0.0, 0.0, "DONE", tuple(Lap(c, a, r) for c, a, r in LAPS), 13.1)  # the default demo's


def _with_lap(index: int, lap: Lap, mode: str = "DONE") -> Run:
    laps = list(UNDISTURBED.laps)
    laps[index] = lap
    return Run(0.015, 48.24, mode, tuple(laps), 20.0)


def test_the_bound_is_the_issues_speed_share_and_rms_margin_on_laps_3_to_5():
    assert within_bound(UNDISTURBED, UNDISTURBED)
    assert within_bound(_with_lap(3, Lap(0.06, 0.057, 0.495)), UNDISTURBED)  # 95 %, +0.1 N: inside
    assert not within_bound(_with_lap(3, Lap(0.06, 0.0569, 0.395)), UNDISTURBED)  # too slow
    assert not within_bound(_with_lap(4, Lap(0.06, 0.0601, 0.516)), UNDISTURBED)  # RMS +0.101 N
    assert within_bound(_with_lap(1, Lap(0.04, 0.02, 2.0)), UNDISTURBED)  # lap 2 is not judged
    assert not within_bound(_with_lap(3, UNDISTURBED.laps[3], mode="FAULT"), UNDISTURBED)


def test_a_run_that_faulted_before_its_last_lap_is_out_and_named_as_such():
    partial = Run(0.2, 40.1, "FAULT", UNDISTURBED.laps[:2], 13.1)
    assert not within_bound(partial, UNDISTURBED) and worst_lap(partial, UNDISTURBED) is None
    assert "OUT" in row_text(partial, UNDISTURBED) and "no lap from lap 3 on finished" in row_text(
        partial, UNDISTURBED
    )
    three = Run(0.2, 40.1, "FAULT", UNDISTURBED.laps[:4], 13.1)  # lap 5 unfinished: out, lap 4 judged
    assert not within_bound(three, UNDISTURBED) and worst_lap(three, UNDISTURBED) in (2, 3)


def test_the_worst_lap_is_the_one_whose_rms_rose_most():
    run = _with_lap(3, Lap(0.06, 0.0601, 0.649))
    assert worst_lap(run, UNDISTURBED) == 3
    text = row_text(run, UNDISTURBED)
    assert "worst lap 4" in text and "+0.254" in text and "OUT" in text


@pytest.mark.parametrize("args", [["--lengths", "0.01,abc"], ["--at", "-3"], ["--jobs", "0"]])
def test_a_malformed_argument_is_refused_naming_it(args, capsys):
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert args[0] in err and repr(args[1].split(",")[-1]) in err


@pytest.mark.slow
def test_a_sweep_of_one_short_hold_up_prints_its_row(capsys):
    """End to end in simulated time: a 5-ms hold-up in lap 4 is one the drives run on through."""
    assert main(["--lengths", "0.005", "--at", "44.3", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "hold-up   5.0 ms at  44.30 s: DONE  within" in out
    assert "1 of 1 within the bound" in out
