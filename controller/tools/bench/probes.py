"""Probes on the real loop: the loop thread's timing and the CPU use of the controller and the simulator processes."""

from __future__ import annotations

import math
import os
import time
from typing import TYPE_CHECKING

import numpy as np

from controller.child_process import process_cpu_s
from drivers import cob_ids

if TYPE_CHECKING:
    import can

    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
    from controller.core.ports import CycleTiming


class LoopProbe:
    """Observer and frame sink of one ``run_controller`` run; preallocated, a few hundred ns a call.

    Per cycle k it keeps: the wake error and step time (from the loop's ``CycleTiming``), how
    long after this cycle's SYNC went out its last TPDO arrived (the devices' answer), how long
    after that the step was done (``CycleTiming.stepped_s``), and how long after it the first RPDO
    of cycle k + 1 went out. Over a bus the loop hands cycle k to its observers after cycle k+1's
    SYNC (in its answer window: controller/shell/loop.py, step 5), so the frames are paired by
    time: a SYNC sent after cycle k's step closes cycle k's answer. It also counts every frame on
    the bus by COB-ID for the measured bus load, and samples CPU times once a second (the loop
    thread's own, the process's, the simulator's).
    """

    def __init__(
        self,
        capacity: int,
        tpdo_ids: frozenset[int],
        first_rpdo_id: int,
        sim_pid: int | None,
        sample_every: int,
    ) -> None:
        self.capacity = capacity
        self.wake_error_s = np.zeros(capacity)
        self.step_s = np.zeros(capacity)
        self.deadline_index = np.zeros(capacity, dtype=np.int64)
        self.ready_after_tpdo_s = np.full(capacity, np.nan)  # last TPDO in -> step done
        self.rpdo_after_tpdo_s = np.full(capacity, np.nan)  # last TPDO in -> first RPDO of the next cycle out
        self.answer_s = np.full(capacity, np.nan)  # SYNC out -> last TPDO in
        self.n = 0
        self._tpdo_ids = tpdo_ids
        self._first_rpdo_id = first_rpdo_id
        self._sync_s = math.nan  # the latest SYNC out
        self._sync_before_s = math.nan  # the one before it
        self._last_tpdo_s = math.nan  # the latest TPDO in
        self._tpdo_at_sync_s = math.nan  # the latest TPDO in when the latest SYNC went out
        self._rpdo_s = math.nan  # the latest send's first RPDO out
        self._rpdo_pending: tuple[int, float] | None = None  # (cycle index, its last TPDO): no RPDO yet
        self.frames: dict[int, int] = {}  # COB-ID -> frames received once the loop runs
        self.frames_out: dict[int, int] = {}  # COB-ID -> frames sent once the loop runs
        self.frame_shape: dict[int, tuple[int, bool, bool]] = {}  # COB-ID -> (bytes, is_fd, brs)
        self.sim_pid = sim_pid
        self.sample_every = sample_every
        self.samples: list[tuple[float, ...]] = []  # (monotonic, thread, process, sim, writer) [s]
        self.writer_pid: int | None = None  # the MCAP writer process, found among our children

    def sink(self, outgoing: bool, t: float, msg: can.Message) -> None:
        cid = msg.arbitration_id
        if self.n > 0:  # the bus load of the cyclic traffic: node set-up frames are not counted
            counts = self.frames_out if outgoing else self.frames
            k = counts.get(cid)
            if k is None:
                self.frame_shape[cid] = (len(msg.data), bool(msg.is_fd), bool(msg.bitrate_switch))
                k = 0
            counts[cid] = k + 1
        if outgoing:
            if cid == cob_ids.SYNC:
                self._sync_before_s, self._sync_s = self._sync_s, t
                self._tpdo_at_sync_s = self._last_tpdo_s
            elif cid == self._first_rpdo_id:
                self._rpdo_s = t
                if self._rpdo_pending is not None:  # observed before its next send (simulated time)
                    i, last_tpdo_s = self._rpdo_pending
                    self.rpdo_after_tpdo_s[i] = t - last_tpdo_s
                    self._rpdo_pending = None
            return
        if cid in self._tpdo_ids:
            self._last_tpdo_s = t

    def on_cycle(
        self,
        cycle: int,
        t: float,
        inputs: CycleInputs,
        state: ControllerState,
        outputs: CycleOutputs,
        events: tuple[Event, ...],
        timing: CycleTiming,
    ) -> None:
        now = time.monotonic()
        stepped = timing.stepped_s if math.isfinite(timing.stepped_s) else now
        i = self.n
        if i < self.capacity:
            self.wake_error_s[i] = timing.wake_error_s
            self.step_s[i] = timing.step_s
            self.deadline_index[i] = cycle
            if self._sync_s > stepped:  # the next cycle's SYNC is out: it closed this cycle's answer
                sync, last_tpdo = self._sync_before_s, self._tpdo_at_sync_s
                self.rpdo_after_tpdo_s[i] = self._rpdo_s - last_tpdo if self._rpdo_s > stepped else math.nan
                self._rpdo_pending = None
            else:
                sync, last_tpdo = self._sync_s, self._last_tpdo_s
                self._rpdo_pending = (i, last_tpdo)
            self.ready_after_tpdo_s[i] = stepped - last_tpdo
            self.answer_s[i] = last_tpdo - sync
        self.n = i + 1
        if i % self.sample_every == 0:
            if self.writer_pid is None:
                self.writer_pid = child_pid("logs.session_writer")
            self.samples.append(
                (
                    now,
                    time.thread_time(),
                    time.process_time(),
                    process_cpu_s(self.sim_pid),
                    process_cpu_s(self.writer_pid),
                )
            )


def child_pid(command_fragment: str) -> int | None:
    """The pid of a child of this process whose command line contains ``command_fragment``."""
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
            if ppid != me:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                if command_fragment.encode() in f.read():
                    return int(entry)
        except (OSError, ValueError, IndexError):
            continue
    return None


def cpu_use_percent(samples: list[tuple[float, ...]]) -> dict[str, float | None]:
    """CPU use between the first and the last sample, in % of one CPU."""
    keys = ("loop_thread", "controller_process", "simulator_process", "writer_process")
    if len(samples) < 2:
        return dict.fromkeys(keys)
    first, last = samples[0], samples[-1]
    dt = last[0] - first[0]

    def pct(a: float, b: float) -> float | None:
        return None if math.isnan(a) or math.isnan(b) else round(100.0 * (b - a) / dt, 1)

    # the writer starts after the first sample: take its first known value
    writer0 = next((x[4] for x in samples if not math.isnan(x[4])), math.nan)
    writer_dt = next((last[0] - x[0] for x in samples if not math.isnan(x[4])), dt)
    writer = (
        None
        if math.isnan(writer0) or math.isnan(last[4]) or writer_dt <= 0
        else round(100.0 * (last[4] - writer0) / writer_dt, 1)
    )
    return {
        "loop_thread": pct(first[1], last[1]),
        "controller_process": pct(first[2], last[2]),
        "simulator_process": pct(first[3], last[3]),
        "writer_process": writer,
    }
