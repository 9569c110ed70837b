"""Online smoothing of actuator setpoints with Ruckig (Community features only).

Every cycle computes a fresh time-optimal trajectory from the last setpoint to the task's
reference and samples it one period ahead. ``Ruckig.calculate`` is used instead of
``update`` on purpose: ``update`` keeps the previous trajectory inside the Ruckig object
and skips the calculation when the input is unchanged, which would make the output depend
on hidden history. With ``calculate`` the next setpoint is a function of the arguments
only, so replaying the recorded inputs reproduces the outputs bit for bit. The Ruckig
objects are preallocated scratch space, not state. Intermediate waypoints are never set
(the PyPI build sends those to a remote service).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from controller.core.records import record


@record
class Setpoint:
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]

    @staticmethod
    def at_rest(position: tuple[float, ...]) -> Setpoint:
        zeros = tuple(0.0 for _ in position)
        return Setpoint(tuple(position), zeros, zeros)


@dataclass(frozen=True)
class AxisLimits:
    max_velocity: tuple[float, ...]  # [unit/s]
    max_acceleration: tuple[float, ...]  # [unit/s^2]
    max_jerk: tuple[float, ...]  # [unit/s^3]
    # A protective reaction's (a back-off's: ``reaction=True``), larger: a planned move's jerk takes
    # max_acceleration / max_jerk (20 ms on Cheope) to reach full braking, all the while going on
    # into whatever the reaction is for. Empty: max_jerk.
    reaction_jerk: tuple[float, ...] = ()


@record
class SmoothingResult:
    setpoint: Setpoint
    ok: bool
    message: str  # why Ruckig refused, empty when ok


TARGET_VELOCITY_MARGIN = 1.0 - 1e-6  # of v_max: 0.5 um/s at 0.5 m/s, far below any tolerance
# The reactive correction asks for at most this part of the speed from which the setpoint can still
# stop within its error (``stoppable_speed``): the margin covers the one period between samples and
# the acceleration already under way. 0.5 converges from every state tried in
# tests/unit/test_setpoint_smoothing.py; 1.0 would be the time-optimal switching curve itself.
STOPPABLE_FRACTION = 0.5


def stoppable_speed(distance: float, max_acceleration: float, max_jerk: float) -> float:
    """The largest speed [unit/s] from which a jerk-limited stop, starting at zero acceleration, ends within ``distance``.

    A stop from v with jerk j and deceleration a: below v = a^2/j the acceleration profile is a
    triangle of duration 2 sqrt(v/j) and the distance is v sqrt(v/j), so v = (j d^2)^(1/3); above,
    the profile has a plateau at a and d = v^2/(2a) + v a/(2j), the positive root of which is taken.
    The two meet at d = a^3/j^2.

    Why it bounds the reactive correction: a proportional correction k (q_ref - q) through a
    jerk-limited velocity interface is a loop whose lag grows with the size of the velocity
    change (the jerk-limited change takes 2 sqrt(dv/j)). For errors where that lag reaches 1/k,
    every correction overshoots more than the last: a velocity step of 74 mm/s at 10 m/s^2 and
    500 m/s^3 with k = 100/s grew into a +-64 mm, 1 m/s limit cycle (the diverging re-approach
    of the contour task after a contact loss). Asking only for a speed the setpoint can still
    shed before the error is used up is the proximate time-optimal servo's idea (linear near the
    target, the braking curve away from it): the correction can no longer overshoot.
    """
    if distance <= 0.0:
        return 0.0
    a, j = max_acceleration, max_jerk
    if distance <= a**3 / (j * j):
        return float((j * distance * distance) ** (1.0 / 3.0))
    return -a * a / (2.0 * j) + math.sqrt(a**4 / (4.0 * j * j) + 2.0 * a * distance)


def _input(limits: AxisLimits, max_jerk: tuple[float, ...], velocity: bool) -> InputParameter:
    """Ruckig's scratch input within ``limits`` and ``max_jerk``, in the velocity interface or the
    position one."""
    inp = InputParameter(len(limits.max_velocity))
    if velocity:
        inp.control_interface = ControlInterface.Velocity
    inp.max_velocity = list(limits.max_velocity)
    inp.max_acceleration = list(limits.max_acceleration)
    inp.max_jerk = list(max_jerk)
    return inp


class RuckigSmoother:
    def __init__(self, limits: AxisLimits, period_s: float) -> None:
        dofs = len(limits.max_velocity)
        self._period_s = period_s
        self._otg = Ruckig(dofs)
        self._traj = Trajectory(dofs)
        self._inp = _input(limits, limits.max_jerk, velocity=False)
        # The velocity interface: braking (come to rest wherever that happens) and reactive tracking,
        # at the planned moves' jerk and at a protective reaction's.
        self._brake = _input(limits, limits.max_jerk, velocity=True)
        self._reaction_jerk = tuple(limits.reaction_jerk or limits.max_jerk)
        self._react = _input(limits, self._reaction_jerk, velocity=True)
        self._zeros = [0.0] * dofs
        self._limits = limits
        # Targets keep a relative margin below v_max: a target exactly at the limit with a rounding
        # error's acceleration left is refused too (found by tests/unit/test_step_properties.py).
        self._target_v_max = tuple(m * TARGET_VELOCITY_MARGIN for m in limits.max_velocity)

    def step(
        self,
        current: Setpoint,
        target_position: tuple[float, ...],
        target_velocity: tuple[float, ...],
        target_acceleration: tuple[float, ...],
    ) -> SmoothingResult:
        """The setpoint one period after ``current`` on the way to the target state.

        A target velocity or acceleration beyond the limits cannot be reached anyway: it is
        clipped to them (Ruckig would refuse the whole input), so a task's abrupt change of
        plan becomes the fastest allowed transition instead of a fault.
        """
        lim = self._limits
        target_v_max = self._target_v_max
        target_velocity = tuple(min(max(v, -m), m) for v, m in zip(target_velocity, target_v_max))
        # A target state must be reachable from a state within the limits: with |a| the jerk-limited
        # velocity change a^2 / (2 j) still ahead (or just behind), |v| + a^2 / (2 j) <= v_max.
        # Ruckig refuses the whole input otherwise ("will inevitably ... exceed its maximum velocity").
        target_acceleration = tuple(
            min(max(a, -ma), ma)
            if (reach := math.sqrt(2.0 * j * max(0.0, mv - abs(v)))) >= ma
            else min(max(a, -reach), reach)
            for a, v, ma, mv, j in zip(
                target_acceleration,
                target_velocity,
                lim.max_acceleration,
                target_v_max,
                lim.max_jerk,
            )
        )
        inp = self._inp
        inp.current_position = current.position
        inp.current_velocity = current.velocity
        inp.current_acceleration = current.acceleration
        inp.target_position = target_position
        inp.target_velocity = target_velocity
        inp.target_acceleration = target_acceleration
        return self._calculate(inp, current)

    def track_velocity(
        self,
        current: Setpoint,
        target_position: tuple[float, ...],
        target_velocity: tuple[float, ...],
        correction_per_s: float,
        reaction: bool = False,
    ) -> SmoothingResult:
        """The setpoint one period later when following a reactive reference by its velocity.

        For references that are recomputed from measurements every cycle (force control),
        the position interface is fragile: once the setpoint lags an accelerating target,
        the time-optimal profile to it changes family from one cycle to the next (brake,
        then catch up) and the setpoints stall. Here Ruckig's velocity interface goes to
        v* = v_ref + correction_per_s (q_ref - q) within the limits: the position error
        decays with time constant 1 / correction_per_s (q is the setpoint extrapolated to the
        reference's sample), and every setpoint keeps the velocity, acceleration and jerk limits
        (``reaction``: a protective reaction's jerk, ``AxisLimits.reaction_jerk``).
        """
        lim = self._limits
        inp = self._react if reaction else self._brake
        inp.current_position = current.position
        inp.current_velocity = current.velocity
        inp.current_acceleration = current.acceleration
        h = self._period_s
        targets = []
        for v, q_ref, q, qd, qdd, m, a_max, j_max in zip(
            target_velocity,
            target_position,
            current.position,
            current.velocity,
            current.acceleration,
            lim.max_velocity,
            lim.max_acceleration,
            self._reaction_jerk if reaction else lim.max_jerk,
        ):
            # The reference is for the sample one period ahead: compare it with where the setpoint
            # would be then, or the setpoint settles a period's travel ahead of its reference.
            error = q_ref - (q + h * qd + 0.5 * h * h * qdd)
            correction = math.copysign(
                min(
                    correction_per_s * abs(error),
                    STOPPABLE_FRACTION * stoppable_speed(abs(error), a_max, j_max),
                ),
                error,
            )
            targets.append(min(max(v + correction, -m), m))
        inp.target_velocity = targets
        inp.target_acceleration = self._zeros
        return self._calculate(inp, current)

    def brake(self, current: Setpoint, reaction: bool = False) -> SmoothingResult:
        """The setpoint one period later on the fastest jerk-limited way to zero velocity (``reaction``:
        with a protective reaction's jerk)."""
        inp = self._react if reaction else self._brake
        inp.current_position = current.position
        inp.current_velocity = current.velocity
        inp.current_acceleration = current.acceleration
        inp.target_velocity = self._zeros
        inp.target_acceleration = self._zeros
        return self._calculate(inp, current)

    def _try(self, inp: InputParameter) -> tuple[Result, str]:
        try:
            return self._otg.calculate(inp, self._traj), ""
        except RuckigError as err:  # the binding raises on invalid input (NaN, limits) and some failures
            return Result.Error, str(err)

    def _calculate(self, inp: InputParameter, current: Setpoint) -> SmoothingResult:
        result, error = self._try(inp)
        if result == Result.ErrorSynchronizationCalculation or "error in step 2" in error:
            # Ruckig 0.19 fails its time synchronisation ("error in step 2") for some nearly
            # identical profiles on several axes; each axis's own time-optimal profile is a
            # valid setpoint for one period, and the next cycle synchronises again.
            inp.synchronization = Synchronization.No
            try:
                result, error = self._try(inp)
            finally:
                inp.synchronization = Synchronization.Time
        if error:
            return SmoothingResult(current, False, f"Ruckig refused the input: {error}")
        if result not in (Result.Working, Result.Finished):
            return SmoothingResult(current, False, f"Ruckig refused the input: {result.name}")
        # Past its duration Ruckig extrapolates the final state at constant acceleration. In the
        # position interface the target state is the setpoint wanted for this sample, so that
        # is where it stops. In the velocity interface the target is a velocity to go on at:
        # stopping at the profile's end would lose (period - duration) of travel every cycle,
        # which the reactive correction then chases with a fresh jerk pulse, and the
        # setpoints' acceleration chatters (0.44 m/s^2 RMS while tracking the contour, 0.004
        # when sampled a whole period ahead).
        if inp.control_interface == ControlInterface.Velocity:
            t = self._period_s
        else:
            t = min(self._period_s, self._traj.duration)
        pos, vel, acc = self._traj.at_time(t)
        return SmoothingResult(Setpoint(tuple(pos), tuple(vel), tuple(acc)), True, "")
