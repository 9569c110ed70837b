"""The LaMaViP 3-URU (seed 003) as the controller and the simulator see it.

``UruRobot`` has the interface of ``CheopeRobot`` that the control law, the path task and
the simulated plant use (``n_actuators``, ``inverse_kinematics``, ``direct_kinematics``,
``jacobian``, ``check_pose``, ``check_actuators``, ``check_path``). The actuator
positions are the **motor-shaft angles** th_iM [rad] (seed 003, eq. (11)), the unit of the
simulated rotary drives.

The per-cycle functions (inverse and direct kinematics, the pose check) are written on plain
floats: the vectorised functions of ``controller/robots/uru/kinematics.py`` cost 80 us (IK), 0.8-1.1 ms
(direct kinematics) and 0.36 ms (singularity measures) per call, too much for a 400 Hz cycle
that also runs Ruckig. The fast versions compute the same equations (tests compare them with
``uru.py`` on random points of the first octant):

- IK: seed 003, eq. (15)-(16) (g_i, h_i), eq. (A1)-(A2) (th_i2 on the configured knee
  branch, written with atan2 as in ``uru._th2``), the phase references of §2 (th_i1) and
  eq. (11) (th_iM = th_i1 + th_i2 / k_i + c_i);
- direct kinematics: Newton on th_M(p) - th_M = 0 in motor space with a forward-difference
  Jacobian of the fast IK, backtracking on the residual; because the residual goes through
  the IK on the configured branch, a converged point is on that branch by construction. If
  Newton fails (e.g. from a far guess) the robust solver ``uru.direct_kinematics`` (Newton
  on the closure equations with continuation) is used;
- the pose check: workspace margin eq. (29), distance to the rotation planes eq. (17),
  min |sin th_i3| eq. (27), det V eq. (20), det A eq. (36) and det S = det A / det V eq. (35),
  against the configured margins (the same as ``uru.check_path``).

``check_path`` adds what a per-point check cannot see: a sign change of det H, det V, det S
or det A between samples (``uru.check_path``); its error names the locus.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from controller.core.linalg3 import Vector3
from controller.core.ports import POSE_OK, PoseStatus
from controller.errors import NoSolutionError, WorkspaceError
from controller.robots.uru import kinematics as uru

_FD_STEP_M = 1e-7
_NEWTON_TOL_RAD = 1e-10
_NEWTON_MAX_ITER = 30


class UruWorkspaceError(WorkspaceError):
    """A path of the 3-URU crosses or comes within a margin of a singularity locus or the boundary.

    ``locus`` names it (e.g. "rotation singularity: distance to plane z=0 (eq. (17)) [m]").
    """

    def __init__(self, message: str, locus: str) -> None:
        super().__init__(message)
        self.locus = locus


@dataclass(frozen=True)
class UruLimits:
    motor_min_rad: float
    motor_max_rad: float
    margins: uru.UruPathMargins = field(default_factory=uru.UruPathMargins)


@dataclass(frozen=True)
class UruRobot:
    geometry: uru.UruGeometry
    limits: UruLimits
    name: str = "uru"
    n_actuators: int = 3
    actuator_unit: str = "rad"

    # -- kinematics ------------------------------------------------------------------------

    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        """Motor-shaft angles th_M [rad] for the platform position p [m]; NoSolutionError if unreachable."""
        return np.array(_ik(self.geometry, float(tcp_m[0]), float(tcp_m[1]), float(tcp_m[2])))

    def direct_kinematics(self, q_rad: np.ndarray, guess_m: np.ndarray | None = None) -> np.ndarray:
        """Platform position p [m] from motor-shaft angles [rad]; Newton from ``guess_m`` (default: home)."""
        g = self.geometry
        target = (float(q_rad[0]), float(q_rad[1]), float(q_rad[2]))
        p0 = (
            g.home_position_m
            if guess_m is None
            else (float(guess_m[0]), float(guess_m[1]), float(guess_m[2]))
        )
        try:
            return np.array(_newton_motor(g, target, p0))
        except NoSolutionError:
            return uru.direct_kinematics(g, np.array(target), p_guess_m=np.array(p0))

    def jacobian(self, tcp_m: np.ndarray) -> np.ndarray:
        """J with th_M_dot = J p_dot [rad/m] (seed 003, eq. (19): J = D^-1 A), as Cheope's q_dot = J s_dot."""
        return uru.inverse_motor_jacobian(self.geometry, np.asarray(tcp_m, float))

    # -- checks ----------------------------------------------------------------------------

    def check_actuators(self, q_rad: tuple[float, ...]) -> PoseStatus:
        lim = self.limits
        for j, x in enumerate(q_rad):
            if not lim.motor_min_rad <= x <= lim.motor_max_rad:  # also False for NaN
                return PoseStatus(
                    False,
                    f"motor {j + 1} at {x:.4f} rad is outside its range "
                    f"[{lim.motor_min_rad}, {lim.motor_max_rad}] rad",
                )
        return POSE_OK

    def check_pose(self, tcp_m: np.ndarray) -> PoseStatus:
        """Workspace, singularity margins and motor range at p (no exception); plain floats, ~30 us."""
        p = (float(tcp_m[0]), float(tcp_m[1]), float(tcp_m[2]))
        if not all(math.isfinite(x) for x in p):
            return PoseStatus(False, f"platform position {list(p)} m is not finite")
        try:
            m = _measures(self.geometry, p)
        except NoSolutionError as err:
            return PoseStatus(False, str(err))
        mg = self.limits.margins
        plane = min(abs(x) for x in p)
        checks = (
            ("reachable-workspace boundary (eq. (29)) margin [m]", m["workspace_m"], mg.workspace_m),
            (
                f"rotation singularity: distance to plane {'xyz'[[abs(x) for x in p].index(plane)]}=0 (eq. (17)) [m]",
                plane,
                mg.plane_distance_m,
            ),
            ("serial singularity min|sin th_i3| (eq. (27))", m["sin_th3"], mg.sin_th3),
            ("translation singularity |det V| (eq. (20))", abs(m["det_v"]), mg.det_v),
            ("actuation singularity |det S| (eq. (35))", abs(m["det_s"]), mg.det_s),
            ("combined singularity |det A| (eq. (36))", abs(m["det_a"]), mg.det_a),
        )
        for name, value, low in checks:
            if not value >= low:
                return PoseStatus(False, f"within the margin of the {name}: {value:.4g} < {low}")
        return self.check_actuators(m["motor_rad"])

    def check_path(self, points_m: np.ndarray) -> None:
        """Raise UruWorkspaceError naming the locus and the sample; sign changes between samples too."""
        pts = np.asarray(points_m, dtype=float)
        try:
            uru.check_path(self.geometry, pts, self.limits.margins)
        except uru.UruPathRefusedError as err:
            raise UruWorkspaceError(str(err), err.locus) from err
        for i, p in enumerate(pts):
            status = self.check_pose(p)
            if not status.ok:
                raise UruWorkspaceError(
                    f"path sample {i} at {np.round(p, 4).tolist()} m: {status.reason}", status.reason
                )


# ---------------------------------------------------------------------------------------------
# Plain-float kinematics (same equations as controller/robots/uru/kinematics.py)


def _limb(geom: uru.UruGeometry, i: int, p: Vector3) -> tuple[float, float, float, Vector3, Vector3, float]:
    """(th_i1, th_i2, beta_i, g_i (3), h_i (3), alpha_i) for limb i at p (seed 003, eq. (15)-(16), (A1)-(A2))."""
    perp = [p[0], p[1], p[2]]
    perp[i] = 0.0
    beta = math.sqrt(perp[0] * perp[0] + perp[1] * perp[1] + perp[2] * perp[2])  # |e_i x p|
    if beta < 1e-12:
        raise NoSolutionError(
            f"platform position {list(p)} m lies on the axis of e_{i + 1}: g_{i + 1} is "
            "undefined (seed 003 eq. (15a))"
        )
    h = (perp[0] / beta, perp[1] / beta, perp[2] / beta)  # eq. (15b)-(16)
    # g_i = e_i x p / |e_i x p| (eq. (15a), '+' sign)
    if i == 0:
        g = (0.0, -p[2] / beta, p[1] / beta)
        th1 = math.atan2(g[2], g[1])  # g_1 = cos th_11 e_2 + sin th_11 e_3
    elif i == 1:
        g = (p[2] / beta, 0.0, -p[0] / beta)
        th1 = math.atan2(g[2], -g[0])  # g_2 = -cos th_21 e_1 + sin th_21 e_3
    else:
        g = (-p[1] / beta, p[0] / beta, 0.0)
        th1 = math.atan2(g[1], g[0])  # g_3 = cos th_31 e_1 + sin th_31 e_2
    alpha = p[i] + geom.offset_m  # e_i . (b_i - a_i)
    f, r = float(geom.f[i]), float(geom.r[i])
    rho = math.hypot(alpha, beta)
    kappa = (rho * rho + f * f - r * r) / (2.0 * f)  # eq. (A1)
    ratio = kappa / rho
    if abs(ratio) > 1.0 + 1e-12:
        raise NoSolutionError(
            f"platform position {list(p)} m is out of reach of limb {i + 1}: |B_{i + 1} - A_{i + 1}| = {rho:.6g} m "
            f"outside [{abs(f - r):.6g}, {f + r:.6g}] m (seed 003 eq. (29))"
        )
    th2 = math.atan2(beta, alpha) - geom.knee_sign * math.acos(max(-1.0, min(1.0, ratio)))  # eq. (A2)
    return th1, th2, beta, g, h, alpha


def _ik(geom: uru.UruGeometry, x: float, y: float, z: float) -> tuple[float, float, float]:
    p = (x, y, z)
    out = []
    for i in range(3):
        th1, th2, *_ = _limb(geom, i, p)
        out.append(th1 + th2 / float(geom.k[i]) + float(geom.c[i]))  # seed 003, eq. (11)
    return out[0], out[1], out[2]


def _solve3(a: list[list[float]], b: list[float]) -> list[float]:
    """Cramer's rule for a 3x3 system; NoSolutionError when singular."""

    def det(m: list[list[float]]) -> float:
        return (
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        )

    d = det(a)
    if abs(d) < 1e-14:
        raise NoSolutionError(f"singular Newton matrix (det {d:.3e})")
    out = []
    for c in range(3):
        m = [row[:] for row in a]
        for r in range(3):
            m[r][c] = b[r]
        out.append(det(m) / d)
    return out


def _newton_motor(
    geom: uru.UruGeometry, target: tuple[float, float, float], p0: tuple[float, float, float]
) -> tuple[float, float, float]:
    p = list(p0)
    q = _ik(geom, *p)
    res = [q[i] - target[i] for i in range(3)]
    norm = max(abs(x) for x in res)
    for _ in range(_NEWTON_MAX_ITER):
        if norm < _NEWTON_TOL_RAD:
            return p[0], p[1], p[2]
        jac = [[0.0] * 3 for _ in range(3)]  # d th_M / d p, forward differences of the fast IK
        for c in range(3):
            pc = list(p)
            pc[c] += _FD_STEP_M
            qc = _ik(geom, *pc)
            for r in range(3):
                jac[r][c] = (qc[r] - q[r]) / _FD_STEP_M
        step = _solve3(jac, [-x for x in res])
        lam = 1.0
        for _ in range(20):  # backtracking on max |residual|
            cand = [p[c] + lam * step[c] for c in range(3)]
            try:
                qn = _ik(geom, *cand)
            except NoSolutionError:
                lam *= 0.5
                continue
            rn = [qn[i] - target[i] for i in range(3)]
            nn = max(abs(x) for x in rn)
            if nn < norm:
                p, q, res, norm = cand, qn, rn, nn
                break
            lam *= 0.5
        else:
            raise NoSolutionError(
                f"direct kinematics for th_M = {list(target)} rad: no Newton step reduces the "
                f"residual {norm:.3e} rad at p = {p} m"
            )
    if norm < 1e-8:
        return p[0], p[1], p[2]
    raise NoSolutionError(
        f"direct kinematics for th_M = {list(target)} rad: residual {norm:.3e} rad after "
        f"{_NEWTON_MAX_ITER} iterations"
    )


class _Measures(TypedDict):
    workspace_m: float
    sin_th3: float
    det_v: float
    det_a: float
    det_s: float
    motor_rad: tuple[float, ...]


def _measures(geom: uru.UruGeometry, p: Vector3) -> _Measures:
    """Singularity measures and motor angles at p on plain floats (same as uru.singularity_measures)."""
    v: list[Vector3] = []
    a: list[Vector3] = []
    sin3: list[float] = []
    motor: list[float] = []
    margin = math.inf
    for i in range(3):
        th1, th2, beta, g, h, _alpha = _limb(geom, i, p)
        f, r, k = float(geom.f[i]), float(geom.r[i]), float(geom.k[i])
        w = [p[0], p[1], p[2]]
        w[i] += geom.offset_m  # b_i - a_i
        dist = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        margin = min(margin, f + r - dist, dist - abs(f - r))  # eq. (29)
        c2, s2 = math.cos(th2), math.sin(th2)
        u = [s2 * h[0], s2 * h[1], s2 * h[2]]
        u[i] += c2  # u_i = cos th_i2 e_i + sin th_i2 h_i
        vi = ((w[0] - f * u[0]) / r, (w[1] - f * u[1]) / r, (w[2] - f * u[2]) / r)  # eq. (21)
        gxu = (g[1] * u[2] - g[2] * u[1], g[2] * u[0] - g[0] * u[2], g[0] * u[1] - g[1] * u[0])
        s3 = vi[0] * gxu[0] + vi[1] * gxu[1] + vi[2] * gxu[2]  # sin th_i3
        coef = k * f * s3 / beta  # k_i G_ii / beta_i with G_ii = f_i sin th_i3 (eq. (6b))
        v.append(vi)
        a.append((vi[0] + coef * g[0], vi[1] + coef * g[1], vi[2] + coef * g[2]))  # eq. (19), (36)
        sin3.append(abs(s3))
        motor.append(th1 + th2 / k + float(geom.c[i]))

    def triple(m: list[Vector3]) -> float:
        x, y, z = m
        return (
            x[0] * (y[1] * z[2] - y[2] * z[1])
            - x[1] * (y[0] * z[2] - y[2] * z[0])
            + x[2] * (y[0] * z[1] - y[1] * z[0])
        )

    det_v, det_a = triple(v), triple(a)
    det_s = det_a / det_v if det_v != 0.0 else math.nan  # det S = det A / det V (uru.py module doc)
    return {
        "workspace_m": margin,
        "sin_th3": min(sin3),
        "det_v": det_v,
        "det_a": det_a,
        "det_s": det_s,
        "motor_rad": tuple(motor),
    }
