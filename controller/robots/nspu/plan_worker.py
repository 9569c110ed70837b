"""Plans computed off the loop: the 3-nSPU's correcting plans, in a worker process.

The planned task (controller/robots/nspu/planned_legs.py) asks for a plan by putting a request in its
state (``request_id``, ``request``: the measured pose). This observer sees the state after each
step and hands a new request to one worker process, which runs the same pure function the step
would (``plan_correction.correction_plan``); the result goes into the task's memo, and
``ready()`` returns the request's number, which the loop passes to the next step as
``CycleInputs.plans_ready`` (a recorded input). The step then takes the plan from the memo; a
replay, with no worker, computes the same plan from the same request inside the step.

A process, not a thread: a planning thread held the GIL for most of its 0.3-1 s, the loop missed
its cycles (375 overruns in one run) and the drives quick-stopped on the lost controller
heartbeat (EMCY 0x8130). The process runs at a lower priority (nice 10) so that the loop and the
simulator keep the CPUs. It is started (spawn: no fork of a threaded process) when the run starts.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from functools import partial
from typing import TYPE_CHECKING, Self

from controller.robots.nspu.plan_correction import (
    CorrectionPlan,
    CorrectionPlanner,
    PoseRequest,
    correction_plan,
)

if TYPE_CHECKING:
    from controller.core.controller_state import ControllerState
    from controller.core.cycle_data import CycleInputs, CycleOutputs, Event
    from controller.core.ports import CycleTiming

log = logging.getLogger(__name__)
WORKER_NICE = 10


def _lower_priority() -> None:
    os.nice(WORKER_NICE)


class PlanWorker:
    """Loop observer and ``plans_ready`` source for a task with a ``correction_planner``. Use as a context manager."""

    def __init__(self, planner: CorrectionPlanner) -> None:
        self.planner = planner
        self._pool = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_lower_priority
        )
        self._pool.submit(int).result()  # start the process now, not at the first request
        self._submitted = 0
        self._ready = 0
        self._lock = threading.Lock()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        # spawn started multiprocessing's resource tracker process for the pool's queues; nothing
        # else in this program uses multiprocessing, so it ends with the pool rather than at exit
        from multiprocessing import resource_tracker

        resource_tracker._resource_tracker._stop()  # type: ignore[attr-defined]

    def ready(self) -> int:
        with self._lock:
            return self._ready

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
        task_state = state.task_state
        request_id = getattr(task_state, "request_id", 0)
        if request_id <= self._submitted:
            return
        self._submitted = request_id
        request: PoseRequest = task_state.request  # type: ignore[attr-defined]
        future = self._pool.submit(correction_plan, self.planner.problem, request)
        future.add_done_callback(partial(self._done, request_id, request))

    def _done(self, request_id: int, request: PoseRequest, future: Future[CorrectionPlan]) -> None:
        if future.cancelled():
            return
        err = future.exception()
        if err is not None:  # the step will plan it itself and fault with the reason
            log.error("correcting plan %d failed in the worker: %s", request_id, err)
        else:
            self.planner.store(request, future.result())
        with self._lock:
            self._ready = max(self._ready, request_id)
