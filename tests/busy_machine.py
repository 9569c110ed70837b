"""Settings for tests that run the controller and the simulator as processes on a busy machine.

The test run starts other processes meanwhile, on two cores without real-time priorities,
so a few late cycles or a TPDO a few cycles late is expected; these tests check behaviour
(plumbing, commands, recordings), not timing, which `cheope bench` measures.
"""

# Late cycles warn instead of faulting. A drive's silence keeps the shipped tolerance
# (loop.max_missing_s = 0.1, the drives' own 100-ms SYNC watchdog): 10 cycles, set here when the
# shipped value was lower, made these runs less tolerant than a user's, and a slow host's CI silenced the
# 3-nSPU's drives for 10 cycles (tests/integration/test_nspu_closed_loop_on_the_bus.py).
TOLERANT = ["--set", 'safety.on_late_cycles="warn"']
