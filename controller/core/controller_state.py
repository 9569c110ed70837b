"""The controller's state between two steps, and its modes: what the pure step passes to itself.

Its own module because everything around the law reads it (the cycle observers' ports, the
recorder, the keyframe of a rotated file, the tools) while only the law writes it; the law's
module (``control_law.py``) says how each field changes.
"""

from __future__ import annotations

import math
from enum import IntEnum

from controller.core.contact_guard import BackOff, ContactWatch
from controller.core.records import record
from controller.core.setpoint_smoothing import Setpoint


class Mode(IntEnum):
    CONFIGURING = 0
    ENABLING = 1
    HOLDING = 2
    RUNNING = 3
    PAUSED = 4
    STOPPING = 5
    DONE = 6
    FAULT = 7
    BACKING_OFF = 8  # the contact guard's protective stop: away from the force, then FAULT


@record
class FaultResetProgress:
    """One drive's fault reset in ENABLING (control_law ``_fault_reset``): attempts made, and since
    when bit 7 has been held high (``holding``) or low again (waiting for the statusword)."""

    attempts: int = 0
    holding: bool = False
    since_s: float = -math.inf


@record
class ControllerState:
    mode: Mode
    cycle: int
    mode_entered_s: float
    setpoint: Setpoint
    controlwords: tuple[int, ...]
    missing_streak: tuple[int, ...]
    task_state: object
    tcp_reference_m: tuple[float, float, float] | None  # path point for the next SYNC; None off the path
    tcp_measured_m: tuple[float, float, float] | None  # direct kinematics of the measured positions
    task_time_s: float = 0.0
    step_t_s: float = -math.inf  # the last step's time (the loop's deadline k * period)
    # The loop was held up long enough before this step that the drives ran out of extrapolation
    # and stand (``LawConfig.drive_extrapolation_periods``): a brake or a reactive reference
    # restarts from rest there (control_law ``_smoothing_start``).
    drives_held: bool = False
    # Periods the drives ran on past the last setpoint during a hold-up before this step, blind
    # (control_law ``_after_hold_up``): the task's time and the setpoint move on as far; -1 when
    # they stood through the whole period, out of extrapolation, and the task and setpoint wait.
    drives_ran_on: int = 0
    # Periods the drives will be past the end of their last target's segment when this step's
    # target comes: 0 but after a hold-up (control_law ``hold_up_effect``).
    drives_blind_periods: int = 0
    fault_reason: str = ""
    sensor_counter: int = -1  # last sensor counter seen, for staleness
    sensor_stale: int = 0  # cycles the counter has not advanced
    sensor_missing: int = 0  # cycles in a row without a usable sample (missing or ambiguous)
    # Of each drive's (and the sensor's) silence in a row, the cycles in which some other device was
    # heard: its own. The rest every device shared (the bus or the simulator paused), which is judged
    # on loop.max_bus_silence_s instead of loop.max_missing_s (SafetyMonitor.silent_too_long).
    missing_alone: tuple[int, ...] = ()
    sensor_missing_alone: int = 0
    late_streak: int = 0  # consecutive late cycles
    warned: frozenset[str] = frozenset()  # warnings already raised in the current episode
    # Each drive's last trusted position: fresh and within its physics. The plausibility check's
    # reference, and the only source of hold and stop targets (never a flagged frame).
    last_measured: tuple[float, ...] = ()
    # Anomaly bursts under "warn": (key, frames, cycles with it, cycle of the last report)
    bursts: tuple[tuple[str, int, int, int], ...] = ()
    # Drives (indices) that may not process RPDOs: reported not OPERATIONAL, or the target of a
    # foreign NMT command, or heartbeat lost. In FAULT they get the quick stop by SDO as well.
    unreachable: frozenset[int] = frozenset()
    sdo_stopped: frozenset[int] = frozenset()  # drives already sent the quick stop by SDO in this fault
    # A second sender on the force sensor's COB-ID during the task (what it was, and the cycle): its
    # frames are withheld from the task, which retracts; the fault follows (_sensor_breach).
    sensor_breach: str = ""
    sensor_breach_cycle: int = 0
    # Each drive's fault reset under way in ENABLING (empty: none yet), and its last error code as
    # its EMCYs said (CiA 301: the code it also holds in 0x603F; 0 after an "error reset" EMCY).
    fault_resets: tuple[FaultResetProgress, ...] = ()
    error_codes: tuple[int, ...] = ()
    # A bus-off faulted the run at this cycle (0: none): FAULT re-checks the drives when the bus
    # is back and says so once (control_law ``_after_bus_off``).
    bus_off_cycle: int = 0
    contact: ContactWatch = ContactWatch()  # the contact guard's watch (contact_guard.py)
    back_off: BackOff | None = None  # the protective back-off in progress (BACKING_OFF)
    protective_cause: str = ""  # a fault this cycle that backs off instead (the sensor's troubles)
