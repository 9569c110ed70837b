"""The simulated drives and sensor in-process, behind the same codecs, without a bus.

An ``Exchange`` for the loop shell (``send`` / ``collect``) that encodes the RPDOs and
decodes the TPDOs with the production codecs but hands the bytes straight to the
simulated devices, on the caller's clock. With ``controller.loop.SimulatedTime`` a whole
run takes milliseconds and is deterministic: the harness of the unit and property tests.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from controller.config import Config
from controller.cycle_data import CycleInputs, CycleOutputs, DriveFeedback, EmcyReport, SensorFeedback
from controller.robots.errors import NoSolutionError
from controller.robots.registry import cheope_from_config
from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    TORQUE_NM_PER_COUNT,
    PositionScale,
    decode_drive_rpdo,
    decode_drive_tpdo,
    decode_sensor_frame,
    encode_drive_rpdo,
    encode_drive_tpdo,
)
from sim_backend.drive import SimulatedDrive
from sim_backend.environment import Environment, FreeSpace
from sim_backend.force_sensor import SensorParams, SimulatedForceSensor
from sim_backend.server import drive_params_from_config


class LoopbackExchange:
    def __init__(self, cfg: Config, clock: Callable[[], float], environment: Environment | None = None) -> None:
        self.clock = clock
        self.scale = PositionScale(cfg.actuators.counts_per_m)
        params = drive_params_from_config(cfg)
        self.drives = [SimulatedDrive(params, position=x) for x in cfg.sim.drive.initial_positions_m]
        for d in self.drives:
            d.mode_of_operation = 8  # what node set-up does over SDO on the real path
        s = cfg.sim.sensor
        self.sensor = SimulatedForceSensor(SensorParams(s.noise_std_n, s.bias_n, s.range_n, s.seed)) \
            if cfg.sensor.enabled else None
        self.environment = environment or FreeSpace()
        self.robot = cheope_from_config(cfg)
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.tcp_m = np.zeros(3)
        self.drop: set[int] = set()  # indices of drives whose TPDOs are dropped (fault injection)
        self._frames: list[tuple[int, int, bytes]] = []
        self._emcy: list[EmcyReport] = []

    def send(self, outputs: CycleOutputs | None) -> None:
        now = self.clock()
        if outputs is not None:
            for d, cw, x in zip(self.drives, outputs.controlwords, outputs.targets):
                d.advance(now)
                d.on_rpdo(*decode_drive_rpdo(encode_drive_rpdo(cw, self.scale.to_counts(x))))
        self._frames = []
        for j, d in enumerate(self.drives):
            d.on_sync(now)
            if j not in self.drop:
                self._frames.append((0, j, encode_drive_tpdo(d.statusword(), d.position_counts())))
            while d.pending_emcy:
                code = d.pending_emcy.pop(0)
                self._emcy.append(EmcyReport(self.drive_ids[j], code, 0x01 if code else 0))
        q = np.array([d.position for d in self.drives])
        try:
            self.tcp_m = self.robot.direct_kinematics(q)
        except NoSolutionError:
            pass
        if self.sensor is not None:
            force, torque = self.environment.contact_wrench(self.tcp_m, np.zeros(3))
            f, t = self.sensor.sample(force, torque)
            self._frames += [(1, 0, f), (2, 0, t)]

    def collect(self, deadline_s: float, stop_requested: bool = False) -> CycleInputs:
        drives: list[DriveFeedback | None] = [None] * len(self.drives)
        force = torque = None
        for kind, j, data in self._frames:
            if kind == 0:
                sw, counts = decode_drive_tpdo(data)
                drives[j] = DriveFeedback(sw, self.scale.to_unit(counts), True)
            elif kind == 1:
                force = decode_sensor_frame(data, FORCE_N_PER_COUNT)
            else:
                torque = decode_sensor_frame(data, TORQUE_NM_PER_COUNT)
        feedback = tuple(fb if fb is not None else DriveFeedback(d.statusword(), d.position, False)
                         for fb, d in zip(drives, self.drives))
        sensor = None
        if force is not None and torque is not None:
            sensor = SensorFeedback(force[:3], torque[:3], force[3], force[4], True)
        emcy, self._emcy = tuple(self._emcy), []
        return CycleInputs(drives=feedback, sensor=sensor, emcy=emcy, stop_requested=stop_requested)
