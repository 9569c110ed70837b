"""Cheope, 3-dof translational configuration (three P[SS]2 legs), seed 001.

Notation follows seed 001 §3: base frame {0} with the origin at the intersection of the
prismatic axes, Z0 along the chassis axis pointing towards the workspace, X0 along the
projection of prismatic axis 1. For leg j:

- ``n_j``  unit vector of the prismatic axis, the slider sits at ``q_j n_j``;
- ``a_j``  platform vector from the TCP to the mid point of the leg's two platform joints;
- ``w_j``  unit vector of the rod pair, from slider to platform;
- ``l``    rod length.

Loop closure (seed 001, eq. (1)):  s + a_j - l w_j - q_j n_j = 0.

Everything here is pure numpy on 3-vectors; nothing reads a clock or does I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from controller.core.linalg3 import (
    Matrix3,
    Vector3,
    dot3,
    matmul3,
    symmetric_eigenvalues3,
    transpose3,
)
from controller.core.ports import POSE_OK, PoseStatus
from controller.errors import NoSolutionError, WorkspaceError
from controller.robots.performance import MassModel, contact_force_from_efforts

_AXES = 3

Rows3 = tuple[Vector3, ...]  # one 3-vector per leg, plain floats
Point3 = np.ndarray | Sequence[float]  # a TCP position or actuator positions: an array or floats


@dataclass(frozen=True)
class CheopeGeometry:
    """Geometry of the 3-dof configuration.

    The prismatic axes lie on a cone: axis j points along azimuth ``axis_azimuths_rad[j]``
    (counter-clockwise from X0) and is tilted ``axis_tilt_rad`` from +Z0. The platform
    vectors ``a_j`` have radius ``platform_radius_m`` at ``platform_azimuths_rad``.
    """

    rod_length_m: float = 0.50
    axis_tilt_rad: float = math.radians(60.0)
    axis_azimuths_rad: tuple[float, float, float] = (0.0, math.pi / 2, math.pi)
    platform_radius_m: float = 0.05
    platform_azimuths_rad: tuple[float, float, float] = (0.0, math.pi / 2, math.pi)
    # Where each spherical joint sits in its neutral (centred) orientation: the rod direction
    # when the TCP is at this point. Seed 001 §5.2: the joints swing about +-22 deg from it.
    joint_neutral_tcp_m: tuple[float, float, float] = (0.0, 0.0, 0.50)
    axes: np.ndarray = field(init=False, repr=False, compare=False)
    platform_vectors: np.ndarray = field(init=False, repr=False, compare=False)
    neutral_rod_directions: np.ndarray = field(init=False, repr=False, compare=False)
    # The same vectors as tuples of floats, for the per-cycle functions.
    rows_axes: Rows3 = field(init=False, repr=False, compare=False)
    rows_platform: Rows3 = field(init=False, repr=False, compare=False)
    rows_neutral: Rows3 = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.rod_length_m > 0:
            raise ValueError(f"rod_length_m must be > 0, got {self.rod_length_m}")
        if not 0.0 < self.axis_tilt_rad < math.pi:
            raise ValueError(f"axis_tilt_rad must be in (0, pi), got {self.axis_tilt_rad}")
        if self.platform_radius_m < 0:
            raise ValueError(f"platform_radius_m must be >= 0, got {self.platform_radius_m}")
        st, ct = math.sin(self.axis_tilt_rad), math.cos(self.axis_tilt_rad)
        axes = np.array([[st * math.cos(az), st * math.sin(az), ct] for az in self.axis_azimuths_rad])
        plat = np.array(
            [
                [self.platform_radius_m * math.cos(az), self.platform_radius_m * math.sin(az), 0.0]
                for az in self.platform_azimuths_rad
            ]
        )
        axes.setflags(write=False)
        plat.setflags(write=False)
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "platform_vectors", plat)
        object.__setattr__(self, "rows_axes", tuple(tuple(float(x) for x in r) for r in axes))
        object.__setattr__(self, "rows_platform", tuple(tuple(float(x) for x in r) for r in plat))
        # The neutral directions need the inverse kinematics of this very geometry.
        q0 = _inverse(
            self.rows_axes,
            self.rows_platform,
            self.rod_length_m,
            np.asarray(self.joint_neutral_tcp_m, dtype=float),
        )
        neutral = rod_directions_from(axes, plat, self.rod_length_m, np.asarray(self.joint_neutral_tcp_m), q0)
        neutral.setflags(write=False)
        object.__setattr__(self, "neutral_rod_directions", neutral)
        object.__setattr__(self, "rows_neutral", tuple(tuple(float(x) for x in r) for r in neutral))


def _inverse(axes: Rows3, plat: Rows3, rod_length_m: float, tcp_m: Point3) -> np.ndarray:
    return np.array(_inverse_floats(axes, plat, rod_length_m, tcp_m))


def _inverse_floats(axes: Rows3, plat: Rows3, rod_length_m: float, tcp_m: Point3) -> list[float]:
    # seed 001, eq. (5): q_j = n_j.r_j + sqrt((n_j.r_j)^2 - r_j.r_j + l^2), r_j = s + a_j.
    # The '+' branch is the one the paper selects (slider beyond the rod's foot point).
    # Plain floats: for 3-vectors numpy's per-call overhead is larger than the arithmetic.
    sx, sy, sz = float(tcp_m[0]), float(tcp_m[1]), float(tcp_m[2])
    l2 = rod_length_m * rod_length_m
    q = []
    for j in range(_AXES):
        n, a = axes[j], plat[j]
        rx, ry, rz = sx + a[0], sy + a[1], sz + a[2]
        nr = n[0] * rx + n[1] * ry + n[2] * rz
        disc = nr * nr - (rx * rx + ry * ry + rz * rz) + l2
        if disc < 0.0:
            raise NoSolutionError(
                f"TCP {[sx, sy, sz]} m is out of reach of leg {j + 1}: "
                f"discriminant of seed 001 eq. (5) is {disc:.3e} m^2 < 0"
            )
        q.append(nr + math.sqrt(disc))
    return q


def inverse_kinematics(geom: CheopeGeometry, tcp_m: Point3) -> np.ndarray:
    """Actuator positions q [m] for a TCP position s [m] (seed 001, eq. (5), '+' branch)."""
    return _inverse(geom.rows_axes, geom.rows_platform, geom.rod_length_m, tcp_m)


def rod_directions_from(
    axes: np.ndarray, plat: np.ndarray, rod_length_m: float, tcp_m: np.ndarray, q_m: np.ndarray
) -> np.ndarray:
    """Rod unit vectors w_j (rows) from eq. (1): w_j = (s + a_j - q_j n_j) / l."""
    return (tcp_m[None, :] + plat - q_m[:, None] * axes) / rod_length_m


def rod_directions(geom: CheopeGeometry, tcp_m: np.ndarray, q_m: np.ndarray) -> np.ndarray:
    return rod_directions_from(
        geom.axes, geom.platform_vectors, geom.rod_length_m, np.asarray(tcp_m, float), np.asarray(q_m, float)
    )


def _sub(a: Vector3, b: Vector3) -> Vector3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _over(v: Vector3, k: float) -> Vector3:
    return (v[0] / k, v[1] / k, v[2] / k)


def direct_kinematics(geom: CheopeGeometry, q_m: np.ndarray) -> np.ndarray:
    """TCP position s [m] from actuator positions q [m]: intersection of three spheres.

    seed 001, eq. (2)-(4): sphere j has centre c_j = q_j n_j - a_j and radius l. In the
    auxiliary frame {a} (origin c_1, X_a through c_2, c_3 in the X_a Y_a plane)
    x_a = x_c2 / 2, y_a = (x_c3^2 + y_c3^2 - x_c2 x_c3) / (2 y_c3), z_a = +-sqrt(l^2 - x_a^2 - y_a^2).
    Of the two solutions we keep the one on the paper's assembly branch (the one the
    inverse kinematics' '+' sign describes, w_j . n_j <= 0 for every leg); the other one
    lies inside the base (seed 001 §4.1).
    """
    q = [float(q_m[0]), float(q_m[1]), float(q_m[2])]
    axes, plat = geom.rows_axes, geom.rows_platform
    c = [
        (q[j] * axes[j][0] - plat[j][0], q[j] * axes[j][1] - plat[j][1], q[j] * axes[j][2] - plat[j][2])
        for j in range(_AXES)
    ]
    d12 = _sub(c[1], c[0])
    x_c2 = math.sqrt(dot3(d12, d12))
    if x_c2 < 1e-12:
        raise NoSolutionError(f"sphere centres 1 and 2 coincide for q={q} m")
    ex = (d12[0] / x_c2, d12[1] / x_c2, d12[2] / x_c2)
    v3 = _sub(c[2], c[0])
    x_c3 = dot3(ex, v3)
    ey = (v3[0] - x_c3 * ex[0], v3[1] - x_c3 * ex[1], v3[2] - x_c3 * ex[2])
    y_c3 = math.sqrt(dot3(ey, ey))
    if y_c3 < 1e-12:
        raise NoSolutionError(f"sphere centres are collinear for q={q} m")
    ey = (ey[0] / y_c3, ey[1] / y_c3, ey[2] / y_c3)
    ez = (ex[1] * ey[2] - ex[2] * ey[1], ex[2] * ey[0] - ex[0] * ey[2], ex[0] * ey[1] - ex[1] * ey[0])
    l = geom.rod_length_m
    x_a = x_c2 / 2.0
    y_a = (x_c3 * x_c3 + y_c3 * y_c3 - x_c2 * x_c3) / (2.0 * y_c3)
    z2 = l * l - x_a * x_a - y_a * y_a
    if z2 < 0.0:
        raise NoSolutionError(
            f"no assembly for q={q} m: the three rod spheres do not intersect "
            f"(l^2 - x_a^2 - y_a^2 = {z2:.3e} m^2)"
        )
    z_a = math.sqrt(z2)
    c0 = c[0]
    base = (  # eq. (3): {a} -> {0}
        c0[0] + x_a * ex[0] + y_a * ey[0],
        c0[1] + x_a * ex[1] + y_a * ey[1],
        c0[2] + x_a * ex[2] + y_a * ey[2],
    )
    best = None
    tolerance = 1e-9 * l
    for sign in (1.0, -1.0):
        s = (base[0] + sign * z_a * ez[0], base[1] + sign * z_a * ez[1], base[2] + sign * z_a * ez[2])
        # on the branch: w_j . n_j = (s - c_j) . n_j / l <= 0 for every leg (written out: it runs
        # every cycle, and the calls cost more than the arithmetic)
        on_branch = True
        for cj, n in zip(c, axes):
            if not (s[0] - cj[0]) * n[0] + (s[1] - cj[1]) * n[1] + (s[2] - cj[2]) * n[2] <= tolerance:
                on_branch = False
                break
        if on_branch and (best is None or s[2] > best[2]):
            best = s
    if best is None:
        raise NoSolutionError(
            f"no assembly on the working branch for q={q} m "
            "(every solution has a rod pointing along its prismatic axis)"
        )
    return np.array(best)


def jacobian(geom: CheopeGeometry, tcp_m: np.ndarray, q_m: np.ndarray | None = None) -> np.ndarray:
    return np.array(_jacobian_rows(geom, tcp_m, q_m))


def _jacobian_rows(geom: CheopeGeometry, tcp_m: Point3, q_m: Point3 | None = None) -> list[Vector3]:
    """J with q_dot = J s_dot (seed 001, eq. (6)-(7)): J = K3^-1 W3^T.

    Derivation (eq. (1) differentiated and projected on w_j): w_j^T s_dot = (w_j^T n_j) q_dot_j.
    Raises NoSolutionError at an inverse singularity (some w_j . n_j = 0).
    """
    q = inverse_kinematics(geom, tcp_m) if q_m is None else q_m
    s = (float(tcp_m[0]), float(tcp_m[1]), float(tcp_m[2]))
    axes, plat = geom.rows_axes, geom.rows_platform
    rows = []
    for j in range(_AXES):
        # w_j scaled by l; the scale cancels in w_j / (w_j . n_j)
        w = (
            s[0] + plat[j][0] - q[j] * axes[j][0],
            s[1] + plat[j][1] - q[j] * axes[j][1],
            s[2] + plat[j][2] - q[j] * axes[j][2],
        )
        k = dot3(w, axes[j])
        if abs(k) < 1e-12 * geom.rod_length_m:
            raise NoSolutionError(f"inverse singularity at TCP {list(s)} m: w_{j + 1} . n_{j + 1} = 0")
        rows.append((w[0] / k, w[1] / k, w[2] / k))
    return rows


@dataclass(frozen=True)
class SingularityMeasures:
    """Distances from the singularity classes of seed 001 §5.1 (all 0 at the singularity).

    - ``direct``: |det W3|, the volume spanned by the unit rod vectors (rods coplanar -> 0);
    - ``inverse``: min_j |w_j . n_j| (a rod orthogonal to its prismatic axis -> 0);
    - ``structural``: min over rod pairs of |w_i x w_j| (two rods parallel -> 0).
    """

    direct: float
    inverse: float
    structural: float


def singularity_measures(
    geom: CheopeGeometry, tcp_m: np.ndarray, q_m: np.ndarray | None = None
) -> SingularityMeasures:
    s = np.asarray(tcp_m, dtype=float)
    q = inverse_kinematics(geom, s) if q_m is None else np.asarray(q_m, float)
    w = rod_directions(geom, s, q)
    direct = abs(float(np.linalg.det(w)))
    inverse = float(np.min(np.abs(np.einsum("ij,ij->i", w, geom.axes))))
    pairs = ((0, 1), (0, 2), (1, 2))
    structural = min(float(np.linalg.norm(np.cross(w[i], w[j]))) for i, j in pairs)
    return SingularityMeasures(direct=direct, inverse=inverse, structural=structural)


def joint_swing_rad(geom: CheopeGeometry, tcp_m: np.ndarray, q_m: np.ndarray | None = None) -> np.ndarray:
    """Swing of each leg's spherical joints from their neutral direction [rad] (seed 001 §5.2).

    The platform only translates and the slider only slides, so both joint housings keep
    their orientation and both joints of a leg swing by the angle between w_j and its
    neutral direction.
    """
    s = np.asarray(tcp_m, dtype=float)
    q = inverse_kinematics(geom, s) if q_m is None else np.asarray(q_m, float)
    w = rod_directions(geom, s, q)
    c = np.clip(np.einsum("ij,ij->i", w, geom.neutral_rod_directions), -1.0, 1.0)
    return np.arccos(c)


@dataclass(frozen=True)
class CheopeLimits:
    stroke_min_m: float
    stroke_max_m: float
    joint_swing_limit_rad: float
    min_direct_measure: float
    min_inverse_measure: float
    min_structural_measure: float
    max_condition_number: float


@dataclass(frozen=True)
class CheopeRobot:
    """The Cheope model with its limits: what the controller and the simulator use."""

    geometry: CheopeGeometry
    limits: CheopeLimits
    name: str = "cheope"
    n_actuators: int = _AXES
    masses: MassModel | None = None  # the lumped masses: the effort witness adds their inertia back
    actuator_stiffness_n_m: float = 2.0e5  # the servo stiffness k the simulated structure has along J

    def inverse_kinematics(self, tcp_m: np.ndarray) -> np.ndarray:
        return inverse_kinematics(self.geometry, tcp_m)

    def direct_kinematics(self, q_m: np.ndarray) -> np.ndarray:
        return direct_kinematics(self.geometry, q_m)

    def jacobian(self, tcp_m: np.ndarray) -> np.ndarray:
        return jacobian(self.geometry, tcp_m)

    def joint_motion(
        self, tcp_m: tuple[float, float, float], velocity_m_s: tuple[float, float, float]
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(q, q_dot = J v) at ``tcp_m`` in plain floats: a task's reference every cycle."""
        g = self.geometry
        q = _inverse_floats(g.rows_axes, g.rows_platform, g.rod_length_m, tcp_m)
        jac = _jacobian_rows(g, tcp_m, q)
        v = velocity_m_s
        return tuple(q), tuple(r[0] * v[0] + r[1] * v[1] + r[2] * v[2] for r in jac)

    def contact_force_from_efforts(
        self,
        tcp_m: tuple[float, float, float],
        q: tuple[float, ...],
        efforts_n: tuple[float, ...],
        qdd: tuple[float, ...],
    ) -> tuple[Vector3, float] | None:
        """The contact force on the tool the drives' efforts imply, F = M a - J^T tau, and |M a|.

        Virtual work with q_dot = J s_dot (seed 001, eq. (7)): efforts tau at the carriages balance
        a force J^T tau at the TCP. The motors push the structure: against a contact force F
        (tau = -J^-T F in a static contact) and to accelerate the robot's own masses,
        M = m_0 I + m_q J^T J (``performance.cartesian_mass_matrix``), with a = J^-1 q_dot_dot the
        commanded TCP acceleration (``performance.contact_force_from_efforts``, any translational
        robot's). Plain floats: it runs every cycle (``ForceWitnessModel``).
        """
        try:
            rows = _jacobian_rows(self.geometry, tcp_m, q)
        except NoSolutionError:
            return None
        return contact_force_from_efforts((rows[0], rows[1], rows[2]), efforts_n, qdd, self.masses)

    def check_pose(self, tcp_m: np.ndarray) -> PoseStatus:
        """Stroke, spherical-joint swing and singularity margins at ``tcp_m`` (no exception).

        Runs every cycle, so it works on plain floats; the measures are those of
        ``singularity_measures``, ``joint_swing_rad`` and cond(J) (tests check they agree).
        """
        g, lim = self.geometry, self.limits
        try:
            q = _inverse_floats(g.rows_axes, g.rows_platform, g.rod_length_m, tcp_m)
        except NoSolutionError as err:
            return PoseStatus(False, str(err))
        s = (float(tcp_m[0]), float(tcp_m[1]), float(tcp_m[2]))
        inv_l = 1.0 / g.rod_length_m
        w: list[Vector3] = []
        k: list[float] = []
        for j in range(_AXES):
            if not lim.stroke_min_m <= q[j] <= lim.stroke_max_m:
                return PoseStatus(
                    False,
                    f"actuator {j + 1} at {q[j]:.4f} m is outside its stroke "
                    f"[{lim.stroke_min_m}, {lim.stroke_max_m}] m",
                )
            n, a = g.rows_axes[j], g.rows_platform[j]
            wj = (
                (s[0] + a[0] - q[j] * n[0]) * inv_l,
                (s[1] + a[1] - q[j] * n[1]) * inv_l,
                (s[2] + a[2] - q[j] * n[2]) * inv_l,
            )
            u = g.rows_neutral[j]
            swing = math.acos(max(-1.0, min(1.0, wj[0] * u[0] + wj[1] * u[1] + wj[2] * u[2])))
            if swing > lim.joint_swing_limit_rad:
                return PoseStatus(
                    False,
                    f"spherical joints of leg {j + 1} swing {math.degrees(swing):.1f} deg, "
                    f"limit {math.degrees(lim.joint_swing_limit_rad):.1f} deg",
                )
            w.append(wj)
            k.append(wj[0] * n[0] + wj[1] * n[1] + wj[2] * n[2])
        # the measures of singularity_measures, with the products written out (every cycle)
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = w
        x01 = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
        x02 = (a1 * c2 - a2 * c1, a2 * c0 - a0 * c2, a0 * c1 - a1 * c0)
        x12 = (b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0)
        direct = abs(a0 * x12[0] + a1 * x12[1] + a2 * x12[2])  # |det W3|
        inverse = min(abs(k[0]), abs(k[1]), abs(k[2]))
        structural = min(
            math.sqrt(x01[0] * x01[0] + x01[1] * x01[1] + x01[2] * x01[2]),
            math.sqrt(x02[0] * x02[0] + x02[1] * x02[1] + x02[2] * x02[2]),
            math.sqrt(x12[0] * x12[0] + x12[1] * x12[1] + x12[2] * x12[2]),
        )
        for name, value, low in (
            ("direct", direct, lim.min_direct_measure),
            ("inverse", inverse, lim.min_inverse_measure),
            ("structural", structural, lim.min_structural_measure),
        ):
            if value < low:
                return PoseStatus(False, f"within the {name}-singularity margin: measure {value:.3f} < {low}")
        jac: Matrix3 = (_over(w[0], k[0]), _over(w[1], k[1]), _over(w[2], k[2]))
        eig = symmetric_eigenvalues3(matmul3(transpose3(jac), jac))
        cond = math.sqrt(eig[2] / eig[0])
        if cond > lim.max_condition_number:
            return PoseStatus(False, f"condition number {cond:.2f} above {lim.max_condition_number}")
        return POSE_OK

    def check_actuators(self, q_m: tuple[float, ...]) -> PoseStatus:
        """Actuator positions (measured, or a task's reference) inside their strokes (and numbers at all)."""
        lim = self.limits
        for j, x in enumerate(q_m):
            if not lim.stroke_min_m <= x <= lim.stroke_max_m:  # also False for NaN
                return PoseStatus(
                    False,
                    f"actuator {j + 1} at {x:.4f} m is outside its stroke "
                    f"[{lim.stroke_min_m}, {lim.stroke_max_m}] m",
                )
        return POSE_OK

    def check_path(self, points_m: np.ndarray) -> None:
        """Raise WorkspaceError naming the first sample of the path that fails ``check_pose``."""
        for i, p in enumerate(np.asarray(points_m, dtype=float)):
            status = self.check_pose(p)
            if not status.ok:
                raise WorkspaceError(f"path sample {i} at {np.round(p, 4).tolist()} m: {status.reason}")
