"""The writer's work bench (controller/tools/bench/writer_work.py) measures the writer doing its real job.

What callgrind counts is ``write_window`` in a second process; these tests run the same function in
this one, on a recorded contour session, and check what it wrote: the session's cycles again, bit
for bit, and each option taking away the part it names (valgrind itself is not needed here).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from controller.tools.bench.writer_work import (
    WARMUP_CYCLES,
    session_records,
    window,
    without_task_values,
    write_window,
    writer_settings,
)
from logs import messages as m
from logs.reader import ReadReport, iter_decoded
from logs.session_writer import CYCLE

SESSION = Path(__file__).resolve().parents[1] / "data" / "contour_contact.mcap"
FIRST, CYCLES = 700, 300  # up to the contour's contact and force loop in this file (1 449 cycles)


def _topics(path: Path) -> dict[str, list[object]]:
    out: dict[str, list[object]] = {}
    for d in iter_decoded(path, None, ReadReport(path)):
        out.setdefault(d.topic, []).append(d.message)
    return out


@pytest.fixture(scope="module")
def session() -> tuple[list[tuple[object, ...]], dict[str, dict[str, str]]]:
    records, metadata, _ = session_records(SESSION)
    return window(records, FIRST, CYCLES), metadata


def test_the_window_rewritten_holds_the_sessions_cycles_bit_for_bit(session, tmp_path):
    records, metadata = session
    out = tmp_path / "w.mcap"
    size = write_window(records, writer_settings(out, metadata), marker=False)
    assert size == out.stat().st_size > 0
    # deterministic: a map's entries in the order of their keys, not of the hash table
    written = [c.SerializeToString(deterministic=True) for c in _topics(out)[m.TOPIC_CYCLE]]
    source = [c.SerializeToString(deterministic=True) for c in _topics(SESSION)[m.TOPIC_CYCLE]]
    assert len(written) == WARMUP_CYCLES + CYCLES
    assert written == source[FIRST : FIRST + WARMUP_CYCLES + CYCLES]
    assert any(c.state.task_values for c in _topics(out)[m.TOPIC_CYCLE])


def test_each_option_takes_away_the_part_it_names(session, tmp_path):
    records, metadata = session
    write_window(records, writer_settings(tmp_path / "whole.mcap", metadata), marker=False)
    whole = _topics(tmp_path / "whole.mcap")
    write_window(
        [without_task_values(r) for r in records],
        writer_settings(tmp_path / "no_task.mcap", metadata),
        marker=False,
    )
    no_task = _topics(tmp_path / "no_task.mcap")[m.TOPIC_CYCLE]
    assert not any(c.state.task_values for c in no_task)
    assert [c.inputs for c in no_task] == [c.inputs for c in whole[m.TOPIC_CYCLE]]
    write_window(
        records, writer_settings(tmp_path / "slow_scene.mcap", metadata, scene_rate_hz=2.0), marker=False
    )
    scenes = len(_topics(tmp_path / "slow_scene.mcap")[m.TOPIC_SCENE])
    assert 1 <= scenes < len(whole[m.TOPIC_SCENE]) / 5  # 20 Hz recorded, 2 Hz asked


def test_a_window_beyond_the_session_is_refused_with_its_length():
    records, _, _ = session_records(SESSION)
    with pytest.raises(ValueError, match="the session has 1449 cycles"):
        window(records, 1400, CYCLES)
    assert sum(1 for r in records if r[0] == CYCLE) == 1449


def test_a_file_that_is_not_a_session_is_refused_in_one_line(tmp_path, capsys):
    from controller.tools.bench.writer_work import main

    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap at all")
    with pytest.raises(SystemExit) as exit_:
        main([str(junk)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "junk.mcap is not an MCAP file" in err and "Traceback" not in err


def test_the_window_carries_the_task_names_once_as_the_recorder_sends_them(session):
    """The writer's path of every cycle (names None), not that of a change of names each cycle."""
    from logs.cycle_encoding import TASK_FIELDS_AT

    records, _ = session
    names = [r[7][TASK_FIELDS_AT][0] for r in records if r[0] == CYCLE and r[7][TASK_FIELDS_AT]]
    carried = [n for n in names if n is not None]
    assert names[0] and 1 <= len(carried) <= 5  # in this window the task's fields change 3 times
    assert all(a != b for a, b in itertools.pairwise(carried))  # carried when changed
