"""How the controller starts a Python child process (the simulator, the CPU shield's guardian, the
status line) so that the child runs the same code as its parent.

``python -m`` puts the working directory first on the module path: started from inside another
checkout of this project, the child would import that checkout's packages (a simulator of other
code beside this controller, or none: "No module named ..."). ``-P`` (Python 3.11) leaves the
working directory out, and ``PYTHONPATH`` names this code's root first. The recording's writer
does the same in ``logs/recorder.py`` (``logs`` does not import the controller).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

REPO = str(Path(__file__).resolve().parents[1])


def python_module_command(module: str, *args: str) -> list[str]:
    """``python -P -m module args...`` with this process's interpreter."""
    return [sys.executable, "-P", "-m", module, *args]


def child_environment(**extra: str) -> dict[str, str]:
    """This process's environment with this code's root first on ``PYTHONPATH``, and ``extra``."""
    path = os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}
