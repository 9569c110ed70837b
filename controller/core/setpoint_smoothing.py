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


@dataclass(frozen=True, slots=True)
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


@dataclass(frozen=True, slots=True)
class SmoothingResult:
    setpoint: Setpoint
    ok: bool
    message: str  # why Ruckig refused, empty when ok


TARGET_VELOCITY_MARGIN = 1.0 - 1e-6  # of v_max: 0.5 um/s at 0.5 m/s, far below any tolerance


class RuckigSmoother:
    def __init__(self, limits: AxisLimits, period_s: float) -> None:
        dofs = len(limits.max_velocity)
        self._period_s = period_s
        self._otg = Ruckig(dofs)
        self._inp = InputParameter(dofs)
        self._traj = Trajectory(dofs)
        self._inp.max_velocity = list(limits.max_velocity)
        self._inp.max_acceleration = list(limits.max_acceleration)
        self._inp.max_jerk = list(limits.max_jerk)
        # The velocity interface: braking (come to rest wherever that happens) and reactive tracking.
        self._brake = InputParameter(dofs)
        self._brake.control_interface = ControlInterface.Velocity
        self._brake.max_velocity = list(limits.max_velocity)
        self._brake.max_acceleration = list(limits.max_acceleration)
        self._brake.max_jerk = list(limits.max_jerk)
        self._zeros = [0.0] * dofs
        self._limits = limits

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
        # Targets keep a relative margin below v_max: a target exactly at the limit with a rounding
        # error's acceleration left is refused too (found by tests/unit/test_step_properties.py).
        target_v_max = tuple(m * TARGET_VELOCITY_MARGIN for m in lim.max_velocity)
        target_velocity = tuple(min(max(v, -m), m) for v, m in zip(target_velocity, target_v_max))
        # A target state must be reachable from a state within the limits: with |a| the jerk-limited
        # velocity change a^2 / (2 j) still ahead (or just behind), |v| + a^2 / (2 j) <= v_max.
        # Ruckig refuses the whole input otherwise ("will inevitably ... exceed its maximum velocity").
        target_acceleration = tuple(
            min(max(a, -ma), ma) if (reach := math.sqrt(2.0 * j * max(0.0, mv - abs(v)))) >= ma
            else min(max(a, -reach), reach)
            for a, v, ma, mv, j in zip(target_acceleration, target_velocity, lim.max_acceleration,
                                       target_v_max, lim.max_jerk))
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
    ) -> SmoothingResult:
        """The setpoint one period later when following a reactive reference by its velocity.

        For references that are recomputed from measurements every cycle (force control),
        the position interface is fragile: once the setpoint lags an accelerating target,
        the time-optimal profile to it changes family from one cycle to the next (brake,
        then catch up) and the setpoints stall. Here Ruckig's velocity interface goes to
        v* = v_ref + correction_per_s (q_ref - q) within the limits: the position error
        decays with time constant 1 / correction_per_s (q is the setpoint extrapolated to the
        reference's sample), and every setpoint keeps the velocity, acceleration and jerk limits.
        """
        lim = self._limits
        inp = self._brake
        inp.current_position = current.position
        inp.current_velocity = current.velocity
        inp.current_acceleration = current.acceleration
        h = self._period_s
        targets = []
        for v, q_ref, q, qd, qdd, m in zip(target_velocity, target_position, current.position, current.velocity,
                                           current.acceleration, lim.max_velocity):
            # The reference is for the sample one period ahead: compare it with where the setpoint
            # would be then, or the setpoint settles a period's travel ahead of its reference.
            q_then = q + h * qd + 0.5 * h * h * qdd
            targets.append(min(max(v + correction_per_s * (q_ref - q_then), -m), m))
        inp.target_velocity = targets
        inp.target_acceleration = self._zeros
        return self._calculate(inp, current)

    def brake(self, current: Setpoint) -> SmoothingResult:
        """The setpoint one period later on the fastest jerk-limited way to zero velocity."""
        inp = self._brake
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
