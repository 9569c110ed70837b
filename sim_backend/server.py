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
from pathlib import Path
from typing import Callable

import can
import canopen
import numpy as np

from controller.config import Config
from controller.robots.errors import NoSolutionError
from controller.robots.registry import cheope_from_config
from drivers import cob_ids
from drivers.pdo_codec import PositionScale, decode_drive_rpdo, encode_drive_tpdo, FrameError
from sim_backend.drive import DriveParams, SimulatedDrive
from sim_backend.environment import Environment, FreeSpace
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor

log = logging.getLogger(__name__)

EDS_DIR = Path(__file__).resolve().parent.parent / "drivers" / "eds"
DRIVE_EDS = EDS_DIR / "cheope_drive.eds"
SENSOR_EDS = EDS_DIR / "force_sensor.eds"
NMT_OPERATIONAL = 5
WATCHDOG_PERIOD_S = 0.005


def drive_params_from_config(cfg: Config) -> DriveParams:
    d = cfg.sim.drive
    c = cfg.robot.cheope
    return DriveParams(
        bandwidth_hz=d.bandwidth_hz, damping_ratio=d.damping_ratio, max_velocity=d.max_velocity_m_s,
        max_acceleration=d.max_acceleration_m_s2, quick_stop_deceleration=d.quick_stop_deceleration_m_s2,
        velocity_feedforward=d.velocity_feedforward,
        stroke_min=c.stroke_min_m, stroke_max=c.stroke_max_m, counts_per_unit=cfg.actuators.counts_per_m,
        sync_timeout_s=d.sync_timeout_s, substep_s=d.substep_s,
    )


class Simulator:
    """Simulated hardware on one bus. Use as a context manager."""

    def __init__(self, cfg: Config, bus: can.BusABC, environment: Environment | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.bus = bus
        self.environment = environment or FreeSpace()
        self.clock = clock
        self.robot = cheope_from_config(cfg)
        self.lock = threading.RLock()
        params = drive_params_from_config(cfg)
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.drives = [SimulatedDrive(params, position=x) for x in cfg.sim.drive.initial_positions_m]
        s = cfg.sim.sensor
        self.sensor = SimulatedForceSensor(SensorParams(s.noise_std_n, s.bias_n, s.range_n, s.seed)) \
            if cfg.sensor.enabled else None
        self.network = canopen.Network(bus)
        self.nodes: dict[int, canopen.LocalNode] = {}
        self.sync_count = 0
        self.rejected_frames = 0
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        self.tcp_m = np.zeros(3)

    # -- life cycle -------------------------------------------------------------------------

    def __enter__(self) -> "Simulator":
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
        with self.lock:
            self._update_mechanics()
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
                drive.advance(self.clock())
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
                self.drives[j].advance(self.clock())
                self.drives[j].on_rpdo(controlword, target)
                self._flush_emcy()

        return on_rpdo

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        now = self.clock()
        frames: list[tuple[int, bytes]] = []
        with self.lock:
            self.sync_count += 1
            for j, node_id in enumerate(self.drive_ids):
                d = self.drives[j]
                d.on_sync(now)
                if self._operational(node_id):
                    frames.append((cob_ids.tpdo1(node_id), encode_drive_tpdo(d.statusword(), d.position_counts())))
            self._update_mechanics()
            if self.sensor is not None and self._operational(self.cfg.sensor.node_id):
                force, torque = self.environment.contact_wrench(self.tcp_m, np.zeros(3))
                f, t = self.sensor.sample(force, torque)
                frames.append((cob_ids.tpdo1(self.cfg.sensor.node_id), f))
                frames.append((cob_ids.tpdo2(self.cfg.sensor.node_id), t))
            self._flush_emcy()
        for cob_id, payload in frames:
            self.network.send_message(cob_id, payload)

    def _update_mechanics(self) -> None:
        q = np.array([d.position for d in self.drives])
        try:
            self.tcp_m = self.robot.direct_kinematics(q)
        except NoSolutionError:
            log.warning("simulated actuators at %s m have no assembly", q.tolist())

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
        while not self._stop.wait(WATCHDOG_PERIOD_S):
            with self.lock:
                now = self.clock()
                for d in self.drives:
                    d.advance(now)
                self._flush_emcy()
