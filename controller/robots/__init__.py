"""The robots the product ships, one home each (``cheope/``, ``uru/``, ``nspu/``): model, section and
entry, simulator hook, 3D scene, analysis, commands and configuration of one robot together, found by
entry points (pyproject.toml) as a plug-in's are. ``performance.py``: the mass and stiffness
ellipsoids of any translational robot with prismatic actuators (its Jacobian and lumped masses)."""
