"""The ``cheope`` command's entry point (pyproject.toml ``[project.scripts]``).

Importing the command (controller/cli.py: python-can, canopen, numpy, the robots) takes about a
second, and building the parser (its commands' imports) a few tenths more; a Ctrl-C in either ended
in a traceback of whichever line it hit. Here both are inside the handling ``cli.main`` gives a
Ctrl-C in a command: one line, exit status 130. So is a refusal before the command runs: the
parser lists the robots and tasks of every plug-in, and one that does not load stopped it with
a traceback (its one line, naming the distribution and entry point, was its last).
"""

from __future__ import annotations

import sys

from controller.errors import CheopeError


def main() -> int:
    try:
        from controller.cli import main as command

        # cli.main handles a Ctrl-C from the command's start; this, until then (the parser's imports)
        return command()
    except KeyboardInterrupt:
        print("cheope: interrupted", file=sys.stderr)
        return 130
    except CheopeError as err:  # before a command runs: a plug-in that does not load, named (own-robot.md)
        print(f"cheope: error: {err}", file=sys.stderr)
        return 2
