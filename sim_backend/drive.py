"""A simulated CiA 402 drive for a linear (or rotary) actuator, cyclic synchronous position.

Behaviour, as a real CSP drive:
- the power state machine of CiA 402 driven by the controlword (``drivers.cia402``);
- on SYNC it latches the last received target and reports the position sampled at the
  SYNC; between SYNCs its position reference is interpolated linearly from the previous to
  the new target over one SYNC period (the drive's interpolator);
- a second-order position loop (natural frequency ``bandwidth_hz``, damping ratio) with
  velocity feed-forward from the interpolator (a fraction ``velocity_feedforward``, 1.0 as
  CSP drives are usually tuned) and velocity and acceleration saturation, integrated in
  sub-steps of ``substep_s``;
- end stops at the stroke limits (the carriage stops there and the drive faults, 0x7320
  "position sensor / range" EMCY);
- quick stop on the quick-stop deceleration, then stays in QUICK STOP ACTIVE (option 6);
- a watchdog: no SYNC for ``sync_timeout_s`` or no controller heartbeat for the consumer
  time while enabled -> quick stop and an EMCY (0x8130 heartbeat / 0x8240 sync lost).

Time is an argument everywhere (``advance(now_s)``); the process shell reads the clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drivers.cia402 import (
    MODE_CYCLIC_SYNC_POSITION,
    SW_FOLLOWING_COMMAND,
    SW_REMOTE,
    SW_TARGET_REACHED,
    SW_VOLTAGE_ENABLED,
    PowerState,
    device_transition,
    statusword_bits,
)

EMCY_NO_ERROR = 0x0000
EMCY_POSITION_RANGE = 0x7320
EMCY_HEARTBEAT_LOST = 0x8130
EMCY_SYNC_LOST = 0x8240
EMCY_FORCED_FAULT = 0x5000  # device hardware, used by fault injection


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


@dataclass
class SimulatedDrive:
    """Mutable device state; owned by one thread of the simulator process."""

    params: DriveParams
    position: float
    velocity: float = 0.0
    acceleration: float = 0.0  # of the last sub-step, for the structure's inertial load (plant.py)
    power: PowerState = PowerState.SWITCH_ON_DISABLED
    mode_of_operation: int = 0
    last_controlword: int = 0
    received_target: float = field(init=False)
    latched_target: float = field(init=False)
    previous_target: float = field(init=False)
    interp_start_s: float = 0.0
    sync_period_s: float = 0.0025
    last_sync_s: float | None = None
    last_heartbeat_s: float | None = None
    time_s: float | None = None
    heartbeat_consumer_s: float = 0.0  # object 0x1016; 0 disables the heartbeat watchdog
    pending_emcy: list[int] = field(default_factory=list)
    error_code: int = EMCY_NO_ERROR

    def __post_init__(self) -> None:
        self.received_target = self.position
        self.latched_target = self.position
        self.previous_target = self.position

    # -- protocol ---------------------------------------------------------------------------

    def on_rpdo(self, controlword: int, target_counts: int) -> None:
        self.received_target = target_counts / self.params.counts_per_unit
        self.on_controlword(controlword)

    def on_controlword(self, controlword: int) -> None:
        new = device_transition(self.power, controlword, self.last_controlword)
        if new != self.power:
            if self.power == PowerState.FAULT:
                self.error_code = EMCY_NO_ERROR
                self.pending_emcy.append(EMCY_NO_ERROR)  # "error reset" EMCY
            if new == PowerState.OPERATION_ENABLED:
                # Enabling starts from where the carriage is: no jump.
                self.latched_target = self.previous_target = self.received_target = self.position
                self.velocity = 0.0
            self.power = new
        self.last_controlword = controlword

    def on_sync(self, now_s: float) -> None:
        self.advance(now_s, check_sync_timeout=False)
        if self.last_sync_s is not None:
            dt = now_s - self.last_sync_s
            if 0.0 < dt < 1.0:
                self.sync_period_s = dt
        self.last_sync_s = now_s
        self.previous_target = self._reference(now_s)
        self.latched_target = self.received_target
        self.interp_start_s = now_s

    def on_controller_heartbeat(self, now_s: float) -> None:
        self.last_heartbeat_s = now_s

    def statusword(self) -> int:
        sw = statusword_bits(self.power) | SW_REMOTE
        if self.power in (PowerState.SWITCHED_ON, PowerState.OPERATION_ENABLED, PowerState.QUICK_STOP_ACTIVE):
            sw |= SW_VOLTAGE_ENABLED
        if self.power == PowerState.OPERATION_ENABLED:
            sw |= SW_FOLLOWING_COMMAND
            if abs(self.position - self.latched_target) * self.params.counts_per_unit < 10:
                sw |= SW_TARGET_REACHED
        return sw

    def position_counts(self) -> int:
        return round(self.position * self.params.counts_per_unit)  # encoder quantisation

    def force_fault(self, error_code: int) -> None:
        if self.power != PowerState.FAULT:
            self.power = PowerState.FAULT
            self.error_code = error_code
            self.pending_emcy.append(error_code)

    # -- dynamics ---------------------------------------------------------------------------

    def _reference(self, now_s: float) -> float:
        x = (now_s - self.interp_start_s) / self.sync_period_s if self.sync_period_s > 0 else 1.0
        x = min(max(x, 0.0), 1.0)
        return self.previous_target + x * (self.latched_target - self.previous_target)

    def _watchdog(self, now_s: float, check_sync_timeout: bool) -> None:
        if self.power != PowerState.OPERATION_ENABLED:
            return
        p = self.params
        # The simulator's frame handlers turn the check off: a long gap seen while handling a
        # frame means the frames waited in the simulator's socket while its process was not
        # scheduled, and a real drive would have had its SYNC on time. A SYNC that really
        # stopped is caught by the simulator's watchdog thread, which checks.
        if check_sync_timeout and self.last_sync_s is not None and now_s - self.last_sync_s > p.sync_timeout_s:
            self._quick_stop(EMCY_SYNC_LOST)
        elif (self.heartbeat_consumer_s > 0 and self.last_heartbeat_s is not None
              and now_s - self.last_heartbeat_s > self.heartbeat_consumer_s):
            self._quick_stop(EMCY_HEARTBEAT_LOST)

    def _quick_stop(self, error_code: int) -> None:
        self.power = PowerState.QUICK_STOP_ACTIVE
        self.pending_emcy.append(error_code)

    def advance(self, now_s: float, check_sync_timeout: bool = True) -> None:
        """Integrate the carriage up to ``now_s`` in sub-steps, checking the watchdogs first."""
        if self.time_s is None:
            self.time_s = now_s
            return
        self._watchdog(now_s, check_sync_timeout)
        h = self.params.substep_s
        while self.time_s < now_s:
            dt = min(h, now_s - self.time_s)
            self._substep(self.time_s, dt)  # reference at the start of the sub-step
            self.time_s += dt

    def _substep(self, t: float, dt: float) -> None:
        p = self.params
        if self.power == PowerState.OPERATION_ENABLED and self.mode_of_operation == MODE_CYCLIC_SYNC_POSITION:
            wn = 2.0 * math.pi * p.bandwidth_hz
            ref = self._reference(t)
            v_ref = p.velocity_feedforward * (self.latched_target - self.previous_target) / self.sync_period_s
            acc = wn * wn * (ref - self.position) + 2.0 * p.damping_ratio * wn * (v_ref - self.velocity)
            acc = max(-p.max_acceleration, min(p.max_acceleration, acc))
        elif self.power in (PowerState.QUICK_STOP_ACTIVE, PowerState.FAULT_REACTION_ACTIVE, PowerState.FAULT):
            if abs(self.velocity) <= p.quick_stop_deceleration * dt:
                self.velocity = 0.0
                acc = 0.0
            else:
                acc = -math.copysign(p.quick_stop_deceleration, self.velocity)
        else:
            # Not enabled, or enabled in a mode this drive does not run: the brake holds.
            self.velocity = 0.0
            self.acceleration = 0.0
            return
        # Semi-implicit Euler: stable for wn * dt << 1 (60 Hz, 0.25 ms: 0.09).
        v0 = self.velocity
        self.velocity = max(-p.max_velocity, min(p.max_velocity, self.velocity + acc * dt))
        self.acceleration = (self.velocity - v0) / dt if dt > 0 else 0.0
        self.position += self.velocity * dt
        if not p.stroke_min <= self.position <= p.stroke_max:
            self.position = min(max(self.position, p.stroke_min), p.stroke_max)
            self.velocity = 0.0
            self.acceleration = 0.0
            self.force_fault(EMCY_POSITION_RANGE)
