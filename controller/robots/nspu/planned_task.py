"""The 3-nSPU's planned task registered (entry point cheope.tasks: planned): the planner's plan
(controller/robots/nspu/planning/) streamed as leg setpoints (planned_legs.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from controller.tasks.registry import BuiltTask, TaskEntry, TaskSettings

if TYPE_CHECKING:  # the tasks load on demand, when one is built: the configuration loads without them
    from controller.core.ports import Robot

# -- the circle path ----------------------------------------------------------------------------


def build_planned_task(_: None, robot: Robot, shared: TaskSettings) -> BuiltTask:
    from controller.robots.nspu.planned_legs import build_planned_legs_task

    task, report = build_planned_legs_task(
        shared.robot_section,  # [robot.nspu]: the planner's settings are the robot's
        shared.units,
        shared.settle_tolerance_m,
        robot,
        tracker=shared.tracker_enabled,
    )
    return BuiltTask(task, (report,))


PLANNED = TaskEntry(kind="planned", section=None, build=build_planned_task)
