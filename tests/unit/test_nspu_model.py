"""Tests of the 3-nSPU model (seed 000 section 3): kinematics, statics, singularities, controllability."""

from __future__ import annotations

import numpy as np
import pytest

from controller.core.rotations import rpy, so3_exp, so3_log, vee
from controller.robots.nspu.kinematics import (
    NspuGeometry,
    NspuModelError,
    Pose,
    SingularityError,
    advance_pose,
    advance_pose_to_leg_lengths,
    constraint_residual,
    controllability_matrix,
    euler_xzx,
    euler_xzx_rate_matrix,
    integrate_leg_trajectory,
    io_blocks,
    io_matrix,
    joint_forces_from_wrench,
    leg_lengths,
    leg_rates_from_twist,
    limb_state,
    reduced_q_matrix,
    static_wrench,
    twist_from_leg_rates,
    vector_field_jacobians,
    vector_fields_xzx,
)

GEOM = NspuGeometry.paper_example()
UNIT = GEOM.length_unit_m


def _poses(n: int, seed: int = 0) -> list[Pose]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        p = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(20, 40)]) * UNIT
        R = so3_exp(rng.uniform(-0.4, 0.4, 3)) @ rpy(0, 0, -np.pi / 6)
        out.append(Pose(p, R))
    return out


# ---------------------------------------------------------------- geometry (seed 000 section 3.5)


def test_paper_geometry_triangles_are_equilateral_and_centred() -> None:
    for pts, radius in ((GEOM.a_m, 39.7), (GEOM.b_platform_m, 11.76)):
        assert np.allclose(pts.mean(axis=0), 0.0, atol=1e-4 * UNIT)
        assert np.allclose(np.linalg.norm(pts, axis=1), radius * UNIT, rtol=1e-4)
        sides = [np.linalg.norm(pts[i] - pts[(i + 1) % 3]) for i in range(3)]
        assert np.allclose(sides, sides[0], rtol=1e-4)
    # x axis points from A3 (B3) towards the centroid (seed 000 section 3.5)
    assert GEOM.a_m[2, 0] < 0 and GEOM.b_platform_m[2, 0] < 0


def test_printed_a3_is_not_equilateral() -> None:
    g = NspuGeometry.paper_example(a3_sign_fixed=False)
    sides = [np.linalg.norm(g.a_m[i] - g.a_m[(i + 1) % 3]) for i in range(3)]
    assert max(sides) / min(sides) > 1.5


def test_paper_geometry_threefold_symmetry_of_w4_and_r() -> None:
    rz = np.array([[-0.5, -np.sqrt(3) / 2, 0], [np.sqrt(3) / 2, -0.5, 0], [0, 0, 1]])  # Rz(120 deg)
    for i in range(2):
        assert np.allclose(rz @ GEOM.w4_platform[i], GEOM.w4_platform[i + 1], atol=1e-3)
        assert np.allclose(rz @ GEOM.r[i], GEOM.r[i + 1], atol=1e-3)
        assert np.allclose(rz @ GEOM.a_m[i], GEOM.a_m[i + 1], atol=1e-3 * UNIT)
    printed = NspuGeometry.paper_example(r3_variant="printed")
    assert not np.allclose(rz @ printed.r[1], printed.r[2], atol=1e-2)


def test_w3_and_h_derivation() -> None:
    pose = _poses(1, seed=3)[0]
    ls = limb_state(GEOM, pose.p_m, pose.R)
    for i in range(3):
        assert abs(ls.w3[i] @ ls.g[i]) < 1e-12  # w3 _|_ limb axis (design assumption)
        assert abs(ls.w3[i] @ ls.w4[i]) < 1e-12  # U-joint axes orthogonal
        assert np.isclose(np.linalg.norm(ls.h[i]), 1.0)
        assert abs(ls.h[i] @ ls.w3[i]) < 1e-12 and abs(ls.h[i] @ ls.w4[i]) < 1e-12
        # h = -(component of g orthogonal to w4), normalised
        perp = ls.g[i] - (ls.g[i] @ ls.w4[i]) * ls.w4[i]
        assert np.allclose(ls.h[i], -perp / np.linalg.norm(perp))
        # s_i is the component of h x r orthogonal to g (eq. (10))
        assert abs(ls.s[i] @ ls.g[i]) < 1e-12


def test_geometry_validation() -> None:
    with pytest.raises(NspuModelError, match="unit"):
        NspuGeometry(GEOM.a_m, 2 * GEOM.r, GEOM.b_platform_m, GEOM.w4_platform)
    with pytest.raises(NspuModelError, match="rotation"):
        Pose(np.zeros(3), np.diag([1.0, 1.0, -1.0]))


# ---------------------------------------------------------------- instantaneous kinematics (eq. (11))


def _limb_frames(p: np.ndarray, R: np.ndarray) -> np.ndarray:
    ls = limb_state(GEOM, p, R)
    return np.stack([ls.g, ls.w3, np.cross(ls.g, ls.w3)], axis=-1)


@pytest.mark.parametrize("pose", _poses(4, seed=1))
def test_twist_solution_satisfies_nonholonomic_constraint_independently(pose: Pose) -> None:
    """The limb's angular velocity, from differentiating the limb frame (g_i, w3i) along the twist
    that eq. (11) returns, is orthogonal to r_i: the nS constraint, derived without eq. (9)-(15)."""
    eps = 1e-7
    for ldot in np.eye(3) * 0.01:
        pdot, w = twist_from_leg_rates(GEOM, pose, ldot)
        fp = _limb_frames(pose.p_m + eps * pdot, so3_exp(eps * w) @ pose.R)
        fm = _limb_frames(pose.p_m - eps * pdot, so3_exp(-eps * w) @ pose.R)
        f0 = _limb_frames(pose.p_m, pose.R)
        for i in range(3):
            w_limb = vee((fp[i] - fm[i]) / (2 * eps) @ f0[i].T)
            assert np.linalg.norm(w_limb) > 1e-3
            assert abs(w_limb @ GEOM.r[i]) < 1e-7 * np.linalg.norm(w_limb) + 1e-9


@pytest.mark.parametrize("pose", _poses(4, seed=2))
def test_twist_solve_consistency(pose: Pose) -> None:
    rng = np.random.default_rng(7)
    ldot = rng.normal(size=3) * 0.02
    pdot, w = twist_from_leg_rates(GEOM, pose, ldot)
    assert np.allclose(leg_rates_from_twist(GEOM, pose, pdot, w), ldot, atol=1e-12)
    assert np.allclose(constraint_residual(GEOM, pose, pdot, w), 0.0, atol=1e-12)
    # leg rates against finite differences of the holonomic leg lengths l = |b - a|
    eps = 1e-6
    lp = leg_lengths(GEOM, Pose(pose.p_m + eps * pdot, so3_exp(eps * w) @ pose.R))
    lm = leg_lengths(GEOM, Pose(pose.p_m - eps * pdot, so3_exp(-eps * w) @ pose.R))
    assert np.allclose((lp - lm) / (2 * eps), ldot, atol=1e-9)


@pytest.mark.parametrize("pose", _poses(4, seed=4))
def test_power_balance_of_statics(pose: Pose) -> None:
    """seed 000 eq. (25) with eq. (11): f.p_dot + m.omega = tau . l_dot (printed 'tau . tau_dot' is garbled)."""
    rng = np.random.default_rng(11)
    tau, tau_perp, ldot = rng.normal(size=3) * 50, rng.normal(size=3) * 20, rng.normal(size=3) * 0.01
    f, m = static_wrench(GEOM, pose, tau, tau_perp)
    pdot, w = twist_from_leg_rates(GEOM, pose, ldot)
    assert np.isclose(f @ pdot + m @ w, tau @ ldot, rtol=1e-9, atol=1e-12)
    # eq. (22): f = sum tau_i g_i + sum tau_perp_i s_i
    blk = io_blocks(GEOM, pose.p_m, pose.R)
    assert np.allclose(f, blk.G.T @ tau + blk.S.T @ tau_perp)
    t2, tp2 = joint_forces_from_wrench(GEOM, pose, f, m)
    assert np.allclose(t2, tau) and np.allclose(tp2, tau_perp)


@pytest.mark.parametrize("pose", _poses(4, seed=5))
def test_reduced_singularity_condition(pose: Pose) -> None:
    """seed 000 eq. (26)-(28): det M = -det S det Q and l_dot = Q omega."""
    det_s, Q = reduced_q_matrix(GEOM, pose)
    M = io_matrix(GEOM, pose)
    assert np.isclose(np.linalg.det(M), -det_s * np.linalg.det(Q), rtol=1e-9)
    _, w = twist_from_leg_rates(GEOM, pose, np.array([0.01, -0.02, 0.005]))
    assert np.allclose(Q @ w, [0.01, -0.02, 0.005], atol=1e-12)


def test_type2_singularity_raises() -> None:
    start = Pose(np.array([0, 0, 25.0]) * UNIT, rpy(0, 0, -np.pi / 6))
    goal = Pose(np.array([-0.4, -0.2, 35.0]) * UNIT, rpy(0, 0, -np.pi / 2))

    def det(s):
        return np.linalg.det(io_matrix(GEOM, _interp(start, goal, s)))

    lo, hi = 0.0, 1.0
    assert det(lo) * det(hi) < 0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if det(mid) * det(lo) > 0 else (lo, mid)
    with pytest.raises(SingularityError, match="type-II"):
        twist_from_leg_rates(GEOM, _interp(start, goal, lo), np.array([0.01, 0, 0]))


def _interp(a: Pose, b: Pose, s: float) -> Pose:
    return Pose((1 - s) * a.p_m + s * b.p_m, so3_exp(s * so3_log(b.R @ a.R.T)) @ a.R)


# ---------------------------------------------------------------- controllability (eq. (29)-(36))


def test_xzx_rate_matrix_against_finite_differences() -> None:
    eta = np.array([0.3, 1.0, -0.4])
    eta_dot = np.array([0.2, -0.5, 0.7])
    e = 1e-6
    Rd = (euler_xzx(eta + e * eta_dot) - euler_xzx(eta - e * eta_dot)) / (2 * e)
    assert np.allclose(vee(Rd @ euler_xzx(eta).T), euler_xzx_rate_matrix(eta) @ eta_dot, atol=1e-9)


X0 = np.array([0.02, -0.01, 0.30, 0.0, 1.0, 0.0])  # XZX (0, 1, 0) as in seed 000 Fig. 7-8


def test_vector_field_jacobians_complex_step_vs_central() -> None:
    dc = vector_field_jacobians(GEOM, X0, method="complex")
    dd = vector_field_jacobians(GEOM, X0, method="central")
    assert np.allclose(dc, dd, rtol=1e-5, atol=1e-6 * np.max(np.abs(dc)))


def _flow(x: np.ndarray, k: int, sign: float, eps: float, n: int = 40) -> np.ndarray:
    h = eps / n

    def f(y):
        return sign * vector_fields_xzx(GEOM, y)[:, k]

    for _ in range(n):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


@pytest.mark.parametrize("i,j,col", [(0, 1, 3), (0, 2, 4), (1, 2, 5)])
def test_lie_brackets_against_commutator_flow(i: int, j: int, col: int) -> None:
    """seed 000 eq. (33): flowing v_i, v_j, -v_i, -v_j for eps each moves x0 by eps^2 [v_i, v_j] + O(eps^3)."""
    L = controllability_matrix(GEOM, X0)
    eps = 2e-3
    x = _flow(_flow(_flow(_flow(X0, i, 1, eps), j, 1, eps), i, -1, eps), j, -1, eps)
    approx = (x - X0) / eps**2
    assert np.linalg.norm(approx - L[:, col]) < 0.02 * np.linalg.norm(L[:, col])


def test_controllability_matrix_full_rank_at_generic_pose() -> None:
    L = controllability_matrix(GEOM, X0)
    assert np.allclose(L[:, :3], vector_fields_xzx(GEOM, X0))
    s = np.linalg.svd(L / np.linalg.norm(L, axis=0), compute_uv=False)
    assert s[-1] / s[0] > 1e-4  # locally controllable (Chow), seed 000 eq. (35)


# ---------------------------------------------------------------- forward simulation on R^3 x SO(3)


def test_advance_pose_is_fourth_order_and_stays_on_so3() -> None:
    pose = _poses(1, seed=9)[0]
    ldot = np.array([0.05, -0.03, 0.04])
    ref = advance_pose(GEOM, pose, ldot, 0.2, substeps=64)
    errs = []
    for n in (4, 8):
        out = advance_pose(GEOM, pose, ldot, 0.2, substeps=n)
        assert np.allclose(out.R.T @ out.R, np.eye(3), atol=1e-12)
        errs.append(np.linalg.norm(out.p_m - ref.p_m) + UNIT * np.linalg.norm(so3_log(out.R @ ref.R.T)))
    assert errs[0] / errs[1] > 10.0  # ~16 for order 4
    # the holonomic part is exact up to the integration error: legs move by ldot * dt
    assert np.allclose(leg_lengths(GEOM, ref), leg_lengths(GEOM, pose) + 0.2 * ldot, atol=1e-9)


def test_advance_to_leg_lengths_and_trajectory() -> None:
    pose = _poses(1, seed=10)[0]
    l0 = leg_lengths(GEOM, pose)
    target = l0 + np.array([0.002, -0.001, 0.0015])
    out = advance_pose_to_leg_lengths(GEOM, pose, target, 0.01, substeps=2)
    assert np.allclose(leg_lengths(GEOM, out), target, atol=1e-10)
    t = np.linspace(0.0, 0.5, 51)
    legs = l0 + np.outer(np.sin(2 * np.pi * t), [0.01, -0.005, 0.008])
    poses = integrate_leg_trajectory(GEOM, pose, t, legs)
    assert len(poses) == t.size
    assert np.allclose(leg_lengths(GEOM, poses[-1]), legs[-1], atol=1e-9)
    with pytest.raises(NspuModelError):
        advance_pose(GEOM, pose, np.array([np.nan, 0, 0]), 0.01)
