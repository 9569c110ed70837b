"""Cheope (seed 001), the contour-tracking robot: everything of it in one place.

``model.py`` (kinematics, Jacobian, singularity measures, the force witness), ``entry.py`` (its section ``[robot.cheope]`` and ``RobotEntry``),
``simulator.py`` (its simulator hook), ``drawing.py`` (its 3D scene), ``analysis.py`` (``cheope
analyze``). Its configuration is the product's default one, controller/configs/cheope.toml, which
every other robot's file overlays. The runtime finds it by entry points (pyproject.toml) and
imports nothing of it by name."""
