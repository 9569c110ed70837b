"""The simulator's true contact force shared with the demo (sim_backend/true_force_tap.py)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sim_backend.true_force_tap import PREFIX, TrueForceReader, TrueForceTap, tap_path


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


def test_a_block_left_by_a_killed_demo_of_an_earlier_version_is_removed_and_a_live_ones_is_kept():
    """Before the blocks were memory files a demo killed with SIGKILL left its named block in
    /dev/shm (an outside tester's finding, 44dbcbc). A new reader removes the named blocks of
    processes that are gone."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its pid is free now (reused within this test only by a very busy machine)
    live, stale = tap_path(f"{PREFIX}{os.getpid()}-2"), tap_path(f"{PREFIX}{gone.pid}-1")
    try:
        for block in (live, stale):
            block.write_bytes(bytes(72))
        new = TrueForceReader(f"{PREFIX}{os.getpid()}-3")
        assert not stale.exists() and live.exists()
        assert not tap_path(f"{PREFIX}{os.getpid()}-3").exists()  # the new block has no name there
        new.close()
    finally:
        live.unlink(missing_ok=True)
        stale.unlink(missing_ok=True)


def test_the_block_cannot_be_shrunk_under_its_readers():
    """An outside tester's ``truncate -s 0`` of the block in /dev/shm killed the demo with SIGBUS at
    its next read (exit code 135, no summary): the block is sealed against it now."""
    reader = TrueForceReader(f"cheope-true-force-test-seal-{os.getpid()}")
    try:
        writer = TrueForceTap(reader.name)
        writer.write(1.0, 2.0, 3.0, 4.0)
        for shrink in (lambda: os.truncate(reader.name, 0), lambda: os.truncate(reader.name, 8)):
            with pytest.raises(PermissionError):
                shrink()
        with pytest.raises(PermissionError):  # nor grown, which would leave the two mappings apart
            os.truncate(reader.name, 4096)
        assert os.stat(reader.name).st_size == 72
        writer.write(1.1, 5.0, 6.0, 7.0)
        assert reader.read() == (5.0, 6.0, 7.0)  # both still mapped, both whole
        writer.close()
    finally:
        reader.close()
