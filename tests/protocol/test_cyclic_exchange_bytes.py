"""The cyclic exchange against a scripted bus: the exact frames out, the decoding of the frames in.

``ScriptedBus`` is a python-can bus (``BusABC``: ``send`` and ``_recv_internal`` only) that
records every frame sent and answers each SYNC with the frames the test scripted for that
cycle, like the drives and the sensor would. Time is a counter the test advances: the
exchange is always asked to collect with its deadline "now", so nothing waits and nothing
depends on the wall clock. Expected bytes are built here with ``struct`` from the layouts of
CiA 301 / CiA 402 and drivers/pdo_codec.py's documentation, never with the codec under test.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable
from typing import Any

import can
import pytest

from controller.core.cycle_data import Anomaly, BusAnomaly, CycleOutputs, EmcyReport, NmtReport
from drivers.cyclic_exchange import (
    CAN_ERR_BUSOFF,
    IN_STEP_BEFORE_TRUSTED,
    OWED_FORGOTTEN_AFTER,
    CyclicExchange,
    of_known_age,
    targets_sync_gap_s,
)
from drivers.pdo_codec import PositionScale

DRIVES = (1, 2, 3)
SENSOR = 16
CONTROLLER = 100
COUNTS_PER_M = 1.0e7  # 0.1 um per count
HEARTBEAT_EVERY = 4  # cycles
HEARTBEAT_TIMEOUT_S = 0.5

SYNC_ID = 0x080


def rpdo1(node: int) -> int:
    return 0x200 + node


def tpdo1(node: int) -> int:
    return 0x180 + node


def tpdo2(node: int) -> int:
    return 0x280 + node


def emcy_id(node: int) -> int:
    return 0x080 + node


def heartbeat_id(node: int) -> int:
    return 0x700 + node


def drive_pdo(word: int, counts: int) -> bytes:
    """Controlword/statusword (u16) and target/actual position (i32), little-endian."""
    return struct.pack("<Hi", word, counts)


def sensor_pdo(x: int, y: int, z: int, status: int, counter: int) -> bytes:
    """Three i16 in 0.01 N (force) or 0.001 N m (torque), status u8, counter u8, little-endian."""
    return struct.pack("<hhhBB", x, y, z, status, counter)


def emcy_frame(code: int, register: int, vendor: bytes = b"\x00" * 5) -> bytes:
    """CiA 301 EMCY: error code u16 LE, error register u8, five manufacturer bytes."""
    return struct.pack("<HB", code, register) + vendor


def frame(cob_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


class ScriptedBus(can.BusABC):
    """Records what is sent; on each SYNC queues the frames scripted for that cycle."""

    def __init__(self, echo: bool = False) -> None:
        super().__init__(channel="scripted")
        self.echo = echo  # like a bus that receives its own transmissions (udp_multicast, vcan with loopback)
        self.sent: list[tuple[int, bytes, bool, bool, bool]] = []  # (id, data, extended, remote, error)
        self.inbox: deque[can.Message] = deque()
        self.answers: dict[int, list[can.Message]] = {}  # SYNC number -> frames
        self.syncs = 0
        self.fail_sends: set[int] = set()  # COB-IDs whose send raises, like a full transmit queue

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id in self.fail_sends:
            raise can.CanOperationError("Transmit buffer full (ENOBUFS)")
        self.sent.append(
            (msg.arbitration_id, bytes(msg.data), msg.is_extended_id, msg.is_remote_frame, msg.is_error_frame)
        )
        if self.echo:
            self.inbox.append(frame(msg.arbitration_id, bytes(msg.data)))
        if msg.arbitration_id == SYNC_ID:
            self.inbox.extend(self.answers.get(self.syncs, ()))
            self.syncs += 1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        # The exchange is always called with its deadline now: a wait here would be a wall-clock wait.
        assert (timeout is not None and timeout <= 0.0) or self.inbox, (
            f"the exchange would block for {timeout} s"
        )
        return (self.inbox.popleft() if self.inbox else None), False

    def ids_sent(self) -> list[int]:
        return [s[0] for s in self.sent]


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def bus():
    b = ScriptedBus()
    yield b
    b.shutdown()


MAX_STEP_M, MAX_JUMP_M = 0.0025, 0.005  # 1 m/s at 400 Hz, safety.max_position_jump_m


def make_exchange(
    bus: ScriptedBus,
    clock: FakeClock,
    sensor: int | None = SENSOR,
    sink: Callable | None = None,
    **options: Any,
) -> CyclicExchange:
    return CyclicExchange(
        bus,
        DRIVES,
        PositionScale(COUNTS_PER_M),
        sensor,
        CONTROLLER,
        heartbeat_every=HEARTBEAT_EVERY,
        clock=clock,
        frame_sink=sink,
        heartbeat_timeout_s=HEARTBEAT_TIMEOUT_S,
        max_position_step=MAX_STEP_M,
        max_position_jump=MAX_JUMP_M,
        **options,
    )


def all_answers(
    cycle: int,
    drives: dict[int, tuple[int, int]] | None = None,
    counter: int | None = None,
    force=(150, -75, 1000),
    torque=(12, -34, 56),
    status: int = 0,
) -> list[can.Message]:
    """Every device's answer to one SYNC: drive TPDO1s, then the sensor's force and torque TPDOs."""
    drives = drives if drives is not None else {n: (0x1637, 5_000_000 + 1000 * n + cycle) for n in DRIVES}
    frames = [frame(tpdo1(n), drive_pdo(sw, counts)) for n, (sw, counts) in drives.items()]
    c = cycle % 256 if counter is None else counter
    frames += [
        frame(tpdo1(SENSOR), sensor_pdo(*force, status, c)),
        frame(tpdo2(SENSOR), sensor_pdo(*torque, status, c)),
    ]
    return frames


def one_cycle(ex: CyclicExchange, clock: FakeClock, outputs: CycleOutputs | None, period_s: float = 0.0025):
    ex.send(outputs)
    fb = ex.collect(clock())  # the deadline is now: take what the scripted devices answered
    clock.now_s += period_s
    return fb


# -- out: RPDOs, SYNC, heartbeat ----------------------------------------------------------------


def test_rpdo_bytes_are_controlword_and_target_counts_little_endian(bus, clock):
    ex = make_exchange(bus, clock)
    outputs = CycleOutputs(controlwords=(0x000F, 0x0006, 0x0080), targets=(0.5, -0.0123456, 0.71508))
    ex.send(outputs)
    rpdos = [s for s in bus.sent if s[0] in (0x201, 0x202, 0x203)]
    assert rpdos == [
        (0x201, bytes.fromhex("0f00404b4c00"), False, False, False),  # 0x000F, 5 000 000 counts = 0x004C4B40
        (0x202, drive_pdo(0x0006, -123456), False, False, False),  # negative: two's complement
        (0x203, drive_pdo(0x0080, 7150800), False, False, False),
    ]
    assert bytes.fromhex("0600c01dfeff") == drive_pdo(0x0006, -123456)  # the helper itself, spelled out once


def test_targets_round_to_the_nearest_count():
    bus = ScriptedBus()
    try:
        ex = make_exchange(bus, FakeClock())
        # 0.1 um per count: 0.30000004 m -> 3000000.4 -> 3000000; 0.30000006 -> 3000001; -0.00000006 -> -1
        ex.send(CycleOutputs((0x0F,) * 3, (0.30000004, 0.30000006, -0.00000006)))
        assert [s[1] for s in bus.sent[:3]] == [
            drive_pdo(0x0F, 3000000),
            drive_pdo(0x0F, 3000001),
            drive_pdo(0x0F, -1),
        ]
    finally:
        bus.shutdown()


def test_one_cycle_out_is_rpdos_then_sync_then_the_heartbeat(bus, clock):
    ex = make_exchange(bus, clock)
    one_cycle(ex, clock, CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5)))
    assert bus.ids_sent() == [0x201, 0x202, 0x203, SYNC_ID, heartbeat_id(CONTROLLER)]
    sync = bus.sent[3]
    assert sync == (0x080, b"", False, False, False)  # SYNC without a counter: no data bytes
    assert bus.sent[4] == (0x764, b"\x05", False, False, False)  # NMT state 5, operational


def test_a_send_held_up_past_its_send_by_time_goes_as_a_sync_without_the_rpdos(bus, clock):
    """The loop's process held up after its wake-up: the targets were meant for an earlier SYNC and
    would pull drives that ran on back to them, so the SYNC goes alone and the loop is told."""
    ex = make_exchange(bus, clock)
    outputs = CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5))
    assert ex.send(outputs, send_by_s=clock() - 1e-6) is False
    assert bus.ids_sent() == [SYNC_ID, heartbeat_id(CONTROLLER)]
    assert ex.send(outputs, send_by_s=clock() + 1e-6) is True  # on time: as before
    assert bus.ids_sent()[2:] == [0x201, 0x202, 0x203, SYNC_ID]
    # at it is past it: send_by_s is the next cycle's deadline, whose SYNC would go at the same
    # instant (controller/core/periods.py DEADLINE_ROUNDING_S)
    assert ex.send(outputs, send_by_s=clock()) is False


def test_a_sync_too_long_after_the_last_goes_without_the_rpdos_and_the_next_carries_them(bus, clock):
    """A SYNC 2.4 ms late after one on time (2.5-ms period): a drive that takes the commanded
    speed from the time between its targets would read half of it, so the SYNC goes alone and the
    loop is told; the SYNC a period after it carries the targets again (a late phase that stays
    costs one SYNC's targets, not every one's)."""
    period = 0.0025
    ex = make_exchange(bus, clock, targets_sync_gap_s=targets_sync_gap_s(period, 4))
    outputs = CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5))
    assert ex.send(outputs) is True  # the first: no SYNC before it
    clock.now_s += period + 0.0024
    assert ex.send(outputs) is False
    clock.now_s += period
    assert ex.send(outputs) is True
    clock.now_s += 1.5 * period  # at the gap: still with them
    assert ex.send(outputs) is True
    rpdos = (0x201, 0x202, 0x203)
    assert [i for i in bus.ids_sent() if i != heartbeat_id(CONTROLLER)] == [
        *rpdos,
        SYNC_ID,
        SYNC_ID,
        *rpdos,
        SYNC_ID,
        *rpdos,
        SYNC_ID,
    ]


def test_a_late_syncs_targets_lead_by_its_lateness_along_their_last_step(bus, clock):
    """Deadlines 2.5 ms apart: on time, the targets as computed; 1 ms late, moved on 0.4 of their
    last step (the drive's segment, starting at this SYNC, ends where the path is when it ends);
    after a SYNC without targets, or at the first, there is no last step to lead along."""
    period = 0.0025
    ex = make_exchange(bus, clock, target_lead_period_s=period)

    def send(targets, late_s, deadline_s):
        clock.now_s = deadline_s + late_s
        start = len(bus.sent)
        ex.send(CycleOutputs((0x0F,) * 3, targets), send_by_s=deadline_s + period)
        return [
            int.from_bytes(d[2:6], "little", signed=True)
            for i, d, *_ in bus.sent[start:]
            if i in (0x201, 0x202, 0x203)
        ]

    d0 = clock.now_s
    assert send((0.5, 0.6, 0.7), 0.001, d0) == [5_000_000, 6_000_000, 7_000_000]  # the first: as computed
    assert send((0.501, 0.599, 0.7), 0.0, d0 + period) == [5_010_000, 5_990_000, 7_000_000]  # on time
    assert send((0.502, 0.598, 0.7), 0.001, d0 + 2 * period) == [5_024_000, 5_976_000, 7_000_000]
    ex.send(None, send_by_s=d0 + 4 * period)  # after skipped deadlines: no targets, no last step
    assert send((0.51, 0.59, 0.7), 0.001, d0 + 4 * period) == [5_100_000, 5_900_000, 7_000_000]
    assert send((0.511, 0.589, 0.7), 0.005, d0 + 5 * period) == []  # past its send-by time: none


class HeldUpAfterRpdos(ScriptedBus):
    """A bus whose send of the last drive's RPDO holds the process up ``hold_s`` (once, then off):
    the moment between the RPDOs and their SYNC."""

    def __init__(self, clock: FakeClock) -> None:
        super().__init__()
        self.clock = clock
        self.hold_s = 0.0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        super().send(msg, timeout)
        if msg.arbitration_id == rpdo1(DRIVES[-1]) and self.hold_s:
            self.clock.now_s += self.hold_s
            self.hold_s = 0.0


def test_a_hold_up_between_the_rpdos_and_their_sync_sends_them_again_chosen_by_the_syncs_time(clock):
    """Held up after the RPDOs went: a drive latches the last RPDO before the SYNC, so they go again,
    led by the lateness the SYNC now has; past the send-by time, with the targets the drives would
    run on to without any (their last latched target, along its step a period, for the periods
    since, at most E = 4), and the loop is told the SYNC went without the step's targets."""
    period = 0.0025
    bus = HeldUpAfterRpdos(clock)
    ex = make_exchange(
        bus,
        clock,
        targets_sync_gap_s=targets_sync_gap_s(period, 4),
        target_lead_period_s=period,
        drive_extrapolation_periods=4,
    )

    def send(targets, deadline_s, hold_s):
        clock.now_s, bus.hold_s = deadline_s, hold_s
        start = len(bus.sent)
        in_time = ex.send(CycleOutputs((0x0F,) * 3, targets), send_by_s=deadline_s + period)
        sent = [(i, int.from_bytes(d[2:6], "little", signed=True)) for i, d, *_ in bus.sent[start:]]
        ids = [i for i, _ in sent]
        assert ids.count(SYNC_ID) == 1 and all(
            i not in (0x201, 0x202, 0x203) for i in ids[ids.index(SYNC_ID) :]
        )
        latched = [c for i, c in sent if i in (0x201, 0x202, 0x203)][-3:]  # the last before the SYNC
        return in_time, len([i for i, _ in sent if i == 0x201]), latched

    d0 = clock.now_s
    assert send((0.5, 0.6, 0.7), d0, 0.0) == (True, 1, [5_000_000, 6_000_000, 7_000_000])
    # held up less than a tenth of a period: the RPDOs stand
    assert send((0.501, 0.599, 0.7), d0 + period, 0.2e-3) == (True, 1, [5_010_000, 5_990_000, 7_000_000])
    assert ex.counters.rpdos_resent == 0
    # 0.75 ms (0.3 of a period): again, led 0.3 of their step
    assert send((0.502, 0.598, 0.7), d0 + 2 * period, 0.75e-3) == (True, 2, [5_023_000, 5_977_000, 7_000_000])
    # 7.25 ms, past the next deadline: the latched 0.5023 at d0 + 2P + 0.75 ms, its step 1.3 mm over
    # 1.3 periods; at the SYNC 3.6 periods later, 3.6 steps on
    in_time, rpdo_sets, latched = send((0.503, 0.597, 0.7), d0 + 3 * period, 7.25e-3)
    assert (in_time, rpdo_sets) == (False, 2)
    assert latched == [5_059_000, 5_941_000, 7_000_000]
    assert ex.counters.rpdos_resent == 2
    # held up again (the loop skipped 3 deadlines): counted from the last of the step's targets the
    # drives latched (0.5023), not from the stand-in, and at most E = 4 steps past it: they stand
    in_time, rpdo_sets, latched = send((0.51, 0.59, 0.7), d0 + 7 * period, 3e-3)
    assert (in_time, rpdo_sets) == (False, 2)
    assert latched == [5_063_000, 5_937_000, 7_000_000]
    # a SYNC without the step's targets after a stand-in: a stand-in again (without it they would run
    # on from the stand-in), with the last controlwords
    clock.now_s = d0 + 8 * period
    start = len(bus.sent)
    assert ex.send(None, send_by_s=d0 + 9 * period) is True
    again = [(i, d) for i, d, *_ in bus.sent[start:] if i in (0x201, 0x202, 0x203)]
    assert [int.from_bytes(d[2:6], "little", signed=True) for _, d in again] == [
        5_063_000,
        5_937_000,
        7_000_000,
    ]
    assert all(int.from_bytes(d[0:2], "little") == 0x0F for _, d in again)
    # the step's targets in time: the anchor again; a SYNC without them then goes alone
    assert send((0.5065, 0.5935, 0.7), d0 + 9 * period, 0.0) == (True, 1, [5_065_000, 5_935_000, 7_000_000])
    clock.now_s = d0 + 10 * period
    start = len(bus.sent)
    ex.send(None, send_by_s=d0 + 11 * period)
    assert [i for i, *_ in bus.sent[start:] if i in (0x201, 0x202, 0x203)] == []


def test_drives_that_stand_without_targets_get_their_last_targets_again_after_a_hold_up(clock):
    """E = 0: a drive without a new target holds its last one, so that is what goes again."""
    period = 0.0025
    bus = HeldUpAfterRpdos(clock)
    ex = make_exchange(bus, clock, target_lead_period_s=period, drive_extrapolation_periods=0)
    d0 = clock.now_s
    for k, x in enumerate((0.5, 0.501)):
        clock.now_s = d0 + k * period
        assert ex.send(CycleOutputs((0x0F,) * 3, (x, 0.6, 0.7)), send_by_s=clock.now_s + period) is True
    clock.now_s, bus.hold_s = d0 + 2 * period, 0.004
    assert ex.send(CycleOutputs((0x0F,) * 3, (0.502, 0.6, 0.7)), send_by_s=d0 + 3 * period) is False
    rpdo1_counts = [int.from_bytes(d[2:6], "little", signed=True) for i, d, *_ in bus.sent if i == 0x201]
    assert rpdo1_counts == [5_000_000, 5_010_000, 5_020_000, 5_010_000]


def test_no_targets_are_withheld_from_drives_that_would_stand_without_them_or_under_kernel_sync(bus, clock):
    """Drives without a period of extrapolation stand when a SYNC brings no target, and with one
    they would spend it on the withheld SYNC: they get it however late; and with the kernel's
    SYNC the loop's send has no SYNC whose time would count."""
    assert targets_sync_gap_s(0.0025, 0) == targets_sync_gap_s(0.0025, 1) == math.inf
    assert targets_sync_gap_s(0.0025, 2) == pytest.approx(0.00375)
    kernel = make_exchange(bus, clock, targets_sync_gap_s=targets_sync_gap_s(0.0025, 4), send_sync=False)
    outputs = CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5))
    kernel.send(outputs)
    clock.now_s += 0.01
    assert kernel.send(outputs) is True


def test_before_the_first_step_only_sync_and_heartbeat_go_out(bus, clock):
    ex = make_exchange(bus, clock)
    one_cycle(ex, clock, None)
    assert bus.ids_sent() == [SYNC_ID, heartbeat_id(CONTROLLER)]


def test_the_heartbeat_goes_out_every_configured_number_of_cycles_after_sync(bus, clock):
    ex = make_exchange(bus, clock)
    outputs = CycleOutputs((0x0F,) * 3, (0.5, 0.6, 0.7))
    per_cycle: list[list[int]] = []
    for _ in range(3 * HEARTBEAT_EVERY + 1):
        start = len(bus.sent)
        one_cycle(ex, clock, outputs)
        per_cycle.append(bus.ids_sent()[start:])
    with_heartbeat = [k for k, ids in enumerate(per_cycle) if heartbeat_id(CONTROLLER) in ids]
    assert with_heartbeat == [0, 4, 8, 12]
    for k, ids in enumerate(per_cycle):
        expected = [0x201, 0x202, 0x203, SYNC_ID] + ([0x764] if k % HEARTBEAT_EVERY == 0 else [])
        assert ids == expected, f"cycle {k}"


def test_a_send_that_fails_is_counted_not_raised(bus, clock):
    ex = make_exchange(bus, clock)
    bus.fail_sends = {0x202}
    one_cycle(ex, clock, CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5)))
    assert bus.ids_sent() == [0x201, 0x203, SYNC_ID, 0x764]
    assert ex.counters.send_errors == 1 and ex.counters.frames_out == 4


# -- in: TPDOs, sensor, EMCY, error frames -------------------------------------------------------


def test_drive_and_sensor_tpdos_decode_into_the_feedback(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(
        0,
        drives={1: (0x1637, 7150800), 2: (0x0250, -1), 3: (0x0208, 2**31 - 1)},
        counter=200,
        force=(150, -75, 32767),
        torque=(12, -34, -32767),
        status=0x01,
    )
    fb = one_cycle(ex, clock, None)
    assert [(d.statusword, d.fresh) for d in fb.drives] == [(0x1637, True), (0x0250, True), (0x0208, True)]
    assert fb.drives[0].position == pytest.approx(0.71508, abs=1e-12)
    assert fb.drives[1].position == pytest.approx(-1e-7, abs=1e-15)
    assert fb.drives[2].position == pytest.approx((2**31 - 1) / COUNTS_PER_M, abs=1e-12)
    s = fb.sensor
    assert s is not None and s.fresh and s.counter == 200 and s.status == 0x01
    assert s.force_n == pytest.approx((1.50, -0.75, 327.67))  # 0.01 N per count
    assert s.torque_nm == pytest.approx((0.012, -0.034, -32.767))  # 0.001 N m per count
    assert fb.emcy == () and fb.error_frames == 0 and not fb.bus_off and fb.lost_heartbeats == ()
    assert ex.counters.missing_drive_frames == 0 and ex.counters.missing_sensor_frames == 0
    assert ex.counters.rejected_frames == 0


def test_frames_in_any_order_and_foreign_frames_are_fine(bus, clock):
    ex = make_exchange(bus, clock)
    answers = all_answers(0)
    bus.answers[0] = [frame(0x123, b"\x01\x02"), *reversed(answers), frame(0x18A, drive_pdo(0x0237, 42))]
    fb = one_cycle(ex, clock, None)
    assert all(d.fresh for d in fb.drives) and fb.sensor.fresh
    assert ex.counters.rejected_frames == 0


def test_emcy_frames_become_reports_with_node_code_and_register(bus, clock):
    ex = make_exchange(bus, clock)
    # before the cycle's last TPDO, so they are this cycle's (after it: the next test)
    bus.answers[0] = [
        frame(emcy_id(2), emcy_frame(0x5000, 0x01, b"\x11\x22\x33\x44\x55")),
        frame(emcy_id(SENSOR), emcy_frame(0x8130, 0x11)),
        frame(emcy_id(3), emcy_frame(0x0000, 0x00)),
        *all_answers(0),
    ]
    fb = one_cycle(ex, clock, None)
    assert fb.emcy == (
        EmcyReport(2, 0x5000, 0x01),
        EmcyReport(SENSOR, 0x8130, 0x11),
        EmcyReport(3, 0x0000, 0x00),
    )
    # reports belong to their cycle
    bus.answers[1] = all_answers(1)
    assert one_cycle(ex, clock, None).emcy == ()


def test_error_frames_are_counted_and_a_bus_off_is_flagged(bus, clock):
    ex = make_exchange(bus, clock)
    controller_problem = can.Message(
        arbitration_id=0x004, is_error_frame=True, data=b"\x00\x04" + b"\x00" * 6
    )
    bus_off = can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=b"\x00" * 8)
    assert CAN_ERR_BUSOFF == 0x040  # linux/can/error.h
    bus.answers[0] = [controller_problem, *all_answers(0)]
    fb = one_cycle(ex, clock, None)
    assert fb.error_frames == 1 and not fb.bus_off and all(d.fresh for d in fb.drives)
    bus.answers[1] = [controller_problem, bus_off, *all_answers(1)]
    fb = one_cycle(ex, clock, None)
    assert fb.error_frames == 2 and fb.bus_off
    bus.answers[2] = all_answers(2)
    fb = one_cycle(ex, clock, None)
    assert fb.error_frames == 0 and not fb.bus_off  # per cycle
    assert ex.counters.error_frames == 3


@pytest.mark.parametrize("late_frame", ["emcy", "bus_off"])
def test_an_emcy_or_bus_off_after_the_cycles_tpdos_reaches_the_next_feedback(bus, clock, late_frame):
    ex = make_exchange(bus, clock)
    late = (
        frame(emcy_id(2), emcy_frame(0x5000, 0x01))
        if late_frame == "emcy"
        else can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True, data=b"\x00" * 8)
    )
    bus.answers[0] = [*all_answers(0), late]  # e.g. a drive faulting between two SYNCs
    bus.answers[1] = all_answers(1)
    reports = [one_cycle(ex, clock, None), one_cycle(ex, clock, None)]
    assert ex.counters.frames_in == 2 * 5 + 1  # it was received
    if late_frame == "emcy":
        assert any(fb.emcy for fb in reports), "the EMCY never reached a BusFeedback"
    else:
        assert any(fb.bus_off for fb in reports), "the bus-off never reached a BusFeedback"


def test_a_missing_tpdo_is_flagged_not_fresh_with_the_last_values_and_counted(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(
        0, drives={1: (0x1637, 100), 3: (0x1637, 300)}, counter=7
    )  # drive 2 never answered
    fb = one_cycle(ex, clock, None)
    assert [d.fresh for d in fb.drives] == [True, False, True]
    assert fb.drives[1].statusword == 0 and math.isnan(fb.drives[1].position)  # nothing received yet
    bus.answers[1] = all_answers(1, drives={1: (0x1637, 101), 2: (0x1637, 201), 3: (0x1637, 301)}, counter=8)
    assert all(d.fresh for d in one_cycle(ex, clock, None).drives)
    bus.answers[2] = [
        f
        for f in all_answers(2, drives={1: (0x1637, 102), 3: (0x0208, 302)}, counter=9)
        if f.arbitration_id != tpdo2(SENSOR)
    ]  # drive 2 and the sensor's torque frame missing
    fb = one_cycle(ex, clock, None)
    assert [d.fresh for d in fb.drives] == [True, False, True]
    assert (fb.drives[1].statusword, fb.drives[1].position) == (
        0x1637,
        pytest.approx(201e-7),
    )  # the last received
    assert fb.drives[2].statusword == 0x0208 and fb.drives[2].position == pytest.approx(302e-7)
    assert not fb.sensor.fresh  # force without its torque frame of the same counter
    assert ex.counters.missing_drive_frames == 2 and ex.counters.missing_sensor_frames == 1


def test_sensor_frames_of_different_counters_are_not_fresh(bus, clock):
    ex = make_exchange(bus, clock)
    force = frame(tpdo1(SENSOR), sensor_pdo(1, 2, 3, 0, 41))
    torque = frame(tpdo2(SENSOR), sensor_pdo(4, 5, 6, 0, 40))  # a sample older
    bus.answers[0] = [*all_answers(0)[:3], force, torque]
    fb = one_cycle(ex, clock, None)
    assert not fb.sensor.fresh and ex.counters.missing_sensor_frames == 1


@pytest.mark.parametrize(
    ("cob_id", "data"),
    [
        (tpdo1(2), drive_pdo(0x1637, 5) + b"\x00"),  # 7 bytes
        (tpdo1(2), drive_pdo(0x1637, 5)[:3]),  # 3 bytes
        (tpdo1(2), b""),
    ],
    ids=["tpdo-7-bytes", "tpdo-3-bytes", "tpdo-empty"],
)
def test_a_drive_tpdo_of_the_wrong_length_is_rejected_and_counted(bus, clock, cob_id, data):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0, drives={1: (0x1637, 100), 2: (0x1637, 200), 3: (0x1637, 300)})
    one_cycle(ex, clock, None)
    bus.answers[1] = [f if f.arbitration_id != cob_id else frame(cob_id, data) for f in all_answers(1)]
    fb = one_cycle(ex, clock, None)
    assert ex.counters.rejected_frames == 1
    assert not fb.drives[1].fresh and fb.drives[1].position == pytest.approx(
        200e-7
    )  # the malformed one changed nothing
    assert ex.counters.missing_drive_frames == 1


@pytest.mark.parametrize(
    ("cob_id", "data"),
    [
        (tpdo1(SENSOR), sensor_pdo(1, 2, 3, 0, 0)[:7]),
        (tpdo2(SENSOR), sensor_pdo(1, 2, 3, 0, 0) + b"\x00"),
        (emcy_id(1), emcy_frame(0x5000, 0x01)[:6]),
    ],
    ids=["force-7-bytes", "torque-9-bytes", "emcy-6-bytes"],
)
def test_sensor_and_emcy_frames_of_the_wrong_length_are_rejected_and_counted(bus, clock, cob_id, data):
    ex = make_exchange(bus, clock)
    answers = [f for f in all_answers(0) if f.arbitration_id != cob_id]
    bus.answers[0] = [frame(cob_id, data), *answers]
    fb = one_cycle(ex, clock, None)
    assert ex.counters.rejected_frames == 1
    assert fb.emcy == ()
    node = 1 if cob_id == emcy_id(1) else SENSOR  # counted per node and named, not rejected silently
    assert ex.counters.rejected_by_node == {node: 1}
    assert (Anomaly.REJECTED_FRAME, node) in {(a.kind, a.node_id) for a in fb.anomalies}


def test_a_tpdo_that_arrives_after_the_collect_is_late_never_used_and_a_second_candidate(bus, clock):
    """Outside its answer window a TPDO is never a sample (its value is not delivered either); one
    for a cycle that already had its sample is a second sender's (or the true one after a rogue's)."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    first = one_cycle(ex, clock, None)
    bus.inbox.append(frame(tpdo1(1), drive_pdo(0x1637, 4242)))  # cycle 0's answer, after its collect
    bus.answers[1] = [f for f in all_answers(1) if f.arbitration_id != tpdo1(1)]
    fb = one_cycle(ex, clock, None)
    assert ex.counters.late_frames == 1
    assert not fb.drives[0].fresh and fb.drives[0].position == first.drives[0].position
    assert BusAnomaly(Anomaly.DUPLICATE_FRAME, tpdo1(1), 1, node_id=1) in fb.anomalies


def test_our_own_frames_echoed_by_the_bus_are_ignored(clock):
    bus = ScriptedBus(echo=True)
    try:
        ex = make_exchange(bus, clock)
        bus.answers[0] = all_answers(0)
        fb = one_cycle(ex, clock, CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5)))
        assert all(d.fresh for d in fb.drives) and ex.counters.rejected_frames == 0
        assert [d.position for d in fb.drives] == [
            pytest.approx((5_000_000 + 1000 * n) / COUNTS_PER_M) for n in DRIVES
        ]
    finally:
        bus.shutdown()


def test_a_drive_whose_heartbeat_is_overdue_is_reported_lost(bus, clock):
    ex = make_exchange(bus, clock)
    period = 0.04
    lost_per_cycle = []
    for k in range(
        18
    ):  # drives 1, 3 and the sensor beat every 0.08 s; drive 2's last beat is at 0.16 s (cycle 4)
        beats = [
            frame(heartbeat_id(n), b"\x05") for n in (*DRIVES, SENSOR) if k % 2 == 0 and (n != 2 or k <= 4)
        ]
        bus.answers[k] = [*beats, *all_answers(k)]
        lost_per_cycle.append(one_cycle(ex, clock, None, period).lost_heartbeats)
    # overdue once more than 0.5 s passed since 0.16 s: from 0.68 s (cycle 17) on, not at 0.64 s
    assert lost_per_cycle[:17] == [()] * 17
    assert lost_per_cycle[17] == (2,)


def test_a_drive_never_heard_is_lost_after_the_timeout_from_the_start(bus, clock):
    ex = make_exchange(bus, clock)
    seen = []
    for k in range(14):
        bus.answers[k] = all_answers(k)  # TPDOs but no heartbeat at all
        seen.append(one_cycle(ex, clock, None, 0.04).lost_heartbeats)
    assert seen[:13] == [()] * 13  # up to 0.48 s after the exchange started
    assert seen[13] == (*DRIVES, SENSOR)  # 0.52 s: the sensor is supervised by its heartbeat too


def test_the_sensor_whose_heartbeat_stops_is_reported_lost(bus, clock):
    ex = make_exchange(bus, clock)
    lost_per_cycle = []
    for k in range(18):  # everyone beats every 0.08 s; the sensor's last beat is at 0.16 s (cycle 4)
        beats = [
            frame(heartbeat_id(n), b"\x05")
            for n in (*DRIVES, SENSOR)
            if k % 2 == 0 and (n != SENSOR or k <= 4)
        ]
        bus.answers[k] = [*beats, *all_answers(k)]
        lost_per_cycle.append(one_cycle(ex, clock, None, 0.04).lost_heartbeats)
    assert lost_per_cycle[:17] == [()] * 17
    assert lost_per_cycle[17] == (SENSOR,)


def test_every_frame_goes_to_the_sink_once_with_its_direction(bus, clock):
    log: list[tuple[bool, float, int, bytes]] = []
    ex = make_exchange(
        bus, clock, sink=lambda out, t, msg: log.append((out, t, msg.arbitration_id, bytes(msg.data)))
    )
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, CycleOutputs((0x0F,) * 3, (0.5, 0.5, 0.5)))
    out = [(i, d) for o, _, i, d in log if o]
    inn = [i for o, _, i, _ in log if not o]
    assert out == [(s[0], s[1]) for s in bus.sent]
    assert inn == [0x181, 0x182, 0x183, 0x190, 0x290]
    assert {t for _, t, _, _ in log} == {100.0}  # stamped with the exchange's clock


# -- the whole bus: frames nobody configured should send ------------------------------------------


def anomalies(fb) -> dict[tuple[Anomaly, int], int]:
    return {(a.kind, a.cob_id): a.count for a in fb.anomalies}


def test_a_cycle_of_the_configured_devices_has_no_anomalies(clock):
    bus = ScriptedBus()  # own echoes never reach the exchange: drivers/frame_tap.py (test_frame_tap.py)
    try:
        ex = make_exchange(bus, clock)
        outputs = CycleOutputs((0x0F,) * 3, (0.5, 0.6, 0.7))
        for k in range(3 * HEARTBEAT_EVERY):  # RPDOs, SYNCs and heartbeats out, every device's answers in
            bus.answers[k] = all_answers(k)
            fb = one_cycle(ex, clock, outputs)
            assert fb.anomalies == () and fb.nmt_reports == (), (k, fb.anomalies)
        assert ex.counters.foreign_frames == 0
    finally:
        bus.shutdown()


def test_a_second_sync_producer_is_a_foreign_sync(clock):
    bus = ScriptedBus()
    try:
        ex = make_exchange(bus, clock)
        bus.answers[0] = all_answers(0)
        assert one_cycle(ex, clock, None).anomalies == ()
        answers = all_answers(1)
        bus.answers[1] = [
            frame(SYNC_ID, b""),
            *answers[:-1],
            frame(SYNC_ID, b""),
            answers[-1],
        ]  # someone else's
        assert anomalies(one_cycle(ex, clock, None)) == {(Anomaly.FOREIGN_SYNC, SYNC_ID): 2}
        # one that comes after the cycle's last TPDO is read before the next SYNC and reported with it
        bus.answers[2] = [*all_answers(2), frame(SYNC_ID, b"")]
        assert one_cycle(ex, clock, None).anomalies == ()
        bus.answers[3] = all_answers(3)
        assert anomalies(one_cycle(ex, clock, None)) == {(Anomaly.FOREIGN_SYNC, SYNC_ID): 1}
    finally:
        bus.shutdown()


def test_frames_on_cob_ids_only_the_controller_sends_are_foreign(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = [
        frame(0x000, b"\x02\x02"),  # NMT stop of drive 2: not ours
        frame(0x000, b"\x81\x00"),  # NMT reset of every node
        frame(0x000, b"\x02\x33"),  # NMT stop of node 0x33, which is nobody we know
        frame(rpdo1(2), drive_pdo(0x000F, 9_000_000)),  # a second master commanding drive 2
        frame(0x600 + 3, bytes(8)),  # an SDO request to drive 3
        *all_answers(0),
    ]
    fb = one_cycle(ex, clock, None)
    assert anomalies(fb) == {
        (Anomaly.FOREIGN_NMT, 0x000): 1,
        (Anomaly.UNKNOWN_FRAME, 0x000): 1,
        (Anomaly.FOREIGN_COMMAND, rpdo1(2)): 1,
        (Anomaly.FOREIGN_COMMAND, 0x603): 1,
    }
    # each foreign NMT command with its target node and command specifier, for the fault to name them
    assert {(a.node_id, a.command) for a in fb.anomalies if a.kind == Anomaly.FOREIGN_NMT} == {
        (2, 0x02),
        (0, 0x81),
    }


def test_an_sdo_answer_the_controller_did_not_ask_for_is_a_second_sdo_client(bus, clock):
    """An answer owed to the controller's own SDO request (a quick stop by SDO) is none of that; one
    more, or one nobody asked for, tells of another client talking to the drive (44dbcbc)."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    assert one_cycle(ex, clock, None).anomalies == ()
    ex.send_controlword_by_sdo(1, 0x0002)  # drive 2
    answer = frame(0x582, bytes((0x60, 0x40, 0x60, 0, 0, 0, 0, 0)))
    bus.answers[1] = [answer, *all_answers(1)]
    assert one_cycle(ex, clock, None).anomalies == ()
    bus.answers[2] = [answer, *all_answers(2)]
    fb = one_cycle(ex, clock, None)
    assert anomalies(fb) == {(Anomaly.FOREIGN_SDO, 0x582): 1}
    assert [a.node_id for a in fb.anomalies] == [2]


def test_unknown_nodes_are_reported_by_what_they_send(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = [
        frame(emcy_id(0x20), emcy_frame(0x8130, 0x11)),
        frame(heartbeat_id(0x21), b"\x05"),
        frame(0x123, b"\x01"),
        frame(0x123, b"\x02"),
        *all_answers(0),
    ]
    fb = one_cycle(ex, clock, None)
    assert anomalies(fb) == {
        (Anomaly.UNKNOWN_EMCY, 0x0A0): 1,
        (Anomaly.UNKNOWN_HEARTBEAT, 0x721): 1,
        (Anomaly.UNKNOWN_FRAME, 0x123): 2,
    }
    assert fb.emcy == ()  # an unknown node's EMCY is not one of ours
    assert all(d.fresh for d in fb.drives) and fb.sensor.fresh


def test_a_29_bit_frame_is_named_and_never_taken_for_the_11_bit_cob_id_it_looks_like(bus, clock):
    """An extended 0x701 [05] is not drive 1's heartbeat, an extended drive TPDO not its sample."""
    ex = make_exchange(bus, clock)
    ext = tpdo1(1)
    bus.answers[0] = [
        can.Message(arbitration_id=heartbeat_id(1), data=b"\x05", is_extended_id=True),
        can.Message(arbitration_id=ext, data=drive_pdo(0x1637, 5_500_000), is_extended_id=True),
        *(f for f in all_answers(0) if f.arbitration_id != tpdo1(1)),
    ]
    fb = one_cycle(ex, clock, None)
    assert anomalies(fb) == {(Anomaly.EXTENDED_FRAME, heartbeat_id(1)): 1, (Anomaly.EXTENDED_FRAME, ext): 1}
    assert not fb.drives[0].fresh  # drive 1 did not answer: the 29-bit frame is nobody's sample
    assert math.isnan(ex.last_heartbeat_s[0])  # nor its sign of life


def test_a_flood_is_diagnosed_with_its_busiest_cob_id(bus, clock):
    ex = CyclicExchange(
        bus,
        DRIVES,
        PositionScale(COUNTS_PER_M),
        SENSOR,
        CONTROLLER,
        heartbeat_every=HEARTBEAT_EVERY,
        clock=clock,
        flood_frames_per_cycle=10,
    )
    bus.answers[0] = [*(frame(0x001, b"") for _ in range(30)), frame(0x123, b""), *all_answers(0)]
    found = anomalies(one_cycle(ex, clock, None))
    assert found[(Anomaly.FRAME_FLOOD, 0x001)] == 31 and found[(Anomaly.UNKNOWN_FRAME, 0x001)] == 30
    bus.answers[1] = [*(frame(0x001, b"") for _ in range(10)), *all_answers(1)]  # at the limit: no flood
    assert anomalies(one_cycle(ex, clock, None)) == {(Anomaly.UNKNOWN_FRAME, 0x001): 10}


@pytest.mark.parametrize("rogue_first", [True, False], ids=["rogue-first", "rogue-second"])
def test_two_tpdos_of_one_drive_in_one_cycle_make_its_sample_unusable_whichever_comes_first(
    bus, clock, rogue_first
):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    before = one_cycle(ex, clock, None).drives[1].position
    answers = all_answers(1)
    real = next(f for f in answers if f.arbitration_id == tpdo1(2))
    rogue = frame(tpdo1(2), drive_pdo(0x1637, 5_500_000))  # a spoofed jump on drive 2's COB-ID
    others = [f for f in answers if f is not real]
    bus.answers[1] = [*((rogue, real) if rogue_first else (real, rogue)), *others]
    fb = one_cycle(ex, clock, None)
    found = {(a.kind, a.cob_id, a.node_id): a.count for a in fb.anomalies}
    # reported with the node; the rogue's candidate is also beyond what the drive can move
    assert found == {(Anomaly.DUPLICATE_FRAME, tpdo1(2), 2): 1, (Anomaly.IMPLAUSIBLE_FRAME, tpdo1(2), 2): 1}
    assert not fb.drives[1].fresh and fb.drives[1].position == before  # neither value is used
    assert fb.drives[0].fresh and fb.drives[2].fresh


def test_a_wrong_length_tpdo_is_a_candidate_reported_with_its_node(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = [frame(tpdo1(3), drive_pdo(0x1637, 1)[:3]), *all_answers(0)]  # before the real answer
    fb = one_cycle(ex, clock, None)
    assert ex.counters.rejected_frames == 1 and not fb.drives[2].fresh
    assert {(a.kind, a.node_id) for a in fb.anomalies} == {
        (Anomaly.REJECTED_FRAME, 3),
        (Anomaly.DUPLICATE_FRAME, 3),
    }


def test_a_second_sensor_sample_that_does_not_follow_makes_the_cycle_s_sample_not_fresh(bus, clock):
    ex = make_exchange(bus, clock)
    spoofed = frame(tpdo1(SENSOR), sensor_pdo(3000, 0, 0, 0, 7))  # 30 N with a counter out of sequence
    answers = all_answers(0, counter=41)
    bus.answers[0] = [*answers[:3], answers[3], spoofed, answers[4]]
    fb = one_cycle(ex, clock, None)
    assert not fb.sensor.fresh and anomalies(fb) == {(Anomaly.DUPLICATE_FRAME, tpdo1(SENSOR)): 1}
    # two force frames in one window are two candidates, even when their counters follow each other:
    # a spoofer who guesses the next counter cannot win the race either
    late, now = all_answers(1, counter=42), all_answers(1, counter=43)
    bus.answers[1] = [late[3], *now]
    fb = one_cycle(ex, clock, None)
    assert not fb.sensor.fresh and anomalies(fb) == {(Anomaly.DUPLICATE_FRAME, tpdo1(SENSOR)): 1}


def test_a_lone_sensor_sample_whose_counter_cannot_follow_is_not_used(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0, counter=10)
    assert one_cycle(ex, clock, None).sensor.fresh
    answers = all_answers(1, counter=10 + 128)  # the only force and torque frames, 128 steps on in one cycle
    bus.answers[1] = answers
    fb = one_cycle(ex, clock, None)
    assert not fb.sensor.fresh and (Anomaly.IMPLAUSIBLE_FRAME, tpdo1(SENSOR)) in anomalies(fb)
    bus.answers[2] = all_answers(2, counter=12)  # the sensor's own next counter (one SYNC missed): used
    assert one_cycle(ex, clock, None).sensor.fresh


def test_heartbeats_are_judged_by_their_nmt_state(bus, clock):
    ex = make_exchange(bus, clock)
    bus.inbox.append(frame(heartbeat_id(2), b"\x7f"))  # before the first SYNC: set-up time, not judged
    # still coming up after the NMT start: a PRE-OPERATIONAL heartbeat before any OPERATIONAL one is not judged
    bus.answers[0] = [frame(heartbeat_id(1), b"\x05"), frame(heartbeat_id(SENSOR), b"\x7f"), *all_answers(0)]
    assert one_cycle(ex, clock, None).nmt_reports == ()
    bus.answers[1] = [frame(heartbeat_id(n), b"\x05") for n in (*DRIVES, SENSOR)] + all_answers(1)
    assert one_cycle(ex, clock, None).nmt_reports == ()
    bus.answers[2] = [
        frame(heartbeat_id(2), b"\x00"),
        frame(heartbeat_id(SENSOR), b"\x7f"),
        frame(heartbeat_id(3), b"\x84"),
        *all_answers(2),
    ]
    fb = one_cycle(ex, clock, None)
    assert fb.nmt_reports == (
        NmtReport(2, 0),
        NmtReport(SENSOR, 127),
        NmtReport(3, 4),
    )  # 0x84: toggle bit + 4
    assert fb.anomalies == ()
    bus.answers[3] = [frame(heartbeat_id(2), b"\x05"), *all_answers(3)]
    assert one_cycle(ex, clock, None).nmt_reports == ()


def test_a_boot_up_is_judged_even_from_a_node_never_heard_operational(bus, clock):
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    bus.answers[1] = [frame(heartbeat_id(2), b"\x00"), *all_answers(1)]
    assert one_cycle(ex, clock, None).nmt_reports == (NmtReport(2, 0),)


def test_a_stalled_device_s_burst_of_owed_answers_is_not_a_second_sender_but_still_not_used(bus, clock):
    """Drive 2 misses a window, then answers both SYNCs in the next one (a stalled simulator): no
    sample (nobody can tell which is which), counted late, no duplicate reported; once it has caught
    up, two candidates again are a second sender's."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    bus.answers[1] = [f for f in all_answers(1) if f.arbitration_id != tpdo1(2)]
    assert not one_cycle(ex, clock, None).drives[1].fresh
    late = next(f for f in all_answers(1) if f.arbitration_id == tpdo1(2))
    bus.answers[2] = [late, *all_answers(2)]
    before = ex.counters.late_frames
    fb = one_cycle(ex, clock, None)
    assert not fb.drives[1].fresh and fb.anomalies == () and ex.counters.late_frames == before + 1
    bus.answers[3] = [late, *all_answers(3)]  # nothing owed any more
    fb = one_cycle(ex, clock, None)
    assert not fb.drives[1].fresh and (Anomaly.DUPLICATE_FRAME, tpdo1(2)) in anomalies(fb)


def test_a_burst_of_owed_answers_that_straddles_the_window_is_not_a_second_sender(bus, clock):
    """Drive 2 stalls for three SYNCs, then answers all four at once: one lands in the window, three
    after it, before the next SYNC (seen in a soak at the defaults: a 9 ms stall of the simulator
    faulted it with "3 TPDO(s) twice in one cycle"). Its debt is paid answer by answer: nothing is
    reported, and the next window's answer is its sample. The lone answer in the window is the
    burst's oldest, three SYNCs old: no sample (a simulator stopped for 120 ms faulted a run on a
    following error when a 46-period-old position was taken for the cycle's)."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    mine = [next(f for f in all_answers(k) if f.arbitration_id == tpdo1(2)) for k in range(1, 5)]
    for k in (1, 2, 3):
        bus.answers[k] = [f for f in all_answers(k) if f.arbitration_id != tpdo1(2)]
        assert not one_cycle(ex, clock, None).drives[1].fresh
    bus.answers[4] = [*(f for f in all_answers(4) if f.arbitration_id != tpdo1(2)), mine[0]]
    before = ex.counters.late_frames
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and not fb.drives[1].fresh and fb.drives[0].fresh
    assert ex.counters.late_frames == before + 1
    bus.inbox.extend(mine[1:])  # after the window, before the next SYNC
    bus.answers[5] = all_answers(5)
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and fb.drives[1].fresh


def test_an_answer_a_device_never_sends_is_forgotten_once_it_is_in_step_again(bus, clock):
    """A SYNC drive 2 really missed (its answer never comes): after OWED_FORGOTTEN_AFTER windows
    with exactly one answer each, a second candidate is a second sender's again."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    bus.answers[1] = [f for f in all_answers(1) if f.arbitration_id != tpdo1(2)]
    one_cycle(ex, clock, None)
    last = 2 + OWED_FORGOTTEN_AFTER
    for k in range(2, last):
        bus.answers[k] = all_answers(k)
        assert one_cycle(ex, clock, None).drives[1].fresh
    rogue = next(f for f in all_answers(last) if f.arbitration_id == tpdo1(2))
    bus.answers[last] = [rogue, *all_answers(last)]
    fb = one_cycle(ex, clock, None)
    assert not fb.drives[1].fresh and (Anomaly.DUPLICATE_FRAME, tpdo1(2)) in anomalies(fb)


def test_answers_a_device_never_sends_leave_its_next_answers_unused_until_it_is_in_step(bus, clock):
    """Drive 2 really missed two SYNCs (their answers never come): its next lone answers may be the
    oldest of a burst still coming, so they are no sample until it has answered in step for
    IN_STEP_BEFORE_TRUSTED windows; then they are, though the debt is not forgotten yet."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    for k in (1, 2):
        bus.answers[k] = [f for f in all_answers(k) if f.arbitration_id != tpdo1(2)]
        one_cycle(ex, clock, None)
    fresh = []
    for k in range(3, 3 + IN_STEP_BEFORE_TRUSTED + 2):
        bus.answers[k] = all_answers(k)
        fb = one_cycle(ex, clock, None)
        assert fb.anomalies == () and fb.drives[0].fresh, k
        fresh.append(fb.drives[1].fresh)
    assert fresh == [False] * IN_STEP_BEFORE_TRUSTED + [True, True]
    assert ex.counters.answers_of_unknown_age == IN_STEP_BEFORE_TRUSTED


def test_one_answer_owed_leaves_a_lone_answer_a_sample():
    """At most one answer owed, a lone answer is at most one SYNC old: a sample (a device lagging one
    behind stays usable); two or more owed, only once the device is in step again."""
    assert of_known_age(0, 0) and of_known_age(1, 0)
    assert not of_known_age(2, 0) and not of_known_age(48, IN_STEP_BEFORE_TRUSTED - 1)
    assert of_known_age(48, IN_STEP_BEFORE_TRUSTED)


def test_a_device_that_lags_one_answer_behind_for_a_while_is_no_second_sender_when_it_catches_up(bus, clock):
    """Drive 2 misses a window, then each window holds its answer to the SYNC before; after some
    windows it catches up with two answers, the second one after the window (a contour demo on a
    loaded machine faulted 2 cycles into its task: "1 TPDO(s) twice in one cycle from node 1",
    after three windows one answer behind). Only the window with the burst has no sample."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0)
    one_cycle(ex, clock, None)
    mine = {k: next(f for f in all_answers(k) if f.arbitration_id == tpdo1(2)) for k in range(1, 12)}
    others = {k: [f for f in all_answers(k) if f.arbitration_id != tpdo1(2)] for k in range(1, 12)}
    bus.answers[1] = others[1]
    assert not one_cycle(ex, clock, None).drives[1].fresh
    for k in range(2, 10):  # one behind: the answer to SYNC k-1 in window k
        bus.answers[k] = [*others[k], mine[k - 1]]
        fb = one_cycle(ex, clock, None)
        assert fb.drives[1].fresh and fb.anomalies == (), k
    bus.answers[10] = [*others[10], mine[9]]
    fb = one_cycle(ex, clock, None)
    bus.inbox.append(mine[10])  # caught up: its answer to SYNC 10 after the window, before the next SYNC
    assert fb.anomalies == ()
    bus.answers[11] = all_answers(11)
    fb = one_cycle(ex, clock, None)
    assert fb.drives[1].fresh and fb.anomalies == ()


def test_the_sensor_s_burst_after_a_stall_is_not_a_counter_jump(bus, clock):
    """The sensor stalls for three SYNCs and answers all four at once, one pair in the window and
    three after it: the next window's counter, four on from the burst's first (the sample of its
    window), is its own (found in a soak: "a TPDO the device cannot have sent")."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0, counter=10)
    assert one_cycle(ex, clock, None).sensor.fresh
    sensor_ids = (tpdo1(SENSOR), tpdo2(SENSOR))
    for k in (1, 2, 3):
        bus.answers[k] = [f for f in all_answers(k, counter=10 + k) if f.arbitration_id not in sensor_ids]
        assert not one_cycle(ex, clock, None).sensor.fresh
    burst = [
        f for k in (1, 2, 3, 4) for f in all_answers(k, counter=10 + k) if f.arbitration_id in sensor_ids
    ]
    bus.answers[4] = [*(f for f in all_answers(4) if f.arbitration_id not in sensor_ids), *burst[:2]]
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and not fb.sensor.fresh  # the burst's oldest pair, three SYNCs old
    assert ex.counters.answers_of_unknown_age == 1
    bus.inbox.extend(burst[2:])
    bus.answers[5] = all_answers(5, counter=15)
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and fb.sensor.fresh and fb.sensor.counter == 15


@pytest.mark.parametrize("first", [10, 254])
def test_the_sensor_s_pair_after_lost_frames_dates_itself_by_its_counter_and_is_used_at_once(
    bus, clock, first
):
    """The sensor's frames lost for three SYNCs (never sent late: lost). Its next pair's counter is
    four on after four SYNCs (across the u8's wrap too), so it is its answer to this SYNC: used at
    once, not held back two windows as a burst's oldest answer of unknown age would be (which kept
    the sensor silent four cycles in all, and the contour task braked for it)."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0, counter=first)
    assert one_cycle(ex, clock, None).sensor.fresh
    sensor_ids = (tpdo1(SENSOR), tpdo2(SENSOR))
    for k in (1, 2, 3):
        bus.answers[k] = [f for f in all_answers(k) if f.arbitration_id not in sensor_ids]
        assert not one_cycle(ex, clock, None).sensor.fresh
    bus.answers[4] = all_answers(4, counter=(first + 4) % 256)
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and fb.sensor.fresh and fb.sensor.counter == (first + 4) % 256
    assert ex.counters.answers_of_unknown_age == 0
    bus.answers[5] = all_answers(5, counter=(first + 5) % 256)
    fb = one_cycle(ex, clock, None)
    assert fb.anomalies == () and fb.sensor.fresh


def test_a_sensor_pair_one_step_on_after_lost_frames_is_still_of_unknown_age(bus, clock):
    """Three SYNCs without the sensor, then a lone pair only one step on: the oldest of a burst,
    whatever its counter says otherwise; not used (its age is not this SYNC's)."""
    ex = make_exchange(bus, clock)
    bus.answers[0] = all_answers(0, counter=10)
    assert one_cycle(ex, clock, None).sensor.fresh
    sensor_ids = (tpdo1(SENSOR), tpdo2(SENSOR))
    for k in (1, 2, 3):
        bus.answers[k] = [f for f in all_answers(k) if f.arbitration_id not in sensor_ids]
        one_cycle(ex, clock, None)
    bus.answers[4] = all_answers(4, counter=11)
    fb = one_cycle(ex, clock, None)
    assert not fb.sensor.fresh and ex.counters.answers_of_unknown_age == 1


# -- sleeping through the answer window (window_sleep, as the service runs it) ----------------


class WindowSleeper:
    """The exchange's ``window_sleep`` on the fake clock: it moves the clock to the time asked for,
    and the frames scheduled to come before then reach the bus's inbox (they came while the
    exchange slept). ``ScriptedBus`` asserts that nothing waits on the bus itself."""

    def __init__(self, bus: ScriptedBus, clock: FakeClock) -> None:
        self.bus, self.clock = bus, clock
        self.slept_to: list[float] = []
        self.coming: list[tuple[float, can.Message]] = []  # (when it comes, frame)

    def __call__(self, until_s: float) -> None:
        self.slept_to.append(until_s)
        self.clock.now_s = max(self.clock.now_s, until_s)
        self.bus.inbox.extend(f for t, f in self.coming if t <= until_s)
        self.coming = [(t, f) for t, f in self.coming if t > until_s]


def test_a_sleeping_collect_wakes_once_at_the_windows_end_and_judges_every_frame_that_came_in_it(bus, clock):
    """One sleep to the window's end, then every frame that came read: the answers, and a second
    sender on drive 2's COB-ID after the true one, which makes its sample ambiguous as when read
    as it came. Nothing waits on the bus (``ScriptedBus`` would fail a wait)."""
    sleeper = WindowSleeper(bus, clock)
    read: list[tuple[float, int]] = []
    ex = make_exchange(
        bus, clock, sink=lambda out, t, msg: read.append((t, msg.arbitration_id)), window_sleep=sleeper
    )
    ex.send(None)
    sent, deadline = clock(), clock() + 0.002
    sleeper.coming = [(sent + 0.0003, f) for f in all_answers(0)]
    sleeper.coming.append((sent + 0.0015, frame(tpdo1(2), drive_pdo(0x1637, 77))))
    read.clear()  # the frames sent
    fb = ex.collect(deadline)
    assert sleeper.slept_to == [deadline] and clock() == deadline
    assert read == [(deadline, f.arbitration_id) for f in all_answers(0)] + [(deadline, tpdo1(2))]
    assert [d.fresh for d in fb.drives] == [True, False, True] and fb.sensor is not None and fb.sensor.fresh
    assert (Anomaly.DUPLICATE_FRAME, tpdo1(2)) in {(a.kind, a.cob_id) for a in fb.anomalies}
    assert ex.counters.missing_drive_frames == 1


def test_a_sleeping_collect_with_a_shorter_window_sleeps_on_to_the_deadline_only_for_a_device_unheard(
    bus, clock
):
    """With an answer window shorter than the loop's deadline (``answer_window_s``): complete at
    the window's end, it ends there; one device unheard, it sleeps on to the deadline and takes
    that device's answer, which came after the window's end."""
    sleeper = WindowSleeper(bus, clock)
    ex = make_exchange(bus, clock, window_sleep=sleeper, answer_window_s=0.001)
    ex.send(None)
    window_end, deadline = clock() + 0.001, clock() + 0.002
    sleeper.coming = [(clock() + 0.0003, f) for f in all_answers(0)]
    fb = ex.collect(deadline)
    assert sleeper.slept_to == [window_end] and all(d.fresh for d in fb.drives)

    clock.now_s = deadline + 0.0005
    ex.send(None)
    window_end, deadline = clock() + 0.001, clock() + 0.002
    answers = all_answers(1)
    sleeper.coming = [(clock() + 0.0003, f) for f in answers if f.arbitration_id != tpdo1(3)]
    sleeper.coming.append((clock() + 0.0015, next(f for f in answers if f.arbitration_id == tpdo1(3))))
    fb = ex.collect(deadline)
    assert sleeper.slept_to[1:] == [window_end, deadline]
    assert all(d.fresh for d in fb.drives) and ex.counters.missing_drive_frames == 0


def test_a_sleeping_collect_woken_past_its_window_reads_without_sleeping(bus, clock):
    """A loop held up past the window's end: nothing to sleep for, the answers waiting are read."""
    sleeper = WindowSleeper(bus, clock)
    ex = make_exchange(bus, clock, window_sleep=sleeper)
    bus.answers[0] = all_answers(0)
    ex.send(None)
    deadline = clock() + 0.002
    clock.now_s = deadline + 0.004
    fb = ex.collect(deadline)
    assert sleeper.slept_to == [] and all(d.fresh for d in fb.drives)


# -- SYNC from the kernel (bus.sync_producer = "kernel"): the windows follow the SYNCs -------------

KERNEL_PERIOD_S = 0.04


def kernel_sync(slot: int) -> can.Message:
    """The broadcast manager's SYNC of period ``slot``, received 0.3 ms after its time."""
    msg = frame(SYNC_ID, b"")
    msg.timestamp = slot * KERNEL_PERIOD_S + 0.0003
    return msg


def drive_answers(slot: int) -> list[can.Message]:
    return [frame(tpdo1(n), drive_pdo(0x1637, 5_000_000 + 1000 * n + slot)) for n in DRIVES]


def kernel_exchange(bus: ScriptedBus, clock: FakeClock, sleeps: bool = False) -> CyclicExchange:
    """``sleeps``: the exchange sleeps through its windows (``window_sleep``, the service at 400 Hz)."""
    ex = CyclicExchange(
        bus,
        DRIVES,
        PositionScale(COUNTS_PER_M),
        None,
        CONTROLLER,
        heartbeat_every=10**9,
        clock=clock,
        send_sync=False,
        sync_period_s=KERNEL_PERIOD_S,
        window_sleep=WindowSleeper(bus, clock) if sleeps else None,
    )
    ex.sync_slot_of = lambda stamp: round(stamp / KERNEL_PERIOD_S)  # what KernelSyncExchange installs
    return ex


def kernel_cycle(ex, bus, clock, slot, before_send=(), after_send=()):
    """One loop cycle of SYNC period ``slot``: frames that came before its send (a loop that woke
    late), its send, frames after it, its collect."""
    ex.cycle_slot = slot  # what KernelSyncExchange sets before each send
    bus.inbox.extend(before_send)
    ex.send(None)
    bus.inbox.extend(after_send)
    fb = ex.collect(clock())
    clock.now_s += KERNEL_PERIOD_S
    return fb


def positions(fb) -> list[int]:
    return [round(d.position * COUNTS_PER_M) if d.fresh else -1 for d in fb.drives]


@pytest.mark.parametrize(
    "sleeps", [False, True], ids=["reading-as-frames-come", "sleeping-through-the-window"]
)
def test_kernel_sync_a_loop_that_wakes_after_its_sync_takes_the_answers_that_followed_it(bus, clock, sleeps):
    ex = kernel_exchange(bus, clock, sleeps)
    assert positions(kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])) == [
        5_001_000,
        5_002_000,
        5_003_000,
    ]
    # the loop woke after SYNC 1, the drives had answered it: those answers are cycle 1's sample (they
    # were taken for late frames of cycle 0, a second sender: the 25-Hz path faulted on it on vcan)
    fb = kernel_cycle(ex, bus, clock, 1, before_send=[kernel_sync(1), *drive_answers(1)])
    assert fb.anomalies == () and positions(fb) == [5_001_001, 5_002_001, 5_003_001]
    fb = kernel_cycle(ex, bus, clock, 2, after_send=[kernel_sync(2), *drive_answers(2)])
    assert fb.anomalies == () and positions(fb) == [5_001_002, 5_002_002, 5_003_002]


def test_kernel_sync_a_sync_later_than_its_window_leaves_its_answers_late_and_the_next_cycle_in_step(
    bus, clock
):
    ex = kernel_exchange(bus, clock)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    assert positions(kernel_cycle(ex, bus, clock, 1)) == [-1, -1, -1]  # SYNC 1 not there yet
    late_before = ex.counters.late_frames
    fb = kernel_cycle(
        ex,
        bus,
        clock,
        2,
        before_send=[kernel_sync(1), *drive_answers(1)],
        after_send=[kernel_sync(2), *drive_answers(2)],
    )
    # SYNC 1's answers are not cycle 2's sample; SYNC 2's are
    assert fb.anomalies == () and positions(fb) == [5_001_002, 5_002_002, 5_003_002]
    assert ex.counters.late_frames - late_before == 3
    fb = kernel_cycle(ex, bus, clock, 3, after_send=[kernel_sync(3), *drive_answers(3)])
    assert fb.anomalies == () and positions(fb) == [5_001_003, 5_002_003, 5_003_003]


@pytest.mark.parametrize(
    "sleeps", [False, True], ids=["reading-as-frames-come", "sleeping-through-the-window"]
)
def test_kernel_sync_a_collect_stops_at_the_next_sync_and_its_answers_are_the_next_cycle_s(
    bus, clock, sleeps
):
    ex = kernel_exchange(bus, clock, sleeps)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    fb = kernel_cycle(
        ex, bus, clock, 1, after_send=[kernel_sync(1), *drive_answers(1), kernel_sync(2), *drive_answers(2)]
    )
    assert fb.anomalies == () and positions(fb) == [5_001_001, 5_002_001, 5_003_001]
    fb = kernel_cycle(ex, bus, clock, 2)  # SYNC 2 and its answers came during the collect before
    assert fb.anomalies == () and positions(fb) == [5_001_002, 5_002_002, 5_003_002]


def test_kernel_sync_the_answers_to_a_skipped_cycle_s_sync_are_nobody_s_sample(bus, clock):
    ex = kernel_exchange(bus, clock)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    kernel_cycle(ex, bus, clock, 1, after_send=[kernel_sync(1), *drive_answers(1)])
    late_before = ex.counters.late_frames
    # the loop overran: cycle 2 skipped, cycle 3 woke after its SYNC
    fb = kernel_cycle(
        ex, bus, clock, 3, before_send=[kernel_sync(2), *drive_answers(2), kernel_sync(3), *drive_answers(3)]
    )
    assert fb.anomalies == () and positions(fb) == [5_001_003, 5_002_003, 5_003_003]
    assert ex.counters.late_frames - late_before == 3


def test_kernel_sync_a_second_sender_is_still_found_when_the_loop_woke_late(bus, clock):
    ex = kernel_exchange(bus, clock)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    rogue = frame(tpdo1(2), drive_pdo(0x1637, 5_002_001))
    fb = kernel_cycle(ex, bus, clock, 1, before_send=[kernel_sync(1), *drive_answers(1), rogue])
    assert {(a.kind, a.node_id) for a in fb.anomalies} == {(Anomaly.DUPLICATE_FRAME, 2)}
    assert positions(fb) == [5_001_001, -1, 5_003_001]


def test_kernel_sync_two_syncs_nearest_one_period_are_each_answered_not_a_second_sender(bus, clock):
    """A stall of the kernel's timer leaves a SYNC half a period late; the lock pulls the next one in
    (0.9 periods): both round to one period. The devices answer both."""
    ex = kernel_exchange(bus, clock)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    late = frame(SYNC_ID, b"")
    late.timestamp = 0.6 * KERNEL_PERIOD_S  # SYNC 1, 0.4 periods early: nearest period 1
    pulled_in = frame(SYNC_ID, b"")
    pulled_in.timestamp = 1.45 * KERNEL_PERIOD_S  # the next, 0.85 periods on: nearest period 1 too
    fb = kernel_cycle(ex, bus, clock, 1, after_send=[late, *drive_answers(1)])
    assert fb.anomalies == () and positions(fb) == [5_001_001, 5_002_001, 5_003_001]
    fb = kernel_cycle(ex, bus, clock, 2, before_send=[pulled_in, *drive_answers(2)])
    assert fb.anomalies == ()  # its answers came before cycle 2's send: late, owed, not a second sender
    fb = kernel_cycle(ex, bus, clock, 3, after_send=[kernel_sync(3), *drive_answers(3)])
    assert fb.anomalies == () and positions(fb) == [5_001_003, 5_002_003, 5_003_003]


def test_kernel_sync_a_loop_behind_two_syncs_takes_their_late_answers_for_owed_not_a_second_sender(
    bus, clock
):
    """The kernel-SYNC defect ("TPDO twice in one cycle" with one sender): the loop woke after SYNC 1
    and SYNC 2, the drives answered both after its send. The window went back to the loop's own
    period 1 and took SYNC 1's answer with none owed, and SYNC 2's, after it, was a second sender's;
    it now stays on period 2, with SYNC 1's answer owed."""
    ex = kernel_exchange(bus, clock)
    kernel_cycle(ex, bus, clock, 0, after_send=[kernel_sync(0), *drive_answers(0)])
    fb = kernel_cycle(
        ex,
        bus,
        clock,
        1,
        before_send=[kernel_sync(1), kernel_sync(2)],
        after_send=[*drive_answers(1), *drive_answers(2)],
    )
    assert fb.anomalies == ()  # SYNC 1's answer is owed, SYNC 2's may come with it: no second sender
    for slot in (3, 4):
        fb = kernel_cycle(ex, bus, clock, slot, after_send=[kernel_sync(slot), *drive_answers(slot)])
        assert fb.anomalies == () and positions(fb) == [5_001_000 + slot, 5_002_000 + slot, 5_003_000 + slot]


def test_kernel_sync_a_debt_from_two_syncs_in_one_period_is_not_forgotten_by_the_windows_before_it(
    bus, clock
):
    """A device in step for more windows than OWED_FORGOTTEN_AFTER; then a SYNC half a period late
    and the next on time round to one period, the second's answer after the window: it is owed (the
    count of windows in step started before the debt and forgot it at once)."""
    ex = kernel_exchange(bus, clock)
    for slot in range(OWED_FORGOTTEN_AFTER + 5):
        kernel_cycle(ex, bus, clock, slot, after_send=[kernel_sync(slot), *drive_answers(slot)])
    k = OWED_FORGOTTEN_AFTER + 5
    late, next_one = frame(SYNC_ID, b""), frame(SYNC_ID, b"")
    late.timestamp = (k + 0.52) * KERNEL_PERIOD_S  # SYNC k, half a period late: nearest period k + 1
    next_one.timestamp = (k + 1.1) * KERNEL_PERIOD_S  # SYNC k + 1: nearest period k + 1 too
    fb = kernel_cycle(ex, bus, clock, k, before_send=[late], after_send=[next_one, *drive_answers(k)])
    assert fb.anomalies == ()
    fb = kernel_cycle(ex, bus, clock, k + 1, before_send=drive_answers(k + 1))  # SYNC k + 1's answers, late
    assert fb.anomalies == ()
    fb = kernel_cycle(ex, bus, clock, k + 2, after_send=[kernel_sync(k + 2), *drive_answers(k + 2)])
    assert fb.anomalies == () and positions(fb) == [5_001_000 + k + 2, 5_002_000 + k + 2, 5_003_000 + k + 2]
