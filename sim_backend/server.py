"""The simulator process: CiA 402 drives and a force sensor as CANopen nodes on a CAN bus.

Each device is a ``canopen.LocalNode`` built from the shipped EDS file, so its SDO server,
NMT slave and heartbeat producer are the canopen package's own; this module adds the
device behaviour (``SimulatedDrive``, ``SimulatedForceSensor``), the cyclic PDOs and the
robot's mechanics (the TCP from the drives' positions through the direct kinematics, the
environment's wrench on the sensor). All frame handling runs in canopen's notifier thread;
a watchdog thread advances the drives when SYNC stops, so they quick-stop on their own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import canopen

from controller.config import Config
from drivers import cob_ids
from drivers.pdo_codec import FrameError, decode_drive_rpdo
from sim_backend.drive import SimulatedDrive
from sim_backend.environment import Environment
from sim_backend.fault_injection import FaultSchedule, apply_device_faults, tpdo_payload
from sim_backend.plant import RobotPlant

log = logging.getLogger(__name__)

EDS_DIR = Path(__file__).resolve().parent.parent / "drivers" / "eds"
DRIVE_EDS = EDS_DIR / "cheope_drive.eds"
SENSOR_EDS = EDS_DIR / "force_sensor.eds"
NMT_OPERATIONAL = 5
WATCHDOG_PERIOD_S = 0.005
# A watchdog tick this late means the simulator's process was not running: SYNC frames may be
# waiting unread in its socket, so this tick does not judge them lost (see _watchdog_loop).
STARVED_TICK_S = 4 * WATCHDOG_PERIOD_S


def watchdog_due(now_s: float, previous_tick_s: float, last_sync_s: float | None, sync_timeout_s: float) -> bool:
    """Whether the watchdog thread advances the drives itself on this tick.

    Only when SYNC is overdue by half the drives' timeout, and not on the first tick after a
    stall of the simulator's process, when unread SYNC frames may be waiting in its socket.
    """
    if now_s - previous_tick_s > STARVED_TICK_S:
        return False
    return last_sync_s is None or now_s - last_sync_s >= 0.5 * sync_timeout_s


class Simulator:
    """Simulated hardware on one bus. Use as a context manager."""

    def __init__(self, cfg: Config, bus: can.BusABC, environment: Environment | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.bus = bus
        self.clock = clock
        self.plant = RobotPlant(cfg, environment)
        self.drives = self.plant.drives
        self.sensor = self.plant.sensor
        self.lock = threading.RLock()
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.faults = FaultSchedule.from_strings(tuple(cfg.sim.faults))
        self._fd = getattr(bus, "protocol", None) == can.CanProtocol.CAN_FD
        self._silenced: set[int] = set()
        self.network = canopen.Network(bus)
        self.nodes: dict[int, canopen.LocalNode] = {}
        self.sync_count = 0
        self.rejected_frames = 0
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None

    # -- life cycle -------------------------------------------------------------------------

    def __enter__(self) -> Simulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        self.network.connect()
        for j, node_id in enumerate(self.drive_ids):
            node = canopen.LocalNode(node_id, str(DRIVE_EDS))
            self.network.add_node(node)
            self._wire_drive(node, self.drives[j])
            self.nodes[node_id] = node
            self.network.subscribe(cob_ids.rpdo1(node_id), self._rpdo_handler(j))
        if self.sensor is not None:
            node = canopen.LocalNode(self.cfg.sensor.node_id, str(SENSOR_EDS))
            self.network.add_node(node)
            self.nodes[self.cfg.sensor.node_id] = node
        self.network.subscribe(cob_ids.SYNC, self._on_sync)
        self.network.subscribe(cob_ids.heartbeat(self.cfg.loop.controller_node_id), self._on_controller_heartbeat)
        self.network.subscribe(cob_ids.NMT, self._on_nmt)
        for node in self.nodes.values():
            self._boot(node)
        self._watchdog = threading.Thread(target=self._watchdog_loop, name="sim-watchdog", daemon=True)
        self._watchdog.start()

    def stop(self) -> None:
        self._stop.set()
        if self._watchdog is not None:
            self._watchdog.join(timeout=1.0)
        for node in self.nodes.values():
            node.nmt.stop_heartbeat()
        if self.network.notifier is not None:
            self.network.notifier.stop(1.0)

    def _boot(self, node: canopen.LocalNode) -> None:
        node.nmt.send_command(0x81)  # reset: sends the boot-up message
        node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL, starts the heartbeat of 0x1017

    # -- object dictionary callbacks --------------------------------------------------------

    def _wire_drive(self, node: canopen.LocalNode, drive: SimulatedDrive) -> None:
        def on_read(index: int, subindex: int, od: object) -> int | None:
            with self.lock:
                self.plant.advance(self.clock(), check_sync_timeout=False)
                return {
                    0x6041: drive.statusword, 0x6064: drive.position_counts,
                    0x6061: lambda: drive.mode_of_operation, 0x603F: lambda: drive.error_code,
                }.get(index, lambda: None)()

        def on_write(index: int, subindex: int, od: canopen.objectdictionary.ODVariable, data: bytes) -> None:
            value = od.decode_raw(data)
            with self.lock:
                if index == 0x6060:
                    drive.mode_of_operation = value
                elif index == 0x6040:
                    drive.on_controlword(value)
                elif index == 0x607A:
                    drive.received_target = value / drive.params.counts_per_unit
                elif index == 0x1016 and subindex == 1:
                    # CiA 301: bits 16..23 node id, bits 0..15 consumer time [ms]
                    drive.heartbeat_consumer_s = (value & 0xFFFF) / 1000.0

        node.add_read_callback(on_read)
        node.add_write_callback(on_write)

    # -- cyclic traffic ---------------------------------------------------------------------

    def _operational(self, node_id: int) -> bool:
        return self.nodes[node_id].nmt._state == NMT_OPERATIONAL  # canopen keeps the code here

    def _rpdo_handler(self, j: int) -> Callable[[int, bytearray, float], None]:
        node_id = self.drive_ids[j]

        def on_rpdo(can_id: int, data: bytearray, timestamp: float) -> None:
            if not self._operational(node_id):
                return
            try:
                controlword, target = decode_drive_rpdo(data)
            except FrameError:
                self.rejected_frames += 1
                return
            with self.lock:
                self.plant.advance(self.clock(), check_sync_timeout=False)
                self.drives[j].on_rpdo(controlword, target)
                self._flush_emcy()

        return on_rpdo

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = self.clock()
        frames: list[tuple[int, bytes]] = []
        delayed: list[tuple[float, int, bytes]] = []
        with self.lock:
            self.sync_count += 1
            apply_device_faults(self.faults, self.plant, self.drive_ids, now)
            drive_payloads, sensor_frames = self.plant.sync(now)
            for node_id, payload in zip(self.drive_ids, drive_payloads):
                out = tpdo_payload(self.faults, node_id, payload, now)
                if out is None or not self._operational(node_id):
                    continue
                delay = self.faults.active("delay", now, node_id)
                if delay is not None:
                    delayed.append((delay.value, cob_ids.tpdo1(node_id), out))
                else:
                    frames.append((cob_ids.tpdo1(node_id), out))
                if self.faults.active("heartbeat", now, node_id) is not None and node_id not in self._silenced:
                    self.nodes[node_id].nmt.stop_heartbeat()
                    self._silenced.add(node_id)
            if sensor_frames is not None and self._operational(self.cfg.sensor.node_id):
                frames.append((cob_ids.tpdo1(self.cfg.sensor.node_id), sensor_frames[0]))
                frames.append((cob_ids.tpdo2(self.cfg.sensor.node_id), sensor_frames[1]))
            self._flush_emcy()
        for cob_id, payload in frames:
            self._send_pdo(cob_id, payload)
        for delay_s, cob_id, payload in delayed:
            timer = threading.Timer(delay_s, self._send_pdo, (cob_id, payload))
            timer.daemon = True
            timer.start()
        bus_off = self.faults.active("bus_off", now) is not None
        if bus_off or self.faults.active("error_frames", now) is not None:
            # error class bits of a SocketCAN error frame: 0x040 bus-off, 0x004 controller problems
            self.bus.send(can.Message(arbitration_id=0x040 if bus_off else 0x004, is_error_frame=True,
                                      data=bytes(8), is_extended_id=False))

    def _send_pdo(self, cob_id: int, payload: bytes) -> None:
        # On an FD bus the PDOs go as FD frames with bit-rate switch, as the controller's do;
        # canopen's send_message would send classical frames, all at the nominal rate.
        self.bus.send(can.Message(arbitration_id=cob_id, data=payload, is_extended_id=False,
                                  is_fd=self._fd, bitrate_switch=self._fd))

    def _on_controller_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = self.clock()
        with self.lock:
            for d in self.drives:
                d.on_controller_heartbeat(now)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # canopen's NmtSlave has already set the state; a reset also reboots the device.
        if len(data) != 2:
            self.rejected_frames += 1
            return
        for node in self.nodes.values():
            if node.nmt._state == 0:
                self._boot(node)

    def _flush_emcy(self) -> None:
        for node_id, d in zip(self.drive_ids, self.drives):
            while d.pending_emcy:
                code = d.pending_emcy.pop(0)
                self.nodes[node_id].emcy.send(code, 0x01 if code else 0x00)

    def _watchdog_loop(self) -> None:
        # While SYNC arrives, the SYNC handler keeps the plant integrated; this thread only
        # steps in when it is overdue (controller gone), so the drives' SYNC watchdogs fire.
        # Taking the lock every time would delay the SYNC answers it competes with.
        # After a stall of the whole process the next tick is skipped, so the SYNC handler gets
        # to the frames that arrived meanwhile before anyone decides they never came.
        timeout = self.cfg.sim.drive.sync_timeout_s
        previous_tick_s = self.clock()
        while not self._stop.wait(WATCHDOG_PERIOD_S):
            now = self.clock()
            due = watchdog_due(now, previous_tick_s, self.plant.last_sync_s, timeout)
            previous_tick_s = now
            if not due:
                continue
            with self.lock:
                self.plant.advance(self.clock())
                self._flush_emcy()
