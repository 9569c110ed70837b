"""The cyclic PDO path: one batch out (RPDOs, SYNC, heartbeat), one batch in (TPDOs), per cycle.

Lean on purpose (DESIGN.md): COB-IDs, struct layouts and ``can.Message`` objects are built
once; a cycle only rewrites payload bytes. Every received frame enters through ``_notify``
and is dispatched by COB-ID. Decoding errors never leave this module: they are counted.

The exchange also watches the whole bus, because one wrong node can steer the robot. Its bus
hands it only other nodes' frames (drivers/frame_tap.py drops the bus's echoes of our own,
exactly), so a SYNC, NMT command, RPDO, SDO request or controller heartbeat that arrives is
someone else's (a second SYNC producer, a second master); frames from COB-IDs no configured node uses,
EMCY and heartbeats of unknown nodes, two TPDOs of one node in one cycle and a flood of
foreign frames become ``BusAnomaly`` reports; heartbeats of configured nodes that do not say
OPERATIONAL become ``NmtReport`` s. What to do about them is the law's decision ([safety]).

A measurement is used only when it can only be the device's (DESIGN.md, "Trust in measurements"):
a TPDO counts as a sample only in its answer window, from this cycle's SYNC to the collect
deadline (the collect waits for the whole window, so a frame that comes before the real answer
cannot complete the cycle); two candidates for one device in one window make the device's
sample unusable for the cycle (as if missing), whichever came first; a frame that does not
decode is a candidate too, and reported with its node. Every candidate is judged on the
device's physics: a drive's position against its last trusted one (``max_position_step`` per
cycle + ``max_position_jump``), the sensor's rolling counter against its last trusted one. A
lone implausible drive sample is delivered for the law's jump check (which faults and names
it); an implausible candidate among several, or a sensor sample whose counter cannot follow,
is reported. Frames of a cycle's devices after the window are late: counted, never used.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import can

from controller.core.cycle_data import (
    Anomaly,
    BusAnomaly,
    BusFeedback,
    CycleOutputs,
    DriveFeedback,
    EmcyReport,
    NmtReport,
    SensorFeedback,
    TrackerFeedback,
)
from controller.core.periods import DEADLINE_ROUNDING_S
from drivers import cob_ids
from drivers.node_setup import description_drive_codec, description_sensor_codecs
from drivers.pdo_codec import (
    TRACKER_M_PER_COUNT,
    TRACKER_RAD_PER_COUNT,
    DriveCodec,
    FrameError,
    PositionScale,
    SensorFrameCodec,
    decode_tracker_frame,
)

FrameSink = Callable[[bool, float, can.Message], None]  # (outgoing, monotonic time [s], frame)

# A SYNC that goes more than this many periods after the one before goes without the targets
# (``targets_sync_gap_s``).
TARGETS_SYNC_GAP_PERIODS = 1.5
# The clock read again just before the SYNC, this many periods or more after the reading the RPDOs
# were chosen by, means the process was held up in between: the RPDOs go again, chosen by the new
# reading (``CyclicExchange._before_sync``). Three RPDOs take about 50 us to go on the development
# VM (0.02 of a 2.5-ms period); a tenth of a period moves a led target by a tenth of a step.
RECHECK_AFTER_PERIODS = 0.1


def targets_sync_gap_s(period_s: float, drive_extrapolation_periods: int) -> float:
    """How long after the last SYNC a SYNC may still carry targets (``CyclicExchange.send``).

    A drive that takes the commanded step a period from the targets' difference over the time
    between their SYNCs reads a SYNC 2.4 ms late (of 2.5) as two periods: half the speed. Were
    deadlines skipped just after it, it ran on at that half speed for its extrapolation periods
    and the next target pulled it on in one period: 22.3 N of contact force where 10 N was asked
    (the contour in simulated time, docs/concepts/realtime.md). Without the late SYNC's targets
    the drive runs on along its last step, at the speed it had, and the law counts the period as
    one it ran blind (``CycleInputs.targets_withheld``). Where the targets can lead by the SYNC's
    lateness (``CyclicExchange._led``) they go: their step over the time between the SYNCs is the
    speed. A drive with fewer than two periods of extrapolation gets its targets however late
    their SYNC: without them it would stand (none), or spend its one period on the withheld SYNC
    and stand through a skipped deadline after it, behind the setpoint the step counts from
    (``hold_up_effect`` cannot move it back)."""
    return TARGETS_SYNC_GAP_PERIODS * period_s if drive_extrapolation_periods >= 2 else math.inf


(
    _DRIVE,
    _SENSOR_FORCE,
    _SENSOR_TORQUE,
    _EMCY,
    _HEARTBEAT,
    _OWN,
    _SDO_ANSWER,
    _TRACKER_P,
    _TRACKER_R,
    _KERNEL_SYNC,
) = range(10)
CAN_ERR_BUSOFF = 0x040  # error class bit of a SocketCAN error frame (linux/can/error.h)
NMT_OPERATIONAL, NMT_BOOT_UP = 5, 0  # CiA 301 heartbeat state byte
SDO_DOWNLOAD_2_BYTES = 0x2B  # CiA 301 expedited download of 2 data bytes (client command specifier)
CONTROLWORD = 0x6040
COUNTER_MODULO = 256  # the sensor's rolling counter is a u8
DEFAULT_FLOOD_FRAMES = (
    16  # foreign frames in one cycle that make a flood (config safety.max_foreign_frames_per_cycle)
)


def _unknown_kind(cob_id: int) -> Anomaly:
    """What a frame of a COB-ID that no configured node uses is (CiA 301 predefined connection set)."""
    if 0x081 <= cob_id <= 0x0FF:
        return Anomaly.UNKNOWN_EMCY
    if 0x701 <= cob_id <= 0x77F:
        return Anomaly.UNKNOWN_HEARTBEAT
    return Anomaly.UNKNOWN_FRAME


@dataclass
class ExchangeCounters:
    frames_in: int = 0
    frames_out: int = 0
    rejected_frames: int = 0  # frames that did not decode
    rejected_by_node: dict[int, int] = field(default_factory=dict)  # the same, per configured node
    # TPDOs of an earlier cycle: found before this cycle's SYNC, or a burst's in its window (``of_known_age``)
    late_frames: int = 0
    missing_drive_frames: int = 0
    missing_sensor_frames: int = 0
    # The longest run of cycles without a usable sample, over the drives and of the sensor: the
    # stalls this machine shows, from which loop.max_missing_s and safety.sensor_stale_s
    # are chosen (docs: "Silence tolerated").
    longest_drive_silence_cycles: int = 0
    longest_sensor_silence_cycles: int = 0
    error_frames: int = 0
    send_errors: int = 0
    foreign_frames: int = 0  # frames reported as a BusAnomaly (unknown, foreign, duplicate)
    # cycles whose RPDOs went a second time, just before their SYNC: the process was held up between
    # the clock reading they were chosen by and the SYNC (``CyclicExchange._before_sync``)
    rpdos_resent: int = 0
    # lone answers not used: their device owed two or more when the window opened (``of_known_age``)
    answers_of_unknown_age: int = 0


# Windows in step (one answer each) after which answers still owed are taken as never coming (a SYNC
# the device really missed). A device can also lag one answer behind for a while (each window holds
# its answer to the SYNC before) and then catch up with two: forgotten after 3 windows, that catch-up
# was taken for a second sender (a contour demo on a loaded machine faulted on it, three windows one
# behind). 20 windows is half the silence the law tolerates from a drive at 400 Hz (loop.max_missing_s,
# 40 cycles there). Meanwhile a second sender's frame may pass unreported once, never as data: a window
# with two candidates has no sample.
OWED_FORGOTTEN_AFTER = 20

# A lone answer from a device that owed this many answers or more when its window opened may be the
# oldest of a burst (a simulator stopped by its host for 120 ms answered 48 queued SYNCs in 6 ms, the
# first inside a window and the rest after it): a position 46 periods old, taken as this cycle's,
# faulted a run on a following error of 11.5 mm against drives standing still. It is a sample again
# once the device has answered in step (one candidate a window, nothing late between) for
# IN_STEP_BEFORE_TRUSTED windows: its burst is over. One answer owed is a sample at most one SYNC old,
# which the law's checks allow for (a device that lags one answer behind stays usable).
OWED_OF_UNKNOWN_AGE = 2
IN_STEP_BEFORE_TRUSTED = 2


def of_known_age(owed_at_open: int, in_step_at_open: int) -> bool:
    """Whether a device's lone answer in a window is its answer to this window's SYNC, as far as the
    exchange can tell: it owed at most one answer, or it has answered in step since its burst."""
    return owed_at_open < OWED_OF_UNKNOWN_AGE or in_step_at_open >= IN_STEP_BEFORE_TRUSTED


def _owed_after(owed: int, in_step: int, candidates: int) -> tuple[int, int]:
    """A device's answers still owed, and its windows in step, after a window with ``candidates``."""
    if candidates == 0:
        return owed + 1, 0
    owed = max(0, owed + 1 - candidates)
    in_step = in_step + 1 if candidates == 1 else 0
    return (0 if in_step >= OWED_FORGOTTEN_AFTER else owed), in_step


class CyclicExchange:
    def __init__(
        self,
        bus: can.BusABC,
        drive_ids: tuple[int, ...],
        scale: PositionScale,
        sensor_id: int | None,
        controller_id: int,
        heartbeat_every: int,
        fd: bool = False,
        clock: Callable[[], float] = time.monotonic,
        frame_sink: FrameSink | None = None,
        heartbeat_timeout_s: float = 0.5,
        drive_codecs: tuple[DriveCodec, ...] | None = None,
        sensor_codecs: tuple[SensorFrameCodec, SensorFrameCodec] | None = None,
        send_sync: bool = True,
        flood_frames_per_cycle: int = DEFAULT_FLOOD_FRAMES,
        tracker_id: int | None = None,
        sync_period_s: float = 0.0,
        max_position_step: float = math.inf,
        max_position_jump: float = math.inf,
        answer_window_s: float = math.inf,
        guarded: Mapping[int, tuple[float, int]] | None = None,
        targets_sync_gap_s: float = math.inf,
        target_lead_period_s: float = 0.0,
        window_sleep: Callable[[float], None] | None = None,
        drive_extrapolation_periods: int = 0,
    ) -> None:
        self.bus = bus
        # Sleeps until a time of ``clock``: with it the collect sleeps through its answer window and
        # then reads what came, rather than waking for each answer (``collect``).
        self.window_sleep = window_sleep
        self.fd = fd
        self.send_sync = (
            send_sync  # False: the kernel's broadcast manager sends SYNC (drivers/kernel_sync.py)
        )
        # With SYNC from the kernel, the SYNCs this socket receives are the broadcast manager's (another
        # socket of this host): their receive times feed drivers/kernel_sync.py's phase lock. One that
        # comes less than half a period after the last is a second producer's.
        self.sync_period_s = sync_period_s
        self.kernel_sync_stamps: list[float] = []  # receive timestamps (the bus's clock) since the last take
        self._last_kernel_sync = -math.inf
        self.n = len(drive_ids)
        self.scale = scale
        self.has_sensor = sensor_id is not None
        self.heartbeat_every = max(1, heartbeat_every)
        self.clock = clock
        self.frame_sink = frame_sink
        self.counters = ExchangeCounters()
        # The layouts as mapped at set-up (drivers/node_setup.py); without one, the shipped EDS's.
        self._codecs = drive_codecs or tuple(description_drive_codec(i) for i in drive_ids)
        if len(self._codecs) != self.n:
            raise ValueError(f"{len(self._codecs)} drive codecs for {self.n} drives")
        self._rpdos = [
            can.Message(
                arbitration_id=codec.rpdo_cob_id,
                data=bytearray(codec.rpdo.size),
                is_extended_id=False,
                is_fd=fd,
                bitrate_switch=fd,
            )
            for codec in self._codecs
        ]
        self._sync = can.Message(
            arbitration_id=cob_ids.SYNC, data=b"", is_extended_id=False, is_fd=fd, bitrate_switch=fd
        )
        # Heartbeat of the controller, NMT state 5 (operational): the drives consume it.
        self._heartbeat = can.Message(
            arbitration_id=cob_ids.heartbeat(controller_id), data=b"\x05", is_extended_id=False
        )
        self._dispatch: dict[int, tuple[int, int]] = {}
        for j, i in enumerate(drive_ids):
            self._dispatch[self._codecs[j].tpdo_cob_id] = (_DRIVE, j)
            self._dispatch[cob_ids.emcy(i)] = (_EMCY, i)
            self._dispatch[cob_ids.heartbeat(i)] = (_HEARTBEAT, j)
        if sensor_id is not None:
            self._force_codec, self._torque_codec = sensor_codecs or description_sensor_codecs(sensor_id)
            self._dispatch[self._force_codec.cob_id] = (_SENSOR_FORCE, 0)
            self._dispatch[self._torque_codec.cob_id] = (_SENSOR_TORQUE, 0)
            self._dispatch[cob_ids.emcy(sensor_id)] = (_EMCY, sensor_id)
            self._dispatch[cob_ids.heartbeat(sensor_id)] = (_HEARTBEAT, -1)
        # The pose tracker samples at its own rate, not at every SYNC: its frames update the last
        # sample and never hold up a cycle (a cycle is complete with the drives and the sensor).
        self.has_tracker = tracker_id is not None
        if tracker_id is not None:
            self._dispatch[cob_ids.tpdo1(tracker_id)] = (_TRACKER_P, 0)
            self._dispatch[cob_ids.tpdo2(tracker_id)] = (_TRACKER_R, 0)
            self._dispatch[cob_ids.emcy(tracker_id)] = (_EMCY, tracker_id)
            self._dispatch[cob_ids.heartbeat(tracker_id)] = (_HEARTBEAT, -1)
        configured = (
            *drive_ids,
            *(() if sensor_id is None else (sensor_id,)),
            *(() if tracker_id is None else (tracker_id,)),
        )
        self._configured_nodes = frozenset(configured)
        for node in configured:  # answers to the controller's SDO requests (_on_sdo_answer)
            self._dispatch[cob_ids.sdo_response(node)] = (_SDO_ANSWER, node)
        # COB-IDs only the controller sends: whatever arrives there is someone else's.
        for cob in (
            cob_ids.SYNC,
            cob_ids.NMT,
            cob_ids.heartbeat(controller_id),
            *(codec.rpdo_cob_id for codec in self._codecs),
            *(cob_ids.sdo_request(i) for i in configured),
        ):
            self._dispatch[cob] = (_OWN, cob)
        if not send_sync:  # but SYNC is the kernel's broadcast manager's (drivers/kernel_sync.py)
            self._dispatch[cob_ids.SYNC] = (_KERNEL_SYNC, cob_ids.SYNC)
        self.flood_frames_per_cycle = flood_frames_per_cycle
        self._anomalies: dict[
            tuple[Anomaly, int, int, int], int
        ] = {}  # (kind, COB-ID, node, command) -> count
        self._foreign_in_cycle = 0
        self._nmt: dict[int, int] = {}  # node -> last non-operational heartbeat state this cycle
        self._operational_nodes: set[int] = set()  # configured nodes heard OPERATIONAL
        self._sensor_ambiguous = False
        self._judging = False  # frames before the first SYNC (set-up echoes, boot-ups) are not judged
        self._statusword = [0] * self.n
        self._position = [math.nan] * self.n
        self._effort = [math.nan] * self.n  # [N], NaN where the TPDO does not map 0x6077
        self._fresh = [False] * self.n
        # This window's candidates per drive: how many, the last decoded one, and whether any was
        # beyond the drive's physics (judged against the last trusted position).
        self._candidates = [0] * self.n
        self._candidate_sw = [0] * self.n
        self._candidate_x = [math.nan] * self.n
        self._candidate_effort = [math.nan] * self.n
        self._candidate_ok = [False] * self.n  # the last candidate decoded
        self._implausible = [False] * self.n
        self._trusted_x = [math.nan] * self.n  # the last position used as a sample
        self._cycles_since_trusted = [0] * self.n
        self.max_position_step = max_position_step  # [unit per cycle] the actuator's speed limit x period
        self.max_position_jump = max_position_jump  # [unit] safety.max_position_jump
        # How long after its SYNC a cycle's answers are taken once every device has answered; at most
        # to collect's deadline (the loop's: collect_fraction of the period). Tools and tests that
        # give a generous deadline for a slow simulator shorten it.
        self.answer_window_s = answer_window_s
        self._sensor_candidates = [0, 0]  # force, torque frames this window
        # Answers a device still owes: windows in a row without any candidate of it. A device that
        # stalls answers the SYNCs it missed in a burst; one extra candidate per answer owed is its
        # own late answer, not a second sender: still no sample (nobody can tell which is which),
        # counted late, not reported. A rogue cannot use it: nothing ambiguous is ever used.
        #
        # A stalled device's burst straddles windows: of four owed answers one may land in this
        # window and three after it, before the next SYNC. The debt is paid answer by answer
        # (owed + 1 - candidates), not cleared by the first window with a candidate: cleared, the
        # three were reported as a second sender, and a 9 ms stall of the simulator faulted a soak
        # at the defaults ("3 TPDO(s) twice in one cycle from node 1"). An answer a device never
        # sends (a SYNC it really missed) is forgotten once it has answered OWED_FORGOTTEN_AFTER
        # windows in a row exactly once each: it is in step again.
        self._owed = [0] * self.n
        self._sensor_owed = [0, 0]
        self._in_step = [0] * self.n  # windows in a row with exactly one candidate and nothing late
        self._sensor_in_step = [0, 0]
        self._slack = [0] * self.n  # answers a device owed when its trusted sample was taken
        self._sensor_slack = 0
        self._sensor_trusted_counter = -1  # the counter of the last sample used
        self._sensor_cycles_since_trusted = 0
        self._force = (0.0, 0.0, 0.0)
        self._torque = (0.0, 0.0, 0.0)
        self._sensor_status = 0
        self._candidate_force = self._candidate_torque = (0.0, 0.0, 0.0)  # this window's, until it closes
        self._candidate_status = 0
        self._force_counter = -1
        self._torque_counter = -1
        self._sensor_fresh = False
        self._tracker_p: tuple[float, float, float] = (math.nan,) * 3
        self._tracker_r: tuple[float, float, float] = (math.nan,) * 3
        self._tracker_counters = [-1, -1]  # of the last position and rotation frames
        self._tracker_statuses = [0, 0]  # of the last position and rotation frames
        self._tracker_fresh = False  # a complete new sample since the last collect
        self._emcy: list[EmcyReport] = []
        self._collecting = False
        # The SYNC periods the windows belong to. With SYNC from the loop every window is its send's
        # (slot 0 throughout); with SYNC from the kernel (drivers/kernel_sync.py) the SYNCs come on
        # their own, and KernelSyncExchange sets, before each send, the slot of the loop's cycle
        # (cycle_slot) and how a SYNC's receive timestamp maps to its slot (sync_slot_of).
        self.cycle_slot = 0
        self.sync_slot_of: Callable[[float], int] | None = None
        self._window_open = False  # this window's candidates are being counted (_open_window)
        self._window_slot = -1  # the SYNC period of the last window opened
        self._sync_ahead: int | None = None  # a collect stopped at the SYNC of this later slot
        self._last_sync_slot = -1  # of the last kernel SYNC received
        self._draining = False
        self.drive_ids = tuple(drive_ids)
        self.sensor_id = sensor_id
        self.tracker_id = tracker_id
        self._sdo = can.Message(arbitration_id=0, data=bytearray(8), is_extended_id=False)
        self._sdo_owed: dict[int, int] = {}  # node -> answers owed to the controller's SDO requests
        self.heartbeat_timeout_s = heartbeat_timeout_s
        # Node guarding (CiA 301) instead of heartbeat for these nodes: node -> (guard time [s], life
        # time factor). A remote frame on 0x700 + node every guard time; the answer (its NMT state
        # and a toggle bit that alternates) counts as its heartbeat; none within guard time x factor:
        # lost, as a heartbeat is.
        self.guarded = dict(guarded or {})
        self._guard_requests = {
            node: can.Message(
                arbitration_id=cob_ids.heartbeat(node), is_remote_frame=True, dlc=1, is_extended_id=False
            )
            for node in self.guarded
        }
        self._guard_due_s = dict.fromkeys(self.guarded, -math.inf)
        self._guard_toggle: dict[int, int] = {}  # the toggle bit the node's next answer must carry
        self.last_heartbeat_s = [math.nan] * self.n
        self.sensor_heartbeat_s = math.nan  # the sensor's heartbeat, supervised as a drive's
        self._drive_silence = [0] * self.n  # cycles in a row without a usable TPDO, per drive
        self._sensor_silence = 0
        self.started_s = clock()
        self._error_frames = 0
        self._bus_off = False
        self.cycles = 0
        self.sent_s = 0.0  # when this cycle's RPDOs went out (or would have)
        self._last_send_s: float | None = None  # the last send's reading (its SYNC's time)
        # the loop's SYNC only: one later than this after the last goes without the targets
        self.targets_sync_gap_s = targets_sync_gap_s if send_sync else math.inf
        # the loop's SYNC only, 0: off. A late SYNC's targets lead by its lateness (``_led``)
        self.target_lead_period_s = target_lead_period_s if send_sync else 0.0
        self._last_targets: tuple[float, ...] | None = None  # the last targets sent, unled ...
        self._last_send_by_s = -math.inf  # ... and their SYNC's send-by time (its deadline + a period)
        self.drive_extrapolation_periods = drive_extrapolation_periods
        # the loop's SYNC only: a reading this long after the first before the SYNC sends the RPDOs again
        self.recheck_after_s = RECHECK_AFTER_PERIODS * self.target_lead_period_s if send_sync else math.inf
        # What the drives' interpolators latched, as the drives model it (``_stand_in_targets``): the
        # step's last targets they latched (the anchor), that SYNC's reading and their step a period
        # after it; the last targets latched, the step's or a stand-in, and that SYNC's reading; and
        # whether those were a stand-in.
        self._anchor: tuple[float, ...] | None = None
        self._anchor_s = -math.inf
        self._anchor_step: tuple[float, ...] = ()
        self._latched: tuple[float, ...] | None = None
        self._latched_s = -math.inf
        self._standing_in = False
        self._last_controlwords: tuple[int, ...] = ()

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

    def send(self, outputs: CycleOutputs | None, send_by_s: float = math.inf) -> bool:
        """RPDOs of ``outputs`` (none before the first step), then SYNC; every Nth cycle a heartbeat.

        False when the SYNC goes without them: the clock, read just before the RPDOs, is past
        ``send_by_s`` (the process was held up since the loop woke, and they were meant for an
        earlier SYNC; controller/shell/loop.py), or more than ``targets_sync_gap_s`` after the last
        SYNC's reading (``targets_sync_gap_s``).

        A SYNC that leaves after its deadline (``send_by_s`` minus ``target_lead_period_s``, the
        loop's convention) carries targets led by its lateness (``_led``); only one that cannot
        lead them is held to ``targets_sync_gap_s``."""
        ahead, self._sync_ahead = self._sync_ahead, None
        self._window_open = self._collecting = False
        if ahead is not None:  # the last collect ended at a later SYNC (kernel SYNC): its answers follow
            self._open_window(ahead)
        self._drain_late()
        self._judging = True
        # This cycle's window: its own SYNC period, or a later one where the bus is ahead of the loop
        # (a SYNC after this cycle's has come already: what answers now may answer it). Going back
        # to the loop's own period after a later SYNC had been seen took both SYNCs' answers into
        # one window with no answer owed: "TPDO twice in one cycle" with one sender, the kernel-SYNC
        # defect (tests/protocol/test_kernel_sync_pairing.py).
        slot = max(self.cycle_slot, self._last_sync_slot)
        if not self._window_open or self._window_slot < slot:
            if self._window_open:  # answers to the SYNC of a cycle the loop skipped: nobody's sample
                self._abandon_window()
            self._open_window(slot)
        last_s, self.sent_s = self._last_send_s, self.clock()
        self._last_send_s = self.sent_s
        led, in_time = self._choose_targets(outputs, send_by_s, last_s)
        sent: tuple[float, ...] | None = None  # what the drives latch at this SYNC
        if outputs is not None and in_time:
            sent = led if led is not None else outputs.targets
            self._send_rpdos(outputs.controlwords, sent)
            self._last_controlwords = outputs.controlwords
            if self.send_sync:
                sent, in_time = self._before_sync(outputs, sent, send_by_s, last_s)
        if outputs is not None and in_time:
            self._last_targets, self._last_send_by_s = outputs.targets, send_by_s
        else:
            self._last_targets = None
        if self.send_sync:
            steps = sent is not None and in_time  # the step's targets (led or not), not a stand-in
            if sent is None and self._standing_in:
                # the drives' last target was a stand-in: without one now they would run on from it,
                # past where running on from the anchor ends (``_stand_in_targets``)
                sent = self._stand_in_targets(self.sent_s)
                if sent is not None:
                    self._send_rpdos(self._last_controlwords, sent)
            self._send(self._sync)
            if sent is not None:
                self._note_latched(sent, steps)
        if self.cycles % self.heartbeat_every == 0:
            self._send(self._heartbeat)
        if self.guarded:
            self._guard(self.sent_s)
        self.cycles += 1
        return in_time

    def _choose_targets(
        self, outputs: CycleOutputs | None, send_by_s: float, last_s: float | None
    ) -> tuple[tuple[float, ...] | None, bool]:
        """By the reading ``sent_s``: the step's targets led by the SYNC's lateness (None: not led),
        and whether the SYNC carries them (``send``'s answer): not past ``send_by_s``, and, where
        they cannot lead, not more than ``targets_sync_gap_s`` after the last SYNC at ``last_s``.
        At ``send_by_s`` is past it (``DEADLINE_ROUNDING_S``): that is the next cycle's deadline, and
        a SYNC with the targets there went at the same instant as the next cycle's."""
        in_time = self.sent_s < send_by_s - DEADLINE_ROUNDING_S
        led = self._led(outputs.targets, send_by_s) if outputs is not None and in_time else None
        if led is None and last_s is not None and self.sent_s - last_s > self.targets_sync_gap_s:
            in_time = False  # late, and no step to lead its targets along: without them
        return led, in_time

    def _send_rpdos(self, controlwords: tuple[int, ...], targets: tuple[float, ...]) -> None:
        to_counts = self.scale.to_counts
        for msg, codec, cw, target in zip(self._rpdos, self._codecs, controlwords, targets):
            codec.pack_rpdo_into(msg.data, cw, to_counts(target))
            self._send(msg)

    def _before_sync(
        self, outputs: CycleOutputs, sent: tuple[float, ...], send_by_s: float, last_s: float | None
    ) -> tuple[tuple[float, ...], bool]:
        """The RPDOs went; just before their SYNC, the clock once more. The targets a drive latches
        and whether the SYNC carries the step's targets (``send``'s answer).

        A hold-up can strike after the reading the RPDOs were chosen by and before the SYNC: the
        SYNC then leaves late with targets meant for an earlier one, and a drive that ran on past
        its last target through the hold-up is pulled back to them. Over the bus a 7.25-ms hold-up
        inside a send (the contour, a quiet machine) pulled the legs back by 2.8 steps; the tool
        left the part, came back at 24.7 N where 10 N was asked, and lap 3's force error RMS was
        0.62 N against 0.42 in simulated time. So when this reading is ``RECHECK_AFTER_PERIODS``
        or more after the first, the choice is made again from it, as ``send`` made it, and the
        RPDOs go again (a drive latches the last one before the SYNC): led by the new lateness,
        or, past ``send_by_s`` or the targets' gap, the targets the drives would run on to without
        any (``_stand_in_targets``), and the SYNC counts as one without targets."""
        period = self.target_lead_period_s
        now = self.clock()
        if period <= 0.0 or now - self.sent_s < self.recheck_after_s:
            return sent, True
        self.sent_s = self._last_send_s = now  # the SYNC's time
        led, in_time = self._choose_targets(outputs, send_by_s, last_s)
        targets = (led if led is not None else outputs.targets) if in_time else self._stand_in_targets(now)
        if targets is None:  # no target of the step's latched yet, nothing to run on from
            targets = outputs.targets
        if targets != sent:  # the same again (nothing to lead along, and in time) changes nothing
            self._send_rpdos(outputs.controlwords, targets)
            self.counters.rpdos_resent += 1
        return targets, in_time

    def _stand_in_targets(self, sync_s: float) -> tuple[float, ...] | None:
        """Targets that, latched at a SYNC at ``sync_s``, end the period after it where a drive that
        got no target since the anchor (the step's last targets it latched) would be: on past them
        along their step for at most ``drive_extrapolation_periods`` (E) periods, then still
        (sim_backend/drive.py ``_reference``, the drives' model of drivers/node_setup.py 0x2010).
        From the anchor, not from a stand-in before: each target latched gives a drive E periods
        more to run on, and counted from the last stand-in, hold-ups back to back carried the
        drives on past where the law, counting from the anchor, had them stand (an outside tester:
        3 ms in each send for 30 ms, 1.8 mm between the drives and the setpoint, FAULT at 63 N).
        None before the drives latched any of the step's targets."""
        anchor = self._anchor
        if anchor is None:
            return None
        periods = min((sync_s - self._anchor_s) / self.target_lead_period_s, self.drive_extrapolation_periods)
        return tuple(x + s * max(periods, 0.0) for x, s in zip(anchor, self._anchor_step))

    def _note_latched(self, targets: tuple[float, ...], the_steps: bool) -> None:
        """The targets the drives latch at the SYNC just sent (at ``sent_s``): the step's
        (``the_steps``, led or not: the new anchor, with its step a period, their difference to
        the last latched over the periods between the SYNCs, at least one, as a drive takes it) or
        a stand-in."""
        period = self.target_lead_period_s
        if the_steps:
            last = self._latched
            if last is None or period <= 0.0:
                self._anchor_step = (0.0,) * len(targets)
            else:
                periods = max(1.0, (self.sent_s - self._latched_s) / period)
                self._anchor_step = tuple((x - x0) / periods for x, x0 in zip(targets, last))
            self._anchor, self._anchor_s = targets, self.sent_s
        self._latched, self._latched_s = targets, self.sent_s
        self._standing_in = not the_steps

    def _led(self, targets: tuple[float, ...], send_by_s: float) -> tuple[float, ...] | None:
        """``targets`` moved on along their last step by this SYNC's lateness (at most a period).

        A drive's interpolator starts each segment at the SYNC that brings its target and ends it a
        period later: a SYNC δ later than the one before gives that segment 1 - δ/P of the speed,
        and the one after it, on time again, more (four wake-ups 0.5-0.8 ms late beside two CPU
        hogs: the legs at 60-120 % of their speed for four periods, their efforts at ±14-26 N, and
        the contour's force rang). Led by δ/P of their step, the targets end each segment where
        the setpoint's path is when it ends: in simulated time, a second of 0-0.8 ms wake-up jitter
        in lap 3 cost a force error RMS of 0.36 N where undisturbed gives 0.29, and 0.29 led. The
        drive's step between its targets over the time between their SYNCs is then the speed too,
        so a SYNC 2.4 ms late keeps its targets (``targets_sync_gap_s`` is for the SYNC that cannot
        lead). The step, and the recorded outputs, keep the targets of the deadline grid.

        None when it cannot lead: no targets went at the deadline before (the first, after skipped
        deadlines or a SYNC without them), whose difference is the speed; or the lead is off."""
        period = self.target_lead_period_s
        last = self._last_targets
        if period <= 0.0 or last is None or abs(send_by_s - self._last_send_by_s - period) > 0.01 * period:
            return None
        late_s = self.sent_s - (send_by_s - period)
        if late_s <= 0.0:
            return targets
        lead = min(late_s, period) / period
        return tuple(x + (x - x0) * lead for x, x0 in zip(targets, last))

    def _guard(self, now: float) -> None:
        """The node guarding requests that are due."""
        for node, (guard_s, _) in self.guarded.items():
            if now >= self._guard_due_s[node]:
                self._guard_due_s[node] = now + guard_s
                self._send(self._guard_requests[node])

    def send_controlword_by_sdo(self, drive_index: int, controlword: int) -> None:
        """An expedited SDO download of 0x6040 to one drive, not waiting for the answer.

        For a drive that does not process RPDOs (PRE-OPERATIONAL, or not heard): SDO works in
        PRE-OPERATIONAL too (CiA 301). Its answer on 0x580 + node is owed (``_on_sdo_answer``).
        """
        node = self.drive_ids[drive_index]
        self._sdo_owed[node] = self._sdo_owed.get(node, 0) + 1
        msg = self._sdo
        msg.arbitration_id = cob_ids.sdo_request(node)
        msg.data[:] = bytes(
            (
                SDO_DOWNLOAD_2_BYTES,
                CONTROLWORD & 0xFF,
                CONTROLWORD >> 8,
                0,
                controlword & 0xFF,
                (controlword >> 8) & 0xFF,
                0,
                0,
            )
        )
        self._send(msg)

    # -- in ---------------------------------------------------------------------------------

    def _open_window(self, slot: int) -> None:
        """The answer window of SYNC period ``slot`` opens: no candidate yet. At the send, or (kernel
        SYNC) at the SYNC when it came first: what arrives after a SYNC answers it."""
        self._window_open = self._collecting = True
        self._window_slot = slot
        self._fresh = [False] * self.n
        self._candidates = [0] * self.n
        self._implausible = [False] * self.n
        self._candidate_ok = [False] * self.n
        self._sensor_candidates = [0, 0]
        self._sensor_fresh = self._sensor_ambiguous = False
        self._force_counter = self._torque_counter = -1

    def _abandon_window(self) -> None:
        """A window given up before its collect (a later SYNC came first): its candidates are late
        frames, nobody's sample, and what each device has not answered yet it still owes (its
        answer comes later: without the debt it was taken for a second sender)."""
        self.counters.late_frames += sum(self._candidates)
        for j, count in enumerate(self._candidates):
            self._owed[j], self._in_step[j] = _owed_after(self._owed[j], self._in_step[j], count)
        for k, count in enumerate(self._sensor_candidates):
            self._sensor_owed[k], self._sensor_in_step[k] = _owed_after(
                self._sensor_owed[k], self._sensor_in_step[k], count
            )
        self._window_open = False

    def _drain_late(self) -> None:
        """What arrived since the last collect: late TPDOs, echoes, reports for the next cycle
        (and, with kernel SYNC, this cycle's answers when its SYNC has already gone)."""
        self._draining = True
        while (msg := self.bus.recv(timeout=0.0)) is not None:
            self._notify(msg)
        self._draining = False

    def _complete(self) -> bool:
        return all(self._candidates) and (not self.has_sensor or min(self._sensor_candidates) > 0)

    def collect(self, deadline_s: float) -> BusFeedback:
        """Receive until ``deadline_s`` (monotonic), the end of this cycle's answer window.

        The whole window, even when every device has answered: a second candidate for a device
        (someone else on its COB-ID) must be seen whether it comes before or after the real one.

        With ``window_sleep`` it sleeps to the window's end and then reads every frame that came:
        the frames wait in the socket, each with its receive timestamp, and nothing is decided
        before the window ends either way. Waiting on the bus instead woke the loop's thread for
        the first answers, then again for the rest and at the window's end (2.4 waits a cycle with
        the sleep to the deadline, ``perf``); each wake-up by a frame was a wake-up of another
        CPU's thread for the simulator's ``sendto`` too. The price: the answers are decoded after
        the window, not while it waits for the last of them, and the step starts that much later
        (the service sleeps through only where the period leaves room: controller/shell/service.py).
        """
        self._collecting = True
        window_end_s = min(deadline_s, self.sent_s + self.answer_window_s)
        if self.window_sleep is not None:
            self._sleep_then_read(self.window_sleep, window_end_s, deadline_s)
        else:
            self._wait_and_read(window_end_s, deadline_s)
        return self._cycle_feedback()

    def _sleep_then_read(
        self, sleep: Callable[[float], None], window_end_s: float, deadline_s: float
    ) -> None:
        """``collect`` with ``window_sleep`` (``sleep``): to the window's end, then read what came;
        when that left a device unheard, to ``deadline_s`` (when it ends later) and read again."""
        ends = (window_end_s,) if window_end_s >= deadline_s else (window_end_s, deadline_s)
        for end_s in ends:
            if self.clock() < end_s:
                sleep(end_s)
            while (msg := self.bus.recv(timeout=0.0)) is not None:
                self._notify(msg)
                if self._sync_ahead is not None:
                    return  # the next cycle's SYNC (kernel SYNC): what follows answers it
            if self._complete():
                return

    def _wait_and_read(self, window_end_s: float, deadline_s: float) -> None:
        """``collect`` without ``window_sleep``: each frame read as it comes."""
        clock = self.clock
        while True:
            remaining = (window_end_s if self._complete() else deadline_s) - clock()
            if remaining <= 0.0 and self._complete():
                break
            # Past the deadline, still take what has already arrived: if this process was
            # descheduled, the answers may be waiting in the socket, and they are on time.
            msg = self.bus.recv(timeout=max(0.0, remaining))
            if msg is None:
                break
            self._notify(msg)
            if self._sync_ahead is not None:
                break  # the next cycle's SYNC (kernel SYNC): what follows answers it

    def _cycle_feedback(self) -> BusFeedback:
        """The window's verdict, the cycle's feedback, and the cycle's reports started again."""
        clock = self.clock
        self._close_window()
        c = self.counters
        missing = self.n - sum(self._fresh)
        c.missing_drive_frames += missing
        if self.has_sensor and not self._sensor_fresh:
            c.missing_sensor_frames += 1
        self._count_silences()
        drives = tuple(
            DriveFeedback(sw, x, f, e)
            for sw, x, f, e in zip(self._statusword, self._position, self._fresh, self._effort)
        )
        sensor = (
            SensorFeedback(
                self._force,
                self._torque,
                self._sensor_status,
                max(self._force_counter, 0),
                self._sensor_fresh and not self._sensor_ambiguous,
            )
            if self.has_sensor
            else None
        )
        tracker = (
            TrackerFeedback(
                self._tracker_p,
                self._tracker_r,
                self._tracker_statuses[0] | self._tracker_statuses[1],
                max(self._tracker_counters[0], 0),
                self._tracker_fresh,
            )
            if self.has_tracker
            else None
        )
        self._tracker_fresh = False
        now = clock()
        lost = self._lost_heartbeats(now)
        feedback = BusFeedback(
            drives=drives,
            sensor=sensor,
            emcy=tuple(self._emcy),
            lost_heartbeats=lost,
            error_frames=self._error_frames,
            bus_off=self._bus_off,
            anomalies=self._anomaly_reports() if self._anomalies else (),
            nmt_reports=tuple(NmtReport(n, st) for n, st in self._nmt.items()) if self._nmt else (),
            tracker=tracker,
        )
        # The reports start again here, not at the next send: what arrives after this cycle's last
        # TPDO (an EMCY, a bus-off) is read by the next send's drain and belongs to the next cycle.
        self._emcy = []
        self._error_frames = 0
        self._bus_off = False
        self._anomalies = {}
        self._foreign_in_cycle = 0
        self._nmt = {}
        return feedback

    def _close_window(self) -> None:
        """The window's verdict per device: one decoded candidate is the sample, else none.

        A device that still owed answers from before the window may have sent its burst's oldest
        one: the sample is then up to that many SYNCs old, and the device's next answer may be as
        many steps further on than the SYNCs since (``_slack``). Without that allowance the
        sensor's next counter seemed to jump, a frame "the device cannot have sent", and a soak at
        the defaults faulted on it. Two or more owed, the answer is of unknown age until the device
        is in step again (``of_known_age``): no sample, counted late."""
        owed_at_open = list(self._owed)
        in_step_at_open = list(self._in_step)
        sensor_owed_at_open = max(self._sensor_owed)
        sensor_dated = self._counter_dates_now()
        sensor_known_age = sensor_dated or of_known_age(sensor_owed_at_open, min(self._sensor_in_step))
        for j, count in enumerate(self._candidates):
            self._owed[j], self._in_step[j] = _owed_after(self._owed[j], self._in_step[j], count)
        for k, count in enumerate(self._sensor_candidates):
            self._sensor_owed[k], self._sensor_in_step[k] = _owed_after(
                self._sensor_owed[k], self._sensor_in_step[k], count
            )
        for j in range(self.n):
            count = self._candidates[j]
            if count == 1 and not of_known_age(owed_at_open[j], in_step_at_open[j]):
                self.counters.late_frames += 1  # most likely the oldest answer of its burst
                self.counters.answers_of_unknown_age += 1
            elif count == 1 and self._candidate_ok[j]:
                self._statusword[j] = self._candidate_sw[j]
                self._position[j] = self._candidate_x[j]
                self._effort[j] = self._candidate_effort[j]
                self._fresh[j] = True
                if not self._implausible[j]:  # a lone implausible one goes to the law's jump check
                    self._trusted_x[j] = self._candidate_x[j]
                    self._cycles_since_trusted[j] = 0
                    self._slack[j] = owed_at_open[j]
                    continue
            elif count > 1 and self._implausible[j]:
                self._report(Anomaly.IMPLAUSIBLE_FRAME, self._codecs[j].tpdo_cob_id, self.drive_ids[j])
            self._cycles_since_trusted[j] += 1
        if self.has_sensor:
            if self._sensor_fresh and not self._sensor_ambiguous and not sensor_known_age:
                self.counters.late_frames += 2  # its force and torque frames
                self.counters.answers_of_unknown_age += 1
                self._sensor_fresh = False
            if self._sensor_fresh and not self._sensor_ambiguous:
                self._force, self._torque = self._candidate_force, self._candidate_torque
                self._sensor_status = self._candidate_status
                self._sensor_trusted_counter = self._force_counter
                self._sensor_cycles_since_trusted = 0
                self._sensor_slack = 0 if sensor_dated else sensor_owed_at_open
            else:
                self._sensor_cycles_since_trusted += 1

    def _anomaly_reports(self) -> tuple[BusAnomaly, ...]:
        reports = tuple(
            BusAnomaly(kind, cob, n, node, command)
            for (kind, cob, node, command), n in self._anomalies.items()
        )
        if self._foreign_in_cycle > self.flood_frames_per_cycle:
            busiest = max(self._anomalies.items(), key=lambda item: item[1])[0][1]
            reports += (BusAnomaly(Anomaly.FRAME_FLOOD, busiest, self._foreign_in_cycle),)
        return reports

    def _report(self, kind: Anomaly, cob_id: int, node_id: int = 0, command: int = 0) -> None:
        if not self._judging:
            return
        key = (kind, cob_id, node_id, command)
        self._anomalies[key] = self._anomalies.get(key, 0) + 1
        self._foreign_in_cycle += 1
        self.counters.foreign_frames += 1

    def _notify(self, msg: can.Message) -> None:  # noqa: C901  (one dispatch per kind of frame the exchange can receive)
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
        if msg.is_extended_id:  # 0x701 on 29 bits is nobody's heartbeat: it is named, never used
            self._report(Anomaly.EXTENDED_FRAME, msg.arbitration_id)
            return
        route = self._dispatch.get(msg.arbitration_id)
        if route is None:
            self._report(_unknown_kind(msg.arbitration_id), msg.arbitration_id)
            return
        kind, index = route
        if kind == _DRIVE:
            self._on_drive_tpdo(index, msg)
            return
        try:
            if kind in (_SENSOR_FORCE, _SENSOR_TORQUE):
                self._on_sensor(kind, msg)
            elif kind in (_TRACKER_P, _TRACKER_R):
                self._on_tracker(kind, msg)
            elif kind == _EMCY:
                if len(msg.data) != 8:
                    raise FrameError(f"EMCY from node {index} must have 8 data bytes, got {len(msg.data)}")
                code = int.from_bytes(msg.data[0:2], "little")
                self._emcy.append(EmcyReport(index, code, msg.data[2]))
            elif kind == _HEARTBEAT:
                if not self._on_heartbeat(index, msg):
                    return  # a guarding answer out of toggle: not a sign of life
                if index >= 0:
                    self.last_heartbeat_s[index] = now
                elif self.sensor_id is not None and msg.arbitration_id == cob_ids.heartbeat(self.sensor_id):
                    self.sensor_heartbeat_s = now
            elif kind == _OWN:
                self._on_own_cob_id(msg)
            elif kind == _KERNEL_SYNC:
                self._on_kernel_sync(msg)
            elif kind == _SDO_ANSWER:
                self._on_sdo_answer(index, msg)
        except FrameError:
            self._reject(msg.arbitration_id, self._node_of(kind, index, msg.arbitration_id))

    def _lost_heartbeats(self, now: float) -> tuple[int, ...]:
        """The drives and the sensor whose heartbeat is overdue (counted from the start until the first)."""
        nodes = list(zip(self.drive_ids, self.last_heartbeat_s))
        if self.sensor_id is not None:
            nodes.append((self.sensor_id, self.sensor_heartbeat_s))
        return tuple(
            node
            for node, last in nodes
            if now - (self.started_s if math.isnan(last) else last) > self._life_time_s(node)
        )

    def _life_time_s(self, node: int) -> float:
        """How long a node may stay unheard: its heartbeat timeout, or its guard time x life time factor."""
        guarding = self.guarded.get(node)
        return self.heartbeat_timeout_s if guarding is None else guarding[0] * guarding[1]

    def _count_silences(self) -> None:
        """Each device's run of cycles without a usable sample, and the longest so far."""
        c = self.counters
        self._drive_silence = [0 if f else s + 1 for f, s in zip(self._fresh, self._drive_silence)]
        if self._drive_silence:
            c.longest_drive_silence_cycles = max(c.longest_drive_silence_cycles, max(self._drive_silence))
        if self.has_sensor:
            usable = self._sensor_fresh and not self._sensor_ambiguous
            self._sensor_silence = 0 if usable else self._sensor_silence + 1
            c.longest_sensor_silence_cycles = max(c.longest_sensor_silence_cycles, self._sensor_silence)

    def _node_of(self, kind: int, index: int, cob_id: int) -> int:
        """The configured node a routed frame belongs to (0: the controller's own COB-IDs)."""
        if kind == _EMCY:
            return index
        if kind == _HEARTBEAT:
            return cob_id - 0x700
        if kind in (_SENSOR_FORCE, _SENSOR_TORQUE):
            return self.sensor_id or 0
        if kind in (_TRACKER_P, _TRACKER_R):
            return self.tracker_id or 0
        return 0

    def _reject(self, cob_id: int, node_id: int) -> None:
        """A configured node's frame that does not decode: counted per node and reported with it."""
        c = self.counters
        c.rejected_frames += 1
        c.rejected_by_node[node_id] = c.rejected_by_node.get(node_id, 0) + 1
        self._report(Anomaly.REJECTED_FRAME, cob_id, node_id)

    def _on_drive_tpdo(self, j: int, msg: can.Message) -> None:
        """A candidate for drive ``j``'s sample: judged, kept until the window closes."""
        node = self.drive_ids[j]
        if not self._collecting:
            # Before this cycle's SYNC: the last window is closed. Late, never used; a second one for a
            # cycle that already had its sample is someone else's (or the true one after a rogue's).
            self.counters.late_frames += 1
            self._in_step[j] = 0
            if self._owed[j] > 0:
                self._owed[j] -= 1  # the answer to a SYNC it missed
            elif self._fresh[j]:
                self._report(Anomaly.DUPLICATE_FRAME, msg.arbitration_id, node)
            return
        self._candidates[j] += 1
        if self._candidates[j] - 1 > self._owed[j]:
            self._report(Anomaly.DUPLICATE_FRAME, msg.arbitration_id, node)
        elif self._candidates[j] > 1:
            self.counters.late_frames += 1
        try:
            sw, counts, effort = self._codecs[j].decode_tpdo(msg.data)
        except FrameError:
            self._reject(msg.arbitration_id, node)
            self._candidate_ok[j] = False
            return
        x = self.scale.to_unit(counts)
        trusted = self._trusted_x[j]
        possible = (
            self.max_position_step * (self._cycles_since_trusted[j] + 1 + self._slack[j])
            + self.max_position_jump
        )
        if abs(x - trusted) > possible:  # False while nothing is trusted yet (NaN)
            self._implausible[j] = True
        self._candidate_sw[j], self._candidate_x[j], self._candidate_ok[j] = sw, x, True
        self._candidate_effort[j] = effort

    def _counter_follows(self, counter: int) -> bool:
        """A sensor counter the sensor can have sent now: the trusted one, or as many steps on as SYNCs since.

        The same counter is a stale sensor (the law's judgement), not someone else's frame.
        """
        if self._sensor_trusted_counter < 0:
            return True
        step = (counter - self._sensor_trusted_counter) % COUNTER_MODULO
        return step <= self._sensor_cycles_since_trusted + 1 + self._sensor_slack

    def _counter_dates_now(self) -> bool:
        """Whether the sensor's candidate is, by its counter, its answer to this window's SYNC: as
        many steps on from the last sample used as SYNCs since, that sample itself of its SYNC (no
        slack), and fewer SYNCs since than the counter's range (a wrap could date an old one anew).

        The sensor counts a sample a SYNC whether its frames reach the bus or not, so after frames
        lost (not late: a lost frame is never answered in a burst) its next pair dates itself. A
        burst's oldest pair does not: its counter is one step on, not as many as the SYNCs since.
        Without this, two lost pairs kept the sensor untrusted for two windows more
        (``IN_STEP_BEFORE_TRUSTED``): four cycles without a sample, which the contour task takes
        for blindness and brakes for."""
        since = self._sensor_cycles_since_trusted + 1
        return (
            self._sensor_trusted_counter >= 0
            and self._sensor_slack == 0
            and since < COUNTER_MODULO
            and (self._force_counter - self._sensor_trusted_counter) % COUNTER_MODULO == since
        )

    def _on_sensor(self, kind: int, msg: can.Message) -> None:
        codec = self._force_codec if kind == _SENSOR_FORCE else self._torque_codec
        k = 0 if kind == _SENSOR_FORCE else 1
        sensor_node = self.sensor_id or 0
        if self._collecting:
            self._sensor_candidates[k] += 1
            if self._sensor_candidates[k] > 1:
                # Two senders on the sensor's COB-ID, or a late sample and the true one: nobody can
                # tell which is true: no fresh sample this cycle.
                if self._sensor_candidates[k] - 1 > self._sensor_owed[k]:
                    self._report(Anomaly.DUPLICATE_FRAME, msg.arbitration_id, sensor_node)
                self._sensor_ambiguous = True
        try:
            x, y, z, status, counter = codec.decode(msg.data)
        except FrameError:
            self._sensor_ambiguous = self._sensor_ambiguous or self._collecting
            raise  # rejected and reported by _notify
        if self._collecting and not self._counter_follows(counter):
            self._report(Anomaly.IMPLAUSIBLE_FRAME, msg.arbitration_id, sensor_node)
            self._sensor_ambiguous = True
        if not self._collecting:
            self.counters.late_frames += 1
            self._sensor_owed[k] = max(0, self._sensor_owed[k] - 1)
            self._sensor_in_step[k] = 0
            return  # outside its window: never a sample
        if kind == _SENSOR_FORCE:
            self._candidate_force, self._force_counter = (x, y, z), counter
        else:
            self._candidate_torque, self._torque_counter = (x, y, z), counter
        self._candidate_status = status
        if self._force_counter == self._torque_counter:
            self._sensor_fresh = True

    def _on_tracker(self, kind: int, msg: can.Message) -> None:
        """A tracker frame, whenever it comes (drained or collected): the pair with one counter is a sample."""
        i = 0 if kind == _TRACKER_P else 1
        x, y, z, status, counter = decode_tracker_frame(
            msg.data, TRACKER_M_PER_COUNT if i == 0 else TRACKER_RAD_PER_COUNT
        )
        if i == 0:
            self._tracker_p = (x, y, z)
        else:
            self._tracker_r = (x, y, z)
        self._tracker_counters[i] = counter
        # both frames' bits: a position saturated is not cleared by a good rotation frame after it
        self._tracker_statuses[i] = status
        if self._tracker_counters[0] == self._tracker_counters[1]:
            self._tracker_fresh = True

    def _on_heartbeat(self, index: int, msg: can.Message) -> bool:
        """A heartbeat or node guarding answer; False for a guarding answer whose toggle bit did not
        alternate (CiA 301: the node did not see the request before, or the answer is a stale one)."""
        if len(msg.data) != 1:
            raise FrameError(
                f"heartbeat 0x{msg.arbitration_id:03X} must have 1 data byte, got {len(msg.data)}"
            )
        state = msg.data[0] & 0x7F  # bit 7 is the toggle bit of node guarding
        node = msg.arbitration_id - 0x700
        if node in self.guarded:
            toggle = msg.data[0] & 0x80
            expected = self._guard_toggle.get(node, toggle)  # the first answer sets the phase
            self._guard_toggle[node] = toggle ^ 0x80
            if toggle != expected:
                return False
        if state == NMT_OPERATIONAL:
            self._operational_nodes.add(node)
        elif self._judging and (state == NMT_BOOT_UP or node in self._operational_nodes):
            # A node that left OPERATIONAL, or restarted. One still coming up after the NMT start (its
            # PRE-OPERATIONAL heartbeat crossing the start command on a slow bus) is not judged.
            self._nmt[node] = state
        return True

    def _on_kernel_sync(self, msg: can.Message) -> None:
        stamp = msg.timestamp
        if stamp - self._last_kernel_sync < 0.5 * self.sync_period_s:
            self._report(Anomaly.FOREIGN_SYNC, msg.arbitration_id)  # two producers: not a sample of ours
            return
        self._last_kernel_sync = stamp
        self.kernel_sync_stamps.append(stamp)
        if not self._judging or self.sync_slot_of is None:
            return
        # The window follows the SYNC the answers follow, not the loop's send. A loop that wakes later
        # than the lead finds its SYNC, and the drives' answers to it, in the drain: taken by the send,
        # those answers were late frames of a cycle that had its sample, "TPDO twice in one cycle", a
        # fault in 4 of 8 runs of the 25-Hz path on the emulated vcan VM (wake-ups up to 39 ms late
        # with a lead of 8 ms). A collect that runs into the next SYNC stops there.
        slot = self.sync_slot_of(stamp)
        if slot == self._last_sync_slot:
            # Two SYNCs nearest one period: a stall of the kernel's timer left one about half a period
            # off and the lock pulls the next one in (intervals down to 0.9 periods). Every device
            # answers both: one more answer owed each, not a second sender (the window's verdict:
            # two candidates, no sample).
            self._owed = [o + 1 for o in self._owed]
            self._sensor_owed = [o + 1 for o in self._sensor_owed]
            # a new debt: the windows in step that forget debts count from here (counted from before,
            # a device long in step had this one forgotten at once, and its late answer was taken
            # for a second sender)
            self._in_step = [0] * self.n
            self._sensor_in_step = [0, 0]
        self._last_sync_slot = slot
        if slot <= self._window_slot:
            return  # this window's SYNC, or a late one of a window before: its answers are late frames
        if not self._draining:
            self._sync_ahead = slot
            return
        if self._window_open:  # a whole period missed: the window before was never collected
            self._abandon_window()
        self._open_window(slot)

    def _on_sdo_answer(self, node: int, msg: can.Message) -> None:
        """A configured node's SDO answer: to the controller's own request, or evidence of another
        SDO client talking to it. On the UDP bus a request from another process is named where it
        is sent (``_on_own_cob_id``); the answer is what a second client cannot hide (an outside
        tester wrote 0x6007, 0x1016:1 and 0x6065 of a running drive by SDO, and the run ended DONE
        with no foreign frame counted, 44dbcbc)."""
        owed = self._sdo_owed.get(node, 0)
        if owed > 0:
            self._sdo_owed[node] = owed - 1
        else:
            self._report(Anomaly.FOREIGN_SDO, msg.arbitration_id, node)

    def _on_own_cob_id(self, msg: can.Message) -> None:
        """A frame on a COB-ID only the controller sends, from someone else (the bus drops our echoes)."""
        cob = msg.arbitration_id
        if cob == cob_ids.SYNC:
            self._report(Anomaly.FOREIGN_SYNC, cob)
        elif cob == cob_ids.NMT:
            command, target = (msg.data[0], msg.data[1]) if len(msg.data) == 2 else (0, 0)
            concerns_us = target == 0 or target in self._configured_nodes
            if concerns_us:
                self._report(Anomaly.FOREIGN_NMT, cob, target, command)
            else:
                self._report(Anomaly.UNKNOWN_FRAME, cob)
        else:
            self._report(Anomaly.FOREIGN_COMMAND, cob)
