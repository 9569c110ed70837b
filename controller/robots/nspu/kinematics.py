"""Kinetostatic model of the under-actuated 3-nSPU parallel robot.

Source: seed 000 (Grosch, Di Gregorio, Thomas, *Generation of under-actuated manipulators with
non-holonomic joints from ordinary manipulators*), section 3, and seed 004 section 2 (the same
robot, called 3-U^PU there).

Robot: a frame with three non-holonomic spherical pairs (nS) at A_i, three prismatic legs of length
l_i (the only actuators) and a U joint at B_i on the platform (end effector).  The nS pair lets the
limb rotate only about axes normal to r_i (r_i fixed in the frame).  The U joint has the revolute
axis w4i fixed in the platform and w3i fixed in the limb, w3i _|_ w4i.

Conventions and derivations of what the papers leave implicit
------------------------------------------------------------
* Pose: position p of the platform point P and rotation R (platform -> frame), so
  b_i = p + R eb_i and w4i = R ew4i.  Twist (p_dot, omega) with omega the *spatial* angular
  velocity: R_dot = [omega] R.
* w3i (fixed in the limb): seed 000 leaves it implicit.  We adopt the usual U-joint design where the
  limb-side revolute axis is orthogonal to the limb axis: w3i _|_ g_i and w3i _|_ w4i, hence
      w3i = (g_i x w4i) / |g_i x w4i|,
      h_i = w3i x w4i = ((g_i . w4i) w4i - g_i) / |g_i x w4i|        (eq. (1), h_i = w3i x w4i)
  i.e. h_i is minus the unit component of g_i orthogonal to w4i.  Both w3i and g_i are fixed in
  the limb, so this choice is consistent with the limb being rigid for every pose; the limb
  orientation is then a function of the platform pose and the configuration space is 6-D, as the
  paper states.  The sign of w3i is irrelevant: it flips row i of S and J together, which leaves
  eq. (11)'s constraint rows, S^-1 J and the feedback of seed 004 eq. (6) unchanged.
  Test: tests/test_nspu_model.py checks that the limb angular velocity obtained by
  differentiating the limb frame (g_i, w3i) along the twists allowed by eq. (11) is orthogonal to
  r_i (the nS constraint), independently of eq. (9)-(15).
* The printed statics power balance "f.p_dot + m.omega = tau . tau_dot" is garbled: from eq. (11) and
  (25) it is f.p_dot + m.omega = tau . l_dot (+ tau_perp . 0).  Tested numerically.
* The printed sentence after eq. (34) lists [v1,v2] twice; eq. (36) (used here) has [v2,v3].

Numerical example of seed 000 section 3.5 (see `NspuGeometry.paper_example`): the text says the x
axis passes through A3 (B3) *pointing from A3 towards O*, and that A_i (B_i) form an equilateral
triangle centred at O (P).  The printed a3 = (39.7, 0, 0) and e(b3 - p) = (11.76, 0, 0) contradict
both statements (|a1 - a3| = 39.7 but |a1 - a2| = 68.8); with a3 = (-39.7, 0, 0),
e(b3 - p) = (-11.76, 0, 0) the triangles are equilateral, and the printed w4i are then exactly the
3-fold symmetric (u_i + z)/sqrt(2) with u_i the outward radial unit vector of B_i.  The printed r1,
r2 are (u_i + t_i + z)/sqrt(3) with t_i = z x u_i, and r2 = Rz(120 deg) r1 exactly; the 3-fold
symmetric r3 = Rz(120 deg) r2 is (-0.5774, -0.5774, 0.5774), while the printed r3 has +0.5774 as
its y component.  The variant is selectable (`r3_variant`); see the planner module for which one
the seed 004 example converges with.

All functions are vectorised over leading batch dimensions (`...`) and are complex-step safe (no
abs/norm of complex numbers), so derivatives can be checked by complex-step differentiation.

Units: SI (m, s, rad, N).  The papers' "arbitrary unit of length" (aul) is taken as 1 cm; the
factor is an argument of `NspuGeometry.paper_example` (`length_unit_m`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from controller.core.rotations import Array, rot_x, rot_z, so3_exp
from controller.errors import RefusedError


class NspuModelError(RefusedError):
    """Base error of the 3-nSPU model."""


class SingularityError(NspuModelError):
    """The pose is (numerically) at a singularity where the requested quantity is undefined."""


# --------------------------------------------------------------------------------------------
# SO(3) helpers
# --------------------------------------------------------------------------------------------


def euler_xzx(eta: Array) -> Array:
    """XZX Euler angles (seed 000 Fig. 7-8): R = Rx(eta1) Rz(eta2) Rx(eta3); vectorised."""
    eta = np.asarray(eta)
    return rot_x(eta[..., 0]) @ rot_z(eta[..., 1]) @ rot_x(eta[..., 2])


def euler_xzx_rate_matrix(eta: Array) -> Array:
    """H of seed 000 eq. (29), omega = H eta_dot, for XZX angles (spatial angular velocity).

    omega = eta1_dot x + eta2_dot Rx(eta1) z + eta3_dot Rx(eta1) Rz(eta2) x; det H = sin(eta2).
    """
    eta = np.asarray(eta)
    e1, e2 = eta[..., 0], eta[..., 1]
    c1, s1, c2, s2 = np.cos(e1), np.sin(e1), np.cos(e2), np.sin(e2)
    o, z = np.ones_like(c1), np.zeros_like(c1)
    col1 = np.stack([o, z, z], -1)
    col2 = np.stack([z, -s1, c1], -1)
    col3 = np.stack([c2, c1 * s2, s1 * s2], -1)
    return np.stack([col1, col2, col3], -1)


# --------------------------------------------------------------------------------------------
# Geometry and pose
# --------------------------------------------------------------------------------------------


def _unit(v: Array) -> Array:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass(frozen=True, eq=False)
class NspuGeometry:
    """Geometry of a 3-nSPU robot (seed 000 Fig. 5, section 3.5).  Rows are limbs i = 1, 2, 3.

    a_m: centres A_i of the nS spheres in the frame {0} [m], shape (3, 3).
    r: unit normals r_i of the nS planes, fixed in the frame, shape (3, 3).
    b_platform_m: e(b_i - p), U-joint centres in the platform frame [m], shape (3, 3).
    w4_platform: U-joint axes ew4i fixed in the platform (unit), shape (3, 3).
    leg_min_m, leg_max_m: stroke of the prismatic actuators [m].
    length_unit_m: size of the papers' length unit in metres (for converting paper numbers).
    """

    a_m: Array
    r: Array
    b_platform_m: Array
    w4_platform: Array
    leg_min_m: float = 0.0
    leg_max_m: float = float("inf")
    length_unit_m: float = 1.0
    name: str = field(default="nspu")

    def __post_init__(self) -> None:
        for key in ("a_m", "r", "b_platform_m", "w4_platform"):
            arr = np.array(getattr(self, key), dtype=float)
            if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
                raise NspuModelError(f"NspuGeometry.{key} must be a finite 3x3 array, got {arr!r}")
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        for key in ("r", "w4_platform"):
            n = np.linalg.norm(getattr(self, key), axis=1)
            if np.any(np.abs(n - 1.0) > 1e-3):
                raise NspuModelError(f"NspuGeometry.{key} rows must be unit vectors, norms {n}")
            unit = _unit(getattr(self, key))
            unit.setflags(write=False)
            object.__setattr__(self, key, unit)
        if not (0.0 <= self.leg_min_m < self.leg_max_m):
            raise NspuModelError(
                f"NspuGeometry stroke needs 0 <= leg_min_m < leg_max_m, got {self.leg_min_m}, {self.leg_max_m}"
            )

    @staticmethod
    def paper_example(
        length_unit_m: float = 0.01,
        r3_variant: Literal["symmetric", "printed"] = "symmetric",
        a3_sign_fixed: bool = True,
        leg_min_aul: float = 20.0,
        leg_max_aul: float = 70.0,
    ) -> NspuGeometry:
        """Geometry of seed 000 section 3.5, lengths converted with `length_unit_m` [m/aul].

        a3_sign_fixed=True uses a3 = (-39.7, 0, 0) and e(b3-p) = (-11.76, 0, 0) (equilateral
        triangles, x axis from A3 towards O as the text says); False keeps the printed +x values.
        r3_variant "symmetric" uses r3 = (-0.5774, -0.5774, 0.5774) (3-fold symmetry with r1, r2);
        "printed" keeps (-0.5774, 0.5774, 0.5774).  The stroke is not given by the papers; the
        default 20-70 aul is an assumption (the seed 004 example plan spans 37.7-54.4 aul).
        """
        s3 = -1.0 if a3_sign_fixed else 1.0
        a = np.array([[19.85, -34.3812, 0.0], [19.85, 34.3812, 0.0], [s3 * 39.7, 0.0, 0.0]])
        b = np.array([[5.88, -10.1845, 0.0], [5.88, 10.1845, 0.0], [s3 * 11.76, 0.0, 0.0]])
        r3y = -0.5774 if r3_variant == "symmetric" else 0.5774
        r = np.array([[0.7887, -0.2113, 0.5774], [-0.2113, 0.7887, 0.5774], [-0.5774, r3y, 0.5774]])
        w4 = np.array([[0.3536, -0.6124, 0.7071], [0.3536, 0.6124, 0.7071], [-0.7071, 0.0, 0.7071]])
        return NspuGeometry(
            a_m=a * length_unit_m,
            r=r,
            b_platform_m=b * length_unit_m,
            w4_platform=w4,
            leg_min_m=leg_min_aul * length_unit_m,
            leg_max_m=leg_max_aul * length_unit_m,
            length_unit_m=length_unit_m,
            name=f"seed000-example(r3={r3_variant}, a3_fixed={a3_sign_fixed})",
        )


@dataclass(frozen=True, eq=False)
class Pose:
    """Platform pose: position p_m [m] of P in {0} and rotation R (platform -> frame)."""

    p_m: Array
    R: Array

    def __post_init__(self) -> None:
        p = np.array(self.p_m, dtype=float).reshape(3)
        rot = np.array(self.R, dtype=float).reshape(3, 3)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(rot))):
            raise NspuModelError(f"Pose must be finite, got p={p}, R={rot}")
        if np.max(np.abs(rot.T @ rot - np.eye(3))) > 1e-6 or np.linalg.det(rot) < 0:
            raise NspuModelError(f"Pose.R is not a rotation matrix: {rot}")
        p.setflags(write=False)
        rot.setflags(write=False)
        object.__setattr__(self, "p_m", p)
        object.__setattr__(self, "R", rot)


# --------------------------------------------------------------------------------------------
# Instantaneous kinematics (seed 000 section 3.1)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class LimbState:
    """Per-limb vectors of seed 000 eq. (1) and (10), shape (..., 3 limbs, 3)."""

    b: Array  # U-joint centres b_i in {0} [m]
    g: Array  # limb-axis unit vectors g_i
    l: Array  # limb lengths l_i [m], shape (..., 3)
    w3: Array  # limb-side U-joint axes
    w4: Array  # platform-side U-joint axes in {0}
    h: Array  # h_i = w3i x w4i
    s: Array  # s_i of eq. (10)


_NEXT = np.array([1, 2, 0])
_PREV = np.array([2, 0, 1])


def _cross(a: Array, b: Array) -> Array:
    """Broadcasting cross product over the last axis: (a_y b_z - a_z b_y, ...) as a[next] b[prev] - a[prev] b[next].

    np.take with precomputed indices: several times faster than np.cross or stacking the
    components for the small arrays of the model (the planner evaluates it ~10^4 times a plan).
    """
    a = np.asarray(a)
    b = np.asarray(b)
    return a.take(_NEXT, axis=-1) * b.take(_PREV, axis=-1) - a.take(_PREV, axis=-1) * b.take(_NEXT, axis=-1)


def _sqrt_sum_sq(v: Array) -> Array:
    return np.sqrt(np.sum(v * v, axis=-1))


def limb_state(geometry: NspuGeometry, p: Array, R: Array) -> LimbState:
    """Limb vectors for pose(s) (p, R) with p (..., 3), R (..., 3, 3)."""
    p = np.asarray(p)
    R = np.asarray(R)
    b = p[..., None, :] + np.einsum("...jk,ik->...ij", R, geometry.b_platform_m)
    d = b - geometry.a_m  # l_i g_i = b_i - a_i, seed 000 eq. (1)
    l = _sqrt_sum_sq(d)
    g = d / l[..., None]
    w4 = np.einsum("...jk,ik->...ij", R, geometry.w4_platform)
    c = _cross(g, w4)
    nc = _sqrt_sum_sq(c)
    if np.any(np.real(nc) < 1e-9):
        raise SingularityError(
            f"U joint degenerate: limb axis parallel to w4i (|g x w4| = {np.min(np.real(nc))})"
        )
    w3 = c / nc[..., None]  # w3i _|_ g_i, w3i _|_ w4i (design assumption, module docstring)
    h = _cross(w3, w4)  # seed 000 eq. (1)
    hxr = _cross(h, geometry.r)
    s = hxr - np.sum(g * hxr, axis=-1)[..., None] * g  # seed 000 eq. (10)
    return LimbState(b=b, g=g, l=l, w3=w3, w4=w4, h=h, s=s)


@dataclass(frozen=True, eq=False)
class IoBlocks:
    """Blocks of seed 000 eq. (11): rows i of G, K, S, J are the vectors of eq. (12)-(15)."""

    G: Array
    K: Array
    S: Array
    J: Array
    limbs: LimbState

    @property
    def M(self) -> Array:
        """The 6x6 matrix [[G, K], [S, J]] of eq. (11)."""
        top = np.concatenate([self.G, self.K], axis=-1)
        bot = np.concatenate([self.S, self.J], axis=-1)
        return np.concatenate([top, bot], axis=-2)


def io_blocks(geometry: NspuGeometry, p: Array, R: Array) -> IoBlocks:
    """G, K, S, J of seed 000 eq. (12)-(15) at pose(s) (p, R)."""
    ls = limb_state(geometry, p, R)
    bp = ls.b - np.asarray(p)[..., None, :]
    G = ls.g  # seed 000 eq. (13): row i = g_i
    K = _cross(bp, ls.g)  # seed 000 eq. (12): row i = (b_i - p) x g_i
    S = ls.s  # seed 000 eq. (15): row i = s_i
    rg = np.sum(geometry.r * ls.g, axis=-1)
    J = _cross(bp, ls.s) - (ls.l * rg)[..., None] * ls.h  # seed 000 eq. (14)
    return IoBlocks(G=G, K=K, S=S, J=J, limbs=ls)


def io_matrix(geometry: NspuGeometry, pose: Pose) -> Array:
    """The 6x6 input-output matrix M of seed 000 eq. (11): (l_dot, 0) = M (p_dot, omega)."""
    return io_blocks(geometry, pose.p_m, pose.R).M


def leg_lengths(geometry: NspuGeometry, pose: Pose) -> Array:
    """Leg lengths l_i = |b_i - a_i| [m] (holonomic, seed 000 eq. (1))."""
    return np.real(limb_state(geometry, pose.p_m, pose.R).l)


def leg_lengths_batch(geometry: NspuGeometry, p: Array, R: Array) -> Array:
    """Leg lengths for batched poses p (..., 3), R (..., 3, 3)."""
    p = np.asarray(p)
    R = np.asarray(R)
    b = p[..., None, :] + np.einsum("...jk,ik->...ij", R, geometry.b_platform_m)
    return np.linalg.norm(b - geometry.a_m, axis=-1)


def constraint_residual(geometry: NspuGeometry, pose: Pose, p_dot: Array, omega: Array) -> Array:
    """S p_dot + J omega (last three rows of eq. (11)); zero for admissible twists."""
    blk = io_blocks(geometry, pose.p_m, pose.R)
    return blk.S @ p_dot + blk.J @ omega


def leg_rates_from_twist(geometry: NspuGeometry, pose: Pose, p_dot: Array, omega: Array) -> Array:
    """l_dot = G p_dot + K omega (first three rows of eq. (11), i.e. eq. (8))."""
    blk = io_blocks(geometry, pose.p_m, pose.R)
    return blk.G @ p_dot + blk.K @ omega


def twist_from_leg_rates(
    geometry: NspuGeometry, pose: Pose, leg_rates_m_s: Array, rcond_min: float = 1e-9
) -> tuple[Array, Array]:
    """Solve seed 000 eq. (11) for the twist (p_dot [m/s], omega [rad/s]) given l_dot [m/s].

    Raises SingularityError at a type-II singularity (eq. (26)), judged by the reciprocal
    condition number of M with its angular columns scaled by the platform radius.
    """
    M = io_matrix(geometry, pose)
    rhs = np.concatenate([np.asarray(leg_rates_m_s, dtype=float), np.zeros(3)])
    scale = _length_scale(geometry)
    Ms = M.copy()
    Ms[:, 3:] /= scale
    rc = 1.0 / np.linalg.cond(Ms)
    if not rc > rcond_min:
        raise SingularityError(
            f"type-II singularity (seed 000 eq. (26)): 1/cond(M) = {rc:.3e} at p = {pose.p_m}"
        )
    x = np.linalg.solve(M, rhs)
    return x[:3], x[3:]


def _length_scale(geometry: NspuGeometry) -> float:
    return float(np.mean(np.linalg.norm(geometry.b_platform_m, axis=1)))


# --------------------------------------------------------------------------------------------
# Statics (seed 000 section 3.2) and singularities (section 3.3)
# --------------------------------------------------------------------------------------------


def static_wrench(geometry: NspuGeometry, pose: Pose, tau_n: Array, tau_perp_n: Array) -> tuple[Array, Array]:
    """(f_ext [N], m_ext [N m]) = M^T (tau, tau_perp), seed 000 eq. (25)."""
    M = io_matrix(geometry, pose)
    w = M.T @ np.concatenate([np.asarray(tau_n, float), np.asarray(tau_perp_n, float)])
    return w[:3], w[3:]


def joint_forces_from_wrench(
    geometry: NspuGeometry, pose: Pose, f_n: Array, m_nm: Array
) -> tuple[Array, Array]:
    """Inverse of eq. (25): actuator forces tau [N] and shear forces tau_perp [N] for a wrench."""
    M = io_matrix(geometry, pose)
    x = np.linalg.solve(M.T, np.concatenate([np.asarray(f_n, float), np.asarray(m_nm, float)]))
    return x[:3], x[3:]


def type2_singularity_det(geometry: NspuGeometry, p: Array, R: Array) -> Array:
    """det M of seed 000 eq. (26) (zero on the type-II singularity locus); batched."""
    return np.linalg.det(io_blocks(geometry, p, R).M)


def reduced_q_matrix(geometry: NspuGeometry, pose: Pose) -> tuple[float, Array]:
    """(det S, Q) of seed 000 eq. (27)-(28): l_dot = Q omega with Q = K - G S^-1 J.

    Identity used in the tests: det M = -det(S) det(Q) (Schur complement after swapping the two
    block rows, which is 3 row swaps).
    """
    blk = io_blocks(geometry, pose.p_m, pose.R)
    det_s = float(np.linalg.det(blk.S))  # = s1 . s2 x s3
    if abs(det_s) < 1e-12:
        raise SingularityError(f"det S = {det_s:.3e}: eq. (27) undefined, use eq. (26)")
    Q = blk.K - blk.G @ np.linalg.solve(blk.S, blk.J)
    return det_s, Q


# --------------------------------------------------------------------------------------------
# Local controllability (seed 000 section 3.4)
# --------------------------------------------------------------------------------------------


def vector_fields_xzx(geometry: NspuGeometry, x: Array) -> Array:
    """Columns v_1..v_3 of V (seed 000 eq. (31)) at x = (p, eta), eta XZX Euler angles.

    V = blockdiag(1, H^-1) M^-1; returns shape (..., 6, 3).  Complex-step safe.
    """
    x = np.asarray(x)
    p, eta = x[..., :3], x[..., 3:]
    R = euler_xzx(eta)
    M = io_blocks(geometry, p, R).M
    rhs = np.broadcast_to(np.concatenate([np.eye(3), np.zeros((3, 3))], axis=0), (*M.shape[:-2], 6, 3))
    tw = np.linalg.solve(M, rhs)  # first three columns of M^-1
    H = euler_xzx_rate_matrix(eta)
    eta_dot = np.linalg.solve(H, tw[..., 3:, :])  # seed 000 eq. (29): eta_dot = H^-1 omega
    return np.concatenate([tw[..., :3, :], eta_dot], axis=-2)


def vector_field_jacobians(
    geometry: NspuGeometry,
    x: Array,
    method: Literal["central", "complex"] = "central",
    step: float | None = None,
) -> Array:
    """d v_i / d x for i = 1..3, shape (..., 3 fields, 6, 6), by central or complex-step differences."""
    x = np.asarray(x, dtype=float)
    eye = np.eye(6)
    cols = []
    for k in range(6):
        if method == "complex":
            hstep = 1e-20 if step is None else step
            vk = np.imag(vector_fields_xzx(geometry, x + 1j * hstep * eye[k])) / hstep
        elif method == "central":
            hstep = 1e-6 * max(1.0, float(np.max(np.abs(x[..., :3])))) if step is None else step
            vk = (
                vector_fields_xzx(geometry, x + hstep * eye[k])
                - vector_fields_xzx(geometry, x - hstep * eye[k])
            ) / (2 * hstep)
        else:
            raise NspuModelError(f"unknown differentiation method {method!r}")
        cols.append(vk)  # (..., 6, 3): derivative wrt x_k
    D = np.stack(cols, axis=-1)  # (..., 6 rows, 3 fields, 6 x_k)
    return np.moveaxis(D, -2, -3)  # (..., 3 fields, 6, 6)


def lie_bracket(v_i: Array, dv_i: Array, v_j: Array, dv_j: Array) -> Array:
    """[v_i, v_j] = (d v_j/dx) v_i - (d v_i/dx) v_j, seed 000 eq. (34)."""
    return np.einsum("...ab,...b->...a", dv_j, v_i) - np.einsum("...ab,...b->...a", dv_i, v_j)


def controllability_matrix(
    geometry: NspuGeometry, x: Array, method: Literal["central", "complex"] = "complex"
) -> Array:
    """L = (v1, v2, v3, [v1,v2], [v1,v3], [v2,v3]) of seed 000 eq. (36); shape (..., 6, 6)."""
    V = vector_fields_xzx(geometry, np.asarray(x, dtype=float))
    D = vector_field_jacobians(geometry, x, method=method)
    v = [V[..., :, k] for k in range(3)]
    d = [D[..., k, :, :] for k in range(3)]
    brackets = [lie_bracket(v[i], d[i], v[j], d[j]) for (i, j) in ((0, 1), (0, 2), (1, 2))]
    return np.stack(v + brackets, axis=-1)


def controllability_det(geometry: NspuGeometry, x: Array, normalise: bool = True) -> Array:
    """det L, seed 000 eq. (35).  normalise=True divides by the product of the column norms."""
    L = controllability_matrix(geometry, x)
    det = np.linalg.det(L)
    if normalise:
        det = det / np.prod(np.linalg.norm(L, axis=-2), axis=-1)
    return det


# --------------------------------------------------------------------------------------------
# Forward simulation of the pose from leg-length rates (R^3 x SO(3))
# --------------------------------------------------------------------------------------------


def _dexpinv(u: Array, w: Array) -> Array:
    """Right-trivialised dexp^-1_u(w) on so(3) truncated after the Bernoulli term B2 (enough for RKMK4)."""
    uw = _cross(u, w)
    return w - 0.5 * uw + _cross(u, uw) / 12.0


def rkmk4_step(
    field_fn: Callable[[Array, Array], tuple[Array, Array]], p: Array, R: Array, dt: float
) -> tuple[Array, Array]:
    """One Runge-Kutta-Munthe-Kaas (order 4) step of p_dot = f_p, R_dot = [f_w] R.

    field_fn(p, R) -> (p_dot, omega) with batch support.  The rotation is updated as
    R <- exp([u]) R with u from the classical RK4 tableau on the Lie algebra (dexp^-1 corrected),
    so R stays exactly on SO(3).
    """
    pd1, w1 = field_fn(p, R)
    k1p, k1w = pd1, w1
    u = 0.5 * dt * k1w
    pd2, w2 = field_fn(p + 0.5 * dt * k1p, so3_exp(u) @ R)
    k2p, k2w = pd2, _dexpinv(u, w2)
    u = 0.5 * dt * k2w
    pd3, w3 = field_fn(p + 0.5 * dt * k2p, so3_exp(u) @ R)
    k3p, k3w = pd3, _dexpinv(u, w3)
    u = dt * k3w
    pd4, w4 = field_fn(p + dt * k3p, so3_exp(u) @ R)
    k4p, k4w = pd4, _dexpinv(u, w4)
    p_new = p + dt / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p)
    u = dt / 6.0 * (k1w + 2 * k2w + 2 * k3w + k4w)
    return p_new, so3_exp(u) @ R


def advance_pose(
    geometry: NspuGeometry, pose: Pose, leg_rates_m_s: Array, dt_s: float, substeps: int = 1
) -> Pose:
    """Integrate the pose over dt_s with constant leg-length rates (seed 000 eq. (11) solved for the twist).

    Uses `substeps` RKMK4 steps.  Raises SingularityError at a type-II singularity.
    """
    if not (dt_s > 0 and np.isfinite(dt_s)):
        raise NspuModelError(f"dt_s must be positive and finite, got {dt_s}")
    ldot = np.asarray(leg_rates_m_s, dtype=float).reshape(3)
    if not np.all(np.isfinite(ldot)):
        raise NspuModelError(f"leg rates must be finite, got {ldot}")

    def field_fn(p: Array, R: Array) -> tuple[Array, Array]:
        return twist_from_leg_rates(geometry, Pose(p, _reortho(R)), ldot)

    p, R = pose.p_m, pose.R
    h = dt_s / substeps
    for _ in range(substeps):
        p, R = rkmk4_step(field_fn, p, R, h)
    return Pose(p, _reortho(R))


def advance_pose_to_leg_lengths(
    geometry: NspuGeometry, pose: Pose, legs_next_m: Array, dt_s: float, substeps: int = 1
) -> Pose:
    """Advance the pose so that the legs go from their current model lengths to `legs_next_m` in dt_s.

    Intended for a simulator fed with the drives' actual positions every cycle: the rates are
    (legs_next - l(pose)) / dt, so integration drift of the holonomic part (the leg lengths) is
    corrected every cycle.  The non-holonomic part (the path) still depends on how the legs moved.
    """
    rates = (np.asarray(legs_next_m, dtype=float).reshape(3) - leg_lengths(geometry, pose)) / dt_s
    return advance_pose(geometry, pose, rates, dt_s, substeps=substeps)


def integrate_leg_trajectory(
    geometry: NspuGeometry, pose0: Pose, t_s: Array, legs_m: Array, substeps: int = 4
) -> list[Pose]:
    """Poses along sampled leg lengths legs_m (N, 3) at times t_s (N,), starting from pose0.

    Leg lengths are interpolated linearly between samples; legs_m[0] should equal l(pose0)
    (a mismatch is corrected during the first interval).
    """
    t = np.asarray(t_s, dtype=float)
    legs = np.asarray(legs_m, dtype=float)
    if t.ndim != 1 or legs.shape != (t.size, 3) or np.any(np.diff(t) <= 0):
        raise NspuModelError(f"need increasing t_s (N,) and legs_m (N, 3), got {t.shape}, {legs.shape}")
    poses = [pose0]
    for k in range(1, t.size):
        poses.append(advance_pose_to_leg_lengths(geometry, poses[-1], legs[k], t[k] - t[k - 1], substeps))
    return poses


def _reortho(R: Array) -> Array:
    u, _, vt = np.linalg.svd(np.real(R))
    return u @ vt
