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
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

from controller.core.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    PowerState,
    controlword_towards,
    decode_statusword,
)
from controller.core.contact_guard import (
    ANOTHER_WALL_FRACTION,
    BackOff,
    Witness,
    advance_back_off,
    back_off_met_n,
    back_off_summary,
    begin_back_off,
    begin_retrace,
)
from controller.core.contact_guard import (
    watch as watch_contact,
)
from controller.core.controller_state import ControllerState, FaultResetProgress, Mode
from controller.core.cycle_data import (
    Anomaly,
    Command,
    CycleInputs,
    CycleOutputs,
    EmcyAction,
    Event,
    Severity,
)
from controller.core.law_config import LawConfig
from controller.core.linalg3 import norm3, sub3
from controller.core.periods import deadlines_skipped
from controller.core.ports import (
    ContactExpectation,
    ForceWitnessModel,
    JointReference,
    Robot,
    Task,
    TaskContext,
    TaskStep,
    missing_capability,
)
from controller.core.records import replace
from controller.core.safety_monitor import GUARDED_MODES, SafetyMonitor, error_text, missing_alone
from controller.core.setpoint_smoothing import RuckigSmoother, Setpoint, SmoothingResult
from controller.errors import NoSolutionError

PIPELINE_PERIODS = 2
# A reactive reference's position error decays with a time constant of 1/0.25 = 4 periods.
REACTIVE_CORRECTION_PERIODS = 0.25


# The drives' efforts sampled at a SYNC show their motion towards the setpoint this many steps old
# (the pipeline: computed, sent at the next deadline, latched, interpolated over the period after):
# the witness adds back the inertia of that setpoint's acceleration (measured: lags 2-4 fit best).
WITNESS_ACCELERATION_LAG = 3
# A back-off that meets this much more force than it started from makes things worse: the quick stop.
BACK_OFF_WORSE_N = 10.0
# ... judged after this many cycles: the setpoints already on their way (PIPELINE_PERIODS) and the
# structure's momentum carry the tool on for a few cycles whatever the back-off commands
BACK_OFF_GRACE_CYCLES = 16


def hold_up_effect(
    skipped: int, extrapolation_periods: int, blind_before: int = 0, withheld: bool = False
) -> tuple[int, bool, int]:
    """For ``skipped`` deadlines and drives that run on ``extrapolation_periods`` (E) without a new
    target (``ControlLaw._after_hold_up`` derives it), when the last step was already
    ``blind_before`` periods past the drives' last target (a hold-up right after a hold-up): the
    periods they ran on past the last setpoint, whether they stood long enough for a restart from
    rest (more than two periods), and how far past their last target they will be when this
    step's target comes (``drives_blind_periods``). After one hold-up, ``min(skipped, E - 1)`` and
    more than E + 1 skipped. A SYNC that went without the targets though no deadline was skipped
    (``withheld``, ``CycleInputs.targets_withheld``) leaves the drives one period blind: as a
    hold-up of no deadline.

    -1 periods run on when the drives were already at the end of their extrapolation
    (``blind_before`` >= E): they stood through the whole period, and so do the task and the setpoint
    (``ControlLaw._running``). Counted as 0, each such step put the setpoint one more period past
    standing drives: in a burst of thirteen hold-ups within 65 ms, 2.4 steps, which the first target
    after it pulled the legs in one period (34.0 N where 10 N is asked, simulated time)."""
    if not skipped and not withheld:
        return 0, False, 0
    blind = blind_before + skipped + 1
    e = extrapolation_periods
    return min(blind, e) - min(blind_before, e) - 1, blind > e + 2, blind


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
        self.monitor = SafetyMonitor(robot, config)  # the checks of each cycle's inputs
        # Robots that tell the contact force from their drives' efforts give the sensor its second witness.
        self._witness_model = (
            None if missing_capability(robot, ForceWitnessModel) else cast(ForceWitnessModel, robot)
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
            missing_alone=(0,) * self.n,
            task_state=None,
            tcp_reference_m=None,
            tcp_measured_m=None,
            last_measured=(math.nan,) * self.n,
        )

    # -- the step -------------------------------------------------------------------------

    def step(
        self, state: ControllerState, inputs: CycleInputs, t: float
    ) -> tuple[ControllerState, CycleOutputs, tuple[Event, ...]]:
        self._check_drive_count(inputs)
        events: list[Event] = []
        measured = tuple(d.position for d in inputs.drives)
        powers = tuple(decode_statusword(d.statusword) for d in inputs.drives)
        skipped = self._skipped_deadlines(state, t)
        jump, implausible = self.monitor.position_jump(state, inputs, skipped)
        streak = tuple(0 if d.fresh else s + 1 for d, s in zip(inputs.drives, state.missing_streak))
        # a drive's own silence, apart from what every device shared (zeros, as the streak, when all answer)
        alone = missing_alone(inputs, state.missing_alone) if any(streak) else streak
        last = tuple(
            d.position if d.fresh and not bad else x
            for d, x, bad in zip(inputs.drives, state.last_measured, implausible)
        )
        state = replace(
            state,
            cycle=state.cycle + 1,
            step_t_s=t,
            missing_streak=streak,
            missing_alone=alone,
            last_measured=last,
            tcp_measured_m=self._measured_tcp(state, inputs, measured),
            unreachable=state.unreachable | self._unreachable(inputs),
        )
        if skipped or state.drives_blind_periods or inputs.targets_withheld:
            state = self._after_hold_up(state, skipped, inputs.targets_withheld)
        if inputs.emcy:
            state = self.monitor.note_error_codes(state, inputs)
        emcy_fault = self.monitor.emcy_fault(inputs)

        if state.mode == Mode.CONFIGURING:
            reason = self.monitor.configuring_fault(state, inputs, emcy_fault)
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

    def _check_drive_count(self, inputs: CycleInputs) -> None:
        """Checked once at the step's entry: its loops over drives and axes zip without ``strict=True``
        (mypyc makes only a zip of positional arguments a native loop), so a short tuple would be
        cut short there, not refused."""
        if len(inputs.drives) != self.n:
            raise ValueError(
                f"cycle inputs carry {len(inputs.drives)} drives' samples, the robot has {self.n} actuators"
            )

    def _skipped_deadlines(self, state: ControllerState, t: float) -> int:
        """The deadlines the loop skipped before this step (it fell behind: a hold-up)."""
        if not math.isfinite(state.step_t_s):  # the first step has no last one
            return 0
        return deadlines_skipped(t - state.step_t_s, self.config.period_s)

    def _after_hold_up(self, state: ControllerState, skipped: int, withheld: bool) -> ControllerState:
        """Where the drives went while the loop was held up for ``skipped`` deadlines.

        The loop shell does not send a cycle's RPDOs after skipped deadlines (they were meant for a
        SYNC that is gone), so the drives ran on along their last segment for E periods at most
        (``drive_extrapolation_periods``), then held. At the SYNC that brings the next target,
        ``skipped + 2`` periods after that segment began, they are ``min(skipped + 2, 1 + E)`` steps
        past the target before it: ``min(skipped, E - 1)`` steps past the last setpoint
        (``drives_ran_on``). The task and the setpoint move on as far, so that the next target carries
        on from where the drives are instead of pulling them back. With E or E + 1 skipped deadlines
        they stood a period or two before that target; with more (``drives_held``) longer, and a
        brake or a reactive reference restarts from rest where they are (earlier, a restart after a
        stand of one or two periods cost the contour more than it saved). With E = 1, a drive's
        usual single period, they are where the last setpoint is and nothing moves.

        A hold-up right after one (beside CPU hogs, 1 then 3 skipped deadlines) finds the drives
        already that far into their extrapolation, the last setpoint never sent: they ran on only
        what was left of it (``drives_blind_periods``). Counted from each hold-up alone, the step
        put the setpoint 3 periods ahead of drives that stood, and the target after pulled them
        on in one period (a force step of 10.6 N over the bus). Once they are past their
        extrapolation, each further period without a target is one they stood through (-1 run on):
        the task and the setpoint wait (``_running``).
        """
        ran_on, held, blind = hold_up_effect(
            skipped, self.config.drive_extrapolation_periods, state.drives_blind_periods, withheld
        )
        # RUNNING, the task steps through the periods they ran on, and the setpoint with it (_running)
        stepped_through = ran_on > 0 and state.mode == Mode.RUNNING
        if ran_on > 0 and state.mode != Mode.FAULT and not stepped_through:
            state = replace(state, setpoint=self._moved_on(state.setpoint, ran_on))
        return replace(state, drives_held=held, drives_ran_on=ran_on, drives_blind_periods=blind)

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
        state, reason = self.monitor.check(state, inputs, events)
        if reason and reason == state.protective_cause and state.mode in GUARDED_MODES:
            # The force sensor gone stale or saturated with the drives enabled: the tool may be
            # pressing on something with a force nobody reads; back off along the drives' effort
            # witness (or brake in place without one), never a quick stop in contact. Backing off
            # already, it goes on.
            if state.mode != Mode.BACKING_OFF:
                state = self._begin_back_off(state, reason, t, events)
            reason = ""
        reason = reason or jump or self.monitor.fault_reason(state, inputs, powers, emcy_fault)
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
            tcp_reference_m=None,  # the last run's path: the measured pose is judged on this run's
            sensor_stale=0,
            sensor_missing=0,
            sensor_missing_alone=0,
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
        nodes = ", ".join(str(self.monitor.node_id(j)) for j in by_sdo)
        events.append(
            Event(
                "sdo_quick_stop",
                Severity.WARNING,
                f"quick stop by SDO 0x6040 as well to node(s) {nodes}: not OPERATIONAL or not heard",
            )
        )
        return replace(state, sdo_stopped=state.sdo_stopped | set(by_sdo)), by_sdo

    def _unreachable(self, inputs: CycleInputs) -> frozenset[int]:
        """Drives this cycle says may not process RPDOs: not OPERATIONAL, told to leave it, or unheard."""
        index = {self.monitor.node_id(j): j for j in range(self.n)}
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
            x if math.isfinite(x) else q for x, q in zip(state.last_measured, state.setpoint.position)
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
        for j, (p, d) in enumerate(zip(powers, inputs.drives)):
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
                f"{j + 1}: {p.name}" + (self.monitor.error_code(state, j) if p == PowerState.FAULT else "")
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
                + self.monitor.error_code(state, j)
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
            try:
                task_state = self.task.start()
            # a task's (a plug-in's) error, sys.exit too, ends in the quick stop, named
            except (Exception, SystemExit) as err:
                return self._faulted(state, task_error(self.task.name, "start", err), t, events)
            state = replace(state, task_state=task_state, tcp_reference_m=None)
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
        inputs = self._task_inputs(state, inputs)
        why = self._measured_pose_fault(state, inputs)
        if why:
            return self._faulted(state, why, t, events)
        if state.drives_ran_on < 0:
            # The drives stood through this period, out of extrapolation and without a target: the task
            # and the setpoint wait with them, one step ahead, the step the next target carries them.
            if not state.drives_held:
                return state
            # Stood long enough for a restart from rest: from where they stand, a step behind.
            state = replace(state, setpoint=self._moved_on(state.setpoint, -1))
        witness = state.contact.witness
        # The periods the drives ran on blind in a hold-up (``_after_hold_up``) are the task's too: it
        # steps through them without measurements, then through this cycle with this cycle's.
        blind = self._blind(inputs) if state.drives_ran_on > 0 else inputs
        task_state, task_time = state.task_state, state.task_time_s
        for k in range(max(0, state.drives_ran_on), -1, -1):
            task_time += period
            ctx = TaskContext(
                t_s=task_time + PIPELINE_PERIODS * period,
                period_s=period,
                setpoint=state.setpoint,
                inputs=blind if k else inputs,
                tcp_measured_m=state.tcp_measured_m,
                sensor_breach=state.sensor_breach,
                force_witness_n=witness.force_n if witness is not None else None,
                sensor_suspect=state.contact.suspect,
                drives_held=state.drives_held and not k,
                drives_ran_on=bool(k),
            )
            try:
                checked = checked_step(self.task.name, self.task.step(task_state, ctx), self.n)
            # a task's (a plug-in's) error, sys.exit too, ends in the quick stop, named
            except (Exception, SystemExit) as err:
                return self._faulted(state, task_error(self.task.name, "step", err), t, events)
            if isinstance(checked, str):
                return self._faulted(state, checked, t, events)
            out = checked  # the law's own copy from here on (checked_step)
            events.extend(out.events)
            task_state, ref = out.state, out.reference
            if out.fault:
                return self._faulted(state, out.fault, t, events, task_state=task_state)
            if not k or out.finished:
                break
            # A blind period: the setpoint goes with it as it would have, near where the drives ran on
            # (from where it is: they were moving then, whatever they did after)
            result = self._smoothed(replace(state, drives_held=False) if state.drives_held else state, ref)
            if not result.ok:
                return self._faulted(state, result.message, t, events)
            state = replace(state, setpoint=result.setpoint)
        finished = out.finished
        too_fast = self._contact_speed(state, ref.tcp_m, ref.contact)
        if too_fast:
            return self._faulted(state, too_fast, t, events, task_state=task_state)
        why = self._reference_fault(ref)
        if why:
            return self._faulted(state, why, t, events)
        result = self._smoothed(state, ref)
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

    @staticmethod
    def _task_inputs(state: ControllerState, inputs: CycleInputs) -> CycleInputs:
        """The cycle's inputs as the task may see them: the force sensor's sample only when trusted."""
        if state.sensor_breach:  # someone else sends on its COB-ID: nothing of it reaches the task
            return replace(inputs, sensor=None)
        if inputs.sensor is not None and inputs.sensor.fresh and state.sensor_stale > 0:
            # A frame whose counter did not advance repeats the last sample: no new evidence for the task.
            return replace(inputs, sensor=replace(inputs.sensor, fresh=False))
        return inputs

    def _measured_pose_fault(self, state: ControllerState, inputs: CycleInputs) -> str:
        """On the path, where the drives really are: a pose of the measured positions (direct
        kinematics) inside the safe workspace. The reference's pose (``tcp_m``) is checked before it
        is followed, but positions that are not that pose's, each inside its stroke, took Cheope
        past its joints' swing limit, or to positions of no assembly, and the run said DONE (an
        outside tester's plug-in). Off the path (moving to the start) the robot may be coming in
        from outside the margins; a cycle without every drive's position has no new pose. A pose
        the positions do not have (no assembly) is not judged: the 3-nSPU has none at all, and
        Cheope's way there passes the joints' swing limit first."""
        measured = state.tcp_measured_m
        if measured is None or state.tcp_reference_m is None or not all(d.fresh for d in inputs.drives):
            return ""  # None: a robot without direct kinematics (the 3-nSPU's pose is integrated)
        try:
            pose = cast(Any, self.robot.check_pose(np.asarray(measured)))  # compiled: no typed reads
            ok, reason = bool(pose.ok), str(pose.reason) or "(no reason given)"
        except Exception as err:  # a plug-in robot's check: its error ends in the quick stop, named
            return f"the robot's pose check raised {type(err).__name__}: {error_text(err)}"
        if ok:
            return ""
        tcp = ", ".join(f"{x:.4f}" for x in measured)
        return f"the measured TCP ({tcp}) m leaves the safe workspace: {reason}"

    def _reference_fault(self, ref: JointReference) -> str:
        """Why the task's reference may not be followed, or "": its positions (what the drives are
        sent) outside the actuators' range, or its pose (``tcp_m``) outside the safe workspace."""
        why = self.monitor.commanded_fault(self.task.name, ref.position)
        if why:  # the positions themselves: a plug-in's +5 m passed the check of the pose it claimed
            return why
        try:
            pose = cast(Any, self.robot.check_pose(np.asarray(ref.tcp_m)))  # compiled: no typed reads
            ok, reason = bool(pose.ok), str(pose.reason) or "(no reason given)"
        except Exception as err:  # a plug-in robot's check: its error ends in the quick stop, named
            return task_error(self.task.name, "reference's pose check", err)
        return "" if ok else f"task reference leaves the safe workspace: {reason}"

    def _smoothed(self, state: ControllerState, ref: JointReference) -> SmoothingResult:
        """The setpoint one period on towards the task's reference (Ruckig): a reactive reference's
        from ``_smoothing_start``, a planned one's from the setpoint (its docstring says why)."""
        if ref.reactive:
            return self.smoother.track_velocity(
                self._smoothing_start(state),
                ref.position,
                ref.velocity,
                REACTIVE_CORRECTION_PERIODS / self.config.period_s,
            )
        return self.smoother.step(state.setpoint, ref.position, ref.velocity, ref.acceleration)

    @staticmethod
    def _blind(inputs: CycleInputs) -> CycleInputs:
        """A cycle the loop missed, as the task steps through it: late, nothing measured, no command."""
        sensor = inputs.sensor
        return replace(
            inputs,
            drives=tuple(replace(d, fresh=False) for d in inputs.drives),
            sensor=replace(sensor, fresh=False) if sensor is not None else None,
            command=Command.NONE,
            command_value=0.0,
            late=True,
        )

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
        if not self.monitor.shutting_down(state):
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
            for p, cw in zip(powers, state.controlwords)
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
            for p, cw in zip(powers, state.controlwords)
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
        for j, (d, p) in enumerate(zip(inputs.drives, powers)):
            node = self.monitor.node_id(j)
            if d.fresh:
                checks.append(f"{j + 1} {p.name} (0x{d.statusword:04X}){self.monitor.error_code(state, j)}")
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
            state.contact,
            inputs,
            state.sensor_stale > 0 or bool(state.sensor_breach),
            self._witness(state, inputs, history),
            at_rest,
            state.cycle,
            self.config.period_s,
            state.sensor_missing,  # counted by the safety monitor's check earlier in this step
            accelerations=history,
            tcp_m=state.tcp_measured_m,
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
            if b is None:
                return state
            # A sensor the back-off was steered against (contact_guard.back_off_direction) does not
            # say the back-off met more: only the drives' effort does (a -75 N phantom along the
            # normal read as 74.9 N met, and the retrace went back into the part, 33 N true, where
            # the back-off was leaving it).
            effort_only = b.sensor_overruled or bool(w.suspect)
            met_n = back_off_met_n(w, effort_only)
            least = min(b.least_force_n, met_n)
            if least < b.least_force_n:
                state = replace(state, back_off=replace(b, least_force_n=least))
            # The grace covers the momentum the back-off inherits, while the force has not yet fallen;
            # once it fell it was the back-off's doing, and a rise from there is another wall (a 1-mm
            # ball wedged in a 2-mm slot fell from 59.8 to 8.8 N within 30 ms, then rose into the other
            # wall, judged only at the grace's end at 60 N: 98.3 N true). Not where the effort judges
            # alone: the start it fell from was the overruled sensor's (a -75 N spike), and the
            # structure rings for the grace after the back-off's brake (its efforts at 30-75 N with
            # nothing touching).
            left = not effort_only and least < b.entry_force_n - BACK_OFF_WORSE_N
            if (b.cycles > BACK_OFF_GRACE_CYCLES or left) and (
                met_n > max(b.entry_force_n, cfg.max_contact_force_n) + BACK_OFF_WORSE_N
                # ... or rising again from where it had fallen to, past a quarter of the limit: another wall
                # met (a 2-mm slot's other one: caught at 76.9 N above its start, the tool carried on to
                # 123.6 N true); a straight back-off's only: a retrace heads for where the force was
                # calm, not gone
                or (
                    not b.path_m
                    and met_n > least + BACK_OFF_WORSE_N
                    and met_n > ANOTHER_WALL_FRACTION * cfg.max_contact_force_n
                )
            ):
                return self._met_more_force(state, b, met_n, t, events)
            return state
        if not cause:
            return state
        return self._begin_back_off(state, cause, t, events)

    def _met_more_force(
        self, state: ControllerState, b: BackOff, force_n: float, t: float, events: list[Event]
    ) -> ControllerState:
        """The back-off met more force (past its start, or, straight, risen again from the least it
        had fallen to: _guard_contact): a straight one retraces the path the tool came in on
        (contact_guard.begin_retrace); a retrace that meets more, or one with no path to follow,
        ends in the quick stop."""
        origin = state.tcp_measured_m
        retrace = (
            begin_retrace(self.config.safety.contact, b, origin, force_n)
            if origin is not None and not b.path_m
            else None
        )
        if retrace is None:
            why = f"{back_off_summary(b)}, and met {force_n:.1f} N backing off: quick stop"
            return self._faulted(state, why, t, events)
        why = f"{back_off_summary(b)}, and met {force_n:.1f} N: retracing the path it came in on"
        events.append(Event("back_off", Severity.WARNING, why))
        return replace(state, back_off=retrace)

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
        steps = 1 + max(0, state.drives_ran_on)  # the task's steps since ``last`` (``_running``)
        speed = norm3(sub3(tcp_m, last)) / (steps * self.config.period_s)
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
                # the robot plug-in's answer, zipped below: one of another length brakes, as none does
                if len(q) == len(ahead) == self.n:
                    qd = tuple((float(a) - float(c)) / period for a, c in zip(ahead, q))
                    result = self.smoother.track_velocity(
                        self._smoothing_start(state),
                        tuple(float(x) for x in q),
                        qd,
                        REACTIVE_CORRECTION_PERIODS / period,
                        reaction=True,
                    )
                    if result.ok:
                        return replace(state, setpoint=result.setpoint)
                else:
                    why = f"the robot's inverse kinematics gave {len(q)} positions for {self.n} actuators"
                    events.append(Event("back_off", Severity.WARNING, f"back-off brakes: {why}"))
                b = replace(b, braking=True)
                state = replace(state, back_off=b)
        state = self._smooth_to_rest(state, t, events, reaction=True)
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
            tuple(x if math.isfinite(x) else q for x, q in zip(state.last_measured, state.setpoint.position))
        )

    def _moved_on(self, sp: Setpoint, periods: int) -> Setpoint:
        """The setpoint ``periods`` periods on along its own speed: where drives that ran on that far
        are (``_after_hold_up``), or, -1, where drives that stood a step short of it are."""
        shift_s = periods * self.config.period_s
        position = tuple(p + shift_s * v for p, v in zip(sp.position, sp.velocity))
        return Setpoint(position, sp.velocity, sp.acceleration)

    @staticmethod
    def _smoothing_start(state: ControllerState) -> Setpoint:
        """Where a brake or a reactive reference's smoothing starts: the last setpoint, or at rest there
        when a hold-up left the drives standing (``drives_held``): sent on at a speed they no longer
        have, they would jump after it into whatever the tool touches.

        Not for a planned reference (``smoother.step``): its path runs on one period a cycle, and a
        setpoint restarted from rest chases it (one 9.6-ms hold-up in the path's half lap, simulated
        time: tracking error 0.71 mm RMS, 4.8 mm at most; 0.95 mm RMS over the bus), where the drives
        going on catch the path up within a few milliseconds (21 um RMS, 0.38 mm at most).
        """
        return Setpoint.at_rest(state.setpoint.position) if state.drives_held else state.setpoint

    def _smooth_to_rest(
        self, state: ControllerState, t: float, events: list[Event], reaction: bool = False
    ) -> ControllerState:
        result = self.smoother.brake(self._smoothing_start(state), reaction)
        if not result.ok:
            return replace(
                self._enter(state, Mode.FAULT, t, events, Severity.FAULT, result.message),
                fault_reason=result.message,
            )
        return replace(state, setpoint=result.setpoint)


def task_error(name: str, what: str, err: BaseException) -> str:
    """The fault reason of a task whose ``what`` raised ``err``: the law's quick stop follows, as for
    any fault (it was an exception out of the loop: the drives left to their SYNC watchdog)."""
    return f"task {name}: its {what} raised {type(err).__name__}: {error_text(err)}"


def checked_step(name: str, out: object, n: int) -> TaskStep | str:
    """A task step's result for ``n`` actuators as the law's own copy, or why it cannot be used.

    The copy is a ``TaskStep`` holding a ``JointReference`` of plain tuples of floats, made once:
    the law checks it and follows it, so a plug-in's subclass whose fields answer differently on
    each read (the range check first, Ruckig after) or an object changed after the return cannot
    slip past the checks. Wrong types (text, None, a list, an event that is not an ``Event``, a
    fault that is not text) are named instead of failing later inside the law or the recorder,
    which ended the loop with a traceback and no quick stop (two outside testers')."""
    if not isinstance(out, TaskStep):
        return f"task {name} gave {type(out).__name__}, not a TaskStep"
    # read as Any: compiled, a typed read of a wrong type is itself a TypeError naming no task
    step = cast(Any, out)
    ref = step.reference
    if not isinstance(ref, JointReference):
        return f"task {name} gave a reference of type {type(ref).__name__}, not a JointReference"
    fields = cast(Any, ref)
    numbers: list[tuple[float, ...]] = []
    for what, values in (
        ("position", fields.position),
        ("velocity", fields.velocity),
        ("acceleration", fields.acceleration),
        ("tcp_m", fields.tcp_m),
    ):
        copied = _numbers(values)
        if isinstance(copied, str):
            return f"task {name} gave a reference {what} {copied}"
        numbers.append(copied)
    p, v, a, tcp = numbers
    if not len(p) == len(v) == len(a) == n:
        return (
            f"task {name} gave a reference of {len(p)} positions, "
            f"{len(v)} velocities and {len(a)} accelerations for {n} actuators"
        )
    if len(tcp) != 3:
        return f"task {name} gave a reference tcp_m of {len(tcp)} values, not 3"
    on_path, reactive, contact = fields.on_path, fields.reactive, fields.contact
    finished, fault, events = step.finished, step.fault, step.events
    if not (type(on_path) is bool and type(reactive) is bool and type(finished) is bool):
        return f"task {name} gave on_path, reactive or finished that is not True or False"
    if not isinstance(contact, ContactExpectation):
        return f"task {name} gave a contact expectation of type {type(contact).__name__}"
    if not isinstance(fault, str):
        return f"task {name} gave a fault of type {type(fault).__name__}, not text"
    if type(events) is not tuple:
        return f"task {name} gave events as {type(events).__name__}, not a tuple of Event"
    copied_events: tuple[Event, ...] = ()
    if events:  # rare: most steps give none
        for e in events:
            if not _is_event(e):
                return f"task {name} gave an event that is not an Event(kind, severity, message): {str(e)[:60]!r}"
        copied_events = tuple(Event(str(e.kind), Severity(e.severity), str(e.message)) for e in events)
    return TaskStep(
        step.state,
        JointReference(p, v, a, (tcp[0], tcp[1], tcp[2]), on_path, reactive, contact),
        finished,
        str.__str__(fault)[:500],  # text, not a subclass's slice; a 1-MB fault was printed whole, twice
        copied_events,
    )


def _numbers(values: object) -> tuple[float, ...] | str:
    """``values`` (a tuple or a list) as a tuple of floats, or what is wrong with them. A real number
    of any type (numpy's float32 and int64 too) is one; text, a bool and anything else is not."""
    if not isinstance(values, (tuple, list)):
        return f"as {type(values).__name__}, not a tuple of numbers"
    items = cast("Sequence[object]", values)  # compiled, a cast to tuple is a check: a list failed it
    out: list[float] = []
    for x in items:
        if type(x) is float:  # nearly always: no conversion
            out.append(x)
            continue
        if isinstance(x, (str, bytes, bool)) or not hasattr(x, "__float__"):
            return f"holding {type(x).__name__} {str(x)[:40]!r}"
        out.append(float(cast(Any, x)))
    return tuple(out)


def _is_event(e: object) -> bool:
    if not isinstance(e, Event):
        return False
    fields = cast(Any, e)
    return (
        isinstance(fields.kind, str)
        and isinstance(fields.severity, Severity)
        and isinstance(fields.message, str)
    )
