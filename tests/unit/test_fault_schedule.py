"""The injected faults' schedule: a spec written back as text reads as the same fault, and the
faults a run ended before are the ones ``not_reached`` names (the run's ``faults_not_reached``)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.sim_config.fault_specs import (
    KINDS,
    KINDS_WITH_NODE,
    Fault,
    FaultSpecError,
    fault_text,
    parse_fault,
)
from sim_backend.fault_injection import FaultSchedule

# what the grammar writes: non-negative numbers, a value's sign, durations > 0 or none
_seconds = st.floats(min_value=0.0, max_value=1e6, allow_nan=False)


@st.composite
def faults(draw: st.DrawFn) -> Fault:
    kind = draw(st.sampled_from(KINDS))
    return Fault(
        kind=kind,
        start_s=draw(_seconds),
        duration_s=draw(st.one_of(st.just(math.inf), st.floats(min_value=1e-3, max_value=1e6))),
        node=draw(st.integers(1, 127)) if kind in KINDS_WITH_NODE else 0,
        value=draw(st.one_of(st.just(0.0), st.floats(min_value=-1e4, max_value=1e4, allow_nan=False))),
    )


@given(faults())
def test_a_fault_written_as_text_reads_back_as_itself(f: Fault) -> None:
    back = parse_fault(fault_text(f))
    assert back.kind == f.kind and back.node == f.node
    for a, b in ((back.start_s, f.start_s), (back.duration_s, f.duration_s), (back.value, f.value)):
        assert a == b or math.isclose(a, b, rel_tol=1e-5)  # "%g": six significant digits


def test_the_faults_not_reached_are_those_that_start_after_the_last_sync() -> None:
    schedule = FaultSchedule.from_strings(
        ("drop:1@0.5+1", "force=100@60", "freeze@10+0.5", "stall=0.001@9.9")
    )
    assert schedule.not_reached() == (  # no SYNC yet: none reached
        "drop:1@0.5+1",
        "force=100@60",
        "freeze@10+0.5",
        "stall=0.001@9.9",
    )
    for k in range(4001):  # SYNCs at 400 Hz from t = 100 s (the schedule's 0) to its 10 s
        schedule.start(100.0 + k * 0.0025)
    assert schedule.not_reached() == ("force=100@60",)
    assert FaultSchedule(()).not_reached() == ()


@pytest.mark.parametrize("kind", [k for k in KINDS if k not in KINDS_WITH_NODE])
def test_a_node_given_to_a_kind_that_takes_none_is_refused_not_ignored(kind: str) -> None:
    # an outside tester's --inject saturate:16@2 ran as saturate@2, the node dropped without a word
    with pytest.raises(FaultSpecError, match=rf"{kind}:16@2.*{kind} takes no node id"):
        parse_fault(f"{kind}:16@2")
    assert parse_fault(f"{kind}@2").node == 0


@pytest.mark.parametrize("kind", KINDS_WITH_NODE)
def test_a_kind_that_needs_a_node_is_refused_without_one(kind: str) -> None:
    with pytest.raises(FaultSpecError, match=rf"{kind} needs a node id"):
        parse_fault(f"{kind}@2")


def _syncs(schedule: FaultSchedule, first_s: float, count: int, period_s: float = 0.0025) -> list[str]:
    """Each SYNC of a 400-Hz grid from ``first_s``: the kinds active at it, as the devices ask."""
    seen = []
    for k in range(count):
        now = first_s + k * period_s
        schedule.start(now)
        seen.append(" ".join(f.kind for f in schedule.faults if schedule.active(f.kind, now, f.node)))
    return seen


@pytest.mark.parametrize("first_s", [0.0025, 0.0, 7.3, 1234.5678])
@pytest.mark.parametrize("k", [1, 2, 3, 7, 400, 1481])
def test_a_fault_of_one_period_on_the_sync_grid_is_active_at_exactly_one_sync(first_s: float, k: int) -> None:
    # `stall=0.02@0.005+0.0025` injected nothing in simulated time: its SYNC read 0.004999999999999999
    # (0.0075 - 0.0025), before the window, and the next one read its end
    start = round(k * 0.0025, 9)
    schedule = FaultSchedule.from_strings((f"freeze@{start:g}+0.0025",))
    seen = _syncs(schedule, first_s, k + 3)
    assert seen.count("freeze") == 1 and seen.index("freeze") == k
    assert schedule.missed() == () and schedule.not_reached() == ()


def test_faults_active_at_no_sync_are_missed_and_the_others_not() -> None:
    schedule = FaultSchedule.from_strings(
        ("drop:1@0.0051+0.001", "drop:2@0.01+0.0025", "freeze@0.0051+0.001", "force=3@9", "drift=0.5@0.001")
    )
    # the SYNCs of a loop held up from 0.0025 s to 0.0175 s: none between
    for now in (0.0, 0.0025, 0.0175, 0.02):
        schedule.start(now)
        schedule.active("drop", now, 1)  # node 1 sends a TPDO at each SYNC; node 2 never does
        schedule.active("freeze", now)
        schedule.with_drift_n(now, 0.0)
    assert schedule.not_reached() == ("force=3@9",)
    # node 2's drop: its drive sent nothing to drop; the others' windows fell between two SYNCs
    assert schedule.missed() == ("drop:1@0.0051+0.001", "drop:2@0.01+0.0025", "freeze@0.0051+0.001")
    one_shot = FaultSchedule.from_strings(("drive_fault:1@0",))
    one_shot.start(0.0)
    assert one_shot.first_time("drive_fault", 0.0, 1) and one_shot.missed() == ()
