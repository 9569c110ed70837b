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


def _devices_after(specs: tuple[str, ...], now_s: float):  # type: ignore[no-untyped-def]
    """The loopback's simulated devices after ``specs`` are applied at the SYNCs 0 s and ``now_s``."""
    from controller.config import load_config
    from controller.shell.loop import SimulatedTime
    from sim_backend.fault_injection import apply_device_faults
    from sim_backend.loopback import LoopbackExchange

    cfg = load_config()
    loopback = LoopbackExchange(cfg, SimulatedTime().clock)
    schedule = FaultSchedule.from_strings(specs)
    for t in (0.0, now_s):
        apply_device_faults(schedule, loopback.plant, loopback.drive_ids, t)
    return loopback.plant, schedule


def test_offsets_of_one_kind_at_once_add_up_and_both_act() -> None:
    """``force=3@1+1`` with ``force=4@1.5+0.5`` offset the sensor by 7 N where both are active (an
    outside tester: it was 3 N, and the second was listed as missed); two jumps of one drive add."""
    plant, schedule = _devices_after(
        ("force=3@1+1", "force=4@1.5+0.5", "jump:1=0.001@1", "jump:1=0.002@1.2"), 1.6
    )
    assert plant.sensor is not None and plant.sensor.extra_force_n == (7.0, 0.0, 0.0)
    assert plant.drives[0].reported_position_error == pytest.approx(0.003)
    assert plant.drives[1].reported_position_error == 0.0
    assert schedule.missed() == ()
    plant, _ = _devices_after(("force=3@1+1", "force=4@1.5+0.5"), 1.2)
    assert plant.sensor is not None and plant.sensor.extra_force_n == (3.0, 0.0, 0.0)


def test_an_on_off_fault_inside_another_of_its_kind_acts_with_it() -> None:
    schedule = FaultSchedule.from_strings(("drop:1@1+1", "drop:1@1.2+0.2", "freeze@1+1", "freeze@1.5+0.1"))
    for now in (0.0, 1.3, 1.55, 2.5):
        schedule.start(now)
        schedule.active("drop", now, 1)
        schedule.active("freeze", now)
    assert schedule.missed() == ()


def test_commands_of_one_kind_at_once_each_go_on_the_bus() -> None:
    """``nmt_stop:2`` with ``nmt_stop:3`` at one time: two NMT commands, not the first alone."""
    from sim_backend.fault_injection import bus_faults, nmt_commands

    schedule = FaultSchedule.from_strings(
        ("nmt_stop:2@1+0.0025", "nmt_stop:3@1+0.0025", "rogue_emcy:1@1+0.0025", "rogue_emcy:2@1+0.0025")
    )
    schedule.start(0.0)
    frames = bus_faults(schedule, 1.0, (1, 2, 3, 16)).foreign_frames
    assert nmt_commands(frames) == [(0x02, 2), (0x02, 3)]
    assert [cob for cob, _ in frames if 0x081 <= cob <= 0x0FF] == [0x081, 0x082]
    assert schedule.missed() == ()


def test_one_shot_faults_due_at_one_time_are_one_event() -> None:
    """Two ``drive_fault:2@2+0.0025``: the second was listed as missed (an outside tester); two
    endless ``reboot:1@1`` rebooted the node twice, a SYNC apart."""
    schedule = FaultSchedule.from_strings(
        ("drive_fault:2@2+0.0025", "drive_fault:2@2+0.0025", "reboot:1@1", "reboot:1@1")
    )
    schedule.start(0.0)
    assert schedule.first_time("drive_fault", 2.0, 2) and schedule.first_time("reboot", 2.0, 1)
    assert not schedule.first_time("drive_fault", 2.0025, 2) and not schedule.first_time("reboot", 2.0025, 1)
    assert schedule.missed() == ()


def test_a_fault_that_acts_with_a_stronger_one_is_not_missed() -> None:
    """``error_frames`` inside ``bus_off``, ``malformed`` inside a ``drop`` of the same drive."""
    from sim_backend.fault_injection import bus_faults, tpdo_payload

    schedule = FaultSchedule.from_strings(
        ("bus_off@1+1", "error_frames@1.2+0.1", "drop:1@1+1", "malformed:1@1.2+0.1")
    )
    schedule.start(0.0)
    for now in (1.25, 2.5):  # in their windows, then past them all
        schedule.start(now)
        bus_faults(schedule, now, (1, 2, 3, 16))
        tpdo_payload(schedule, 1, bytes(8), now)
    assert tpdo_payload(schedule, 1, bytes(8), 1.25) is None
    assert schedule.missed() == ()
