"""The simulator's cyclic thread on a scripted bus: the exact frames it answers with.

The bus is a ``can.BusABC`` whose received frames the test scripts and whose sent frames it
records; the test waits on the frames it expects (a condition variable), never on a sleep.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator

import can
import pytest

from controller.config import load_config
from controller.core.cia402 import (
    CW_ENABLE_OPERATION,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    PowerState,
    decode_statusword,
)
from controller.robot_registry import robot_entry
from drivers import cob_ids
from drivers.pacing import arrival_s
from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    decode_drive_tpdo,
    decode_sensor_frame,
    encode_drive_rpdo,
    encode_drive_tpdo,
)
from sim_backend.server import Simulator

WAIT_S = 20.0  # generous: only a broken simulator takes this long
COUNTS_PER_M = 1e7


class ScriptedBus(can.BusABC):
    """Frames to receive are queued by the test; frames sent are recorded and announced."""

    def __init__(self) -> None:
        self.inbox: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self.sent: list[can.Message] = []
        self._changed = threading.Condition()
        super().__init__(channel="scripted")
        self.channel_info = "scripted bus"

    def push(self, *msgs: can.Message) -> None:
        for m in msgs:
            self.inbox.put(m)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        copy = can.Message(
            arbitration_id=msg.arbitration_id,
            data=bytes(msg.data),
            is_extended_id=False,
            is_error_frame=msg.is_error_frame,
            is_fd=msg.is_fd,
        )
        with self._changed:
            self.sent.append(copy)
            self._changed.notify_all()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            return self.inbox.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def wait_for(self, done: Callable[[list[can.Message]], bool]) -> list[can.Message]:
        with self._changed:
            if not self._changed.wait_for(lambda: done(self.sent), timeout=WAIT_S):
                raise AssertionError(
                    f"expected frames not sent; sent: {[hex(m.arbitration_id) for m in self.sent]}"
                )
            return list(self.sent)


def frame(cob_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


def after(sent: list[can.Message], start: int, cob_id: int) -> list[can.Message]:
    return [m for m in sent[start:] if m.arbitration_id == cob_id]


@pytest.fixture
def sim() -> Iterator[tuple[Simulator, ScriptedBus]]:
    cfg = load_config()
    bus = ScriptedBus()
    simulator = Simulator(cfg, bus)
    simulator.start()
    try:
        nodes = (*cfg.actuators.node_ids, cfg.sensor.node_id)
        bus.wait_for(
            lambda sent: all(
                any(m.arbitration_id == cob_ids.heartbeat(n) and bytes(m.data) == b"\x00" for m in sent)
                for n in nodes
            )
        )  # boot-up messages
        bus.push(frame(cob_ids.NMT, bytes([0x01, 0x00])))  # NMT start, all nodes
        yield simulator, bus
    finally:
        simulator.stop()
        bus.shutdown()


def sync_and_wait(bus: ScriptedBus, *before: can.Message, tpdos: int = 5) -> list[can.Message]:
    """Push the frames and a SYNC; wait for its ``tpdos`` answers; return the frames sent after the SYNC."""
    start = len(bus.sent)
    bus.push(*before, frame(cob_ids.SYNC))
    tpdo_ids = {cob_ids.tpdo1(n) for n in (1, 2, 3)} | {cob_ids.tpdo1(16), cob_ids.tpdo2(16)}
    sent = bus.wait_for(lambda s: sum(m.arbitration_id in tpdo_ids for m in s[start:]) >= tpdos)
    return sent[start:]


def rpdos(controlword: int, targets_m: tuple[float, ...]) -> list[can.Message]:
    return [
        frame(cob_ids.rpdo1(n), encode_drive_rpdo(controlword, round(x * COUNTS_PER_M)))
        for n, x in zip((1, 2, 3), targets_m, strict=True)
    ]


def test_sync_is_answered_with_the_exact_tpdos_of_every_device(sim):
    simulator, bus = sim
    out = sync_and_wait(bus)
    for j, node in enumerate((1, 2, 3)):
        (tpdo,) = after(out, 0, cob_ids.tpdo1(node))
        d = simulator.drives[j]
        assert bytes(tpdo.data) == encode_drive_tpdo(d.statusword(), d.position_counts())
        assert decode_statusword(decode_drive_tpdo(tpdo.data)[0]) == PowerState.SWITCH_ON_DISABLED
    (force,) = after(out, 0, cob_ids.tpdo1(16))
    (torque,) = after(out, 0, cob_ids.tpdo2(16))
    fx, fy, fz, status, counter = decode_sensor_frame(force.data, FORCE_N_PER_COUNT)
    assert counter == decode_sensor_frame(torque.data, 0.001)[4] == 1 and status == 0
    bias = load_config().sim.sensor.bias_n  # free space: bias and noise only
    assert (fx, fy, fz) == pytest.approx(bias, abs=0.5)


def test_a_sync_is_latched_when_it_arrived_not_when_the_simulator_got_to_it(sim):
    """A real drive latches at SYNC; the simulator's process may come to the frame later. Its
    receive timestamp (wall clock, python-can's) says when it arrived: 3 ms before it was pushed
    here, so the drives latch 3 ms before the push, however late the thread handles it."""
    simulator, bus = sim
    start = len(bus.sent)
    pushed_s = time.monotonic()
    sync = frame(cob_ids.SYNC)
    sync.timestamp = time.time() - 0.003
    bus.push(sync)
    tpdo_ids = {cob_ids.tpdo1(n) for n in (1, 2, 3)}
    bus.wait_for(lambda s: sum(m.arbitration_id in tpdo_ids for m in s[start:]) >= 3)
    assert simulator.plant.last_sync_s is not None
    assert simulator.plant.last_sync_s < pushed_s - 0.002


def test_a_frame_without_a_plausible_timestamp_is_timed_by_its_handling():
    assert arrival_s(1000.000, now_s=50.002, wall_now_s=1000.002) == pytest.approx(50.000)
    assert arrival_s(0.0, now_s=50.0, wall_now_s=1000.0) == 50.0  # no timestamp (a frame built here)
    assert arrival_s(1000.5, now_s=50.0, wall_now_s=1000.0) == 50.0  # from the future: another clock
    assert arrival_s(998.0, now_s=50.0, wall_now_s=1000.0) == 50.0  # 2 s old: beyond MAX_FRAME_AGE_S


def test_rpdo_targets_wait_for_the_next_sync_and_a_batch_is_drained_in_order(sim):
    simulator, bus = sim
    start = tuple(d.position for d in simulator.drives)
    for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
        sync_and_wait(bus, *rpdos(cw, start))
    assert all(d.power == PowerState.OPERATION_ENABLED for d in simulator.drives)
    for d in simulator.drives:
        d.mode_of_operation = 8  # CSP (what the set-up writes over SDO)
    # three cycles queued at once, as a stalled simulator finds them: each RPDO before its SYNC
    step = 1e-4
    batch = []
    for k in (1, 2, 3):
        batch += [*rpdos(CW_ENABLE_OPERATION, tuple(x + k * step for x in start)), frame(cob_ids.SYNC)]
    first = len(bus.sent)
    bus.push(*batch)
    bus.wait_for(lambda s: len(after(s, first, cob_ids.tpdo1(3))) >= 3)
    for d, x in zip(simulator.drives, start, strict=True):
        assert d.latched_target == pytest.approx(
            x + 3 * step, abs=1e-9
        )  # the last SYNC latched the last target
    assert simulator.sync_count == 3 + 3


def test_echoed_own_frames_and_unknown_ids_change_nothing(sim):
    simulator, bus = sim
    before = [(d.power, d.received_target) for d in simulator.drives]
    bus.push(frame(cob_ids.tpdo1(1), bytes(6)), frame(0x123, bytes(8)), frame(cob_ids.emcy(2), bytes(8)))
    sync_and_wait(bus)  # processed in order: everything before the SYNC was handled
    assert [(d.power, d.received_target) for d in simulator.drives] == before
    assert simulator.rejected_frames == 0


def test_sdo_reaches_canopens_node_through_the_cyclic_thread(sim):
    simulator, bus = sim
    sdo_rx, sdo_tx = 0x600 + 2, 0x580 + 2
    # expedited downloads of one byte (command 0x2F): 0x60C2 sub 2 = -4, sub 1 = 25 -> 2.5 ms
    for sub, value in ((2, 0xFC), (1, 25)):
        start = len(bus.sent)
        bus.push(frame(sdo_rx, bytes([0x2F, 0xC2, 0x60, sub, value, 0, 0, 0])))
        sent = bus.wait_for(lambda s, start=start: bool(after(s, start, sdo_tx)))
        reply = after(sent, start, sdo_tx)[0]
        assert bytes(reply.data)[:4] == bytes([0x60, 0xC2, 0x60, sub])  # download confirmed
    assert simulator.drives[1].interpolation_period_s == pytest.approx(0.0025)
    assert simulator.drives[0].interpolation_period_s == 0.0


@pytest.fixture
def faulty_sim(request) -> Iterator[tuple[Simulator, ScriptedBus]]:
    cfg = load_config(overrides={"sim.faults": [request.param]})
    bus = ScriptedBus()
    simulator = Simulator(cfg, bus)
    simulator.start()
    try:
        bus.wait_for(lambda sent: any(m.arbitration_id == cob_ids.heartbeat(16) for m in sent))
        bus.push(frame(cob_ids.NMT, bytes([0x01, 0x00])))
        yield simulator, bus
    finally:
        simulator.stop()
        bus.shutdown()


@pytest.mark.parametrize(
    "faulty_sim,bus_off", [("error_frames@0", False), ("bus_off@0", True)], indirect=["faulty_sim"]
)
def test_a_bus_fault_is_one_decision_sent_as_a_frame_and_fed_back_in_process(faulty_sim, bus_off):
    """The simulator process sends the error frame the in-process loopback reports as feedback
    (sim_backend/fault_injection.py ``bus_faults``), and the exchange reads it the same way."""
    from drivers.cyclic_exchange import CAN_ERR_BUSOFF
    from sim_backend.loopback import LoopbackExchange

    simulator, bus = faulty_sim
    start = len(bus.sent)
    bus.push(frame(cob_ids.SYNC))
    sent = bus.wait_for(lambda s: any(m.is_error_frame for m in s[start:]))
    (error,) = [m for m in sent[start:] if m.is_error_frame]
    assert bool(error.arbitration_id & CAN_ERR_BUSOFF) == bus_off  # how drivers/cyclic_exchange.py reads it
    loopback = LoopbackExchange(simulator.cfg, lambda: 0.0)
    loopback.send(None)
    feedback = loopback.collect(0.0)
    assert (feedback.error_frames, feedback.bus_off) == (1, bus_off)


@pytest.mark.parametrize("faulty_sim", ["tx_full@0+0.000001"], indirect=True)
def test_a_full_transmit_queue_leaves_the_sync_unanswered_in_the_simulator_process_too(faulty_sim):
    simulator, bus = faulty_sim
    start = len(bus.sent)
    bus.push(frame(cob_ids.SYNC), *rpdos(CW_SHUTDOWN, (0.5, 0.5, 0.5)))  # lost: tx_full is active
    out = sync_and_wait(bus)  # after the fault's microsecond: answered
    assert simulator.sync_count == 1
    assert len(after(bus.sent, start, cob_ids.tpdo1(1))) == 1 == len(after(out, 0, cob_ids.tpdo1(1)))
    assert all(d.received_target != 0.5 for d in simulator.drives)


def test_the_simulated_tracker_answers_a_sync_with_the_pose_in_two_frames():
    from controller.core.rotations import so3_log
    from drivers.pdo_codec import TRACKER_M_PER_COUNT, TRACKER_RAD_PER_COUNT, decode_tracker_frame

    cfg = load_config(
        robot_entry("nspu").config_file,
        {"tracker.enabled": True, "sim.tracker.position_noise_m": 0.0, "sim.tracker.angle_noise_rad": 0.0},
    )
    bus = ScriptedBus()
    simulator = Simulator(cfg, bus)
    simulator.start()
    try:
        node = cfg.tracker.node_id
        bus.push(frame(cob_ids.NMT, bytes([0x01, 0x00])), frame(cob_ids.SYNC))
        sent = bus.wait_for(lambda s: any(m.arbitration_id == cob_ids.tpdo2(node) for m in s))
        (p_frame,) = after(sent, 0, cob_ids.tpdo1(node))
        (r_frame,) = after(sent, 0, cob_ids.tpdo2(node))
        p = decode_tracker_frame(p_frame.data, TRACKER_M_PER_COUNT)
        r = decode_tracker_frame(r_frame.data, TRACKER_RAD_PER_COUNT)
        pose = simulator.plant.kinematics.pose  # type: ignore[attr-defined]
        assert p[:3] == pytest.approx(tuple(pose.p_m), abs=TRACKER_M_PER_COUNT / 2)
        assert r[:3] == pytest.approx(tuple(so3_log(pose.R)), abs=TRACKER_RAD_PER_COUNT / 2)
        assert p[3:] == r[3:] == (0, 1)  # status, counter: one sample
    finally:
        simulator.stop()
        bus.shutdown()


@pytest.mark.parametrize("late_s", [0.0, 0.0012, 0.002])
def test_after_a_late_sync_the_drives_move_as_integrated_to_each_sync_when_it_came(late_s):
    """A real drive is causal: a SYNC late by ``late_s``, and the next one on the loop's grid (the
    loop catches up: it comes ``PERIOD - late_s`` after), move its carriage as its interpolator
    gives, at the times the SYNCs came. The simulator's answers are those of a plant integrated to
    each SYNC when it came (``RobotPlant.sync``), bit for bit. Integrating the interval after
    each SYNC ahead, to answer the next sooner, ran the drives a whole period past the late SYNC,
    beyond the next one: 57 um off the undisturbed path 1.2 ms late, 99 um 2 ms late, where the
    causal carriage is 19 and 8 um off, and the drives' answers differed by up to 45 um."""
    from sim_backend.plant import RobotPlant

    period = 0.0025
    now = [100.0]
    cfg = load_config()
    bus = ScriptedBus()
    simulator = Simulator(cfg, bus, clock=lambda: now[0])
    reference = RobotPlant(cfg)
    simulator.start()
    try:
        bus.wait_for(lambda sent: any(m.arbitration_id == cob_ids.heartbeat(16) for m in sent))
        bus.push(frame(cob_ids.NMT, bytes([0x01, 0x00])))
        start = tuple(d.position for d in reference.drives)
        with simulator.lock:
            for d in (*simulator.drives, *reference.drives):
                d.mode_of_operation = 8  # CSP, with 0x60C2 at the period (what the set-up writes)
                d.interpolation_period_s = period
        off_um = []
        for k in range(60):
            cw = (CW_SHUTDOWN, CW_SWITCH_ON)[k] if k < 2 else CW_ENABLE_OPERATION
            targets = tuple(x + 0.02 * (j + 1) * max(0, k - 3) * period for j, x in enumerate(start))
            now[0] = t = 100.0 + k * period + (late_s if k == 40 else 0.0)
            out = sync_and_wait(bus, *rpdos(cw, targets), tpdos=3)
            for d, x in zip(reference.drives, targets, strict=True):
                d.on_rpdo(cw, round(x * COUNTS_PER_M))
            reference.sync(t)
            answered = [decode_drive_tpdo(after(out, 0, cob_ids.tpdo1(n))[0].data)[1] for n in (1, 2, 3)]
            expected = [d.position_counts() for d in reference.drives]
            off_um.append(
                max(abs(a - e) for a, e in zip(answered, expected, strict=True)) / COUNTS_PER_M * 1e6
            )
        assert all(d.power == PowerState.OPERATION_ENABLED for d in simulator.drives)
        assert reference.drives[2].position - start[2] > 1e-3  # the legs moved: up to 60 mm/s
        assert max(off_um) == 0.0, (
            f"answers off the causal plant by {max(off_um):.1f} um (cycle {off_um.index(max(off_um))})"
        )
    finally:
        simulator.stop()
        bus.shutdown()
