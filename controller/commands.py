"""A command a plug-in brings to ``cheope``: declared under the entry-point group ``cheope.commands``.

The entry point's name is the command's (``cheope NAME``); its object a ``Command``. The command line
(controller/cli.py) adds one sub-command per entry point, with the configuration options every
command has (``--config``, ``--set``, ``--robot``) when the command reads a configuration, and calls
``run`` with the parsed arguments and the loaded configuration. The 3-nSPU's planner commands are
declared so (``cheope plan``, ``cheope plan-bench``: controller/robots/nspu/commands.py).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from controller.plugins import COMMANDS_GROUP, Hooks

if TYPE_CHECKING:
    from controller.config import Config


@dataclass(frozen=True)
class Command:
    help: str  # one line of plain text (a % is a percent sign), shown by ``cheope --help``
    # (the command's parser) -> None: its own arguments, besides the configuration's
    add_arguments: Callable[[argparse.ArgumentParser], None]
    # (args, the configuration) -> exit status; raise ConfigError (or any InputError) to refuse
    run: Callable[[argparse.Namespace, Config], int]
    # The robots whose configuration it reads (the --robot choices; the first is the default without
    # --robot or --config; a configuration of another robot is refused naming them); () any robot.
    robots: tuple[str, ...] = ()


COMMANDS = Hooks(COMMANDS_GROUP, "Command", Command)


def plugin_commands() -> dict[str, Command]:
    """Every command declared under ``cheope.commands`` (or registered), by name."""
    found: dict[str, Command] = COMMANDS.all()
    return dict(sorted(found.items()))
