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

The broadcast manager does not keep a period on its own: it re-arms its timer at
``ktime_get() + ival`` inside the timer's handler (``bcm_tx_set_expiry`` in net/can/bcm.c), so
every interval is ``ival`` plus the timer's wake-up latency, and the SYNC drifts against the
loop's absolute deadlines (2.2-3.1 % long in the emulated vcan VM; microseconds a period on real
hardware, which still add up to a period within seconds at 400 Hz). ``SyncPhaseLock`` therefore
watches the SYNCs (a socket of its own, kernel receive timestamps) and sets the next ``ival`` so
that each SYNC stays ``lead_s`` after a deadline of the loop: a phase-locked loop of type 2 (the
integral learns the mean latency, the proportional part removes the phase error).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
from can.interfaces.socketcan import constants as bcm
from can.interfaces.socketcan.socketcan import CyclicSendTask as SocketcanCyclicSendTask
from can.interfaces.socketcan.socketcan import build_bcm_header, build_can_frame, send_bcm

from controller.core.cycle_data import BusFeedback, CycleOutputs
from controller.errors import InputError
from drivers import cob_ids
from drivers.cyclic_exchange import CyclicExchange


class KernelSyncError(InputError):
    """The kernel's broadcast manager cannot produce SYNC on this bus."""


def check_kernel_sync(interface: str) -> None:
    if interface != "socketcan":
        raise KernelSyncError(
            f"bus.sync_producer = 'kernel' needs a socketcan bus (the kernel's broadcast "
            f"manager); the bus is {interface}: use sync_producer = 'loop'"
        )


def sync_message(fd: bool = False) -> can.Message:
    return can.Message(
        arbitration_id=cob_ids.SYNC, data=b"", is_extended_id=False, is_fd=fd, bitrate_switch=fd
    )


@dataclass
class SyncPhaseLock:
    """The broadcast manager's next interval from the SYNC times seen, so that SYNC n comes at
    ``origin_s + n * period_s`` (pure: times in, interval out).

    With ``ival`` the interval set and ``lat`` the timer's mean latency, a SYNC is late by
    ``e_(n+1) = e_n + ival + lat - period``. ``ival = period - i - kp e`` with ``i += ki e`` drives e
    to 0 with i -> lat: z^2 - (2 - kp) z + (1 - kp + ki), poles 0.9 and 0.8 for the defaults (one
    more, near 0, from the timer already armed with the last interval). The interval is kept within
    ``max_correction`` of the period and is in whole microseconds (the broadcast manager's timeval).
    """

    period_s: float
    kp: float = 0.3
    ki: float = 0.02
    max_correction: float = 0.1
    # the grid every SYNC is held to: KernelSyncExchange sets it to the first SYNC's send time (the
    # loop's grid); left None, the first SYNC seen, latency and all
    origin_s: float | None = None
    integral_s: float = 0.0  # the learned mean latency of the timer
    last_error_s: float = 0.0
    syncs: int = 0

    def update(self, sync_s: float) -> float:
        """A SYNC seen at ``sync_s`` (monotonic): the interval to set now [s]."""
        if self.origin_s is None:
            self.origin_s = sync_s
        t = sync_s - self.origin_s
        error = t - round(t / self.period_s) * self.period_s  # late (+) or early (-) against its slot
        self.last_error_s = error
        self.syncs += 1
        self.integral_s += self.ki * error
        limit = self.max_correction * self.period_s
        correction = min(max(self.integral_s + self.kp * error, -limit), limit)
        return round((self.period_s - correction) * 1e6) * 1e-6


class KernelSyncExchange:
    """The loop's ``Exchange`` with SYNC from the kernel: RPDOs (and heartbeat) from the loop.

    ``exchange`` must be built with ``send_sync=False`` (it then hands over the SYNCs it receives,
    the broadcast manager's, for the phase lock); its bus must be SocketCAN's (or a ``FrameTap`` of
    it), whose ``send_periodic`` is the broadcast manager.
    """

    def __init__(
        self,
        exchange: CyclicExchange,
        period_s: float,
        lead_s: float,
        clock: Callable[[], float] = time.monotonic,
        lock: SyncPhaseLock | None = None,
    ) -> None:
        if exchange.send_sync:
            raise ValueError("the exchange sends SYNC itself: build it with send_sync=False")
        if not 0.0 < lead_s < period_s:
            raise ValueError(f"lead {lead_s} s must be within the period {period_s} s")
        self.exchange = exchange
        self.period_s = period_s
        self.lead_s = lead_s
        self.clock = clock
        self.lock = lock or SyncPhaseLock(period_s)
        self.task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self.first_sync_s = 0.0
        self.stamp_offset_s = 0.0  # receive timestamps' clock minus the loop's
        self._deadline_s: float | None = None  # the next send's cycle deadline (cycle_deadline)
        self.interval_s = period_s  # what the broadcast manager re-arms with now
        self.retimes = 0  # interval changes sent to the broadcast manager

    @property
    def counters(self) -> object:
        return self.exchange.counters

    def cycle_deadline(self, deadline_s: float) -> None:
        """The deadline of the cycle whose send comes next (the loop's ``CycleDeadlines``)."""
        self._deadline_s = deadline_s

    def send(self, outputs: CycleOutputs | None, send_by_s: float = math.inf) -> bool:
        # the cycle's deadline, or (a caller that does not give it) now, within half a period after it
        deadline_s, self._deadline_s = (
            self._deadline_s if self._deadline_s is not None else self.clock(),
            None,
        )
        if self.task is not None:
            self.exchange.cycle_slot = self._cycle_slot(deadline_s)
        in_time = self.exchange.send(outputs, send_by_s)
        if self.task is None:
            self._start(deadline_s + self.lead_s)
            return in_time
        stamps = self.exchange.kernel_sync_stamps
        if stamps:
            interval = self.interval_s
            for stamp in stamps:
                interval = self.lock.update(stamp)
            stamps.clear()
            if interval != self.interval_s:
                self._retime(interval)
        return in_time

    def _start(self, at_s: float) -> None:
        # Once, at the start: spin to the first SYNC's time (a sleep could wake a tick late).
        while self.clock() < at_s:
            pass
        # SYNC n is due at at_s + n periods, lead_s after the loop's deadline n: the grid the lock holds
        # the SYNCs to, on the clock of the receive timestamps (SocketCAN's: CLOCK_REALTIME, a constant
        # offset from the loop's monotonic clock). From the deadline, not from when the first SYNC went
        # or was seen: the first cycle's send came 5-20 ms after its deadline in the emulated VM, and
        # a grid that late took the next cycle's SYNC for this one's, one period behind ever after.
        self.first_sync_s = at_s
        self.stamp_offset_s = time.time() - self.clock()
        if self.lock.origin_s is None:
            self.lock.origin_s = self.first_sync_s + self.stamp_offset_s
        self.exchange.sync_slot_of = self._sync_slot
        task = self.exchange.bus.send_periodic(sync_message(self.exchange.fd), self.period_s)
        if not isinstance(task, can.broadcastmanager.CyclicSendTaskABC):
            raise KernelSyncError(f"python-can returned {type(task).__name__} for a periodic SYNC")
        self.task = task

    def _sync_slot(self, stamp_s: float) -> int:
        """The SYNC period a SYNC received at ``stamp_s`` (its receive timestamp) belongs to."""
        return round((stamp_s - (self.lock.origin_s or 0.0)) / self.period_s)

    def _cycle_slot(self, deadline_s: float) -> int:
        """The SYNC period of the loop's cycle with ``deadline_s``: the SYNC lead_s after it."""
        return round((deadline_s + self.lead_s - self.first_sync_s) / self.period_s)

    def _retime(self, interval_s: float) -> None:
        """The broadcast manager's next intervals: TX_SETUP with SETTIMER and without STARTTIMER
        changes the interval its handler re-arms with, without restarting or sending at once."""
        task = self.task
        if not isinstance(task, SocketcanCyclicSendTask):
            return  # no broadcast manager (a test's bus): nothing to retime
        seconds = int(interval_s)
        header = build_bcm_header(
            bcm.CAN_BCM_TX_SETUP,
            task.flags | bcm.SETTIMER,
            0,
            0,
            0,
            seconds,
            round((interval_s - seconds) * 1e6),
            task.task_id,
            1,
        )
        send_bcm(task.bcm_socket, header + build_can_frame(task.messages[0]))
        self.interval_s = interval_s
        self.retimes += 1

    def report(self) -> dict[str, float | int]:
        """The lock's state for the run summary."""
        return {
            "syncs_seen": self.lock.syncs,
            "interval_us": round(self.interval_s * 1e6, 1),
            "learned_latency_us": round(self.lock.integral_s * 1e6, 1),
            "last_phase_error_us": round(self.lock.last_error_s * 1e6, 1),
            "retimes": self.retimes,
        }

    def collect(self, deadline_s: float) -> BusFeedback:
        return self.exchange.collect(deadline_s)

    def send_controlword_by_sdo(self, drive_index: int, controlword: int) -> None:
        self.exchange.send_controlword_by_sdo(drive_index, controlword)

    def stop(self) -> None:
        """Stop the SYNC (the drives then stop on their SYNC watchdog, as with a silent loop)."""
        if self.task is not None:
            self.task.stop()
            self.task = None
