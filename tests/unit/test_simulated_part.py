"""The simulated part's contact within what the simulator's substep integrates (sim_backend/plant.py)."""

from __future__ import annotations

import pytest

from controller.config import load_config
from sim_backend.environment import FreeSpace
from sim_backend.plant import RobotPlant, environment_named

STIFF = {
    "task.kind": "contour",
    "sim.workpiece.contact_stiffness_n_m": 1e10,
    "sim.workpiece.sensor_stiffness_n_m": 1e10,
}


def test_a_part_too_stiff_for_the_substep_is_refused_naming_the_keys_and_the_substep_it_needs():
    """An outside tester's 1e10 N/m part at the 0.5-ms substep read 4 907 N and threw the TCP 2.7 m
    (44dbcbc): refused at the start; a substep short enough integrates it."""
    cfg = load_config(overrides={**STIFF, "sim.environment": "workpiece"})
    with pytest.raises(
        ValueError, match=r"too stiff .* in series 5e\+09 N/m.* need sim.drive.substep_s <= 4.\de-05 s"
    ):
        RobotPlant(cfg)
    RobotPlant(load_config(overrides={**STIFF, "sim.environment": "workpiece", "sim.drive.substep_s": 4e-5}))
    RobotPlant(
        load_config(overrides={"task.kind": "contour", "sim.environment": "workpiece"})
    )  # the defaults


def test_a_part_announced_after_the_start_is_checked_alike():
    """sim.environment = "auto": the part comes when the controller's task announces it."""
    cfg = load_config(overrides=STIFF)
    plant = RobotPlant(cfg, FreeSpace())  # free space: nothing to integrate
    with pytest.raises(ValueError, match="too stiff"):
        plant.set_environment(environment_named(cfg, "workpiece"))
