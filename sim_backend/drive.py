"""A simulated CiA 402 drive for a linear (or rotary) actuator, cyclic synchronous position.

Behaviour, as a real CSP drive:
- the power state machine of CiA 402 driven by the controlword (``controller.core.cia402``);
- on SYNC it latches the last received target and reports the position sampled at the
  SYNC; between SYNCs its position reference is interpolated linearly from the previous to
  the new target over the interpolation time period (object 0x60C2, written by the master at
  set-up; the measured SYNC interval while it is 0), the drive's interpolator;
- a late or missing setpoint costs nothing visible (CiA 402 leaves this to the manufacturer;
  this drive models the common choice of a bounded linear extrapolation, with the bound as a
  parameter as real drives have it, e.g. Lenze 9400's accepted telegram failures): past the end
  of its interpolation segment the reference goes on past the target at the commanded speed
  (the last step between targets a period), whether no SYNC comes or SYNCs come without a new
  target, for up to ``extrapolation_periods`` interpolation periods (object 0x2010, written by
  the master at set-up; 1 at power-on), then holds, still. A new target starts a segment from
  wherever the reference is. A drive whose master is really silent still stops on its SYNC
  watchdog;
- a second-order position loop (natural frequency ``bandwidth_hz``, damping ratio) with
  velocity feed-forward from the interpolator (a fraction ``velocity_feedforward``, 1.0 as
  CSP drives are usually tuned) and velocity and acceleration saturation, integrated in
  sub-steps of ``substep_s``;
- end stops at the stroke limits (the carriage stops there and the drive faults, 0x7320
  "position sensor / range" EMCY);
- quick stop on the quick-stop deceleration, then stays in QUICK STOP ACTIVE (option 6);
- a following-error monitor (0x6065 window, 0x6066 time, written by the master): the position
  reference and the carriage further apart than the window for longer than the time -> FAULT
  and EMCY 0x8611;
- a watchdog: no SYNC for ``sync_timeout_s`` while enabled -> quick stop and EMCY 0x8240; the time
  is the power-on value of ``params.sync_timeout_s`` until the master writes object 0x2011 (ms);
- the abort connection option code 0x6007 (CiA 402), the drive's own reaction to losing its
  master while enabled: the controller's heartbeat not heard for the consumer time (0x1016,
  EMCY 0x8130) or NMT leaving OPERATIONAL (PRE-OPERATIONAL or STOPPED, where RPDOs are no
  longer processed): 0 nothing, 1 FAULT, 2 disable voltage, 3 quick stop;
- where ``quirks`` (``DriveQuirks``, sim_backend/quirks.py) say so, a real drive's habits: a
  boot in FAULT until its power stage is ready, a fault reset that needs bit 7 held, slow
  transitions towards OPERATION ENABLED, homing without "attained", no homing mode, a warning
  EMCY at each enable. The ideal drive has none.

Time is an argument everywhere (``advance(now_s)``); the process shell reads the clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from controller.core.cia402 import (
    CW_FAULT_RESET,
    CW_HOMING_START,
    MODE_CYCLIC_SYNC_POSITION,
    MODE_HOMING,
    SW_FOLLOWING_COMMAND,
    SW_HOMING_ATTAINED,
    SW_HOMING_ERROR,
    SW_REMOTE,
    SW_TARGET_REACHED,
    SW_VOLTAGE_ENABLED,
    SW_WARNING,
    PowerState,
    device_transition,
    statusword_bits,
)
from sim_backend.homing import HomingPhase, HomingRun, HomingSettings

EMCY_NO_ERROR = 0x0000
EMCY_POSITION_RANGE = 0x7320
EMCY_HEARTBEAT_LOST = 0x8130
EMCY_SYNC_LOST = 0x8240
EMCY_FORCED_FAULT = 0x5000  # device hardware, used by fault injection
EMCY_FOLLOWING_ERROR = 0x8611  # CiA 402: following error (window 0x6065 exceeded for longer than 0x6066)
EMCY_SYNC_PERIOD = 0x8700  # CiA 402 "sync controller": the SYNC interval is not the configured period
EMCY_COMMUNICATION = 0x8100  # CiA 301 communication error: here NMT left OPERATIONAL while enabled
EMCY_DC_LINK_UNDERVOLTAGE = 0x3220  # CiA 402: the power stage's DC link is not up (quirk boots_in_fault)
ERROR_REGISTER_GENERIC = 0x01  # CiA 301 0x1001 bit 0
ERROR_REGISTER_MANUFACTURER = 0x80  # bit 7: a manufacturer-specific error (EMCY 0xFF00-0xFFFF)
# 0x6007 abort connection option codes (CiA 402)
ABORT_NO_ACTION, ABORT_FAULT, ABORT_DISABLE_VOLTAGE, ABORT_QUICK_STOP = 0, 1, 2, 3

# The SYNC period check: the median of this many SYNC intervals (robust to a descheduled master
# or simulator) against the configured cycle, off by this factor or more either way. It catches a
# master running another period than it configured (a rate, 0x1006 or 0x60C2 that does not
# match), not timing quality, which the controller measures itself: without real-time scheduling
# on the busy 2-core development machine the loop achieved 321 and 232 of 400 Hz (cheope demo
# --no-realtime, two runs; it skips the deadlines it missed), and that must not fault the drives.
SYNC_PERIOD_WINDOW = 64
SYNC_PERIOD_MISMATCH_FACTOR = 2.0


def error_register(code: int) -> int:
    """The error register (0x1001) an EMCY with ``code`` carries: none for "error reset"."""
    if code == EMCY_NO_ERROR:
        return 0
    return ERROR_REGISTER_MANUFACTURER if code >= 0xFF00 else ERROR_REGISTER_GENERIC


@dataclass(frozen=True)
class DriveQuirks:
    """A real drive's habits (sim_backend/quirks.py names and documents them); all off: ideal."""

    boot_fault_code: int = 0  # boots in FAULT with this 0x603F until its power stage is ready (0: no)
    power_stage_ready_s: float = 0.0  # ... this long after boot: until then a reset is refused
    fault_reset_hold_s: float = 0.0  # bit 7 must be held high this long to reset (0: the edge)
    transition_delay_s: float = 0.0  # each transition towards OPERATION ENABLED takes this long
    homing_attained_bit: bool = True  # False: homing never sets statusword bit 12
    homing_mode: bool = True  # False: no homing mode (absolute encoder, 0x6060 = 6 refused)
    warning_emcy_code: int = 0  # a warning EMCY at each enable (0: none)


# Transitions that wait for the power stage or the brake on a slow drive (CiA 402 2, 3, 4, 16):
# towards OPERATION ENABLED. Switching off or stopping is never delayed.
_UP = {
    (PowerState.SWITCH_ON_DISABLED, PowerState.READY_TO_SWITCH_ON),
    (PowerState.READY_TO_SWITCH_ON, PowerState.SWITCHED_ON),
    (PowerState.SWITCHED_ON, PowerState.OPERATION_ENABLED),
    (PowerState.QUICK_STOP_ACTIVE, PowerState.OPERATION_ENABLED),
}


@dataclass(frozen=True)
class DriveParams:
    bandwidth_hz: float
    damping_ratio: float
    max_velocity: float  # [unit/s]
    max_acceleration: float  # [unit/s^2]
    quick_stop_deceleration: float  # [unit/s^2]
    velocity_feedforward: float  # 0..1
    stroke_min: float  # [unit]
    stroke_max: float
    counts_per_unit: float
    sync_timeout_s: float
    substep_s: float
    extrapolation_periods: int = 1  # object 0x2010 at power-on: how far the reference runs on blind
    negative_limit_switch: float = -math.inf  # homing switches, true coordinates [unit]
    positive_limit_switch: float = math.inf


# Object 0x2010 (manufacturer-specific, UNSIGNED8): how many interpolation periods past the end of
# its segment the reference runs on blind (drivers/eds/cheope_drive.eds).
EXTRAPOLATION_PERIODS_INDEX = 0x2010
# More is refused: 62.5 ms of blind motion at 400 Hz, 25 ms at 1 kHz. Real drives bound it likewise, in
# periods (Lenze 9400's accepted telegram failures) or in time (Stober's maximum extrapolation time).
MAX_EXTRAPOLATION_PERIODS = 25
# Object 0x2011 (manufacturer-specific, UNSIGNED16): the SYNC watchdog's time in ms, 1-65 535 (0 is
# refused: a drive that never notices its master gone). Drives take this time from their integrator
# (Siemens MICROMASTER's CANopen module: a SYNC consumer time, then a SYNC loss trip).
SYNC_WATCHDOG_INDEX = 0x2011


@dataclass
class SimulatedDrive:
    """Mutable device state; owned by one thread of the simulator process."""

    params: DriveParams
    position: float
    velocity: float = 0.0
    acceleration: float = 0.0  # of the last sub-step, for the structure's inertial load (plant.py)
    effort_n: float = 0.0  # the motor's force on its carriage along +q, set by the plant (0x6077)
    power: PowerState = PowerState.SWITCH_ON_DISABLED
    mode_of_operation: int = 0
    last_controlword: int = 0
    received_target: float = field(init=False)
    latched_target: float = field(init=False)
    previous_target: float = field(init=False)
    interp_start_s: float = 0.0
    sync_period_s: float = 0.0025  # measured between SYNCs; the interpolation period while 0x60C2 is 0
    interpolation_period_s: float = 0.0  # object 0x60C2 (value x 10^index s); 0: not configured
    target_received: bool = False  # an RPDO came since the last SYNC
    # the commanded step a period [unit]: the last two targets' difference over the time between their SYNCs
    target_step: float = 0.0
    target_step_valid: bool = False  # the last target was latched enabled (interp_start_s is its SYNC)
    extrapolation_periods: int = field(init=False)  # object 0x2010 (params.extrapolation_periods at boot)
    sync_timeout_s: float = field(init=False)  # object 0x2011 (params.sync_timeout_s at boot)
    last_sync_s: float | None = None
    last_heartbeat_s: float | None = None
    time_s: float | None = None
    heartbeat_consumer_s: float = 0.0  # object 0x1016; 0 disables the heartbeat watchdog
    abort_connection_option: int = ABORT_FAULT  # object 0x6007 (the EDS default; set-up writes quick stop)
    communication_cycle_period_s: float = 0.0  # object 0x1006; 0: not configured
    sync_intervals_s: list[float] = field(default_factory=list)  # the last SYNC_PERIOD_WINDOW intervals
    sync_period_mismatch: bool = False  # reported once by EMCY_SYNC_PERIOD until the period matches again
    pending_emcy: list[int] = field(default_factory=list)
    error_code: int = EMCY_NO_ERROR
    # An incremental encoder: it reports the true position plus this offset, unknown to the master
    # until homing (sim_backend/homing.py) sets it so that home reads as the home offset 0x607C.
    encoder_offset: float = 0.0
    homing_settings: HomingSettings = field(default_factory=HomingSettings)
    homing: HomingRun | None = None
    reported_position_error: float = 0.0  # fault injection: the position it reports is off by this [unit]
    blocked: bool = False  # fault injection: the carriage is mechanically stuck
    following_error_window: float = 0.0  # 0x6065 [unit]; 0: no monitoring
    following_error_time_s: float = 0.0  # 0x6066
    _following_error_since_s: float | None = None
    interpolation: list[int] = field(default_factory=lambda: [0, -3])  # 0x60C2 sub 1, sub 2 (EDS defaults)
    guarding: list[int] = field(default_factory=lambda: [0, 0])  # 0x100C guard time [ms], 0x100D factor
    quirks: DriveQuirks = field(default_factory=DriveQuirks)
    homed: bool = False  # homing attained since the last boot (an absolute encoder: always)
    warning: bool = False  # statusword bit 7: a warning is active (quirk warning_emcy_on_enable)
    booted_s: float | None = None  # when it (re)booted, on its clock (its first advance after it)
    fault_cause_until_s: float | None = None  # a fault whose cause lasts: until then a reset is refused
    _pending: tuple[PowerState, float] | None = None  # a slow transition: (state, when it completes)
    _reset_high_since_s: float | None = None  # bit 7 high since (quirk fault_reset_hold)

    def __post_init__(self) -> None:
        self.received_target = self.position
        self.latched_target = self.position
        self.previous_target = self.position
        self.extrapolation_periods = self.params.extrapolation_periods
        self.sync_timeout_s = self.params.sync_timeout_s
        self._boot()

    def _boot(self) -> None:
        """Power-on: an absolute encoder knows where it is; a drive whose power stage comes up late
        starts in FAULT, and says so by EMCY (0x603F holds the code)."""
        self.homed = not self.quirks.homing_mode
        self.booted_s = None
        self._pending = None
        self._reset_high_since_s = None
        self.warning = False
        q = self.quirks
        if q.boot_fault_code:
            self.power = PowerState.FAULT
            self.error_code = q.boot_fault_code
            self.fault_cause_until_s = -1.0  # from the boot on: set at the first advance
            self.pending_emcy.append(q.boot_fault_code)

    # -- protocol ---------------------------------------------------------------------------

    def on_rpdo(self, controlword: int, target_counts: int) -> None:
        self.received_target = self.from_counts(target_counts)
        self.target_received = True
        self.on_controlword(controlword)

    def write_object(self, index: int, subindex: int, value: int) -> bool:  # noqa: C901  (one branch per object a drive acts on)
        """An SDO write of one of its objects (CiA 301/402), positions in counts; False when the
        value is one the drive refuses (a mode of operation it does not have)."""
        counts = self.params.counts_per_unit
        if index == 0x1006:
            self.communication_cycle_period_s = value * 1e-6
        elif index == 0x6060:
            if value == MODE_HOMING and not self.quirks.homing_mode:
                return False
            self.set_mode(value)
        elif index == 0x6040:
            self.on_controlword(value)
        elif index == 0x607A:
            self.received_target = self.from_counts(value)
        elif index == 0x6098:  # the homing objects (CiA 402), positions in counts
            self.homing_settings = replace(self.homing_settings, method=value)
        elif index == 0x607C:
            self.homing_settings = replace(self.homing_settings, home_offset=value / counts)
        elif index == 0x6099 and subindex == 1:
            self.homing_settings = replace(self.homing_settings, switch_speed=value / counts)
        elif index == 0x6099 and subindex == 2:
            self.homing_settings = replace(self.homing_settings, zero_speed=value / counts)
        elif index == 0x609A:
            self.homing_settings = replace(self.homing_settings, acceleration=value / counts)
        elif index == 0x6065:  # following error window [counts]; 0xFFFFFFFF: off (CiA 402)
            self.following_error_window = 0.0 if value == 0xFFFFFFFF else value / counts
        elif index == 0x6066:  # following error time out [ms]
            self.following_error_time_s = value / 1000.0
        elif index == 0x6007:  # abort connection option code (CiA 402)
            self.abort_connection_option = value
        elif index == 0x1016 and subindex == 1:
            # CiA 301: bits 16..23 node id, bits 0..15 consumer time [ms]
            self.heartbeat_consumer_s = (value & 0xFFFF) / 1000.0
        elif index in (0x100C, 0x100D):
            # node guarding (CiA 301): guard time [ms] x life time factor is the life time within
            # which the master's next poll must come; the drive's life guarding (EMCY 0x8130)
            self.guarding[0 if index == 0x100C else 1] = value
            guard_ms, factor = self.guarding
            self.heartbeat_consumer_s = guard_ms * factor / 1000.0
        elif index == EXTRAPOLATION_PERIODS_INDEX:
            if value > MAX_EXTRAPOLATION_PERIODS:
                return False
            self.extrapolation_periods = value
        elif index == SYNC_WATCHDOG_INDEX:
            if not 0 < value <= 0xFFFF:
                return False
            self.sync_timeout_s = value / 1000.0
        elif index == 0x60C2 and subindex in (1, 2):
            # CiA 402 interpolation time period: value (sub 1) x 10^index (sub 2) s; 0: the drive
            # takes the measured SYNC interval
            self.interpolation[subindex - 1] = value
            self.interpolation_period_s = self.interpolation[0] * 10.0 ** self.interpolation[1]
        return True

    def read_object(self, index: int) -> int | None:
        """An SDO read of one of its live objects (None: the object dictionary's stored value)."""
        if index == 0x6041:
            return self.statusword()
        if index == 0x6064:
            return self.position_counts()
        if index == 0x6061:
            return self.mode_of_operation
        if index == 0x603F:
            return self.error_code
        return None

    def from_counts(self, counts: int) -> float:
        """A position the master sent, in the drive's true coordinates."""
        return counts / self.params.counts_per_unit - self.encoder_offset

    def set_mode(self, mode: int) -> None:
        """0x6060; leaving homing mode forgets an unfinished homing run."""
        if mode != self.mode_of_operation:
            self.homing = None
        self.mode_of_operation = mode

    def on_controlword(self, controlword: int) -> None:
        previous = self.last_controlword
        self._on_power_controlword(controlword)
        if (
            self.mode_of_operation == MODE_HOMING
            and self.power == PowerState.OPERATION_ENABLED
            and controlword & CW_HOMING_START
            and not previous & CW_HOMING_START
        ):
            p = self.params
            self.homing = HomingRun(
                self.homing_settings,
                p.negative_limit_switch,
                p.positive_limit_switch,
                p.stroke_min,
                p.stroke_max,
            )
            self.homing.start(self.position)
            self._homing_result()

    def _homing_result(self) -> None:
        run = self.homing
        if run is not None and run.phase == HomingPhase.ATTAINED and not math.isnan(run.home_position):
            # home reads as the home offset from now on: the unknown encoder offset is gone
            self.encoder_offset = self.homing_settings.home_offset - run.home_position
            run.home_position = math.nan  # applied once
            self.latched_target = self.previous_target = self.received_target = self.position
            self.homed = True

    def _on_power_controlword(self, controlword: int) -> None:
        new = device_transition(self.power, controlword, self.last_controlword)
        reset_bit = bool(controlword & CW_FAULT_RESET)
        if self.power == PowerState.FAULT:
            if not reset_bit:
                self._reset_high_since_s = None
            elif new != self.power and self.quirks.fault_reset_hold_s > 0.0:
                # the edge starts the hold; the reset comes when bit 7 has stayed high long enough
                self._reset_high_since_s = self.time_s if self.time_s is not None else 0.0
                new = self.power
            if new != self.power and self._cause_present():
                new = self.power  # refused: the cause of the fault is still there
        if new != self.power and (self.power, new) in _UP and self.quirks.transition_delay_s > 0.0:
            pending = self._pending
            if pending is None or pending[0] != new:
                now = self.time_s if self.time_s is not None else 0.0
                self._pending = (new, now + self.quirks.transition_delay_s)
            new = self.power
        elif new != self.power:
            self._pending = None  # switching off or stopping: at once, whatever was under way
        if new != self.power:
            self._set_power(new)
        self.last_controlword = controlword

    def _set_power(self, new: PowerState) -> None:
        if self.power == PowerState.FAULT:
            self.error_code = EMCY_NO_ERROR
            self.fault_cause_until_s = None
            self._reset_high_since_s = None
            self.pending_emcy.append(EMCY_NO_ERROR)  # "error reset" EMCY
        if new == PowerState.OPERATION_ENABLED:
            # Enabling starts from where the carriage is: no jump.
            self.latched_target = self.previous_target = self.received_target = self.position
            self.velocity = 0.0
            self.target_step = 0.0
            self.target_step_valid = False
            if self.quirks.warning_emcy_code:
                self.warning = True
                self.pending_emcy.append(self.quirks.warning_emcy_code)
        elif self.power == PowerState.OPERATION_ENABLED:
            self.warning = False
        self.power = new

    def _cause_present(self) -> bool:
        """Whether the current fault's cause is still there (a reset is then refused)."""
        until = self.fault_cause_until_s
        if until is None:
            return False
        return until < 0.0 or self.time_s is None or self.time_s < until

    def _timed_changes(self, now_s: float) -> None:
        """What happens by itself with time: the boot's clock, a slow transition completing, a
        fault reset held long enough."""
        if self.booted_s is None:
            self.booted_s = now_s
            if self.fault_cause_until_s is not None and self.fault_cause_until_s < 0.0:
                self.fault_cause_until_s = now_s + self.quirks.power_stage_ready_s
        pending = self._pending
        if pending is not None and now_s >= pending[1]:
            self._pending = None
            if (self.power, pending[0]) in _UP:
                self._set_power(pending[0])
        since = self._reset_high_since_s
        if (
            since is not None
            and self.power == PowerState.FAULT
            and now_s - since >= self.quirks.fault_reset_hold_s
            and not self._cause_present()
        ):
            self._set_power(PowerState.SWITCH_ON_DISABLED)  # transition 15, after the hold

    def on_sync(self, now_s: float) -> None:
        self.advance(now_s, check_sync_timeout=False)
        if self.last_sync_s is not None:
            dt = now_s - self.last_sync_s
            if 0.0 < dt < 1.0:
                self.sync_period_s = dt
                self._check_sync_period(dt)
        self.last_sync_s = now_s
        if self.target_received or self.power != PowerState.OPERATION_ENABLED:
            # a new segment, from wherever the reference is (on a late SYNC, past the last target);
            # past its end the reference goes on at the commanded speed, the step between targets
            self.previous_target = self._reference(now_s)
            # the commanded step a period: the targets' difference over the time between their SYNCs
            # (after SYNCs without a target, or none for a while, it spans several periods)
            since = self.interp_start_s if self.target_step_valid else now_s
            periods = max(1.0, (now_s - since) / self.segment_period_s) if self.segment_period_s > 0 else 1.0
            self.target_step = (self.received_target - self.latched_target) / periods
            self.target_step_valid = self.power == PowerState.OPERATION_ENABLED
            self.latched_target = self.received_target
            self.interp_start_s = now_s
        # else no setpoint for this SYNC: the reference goes on past the last target, up to
        # extrapolation_periods (``_reference``), as when no SYNC comes at all
        self.target_received = False

    def _check_sync_period(self, interval_s: float) -> None:
        """EMCY 0x8700 once when the SYNC intervals' median is SYNC_PERIOD_MISMATCH_FACTOR times the
        configured period (0x1006, else 0x60C2) or more, or as many times less."""
        expected = self.communication_cycle_period_s or self.interpolation_period_s
        intervals = self.sync_intervals_s
        intervals.append(interval_s)
        if len(intervals) > SYNC_PERIOD_WINDOW:
            del intervals[0]
        if expected <= 0.0 or len(intervals) < SYNC_PERIOD_WINDOW:
            return
        median = sorted(intervals)[SYNC_PERIOD_WINDOW // 2]
        ratio = median / expected
        off = ratio >= SYNC_PERIOD_MISMATCH_FACTOR or ratio <= 1.0 / SYNC_PERIOD_MISMATCH_FACTOR
        if off and not self.sync_period_mismatch:
            self.pending_emcy.append(EMCY_SYNC_PERIOD)
        self.sync_period_mismatch = off

    def on_controller_heartbeat(self, now_s: float) -> None:
        self.last_heartbeat_s = now_s

    def statusword(self) -> int:
        sw = statusword_bits(self.power) | SW_REMOTE
        if self.power in (PowerState.SWITCHED_ON, PowerState.OPERATION_ENABLED, PowerState.QUICK_STOP_ACTIVE):
            sw |= SW_VOLTAGE_ENABLED
        if self.warning:
            sw |= SW_WARNING
        attained = SW_HOMING_ATTAINED if self.quirks.homing_attained_bit else 0
        if self.mode_of_operation == MODE_HOMING and self.power != PowerState.OPERATION_ENABLED:
            # not running a method: whether the drive is homed (what canopen's is_homed reads)
            if self.homed:
                sw |= SW_TARGET_REACHED | attained
        elif self.power == PowerState.OPERATION_ENABLED and self.mode_of_operation == MODE_HOMING:
            # CiA 402 homing: 10 reached (or interrupted), 12 attained, 13 error; none while moving
            run = self.homing
            phase = run.phase if run is not None else HomingPhase.IDLE
            if phase == HomingPhase.ATTAINED:
                sw |= SW_TARGET_REACHED | attained
            elif phase == HomingPhase.ERROR:
                sw |= SW_HOMING_ERROR
            elif phase == HomingPhase.IDLE:
                sw |= SW_TARGET_REACHED | (attained if self.homed else 0)
        elif self.power == PowerState.OPERATION_ENABLED:
            sw |= SW_FOLLOWING_COMMAND
            if abs(self.position - self.latched_target) * self.params.counts_per_unit < 10:
                sw |= SW_TARGET_REACHED
        return sw

    def position_counts(self) -> int:
        # quantised; the fault injection's error on top of the incremental encoder's offset
        return round(
            (self.position + self.encoder_offset + self.reported_position_error) * self.params.counts_per_unit
        )

    def on_nmt_stopped(self) -> None:
        """NMT STOPPED while enabled: an abort connection (0x6007)."""
        self.on_nmt_left_operational()

    def on_nmt_left_operational(self) -> None:
        """NMT PRE-OPERATIONAL or STOPPED while enabled: RPDOs no longer reach it, an abort connection."""
        self.abort_connection(EMCY_COMMUNICATION)

    def abort_connection(self, error_code: int) -> None:
        """The reaction 0x6007 asks for to a lost master, while enabled (nothing otherwise)."""
        if self.power != PowerState.OPERATION_ENABLED:
            return
        option = self.abort_connection_option
        if option == ABORT_FAULT:
            self.force_fault(error_code)
        elif option == ABORT_DISABLE_VOLTAGE:
            self.power = PowerState.SWITCH_ON_DISABLED
            self.pending_emcy.append(error_code)
        elif option == ABORT_QUICK_STOP:
            self._quick_stop(error_code)

    def reboot(self) -> None:
        """Power cycle of the drive's electronics: the power state machine starts again, the carriage
        stays; an incremental encoder has lost its home (an absolute one has not)."""
        self.power = PowerState.SWITCH_ON_DISABLED
        self.velocity = 0.0
        self.last_controlword = 0
        self.latched_target = self.previous_target = self.received_target = self.position
        self.target_step = 0.0
        self.target_step_valid = False
        self.extrapolation_periods = self.params.extrapolation_periods
        self.sync_timeout_s = self.params.sync_timeout_s
        self.error_code = EMCY_NO_ERROR
        self.fault_cause_until_s = None
        self.homing = None
        self._boot()

    def force_fault(self, error_code: int) -> None:
        if self.power != PowerState.FAULT:
            self.power = PowerState.FAULT
            self.error_code = error_code
            self.pending_emcy.append(error_code)

    # -- dynamics ---------------------------------------------------------------------------

    @property
    def segment_period_s(self) -> float:
        """The interpolation period: 0x60C2 when the master set it, else the measured SYNC interval."""
        return self.interpolation_period_s or self.sync_period_s

    def _reference(self, now_s: float) -> float:
        """The interpolator's position reference: from the previous target to the latched one over a
        period, then on past it by the last step between targets a period, for at most
        ``extrapolation_periods``; then it holds."""
        period = self.segment_period_s
        x = (now_s - self.interp_start_s) / period if period > 0 else 1.0
        if x <= 1.0:
            return self.previous_target + max(x, 0.0) * (self.latched_target - self.previous_target)
        return self.latched_target + (min(x, 1.0 + self.extrapolation_periods) - 1.0) * self.target_step

    def _watchdog(self, now_s: float, check_sync_timeout: bool) -> None:
        if self.power != PowerState.OPERATION_ENABLED:
            return
        # The simulator's frame handlers turn the check off: a long gap seen while handling a
        # frame means the frames waited in the simulator's socket while its process was not
        # scheduled, and a real drive would have had its SYNC on time. A SYNC that really
        # stopped is caught by the simulator's watchdog thread, which checks.
        if (
            check_sync_timeout
            and self.last_sync_s is not None
            and now_s - self.last_sync_s > self.sync_timeout_s
        ):
            self._quick_stop(EMCY_SYNC_LOST)
        elif (
            self.heartbeat_consumer_s > 0
            and self.last_heartbeat_s is not None
            and now_s - self.last_heartbeat_s > self.heartbeat_consumer_s
        ):
            self.abort_connection(EMCY_HEARTBEAT_LOST)

    def _quick_stop(self, error_code: int) -> None:
        self.power = PowerState.QUICK_STOP_ACTIVE
        self.pending_emcy.append(error_code)

    def _advance_homing(self, run: HomingRun, n: int, h: float, trace: list[float] | None) -> None:
        x, v, a = self.position, self.velocity, 0.0
        for _ in range(n):
            if run.moving:
                v0 = v
                x, v = run.step(x, v, h)
                a = (v - v0) / h
            else:
                v = a = 0.0  # attained or failed: the drive holds where it stopped
            if trace is not None:
                trace.append(x)
                trace.append(a)
        self.position, self.velocity, self.acceleration = x, v, a
        self._homing_result()

    def advance(
        self,
        now_s: float,
        check_sync_timeout: bool = True,
        substeps: int = 0,
        trace: list[float] | None = None,
    ) -> None:
        """Integrate the carriage up to ``now_s`` in equal sub-steps, checking the watchdogs first.

        ``substeps`` (0: as many as ``params.substep_s`` needs) lets the plant step drives and
        structure on one grid; ``trace`` receives position and acceleration after each sub-step.
        """
        if self.time_s is None:
            self.time_s = now_s
            self._timed_changes(now_s)
            return
        self._timed_changes(now_s)
        self._watchdog(now_s, check_sync_timeout)
        span = now_s - self.time_s
        if span <= 0.0:
            return
        p = self.params
        n = substeps or max(1, math.ceil(span / p.substep_s - 1e-9))
        h = span / n
        t = self.time_s
        x, v, a = self.position, self.velocity, self.acceleration
        vmax = p.max_velocity
        if self.power == PowerState.OPERATION_ENABLED and self.homing is not None and self.homing.moving:
            self._advance_homing(self.homing, n, h, trace)
            self.time_s = now_s
            return
        enabled = (
            self.power == PowerState.OPERATION_ENABLED and self.mode_of_operation == MODE_CYCLIC_SYNC_POSITION
        )
        stopping = self.power in (
            PowerState.QUICK_STOP_ACTIVE,
            PowerState.FAULT_REACTION_ACTIVE,
            PowerState.FAULT,
        )
        if enabled:
            wn = 2.0 * math.pi * p.bandwidth_hz
            wn2, c = wn * wn, 2.0 * p.damping_ratio * wn
            amax = p.max_acceleration
            period = self.segment_period_s
            x0, dx, x1, step = (
                self.previous_target,
                self.latched_target - self.previous_target,
                self.latched_target,
                self.target_step,
            )
            v_ff = p.velocity_feedforward * dx / period if period > 0 else 0.0
            v_on = p.velocity_feedforward * step / period if period > 0 else 0.0
            t0, x_end = self.interp_start_s, 1.0 + self.extrapolation_periods
        moving = not self.blocked  # a stuck carriage (fault injection) holds whatever the drive does
        for _ in range(n):
            if enabled and moving:
                # the reference at the start of the sub-step (``_reference``, inlined: this is
                # the simulator's inner loop)
                r = (t - t0) / period if period > 0 else 1.0
                if 0.0 <= r <= 1.0:
                    ref, vr = x0 + r * dx, v_ff
                elif 1.0 < r <= x_end:  # extrapolated: on past the target at the commanded speed
                    ref, vr = x1 + (r - 1.0) * step, v_on
                else:  # before the segment or past its extrapolation: the reference holds, still
                    ref, vr = (x0, 0.0) if r < 0.0 else (x1 + (x_end - 1.0) * step, 0.0)
                # A held reference stands still, as a real interpolator's: fed the segment's speed
                # forward, the carriage settled 2 zeta v / wn past it (0.48 mm at 0.1 m/s).
                acc = wn2 * (ref - x) + c * (vr - v)
                acc = amax if acc > amax else (-amax if acc < -amax else acc)  # no call: inner loop
            elif stopping and moving:
                if abs(v) <= p.quick_stop_deceleration * h:
                    v, acc = 0.0, 0.0
                else:
                    acc = -math.copysign(p.quick_stop_deceleration, v)
            else:
                # Not enabled, enabled in a mode this drive does not run (the brake holds), or stuck.
                v = a = 0.0
                t += h
                if trace is not None:
                    trace.append(x)
                    trace.append(0.0)
                continue
            # Semi-implicit Euler: stable for wn * h << 1 (60 Hz, 0.5 ms: 0.19).
            v0 = v
            v = v + acc * h
            v = vmax if v > vmax else (-vmax if v < -vmax else v)  # no call: inner loop
            a = (v - v0) / h
            x += v * h
            t += h
            if not p.stroke_min <= x <= p.stroke_max:
                x = min(max(x, p.stroke_min), p.stroke_max)
                v = a = 0.0
                self.position, self.velocity, self.acceleration = x, v, a
                self.force_fault(EMCY_POSITION_RANGE)
                enabled, stopping = False, True
            if trace is not None:
                trace.append(x)
                trace.append(a)
        self.position, self.velocity, self.acceleration = x, v, a
        self.time_s = now_s
        if enabled:
            self._monitor_following_error(now_s, abs(self._reference(now_s) - x))

    def _monitor_following_error(self, now_s: float, error: float) -> None:
        """CiA 402 following error: beyond the window (0x6065) for longer than the time (0x6066)."""
        if self.following_error_window <= 0.0 or error <= self.following_error_window:
            self._following_error_since_s = None
        elif self._following_error_since_s is None:
            self._following_error_since_s = now_s
        elif now_s - self._following_error_since_s >= self.following_error_time_s:
            self._following_error_since_s = None
            self.force_fault(EMCY_FOLLOWING_ERROR)
