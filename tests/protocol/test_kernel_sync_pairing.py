"""The kernel-SYNC path's pairing of answer windows with SYNCs, on a timed scripted bus.

The kernel's broadcast manager sends SYNC on its own clock (drivers/kernel_sync.py); the loop sends
its RPDOs ``lead`` before each SYNC and may wake late; the simulated drive answers each SYNC after a
delay, now and then a long one. Frames come in time order, the exchange reads them as the loop does
(drain at the send, collect to the window's end, a collect that meets the next SYNC stops there).
With one sender per COB-ID no "TPDO twice in one cycle" may ever be reported: the vcan test's rule
(tests/vcan/test_kernel_sync_on_vcan.py), which the emulated VM broke 15 and 22 cycles in while the
first cycles ran late; and a second sender must still be found. The model found two causes (fixed
in drivers/cyclic_exchange.py; tests/protocol/test_cyclic_exchange_bytes.py has each as a script):
a send that went back to the loop's own SYNC period after a later SYNC had come took two SYNCs'
answers into one window with none owed, and a debt from two SYNCs in one period was forgotten at
once by a device long in step.
"""

from __future__ import annotations

import heapq
import random
import struct

import can
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.core.cycle_data import Anomaly
from controller.shell.loop import WINDOW_MARGIN_S
from drivers.cyclic_exchange import CyclicExchange
from drivers.pdo_codec import PositionScale

PERIOD_S = 0.04  # the 25-Hz path of the vcan test
COLLECT_FRACTION = 0.8
DRIVES = (1, 2, 3)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class TimedBus(can.BusABC):
    """Frames at their times; a receive with a timeout moves the clock (no wall-clock wait)."""

    def __init__(self, clock: Clock) -> None:
        super().__init__(channel="timed")
        self.clock = clock
        self.events: list[tuple[float, int, can.Message]] = []
        self.pushed = 0  # frames at one time keep their order
        self._is_shutdown = True  # nothing to release

    def at(self, t: float, msg: can.Message) -> None:
        msg.timestamp = t  # the receive timestamp, on the clock the SYNC slots are computed on
        self.pushed += 1
        heapq.heappush(self.events, (t, self.pushed, msg))

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass  # RPDOs and heartbeats: the drives in this model answer SYNC whatever they get

    def recv(self, timeout: float | None = None) -> can.Message | None:
        limit = self.clock.t + (timeout or 0.0)
        if self.events and self.events[0][0] <= limit:
            t, _, msg = heapq.heappop(self.events)
            self.clock.t = max(self.clock.t, t)
            return msg
        self.clock.t = limit
        return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), False


def run(seed: int, lead: float, cycles: int = 60, rogue_at: int | None = None) -> list[int]:
    """The cycles whose feedback reported a duplicate TPDO."""
    rng = random.Random(seed)
    clock = Clock()
    bus = TimedBus(clock)
    ex = CyclicExchange(
        bus,
        DRIVES,
        PositionScale(1e7),
        None,
        100,
        heartbeat_every=10**9,
        clock=clock,
        send_sync=False,
        sync_period_s=PERIOD_S,
    )
    lead_s = lead * PERIOD_S
    origin = lead_s  # SYNC n is due lead after the loop's deadline n (n P)
    ex.sync_slot_of = lambda stamp: round((stamp - origin) / PERIOD_S)  # as KernelSyncExchange installs it
    wake0 = rng.choice([0.0, rng.uniform(0.0, 1.5 * PERIOD_S)])
    start_delay = max(0.0, wake0 - origin)  # the broadcast manager starts in the first send
    previous_sync, last_answer = -1.0, [0.0] * len(DRIVES)
    for n in range(cycles + 5):
        # a timer stall now and then leaves a SYNC up to 0.7 periods late; the lock pulls the next in;
        # a SYNC within half a period of the last is a second producer's (not modelled: none here)
        off = rng.choice([0.0] * 8 + [rng.uniform(-0.3, 0.7) * PERIOD_S])
        s = origin + n * PERIOD_S + rng.uniform(0, 0.05) * PERIOD_S + off + start_delay * max(0.0, 1 - n / 10)
        s = max(s, previous_sync + 0.5 * PERIOD_S + 1e-4)
        previous_sync = s
        bus.at(s, can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        for j, node in enumerate(DRIVES):
            # one simulator thread: its answers in order, now and then a long stall
            delay = rng.choice([rng.uniform(0.0002, 0.002)] * 10 + [rng.uniform(0.002, 1.5 * PERIOD_S)])
            last_answer[j] = max(last_answer[j] + 1e-5, s + delay)
            data = struct.pack("<Hi", 0x1637, 1000 * n + node)
            bus.at(last_answer[j], can.Message(arbitration_id=0x180 + node, data=data, is_extended_id=False))
            if rogue_at is not None and n >= rogue_at and j == 1:  # a second sender on drive 2's COB-ID
                bus.at(
                    last_answer[j] + 1e-4,
                    can.Message(arbitration_id=0x180 + node, data=data, is_extended_id=False),
                )
    duplicates, k = [], 0
    collect_s = COLLECT_FRACTION * PERIOD_S
    while k < cycles:
        deadline = k * PERIOD_S
        late = rng.choice([0.0] * 6 + [rng.uniform(0.0, 1.3 * PERIOD_S)])
        clock.t = max(clock.t, wake0 if k == 0 else deadline + late)
        ex.cycle_slot = round((deadline + lead_s - origin) / PERIOD_S)  # KernelSyncExchange._cycle_slot
        ex.send(None)
        end = min(deadline + collect_s, deadline + PERIOD_S - WINDOW_MARGIN_S)  # CycleLoop._window_end
        fb = ex.collect(max(end, clock.t + 0.5 * collect_s))
        if any(a.kind == Anomaly.DUPLICATE_FRAME for a in fb.anomalies):
            duplicates.append(k)
        k += 1
        behind = clock.t - k * PERIOD_S
        if behind > PERIOD_S:  # the loop's overrun: the deadlines it missed are skipped
            k += int(behind / PERIOD_S)
    return duplicates


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32), lead=st.sampled_from([0.2, 0.5]))
def test_one_sender_is_never_taken_for_two_whatever_the_syncs_and_the_loop_do(seed, lead):
    assert run(seed, lead) == []


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32), lead=st.sampled_from([0.2, 0.5]), at=st.integers(5, 50))
def test_a_second_sender_is_still_found(seed, lead, at):
    """From SYNC ``at`` on, someone else repeats drive 2's answer: reported (one frame may pass while a
    debt of the drive's own late answers lasts, never as data: drivers/cyclic_exchange.py)."""
    assert run(seed, lead, rogue_at=at), "the second sender passed unreported"
