"""The end-point map of seed 004 system (7) and its Jacobian from the variational equations (11).

System (7) of seed 004: p_dot = F(p, R) v with F = S^-1 J (seed 000 eq. (14)-(15)), R_dot = -[v] R,
driven by the truncated Fourier controls v(t) = P(t) Lambda of eq. (15).  Its end-point map
Lambda -> (p(T), R(T)) and the Jacobian of that map with respect to Lambda are integrated here in
one pass, the motion and its linearisation side by side:

* the motion with the Runge-Kutta-Munthe-Kaas scheme of order 4 on R^3 x SO(3)
  (`controller.robots.nspu.rkmk4_step`, written out here so the stage poses are at hand);
* the variational system of seed 004 eq. (10)-(11) for the sensitivities
  w = dp/dLambda (3 x n) and s with [s] = (dR/dLambda) R^T (3 x n, the spatial perturbation of R):
      w_dot = A11 w + A12 s + F P(t),       A11 = d(F v)/dp,  A12 = d(F v)/ds,
      s_dot = -[v] s - P(t),
  derivation of the s row: [s_dot] = d/dt(dR R^T) = d(R_dot) R^T + dR R_dot^T
  = -[dv] - [v][s] + [s][v] = -[dv] - [v x s], with dv = P dLambda;
  integrated with the classical RK4 tableau at the same stage poses (initial value 0, eq. (12));
* A11, A12 by complex-step differentiation of F v (six directions in one batched evaluation of
  seed 000 eq. (12)-(15); the model is complex-step safe, so they are exact to rounding).

Accuracy: both parts are fourth order in the step.  The Jacobian is that of the continuous map up
to O(dt^4) (it is not the exact derivative of the discrete map; tests compare it with central
differences of the discrete map).  With 32 steps over T = 1 s the end point of the paper's initial
controls is within 4e-6 (aul and rad) of a 1600-step integration (measured: 25 steps 1.3e-5,
50 steps 8.3e-7, 100 steps 5.2e-8); the planner verifies every converged plan with a finer
integration and refines its step when the two disagree (`nonholonomic.PlannerConfig.plan_steps`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from controller.core.rotations import hat
from controller.robots.nspu.kinematics import _NEXT, _PREV, NspuGeometry, Pose, _cross, _dexpinv, io_blocks

Array = NDArray[np.float64]

_CSTEP = 1e-20  # complex step; the derivative's error is O(step^2), far below rounding


def fourier_rows(t_s: Array, horizon_s: float, harmonics: int) -> Array:
    """P(t) of seed 004 eq. (15) as (..., 3, 3(2h+1)): v(t) = P(t) Lambda, Lambda ordered by control."""
    t = np.asarray(t_s, dtype=float)
    cols = [np.ones_like(t)]
    for k in range(1, harmonics + 1):
        arg = 2.0 * np.pi * k * t / horizon_s
        cols += [np.sin(arg), np.cos(arg)]
    basis = np.stack(cols, axis=-1)  # (..., 2h+1)
    m = basis.shape[-1]
    out = np.zeros((*t.shape, 3, 3 * m))
    for i in range(3):
        out[..., i, i * m : (i + 1) * m] = basis
    return out


def rate_matrix(geometry: NspuGeometry, p: Array, R: Array) -> Array:
    """F = S^-1 J of seed 004 eq. (7), (..., 3, 3); complex-step safe.  LinAlgError where det S = 0."""
    blk = io_blocks(geometry, p, R)
    return cast(Array, np.linalg.solve(blk.S, blk.J))


def _rate_matrix_single(geometry: NspuGeometry, p: Array, R: Array) -> Array:
    """`rate_matrix` at one real pose, written for speed (the motion is stepped one pose at a time).

    The same formulas as `controller.robots.nspu.limb_state` / `io_blocks` (seed 000 eq. (1),
    (10), (14)-(15), w3i = g_i x w4i / |g_i x w4i|), and S^-1 from the cross products of its rows
    (S^-1 = [s2 x s3, s3 x s1, s1 x s2] / det S).  Tested against `rate_matrix`.
    """
    bp = geometry.b_platform_m @ R.T  # rows R eb_i = b_i - p
    d = bp + (p - geometry.a_m)  # l_i g_i = b_i - a_i
    l = np.sqrt(np.einsum("ij,ij->i", d, d))
    g = d / l[:, None]
    w4 = geometry.w4_platform @ R.T
    c = _cross(g, w4)
    w3 = c / np.sqrt(np.einsum("ij,ij->i", c, c))[:, None]
    h = _cross(w3, w4)
    hxr = _cross(h, geometry.r)
    s = hxr - np.einsum("ij,ij->i", g, hxr)[:, None] * g  # eq. (10)
    rg = np.einsum("ij,ij->i", geometry.r, g)
    J = _cross(bp, s) - (l * rg)[:, None] * h  # eq. (14)
    cof = _cross(s.take(_NEXT, axis=0), s.take(_PREV, axis=0))  # rows s2 x s3, s3 x s1, s1 x s2
    det_s = float(s[0] @ cof[0])
    if not abs(det_s) > 1e-300:
        raise np.linalg.LinAlgError("det S = 0")
    out: Array = (cof.T @ J) / det_s
    return out


def _so3_exp_single(w: Array) -> Array:
    """exp([w]) for one real rotation vector (Rodrigues), the fast path of `so3_exp`."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    th2 = x * x + y * y + z * z
    if th2 < 1e-12:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return np.array(
        [
            [1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z],
            [a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z],
            [-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)],
        ]
    )


def integrate_motion(
    geometry: NspuGeometry,
    start: Pose,
    lambdas: Array,
    horizon_s: float,
    harmonics: int,
    n_steps: int,
    keep_stages: bool = False,
) -> tuple[Array, Array, Array, Array | None, Array | None]:
    """RKMK4 steps of system (7) for one coefficient vector (as `controller.robots.nspu.rkmk4_step`).

    Returns t (N+1,), p (N+1, 3), R (N+1, 3, 3) and, with keep_stages, the four stage poses of
    every step, (N, 4, 3) and (N, 4, 3, 3).  Raises np.linalg.LinAlgError where det S = 0.
    """
    lam = np.asarray(lambdas, dtype=float)
    h = horizon_s / n_steps
    t = np.linspace(0.0, horizon_s, n_steps + 1)
    v_nodes = fourier_rows(t, horizon_s, harmonics) @ lam
    v_half = fourier_rows(t[:-1] + 0.5 * h, horizon_s, harmonics) @ lam
    ps = np.empty((n_steps + 1, 3))
    Rs = np.empty((n_steps + 1, 3, 3))
    stage_p = np.empty((n_steps, 4, 3)) if keep_stages else None
    stage_R = np.empty((n_steps, 4, 3, 3)) if keep_stages else None
    p, R = np.array(start.p_m, dtype=float), np.array(start.R, dtype=float)
    ps[0], Rs[0] = p, R
    rate = _rate_matrix_single
    for k in range(n_steps):
        v1, v2, v4 = v_nodes[k], v_half[k], v_nodes[k + 1]
        k1p = rate(geometry, p, R) @ v1
        u = -0.5 * h * v1
        p2, R2 = p + 0.5 * h * k1p, _so3_exp_single(u) @ R
        k2p, k2w = rate(geometry, p2, R2) @ v2, _dexpinv(u, -v2)
        u = 0.5 * h * k2w
        p3, R3 = p + 0.5 * h * k2p, _so3_exp_single(u) @ R
        k3p, k3w = rate(geometry, p3, R3) @ v2, _dexpinv(u, -v2)
        u = h * k3w
        p4, R4 = p + h * k3p, _so3_exp_single(u) @ R
        k4p, k4w = rate(geometry, p4, R4) @ v4, _dexpinv(u, -v4)
        if stage_p is not None and stage_R is not None:
            stage_p[k, 0], stage_p[k, 1], stage_p[k, 2], stage_p[k, 3] = p, p2, p3, p4
            stage_R[k, 0], stage_R[k, 1], stage_R[k, 2], stage_R[k, 3] = R, R2, R3, R4
        p = p + h / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p)
        R = _so3_exp_single(h / 6.0 * (-v1 + 2 * k2w + 2 * k3w + k4w)) @ R
        ps[k + 1], Rs[k + 1] = p, R
    return t, ps, Rs, stage_p, stage_R


def _linearise(geometry: NspuGeometry, p: Array, R: Array, v: Array) -> tuple[Array, Array]:
    """F (M, 3, 3) and A_top = d(F v)/d(p, s) (M, 3, 6) at M poses p (M, 3), R (M, 3, 3), controls v (M, 3).

    Complex steps along the six tangent directions (p + i h e_k; R + i h [e_k] R), all M x 6
    members in one batched evaluation of seed 000 eq. (12)-(15).
    """
    eye = np.eye(3)
    dp = np.zeros((6, 3), dtype=complex)
    dp[:3] = 1j * _CSTEP * eye
    drot = np.zeros((6, 3, 3), dtype=complex)
    drot[3:] = 1j * _CSTEP * hat(eye)  # the tangent direction [e_k] R of a spatial rotation
    pc = p[:, None, :] + dp  # (M, 6, 3)
    rc = R[:, None] + drot @ R[:, None]  # (M, 6, 3, 3)
    F = rate_matrix(geometry, pc, rc)  # (M, 6, 3, 3)
    dfv = np.imag(np.einsum("mkij,mj->mik", F, v)) / _CSTEP  # (M, 3, 6)
    return np.real(F[:, 0]), dfv


@dataclass(frozen=True, eq=False)
class Sensitivity:
    """Motion of system (7) at the step times and its derivative with respect to Lambda.

    t_s (N+1,), p_m (N+1, 3), R (N+1, 3, 3); d_pose (N+1, 6, n): rows 0-2 w = dp/dLambda [m per
    unit of Lambda], rows 3-5 s with [s] = dR/dLambda R^T (seed 004 eq. (10)).
    """

    t_s: Array
    p_m: Array
    R: Array
    d_pose: Array


@dataclass(frozen=True, eq=False)
class Motion:
    """One integration of system (7): t_s (N+1,), p_m (N+1, 3), R (N+1, 3, 3) and the four stage
    poses of each step, (N, 4, 3) and (N, 4, 3, 3), from which `sensitivity` gets the Jacobian."""

    t_s: Array
    p_m: Array
    R: Array
    stage_p: Array
    stage_R: Array


def integrate_motion_with_stages(
    geometry: NspuGeometry, start: Pose, lambdas: Array, horizon_s: float, harmonics: int, n_steps: int
) -> Motion:
    """`integrate_motion` keeping the stage poses (pass 1 of `integrate_with_sensitivity`)."""
    t, ps, Rs, sp, sr = integrate_motion(geometry, start, lambdas, horizon_s, harmonics, n_steps, True)
    assert sp is not None and sr is not None
    return Motion(t, ps, Rs, sp, sr)


def sensitivity(
    geometry: NspuGeometry, motion: Motion, lambdas: Array, horizon_s: float, harmonics: int
) -> Array:
    """d_pose (N+1, 6, n) of a `Motion` (passes 2 and 3 of `integrate_with_sensitivity`)."""
    n = np.asarray(lambdas).size
    n_steps = motion.t_s.size - 1
    h = horizon_s / n_steps
    P_nodes = fourier_rows(motion.t_s, horizon_s, harmonics)  # (N+1, 3, n)
    P_half = fourier_rows(motion.t_s[:-1] + 0.5 * h, horizon_s, harmonics)  # (N, 3, n)
    lam = np.asarray(lambdas, dtype=float)
    v_nodes = P_nodes @ lam
    v_half = P_half @ lam
    # pass 2: the variational system's matrices at every stage (seed 004 eq. (11))
    stage_v = np.stack([v_nodes[:-1], v_half, v_half, v_nodes[1:]], axis=1)  # (N, 4, 3)
    stage_P = np.stack([P_nodes[:-1], P_half, P_half, P_nodes[1:]], axis=1)  # (N, 4, 3, n)
    F, A_top = _linearise(
        geometry, motion.stage_p.reshape(-1, 3), motion.stage_R.reshape(-1, 3, 3), stage_v.reshape(-1, 3)
    )
    A = np.zeros((n_steps, 4, 6, 6))
    A[:, :, :3, :] = A_top.reshape(n_steps, 4, 3, 6)  # A11 | A12
    A[:, :, 3:, 3:] = -hat(stage_v)  # -[v]
    B = np.concatenate([F.reshape(n_steps, 4, 3, 3) @ stage_P, -stage_P], axis=2)  # (N, 4, 6, n): [F P; -P]
    # pass 3: RK4 of Y_dot = A Y + B as Y_k+1 = M_k Y_k + N_k, stage by stage K_j = Ka_j Y + Kb_j
    eye6 = np.eye(6)
    ka, kb = A[:, 0], B[:, 0]
    m_sum, n_sum = ka.copy(), kb.copy()
    for j, (c, w) in enumerate(((0.5, 2.0), (0.5, 2.0), (1.0, 1.0)), start=1):
        ka, kb = A[:, j] @ (eye6 + c * h * ka), A[:, j] @ (c * h * kb) + B[:, j]
        m_sum += w * ka
        n_sum += w * kb
    M = eye6 + h / 6.0 * m_sum
    N = h / 6.0 * n_sum
    Ys = np.empty((n_steps + 1, 6, n))
    Ys[0] = 0.0  # eq. (12): w_0 = s_0 = 0
    for k in range(n_steps):
        Ys[k + 1] = M[k] @ Ys[k] + N[k]
    return Ys


def integrate_with_sensitivity(
    geometry: NspuGeometry, start: Pose, lambdas: Array, horizon_s: float, harmonics: int, n_steps: int
) -> Sensitivity:
    """Integrate system (7) and its variational system (11) over [0, T] in n_steps fixed steps (module doc).

    Three passes, so that only the motion itself is stepped one pose at a time: (1) the RKMK4
    steps of the motion, keeping the four stage poses of each step; (2) F and A at all 4N stage
    poses in one batched complex-step evaluation; (3) the RK4 steps of the linear system (11),
    written as Y_k+1 = M_k Y_k + N_k with M_k, N_k from the stage matrices (batched over k).
    Raises np.linalg.LinAlgError where S is singular; non-finite values mean the same.
    """
    motion = integrate_motion_with_stages(geometry, start, lambdas, horizon_s, harmonics, n_steps)
    return Sensitivity(
        motion.t_s, motion.p_m, motion.R, sensitivity(geometry, motion, lambdas, horizon_s, harmonics)
    )


def so3_log_left_jacobian_inverse(r: Array) -> Array:
    """d log(exp([s]) exp([r])) / ds at s = 0: J_l^-1(r) = I - [r]/2 + (1/a^2 - (1 + cos a)/(2 a sin a)) [r]^2.

    Used for the rotation part of the error e = log(R_T R_d^T) (seed 004 eq. (13)): a spatial
    perturbation [s] R_T of R_T perturbs R_T R_d^T on the left.
    """
    r = np.asarray(r, dtype=float)
    a2 = float(r @ r)
    K = hat(r)
    if a2 < 1e-10:
        c = 1.0 / 12.0 + a2 / 720.0
    else:
        a = np.sqrt(a2)
        c = 1.0 / a2 - (1.0 + np.cos(a)) / (2.0 * a * np.sin(a))
    return np.eye(3) - 0.5 * K + c * (K @ K)
