"""The 3-URU in the simulator (entry point cheope.sim_kinematics): its direct kinematics by Newton from the
previous pose, the drives starting at its home position."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from sim_backend.plant_kinematics import PlantKinematics, RigidKinematics

if TYPE_CHECKING:
    from controller.config import Config


class UruKinematics(RigidKinematics):
    """Newton from the previous pose: the assembly the platform is in (several exist)."""

    def tcp_m(self, t_s: float | None, q: np.ndarray, previous_tcp_m: np.ndarray) -> np.ndarray:
        guess = previous_tcp_m if np.any(previous_tcp_m) else None
        return np.asarray(self.robot.direct_kinematics(q, guess))


def uru_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    home = np.asarray(cfg.robot.model("uru").home_position_m)
    return UruKinematics(robot, tuple(robot.inverse_kinematics(home).tolist()))
