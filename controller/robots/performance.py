"""Kinetostatic performance indices of a translational parallel robot (seed 001 §6).

The printed eq. (8)-(10) of seed 001 swap inverses and transposes; these are derived again
from the Jacobian's definition q_dot = J s_dot (eq. (7)) and virtual work:

- velocity: actuator speeds bounded by |q_dot| <= 1 give {s_dot : s_dot^T J^T J s_dot <= 1};
  semi-axes 1/sigma_i(J) along the right singular vectors v_i of J;
- force: tau^T q_dot = F^T s_dot for every s_dot gives F = J^T tau; |tau| <= 1 gives
  {F : F^T (J^T J)^-1 F <= 1}; semi-axes sigma_i(J) along v_i;
- stiffness: tau = k dq = k J ds and F = J^T tau give K = k J^T J; semi-axes k sigma_i^2;
- mass: a documented lumped model (see ``cartesian_mass_matrix``), M = m_0 I + m_q J^T J.

The reach of an ellipsoid {x : x^T A^-1 x <= 1} along a unit direction u is sqrt(u^T A u),
so the force capacity along u is |J u| and the velocity capacity is 1 / sqrt(u^T (J^T J)^-1 u).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.core.linalg3 import Matrix3, Vector3, inverse3, matvec, transpose3
from controller.core.ports import LumpedMasses


@dataclass(frozen=True)
class Ellipsoid:
    """Principal semi-axes (lengths, ascending) and their unit directions (columns)."""

    semi_axes: np.ndarray
    directions: np.ndarray

    def reach(self, direction: np.ndarray) -> float:
        """Distance from the centre to the surface along ``direction``."""
        u = np.asarray(direction, dtype=float)
        u = u / np.linalg.norm(u)
        coords = self.directions.T @ u
        return float(1.0 / np.sqrt(np.sum((coords / self.semi_axes) ** 2)))


def _ellipsoid_from_shape(shape: np.ndarray) -> Ellipsoid:
    """Ellipsoid {x : x^T shape^-1 x <= 1} for a symmetric positive-definite ``shape``."""
    vals, vecs = np.linalg.eigh(shape)
    return Ellipsoid(semi_axes=np.sqrt(vals), directions=vecs)


def velocity_ellipsoid(jac: np.ndarray) -> Ellipsoid:
    """TCP velocities reachable with unit actuator speed norm: shape (J^T J)^-1."""
    return _ellipsoid_from_shape(np.linalg.inv(jac.T @ jac))


def force_ellipsoid(jac: np.ndarray) -> Ellipsoid:
    """TCP forces produced by unit actuator force norm (F = J^T tau): shape J^T J."""
    return _ellipsoid_from_shape(jac.T @ jac)


def cartesian_stiffness(jac: np.ndarray, actuator_stiffness_n_m: float) -> np.ndarray:
    """K = k J^T J [N/m], compliance lumped in the actuators."""
    return actuator_stiffness_n_m * (jac.T @ jac)


def stiffness_ellipsoid(jac: np.ndarray, actuator_stiffness_n_m: float) -> Ellipsoid:
    """Forces needed for a unit displacement norm: semi-axes k sigma_i^2 (shape K^2)."""
    k = cartesian_stiffness(jac, actuator_stiffness_n_m)
    return _ellipsoid_from_shape(k @ k)


@dataclass(frozen=True)
class MassModel:
    """Lumped masses of a translational robot with prismatic actuators [kg].

    Each rod pair is split in two halves, one moving with the slider and one with the
    platform: the platform-side mass translates with the TCP, the slider-side mass moves
    with q_j. Kinetic energy 1/2 m_0 |s_dot|^2 + 1/2 m_q |J s_dot|^2 gives
    M = m_0 I + m_q J^T J.
    """

    platform_kg: float = 8.0
    slider_kg: float = 1.0
    rod_pair_kg: float = 0.4

    @property
    def translating_kg(self) -> float:
        return self.platform_kg + 3 * self.rod_pair_kg / 2

    @property
    def per_actuator_kg(self) -> float:
        return self.slider_kg + self.rod_pair_kg / 2


def cartesian_mass_matrix(jac: np.ndarray, masses: LumpedMasses) -> np.ndarray:
    return masses.translating_kg * np.eye(3) + masses.per_actuator_kg * (jac.T @ jac)


def mass_ellipsoid(jac: np.ndarray, masses: LumpedMasses) -> Ellipsoid:
    """Forces needed for a unit acceleration norm: shape M^2 (semi-axes = eigenvalues of M)."""
    m = cartesian_mass_matrix(jac, masses)
    return _ellipsoid_from_shape(m @ m)


@dataclass(frozen=True)
class JacobianIndices:
    condition_number: float
    sigma_min: float
    sigma_max: float
    det: float


def jacobian_indices(jac: np.ndarray) -> JacobianIndices:
    sv = np.linalg.svd(jac, compute_uv=False)
    return JacobianIndices(
        condition_number=float(sv[0] / sv[-1]),
        sigma_min=float(sv[-1]),
        sigma_max=float(sv[0]),
        det=float(np.linalg.det(jac)),
    )


def contact_force_from_efforts(
    jac: Matrix3, efforts_n: tuple[float, ...], qdd: tuple[float, ...], masses: LumpedMasses | None
) -> tuple[Vector3, float]:
    """The contact force on the tool the drives' efforts imply, F = M a - J^T tau, and |M a| [N].

    For any translational robot with prismatic actuators and q_dot = J s_dot (``jac``, 3 x 3 rows):
    virtual work balances efforts tau at the carriages with J^T tau at the TCP; the motors push
    against a contact force (tau = -J^-T F when static) and accelerate the robot's own masses,
    M = m_0 I + m_q J^T J, at a = J^-1 q_dot_dot. Plain floats: a ``ForceWitnessModel`` calls it
    every cycle (Cheope's, controller/robots/cheope/model.py).
    """
    jt = transpose3(jac)
    push = matvec(jt, (efforts_n[0], efforts_n[1], efforts_n[2]))  # J^T tau
    inertia: Vector3 = (0.0, 0.0, 0.0)
    if masses is not None and any(qdd):
        a = matvec(inverse3(jac), (qdd[0], qdd[1], qdd[2]))
        jtja = matvec(jt, (qdd[0], qdd[1], qdd[2]))  # J^T (J a)
        m0, mq = masses.translating_kg, masses.per_actuator_kg
        inertia = (m0 * a[0] + mq * jtja[0], m0 * a[1] + mq * jtja[1], m0 * a[2] + mq * jtja[2])
    force = (inertia[0] - push[0], inertia[1] - push[1], inertia[2] - push[2])
    return force, math.sqrt(inertia[0] ** 2 + inertia[1] ** 2 + inertia[2] ** 2)
