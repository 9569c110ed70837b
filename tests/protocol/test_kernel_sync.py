"""``bus.sync_producer = "kernel"`` off SocketCAN: refused before anything opens, naming the key.

Its behaviour on SocketCAN is tested in tests/vcan/test_kernel_sync_on_vcan.py.
"""

from __future__ import annotations

import random
import re
import statistics
from collections import deque
from collections.abc import Callable

import can
import pytest
from kernel_sync_exchange import quiet_exchange
from stepping_clock import SteppingClock

from controller.config import ConfigError, load_config
from controller.core.cycle_data import Anomaly
from controller.shell.service import run_controller
from drivers.bus import parse_bus_spec
from drivers.cyclic_exchange import CyclicExchange
from drivers.frame_tap import FrameTap
from drivers.kernel_sync import KernelSyncError, KernelSyncExchange, SyncPhaseLock
from drivers.pdo_codec import PositionScale


def test_kernel_sync_on_a_bus_without_a_broadcast_manager_is_refused_before_the_bus_opens(monkeypatch):
    def no_bus(*args, **kwargs):
        raise AssertionError("the bus was opened")

    monkeypatch.setattr("controller.shell.service.open_bus", no_bus)
    cfg = load_config(
        overrides={"bus.sync_producer": "kernel", "recording.enabled": False, "monitoring.enabled": False}
    )
    with pytest.raises(
        KernelSyncError, match=r"bus.sync_producer = 'kernel' needs a socketcan bus.*udp_multicast"
    ):
        run_controller(cfg, parse_bus_spec("udp_multicast"))


def test_an_unknown_sync_producer_is_a_configuration_error():
    with pytest.raises(ConfigError, match=r"bus.sync_producer = 'bcm'"):
        load_config(overrides={"bus.sync_producer": "bcm"})


def test_the_kernel_exchange_needs_an_exchange_that_sends_no_sync():
    with can.Bus(interface="virtual", channel="kernel-sync-check") as bus:
        ex = CyclicExchange(bus, (1,), PositionScale(1e7), None, 100, heartbeat_every=1)
        with pytest.raises(ValueError, match="send_sync=False"):
            KernelSyncExchange(ex, 0.0025, 0.0005)
        quiet = quiet_exchange(bus, heartbeat_every=1)
        with pytest.raises(ValueError, match=re.escape("lead 0.003 s must be within the period 0.0025 s")):
            KernelSyncExchange(quiet, 0.0025, 0.003)


def _broadcast_manager(
    period_s: float, latency_s: Callable[[int], float], syncs: int, lock: SyncPhaseLock | None
) -> list[float]:
    """SYNC times of Linux's broadcast manager (net/can/bcm.c): the handler of SYNC n re-arms at its
    own time + the interval set then, and fires that much plus its latency later. The loop sees
    SYNC n at its next cycle and sets the interval the handler of SYNC n + 1 uses."""
    ival, t, times = period_s, 0.0, []
    pending = ival
    for n in range(syncs):
        times.append(t)
        ival, pending = pending, (lock.update(t) if lock is not None else period_s)
        t += ival + latency_s(n)
    return times


@pytest.mark.parametrize(
    ("period", "mean_latency_us", "jitter_us"), [(0.0025, 5.0, 3.0), (0.01, 250.0, 150.0)]
)
def test_the_phase_lock_holds_each_sync_at_its_slot_where_the_broadcast_manager_drifts(
    period, mean_latency_us, jitter_us
):
    # 5 us at 400 Hz: a real machine's timer latency; 250 us at 100 Hz: what the emulated vcan VM
    # showed (a 2-3 % long period)
    rng = random.Random(7)

    def latency(n: int) -> float:
        return max(0.0, rng.gauss(mean_latency_us, jitter_us)) * 1e-6

    syncs = 4000
    free = _broadcast_manager(period, latency, syncs, None)
    locked = _broadcast_manager(period, latency, syncs, SyncPhaseLock(period))
    drift = free[-1] - (syncs - 1) * period
    assert drift > 4000 * mean_latency_us * 1e-6 * 0.8  # the drift the lock is for: seconds' worth of latency
    errors = [abs(t - n * period) for n, t in enumerate(locked)][200:]
    # after the lock has learned the latency: each SYNC within its jitter's reach of its slot
    assert max(errors) < 10 * jitter_us * 1e-6 + 2e-6, max(errors)
    assert statistics.mean(errors) < 2 * jitter_us * 1e-6 + 1e-6


def test_the_phase_lock_keeps_the_interval_within_its_bounds_and_in_microseconds():
    lock = SyncPhaseLock(0.01, max_correction=0.1)
    ivals = [lock.update(t) for t in (0.0, 0.0105, 0.0230, 0.0400)]  # ever later SYNCs
    assert all(0.009 - 1e-12 <= i <= 0.011 + 1e-12 for i in ivals)
    assert all(abs(i * 1e6 - round(i * 1e6)) < 1e-6 for i in ivals)
    assert ivals[-1] < 0.01  # late SYNCs: a shorter interval


class _Inbox(can.BusABC):
    """Frames handed to the exchange as received, timestamps kept (a virtual bus sets its own)."""

    def __init__(self, frames: list[can.Message]) -> None:
        super().__init__(channel="inbox")
        self.frames = deque(frames)

    def send(self, msg: can.Message, timeout: float | None = None) -> None: ...

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.frames.popleft() if self.frames else None), False


def test_with_kernel_sync_the_exchange_takes_the_syncs_it_receives_as_the_kernels_and_flags_a_second_producer():
    # 100.013: a second producer's SYNC, 3 ms after one of the kernel's at a 10 ms period
    syncs = [
        can.Message(arbitration_id=0x080, data=b"", is_extended_id=False, timestamp=t)
        for t in (100.000, 100.010, 100.013, 100.020)
    ]
    with _Inbox([]) as bus:
        ex = quiet_exchange(bus, sync_period_s=0.01, heartbeat_every=10**6)
        ex.send(None)
        bus.frames.extend(syncs)
        feedback = ex.collect(deadline_s=0.0)
    assert ex.kernel_sync_stamps == pytest.approx([100.000, 100.010, 100.020])
    assert [(a.kind, a.count) for a in feedback.anomalies] == [(Anomaly.FOREIGN_SYNC, 1)]


def test_a_frame_tap_hands_periodic_sending_to_its_bus():
    sent_by_bus = []

    class PeriodicBus(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="periodic")

        def send(self, msg: can.Message, timeout: float | None = None) -> None: ...

        def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
            return None, False

        def _send_periodic_internal(
            self, msgs, period, duration=None, autostart=True, modifier_callback=None
        ):
            sent_by_bus.append(period)
            return super()._send_periodic_internal(msgs, period, duration, autostart=False)

    with FrameTap(PeriodicBus()) as tap:
        tap.send_periodic(
            can.Message(arbitration_id=0x080, data=b"", is_extended_id=False), 0.0025, store_task=False
        )
    assert sent_by_bus == [
        0.0025
    ]  # the bus's own periodic sending (the kernel's on SocketCAN), not a thread's


def test_the_kernel_exchange_pairs_each_cycle_with_the_sync_lead_s_after_its_deadline():
    period, lead = 0.01, 0.002
    clock = SteppingClock(1e-6, start_s=1000.0)  # 1 us a reading: the start spins on it
    with can.Bus(interface="virtual", channel="kernel-sync-slots") as bus:
        ex = quiet_exchange(bus, sync_period_s=period)
        sync = KernelSyncExchange(ex, period, lead, clock=clock)
        first_deadline = clock() - 0.015  # the first cycle's send 15 ms after its deadline (the VM's worst)
        try:
            sync.cycle_deadline(first_deadline)
            sync.send(None)  # the first cycle: starts the SYNC lead s after its deadline
            for k in (1, 2, 7):
                sync.cycle_deadline(first_deadline + k * period)
                sync.send(None)
                assert ex.cycle_slot == k
        finally:
            sync.stop()
    assert sync.first_sync_s == first_deadline + lead  # the grid is the deadline's, not the late send's
    assert ex.sync_slot_of is not None
    origin = sync.lock.origin_s  # held to the grid, on the stamps' clock
    assert origin == pytest.approx(sync.first_sync_s + sync.stamp_offset_s)
    # a SYNC belongs to the period whose time it is nearest, early or late
    assert [ex.sync_slot_of(origin + 5 * period + d) for d in (-0.004, 0.0, 0.004)] == [5, 5, 5]
