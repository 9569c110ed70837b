"""The circle path's position in floats is its sample's, bit for bit, and the path task takes the
same doubles from a path with or without it (controller/tasks/path_task.py ``position_of``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.tasks.circle_path import CirclePath
from controller.tasks.path_task import PathTask, position_of

finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    center=st.tuples(finite, finite, st.floats(min_value=0.2, max_value=0.8)),
    radius=st.floats(min_value=0.005, max_value=0.2),
    start=st.floats(min_value=-math.pi, max_value=math.pi),
    tau_fraction=st.floats(min_value=-0.1, max_value=1.1),
)
def test_position_is_the_samples_first_array_bit_for_bit(center, radius, start, tau_fraction):
    path = CirclePath(center, radius, speed_m_s=0.05, laps=2.0, ramp_s=0.5, start_angle_rad=start)
    tau = tau_fraction * path.duration_s
    expected = path.sample(tau)[0].tolist()
    got = path.position(tau)
    assert all(type(x) is float for x in got)
    assert list(got) == expected  # == on doubles: the same bits (no NaN here)


@dataclass(frozen=True)
class _ArraysOnly:
    """A path with ``sample`` only, as a plug-in's may be."""

    circle: CirclePath

    @property
    def duration_s(self) -> float:
        return self.circle.duration_s

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.circle.sample(tau)

    def points(self, n: int) -> np.ndarray:
        return self.circle.points(n)


class _Cheope:
    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        from controller.robots.cheope.model import CheopeGeometry, inverse_kinematics

        return inverse_kinematics(CheopeGeometry(), tcp_m)


def test_a_path_without_position_gives_the_task_the_same_reference():
    circle = CirclePath((0.0, 0.0, 0.5), 0.05, 0.05, 1.0, 0.5)
    plain = _ArraysOnly(circle)
    assert position_of(circle) == circle.position
    assert position_of(plain)(1.234) == circle.position(1.234)
    robot = _Cheope()
    with_floats, from_arrays = PathTask(robot, circle, 1e-4), PathTask(robot, plain, 1e-4)
    for tau in (0.0, 0.3, 1.7, circle.duration_s - 0.01):
        assert with_floats._joint_reference(tau) == from_arrays._joint_reference(tau)


@pytest.mark.parametrize("rate_hz", [25.0, 400.0])
def test_a_bounded_move_to_the_start_arrives_and_the_path_runs(rate_hz: float):
    """``task.path.move_speed_m_s`` > 0: a straight move to the start at that speed, then the path.
    Once arrived the move stays there while the setpoint settles; restarted from the measured
    position (micrometres off) it moved again every other cycle, and at 25 Hz the path never
    started (the run went on until its time limit)."""
    from controller.config import load_config
    from controller.shell.simulated_rig import SimulatedRig

    overrides = {
        "task.kind": "path",
        "loop.rate_hz": rate_hz,
        "task.path.laps": 0.25,
        "task.path.speed_m_s": 0.05,
        "task.path.move_speed_m_s": 0.05,
    }
    state, _ = SimulatedRig(load_config(overrides=overrides)).run((), 10.0)
    assert state.mode.name == "DONE" and state.task_state.phase.name == "FINISHED"
