"""The force error's RMS by cycles since the loop's last hold-up (controller/tools/contour/holdup_response.py)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from controller.config import recorded_config_from_dict
from controller.tools.contour.holdup_response import (
    TrackingCycle,
    by_cycles_since_holdup,
    drives_held,
    read_cycles,
)

DATA = Path(__file__).resolve().parent.parent / "data"


def _cycles(*rows: tuple[int, bool, float, bool, float]) -> list[TrackingCycle]:
    """(lap, tracking, force error, held up, wake error) a cycle, one 2.5-ms deadline after another."""
    return [TrackingCycle(lap, tr, e, h, k * 0.0025, w) for k, (lap, tr, e, h, w) in enumerate(rows)]


def test_each_cycle_lands_in_the_bin_of_cycles_since_the_last_holdup():
    # lap 3: a hold-up, 1 N right after it; then 3 N from 5 to 9 cycles after; lap 2 is not asked for
    cycles = _cycles(
        (2, True, 9.0, True, 0.0),
        (3, True, 0.0, True, 0.0),
        *[(3, True, 1.0, False, 0.0)] * 4,  # 1-4 cycles since
        *[(3, True, 3.0, False, 0.0)] * 5,  # 5-9
        (3, False, 50.0, False, 0.0),  # not tracking: not counted, but counts as a cycle
        (3, True, 2.0, False, 0.0),  # 11 cycles since
    )
    bins = {(b.first, b.last): b for b in by_cycles_since_holdup(cycles, [3])}
    assert (bins[(0, 0)].cycles, bins[(0, 0)].rms_n) == (1, 0.0)
    assert (bins[(1, 4)].cycles, bins[(1, 4)].rms_n) == (4, 1.0)
    assert (bins[(5, 9)].cycles, bins[(5, 9)].rms_n) == (5, 3.0)
    assert (bins[(10, 19)].cycles, bins[(10, 19)].rms_n) == (1, 2.0)
    assert bins[(640, None)].cycles == 0 and math.isnan(bins[(640, None)].rms_n)


@pytest.mark.parametrize("extrapolation_periods", [1, 2, 4])
def test_the_drives_stood_where_more_deadlines_were_skipped_than_their_extrapolation_and_one(
    extrapolation_periods,
):
    # deadlines 2.5 ms apart: one skipped (5 ms), two skipped (the wake-up 0.5 ms late: 8 ms), three
    cycles = [
        TrackingCycle(3, True, 0.0, False, 0.0, 0.0),
        TrackingCycle(3, True, 0.0, True, 0.005, 0.0),  # one skipped: they ran on, or stood a period
        TrackingCycle(3, True, 0.0, False, 0.0075, 0.0),
        TrackingCycle(3, True, 0.0, True, 0.015, 0.0005),  # two skipped
        TrackingCycle(3, True, 0.0, False, 0.0175, 0.0),
        TrackingCycle(3, True, 0.0, True, 0.0275, 0.0005),  # three skipped
        TrackingCycle(4, True, 0.0, False, 0.03, 0.0),
    ]
    want = {1: [0.0105], 2: [], 4: []}[extrapolation_periods]  # more than E + 1 skipped
    assert drives_held(cycles, [3], extrapolation_periods) == pytest.approx(want)
    assert drives_held(cycles, [4], extrapolation_periods) == []


def test_a_sync_without_targets_before_a_hold_up_counts_as_the_law_counts_it():
    """E = 4: five skipped deadlines alone leave the drives running on (blind 6); after a SYNC that
    went without the targets (``targets_withheld``) the same five leave them standing (blind 7)."""

    def run(withheld: bool) -> list[TrackingCycle]:
        return [
            TrackingCycle(3, True, 0.0, False, 0.0, 0.0),
            TrackingCycle(3, True, 0.0, withheld, 0.0025, 0.0024 if withheld else 0.0, withheld),
            TrackingCycle(3, True, 0.0, True, 0.0175, 0.0),  # five deadlines skipped
        ]

    assert drives_held(run(False), [3], 4) == []
    assert drives_held(run(True), [3], 4) == pytest.approx([0.0126])  # from the late SYNC


def test_a_recording_written_before_0x2010_is_read_with_one_period_of_extrapolation():
    # its drives ran on one period past a missing target; its replay rebuilds the law that knew it
    assert recorded_config_from_dict({}).drive_extrapolation_periods == 1
    assert recorded_config_from_dict({"loop": {"rate_hz": 1000}}).drive_extrapolation_periods == 1
    assert (
        recorded_config_from_dict({"actuators": {"extrapolation_s": 0.01}}).drive_extrapolation_periods == 4
    )


def test_a_recording_written_before_0x2011_is_read_with_the_drives_power_on_watchdog():
    # its drives kept the watchdog they booted with: the simulated drive's, 100 ms unless set
    assert recorded_config_from_dict({}).actuators.sync_watchdog_s == 0.1
    assert (
        recorded_config_from_dict({"sim": {"drive": {"sync_timeout_s": 0.5}}}).actuators.sync_watchdog_s
        == 0.5
    )
    assert recorded_config_from_dict({"actuators": {"sync_watchdog_s": 0.3}}).actuators.sync_watchdog_s == 0.3


def test_a_recording_written_before_the_shared_silence_had_its_tolerance_faults_as_it_did():
    # every device silent faulted on loop.max_missing_s (given in seconds or, older, in cycles)
    assert recorded_config_from_dict({"loop": {"max_missing_s": 0.05}}).loop.max_bus_silence_s == 0.05
    old = recorded_config_from_dict({"loop": {"rate_hz": 1000.0, "max_missing_cycles": 40}})
    assert old.loop.max_missing_s == old.loop.max_bus_silence_s == 0.04
    kept = recorded_config_from_dict({"loop": {"max_missing_s": 0.1, "max_bus_silence_s": 0.3}})
    assert kept.loop.max_bus_silence_s == 0.3


def test_a_recorded_contour_run_without_holdups_is_all_in_the_last_bin():
    cycles = read_cycles(str(DATA / "contour_contact.mcap"))
    assert cycles and not any(c.held_up for c in cycles)  # a simulated-time run: the loop is never late
    laps = {c.lap for c in cycles}
    bins = by_cycles_since_holdup(cycles, laps)
    tracking = sum(c.tracking for c in cycles)
    assert tracking > 0 and bins[-1].cycles == tracking and sum(b.cycles for b in bins[:-1]) == 0
    assert drives_held(cycles, laps) == []
