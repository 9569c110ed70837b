"""A rigid disk lying in the XY plane: the workpiece of the contour-tracking experiment.

Seed 001 §7: a round steel disk of 14 cm diameter, centred on the Z axis at 50 cm. Only
the simulator knows where it is; the controller finds it with the force sensor.

Contact with the tool (a sphere of radius ``tool_radius_m``) on the disk's rim: with
penetration d = R + r_tool - |p_xy - c| > 0 and outward normal n, the normal force is
F_n = max(0, k d - c d_dot) with k the series stiffness of the contact and the sensor
(1/k = 1/k_contact + 1/k_sensor); Coulomb friction -mu F_n sign(v_t) t along the tangent,
smoothed over ``friction_velocity_m_s`` so the integration stays stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim_backend.environment import NO_FORCE, Vector3, series_stiffness_n_m


@dataclass(frozen=True)
class DiskParams:
    centre_m: tuple[float, float]
    height_m: float  # z of the disk's mid plane
    radius_m: float
    thickness_m: float
    tool_radius_m: float
    contact_stiffness_n_m: float
    sensor_stiffness_n_m: float
    contact_damping_n_s_m: float
    friction_coefficient: float
    friction_velocity_m_s: float = 1e-3

    @property
    def series_stiffness_n_m(self) -> float:
        return series_stiffness_n_m(self.contact_stiffness_n_m, self.sensor_stiffness_n_m)


class DiskEnvironment:
    def __init__(self, params: DiskParams) -> None:
        self.params = params
        self._k_series = params.series_stiffness_n_m

    def contact_force(self, x_m: float, y_m: float, z_m: float, vx_m_s: float, vy_m_s: float) -> Vector3:
        p = self.params
        if abs(z_m - p.height_m) > p.thickness_m / 2 + p.tool_radius_m:
            return NO_FORCE
        rx, ry = x_m - p.centre_m[0], y_m - p.centre_m[1]
        dist = math.hypot(rx, ry)
        penetration = p.radius_m + p.tool_radius_m - dist
        if penetration <= 0.0 or dist < 1e-9:
            return NO_FORCE
        nx, ny = rx / dist, ry / dist
        fn = self._k_series * penetration - p.contact_damping_n_s_m * (vx_m_s * nx + vy_m_s * ny)
        if fn <= 0.0:
            return NO_FORCE
        tx, ty = -ny, nx  # z x n
        friction = (
            -p.friction_coefficient * fn * math.tanh((vx_m_s * tx + vy_m_s * ty) / p.friction_velocity_m_s)
        )
        return (fn * nx + friction * tx, fn * ny + friction * ty, 0.0)

    def contour_points(self, n: int = 180) -> np.ndarray:
        """The disk's rim (for plots and viewers)."""
        th = np.linspace(0, 2 * np.pi, n)
        p = self.params
        return np.column_stack(
            [
                p.centre_m[0] + p.radius_m * np.cos(th),
                p.centre_m[1] + p.radius_m * np.sin(th),
                np.full(n, p.height_m),
            ]
        )
