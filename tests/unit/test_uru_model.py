"""Tests of the LaMaViP 3-URU model (seed 003): position analysis, velocities, singularities, paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.robots.uru.kinematics import (
    UruGeometry,
    UruNoSolutionError,
    UruPathMargins,
    UruPathRefusedError,
    actuated_joint_angles,
    actuation_matrix_explicit,
    check_path,
    configuration,
    default_path,
    direct_kinematics,
    direct_kinematics_joint,
    in_reachable_workspace,
    inverse_kinematics,
    inverse_motor_jacobian,
    joint_from_motor_angles,
    joint_rate_jacobian,
    motor_from_joint_angles,
    motor_jacobian,
    rotation_singularity_measure,
    singularity_fields,
    singularity_measures,
    velocity_matrices,
    workspace_margin_m,
)

GEOM = UruGeometry()
# A less symmetric geometry: d_b != d_p, unequal links, reduction gears, offsets.
GEOM_ASYM = UruGeometry(
    base_offset_m=0.08,
    platform_offset_m=0.06,
    proximal_lengths_m=(0.20, 0.21, 0.19),
    distal_lengths_m=(0.22, 0.20, 0.21),
    gear_ratios=(0.5, -0.25, 2.0),
    motor_offsets_rad=(0.3, -1.0, 2.0),
)


def _useful_points(geom: UruGeometry, n: int, seed: int) -> np.ndarray:
    """Seeded random points of the first octant, 0.03 m from the planes and the workspace boundary,
    with |det V|, |det A| and min|sin th3| bounded away from 0."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        p = rng.uniform(0.03, 0.3, 3)
        if workspace_margin_m(geom, p) < 0.03:
            continue
        m = singularity_measures(geom, p)
        if abs(m.translation_det_v) > 0.1 and abs(m.combined_det_a) > 0.1 and m.serial_min_sin_th3 > 0.2:
            out.append(p)
    return np.array(out)


def _fd(fun, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of fun: R^3 -> R^3."""
    cols = []
    for j in range(3):
        dx = np.zeros(3)
        dx[j] = h
        cols.append((fun(x + dx) - fun(x - dx)) / (2 * h))
    return np.stack(cols, axis=1)


# --- position analysis -------------------------------------------------------------------------


def test_ik_satisfies_closure_and_link_lengths() -> None:
    for geom in (GEOM, GEOM_ASYM):
        for p in _useful_points(geom, 20, seed=1):
            cfg = configuration(geom, p)
            a = geom.base_offset_m * np.eye(3)
            b = p[None, :] + geom.platform_offset_m * np.eye(3)
            c = a + geom.f[:, None] * cfg.u
            np.testing.assert_allclose(np.linalg.norm(c - a, axis=1), geom.f, atol=1e-12)
            np.testing.assert_allclose(np.linalg.norm(b - c, axis=1), geom.r, atol=1e-12)
            # intermediate R-pair axes g_i orthogonal to both links and to e_i (seed 003 §2)
            np.testing.assert_allclose(np.einsum("ij,ij->i", cfg.g, b - c), 0.0, atol=1e-12)
            np.testing.assert_allclose(np.einsum("ij,ij->i", cfg.g, c - a), 0.0, atol=1e-12)
            np.testing.assert_allclose(np.diag(cfg.g), 0.0, atol=1e-15)
            # branch: sin th_i3 > 0 for knee_sign = +1
            assert np.all(np.sin(cfg.th3_rad) > 0)
            # phase references of th_i1 (seed 003 §2)
            t = cfg.th1_rad
            np.testing.assert_allclose(cfg.g[0], [0, math.cos(t[0]), math.sin(t[0])], atol=1e-12)
            np.testing.assert_allclose(cfg.g[1], [-math.cos(t[1]), 0, math.sin(t[1])], atol=1e-12)
            np.testing.assert_allclose(cfg.g[2], [math.cos(t[2]), math.sin(t[2]), 0], atol=1e-12)


def test_ik_matches_printed_tan_half_formula_a2() -> None:
    """eq. (A2) with the upper ('-') sign is the knee_sign = +1 branch, the '+' sign the other."""
    for knee, sign in ((1, -1.0), (-1, 1.0)):
        geom = UruGeometry(base_offset_m=0.08, platform_offset_m=0.06, knee_sign=knee)
        for p in _useful_points(GEOM, 10, seed=2):
            x, y, z = p
            alpha = p + geom.offset_m
            beta = np.array([math.hypot(y, z), math.hypot(x, z), math.hypot(x, y)])
            f, r = geom.f, geom.r
            q = alpha**2 + beta**2 + f**2 - r**2
            t = (2 * f * beta + sign * np.sqrt(4 * f**2 * (alpha**2 + beta**2) - q**2)) / (
                (alpha + f) ** 2 + beta**2 - r**2
            )
            th = actuated_joint_angles(geom, p)
            np.testing.assert_allclose(np.tan(th / 2), t, rtol=1e-9, atol=1e-12)
            # eq. (A1) itself
            np.testing.assert_allclose(q - 2 * f * (alpha * np.cos(th) + beta * np.sin(th)), 0.0, atol=1e-14)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(0.04, 0.28),
    st.floats(0.04, 0.28),
    st.floats(0.04, 0.28),
    st.floats(-0.001, 0.001),
    st.floats(-0.001, 0.001),
    st.floats(-0.001, 0.001),
)
def test_round_trip_motor_angles(x: float, y: float, z: float, dx: float, dy: float, dz: float) -> None:
    p = np.array([x, y, z])
    for geom in (GEOM, GEOM_ASYM):
        if workspace_margin_m(geom, p) < 0.03:
            continue
        m = singularity_measures(geom, p)
        if abs(m.combined_det_a) < 0.05 or m.serial_min_sin_th3 < 0.1:
            continue
        thm = inverse_kinematics(geom, p)
        # start up to 1 mm away, as the controller does from the previous cycle's pose (0.25 mm at
        # 0.1 m/s and 400 Hz). Not 4 mm: near an actuation singularity (GEOM_ASYM at (0.0586, 0.0625,
        # 0.0469) m, det A = -0.064) a second solution with the same motor angles lies 7 mm away, and
        # Newton from 5.5 mm off finds it (hypothesis found that pose).
        p_back = direct_kinematics(geom, thm, p_guess_m=p + np.array([dx, dy, dz]))
        np.testing.assert_allclose(p_back, p, atol=1e-10)
        np.testing.assert_allclose(inverse_kinematics(geom, p_back), thm, atol=1e-10)


def test_round_trip_from_home_and_joint_angles() -> None:
    """Without a guess, direct kinematics starts at home (Newton, then continuation): it must
    find the pose anywhere in the singularity-free first octant."""
    for geom in (GEOM, GEOM_ASYM):
        for p in _useful_points(geom, 40, seed=3):
            np.testing.assert_allclose(direct_kinematics(geom, inverse_kinematics(geom, p)), p, atol=1e-10)
        for p in _useful_points(geom, 25, seed=4):
            th2 = actuated_joint_angles(geom, p)
            np.testing.assert_allclose(direct_kinematics_joint(geom, th2), p, atol=1e-10)


def test_motor_joint_angle_mapping_eq11() -> None:
    th1 = np.array([2.0, -2.5, 1.9])
    th2 = np.array([0.1, -0.4, 0.7])
    thm = motor_from_joint_angles(GEOM_ASYM, th1, th2)
    np.testing.assert_allclose(joint_from_motor_angles(GEOM_ASYM, th1, thm), th2, atol=1e-15)
    # eq. (11) as printed with th_iM|0 - th_i1|0 = c_i
    np.testing.assert_allclose(GEOM_ASYM.k * ((thm - th1) - GEOM_ASYM.c), th2, atol=1e-15)


def test_ik_refuses_unreachable_and_axis_points() -> None:
    with pytest.raises(UruNoSolutionError, match="out of reach of limb"):
        inverse_kinematics(GEOM, np.array([0.3, 0.3, 0.3]))  # |p| = 0.52 m > 2 R
    with pytest.raises(UruNoSolutionError, match="axis of e_1"):
        inverse_kinematics(GEOM, np.array([0.1, 0.0, 0.0]))


def test_direct_kinematics_reports_no_solution() -> None:
    """A provably unsolvable input: with th_12 = -pi/2, beta_1 = h_1 . (b_1 - a_1)
    = f_1 sin th_12 + r_1 (v_1 . h_1) <= -f_1 + r_1 < 0 when f_1 > r_1, but beta_1 = |e_1 x p| >= 0."""
    geom = UruGeometry(proximal_lengths_m=(0.3, 0.3, 0.3), distal_lengths_m=(0.1, 0.1, 0.1))
    th2 = actuated_joint_angles(geom, np.array([0.12, 0.12, 0.12]))
    th2[0] = -math.pi / 2
    with pytest.raises(UruNoSolutionError, match=r"direct kinematics .*no convergence"):
        direct_kinematics_joint(geom, th2)


def test_direct_kinematics_detects_other_branch() -> None:
    """The closure equations (A1) do not know the branch: angles of the knee -1 branch at p
    satisfy them at p, so Newton started at p stops there; the branch check must refuse it."""
    geom_other = UruGeometry(knee_sign=-1)
    p = np.array([0.12, 0.1, 0.14])
    th2_other = actuated_joint_angles(geom_other, p)
    assert np.all(np.sin(configuration(geom_other, p).th3_rad) < 0)
    np.testing.assert_allclose(direct_kinematics_joint(geom_other, th2_other, p_guess_m=p), p, atol=1e-12)
    with pytest.raises(UruNoSolutionError, match="other knee branch"):
        direct_kinematics_joint(GEOM, th2_other, p_guess_m=p)


# --- instantaneous kinematics ------------------------------------------------------------------


def test_joint_jacobian_eq18_against_finite_differences() -> None:
    for geom in (GEOM, GEOM_ASYM):
        for p in _useful_points(geom, 8, seed=5):
            # d th2 / d p by finite differences of the IK, inverse of p_dot = V^-1 G th2_dot
            fd = _fd(lambda q, gm=geom: actuated_joint_angles(gm, q), p)
            np.testing.assert_allclose(fd @ joint_rate_jacobian(geom, p), np.eye(3), atol=1e-6)


def test_motor_jacobian_eq19_against_finite_differences() -> None:
    for geom in (GEOM, GEOM_ASYM):
        for p in _useful_points(geom, 8, seed=6):
            fd = _fd(lambda q, gm=geom: inverse_kinematics(gm, q), p)  # includes the gear mapping eq. (11)
            np.testing.assert_allclose(inverse_motor_jacobian(geom, p), fd, rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(motor_jacobian(geom, p) @ fd, np.eye(3), atol=1e-6)


def test_eq12_cross_rates_and_eq10_gear_relation() -> None:
    geom = GEOM_ASYM
    p = _useful_points(geom, 1, seed=7)[0]
    pdot = np.array([0.03, -0.02, 0.05])
    h = 1e-6
    c_p, c_m = configuration(geom, p + h * pdot), configuration(geom, p - h * pdot)
    th1dot = (c_p.th1_rad - c_m.th1_rad) / (2 * h)
    th2dot = (c_p.th2_rad - c_m.th2_rad) / (2 * h)
    mats = velocity_matrices(geom, p)
    np.testing.assert_allclose(th1dot, mats.N @ mats.M @ pdot, rtol=1e-6)  # eq. (12), omega = 0
    thmdot = inverse_motor_jacobian(geom, p) @ pdot
    np.testing.assert_allclose(th2dot, geom.k * (thmdot - th1dot), rtol=1e-6)  # eq. (10)
    np.testing.assert_allclose(mats.S @ th2dot, mats.K @ thmdot, rtol=1e-6, atol=1e-9)  # eq. (32)


def test_eq34_corrected_matches_matrix_product_and_det_identity() -> None:
    for geom in (GEOM, GEOM_ASYM):
        for p in _useful_points(geom, 6, seed=8):
            mats = velocity_matrices(geom, p)
            np.testing.assert_allclose(actuation_matrix_explicit(geom, p), mats.S, atol=1e-10)
            # derived: det A (eq. (36)) = det S (eq. (35)) * det V (eq. (20))
            assert np.linalg.det(mats.A) == pytest.approx(
                np.linalg.det(mats.S) * np.linalg.det(mats.V), rel=1e-9
            )
            # eq. (6b)/(27): G_ii = f_i sin th_i3
            cfg = configuration(geom, p)
            np.testing.assert_allclose(np.diag(mats.G), geom.f * np.sin(cfg.th3_rad), atol=1e-12)


def test_printed_eq34_index_is_a_typo() -> None:
    """With the printed index (i instead of j) the entries differ from S = I + K N M V^-1 G."""
    p = _useful_points(GEOM_ASYM, 1, seed=9)[0]
    mats = velocity_matrices(GEOM_ASYM, p)
    cfg = configuration(GEOM_ASYM, p)
    v, detv = cfg.v, float(np.linalg.det(cfg.v))
    printed = np.eye(3)
    for i in range(3):
        for j in range(3):
            printed[i, j] += (
                GEOM_ASYM.k[i]
                * cfg.g[i]
                @ np.cross(v[(i + 1) % 3], v[(i + 2) % 3])
                * mats.G[j, j]
                / (detv * cfg.beta_m[i])
            )
    assert np.max(np.abs(printed - mats.S)) > 1e-3


def test_omega_terms_t_and_h_eq5_by_rigid_body_velocities() -> None:
    """T and H of eq. (6a): for a platform twist with omega != 0 built from joint rates of one limb.

    Limb i moves its joints with rates (th1, th2, th3, th4, th5); the platform twist follows
    from the serial chain. Eq. (4) (row i of [V T] vs G) and eq. (2) (h_i . omega = 0) must hold.
    """
    geom = GEOM_ASYM
    p = _useful_points(geom, 1, seed=10)[0]
    cfg = configuration(geom, p)
    mats = velocity_matrices(geom, p)
    rng = np.random.default_rng(11)
    a = geom.base_offset_m * np.eye(3)
    b = p[None, :] + geom.platform_offset_m * np.eye(3)
    c = a + geom.f[:, None] * cfg.u
    for i in range(3):
        e, g = np.eye(3)[i], cfg.g[i]
        rates = rng.normal(size=5)
        # joint screws (axis, point): e through A, g through A, g through C, g through B, e through B
        axes = [(e, a[i]), (g, a[i]), (g, c[i]), (g, b[i]), (e, b[i])]
        omega = sum(w * ax for w, (ax, _pt) in zip(rates, axes, strict=True))
        v_p = sum(w * np.cross(ax, p - pt) for w, (ax, pt) in zip(rates, axes, strict=True))  # velocity of P
        assert mats.H[i] @ omega == pytest.approx(0.0, abs=1e-12)  # eq. (2)
        lhs = mats.V[i] @ v_p + mats.T[i] @ omega  # eq. (4)
        assert lhs == pytest.approx(mats.G[i, i] * rates[1], abs=1e-12)
        th1dot = (g @ v_p + np.cross(g, p - b[i]) @ omega) / cfg.beta_m[i]  # eq. (12)
        assert th1dot == pytest.approx(rates[0], abs=1e-12)
        # eq. (13): with th_iM_dot = th_i2_dot / k_i + th_i1_dot (eq. (10))
        thm_dot = rates[1] / geom.k[i] + rates[0]
        lhs13 = mats.A[i] @ v_p + mats.T_motor[i] @ omega
        assert lhs13 == pytest.approx(mats.D[i, i] * thm_dot, abs=1e-12)


# --- singularities and workspace ---------------------------------------------------------------


def test_rotation_singularity_is_the_coordinate_planes() -> None:
    rng = np.random.default_rng(12)
    pts = rng.uniform(-0.3, 0.3, (200, 3))
    x, y, z = pts.T
    # eq. (17) equals det H from the unit vectors eq. (16)
    for p in pts[:20]:
        h = configuration(UruGeometry(), p * 0.5).h if np.linalg.norm(p * 0.5) < 0.39 else None
        if h is not None:
            assert np.linalg.det(h) == pytest.approx(float(rotation_singularity_measure(p * 0.5)), abs=1e-12)
    expected = 2 * x * y * z / np.sqrt((x**2 + z**2) * (x**2 + y**2) * (y**2 + z**2))
    np.testing.assert_allclose(rotation_singularity_measure(pts), expected, atol=1e-14)
    # zero exactly on each coordinate plane, nonzero off them
    for axis in range(3):
        on = pts.copy()
        on[:, axis] = 0.0
        np.testing.assert_allclose(rotation_singularity_measure(on), 0.0, atol=1e-15)
    assert np.all(np.abs(rotation_singularity_measure(pts)) > 0)
    # det H of the model (from g_i, h_i of the IK) vanishes when P approaches the planes
    for axis in range(3):
        p = np.array([0.1, 0.12, 0.14])
        p[axis] = 1e-9
        assert abs(singularity_measures(GEOM, p).rotation_det_h) < 1e-7
    # sign of det H = sign of xyz: constant in each octant
    np.testing.assert_array_equal(np.sign(rotation_singularity_measure(pts)), np.sign(x * y * z))


@pytest.mark.parametrize("radius_m,offset_m", [(0.2, 0.1), (0.15, 0.0), (0.31, 0.07)])
def test_workspace_is_sphere_of_radius_2r(radius_m: float, offset_m: float) -> None:
    geom = UruGeometry(
        base_offset_m=offset_m,
        platform_offset_m=offset_m,
        proximal_lengths_m=(radius_m,) * 3,
        distal_lengths_m=(radius_m,) * 3,
    )
    rng = np.random.default_rng(13)
    dirs = rng.normal(size=(300, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    inside = dirs * (2 * radius_m) * rng.uniform(0.05, 0.999, (300, 1))
    outside = dirs * (2 * radius_m) * rng.uniform(1.001, 1.5, (300, 1))
    assert np.all(in_reachable_workspace(geom, inside))
    assert not np.any(in_reachable_workspace(geom, outside))
    np.testing.assert_allclose(workspace_margin_m(geom, dirs * 2 * radius_m), 0.0, atol=1e-12)
    # eq. (29) agrees with the IK: solvable inside, "out of reach" outside
    for p in inside[:50]:
        actuated_joint_angles(geom, p)
    for p in outside[:50]:
        with pytest.raises(UruNoSolutionError):
            actuated_joint_angles(geom, p)


def test_workspace_boundary_is_serial_singularity_eq27() -> None:
    """d_b = d_p, f = r = R: |b_i - a_i| = |p| = 2 R s for every limb and, from the triangle
    A_i C_i B_i, |p|^2 = 2 R^2 (1 + cos th_i3), i.e. sin th_i3 = 2 s sqrt(1 - s^2) -> 0 at s = 1."""
    d = np.array([1.0, 1.3, 0.8]) / np.linalg.norm([1.0, 1.3, 0.8])
    for s in (0.5, 0.9, 0.999, 0.99999):
        m = singularity_measures(GEOM, d * 0.4 * s)
        assert m.serial_min_sin_th3 == pytest.approx(2 * s * math.sqrt(1 - s * s), rel=1e-6)
        assert m.workspace_margin_m == pytest.approx(0.4 * (1 - s), abs=1e-12)
        mats = velocity_matrices(GEOM, d * 0.4 * s)
        np.testing.assert_allclose(np.diag(mats.G), 0.2 * 2 * s * math.sqrt(1 - s * s), rtol=1e-6)


def test_eq25_expansion_equals_det_v() -> None:
    geom = GEOM_ASYM
    for p in _useful_points(geom, 5, seed=14):
        x, y, z = p
        cfg = configuration(geom, p)
        th, f = cfg.th2_rad, geom.f
        m = 1 / np.array([math.hypot(y, z), math.hypot(x, z), math.hypot(x, y)])  # eq. (23)
        n = 1 - f * m * np.sin(th)  # eq. (26a)
        q = geom.offset_m - f * np.cos(th)  # eq. (26b)
        e25 = (
            x * y * z * (1 - n[1] * n[2] - n[0] * n[1] - n[0] * n[2] + 2 * n[0] * n[1] * n[2])
            + x * y * q[2] * (1 - n[0] * n[1])
            + x * z * q[1] * (1 - n[0] * n[2])
            + y * z * q[0] * (1 - n[1] * n[2])
            + x * q[1] * q[2]
            + y * q[0] * q[2]
            + z * q[0] * q[1]
            + q[0] * q[1] * q[2]
        )
        assert e25 == pytest.approx(np.prod(geom.r) * np.linalg.det(cfg.v), rel=1e-10)  # eq. (24)


def test_vectorised_fields_match_pointwise_measures() -> None:
    pts = _useful_points(GEOM_ASYM, 10, seed=15)
    fields = singularity_fields(GEOM_ASYM, pts)
    for idx, p in enumerate(pts):
        m = singularity_measures(GEOM_ASYM, p)
        assert fields["translation_det_v"][idx] == pytest.approx(m.translation_det_v, rel=1e-10)
        assert fields["actuation_det_s"][idx] == pytest.approx(m.actuation_det_s, rel=1e-9)
        assert fields["combined_det_a"][idx] == pytest.approx(m.combined_det_a, rel=1e-10)
        assert fields["serial_min_sin_th3"][idx] == pytest.approx(m.serial_min_sin_th3, rel=1e-10)


def test_default_first_octant_is_free_of_translation_and_actuation_singularities() -> None:
    s = np.linspace(0.02, 0.4, 30)
    pts = np.stack(np.meshgrid(s, s, s, indexing="ij"), -1).reshape(-1, 3)
    pts = pts[workspace_margin_m(GEOM, pts) > 0.02]
    f = singularity_fields(GEOM, pts)
    assert np.min(f["translation_det_v"]) > 0.15
    assert np.min(f["actuation_det_s"]) > 2.0
    assert np.min(f["combined_det_a"]) > 0.4
    # while a mixed-sign octant of the same geometry holds actuation singularities
    f2 = singularity_fields(GEOM, pts * np.array([1.0, -1.0, 1.0]))
    assert np.nanmin(f2["actuation_det_s"]) < 0 < np.nanmax(f2["actuation_det_s"])


# --- path checks -------------------------------------------------------------------------------


def test_default_path_is_accepted_and_in_first_octant() -> None:
    path = default_path(np.linspace(0.0, 1.0, 721))
    check_path(GEOM, path)
    assert np.all(path > 0.08)
    np.testing.assert_allclose(default_path(0.0), default_path(1.0), atol=1e-15)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        default_path(1.2)


def test_path_crossing_a_coordinate_plane_is_refused() -> None:
    start, end = np.array([0.12, 0.101, 0.15]), np.array([0.12, -0.099, 0.15])
    path = start + np.linspace(0, 1, 101)[:, None] * (end - start)
    with pytest.raises(UruPathRefusedError) as info:
        check_path(GEOM, path)
    err = info.value
    assert "plane y=0" in str(err) and "eq. (17)" in str(err)
    assert err.sample_index == 41  # y = 0.101 - 0.002 * 41 = 0.019 < 0.02 m
    assert err.value == pytest.approx(0.019, abs=1e-12)
    # a coarse path that jumps over the plane is refused by the sign check of det H
    with pytest.raises(UruPathRefusedError, match=r"det H .*changed sign"):
        check_path(GEOM, np.array([start, end]), UruPathMargins(plane_distance_m=0.0))


def test_path_leaving_the_workspace_is_refused() -> None:
    d = np.ones(3) / math.sqrt(3)
    path = d[None, :] * np.linspace(0.2, 0.39, 50)[:, None]
    with pytest.raises(UruPathRefusedError, match="workspace boundary") as info:
        check_path(GEOM, path)
    assert info.value.value < 0.02


def test_path_through_actuation_singularity_is_refused() -> None:
    # section z = 0.05 m, octant (+, -, +): det S changes sign between y = -0.03 and y = -0.1 at x = 0.2
    path = np.array([[0.2, y, 0.05] for y in np.linspace(-0.03, -0.1, 40)])
    with pytest.raises(UruPathRefusedError, match=r"actuation|combined"):
        check_path(GEOM, path, UruPathMargins(plane_distance_m=0.01))


@pytest.mark.slow
def test_plots_are_written(tmp_path) -> None:
    from controller.robots.uru.analysis import plot_workspace_and_singularities

    files = plot_workspace_and_singularities(GEOM, tmp_path / "png", grid_points=61)
    assert [f.name for f in files] == [
        "uru_workspace_3d.png",
        "uru_sections_z.png",
        "uru_section_diagonal.png",
    ]
    for f in files:
        assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f.stat().st_size > 20_000


def test_geometry_validation() -> None:
    with pytest.raises(ValueError, match="gear_ratios"):
        UruGeometry(gear_ratios=(1.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="proximal_lengths_m"):
        UruGeometry(proximal_lengths_m=(0.2, -0.1, 0.2))
    with pytest.raises(ValueError, match="knee_sign"):
        UruGeometry(knee_sign=0)
