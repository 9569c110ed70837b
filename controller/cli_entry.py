"""The ``cheope`` command's entry point (pyproject.toml ``[project.scripts]``).

Importing the command (controller/cli.py: python-can, canopen, numpy, the robots) takes about a
second, and building the parser (its commands' imports) a few tenths more; a Ctrl-C in either ended
in a traceback of whichever line it hit. Here both are inside the handling ``cli.main`` gives a
Ctrl-C in a command: one line, exit status 130.
"""

from __future__ import annotations

import sys


def main() -> int:
    try:
        from controller.cli import main as command

        # cli.main handles a Ctrl-C from the command's start; this, until then (the parser's imports)
        return command()
    except KeyboardInterrupt:
        print("cheope: interrupted", file=sys.stderr)
        return 130
