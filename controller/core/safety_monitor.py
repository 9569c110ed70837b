"""The safety monitor: the checks of one cycle's inputs that the control law's supervisor acts on.

Pure, like the law (controller/core/control_law.py): each check reads the state and the cycle's
inputs and returns what is wrong (a fault reason, "" when nothing is) or the state with what it
noted (a warning given once, a running count); the supervisor decides the mode. In the order of
precedence of ``check``: the force sensor's breach, staleness and saturation, the contact-force
limit outside the guarded modes, the bus's anomalies (rogue frames, a second master, floods), late
cycles, silent drives, the actuators' strokes; beside them the drives' position plausibility
(``position_jump``), following error and power states (``fault_reason``), their EMCYs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

from controller.core.cia402 import PowerState, controlword_towards
from controller.core.controller_state import ControllerState, Mode
from controller.core.cycle_data import (
    SENSOR_FORCE_SATURATED,
    Anomaly,
    BusAnomaly,
    CycleInputs,
    EmcyAction,
    Event,
    Reaction,
    Severity,
)
from controller.core.ports import ChecksActuators, PoseStatus, Robot
from controller.core.records import replace

if TYPE_CHECKING:
    from controller.core.law_config import LawConfig


ANOMALY_TEXT = {
    Anomaly.UNKNOWN_FRAME: "frame(s) from a COB-ID no configured node uses",
    Anomaly.EXTENDED_FRAME: "frame(s) with a 29-bit identifier (CANopen's COB-IDs are 11-bit)",
    Anomaly.UNKNOWN_EMCY: "EMCY from a node that is not configured",
    Anomaly.UNKNOWN_HEARTBEAT: "heartbeat from a node that is not configured",
    Anomaly.FOREIGN_SYNC: "SYNC the controller did not send (a second SYNC producer)",
    Anomaly.FOREIGN_NMT: "NMT command the controller did not send",
    Anomaly.FOREIGN_COMMAND: "frame on a COB-ID only the controller sends (a second master)",
    Anomaly.FOREIGN_SDO: "SDO answer to a request the controller did not send (a second SDO client)",
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


# The force sensor's troubles: with the drives enabled, their fault is a protective back-off.
SENSOR_TROUBLE = frozenset(("sensor_stale", "sensor_saturated"))


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
    if a.kind == Anomaly.EXTENDED_FRAME:
        return f"{a.count} {ANOMALY_TEXT[a.kind]} (identifier 0x{a.cob_id:08X})"
    return f"{a.count} {ANOMALY_TEXT[a.kind]}{_from_node(a.node_id)} (COB-ID 0x{a.cob_id:03X})"


def _from_node(node_id: int) -> str:
    return f" from node {node_id}" if node_id else ""


def listed(names: list[str]) -> str:
    """ "2", "1 and 2", "1, 2, 3 and the force sensor"."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


NMT_STATE_NAMES = {0: "boot-up (it restarted)", 4: "STOPPED", 5: "OPERATIONAL", 127: "PRE-OPERATIONAL"}


def error_code_text(code: int) -> str:
    """ ", error code 0x3220" (the drive's last EMCY: CiA 301, the code 0x603F holds too), or ""."""
    return f", error code 0x{code:04X}" if code else ""


def error_text(err: BaseException) -> str:
    """An exception's text, at most 200 characters, whatever its ``__str__`` does (a plug-in's own
    exception may raise there): for the fault reasons of a plug-in's error (here and control_law)."""
    try:
        return str.__str__(str(err))[:200]
    except Exception:
        return "(its text could not be read)"


def every_device_silent(inputs: CycleInputs) -> bool:
    """No drive and no force sensor gave a usable sample this cycle: the bus, the simulator or the
    host they share paused, not one device (a sensor that is not configured does not count)."""
    sensor = inputs.sensor
    return all(not d.fresh for d in inputs.drives) and (sensor is None or not sensor.fresh)


def missing_alone(inputs: CycleInputs, alone: tuple[int, ...]) -> tuple[int, ...]:
    """Each drive's cycles of silence in a row in which another device was heard (its own): 0 when
    it is heard, unchanged in a cycle every device shares."""
    if every_device_silent(inputs):
        return alone
    return tuple(0 if d.fresh else a + 1 for d, a in zip(inputs.drives, alone))


# The modes in which the contact guard watches (the drives enabled, the law commanding them).
GUARDED_MODES = frozenset((Mode.HOLDING, Mode.RUNNING, Mode.PAUSED, Mode.STOPPING, Mode.BACKING_OFF))


class SafetyMonitor:
    """The checks of each cycle's inputs, for a robot and the law's configuration."""

    def __init__(self, robot: Robot, config: LawConfig) -> None:
        self.config = config
        self.n = robot.n_actuators
        # Robots that know their actuators' strokes check the measured positions every cycle.
        self._check_actuators = robot.check_actuators if isinstance(robot, ChecksActuators) else None

    def node_id(self, j: int) -> int:
        ids = self.config.drive_node_ids
        return ids[j] if j < len(ids) else j + 1

    def react(
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

    def check(  # noqa: C901  (the safety checks in their order of precedence, one branch each)
        self, state: ControllerState, inputs: CycleInputs, events: list[Event]
    ) -> tuple[ControllerState, str]:
        """Configurable checks of the inputs; returns the updated state and a fault reason or ""."""
        sc = self.config.safety
        sensor = inputs.sensor
        stale = 0
        if state.sensor_breach:
            why = self.sensor_breach_fault(state)
            if why:
                return state, why
        elif sensor is not None:  # a breached sensor's frames count for nothing, nor does their absence
            if sensor.fresh:
                stale = state.sensor_stale + 1 if sensor.counter == state.sensor_counter else 0
                state = replace(state, sensor_counter=sensor.counter, sensor_stale=stale)
                if state.sensor_missing:
                    state = replace(state, sensor_missing=0, sensor_missing_alone=0)
            else:
                shared = every_device_silent(inputs)  # not its own: counted apart (silent_too_long)
                alone = state.sensor_missing_alone + (0 if shared else 1)
                state = replace(state, sensor_missing=state.sensor_missing + 1, sensor_missing_alone=alone)
        if sensor is not None and sensor.fresh:
            f = sensor.force_n
            magnitude = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
            if magnitude > sc.max_contact_force_n and state.mode not in GUARDED_MODES:
                # Drives not yet enabled: nothing to back off with. Enabled, the contact guard judges.
                return state, f"contact force {magnitude:.1f} N above the limit of {sc.max_contact_force_n} N"
            if sensor.status & SENSOR_FORCE_SATURATED:
                state, why = self.react(
                    state,
                    sc.on_sensor_saturated,
                    "sensor_saturated",
                    f"force sensor saturated (status 0x{sensor.status:02X})",
                    events,
                )
                if why:
                    return state, why
        if sensor is not None and stale >= sc.sensor_stale_cycles:  # stale > 0 only with a sensor
            state, why = self.react(
                state,
                sc.on_sensor_stale,
                "sensor_stale",
                f"force sensor stale: counter stuck at {sensor.counter} for {stale} cycles",
                events,
            )
            if why:
                return state, why
        silence = self.silence(state)
        if silence:
            return state, silence
        if (
            self.config.sensor_in_task
            and not state.sensor_breach
            and state.sensor_missing >= sc.sensor_stale_cycles  # (silent_too_long's least, first: cheap)
            and self.silent_too_long(state.sensor_missing, state.sensor_missing_alone, sc.sensor_stale_cycles)
        ):
            # No usable sample (missing, or two senders on its COB-ID): no new information, as a counter
            # that does not advance, so the same tolerance (the contour task holds from the 4th cycle).
            state, why = self.react(
                state,
                sc.on_sensor_stale,
                "sensor_stale",
                f"force sensor: no usable sample for {state.sensor_missing} cycles",
                events,
            )
            if why:
                return state, why
        if inputs.lost_heartbeats:
            state, why = self.react(
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
            state, why = self.react(
                state,
                sc.on_error_frames,
                "error_frames",
                f"{inputs.error_frames} CAN error frame(s) received",
                events,
            )
            if why:
                return state, why
        state, why = self.anomalies(state, inputs, events)
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
            state, why = self.react(
                state, sc.on_late_cycles, "late_cycles", f"the loop woke late {late} cycles in a row", events
            )
            if why:
                return state, why
        if self._check_actuators is not None:
            why = self._actuators_fault(tuple(d.position for d in inputs.drives))
            if why:
                return state, f"measured: {why}"
        return state, ""

    def commanded_fault(self, task_name: str, q: tuple[float, ...]) -> str:
        """The task's reference positions (what the drives will be sent) outside the actuators'
        range, for a robot that knows it; "" else. The pose check of its ``tcp_m`` did not see a
        plug-in whose positions said otherwise: +5 m on every actuator reached the drives."""
        why = self._actuators_fault(q)
        return f"task {task_name} commands {why}" if why else ""

    def _actuators_fault(self, q: tuple[float, ...]) -> str:
        """The robot's ``check_actuators`` of ``q``: its reason, or "" (none, or no such check). A
        plug-in robot's check that raises or gives no ``PoseStatus`` is a reason too: it ended the
        loop with a traceback, the drives left enabled."""
        if self._check_actuators is None:
            return ""
        check = cast(Callable[[tuple[float, ...]], Any], self._check_actuators)  # compiled: no typed reads
        try:
            status = check(q)
            if not isinstance(status, PoseStatus):
                return f"(the robot's check_actuators gave {type(status).__name__}, not a PoseStatus)"
            fields = cast(
                Any, status
            )  # compiled, a narrowed PoseStatus's reads are typed: numpy's bool_ failed
            ok, reason = bool(fields.ok), str(fields.reason)
        except Exception as err:
            return f"(the robot's check_actuators raised {type(err).__name__}: {error_text(err)})"
        return "" if ok else reason or "(the robot's check_actuators gave no reason)"

    def retract_on_breach(self, state: ControllerState, a: BusAnomaly) -> bool:
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

    def sensor_breach_fault(self, state: ControllerState) -> str:
        """The fault after a sensor breach: out of RUNNING (a stop, a pause), or past the retract's time."""
        why = f"force sensor not trusted: {state.sensor_breach}"
        if state.mode != Mode.RUNNING:
            return why
        limit_s = self.config.safety.sensor_breach_retract_s
        if (state.cycle - state.sensor_breach_cycle) * self.config.period_s > limit_s:
            return f"{why}; the task did not retract within {limit_s:g} s"
        return ""

    def silent_too_long(self, streak: int, alone: int, limit: int) -> bool:
        """A device ``streak`` cycles without a usable sample, ``alone`` of them while another device
        was heard: past its own ``limit`` (loop.max_missing_s, safety.sensor_stale_s) on those, or
        past loop.max_bus_silence_s in all. A pause every device shares is the bus's, the
        simulator's or their host's (a host took the simulator's CPU away for 105 ms, in CI), and
        the task holds meanwhile, as the drives do through the loop's own pauses."""
        return alone >= limit or streak >= max(limit, self.config.max_bus_silence_cycles)

    def drive_silent_too_long(self, state: ControllerState, j: int) -> bool:
        alone = state.missing_alone[j] if j < len(state.missing_alone) else state.missing_streak[j]
        return self.silent_too_long(state.missing_streak[j], alone, self.config.max_missing_cycles)

    def silence(self, state: ControllerState) -> str:
        """Every drive (and the sensor) silent too long (``silent_too_long``), named in one fault."""
        limit = self.config.max_missing_cycles
        if max(state.missing_streak) < limit:  # silent_too_long's least, first: this runs every cycle
            return ""
        silent = [j for j in range(len(state.missing_streak)) if self.drive_silent_too_long(state, j)]
        if not silent:
            return ""
        sensor = self.silent_too_long(state.sensor_missing, state.sensor_missing_alone, limit)
        if len(silent) == 1 and not sensor:
            return f"drive {silent[0] + 1}: no TPDO for {state.missing_streak[silent[0]]} cycles"
        cycles = min(state.missing_streak[j] for j in silent)
        names = [str(j + 1) for j in silent]
        if sensor:
            names.append("the force sensor")
            cycles = min(cycles, state.sensor_missing)
        return f"{'drives' if len(silent) > 1 else 'drive'} {listed(names)} silent for {cycles} cycles"

    def anomalies(
        self, state: ControllerState, inputs: CycleInputs, events: list[Event]
    ) -> tuple[ControllerState, str]:
        """This cycle's bus anomalies by their configured reaction; "warn" is reported per burst."""
        sc = self.config.safety
        seen: dict[str, int] = {}
        texts: dict[str, str] = {}
        for a in inputs.anomalies:
            reaction = sc.reaction_to(a.kind)
            if reaction == Reaction.FAULT and self.retract_on_breach(state, a):
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
                        f"burst ended: {frames} {self.burst_what(key)} in {cycles} cycle(s)",
                    )
                )
                continue
            frames, cycles = frames + seen.pop(key), cycles + 1
            if state.cycle - reported >= every:
                events.append(
                    Event(
                        kind,
                        Severity.WARNING,
                        f"burst goes on: {frames} {self.burst_what(key)} in {cycles} cycle(s) so far",
                    )
                )
                reported = state.cycle
            bursts.append((key, frames, cycles, reported))
        for key, frames in seen.items():  # bursts that start in this cycle
            events.append(Event(key.split(":")[0], Severity.WARNING, f"burst starts: {texts[key]}"))
            bursts.append((key, frames, 1, state.cycle))
        return replace(state, bursts=tuple(bursts)), ""

    @staticmethod
    def burst_what(key: str) -> str:
        kind, node, cob = key.split(":")
        return f"{ANOMALY_TEXT[Anomaly(kind)]}{_from_node(int(node))} (COB-ID {cob})"

    def position_jump(
        self, state: ControllerState, inputs: CycleInputs, skipped: int = 0
    ) -> tuple[str, tuple[bool, ...]]:
        """Fresh positions further from the last trusted ones than the actuator can move: a lying encoder
        or frame. Returns the fault (none in CONFIGURING or FAULT) and which drives' positions are not
        to be trusted (judged in FAULT too: hold targets come only from trusted positions). ``skipped``:
        deadlines the loop skipped before this step, periods the drives moved on through as well."""
        cfg = self.config
        tolerance = cfg.safety.max_position_jump
        flags = [False] * self.n
        if not math.isfinite(tolerance) or state.mode == Mode.CONFIGURING:
            return "", tuple(flags)
        reason = ""
        for j, (d, last, gap) in enumerate(zip(inputs.drives, state.last_measured, state.missing_streak)):
            if not (d.fresh and math.isfinite(last)):
                continue
            periods = gap + 1 + skipped
            possible = cfg.max_speed * periods * cfg.period_s + tolerance
            step = abs(d.position - last)
            if step > possible:  # also catches NaN below: NaN > x is False, the finite check is elsewhere
                flags[j] = True
                u = cfg.position_unit
                reason = reason or (
                    f"drive {j + 1} position jumped {step:.4f} {u} in {periods} period(s) (from {last:.4f} to "
                    f"{d.position:.4f} {u}); at most {possible:.4f} {u} is possible "
                    f"({cfg.max_speed} {u}/s + safety.max_position_jump {tolerance} {u})"
                )
        return ("" if state.mode == Mode.FAULT else reason), tuple(flags)

    def following_error(self, state: ControllerState, inputs: CycleInputs) -> str:
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
        # After a hold-up the sample was taken somewhere along the drives' extrapolation, up to its E
        # periods past the expected position (control_law ``_after_hold_up``).
        run_on_s = (
            self.config.drive_extrapolation_periods * t_s if state.drives_ran_on or state.drives_held else 0.0
        )
        # ... and the sample's place in its period is known to a period's travel: at 25 Hz a path's drives
        # at 0.3 m/s sampled 4 mm from the expected position, where the contour's over a bus at 400 Hz
        # sampled at most 0.71 mm off (the window, 3 mm, is for the latter: a jammed carriage).
        for j, (d, q, v, a) in enumerate(zip(inputs.drives, sp.position, sp.velocity, sp.acceleration)):
            expected = q - v * t_s + 0.5 * a * t_s * t_s
            allowed = window + abs(v) * (t_s + run_on_s)
            if d.fresh and abs(d.position - expected) > allowed:
                u = self.config.position_unit
                return (
                    f"drive {j + 1} following error {abs(d.position - expected):.4f} {u} beyond {allowed:.4f} {u} "
                    f"(safety.following_window {window} {u} and the setpoint's travel in a period; measured "
                    f"{d.position:.4f} {u}, expected {expected:.4f} {u} at this sample)"
                )
        return ""

    def configuring_fault(self, state: ControllerState, inputs: CycleInputs, emcy_fault: str) -> str:
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

    def fault_reason(
        self, state: ControllerState, inputs: CycleInputs, powers: tuple[PowerState, ...], emcy_fault: str
    ) -> str:
        # ENABLING after the operator's reset resets the drives' faults and judges its attempts itself;
        # a drive in FAULT at the start, or one that faults on its way to enabled, is a fault
        resetting = state.mode == Mode.ENABLING and bool(state.fault_resets)
        for j, (p, streak) in enumerate(zip(powers, state.missing_streak)):
            # Judged on this cycle's TPDO only: a statusword not refreshed (missing frame) is old news,
            # e.g. the FAULT a reset has just cleared; silence has its own limit below.
            faulted = p in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE)
            if inputs.drives[j].fresh and faulted and not resetting:
                return (
                    f"drive {j + 1} reports {p.name} (statusword 0x{inputs.drives[j].statusword:04X})"
                    + self.error_code(state, j)
                )
            if streak >= self.config.max_missing_cycles and self.drive_silent_too_long(state, j):
                # (silence() names them first, all at once)
                return f"drive {j + 1}: no TPDO for {streak} cycles"
        if emcy_fault:
            return emcy_fault
        if state.mode in (Mode.HOLDING, Mode.RUNNING, Mode.PAUSED, Mode.BACKING_OFF) or (
            state.mode == Mode.STOPPING and not self.shutting_down(state)
        ):
            for j, p in enumerate(powers):
                if inputs.drives[j].fresh and p != PowerState.OPERATION_ENABLED:
                    return f"drive {j + 1} left OPERATION ENABLED (now {p.name})"
            following = self.following_error(state, inputs)
            if following:
                return following
        for j, x in enumerate(inputs.drives):
            if not math.isfinite(x.position):
                return f"drive {j + 1} position is not a number"
        return ""

    def error_code(self, state: ControllerState, j: int) -> str:
        return error_code_text(state.error_codes[j]) if j < len(state.error_codes) else ""

    def note_error_codes(self, state: ControllerState, inputs: CycleInputs) -> ControllerState:
        """Each drive's last error code as its EMCYs say (0 after an "error reset" EMCY)."""
        codes = list(state.error_codes) or [0] * self.n
        index = {self.node_id(j): j for j in range(self.n)}
        for e in inputs.emcy:
            j = index.get(e.node_id)
            if j is not None and self.config.emcy_action(e.node_id, e.error_code) == EmcyAction.FAULT:
                codes[j] = e.error_code  # a warning's code is no fault's
        return replace(state, error_codes=tuple(codes))

    def emcy_fault(self, inputs: CycleInputs) -> str:
        """The first EMCY of this cycle whose configured reaction is a fault ("" if none)."""
        for e in inputs.emcy:
            if e.error_code != 0 and self.config.emcy_action(e.node_id, e.error_code) == EmcyAction.FAULT:
                return f"EMCY from node {e.node_id}: error code 0x{e.error_code:04X}, register 0x{e.error_register:02X}"
        return ""

    def shutting_down(self, state: ControllerState) -> bool:
        return any(
            cw != controlword_towards(PowerState.OPERATION_ENABLED, PowerState.OPERATION_ENABLED)
            for cw in state.controlwords
        )
