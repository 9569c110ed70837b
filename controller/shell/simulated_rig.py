"""The in-process rig: the law, the loopback devices and the loop a run over a bus has, on a simulated clock.

What every run in simulated time is built from (``cheope demo --simulated-time``, the contour's
experiment and scans, ``cheope faults``): deterministic, independent of the machine's load. The
clock's wake-ups come late where the simulator's ``stall`` fault says so (``SimulatedTime``'s
``lateness``), its sends are held up where ``send_stall`` says so (``SimulatedTime.hold_up``), and
the loop has the configured late tolerance, so a hold-up of the loop is
reproduced as a run over a bus meets it: a late cycle, then the deadlines it missed skipped.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TYPE_CHECKING, Any

from controller.shell.loop import CycleLoop, LoopStats, SimulatedTime

if TYPE_CHECKING:
    from controller.config import Config
    from controller.core.control_law import ControlLaw
    from controller.core.controller_state import ControllerState
    from controller.core.ports import CycleObserver
    from sim_backend.loopback import LoopbackExchange


# The stop request of the runs of this context (``stopped_by``): a command's signals, which reach
# the rigs an experiment builds inside its own simulated_time() (an entry point's fixed signature).
_STOP_REQUEST: ContextVar[threading.Event | None] = ContextVar("cheope_simulated_stop", default=None)


@contextmanager
def stopped_by(stop: threading.Event) -> Iterator[None]:
    """Every ``SimulatedRig.run`` within stops as a run over a bus does when ``stop`` is set: the
    law brakes, disables the drives and ends DONE (``cheope demo --simulated-time`` and its
    SIGTERM, SIGINT and SIGHUP, as the demo over a bus)."""
    token = _STOP_REQUEST.set(stop)
    try:
        yield
    finally:
        _STOP_REQUEST.reset(token)


class SimulatedRig:
    def __init__(self, cfg: Config) -> None:
        from controller.assembly import build_law
        from sim_backend.loopback import LoopbackExchange

        self.cfg = cfg
        self.clock = SimulatedTime()
        self.law: ControlLaw = build_law(cfg)
        self.exchange: LoopbackExchange = LoopbackExchange(cfg, self.clock.clock, hold_up=self.clock.hold_up)
        self.clock.lateness = self.exchange.stall_s  # the stall fault: the loop wakes late

    def loop(self, observers: tuple[CycleObserver, ...] = (), **options: Any) -> CycleLoop:
        """The loop over the rig; ``options`` are CycleLoop's other keywords (stop events, commands)."""
        cfg = self.cfg
        return CycleLoop(
            self.law,
            self.exchange,
            cfg.period_s,
            cfg.loop.collect_fraction,
            self.clock,
            self.clock.clock,
            observers=observers,
            late_tolerance_s=cfg.safety.late_tolerance_fraction * cfg.period_s,
            **options,
        )

    def run(
        self,
        observers: tuple[CycleObserver, ...] = (),
        max_duration_s: float | None = None,
        linger_after_end_s: float = 0.1,
    ) -> tuple[ControllerState, LoopStats]:
        """From the law's initial state until it ends (or ``max_duration_s`` of simulated time, or
        a stop requested through ``stopped_by``), and ``linger_after_end_s`` after (``CycleLoop.run``)."""
        return self.loop(observers, stop_event=_STOP_REQUEST.get()).run(
            self.law.initial_state(), max_duration_s, linger_after_end_s
        )
