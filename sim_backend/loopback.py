"""The simulated drives and sensor in-process, behind the same codecs, without a bus.

An ``Exchange`` for the loop shell (``send`` / ``collect``) that encodes the RPDOs and
decodes the TPDOs with the production codecs but hands the bytes straight to the
simulated devices, on the caller's clock. With ``controller.shell.loop.SimulatedTime`` a whole
run takes milliseconds and is deterministic: the harness of the unit and property tests.
"""

from __future__ import annotations

from collections.abc import Callable

from controller.config import Config
from controller.core.cycle_data import BusFeedback, CycleOutputs, DriveFeedback, EmcyReport, SensorFeedback
from controller.robots.registry import actuator_units
from drivers.pdo_codec import (
    FORCE_N_PER_COUNT,
    TORQUE_NM_PER_COUNT,
    FrameError,
    PositionScale,
    decode_drive_rpdo,
    decode_drive_tpdo,
    decode_sensor_frame,
    encode_drive_rpdo,
)
from sim_backend.environment import Environment
from sim_backend.fault_injection import (
    ERROR_CLASS_BUS_OFF,
    NO_BUS_FAULTS,
    FaultSchedule,
    apply_device_faults,
    bus_faults,
    tpdo_payload,
)
from sim_backend.plant import RobotPlant


class LoopbackExchange:
    def __init__(self, cfg: Config, clock: Callable[[], float], environment: Environment | None = None) -> None:
        self.clock = clock
        self.scale = PositionScale(actuator_units(cfg).counts_per_unit)  # m or rad
        self.plant = RobotPlant(cfg, environment)
        self.drives = self.plant.drives
        for d in self.drives:
            d.mode_of_operation = 8  # what node set-up does over SDO on the real path: CSP,
            d.interpolation_period_s = cfg.period_s  # and 0x60C2
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.faults = FaultSchedule.from_strings(tuple(cfg.sim.faults))
        self.rejected_frames = 0
        self.send_errors = 0
        self._frames: list[tuple[int, int, bytes]] = []
        self._emcy: list[EmcyReport] = []
        self._bus_faults = NO_BUS_FAULTS

    def send(self, outputs: CycleOutputs | None) -> None:
        now = self.clock()
        self.plant.advance(now)
        self.faults.start(now)
        self._bus_faults = bus_faults(self.faults, now, self.drive_ids)
        if self._bus_faults.controller_frames_lost:
            # nothing reaches the devices: no RPDO, no SYNC, so no device answers
            self.send_errors += 5
            self._frames = []
            return
        if outputs is not None:
            for d, cw, x in zip(self.drives, outputs.controlwords, outputs.targets):
                d.on_rpdo(*decode_drive_rpdo(encode_drive_rpdo(cw, self.scale.to_counts(x))))
        apply_device_faults(self.faults, self.plant, self.drive_ids, now)
        drive_payloads, sensor_frames = self.plant.sync(now)
        sample = self.plant.kinematics_sample()
        if sample is not None:
            self.plant.update_kinematics(*sample)
        self._frames = []
        for j, data in enumerate(drive_payloads):
            payload = tpdo_payload(self.faults, self.drive_ids[j], data, now)
            late = any(n == self.drive_ids[j] for n, _ in self._bus_faults.delays_s)  # misses its cycle
            if payload is not None and not late:
                self._frames.append((0, j, payload))
        if sensor_frames is not None:
            self._frames += [(1, 0, sensor_frames[0]), (2, 0, sensor_frames[1])]
        for j, d in enumerate(self.drives):
            while d.pending_emcy:
                code = d.pending_emcy.pop(0)
                self._emcy.append(EmcyReport(self.drive_ids[j], code, 0x01 if code else 0))

    def collect(self, deadline_s: float) -> BusFeedback:
        drives: list[DriveFeedback | None] = [None] * len(self.drives)
        force = torque = None
        for kind, j, data in self._frames:
            if kind == 0:
                try:
                    sw, counts = decode_drive_tpdo(data)
                except FrameError:
                    self.rejected_frames += 1
                    continue
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
        bus = self._bus_faults  # as the exchange would decode the simulator process's frames
        return BusFeedback(drives=feedback, sensor=sensor, emcy=emcy, lost_heartbeats=bus.silent_heartbeats,
                           error_frames=1 if bus.error_class else 0,
                           bus_off=bus.error_class == ERROR_CLASS_BUS_OFF)
