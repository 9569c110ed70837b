"""The memory squeeze: a neighbour that holds the machine's available memory near a floor while a
command runs (controller/tools/bench/memory_squeeze.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from controller.tools.bench.memory_squeeze import available_mb, main

TAKE_MB = 400  # well above the squeeze's band (3 blocks of 16 MiB), small for any machine that runs the suite


def _squeezers(floor_mb: int) -> list[int]:
    """Process ids of the squeeze children holding ``floor_mb``."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"controller.tools.bench.memory_squeeze" in args and str(floor_mb).encode() in args:
            found.append(int(pid))
    return found


def test_the_command_runs_with_the_memory_taken_and_the_squeeze_ends_with_it():
    floor = available_mb() - TAKE_MB
    seen = "import sys; from controller.tools.bench.memory_squeeze import available_mb as a; print(a()); sys.exit(3)"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller.tools.bench.memory_squeeze",
            "--floor-mb",
            str(floor),
            "--",
            sys.executable,
            "-c",
            seen,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 3, done.stderr  # the command's own exit code
    held = int(done.stderr.split("floor reached: ")[1].split(" MB held")[0])
    assert held >= TAKE_MB // 2, done.stderr  # it took memory before the command began
    assert int(done.stdout) < floor + TAKE_MB // 2  # and the command ran short of it
    assert '"blocks_written"' in done.stderr
    assert _squeezers(floor) == []  # the squeeze's child is gone with the command


def test_a_floor_beyond_the_machines_memory_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--floor-mb", "99999999", "--", "true"])
    assert exit_.value.code == 2
    assert "--floor-mb 99999999: must be 0 to" in capsys.readouterr().err
