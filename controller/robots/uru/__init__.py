"""The 3-URU (seed 003): everything of it in one place.

``kinematics.py`` (the paper's equations), ``model.py`` (the ``Robot``: motor angles, checks),
``entry.py`` (``[robot.uru]`` and its ``RobotEntry``), ``simulator.py``, ``drawing.py``,
``analysis.py`` (workspace and singularity sections) and ``uru.toml`` (``--robot uru``)."""
