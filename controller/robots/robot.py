"""What a robot model is to the controller: the interface every registered robot implements.

Positions ``q`` are in actuator units (m for linear, rad for rotary actuators, see
``ActuatorUnit``); poses and points in metres in the base frame.
"""

from __future__ import annotations

from enum import StrEnum
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:  # annotations only: the registry and the configuration load without numpy
    import numpy as np

    from controller.robots.cheope import PoseStatus


class ActuatorUnit(StrEnum):
    """The position unit of a robot's actuators; it selects the ``_m`` or ``_rad`` limit keys."""

    METRE = "m"
    RADIAN = "rad"


class Robot(Protocol):
    """A parallel robot's model: kinematics and the checks the law and the service make."""

    @property
    def n_actuators(self) -> int: ...  # read-only: the models are frozen dataclasses

    def inverse_kinematics(self, tcp_m: np.ndarray, /) -> np.ndarray:
        """Actuator positions for a TCP position; raises NoSolutionError outside the workspace."""
        ...

    def direct_kinematics(self, q: np.ndarray, /) -> np.ndarray:
        """The TCP position for actuator positions; raises NoSolutionError where there is none."""
        ...

    def check_pose(self, tcp_m: np.ndarray, /) -> PoseStatus:
        """Every cycle, on the task's reference: inside the safe workspace and margins?"""
        ...

    def check_path(self, points_m: np.ndarray, /) -> None:
        """Before a run, on a whole path: raises WorkspaceError naming the first bad sample."""
        ...
