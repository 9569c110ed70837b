"""How the controller starts a Python child process (the simulator, the CPU shield's guardian, the
status line) so that the child runs the same code as its parent, and what a child has cost.

``python -m`` puts the working directory first on the module path: started from inside another
checkout of this project, the child would import that checkout's packages (a simulator of other
code beside this controller, or none: "No module named ..."). ``-P`` (Python 3.11) leaves the
working directory out, and ``PYTHONPATH`` names this code's root first. The recording's writer
does the same in ``logs/recorder.py`` (``logs`` does not import the controller).
"""

from __future__ import annotations

import ctypes
import math
import os
import signal
import sys
from pathlib import Path

REPO = str(Path(__file__).resolve().parents[1])
PARENT_ENV = "CHEOPE_PARENT_PID"  # set by a parent whose child must not outlive it (end_with_parent)
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def python_module_command(module: str, *args: str) -> list[str]:
    """``python -P -m module args...`` with this process's interpreter."""
    return [sys.executable, "-P", "-m", module, *args]


def exit_text(returncode: int) -> str:
    """A child's exit status as words: "exited with status 1", "killed by SIGKILL"."""
    if returncode >= 0:
        return f"exited with status {returncode}"
    try:
        return f"killed by {signal.Signals(-returncode).name}"
    except ValueError:
        return f"killed by signal {-returncode}"


def child_environment(**extra: str) -> dict[str, str]:
    """This process's environment with this code's root first on ``PYTHONPATH``, and ``extra``."""
    path = os.pathsep.join(p for p in (REPO, os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}


def process_cpu_s(pid: int | None) -> float:
    """user + system CPU time of ``pid`` from /proc [s] (nan when unknown: no pid, or gone)."""
    if pid is None:
        return math.nan
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            fields = f.read().rsplit(b")", 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def ending_with_parent() -> dict[str, str]:
    """The environment entry that makes a child calling ``end_with_parent`` end with this process."""
    return {PARENT_ENV: str(os.getpid())}


def end_with_parent() -> None:
    """In a child started with ``ending_with_parent()``: a SIGTERM (an orderly stop) when the
    parent ends, however it ends. A ``cheope demo`` killed with SIGKILL left its simulator running
    for ever under init, 390 MB and its shared-memory block with it (an outside tester's finding).
    The kernel sends it when the thread that started this process ends: the demo starts its
    simulator from its main thread. Linux only; elsewhere nothing."""
    parent = os.environ.get(PARENT_ENV, "")
    if not parent.isdigit() or not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
            return  # refused (errno): the child lives as before
    except (OSError, AttributeError):
        return
    if os.getppid() != int(parent):  # gone before the prctl: the signal would never come
        os.kill(os.getpid(), signal.SIGTERM)


def parent_is_gone() -> bool:
    """Whether the parent named by ``ending_with_parent`` has ended (False for any other process)."""
    parent = os.environ.get(PARENT_ENV, "")
    return parent.isdigit() and os.getppid() != int(parent)
