"""The remote command gate's bound on set_force: the running task's own limit (issue 38, item 5).

Before, a set_force was checked against safety.max_contact_force_n (60 N): during a contour
``cheope command set_force 45`` was accepted and the task faulted 2.1 s later at its own 40 N.
"""

from __future__ import annotations

import math
import re
import threading
from dataclasses import replace

import pytest

from controller.assembly import build_law
from controller.config import load_config
from controller.config_schema import ConfigError
from controller.core.cycle_data import Command, CycleInputs, DriveFeedback, SensorFeedback
from controller.core.ports import ForceSetpointLimit, ForceSetpointTask, TaskContext
from controller.core.setpoint_smoothing import Setpoint
from controller.monitoring.command_gate import decide_command
from controller.monitoring.publisher import monitoring_publisher
from controller.shell.service import publisher_settings

CONTOUR = {"task.kind": "contour"}


def _limit(**overrides: object) -> ForceSetpointLimit:
    task = build_law(load_config(overrides={**CONTOUR, **overrides})).task
    assert isinstance(task, ForceSetpointTask)
    return task.force_setpoint_limit()


def test_the_contours_limit_is_its_admittance_saturation_when_below_its_force_limit() -> None:
    limit = _limit()  # 0.5 x 60 N = 30 N of saturation, 40 N of task.contour.max_force_n
    assert limit.below_n == pytest.approx(30.0 / 1.3)  # the setpoint's band of 30 % below the saturation
    assert "admittance_saturation_fraction" in limit.why and "task.contour.max_force_n = 40 N" in limit.why


def test_the_contours_limit_is_its_force_limit_when_the_saturation_is_above_it() -> None:
    limit = _limit(**{"task.contour.admittance_saturation_fraction": 1.0})  # 60 N of saturation
    assert limit.below_n == pytest.approx(40.0 / 1.3) and "task.contour.max_force_n = 40 N" in limit.why


@pytest.mark.parametrize("value", [45.0, 40.0, 30.0, 29.0, 23.1, 1e9, math.inf, math.nan, 0.0, -1.0])
def test_set_force_at_or_above_the_tasks_limit_is_refused_naming_it(value: float) -> None:
    """45 N: the issue's case, accepted before against the 60 N of safety.max_contact_force_n."""
    decision = decide_command("set_force", value, True, _limit(), "contour")
    assert not decision.accepted and not decision.forward
    assert "below 23.0769 N" in decision.message and "task.contour.max_force_n = 40 N" in decision.message
    assert "less the force's band of 30% above the setpoint" in decision.message


@pytest.mark.parametrize("value", [1.001, 10.0, 23.0])
def test_set_force_within_the_tasks_limits_is_forwarded_to_the_law(value: float) -> None:
    assert decide_command("set_force", value, True, _limit(), "contour").forward


@pytest.mark.parametrize("value", [0.3, 1.0, 1e-3])
def test_set_force_at_or_below_the_contact_lost_force_is_refused_naming_it(value: float) -> None:
    """0.3 N: an outside tester's, accepted though the configured setpoint must exceed
    task.contour.contact_lost_force_n (1 N): the task would take the force it asked for as contact lost."""
    decision = decide_command("set_force", value, True, _limit(), "contour")
    assert not decision.accepted and not decision.forward
    assert "must be above 1 N" in decision.message
    assert "task.contour.contact_lost_force_n = 1 N" in decision.message


def test_the_configured_setpoint_and_a_remote_one_have_the_same_floor() -> None:
    """One rule (ForceSetpointLimit.accepts): the configured floor moved, the gate's moves with it."""
    raised = {"task.contour.contact_lost_force_n": 3.0}
    assert not decide_command("set_force", 2.5, True, _limit(**raised), "contour").accepted
    assert decide_command("set_force", 3.5, True, _limit(**raised), "contour").forward
    with pytest.raises(ConfigError, match="contact_lost_force_n"):
        build_law(load_config(overrides={**CONTOUR, **raised, "task.contour.force_setpoint_n": 2.5}))


def test_a_task_without_a_force_setpoint_refuses_set_force() -> None:
    decision = decide_command("set_force", 5.0, True, None, "path")
    assert not decision.accepted and "the task path takes no force setpoint" in decision.message


def test_the_publisher_takes_the_running_tasks_limit() -> None:
    # a lower limit of the task's asks for a slower search (controller/core/contact_budget.py)
    lower = {"task.contour.max_force_n": 20.0, "task.contour.search_speed_m_s": 0.005}
    for overrides, below in (({}, 30.0 / 1.3), (lower, 20.0 / 1.3)):
        cfg = load_config(overrides={**CONTOUR, **overrides})
        pub = monitoring_publisher(publisher_settings(cfg), threading.Event(), build_law(cfg).task)
        assert pub.force_limit is not None and pub.force_limit.below_n == pytest.approx(below)
    path = load_config(overrides={"task.kind": "path"})
    assert (
        monitoring_publisher(publisher_settings(path), threading.Event(), build_law(path).task).force_limit
        is None
    )


def test_the_step_takes_no_setpoint_at_or_above_the_limit() -> None:
    """A second line behind the gate: the pure step keeps its setpoint for a value it cannot track."""
    from controller.tasks.contour_tracking import ContourPhase, ContourTrackingTask

    task = build_law(load_config(overrides=CONTOUR)).task
    assert isinstance(task, ContourTrackingTask)
    tracking = replace(task.start(), phase=ContourPhase.TRACKING, p_cmd=(0.07, 0.0, 0.5))
    sensor = SensorFeedback((10.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 1, True)
    drives = tuple(DriveFeedback(0x1637, 0.55, True) for _ in range(3))

    def setpoint_after(value: float) -> float:
        inputs = CycleInputs(drives, sensor, command=Command.SET_FORCE, command_value=value)
        ctx = TaskContext(1.0, 0.0025, Setpoint.at_rest((0.55,) * 3), inputs, (0.07, 0.0, 0.5))
        return float(task.step(tracking, ctx).state.force_setpoint_n)

    assert setpoint_after(45.0) == tracking.force_setpoint_n
    assert setpoint_after(25.0) == tracking.force_setpoint_n  # its band would reach over the saturation
    assert setpoint_after(0.3) == tracking.force_setpoint_n  # it would read as contact lost
    assert setpoint_after(20.0) == 20.0


def test_the_other_gated_commands_ignore_the_value() -> None:
    for name in ("pause", "resume", "reset"):
        assert decide_command(name, 1e9, True, None).forward


@pytest.mark.parametrize(
    ("overrides", "refused"),
    [
        # an outside tester's: 29 N under a saturation of 30 N crawled at 5 mm/s and stalled, 22 N off
        ({"task.contour.force_setpoint_n": 29.0}, "force_setpoint_n = 29 N refused: must be above 1 N"),
        # the limits lowered, the setpoint kept: 10 N at a saturation of 0.5 x 20 N
        (
            {
                "safety.max_contact_force_n": 20.0,
                "safety.contact.guarded_move_force_n": 10.0,
                "task.contour.max_force_n": 10.0,
                "task.contour.force_setpoint_n": 9.0,
                "task.contour.search_speed_m_s": 0.002,
            },
            "force_setpoint_n = 9 N refused: must be above 1 N, task.contour.contact_lost_force_n = 1 N "
            "(the task takes a force below it for contact lost), and below 7.69231 N",
        ),
    ],
)
def test_a_configured_setpoint_whose_band_reaches_the_saturation_is_refused(
    overrides: dict[str, object], refused: str
) -> None:
    with pytest.raises(ConfigError, match=re.escape(refused)):
        build_law(load_config(overrides={**CONTOUR, **overrides}))
    build_law(load_config(overrides={**CONTOUR, "task.contour.force_setpoint_n": 23.0}))
