"""What a guarded move's speed costs in force when it meets the stiffest contact of the cell.

A guarded move (a contour's search and approach, a re-approach) advances into a part it has not
met yet. When the tool touches, the force rises as stiffly as the cell is: the sensor, its mount
and the part, in series (``safety.contact.cell_stiffness_n_m``, the stiffest the cell presents).
The law sees the touch only in a later cycle, and the setpoints then brake within the actuators'
acceleration and jerk limits (Ruckig): meanwhile the tool goes on into the part by the stopping
distance, and the force with it. So the force a guarded move ends at is set by its speed before the
touch, not by any guard after it: the one defence is a speed the cell can stop within the force
limit, checked when the task is configured. An outside tester met 354 N at an approach speed of
0.08 m/s that the configuration accepted (the force limit is 60 N).

The stopping distance from ``speed_m_s`` [m]:

    d_stop = v (2 T + a / (2 j)) + v^2 / (2 a)

- ``2 T``: two loop periods go by at full speed before the braking begins: the sample that shows
  the touch answers the SYNC of the cycle after the touch, and the setpoint that brakes is sent in
  the cycle after that;
- ``a / (2 j)``: a jerk-limited stop from ``v`` covers ``v a / (2 j)`` more than one braking at
  ``a`` from the start (the acceleration ramps up over ``a / j``, during which the speed falls
  by only half as much as at full braking);
- ``v^2 / (2 a)``: the braking at the actuators' acceleration limit.

The actuators' limits stand for the tool's: on Cheope a leg moves about as fast as the tool along
the contour's plane. The robot's own compliance (its drives' servo stiffness, in series with the
cell) is left out. Against the shipped cell (2.31e5 N/m), the simulator's true force where the search
met a part 15 mm towards the approach (`cheope demo --task contour --simulated-time --set
task.contour.max_force_n=59 --set 'sim.workpiece.centre_m=[0.015,0.0]'`, before a limit within 10 N of
the safety layer's was refused; 50 N now): 23.8 N at 400 Hz, 28.1 N at
250 Hz, where this predicts 38.2 and 45.4 N; an outside tester's approaches met 54.3 N at 0.02 m/s
(predicted 74.6 N) and 354 N at 0.08 m/s, eight times faster than the shipped cell allows, where the
braking is slower than the actuators' limit (predicted 352 N). Against a sensor mount of 1e7 N/m
(9.1e5 in series) at the 4.3 mm/s the budget of 59 N allows: 20.2 N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PERIODS_BEFORE_BRAKING = 2  # the touch's sample, then the braking setpoint (module text)


@dataclass(frozen=True)
class StoppingModel:
    """The guarded move's stop: the loop's period and the actuators' limits (module text)."""

    period_s: float
    max_acceleration_m_s2: float
    max_jerk_m_s3: float

    def distance_m(self, speed_m_s: float) -> float:
        """How far the tool goes on after touching at ``speed_m_s`` [m]."""
        a, j = self.max_acceleration_m_s2, self.max_jerk_m_s3
        return speed_m_s * (PERIODS_BEFORE_BRAKING * self.period_s + a / (2.0 * j)) + speed_m_s**2 / (2.0 * a)

    def peak_force_n(self, speed_m_s: float, touch_force_n: float, stiffness_n_m: float) -> float:
        """The force a guarded move at ``speed_m_s`` ends at against ``stiffness_n_m``, when it takes
        the contact for one at ``touch_force_n`` [N]: an upper bound (module text)."""
        return touch_force_n + stiffness_n_m * self.distance_m(speed_m_s)

    def fastest_m_s(self, force_budget_n: float, stiffness_n_m: float) -> float:
        """The highest guarded speed whose stop stays within ``force_budget_n`` past the touch [m/s]:
        the positive root of ``distance_m(v) = force_budget_n / stiffness_n_m``."""
        if force_budget_n <= 0.0:
            return 0.0
        a = self.max_acceleration_m_s2
        linear = PERIODS_BEFORE_BRAKING * self.period_s + a / (2.0 * self.max_jerk_m_s3)
        quadratic = 1.0 / (2.0 * a)
        distance = force_budget_n / stiffness_n_m
        # q v^2 + l v - d = 0, in the form that loses no digits when q v^2 is small
        return 2.0 * distance / (linear + math.sqrt(linear * linear + 4.0 * quadratic * distance))
