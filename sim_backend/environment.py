"""The environment the simulated robot touches: the seam for contact models.

An environment maps the TCP's position and velocity to the wrench it receives. Free space
gives none; the contact-tracking issue adds a rigid disk with a contact model here.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

ZERO3 = np.zeros(3)


class Environment(Protocol):
    def contact_wrench(self, tcp_m: np.ndarray, tcp_velocity_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Force [N] and torque [N m] on the tool, in the base frame."""
        ...


class FreeSpace:
    def contact_wrench(self, tcp_m: np.ndarray, tcp_velocity_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return ZERO3, ZERO3
