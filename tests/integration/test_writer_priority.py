"""The recording's writer runs real-time below the loop's helpers, so that no normal task starves it
(controller/shell/helper_threads.py: two CPU hogs at nice -20 stopped the demo after lap 2 by
starving it). A real writer process; the scheduler calls are the system's, skipped where refused."""

from __future__ import annotations

import os

import can
import pytest

from controller.config import load_config
from controller.realtime import scheduling_policy
from controller.shell.helper_threads import helper_priority, writer_priority
from logs import messages as m
from logs.reader import iter_decoded
from logs.recorder import SessionRecorder, session_metadata

LOOP_PRIORITY = 80  # the service's default


def _policy(pid: int) -> tuple[int, int]:
    return scheduling_policy(pid), os.sched_getparam(pid).sched_priority


def test_the_writer_s_priority_lies_below_the_helpers_and_above_every_normal_task():
    assert 1 <= writer_priority(LOOP_PRIORITY) < helper_priority(LOOP_PRIORITY) < LOOP_PRIORITY - 10
    assert writer_priority(LOOP_PRIORITY) == 50
    assert writer_priority(20) == 1  # never below SCHED_FIFO's lowest


def test_the_writer_s_main_thread_runs_real_time_and_records_on(tmp_path):
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no SCHED_FIFO on this system")
    path = tmp_path / "w.mcap"
    with SessionRecorder(path, session_metadata(load_config())) as rec:
        pid = rec._proc.pid  # type: ignore[union-attr]  # started by the context
        assert rec.writer_scheduling == "normal scheduler"
        got = rec.raise_writer(writer_priority(LOOP_PRIORITY))
        if got.startswith("normal scheduler (SCHED_FIFO 50 refused"):
            pytest.skip(f"SCHED_FIFO not permitted here: {got}")
        assert got == rec.writer_scheduling == "SCHED_FIFO 50"
        assert _policy(pid) == (os.SCHED_FIFO, 50)
        assert os.sched_getscheduler(pid) & os.SCHED_RESET_ON_FORK  # what it starts later: normal
        threads = {int(t) for t in os.listdir(f"/proc/{pid}/task")}
        others = threads - {pid}
        # its other threads (a live view's server, none here) are left under their scheduler
        assert all(_policy(t)[0] == os.SCHED_OTHER for t in others)
        for k in range(50):
            rec.on_frame(False, float(k), _frame(k))
    assert len(list(iter_decoded(path, [m.TOPIC_CAN]))) == 50  # the recording goes on, every frame in it


def test_a_refused_priority_is_named_and_the_writer_records_on(tmp_path, monkeypatch):
    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    path = tmp_path / "r.mcap"
    with SessionRecorder(path, session_metadata(load_config())) as rec:
        monkeypatch.setattr(os, "sched_setscheduler", refuse)
        got = rec.raise_writer(50)
        monkeypatch.undo()
        assert (
            got
            == rec.writer_scheduling
            == "normal scheduler (SCHED_FIFO 50 refused: Operation not permitted)"
        )
        for k in range(50):
            rec.on_frame(False, float(k), _frame(k))
    assert len(list(iter_decoded(path, [m.TOPIC_CAN]))) == 50


def test_a_writer_that_is_gone_is_left_alone(tmp_path):
    rec = SessionRecorder(tmp_path / "g.mcap", session_metadata(load_config()))
    assert rec.raise_writer(50) == "normal scheduler"  # never started


def _frame(k: int) -> can.Message:
    return can.Message(
        arbitration_id=0x181, data=bytes([k % 256] * 8), is_extended_id=False, timestamp=float(k)
    )
