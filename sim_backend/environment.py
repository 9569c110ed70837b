"""The environment the simulated robot touches: the seam for contact models.

An environment maps the TCP's position and velocity to the force it receives. Free space
gives none; ``contact_disk.py`` is the workpiece of the contour experiment. Plain floats: the
plant calls it every sub-step. The contact is a point at the TCP, where the sensor's frame is
centred, so it puts no torque on the sensor.
"""

from __future__ import annotations

from typing import Protocol

Vector3 = tuple[float, float, float]
NO_FORCE: Vector3 = (0.0, 0.0, 0.0)


def series_stiffness_n_m(contact_stiffness_n_m: float, sensor_stiffness_n_m: float) -> float:
    """The part's contact spring and the force sensor's in series: what the tool meets."""
    return 1.0 / (1.0 / contact_stiffness_n_m + 1.0 / sensor_stiffness_n_m)


class Environment(Protocol):
    def contact_force(self, x_m: float, y_m: float, z_m: float, vx_m_s: float, vy_m_s: float) -> Vector3:
        """Force [N] on the tool at TCP (x, y, z) moving at (vx, vy) in XY, in the base frame."""
        ...


class FreeSpace:
    def contact_force(self, x_m: float, y_m: float, z_m: float, vx_m_s: float, vy_m_s: float) -> Vector3:
        return NO_FORCE
