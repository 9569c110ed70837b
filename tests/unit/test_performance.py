"""Seed 001 §6 indices, derived again from q_dot = J s_dot and virtual work."""

from __future__ import annotations

import numpy as np
import pytest

from controller.robots.cheope.model import CheopeGeometry, jacobian
from controller.robots.performance import (
    MassModel,
    cartesian_mass_matrix,
    cartesian_stiffness,
    force_ellipsoid,
    jacobian_indices,
    mass_ellipsoid,
    stiffness_ellipsoid,
    velocity_ellipsoid,
)

GEOM = CheopeGeometry()
CENTRE = np.array([0.0, 0.0, 0.5])
RNG = np.random.default_rng(7)


def _unit(v):
    return v / np.linalg.norm(v)


def test_velocity_ellipsoid_is_the_image_of_unit_actuator_speeds():
    jac = jacobian(GEOM, CENTRE)
    ell = velocity_ellipsoid(jac)
    for _ in range(50):
        u = _unit(RNG.normal(size=3))
        # the largest TCP speed along u with |J s_dot| = 1 is 1 / |J u|
        assert ell.reach(u) == pytest.approx(1.0 / np.linalg.norm(jac @ u), rel=1e-9)


def test_force_ellipsoid_satisfies_virtual_work():
    jac = jacobian(GEOM, CENTRE)
    ell = force_ellipsoid(jac)
    for _ in range(50):
        tau = _unit(RNG.normal(size=3))
        force = jac.T @ tau  # F = J^T tau
        s_dot = RNG.normal(size=3)
        assert force @ s_dot == pytest.approx(tau @ (jac @ s_dot), rel=1e-12)  # power balance
        # a unit actuator force vector lands on the ellipsoid's surface
        assert np.linalg.norm(force) == pytest.approx(ell.reach(force), rel=1e-9)


def test_stiffness_matches_a_small_displacement():
    k = 2.0e6
    jac = jacobian(GEOM, CENTRE)
    stiffness = cartesian_stiffness(jac, k)
    ds = 1e-6 * _unit(np.array([0.3, -0.2, 0.9]))
    tau = k * (jac @ ds)  # actuator springs stretched by dq = J ds
    assert np.allclose(jac.T @ tau, stiffness @ ds, rtol=1e-12)
    ell = stiffness_ellipsoid(jac, k)
    assert np.allclose(np.sort(ell.semi_axes), np.sort(k * np.linalg.svd(jac, compute_uv=False) ** 2))


def test_paper_section6_anisotropy():
    # seed 001 §6: more force along X than Y, more speed along Y than X, less stiffness along Y,
    # and the equivalent mass along X larger than along Y; at several heights and points.
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    for p in ([0, 0, 0.45], [0, 0, 0.5], [0, 0, 0.55], [0.04, -0.03, 0.5]):
        jac = jacobian(GEOM, np.array(p))
        assert force_ellipsoid(jac).reach(ex) > force_ellipsoid(jac).reach(ey)
        assert velocity_ellipsoid(jac).reach(ey) > velocity_ellipsoid(jac).reach(ex)
        assert stiffness_ellipsoid(jac, 1e6).reach(ey) < stiffness_ellipsoid(jac, 1e6).reach(ex)
        assert mass_ellipsoid(jac, MassModel()).reach(ex) > mass_ellipsoid(jac, MassModel()).reach(ey)


def test_mass_matrix_reproduces_kinetic_energy():
    m = MassModel(platform_kg=2.0, slider_kg=1.5, rod_pair_kg=0.4)
    jac = jacobian(GEOM, CENTRE)
    s_dot = np.array([0.1, -0.2, 0.05])
    q_dot = jac @ s_dot
    energy = 0.5 * m.translating_kg * s_dot @ s_dot + 0.5 * m.per_actuator_kg * q_dot @ q_dot
    assert 0.5 * s_dot @ cartesian_mass_matrix(jac, m) @ s_dot == pytest.approx(energy, rel=1e-12)


def test_indices_agree_with_numpy():
    jac = jacobian(GEOM, CENTRE)
    ind = jacobian_indices(jac)
    assert ind.condition_number == pytest.approx(np.linalg.cond(jac))
    assert ind.det == pytest.approx(np.linalg.det(jac))
    assert ind.sigma_min * ind.condition_number == pytest.approx(ind.sigma_max)
