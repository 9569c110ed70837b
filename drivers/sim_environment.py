"""The simulator's environment object: the controller tells ``cheope sim`` which workpiece its task needs.

The task's world comes from one place, the controller's ``task.kind``: a separately started
``cheope sim`` does not know the task, so at set-up the controller writes the environment its
task expects (``TaskEntry.sim_environment``: "free" or "workpiece") over SDO to this object of the
simulated force sensor, in the manufacturer-specific range (CiA 301: 0x2000-0x5FFF), where no
shipped EDS puts anything. The simulator places it when its own ``sim.environment`` is "auto"
(the default), and refuses the write with an SDO abort when it was configured to something else;
the controller then reads the object back and refuses to start with one line naming both.

A real sensor has no such object (SDO abort 0x06020000, "object does not exist"): the controller
takes that as "no simulator here" and goes on.
"""

from __future__ import annotations

SIM_ENVIRONMENT_INDEX = 0x5FE0
SIM_ENVIRONMENT_SUBINDEX = 0
ENVIRONMENT_CODES = {"free": 0, "workpiece": 1}  # UNSIGNED8
ENVIRONMENT_NAMES = {code: name for name, code in ENVIRONMENT_CODES.items()}
# CiA 301 SDO abort codes
ABORT_OBJECT_DOES_NOT_EXIST = 0x06020000
ABORT_VALUE_RANGE_CODE = 0x06090030  # value range of parameter exceeded
ABORT_DEVICE_STATE = 0x08000022  # data cannot be transferred or stored because of the present device state

ENVIRONMENT_WORDS = {"free": "free space", "workpiece": "the contour task's workpiece"}


def mismatch_message(simulator: str, expected: str, task_kind: str) -> str:
    """The one line a refused start prints."""
    return (
        f"the simulator has {ENVIRONMENT_WORDS.get(simulator, simulator)} (its sim.environment = "
        f'"{simulator}"), task.kind = "{task_kind}" needs {ENVIRONMENT_WORDS.get(expected, expected)}: '
        f'start cheope sim with sim.environment = "auto" (the default: the controller\'s task decides) '
        f'or "{expected}"'
    )
