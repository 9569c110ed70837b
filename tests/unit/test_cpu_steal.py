"""The run summary's ``steal_s`` (controller/shell/cpu_steal.py): each CPU's steal column of
``/proc/stat`` between two readings, in seconds."""

from __future__ import annotations

import os
from pathlib import Path

from controller.shell.cpu_steal import steal_s_since, steal_ticks

STAT = """cpu  7515997 98764 689893 7723427 15134 0 42227 {total} 0 0
cpu0 3472728 27524 357093 4164636 2585 0 20199 {cpu0} 0 0
cpu1 4043268 71239 332799 3558791 12548 0 22028 {cpu1} 0 0
intr 1 2 3
ctxt 42
"""


def _stat(tmp_path: Path, cpu0: int, cpu1: int) -> str:
    p = tmp_path / "stat"
    p.write_text(STAT.format(total=cpu0 + cpu1, cpu0=cpu0, cpu1=cpu1))
    return str(p)


def test_each_cpus_steal_over_the_run_in_seconds(tmp_path: Path) -> None:
    before = steal_ticks(_stat(tmp_path, 1854, 1726))
    assert before == {"cpu0": 1854, "cpu1": 1726}  # the machine's total line is not a CPU
    after = _stat(tmp_path, 1854 + 11, 1726)
    tick_s = 1 / os.sysconf("SC_CLK_TCK")
    assert steal_s_since(before, after) == {"cpu0": round(11 * tick_s, 3), "cpu1": 0.0}


def test_no_file_or_no_steal_column_gives_nothing(tmp_path: Path) -> None:
    assert steal_ticks(str(tmp_path / "missing")) == {}
    old = tmp_path / "old_stat"
    old.write_text("cpu0 1 2 3 4\ncpu1 1 2 3 4\n")  # a kernel before the steal column
    assert steal_ticks(str(old)) == {}
    assert steal_s_since({}, str(old)) == {}


def test_this_machine_reads() -> None:
    """On Linux every online CPU has a reading (zero on bare metal), and it never runs back."""
    before = steal_ticks()
    assert before and all(t >= 0 for t in before.values())
    assert all(s >= 0.0 for s in steal_s_since(before).values())
