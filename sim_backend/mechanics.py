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
from dataclasses import dataclass, field

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


@dataclass
class CompliantTool:
    params: ComplianceParams
    deflection_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def step(self, jac: np.ndarray, force_n: np.ndarray, dt: float) -> None:
        jtj = jac.T @ jac
        p = self.params
        stiffness = p.actuator_stiffness_n_m * jtj
        damping = p.actuator_damping_n_s_m * jtj
        mass = cartesian_mass_matrix(jac, p.masses)
        acc = np.linalg.solve(mass, force_n - stiffness @ self.deflection_m - damping @ self.velocity_m_s)
        self.velocity_m_s = self.velocity_m_s + acc * dt
        self.deflection_m = self.deflection_m + self.velocity_m_s * dt
