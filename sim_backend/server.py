"""The simulator process: CiA 402 drives and a force sensor as CANopen nodes on a CAN bus.

Each device is a ``canopen.LocalNode`` built from the shipped EDS file, so its SDO server,
NMT slave and heartbeat producer are the canopen package's own; this module adds the
device behaviour (``SimulatedDrive``, ``SimulatedForceSensor``), the cyclic PDOs and the
robot's mechanics (the TCP from the drives' positions through the direct kinematics, the
environment's wrench on the sensor).

Real drives answer SYNC from firmware within a few hundred microseconds whatever their host
does; this process has to come close on a shared 2-core machine. So one thread does all the
frame handling, lean: it blocks on the bus, drains every frame that is waiting in one batch,
integrates the plant up to each SYNC's arrival and answers it with TPDOs of that state, stores
RPDO targets without touching the plant, and hands only the rare SDO and NMT frames to canopen
(``Network.notify``, canopen's documented entry for a custom receive loop; no canopen notifier
thread). The same thread ticks the drives' SYNC watchdog when no frame has come for
``WATCHDOG_PERIOD_S``.

It does not integrate the interval after a SYNC ahead, before the next one comes, although its
answers would then wait for nothing (0.17 ms sooner at p50 when that was measured, about 0.05 ms
in the demos that ended it: docs/concepts/contour-tracking.md): after a late SYNC the
loop's next one comes less than a period after it, and the drives had already run past it on the
old segment. One SYNC 1.2 ms late put the carriages 57 um off their undisturbed path where a
causal drive is 19 um off (tests/protocol/test_sim_answer_path.py), a kick through the contact
that simulated time, integrating each interval when its SYNC comes, never had.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import random
import threading
import time
from collections.abc import Callable
from typing import Self

import can
import canopen
import numpy as np

from controller.config import Config
from controller.realtime import below_own_priority
from controller.sim_config.quirk_specs import Quirk
from drivers import cob_ids
from drivers.drop_counter import DropCounter
from drivers.node_setup import ABORT_TRANSFER
from drivers.node_setup import DRIVE_EDS as SHIPPED_DRIVE_EDS
from drivers.node_setup import SENSOR_EDS as SHIPPED_SENSOR_EDS
from drivers.pacing import arrival_s
from drivers.sim_environment import (
    ABORT_OBJECT_DOES_NOT_EXIST,
    ENVIRONMENT_CODES,
    ENVIRONMENT_NAMES,
    SIM_ENVIRONMENT_INDEX,
    SIM_ENVIRONMENT_SUBINDEX,
)
from sim_backend.device_pdos import SimulatedPdos
from sim_backend.drive import SimulatedDrive, error_register
from sim_backend.environment import Environment
from sim_backend.fault_injection import (
    FaultSchedule,
    apply_device_faults,
    bus_faults,
    nmt_commands,
    rogue_drive_frames,
    spoofed_sensor_frame,
    tpdo_payload,
)
from sim_backend.lss_slave import LSS_REQUEST, LSS_RESPONSE, LssSlave
from sim_backend.pdo_parameters import ABORT_DEVICE_STATE, ABORT_VALUE_RANGE, DevicePdos
from sim_backend.plant import RobotPlant, environment_named
from sim_backend.quirks import BusOffSchedule, bus_has, quirks_of
from sim_backend.true_force_tap import TrueForceTap

log = logging.getLogger(__name__)

DRIVE_EDS, SENSOR_EDS = SHIPPED_DRIVE_EDS, SHIPPED_SENSOR_EDS  # the tools' names for the shipped files
NMT_OPERATIONAL = 5
NMT_STOPPED = 4
NMT_PRE_OPERATIONAL = 127
WATCHDOG_PERIOD_S = 0.005
# A watchdog tick this late means the simulator's process was not running: SYNC frames may be
# waiting unread in its socket, so this tick does not judge them lost (see _watchdog_loop).
STARVED_TICK_S = 4 * WATCHDOG_PERIOD_S


def watchdog_due(
    now_s: float, previous_tick_s: float, last_sync_s: float | None, sync_timeout_s: float
) -> bool:
    """Whether the watchdog thread advances the drives itself on this tick.

    Only when SYNC is overdue by half the drives' timeout, and not on the first tick after a
    stall of the simulator's process, when unread SYNC frames may be waiting in its socket.
    """
    if now_s - previous_tick_s > STARVED_TICK_S:
        return False
    return last_sync_s is None or now_s - last_sync_s >= 0.5 * sync_timeout_s


def add_environment_object(node: canopen.LocalNode, kind: str) -> None:
    """The simulator-only object the controller announces its task's environment to (not in the
    shipped EDS, which describes the real sensor); reads give the environment placed."""
    var = canopen.objectdictionary.ODVariable(
        "Simulated environment", SIM_ENVIRONMENT_INDEX, SIM_ENVIRONMENT_SUBINDEX
    )
    var.data_type = canopen.objectdictionary.UNSIGNED8
    var.access_type = "rw"
    var.default = ENVIRONMENT_CODES[kind]
    node.object_dictionary.add_object(var)


# The objects a drive without heartbeat (guarding_only) or without node guarding (heartbeat_only) lacks.
_SUPERVISION_MISSING = {Quirk.GUARDING_ONLY: (0x1016, 0x1017), Quirk.HEARTBEAT_ONLY: (0x100C, 0x100D)}
SIM_SERIAL_BASE = 0x53494D00  # "SIM" and the node id: each simulated node's serial number (0x1018 sub 4)
NMT_START_REMOTE_NODE = 0x01  # CiA 301 NMT command specifiers
NMT_RESET_NODE, NMT_RESET_COMMUNICATION = 0x81, 0x82


def _give_serial(node: canopen.LocalNode, node_id: int) -> None:
    """Each simulated node its own serial number: an LSS address (0x1018) is unique."""
    node.set_data(0x1018, 4, (SIM_SERIAL_BASE | node_id).to_bytes(4, "little"))


class Simulator:
    """Simulated hardware on one bus. Use as a context manager."""

    def __init__(
        self,
        cfg: Config,
        bus: can.BusABC,
        environment: Environment | None = None,
        clock: Callable[[], float] = time.monotonic,
        true_force_tap: TrueForceTap | None = None,
    ) -> None:
        self.cfg = cfg
        self.true_force_tap = true_force_tap  # the true contact force, shared with the demo (a diagnostic)
        self.bus = bus
        self.clock = clock
        self.plant = RobotPlant(cfg, environment)
        self.drives = self.plant.drives
        self.sensor = self.plant.sensor
        self.lock = threading.RLock()  # the cyclic thread against SDO callbacks and tests reading state
        self.drive_ids = tuple(cfg.actuators.node_ids)
        self.faults = FaultSchedule.from_strings(tuple(cfg.sim.faults))
        self._lost_until_next_sync = False  # tx_full: the controller's frames do not arrive
        self._fd = getattr(bus, "protocol", None) == can.CanProtocol.CAN_FD
        self._silenced: set[int] = set()
        # canopen without its notifier: the cyclic thread feeds it the frames it subscribed to
        self.network = canopen.Network(bus)
        self.nodes: dict[int, canopen.LocalNode] = {}
        self.sync_count = 0
        # frames no device takes (a 29-bit frame, an NMT command or SDO request of the wrong
        # length, an RPDO that does not decode): counted, named in a warning at most every 5 s
        self.rejected = DropCounter(
            log, "simulator: %d frame(s) rejected so far (last COB-ID 0x%03X, %d bytes: %s)"
        )
        # the simulator's true contact force, largest at any SYNC, per controller session (a new one
        # at each NMT start to all nodes or one of these): what a disturbance of the measurement can
        # hide from the controller, reported when the simulator stops (sim_backend/process.py)
        self.max_contact_force_n: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._kinematics: queue.SimpleQueue[tuple[float, np.ndarray] | None] = queue.SimpleQueue()
        self._pose_thread: threading.Thread | None = None
        self._fast: dict[int, Callable[[bytearray, float], None]] = {}
        self._rpdo_routes: list[int] = []
        self._tx: dict[int, can.Message] = {}
        self.pdos = SimulatedPdos(cfg, self.drives, self.sensor)  # the mappings as written over SDO
        # The nodes' own habits (sim_backend/quirks.py): boot, SDO, supervision; the drives' device
        # habits are in the drives, the fixed mapping in their PDOs.
        nodes = (*self.drive_ids, *((cfg.sensor.node_id,) if self.sensor is not None else ()))
        self.quirks = {n: quirks_of(cfg.sim.drive.quirks, n, n in self.drive_ids) for n in nodes}
        q = cfg.sim.quirk
        self._boot_at: dict[int, float | None] = {}  # not booted yet: when it will (None: on an NMT reset)
        self._sdo_requests: dict[int, int] = {}  # per node, for sdo_aborts
        self._sdo_random = random.Random(q.seed)
        self._guard_toggle: dict[int, int] = {}  # node guarding: the next answer's toggle bit
        self._lss: dict[int, LssSlave] = {}  # the unconfigured nodes' LSS slaves
        self.bus_off = (
            BusOffSchedule(q.bus_off_after_s, q.error_passive_s, q.bus_off_restart_s)
            if bus_has(cfg.sim.drive.quirks, Quirk.BUS_OFF)
            else None
        )
        self._bus_off_elapsed_s = -math.inf
        self._bus_is_off = False
        self.failure: Exception | None = None  # what ended the devices' thread (``_run``)
        self.on_failure: Callable[[], None] | None = None  # called then, from that thread

    # -- life cycle -------------------------------------------------------------------------

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """The devices' nodes (``build_nodes``, unless done), then their boot-up, heartbeats and threads.

        The threads inherit the calling thread's scheduling: a process that runs the simulator
        real-time applies it between ``build_nodes`` and ``start`` (sim_backend/process.py).
        """
        if not self.nodes:
            self.build_nodes()
        now = self.clock()
        with self.lock:
            self.plant.advance(now, check_sync_timeout=False)  # power-on: the drives' clocks start
        for node_id, node in self.nodes.items():
            quirks = self.quirks.get(node_id)
            if quirks is not None and Quirk.UNCONFIGURED in quirks:
                self._boot_at[node_id] = None  # silent until an LSS master gives it its node id
                self._lss[node_id] = LssSlave(self._identity(node), frozenset((node_id,)))
            elif quirks is not None and Quirk.NEEDS_NMT_RESET in quirks:
                self._boot_at[node_id] = None  # silent until an NMT reset
            elif quirks is not None and Quirk.LATE_BOOT in quirks:
                self._boot_at[node_id] = now + self.cfg.sim.quirk.boot_delay_s
            else:
                self.network.add_node(node)
        for node_id, node in self.nodes.items():
            if node_id not in self._boot_at:
                self._boot(node)
        self._thread = threading.Thread(target=self._run, name="sim-cyclic", daemon=True)
        self._thread.start()
        self._pose_thread = threading.Thread(target=self._follow_pose, name="sim-pose", daemon=True)
        self._pose_thread.start()

    def build_nodes(self) -> None:
        """The canopen nodes from the object dictionaries, wired to the devices: start-up work
        that sends nothing and starts no thread."""
        for j, node_id in enumerate(self.drive_ids):
            node = canopen.LocalNode(node_id, self.pdos.drive_pdos[j].od)
            _give_serial(node, node_id)
            self._wire_drive(node, self.drives[j], self.pdos.drive_pdos[j])
            self.nodes[node_id] = node
        if self.sensor is not None and self.pdos.sensor_pdos is not None:
            node = canopen.LocalNode(self.cfg.sensor.node_id, self.pdos.sensor_pdos.od)
            _give_serial(node, self.cfg.sensor.node_id)
            self._wire_sensor(node, self.pdos.sensor_pdos)
            self.nodes[self.cfg.sensor.node_id] = node
        self._route_rpdos()
        self.pdos.on_cob_ids_changed = self._route_rpdos
        if self.plant.tracker is not None:  # no CANopen object dictionary: it starts sending by itself
            for cob in (cob_ids.tpdo1(self.cfg.tracker.node_id), cob_ids.tpdo2(self.cfg.tracker.node_id)):
                self._tx[cob] = self._message(cob)
        self._fast[LSS_REQUEST] = self._on_lss
        self._fast[cob_ids.SYNC] = self._on_sync
        self._fast[cob_ids.heartbeat(self.cfg.loop.controller_node_id)] = self._on_controller_heartbeat
        self.network.subscribe(cob_ids.NMT, self._on_nmt)

    def stop(self) -> None:
        self._stop.set()
        self._kinematics.put(None)
        for thread in (self._thread, self._pose_thread):
            if thread is not None:
                thread.join(timeout=1.0)
        for node in self.nodes.values():
            node.nmt.stop_heartbeat()

    def _boot(self, node: canopen.LocalNode) -> None:
        node.nmt.send_command(0x81)  # reset: sends the boot-up message
        node.nmt.send_command(0x80)  # -> PRE-OPERATIONAL, starts the heartbeat of 0x1017
        self._guard_toggle.pop(node.id or 0, None)
        self._flush_emcy()  # what a drive says at boot (boots_in_fault: its error code)

    def _boot_late(self, node_id: int) -> None:
        """A node that was silent (late_boot, needs_nmt_reset) boots now: on the bus from here on."""
        del self._boot_at[node_id]
        node = self.nodes[node_id]
        self.network.add_node(node)
        if node_id in self.drive_ids:
            self.drives[self.drive_ids.index(node_id)].reboot()
        self._boot(node)
        log.info("node %d booted (sim.drive.quirks)", node_id)

    def _on_sdo_request(self, msg: can.Message) -> bool:
        """A node's SDO habits: silent before boot, a late answer, an abort now and then. True when
        handled here (dropped, answered, or scheduled); False: canopen's SDO server answers at once."""
        node_id = msg.arbitration_id - 0x600
        quirks = self.quirks.get(node_id)
        if quirks is None:
            return False
        if node_id in self._boot_at:
            return True  # not booted: no SDO server yet
        if Quirk.SDO_ABORTS in quirks:
            n = self._sdo_requests[node_id] = self._sdo_requests.get(node_id, 0) + 1
            if n % self.cfg.sim.quirk.sdo_abort_every == 0:
                abort = bytes((0x80, msg.data[1], msg.data[2], msg.data[3])) + ABORT_TRANSFER.to_bytes(
                    4, "little"
                )
                self.bus.send(can.Message(arbitration_id=0x580 + node_id, data=abort, is_extended_id=False))
                return True
        if Quirk.SLOW_SDO in quirks:
            q = self.cfg.sim.quirk
            delay = self._sdo_random.uniform(q.sdo_delay_min_s, q.sdo_delay_max_s)
            request = (msg.arbitration_id, bytearray(msg.data), msg.timestamp)
            timer = threading.Timer(delay, self._late_sdo, request)
            timer.daemon = True
            timer.start()
            return True
        return False

    @staticmethod
    def _identity(node: canopen.LocalNode) -> tuple[int, int, int, int]:
        def u32(sub: int) -> int:
            return int.from_bytes(node.get_data(0x1018, sub), "little")

        return (u32(1), u32(2), u32(3), u32(4))

    def _on_lss(self, data: bytearray, now: float) -> None:
        """An LSS request: each unconfigured node's slave answers; one given its id starts with it."""
        for node_id, slave in list(self._lss.items()):
            answer = slave.on_request(bytes(data))
            if answer is not None:
                self.bus.send(can.Message(arbitration_id=LSS_RESPONSE, data=answer, is_extended_id=False))
            if slave.started:
                del self._lss[node_id]
                with self.lock:
                    self._boot_late(node_id)

    def _late_sdo(self, cob_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            if self._stop.is_set():
                return  # the simulator stopped meanwhile (its bus may be closed)
            with contextlib.suppress(can.CanError):
                self.network.notify(cob_id, data, timestamp)

    def _on_guarding_request(self, node_id: int, now: float) -> None:
        """A node guarding request (a remote frame on 0x700 + node): the NMT state with the toggle bit
        (CiA 301); the drive's life guarding takes it as the master's sign of life."""
        quirks = self.quirks.get(node_id)
        if quirks is None or Quirk.HEARTBEAT_ONLY in quirks or node_id in self._boot_at:
            return
        toggle = self._guard_toggle.get(node_id, 0)
        self._guard_toggle[node_id] = toggle ^ 0x80
        state = self.nodes[node_id].nmt._state  # canopen keeps the code here
        self.bus.send(
            can.Message(arbitration_id=0x700 + node_id, data=bytes((state | toggle,)), is_extended_id=False)
        )
        if node_id in self.drive_ids:
            with self.lock:
                self.drives[self.drive_ids.index(node_id)].on_controller_heartbeat(now)

    def _message(self, cob_id: int) -> can.Message:
        # On an FD bus the PDOs go as FD frames with bit-rate switch, as the controller's do;
        # canopen's send_message would send classical frames, all at the nominal rate.
        return can.Message(
            arbitration_id=cob_id,
            data=bytes(8),
            is_extended_id=False,
            is_fd=self._fd,
            bitrate_switch=self._fd,
        )

    # -- the cyclic thread ------------------------------------------------------------------

    def _run(self) -> None:
        """The devices' thread. Should it end on an error nonetheless, the devices go silent
        (heartbeats stopped: their master sees them lost) and ``on_failure`` ends the process
        loudly: a simulator whose devices no longer answer must not look alive."""
        try:
            self._serve_frames()
        except Exception as err:
            if self._stop.is_set():
                return  # stopping: the bus may already be closed under a receive
            self.failure = err
            log.critical(
                "simulator: the devices' thread ended on an error; the devices go silent", exc_info=True
            )
            try:
                for node in self.nodes.values():
                    with contextlib.suppress(Exception):  # a heartbeat task on a bus that is down
                        node.nmt.stop_heartbeat()
            finally:
                if self.on_failure is not None:
                    self.on_failure()

    def _serve_frames(self) -> None:
        bus, clock = self.bus, self.clock
        previous_tick_s = clock()
        while not self._stop.is_set():
            msg = bus.recv(timeout=WATCHDOG_PERIOD_S)
            while msg is not None:  # drain what is waiting before judging anything by the clock
                self._dispatch(msg)
                msg = bus.recv(timeout=0.0)
            now = clock()
            if self.bus_off is not None:
                self._bus_off_step(now)
            for node_id, at in list(self._boot_at.items()) if self._boot_at else ():
                if at is not None and now >= at:
                    with self.lock:
                        self._boot_late(node_id)
            if now - previous_tick_s < WATCHDOG_PERIOD_S:
                continue
            # the drives' watchdog time as set-up wrote it (0x2011), the shortest
            timeout = min(
                (d.sync_timeout_s for d in self.plant.drives), default=self.cfg.sim.drive.sync_timeout_s
            )
            due = watchdog_due(now, previous_tick_s, self.plant.last_sync_s, timeout)
            previous_tick_s = now
            if due:
                # SYNC overdue (controller gone): integrate with the watchdogs armed, so the drives
                # quick-stop on their own as real ones do
                with self.lock:
                    self.plant.advance(now)
                    self._flush_emcy()

    def _dispatch(self, msg: can.Message) -> None:
        """One frame to the device it is for. A 29-bit frame is no CANopen frame (its identifier
        only looks like a COB-ID) and reaches no device; an NMT command of another length than 2
        or an SDO request of another length than 8, which canopen's NMT or SDO server cannot
        parse (the ``struct.error`` of a 1-byte NMT command or an empty SDO request ended this
        thread), is rejected, counted and named, as a real device ignores it."""
        if self._bus_is_off or msg.is_error_frame:
            return  # bus_off: nothing reaches the devices
        if msg.is_extended_id:
            self._reject(msg, "a 29-bit frame reaches no CANopen device")
            return
        clock = self.clock
        if msg.is_remote_frame:
            if 0x701 <= msg.arbitration_id <= 0x77F:  # node guarding
                self._on_guarding_request(msg.arbitration_id - 0x700, clock())
            return
        handler = self._fast.get(msg.arbitration_id)
        if handler is not None:
            # A real drive latches its position when SYNC arrives, whatever its firmware does next;
            # this process may run a while after (kernel to handler 0.16 ms at p50 and 1.4-6.6 ms at
            # the worst in three contour demos, issue 26's note). Integrating the drives to the time
            # the SYNC is handled turned that delay into a longer SYNC interval followed by a shorter
            # one: a kick the structure does not get from real drives. So: its arrival.
            handler(msg.data, arrival_s(msg.timestamp, clock(), time.time()))
        elif msg.arbitration_id == cob_ids.NMT and len(msg.data) != 2:
            self._reject(msg, "an NMT command is 2 bytes")
        elif 0x601 <= msg.arbitration_id <= 0x67F and len(msg.data) != 8:
            self._reject(msg, "an SDO request is 8 bytes")
        elif 0x601 <= msg.arbitration_id <= 0x67F and self._on_sdo_request(msg):
            pass
        elif msg.arbitration_id in self.network.subscribers:  # SDO requests, NMT: canopen's nodes
            # frames of the lengths checked above parse (canopen's SDO server answers an abort to
            # what it cannot serve): an error here is the simulator's own, and ends the thread (_run)
            with self.lock:
                self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    def _reject(self, msg: can.Message, why: str) -> None:
        self.rejected.add(msg.arbitration_id, len(msg.data), why)

    @property
    def rejected_frames(self) -> int:
        return self.rejected.count

    def _follow_pose(self) -> None:
        """The free robot's pose from the drives' positions at each SYNC, behind the answers.

        One priority below the cyclic thread when that one is real-time (``below_own_priority``):
        the cyclic thread preempts it and takes the interpreter back within the switch interval
        when a frame arrives. It ran under the normal scheduler until the recording's writer went
        real-time (``SCHED_FIFO`` 50, controller/shell/helper_threads.py) on the same CPU: a
        writer's burst then kept it off the CPU while it held this process's interpreter lock,
        and the cyclic thread, at 70, waited for the lock with it.
        """
        with contextlib.suppress(OSError):
            below_own_priority()
        while (sample := self._kinematics.get()) is not None:
            self.plant.update_kinematics(*sample)

    # -- object dictionary callbacks --------------------------------------------------------

    def _route_rpdos(self) -> None:
        """The RPDO COB-IDs as mapped now (a master may have moved one while the PDO was invalid)."""
        for cob in self._rpdo_routes:
            self._fast.pop(cob, None)
        self._rpdo_routes = self.pdos.rpdo_cob_ids()
        for j, cob in enumerate(self._rpdo_routes):
            self._fast[cob] = self._rpdo_handler(j, cob)

    def _wire_sensor(self, node: canopen.LocalNode, pdos: DevicePdos) -> None:
        add_environment_object(node, self.plant.environment_kind)

        def on_write(index: int, subindex: int, od: canopen.objectdictionary.ODVariable, data: bytes) -> None:
            raw = od.decode_raw(data)
            if not isinstance(raw, int):
                return
            if index == SIM_ENVIRONMENT_INDEX:
                self._on_environment_announced(raw)
                return
            with self.lock:
                pdos.write(index, subindex, raw)  # SdoAbortedError refuses an invalid mapping

        node.add_write_callback(on_write)

    def _on_environment_announced(self, code: int) -> None:
        """The controller's task needs this environment: place it (sim.environment = "auto"), or
        refuse it with an SDO abort when this simulator was configured to another one."""
        wanted = ENVIRONMENT_NAMES.get(code)
        if wanted is None:
            raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)
        configured = self.cfg.sim.environment
        if configured != "auto" and configured != wanted:
            log.warning("the controller's task needs %s; sim.environment = %r: refused", wanted, configured)
            raise canopen.SdoAbortedError(ABORT_DEVICE_STATE)
        with self.lock:
            if wanted != self.plant.environment_kind:
                try:
                    self.plant.set_environment(environment_named(self.cfg, wanted))
                except ValueError as err:  # the robot cannot meet this part (no structure, starts in it)
                    log.error("the controller's task needs %s: %s", wanted, err)
                    raise canopen.SdoAbortedError(ABORT_DEVICE_STATE) from err
                log.info("environment %s placed for the controller's task", wanted)

    def _wire_drive(self, node: canopen.LocalNode, drive: SimulatedDrive, pdos: DevicePdos) -> None:
        def on_read(index: int, subindex: int, od: object) -> int | None:
            with self.lock:
                self.plant.advance(self.clock(), check_sync_timeout=False)
                value = pdos.read(index, subindex)  # its PDO parameters as they are (a fixed mapping too)
                return value if value is not None else drive.read_object(index)

        def on_write(index: int, subindex: int, od: canopen.objectdictionary.ODVariable, data: bytes) -> None:
            raw = od.decode_raw(data)
            if not isinstance(raw, int):  # every object written here is an integer in the EDS
                return
            with self.lock:
                pdos.write(index, subindex, raw)  # SdoAbortedError refuses an invalid mapping
                if not drive.write_object(index, subindex, raw):
                    raise canopen.SdoAbortedError(ABORT_VALUE_RANGE)  # a mode it does not have
                self._flush_emcy()  # a reset's "error reset" EMCY goes out now, not at the next SYNC

        quirks = self.quirks.get(node.id or 0)
        missing = {
            i for q, indices in _SUPERVISION_MISSING.items() if quirks and q in quirks for i in indices
        }

        def refuse_missing(index: int, subindex: int, od: object, data: bytes) -> None:
            if index in missing:
                raise canopen.SdoAbortedError(ABORT_OBJECT_DOES_NOT_EXIST)  # this drive has no such service

        node.add_read_callback(on_read)
        node.add_write_callback(on_write)
        # before canopen's own NMT callback, which would start a heartbeat a drive without one lacks
        node._write_callbacks.insert(0, refuse_missing)

    # -- cyclic traffic ---------------------------------------------------------------------

    def _operational(self, node_id: int) -> bool:
        return self.nodes[node_id].nmt._state == NMT_OPERATIONAL  # canopen keeps the code here

    def _rpdo_handler(self, j: int, cob_id: int) -> Callable[[bytearray, float], None]:
        node_id = self.drive_ids[j]

        def on_rpdo(data: bytearray, now_s: float) -> None:
            # The target waits for the next SYNC, as in a real CSP drive: no integration here.
            if not self._operational(node_id) or self._lost_until_next_sync:
                return
            with self.lock:
                if not self.pdos.receive_rpdo(j, data):
                    self.rejected.add(cob_id, len(data), "an RPDO that does not decode")
                    return
                self._flush_emcy()

        return on_rpdo

    def _on_sync(self, data: bytearray, now: float) -> None:  # noqa: C901  (one SYNC of every simulated device and every scheduled fault)
        frames: list[tuple[int, bytes]] = []
        delayed: list[tuple[float, int, bytes]] = []
        self.faults.start(now)
        bus = bus_faults(self.faults, now, (*self.drive_ids, self.cfg.sensor.node_id))
        if bus.controller_frames_lost:
            self._lost_until_next_sync = True  # and this cycle's RPDOs with it (_rpdo_handler)
            return
        self._lost_until_next_sync = False
        delays = dict(bus.delays_s)
        for cob_id, payload in bus.foreign_frames:  # someone else's frames, sent with this SYNC
            self.bus.send(can.Message(arbitration_id=cob_id, data=payload, is_extended_id=False))
        if nmt_commands(bus.foreign_frames):  # and the nodes obey them, echoed back or not
            with self.lock:
                for cob_id, payload in bus.foreign_frames:
                    if cob_id == cob_ids.NMT:
                        self.network.notify(cob_id, bytearray(payload), now)
                self._after_nmt()
        with self.lock:
            for node_id in bus.reboots:
                self.drives[self.drive_ids.index(node_id)].reboot()
                self._boot(self.nodes[node_id])
        with self.lock:
            self.sync_count += 1
            apply_device_faults(self.faults, self.plant, self.drive_ids, now)
            self.plant.sync(now)
            f = self.plant.force_n
            force_n = math.sqrt(float(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]))
            if self.true_force_tap is not None:
                self.true_force_tap.write(now, float(f[0]), float(f[1]), float(f[2]))
            if not self.max_contact_force_n:
                self.max_contact_force_n.append(0.0)
            if force_n > self.max_contact_force_n[-1]:
                self.max_contact_force_n[-1] = force_n
            sample = self.plant.kinematics_sample()
            frames += rogue_drive_frames(self.pdos, self.drive_ids, bus)  # someone else's, first
            for node_id, tpdo in zip(self.drive_ids, self.pdos.drive_tpdos(), strict=True):
                out = tpdo_payload(self.faults, node_id, tpdo[1], now) if tpdo is not None else None
                if tpdo is None or out is None or not self._operational(node_id):
                    continue
                if node_id in delays:
                    delayed.append((delays[node_id], tpdo[0], out))
                else:
                    frames.append((tpdo[0], out))
            for node_id in bus.silent_heartbeats:  # drives and the sensor alike (heartbeat:N)
                if node_id in self.nodes and node_id not in self._silenced:
                    self.nodes[node_id].nmt.stop_heartbeat()
                    self._silenced.add(node_id)
            sensor_frames = self.pdos.sensor_tpdos()
            sensor_id = self.cfg.sensor.node_id
            if sensor_frames and self._operational(sensor_id):
                for k, (cob, payload) in enumerate(sensor_frames):
                    if (
                        k == 0 and bus.spoofed_force_n is not None
                    ):  # a second sender on the force COB-ID, first
                        frames.append((cob, spoofed_sensor_frame(payload, bus.spoofed_force_n)))
                    out = tpdo_payload(self.faults, sensor_id, payload, now)  # drop:N, malformed:N
                    if out is not None:
                        frames.append((cob, out))
            tracker_frames = self.plant.tracker_frames(now)  # the pose as the pose thread last had it
            if tracker_frames is not None:
                frames.append((cob_ids.tpdo1(self.cfg.tracker.node_id), tracker_frames[0]))
                frames.append((cob_ids.tpdo2(self.cfg.tracker.node_id), tracker_frames[1]))
            self._flush_emcy()
        for cob_id, payload in frames:
            self._send_pdo(cob_id, payload)
        if sample is not None:
            self._kinematics.put(sample)
        for delay_s, cob_id, payload in delayed:
            timer = threading.Timer(delay_s, self._send_pdo, (cob_id, payload, False))
            timer.daemon = True
            timer.start()
        if bus.error_class:  # the class bits of a SocketCAN error frame
            self.bus.send(
                can.Message(
                    arbitration_id=bus.error_class, is_error_frame=True, data=bytes(8), is_extended_id=False
                )
            )

    def _send_pdo(self, cob_id: int, payload: bytes, reuse: bool = True) -> None:
        msg = self._tx.get(cob_id) if reuse else None
        if msg is None:  # frames sent from another thread (delayed) get their own object
            msg = self._message(cob_id)
            if reuse:
                self._tx[cob_id] = msg
        msg.data = bytearray(payload)
        msg.dlc = len(payload)
        self.bus.send(msg)

    def _on_controller_heartbeat(self, data: bytearray, now: float) -> None:
        with self.lock:
            for d in self.drives:
                d.on_controller_heartbeat(now)

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # canopen's NmtSlave has already set the state; a reset also reboots the device.
        if len(data) != 2:
            self.rejected.add(can_id, len(data), "an NMT command is 2 bytes")
            return
        if data[0] == NMT_START_REMOTE_NODE and data[1] in (0, *self.nodes):
            with self.lock:
                self.max_contact_force_n.append(0.0)  # a controller's session starts
        if data[0] in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
            for node_id, at in list(self._boot_at.items()):
                if at is None and data[1] in (0, node_id) and node_id not in self._lss:  # needs_nmt_reset
                    with self.lock:
                        self._boot_late(node_id)
        self._after_nmt()

    def _after_nmt(self) -> None:
        """What the devices do after an NMT command: a reset reboots; leaving OPERATIONAL (stop,
        pre-operational) aborts the connection while enabled (0x6007)."""
        for node_id, node in self.nodes.items():
            if node_id in self._boot_at:
                continue  # not on the bus yet
            if node.nmt._state == 0:
                if node_id in self.drive_ids:
                    self.drives[self.drive_ids.index(node_id)].reboot()
                self._boot(node)
            elif node.nmt._state in (NMT_STOPPED, NMT_PRE_OPERATIONAL) and node_id in self.drive_ids:
                self.drives[self.drive_ids.index(node_id)].on_nmt_left_operational()

    def _bus_off_step(self, now: float) -> None:
        """The bus_off quirk on the clock: its error frames as they fall due; while the bus is off the
        nodes' heartbeats stop and nothing passes either way (the SYNC watchdog of each drive sees it)."""
        assert self.bus_off is not None
        elapsed = self.faults.elapsed(now)
        for cls, data in self.bus_off.error_frames(self._bus_off_elapsed_s, elapsed):
            self.bus.send(
                can.Message(arbitration_id=cls, is_error_frame=True, data=data, is_extended_id=False)
            )
        self._bus_off_elapsed_s = elapsed
        off = self.bus_off.off(elapsed)
        if off == self._bus_is_off:
            return
        self._bus_is_off = off
        for node_id, node in self.nodes.items():
            if node_id in self._boot_at or node_id in self._silenced:
                continue
            if off:
                node.nmt.stop_heartbeat()
            else:
                node.nmt.start_heartbeat(node.nmt._heartbeat_time_ms)  # canopen keeps the period here
        if not off:
            with self.lock:
                self._flush_emcy()  # what the drives said while the bus was off

    def _flush_emcy(self) -> None:
        if self._bus_is_off:
            return  # said when the bus is back
        for node_id, d in zip(self.drive_ids, self.drives, strict=True):
            if node_id in self._boot_at:
                continue  # not booted: said when it boots
            while d.pending_emcy:
                code = d.pending_emcy.pop(0)
                self.nodes[node_id].emcy.send(code, error_register(code))
