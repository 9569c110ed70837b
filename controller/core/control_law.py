"""The pure control step: ``step(state, inputs, t) -> (state, outputs, events)``.

One call per cycle. ``t`` is the cycle's nominal time [s] (cycle index times period), never
a clock reading, so a recorded session replays bit for bit. The setpoint computed at ``t``
is sent at the next deadline, latched by the drives on that cycle's SYNC, and reached by
the drives' interpolators one period later: it is the setpoint for ``t + 2 * period``
(``PIPELINE_PERIODS``).

Supervisor modes (see ``Mode``)::

    CONFIGURING -> ENABLING -> HOLDING -> RUNNING <-> PAUSED
                                             |          |
                                             v          v
                                            STOPPING -> DONE          (any mode) -> FAULT

    HOLDING, RUNNING, PAUSED, STOPPING -> BACKING_OFF -> FAULT        (the contact guard)

CONFIGURING waits for every drive's first TPDO (the loop shell has done NMT and SDO set-up
before the first cycle; an EMCY, a bus-off or a drive not heard within ``enable_timeout_s``
faults here too), ENABLING walks each drive's CiA 402 power state machine to
OPERATION ENABLED while commanding its measured position (no jump at enable), HOLDING keeps
the position for ``hold_before_task_s``, RUNNING streams the task through Ruckig, PAUSED
brakes and holds with the task clock stopped (remote ``pause``/``resume``), STOPPING brakes
within the limits and then shuts the drives down, FAULT quick-stops them. BACKING_OFF is the
contact guard's protective stop (``contact_guard.py``): a contact force beyond what the task's
reference expects moves the tool away along the force, at a bounded speed, then the law faults
naming the cause; a force is never answered by a stop in place.

The task runs on its own clock, ``task_time_s``, which advances one period per RUNNING
cycle: a pause does not make a path jump ahead when it resumes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    FaultResetConfig,
    PowerState,
    controlword_towards,
    decode_statusword,
)
from controller.core.contact_guard import (
    ContactGuardConfig,
    Witness,
    advance_back_off,
    back_off_summary,
    begin_back_off,
)
from controller.core.contact_guard import (
    watch as watch_contact,
)
from controller.core.controller_state import ControllerState, FaultResetProgress, Mode
from controller.core.cycle_data import (
    SENSOR_FORCE_SATURATED,
    Anomaly,
    BusAnomaly,
    Command,
    CycleInputs,
    CycleOutputs,
    EmcyAction,
    Event,
    Reaction,
    Severity,
)
from controller.core.linalg3 import norm3, sub3
from controller.core.ports import ContactExpectation, ForceWitnessModel, PoseStatus, Robot, Task, TaskContext
from controller.core.records import replace
from controller.core.setpoint_smoothing import RuckigSmoother, Setpoint
from controller.errors import NoSolutionError

PIPELINE_PERIODS = 2
# A reactive reference's position error decays with a time constant of 1/0.25 = 4 periods.
REACTIVE_CORRECTION_PERIODS = 0.25


@runtime_checkable
class ChecksActuators(Protocol):
    """A robot that knows its actuators' strokes (all three robots in controller/robots)."""

    def check_actuators(self, q: tuple[float, ...]) -> PoseStatus: ...


@dataclass(frozen=True)
class SafetyConfig:
    """Reactions to abnormal inputs ("fault", "warn" or "ignore"); see config.SafetySection."""

    max_contact_force_n: float = 60.0
    sensor_stale_cycles: int = 20
    on_sensor_stale: Reaction = Reaction.FAULT
    on_sensor_saturated: Reaction = Reaction.FAULT
    on_heartbeat_lost: Reaction = Reaction.FAULT
    on_error_frames: Reaction = Reaction.WARN
    max_consecutive_late_cycles: int = 50
    on_late_cycles: Reaction = Reaction.FAULT
    # Position plausibility [actuator unit]: a measured step beyond what the speed limit allows plus
    # this is a jump; a measured position this far from the commanded one is a following error.
    max_position_jump: float = math.inf
    following_window: float = math.inf
    on_unknown_node: Reaction = Reaction.WARN
    on_foreign_sync: Reaction = Reaction.FAULT
    on_foreign_nmt: Reaction = Reaction.FAULT
    on_foreign_command: Reaction = Reaction.FAULT
    on_duplicate_frames: Reaction = Reaction.FAULT
    on_rejected_frames: Reaction = Reaction.WARN
    on_frame_flood: Reaction = Reaction.FAULT
    sensor_breach_retract_s: float = 0.0  # see config.SafetySection; 0: fault at once
    contact: ContactGuardConfig = ContactGuardConfig()  # the contact guard ([safety.contact])

    def reaction_to(self, anomaly: Anomaly) -> Reaction:
        return {
            Anomaly.REJECTED_FRAME: self.on_rejected_frames,
            # beyond the device's physics, among several candidates: the law's jump check always faults too
            Anomaly.IMPLAUSIBLE_FRAME: Reaction.FAULT,
            Anomaly.UNKNOWN_FRAME: self.on_unknown_node,
            Anomaly.UNKNOWN_EMCY: self.on_unknown_node,
            Anomaly.UNKNOWN_HEARTBEAT: self.on_unknown_node,
            Anomaly.FOREIGN_SYNC: self.on_foreign_sync,
            Anomaly.FOREIGN_NMT: self.on_foreign_nmt,
            Anomaly.FOREIGN_COMMAND: self.on_foreign_command,
            Anomaly.DUPLICATE_FRAME: self.on_duplicate_frames,
            Anomaly.FRAME_FLOOD: self.on_frame_flood,
        }[anomaly]


ANOMALY_TEXT = {
    Anomaly.UNKNOWN_FRAME: "frame(s) from a COB-ID no configured node uses",
    Anomaly.UNKNOWN_EMCY: "EMCY from a node that is not configured",
    Anomaly.UNKNOWN_HEARTBEAT: "heartbeat from a node that is not configured",
    Anomaly.FOREIGN_SYNC: "SYNC the controller did not send (a second SYNC producer)",
    Anomaly.FOREIGN_NMT: "NMT command the controller did not send",
    Anomaly.FOREIGN_COMMAND: "frame on a COB-ID only the controller sends (a second master)",
    Anomaly.DUPLICATE_FRAME: "TPDO(s) twice in one cycle (a second sender; neither is used)",
    Anomaly.REJECTED_FRAME: "frame(s) of the wrong length (rejected)",
    Anomaly.IMPLAUSIBLE_FRAME: "TPDO(s) the device cannot have sent (a position step or counter beyond it; not used)",
    Anomaly.FRAME_FLOOD: "foreign frames in one cycle: a frame flood",
}
NMT_COMMAND_NAMES = {
    0x01: "start",
    0x02: "stop",
    0x80: "enter PRE-OPERATIONAL",
    0x81: "reset node",
    0x82: "reset communication",
}  # CiA 301 NMT command specifiers
# The modes in which the contact guard watches (the drives enabled, the law commanding them).
GUARDED_MODES = frozenset((Mode.HOLDING, Mode.RUNNING, Mode.PAUSED, Mode.STOPPING, Mode.BACKING_OFF))
# The drives' efforts sampled at a SYNC show their motion towards the setpoint this many steps old
# (the pipeline: computed, sent at the next deadline, latched, interpolated over the period after):
# the witness adds back the inertia of that setpoint's acceleration (measured: lags 2-4 fit best).
WITNESS_ACCELERATION_LAG = 3
# The force sensor's troubles: with the drives enabled, their fault is a protective back-off.
SENSOR_TROUBLE = frozenset(("sensor_stale", "sensor_saturated"))
# A back-off that meets this much more force than it started from makes things worse: the quick stop.
BACK_OFF_WORSE_N = 10.0
# ... judged after this many cycles: the setpoints already on their way (PIPELINE_PERIODS) and the
# structure's momentum carry the tool on for a few cycles whatever the back-off commands
BACK_OFF_GRACE_CYCLES = 16
# A burst of anomalies under "warn": one event when it starts, one with its count when it ends
# (the first cycle without it), and one with the running count this often while it goes on.
BURST_REPORT_S = 1.0


def anomaly_text(a: BusAnomaly) -> str:
    """One line for a cycle's anomaly: how many, what, from or to which node, on which COB-ID."""
    if a.kind == Anomaly.FOREIGN_NMT:
        command = NMT_COMMAND_NAMES.get(a.command, f"command 0x{a.command:02X}")
        target = f"node {a.node_id}" if a.node_id else "all nodes"
        times = f" ({a.count} times)" if a.count > 1 else ""
        return f"NMT {command} to {target} from another master{times}"
    return f"{a.count} {ANOMALY_TEXT[a.kind]}{_from_node(a.node_id)} (COB-ID 0x{a.cob_id:03X})"


def _from_node(node_id: int) -> str:
    return f" from node {node_id}" if node_id else ""


def listed(names: list[str]) -> str:
    """ "2", "1 and 2", "1, 2, 3 and the force sensor"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


NMT_STATE_NAMES = {0: "boot-up (it restarted)", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}


@dataclass(frozen=True)
class EmcyReaction:
    """EMCY error codes ``first``..``last`` of the drives get ``action`` (config ``actuators.emcy_reactions``)."""

    first: int
    last: int
    action: EmcyAction


def error_code_text(code: int) -> str:
    """ ", error code 0x3220" (the drive's last EMCY: CiA 301, the code 0x603F holds too), or ""."""
    return f", error code 0x{code:04X}" if code else ""


@dataclass(frozen=True)
class LawConfig:
    period_s: float
    enable_timeout_s: float
    hold_before_task_s: float
    max_missing_cycles: int
    settle_tolerance: float  # [actuator unit] and [unit/s]: "at rest" for the stop
    safety: SafetyConfig = SafetyConfig()
    max_speed: float = math.inf  # [unit/s] the actuators' speed limit, for the plausibility check
    position_unit: str = "m"  # for messages
    rest_target: float = 0.0  # [unit] the target sent before a drive's first TPDO (mid-stroke)
    drive_node_ids: tuple[int, ...] = ()  # CANopen node ids of the drives, in order (empty: 1..n)
    # Does the task use the force sensor's samples? If it does, a sensor without a usable sample for
    # safety.sensor_stale_cycles faults; if not, a stall of its frames is no hazard and the sensor is
    # supervised by its heartbeat (loop.heartbeat_consumer_s), as any node the task does not read.
    # Its samples, when they come, are still judged against the contact-force limit. From the
    # task's entry (controller/tasks/registry.py ``uses_force_sensor``).
    sensor_in_task: bool = True
    sensor_node_id: int = 0  # the force sensor's CANopen node id (0: none), for a breach of its frames
    # The task retracts without force data when the sensor's frames are no longer trusted
    # (TaskEntry.retracts_on_sensor_breach); with safety.sensor_breach_retract_s > 0 the law lets it.
    task_retracts_on_sensor_breach: bool = False
    fault_resets: tuple[FaultResetConfig, ...] = ()  # per drive; empty: FaultResetConfig() for each
    emcy_reactions: tuple[EmcyReaction, ...] = ()  # the drives' EMCY codes that do not fault (first match)

    def fault_reset(self, j: int) -> FaultResetConfig:
        return self.fault_resets[j] if j < len(self.fault_resets) else FaultResetConfig()

    def emcy_action(self, node_id: int, code: int) -> EmcyAction:
        """A drive's EMCY ``code`` by the configured reactions; any other node's, or a code not listed: fault."""
        if node_id in self.drive_node_ids:
            for r in self.emcy_reactions:
                if r.first <= code <= r.last:
                    return r.action
        return EmcyAction.FAULT


# One handler per mode: (state, inputs, power states, measured positions, t, events) -> state.
ModeHandler = Callable[
    [ControllerState, CycleInputs, tuple[PowerState, ...], tuple[float, ...], float, list[Event]],
    ControllerState,
]


class ControlLaw:
    """Composes supervisor, CiA 402 power management, task and smoothing into ``step``."""

    def __init__(self, robot: Robot, task: Task[Any], smoother: RuckigSmoother, config: LawConfig) -> None:
        self.robot = robot
        self.task = task
        self.smoother = smoother
        self.config = config
        self.n = robot.n_actuators
        # Robots that know their actuators' strokes check the measured positions every cycle.
        self._check_actuators = robot.check_actuators if isinstance(robot, ChecksActuators) else None
        # Robots that tell the contact force from their drives' efforts give the sensor its second witness.
        self._witness_model: ForceWitnessModel | None = (
            robot if callable(getattr(robot, "contact_force_from_efforts", None)) else None  # type: ignore[assignment]
        )
        self._handlers: dict[Mode, ModeHandler] = {
            Mode.CONFIGURING: self._configuring,
            Mode.ENABLING: self._enabling,
            Mode.HOLDING: self._holding,
            Mode.RUNNING: self._running,
            Mode.PAUSED: self._paused,
            Mode.STOPPING: self._stopping,
            Mode.DONE: self._done,
            Mode.FAULT: self._fault,
            Mode.BACKING_OFF: self._backing_off,
        }

    def initial_state(self) -> ControllerState:
        rest = (self.config.rest_target,) * self.n
        return ControllerState(
            mode=Mode.CONFIGURING,
            cycle=0,
            mode_entered_s=0.0,
            setpoint=Setpoint.at_rest(rest),
            controlwords=(0,) * self.n,
            missing_streak=(0,) * self.n,
            task_state=None,
            tcp_reference_m=None,
            tcp_measured_m=None,
            last_measured=(math.nan,) * self.n,
        )

    # -- the step -------------------------------------------------------------------------

    def step(
        self, state: ControllerState, inputs: CycleInputs, t: float
    ) -> tuple[ControllerState, CycleOutputs, tuple[Event, ...]]:
        events: list[Event] = []
        measured = tuple(d.position for d in inputs.drives)
        powers = tuple(decode_statusword(d.statusword) for d in inputs.drives)
        jump, implausible = self._position_jump(state, inputs)
        streak = tuple(
            0 if d.fresh else s + 1 for d, s in zip(inputs.drives, state.missing_streak, strict=True)
        )
        last = tuple(
            d.position if d.fresh and not bad else x
            for d, x, bad in zip(inputs.drives, state.last_measured, implausible, strict=True)
        )
        state = replace(
            state,
            cycle=state.cycle + 1,
            missing_streak=streak,
            last_measured=last,
            tcp_measured_m=self._measured_tcp(state, inputs, measured),
            unreachable=state.unreachable | self._unreachable(inputs),
        )
        if inputs.emcy:
            state = self._note_error_codes(state, inputs)
        emcy_fault = self._emcy_fault(inputs)

        if state.mode == Mode.CONFIGURING:
            reason = self._configuring_fault(state, inputs, emcy_fault)
            if reason:
                state = self._enter(state, Mode.FAULT, t, events, Severity.FAULT, reason)
                state = replace(state, fault_reason=reason)
        elif state.mode == Mode.DONE and not all(math.isfinite(x) for x in state.last_measured):
            # Stopped before every drive had answered (CONFIGURING -> DONE): nothing was enabled,
            # the controlwords say disable voltage, and a never-heard position is no measurement.
            pass
        elif state.mode != Mode.FAULT:
            state = self._supervise(state, inputs, powers, jump, emcy_fault, t, events)
        elif state.mode == Mode.FAULT and inputs.command == Command.RESET:
            state = self._reset(state, t, events)
        if state.mode in GUARDED_MODES:
            state = self._guard_contact(state, inputs, t, events)
        if inputs.command == Command.QUICK_STOP and state.mode not in (Mode.FAULT, Mode.DONE):
            why = "quick stop requested"
            state = self._faulted(state, why, t, events)
        elif inputs.stop_requested and state.mode == Mode.CONFIGURING:
            # nothing has been enabled yet: there is nothing to brake or to shut down
            state = self._enter(state, Mode.DONE, t, events, Severity.INFO, "stop requested before enabling")
        elif inputs.stop_requested and state.mode in (Mode.ENABLING, Mode.HOLDING, Mode.RUNNING, Mode.PAUSED):
            state = self._enter(state, Mode.STOPPING, t, events, Severity.INFO, "stop requested")
        elif inputs.command == Command.PAUSE and state.mode == Mode.RUNNING:
            state = self._enter(state, Mode.PAUSED, t, events, why="remote pause")
        elif inputs.command == Command.RESUME and state.mode == Mode.PAUSED:
            state = self._enter(state, Mode.RUNNING, t, events, why="remote resume")

        if inputs.bus_off and state.mode == Mode.FAULT:
            state = replace(state, bus_off_cycle=state.cycle)  # re-check the drives once the bus is back
        state = self._handlers[state.mode](state, inputs, powers, measured, t, events)
        state, by_sdo = self._quick_stops_by_sdo(state, events)
        outputs = CycleOutputs(
            controlwords=state.controlwords,
            targets=state.setpoint.position,
            sdo_controlwords=tuple((j, CW_QUICK_STOP) for j in by_sdo),
        )
        return state, outputs, tuple(events)

    def _supervise(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        jump: str,
        emcy_fault: str,
        t: float,
        events: list[Event],
    ) -> ControllerState:
        """Every mode but FAULT: the safety layer's limits, the drives' faults and EMCYs."""
        state, reason = self._safety(state, inputs, events)
        if reason and reason == state.protective_cause and state.mode in GUARDED_MODES:
            # The force sensor gone stale or saturated with the drives enabled: the tool may be
            # pressing on something with a force nobody reads; back off along the drives' effort
            # witness (or brake in place without one), never a quick stop in contact. Backing off
            # already, it goes on.
            if state.mode != Mode.BACKING_OFF:
                state = self._begin_back_off(state, reason, t, events)
            reason = ""
        reason = reason or jump or self._fault_reason(state, inputs, powers, emcy_fault)
        if reason:
            state = self._faulted(state, reason, t, events)
        elif inputs.emcy:
            state = self._emcy_notes(state, inputs, t, events)
        return state

    def _reset(self, state: ControllerState, t: float, events: list[Event]) -> ControllerState:
        """The operator's reset in FAULT."""
        # Recovery without a jump: ENABLING resets the drives' faults and commands the
        # measured positions; HOLDING restarts Ruckig from rest there; the task starts again.
        return replace(
            self._enter(state, Mode.ENABLING, t, events, why="reset"),
            fault_reason="",
            setpoint=self._hold(state),
            task_time_s=0.0,
            sensor_stale=0,
            sensor_missing=0,
            late_streak=0,
            warned=frozenset(),
            unreachable=frozenset(),
            sdo_stopped=frozenset(),
            sensor_breach="",
            fault_resets=(FaultResetProgress(),) * self.n,  # this ENABLING resets the drives' faults
            bus_off_cycle=0,
            contact=replace(
                state.contact, expectation=ContactExpectation.NONE, suspect="", disagreeing=0, agreeing=0
            ),
            back_off=None,
        )

    def _faulted(
        self, state: ControllerState, why: str, t: float, events: list[Event], **fields: Any
    ) -> ControllerState:
        """FAULT now, named ``why``, the setpoint held where it is (the quick stop's controlwords
        follow in the FAULT handler); ``fields``: more of the state to set with it."""
        return replace(
            self._enter(state, Mode.FAULT, t, events, Severity.FAULT, why),
            fault_reason=why,
            setpoint=self._hold(state),
            **fields,
        )

    def _quick_stops_by_sdo(
        self, state: ControllerState, events: list[Event]
    ) -> tuple[ControllerState, tuple[int, ...]]:
        """In FAULT: the drives to be sent the quick stop by SDO as well (once each), those that may
        not process the RPDO that carries it: not OPERATIONAL, told to leave it, or not heard."""
        if state.mode != Mode.FAULT:
            return state, ()
        doubtful = state.unreachable | {j for j, s in enumerate(state.missing_streak) if s > 0}
        by_sdo = tuple(sorted(doubtful - state.sdo_stopped))
        if not by_sdo:
            return state, ()
        nodes = ", ".join(str(self._node_id(j)) for j in by_sdo)
        events.append(
            Event(
                "sdo_quick_stop",
                Severity.WARNING,
                f"quick stop by SDO 0x6040 as well to node(s) {nodes}: not OPERATIONAL or not heard",
            )
        )
        return replace(state, sdo_stopped=state.sdo_stopped | set(by_sdo)), by_sdo

    def _node_id(self, j: int) -> int:
        ids = self.config.drive_node_ids
        return ids[j] if j < len(ids) else j + 1

    def _unreachable(self, inputs: CycleInputs) -> frozenset[int]:
        """Drives this cycle says may not process RPDOs: not OPERATIONAL, told to leave it, or unheard."""
        index = {self._node_id(j): j for j in range(self.n)}
        found = {index[r.node_id] for r in inputs.nmt_reports if r.node_id in index}
        found |= {index[n] for n in inputs.lost_heartbeats if n in index}
        for a in inputs.anomalies:
            if a.kind == Anomaly.FOREIGN_NMT and a.command != 0x01:  # anything but "start"
                found |= (
                    set(range(self.n))
                    if a.node_id == 0
                    else ({index[a.node_id]} if a.node_id in index else set())
                )
        return frozenset(found)

    # -- checks ---------------------------------------------------------------------------

    def _measured_tcp(
        self, state: ControllerState, inputs: CycleInputs, measured: tuple[float, ...]
    ) -> tuple[float, float, float] | None:
        if not all(d.fresh for d in inputs.drives):
            return state.tcp_measured_m
        try:
            return tuple(self.robot.direct_kinematics(np.asarray(measured)).tolist())
        except NoSolutionError:
            return None

    def _react(
        self, state: ControllerState, reaction: Reaction, key: str, why: str, events: list[Event]
    ) -> tuple[ControllerState, str]:
        """Apply a configured reaction to an abnormal condition ``key``."""
        if reaction == Reaction.FAULT:
            if key in SENSOR_TROUBLE:
                state = replace(state, protective_cause=why)
            return state, why
        if reaction == Reaction.WARN and key not in state.warned:
            events.append(Event(key, Severity.WARNING, why))
            return replace(state, warned=state.warned | {key}), ""
        return state, ""

    def _safety(  # noqa: C901  (the safety checks in their order of precedence, one branch each)
        self, state: ControllerState, inputs: CycleInputs, events: list[Event]
    ) -> tuple[ControllerState, str]:
        """Configurable checks of the inputs; returns the updated state and a fault reason or ""."""
        sc = self.config.safety
        sensor = inputs.sensor
        stale = 0
        if state.sensor_breach:
            why = self._sensor_breach_fault(state)
            if why:
                return state, why
        elif sensor is not None:  # a breached sensor's frames count for nothing, nor does their absence
            if sensor.fresh:
                stale = state.sensor_stale + 1 if sensor.counter == state.sensor_counter else 0
                state = replace(state, sensor_counter=sensor.counter, sensor_stale=stale)
            missing = 0 if sensor.fresh else state.sensor_missing + 1
            if missing != state.sensor_missing:
                state = replace(state, sensor_missing=missing)
        if sensor is not None and sensor.fresh:
            f = sensor.force_n
            magnitude = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            if magnitude > sc.max_contact_force_n and state.mode not in GUARDED_MODES:
                # Drives not yet enabled: nothing to back off with. Enabled, the contact guard judges.
                return state, f"contact force {magnitude:.1f} N above the limit of {sc.max_contact_force_n} N"
            if sensor.status & SENSOR_FORCE_SATURATED:
                state, why = self._react(
                    state,
                    sc.on_sensor_saturated,
                    "sensor_saturated",
                    f"force sensor saturated (status 0x{sensor.status:02X})",
                    events,
                )
                if why:
                    return state, why
        if sensor is not None and stale >= sc.sensor_stale_cycles:  # stale > 0 only with a sensor
            state, why = self._react(
                state,
                sc.on_sensor_stale,
                "sensor_stale",
                f"force sensor stale: counter stuck at {sensor.counter} for {stale} cycles",
                events,
            )
            if why:
                return state, why
        silence = self._silence(state)
        if silence:
            return state, silence
        if (
            self.config.sensor_in_task
            and not state.sensor_breach
            and state.sensor_missing >= sc.sensor_stale_cycles
        ):
            # No usable sample (missing, or two senders on its COB-ID): no new information, as a counter
            # that does not advance, so the same tolerance (the contour task holds from the 4th cycle).
            state, why = self._react(
                state,
                sc.on_sensor_stale,
                "sensor_stale",
                f"force sensor: no usable sample for {state.sensor_missing} cycles",
                events,
            )
            if why:
                return state, why
        if inputs.lost_heartbeats:
            state, why = self._react(
                state,
                sc.on_heartbeat_lost,
                "heartbeat_lost",
                f"heartbeat lost from node(s) {list(inputs.lost_heartbeats)}",
                events,
            )
            if why:
                return state, why
        elif "heartbeat_lost" in state.warned:  # the episode under "warn" ends: said, and armed again
            events.append(
                Event("heartbeat_back", Severity.INFO, "every node's heartbeat (or guarding) is back")
            )
            state = replace(state, warned=state.warned - {"heartbeat_lost"})
        if inputs.bus_off:
            return state, "CAN bus-off reported by an error frame"
        if inputs.error_frames:
            state, why = self._react(
                state,
                sc.on_error_frames,
                "error_frames",
                f"{inputs.error_frames} CAN error frame(s) received",
                events,
            )
            if why:
                return state, why
        state, why = self._anomalies(state, inputs, events)
        if why:
            return state, why
        for r in inputs.nmt_reports:
            return state, (
                f"node {r.node_id} heartbeat reports {NMT_STATE_NAMES.get(r.state, f'state {r.state}')}"
                f", not OPERATIONAL"
            )
        late = state.late_streak + 1 if inputs.late else 0
        if late != state.late_streak:
            state = replace(state, late_streak=late)
        if late >= sc.max_consecutive_late_cycles:
            state, why = self._react(
                state, sc.on_late_cycles, "late_cycles", f"the loop woke late {late} cycles in a row", events
            )
            if why:
                return state, why
        if self._check_actuators is not None:
            status = self._check_actuators(tuple(d.position for d in inputs.drives))
            if not status.ok:
                return state, status.reason
        return state, ""

    def _retract_on_breach(self, state: ControllerState, a: BusAnomaly) -> bool:
        """A second sender on the force sensor's COB-ID while a task that can retract without force
        data runs: the retract comes before the fault. Holding still in contact under a quick stop,
        the force is whatever it was; the drives' own frames are still trusted, so moving away along
        the last normal is the safer end (scan: the spoofed-sample scenarios)."""
        c = self.config
        return (
            a.kind in (Anomaly.DUPLICATE_FRAME, Anomaly.IMPLAUSIBLE_FRAME)
            and c.sensor_node_id != 0
            and a.node_id == c.sensor_node_id
            and c.task_retracts_on_sensor_breach
            and c.safety.sensor_breach_retract_s > 0.0
            and state.mode == Mode.RUNNING
        )

    def _sensor_breach_fault(self, state: ControllerState) -> str:
        """The fault after a sensor breach: out of RUNNING (a stop, a pause), or past the retract's time."""
        why = f"force sensor not trusted: {state.sensor_breach}"
        if state.mode != Mode.RUNNING:
            return why
        limit_s = self.config.safety.sensor_breach_retract_s
        if (state.cycle - state.sensor_breach_cycle) * self.config.period_s > limit_s:
            return f"{why}; the task did not retract within {limit_s:g} s"
        return ""

    def _silence(self, state: ControllerState) -> str:
        """Every drive (and the sensor) without a usable sample for max_missing_cycles, named in one fault."""
        limit = self.config.max_missing_cycles
        silent = [j for j, s in enumerate(state.missing_streak) if s >= limit]
        if not silent:
            return ""
        sensor = state.sensor_missing >= limit
        if len(silent) == 1 and not sensor:
            return f"drive {silent[0] + 1}: no TPDO for {state.missing_streak[silent[0]]} cycles"
        cycles = min(state.missing_streak[j] for j in silent)
        names = [str(j + 1) for j in silent]
        if sensor:
            names.append("the force sensor")
            cycles = min(cycles, state.sensor_missing)
        return f"{'drives' if len(silent) > 1 else 'drive'} {listed(names)} silent for {cycles} cycles"

    def _anomalies(
        self, state: ControllerState, inputs: CycleInputs, events: list[Event]
    ) -> tuple[ControllerState, str]:
        """This cycle's bus anomalies by their configured reaction; "warn" is reported per burst."""
        sc = self.config.safety
        seen: dict[str, int] = {}
        texts: dict[str, str] = {}
        for a in inputs.anomalies:
            reaction = sc.reaction_to(a.kind)
            if reaction == Reaction.FAULT and self._retract_on_breach(state, a):
                if not state.sensor_breach:
                    state = replace(state, sensor_breach=anomaly_text(a), sensor_breach_cycle=state.cycle)
                    events.append(
                        Event(
                            "sensor_breach",
                            Severity.WARNING,
                            f"{anomaly_text(a)}: the force sensor's data is no longer used; "
                            f"the task retracts before the fault",
                        )
                    )
                continue
            if reaction == Reaction.FAULT:
                return state, anomaly_text(a)
            if reaction == Reaction.WARN:
                key = f"{a.kind.value}:{a.node_id}:0x{a.cob_id:03X}"
                seen[key] = seen.get(key, 0) + a.count
                texts.setdefault(key, anomaly_text(a))
        if not seen and not state.bursts:
            return state, ""
        every = max(1, round(BURST_REPORT_S / self.config.period_s))
        bursts = []
        for key, frames, cycles, reported in state.bursts:
            kind = key.split(":")[0]
            if key not in seen:
                events.append(
                    Event(
                        kind,
                        Severity.WARNING,
                        f"burst ended: {frames} {self._burst_what(key)} in {cycles} cycle(s)",
                    )
                )
                continue
            frames, cycles = frames + seen.pop(key), cycles + 1
            if state.cycle - reported >= every:
                events.append(
                    Event(
                        kind,
                        Severity.WARNING,
                        f"burst goes on: {frames} {self._burst_what(key)} in {cycles} cycle(s) so far",
                    )
                )
                reported = state.cycle
            bursts.append((key, frames, cycles, reported))
        for key, frames in seen.items():  # bursts that start in this cycle
            events.append(Event(key.split(":")[0], Severity.WARNING, f"burst starts: {texts[key]}"))
            bursts.append((key, frames, 1, state.cycle))
        return replace(state, bursts=tuple(bursts)), ""

    @staticmethod
    def _burst_what(key: str) -> str:
        kind, node, cob = key.split(":")
        return f"{ANOMALY_TEXT[Anomaly(kind)]}{_from_node(int(node))} (COB-ID {cob})"

    def _position_jump(self, state: ControllerState, inputs: CycleInputs) -> tuple[str, tuple[bool, ...]]:
        """Fresh positions further from the last trusted ones than the actuator can move: a lying encoder
        or frame. Returns the fault (none in CONFIGURING or FAULT) and which drives' positions are not
        to be trusted (judged in FAULT too: hold targets come only from trusted positions)."""
        cfg = self.config
        tolerance = cfg.safety.max_position_jump
        flags = [False] * self.n
        if not math.isfinite(tolerance) or state.mode == Mode.CONFIGURING:
            return "", tuple(flags)
        reason = ""
        for j, (d, last, gap) in enumerate(
            zip(inputs.drives, state.last_measured, state.missing_streak, strict=True)
        ):
            if not (d.fresh and math.isfinite(last)):
                continue
            possible = cfg.max_speed * (gap + 1) * cfg.period_s + tolerance
            step = abs(d.position - last)
            if step > possible:  # also catches NaN below: NaN > x is False, the finite check is elsewhere
                flags[j] = True
                u = cfg.position_unit
                reason = reason or (
                    f"drive {j + 1} position jumped {step:.4f} {u} in {gap + 1} cycle(s) (from {last:.4f} to "
                    f"{d.position:.4f} {u}); at most {possible:.4f} {u} is possible "
                    f"({cfg.max_speed} {u}/s + safety.max_position_jump {tolerance} {u})"
                )
        return ("" if state.mode == Mode.FAULT else reason), tuple(flags)

    def _following_error(self, state: ControllerState, inputs: CycleInputs) -> str:
        """A fresh position further than the window from where the drive should be at its sample.

        The position was sampled at this cycle's SYNC, where the drive reached the setpoint of two
        steps ago; ``state.setpoint`` is the last step's, aimed one period later (the cycle in
        docs/concepts/cycle.md): the expected position is that setpoint taken back one period along its own
        motion, q - v T + a T^2 / 2. Against the last setpoint itself a drive at full speed would
        lag by v T: 20 mm at 0.5 m/s and 25 Hz, twice the default window.
        """
        window = self.config.safety.following_window
        if not math.isfinite(window):
            return ""
        t_s = self.config.period_s
        sp = state.setpoint
        for j, (d, q, v, a) in enumerate(
            zip(inputs.drives, sp.position, sp.velocity, sp.acceleration, strict=True)
        ):
            expected = q - v * t_s + 0.5 * a * t_s * t_s
            if d.fresh and abs(d.position - expected) > window:
                u = self.config.position_unit
                return (
                    f"drive {j + 1} following error {abs(d.position - expected):.4f} {u} beyond the window of "
                    f"{window} {u} (measured {d.position:.4f} {u}, expected {expected:.4f} {u} at this sample)"
                )
        return ""

    def _configuring_fault(self, state: ControllerState, inputs: CycleInputs, emcy_fault: str) -> str:
        """Before every drive has answered: what already makes starting pointless."""
        if inputs.bus_off:
            return "CAN bus-off reported by an error frame"
        if emcy_fault:
            return emcy_fault
        # A drive that never answered is judged on the time devices may take to come up after their
        # NMT start (a slow machine, an emulated one), not on max_missing_cycles of a running bus.
        waited_s = state.cycle * self.config.period_s
        if waited_s >= self.config.enable_timeout_s:
            for j, x in enumerate(state.last_measured):
                if math.isnan(x):
                    return f"drive {j + 1}: no TPDO within {self.config.enable_timeout_s} s of the start"
        return ""

    def _fault_reason(
        self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...], emcy_fault: str
    ) -> str:
        # ENABLING after the operator's reset resets the drives' faults and judges its attempts itself;
        # a drive in FAULT at the start, or one that faults on its way to enabled, is a fault
        resetting = state.mode == Mode.ENABLING and bool(state.fault_resets)
        for j, (p, streak) in enumerate(zip(powers, state.missing_streak, strict=True)):
            # Judged on this cycle's TPDO only: a statusword not refreshed (missing frame) is old news,
            # e.g. the FAULT a reset has just cleared; silence has its own limit below.
            faulted = p in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE)
            if inputs.drives[j].fresh and faulted and not resetting:
                return (
                    f"drive {j + 1} reports {p.name} (statusword 0x{inputs.drives[j].statusword:04X})"
                    + self._error_code(state, j)
                )
            if streak >= self.config.max_missing_cycles:  # _safety names them first, all at once
                return f"drive {j + 1}: no TPDO for {streak} cycles"
        if emcy_fault:
            return emcy_fault
        if state.mode in (Mode.HOLDING, Mode.RUNNING, Mode.PAUSED, Mode.BACKING_OFF) or (
            state.mode == Mode.STOPPING and not self._shutting_down(state)
        ):
            for j, p in enumerate(powers):
                if inputs.drives[j].fresh and p != PowerState.OPERATION_ENABLED:
                    return f"drive {j + 1} left OPERATION ENABLED (now {p.name})"
            following = self._following_error(state, inputs)
            if following:
                return following
        for j, x in enumerate(inputs.drives):
            if not math.isfinite(x.position):
                return f"drive {j + 1} position is not a number"
        return ""

    def _error_code(self, state: ControllerState, j: int) -> str:
        return error_code_text(state.error_codes[j]) if j < len(state.error_codes) else ""

    def _note_error_codes(self, state: ControllerState, inputs: CycleInputs) -> ControllerState:
        """Each drive's last error code as its EMCYs say (0 after an "error reset" EMCY)."""
        codes = list(state.error_codes) or [0] * self.n
        index = {self._node_id(j): j for j in range(self.n)}
        for e in inputs.emcy:
            j = index.get(e.node_id)
            if j is not None and self.config.emcy_action(e.node_id, e.error_code) == EmcyAction.FAULT:
                codes[j] = e.error_code  # a warning's code is no fault's
        return replace(state, error_codes=tuple(codes))

    def _emcy_fault(self, inputs: CycleInputs) -> str:
        """The first EMCY of this cycle whose configured reaction is a fault ("" if none)."""
        for e in inputs.emcy:
            if e.error_code != 0 and self.config.emcy_action(e.node_id, e.error_code) == EmcyAction.FAULT:
                return f"EMCY from node {e.node_id}: error code 0x{e.error_code:04X}, register 0x{e.error_register:02X}"
        return ""

    def _emcy_notes(
        self, state: ControllerState, inputs: CycleInputs, t: float, events: list[Event]
    ) -> ControllerState:
        """EMCYs configured as "warn" (an event per code and episode) or "hold" (a running task pauses)."""
        for e in inputs.emcy:
            if e.error_code == 0:
                continue
            action = self.config.emcy_action(e.node_id, e.error_code)
            what = f"EMCY from node {e.node_id}: error code 0x{e.error_code:04X}, register 0x{e.error_register:02X}"
            if action == EmcyAction.HOLD and state.mode == Mode.RUNNING:
                why = f"{what} (actuators.emcy_reactions: hold); the task resumes on the operator's resume"
                state = self._enter(state, Mode.PAUSED, t, events, Severity.WARNING, why)
                continue
            key = f"emcy:{e.node_id}:0x{e.error_code:04X}"
            if key not in state.warned:
                events.append(
                    Event("emcy_warning", Severity.WARNING, f"{what} (actuators.emcy_reactions: {action})")
                )
                state = replace(state, warned=state.warned | {key})
        return state

    def _shutting_down(self, state: ControllerState) -> bool:
        return any(
            cw != controlword_towards(PowerState.OPERATION_ENABLED, PowerState.OPERATION_ENABLED)
            for cw in state.controlwords
        )

    # -- mode handlers ----------------------------------------------------------------------

    def _enter(
        self,
        state: ControllerState,
        mode: Mode,
        t: float,
        events: list[Event],
        severity: Severity = Severity.INFO,
        why: str = "",
    ) -> ControllerState:
        text = f"{state.mode.name} -> {mode.name}" + (f": {why}" if why else "")
        events.append(Event("mode", severity, text))
        return replace(state, mode=mode, mode_entered_s=t)

    def _configuring(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        if all(d.fresh for d in inputs.drives):
            state = replace(state, setpoint=Setpoint.at_rest(measured))
            return self._enter(state, Mode.ENABLING, t, events, why="all drives answer")
        # Until every drive has answered, each is sent where it was last heard (else mid-stroke).
        heard = tuple(
            x if math.isfinite(x) else q
            for x, q in zip(state.last_measured, state.setpoint.position, strict=True)
        )
        return replace(state, setpoint=Setpoint.at_rest(heard))

    def _enabling(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        # Command the measured (trusted) position while the drives are not enabled: no jump at enable. A drive
        # not heard this cycle keeps its controlword: its statusword is old news (it may say FAULT).
        resets = list(state.fault_resets)  # empty: not after a reset
        cws = list(state.controlwords)
        stuck = ""
        for j, (p, d) in enumerate(zip(powers, inputs.drives, strict=True)):
            if not d.fresh:
                continue
            if p == PowerState.FAULT and resets:
                cws[j], resets[j], why = self._fault_reset(state, j, resets[j], t)
                stuck = stuck or why
            else:
                cws[j] = controlword_towards(p, PowerState.OPERATION_ENABLED, cws[j])
                if resets and resets[j].holding:
                    resets[j] = replace(resets[j], holding=False)
        state = replace(
            state, controlwords=tuple(cws), fault_resets=tuple(resets), setpoint=self._hold(state)
        )  # where each was last trusted
        if stuck:
            return replace(
                self._enter(state, Mode.FAULT, t, events, Severity.FAULT, stuck), fault_reason=stuck
            )
        if all(p == PowerState.OPERATION_ENABLED for p in powers):
            state = replace(state, fault_resets=())
            return self._enter(state, Mode.HOLDING, t, events, why="all drives in OPERATION ENABLED")
        if t - state.mode_entered_s > self.config.enable_timeout_s:
            states = ", ".join(
                f"{j + 1}: {p.name}" + (self._error_code(state, j) if p == PowerState.FAULT else "")
                for j, p in enumerate(powers)
            )
            why = f"drives not enabled within {self.config.enable_timeout_s} s ({states})"
            return replace(self._enter(state, Mode.FAULT, t, events, Severity.FAULT, why), fault_reason=why)
        return state

    def _fault_reset(
        self, state: ControllerState, j: int, progress: FaultResetProgress, t: float
    ) -> tuple[int, FaultResetProgress, str]:
        """One cycle of drive ``j``'s fault reset: (controlword, progress, fault reason or "").

        Edge, hold, wait, verify: bit 7 goes high (a rising edge: the controlword before it has it
        low) and stays high for ``hold_s`` (one cycle at least), goes low, and the statusword has
        ``wait_s`` to leave FAULT; a drive still in FAULT then gets the next attempt, up to
        ``attempts``. Some drives reset on the edge, some only after bit 7 was held (ros_canopen
        #138/#139), and a fault whose cause is still present does not clear at all: the statusword
        is the verification (canopen #261), and the error code names the cause.
        """
        cfg = self.config.fault_reset(j)
        eps = 1e-9
        if progress.holding:
            if t - progress.since_s < max(cfg.hold_s, self.config.period_s) - eps:
                return CW_FAULT_RESET, progress, ""
            return CW_DISABLE_VOLTAGE, FaultResetProgress(progress.attempts, False, t), ""
        if progress.attempts and t - progress.since_s < cfg.wait_s - eps:
            return CW_DISABLE_VOLTAGE, progress, ""  # waiting for the statusword
        if cfg.attempts and progress.attempts >= cfg.attempts:
            why = (
                f"drive {j + 1} stays in FAULT after {progress.attempts} fault reset(s) "
                f"(actuators.fault_reset_attempts = {cfg.attempts}, hold {cfg.hold_s:g} s, wait {cfg.wait_s:g} s)"
                + self._error_code(state, j)
            )
            return CW_DISABLE_VOLTAGE, progress, why
        return CW_FAULT_RESET, FaultResetProgress(progress.attempts + 1, True, t), ""

    def _holding(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        state = self._smooth_to_rest(state, t, events)
        if t - state.mode_entered_s >= self.config.hold_before_task_s and state.mode == Mode.HOLDING:
            state = replace(state, task_state=self.task.start())
            return self._enter(state, Mode.RUNNING, t, events, why=f"task {self.task.name} starts")
        return state

    def _running(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        period = self.config.period_s
        task_time = state.task_time_s + period
        if state.sensor_breach:  # someone else sends on its COB-ID: nothing of it reaches the task
            inputs = replace(inputs, sensor=None)
        elif inputs.sensor is not None and inputs.sensor.fresh and state.sensor_stale > 0:
            # A frame whose counter did not advance repeats the last sample: no new evidence for the task.
            inputs = replace(inputs, sensor=replace(inputs.sensor, fresh=False))
        witness = state.contact.witness
        ctx = TaskContext(
            t_s=task_time + PIPELINE_PERIODS * period,
            period_s=period,
            setpoint=state.setpoint,
            inputs=inputs,
            tcp_measured_m=state.tcp_measured_m,
            sensor_breach=state.sensor_breach,
            force_witness_n=witness.force_n if witness is not None else None,
            sensor_suspect=state.contact.suspect,
        )
        out = self.task.step(state.task_state, ctx)
        events.extend(out.events)
        task_state, ref, finished = out.state, out.reference, out.finished
        if out.fault:
            return self._faulted(state, out.fault, t, events, task_state=task_state)
        too_fast = self._contact_speed(state, ref.tcp_m, ref.contact)
        if too_fast:
            return self._faulted(state, too_fast, t, events, task_state=task_state)
        pose = self.robot.check_pose(np.asarray(ref.tcp_m))
        if not pose.ok:
            why = f"task reference leaves the safe workspace: {pose.reason}"
            return self._faulted(state, why, t, events)
        if ref.reactive:
            result = self.smoother.track_velocity(
                state.setpoint, ref.position, ref.velocity, REACTIVE_CORRECTION_PERIODS / period
            )
        else:
            result = self.smoother.step(state.setpoint, ref.position, ref.velocity, ref.acceleration)
        if not result.ok:
            return self._faulted(state, result.message, t, events)
        state = replace(
            state,
            task_state=task_state,
            setpoint=result.setpoint,
            task_time_s=task_time,
            tcp_reference_m=ref.tcp_m if ref.on_path else None,
            contact=replace(state.contact, expectation=ref.contact, reference_m=ref.tcp_m),
        )
        if finished:
            return self._enter(state, Mode.STOPPING, t, events, why=f"task {self.task.name} finished")
        return state

    def _paused(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        return replace(self._smooth_to_rest(state, t, events), tcp_reference_m=None)

    def _stopping(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        state = replace(state, tcp_reference_m=None)
        if not self._shutting_down(state):
            state = self._smooth_to_rest(state, t, events)
            if state.mode != Mode.STOPPING:
                return state
            tol = self.config.settle_tolerance
            if all(abs(v) <= tol for v in state.setpoint.velocity):
                state = replace(state, setpoint=Setpoint.at_rest(state.setpoint.position))
            else:
                return state
        cws = tuple(
            controlword_towards(p, PowerState.READY_TO_SWITCH_ON, cw)
            for p, cw in zip(powers, state.controlwords, strict=True)
        )
        state = replace(state, controlwords=cws)
        if all(p in (PowerState.READY_TO_SWITCH_ON, PowerState.SWITCH_ON_DISABLED) for p in powers):
            return self._enter(state, Mode.DONE, t, events, why="drives shut down")
        return state

    def _done(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        return state

    def _fault(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        cws = tuple(
            controlword_towards(p, PowerState.QUICK_STOP_ACTIVE, cw)
            for p, cw in zip(powers, state.controlwords, strict=True)
        )
        state = replace(state, controlwords=cws, setpoint=self._hold(state))
        if state.bus_off_cycle and state.cycle > state.bus_off_cycle and any(d.fresh for d in inputs.drives):
            state = self._after_bus_off(state, inputs, powers, events)
        return state

    def _after_bus_off(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        events: list[Event],
    ) -> ControllerState:
        """The first cycle a drive is heard again after a bus-off (the interface restarted): each
        drive re-checked in one event; the task waits in FAULT for the operator's reset."""
        down_s = (state.cycle - state.bus_off_cycle) * self.config.period_s
        checks = []
        restarted = {r.node_id for r in inputs.nmt_reports if r.state == 0}
        for j, (d, p) in enumerate(zip(inputs.drives, powers, strict=True)):
            node = self._node_id(j)
            if d.fresh:
                checks.append(f"{j + 1} {p.name} (0x{d.statusword:04X}){self._error_code(state, j)}")
            else:
                checks.append(f"{j + 1} silent" + (" (it restarted)" if node in restarted else ""))
        events.append(
            Event(
                "bus_restored",
                Severity.WARNING,
                f"the bus is back {down_s:.2f} s after the bus-off; drives re-checked: {', '.join(checks)}; "
                f"the task resumes only on the operator's reset",
            )
        )
        return replace(state, bus_off_cycle=0)

    # -- the contact guard (contact_guard.py) ---------------------------------------------------

    def _witness(
        self, state: ControllerState, inputs: CycleInputs, history: tuple[tuple[float, ...], ...]
    ) -> Witness | None:
        """The contact force the drives' efforts imply this cycle, where the robot and the drives tell
        it; ``history``: the setpoints' last accelerations, newest last."""
        model = self._witness_model
        tcp = state.tcp_measured_m
        if (
            model is None
            or tcp is None
            or len(history) < WITNESS_ACCELERATION_LAG
            or not all(d.fresh and d.effort_n == d.effort_n for d in inputs.drives)
        ):
            return None
        found = model.contact_force_from_efforts(
            tcp,
            tuple(d.position for d in inputs.drives),
            tuple(d.effort_n for d in inputs.drives),
            history[-WITNESS_ACCELERATION_LAG],
        )
        return Witness(*found) if found is not None else None

    def _guard_contact(
        self, state: ControllerState, inputs: CycleInputs, t: float, events: list[Event]
    ) -> ControllerState:
        """The guard's watch this cycle; past a limit, the protective back-off (or, backing off into
        more force, the quick stop)."""
        cfg = self.config.safety.contact
        was_suspect = state.contact.suspect
        history = (*state.contact.accelerations, state.setpoint.acceleration)[-WITNESS_ACCELERATION_LAG:]
        tolerance = self.config.settle_tolerance
        at_rest = all(-tolerance <= v <= tolerance for v in state.setpoint.velocity)
        w, cause = watch_contact(
            cfg,
            replace(state.contact, accelerations=history),
            inputs,
            state.sensor_stale > 0 or bool(state.sensor_breach),
            self._witness(state, inputs, history),
            at_rest,
            state.cycle,
            self.config.period_s,
        )
        state = replace(state, contact=w)
        if w.suspect and not was_suspect:
            events.append(Event("sensor_suspect", Severity.WARNING, f"force sensor suspect: {w.suspect}"))
        elif was_suspect and not w.suspect:
            events.append(
                Event("sensor_suspect", Severity.INFO, "force sensor and drives' effort agree again")
            )
        if state.mode == Mode.BACKING_OFF:
            b = state.back_off
            if (
                b is not None
                and b.cycles > BACK_OFF_GRACE_CYCLES
                and w.force_n > max(b.entry_force_n, cfg.max_contact_force_n) + BACK_OFF_WORSE_N
            ):
                why = f"{back_off_summary(b)}, and met {w.force_n:.1f} N backing off: quick stop"
                return self._faulted(state, why, t, events)
            return state
        if not cause:
            return state
        return self._begin_back_off(state, cause, t, events)

    def _begin_back_off(
        self, state: ControllerState, cause: str, t: float, events: list[Event]
    ) -> ControllerState:
        """BACKING_OFF along the force the guard trusts (contact_guard.begin_back_off), naming ``cause``."""
        origin = state.tcp_measured_m or state.contact.reference_m
        if origin is None:  # no pose to move from: the quick stop is all there is
            return self._faulted(state, cause, t, events)
        back_off = begin_back_off(
            self.config.safety.contact, state.contact, cause, origin, cause != state.protective_cause
        )
        d = back_off.direction
        where = f"backing off along ({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f})" if d else "braking in place"
        events.append(Event("protective_stop", Severity.FAULT, f"{cause}: {where}"))
        return replace(
            self._enter(state, Mode.BACKING_OFF, t, events, Severity.FAULT, f"protective stop: {cause}"),
            back_off=back_off,
            tcp_reference_m=None,
        )

    def _contact_speed(
        self, state: ControllerState, tcp_m: tuple[float, float, float], contact: ContactExpectation
    ) -> str:
        """A reference that expects contact and moves faster than a guarded move may: the task's bug."""
        last = state.contact.reference_m
        if contact == ContactExpectation.NONE or last is None:
            return ""
        speed = norm3(sub3(tcp_m, last)) / self.config.period_s
        limit = self.config.safety.contact.max_contact_speed_m_s
        if speed <= limit:
            return ""
        return (
            f"the task's reference moves at {speed:.3f} m/s where it expects contact; a guarded move "
            f"is at most safety.contact.max_contact_speed_m_s = {limit} m/s"
        )

    def _backing_off(
        self,
        state: ControllerState,
        inputs: CycleInputs,
        powers: tuple[PowerState, ...],
        measured: tuple[float, ...],
        t: float,
        events: list[Event],
    ) -> ControllerState:
        """Away from the force at a bounded speed (reactive, as a task's guarded move), then at rest: FAULT."""
        b = state.back_off
        assert b is not None
        period = self.config.period_s
        b, p, v = advance_back_off(self.config.safety.contact, b, period)
        state = replace(state, back_off=b)
        if not b.braking:
            try:
                q = self.robot.inverse_kinematics(np.asarray(p))
                ahead = self.robot.inverse_kinematics(
                    np.asarray((p[0] + v[0] * period, p[1] + v[1] * period, p[2] + v[2] * period))
                )
            except NoSolutionError:
                b = replace(b, braking=True)
                state = replace(state, back_off=b)
            else:
                qd = tuple((float(a) - float(c)) / period for a, c in zip(ahead, q, strict=True))
                result = self.smoother.track_velocity(
                    state.setpoint, tuple(float(x) for x in q), qd, REACTIVE_CORRECTION_PERIODS / period
                )
                if result.ok:
                    return replace(state, setpoint=result.setpoint)
                b = replace(b, braking=True)
                state = replace(state, back_off=b)
        state = self._smooth_to_rest(state, t, events)
        if state.mode != Mode.BACKING_OFF or any(
            abs(x) > self.config.settle_tolerance for x in state.setpoint.velocity
        ):
            return state
        why = back_off_summary(b)
        return replace(
            self._enter(state, Mode.FAULT, t, events, Severity.FAULT, why),
            fault_reason=why,
            setpoint=Setpoint.at_rest(state.setpoint.position),
        )

    @staticmethod
    def _hold(state: ControllerState) -> Setpoint:
        """At rest where each drive was last measured and trusted; where it never was, where it was sent.

        Never from a flagged frame: a position the plausibility check refused is not in
        ``last_measured``, so a rogue frame cannot choose where the robot stops.
        """
        return Setpoint.at_rest(
            tuple(
                x if math.isfinite(x) else q
                for x, q in zip(state.last_measured, state.setpoint.position, strict=True)
            )
        )

    def _smooth_to_rest(self, state: ControllerState, t: float, events: list[Event]) -> ControllerState:
        result = self.smoother.brake(state.setpoint)
        if not result.ok:
            return replace(
                self._enter(state, Mode.FAULT, t, events, Severity.FAULT, result.message),
                fault_reason=result.message,
            )
        return replace(state, setpoint=result.setpoint)
