"""The simulated drives and sensor in-process, behind the production exchange, without a bus.

An ``Exchange`` for the loop shell (``send`` / ``collect``): the production
``drivers.cyclic_exchange.CyclicExchange`` over an in-memory python-can bus (``DeviceBus``)
whose other end is the simulated devices, on the caller's clock. The controller's frames are
decoded by the devices as they are sent; a SYNC makes the devices answer, and their frames
(TPDOs, EMCY, heartbeats, error frames, and whatever the fault schedule has someone else send)
wait in the bus for the exchange to read, in the order the simulator process would send them.
With ``controller.shell.loop.SimulatedTime`` a whole run takes milliseconds and is deterministic:
the harness of the unit and property tests and of ``cheope faults``.

Differences from the simulator process, on purpose: the controller's frames never get lost on
the way unless a fault says so, and every frame arrives within its cycle unless delayed by one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import can
import numpy as np

from controller.assembly import position_plausibility, safety_config
from controller.config import Config
from controller.configured_robot import actuator_units
from controller.core.cia402 import MODE_CYCLIC_SYNC_POSITION
from controller.core.cycle_data import BusFeedback, CycleOutputs
from controller.core.periods import DEADLINE_ROUNDING_S
from controller.node_plan import homing_plans, node_options
from controller.sim_config.quirk_specs import Quirk
from drivers import cob_ids
from drivers.cyclic_exchange import CyclicExchange, ExchangeCounters, targets_sync_gap_s
from drivers.fault_reset import reset_fault
from drivers.homing import home_drive
from drivers.node_setup import (
    ABORT_CONNECTION_QUICK_STOP,
    DRIVE_EDS,
    EXTRAPOLATION_PERIODS,
    SENSOR_EDS,
    SYNC_WATCHDOG,
    NodeSetupError,
    check_extrapolation_object,
    description_drive_codec,
    description_sensor_codecs,
    device_description_path,
    refusal_hint,
)
from drivers.pdo_codec import PositionScale
from drivers.pdo_mapping import find_variable, load_device_description
from sim_backend.device_pdos import PdoWriteRefusedError, SimulatedPdos
from sim_backend.drive import SimulatedDrive, error_register
from sim_backend.environment import Environment
from sim_backend.fault_injection import (
    NMT_ENTER_PRE_OPERATIONAL,
    NMT_RESET_NODE,
    NMT_STOP,
    NO_BUS_FAULTS,
    BusFaults,
    FaultSchedule,
    apply_device_faults,
    bus_faults,
    nmt_commands,
    rogue_drive_frames,
    spoofed_sensor_frame,
    tpdo_payload,
)
from sim_backend.pdo_parameters import ABORT_VALUE_RANGE
from sim_backend.plant import RobotPlant
from sim_backend.quirks import BusOffSchedule, bus_has

NMT_OPERATIONAL, NMT_STOPPED, NMT_PRE_OPERATIONAL, NMT_BOOT_UP = 5, 4, 127, 0


def _frame(cob_id: int, data: bytes, error: bool = False) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, is_error_frame=error)


class DeviceBus(can.BusABC):
    """An in-memory bus: what the controller sends goes to ``on_send``; ``inbox`` is what it reads."""

    def __init__(self, on_send: Callable[[can.Message], None]) -> None:
        super().__init__(channel="loopback")
        self.on_send = on_send
        self.inbox: deque[can.Message] = deque()
        self.full = False  # a full transmit queue: send raises as python-can's do (ENOBUFS)
        self._is_shutdown = True  # nothing to release: python-can's "not properly shut down" does not apply

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.full:
            raise can.CanOperationError("Transmit buffer full (ENOBUFS): fault injection tx_full")
        self.on_send(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        # Simulated time: everything the devices answered is already here, nothing to wait for.
        return self.inbox.popleft() if self.inbox else None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(), False


class _DriveTime:
    """A drive's simulated time during set-up: sleeping advances the drive."""

    def __init__(self, drive: SimulatedDrive, step_s: float) -> None:
        self.drive, self.step_s, self.t = drive, step_s, 0.0
        drive.advance(0.0)

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        end = self.t + seconds
        while self.t < end:
            self.t = min(end, self.t + self.step_s)
            self.drive.advance(self.t)


def _sdo_on(drive: SimulatedDrive, node_id: int) -> Callable[[int, int, int], None]:
    """Set-up's SDO writes as the drive takes them; a refused value is refused as over the bus."""

    def write(index: int, subindex: int, value: int) -> None:
        if not drive.write_object(index, subindex, value):
            raise NodeSetupError(
                f"node {node_id}: writing 0x{index:04X}sub{subindex} = 0x{value:X} refused: "
                f"Code 0x{ABORT_VALUE_RANGE:08X}{refusal_hint(index, ABORT_VALUE_RANGE)}"
            )

    return write


class LoopbackExchange:
    def __init__(
        self,
        cfg: Config,
        clock: Callable[[], float],
        environment: Environment | None = None,
        hold_up: Callable[[float], None] | None = None,
    ) -> None:
        self.clock = clock
        # moves ``clock`` on from inside a send: the ``send_stall`` fault (SimulatedTime.hold_up)
        self.hold_up = hold_up
        self._held_up_s = -math.inf  # the last SYNC's time at which send_stall held the send up
        units = actuator_units(cfg)
        self.scale = PositionScale(units.counts_per_unit)  # m or rad
        self.plant = RobotPlant(cfg, environment)
        self.drives = self.plant.drives
        self._set_up(cfg)
        rotary = units.unit.value == "rad"
        for d in self.drives:  # what node set-up does over SDO on the real path: CSP, 0x60C2, 0x6065/0x6066
            d.interpolation_period_s = cfg.period_s
            d.following_error_window = (
                cfg.actuators.following_error_window_rad if rotary else cfg.actuators.following_error_window_m
            )
            d.following_error_time_s = cfg.actuators.following_error_time_s
            d.abort_connection_option = ABORT_CONNECTION_QUICK_STOP  # 0x6007, and 0x1016 below
            d.heartbeat_consumer_s = cfg.loop.heartbeat_consumer_s
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.sensor_id = cfg.sensor.node_id if self.plant.sensor is not None else None
        # both sides mapped as the configuration and the EDS say, as set-up would write and read back
        self.pdos = SimulatedPdos(cfg, self.drives, self.plant.sensor)
        read = {n for n in self.drive_ids if node_options(cfg, n).pdo_mapping == "read"}
        try:
            self.pdos.apply_configured_mapping(cfg, read)
        except PdoWriteRefusedError as err:
            raise NodeSetupError(f"{err}{refusal_hint(err.index, err.code)}") from err
        eds = device_description_path(cfg.actuators.eds_file, DRIVE_EDS)
        description = load_device_description(eds, 1)
        has_extrapolation = find_variable(description, EXTRAPOLATION_PERIODS, 0) is not None
        has_watchdog = find_variable(description, SYNC_WATCHDOG, 0) is not None
        for n, d in zip(self.drive_ids, self.drives, strict=True):  # set-up's 0x2010, refused as over the bus
            check_extrapolation_object(n, cfg.drive_extrapolation_periods, has_extrapolation)
            if has_extrapolation:
                _sdo_on(d, n)(EXTRAPOLATION_PERIODS, 0, cfg.drive_extrapolation_periods)
            if has_watchdog:  # and 0x2011, the SYNC watchdog
                _sdo_on(d, n)(SYNC_WATCHDOG, 0, cfg.drive_sync_watchdog_ms)
        self.codecs = tuple(
            self.pdos.drive_codec(j)
            if n in read
            else description_drive_codec(n, eds, cfg.actuators.rpdo_objects, cfg.actuators.tpdo_objects)
            for j, n in enumerate(self.drive_ids)
        )
        self.sensor_codecs = (
            description_sensor_codecs(
                cfg.sensor.node_id, device_description_path(cfg.sensor.eds_file, SENSOR_EDS)
            )
            if cfg.sensor.enabled
            else None
        )
        self.faults = FaultSchedule.from_strings(tuple(cfg.sim.faults))
        if hold_up is None and any(f.kind == "send_stall" for f in self.faults.faults):
            raise ValueError(
                "send_stall holds the loop's clock inside a send: give the loopback exchange the "
                "clock's hold_up (controller/shell/simulated_rig.py does)"
            )
        self.heartbeat_period_s = cfg.loop.heartbeat_period_s
        self._heartbeat_due_s: dict[int, float] = {}  # each node's next heartbeat (_heartbeats)
        self.tracker_id = cfg.tracker.node_id if self.plant.tracker is not None else None
        # the tracker has no NMT slave or heartbeat, as in the simulator process: it sends by itself
        nodes = (*self.drive_ids, *(() if self.sensor_id is None else (self.sensor_id,)))
        self.nmt_state = {n: NMT_OPERATIONAL for n in nodes}  # node set-up has started them all
        self.bus = DeviceBus(self._on_controller_frame)
        step_limit, jump_margin = position_plausibility(
            units, safety_config(cfg.safety, units, cfg.period_s), cfg.period_s
        )
        self.exchange = CyclicExchange(
            self.bus,
            self.drive_ids,
            self.scale,
            self.sensor_id,
            cfg.loop.controller_node_id,
            heartbeat_every=max(1, round(cfg.loop.heartbeat_period_s * cfg.loop.rate_hz)),
            clock=clock,
            heartbeat_timeout_s=cfg.loop.heartbeat_consumer_s,
            drive_codecs=self.codecs,
            sensor_codecs=self.sensor_codecs,
            flood_frames_per_cycle=cfg.safety.max_foreign_frames_per_cycle,
            tracker_id=self.tracker_id,
            max_position_step=step_limit,
            max_position_jump=jump_margin,
            targets_sync_gap_s=targets_sync_gap_s(cfg.period_s, cfg.drive_extrapolation_periods),
            target_lead_period_s=cfg.period_s,
            drive_extrapolation_periods=cfg.drive_extrapolation_periods,
        )
        self._rpdo_drive = {c.rpdo_cob_id: j for j, c in enumerate(self.codecs)}
        self._sdo_drive = {cob_ids.sdo_request(n): j for j, n in enumerate(self.drive_ids)}
        self._controller_heartbeat = cob_ids.heartbeat(cfg.loop.controller_node_id)
        self._delayed: list[can.Message] = []
        self._bus_faults = NO_BUS_FAULTS
        self._silenced: set[int] = set()
        q = cfg.sim.quirk
        self.bus_off = (
            BusOffSchedule(q.bus_off_after_s, q.error_passive_s, q.bus_off_restart_s)
            if bus_has(cfg.sim.drive.quirks, Quirk.BUS_OFF)
            else None
        )
        self._bus_off_elapsed_s = -math.inf

    def _set_up(self, cfg: Config) -> None:
        """What node set-up does with each drive before the first cycle (drivers/node_setup.py), with
        the same procedures, on each drive's own simulated time: a fault found at start reset and
        verified (drivers/fault_reset.py), homing (drivers/homing.py).

        Their motion and waits take simulated seconds before the loop's time 0: each drive runs
        them from t = 0, then forgets its time, so the loop's first cycle starts where they ended.
        The EMCYs a drive sent at boot went out before any master listened.
        """
        plans = homing_plans(cfg, actuator_units(cfg))
        for j, (node_id, d) in enumerate(zip(cfg.actuators.node_ids, self.drives, strict=True)):
            d.pending_emcy.clear()
            clock = _DriveTime(d, cfg.sim.drive.substep_s * 10)
            opts = node_options(cfg, node_id)
            write, read = _sdo_on(d, node_id), (lambda index, sub, d=d: d.read_object(index) or 0)
            reset_fault(
                node_id,
                opts.fault_reset,
                opts.fault_reset_timeout_s,
                write,
                read,
                True,
                clock.now,
                clock.sleep,
            )
            plan = plans[j] if plans is not None else None
            if plan is not None:
                home_drive(node_id, plan, write, read, clock.now, sleep=clock.sleep)
            d.set_mode(MODE_CYCLIC_SYNC_POSITION)
            d.pending_emcy.clear()  # the "error reset" EMCY of set-up's reset: before the loop listens
            d.time_s = None  # the loop's clock starts at its own 0
        self.plant.update_kinematics(None, np.array([d.position for d in self.drives]))

    @property
    def counters(self) -> ExchangeCounters:
        return self.exchange.counters

    @property
    def rejected_frames(self) -> int:
        return self.exchange.counters.rejected_frames

    @property
    def send_errors(self) -> int:
        return self.exchange.counters.send_errors

    # -- the loop shell's side ----------------------------------------------------------------

    def stall_s(self, deadline_s: float) -> float:
        """How late the loop wakes for ``deadline_s`` under the ``stall`` fault (``SimulatedTime``'s
        ``lateness``): 0 when none is active. The first deadline is the schedule's t = 0: the
        first SYNC goes at it, and before it started the schedule a ``stall`` at 0 s held nothing."""
        if self.faults.t0_s is None:
            self.faults.start(deadline_s)
        stall = self.faults.active("stall", deadline_s)
        return stall.value if stall is not None else 0.0

    def send(self, outputs: CycleOutputs | None, send_by_s: float = math.inf) -> bool:
        now = self.clock()
        self.plant.advance(now)
        self.faults.start(now)
        sensor = () if self.sensor_id is None else (self.sensor_id,)
        self._bus_faults = bus_faults(self.faults, now, (*self.drive_ids, *sensor))
        self.bus.full = self._bus_faults.controller_frames_lost
        if self.bus_off is not None:  # the bus_off quirk: while off, nothing passes either way
            elapsed = self.faults.elapsed(now)
            for cls, data in self.bus_off.error_frames(self._bus_off_elapsed_s, elapsed):
                self.bus.inbox.append(_frame(cls, data, error=True))
            self._bus_off_elapsed_s = elapsed
            self.bus.full = self.bus.full or self.bus_off.off(elapsed)
        self.bus.inbox.extend(self._delayed)  # last cycle's late TPDOs: read before this SYNC, as late
        self._delayed = []
        return self.exchange.send(outputs, send_by_s)

    def collect(self, deadline_s: float) -> BusFeedback:
        return self.exchange.collect(deadline_s)

    def send_controlword_by_sdo(self, drive_index: int, controlword: int) -> None:
        self.exchange.send_controlword_by_sdo(drive_index, controlword)

    # -- the devices' side --------------------------------------------------------------------

    def _on_controller_frame(self, msg: can.Message) -> None:
        cob = msg.arbitration_id
        j = self._rpdo_drive.get(cob)
        if j is not None:
            if self.nmt_state[self.drive_ids[j]] != NMT_OPERATIONAL:
                return  # a PDO is only processed in OPERATIONAL (CiA 301)
            self.pdos.receive_rpdo(j, msg.data)  # as the drive's mapping says; a wrong one is dropped
            if j == len(self.drives) - 1:
                self._send_stall()
        elif cob == cob_ids.SYNC:
            self._on_sync(self.clock())
        elif cob == self._controller_heartbeat:
            for d in self.drives:
                d.on_controller_heartbeat(self.clock())
        elif cob in self._sdo_drive:
            self._on_sdo_request(self._sdo_drive[cob], bytes(msg.data))

    def _send_stall(self) -> None:
        """The ``send_stall`` fault: the send held up after the last drive's RPDO, before the SYNC,
        once a cycle (the RPDOs the exchange may send again after it pass)."""
        now = self.clock()
        last_sync = self.faults.last_s
        stall = self.faults.active("send_stall", now)
        if stall is None or self.hold_up is None or last_sync == self._held_up_s:
            return
        self._held_up_s = last_sync if last_sync is not None else now
        self.hold_up(stall.value)

    def _on_sdo_request(self, j: int, data: bytes) -> None:
        """The one SDO the loop sends (drivers/cyclic_exchange.py): an expedited write of the controlword.

        SDO is served in PRE-OPERATIONAL and OPERATIONAL, not in STOPPED (CiA 301); the answer is
        not modelled (the exchange ignores it).
        """
        node = self.drive_ids[j]
        if self.nmt_state[node] == NMT_STOPPED or len(data) != 8 or data[1:4] != b"\x40\x60\x00":
            return
        self.drives[j].on_controlword(int.from_bytes(data[4:6], "little"))

    def _on_sync(self, now: float) -> None:  # noqa: C901  (one SYNC of every simulated device and every scheduled fault)
        faults: BusFaults = self._bus_faults
        inbox = self.bus.inbox
        if faults.error_class:  # the bus's trouble shows while this cycle's frames are on it
            inbox.append(_frame(faults.error_class, bytes(8), error=True))
        for cob, data in faults.foreign_frames:  # someone else's, sent with the SYNC
            inbox.append(_frame(cob, data))
        reboots = list(faults.reboots)
        for command, node in nmt_commands(faults.foreign_frames):
            for n in self.nmt_state:
                if node not in (0, n):
                    continue
                if command == NMT_RESET_NODE:
                    reboots.append(n)
                elif command in (NMT_STOP, NMT_ENTER_PRE_OPERATIONAL):
                    self.nmt_state[n] = NMT_STOPPED if command == NMT_STOP else NMT_PRE_OPERATIONAL
                    if n in self.drive_ids:  # no RPDO reaches it now: its 0x6007 reaction
                        self.drives[self.drive_ids.index(n)].on_nmt_left_operational()
        for node in reboots:
            self.nmt_state[node] = NMT_PRE_OPERATIONAL
            if node in self.drive_ids:
                self.drives[self.drive_ids.index(node)].reboot()
            inbox.append(_frame(cob_ids.heartbeat(node), bytes((NMT_BOOT_UP,))))
        apply_device_faults(self.faults, self.plant, self.drive_ids, now)
        self.plant.sync(now)
        sample = self.plant.kinematics_sample()
        if sample is not None:
            self.plant.update_kinematics(*sample)
        delays = dict(faults.delays_s)
        inbox.extend(_frame(cob, data) for cob, data in rogue_drive_frames(self.pdos, self.drive_ids, faults))
        for node, tpdo in zip(
            self.drive_ids, self.pdos.drive_tpdos(), strict=True
        ):  # as each drive's mapping says
            if tpdo is None or self.nmt_state[node] != NMT_OPERATIONAL:
                continue
            cob, data = tpdo
            payload = tpdo_payload(self.faults, node, data, now)
            if payload is not None:
                (self._delayed if node in delays else inbox).append(_frame(cob, payload))
        sensor_frames = self.pdos.sensor_tpdos()
        if sensor_frames and self.sensor_id is not None and self.nmt_state[self.sensor_id] == NMT_OPERATIONAL:
            for k, (cob, data) in enumerate(sensor_frames):
                if k == 0 and faults.spoofed_force_n is not None:  # someone else's, before the true one
                    inbox.append(_frame(cob, spoofed_sensor_frame(data, faults.spoofed_force_n)))
                payload = tpdo_payload(self.faults, self.sensor_id, data, now)  # drop:N, malformed:N
                if payload is not None:
                    inbox.append(_frame(cob, payload))
        tracker_frames = self.plant.tracker_frames(now)  # after the pose was advanced to this SYNC
        if tracker_frames is not None and self.tracker_id is not None:
            inbox.append(_frame(cob_ids.tpdo1(self.tracker_id), tracker_frames[0]))
            inbox.append(_frame(cob_ids.tpdo2(self.tracker_id), tracker_frames[1]))
        for node, d in zip(self.drive_ids, self.drives, strict=True):
            while d.pending_emcy:
                code = d.pending_emcy.pop(0)
                data = code.to_bytes(2, "little") + bytes((error_register(code),)) + bytes(5)
                inbox.append(_frame(cob_ids.emcy(node), data))
        self._heartbeats(now, faults)

    def _heartbeats(self, now: float, faults: BusFaults) -> None:
        """Each node's heartbeat producer (0x1017), checked at the SYNCs: its NMT state at the first
        SYNC at or after each due time. The next is due a period after the last due time, not after
        the SYNC that sent it (a grid that does not divide the period would stretch it), and a SYNC
        within ``DEADLINE_ROUNDING_S`` of a due time is at it: ``now - last >= period`` missed 40
        periods of 2.5 ms by rounding, and every heartbeat came 102.5 ms after the last. After a
        silence (``heartbeat:N``) the node starts again from the SYNC that sends."""
        period = self.heartbeat_period_s
        due_s = self._heartbeat_due_s
        for node, state in self.nmt_state.items():
            if node in faults.silent_heartbeats:
                due_s.pop(node, None)  # after the silence: from the SYNC that sends again
                continue
            due = due_s.get(node)
            if due is not None and now < due - DEADLINE_ROUNDING_S:
                continue
            due_s[node] = due + period if due is not None and due + period > now else now + period
            self.bus.inbox.append(_frame(cob_ids.heartbeat(node), bytes((state,))))
