"""The ROS 2 bridge's samples (controller/ros2/samples.py): no ROS needed, the same for live and replay."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.config import load_config
from controller.configured_robot import robot_from_config
from controller.messages import cheope_pb2 as pb
from controller.ros2.samples import (
    CycleSampler,
    EveryInterval,
    commanded_tcp,
    diagnostic_level,
    sample_from_state,
)
from logs.messages import JointVelocities


@pytest.fixture(scope="module")
def robot():
    return robot_from_config(load_config())


def test_the_commanded_tcp_is_the_direct_kinematics_of_the_targets(robot):
    p = np.array([0.01, -0.02, 0.5])
    q = tuple(float(x) for x in robot.inverse_kinematics(p))
    assert commanded_tcp(robot, q) == pytest.approx(tuple(p), abs=1e-9)
    assert commanded_tcp(robot, q[:2]) is None  # not one target per actuator
    assert commanded_tcp(None, q) is None


def test_a_state_sample_is_stamped_in_ros_time_and_keeps_the_values(robot):
    p = np.array([0.0, 0.0, 0.5])
    targets = [float(x) for x in robot.inverse_kinematics(p)]
    state = pb.MonitorState(
        robot_id="r",
        cycle=12,
        t_s=0.03,
        mode="RUNNING",
        task="path",
        targets=targets,
        positions=[0.1, 0.2, 0.3],
        tcp_m=[1.0, 2.0, 3.0],
        force_n=[4.0, 5.0, 6.0],
        alarms=["sensor: no frame this cycle"],
        cycle_monotonic_s=1234.5,
    )
    state.loop.late_cycles = 7
    offset_ns = 1_795_000_000_123_456_789  # the controller's wall clock minus its monotonic clock
    s = sample_from_state(state, robot, offset_ns)
    assert (s.stamp_ns, s.cycle, s.positions, s.tcp_measured_m, s.force_n, s.torque_nm) == (
        1_234_500_000_000 + offset_ns,
        12,
        (0.1, 0.2, 0.3),
        (1.0, 2.0, 3.0),
        (4.0, 5.0, 6.0),
        None,
    )
    assert s.tcp_reference_m == pytest.approx((0.0, 0.0, 0.5), abs=1e-9)
    assert s.counters["late_cycles"] == 7
    assert diagnostic_level(s) == 1  # an alarm: WARN


def _cycle(n: int, period_s: float, late: bool = False) -> pb.Cycle:
    c = pb.Cycle(cycle=n, t_s=n * period_s)
    c.inputs.late = late
    c.state.mode = "FAULT" if n == 99 else "RUNNING"
    return c


def test_recorded_cycles_are_sampled_at_the_monitoring_rate_and_late_cycles_counted():
    period_s = 1.0 / 400.0
    sampler = CycleSampler("r", "path", None, rate_hz=50.0)
    picked = [
        s for n in range(100) if (s := sampler.sample(_cycle(n, period_s, late=n % 10 == 0), n * 10**6))
    ]
    assert [s.cycle for s in picked] == list(range(0, 100, 8))
    assert sampler.late_cycles == 10
    assert picked[-1].counters["late_cycles"] == 10
    assert all(s.tcp_reference_m is None for s in picked)  # no robot model: no reference


def test_a_fault_is_an_error_level():
    sampler = CycleSampler("r", "path", None, rate_hz=400.0)
    s = sampler.sample(_cycle(99, 1.0 / 400.0), 0)
    assert s is not None and diagnostic_level(s) == 2 and not math.isnan(s.t_s)


def test_joint_velocities_are_the_positions_difference_over_the_time_between_samples():
    v = JointVelocities()
    assert v.update(1_000_000_000, (0.1, 0.2)) == ()  # nothing to difference yet
    assert v.update(1_020_000_000, (0.1002, 0.1998)) == pytest.approx((0.01, -0.01))
    assert v.update(1_020_000_000, (0.2, 0.2)) == ()  # no time between: no velocity, not infinity
    assert v.update(1_040_000_000, (0.2, 0.2, 0.3)) == ()  # another number of actuators


def test_diagnostics_are_due_once_a_second_of_sample_time():
    every = EveryInterval(1_000_000_000)
    due = [t for t in range(0, 5_000_000_000, 20_000_000) if every.due(t)]
    assert due == [0, 1_000_000_000, 2_000_000_000, 3_000_000_000, 4_000_000_000]
