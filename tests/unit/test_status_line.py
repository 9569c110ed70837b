"""The live status line of `cheope demo` / `cheope run` (controller/shell/status_line.py): its text as
a function of the run's state, and when it is shown. Its drawing on a terminal is rich's business."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os

import pytest

from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import CycleInputs, CycleOutputs
from controller.core.ports import CycleTiming
from controller.core.setpoint_smoothing import Setpoint
from controller.shell.status_line import StatusObserver, StatusSnapshot, status_text, status_wanted
from controller.tasks.contour_tracking import ContourPhase, ContourState
from controller.tasks.path_task import PathPhase, PathTaskState

PERIOD_S = 0.0025
INPUTS = CycleInputs(drives=())
OUTPUTS = CycleOutputs(controlwords=(), targets=())
ON_TIME = CycleTiming(wake_error_s=1e-5, step_s=1e-4)
LATE = CycleTiming(wake_error_s=0.5 * PERIOD_S, step_s=1e-4)


def _state(mode: Mode, task_state: object, fault: str = "") -> ControllerState:
    return ControllerState(
        mode=mode,
        cycle=0,
        mode_entered_s=0.0,
        setpoint=Setpoint.at_rest((0.0,) * 3),
        controlwords=(0,) * 3,
        missing_streak=(0,) * 3,
        task_state=task_state,
        tcp_reference_m=None,
        tcp_measured_m=None,
        fault_reason=fault,
    )


def _snapshot(**kw: object) -> StatusSnapshot:
    base = StatusSnapshot(
        run=1,
        elapsed_s=12.5,
        mode="RUNNING",
        phase="TRACKING",
        lap=2,
        laps=5,
        force_error_rms_n=0.314,
        force_error_samples=100,
        late_cycles=3,
    )
    return dataclasses.replace(base, **kw)


def test_the_text_says_phase_lap_force_error_and_late_cycles():
    assert (
        status_text(_snapshot())
        == " 12.5 s  RUNNING  TRACKING  lap 2/5  force error 0.31 N RMS  late cycles 3"
    )


def test_the_text_leaves_out_what_the_task_does_not_have():
    text = status_text(
        _snapshot(
            phase="MOVE_TO_START",
            lap=None,
            laps=None,
            force_error_rms_n=None,
            force_error_samples=0,
            late_cycles=0,
        )
    )
    assert text == " 12.5 s  RUNNING  MOVE_TO_START  late cycles 0"
    assert (
        status_text(_snapshot(mode="CONFIGURING", phase="", lap=None, force_error_rms_n=None))
        == " 12.5 s  CONFIGURING  late cycles 3"
    )
    assert status_text(_snapshot(run=2, elapsed_s=0.5, force_error_rms_n=None)).startswith(
        "run 2    0.5 s  RUNNING  TRACKING  lap 2/5  late"
    )  # the contour demo's comparison run


def test_the_text_names_a_fault():
    text = status_text(_snapshot(mode="FAULT", fault="drive 2: no TPDO for 3 cycles"))
    assert text.endswith("late cycles 3  fault: drive 2: no TPDO for 3 cycles")


def _lines(written: list[bytes]) -> list[StatusSnapshot]:
    return [StatusSnapshot(**json.loads(b)) for b in written]


def test_the_observer_counts_late_and_skipped_cycles_and_the_force_error_while_tracking():
    written: list[bytes] = []
    obs = StatusObserver(written.append, PERIOD_S, laps=5, interval_s=10 * PERIOD_S)
    approach = ContourState(phase=ContourPhase.APPROACH, force_error_n=9.0)  # not counted: not tracking
    for k in range(10):
        obs.on_cycle(k, k * PERIOD_S, INPUTS, _state(Mode.RUNNING, approach), OUTPUTS, (), ON_TIME)
    errors = [0.5, -0.5, 1.0, -1.0, 0.5, -0.5, 1.0, -1.0]
    for i, e in enumerate(errors):  # cycles 10..17, two of them late
        tracking = ContourState(phase=ContourPhase.TRACKING, lap=1, force_error_n=e)
        obs.on_cycle(
            10 + i, 0.0, INPUTS, _state(Mode.RUNNING, tracking), OUTPUTS, (), LATE if i in (2, 5) else ON_TIME
        )
    # the loop skipped cycles 18..22 (an overrun of five deadlines), then cycle 23
    obs.on_cycle(23, 0.0, INPUTS, _state(Mode.RUNNING, tracking), OUTPUTS, (), ON_TIME)
    snaps = _lines(written)
    # one line in each block of 10 cycles: at cycle 0, 10, and 23 (the first after the overrun)
    assert [s.elapsed_s for s in snaps] == [0.0, 10 * PERIOD_S, 23 * PERIOD_S]
    first, _, last = snaps
    assert (first.phase, first.lap, first.force_error_rms_n, first.late_cycles) == ("APPROACH", 1, None, 0)
    assert (last.phase, last.lap, last.laps, last.late_cycles) == ("TRACKING", 2, 5, 2 + 5)
    rms = math.sqrt(sum(e * e for e in [*errors, -1.0]) / 9)
    assert last.force_error_samples == 9 and last.force_error_rms_n == pytest.approx(rms)


def test_a_second_run_starts_counting_again():
    """The contour demo's position-control comparison is a second loop from cycle 0."""
    written: list[bytes] = []
    obs = StatusObserver(written.append, PERIOD_S, interval_s=PERIOD_S)
    tracking = ContourState(phase=ContourPhase.TRACKING, force_error_n=2.0)
    for k in range(3):
        obs.on_cycle(k, 0.0, INPUTS, _state(Mode.RUNNING, tracking), OUTPUTS, (), LATE)
    path = PathTaskState(phase=PathPhase.TRACKING)
    obs.on_cycle(0, 0.0, INPUTS, _state(Mode.FAULT, path, "x"), OUTPUTS, (), ON_TIME)
    snaps = _lines(written)
    assert [(s.run, s.late_cycles) for s in snaps] == [(1, 1), (1, 2), (1, 3), (2, 0)]
    second = snaps[-1]
    assert (second.mode, second.phase, second.lap, second.force_error_rms_n, second.fault) == (
        "FAULT",
        "TRACKING",
        None,
        None,
        "x",
    )


def test_shown_only_on_a_terminal_and_never_with_json():
    assert not status_wanted(False, io.StringIO())  # a pipe, a file: not a terminal
    leader, follower = os.openpty()
    try:
        with os.fdopen(follower, "w", closefd=False) as tty:
            assert status_wanted(False, tty)
            assert not status_wanted(True, tty)
    finally:
        os.close(leader)
        os.close(follower)
    closed = io.StringIO()
    closed.close()
    assert not status_wanted(False, closed)


def test_a_full_pipe_drops_lines_and_never_blocks():
    from controller.shell.status_line import StatusDisplay

    class _Proc:  # the pipe's reader stops reading
        def __init__(self) -> None:
            self.read_fd, write_fd = os.pipe()
            self.stdin = os.fdopen(write_fd, "wb")

        def wait(self, timeout: float | None = None) -> int:
            return 0

    proc = _Proc()
    display = StatusDisplay(proc)  # type: ignore[arg-type]
    line = json.dumps(dataclasses.asdict(_snapshot())).encode() + b"\n"
    try:
        for _ in range(100_000 // len(line) + 1000):
            display.write(line)
        assert display.dropped > 0
    finally:
        display.close()
        os.close(proc.read_fd)
