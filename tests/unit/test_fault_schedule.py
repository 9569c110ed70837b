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
