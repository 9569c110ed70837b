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

from controller.core.linalg3 import Matrix3, Vector3, as_rows, inverse3, matmul3, matvec, scaled3, transpose3
from controller.core.ports import LumpedMasses


@dataclass(frozen=True)
class ComplianceParams:
    actuator_stiffness_n_m: float
    damping_ratio: float
    masses: LumpedMasses

    @property
    def actuator_damping_n_s_m(self) -> float:
        return 2.0 * self.damping_ratio * math.sqrt(self.actuator_stiffness_n_m * self.masses.per_actuator_kg)


NO_ACCELERATION: Vector3 = (0.0, 0.0, 0.0)


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

    def set_structure(self, jac: np.ndarray | Matrix3) -> None:
        j = as_rows(np.asarray(jac)) if isinstance(jac, np.ndarray) else jac
        jtj = matmul3(transpose3(j), j)
        p = self.params
        m0, mq = (
            p.masses.translating_kg,
            p.masses.per_actuator_kg,
        )  # M = m_0 I + m_q J^T J (cartesian_mass_matrix)

        def mass_row(r: int) -> Vector3:
            return (
                mq * jtj[r][0] + (m0 if r == 0 else 0.0),
                mq * jtj[r][1] + (m0 if r == 1 else 0.0),
                mq * jtj[r][2] + (m0 if r == 2 else 0.0),
            )

        inv_mass = inverse3((mass_row(0), mass_row(1), mass_row(2)))
        self._inv_mass = inv_mass
        self._inv_mass_stiffness = matmul3(inv_mass, scaled3(jtj, p.actuator_stiffness_n_m))
        self._inv_mass_damping = matmul3(inv_mass, scaled3(jtj, p.actuator_damping_n_s_m))

    def step(self, force_n: Vector3, dt: float, base_acceleration_m_s2: Vector3 = NO_ACCELERATION) -> None:
        """Semi-implicit Euler: x'' = M^-1 (F - K x - D x') - a_base.

        ``a_base`` is the kinematic TCP's acceleration: the tool's mass moves with it, so the
        structure carries M a_base (zero unless the plant's ``structure_inertial_load`` is on).
        """
        a_f = matvec(self._inv_mass, force_n)
        a_k = matvec(self._inv_mass_stiffness, self.deflection_m)
        a_d = matvec(self._inv_mass_damping, self.velocity_m_s)
        a_b = base_acceleration_m_s2
        v0, v1, v2 = self.velocity_m_s
        v0 += (a_f[0] - a_k[0] - a_d[0] - a_b[0]) * dt
        v1 += (a_f[1] - a_k[1] - a_d[1] - a_b[1]) * dt
        v2 += (a_f[2] - a_k[2] - a_d[2] - a_b[2]) * dt
        x = self.deflection_m
        self.velocity_m_s = (v0, v1, v2)
        self.deflection_m = (x[0] + v0 * dt, x[1] + v1 * dt, x[2] + v2 * dt)
