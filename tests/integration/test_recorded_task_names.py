"""The task fields' names go to the writer only when they change (logs/recorder.py ``on_cycle``):
every recorded cycle still carries its own names and values, whatever records the pipe dropped."""

from __future__ import annotations

import dataclasses
import os
import pickle
import select
import signal

from test_recording import record_session

from controller.config import load_config
from controller.core.records import replace
from logs import messages as m
from logs.cycle_encoding import TASK_FIELDS_AT, cycle_values, task_values, with_task_names
from logs.reader import iter_decoded, read_info
from logs.recorder import SessionRecorder, session_metadata
from logs.session_writer import CYCLE, SessionWriter


@dataclasses.dataclass(frozen=True)
class _TaskState:
    lap: int
    held_force: tuple[float, float] | None


def _task_state(k: int) -> _TaskState:
    """The names change every 3 cycles: ("lap",), then ("lap", "held_force.0", "held_force.1")."""
    return _TaskState(lap=k, held_force=(0.5 * k, -0.5 * k) if (k // 3) % 2 else None)


class _Timing:
    wake_error_s = 0.0
    step_s = 0.0


def test_the_names_are_sent_with_the_first_cycle_and_again_only_when_they_change(tmp_path):
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.1, frames=False)
    inputs, state, outputs = trace.rows[0][2:5]
    rec = SessionRecorder(tmp_path / "n.mcap", session_metadata(load_config()))
    sent: list[tuple] = []
    real_send = rec._send

    def keep(record: bytes, items: int) -> None:
        sent.append(pickle.loads(record[4:]))
        real_send(record, items)

    rec._send = keep  # type: ignore[method-assign]
    with rec:
        for k in range(9):
            rec.on_cycle(
                k, k * 0.0025, inputs, replace(state, task_state=_task_state(k)), outputs, (), _Timing()
            )
    names = [r[7][TASK_FIELDS_AT][0] for r in sent if r[0] == CYCLE]
    lap, held = ("lap",), ("lap", "held_force.0", "held_force.1")
    assert names == [lap, None, None, held, None, None, lap, None, None]
    recorded = {
        d.message.cycle: dict(d.message.state.task_values) for d in iter_decoded(rec.path, [m.TOPIC_CYCLE])
    }
    assert recorded == {k: task_values(_task_state(k)) for k in range(9)}


def test_records_dropped_with_new_names_never_leave_a_cycle_under_the_wrong_names(tmp_path):
    """The writer stops reading (SIGSTOP) while the names change every 3 cycles, so records that
    carried new names are dropped: a record is marked as having given the writer its names only
    when it went into the pipe, so each recorded cycle reads back with its own names and values."""
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.1, frames=False)
    inputs, state, outputs = trace.rows[0][2:5]
    rec = SessionRecorder(tmp_path / "d.mcap", session_metadata(load_config()), buffer_bytes=4096)
    k = 0

    def cycle() -> None:
        nonlocal k
        rec.on_cycle(k, k * 0.0025, inputs, replace(state, task_state=_task_state(k)), outputs, (), _Timing())
        k += 1

    with rec:
        for _ in range(10):
            cycle()
        os.kill(rec._proc.pid, signal.SIGSTOP)
        try:
            while rec.dropped < 40:  # the pipe and the backlog full, then records dropped
                cycle()
                assert k < 100_000, "nothing was dropped"
        finally:
            os.kill(rec._proc.pid, signal.SIGCONT)
        for _ in range(30):  # each when the writer has read what came before: none dropped
            for _ in range(100):
                select.select([], [rec._fd], [], 10.0)  # the pipe has room again
                rec._write_backlog()
                if not rec._backlog:
                    break
            select.select([], [rec._fd], [], 10.0)
            dropped = rec.dropped
            cycle()
            assert rec.dropped == dropped, "the writer did not read again"
    recorded = {
        d.message.cycle: dict(d.message.state.task_values) for d in iter_decoded(rec.path, [m.TOPIC_CYCLE])
    }
    assert 0 < len(recorded) < k and rec.dropped >= 40
    assert set(range(k - 30, k)) <= set(recorded)  # the cycles after the writer went on
    wrong = {c: v for c, v in recorded.items() if v != task_values(_task_state(c))}
    assert not wrong


def test_a_record_without_names_before_any_stops_the_recording_with_the_file_whole(tmp_path):
    """A malformed stream (values without the names they refer to) is named, not guessed at: the
    recording stops, and the cycles before are in a complete file."""
    _, _, _, trace, _, _ = record_session(tmp_path / "ref.mcap", max_s=0.1, frames=False)
    inputs, state, outputs = trace.rows[0][2:5]
    path = tmp_path / "cheope-20260101-000000.mcap"
    settings = {
        "path": str(path),
        "metadata": session_metadata(load_config()),
        "clock_offset_ns": 0,
        "chunk_size_bytes": 1024,
        "flush_interval_s": 0.5,
        "compression": "zstd",
        "session_id": "s" * 32,
    }
    w = SessionWriter(settings)
    plain = cycle_values(0, 0.0, inputs, replace(state, task_state=None), outputs, _Timing())
    w.write((CYCLE, 0, [], 0, 0.0, 0.0, 0, plain, (), None, None))
    named = cycle_values(1, 0.0025, inputs, replace(state, task_state=_task_state(1)), outputs, _Timing())
    nameless = with_task_names(named, None)
    w.write((CYCLE, 0, [], 1, 0.0025, 0.0025, 1, nameless, (), None, None))
    assert w.stopped.startswith("cycle 1 cannot be recorded (ValueError: task values without their names")
    w.finish(2, 0)
    info = read_info(path)
    assert info.complete and info.message_counts[m.TOPIC_CYCLE] == 1
