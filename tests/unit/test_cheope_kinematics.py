"""Seed 001 kinematics: round trips, Jacobian, singularities, joint swing, the issue's figures."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from controller.config import load_config
from controller.errors import NoSolutionError
from controller.robots.cheope.entry import build_cheope
from controller.robots.cheope.model import (
    CheopeGeometry,
    direct_kinematics,
    inverse_kinematics,
    jacobian,
    joint_swing_rad,
    rod_directions,
    singularity_measures,
)

GEOM = CheopeGeometry()
ROBOT = build_cheope(load_config().robot.model("cheope"))
coord = st.floats(min_value=-0.12, max_value=0.12)
height = st.floats(min_value=0.35, max_value=0.65)


def usable(x: float, y: float, z: float) -> np.ndarray:
    """Keep the poses inside the configured usable workspace (about half of the box)."""
    s = np.array([x, y, z])
    assume(ROBOT.check_pose(s).ok)
    return s


@settings(max_examples=300, deadline=None)
@given(coord, coord, height)
def test_inverse_then_direct_returns_the_tcp(x, y, z):
    s = usable(x, y, z)
    q = inverse_kinematics(GEOM, s)
    assert np.allclose(direct_kinematics(GEOM, q), s, atol=1e-10)


@settings(max_examples=100, deadline=None)
@given(coord, coord, height)
def test_loop_closure_eq1_holds(x, y, z):
    # seed 001 eq. (1): s + a_j - l w_j - q_j n_j = 0 with |w_j| = 1
    s = usable(x, y, z)
    q = inverse_kinematics(GEOM, s)
    w = rod_directions(GEOM, s, q)
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    residual = s[None, :] + GEOM.platform_vectors - GEOM.rod_length_m * w - q[:, None] * GEOM.axes
    assert np.abs(residual).max() < 1e-12


def test_inverse_kinematics_uses_the_plus_branch():
    # eq. (5) '+' sign: the slider lies beyond the foot of the rod, so w_j . n_j < 0
    s = np.array([0.02, -0.03, 0.5])
    q = inverse_kinematics(GEOM, s)
    w = rod_directions(GEOM, s, q)
    assert np.all(np.einsum("ij,ij->i", w, GEOM.axes) < 0)


@pytest.mark.parametrize("s", [(0.0, 0.0, 0.5), (0.06, 0.03, 0.45), (-0.08, 0.05, 0.55)])
def test_jacobian_matches_finite_differences(s):
    s = np.array(s)
    jac = jacobian(GEOM, s)
    h = 1e-6
    fd = np.column_stack(
        [
            (inverse_kinematics(GEOM, s + h * e) - inverse_kinematics(GEOM, s - h * e)) / (2 * h)
            for e in np.eye(3)
        ]
    )
    assert np.allclose(jac, fd, rtol=1e-7, atol=1e-8)


def test_direct_kinematics_reports_unreachable_input():
    with pytest.raises(NoSolutionError, match="do not intersect"):
        direct_kinematics(GEOM, np.array([0.1, 1.5, 0.1]))


def test_inverse_kinematics_reports_the_leg_out_of_reach():
    with pytest.raises(NoSolutionError, match="out of reach of leg"):
        inverse_kinematics(GEOM, np.array([0.0, -2.0, 0.0]))


def test_issue_figures_for_the_default_geometry():
    s = np.array([0.0, 0.0, 0.5])
    q = inverse_kinematics(GEOM, s)
    assert np.allclose(q, 0.58, atol=0.005)
    sv = np.linalg.svd(jacobian(GEOM, s), compute_uv=False)
    assert sv[0] / sv[-1] == pytest.approx(2.5, abs=0.05)
    for r in (0.07, 0.08, 0.09):
        conds, swings = [], []
        for th in np.linspace(0, 2 * np.pi, 73):
            p = np.array([r * np.cos(th), r * np.sin(th), 0.5])
            sv = np.linalg.svd(jacobian(GEOM, p), compute_uv=False)
            conds.append(sv[0] / sv[-1])
            swings.append(np.degrees(joint_swing_rad(GEOM, p)).max())
        assert max(conds) < 4.5
        assert max(swings) < 11.0


def test_inverse_singularity_measure_vanishes_where_a_rod_is_orthogonal_to_its_axis():
    # Raise the TCP along Z until the discriminant of eq. (5) for leg 1 vanishes: there the
    # two branches meet and w_1 . n_1 = 0.
    def disc(z):
        r = np.array([0.0, 0.0, z]) + GEOM.platform_vectors[0]
        n = GEOM.axes[0]
        return (n @ r) ** 2 - r @ r + GEOM.rod_length_m**2

    lo, hi = 0.5, 2.0
    assert disc(lo) > 0 > disc(hi)
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if disc(mid) > 0 else (lo, mid)
    m = singularity_measures(GEOM, np.array([0.0, 0.0, lo]))
    assert m.inverse < 1e-6
    assert singularity_measures(GEOM, np.array([0, 0, 0.5])).inverse > 0.5


def test_direct_singularity_measure_vanishes_when_the_rods_are_coplanar():
    # Rods coplanar: choose q so that all three w_j are horizontal-ish in one plane. Construct it
    # by a geometry with zero tilt spread: axes all in the XY plane and the TCP in that plane.
    flat = CheopeGeometry(axis_tilt_rad=math.pi / 2, joint_neutral_tcp_m=(0.0, 0.0, 0.3))
    s = np.array([0.0, 0.0, 0.0])
    q = inverse_kinematics(flat, s)
    w = rod_directions(flat, s, q)
    assert abs(np.linalg.det(w)) < 1e-12
    assert singularity_measures(flat, s, q).direct < 1e-12
    assert singularity_measures(GEOM, np.array([0, 0, 0.5])).direct > 0.3


def test_structural_measure_vanishes_when_two_rods_are_parallel():
    # Rods 1 and 3 (opposite axes) are parallel when a_1 - a_3 = q n_1 - q n_3, i.e.
    # q_1 = q_3 = |a_1 - a_3| / (2 sin(tilt)); with w_1 = w_3 = +Z the TCP follows from eq. (1).
    # This pose lies on the other assembly branch, outside the paper's workspace (seed 001 §5.1).
    q13 = 0.1 / (2 * math.sin(GEOM.axis_tilt_rad))
    s = q13 * GEOM.axes[0] - GEOM.platform_vectors[0] + GEOM.rod_length_m * np.array([0.0, 0.0, 1.0])
    q = np.array([q13, inverse_kinematics(GEOM, s)[1], q13])
    w = rod_directions(GEOM, s, q)
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0)
    assert singularity_measures(GEOM, s, q).structural < 1e-12
    assert singularity_measures(GEOM, np.array([0, 0, 0.5])).structural > 0.3


def test_joint_swing_is_zero_at_the_neutral_point_and_grows_away_from_it():
    assert np.allclose(joint_swing_rad(GEOM, np.array([0, 0, 0.5])), 0.0, atol=1e-7)
    assert joint_swing_rad(GEOM, np.array([0.08, 0, 0.5])).max() > math.radians(5)


@settings(max_examples=150, deadline=None)
@given(coord, coord, height)
def test_fast_pose_check_agrees_with_the_reference_measures(x, y, z):
    """check_pose (plain floats, every cycle) against the numpy measures it duplicates for speed."""
    s = np.array([x, y, z])
    try:
        q = inverse_kinematics(GEOM, s)
    except NoSolutionError:
        assert not ROBOT.check_pose(s).ok
        return
    lim = ROBOT.limits
    m = singularity_measures(GEOM, s, q)
    sv = np.linalg.svd(jacobian(GEOM, s, q), compute_uv=False)
    expected = (
        all(lim.stroke_min_m <= v <= lim.stroke_max_m for v in q)
        and joint_swing_rad(GEOM, s, q).max() <= lim.joint_swing_limit_rad
        and m.direct >= lim.min_direct_measure
        and m.inverse >= lim.min_inverse_measure
        and m.structural >= lim.min_structural_measure
        and sv[0] / sv[-1] <= lim.max_condition_number
    )
    assert ROBOT.check_pose(s).ok == expected
