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
    "safety.contact.cell_stiffness_n_m": 5e9,  # declared as it is: a stiffer part than told is refused too
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


@pytest.mark.parametrize("start_m", [500.0, 1e300, -215.0])
def test_a_start_the_encoder_cannot_report_is_refused_naming_the_keys(start_m):
    """An outside tester's sim.drive.initial_positions_m = [500, 0.5, 0.5]: a struct.error traceback
    from the first TPDO's pack, naming no key. 2**31 counts at 1e7 counts/m is 214.7 m."""
    cfg = load_config(overrides={"sim.drive.initial_positions_m": [0.6, start_m, 0.5]})
    with pytest.raises(ValueError, match=r"drive 2 starts at .*sim.drive.initial_positions_m.*INTEGER32"):
        RobotPlant(cfg, FreeSpace())
    RobotPlant(load_config(overrides={"sim.drive.initial_positions_m": [0.6, 214.0, 0.5]}), FreeSpace())


class _Wedge:
    """A part that holds the tool between two walls: 40 N each, 5 N of sum (what the sensor feels)."""

    last_max_normal_force_n = 40.0

    def contact_force(self, x_m: float, y_m: float, z_m: float, vx_m_s: float, vy_m_s: float):
        return (3.0, 4.0, 0.0)


class _OneWall(_Wedge):
    last_max_normal_force_n = 0.0


@pytest.mark.parametrize(("part", "load_n"), [(_Wedge(), 40.0), (_OneWall(), 5.0)])
def test_the_load_on_the_part_is_the_most_one_contact_presses_not_the_sum_the_sensor_feels(part, load_n):
    """The scans judge the true force by ``contact_load_n``: a ball wedged in a notch narrower than it
    presses each wall harder than the sum of both (workpiece.py)."""
    plant = RobotPlant(load_config(overrides={"task.kind": "contour"}), part)
    plant.advance(1.0)
    plant.advance(1.0025)
    assert plant.force_n.tolist() == [3.0, 4.0, 0.0]
    assert plant.contact_load_n == pytest.approx(load_n)
