"""Cheope in the simulator (entry point cheope.sim_kinematics): rigid kinematics from its drives'
positions; its iron-core motors' cogging loads the compliant structure (sim_backend/plant.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sim_backend.plant_kinematics import PlantKinematics, RigidKinematics

if TYPE_CHECKING:
    from controller.config import Config


def cheope_kinematics(cfg: Config, robot: Any) -> PlantKinematics:
    return RigidKinematics(robot, cfg.sim.drive.initial_positions_m, cogging=True)
