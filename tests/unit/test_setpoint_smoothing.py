"""The reactive tracking of RuckigSmoother: it settles from any state within the limits.

The contour task's re-approach after a contact loss asked for a velocity step of 74 mm/s on
one axis; the proportional correction through the jerk-limited velocity interface grew it into
a +-64 mm, 1 m/s limit cycle that drove the tool into the workpiece. These tests hold the
smoother alone against such steps, and the bound that removed the cycle against its formula.
"""

from __future__ import annotations

import itertools
import math

import pytest

from controller.core.setpoint_smoothing import AxisLimits, RuckigSmoother, Setpoint, stoppable_speed

PERIOD_S = 0.0025
LIMITS = AxisLimits((1.0,), (10.0,), (500.0,))  # the shipped Cheope actuator limits
CORRECTION_PER_S = 0.25 / PERIOD_S  # as the law asks (REACTIVE_CORRECTION_PERIODS)


def _settle(start: Setpoint, cycles: int) -> list[Setpoint]:
    smoother = RuckigSmoother(LIMITS, PERIOD_S)
    out = [start]
    for _ in range(cycles):
        result = smoother.track_velocity(out[-1], (0.0,), (0.0,), CORRECTION_PER_S)
        assert result.ok, result.message
        out.append(result.setpoint)
    return out


@pytest.mark.parametrize("velocity_m_s", [0.02, 0.074, 0.2, 0.5, 0.99, -0.3])
@pytest.mark.parametrize("error_m", [0.0, 0.002, -0.05])
def test_a_reference_that_stops_dead_is_reached_without_a_growing_oscillation(
    velocity_m_s: float, error_m: float
) -> None:
    trace = _settle(Setpoint((error_m,), (velocity_m_s,), (0.0,)), 1200)
    # The stop overshoots at most by the braking distance from the start (jerk- and acceleration-
    # limited), never more on a later swing, and ends at rest on the reference.
    peaks = [abs(s.position[0]) for s in trace]
    first_half, second_half = max(peaks[:600]), max(peaks[600:])
    assert second_half < 1e-6
    assert first_half <= abs(error_m) + abs(velocity_m_s) * math.sqrt(abs(velocity_m_s) / 500.0) + 0.06
    assert abs(trace[-1].velocity[0]) < 1e-6


def test_the_swings_after_a_74_mm_s_step_shrink() -> None:
    trace = _settle(Setpoint((0.0,), (0.074,), (0.0,)), 400)
    # extremes of the position between velocity sign changes
    swings, last = [], 0.0
    for a, b in itertools.pairwise(trace):
        if a.velocity[0] * b.velocity[0] < 0.0:
            swings.append(abs(b.position[0] - last))
            last = b.position[0]
    assert all(later <= earlier for earlier, later in itertools.pairwise(swings)), swings


@pytest.mark.parametrize("speed", [0.001, 0.05, 0.2, 0.5, 1.0])
def test_stoppable_speed_inverts_the_braking_distance(speed: float) -> None:
    a, j = 10.0, 500.0
    if speed <= a * a / j:
        distance = speed * math.sqrt(speed / j)  # triangular acceleration profile
    else:
        distance = speed * speed / (2 * a) + speed * a / (2 * j)  # with a plateau at a
    assert stoppable_speed(distance, a, j) == pytest.approx(speed, rel=1e-9)
    assert stoppable_speed(0.0, a, j) == 0.0


REACTION = AxisLimits((1.0,), (10.0,), (500.0,), (5000.0,))  # the shipped reaction_ramp_s, 2 ms


def _brake_cycles(reaction: bool, speed_m_s: float) -> tuple[int, float, list[Setpoint]]:
    smoother = RuckigSmoother(REACTION, PERIOD_S)
    trace = [Setpoint((0.0,), (speed_m_s,), (0.0,))]
    while abs(trace[-1].velocity[0]) > 1e-9 or abs(trace[-1].acceleration[0]) > 1e-9:
        result = smoother.brake(trace[-1], reaction)
        assert result.ok, result.message
        trace.append(result.setpoint)
        assert len(trace) < 100
    return len(trace) - 1, trace[-1].position[0], trace


def test_a_reaction_brakes_at_full_acceleration_within_its_ramp_where_a_planned_stop_takes_its_jerk():
    """A carriage going on at 96 mm/s while another was jammed pressed the part 16 ms after the guard
    tripped, braking at the planned moves' jerk (20 ms to full deceleration). A reaction ramps to the
    same acceleration limit in 2 ms: its stop takes v / a + a / j, not 2 sqrt(v / j)."""
    planned, planned_m, _ = _brake_cycles(False, 0.096)
    reacting, reacting_m, trace = _brake_cycles(True, 0.096)
    assert planned * PERIOD_S >= 2.0 * math.sqrt(0.096 / 500.0) - PERIOD_S  # 27.7 ms
    assert reacting * PERIOD_S <= 0.096 / 10.0 + 10.0 / 5000.0 + PERIOD_S  # 11.6 ms
    assert reacting_m < 0.6 * planned_m
    for a, b in itertools.pairwise(trace):  # within the acceleration limit and the reaction's jerk
        assert abs(b.acceleration[0]) <= 10.0 + 1e-9
        assert abs(b.acceleration[0] - a.acceleration[0]) <= 5000.0 * PERIOD_S + 1e-9


@pytest.mark.parametrize("velocity_m_s", [0.02, 0.096, 0.5, -0.3])
def test_a_reactions_tracking_settles_on_its_reference_without_a_growing_oscillation(
    velocity_m_s: float,
) -> None:
    smoother = RuckigSmoother(REACTION, PERIOD_S)
    trace = [Setpoint((0.002,), (velocity_m_s,), (0.0,))]
    for _ in range(1200):
        result = smoother.track_velocity(trace[-1], (0.0,), (0.0,), CORRECTION_PER_S, reaction=True)
        assert result.ok, result.message
        trace.append(result.setpoint)
    assert max(abs(s.position[0]) for s in trace[600:]) < 1e-6
    assert abs(trace[-1].velocity[0]) < 1e-6
