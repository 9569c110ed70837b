"""Settings for tests that run the controller and the simulator as processes on a busy machine.

The test run starts other processes meanwhile, on two cores without real-time priorities,
so a few late cycles or a TPDO a few cycles late is expected; these tests check behaviour
(plumbing, commands, recordings), not timing, which `cheope bench` measures.
"""

TOLERANT = ["--set", "loop.max_missing_cycles=10", "--set", 'safety.on_late_cycles="warn"']
