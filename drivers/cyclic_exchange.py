"""The cyclic PDO path: one batch out (RPDOs, SYNC, heartbeat), one batch in (TPDOs), per cycle.

Lean on purpose (DESIGN.md): COB-IDs, struct layouts and ``can.Message`` objects are built
once; a cycle only rewrites payload bytes. Every received frame enters through ``_notify``
and is dispatched by COB-ID; frames the bus echoes back (our own RPDOs, SYNC, heartbeat)
fall through the table. Decoding errors never leave this module: they are counted.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import can

from controller.core.cycle_data import BusFeedback, CycleOutputs, DriveFeedback, EmcyReport, SensorFeedback
from drivers import cob_ids
from drivers.pdo_codec import (
    DRIVE_RPDO,
    FORCE_N_PER_COUNT,
    TORQUE_NM_PER_COUNT,
    FrameError,
    PositionScale,
    decode_drive_tpdo,
    decode_sensor_frame,
)

FrameSink = Callable[[bool, float, can.Message], None]  # (outgoing, monotonic time [s], frame)

_DRIVE, _SENSOR_FORCE, _SENSOR_TORQUE, _EMCY, _HEARTBEAT = range(5)
CAN_ERR_BUSOFF = 0x040  # error class bit of a SocketCAN error frame (linux/can/error.h)


@dataclass
class ExchangeCounters:
    frames_in: int = 0
    frames_out: int = 0
    rejected_frames: int = 0  # frames that did not decode
    late_frames: int = 0  # TPDOs of an earlier cycle, found before this cycle's SYNC
    missing_drive_frames: int = 0
    missing_sensor_frames: int = 0
    error_frames: int = 0
    send_errors: int = 0


class CyclicExchange:
    def __init__(self, bus: can.BusABC, drive_ids: tuple[int, ...], scale: PositionScale,
                 sensor_id: int | None, controller_id: int, heartbeat_every: int, fd: bool = False,
                 clock: Callable[[], float] = time.monotonic, frame_sink: FrameSink | None = None,
                 heartbeat_timeout_s: float = 0.5) -> None:
        self.bus = bus
        self.n = len(drive_ids)
        self.scale = scale
        self.has_sensor = sensor_id is not None
        self.heartbeat_every = max(1, heartbeat_every)
        self.clock = clock
        self.frame_sink = frame_sink
        self.counters = ExchangeCounters()
        self._rpdos = [can.Message(arbitration_id=cob_ids.rpdo1(i), data=bytearray(DRIVE_RPDO.size),
                                   is_extended_id=False, is_fd=fd, bitrate_switch=fd) for i in drive_ids]
        self._sync = can.Message(arbitration_id=cob_ids.SYNC, data=b"", is_extended_id=False, is_fd=fd,
                                 bitrate_switch=fd)
        # Heartbeat of the controller, NMT state 5 (operational): the drives consume it.
        self._heartbeat = can.Message(arbitration_id=cob_ids.heartbeat(controller_id), data=b"\x05",
                                      is_extended_id=False)
        self._dispatch: dict[int, tuple[int, int]] = {}
        for j, i in enumerate(drive_ids):
            self._dispatch[cob_ids.tpdo1(i)] = (_DRIVE, j)
            self._dispatch[cob_ids.emcy(i)] = (_EMCY, i)
            self._dispatch[cob_ids.heartbeat(i)] = (_HEARTBEAT, j)
        if sensor_id is not None:
            self._dispatch[cob_ids.tpdo1(sensor_id)] = (_SENSOR_FORCE, 0)
            self._dispatch[cob_ids.tpdo2(sensor_id)] = (_SENSOR_TORQUE, 0)
            self._dispatch[cob_ids.emcy(sensor_id)] = (_EMCY, sensor_id)
        self._statusword = [0] * self.n
        self._position = [math.nan] * self.n
        self._fresh = [False] * self.n
        self._force = (0.0, 0.0, 0.0)
        self._torque = (0.0, 0.0, 0.0)
        self._sensor_status = 0
        self._force_counter = -1
        self._torque_counter = -1
        self._sensor_fresh = False
        self._emcy: list[EmcyReport] = []
        self._collecting = False
        self.drive_ids = tuple(drive_ids)
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.last_heartbeat_s = [math.nan] * self.n
        self.started_s = clock()
        self._error_frames = 0
        self._bus_off = False
        self.cycles = 0
        self.last_frame_in_s = 0.0  # arrival of the last frame that completed a cycle's inputs
        self.sent_s = 0.0  # when this cycle's RPDOs went out

    # -- out --------------------------------------------------------------------------------

    def _send(self, msg: can.Message) -> None:
        try:
            self.bus.send(msg, timeout=0.0)
        except can.CanError:
            # A full transmit queue (ENOBUFS) or a bus-off must not raise mid-cycle:
            # count it; the missing answers show up as missing TPDOs.
            self.counters.send_errors += 1
            return
        self.counters.frames_out += 1
        if self.frame_sink is not None:
            self.frame_sink(True, self.clock(), msg)

    def send(self, outputs: CycleOutputs | None) -> None:
        """RPDOs of ``outputs`` (none before the first step), then SYNC; every Nth cycle a heartbeat."""
        self._drain_late()
        self.sent_s = self.clock()
        if outputs is not None:
            to_counts = self.scale.to_counts
            for msg, cw, target in zip(self._rpdos, outputs.controlwords, outputs.targets):
                DRIVE_RPDO.pack_into(msg.data, 0, cw, to_counts(target))
                self._send(msg)
        self._send(self._sync)
        if self.cycles % self.heartbeat_every == 0:
            self._send(self._heartbeat)
        self.cycles += 1
        self._fresh = [False] * self.n
        self._sensor_fresh = False
        self._force_counter = self._torque_counter = -1
        self._emcy = []
        self._error_frames = 0
        self._bus_off = False

    # -- in ---------------------------------------------------------------------------------

    def _drain_late(self) -> None:
        self._collecting = False
        while True:
            msg = self.bus.recv(timeout=0.0)
            if msg is None:
                return
            self._notify(msg)

    def _complete(self) -> bool:
        return all(self._fresh) and (self._sensor_fresh or not self.has_sensor)

    def collect(self, deadline_s: float) -> BusFeedback:
        """Receive until every TPDO of this cycle arrived or ``deadline_s`` (monotonic) passed."""
        self._collecting = True
        clock = self.clock
        while not self._complete():
            # Past the deadline, still take what has already arrived: if this process was
            # descheduled, the answers may be waiting in the socket, and they are on time.
            remaining = max(0.0, deadline_s - clock())
            msg = self.bus.recv(timeout=remaining)
            if msg is None:
                break
            self._notify(msg)
        c = self.counters
        missing = self.n - sum(self._fresh)
        c.missing_drive_frames += missing
        if self.has_sensor and not self._sensor_fresh:
            c.missing_sensor_frames += 1
        drives = tuple(DriveFeedback(sw, x, f) for sw, x, f in zip(self._statusword, self._position, self._fresh))
        sensor = SensorFeedback(self._force, self._torque, self._sensor_status, max(self._force_counter, 0),
                                self._sensor_fresh) if self.has_sensor else None
        now = clock()
        lost = tuple(node for node, last in zip(self.drive_ids, self.last_heartbeat_s)
                     if now - (self.started_s if math.isnan(last) else last) > self.heartbeat_timeout_s)
        return BusFeedback(drives=drives, sensor=sensor, emcy=tuple(self._emcy), lost_heartbeats=lost,
                            error_frames=self._error_frames, bus_off=self._bus_off)

    def _notify(self, msg: can.Message) -> None:
        now = self.clock()
        c = self.counters
        c.frames_in += 1
        if self.frame_sink is not None:
            self.frame_sink(False, now, msg)
        if msg.is_error_frame:
            c.error_frames += 1
            self._error_frames += 1
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                self._bus_off = True
            return
        route = self._dispatch.get(msg.arbitration_id)
        if route is None:
            return
        kind, index = route
        try:
            if kind == _DRIVE:
                sw, counts = decode_drive_tpdo(msg.data)
                self._statusword[index] = sw
                self._position[index] = self.scale.to_unit(counts)
                if self._collecting:
                    self._fresh[index] = True
                    self.last_frame_in_s = now
                else:
                    c.late_frames += 1
            elif kind in (_SENSOR_FORCE, _SENSOR_TORQUE):
                per_count = FORCE_N_PER_COUNT if kind == _SENSOR_FORCE else TORQUE_NM_PER_COUNT
                x, y, z, status, counter = decode_sensor_frame(msg.data, per_count)
                if kind == _SENSOR_FORCE:
                    self._force, self._force_counter = (x, y, z), counter
                else:
                    self._torque, self._torque_counter = (x, y, z), counter
                self._sensor_status = status
                if self._collecting and self._force_counter == self._torque_counter:
                    self._sensor_fresh = True
                    self.last_frame_in_s = now
                elif not self._collecting:
                    c.late_frames += 1
            elif kind == _EMCY:
                if len(msg.data) != 8:
                    raise FrameError(f"EMCY from node {index} must have 8 data bytes, got {len(msg.data)}")
                code = int.from_bytes(msg.data[0:2], "little")
                self._emcy.append(EmcyReport(index, code, msg.data[2]))
            elif kind == _HEARTBEAT:
                self.last_heartbeat_s[index] = now
        except FrameError:
            c.rejected_frames += 1
