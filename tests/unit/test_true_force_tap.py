"""The simulator's true contact force shared with the demo (sim_backend/true_force_tap.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sim_backend.true_force_tap import PREFIX, TrueForceReader, TrueForceTap


def test_the_reader_sees_what_another_process_writes_and_removes_the_block():
    reader = TrueForceReader(f"cheope-true-force-test-{os.getpid()}")
    assert reader.read() == (0.0, 0.0, 0.0)  # before the first SYNC
    code = (
        "from sim_backend.true_force_tap import TrueForceTap\n"
        f"t = TrueForceTap({reader.name!r}); t.write(10.0, 1.5, -2.0, 0.25); t.write(10.001, 3.0, 4.0, 0.0)\n"
        "t.write(10.002, 5.0, 6.0, 0.5); t.close()"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
    assert reader.read() == (5.0, 6.0, 0.5)  # the latest write, whole
    # a cycle observed after the next SYNC reached the simulator: the force of its own SYNC
    assert reader.read(10.0015) == (3.0, 4.0, 0.0)
    assert reader.read(10.0005) == (3.0, 4.0, 0.0)  # two SYNCs behind: the older of the two kept
    assert reader.read(float("nan")) == (5.0, 6.0, 0.5)
    reader.close()
    assert not os.path.exists(reader.name)
    with pytest.raises(FileNotFoundError):  # the simulator given a block nobody made
        TrueForceTap(reader.name)


def test_a_process_pool_beside_it_does_not_take_the_block_away():
    """multiprocessing's resource tracker removed a shared_memory block under the 3-nSPU demo, which
    uses a process pool; a plain mapped file is the reader's alone."""
    from concurrent.futures import ProcessPoolExecutor

    reader = TrueForceReader(f"cheope-true-force-test-pool-{os.getpid()}")
    with ProcessPoolExecutor(1) as pool:
        assert pool.submit(abs, -1).result() == 1
    assert os.path.exists(reader.name)
    reader.close()


def test_a_block_left_by_a_killed_demo_is_removed_by_the_next_one_and_a_live_ones_is_kept():
    """A demo killed with SIGKILL cannot remove its block: each left a file in /dev/shm (an outside
    tester's finding, 44dbcbc). The next demo removes the blocks of processes that are gone."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its pid is free now (reused within this test only by a very busy machine)
    live = TrueForceReader(f"{PREFIX}{os.getpid()}-2")
    stale = TrueForceReader(f"{PREFIX}{gone.pid}-1")
    stale._map.close()  # killed: the block stays behind
    try:
        assert stale.path.exists() and live.path.exists()
        new = TrueForceReader(f"{PREFIX}{os.getpid()}-3")
        assert not stale.path.exists() and live.path.exists() and new.path.exists()
        new.close()
    finally:
        live.close()
        stale.path.unlink(missing_ok=True)
