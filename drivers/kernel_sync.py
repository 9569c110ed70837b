"""SYNC from the kernel's broadcast manager (SocketCAN BCM) instead of the Python loop.

With ``bus.sync_producer = "kernel"`` the SYNC period no longer depends on when the Python loop
wakes up: python-can's ``send_periodic`` on a ``socketcan`` bus hands the frame to the kernel's
broadcast manager (``CAN_BCM`` ``TX_SETUP`` with ``SETTIMER | STARTTIMER``), whose hrtimer sends
it every period on the monotonic clock. The loop then only refreshes the RPDOs ahead of each
SYNC: the task is started ``lead_s`` after the loop's first deadline (the broadcast manager
sends the first frame at once when its timer starts), so every later deadline of the loop falls
``lead_s`` before a SYNC on the same clock and the same period.

A wake-up later than ``lead_s`` lets that cycle's RPDOs miss their SYNC: the drives then
extrapolate the last setpoint (``sim_backend/drive.py``; real drives do what their manufacturer
chose), where with the loop as producer the whole cycle, SYNC included, would have been late.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import can

from controller.core.cycle_data import BusFeedback, CycleOutputs
from controller.errors import InputError
from drivers import cob_ids
from drivers.cyclic_exchange import CyclicExchange


class KernelSyncError(InputError):
    """The kernel's broadcast manager cannot produce SYNC on this bus."""


def check_kernel_sync(interface: str) -> None:
    if interface != "socketcan":
        raise KernelSyncError(f"bus.sync_producer = 'kernel' needs a socketcan bus (the kernel's broadcast "
                              f"manager); the bus is {interface}: use sync_producer = 'loop'")


def sync_message(fd: bool = False) -> can.Message:
    return can.Message(arbitration_id=cob_ids.SYNC, data=b"", is_extended_id=False, is_fd=fd, bitrate_switch=fd)


class KernelSyncExchange:
    """The loop's ``Exchange`` with SYNC from the kernel: RPDOs (and heartbeat) from the loop.

    ``exchange`` must be built with ``send_sync=False``.
    """

    def __init__(self, exchange: CyclicExchange, period_s: float, lead_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if exchange.send_sync:
            raise ValueError("the exchange sends SYNC itself: build it with send_sync=False")
        if not 0.0 < lead_s < period_s:
            raise ValueError(f"lead {lead_s} s must be within the period {period_s} s")
        self.exchange = exchange
        self.period_s = period_s
        self.lead_s = lead_s
        self.clock = clock
        self.task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self.first_sync_s = 0.0

    @property
    def counters(self) -> object:
        return self.exchange.counters

    def send(self, outputs: CycleOutputs | None) -> None:
        self.exchange.send(outputs)
        if self.task is None:
            self._start(self.clock() + self.lead_s)

    def _start(self, at_s: float) -> None:
        # Once, at the start: spin to the first SYNC's time (a sleep could wake a tick late).
        while self.clock() < at_s:
            pass
        self.first_sync_s = self.clock()
        task = self.exchange.bus.send_periodic(sync_message(self.exchange.fd), self.period_s)
        if not isinstance(task, can.broadcastmanager.CyclicSendTaskABC):
            raise KernelSyncError(f"python-can returned {type(task).__name__} for a periodic SYNC")
        self.task = task

    def collect(self, deadline_s: float) -> BusFeedback:
        return self.exchange.collect(deadline_s)

    def stop(self) -> None:
        """Stop the SYNC (the drives then stop on their SYNC watchdog, as with a silent loop)."""
        if self.task is not None:
            self.task.stop()
            self.task = None
