"""Which remote commands a controller accepts: the one list the publisher and the CLI share.

A remote ``stop`` is always accepted (a controlled stop, as Ctrl-C); ``pause``, ``resume``,
``set_force`` (to a task that takes a force setpoint, within that task's own limits) and ``reset`` (leave FAULT,
controller/core/control_law.py) only when the controller was started with ``--allow-remote-commands`` (DESIGN.md: monitoring is read-only,
any other remote command is off unless explicitly enabled). Imports nothing heavy: the
command line's parser uses it.
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.core.ports import ForceSetpointLimit

ALWAYS_ACCEPTED = ("stop",)
GATED_COMMANDS = ("pause", "resume", "set_force", "reset")


@dataclass(frozen=True)
class CommandDecision:
    accepted: bool
    message: str
    forward: bool = False  # hand it to the control law as CycleInputs.command


def decide_command(
    name: str,
    value: float,
    commands_enabled: bool,
    force_limit: ForceSetpointLimit | None,
    task_name: str = "",
) -> CommandDecision:
    """The gate: stop always; the gated commands only when enabled; anything else refused.

    A ``set_force`` needs a task that takes a force setpoint (``force_limit`` not None, the
    running task's ``force_setpoint_limit``), and a value that limit accepts: above the force the
    task takes for contact lost and below the force it can hold and does not fault at (not
    ``safety.max_contact_force_n``, above it).
    """
    if name == "stop":
        return CommandDecision(True, "stop accepted: the controller brings the robot to a controlled stop")
    if name not in GATED_COMMANDS:
        # at most 40 characters of it back: a 1-MB name was echoed whole (an outside tester's finding)
        shown = repr(name) if len(name) <= 40 else f"{name[:40]!r}... ({len(name)} characters)"
        return CommandDecision(False, f"unknown command {shown}; known: stop, {', '.join(GATED_COMMANDS)}")
    if not commands_enabled:
        return CommandDecision(
            False,
            f"command {name!r} refused: remote commands other than stop are disabled "
            "(start the controller with --allow-remote-commands)",
        )
    if name == "set_force" and force_limit is None:
        return CommandDecision(
            False, f"set_force refused: the task {task_name or '(none)'} takes no force setpoint"
        )
    if name == "set_force" and force_limit is not None and not force_limit.accepts(value):
        return CommandDecision(False, f"set_force value {force_limit.refusal(value)}")
    return CommandDecision(True, f"{name} accepted: applied at the next cycle", forward=True)
