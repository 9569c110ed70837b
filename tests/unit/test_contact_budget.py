"""A guarded move's speed against the stiffest contact of the cell (controller/core/contact_budget.py):
the stopping model, the configuration's refusal of a speed that would press past the task's limit,
and the simulator's refusal of a cell stiffer than declared. The model's figures against the
simulator's true forces are in test_contour_safe_by_design.py."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.assembly import build_law
from controller.config import load_config
from controller.config_schema import ConfigError
from controller.core.contact_budget import StoppingModel
from sim_backend.plant import RobotPlant

SHIPPED = StoppingModel(period_s=0.0025, max_acceleration_m_s2=10.0, max_jerk_m_s3=500.0)


def test_the_stop_goes_on_two_periods_then_brakes_within_the_limits() -> None:
    # 10 mm/s at 400 Hz: 2 x 2.5 ms at full speed, 10 / (2 x 500) s of jerk, then v^2 / 20
    assert SHIPPED.distance_m(0.01) == pytest.approx(0.01 * (0.005 + 0.01) + 0.01**2 / 20.0)
    assert SHIPPED.distance_m(0.0) == 0.0
    # against the shipped cell (2.31e5 N/m) what the simulator met (an outside tester's approaches):
    # 54.3 N at 0.02 m/s, within the model's bound; 354 N at 0.08 m/s, eight times faster than the
    # model allows, where it predicts 352 N (the braking there is slower than the actuators' limit)
    assert 54.3 < SHIPPED.peak_force_n(0.02, 1.0, 2.31e5) < 80.0
    assert SHIPPED.peak_force_n(0.08, 1.0, 2.31e5) == pytest.approx(354.0, rel=0.05)


@given(
    budget=st.floats(0.1, 1e4),
    stiffness=st.floats(1e2, 1e10),
    period=st.sampled_from([0.001, 0.0025, 0.004, 0.01]),
)
def test_the_fastest_speed_stops_exactly_at_the_budget(
    budget: float, stiffness: float, period: float
) -> None:
    model = StoppingModel(period, 10.0, 500.0)
    fastest = model.fastest_m_s(budget, stiffness)
    assert fastest > 0.0
    assert math.isclose(model.peak_force_n(fastest, 0.0, stiffness), budget, rel_tol=1e-9)
    assert model.peak_force_n(fastest * 1.001, 0.0, stiffness) > budget


def test_no_budget_no_speed() -> None:
    assert SHIPPED.fastest_m_s(0.0, 2.4e5) == 0.0


def _contour(**overrides: object) -> None:
    build_law(load_config(overrides={"task.kind": "contour", **overrides}))


def test_the_shipped_guarded_speeds_stop_within_the_limit_at_400_hz_and_1_khz() -> None:
    _contour()
    _contour(**{"loop.rate_hz": 1000.0})


@pytest.mark.parametrize("key", ["approach_speed_m_s", "search_speed_m_s"])
def test_a_guarded_speed_that_would_press_past_the_limit_is_refused_naming_the_fastest(key: str) -> None:
    # an outside tester's approach at 0.08 m/s (accepted up to max_contact_speed_m_s) met 354 N
    with pytest.raises(ConfigError) as err:
        _contour(**{f"task.contour.{key}": 0.08})
    text = str(err.value)
    assert text.startswith(f"task.contour.{key} = 0.08 m/s: a guarded move this fast would meet the part")
    assert "max_force_n = 40 N" in text and "cell_stiffness_n_m = 2.4e+05 N/m" in text
    assert "at most 0.01047 m/s" in text


def test_a_stiffer_cell_declared_asks_for_slower_guarded_moves() -> None:
    # a rigid probe mount (1e7) on a steel part (1e8): the shipped search speed is refused
    with pytest.raises(ConfigError, match=r"search_speed_m_s = 0.01 m/s.*at most 0.0002854"):
        _contour(**{"safety.contact.cell_stiffness_n_m": 9.1e6})
    _contour(
        **{
            "safety.contact.cell_stiffness_n_m": 9.1e6,
            "task.contour.search_speed_m_s": 0.00028,
            "task.contour.approach_speed_m_s": 0.00028,
        }
    )


def test_a_slower_loop_sees_the_touch_later_and_asks_for_slower_guarded_moves() -> None:
    with pytest.raises(ConfigError, match=r"search_speed_m_s = 0.01 m/s.*at most 0.005"):
        _contour(**{"loop.rate_hz": 100.0})


def test_the_simulator_refuses_a_part_stiffer_than_the_controller_is_told() -> None:
    # an outside tester's rigid mount on a steel part, with the shipped declaration: 125 N at the
    # shipped speeds. A cell stiffer than declared is no scenario the simulator stages unasked.
    stiff = {
        "task.kind": "contour",
        "sim.environment": "workpiece",
        "sim.workpiece.sensor_stiffness_n_m": 1e7,
        "sim.workpiece.contact_stiffness_n_m": 1e8,
    }
    with pytest.raises(ValueError, match=r"stiffer than the controller is told.*9.09e\+06 N/m, above "):
        RobotPlant(load_config(overrides=stiff))
    declared = {**stiff, "safety.contact.cell_stiffness_n_m": 9.1e6, "task.contour.search_speed_m_s": 0.00028}
    RobotPlant(load_config(overrides={**declared, "task.contour.approach_speed_m_s": 0.00028}))
