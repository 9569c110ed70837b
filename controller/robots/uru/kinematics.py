"""LaMaViP 3-URU translational parallel robot with actuators on the base (seed 003).

Notation of seed 003 §2 (frames, points and unit vectors):

- ``O x_b y_b z_b`` base frame, ``P x_p y_p z_p`` platform frame with parallel axes; the
  platform only translates, its pose is ``p = P - O = (x, y, z)`` [m].
- ``e_1, e_2, e_3`` unit vectors of the coordinate axes and, at the same time, of the three
  R-pair axes fixed in the base (through ``A_i``) and in the platform (through ``B_i``):
  mutually orthogonal, meeting at O (base) and at P (platform).
- ``a_i = A_i - O = d_b e_i``, ``b_i = B_i - O = p + d_p e_i``, ``c_i = a_i + f_i u_i``.
- ``f_i = |A_i C_i|`` (proximal link), ``r_i = |B_i C_i|`` (distal link).
- ``g_i`` unit vector of the three intermediate R-pairs of limb i, ``h_i = g_i x e_i``,
  ``u_i = cos(th_i2) e_i + sin(th_i2) h_i``, ``v_i = (B_i - C_i)/r_i``
  ``= cos(th_i3) u_i + sin(th_i3) (g_i x u_i)`` (seed 003 §2; note ``g_i x u_i =
  cos(th_i2) h_i - sin(th_i2) e_i``, which is the vector printed in the paper).
- ``th_i1`` rotation of the U-joint cross about ``e_i`` (phase reference of §2:
  ``g_1 = cos th_11 e_2 + sin th_11 e_3``, ``g_2 = -cos th_21 e_1 + sin th_21 e_3``,
  ``g_3 = cos th_31 e_1 + sin th_31 e_2``); ``th_i2`` actuated joint; ``th_iM`` motor shaft,
  coupled to ``th_i2`` through a bevel gearbox with speed ratio ``k_i`` (eq. (9)-(11)).

Conventions chosen here (the paper leaves them implicit):

- Sign of ``g_i``: ``g_i = e_i x p / |e_i x p|`` (seed 003, eq. (15a), '+' sign). Then
  ``h_i = p_perp,i / |p_perp,i|`` (eq. (15b)-(16)) and ``beta_i = h_i . (b_i - a_i) =
  |e_i x p| > 0``. ``g_i`` is undefined on the coordinate axis of ``e_i`` (a double
  rotation singularity) and continuous everywhere else, so ``th_i1`` and therefore the
  motor angles are continuous inside each octant.
- Assembly branch of each limb ("knee" side): ``knee_sign = +1`` takes
  ``sin(th_i3) > 0``, which is the upper sign ('-') of eq. (A2); ``-1`` the other one.
  ``+1`` is the default because with it the whole first octant of the default geometry is
  free of translation and actuation singularities (see ``tests/test_uru_model.py`` and
  the plots of ``controller/robots/uru/analysis.py``).
- Angles are not wrapped: ``th_i2`` lies in (-pi, pi) for ``knee_sign = +1`` and in
  (0, 2 pi) for ``-1``; ``th_i1`` comes from ``atan2`` and is continuous in every octant.

Garbled or ambiguous printed equations, derived again and tested numerically:

- eq. (34): the printed numerator has ``g_i . (v_(i+1) x v_(i+2))``; expanding
  ``S = I + K N M V^-1 G`` (eq. (32)-(33)) gives ``(K N M V^-1 G)_ij = k_i / beta_i *
  g_i . (column j of V^-1) * G_jj`` and column j of ``V^-1`` is
  ``v_(j+1) x v_(j+2) / det V``: the index must be ``j``, not ``i``. Implemented with
  ``j`` and tested against the matrix product.
- eq. (13)/(19): rewritten as ``A p_dot = D th_M_dot`` with rows
  ``a_i = v_i + k_i G_ii / beta_i g_i`` and ``D = diag(k_i G_ii)``; the code checks
  ``det A = det S det V`` (so the combined condition eq. (36) is the union of the
  translation eq. (20) and actuation eq. (35) loci whenever no serial singularity occurs).
  The text after eq. (17) says "system (14)" where system (13) is meant.
- eq. (17): the mixed product of the unit vectors (16) is ``2xyz / sqrt(...)``; checked.

Everything here is pure numpy; nothing reads a clock or does I/O.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from controller.errors import NoSolutionError, RefusedError

_E = np.eye(3)
_E.setflags(write=False)


class UruNoSolutionError(NoSolutionError):
    """A 3-URU position problem has no solution (on the configured branch); the message says why."""


class UruPathRefusedError(RefusedError):
    """A Cartesian path comes too close to (or crosses) a singularity locus or the workspace boundary."""

    def __init__(self, locus: str, sample_index: int, value: float, limit: float, position_m: np.ndarray):
        self.locus = locus
        self.sample_index = sample_index
        self.value = value
        self.limit = limit
        self.position_m = np.array(position_m, dtype=float)
        super().__init__(
            f"path refused: {locus} at sample {sample_index} "
            f"(p = {np.round(self.position_m, 6).tolist()} m): value {value:.6g}, limit {limit:.6g}"
        )


def _triple(x: tuple[float, float, float] | list[float], name: str) -> tuple[float, float, float]:
    if len(x) != 3:
        raise ValueError(f"{name} needs 3 values, got {x!r}")
    return (float(x[0]), float(x[1]), float(x[2]))


@dataclass(frozen=True)
class UruGeometry:
    """Geometry and transmission of a LaMaViP 3-URU (seed 003 §2, Fig. 1-2).

    Default: a desktop-size robot, ``f_i = r_i = 0.20 m``, ``d_b = d_p = 0.10 m``, gear
    speed ratio ``k_i = 1`` (1:1 bevel pair, eq. (9)), zero motor offsets, knee branch +1.
    This is the case the paper singles out after eq. (29): the reachable workspace is the
    ball of radius 2 R = 0.40 m centred at O. Measured on a 40^3 grid of the first octant
    kept 0.02 m from the coordinate planes and from the workspace boundary:
    det V in [0.20, 1.00], det S in [2.26, 9.13], det A in [0.46, 6.25], i.e. the first octant
    is free of translation, actuation and combined singularities (the mixed-sign octants are
    not: det S changes sign in about 8 % of each). The useful workspace is the first octant.

    - ``base_offset_m``: ``d_b = |A_i O|``;
    - ``platform_offset_m``: ``d_p = |B_i P|``;
    - ``proximal_lengths_m``: ``f_i = |A_i C_i|``;
    - ``distal_lengths_m``: ``r_i = |B_i C_i|``;
    - ``gear_ratios``: ``k_i = th_i2_dot / (th_iM_dot - th_i1_dot)`` (eq. (9)), dimensionless,
      non-zero (``|k_i| < 1`` for a reduction);
    - ``motor_offsets_rad``: ``c_i = th_iM|0 - th_i1|0`` of eq. (11), the motor-shaft angle
      minus the cross angle at the calibration pose where ``th_i2 = 0``;
    - ``knee_sign``: assembly branch, ``+1`` -> ``sin(th_i3) > 0`` ('-' sign in eq. (A2)),
      ``-1`` -> ``sin(th_i3) < 0``; the same for the three limbs;
    - ``home_position_m``: start point of the numerical direct kinematics when no guess is
      given; must be reachable.
    """

    base_offset_m: float = 0.10
    platform_offset_m: float = 0.10
    proximal_lengths_m: tuple[float, float, float] = (0.20, 0.20, 0.20)
    distal_lengths_m: tuple[float, float, float] = (0.20, 0.20, 0.20)
    gear_ratios: tuple[float, float, float] = (1.0, 1.0, 1.0)
    motor_offsets_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    knee_sign: int = 1
    home_position_m: tuple[float, float, float] = (0.12, 0.12, 0.12)
    f: np.ndarray = field(init=False, repr=False, compare=False)
    r: np.ndarray = field(init=False, repr=False, compare=False)
    k: np.ndarray = field(init=False, repr=False, compare=False)
    c: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        f = np.array(_triple(self.proximal_lengths_m, "proximal_lengths_m"))
        r = np.array(_triple(self.distal_lengths_m, "distal_lengths_m"))
        k = np.array(_triple(self.gear_ratios, "gear_ratios"))
        c = np.array(_triple(self.motor_offsets_rad, "motor_offsets_rad"))
        _triple(self.home_position_m, "home_position_m")
        if not (np.all(np.isfinite(f)) and np.all(f > 0)):
            raise ValueError(f"proximal_lengths_m must be finite and > 0, got {self.proximal_lengths_m}")
        if not (np.all(np.isfinite(r)) and np.all(r > 0)):
            raise ValueError(f"distal_lengths_m must be finite and > 0, got {self.distal_lengths_m}")
        if not (np.all(np.isfinite(k)) and np.all(k != 0)):
            raise ValueError(f"gear_ratios must be finite and non-zero, got {self.gear_ratios}")
        if not np.all(np.isfinite(c)):
            raise ValueError(f"motor_offsets_rad must be finite, got {self.motor_offsets_rad}")
        for name in ("base_offset_m", "platform_offset_m"):
            val = getattr(self, name)
            if not (math.isfinite(val) and val >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {val}")
        if self.knee_sign not in (1, -1):
            raise ValueError(f"knee_sign must be +1 or -1, got {self.knee_sign}")
        for name, arr in (("f", f), ("r", r), ("k", k), ("c", c)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def offset_m(self) -> float:
        """``d_p - d_b`` [m], the term that recurs in eq. (21)-(29) and (A1)."""
        return self.platform_offset_m - self.base_offset_m


# ---------------------------------------------------------------------------------------------
# Batched internals: p has shape (N, 3); per-limb arrays have shape (N, 3) [point, limb] or
# (N, 3, 3) [point, limb, xyz].


@dataclass(frozen=True)
class UruConfiguration:
    """Joint variables and limb vectors at one platform position (seed 003 §2).

    Angles [rad] have shape (3,) (limb index); vectors have shape (3, 3) with one row per limb.
    ``beta_m`` is ``h_i . (b_i - a_i) = |e_i x p|`` (eq. (12), (31)), ``sin_th3`` the serial
    measure of eq. (27) divided by ``f_i r_i``.
    """

    position_m: np.ndarray
    th1_rad: np.ndarray
    th2_rad: np.ndarray
    th3_rad: np.ndarray
    g: np.ndarray
    h: np.ndarray
    u: np.ndarray
    v: np.ndarray
    alpha_m: np.ndarray
    beta_m: np.ndarray


def _as_points(p_m: np.ndarray) -> np.ndarray:
    p = np.asarray(p_m, dtype=float)
    if p.shape[-1] != 3:
        raise ValueError(f"positions need 3 coordinates (x, y, z) in the last axis, got shape {p.shape}")
    return p.reshape(-1, 3)


def _frames(
    p: np.ndarray, geom: UruGeometry
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """g, h, w = b - a, alpha, beta for each point and limb (seed 003, eq. (15)-(16), (A1))."""
    perp = p[:, None, :] * (1.0 - _E)[None, :, :]  # p - (e_i . p) e_i
    beta = np.linalg.norm(perp, axis=2)  # |e_i x p|, seed 003 eq. (A1)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = perp / beta[:, :, None]  # seed 003, eq. (15b)-(16)
        g = np.cross(_E[None, :, :], p[:, None, :]) / beta[:, :, None]  # seed 003, eq. (15a)
    w = p[:, None, :] + geom.offset_m * _E[None, :, :]  # b_i - a_i = p + (d_p - d_b) e_i
    alpha = np.einsum("ij,nij->ni", _E, w)  # x + d_p - d_b, ... (eq. (A1))
    return g, h, w, alpha, beta


def _th1(g: np.ndarray) -> np.ndarray:
    """Cross angles th_i1 from g_i with the phase references of seed 003 §2."""
    th11 = np.arctan2(g[:, 0, 2], g[:, 0, 1])  # g_1 = cos e_2 + sin e_3
    th21 = np.arctan2(g[:, 1, 2], -g[:, 1, 0])  # g_2 = -cos e_1 + sin e_3
    th31 = np.arctan2(g[:, 2, 1], g[:, 2, 0])  # g_3 = cos e_1 + sin e_2
    return np.stack([th11, th21, th31], axis=1)


def _kappa_rho(alpha: np.ndarray, beta: np.ndarray, geom: UruGeometry) -> tuple[np.ndarray, np.ndarray]:
    rho = np.hypot(alpha, beta)
    kappa = (rho**2 + geom.f**2 - geom.r**2) / (2.0 * geom.f)
    return kappa, rho


def _th2(alpha: np.ndarray, beta: np.ndarray, geom: UruGeometry) -> np.ndarray:
    """Actuated angles th_i2 from eq. (A1) on the configured branch (NaN where unreachable).

    seed 003, eq. (A1): alpha cos th + beta sin th = kappa, kappa = (alpha^2 + beta^2 + f^2 - r^2)/(2 f).
    With rho = |(alpha, beta)|, phi = atan2(beta, alpha): cos(th - phi) = kappa / rho, so
    th = phi - knee_sign * acos(kappa / rho). This is eq. (A2) written with atan2 (no
    division by its denominator, which vanishes when C_i is on the e_i axis); the '-' root of
    eq. (A2) is knee_sign = +1, i.e. sin(th_i3) = rho sin(phi - th) / r > 0.
    """
    kappa, rho = _kappa_rho(alpha, beta, geom)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = kappa / rho
    ratio = np.where(np.abs(ratio) <= 1.0 + 1e-12, np.clip(ratio, -1.0, 1.0), np.nan)
    phi = np.arctan2(beta, alpha)
    return phi - geom.knee_sign * np.arccos(ratio)


def _configurations(p: np.ndarray, geom: UruGeometry, th2: np.ndarray | None = None) -> dict[str, np.ndarray]:
    g, h, w, alpha, beta = _frames(p, geom)
    if th2 is None:
        th2 = _th2(alpha, beta, geom)
    u = np.cos(th2)[:, :, None] * _E[None] + np.sin(th2)[:, :, None] * h  # seed 003 §2
    d = w - geom.f[None, :, None] * u  # b_i - c_i = r_i v_i (eq. (21))
    v = d / geom.r[None, :, None]
    gxu = np.cross(g, u)
    sin3 = np.einsum("nij,nij->ni", v, gxu)
    cos3 = np.einsum("nij,nij->ni", v, u)
    return {
        "g": g,
        "h": h,
        "w": w,
        "alpha": alpha,
        "beta": beta,
        "th1": _th1(g),
        "th2": th2,
        "u": u,
        "v": v,
        "d": d,
        "gxu": gxu,
        "sin3": sin3,
        "cos3": cos3,
    }


# ---------------------------------------------------------------------------------------------
# Workspace (seed 003, eq. (28)-(29))


def workspace_margin_m(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """Signed distance [m] of B_i's distance from A_i to the shell of eq. (29), worst limb.

    seed 003, eq. (29): (f_i - r_i)^2 <= |p + (d_p - d_b) e_i|^2 <= (f_i + r_i)^2. The margin is
    min_i min(f_i + r_i - |b_i - a_i|, |b_i - a_i| - |f_i - r_i|): > 0 inside the reachable
    workspace, 0 on its boundary (the serial-singularity spheres of eq. (28)). Shape: p's
    leading shape.
    """
    p = np.asarray(p_m, dtype=float)
    pts = _as_points(p)
    w = pts[:, None, :] + geom.offset_m * _E[None]
    dist = np.linalg.norm(w, axis=2)
    margin = np.minimum(geom.f + geom.r - dist, dist - np.abs(geom.f - geom.r)).min(axis=1)
    return margin.reshape(p.shape[:-1])


def in_reachable_workspace(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """Boolean mask of the points that satisfy the inequalities of seed 003, eq. (29)."""
    return workspace_margin_m(geom, p_m) >= 0.0


# ---------------------------------------------------------------------------------------------
# Position analysis


def configuration(geom: UruGeometry, p_m: np.ndarray) -> UruConfiguration:
    """Inverse position analysis at one point (seed 003, App. A, eq. (A1)-(A2)), all joint data.

    Raises UruNoSolutionError when the point is outside the reachable workspace (eq. (29)) or
    on a coordinate axis, where g_i is undefined (eq. (15a)).
    """
    p = _as_points(p_m)
    if p.shape[0] != 1:
        raise ValueError(f"configuration() takes one point, got shape {np.shape(p_m)}")
    if not np.all(np.isfinite(p)):
        raise UruNoSolutionError(f"platform position {p[0].tolist()} m is not finite")
    cfg = _configurations(p, geom)
    beta = cfg["beta"][0]
    if np.any(beta < 1e-12):
        i = int(np.argmin(beta))
        raise UruNoSolutionError(
            f"platform position {p[0].tolist()} m lies on the axis of e_{i + 1}: g_{i + 1} is undefined "
            f"(|e_{i + 1} x p| = {beta[i]:.3e} m, seed 003 eq. (15a))"
        )
    th2 = cfg["th2"][0]
    if np.any(np.isnan(th2)):
        i = int(np.argmax(np.isnan(th2)))
        dist = float(np.hypot(cfg["alpha"][0, i], beta[i]))
        raise UruNoSolutionError(
            f"platform position {p[0].tolist()} m is out of reach of limb {i + 1}: |B_{i + 1} - A_{i + 1}| = "
            f"{dist:.6g} m outside [{abs(geom.f[i] - geom.r[i]):.6g}, {geom.f[i] + geom.r[i]:.6g}] m "
            "(seed 003 eq. (29))"
        )
    return UruConfiguration(
        position_m=p[0].copy(),
        th1_rad=cfg["th1"][0],
        th2_rad=th2,
        th3_rad=np.arctan2(cfg["sin3"][0], cfg["cos3"][0]),
        g=cfg["g"][0],
        h=cfg["h"][0],
        u=cfg["u"][0],
        v=cfg["v"][0],
        alpha_m=cfg["alpha"][0],
        beta_m=beta,
    )


def actuated_joint_angles(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """th_i2 [rad] for a platform position p [m] (seed 003, eq. (A1)-(A2), configured branch)."""
    return configuration(geom, p_m).th2_rad


def motor_from_joint_angles(geom: UruGeometry, th1_rad: np.ndarray, th2_rad: np.ndarray) -> np.ndarray:
    """Motor-shaft angles th_iM [rad] from the cross and actuated-joint angles.

    seed 003, eq. (11): th_i2 = k_i [(th_iM - th_i1) - (th_iM|0 - th_i1|0)], solved for th_iM:
    th_iM = th_i1 + th_i2 / k_i + c_i with c_i = th_iM|0 - th_i1|0 (``motor_offsets_rad``).
    """
    return np.asarray(th1_rad, float) + np.asarray(th2_rad, float) / geom.k + geom.c


def joint_from_motor_angles(geom: UruGeometry, th1_rad: np.ndarray, thm_rad: np.ndarray) -> np.ndarray:
    """Actuated-joint angles th_i2 [rad] from motor-shaft and cross angles (seed 003, eq. (11))."""
    return geom.k * (np.asarray(thm_rad, float) - np.asarray(th1_rad, float) - geom.c)


def inverse_kinematics(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """Motor-shaft angles th_M [rad] that put the platform at p [m] (eq. (A1)-(A2) then eq. (11))."""
    cfg = configuration(geom, p_m)
    return motor_from_joint_angles(geom, cfg.th1_rad, cfg.th2_rad)


def _newton(
    geom: UruGeometry,
    residual_and_jacobian: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    p0: np.ndarray,
    what: str,
    tol_m: float,
    max_iter: int,
) -> np.ndarray:
    """Damped Newton iteration on 3 closure residuals [m^2] with backtracking on |R|.

    Converged when max |R_i| < 1e-14 m^2 (about 1e-13 m of position for 0.2 m links away from
    singularities) or when the step is below ``tol_m`` with max |R_i| < 1e-12 m^2.
    """
    p = p0.astype(float).copy()
    res, jac = residual_and_jacobian(p)
    for _ in range(max_iter):
        if float(np.max(np.abs(res))) < 1e-14:
            return p
        try:
            step = np.linalg.solve(jac, -res)
        except np.linalg.LinAlgError as err:
            raise UruNoSolutionError(
                f"direct kinematics for {what}: singular Newton matrix at p = {p.tolist()} m "
                "(translation or actuation singularity, seed 003 eq. (20)/(36))"
            ) from err
        norm0 = float(np.linalg.norm(res))
        lam = 1.0
        while lam >= 1e-6:
            trial = p + lam * step
            r_t, j_t = residual_and_jacobian(trial)
            if np.all(np.isfinite(r_t)) and float(np.linalg.norm(r_t)) < norm0 * (1.0 - 1e-4 * lam):
                break
            lam *= 0.5
        if lam < 1e-6:
            if float(np.max(np.abs(res))) < 1e-12:
                return p
            break
        p, res, jac = trial, r_t, j_t
        if float(np.linalg.norm(lam * step)) < tol_m and float(np.max(np.abs(res))) < 1e-12:
            return p
    raise UruNoSolutionError(
        f"direct kinematics for {what}: no convergence from p0 = {p0.tolist()} m "
        f"(last p = {p.tolist()} m, closure residual {float(np.linalg.norm(res)):.3e} m^2, seed 003 eq. (A1)); "
        "the input is probably outside the reachable workspace"
    )


def _closure_residual(
    geom: UruGeometry, p: np.ndarray, th2: np.ndarray
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """R_i = |b_i - c_i|^2 - r_i^2 for given th_i2 (seed 003, eq. (A1) is R_i = 0)."""
    cfg = _configurations(p[None, :], geom, th2[None, :])
    d = cfg["d"][0]
    return np.einsum("ij,ij->i", d, d) - geom.r**2, cfg


def _branch_check(
    geom: UruGeometry,
    p: np.ndarray,
    target: np.ndarray,
    to_target: Callable[[np.ndarray], np.ndarray],
    what: str,
) -> np.ndarray:
    try:
        got = to_target(p)
    except UruNoSolutionError as err:
        raise UruNoSolutionError(
            f"direct kinematics for {what}: solution p = {p.tolist()} m fails IK ({err})"
        ) from err
    if not np.allclose(got, target, atol=1e-7, rtol=0.0):
        raise UruNoSolutionError(
            f"direct kinematics for {what}: converged to p = {p.tolist()} m on the other knee branch "
            f"(IK on knee_sign={geom.knee_sign} gives {got.tolist()} rad); start closer to the expected pose"
        )
    return p


_CONTINUATION_STEPS = 16


def _swap_call(
    rj: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]], tgt: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    return rj(p, tgt)


def _solve(
    geom: UruGeometry,
    rj: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    ik: Callable[[np.ndarray], np.ndarray],
    target: np.ndarray,
    p0: np.ndarray,
    what: str,
    tol_m: float,
    max_iter: int,
) -> np.ndarray:
    """Newton from p0; if that fails, continuation from the guess's own joint values to the target.

    The continuation interpolates the inputs linearly from ik(p0) to ``target`` in
    ``_CONTINUATION_STEPS`` steps, solving each step from the previous solution: it follows the
    solution branch connected to p0, which reaches the target when no singularity lies between.
    """
    try:
        return _branch_check(
            geom, _newton(geom, lambda q: rj(q, target), p0, what, tol_m, max_iter), target, ik, what
        )
    except UruNoSolutionError as first:
        try:
            start = ik(p0)
        except UruNoSolutionError:
            raise first from None
        p = p0
        try:
            for j in range(1, _CONTINUATION_STEPS + 1):
                tgt = start + (target - start) * (j / _CONTINUATION_STEPS)
                p = _newton(geom, functools.partial(_swap_call, rj, tgt), p, what, tol_m, max_iter)
        except UruNoSolutionError as second:
            raise UruNoSolutionError(
                f"{first}; continuation from the guess also failed: {second}"
            ) from second
        return _branch_check(geom, p, target, ik, what)


def direct_kinematics_joint(
    geom: UruGeometry,
    th2_rad: np.ndarray,
    p_guess_m: np.ndarray | None = None,
    tol_m: float = 1e-12,
    max_iter: int = 50,
) -> np.ndarray:
    """Platform position p [m] from the actuated-joint angles th_i2 [rad] (direct position analysis).

    Solves the closure equations seed 003, eq. (A1) (R_i = |b_i - c_i|^2 - r_i^2 = 0) by damped
    Newton from ``p_guess_m`` (default ``geom.home_position_m``). Jacobian, derived here: with
    d_i = b_i - c_i, dR_i/dp = 2 d_i^T, because the rotation of h_i with p (dh_i = g_i dth_i1)
    is orthogonal to d_i (d_i and u_i lie in the plane normal to g_i). At a solution this is
    2 r_i v_i^T, i.e. the matrix V of eq. (6a): Newton fails exactly on the translation
    singularities (eq. (20)). The solution must reproduce th_i2 through the IK on the
    configured branch, else UruNoSolutionError. The direct problem has several solutions; the
    one nearest (in the Newton sense) to the guess is returned. If plain Newton fails, a
    continuation from the guess's own joint angles to the target is tried (see ``_solve``).
    """
    target = np.asarray(th2_rad, dtype=float).reshape(3)
    what = f"th2 = {target.tolist()} rad"

    def rj(p: np.ndarray, tgt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        res, cfg = _closure_residual(geom, p, tgt)
        return res, 2.0 * cfg["d"][0]

    p0 = np.asarray(geom.home_position_m if p_guess_m is None else p_guess_m, dtype=float).reshape(3)
    return _solve(geom, rj, lambda q: actuated_joint_angles(geom, q), target, p0, what, tol_m, max_iter)


def direct_kinematics(
    geom: UruGeometry,
    thm_rad: np.ndarray,
    p_guess_m: np.ndarray | None = None,
    tol_m: float = 1e-12,
    max_iter: int = 50,
) -> np.ndarray:
    """Platform position p [m] from the motor-shaft angles th_M [rad].

    Closure equations eq. (A1) with th_i2 = k_i (th_iM - c_i - th_i1(p)) (eq. (11)), damped
    Newton. Jacobian (derived): dR_i/dp = 2 d_i^T - 2 f_i (d_i . (g_i x u_i)) dth_i2/dp and
    dth_i2/dp = -k_i dth_i1/dp = -k_i g_i^T / beta_i (eq. (12) with omega = 0), so
    dR_i/dp = 2 d_i^T + 2 k_i f_i (d_i . (g_i x u_i)) / beta_i g_i^T; at a solution this is
    2 r_i times row i of the matrix of eq. (19) (combined singularity eq. (36)). Same start,
    branch check and continuation fallback as :func:`direct_kinematics_joint`.
    """
    target = np.asarray(thm_rad, dtype=float).reshape(3)
    what = f"th_M = {target.tolist()} rad"

    def rj(p: np.ndarray, tgt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g, _h, _w, _a, _b = _frames(p[None, :], geom)
        th2 = joint_from_motor_angles(geom, _th1(g)[0], tgt)
        res, cfg = _closure_residual(geom, p, th2)
        d, gxu, beta = cfg["d"][0], cfg["gxu"][0], cfg["beta"][0]
        coef = 2.0 * geom.k * geom.f * np.einsum("ij,ij->i", d, gxu) / beta
        return res, 2.0 * d + coef[:, None] * cfg["g"][0]

    p0 = np.asarray(geom.home_position_m if p_guess_m is None else p_guess_m, dtype=float).reshape(3)
    return _solve(geom, rj, lambda q: inverse_kinematics(geom, q), target, p0, what, tol_m, max_iter)


# ---------------------------------------------------------------------------------------------
# Instantaneous kinematics (seed 003, eq. (2)-(13), (18)-(19), (30)-(36))


@dataclass(frozen=True)
class UruVelocityMatrices:
    """Matrices of seed 003, eq. (5)-(6), (19), (31)-(33) at one platform position.

    - ``V, T, H, G``: eq. (6): [V T; 0 H] (p_dot, omega) = [G; 0] th2_dot (eq. (5));
    - ``M`` rows g_i^T, ``N = diag(1 / (h_i . (b_i - a_i)))`` [1/m] (eq. (31));
    - ``K = diag(k_i)``; ``S = I + K N M V^-1 G`` (eq. (32)); S th2_dot = K thM_dot;
    - ``A`` rows v_i + k_i G_ii / beta_i g_i and ``D = diag(k_i G_ii)`` [m]: A p_dot = D thM_dot
      (eq. (19)); ``T_motor`` the omega coefficients of eq. (13) (rows
      v_i x (p - b_i) + k_i G_ii / beta_i g_i x (p - b_i)) [m].
    """

    V: np.ndarray
    T: np.ndarray
    H: np.ndarray
    G: np.ndarray
    M: np.ndarray
    N: np.ndarray
    K: np.ndarray
    S: np.ndarray
    A: np.ndarray
    D: np.ndarray
    T_motor: np.ndarray


def velocity_matrices(geom: UruGeometry, p_m: np.ndarray) -> UruVelocityMatrices:
    """All matrices of the instantaneous kinematics at p [m] (IK on the configured branch).

    S is computed only where V is invertible; elsewhere it is filled with NaN (eq. (32) is
    indeterminate on the translation-singularity locus, seed 003 §3.2).
    """
    cfg = configuration(geom, p_m)
    p = cfg.position_m
    b = p[None, :] + geom.platform_offset_m * _E  # seed 003 §2: b_i = p + d_p e_i
    a = geom.base_offset_m * _E  # a_i = d_b e_i
    V = cfg.v  # seed 003, eq. (6a)
    T = np.cross(cfg.v, p[None, :] - b)  # eq. (6a): rows [v_i x (p - b_i)]^T
    H = cfg.h  # eq. (6a)
    Gd = np.einsum("ij,ij->i", np.cross(cfg.g, b - a), cfg.v)  # eq. (6b) = f_i r_i sin th_i3 / r_i
    G = np.diag(Gd)
    M = cfg.g  # eq. (31)
    beta = np.einsum("ij,ij->i", cfg.h, b - a)  # h_i . (b_i - a_i) = |e_i x p|
    N = np.diag(1.0 / beta)  # eq. (31)
    K = np.diag(geom.k)  # eq. (33)
    detv = float(np.linalg.det(V))
    # eq. (32); undefined (NaN) where V is singular
    S = np.eye(3) + K @ N @ M @ np.linalg.solve(V, G) if abs(detv) > 1e-14 else np.full((3, 3), np.nan)
    coef = geom.k * Gd / beta
    A = V + coef[:, None] * M  # eq. (19): coefficient rows of p_dot
    D = np.diag(geom.k * Gd)  # eq. (19): right-hand side k_i [g_i x (b_i - a_i)] . v_i
    T_motor = T + coef[:, None] * np.cross(cfg.g, p[None, :] - b)  # eq. (13): omega coefficients
    return UruVelocityMatrices(V=V, T=T, H=H, G=G, M=M, N=N, K=K, S=S, A=A, D=D, T_motor=T_motor)


def actuation_matrix_explicit(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """S from the entry-wise expression of seed 003, eq. (34), index corrected (see module doc).

    s_ij = delta_ij + k_i [g_i . (v_(j+1) x v_(j+2))] [g_j x (b_j - a_j)] . v_j
                      / ( v_1 . (v_2 x v_3) [h_i . (b_i - a_i)] ),  indices cyclic in 1..3.
    """
    cfg = configuration(geom, p_m)
    p = cfg.position_m
    b = p[None, :] + geom.platform_offset_m * _E
    a = geom.base_offset_m * _E
    v = cfg.v
    detv = float(v[0] @ np.cross(v[1], v[2]))
    gd = np.einsum("ij,ij->i", np.cross(cfg.g, b - a), v)
    beta = np.einsum("ij,ij->i", cfg.h, b - a)
    s = np.eye(3)
    for i in range(3):
        for j in range(3):
            col = np.cross(v[(j + 1) % 3], v[(j + 2) % 3])
            s[i, j] += geom.k[i] * float(cfg.g[i] @ col) * gd[j] / (detv * beta[i])
    return s


def joint_rate_jacobian(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """J2 with p_dot = J2 th2_dot [m/rad] (seed 003, eq. (18): V p_dot = G th2_dot)."""
    mats = velocity_matrices(geom, p_m)
    return np.linalg.solve(mats.V, mats.G)


def motor_jacobian(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """J_M with p_dot = J_M thM_dot [m/rad] (seed 003, eq. (19): A p_dot = D thM_dot, J_M = A^-1 D).

    Raises UruNoSolutionError on the combined singularity (det A = 0, eq. (36)).
    """
    mats = velocity_matrices(geom, p_m)
    deta = float(np.linalg.det(mats.A))
    if abs(deta) < 1e-12:
        raise UruNoSolutionError(
            f"motor Jacobian undefined at p = {np.asarray(p_m, float).tolist()} m: det A = {deta:.3e} "
            "(translation/actuation singularity, seed 003 eq. (36))"
        )
    return np.linalg.solve(mats.A, mats.D)


def inverse_motor_jacobian(geom: UruGeometry, p_m: np.ndarray) -> np.ndarray:
    """J_M^-1 with thM_dot = J_M^-1 p_dot [rad/m] (eq. (19): thM_dot = D^-1 A p_dot).

    Raises UruNoSolutionError on a serial singularity (some G_ii = 0, eq. (27)).
    """
    mats = velocity_matrices(geom, p_m)
    dd = np.diag(mats.D)
    if np.any(np.abs(dd) < 1e-12):
        raise UruNoSolutionError(
            f"inverse motor Jacobian undefined at p = {np.asarray(p_m, float).tolist()} m: "
            f"k_i G_ii = {dd.tolist()} m (serial singularity, seed 003 eq. (27))"
        )
    return mats.A / dd[:, None]


# ---------------------------------------------------------------------------------------------
# Singularity measures


@dataclass(frozen=True)
class UruSingularityMeasures:
    """Measures of the singularity loci at one point (each vanishes on its locus).

    - ``rotation_det_h``: det H = h_1 . (h_2 x h_3) = 2xyz / sqrt(...) (eq. (14), (17));
    - ``rotation_plane_distance_m``: min(|x|, |y|, |z|), distance to the locus of eq. (17);
    - ``translation_det_v``: det V = v_1 . (v_2 x v_3) (eq. (20)), in [-1, 1];
    - ``serial_min_sin_th3``: min_i |sin th_i3| (eq. (27) divided by f_i r_i), in [0, 1];
    - ``actuation_det_s``: det S (eq. (35)); NaN when det V = 0;
    - ``combined_det_a``: det A, the mixed product of eq. (36) (= det S det V);
    - ``workspace_margin_m``: eq. (29) margin, see :func:`workspace_margin_m`.
    """

    rotation_det_h: float
    rotation_plane_distance_m: float
    translation_det_v: float
    serial_min_sin_th3: float
    actuation_det_s: float
    combined_det_a: float
    workspace_margin_m: float


def rotation_singularity_measure(p_m: np.ndarray) -> np.ndarray:
    """det H at p (seed 003, eq. (17)): 2xyz / sqrt((x^2+z^2)(x^2+y^2)(y^2+z^2)); 0 on the coordinate planes.

    Defined as 0 on the coordinate axes, where eq. (17) is 0/0 (the platform gains two or
    three rotational DOFs there, seed 003 §3.1.1). Vectorised over p's leading shape.
    """
    p = np.asarray(p_m, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    den = np.sqrt((x * x + z * z) * (x * x + y * y) * (y * y + z * z))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(den > 0, 2.0 * x * y * z / np.where(den > 0, den, 1.0), 0.0)
    return out


def singularity_measures(geom: UruGeometry, p_m: np.ndarray) -> UruSingularityMeasures:
    """All singularity measures at p [m]; raises UruNoSolutionError outside the workspace."""
    mats = velocity_matrices(geom, p_m)
    p = np.asarray(p_m, dtype=float).reshape(3)
    cfg = configuration(geom, p)
    return UruSingularityMeasures(
        rotation_det_h=float(np.linalg.det(mats.H)),  # eq. (14)
        rotation_plane_distance_m=float(np.min(np.abs(p))),
        translation_det_v=float(np.linalg.det(mats.V)),  # eq. (20)
        serial_min_sin_th3=float(np.min(np.abs(np.sin(cfg.th3_rad)))),  # eq. (27)
        actuation_det_s=float(np.linalg.det(mats.S)),  # eq. (35)
        combined_det_a=float(np.linalg.det(mats.A)),  # eq. (36)
        workspace_margin_m=float(workspace_margin_m(geom, p)),  # eq. (29)
    )


def singularity_fields(geom: UruGeometry, p_m: np.ndarray) -> dict[str, np.ndarray]:
    """Vectorised measures on an array of points (..., 3), for plots; NaN outside the workspace.

    Keys: ``workspace_margin_m``, ``rotation_det_h``, ``translation_det_v``,
    ``serial_min_sin_th3``, ``actuation_det_s``, ``combined_det_a``.
    """
    p = np.asarray(p_m, dtype=float)
    lead = p.shape[:-1]
    pts = _as_points(p)
    cfg = _configurations(pts, geom)
    v, g, beta = cfg["v"], cfg["g"], cfg["beta"]
    gd = geom.f[None, :] * cfg["sin3"]  # eq. (6b): [g_i x (b_i - a_i)] . v_i = f_i sin th_i3
    with np.errstate(invalid="ignore", divide="ignore"):
        detv = np.einsum("ni,ni->n", v[:, 0], np.cross(v[:, 1], v[:, 2]))
        a = v + (geom.k[None, :] * gd / beta)[:, :, None] * g  # eq. (36) vectors
        deta = np.einsum("ni,ni->n", a[:, 0], np.cross(a[:, 1], a[:, 2]))
        dets = deta / detv  # det S = det A / det V (derived, see module doc)
    out = {
        "workspace_margin_m": workspace_margin_m(geom, pts),
        "rotation_det_h": rotation_singularity_measure(pts),
        "translation_det_v": detv,
        "serial_min_sin_th3": np.min(np.abs(cfg["sin3"]), axis=1),
        "actuation_det_s": dets,
        "combined_det_a": deta,
    }
    return {key: val.reshape(lead) for key, val in out.items()}


# ---------------------------------------------------------------------------------------------
# Path checks


@dataclass(frozen=True)
class UruPathMargins:
    """Minimum distances from each locus that a path must keep (defaults for the default geometry).

    - ``plane_distance_m``: min(|x|, |y|, |z|) from the rotation-singularity planes (eq. (17));
    - ``det_v``: |det V| (eq. (20)); ``det_s``: |det S| (eq. (35)); ``det_a``: |det A| (eq. (36));
    - ``sin_th3``: min |sin th_i3| (serial, eq. (27));
    - ``workspace_m``: distance from the reachable-workspace boundary (eq. (29)).

    Besides the magnitudes, a sign change of det H, det V, det S or det A between consecutive
    samples is refused (the path jumped across a locus between samples).
    """

    plane_distance_m: float = 0.02
    det_v: float = 0.05
    det_s: float = 0.05
    det_a: float = 0.05
    sin_th3: float = 0.10
    workspace_m: float = 0.02


def check_path(geom: UruGeometry, path_m: np.ndarray, margins: UruPathMargins = UruPathMargins()) -> None:
    """Refuse a Cartesian path (M, 3) [m] that violates a margin; returns None when it is safe.

    Raises UruPathRefusedError naming the locus or boundary, the sample index and the value.
    Checks, in this order at every sample: finiteness, workspace boundary (eq. (29)),
    rotation planes (eq. (17)), serial (eq. (27)), translation (eq. (20)), actuation
    (eq. (35)), combined (eq. (36)); then a sign change of the determinants with respect to the
    previous sample. The path should be sampled finely enough that the margins cannot be
    jumped over between samples.
    """
    path = np.asarray(path_m, dtype=float)
    if path.ndim != 2 or path.shape[1] != 3 or path.shape[0] == 0:
        raise ValueError(f"path_m must have shape (M, 3) with M >= 1, got {path.shape}")
    prev_signs: np.ndarray | None = None
    for idx, p in enumerate(path):
        if not np.all(np.isfinite(p)):
            raise UruPathRefusedError("non-finite position", idx, float("nan"), 0.0, p)
        ws = float(workspace_margin_m(geom, p))
        if ws < margins.workspace_m:
            raise UruPathRefusedError(
                "reachable-workspace boundary (eq. (29)) margin [m]", idx, ws, margins.workspace_m, p
            )
        plane = float(np.min(np.abs(p)))
        if plane < margins.plane_distance_m:
            axis = "xyz"[int(np.argmin(np.abs(p)))]
            raise UruPathRefusedError(
                f"rotation singularity: distance to plane {axis}=0 (eq. (17)) [m]",
                idx,
                plane,
                margins.plane_distance_m,
                p,
            )
        m = singularity_measures(geom, p)
        checks = (
            ("serial singularity min|sin th_i3| (eq. (27))", m.serial_min_sin_th3, margins.sin_th3),
            ("translation singularity |det V| (eq. (20))", abs(m.translation_det_v), margins.det_v),
            ("actuation singularity |det S| (eq. (35))", abs(m.actuation_det_s), margins.det_s),
            ("combined singularity |det A| (eq. (36))", abs(m.combined_det_a), margins.det_a),
        )
        for name, val, lim in checks:
            if not val >= lim:
                raise UruPathRefusedError(name, idx, val, lim, p)
        signs = np.sign([m.rotation_det_h, m.translation_det_v, m.actuation_det_s, m.combined_det_a])
        if prev_signs is not None:
            names = (
                "rotation singularity det H (eq. (14))",
                "translation singularity det V (eq. (20))",
                "actuation singularity det S (eq. (35))",
                "combined singularity det A (eq. (36))",
            )
            values = (m.rotation_det_h, m.translation_det_v, m.actuation_det_s, m.combined_det_a)
            for name, s_now, s_prev, val in zip(names, signs, prev_signs, values, strict=True):
                if s_now != s_prev:
                    raise UruPathRefusedError(
                        f"{name} changed sign (locus crossed between samples)", idx, val, 0.0, p
                    )
        prev_signs = signs


# ---------------------------------------------------------------------------------------------
# Default demo path


DEFAULT_PATH_CENTRE_M = (0.12, 0.12, 0.12)
DEFAULT_PATH_RADIUS_M = 0.04


def default_path(
    s: float | np.ndarray,
    centre_m: tuple[float, float, float] = DEFAULT_PATH_CENTRE_M,
    radius_m: float = DEFAULT_PATH_RADIUS_M,
) -> np.ndarray:
    """Platform positions [m] on a circle inside the first octant for s in [0, 1] (one lap).

    The circle lies in the plane through ``centre_m`` normal to (1, 1, 1)/sqrt(3); with the
    defaults its points keep at least 0.12 - 0.04 sqrt(2/3) = 0.087 m from the coordinate
    planes. ``s`` may be a scalar (returns (3,)) or an array (returns (..., 3)); values outside
    [0, 1] raise ValueError.
    """
    s_arr = np.asarray(s, dtype=float)
    if np.any(~np.isfinite(s_arr)) or np.any(s_arr < 0.0) or np.any(s_arr > 1.0):
        raise ValueError(f"path parameter s must be in [0, 1], got {s!r}")
    n = np.ones(3) / math.sqrt(3.0)
    e_a = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
    e_b = np.cross(n, e_a)
    ang = 2.0 * math.pi * s_arr
    pts = np.asarray(centre_m, float) + radius_m * (
        np.cos(ang)[..., None] * e_a + np.sin(ang)[..., None] * e_b
    )
    return pts
