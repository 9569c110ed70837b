"""The robot's structural compliance and moving mass, between the actuators and the tool.

Seed 001 §6 lumps the compliance in the actuators: Cartesian stiffness K = k J^T J. Here the
tool centre point deviates from the kinematic TCP (the direct kinematics of the encoder
positions) by a deflection x obeying

    M(q) x'' = -K(q) x - D(q) x' + F_contact,

with M = m_0 I + m_q J^T J (controller/robots/performance.py), K = k J^T J and
D = c J^T J, c = 2 zeta sqrt(k m_q) (each actuator mode damped with ratio zeta). The
compliance sits outside the drives' encoder loop: the drives hold their carriages, the
structure bends, the encoders do not see it; the force sensor does. Integrated with
semi-implicit Euler in the plant's sub-steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.robots.performance import MassModel, cartesian_mass_matrix


@dataclass(frozen=True)
class ComplianceParams:
    actuator_stiffness_n_m: float
    damping_ratio: float
    masses: MassModel

    @property
    def actuator_damping_n_s_m(self) -> float:
        return 2.0 * self.damping_ratio * math.sqrt(self.actuator_stiffness_n_m * self.masses.per_actuator_kg)


Matrix3 = tuple[tuple[float, float, float], ...]
Vector3 = tuple[float, float, float]
NO_ACCELERATION: Vector3 = (0.0, 0.0, 0.0)


def matvec(m: Matrix3, v: Vector3) -> Vector3:
    return (m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
            m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
            m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2])


def as_rows(m: np.ndarray) -> Matrix3:
    return tuple(tuple(float(x) for x in row) for row in m)  # type: ignore[return-value]


@dataclass
class CompliantTool:
    """Deflection state of the structure. ``set_structure`` when the pose has moved, ``step`` often.

    The matrices depend on the pose through J; the plant refreshes them every millisecond or
    so (the TCP moves micrometres in that time) and steps in plain floats in between, which
    keeps the simulator's cost per SYNC low enough to answer within the cycle.
    """

    params: ComplianceParams
    deflection_m: Vector3 = (0.0, 0.0, 0.0)
    velocity_m_s: Vector3 = (0.0, 0.0, 0.0)
    _inv_mass_stiffness: Matrix3 = ((0.0,) * 3,) * 3
    _inv_mass_damping: Matrix3 = ((0.0,) * 3,) * 3
    _inv_mass: Matrix3 = ((0.0,) * 3,) * 3

    def set_structure(self, jac: np.ndarray) -> None:
        jtj = jac.T @ jac
        p = self.params
        inv_mass = np.linalg.inv(cartesian_mass_matrix(jac, p.masses))
        self._inv_mass = as_rows(inv_mass)
        self._inv_mass_stiffness = as_rows(inv_mass @ (p.actuator_stiffness_n_m * jtj))
        self._inv_mass_damping = as_rows(inv_mass @ (p.actuator_damping_n_s_m * jtj))

    def step(self, force_n: Vector3, dt: float, base_acceleration_m_s2: Vector3 = NO_ACCELERATION) -> None:
        """Semi-implicit Euler: x'' = M^-1 (F - K x - D x') - a_base.

        ``a_base`` is the kinematic TCP's acceleration: the tool's mass moves with it, so the
        structure carries M a_base (zero unless the plant's ``structure_inertial_load`` is on).
        """
        a_f = matvec(self._inv_mass, force_n)
        a_k = matvec(self._inv_mass_stiffness, self.deflection_m)
        a_d = matvec(self._inv_mass_damping, self.velocity_m_s)
        a_b = base_acceleration_m_s2
        v = tuple(self.velocity_m_s[i] + (a_f[i] - a_k[i] - a_d[i] - a_b[i]) * dt for i in range(3))
        self.velocity_m_s = v  # type: ignore[assignment]
        self.deflection_m = tuple(self.deflection_m[i] + v[i] * dt for i in range(3))  # type: ignore[assignment]
