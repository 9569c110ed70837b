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

from sim_backend.environment import ZERO3

EZ = np.array([0.0, 0.0, 1.0])


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
        return 1.0 / (1.0 / self.contact_stiffness_n_m + 1.0 / self.sensor_stiffness_n_m)


class DiskEnvironment:
    def __init__(self, params: DiskParams) -> None:
        self.params = params
        self._centre = np.array([params.centre_m[0], params.centre_m[1], 0.0])

    def contact_wrench(self, tcp_m: np.ndarray, tcp_velocity_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        if abs(tcp_m[2] - p.height_m) > p.thickness_m / 2 + p.tool_radius_m:
            return ZERO3, ZERO3
        radial = tcp_m - self._centre
        radial[2] = 0.0
        dist = math.hypot(radial[0], radial[1])
        penetration = p.radius_m + p.tool_radius_m - dist
        if penetration <= 0.0 or dist < 1e-9:
            return ZERO3, ZERO3
        n = radial / dist
        vn = float(tcp_velocity_m_s @ n)
        fn = p.series_stiffness_n_m * penetration - p.contact_damping_n_s_m * vn
        if fn <= 0.0:
            return ZERO3, ZERO3
        t = np.cross(EZ, n)
        vt = float(tcp_velocity_m_s @ t)
        friction = -p.friction_coefficient * fn * math.tanh(vt / p.friction_velocity_m_s)
        return fn * n + friction * t, ZERO3

    def contour_points(self, n: int = 180) -> np.ndarray:
        """The disk's rim (for plots and viewers)."""
        th = np.linspace(0, 2 * np.pi, n)
        p = self.params
        return np.column_stack([p.centre_m[0] + p.radius_m * np.cos(th), p.centre_m[1] + p.radius_m * np.sin(th),
                                np.full(n, p.height_m)])
