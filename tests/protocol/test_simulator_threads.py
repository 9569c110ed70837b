"""The simulator's pose thread runs one real-time priority below its cyclic thread when the
simulator runs real-time (sim_backend/server.py ``_follow_pose``): under the normal scheduler a
real-time task of the same CPU (the recording's writer, SCHED_FIFO 50) could keep it off the CPU
while it held the interpreter lock that the cyclic thread waits for."""

from __future__ import annotations

import os
import threading
import time

import can
import pytest
from waiting import GENEROUS_S, wait_until

from controller.config import load_config
from controller.realtime import below_own_priority, scheduling_policy
from sim_backend.server import Simulator

SIM_PRIORITY = 10


def _policy(tid: int) -> tuple[int, int]:
    return scheduling_policy(tid), os.sched_getparam(tid).sched_priority


def _threads(*names: str) -> dict[str, int]:
    found = {t.name: t.native_id for t in threading.enumerate() if t.name in names}
    return {n: tid for n, tid in found.items() if tid is not None}


def test_below_own_priority_lowers_a_real_time_thread_by_one_and_leaves_others():
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no SCHED_FIFO on this system")
    seen: dict[str, tuple[int, int]] = {}

    def at(priority: int | None, key: str) -> None:
        if priority is not None:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        below_own_priority()
        seen[key] = _policy(0)

    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(SIM_PRIORITY))
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except PermissionError:
        pytest.skip("SCHED_FIFO not permitted here")
    for priority, key in ((SIM_PRIORITY, "fifo"), (1, "lowest"), (None, "normal")):
        t = threading.Thread(target=at, args=(priority, key))
        t.start()
        t.join(GENEROUS_S)
    assert seen == {
        "fifo": (os.SCHED_FIFO, SIM_PRIORITY - 1),
        "lowest": (os.SCHED_FIFO, 1),
        "normal": (os.SCHED_OTHER, 0),
    }


def test_the_pose_thread_runs_one_priority_below_the_cyclic_thread():
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no SCHED_FIFO on this system")
    cfg = load_config(overrides={"sensor.enabled": False})
    bus = can.Bus(
        interface="virtual", channel=f"sim-threads-{time.monotonic_ns()}", receive_own_messages=True
    )
    sim = Simulator(cfg, bus)
    started = threading.Event()
    failed: list[BaseException] = []

    def start_real_time() -> None:  # as sim_backend/process.py: real-time, then the threads
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(SIM_PRIORITY))
            sim.start()
        except BaseException as err:  # handed to the test's thread
            failed.append(err)
        started.set()

    starter = threading.Thread(target=start_real_time)
    starter.start()
    try:
        assert started.wait(GENEROUS_S)
        if failed and isinstance(failed[0], PermissionError):
            pytest.skip("SCHED_FIFO not permitted here")
        assert not failed, failed
        wait_until(lambda: len(_threads("sim-cyclic", "sim-pose")) == 2, "the simulator's two threads")
        # the pose thread sets its own at its start
        wait_until(
            lambda: _policy(_threads("sim-pose")["sim-pose"])[1] == SIM_PRIORITY - 1,
            "the pose thread's own priority",
        )
        tids = _threads("sim-cyclic", "sim-pose")
        assert _policy(tids["sim-cyclic"]) == (os.SCHED_FIFO, SIM_PRIORITY)
        assert _policy(tids["sim-pose"]) == (os.SCHED_FIFO, SIM_PRIORITY - 1)
    finally:
        starter.join(GENEROUS_S)
        sim.stop()
        bus.shutdown()
