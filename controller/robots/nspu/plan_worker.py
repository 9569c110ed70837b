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

A worker that dies (killed, out of memory) is replaced and the request it had is sent to the new
one, up to ``MAX_RESTARTS`` times a run; a plan that raises is not retried. Either way a request
that never gets its plan is never marked ready: the task faults after
``robot.nspu.correction_plan_timeout_s``, naming it (planned_legs.py). Before, a failed request was
marked ready and the step planned it itself: 0.54 s inside one cycle, and the drives' SYNC
watchdog quick-stopped them (EMCY 0x8240) with nothing naming the worker.
"""

from __future__ import annotations

import gc
import logging
import multiprocessing
import os
import queue
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from functools import partial
from typing import TYPE_CHECKING, Self

from controller.errors import DeviceError
from controller.realtime import reset_scheduler, scheduling_policy
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
MAX_RESTARTS = 3  # worker processes replaced in a run before its requests are left to time out


def _lower_priority() -> None:
    """The worker's initializer: the normal scheduler, nice 10, whatever its parent thread ran at."""
    reset_scheduler()
    os.nice(WORKER_NICE)


def _children_start_normal() -> None:
    """Processes this thread starts begin under the normal scheduler (SCHED_RESET_ON_FORK): the
    loop's helper threads run at SCHED_FIFO (controller/shell/helper_threads.py, which leaves the
    flag alone), and a worker spawned from one inherited it and imported its modules at
    real-time priority."""
    if not hasattr(os, "SCHED_RESET_ON_FORK"):
        return
    policy = scheduling_policy()
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, policy | os.SCHED_RESET_ON_FORK, os.sched_getparam(0))


class PlanWorker:
    """Loop observer and ``plans_ready`` source for a task with a ``correction_planner``. Use as a context manager."""

    def __init__(self, planner: CorrectionPlanner) -> None:
        self.planner = planner
        self._lock = threading.Lock()  # the loop's thread submits, the pool's thread calls _done
        self._pool = self._start_pool()
        self._submitted = 0
        self._ready = 0
        self.restarts = 0
        self._closed = False
        # dead workers are replaced on a thread of this object's, started now: one started by the
        # loop thread when a worker died inherited the loop's SCHED_FIFO priority and CPU, and the
        # process it spawned stalled the loop 0.37-0.42 s (3 runs; the drives' SYNC watchdog FAULT)
        self._replacements: queue.SimpleQueue[tuple[int, PoseRequest, BaseException] | None] = (
            queue.SimpleQueue()
        )
        self._replacer = threading.Thread(target=self._replace_dead, name="plan-worker-replacer", daemon=True)
        self._replacer.start()

    @staticmethod
    def _start_pool() -> ProcessPoolExecutor:
        """A pool of one worker process, started now rather than at the first request."""
        pool = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_lower_priority
        )
        try:
            pool.submit(int).result()
        except BrokenProcessPool as err:
            pool.shutdown(wait=False)
            raise DeviceError(f"the 3-nSPU's planning worker process ended while it started: {err}") from err
        return pool

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with self._lock:
            self._closed = True
        self._replacements.put(None)
        self._replacer.join()  # a replacement under way ends first (its new pool shut down)
        self._pool.shutdown(wait=True, cancel_futures=True)
        # the pools of dead workers (_replace) hold semaphores that only a collection of their
        # reference cycles releases: now, while the resource tracker is still there to unregister
        # them (after it, each printed a FileNotFoundError or BrokenPipeError traceback)
        gc.collect()
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
        self._submit(request_id, task_state.request)  # type: ignore[attr-defined]

    def _submit(self, request_id: int, request: PoseRequest) -> None:
        with self._lock:
            if self._closed:
                return
            try:
                future = self._pool.submit(correction_plan, self.planner.problem, request)
            except (BrokenProcessPool, RuntimeError):  # died while idle, or not replaced (shut down)
                future = Future()  # _done sends it to the replacer
                future.set_exception(BrokenProcessPool("the worker process had ended"))
        future.add_done_callback(partial(self._done, request_id, request))

    def _done(self, request_id: int, request: PoseRequest, future: Future[CorrectionPlan]) -> None:
        if future.cancelled():
            return
        err = future.exception()
        if isinstance(err, BrokenProcessPool):  # the replacer's work: starting a process takes a second
            self._replacements.put((request_id, request, err))
            return
        if err is not None:  # a bug of the planner: not retried, never ready; the task's timeout names it
            log.error("correcting plan %d raised in the worker: %r", request_id, err)
            return
        self.planner.store(request, future.result())
        with self._lock:
            self._ready = max(self._ready, request_id)

    def _replace_dead(self) -> None:
        while (job := self._replacements.get()) is not None:
            self._replace(*job)

    def _replace(self, request_id: int, request: PoseRequest, err: BaseException) -> None:
        """A new worker process for a dead one, and the request again."""
        with self._lock:
            if self._closed:
                return
            dead = self._pool
            replace = self.restarts < MAX_RESTARTS
            self.restarts += replace
        dead.shutdown(wait=True, cancel_futures=True)  # its queues and threads released now, not at exit
        if not replace:
            log.error(
                "correcting plan %d: the worker process died again (%s); %d replaced this run already, "
                "the request is left to the task's timeout",
                request_id,
                err,
                MAX_RESTARTS,
            )
            return
        log.warning(
            "correcting plan %d: the worker process died (%s); a new one takes the request (%d of %d)",
            request_id,
            err,
            self.restarts,
            MAX_RESTARTS,
        )
        try:
            _children_start_normal()
            pool = self._start_pool()
        except DeviceError as start_err:
            log.error("correcting plan %d: %s", request_id, start_err)
            return
        with self._lock:
            closed = self._closed
            if not closed:
                self._pool = pool
        if closed:
            pool.shutdown(wait=True)
            return
        self._submit(request_id, request)
