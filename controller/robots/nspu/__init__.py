"""The 3-nSPU (seeds 000, 004), the non-holonomic robot: everything of it in one place.

``kinematics.py`` (the paper's model), ``model.py`` (the ``Robot``), ``entry.py`` (``[robot.nspu]``
and its ``RobotEntry``), ``planning/`` (the motion planner of seed 004), ``planned_legs.py``,
``streamed_plan.py``, ``plan_correction.py`` and ``planned_task.py`` (the planned task that streams a
plan), ``simulator.py`` (odometry), ``drawing.py``, ``analysis.py``, ``commands.py`` (``cheope plan``,
``cheope plan-bench``), ``planner_benchmark.py`` and ``nspu.toml`` (``--robot nspu``)."""
