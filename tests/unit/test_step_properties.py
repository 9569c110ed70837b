"""Hypothesis properties of the pure control step, in closed loop on simulated time.

``ControlLaw.step`` runs against the in-process simulated drives (sim_backend/loopback.py)
with ``SimulatedTime``: a run of a few hundred cycles takes a fraction of a second and is
deterministic. Between the exchange and the step the harness perturbs the bus's feedback
the way a real bus and loop shell can (a TPDO missing, a stale sample, a late wake-up, a
remote command, an injected fault), exactly as ``CyclicExchange`` would present it: a
missing TPDO keeps the last values received, flagged not fresh, NaN before the first one.

Properties:
  a. the targets never imply a velocity or acceleration beyond the actuator limits and stay
     within the actuator stroke;
  b. no jump at enable: while ENABLING and in the first cycles after OPERATION ENABLED the
     target is the measured position, and every RPDO a drive receives carries where it is;
  c. every fault cause leads, within a bounded number of cycles, to Mode.FAULT with quick
     stop / disable voltage controlwords, and the law stays there.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import pytest
from hypothesis import HealthCheck, event, given, note, reject, settings
from hypothesis import strategies as st

from controller.assembly import build_law
from controller.config import Config, ConfigError, load_config
from controller.core.control_law import ControlLaw, ControllerState, Mode
from controller.core.cycle_data import (
    BusFeedback,
    Command,
    CycleOutputs,
    DriveFeedback,
    cycle_inputs,
)
from controller.core.setpoint_smoothing import AxisLimits, RuckigSmoother, Setpoint
from controller.robots.cheope import WorkspaceError
from controller.shell.loop import SimulatedTime
from drivers.cia402 import (
    PowerState,
    decode_statusword,
)
from sim_backend.loopback import LoopbackExchange

PROPERTY_SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# The tolerance of the limit checks. Ruckig (include/ruckig/profile.hpp) accepts a profile
# whose velocity or acceleration passes its limit by v_eps = a_eps = 1e-12 (absolute). Every
# setpoint is a sample of a profile that starts at the previous sample, so consecutive targets
# lie on one continuous jerk-limited curve: their first difference / T is the mean velocity
# over [t_k, t_k+1], |.| <= v_max + v_eps, their second difference / T^2 a triangle-weighted
# mean of the acceleration over [t_k-1, t_k+1], |.| <= a_max + a_eps. (A profile that ends
# within the period is sampled at its end, setpoint_smoothing.py: that shortens a step, never
# lengthens it.) What is left is rounding: each target x carries up to eps |x| (eps = 2.2e-16),
# the differences add a few of those and divide them by T or T^2, e.g. 16 eps 0.9 m / (1 ms)^2 =
# 3e-9 m/s^2. The differences are taken of the floats the step returns, not of the counts on
# the wire: those add +-0.5 count each (0.03 m/s^2 at 400 Hz and 10^7 counts/m, more than the
# whole Ruckig margin), which is quantisation of the drive's input, not a property of the law.
RUCKIG_EPS = 1e-12  # [m/s], [m/s^2]
FLOAT_EPS = 2.220446049250313e-16


def velocity_tolerance(x_max_m: float, period_s: float) -> float:
    return RUCKIG_EPS + 4.0 * FLOAT_EPS * x_max_m / period_s


def acceleration_tolerance(x_max_m: float, period_s: float) -> float:
    return RUCKIG_EPS + 16.0 * FLOAT_EPS * x_max_m / (period_s * period_s)


# Stale input: before the first TPDO, CyclicExchange reports statusword 0 and a NaN position.
NO_FRAME_YET = DriveFeedback(0, math.nan, False)


# -- the harness ----------------------------------------------------------------------------

@dataclass
class CycleRecord:
    k: int
    inputs_fresh: tuple[bool, ...]
    measured: tuple[float, ...]
    powers: tuple[PowerState, ...]
    state: ControllerState
    outputs: CycleOutputs


@dataclass
class Perturbation:
    """What happens to the feedback of each cycle before the step sees it (all cycle-indexed)."""

    missing: frozenset[tuple[int, int]] = frozenset()  # (cycle, drive index): the TPDO did not arrive
    stale: frozenset[tuple[int, int]] = frozenset()  # (cycle, drive index): it repeats the previous sample
    late: frozenset[int] = frozenset()  # the loop woke late
    commands: dict[int, Command] = field(default_factory=dict)
    stop_from: int | None = None  # stop requested from this cycle on


NO_PERTURBATION = Perturbation()


class ClosedLoop:
    """The law, the loopback drives and simulated time, one ``cycle()`` per period."""

    def __init__(self, cfg: Config, law: ControlLaw | None = None) -> None:
        self.cfg = cfg
        self.law = law or build_law(cfg)
        self.period = cfg.period_s
        self.time = SimulatedTime()
        self.ex = LoopbackExchange(cfg, self.time.clock)
        self.state = self.law.initial_state()
        self.outputs: CycleOutputs | None = None
        self.k = 0
        self.delivered = [NO_FRAME_YET] * len(self.ex.drives)  # last values a real exchange would hold
        self.previous_raw: tuple[DriveFeedback, ...] | None = None
        self.records: list[CycleRecord] = []
        # every RPDO as the drives receive it: (cycle, drive index, controlword, target counts, position counts)
        self.rpdos: list[tuple[int, int, int, int, int]] = []
        for j, d in enumerate(self.ex.drives):
            d.on_rpdo = self._recording_rpdo(j, d, d.on_rpdo)

    def _recording_rpdo(self, j: int, drive, original: Callable[[int, int], None]) -> Callable[[int, int], None]:
        def on_rpdo(controlword: int, target_counts: int) -> None:
            self.rpdos.append((self.k, j, controlword, target_counts, drive.position_counts()))
            original(controlword, target_counts)

        return on_rpdo

    def cycle(self, perturbation: Perturbation = NO_PERTURBATION,
              extra: Callable[[int, BusFeedback], BusFeedback] | None = None) -> CycleRecord:
        k, p = self.k, perturbation
        self.time.sleep_until((k + 1) * self.period)
        self.ex.send(self.outputs)
        fb = self.ex.collect(self.time.clock() + 0.8 * self.period)
        raw = fb.drives
        drives = []
        for j, d in enumerate(raw):
            if (k, j) in p.missing or not d.fresh:
                drives.append(replace(self.delivered[j], fresh=False))
                continue
            if (k, j) in p.stale and self.previous_raw is not None:
                d = replace(self.previous_raw[j], fresh=True)
            drives.append(d)
            self.delivered[j] = d
        self.previous_raw = raw
        fb = replace(fb, drives=tuple(drives))
        if extra is not None:
            fb = extra(k, fb)
        stop = p.stop_from is not None and k >= p.stop_from
        inputs = cycle_inputs(fb, stop_requested=stop, command=p.commands.get(k, Command.NONE), late=k in p.late)
        self.state, self.outputs, _ = self.law.step(self.state, inputs, k * self.period)
        rec = CycleRecord(k, tuple(d.fresh for d in inputs.drives), tuple(d.position for d in inputs.drives),
                          tuple(decode_statusword(d.statusword) for d in inputs.drives), self.state, self.outputs)
        self.records.append(rec)
        self.k += 1
        return rec


def build_or_reject(overrides: dict) -> tuple[Config, ControlLaw]:
    """A configuration the service would accept, or hypothesis drops the example."""
    try:
        cfg = load_config(overrides=overrides)
        return cfg, build_law(cfg)
    except (ConfigError, WorkspaceError):
        reject()
        raise  # unreachable: reject() raises


def trim_streaks(cycles_by_drive: dict[int, set[int]], max_streak: int) -> set[int]:
    """Drop cycles from each set so that no run of consecutive cycles reaches ``max_streak``."""
    kept: set[int] = set()
    for cycles in cycles_by_drive.values():
        streak, last = 0, None
        for c in sorted(cycles):
            streak = streak + 1 if last is not None and c == last + 1 else 1
            if streak < max_streak:
                kept.add(c)
                last = c
            else:
                last = None  # c is delivered: the next missing cycle starts a new run
    return kept


# -- a. no output beyond the limits ------------------------------------------------------------

@st.composite
def limited_task(draw):
    """A path task and actuator limits within the configuration's valid ranges."""
    rate = draw(st.sampled_from([200.0, 250.0, 400.0, 500.0, 1000.0]))
    return {
        "loop.rate_hz": rate,
        "loop.hold_before_task_s": draw(st.floats(0.0, 0.05)),
        "task.path.center_m": [draw(st.floats(-0.01, 0.01)), draw(st.floats(-0.01, 0.01)), draw(st.floats(0.47, 0.53))],
        "task.path.radius_m": draw(st.floats(0.01, 0.08)),
        "task.path.speed_m_s": draw(st.floats(0.02, 0.4)),
        "task.path.laps": draw(st.floats(0.05, 1.0)),
        "task.path.ramp_s": draw(st.sampled_from([0.0, 0.02, 0.1, 0.3])),
        "actuators.max_velocity_m_s": draw(st.floats(0.05, 1.0)),
        "actuators.max_acceleration_m_s2": draw(st.floats(0.5, 20.0)),
        "actuators.max_jerk_m_s3": draw(st.floats(20.0, 2000.0)),
        # start away from the path, so that the move to its start meets the limits too
        "sim.drive.initial_positions_m": [0.71508 + draw(st.floats(-0.1, 0.1)),
                                          0.56794 + draw(st.floats(-0.1, 0.1)),
                                          0.42697 + draw(st.floats(-0.1, 0.1))],
    }


@st.composite
def perturbations(draw, cycles: int, n_drives: int, max_missing: int, max_late: int):
    """Missing and stale TPDOs, late wake-ups, pause/resume and maybe a stop; never enough to fault."""
    def bursts(max_len: int) -> list[tuple[int, int]]:
        return draw(st.lists(st.tuples(st.integers(0, cycles - 1), st.integers(1, max_len)), max_size=8))

    missing = {}
    for j in range(n_drives):
        cs = {c + i for c, n in bursts(max_missing + 2) for i in range(n)}
        missing[j] = cs
    missing_pairs = set()
    for j, cs in missing.items():
        missing_pairs |= {(c, j) for c in trim_streaks({j: cs}, max_missing)}
    stale = {(c, j) for c, j in draw(st.lists(st.tuples(st.integers(0, cycles - 1), st.integers(0, n_drives - 1)),
                                              max_size=20))}
    late = trim_streaks({0: {c + i for c, n in bursts(max_late + 5) for i in range(n)}}, max_late)
    commands: dict[int, Command] = {}
    for c in draw(st.lists(st.integers(0, cycles - 1), max_size=6, unique=True)):
        commands[c] = draw(st.sampled_from([Command.PAUSE, Command.RESUME]))
    stop_from = draw(st.none() | st.integers(0, cycles - 1))
    return Perturbation(frozenset(missing_pairs), frozenset(stale), frozenset(late), commands, stop_from)


@PROPERTY_SETTINGS
@given(task=limited_task(), data=st.data())
def test_targets_never_exceed_the_actuator_limits_or_leave_the_stroke(task, data):
    cfg, law = build_or_reject(task)
    cycles = min(600, int(0.75 * cfg.loop.rate_hz))
    p = data.draw(perturbations(cycles, law.n, cfg.loop.max_missing_cycles, cfg.safety.max_consecutive_late_cycles))
    loop = ClosedLoop(cfg, law)
    for _ in range(cycles):
        loop.cycle(p)
    modes = [r.state.mode for r in loop.records]
    note(f"modes: {[(m.name, modes.count(m)) for m in Mode if m in modes]}")
    end = len(modes)
    if Mode.FAULT in modes:
        # The perturbations stay below every threshold: the only fault accepted is Ruckig's own
        # refusal of a valid input (a finding, pinned by the strict xfail below). A fault holds
        # the measured positions under quick stop: not a trajectory the limits apply to.
        assert loop.state.fault_reason.startswith("Ruckig refused"), loop.state.fault_reason
        event("Ruckig refused a valid input")
        end = modes.index(Mode.FAULT)

    a = cfg.actuators
    vmax, amax = a.max_velocity_m_s, a.max_acceleration_m_s2
    lo, hi = cfg.robot.model("cheope").stroke_min_m, cfg.robot.model("cheope").stroke_max_m
    T = cfg.period_s
    # From the first step that has heard every drive (before it, see the strict xfail below).
    started = next(i for i, m in enumerate(modes) if m != Mode.CONFIGURING)
    targets = [r.outputs.targets for r in loop.records[started:end]]
    v_tol, a_tol = velocity_tolerance(hi, T), acceleration_tolerance(hi, T)
    for i, x in enumerate(targets):
        assert all(lo <= q <= hi for q in x), f"cycle {started + i}: target {x} outside the stroke [{lo}, {hi}] m"
    for i in range(1, len(targets)):
        for j in range(law.n):
            v = (targets[i][j] - targets[i - 1][j]) / T
            assert abs(v) <= vmax + v_tol, \
                f"cycle {started + i}, actuator {j + 1}: targets imply {v} m/s, limit {vmax} ({modes[started + i].name})"
    for i in range(2, len(targets)):
        for j in range(law.n):
            acc = (targets[i][j] - 2.0 * targets[i - 1][j] + targets[i - 2][j]) / (T * T)
            assert abs(acc) <= amax + a_tol, \
                f"cycle {started + i}, actuator {j + 1}: targets imply {acc} m/s^2, limit {amax} ({modes[started + i].name})"
    # and the smoother's own state agrees
    for r in loop.records[started:end]:
        sp = r.state.setpoint
        assert max(abs(v) for v in sp.velocity) <= vmax + RUCKIG_EPS
        assert max(abs(x) for x in sp.acceleration) <= amax + RUCKIG_EPS


# The input the limits property found (1 kHz, a_max 2 m/s^2, j_max 20 m/s^3, the move to the
# path's start of three symmetric axes): each axis alone is solvable (all three in 0.0379661803013 s,
# within 1e-13 s of each other), all three together are not, neither to the target nor braking.
RUCKIG_STEP2_CASE = Setpoint((0.6889135428952743, 0.5945763663104189, 0.505413742420422),
                             (-0.014413332459232361, 0.014413332459508443, 0.014413332459346628),
                             (0.7592978985218729, -0.7592978985291448, -0.7592978985248826))


@pytest.mark.xfail(strict=True, reason="finding: the smoother clips a target velocity to the limit but keeps a "
                                       "decelerating target acceleration, a target state Ruckig refuses ('will "
                                       "inevitably have reached a velocity ... that will exceed its maximum velocity')")
def test_a_fast_decelerating_target_is_clipped_not_refused():
    # What the limits property met in RUNNING when a path's joint velocity peaks near v_max.
    smoother = RuckigSmoother(AxisLimits((1.0,), (10.0,), (500.0,)), 0.0025)
    result = smoother.step(Setpoint.at_rest((0.5,)), (0.7,), (1.2,), (-5.0,))
    assert result.ok, result.message[:160]


@pytest.mark.xfail(strict=True, reason="finding: Ruckig 0.19 answers 'error in step 2' (time synchronisation) "
                                       "for three nearly identical profiles, and the law faults on a valid input")
def test_the_smoother_accepts_three_symmetric_axes_near_their_target():
    smoother = RuckigSmoother(AxisLimits((1.0,) * 3, (2.0,) * 3, (20.0,) * 3), 0.001)
    target = (0.6887311426778018, 0.5947587665278841, 0.5055961426378881)
    step = smoother.step(RUCKIG_STEP2_CASE, target, (0.0,) * 3, (0.0,) * 3)
    brake = smoother.brake(RUCKIG_STEP2_CASE)
    assert step.ok and brake.ok, (step.message or brake.message)[:120]


@pytest.mark.xfail(strict=True, reason="finding: before every drive has answered once, CONFIGURING outputs the "
                                       "initial setpoint, target 0.0 m (outside the stroke), with controlword 0")
def test_a_target_before_the_first_tpdo_is_within_the_stroke():
    cfg = load_config()
    loop = ClosedLoop(cfg)
    rec = loop.cycle(Perturbation(missing=frozenset({(0, 0)})))  # drive 1's first TPDO is missing
    assert rec.state.mode == Mode.CONFIGURING
    lo, hi = cfg.robot.model("cheope").stroke_min_m, cfg.robot.model("cheope").stroke_max_m
    assert all(lo <= q <= hi for q in rec.outputs.targets), rec.outputs


# -- b. no jump at enable ----------------------------------------------------------------------

START_STATES = [PowerState.SWITCH_ON_DISABLED, PowerState.READY_TO_SWITCH_ON, PowerState.SWITCHED_ON,
                PowerState.OPERATION_ENABLED, PowerState.QUICK_STOP_ACTIVE, PowerState.FAULT]


@PROPERTY_SETTINGS
@given(data=st.data(),
       rate=st.sampled_from([200.0, 400.0, 1000.0]),
       start=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
       powers=st.lists(st.sampled_from(START_STATES), min_size=3, max_size=3),
       reset_after=st.integers(1, 20))
def test_no_jump_at_enable_the_target_is_where_the_drive_is(data, rate, start, powers, reset_after):
    base = load_config()
    lo, hi = base.robot.model("cheope").stroke_min_m, base.robot.model("cheope").stroke_max_m
    initial = [min(hi, lo + u * (hi - lo)) for u in start]  # anywhere in the stroke, end stops included
    cfg, law = build_or_reject({"loop.rate_hz": rate, "loop.hold_before_task_s": 0.05,
                                "sim.drive.initial_positions_m": initial})
    loop = ClosedLoop(cfg, law)
    for d, power in zip(loop.ex.drives, powers):
        d.power = power  # a drive left in any state by whatever ran before
    cycles = int(0.15 * rate) + 40
    # TPDOs missing now and then from the second cycle on (cycle 0: see the CONFIGURING xfail above)
    missing = frozenset(data.draw(st.lists(st.tuples(st.integers(1, cycles - 1), st.integers(0, 2)), max_size=12)))
    p = Perturbation(missing=frozenset((c, j) for c, j in missing if (c - 1, j) not in missing))
    scale = loop.ex.scale
    faults = []
    for _ in range(cycles):
        rec = loop.cycle(p)
        if rec.state.mode == Mode.FAULT and not faults:
            faults.append(rec.state.fault_reason)  # a drive that started in FAULT: the operator resets it once
            p.commands[rec.k + reset_after] = Command.RESET
        if rec.state.mode == Mode.RUNNING:
            break
    modes = [r.state.mode for r in loop.records]
    note(f"modes: {[m.name for m in modes]}")

    # The step's view: while ENABLING and HOLDING, every target is the position measured, to the count.
    enabled_at = None
    for r in loop.records:
        if r.state.mode not in (Mode.ENABLING, Mode.HOLDING):
            continue
        if r.state.mode == Mode.HOLDING and enabled_at is None:
            enabled_at = r.measured  # all drives report OPERATION ENABLED in this very cycle
        reference = r.measured if r.state.mode == Mode.ENABLING else enabled_at
        for j, (x, m) in enumerate(zip(r.outputs.targets, reference)):
            assert scale.to_counts(x) == scale.to_counts(m), \
                f"cycle {r.k} ({r.state.mode.name}): target {x} m for drive {j + 1} measured at {m} m"

    # The drives' view: every RPDO that leaves or keeps a drive enabled, until the task starts, carries
    # the position the drive is at when it arrives; and no drive has moved.
    first_running = modes.index(Mode.RUNNING)
    for c, j, cw, target, position in loop.rpdos:
        if c - 1 >= first_running:
            break
        if cw & 0x8F == 0x0F or loop.records[c - 1].powers[j] == PowerState.OPERATION_ENABLED:
            assert target == position, f"cycle {c}: drive {j + 1} at {position} counts was sent {target} (cw 0x{cw:04X})"
    for j, (d, x0) in enumerate(zip(loop.ex.drives, initial)):
        assert d.position_counts() == round(x0 * scale.counts_per_unit), f"drive {j + 1} moved before the task"
    # and the run got there: the only fault is the one of a drive that started in FAULT, reset once
    assert all("reports FAULT" in f for f in faults) and (PowerState.FAULT in powers) == bool(faults), faults
    assert Mode.HOLDING in modes and Mode.RUNNING in modes, loop.state.fault_reason
